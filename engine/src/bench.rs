//! Throughput benchmark: a settled, polydisperse bed of spheres on a floor, periodic in x and
//! y, stepped with Hertz-Mindlin + tangential history + CDT rolling friction.
//!
//! No printing: the caller (CLI) reports the returned figures.

use std::time::Instant;

use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::kinematics::Motion;
use crate::material::{Cohesion, Interaction, MaterialSet};
use crate::math::{Pose, Vec3};
use crate::mesh::TriMesh;
use crate::neighbor::Domain;
use crate::particles::{ParticleSpec, Particles};
use crate::world::{Geometry, World, WorldConfig, WorldError};

/// What to measure.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchConfig {
    pub particles: usize,
    /// Threads of the local rayon pool the benchmark runs in.
    pub threads: usize,
    /// Timed steps (after settling).
    pub steps: u64,
    pub seed: u64,
}

/// Measured figures.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchResult {
    pub particles: usize,
    pub threads: usize,
    pub steps: u64,
    /// Wall-clock time of the timed steps, s.
    pub seconds: f64,
    /// particles × steps / seconds.
    pub particle_steps_per_second: f64,
    /// Particle arrays + pair list + histories, divided by the particle count.
    pub bytes_per_particle: f64,
    /// Particle-particle contacts per particle (coordination number, each contact counted for
    /// both particles) at the end of the run.
    pub contacts_per_particle: f64,
    /// Neighbour-list pairs per particle (half list).
    pub pairs_per_particle: f64,
    /// Neighbour-list rebuilds during the timed steps.
    pub rebuilds: u64,
}

/// Mean particle radius of the bed, m (sand-grain scale; the radii vary ±10 %).
pub const BED_RADIUS: f64 = 1.0e-3;

/// The bed's contact coefficients during the timed steps (soil-like).
fn measured_interaction() -> Interaction {
    Interaction {
        restitution: 0.3,
        static_friction: 0.5,
        rolling_friction: 0.1,
        cohesion: Cohesion::None,
    }
}

/// A periodic world with a floor, for `particles` spheres of the bed's size.
fn bed_world(
    particles: usize,
    interaction: Interaction,
    seed: u64,
) -> Result<(World, usize, usize, f64), WorldError> {
    let materials = MaterialSet::paper(interaction, interaction).build()?;
    let soil = materials.id("soil").expect("paper material set has soil");
    let steel = materials.id("steel").expect("paper material set has steel");
    let spacing = 2.2 * BED_RADIUS * 1.1;
    let side = ((2.0 * particles as f64).cbrt().ceil() as usize).max(4);
    let layers = particles.div_ceil(side * side);
    let width = side as f64 * spacing;
    let height = (layers as f64 + 2.0) * spacing;
    let domain = Domain {
        min: Vec3::new(0.0, 0.0, -0.5 * spacing),
        max: Vec3::new(width, width, height + spacing),
        periodic_x: true,
        periodic_y: true,
    };
    let dt = materials.rayleigh_time_step(soil, 0.9 * BED_RADIUS, 0.2);
    let mut config = WorldConfig::new(dt, domain);
    config.seed = seed;
    let mut world = World::new(materials, config)?;
    let margin = 4.0 * spacing;
    let floor = TriMesh::new(
        vec![
            Vec3::new(-margin, -margin, 0.0),
            Vec3::new(width + margin, -margin, 0.0),
            Vec3::new(width + margin, width + margin, 0.0),
            Vec3::new(-margin, width + margin, 0.0),
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    )
    .expect("floor mesh is valid");
    world.add_geometry(Geometry {
        name: "floor".into(),
        mesh: floor,
        motion: Motion::stationary(Pose::identity()),
        material: steel,
    })?;
    Ok((world, side, layers, spacing))
}

/// The unsettled bed: `particles` spheres (radii ±10 % around [`BED_RADIUS`]) on a jittered
/// cubic lattice slightly wider than their diameter, over a floor, periodic in x and y, in the
/// strongly damped, low-friction settling world (e 0.05, μs 0.1, μr 0) that packs densely
/// (≈ 5 contacts per particle) and comes to rest fast. Returns the world and the lattice top's
/// fall time, s, which bounds the settling ([`settle`]). Any engine backend settles it.
pub fn bed_lattice(particles: usize, seed: u64) -> Result<(World, f64), WorldError> {
    let settling = Interaction {
        restitution: 0.05,
        static_friction: 0.1,
        rolling_friction: 0.0,
        cohesion: Cohesion::None,
    };
    let (mut world, side, layers, spacing) = bed_world(particles, settling, seed)?;
    let soil = world.materials().id("soil").expect("soil");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut placed = 0;
    'fill: for z in 0..layers {
        for y in 0..side {
            for x in 0..side {
                if placed == particles {
                    break 'fill;
                }
                let jitter = Vec3::new(
                    rng.gen_range(-0.05..0.05),
                    rng.gen_range(-0.05..0.05),
                    rng.gen_range(-0.05..0.05),
                ) * spacing;
                let centre = Vec3::new(
                    (x as f64 + 0.5) * spacing,
                    (y as f64 + 0.5) * spacing,
                    (z as f64 + 0.5) * spacing + BED_RADIUS,
                ) + jitter;
                let radius = BED_RADIUS * rng.gen_range(0.9..1.1);
                world.add_particle(ParticleSpec::at_rest(centre, radius, soil))?;
                placed += 1;
            }
        }
    }
    // The lattice's top falls by about a gap per layer.
    let drop = layers as f64 * (spacing - 2.0 * BED_RADIUS);
    Ok((world, (2.0 * drop / 9.81).sqrt()))
}

/// How far [`settle`] asks a backend to advance the settling world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Advance {
    /// Step until the world's time reaches this, s.
    Until(f64),
    /// This many steps.
    Steps(u64),
}

/// The settling schedule of a lattice whose top falls for `fall` seconds: run until twice
/// that, then in blocks of 100 steps until the fastest particle is slower than
/// [`SETTLED_SPEED`], at most until ten times the fall (so a pathological case still ends).
/// `advance` moves the settling world on and returns (its time, its fastest speed).
pub fn settle(fall: f64, mut advance: impl FnMut(Advance) -> (f64, f64)) {
    let (mut time, _) = advance(Advance::Until(2.0 * fall));
    let limit = 10.0 * fall;
    while time < limit {
        let (t, fastest) = advance(Advance::Steps(100));
        time = t;
        if fastest < SETTLED_SPEED {
            break;
        }
    }
}

/// A bed is settled when its fastest particle is slower than this, m/s.
pub const SETTLED_SPEED: f64 = 1e-3;

/// The measured bed (e 0.3, μs 0.5, μr 0.1, CDT) holding `settled`'s particles at rest.
pub fn measured_bed(particles: usize, seed: u64, settled: &Particles) -> Result<World, WorldError> {
    let (mut bed, ..) = bed_world(particles, measured_interaction(), seed)?;
    for k in 0..settled.len() {
        bed.add_particle(ParticleSpec::at_rest(
            settled.position[k],
            settled.radius[k],
            settled.material[k],
        ))?;
    }
    Ok(bed)
}

/// Build a bed of `particles` spheres (radii ±10 % around [`BED_RADIUS`]) at rest on a floor,
/// periodic in x and y, with soil-like contacts (e 0.3, μs 0.5, μr 0.1, CDT), settled by this
/// (CPU) engine: [`bed_lattice`], [`settle`], then [`measured_bed`].
pub fn settled_bed(particles: usize, seed: u64) -> Result<World, WorldError> {
    let (mut world, fall) = bed_lattice(particles, seed)?;
    settle(fall, |advance| {
        match advance {
            Advance::Until(time) => world.run_until(time),
            Advance::Steps(steps) => world.run(steps),
        }
        let fastest = world
            .particles()
            .velocity
            .iter()
            .map(|v| v.norm())
            .fold(0.0, f64::max);
        (world.time(), fastest)
    });
    measured_bed(particles, seed, world.particles())
}

/// Build a settled bed, then time `config.steps` steps in a local pool of `threads` threads.
pub fn run_benchmark(config: &BenchConfig) -> Result<BenchResult, WorldError> {
    let bed = settled_bed(config.particles, config.seed)?;
    Ok(time_steps(&bed, config.threads, config.steps))
}

/// Time `steps` steps of a copy of `bed` in a local pool of `threads` threads (reuse one bed
/// for several thread counts).
pub fn time_steps(bed: &World, threads: usize, steps: u64) -> BenchResult {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()
        .expect("building a rayon thread pool");
    pool.install(|| {
        let mut world = bed.clone();
        // Warm up (caches, allocations, the first pair-list build) outside the timed region.
        world.run(20);
        let rebuilds_before = world.rebuild_count();
        let start = Instant::now();
        world.run(steps);
        let seconds = start.elapsed().as_secs_f64();
        let n = world.particles().len().max(1) as f64;
        BenchResult {
            particles: world.particles().len(),
            threads,
            steps,
            seconds,
            particle_steps_per_second: n * steps as f64 / seconds,
            bytes_per_particle: world.memory_bytes() as f64 / n,
            contacts_per_particle: 2.0 * world.contact_count() as f64 / n,
            pairs_per_particle: world.pair_count() as f64 / n,
            rebuilds: world.rebuild_count() - rebuilds_before,
        }
    })
}
