//! A world stepped on the GPU: the buffers, the pipelines and the step's dispatch order.

use bytemuck::Pod;
use repose_engine::integrate::Integrator;
use repose_engine::math::Vec3;
use repose_engine::world::World;
use wgpu::util::DeviceExt;

use crate::scene::{
    Grid, Params, Scene, BIN_CAPACITY, NEIGHBOUR_CAPACITY, WALL_CAPACITY, WORKGROUP,
};
use crate::{Gpu, GpuError};

const SHADER: &str = include_str!("shaders/dem.wgsl");

/// Steps encoded into one command buffer.
const STEPS_PER_SUBMIT: u64 = 100;

/// Control words (the shader's `ctl`).
mod ctl {
    pub const REBUILD: usize = 0;
    pub const REBUILDS: usize = 1;
    pub const NEIGHBOUR_OVERFLOW: usize = 2;
    pub const BIN_OVERFLOW: usize = 3;
    pub const REMOVED: usize = 4;
    pub const FASTEST: usize = 5;
    pub const WALL_OVERFLOW: usize = 6;
    pub const WORDS: usize = 8;
}

struct Pipelines {
    clear_bins: wgpu::ComputePipeline,
    bin: wgpu::ComputePipeline,
    build: wgpu::ComputePipeline,
    commit: wgpu::ComputePipeline,
    arm: wgpu::ComputePipeline,
    forces: wgpu::ComputePipeline,
    euler: wgpu::ComputePipeline,
    kick_drift: wgpu::ComputePipeline,
    half_kick: wgpu::ComputePipeline,
    fastest: wgpu::ComputePipeline,
}

struct Buffers {
    cell: wgpu::Buffer,
    off: wgpu::Buffer,
    vel: wgpu::Buffer,
    omg: wgpu::Buffer,
    trq: wgpu::Buffer,
    nbn: wgpu::Buffer,
    ctl: wgpu::Buffer,
    bytes: u64,
}

/// The particles as read back from the GPU, in the CPU world's order and units.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuParticles {
    pub position: Vec<Vec3>,
    pub velocity: Vec<Vec3>,
    pub angular_velocity: Vec<Vec3>,
    pub radius: Vec<f64>,
    /// Removed (left the domain): no longer simulated.
    pub removed: Vec<bool>,
    /// Particle-particle contacts of each particle at the last force evaluation.
    pub contacts: Vec<u32>,
}

/// Counters of the run so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Counters {
    pub rebuilds: u64,
    pub removed: u64,
}

/// A world on the GPU, built from a CPU [`World`] (its particles, materials, static
/// geometries and configuration) and stepped there. Deterministic on one adapter: the same
/// world and steps give the same bits.
pub struct GpuWorld {
    device: wgpu::Device,
    queue: wgpu::Queue,
    grid: Grid,
    integrator: Integrator,
    n: usize,
    radius: Vec<f64>,
    pipelines: Pipelines,
    buffers: Buffers,
    main_group: wgpu::BindGroup,
    step_params: wgpu::BindGroup,
    start_params: wgpu::BindGroup,
    indirect_group: wgpu::BindGroup,
    indirect: wgpu::Buffer,
    time: f64,
    time_step: f64,
    steps: u64,
    forces_current: bool,
    adapter: String,
}

impl std::fmt::Debug for GpuWorld {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuWorld")
            .field("adapter", &self.adapter)
            .field("particles", &self.n)
            .field("time", &self.time)
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

fn groups(count: usize) -> u32 {
    count.div_ceil(WORKGROUP as usize) as u32
}

impl GpuWorld {
    /// Uploads `world` (at its present time) to `gpu`.
    pub fn new(gpu: &Gpu, world: &World) -> Result<GpuWorld, GpuError> {
        let scene = Scene::from_world(world)?;
        let n = scene.cell.len();
        let limits = gpu.limits();
        let largest =
            (n * NEIGHBOUR_CAPACITY * 16).max(scene.grid.cells() * BIN_CAPACITY * 4) as u64;
        if largest > limits.max_storage_buffer_binding_size as u64
            || largest > limits.max_buffer_size
        {
            return Err(GpuError::Capacity(format!(
                "{n} particles need a {largest}-byte buffer; the adapter allows {} bytes \
                 per binding",
                limits.max_storage_buffer_binding_size
            )));
        }
        if groups(n.max(scene.grid.cells())) > limits.max_compute_workgroups_per_dimension {
            return Err(GpuError::Capacity(format!(
                "{n} particles or {} cells exceed {} workgroups of {WORKGROUP}",
                scene.grid.cells(),
                limits.max_compute_workgroups_per_dimension
            )));
        }
        let device = gpu.device.clone();
        let queue = gpu.queue.clone();
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST;
        let mut bytes = 0u64;
        let mut init = |label: &str, contents: &[u8]| {
            bytes += contents.len() as u64;
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: storage,
            })
        };
        let cell = init("cell", bytemuck::cast_slice(&scene.cell));
        let off = init("off", bytemuck::cast_slice(&scene.off));
        let vel = init("vel", bytemuck::cast_slice(&scene.vel));
        let omg = init("omg", bytemuck::cast_slice(&scene.omg));
        let tris_data: Vec<u8> = if scene.tris.is_empty() {
            vec![0u8; 80]
        } else {
            bytemuck::cast_slice(&scene.tris).to_vec()
        };
        let tris = init("tris", &tris_data);
        let pc = init("pairs", bytemuck::cast_slice(&scene.pairs));
        let mut zeroed = |label: &str, size: u64| {
            bytes += size;
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16),
                usage: storage,
                mapped_at_creation: false,
            })
        };
        let n64 = n as u64;
        let frc = zeroed("frc", n64 * 16);
        let trq = zeroed("trq", n64 * 16);
        let disp = zeroed("disp", n64 * 16);
        let list = n64 * NEIGHBOUR_CAPACITY as u64;
        let nbr = zeroed("nbr", list * 4);
        let nbn = zeroed("nbn", n64 * 4);
        let spr = zeroed("spr", list * 16);
        let nbr2 = zeroed("nbr2", list * 4);
        let nbn2 = zeroed("nbn2", n64 * 4);
        let spr2 = zeroed("spr2", list * 16);
        let cells = scene.grid.cells() as u64;
        let bins = zeroed("bins", cells * BIN_CAPACITY as u64 * 4);
        let binn = zeroed("binn", cells * 4);
        let walls = zeroed("walls", n64 * WALL_CAPACITY as u64 * 32);
        let ctl = zeroed("ctl", ctl::WORDS as u64 * 4);
        let indirect = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("indirect"),
            size: 32,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDIRECT,
            mapped_at_creation: false,
        });

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
        let main_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("main"),
            entries: &(0..19).map(storage_entry).collect::<Vec<_>>(),
        });
        let params_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("params"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let indirect_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("indirect"),
            entries: &[storage_entry(0)],
        });
        let all: [&wgpu::Buffer; 19] = [
            &cell, &off, &vel, &omg, &frc, &trq, &disp, &nbr, &nbn, &spr, &nbr2, &nbn2, &spr2,
            &bins, &binn, &walls, &tris, &pc, &ctl,
        ];
        let main_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("main"),
            layout: &main_layout,
            entries: &all
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
                layout: &params_layout,
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
        let indirect_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("indirect"),
            layout: &indirect_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: indirect.as_entire_binding(),
            }],
        });

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("dem.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("step"),
            bind_group_layouts: &[&main_layout, &params_layout],
            push_constant_ranges: &[],
        });
        let arm_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("arm"),
            bind_group_layouts: &[&main_layout, &params_layout, &indirect_layout],
            push_constant_ranges: &[],
        });
        let pipeline = |entry: &str, layout: &wgpu::PipelineLayout| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let pipelines = Pipelines {
            clear_bins: pipeline("clear_bins", &layout),
            bin: pipeline("bin", &layout),
            build: pipeline("build", &layout),
            commit: pipeline("commit", &layout),
            arm: pipeline("arm", &arm_layout),
            forces: pipeline("forces", &layout),
            euler: pipeline("euler", &layout),
            kick_drift: pipeline("kick_drift", &layout),
            half_kick: pipeline("half_kick", &layout),
            fastest: pipeline("fastest", &layout),
        };
        let gpu_world = GpuWorld {
            device,
            queue,
            grid: scene.grid,
            integrator: scene.integrator,
            n,
            radius: scene.radius,
            pipelines,
            buffers: Buffers {
                cell,
                off,
                vel,
                omg,
                trq,
                nbn,
                ctl,
                bytes,
            },
            main_group,
            step_params,
            start_params,
            indirect_group,
            indirect,
            time: world.time(),
            time_step: world.config().time_step,
            steps: 0,
            forces_current: false,
            adapter: gpu.name().to_owned(),
        };
        // The first step builds the neighbour lists.
        gpu_world.write_control(ctl::REBUILD, 1);
        Ok(gpu_world)
    }

    fn write_control(&self, word: usize, value: u32) {
        self.queue.write_buffer(
            &self.buffers.ctl,
            word as u64 * 4,
            bytemuck::bytes_of(&value),
        );
    }

    /// Simulated time, s.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Steps taken on the GPU.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Bytes of device memory the world's buffers take.
    pub fn memory_bytes(&self) -> u64 {
        self.buffers.bytes
    }

    fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass,
        pipeline: &wgpu::ComputePipeline,
        count: usize,
    ) {
        pass.set_pipeline(pipeline);
        pass.dispatch_workgroups(groups(count), 1, 1);
    }

    /// Arms the rebuild (indirect arguments: zero groups when none is wanted) and runs it.
    fn rebuild_phase(&self, pass: &mut wgpu::ComputePass) {
        let p = &self.pipelines;
        pass.set_pipeline(&p.arm);
        pass.set_bind_group(2, &self.indirect_group, &[]);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&p.clear_bins);
        pass.dispatch_workgroups_indirect(&self.indirect, 12);
        for pipeline in [&p.bin, &p.build, &p.commit] {
            pass.set_pipeline(pipeline);
            pass.dispatch_workgroups_indirect(&self.indirect, 0);
        }
    }

    /// Advances `steps` steps (queued: call [`GpuWorld::finish`] or read something back to
    /// wait for them).
    pub fn run(&mut self, steps: u64) {
        let mut left = steps;
        while left > 0 {
            let chunk = left.min(STEPS_PER_SUBMIT);
            let mut encoder = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("steps"),
                });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("steps"),
                    timestamp_writes: None,
                });
                pass.set_bind_group(0, &self.main_group, &[]);
                if self.integrator == Integrator::VelocityVerlet && !self.forces_current {
                    pass.set_bind_group(1, &self.start_params, &[]);
                    self.rebuild_phase(&mut pass);
                    self.dispatch(&mut pass, &self.pipelines.forces, self.n);
                }
                self.forces_current = true;
                pass.set_bind_group(1, &self.step_params, &[]);
                for _ in 0..chunk {
                    self.encode_step(&mut pass);
                }
            }
            self.queue.submit([encoder.finish()]);
            for _ in 0..chunk {
                self.time += self.time_step;
            }
            self.steps += chunk;
            left -= chunk;
        }
    }

    /// Advances until the world's time reaches `time` (the CPU engine's `run_until`).
    pub fn run_until(&mut self, time: f64) {
        let mut t = self.time;
        let mut steps = 0;
        while t < time {
            t += self.time_step;
            steps += 1;
        }
        self.run(steps);
    }

    fn encode_step(&self, pass: &mut wgpu::ComputePass) {
        let p = &self.pipelines;
        match self.integrator {
            Integrator::SymplecticEuler => {
                self.rebuild_phase(pass);
                self.dispatch(pass, &p.forces, self.n);
                self.dispatch(pass, &p.euler, self.n);
            }
            Integrator::VelocityVerlet => {
                self.dispatch(pass, &p.kick_drift, self.n);
                self.rebuild_phase(pass);
                self.dispatch(pass, &p.forces, self.n);
                self.dispatch(pass, &p.half_kick, self.n);
            }
        }
    }

    /// Waits for every queued step.
    pub fn finish(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::Wait)
            .map(|_| ())
            .map_err(|e| GpuError::Lost(e.to_string()))
    }

    fn read<T: Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>, GpuError> {
        let size = buffer.size();
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("read"),
            });
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
        self.queue.submit([encoder.finish()]);
        let slice = staging.slice(..);
        let (sender, receiver) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = sender.send(r);
        });
        self.finish()?;
        receiver
            .recv()
            .map_err(|e| GpuError::Lost(e.to_string()))?
            .map_err(|e| GpuError::Lost(e.to_string()))?;
        let data = bytemuck::cast_slice::<u8, T>(&slice.get_mapped_range()).to_vec();
        staging.unmap();
        Ok(data)
    }

    fn control(&self) -> Result<Vec<u32>, GpuError> {
        let words: Vec<u32> = self.read(&self.buffers.ctl)?;
        let overflow = |word: usize, what: &str| -> Result<(), GpuError> {
            if words[word] > 0 {
                return Err(GpuError::Overflow(format!(
                    "{} times more {what} than the backend holds",
                    words[word]
                )));
            }
            Ok(())
        };
        overflow(
            ctl::NEIGHBOUR_OVERFLOW,
            &format!("neighbours within the skin ({NEIGHBOUR_CAPACITY} per particle)"),
        )?;
        overflow(
            ctl::BIN_OVERFLOW,
            &format!("particles in a neighbour cell ({BIN_CAPACITY} per cell)"),
        )?;
        overflow(ctl::WALL_OVERFLOW, "triangle contacts (8 per particle)")?;
        Ok(words)
    }

    /// The run's counters; an overflow of a fixed capacity is an error (the results are not
    /// valid).
    pub fn counters(&self) -> Result<Counters, GpuError> {
        let words = self.control()?;
        Ok(Counters {
            rebuilds: words[ctl::REBUILDS] as u64,
            removed: words[ctl::REMOVED] as u64,
        })
    }

    /// The fastest particle's speed now, m/s.
    pub fn fastest_speed(&self) -> Result<f64, GpuError> {
        self.write_control(ctl::FASTEST, 0);
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("fastest"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("fastest"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, &self.main_group, &[]);
            pass.set_bind_group(1, &self.step_params, &[]);
            self.dispatch(&mut pass, &self.pipelines.fastest, self.n);
        }
        self.queue.submit([encoder.finish()]);
        let words = self.control()?;
        Ok(f32::from_bits(words[ctl::FASTEST]) as f64)
    }

    /// Neighbour-list pairs (each pair once).
    pub fn pair_count(&self) -> Result<usize, GpuError> {
        let counts: Vec<u32> = self.read(&self.buffers.nbn)?;
        Ok(counts.iter().map(|&c| c as usize).sum::<usize>() / 2)
    }

    /// The particles now.
    pub fn particles(&self) -> Result<GpuParticles, GpuError> {
        let cell: Vec<[i32; 4]> = self.read(&self.buffers.cell)?;
        let off: Vec<[f32; 4]> = self.read(&self.buffers.off)?;
        let vel: Vec<[f32; 4]> = self.read(&self.buffers.vel)?;
        let omg: Vec<[f32; 4]> = self.read(&self.buffers.omg)?;
        let trq: Vec<[f32; 4]> = self.read(&self.buffers.trq)?;
        let v3 = |v: &[f32; 4]| Vec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
        Ok(GpuParticles {
            position: cell
                .iter()
                .zip(&off)
                .map(|(c, o)| {
                    self.grid
                        .to_position([c[0], c[1], c[2]], [o[0], o[1], o[2]])
                })
                .collect(),
            velocity: vel.iter().map(v3).collect(),
            angular_velocity: omg.iter().map(v3).collect(),
            radius: self.radius.clone(),
            removed: cell.iter().map(|c| c[3] < 0).collect(),
            contacts: trq.iter().map(|t| t[3] as u32).collect(),
        })
    }

    /// The raw device state (voxels, offsets, velocities, spins, springs' list lengths), for
    /// bit-identity checks.
    pub fn state_bytes(&self) -> Result<Vec<u8>, GpuError> {
        let mut bytes: Vec<u8> = self.read(&self.buffers.cell)?;
        for buffer in [
            &self.buffers.off,
            &self.buffers.vel,
            &self.buffers.omg,
            &self.buffers.nbn,
        ] {
            bytes.extend(self.read::<u8>(buffer)?);
        }
        Ok(bytes)
    }

    /// The adapter this world runs on.
    pub fn adapter(&self) -> &str {
        &self.adapter
    }
}
