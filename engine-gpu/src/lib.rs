//! repose's DEM engine on the GPU, through wgpu compute shaders (Vulkan, Metal, DX12; Mesa's
//! lavapipe runs it on a CPU for tests).
//!
//! The scene is the CPU engine's: a [`GpuWorld`] is built from a `repose_engine::World`
//! (particles, materials and their pair table, static and moving triangle meshes, gravity,
//! domain, integrator) and steps it with the same contact laws — Hertz-Mindlin no-slip with
//! tangential history, damping and the Coulomb cap; constant-directional-torque rolling
//! friction as a brake on the new spin, or EPSD's rolling spring; linear (SJKR) or JKR
//! cohesion, JKR's necking included — in f32. A moving mesh's motion is evaluated in f64 on the
//! host before each force evaluation (`movers`). Grains can be inserted between runs of steps
//! into a fixed number of slots ([`GpuWorld::with_capacity`], [`GpuWorld::insert`]). A still
//! geometry can be held as a moving mesh ([`GpuWorld::with_movers`]) to record its loads and
//! to be set moving during the run ([`GpuWorld::set_motion`]), and a slab's contact stress
//! sums are sampled on the GPU ([`GpuWorld::run_sampling_slab`]: the shear test's window).
//! What this backend does not simulate (a world's own particle sources: its caller serves
//! them) is refused by name, never approximated.
//!
//! **Sharing a device**: one [`Gpu`] runs several worlds at once, each from its own thread (a
//! worker's GPU slots), each giving the bits it gives alone; a read-back waits for its own
//! world's submissions only. Every world is admitted against the device's memory before
//! anything is allocated ([`Gpu::memory_budget`]: by default 90 % of the largest device-local
//! heap, where Vulkan tells it): one that can never fit is refused at once
//! ([`GpuError::Capacity`], naming both sizes), one that fits only once others end waits for
//! them. A lost device ([`Gpu::lost`]) refuses new worlds.
//!
//! **Positions** are integer voxels plus f32 offsets inside the voxel, so the vector between
//! two nearby particles (and a particle and a triangle's first corner) is exact to the
//! offsets' resolution anywhere in the domain ([`scene::Grid`]).
//!
//! **Determinism per device**: no float atomics; every particle sums its contacts in a fixed
//! order (neighbours sorted by index, then its voxel's triangles in mesh order) and each pair's
//! force is computed in one canonical orientation by both particles, so the same run twice
//! (with the same insertions) on the same adapter is bit-identical. Results are not bit-identical with the CPU engine (f32, another
//! summation order); a result names its backend.

mod device;
mod error;
mod grid;
mod movers;
mod profile;
pub mod scene;
mod world;

pub mod bench;

pub use device::{Gpu, DEFAULT_ADMISSION_WAIT};
pub use error::GpuError;
pub use movers::MAX_MOVERS;
pub use profile::{KernelTime, Profile};
pub use scene::Capacity;
pub use world::{Counters, GpuParticles, GpuWorld, Slab};

/// The backend's name in a result's provenance: `gpu:<adapter>`.
pub fn engine_version(gpu: &Gpu) -> String {
    format!("{}+gpu:{}", repose_engine::VERSION, gpu.name())
}
