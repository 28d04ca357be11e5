//! The engine an experiment runs on, behind one seam: an experiment builds its scene as a CPU
//! engine [`World`] (materials, geometries, particle sources such as a mass-rate factory, the
//! configuration) and drives a [`Backend`] with it: advance, read the grains, read the sources'
//! books. Its run loop is written once for every backend; a backend is one file here
//! ([`CpuBackend`], the reference; [`GpuBackend`], wgpu compute) and a variant of [`Engine`].
//!
//! Grains that leave the simulation box are removed by every backend (and counted,
//! [`Backend::removed_count`]), as the CPU engine does.

mod cpu;
mod gpu;
mod window;

pub use cpu::CpuBackend;
pub use gpu::GpuBackend;
/// An opened GPU (adapter, device, queue): open once with `Gpu::open()`, share among runs.
pub use repose_engine_gpu::{Gpu, DEFAULT_ADMISSION_WAIT};
pub use window::{PlaneStress, Window};

use repose_engine::factory::ParticleSource;
use repose_engine::kinematics::Motion;
use repose_engine::math::Vec3;
use repose_engine::world::{Geometry, GeometryId, GeometrySample, World};

/// Which engine runs an experiment, as a spec, a job or a command line names it (serde `cpu`,
/// `gpu`); a wire type, so it lives in `repose-api`.
pub use repose_api::BackendKind;

/// The engine a run uses, ready to start: the CPU, or an opened GPU.
#[derive(Debug, Clone, Copy)]
pub enum Engine<'a> {
    Cpu,
    Gpu(&'a Gpu),
}

impl Engine<'_> {
    pub fn kind(&self) -> BackendKind {
        match self {
            Engine::Cpu => BackendKind::Cpu,
            Engine::Gpu(_) => BackendKind::Gpu,
        }
    }

    /// The backend running `world` (its particles, geometries and sources) from its present
    /// state.
    pub fn start(&self, world: World) -> Result<Box<dyn Backend>, BackendError> {
        self.start_movable(world, &[])
    }

    /// [`Engine::start`], with the geometries `movable` (still or not) ready to be given a
    /// motion during the run ([`Backend::set_geometry_motion`]) and to have their loads
    /// recorded on every backend ([`Backend::geometry_series`]).
    pub fn start_movable(
        &self,
        world: World,
        movable: &[GeometryId],
    ) -> Result<Box<dyn Backend>, BackendError> {
        Ok(match self {
            Engine::Cpu => Box::new(CpuBackend::new(world)),
            Engine::Gpu(gpu) => Box::new(GpuBackend::new(gpu, world, movable)?),
        })
    }

    /// What a result records as the engine that computed it: the CPU engine's version, or
    /// `<version>+gpu:<adapter>` ([`repose_engine_gpu::engine_version`]).
    pub fn engine_version(&self) -> String {
        match self {
            Engine::Cpu => repose_engine::VERSION.to_owned(),
            Engine::Gpu(gpu) => repose_engine_gpu::engine_version(gpu),
        }
    }
}

/// Why a backend cannot run a scene or stopped.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BackendError {
    /// The scene uses something this backend (`CPU`, `GPU`) does not simulate (yet), named.
    #[error("the {backend} backend does not support {what} yet")]
    Unsupported { backend: &'static str, what: String },
    /// The GPU failed: no adapter, a scene that does not fit, a capacity overflow during the
    /// run (its results would not be valid), a lost device.
    #[error("{0}")]
    Gpu(String),
}

impl From<repose_engine_gpu::GpuError> for BackendError {
    fn from(e: repose_engine_gpu::GpuError) -> Self {
        match e {
            repose_engine_gpu::GpuError::Unsupported(what) => BackendError::Unsupported {
                backend: BackendKind::Gpu.label(),
                what,
            },
            e => BackendError::Gpu(e.to_string()),
        }
    }
}

/// The grains now in a backend's simulation (removed ones left out), in the CPU engine's units
/// (m, m/s, kg). The order is the backend's own.
#[derive(Debug, Clone, Copy)]
pub struct Grains<'a> {
    pub position: &'a [Vec3],
    pub velocity: &'a [Vec3],
    pub angular_velocity: &'a [Vec3],
    pub radius: &'a [f64],
    pub mass: &'a [f64],
    pub inverse_inertia: &'a [f64],
}

impl Grains<'_> {
    /// A CPU world's grains, as its backend hands them out.
    pub fn of(world: &World) -> Grains<'_> {
        let p = world.particles();
        Grains {
            position: &p.position,
            velocity: &p.velocity,
            angular_velocity: &p.angular_velocity,
            radius: &p.radius,
            mass: &p.mass,
            inverse_inertia: &p.inverse_inertia,
        }
    }

    pub fn len(&self) -> usize {
        self.position.len()
    }

    pub fn is_empty(&self) -> bool {
        self.position.is_empty()
    }

    /// Σ ½ m v² + ½ I ω², J, summed in the grains' order (the CPU engine's
    /// `Particles::kinetic_energy`, to the bit on the CPU backend).
    pub fn kinetic_energy(&self) -> f64 {
        (0..self.len())
            .map(|k| {
                0.5 * self.mass[k] * self.velocity[k].norm_squared()
                    + 0.5 * self.angular_velocity[k].norm_squared() / self.inverse_inertia[k]
            })
            .sum()
    }

    /// Σ ½ m v², J, summed in the grains' order (the CPU engine's
    /// `Particles::translational_kinetic_energy`, to the bit on the CPU backend).
    pub fn translational_kinetic_energy(&self) -> f64 {
        (0..self.len())
            .map(|k| 0.5 * self.mass[k] * self.velocity[k].norm_squared())
            .sum()
    }
}

/// A mass-rate factory's books.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FactoryBooks {
    /// It will insert nothing more.
    pub finished: bool,
    /// kg
    pub inserted_mass: f64,
    pub inserted_count: u64,
}

/// The books of the first factory among `sources`.
pub(crate) fn first_factory<'a>(
    mut sources: impl Iterator<Item = &'a ParticleSource>,
) -> Option<FactoryBooks> {
    sources.find_map(|source| match source {
        ParticleSource::Factory(f) => Some(FactoryBooks {
            finished: f.is_finished(),
            inserted_mass: f.inserted_mass(),
            inserted_count: f.inserted_count(),
        }),
        ParticleSource::List(_) => None,
    })
}

/// One engine running one scene. Time advances only through [`Backend::advance`].
pub trait Backend {
    /// What a result records as the engine that computed it (see [`Engine::engine_version`]).
    fn engine_version(&self) -> String;

    /// Simulated time, s.
    fn time(&self) -> f64;

    /// Steps taken.
    fn steps(&self) -> u64;

    /// The time step, s.
    fn time_step(&self) -> f64;

    /// Advances at least one step and at most `max_steps` (≥ 1), serving the particle
    /// sources as they fall due; returns the steps taken. A caller that looks at the state
    /// after a given step passes the steps up to it: a backend that stops early (the CPU
    /// engine takes one step per call) is called again. A source's books change only at the
    /// end of a call.
    fn advance(&mut self, max_steps: u64) -> Result<u64, BackendError>;

    /// Steps between two progress reports of a run loop: each report counts the grains,
    /// which a GPU backend reads back (a stall), so it reports less often per step.
    fn steps_between_reports(&self) -> u64 {
        200
    }

    /// The grains now (a GPU backend reads them back).
    fn grains(&mut self) -> Result<Grains<'_>, BackendError>;

    /// Grains now in the simulation (cheaper than [`Backend::grains`] on a GPU).
    fn grain_count(&mut self) -> Result<usize, BackendError>;

    /// Grains removed because they left the simulation box.
    fn removed_count(&mut self) -> Result<u64, BackendError>;

    /// The books of the scene's first factory (none: the scene has none).
    fn factory(&self) -> Option<FactoryBooks>;

    /// The scene's geometries, in the order added.
    fn geometries(&self) -> &[Geometry];

    /// The loads recorded on geometry `id` since the start or the last
    /// [`Backend::clear_geometry_series`] (the CPU engine's `World::geometry_series`: every
    /// `geometry_record_interval` steps, the grains' force on it and its torque about its
    /// reference point). The GPU records those of the geometries that move or were started
    /// movable ([`Engine::start_movable`]) only; another's is an error naming it.
    fn geometry_series(&mut self, id: GeometryId) -> Result<Vec<GeometrySample>, BackendError>;

    /// Forgets the loads recorded so far.
    fn clear_geometry_series(&mut self);

    /// Gives geometry `id` `motion` from now on (the CPU engine's
    /// `World::set_geometry_motion`; a motion that continues the geometry's present pose keeps
    /// it in place). The GPU changes the motion of a geometry that moved from the start or was
    /// started movable ([`Engine::start_movable`]) only; another is an error naming it.
    fn set_geometry_motion(&mut self, id: GeometryId, motion: Motion) -> Result<(), BackendError>;

    /// Advances exactly `steps` steps (at least one) and returns `window`'s stresses from the
    /// particle contacts of the last step's force evaluation ([`Window`]).
    fn advance_sampling(
        &mut self,
        steps: u64,
        window: &Window,
    ) -> Result<PlaneStress, BackendError>;

    /// The CPU world a checkpoint keeps, if this backend's run can be checkpointed and
    /// continued bit for bit (the CPU engine's); none otherwise.
    fn checkpoint_world(&self) -> Option<&World>;

    /// The final state as a CPU world: the CPU engine's own; for another backend, the scene's
    /// world with the backend's grains (centres, velocities, spins, radii, materials) and the
    /// sources' books copied in, e.g. to write the grains out (it is not a continuation of the
    /// backend's trajectory).
    fn into_world(self: Box<Self>) -> Result<World, BackendError>;
}

/// Advances `backend` exactly `steps` steps (none: none), in as few calls as it takes.
pub(crate) fn advance_exactly(backend: &mut dyn Backend, steps: u64) -> Result<(), BackendError> {
    let mut left = steps;
    while left > 0 {
        left -= backend.advance(left)?;
    }
    Ok(())
}

/// The time after `steps` steps of `dt` from `t`, as the engines advance it (one addition a
/// step).
pub(crate) fn time_after(t: f64, dt: f64, steps: u64) -> f64 {
    (0..steps).fold(t, |t, _| t + dt)
}

/// Steps (at least one, at most `cap`) until the time, advanced from `t` by `dt` a step as
/// the engines advance it, reaches `target`: what a run loop that looks at the state at
/// `target` lets a backend take at once.
pub(crate) fn steps_until(t: f64, dt: f64, target: f64, cap: u64) -> u64 {
    let mut t = t;
    let mut steps = 0;
    while steps < cap {
        steps += 1;
        t += dt;
        if t >= target {
            break;
        }
    }
    steps.max(1)
}
