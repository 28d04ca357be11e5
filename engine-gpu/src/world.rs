//! A world stepped on the GPU: the buffers, the pipelines and the step's dispatch order.

use std::sync::Mutex;
use std::time::Instant;

use bytemuck::Pod;
use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::math::Vec3;
use repose_engine::world::{GeometrySample, World};
use wgpu::util::DeviceExt;

use repose_engine::particles::ParticleSpec;

use crate::movers::{frames_at, Frames, Mover, SlabFrame};
use crate::profile::{Profile, Profiler};
use crate::scene::{
    particle_record, Capacity, Grid, Params, Record, Scene, Voxel, BIN_CAPACITY,
    NEIGHBOUR_CAPACITY, WALL_CAPACITY, WORKGROUP,
};
use crate::{Gpu, GpuError};

/// The shader: its files joined in order (each names what it holds).
const SHADER: &str = concat!(
    include_str!("shaders/common.wgsl"),
    include_str!("shaders/contact.wgsl"),
    include_str!("shaders/neighbours.wgsl"),
    include_str!("shaders/walls.wgsl"),
    include_str!("shaders/forces.wgsl"),
    include_str!("shaders/integrate.wgsl"),
);

/// Steps encoded into one command buffer.
const STEPS_PER_SUBMIT: u64 = 25;

/// Steps of the first submission after a read-back, which found the queue empty: the GPU
/// waits while the host encodes them (about 30 µs a step on the H200's host), so they are few.
const STEPS_AFTER_READ_BACK: u64 = 4;

/// Load records (one per recorded force evaluation, each a force and a torque per moving
/// geometry) the device holds before the host reads them back.
const SERIES_RECORDS: usize = 16_384;

/// One force evaluation's block of moving-geometry frames (a multiple of every adapter's
/// uniform offset alignment, at most 256).
const FRAME_BYTES: u64 = std::mem::size_of::<Frames>() as u64;
const _: () = assert!(FRAME_BYTES % 256 == 0);

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
    bin: wgpu::ComputePipeline,
    build: wgpu::ComputePipeline,
    commit: wgpu::ComputePipeline,
    forces: wgpu::ComputePipeline,
    euler: wgpu::ComputePipeline,
    kick_drift: wgpu::ComputePipeline,
    half_kick: wgpu::ComputePipeline,
    fastest: wgpu::ComputePipeline,
    reduce_loads: wgpu::ComputePipeline,
}

struct Buffers {
    cell: wgpu::Buffer,
    off: wgpu::Buffer,
    vel: wgpu::Buffer,
    omg: wgpu::Buffer,
    trq: wgpu::Buffer,
    disp: wgpu::Buffer,
    nbn: wgpu::Buffer,
    nbr: wgpu::Buffer,
    ctl: wgpu::Buffer,
    series: wgpu::Buffer,
    slab: wgpu::Buffer,
    bytes: u64,
}

/// The particles as read back from the GPU, by slot: the CPU world's particles first, in its
/// order, then the inserted ones in their slots ([`GpuWorld::insert`]); in the CPU world's
/// units.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuParticles {
    pub position: Vec<Vec3>,
    pub velocity: Vec<Vec3>,
    pub angular_velocity: Vec<Vec3>,
    pub radius: Vec<f64>,
    /// An empty slot: its grain was removed (left the domain) and is no longer simulated.
    pub removed: Vec<bool>,
    /// Particle-particle contacts of each particle at the last force evaluation.
    pub contacts: Vec<u32>,
}

/// A box of the domain, m: `x`, `y` and `z` ranges (low, high) for
/// [`GpuWorld::run_sampling_slab`] (the slab is the `z` range).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slab {
    pub x: [f64; 2],
    pub y: [f64; 2],
    pub z: [f64; 2],
}

/// Counters of the run so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Counters {
    pub rebuilds: u64,
    pub removed: u64,
}

/// A world on the GPU, built from a CPU [`World`] (its particles, materials, static
/// geometries and configuration) and stepped there, with a fixed number of particle slots
/// that [`GpuWorld::insert`] fills during the run. Deterministic on one adapter: the same
/// world, steps and insertions give the same bits.
pub struct GpuWorld {
    device: wgpu::Device,
    queue: wgpu::Queue,
    grid: Grid,
    integrator: Integrator,
    /// Particle slots (the buffers' length).
    capacity: usize,
    /// The largest radius a particle may have (the grid and the triangles' reach).
    max_radius: f64,
    /// Slots ever filled: the kernels run over these (every slot past them is empty).
    n: usize,
    /// Each material's particle density, kg/m³.
    densities: Vec<f64>,
    radius: Vec<f64>,
    pipelines: Pipelines,
    buffers: Buffers,
    main_group: wgpu::BindGroup,
    /// The moving geometries and their frames, one block per force evaluation of a
    /// submission (bound at a dynamic offset).
    movers: Vec<Mover>,
    frames: wgpu::Buffer,
    frames_group: wgpu::BindGroup,
    /// The submission being encoded has a block per force evaluation (else one blank block).
    frames_per_evaluation: bool,
    /// Steps between two recorded force evaluations (the CPU engine's
    /// `geometry_record_interval`).
    record_interval: u64,
    /// The times of the load records on the device not read back yet, in record order.
    pending: Vec<f64>,
    /// Per moving geometry, the loads read back.
    loads: Vec<Vec<GeometrySample>>,
    /// The geometries of the world the GPU world was built from.
    geometries: usize,
    step_params: wgpu::BindGroup,
    start_params: wgpu::BindGroup,
    /// Removed grains' slots refilled by [`GpuWorld::insert`].
    refilled: u64,
    time: f64,
    time_step: f64,
    steps: u64,
    forces_current: bool,
    adapter: String,
    /// Kernel timestamps, when the GPU was opened to profile ([`Gpu::profiling`]).
    profiler: Option<Mutex<Profiler>>,
    /// What the last read-back of the particles saw, for later questions about the same step.
    seen: Mutex<Option<Seen>>,
    /// A read-back waited for the queue since the last submission of steps.
    drained: std::sync::atomic::AtomicBool,
}

/// The control words and the empty slots as a read-back of the particles found them after
/// `steps` steps: the counters and an insertion's free slots at that step need no read-back
/// of their own (each one idles the GPU until the host submits again). Only steps change
/// them, and [`GpuWorld::insert`] keeps `empty` up to date.
struct Seen {
    steps: u64,
    control: Vec<u32>,
    /// Slots of removed grains, ascending.
    empty: Vec<usize>,
}

impl Drop for GpuWorld {
    fn drop(&mut self) {
        if let Some(profile) = self.profile() {
            tracing::info!(target: "repose_engine_gpu::profile", "{} grain slots, {} cells\n{profile}", self.n, self.grid.cells());
        }
    }
}

impl std::fmt::Debug for GpuWorld {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuWorld")
            .field("adapter", &self.adapter)
            .field("slots", &self.n)
            .field("capacity", &self.capacity)
            .field("time", &self.time)
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

/// The profiler or the last read-back's notes (a panic while one was held left nothing
/// half-written that matters).
fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|e| e.into_inner())
}

/// Per buffer read, its slots' 16-byte records; then the control words.
type SlotsRead<const K: usize> = ([Vec<[f32; 4]>; K], Vec<u32>);

/// Whether a slot is empty: a removed grain's voxel record has a negative fourth word.
fn is_empty(cell: &[i32; 4]) -> bool {
    cell[3] < 0
}

/// The empty slots, ascending.
fn empty_of(cell: &[[i32; 4]]) -> Vec<usize> {
    (0..cell.len()).filter(|&k| is_empty(&cell[k])).collect()
}

/// Workgroups for `count` threads (at least one: an empty world's kernels run as no-ops).
fn groups(count: usize) -> u32 {
    count.div_ceil(WORKGROUP as usize).max(1) as u32
}

impl GpuWorld {
    /// Uploads `world` (at its present time) to `gpu`, with room for exactly its particles
    /// (removed grains' slots can be refilled).
    pub fn new(gpu: &Gpu, world: &World) -> Result<GpuWorld, GpuError> {
        GpuWorld::with_capacity(gpu, world, Capacity::of(world))
    }

    /// Uploads `world` (at its present time) to `gpu` with `capacity.particles` slots, its
    /// particles in the first ones; grains up to `capacity.max_radius` can be inserted into
    /// the others during the run ([`GpuWorld::insert`]). The world may have no particles.
    pub fn with_capacity(
        gpu: &Gpu,
        world: &World,
        capacity: Capacity,
    ) -> Result<GpuWorld, GpuError> {
        GpuWorld::with_movers(gpu, world, capacity, &[])
    }

    /// [`GpuWorld::with_capacity`], with the geometries listed in `movable` (indices into
    /// `world.geometries()`) held as moving meshes even while their motion is stationary: their
    /// loads are recorded ([`GpuWorld::geometry_series`]) and their motion can be replaced
    /// during the run ([`GpuWorld::set_motion`]). The geometries that move are moving meshes
    /// whether listed or not. Errors: an index that is not one of the world's geometries
    /// ([`GpuError::Invalid`]), more than [`MAX_MOVERS`](crate::MAX_MOVERS) moving meshes in
    /// all ([`GpuError::Capacity`]).
    pub fn with_movers(
        gpu: &Gpu,
        world: &World,
        capacity: Capacity,
        movable: &[usize],
    ) -> Result<GpuWorld, GpuError> {
        let scene = Scene::from_world(world, capacity, movable)?;
        let n = scene.cell.len();
        let limits = gpu.limits();
        // EPSD keeps a rolling spring after each tangential one (the shader's `epsd()`).
        let springs: u64 = if scene.params.epsd() { 2 } else { 1 };
        let largest = (n * NEIGHBOUR_CAPACITY * 16 * springs as usize)
            .max(scene.grid.cells() * BIN_CAPACITY * 4)
            .max(scene.tri_grid.len() * 4) as u64;
        if largest > limits.max_storage_buffer_binding_size as u64
            || largest > limits.max_buffer_size
        {
            return Err(GpuError::Capacity(format!(
                "{n} particles, {} grid cells and {} binned triangle entries need a \
                 {largest}-byte buffer; the adapter allows {} bytes per binding",
                scene.grid.cells(),
                scene.tri_grid.len() - scene.grid.cells() - 1,
                limits.max_storage_buffer_binding_size
            )));
        }
        if groups(n) > limits.max_compute_workgroups_per_dimension {
            return Err(GpuError::Capacity(format!(
                "{n} particles exceed {} workgroups of {WORKGROUP}",
                limits.max_compute_workgroups_per_dimension
            )));
        }
        let device = gpu.device.clone();
        let queue = gpu.queue.clone();
        // Allocation and pipeline errors come back as errors, not as wgpu's default panic.
        // A device's error scopes are one stack, whichever thread pushes: worlds built at
        // once on one GPU (a worker's slots) take turns, so each pops its own.
        let _scopes = gpu.error_scopes.lock().unwrap_or_else(|e| e.into_inner());
        device.push_error_scope(wgpu::ErrorFilter::Validation);
        device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
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
        let tri_grid = init("tri grid", bytemuck::cast_slice(&scene.tri_grid));
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
        let spr = zeroed("spr", list * 16 * springs);
        let nbr2 = zeroed("nbr2", list * 4);
        // The cell each slot was binned in at the last rebuild (`commit` empties those).
        let binned = zeroed("binned", n64 * 4);
        let spr2 = zeroed("spr2", list * 16 * springs);
        let cells = scene.grid.cells() as u64;
        let bins = zeroed("bins", cells * BIN_CAPACITY as u64 * 4);
        let binn = zeroed("binn", cells * 4);
        let walls = zeroed("walls", n64 * WALL_CAPACITY as u64 * 16 * (1 + springs));
        let ctl = zeroed("ctl", ctl::WORDS as u64 * 4);
        // Each grain's load on each moving geometry, then their sums (`reduce_loads`).
        let movers = scene.movers.len() as u64;
        let wload = zeroed("wload", n64 * movers * 32);
        let series = zeroed("series", SERIES_RECORDS as u64 * movers * 32);
        // Each grain's share of a sampled slab's stress sums (`run_sampling_slab`).
        let slab = zeroed("slab", n64 * 16);

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
            entries: &(0..23).map(storage_entry).collect::<Vec<_>>(),
        });
        let frames_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frames"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: true,
                    min_binding_size: wgpu::BufferSize::new(FRAME_BYTES),
                },
                count: None,
            }],
        });
        // One block per force evaluation of a submission (its steps and a Verlet start-up).
        let frames = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frames"),
            size: FRAME_BYTES * (STEPS_PER_SUBMIT + 1),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        bytes += frames.size();
        let frames_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frames"),
            layout: &frames_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &frames,
                    offset: 0,
                    size: wgpu::BufferSize::new(FRAME_BYTES),
                }),
            }],
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
        let all: [&wgpu::Buffer; 23] = [
            &cell, &off, &vel, &omg, &frc, &trq, &disp, &nbr, &nbn, &spr, &nbr2, &binned, &spr2,
            &bins, &binn, &walls, &tris, &pc, &ctl, &tri_grid, &wload, &series, &slab,
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

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("dem"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("step"),
            bind_group_layouts: &[&main_layout, &params_layout, &frames_layout],
            push_constant_ranges: &[],
        });
        let constants = scene.pipeline_constants();
        let pipeline = |entry: &str, layout: &wgpu::PipelineLayout| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(layout),
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
            bin: pipeline("bin", &layout),
            build: pipeline("build", &layout),
            commit: pipeline("commit", &layout),
            forces: pipeline("forces", &layout),
            euler: pipeline("euler", &layout),
            kick_drift: pipeline("kick_drift", &layout),
            half_kick: pipeline("half_kick", &layout),
            fastest: pipeline("fastest", &layout),
            reduce_loads: pipeline("reduce_loads", &layout),
        };
        let out_of_memory = pollster::block_on(device.pop_error_scope());
        let invalid = pollster::block_on(device.pop_error_scope());
        drop(_scopes);
        if let Some(e) = out_of_memory {
            return Err(GpuError::Capacity(format!("allocating {bytes} bytes: {e}")));
        }
        if let Some(e) = invalid {
            return Err(GpuError::Lost(format!("creating the pipelines: {e}")));
        }
        let profiler = gpu
            .profiling()
            .then(|| Mutex::new(Profiler::new(&device, &queue)));
        let gpu_world = GpuWorld {
            device,
            queue,
            grid: scene.grid,
            integrator: scene.integrator,
            capacity: n,
            max_radius: capacity.max_radius,
            n: world.particles().len(),
            densities: (0..world.materials().len())
                .map(|m| {
                    world
                        .materials()
                        .material(repose_engine::material::MaterialId(m as u16))
                        .density
                })
                .collect(),
            radius: scene.radius,
            pipelines,
            buffers: Buffers {
                cell,
                off,
                vel,
                omg,
                trq,
                disp,
                nbn,
                nbr,
                ctl,
                series,
                slab,
                bytes,
            },
            main_group,
            loads: vec![Vec::new(); scene.movers.len()],
            geometries: world.geometries().len(),
            movers: scene.movers,
            frames,
            frames_group,
            frames_per_evaluation: false,
            record_interval: world.config().geometry_record_interval.max(1),
            pending: Vec::new(),
            step_params,
            start_params,
            time: world.time(),
            time_step: world.config().time_step,
            refilled: 0,
            steps: 0,
            profiler,
            seen: Mutex::new(None),
            drained: std::sync::atomic::AtomicBool::new(true),
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

    /// Slots filled so far (the world's particles and the inserted ones, removed grains
    /// included): the read-backs ([`GpuWorld::particles`]) hold this many.
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Particle slots, fixed at creation.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Inserts `specs` into free slots (removed grains' slots first, lowest first, then unused
    /// ones in order) before the next step; returns their slots, in `specs`' order. Mass and
    /// inertia are the CPU engine's (a solid sphere of the material's density); the grains start
    /// without contact history and the next step rebuilds the neighbour lists (with velocity
    /// Verlet it first evaluates the forces, as the CPU engine does after an insertion). Reads
    /// back the control words, and the particle records when grains were removed, unless
    /// [`GpuWorld::positions`] or [`GpuWorld::particles`] read them at this step.
    ///
    /// Errors: a spec with an unknown material, a radius not in (0, the capacity's largest], a
    /// centre outside the domain ([`GpuError::Particle`]); more grains than free slots
    /// ([`GpuError::Capacity`]). Nothing is inserted on error.
    pub fn insert(&mut self, specs: &[ParticleSpec]) -> Result<Vec<usize>, GpuError> {
        let mut records = Vec::with_capacity(specs.len());
        for (k, spec) in specs.iter().enumerate() {
            let m = spec.material.0 as usize;
            let Some(&density) = self.densities.get(m) else {
                return Err(GpuError::Particle(format!(
                    "particle {k}: material {m} is not one of the world's {}",
                    self.densities.len()
                )));
            };
            if !(spec.radius > 0.0 && spec.radius <= self.max_radius) {
                return Err(GpuError::Particle(format!(
                    "particle {k}: radius {} m is not in (0, {}] m (the capacity's largest)",
                    spec.radius, self.max_radius
                )));
            }
            let finite = |v: Vec3| v.iter().all(|c| c.is_finite());
            if !(finite(spec.position) && finite(spec.velocity) && finite(spec.angular_velocity)) {
                return Err(GpuError::Particle(format!(
                    "particle {k}: a position, velocity or spin that is not finite"
                )));
            }
            let record = particle_record(&self.grid, spec, density);
            let c = record.0;
            if (0..3).any(|a| c[a] < 0 || c[a] >= self.grid.dims[a]) {
                return Err(GpuError::Particle(format!(
                    "particle {k}: centre {:?} is outside the domain",
                    spec.position
                )));
            }
            records.push(record);
        }
        if records.is_empty() {
            return Ok(Vec::new());
        }
        // Slots of removed grains not refilled yet, lowest first, then the unused ones.
        let removed = self.counters()?.removed;
        let mut slots = Vec::with_capacity(records.len());
        if removed > self.refilled {
            slots.extend(self.empty_slots()?.into_iter().take(records.len()));
        }
        let reused = slots.len();
        slots.extend(self.n..(self.n + records.len() - reused).min(self.capacity));
        if slots.len() < records.len() {
            return Err(GpuError::Capacity(format!(
                "inserting {} particles: only {} of the {} particle slots (the capacity) are \
                 free",
                records.len(),
                slots.len(),
                self.capacity
            )));
        }
        // One write per buffer and run of consecutive slots.
        let mut start = 0;
        while start < slots.len() {
            let mut end = start + 1;
            while end < slots.len() && slots[end] == slots[end - 1] + 1 {
                end += 1;
            }
            let run = &records[start..end];
            let at = slots[start] as u64 * 16;
            let write = |buffer: &wgpu::Buffer, data: &[u8]| {
                self.queue.write_buffer(buffer, at, data);
            };
            let column = |f: fn(&Record) -> [u8; 16]| run.iter().flat_map(f).collect::<Vec<u8>>();
            write(&self.buffers.cell, &column(|r| bytemuck::cast(r.0)));
            write(&self.buffers.off, &column(|r| bytemuck::cast(r.1)));
            write(&self.buffers.vel, &column(|r| bytemuck::cast(r.2)));
            write(&self.buffers.omg, &column(|r| bytemuck::cast(r.3)));
            // Inserted since the build: no history carried into the new lists.
            let fresh: Vec<[f32; 4]> = vec![[0.0, 0.0, 0.0, 1.0]; run.len()];
            write(&self.buffers.disp, bytemuck::cast_slice(&fresh));
            start = end;
        }
        self.refilled += reused as u64;
        if let Some(seen) = lock(&self.seen).as_mut().filter(|s| s.steps == self.steps) {
            seen.empty.drain(..reused);
        }
        self.n = self.n.max(slots.iter().max().map_or(0, |&k| k + 1));
        self.radius.resize(self.n, 0.0);
        for (&k, spec) in slots.iter().zip(specs) {
            self.radius[k] = spec.radius;
        }
        self.write_control(ctl::REBUILD, 1);
        self.forces_current = false;
        Ok(slots)
    }

    /// Where the steps' time went so far, when the GPU was opened to profile
    /// ([`Gpu::profiling`]); `None` otherwise. The world also logs it when dropped (target
    /// `repose_engine_gpu::profile`, level info).
    pub fn profile(&self) -> Option<Profile> {
        self.profiler.as_ref().map(|p| lock(p).totals().clone())
    }

    /// Bytes of device memory the world's buffers take.
    pub fn memory_bytes(&self) -> u64 {
        self.buffers.bytes
    }

    /// Runs `pipeline` over `count` threads (kernel `name` in a profile).
    fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass,
        pipeline: &wgpu::ComputePipeline,
        count: usize,
        name: &'static str,
    ) {
        self.dispatch_groups(pass, pipeline, groups(count), name);
    }

    fn dispatch_groups(
        &self,
        pass: &mut wgpu::ComputePass,
        pipeline: &wgpu::ComputePipeline,
        workgroups: u32,
        name: &'static str,
    ) {
        pass.set_pipeline(pipeline);
        pass.dispatch_workgroups(workgroups, 1, 1);
        if let Some(profiler) = &self.profiler {
            lock(profiler).after(pass, name);
        }
    }

    /// The rebuild kernels: each a no-op unless a grain moved half a skin since the last
    /// rebuild or grains were inserted (the request word the step's `forces` resets; no
    /// GPU-written dispatch sizes, no read-back). `commit` also empties the bins `bin` filled,
    /// so no kernel runs over the grid's cells.
    fn rebuild_phase(&self, pass: &mut wgpu::ComputePass) {
        let p = &self.pipelines;
        for (pipeline, name) in [(&p.bin, "bin"), (&p.build, "build"), (&p.commit, "commit")] {
            self.dispatch(pass, pipeline, self.n, name);
        }
    }

    /// Advances `steps` steps (queued: call [`GpuWorld::finish`] or read something back to
    /// wait for them). Errors: the device was lost while the moving geometries' load records
    /// were read back (every 16 384 records).
    pub fn run(&mut self, steps: u64) -> Result<(), GpuError> {
        self.run_steps(steps, None)
    }

    /// Advances `steps` (at least one) steps, as [`GpuWorld::run`] does (the moving geometries'
    /// loads recorded alike), and returns the stress sum of `slab` at the last step's force
    /// evaluation: over the particle-particle contacts, each pair once, whose branch's midpoint
    /// has its x and y in `[x0, x1) × [y0, y1)`, Σ (the contact's force on the pair's upper
    /// grain from the lower one) × (the length of the branch's vertical extent inside
    /// `[z0, z1]`), N·m; components x, y, z. The force is the whole contact force (elastic,
    /// damping, tangential, cohesion), not its torques; the upper grain is the one with the
    /// higher centre, and a contact with no length inside the slab does not count (the
    /// shear test's measurement window: its normal stress is `sum.z / V`, its shear stress
    /// `-sum.x / V`, V the slab's volume). The branch is the one of the force evaluation (the
    /// CPU engine's, read after a symplectic Euler step, is one drift later) and its midpoint
    /// is taken from the pair's lower slot (in a periodic domain, the image next to it).
    ///
    /// Each grain sums its shares of its pairs with higher slots in f32 in its list order; the
    /// host sums the grains in f64 in slot order: the same bits every time on one adapter.
    /// Waits for the steps. Errors: no steps, or a slab bound that is not finite or a range
    /// whose low end is above its high end ([`GpuError::Invalid`]); a lost device.
    pub fn run_sampling_slab(&mut self, steps: u64, slab: &Slab) -> Result<[f64; 3], GpuError> {
        if steps == 0 {
            return Err(GpuError::Invalid(
                "sampling a slab takes at least one step".into(),
            ));
        }
        let frame = self.slab_frame(slab)?;
        self.run_steps(steps, Some(frame))?;
        if self.n == 0 {
            return Ok([0.0; 3]);
        }
        let shares: Vec<[f32; 4]> = self.read_prefix(&self.buffers.slab, self.n as u64 * 16)?;
        let mut sum = [0.0f64; 3];
        for share in &shares {
            for (s, &v) in sum.iter_mut().zip(share) {
                *s += v as f64;
            }
        }
        Ok(sum)
    }

    /// `slab` as the shader takes it: its low corner as a voxel and an offset, and its extent.
    /// A bound farther than the grid's span outside it is moved to that distance (no grain
    /// or branch midpoint lies there: the same sums).
    fn slab_frame(&self, slab: &Slab) -> Result<SlabFrame, GpuError> {
        let ranges = [slab.x, slab.y, slab.z];
        for (axis, r) in ["x", "y", "z"].iter().zip(&ranges) {
            if !(r[0].is_finite() && r[1].is_finite()) || r[0] > r[1] {
                return Err(GpuError::Invalid(format!(
                    "the slab's {axis} range [{}, {}] is not a finite range, low end first",
                    r[0], r[1]
                )));
            }
        }
        let g = &self.grid;
        let clamp = |a: usize, v: f64| {
            let span = g.dims[a] as f64 * g.voxel[a];
            v.clamp(g.min[a] - span, g.min[a] + 2.0 * span)
        };
        let lo = Vec3::from_fn(|a, _| clamp(a, ranges[a][0]));
        let hi = Vec3::from_fn(|a, _| clamp(a, ranges[a][1]));
        let (cell, off) = g.to_voxel_unwrapped(lo);
        Ok(SlabFrame {
            cell: [cell[0], cell[1], cell[2], 0],
            off: [off[0], off[1], off[2], 0.0],
            size: [
                (hi.x - lo.x) as f32,
                (hi.y - lo.y) as f32,
                (hi.z - lo.z) as f32,
                0.0,
            ],
        })
    }

    /// [`GpuWorld::run`]; given a slab, the last step's force evaluation writes its shares.
    fn run_steps(&mut self, steps: u64, slab: Option<SlabFrame>) -> Result<(), GpuError> {
        let mut left = steps;
        while left > 0 {
            let encoding = Instant::now();
            let drained = self
                .drained
                .swap(false, std::sync::atomic::Ordering::Relaxed);
            let chunk = left.min(if drained {
                STEPS_AFTER_READ_BACK
            } else {
                STEPS_PER_SUBMIT
            });
            // The CPU engine records a step's loads when its count after the step is a
            // multiple of the interval (and never the Verlet start-up's).
            let records: Vec<bool> = (1..=chunk)
                .map(|k| !self.movers.is_empty() && (self.steps + k) % self.record_interval == 0)
                .collect();
            let recorded = records.iter().filter(|&&r| r).count();
            if self.pending.len() + recorded > SERIES_RECORDS {
                self.read_loads()?;
            }
            let startup = self.integrator == Integrator::VelocityVerlet && !self.forces_current;
            let sample = if left == chunk { slab.as_ref() } else { None };
            self.write_frames(&records, startup, sample);
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
                if let Some(profiler) = &self.profiler {
                    lock(profiler).begin(&mut pass);
                }
                pass.set_bind_group(0, &self.main_group, &[]);
                let mut evaluation = 0;
                if startup {
                    pass.set_bind_group(1, &self.start_params, &[]);
                    self.set_frames(&mut pass, &mut evaluation);
                    self.rebuild_phase(&mut pass);
                    self.dispatch(&mut pass, &self.pipelines.forces, self.n, "forces");
                }
                self.forces_current = true;
                pass.set_bind_group(1, &self.step_params, &[]);
                for &record in &records {
                    self.encode_step(&mut pass, &mut evaluation, record);
                }
            }
            self.queue.submit([encoder.finish()]);
            if let Some(profiler) = &self.profiler {
                let encoding = encoding.elapsed();
                lock(profiler).end(&self.device, &self.queue, chunk, encoding)?;
            }
            for _ in 0..chunk {
                self.time += self.time_step;
            }
            self.steps += chunk;
            left -= chunk;
        }
        Ok(())
    }

    /// Replaces moving geometry `geometry`'s motion (its index in the world the GPU world was
    /// built from) from the present time on, as the CPU engine's `World::set_geometry_motion`:
    /// the host evaluates the new motion for the following force evaluations, and a velocity
    /// Verlet run evaluates the forces again with it before its next step. The mesh stays in
    /// its body frame (its body grid is valid for any pose); the new motion should start at the
    /// pose the geometry has now (e.g. `Motion::translating(pose, velocity, time)`), or the
    /// geometry jumps. Errors: a geometry that is not one of the world's
    /// ([`GpuError::Invalid`]) or is baked into the voxels, neither moving nor listed as
    /// movable at creation ([`GpuWorld::with_movers`]; [`GpuError::Unsupported`]).
    pub fn set_motion(&mut self, geometry: usize, motion: Motion) -> Result<(), GpuError> {
        if geometry >= self.geometries {
            return Err(GpuError::Invalid(format!(
                "geometry {geometry}: the world has {} geometries",
                self.geometries
            )));
        }
        let Some(mover) = self.movers.iter_mut().find(|m| m.geometry == geometry) else {
            return Err(GpuError::Unsupported(format!(
                "a new motion for geometry {geometry}, which was still and not listed as \
                 movable when the GPU world was built"
            )));
        };
        mover.motion = motion;
        self.forces_current = false;
        Ok(())
    }

    /// Writes the moving geometries' frames for the force evaluations of the next steps
    /// (`records`: whether each step records its loads), in the order they run: a Verlet
    /// start-up's at the present time, then one per step, at the step's start (symplectic
    /// Euler) or end (velocity Verlet), the times the CPU engine evaluates its forces at; the
    /// last step's samples `slab`, if any. Notes the recorded evaluations' times as pending.
    fn write_frames(&mut self, records: &[bool], startup: bool, slab: Option<&SlabFrame>) {
        // Nothing moves and nothing is sampled: one blank block serves every evaluation (it
        // also clears a sampling flag an earlier submission left in the first block).
        self.frames_per_evaluation = !self.movers.is_empty() || slab.is_some();
        if !self.frames_per_evaluation {
            let blank = frames_at(&[], &self.grid, self.time, -1, None);
            self.queue
                .write_buffer(&self.frames, 0, bytemuck::bytes_of(&blank));
            return;
        }
        let mut frames = Vec::with_capacity(records.len() + 1);
        let mut t = self.time;
        if startup {
            frames.push(frames_at(&self.movers, &self.grid, t, -1, None));
        }
        for (k, &record) in records.iter().enumerate() {
            let sample = if k + 1 == records.len() { slab } else { None };
            let end = t + self.time_step;
            let at = match self.integrator {
                Integrator::SymplecticEuler => t,
                Integrator::VelocityVerlet => end,
            };
            let slot = if record {
                self.pending.push(at);
                self.pending.len() as i32 - 1
            } else {
                -1
            };
            frames.push(frames_at(&self.movers, &self.grid, at, slot, sample));
            t = end;
        }
        self.queue
            .write_buffer(&self.frames, 0, bytemuck::cast_slice(&frames));
    }

    /// Binds the frames of the next force evaluation.
    fn set_frames(&self, pass: &mut wgpu::ComputePass, evaluation: &mut u32) {
        let offset = if self.frames_per_evaluation {
            *evaluation * FRAME_BYTES as u32
        } else {
            0
        };
        pass.set_bind_group(2, &self.frames_group, &[offset]);
        *evaluation += 1;
    }

    /// Reads the pending load records back into the series.
    fn read_loads(&mut self) -> Result<(), GpuError> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let movers = self.movers.len();
        let words: Vec<[f32; 4]> = self.read_prefix(
            &self.buffers.series,
            (self.pending.len() * movers * 32) as u64,
        )?;
        let v = |w: [f32; 4]| Vec3::new(w[0] as f64, w[1] as f64, w[2] as f64);
        for (r, &time) in self.pending.iter().enumerate() {
            for (m, series) in self.loads.iter_mut().enumerate() {
                let at = 2 * (r * movers + m);
                series.push(GeometrySample {
                    time,
                    force: v(words[at]),
                    torque: v(words[at + 1]),
                });
            }
        }
        self.pending.clear();
        Ok(())
    }

    /// The loads recorded on moving geometry `geometry` (its index in the world the GPU world
    /// was built from), as the CPU engine's `World::geometry_series` has them: every
    /// `geometry_record_interval` steps since the start or the last
    /// [`GpuWorld::clear_geometry_series`], the force the grains exert on it and its torque
    /// about its reference point, at the time of the force evaluation. Summed in f32 in a
    /// fixed order (the same bits on one adapter). The loads on a geometry baked into the
    /// voxels (still, and not listed as movable: [`GpuWorld::with_movers`]) are not summed on
    /// the GPU: an error naming it.
    pub fn geometry_series(&mut self, geometry: usize) -> Result<&[GeometrySample], GpuError> {
        let Some(m) = self.movers.iter().position(|m| m.geometry == geometry) else {
            return Err(GpuError::Unsupported(format!(
                "the loads on geometry {geometry}, which does not move"
            )));
        };
        self.read_loads()?;
        Ok(&self.loads[m])
    }

    /// Forgets the loads recorded so far.
    pub fn clear_geometry_series(&mut self) {
        self.pending.clear();
        for series in &mut self.loads {
            series.clear();
        }
    }

    /// Advances until the world's time reaches `time` (the CPU engine's `run_until`).
    pub fn run_until(&mut self, time: f64) -> Result<(), GpuError> {
        let mut t = self.time;
        let mut steps = 0;
        while t < time {
            t += self.time_step;
            steps += 1;
        }
        self.run(steps)
    }

    /// One step's kernels; `record`: sum the moving geometries' loads after its forces.
    fn encode_step(&self, pass: &mut wgpu::ComputePass, evaluation: &mut u32, record: bool) {
        let p = &self.pipelines;
        self.set_frames(pass, evaluation);
        if self.integrator == Integrator::VelocityVerlet {
            self.dispatch(pass, &p.kick_drift, self.n, "kick_drift");
        }
        self.rebuild_phase(pass);
        self.dispatch(pass, &p.forces, self.n, "forces");
        if record {
            let movers = self.movers.len() as u32;
            self.dispatch_groups(pass, &p.reduce_loads, movers, "reduce_loads");
        }
        match self.integrator {
            Integrator::SymplecticEuler => self.dispatch(pass, &p.euler, self.n, "euler"),
            Integrator::VelocityVerlet => self.dispatch(pass, &p.half_kick, self.n, "half_kick"),
        }
    }

    /// Waits for every queued step.
    pub fn finish(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::Wait)
            .map_err(|e| GpuError::Lost(e.to_string()))?;
        self.drained
            .store(true, std::sync::atomic::Ordering::Relaxed);
        Ok(())
    }

    fn read<T: Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>, GpuError> {
        self.read_prefix(buffer, buffer.size())
    }

    /// The first `size` bytes of `buffer`.
    fn read_prefix<T: Pod>(&self, buffer: &wgpu::Buffer, size: u64) -> Result<Vec<T>, GpuError> {
        let bytes = self.read_prefixes(&[(buffer, size)])?;
        Ok(bytemuck::pod_collect_to_vec(&bytes[0]))
    }

    /// The first `size` bytes of each buffer, copied in one submission and read after one
    /// wait for the queue (each wait idles the GPU until the host submits again).
    fn read_prefixes(&self, parts: &[(&wgpu::Buffer, u64)]) -> Result<Vec<Vec<u8>>, GpuError> {
        let started = Instant::now();
        let total: u64 = parts.iter().map(|&(_, size)| size).sum();
        if total == 0 {
            return Ok(vec![Vec::new(); parts.len()]);
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size: total,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("read"),
            });
        let mut at = 0;
        for &(buffer, size) in parts {
            if size > 0 {
                encoder.copy_buffer_to_buffer(buffer, 0, &staging, at, size);
            }
            at += size;
        }
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
        let out = {
            let mapped = slice.get_mapped_range();
            let mut at = 0;
            parts
                .iter()
                .map(|&(_, size)| {
                    let bytes = mapped[at as usize..(at + size) as usize].to_vec();
                    at += size;
                    bytes
                })
                .collect()
        };
        staging.unmap();
        if let Some(profiler) = &self.profiler {
            lock(profiler).read_back(started.elapsed());
        }
        Ok(out)
    }

    /// The first [`GpuWorld::len`] slots' records of the particle buffers `buffers` (16 bytes
    /// a slot) and the control words, read back together.
    fn read_slots<const K: usize>(
        &self,
        buffers: [&wgpu::Buffer; K],
    ) -> Result<SlotsRead<K>, GpuError> {
        let size = self.n as u64 * 16;
        let ctl = &self.buffers.ctl;
        let parts: Vec<(&wgpu::Buffer, u64)> = (buffers.iter().map(|&b| (b, size)))
            .chain([(ctl, ctl.size())])
            .collect();
        let mut bytes = self.read_prefixes(&parts)?;
        let control = bytemuck::pod_collect_to_vec(&bytes.pop().expect("the control words"));
        let slots: Vec<Vec<[f32; 4]>> = bytes
            .iter()
            .map(|b| bytemuck::pod_collect_to_vec(b))
            .collect();
        let slots = slots.try_into().expect("one vector a buffer");
        Ok((slots, control))
    }

    /// The control words after the present step: those a read-back of the particles saw at
    /// this step, or read back now. An overflowed capacity is an error.
    fn control(&self) -> Result<Vec<u32>, GpuError> {
        let seen = lock(&self.seen)
            .as_ref()
            .filter(|seen| seen.steps == self.steps)
            .map(|seen| seen.control.clone());
        let words = match seen {
            Some(words) => words,
            None => self.read(&self.buffers.ctl)?,
        };
        Self::check_overflows(&words)?;
        Ok(words)
    }

    /// The empty slots (removed grains') after the present step, ascending: as a read-back of
    /// the particles saw them at this step, or read back now.
    fn empty_slots(&self) -> Result<Vec<usize>, GpuError> {
        if let Some(seen) = lock(&self.seen).as_ref().filter(|s| s.steps == self.steps) {
            return Ok(seen.empty.clone());
        }
        let cell: Vec<[i32; 4]> = self.read_prefix(&self.buffers.cell, self.n as u64 * 16)?;
        Ok(empty_of(&cell))
    }

    /// Notes what a read-back of the particles (`cell` and the control words) saw now.
    fn note_seen(&self, cell: &[[i32; 4]], control: Vec<u32>) {
        *lock(&self.seen) = Some(Seen {
            steps: self.steps,
            control,
            empty: empty_of(cell),
        });
    }

    fn check_overflows(words: &[u32]) -> Result<(), GpuError> {
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
        overflow(
            ctl::WALL_OVERFLOW,
            "triangle contact candidates (16 per particle before merging)",
        )
    }

    /// The run's counters; an overflow of a fixed capacity is an error (the results are not
    /// valid). No read-back after [`GpuWorld::positions`] or [`GpuWorld::particles`] at the
    /// same step (they read the counters too).
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
            pass.set_bind_group(2, &self.frames_group, &[0]);
            self.dispatch(&mut pass, &self.pipelines.fastest, self.n, "fastest");
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

    /// Each particle's neighbour list (partner slots, ascending) as of the last rebuild.
    pub fn neighbour_lists(&self) -> Result<Vec<Vec<u32>>, GpuError> {
        let counts: Vec<u32> = self.read(&self.buffers.nbn)?;
        let slots: Vec<u32> = self.read(&self.buffers.nbr)?;
        Ok(counts[..self.n]
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                (0..c as usize)
                    .map(|k| slots[k * self.capacity + i])
                    .collect()
            })
            .collect())
    }

    /// The voxel grid positions are held on.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The particles' voxels and offsets (as the shader holds them), by slot.
    pub fn voxels(&self) -> Result<Vec<Voxel>, GpuError> {
        let cell: Vec<[i32; 4]> = self.read(&self.buffers.cell)?;
        let off: Vec<[f32; 4]> = self.read(&self.buffers.off)?;
        Ok(cell[..self.n]
            .iter()
            .zip(&off)
            .map(|(c, o)| ([c[0], c[1], c[2]], [o[0], o[1], o[2]]))
            .collect())
    }

    /// The particles' centres now and whether each slot is empty (its grain removed), by slot:
    /// one read-back of two buffers (and the counters) where [`GpuWorld::particles`] reads five
    /// (e.g. a host-side room test). An [`GpuWorld::insert`] at the same step then finds the
    /// removed grains' slots without a read-back.
    pub fn positions(&self) -> Result<(Vec<Vec3>, Vec<bool>), GpuError> {
        let ([cell, off], control) = self.read_slots([&self.buffers.cell, &self.buffers.off])?;
        let cell: Vec<[i32; 4]> = cell.into_iter().map(bytemuck::cast).collect();
        self.note_seen(&cell, control);
        Ok((
            cell.iter()
                .zip(&off)
                .map(|(c, o)| {
                    self.grid
                        .to_position([c[0], c[1], c[2]], [o[0], o[1], o[2]])
                })
                .collect(),
            cell.iter().map(is_empty).collect(),
        ))
    }

    /// The particles now, by slot (the first [`GpuWorld::len`] slots).
    pub fn particles(&self) -> Result<GpuParticles, GpuError> {
        let b = &self.buffers;
        let ([cell, off, vel, omg, trq], control) =
            self.read_slots([&b.cell, &b.off, &b.vel, &b.omg, &b.trq])?;
        let cell: Vec<[i32; 4]> = cell.into_iter().map(bytemuck::cast).collect();
        self.note_seen(&cell, control);
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
            removed: cell.iter().map(is_empty).collect(),
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
