//! The shader, the world's compute pipelines (one per kernel, made for its scene) and the bind
//! groups they run with.

use wgpu::util::DeviceExt;

use super::buffers::{Buffers, FRAME_BYTES, MAIN_BINDINGS};
use crate::scene::{Params, Scene};

/// The shader: its files joined in order (each names what it holds). A compilation error
/// names a line of the joined text; the test `shader` names the file and its line.
macro_rules! shader_files {
    ($($file:literal),* $(,)?) => {
        pub(crate) const SHADER: &str = concat!($(include_str!(concat!("../shaders/", $file))),*);
        /// The shader's files in order, each with its text.
        #[cfg(test)]
        pub(crate) const SHADER_FILES: &[(&str, &str)] =
            &[$(($file, include_str!(concat!("../shaders/", $file)))),*];
    };
}
shader_files!(
    "common.wgsl",
    "contact.wgsl",
    "neighbours.wgsl",
    "walls.wgsl",
    "forces.wgsl",
    "integrate.wgsl",
);

/// The kernels, one pipeline each (the shader's entry points).
pub(super) struct Pipelines {
    pub bin: wgpu::ComputePipeline,
    pub build: wgpu::ComputePipeline,
    pub commit: wgpu::ComputePipeline,
    pub forces: wgpu::ComputePipeline,
    pub euler: wgpu::ComputePipeline,
    pub kick_drift: wgpu::ComputePipeline,
    pub half_kick: wgpu::ComputePipeline,
    pub fastest: wgpu::ComputePipeline,
    pub reduce_loads: wgpu::ComputePipeline,
}

/// The bind groups: the buffers (group 0), the parameters of a step and of the Verlet
/// start-up (group 1), and the frames (group 2, at a dynamic offset).
pub(super) struct Bindings {
    pub main: wgpu::BindGroup,
    pub step_params: wgpu::BindGroup,
    pub start_params: wgpu::BindGroup,
    pub frames: wgpu::BindGroup,
}

/// The layouts of the three groups.
struct Layouts {
    main: wgpu::BindGroupLayout,
    params: wgpu::BindGroupLayout,
    frames: wgpu::BindGroupLayout,
}

impl Layouts {
    fn new(device: &wgpu::Device) -> Layouts {
        let storage_entry = |binding: u32| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: false },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let uniform = |label: &str, dynamic: bool, min_binding_size| {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &[wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: dynamic,
                        min_binding_size,
                    },
                    count: None,
                }],
            })
        };
        let main = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("main"),
            entries: &(0..MAIN_BINDINGS as u32)
                .map(storage_entry)
                .collect::<Vec<_>>(),
        });
        let frames = uniform("frames", true, wgpu::BufferSize::new(FRAME_BYTES));
        let params = uniform("params", false, None);
        Layouts {
            main,
            params,
            frames,
        }
    }
}

impl Bindings {
    fn new(device: &wgpu::Device, layouts: &Layouts, buffers: &Buffers, scene: &Scene) -> Self {
        let frames = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frames"),
            layout: &layouts.frames,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &buffers.frames,
                    offset: 0,
                    size: wgpu::BufferSize::new(FRAME_BYTES),
                }),
            }],
        });
        let main = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("main"),
            layout: &layouts.main,
            entries: &buffers
                .main_group()
                .iter()
                .enumerate()
                .map(|(k, b)| wgpu::BindGroupEntry {
                    binding: k as u32,
                    resource: b.as_entire_binding(),
                })
                .collect::<Vec<_>>(),
        });
        let params_group = |params: &Params| {
            let buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("params"),
                contents: bytemuck::bytes_of(params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("params"),
                layout: &layouts.params,
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: buffer.as_entire_binding(),
                }],
            })
        };
        let step_params = params_group(&scene.params);
        // The Verlet start-up evaluation wants forces only: its springs do not advance.
        let mut start = scene.params;
        start.misc[0] = 0.0;
        let start_params = params_group(&start);
        Bindings {
            main,
            step_params,
            start_params,
            frames,
        }
    }
}

/// `scene`'s pipelines and bind groups over `buffers`: the shader's overridable constants
/// are the scene's ([`Scene::pipeline_constants`]).
pub(super) fn create(
    device: &wgpu::Device,
    scene: &Scene,
    buffers: &Buffers,
) -> (Pipelines, Bindings) {
    let layouts = Layouts::new(device);
    let bindings = Bindings::new(device, &layouts, buffers, scene);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("dem"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("step"),
        bind_group_layouts: &[&layouts.main, &layouts.params, &layouts.frames],
        push_constant_ranges: &[],
    });
    let constants = scene.pipeline_constants();
    let pipeline = |entry: &str| {
        device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: Some(&layout),
            module: &module,
            entry_point: Some(entry),
            compilation_options: wgpu::PipelineCompilationOptions {
                constants: &constants,
                ..Default::default()
            },
            cache: None,
        })
    };
    let pipelines = Pipelines {
        bin: pipeline("bin"),
        build: pipeline("build"),
        commit: pipeline("commit"),
        forces: pipeline("forces"),
        euler: pipeline("euler"),
        kick_drift: pipeline("kick_drift"),
        half_kick: pipeline("half_kick"),
        fastest: pipeline("fastest"),
        reduce_loads: pipeline("reduce_loads"),
    };
    (pipelines, bindings)
}

#[cfg(test)]
mod tests {
    use super::*;
    use wgpu::naga;

    /// The joined shader parses and validates (no GPU needed); an error is reported at its
    /// file and line there.
    #[test]
    fn shader() {
        let place = |location: Option<naga::SourceLocation>| {
            let Some(line) = location.map(|l| l.line_number as usize) else {
                return "the shader".to_string();
            };
            let mut first = 1;
            for (file, text) in SHADER_FILES {
                let lines = text.lines().count();
                if line < first + lines {
                    return format!("{file}:{}", line - first + 1);
                }
                first += lines;
            }
            format!("line {line} of the shader")
        };
        let module = naga::front::wgsl::parse_str(SHADER).unwrap_or_else(|e| {
            panic!(
                "{}: {}",
                place(e.location(SHADER)),
                e.emit_to_string(SHADER)
            )
        });
        let mut validator = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::empty(),
        );
        if let Err(e) = validator.validate(&module) {
            panic!(
                "{}: {}",
                place(e.location(SHADER)),
                e.emit_to_string(SHADER)
            );
        }
    }
}
