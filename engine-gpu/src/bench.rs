//! The engine benchmark's settled bed (`repose_engine::bench`) on the GPU: the same lattice and
//! settling schedule, settled and stepped here. No printing: the caller reports the figures.

use std::time::Instant;

use repose_engine::bench::{bed_lattice, measured_bed, settle, Advance, BenchResult};
use repose_engine::world::World;

use crate::{Gpu, GpuError, GpuWorld};

/// Measured figures of [`time_steps`]: the CPU benchmark's figures (`threads` 0; bytes are the
/// device buffers', pairs each listed once) and the fastest grain at the end.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuBenchResult {
    pub bench: BenchResult,
    /// The fastest grain at the end, m/s: a settled bed stays at rest (mm/s), so a large
    /// figure says the run is not physical.
    pub fastest_speed: f64,
}

/// The benchmark's bed of `particles` spheres, settled on the GPU: the CPU engine's lattice
/// ([`bed_lattice`]) and schedule ([`settle`]), then the measured bed at rest
/// ([`measured_bed`]) holding the settled positions. Returns it and the settling steps.
pub fn settled_bed(gpu: &Gpu, particles: usize, seed: u64) -> Result<(World, u64), GpuError> {
    let (mut world, fall) = bed_lattice(particles, seed)
        .map_err(|e| GpuError::Capacity(format!("building the bed: {e}")))?;
    let mut gpu_world = GpuWorld::new(gpu, &world)?;
    let mut failed = None;
    settle(fall, |advance| {
        let advanced = match advance {
            Advance::Until(time) => gpu_world.run_until(time),
            Advance::Steps(steps) => gpu_world.run(steps),
        };
        match advanced.and_then(|()| gpu_world.fastest_speed()) {
            Ok(fastest) => (gpu_world.time(), fastest),
            Err(e) => {
                failed = Some(e);
                (f64::INFINITY, 0.0)
            }
        }
    });
    if let Some(e) = failed {
        return Err(e);
    }
    let counters = gpu_world.counters()?;
    if counters.removed > 0 {
        return Err(GpuError::Capacity(format!(
            "{} particles left the bed's domain while settling",
            counters.removed
        )));
    }
    let settled = gpu_world.particles()?;
    world.particles_mut().position = settled.position;
    let bed = measured_bed(particles, seed, world.particles())
        .map_err(|e| GpuError::Capacity(format!("building the bed: {e}")))?;
    Ok((bed, gpu_world.steps()))
}

/// Uploads `bed`, runs 20 warm-up steps (first neighbour build, pipelines), then times
/// `steps` steps to completion.
pub fn time_steps(gpu: &Gpu, bed: &World, steps: u64) -> Result<GpuBenchResult, GpuError> {
    let mut world = GpuWorld::new(gpu, bed)?;
    world.run(20)?;
    world.finish()?;
    let before = world.counters()?;
    let start = Instant::now();
    world.run(steps)?;
    world.finish()?;
    let seconds = start.elapsed().as_secs_f64();
    let after = world.counters()?;
    let particles = world.particles()?;
    let n = world.len().max(1) as f64;
    Ok(GpuBenchResult {
        bench: BenchResult {
            particles: world.len(),
            threads: 0,
            steps,
            seconds,
            particle_steps_per_second: n * steps as f64 / seconds,
            bytes_per_particle: world.memory_bytes() as f64 / n,
            contacts_per_particle: particles.contacts.iter().map(|&c| c as f64).sum::<f64>() / n,
            pairs_per_particle: world.pair_count()? as f64 / n,
            rebuilds: after.rebuilds - before.rebuilds,
        },
        fastest_speed: world.fastest_speed()?,
    })
}
