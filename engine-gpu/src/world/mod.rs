//! A world stepped on the GPU. Its `impl` spans files by stage, as the CPU engine's world
//! does:
//! - `mod.rs`: the world's state, its creation and what it answers without the device;
//! - [`buffers`]: the device buffers (one per shader binding), their sizes and the control
//!   words' layout;
//! - [`pipelines`]: the shader (its files joined), the kernels' pipelines made for the
//!   world's scene, and the bind groups;
//! - [`step`]: the steps' dispatch order, the submissions, the moving geometries' frames, a
//!   sampled slab, a new motion;
//! - [`insert`]: grains inserted into free slots between runs of steps;
//! - [`readback`]: what is read back from the device (the particles, the counters, the
//!   moving geometries' loads, the neighbour lists) and the waits for the queue.

mod buffers;
mod insert;
mod pipelines;
mod readback;
mod step;

use std::sync::Mutex;

use repose_engine::integrate::Integrator;
use repose_engine::math::Vec3;
use repose_engine::world::{GeometrySample, World};

use self::buffers::{ctl, Buffers};
use self::pipelines::{Bindings, Pipelines};
use crate::device::Admission;
use crate::movers::Mover;
use crate::profile::{Profile, Profiler};
use crate::scene::{Capacity, Grid, Scene, WORKGROUP};
use crate::{Gpu, GpuError};

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
    bindings: Bindings,
    /// The moving geometries; their frames are written one block per force evaluation of a
    /// submission (bound at a dynamic offset).
    movers: Vec<Mover>,
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
    /// The world's share of the device's memory, given back when it is dropped.
    _admission: Admission,
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

/// Workgroups for `count` threads (at least one: an empty world's kernels run as no-ops).
fn groups(count: usize) -> u32 {
    count.div_ceil(WORKGROUP as usize).max(1) as u32
}

/// Refuses a scene whose largest buffer or whose particles' workgroups exceed the adapter's
/// limits.
fn check_limits(limits: &wgpu::Limits, scene: &Scene) -> Result<(), GpuError> {
    let n = scene.cell.len();
    let largest = buffers::largest_binding(scene);
    if largest > limits.max_storage_buffer_binding_size as u64 || largest > limits.max_buffer_size {
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
    Ok(())
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
        check_limits(gpu.limits(), &scene)?;
        // Admitted against the device's memory before anything is allocated: its buffers and
        // its largest read-back's staging (the grains' four records).
        let n = scene.cell.len();
        let footprint = buffers::footprint(&scene);
        let admission = gpu.admit(
            footprint + buffers::READ_BACK_BYTES_PER_SLOT * n as u64,
            &format!(
                "a world of {n} grain slots and {} grid cells",
                scene.grid.cells()
            ),
        )?;
        let device = gpu.device.clone();
        let queue = gpu.queue.clone();
        // Allocation and pipeline errors come back as errors, not as wgpu's default panic.
        // A device's error scopes are one stack, whichever thread pushes: worlds built at
        // once on one GPU (a worker's slots) take turns, so each pops its own.
        let scopes = lock(&gpu.error_scopes);
        device.push_error_scope(wgpu::ErrorFilter::Validation);
        device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let buffers = Buffers::new(&device, &scene);
        let (pipelines, bindings) = pipelines::create(&device, &scene, &buffers);
        let out_of_memory = pollster::block_on(device.pop_error_scope());
        let invalid = pollster::block_on(device.pop_error_scope());
        drop(scopes);
        debug_assert_eq!(buffers.bytes, footprint, "footprint() counts every buffer");
        if let Some(e) = out_of_memory {
            let bytes = buffers.bytes;
            return Err(GpuError::Capacity(format!("allocating {bytes} bytes: {e}")));
        }
        if let Some(e) = invalid {
            return Err(GpuError::Lost(format!("creating the pipelines: {e}")));
        }
        let profiler = gpu
            .profiling()
            .then(|| Mutex::new(Profiler::new(&device, &queue)));
        let materials = world.materials();
        let gpu_world = GpuWorld {
            device,
            queue,
            grid: scene.grid,
            integrator: scene.integrator,
            capacity: scene.cell.len(),
            max_radius: capacity.max_radius,
            n: world.particles().len(),
            densities: (0..materials.len())
                .map(|m| materials.material(repose_engine::material::MaterialId(m as u16)))
                .map(|material| material.density)
                .collect(),
            radius: scene.radius,
            pipelines,
            buffers,
            bindings,
            loads: vec![Vec::new(); scene.movers.len()],
            geometries: world.geometries().len(),
            movers: scene.movers,
            frames_per_evaluation: false,
            record_interval: world.config().geometry_record_interval.max(1),
            pending: Vec::new(),
            time: world.time(),
            time_step: world.config().time_step,
            refilled: 0,
            steps: 0,
            profiler,
            seen: Mutex::new(None),
            drained: std::sync::atomic::AtomicBool::new(true),
            forces_current: false,
            adapter: gpu.name().to_owned(),
            _admission: admission,
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

    /// The voxel grid positions are held on.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The adapter this world runs on.
    pub fn adapter(&self) -> &str {
        &self.adapter
    }
}
