//! The settled soil bed: built once per set of bed-determining parameters, returned as plain
//! data ([`SettledBed`]) so a caller can store it and hand it back ([`bed_key`] names it).
//!
//! The bed is built by gravity deposition: the grain count is sized from the bed depth and an
//! assumed packing fraction, the grains are placed on a loose lattice filling the bin's
//! footprint (random sizes from the distribution, small random velocities so the lattice does
//! not fall as a crystal) and let fall into the steel bin until the mean kinetic energy per
//! grain is below the threshold.

use std::time::Instant;

use repose_engine::distribution::SizeDistribution;
use repose_engine::kinematics::Motion;
use repose_engine::material::{rayleigh_time, MaterialTable};
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::generators::open_box;
use repose_engine::neighbor::Domain;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, World, WorldConfig};
use serde::Serialize;

use super::measure::{height_field, surface_level};
use super::run::{build_error, DrillError};
use super::spec::DrillSpec;
use crate::progress::Control;
use crate::soil::{SettledBed, SettledBy, BED_FORMAT};

/// Progress of the bed build.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BedProgress {
    /// 0..1 (against the settle time cap; jumps to 1 when the bed is at rest).
    pub fraction: f64,
    /// Simulated time, s.
    pub time: f64,
    pub particles: usize,
    /// Mean kinetic energy per grain / (m g d).
    pub kinetic_energy_ratio: f64,
}

/// Everything that determines the bed, hashed by [`bed_key`].
#[derive(Serialize)]
struct BedInputs<'a> {
    format: u32,
    materials: &'a crate::soil::Materials,
    soil_soil: &'a repose_engine::material::Interaction,
    soil_steel: &'a repose_engine::material::Interaction,
    rolling: repose_engine::contact::RollingModel,
    particle: &'a repose_engine::distribution::SizeDistributionSpec,
    bin: &'a super::spec::BinSpec,
    depth: f64,
    packing_fraction: f64,
    settle: &'a crate::soil::SettleSpec,
    time_step_rayleigh_fraction: f64,
    seed: u64,
}

/// Cache key of the bed `spec` needs: `bed-v{format}-{16 hex digits}`, a 64-bit FNV-1a hash of
/// the JSON of everything that determines the bed (materials, both interactions, rolling model,
/// grain sizes, bin, bed depth, packing fraction and settle criteria, time-step rule, bed
/// seed), and of nothing else (the auger, its kinematics and the measurement may change freely).
pub fn bed_key(spec: &DrillSpec) -> String {
    let inputs = BedInputs {
        format: BED_FORMAT,
        materials: &spec.materials,
        soil_soil: &spec.soil_soil,
        soil_steel: &spec.soil_steel,
        rolling: spec.engine_rolling_model(),
        particle: &spec.particle,
        bin: &spec.bin,
        depth: spec.bed.depth,
        packing_fraction: spec.bed.packing_fraction,
        settle: &spec.bed.settle,
        time_step_rayleigh_fraction: spec.time_step_rayleigh_fraction,
        seed: spec.bed_seed(),
    };
    let json = serde_json::to_string(&inputs).expect("bed inputs serialise");
    format!("bed-v{BED_FORMAT}-{:016x}", crate::fnv1a(json.as_bytes()))
}

/// SplitMix64: the lattice jitter's random numbers (the engine's RNG draws the grain sizes).
#[derive(Debug)]
pub(crate) struct SplitMix(pub u64);

impl SplitMix {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [-1, 1).
    pub fn symmetric(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// The shared parts of the bed and drill worlds.
pub(crate) struct Setup {
    pub table: MaterialTable,
    pub soil: repose_engine::material::MaterialId,
    pub steel: repose_engine::material::MaterialId,
    pub size: SizeDistribution,
    pub dt: f64,
}

/// Checks the bed's fields only ([`DrillSpec::validate_bed`]): a drilling run checks the rest
/// itself.
pub(crate) fn setup(spec: &DrillSpec) -> Result<Setup, DrillError> {
    spec.validate_bed()?;
    let table = spec
        .material_set()
        .build()
        .map_err(|e| build_error("materials", e))?;
    let soil = table.id("soil").expect("the paper set has soil");
    let steel = table.id("steel").expect("the paper set has steel");
    let size =
        SizeDistribution::new(spec.particle.clone()).map_err(|e| build_error("particle", e))?;
    let dt =
        spec.time_step_rayleigh_fraction * rayleigh_time(size.min_radius(), table.material(soil));
    Ok(Setup {
        table,
        soil,
        steel,
        size,
        dt,
    })
}

/// A world with the steel bin (geometry 0) and nothing else; `top` is the domain's top, m.
pub(crate) fn bin_world(
    spec: &DrillSpec,
    s: &Setup,
    top: f64,
    seed: u64,
) -> Result<World, DrillError> {
    let margin = 4.0 * s.size.max_radius();
    let (hx, hy) = (0.5 * spec.bin.size_x, 0.5 * spec.bin.size_y);
    let domain = Domain::closed(
        Vec3::new(-hx - margin, -hy - margin, -0.02),
        Vec3::new(hx + margin, hy + margin, top),
    );
    let mut config = WorldConfig::new(s.dt, domain);
    config.rolling_model = spec.engine_rolling_model();
    config.seed = seed;
    let mut world = World::new(s.table.clone(), config).map_err(|e| build_error("world", e))?;
    let mesh = open_box(spec.bin.size_x, spec.bin.size_y, spec.bin.height)
        .map_err(|e| build_error("bin", e))?;
    world
        .add_geometry(Geometry {
            name: "bin".into(),
            mesh,
            motion: Motion::stationary(Pose::identity()),
            material: s.steel,
        })
        .map_err(|e| build_error("bin", e))?;
    Ok(world)
}

/// Mean kinetic energy per grain over m g d (mean mass and diameter).
pub(crate) fn kinetic_energy_ratio(world: &World) -> f64 {
    let p = world.particles();
    if p.is_empty() {
        return 0.0;
    }
    let n = p.len() as f64;
    let mean_mass = p.mass.iter().sum::<f64>() / n;
    let mean_d = 2.0 * p.radius.iter().sum::<f64>() / n;
    p.kinetic_energy() / n / (mean_mass * 9.81 * mean_d)
}

/// True if the last `window` values lie within `tolerance_diameters × d` of each other.
pub(crate) fn is_stable(values: &[f64], settle: &crate::soil::SettleSpec, d: f64) -> bool {
    let window = settle.stable_window;
    if values.len() < window {
        return false;
    }
    let recent = &values[values.len() - window..];
    let lo = recent.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = recent.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    hi - lo <= settle.stable_tolerance_diameters * d
}

/// The bed's surface level: median of the probe height field away from the walls.
fn bed_surface(spec: &DrillSpec, world: &World, mean_r: f64) -> Result<f64, DrillError> {
    let p = world.particles();
    let positions: Vec<[f64; 3]> = p.position.iter().map(|v| [v.x, v.y, v.z]).collect();
    let m = &spec.measure;
    let hf = height_field(
        &positions,
        &p.radius,
        0.5 * spec.bin.size_x,
        0.5 * spec.bin.size_y,
        m.cell_fraction * mean_r,
        m.probe_fraction * mean_r,
        0.0,
    )
    .map_err(|e| build_error("bed surface", e))?;
    Ok(surface_level(&hf, m.wall_margin_diameters * 2.0 * mean_r))
}

/// Builds and settles the bed of `spec`. `progress` may cancel ([`DrillError::Cancelled`]).
pub fn build_bed(
    spec: &DrillSpec,
    progress: &mut dyn FnMut(BedProgress) -> Control,
) -> Result<SettledBed, DrillError> {
    let started = Instant::now();
    let s = setup(spec)?;
    let seed = spec.bed_seed();
    let r_max = s.size.max_radius();

    // Grain sizes first (the engine RNG, seeded by the bed seed), until the solid volume of the
    // bed is reached.
    let area = spec.bin.size_x * spec.bin.size_y;
    let target = area * spec.bed.depth * spec.bed.packing_fraction;
    let mut sizer = bin_world(spec, &s, 1.0, seed)?;
    let mut radii = Vec::new();
    let mut volume = 0.0;
    while volume < target {
        let r = s.size.sample(sizer.rng());
        volume += 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
        radii.push(r);
    }

    // A loose lattice over the footprint, one grain's clearance from the walls.
    let spacing = 2.0 * r_max * 1.05;
    let usable_x = spec.bin.size_x - 2.0 * r_max * 0.1 - spacing;
    let usable_y = spec.bin.size_y - 2.0 * r_max * 0.1 - spacing;
    let nx = ((usable_x / spacing).floor() as usize + 1).max(1);
    let ny = ((usable_y / spacing).floor() as usize + 1).max(1);
    let layers = radii.len().div_ceil(nx * ny);
    let top = r_max * 1.1 + layers as f64 * spacing;
    let mut world = bin_world(spec, &s, top.max(spec.bin.height) + 4.0 * spacing, seed)?;
    let mut jitter = SplitMix(seed ^ 0x5eed_bed0_0000_0001);
    let x_start = -0.5 * (nx - 1) as f64 * spacing;
    let y_start = -0.5 * (ny - 1) as f64 * spacing;
    for (k, &r) in radii.iter().enumerate() {
        let layer = k / (nx * ny);
        let (j, i) = ((k % (nx * ny)) / nx, k % nx);
        let room = 0.5 * (spacing - 2.0 * r);
        let position = Vec3::new(
            x_start + i as f64 * spacing + room * jitter.symmetric(),
            y_start + j as f64 * spacing + room * jitter.symmetric(),
            r_max * 1.1 + (layer as f64 + 0.5) * spacing,
        );
        let velocity = Vec3::new(jitter.symmetric(), jitter.symmetric(), jitter.symmetric()) * 0.1;
        world
            .add_particle(ParticleSpec {
                position,
                velocity,
                angular_velocity: Vec3::zeros(),
                radius: r,
                material: s.soil,
            })
            .map_err(|e| build_error("bed", e))?;
    }

    let settle = &spec.bed.settle;
    // The lattice needs about the free-fall time of its top layer to collapse.
    let fall = (2.0 * top / 9.81).sqrt();
    let first_check = fall + settle.min_time;
    let deadline = fall + settle.time_cap;
    let mut next_check = first_check;
    let mut ke = f64::INFINITY;
    let mut settled_by = SettledBy::TimeCap;
    let mut levels: Vec<f64> = Vec::new();
    let mean_r = radii.iter().sum::<f64>() / radii.len().max(1) as f64;
    loop {
        world.step();
        let t = world.time();
        let is_check = t >= next_check;
        if is_check {
            next_check += settle.check_interval;
            ke = kinetic_energy_ratio(&world);
            levels.push(bed_surface(spec, &world, mean_r)?);
            if ke < settle.kinetic_energy_threshold {
                settled_by = SettledBy::KineticEnergy;
            } else if is_stable(&levels, settle, 2.0 * mean_r) {
                settled_by = SettledBy::Stable;
            }
        }
        let settled = settled_by != SettledBy::TimeCap;
        if world.steps() % 200 == 0 || is_check {
            let control = progress(BedProgress {
                fraction: if settled {
                    1.0
                } else {
                    (t / deadline).min(1.0)
                },
                time: t,
                particles: world.particles().len(),
                kinetic_energy_ratio: ke,
            });
            if control == Control::Cancel {
                return Err(DrillError::Cancelled);
            }
        }
        if settled || t >= deadline {
            break;
        }
        if let Some(cap) = spec.wall_time_cap {
            if world.steps() % 200 == 0 && started.elapsed().as_secs_f64() > cap {
                return Err(DrillError::WallTimeCap {
                    phase: "bed",
                    cap_s: cap,
                });
            }
        }
    }

    let p = world.particles();
    let v3 = |v: &Vec3| [v.x, v.y, v.z];
    let surface_z = bed_surface(spec, &world, mean_r)?;
    Ok(SettledBed {
        key: bed_key(spec),
        positions: p.position.iter().map(v3).collect(),
        velocities: p.velocity.iter().map(v3).collect(),
        angular_velocities: p.angular_velocity.iter().map(v3).collect(),
        radii: p.radius.clone(),
        surface_z,
        settled: settled_by != SettledBy::TimeCap,
        settled_by,
        kinetic_energy_ratio: ke,
        simulated_time_s: world.time(),
        steps: world.steps(),
        wall_time_s: started.elapsed().as_secs_f64(),
        escaped: world.removed_count(),
    })
}
