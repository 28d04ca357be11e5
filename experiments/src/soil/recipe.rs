//! The recipe of a settled soil bed ([`BedRecipe`]): the soil, the steel bin it is poured
//! into, how deep and how it settles, the time step and how its surface is read. The drilling
//! test's bed and the shear test's sample (the same recipe in the closed box) are both made by
//! it, and [`BedRecipe::key`] names what it makes, so a bed kept under the key is reused.
//!
//! The bed is built by gravity deposition: the grain count is sized from the bed depth and an
//! assumed packing fraction, the grains are placed on a loose lattice filling the bin's
//! footprint (random sizes from the distribution, small random velocities so the lattice does
//! not fall as a crystal) and let fall into the steel bin until the mean kinetic energy per
//! grain is below the threshold (or its surface stands still).

use std::time::Instant;

use repose_engine::contact::RollingModel;
use repose_engine::distribution::{SizeDistribution, SizeDistributionSpec};
use repose_engine::kinematics::Motion;
use repose_engine::material::{rayleigh_time, Interaction, MaterialSet, MaterialTable};
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::generators::open_box;
use repose_engine::neighbor::Domain;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, World, WorldConfig};
use serde::{Deserialize, Serialize};

use super::bed::{SettledBed, SettledBy, BED_FORMAT};
use super::spec::{
    check_contacts, check_rayleigh_fraction, max_radius, non_negative, positive, Materials,
    RollingSpec, SettleSpec,
};
use super::surface::{height_field, surface_level};
use crate::backend::{steps_until, Backend, BackendError, BackendKind, Engine, Grains};
use crate::progress::Control;
use crate::spec_path::{invalid, SpecError};

/// The steel soil bin: an open box, floor at z = 0, centred on the drill axis (x = y = 0).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BinSpec {
    /// m
    pub size_x: f64,
    /// m
    pub size_y: f64,
    /// Wall height, m (at least the bed depth).
    pub height: f64,
}

/// The soil bed: grains dropped from a loose lattice filling the bin, settled under gravity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BedSpec {
    /// Depth of the settled bed aimed at, m (the grain count is sized from it).
    pub depth: f64,
    /// Solid volume fraction assumed to size the grain count.
    pub packing_fraction: f64,
    /// Seed of the bed; `None` uses the spec's `seed`.
    #[serde(default)]
    pub seed: Option<u64>,
    pub settle: SettleSpec,
}

/// How a bed's surface is read: a probe height field ([`height_field`]) whose level away from
/// the walls ([`surface_level`]) is the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceReading {
    /// Side of the height-field cells, as a fraction of the mean grain radius.
    pub cell_fraction: f64,
    /// Radius of the probe sphere, as a fraction of the mean grain radius.
    pub probe_fraction: f64,
    /// Cells within this many grain diameters of a wall are left out of the level.
    pub wall_margin_diameters: f64,
}

impl Default for SurfaceReading {
    fn default() -> Self {
        SurfaceReading {
            cell_fraction: 0.5,
            probe_fraction: 1.0,
            wall_margin_diameters: 2.0,
        }
    }
}

/// Everything that makes a settled bed. The checks of [`BedRecipe::validate`] name the fields
/// as the drilling spec does (`bin.size_x`, `bed.depth`, `measure.cell_fraction`, …).
#[derive(Debug, Clone, PartialEq)]
pub struct BedRecipe {
    pub materials: Materials,
    pub soil_soil: Interaction,
    /// The bin is steel.
    pub soil_steel: Interaction,
    pub rolling_model: RollingSpec,
    pub epsd_viscous_damping: f64,
    /// Grain sizes (engine distribution spec, radii in m).
    pub particle: SizeDistributionSpec,
    pub bin: BinSpec,
    pub bed: BedSpec,
    /// Δt as a fraction of the Rayleigh time of the smallest grain.
    pub time_step_rayleigh_fraction: f64,
    /// Wall-clock cap of the build, s; `None`: none.
    pub wall_time_cap: Option<f64>,
    /// The spec's seed: the bed's unless `bed.seed` is set.
    pub seed: u64,
    pub surface: SurfaceReading,
}

/// Why a bed could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BedError {
    #[error(transparent)]
    Spec(#[from] SpecError),
    /// The engine rejected the world built from the recipe (materials, bin, grains).
    #[error("{part}: {reason}")]
    Build { part: &'static str, reason: String },
    /// The progress callback cancelled.
    #[error("cancelled")]
    Cancelled,
    /// `wall_time_cap` ran out.
    #[error("wall_time_cap ({cap_s} s) reached while building the bed")]
    WallTimeCap { cap_s: f64 },
    /// The engine backend cannot run the bed or failed (a GPU's).
    #[error(transparent)]
    Backend(#[from] BackendError),
}

fn build_error(part: &'static str, e: impl std::fmt::Display) -> BedError {
    BedError::Build {
        part,
        reason: e.to_string(),
    }
}

/// Facts about the bed a run used (part of the drilling and shear results).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BedInfo {
    pub key: String,
    pub particles: usize,
    pub settled: bool,
    /// True if the bed was handed in (e.g. from a cache) rather than built by this call.
    pub reused: bool,
    pub surface_z_mm: f64,
    pub simulated_time_s: f64,
    pub wall_time_s: f64,
}

impl BedInfo {
    /// The facts of `bed`, handed in to a run (`reused` until the run says otherwise).
    pub fn of(bed: &SettledBed) -> BedInfo {
        BedInfo {
            key: bed.key.clone(),
            particles: bed.positions.len(),
            settled: bed.settled,
            reused: true,
            surface_z_mm: 1e3 * bed.surface_z,
            simulated_time_s: bed.simulated_time_s,
            wall_time_s: bed.wall_time_s,
        }
    }
}

impl BedRecipe {
    /// Cache key of the bed: `bed-v{format}-{16 hex digits}`, a 64-bit FNV-1a hash of the JSON
    /// of everything that determines the bed (materials, both interactions, rolling model,
    /// grain sizes, bin, bed depth, packing fraction and settle criteria, time-step rule, bed
    /// seed), and of nothing else (the wall-time cap and the surface reading may change).
    pub fn key(&self) -> String {
        bed_key(self)
    }

    /// The key of the bed settled on `backend`: [`BedRecipe::key`] on the CPU, with `-gpu`
    /// after it on the GPU (a run on one engine never takes the other's bed).
    pub fn key_on(&self, backend: BackendKind) -> String {
        match backend {
            BackendKind::Cpu => self.key(),
            BackendKind::Gpu => format!("{}-gpu", self.key()),
        }
    }

    /// Builds and settles the bed. `progress` may cancel ([`BedError::Cancelled`]).
    pub fn build(
        &self,
        progress: &mut dyn FnMut(BedProgress) -> Control,
    ) -> Result<SettledBed, BedError> {
        build_bed(Engine::Cpu, self, progress)
    }

    /// [`BedRecipe::build`] on `engine` (the same lattice and settling rule; the bed's key is
    /// [`BedRecipe::key_on`] the engine's).
    pub fn build_on(
        &self,
        engine: Engine<'_>,
        progress: &mut dyn FnMut(BedProgress) -> Control,
    ) -> Result<SettledBed, BedError> {
        build_bed(engine, self, progress)
    }

    /// The bed's seed.
    pub fn bed_seed(&self) -> u64 {
        self.bed.seed.unwrap_or(self.seed)
    }

    /// The engine material set (soil = material 0, steel = material 1).
    pub fn material_set(&self) -> MaterialSet {
        self.materials.material_set(self.soil_soil, self.soil_steel)
    }

    /// The engine rolling model.
    pub fn engine_rolling_model(&self) -> RollingModel {
        self.rolling_model.engine_model(self.epsd_viscous_damping)
    }

    /// Checks what the engine does not check itself; the error names the field.
    pub fn validate(&self) -> Result<(), SpecError> {
        check_contacts(&self.materials, &self.soil_soil, &self.soil_steel)?;
        positive("bin.size_x", self.bin.size_x)?;
        positive("bin.size_y", self.bin.size_y)?;
        positive("bin.height", self.bin.height)?;
        positive("bed.depth", self.bed.depth)?;
        let phi = self.bed.packing_fraction;
        if !(phi > 0.2 && phi < 0.75) {
            return Err(invalid(
                "bed.packing_fraction",
                format!("must be between 0.2 and 0.75, got {phi}"),
            ));
        }
        if self.bed.depth > self.bin.height {
            return Err(invalid(
                "bed.depth",
                format!("must not exceed bin.height = {}", self.bin.height),
            ));
        }
        self.bed.settle.check("bed.settle")?;
        let max_radius = max_radius(&self.particle);
        if max_radius.is_finite()
            && max_radius > 0.0
            && 8.0 * max_radius > self.bin.size_x.min(self.bin.size_y)
        {
            return Err(invalid(
                "particle",
                "grains are too large for the bin (need at least 4 across)",
            ));
        }
        check_rayleigh_fraction(self.time_step_rayleigh_fraction)?;
        if let Some(cap) = self.wall_time_cap {
            positive("wall_time_cap", cap)?;
        }
        let m = &self.surface;
        positive("measure.cell_fraction", m.cell_fraction)?;
        non_negative("measure.probe_fraction", m.probe_fraction)?;
        non_negative("measure.wall_margin_diameters", m.wall_margin_diameters)?;
        Ok(())
    }
}

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

/// Everything that determines the bed, hashed by [`BedRecipe::key`].
#[derive(Serialize)]
struct BedInputs<'a> {
    format: u32,
    materials: &'a Materials,
    soil_soil: &'a repose_engine::material::Interaction,
    soil_steel: &'a repose_engine::material::Interaction,
    rolling: repose_engine::contact::RollingModel,
    particle: &'a repose_engine::distribution::SizeDistributionSpec,
    bin: &'a BinSpec,
    depth: f64,
    packing_fraction: f64,
    settle: &'a SettleSpec,
    time_step_rayleigh_fraction: f64,
    seed: u64,
}

/// [`BedRecipe::key`].
fn bed_key(recipe: &BedRecipe) -> String {
    let inputs = BedInputs {
        format: BED_FORMAT,
        materials: &recipe.materials,
        soil_soil: &recipe.soil_soil,
        soil_steel: &recipe.soil_steel,
        rolling: recipe.engine_rolling_model(),
        particle: &recipe.particle,
        bin: &recipe.bin,
        depth: recipe.bed.depth,
        packing_fraction: recipe.bed.packing_fraction,
        settle: &recipe.bed.settle,
        time_step_rayleigh_fraction: recipe.time_step_rayleigh_fraction,
        seed: recipe.bed_seed(),
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

/// The engine's materials, grain sizes and time step of `recipe`, checked first
/// ([`BedRecipe::validate`]).
pub(crate) fn setup(recipe: &BedRecipe) -> Result<Setup, BedError> {
    recipe.validate()?;
    let table = recipe
        .material_set()
        .build()
        .map_err(|e| build_error("materials", e))?;
    let soil = table.id("soil").expect("the paper set has soil");
    let steel = table.id("steel").expect("the paper set has steel");
    let size =
        SizeDistribution::new(recipe.particle.clone()).map_err(|e| build_error("particle", e))?;
    let dt =
        recipe.time_step_rayleigh_fraction * rayleigh_time(size.min_radius(), table.material(soil));
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
    recipe: &BedRecipe,
    s: &Setup,
    top: f64,
    seed: u64,
) -> Result<World, BedError> {
    let margin = 4.0 * s.size.max_radius();
    let (hx, hy) = (0.5 * recipe.bin.size_x, 0.5 * recipe.bin.size_y);
    let domain = Domain::closed(
        Vec3::new(-hx - margin, -hy - margin, -0.02),
        Vec3::new(hx + margin, hy + margin, top),
    );
    let mut config = WorldConfig::new(s.dt, domain);
    config.rolling_model = recipe.engine_rolling_model();
    config.seed = seed;
    let mut world = World::new(s.table.clone(), config).map_err(|e| build_error("world", e))?;
    let mesh = open_box(recipe.bin.size_x, recipe.bin.size_y, recipe.bin.height)
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
pub(crate) fn kinetic_energy_ratio(p: &Grains<'_>) -> f64 {
    if p.is_empty() {
        return 0.0;
    }
    let n = p.len() as f64;
    let mean_mass = p.mass.iter().sum::<f64>() / n;
    let mean_d = 2.0 * p.radius.iter().sum::<f64>() / n;
    p.kinetic_energy() / n / (mean_mass * 9.81 * mean_d)
}

/// True if the last `window` values lie within `tolerance_diameters × d` of each other.
pub(crate) fn is_stable(values: &[f64], settle: &SettleSpec, d: f64) -> bool {
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
fn bed_surface(recipe: &BedRecipe, p: &Grains<'_>, mean_r: f64) -> Result<f64, BedError> {
    let positions: Vec<[f64; 3]> = p.position.iter().map(|v| [v.x, v.y, v.z]).collect();
    let m = &recipe.surface;
    let hf = height_field(
        &positions,
        p.radius,
        0.5 * recipe.bin.size_x,
        0.5 * recipe.bin.size_y,
        m.cell_fraction * mean_r,
        m.probe_fraction * mean_r,
        0.0,
    )
    .map_err(|e| build_error("bed surface", e))?;
    Ok(surface_level(&hf, m.wall_margin_diameters * 2.0 * mean_r))
}

/// [`BedRecipe::build_on`].
fn build_bed(
    engine: Engine<'_>,
    recipe: &BedRecipe,
    progress: &mut dyn FnMut(BedProgress) -> Control,
) -> Result<SettledBed, BedError> {
    let started = Instant::now();
    let s = setup(recipe)?;
    let seed = recipe.bed_seed();
    let r_max = s.size.max_radius();

    // Grain sizes first (the engine RNG, seeded by the bed seed), until the solid volume of the
    // bed is reached.
    let area = recipe.bin.size_x * recipe.bin.size_y;
    let target = area * recipe.bed.depth * recipe.bed.packing_fraction;
    let mut sizer = bin_world(recipe, &s, 1.0, seed)?;
    let mut radii = Vec::new();
    let mut volume = 0.0;
    while volume < target {
        let r = s.size.sample(sizer.rng());
        volume += 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
        radii.push(r);
    }

    // A loose lattice over the footprint, one grain's clearance from the walls.
    let spacing = 2.0 * r_max * 1.05;
    let usable_x = recipe.bin.size_x - 2.0 * r_max * 0.1 - spacing;
    let usable_y = recipe.bin.size_y - 2.0 * r_max * 0.1 - spacing;
    let nx = ((usable_x / spacing).floor() as usize + 1).max(1);
    let ny = ((usable_y / spacing).floor() as usize + 1).max(1);
    let layers = radii.len().div_ceil(nx * ny);
    let top = r_max * 1.1 + layers as f64 * spacing;
    let mut world = bin_world(recipe, &s, top.max(recipe.bin.height) + 4.0 * spacing, seed)?;
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

    let settle = &recipe.bed.settle;
    // The lattice needs about the free-fall time of its top layer to collapse.
    let fall = (2.0 * top / 9.81).sqrt();
    let first_check = fall + settle.min_time;
    let deadline = fall + settle.time_cap;
    let mut next_check = first_check;
    let mut ke = f64::INFINITY;
    let mut settled_by = SettledBy::TimeCap;
    let mut levels: Vec<f64> = Vec::new();
    let mean_r = radii.iter().sum::<f64>() / radii.len().max(1) as f64;
    let mut backend = engine.start(world)?;
    loop {
        let t = advance_to_check(backend.as_mut(), next_check)?;
        let is_check = t >= next_check;
        if is_check {
            next_check += settle.check_interval;
            let grains = backend.grains()?;
            ke = kinetic_energy_ratio(&grains);
            levels.push(bed_surface(recipe, &grains, mean_r)?);
            if ke < settle.kinetic_energy_threshold {
                settled_by = SettledBy::KineticEnergy;
            } else if is_stable(&levels, settle, 2.0 * mean_r) {
                settled_by = SettledBy::Stable;
            }
        }
        let settled = settled_by != SettledBy::TimeCap;
        if backend.steps() % backend.steps_between_reports() == 0 || is_check {
            let control = progress(BedProgress {
                fraction: if settled {
                    1.0
                } else {
                    (t / deadline).min(1.0)
                },
                time: t,
                particles: backend.grain_count()?,
                kinetic_energy_ratio: ke,
            });
            if control == Control::Cancel {
                return Err(BedError::Cancelled);
            }
        }
        if settled || t >= deadline {
            break;
        }
        if let Some(cap) = recipe.wall_time_cap {
            if backend.steps() % backend.steps_between_reports() == 0
                && started.elapsed().as_secs_f64() > cap
            {
                return Err(BedError::WallTimeCap { cap_s: cap });
            }
        }
    }

    let (simulated_time_s, steps) = (backend.time(), backend.steps());
    let escaped = backend.removed_count()?;
    let p = backend.grains()?;
    let v3 = |v: &Vec3| [v.x, v.y, v.z];
    let surface_z = bed_surface(recipe, &p, mean_r)?;
    Ok(SettledBed {
        key: recipe.key_on(engine.kind()),
        positions: p.position.iter().map(v3).collect(),
        velocities: p.velocity.iter().map(v3).collect(),
        angular_velocities: p.angular_velocity.iter().map(v3).collect(),
        radii: p.radius.to_vec(),
        surface_z,
        settled: settled_by != SettledBy::TimeCap,
        settled_by,
        kinetic_energy_ratio: ke,
        simulated_time_s,
        steps,
        wall_time_s: started.elapsed().as_secs_f64(),
        escaped,
    })
}

/// Advances a soil run's `backend` up to the first of the check at `next_check` (s) and the
/// next progress report ([`Backend::steps_between_reports`]), the states its loop looks at: a
/// backend may take those steps at once (the CPU engine takes one). Returns the time reached.
pub(crate) fn advance_to_check(
    backend: &mut dyn Backend,
    next_check: f64,
) -> Result<f64, BackendError> {
    let every = backend.steps_between_reports();
    let report_in = every - backend.steps() % every;
    let (t, dt) = (backend.time(), backend.time_step());
    backend.advance(steps_until(t, dt, next_check, report_in))?;
    Ok(backend.time())
}
