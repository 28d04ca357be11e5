//! Runs a [`TriaxialSpec`]: the specimen is prepared once (a caller may cache it), then for
//! each confining pressure σ3, from a copy of that specimen: isotropic consolidation to σ3 by
//! six servo-controlled walls, then drained axial loading, the two platens closing at a
//! constant strain rate while the four lateral walls hold σ3, to `loading.axial_strain`.
//!
//! Frame: z is the specimen's axis; the walls are, in this order, x−, x+, y−, y+ (lateral) and
//! z−, z+ (the platens): flat squares larger than the specimen, frictionless and without
//! cohesion (material 1, [`TriaxialSpec::walls`]), moved along their normals only. Gravity is
//! off. Each wall's stress is the grains' force on it along its normal over the face it
//! bounds (the product of the specimen's two other sizes, from the walls' positions); the
//! specimen's volume is the box the walls make.

use std::time::Instant;

use repose_engine::material::{Cohesion, Interaction};
use repose_engine::math::Vec3;
use repose_engine::particles::ParticleSpec;
use serde::{Deserialize, Serialize};

use super::measure::{envelope, failure, stiffness, Envelope, TriaxialSample};
use super::picture::{curves_svg, mohr_svg, specimen_svg};
use super::rig::{box_world, check, consolidate, setup, Servo, Setup};
use super::spec::TriaxialSpec;
use crate::backend::{advance_exactly, Backend, Engine};
pub use crate::progress::{Control, Progress};
use crate::soil::{
    kinetic_energy_ratio, BedInfo, On, OnBed, OnBedError, SettledBed, SettledBy, SplitMix,
    BED_FORMAT,
};

/// Why a run could not start or was stopped before it could report.
pub type TriaxialError = OnBedError;

/// Overall outcome. The strength is reported for every status but `measurement_failed`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TriaxialStatus {
    Ok,
    /// The specimen's walls did not hold the preparation pressure within the time cap.
    SpecimenNotPrepared,
    /// A stage did not consolidate within its time cap (it was loaded anyway).
    NotConsolidated,
    /// No envelope could be fitted.
    MeasurementFailed,
}

/// One confining pressure: consolidation and loading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TriaxialStage {
    /// σ3 aimed at, kPa.
    pub confining_kpa: f64,
    pub consolidated: bool,
    /// Simulated time of the consolidation, and of the whole stage, s.
    pub consolidation_time_s: f64,
    pub simulated_time_s: f64,
    /// Void ratio after consolidation.
    pub void_ratio: f64,
    /// Failure: the peak deviator (or the end's, `peaked` false), kPa, the lateral walls'
    /// stress there (the circle's σ3), kPa, and the axial strain there.
    pub peak_deviator_kpa: f64,
    pub failure_confining_kpa: f64,
    pub axial_strain_at_peak: f64,
    pub peaked: bool,
    /// E50, MPa, and ν (Eq. 2) to half the failure deviator; none if not read.
    pub young_modulus_mpa: Option<f64>,
    pub poisson_ratio: Option<f64>,
    /// Volumetric strain at failure (positive: contraction).
    pub volumetric_strain_at_peak: f64,
    /// I = ε̇ d √(ρ/σ3) of the loading (below 1e-3: quasi-static).
    pub inertial_number: f64,
    /// Mean kinetic energy per grain over m g d at the end of consolidation.
    pub kinetic_energy_ratio: f64,
    pub particles: usize,
    /// Grains that left the walls' box during the stage.
    pub escaped: u64,
    pub steps: u64,
    /// The loading's record (thinned in a job's details).
    pub series: Vec<TriaxialSample>,
}

/// The result of one triaxial test (serde; what `result.json` holds). Stresses in kPa,
/// lengths in mm, times in s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TriaxialResult {
    pub status: TriaxialStatus,
    pub message: Option<String>,
    /// Of `envelope`.
    pub cohesion_kpa: Option<f64>,
    pub friction_angle_deg: Option<f64>,
    pub envelope: Option<Envelope>,
    /// The stages' mean E50 and ν.
    pub young_modulus_mpa: Option<f64>,
    pub poisson_ratio: Option<f64>,
    /// Void ratio of the prepared specimen (at the preparation pressure).
    pub void_ratio: f64,
    pub stages: Vec<TriaxialStage>,
    /// The prepared specimen (the settled bed of this kind).
    pub specimen: BedInfo,
    pub width_mm: f64,
    pub height_mm: f64,
    pub grain_diameter_mm: f64,
    pub particles: usize,
    pub time_step_s: f64,
    /// Over all stages (the specimen's own time is in `specimen`).
    pub simulated_time_s: f64,
    pub steps: u64,
    /// Wall time of this call (the specimen included if it was prepared here), s.
    pub wall_time_s: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub engine_version: Option<String>,
}

impl TriaxialResult {
    /// Samples kept over all stages in a job's `details` ([`Self::for_details`]).
    pub const DETAILS_SAMPLES: usize = 240;

    /// The copy a job's `details` hold: each stage's record thinned to its share of
    /// [`Self::DETAILS_SAMPLES`] (the failure sample kept), about 120 bytes a sample.
    pub fn for_details(&self) -> TriaxialResult {
        let per_stage = (Self::DETAILS_SAMPLES / self.stages.len().max(1)).max(3);
        let mut out = self.clone();
        for stage in &mut out.stages {
            let n = stage.series.len();
            if n <= per_stage {
                continue;
            }
            let mut keep: Vec<usize> = (0..per_stage - 1)
                .map(|k| k * (n - 1) / (per_stage - 2))
                .collect();
            if let Some(f) = failure(&stage.series) {
                keep.push(f.index);
            }
            keep.sort_unstable();
            keep.dedup();
            stage.series = keep.into_iter().map(|i| stage.series[i]).collect();
        }
        out
    }

    /// Scalar results for a job server: `cohesion_kpa`, `friction_angle_deg`, `r_squared`
    /// (of the σ1-σ3 line), `young_modulus_mpa`, `poisson_ratio`, `void_ratio`,
    /// `max_inertial_number`, `particles`, `simulated_time_s`, and `came_to_rest` (1 when
    /// the specimen was prepared and every stage consolidated, else 0; still measured).
    pub fn metrics(&self) -> std::collections::BTreeMap<String, f64> {
        let mut m = std::collections::BTreeMap::new();
        let Some(env) = &self.envelope else {
            return m;
        };
        let ok = self.status == TriaxialStatus::Ok;
        let values = [
            ("came_to_rest", Some(if ok { 1.0 } else { 0.0 })),
            ("cohesion_kpa", Some(env.cohesion_kpa)),
            ("friction_angle_deg", Some(env.friction_angle_deg)),
            ("r_squared", Some(env.r_squared)),
            ("young_modulus_mpa", self.young_modulus_mpa),
            ("poisson_ratio", self.poisson_ratio),
            ("void_ratio", Some(self.void_ratio)),
            (
                "max_inertial_number",
                self.stages
                    .iter()
                    .map(|s| s.inertial_number)
                    .reduce(f64::max),
            ),
            ("particles", Some(self.particles as f64)),
            ("simulated_time_s", Some(self.simulated_time_s)),
        ];
        for (k, v) in values {
            if let Some(v) = v.filter(|v| v.is_finite()) {
                m.insert(k.to_owned(), v);
            }
        }
        m
    }
}

/// A finished run: the result and what a caller may want to draw or keep.
#[derive(Debug, Clone)]
pub struct TriaxialRun {
    pub result: TriaxialResult,
    /// The last stage's grains at the end of loading: centre and radius.
    pub sheared: Vec<Grain>,
}

impl TriaxialRun {
    /// q and εv against εa, one curve per confining pressure.
    pub fn curves_svg(&self) -> String {
        curves_svg(&self.result)
    }

    /// The failure circles with the fitted envelope and the paper's.
    pub fn mohr_svg(&self) -> String {
        mohr_svg(&self.result)
    }

    /// The last specimen at the end of loading, seen from the side.
    pub fn specimen_svg(&self) -> String {
        specimen_svg(&self.result, &self.sheared)
    }

    /// Every stage's record as CSV: `confining_kpa,axial_strain,deviator_kpa,
    /// volumetric_strain,lateral_kpa`.
    pub fn curves_csv(&self) -> String {
        let mut s =
            String::from("confining_kpa,axial_strain,deviator_kpa,volumetric_strain,lateral_kpa\n");
        for stage in &self.result.stages {
            for p in &stage.series {
                s.push_str(&format!(
                    "{},{},{},{},{}\n",
                    stage.confining_kpa,
                    p.axial_strain,
                    p.deviator_kpa,
                    p.volumetric_strain,
                    p.lateral_kpa
                ));
            }
        }
        s
    }
}

/// The spec on an engine: the specimen is prepared and loaded there.
pub type TriaxialOn<'a> = On<'a, TriaxialSpec>;

/// The specimen takes the first 30 % of the progress when prepared here.
impl OnBed for TriaxialOn<'_> {
    type Run = TriaxialRun;
    type Error = OnBedError;
    const BED_SHARE: f64 = 0.3;

    fn bed_key(&self) -> String {
        let key = specimen_key(self.spec);
        match self.engine {
            Engine::Cpu => key,
            Engine::Gpu(_) => format!("{key}-gpu"),
        }
    }

    fn build_bed(
        &self,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<SettledBed, OnBedError> {
        prepare(self, progress)
    }

    fn run_on_matching_bed(
        &self,
        bed: SettledBed,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<TriaxialRun, OnBedError> {
        load_stages(self, bed, progress)
    }

    fn bed_of(run: &mut TriaxialRun) -> (&mut BedInfo, &mut f64) {
        (&mut run.result.specimen, &mut run.result.wall_time_s)
    }
}

/// Everything that determines the prepared specimen, hashed by [`specimen_key`].
#[derive(Serialize)]
struct SpecimenInputs<'a> {
    format: u32,
    materials: &'a crate::soil::Materials,
    soil_soil: Interaction,
    walls: Interaction,
    rolling: repose_engine::contact::RollingModel,
    particle: &'a repose_engine::distribution::SizeDistributionSpec,
    specimen: &'a super::spec::SpecimenSpec,
    pressure_kpa: f64,
    servo: &'a super::spec::TriaxialServoSpec,
    consolidation: &'a super::spec::TriaxialConsolidationSpec,
    time_step_rayleigh_fraction: f64,
    seed: u64,
}

/// The key of the specimen `spec` prepares on the CPU: `specimen-v{format}-{16 hex digits}`,
/// a 64-bit FNV-1a hash of the JSON of everything that determines it (the soil as compacted:
/// the preparation friction, no cohesion) and of nothing else.
pub fn specimen_key(spec: &TriaxialSpec) -> String {
    let inputs = SpecimenInputs {
        format: BED_FORMAT,
        materials: &spec.materials,
        soil_soil: preparation_contact(spec),
        walls: spec.walls(),
        rolling: spec.engine_rolling_model(),
        particle: &spec.particle,
        specimen: &spec.specimen,
        pressure_kpa: spec.preparation.pressure_kpa,
        servo: &spec.servo,
        consolidation: &spec.consolidation,
        time_step_rayleigh_fraction: spec.time_step_rayleigh_fraction,
        seed: spec.specimen_seed(),
    };
    let json = serde_json::to_string(&inputs).expect("specimen inputs serialise");
    format!(
        "specimen-v{BED_FORMAT}-{:016x}",
        crate::fnv1a(json.as_bytes())
    )
}

/// The soil-soil contact while the specimen is compacted: the preparation friction (or the
/// soil's), no cohesion.
fn preparation_contact(spec: &TriaxialSpec) -> Interaction {
    Interaction {
        static_friction: spec
            .preparation
            .friction
            .unwrap_or(spec.soil_soil.static_friction),
        cohesion: Cohesion::None,
        ..spec.soil_soil
    }
}

/// Prepares the specimen of `on`: grains on a loose jittered lattice with random velocities,
/// filling a box of the specimen's aspect at about a quarter solid, compacted by the six walls
/// to `preparation.pressure_kpa` with the preparation friction and no cohesion (the
/// consolidation's criteria; three of its time caps, the compaction included).
fn prepare(
    on: &TriaxialOn<'_>,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<SettledBed, OnBedError> {
    let spec = on.spec;
    let started = Instant::now();
    let s = setup(spec, preparation_contact(spec))?;
    let seed = spec.specimen_seed();
    let r_max = s.size.max_radius();
    let sp = &spec.specimen;
    let target_solid = sp.width * sp.width * sp.height * sp.packing_fraction;
    let spacing = 2.0 * r_max * 1.3;
    // Grain sizes first (the engine RNG, seeded by the specimen's seed).
    let aimed = 0.5 * Vec3::new(sp.width, sp.width, sp.height);
    let (mut sizer, _) = box_world(spec, &s, -aimed, aimed, (-aimed, aimed), seed)?;
    let mut radii = Vec::new();
    let mut volume = 0.0;
    while volume < target_solid {
        let r = s.size.sample(sizer.rng());
        volume += 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
        radii.push(r);
    }
    // A lattice nx × nx across and as many layers as it takes: the specimen's aspect.
    let nx = ((radii.len() as f64 * sp.width / sp.height).cbrt().ceil() as usize).max(2);
    let layers = radii.len().div_ceil(nx * nx);
    let half = Vec3::new(
        0.5 * nx as f64 * spacing,
        0.5 * nx as f64 * spacing,
        0.5 * layers as f64 * spacing,
    );
    let margin = Vec3::repeat(4.0 * r_max);
    let (mut world, walls) =
        box_world(spec, &s, -half, half, (-half - margin, half + margin), seed)?;
    let mut jitter = SplitMix(seed ^ 0x7a1a_0000_5eed_0001);
    for (k, &r) in radii.iter().enumerate() {
        let layer = k / (nx * nx);
        let (j, i) = ((k % (nx * nx)) / nx, k % nx);
        let room = 0.5 * (spacing - 2.0 * r);
        let cell = |n: usize| (n as f64 + 0.5) * spacing;
        let position = Vec3::new(
            -half.x + cell(i) + room * jitter.symmetric(),
            -half.y + cell(j) + room * jitter.symmetric(),
            -half.z + cell(layer) + room * jitter.symmetric(),
        );
        // Speeds of a few grain diameters over the compaction, so the lattice is forgotten.
        let speed = 20.0 * r_max;
        let velocity =
            Vec3::new(jitter.symmetric(), jitter.symmetric(), jitter.symmetric()) * speed;
        world
            .add_particle(ParticleSpec {
                position,
                velocity,
                angular_velocity: Vec3::zeros(),
                radius: r,
                material: s.soil,
            })
            .map_err(|e| OnBedError::build("specimen", e))?;
    }
    let backend = &mut *on.engine.start_movable(world, &walls.ids)?;
    let mut servo = Servo::new(spec, walls, s.dt);
    let time_cap = 3.0 * spec.consolidation.time_cap;
    let held = consolidate(
        spec,
        &mut servo,
        backend,
        1e3 * spec.preparation.pressure_kpa,
        time_cap,
        &mut |fraction, backend| check(spec, backend, started, "preparing", fraction, progress),
    )?;
    let grains = backend.grains()?;
    let ke = kinetic_energy_ratio(&grains);
    let v3 = |v: &Vec3| [v.x, v.y, v.z];
    let bed = SettledBed {
        key: on.bed_key(),
        positions: grains.position.iter().map(v3).collect(),
        velocities: grains.velocity.iter().map(v3).collect(),
        angular_velocities: grains.angular_velocity.iter().map(v3).collect(),
        radii: grains.radius.to_vec(),
        surface_z: held.state.hi.z,
        settled: held.consolidated,
        settled_by: if held.consolidated {
            SettledBy::Stable
        } else {
            SettledBy::TimeCap
        },
        kinetic_energy_ratio: ke,
        simulated_time_s: backend.time(),
        steps: backend.steps(),
        wall_time_s: started.elapsed().as_secs_f64(),
        escaped: backend.removed_count()?,
    };
    Ok(bed)
}

/// The box the grains of `bed` fill (each grain's extent), lower and upper corners.
fn extent(bed: &SettledBed) -> (Vec3, Vec3) {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for (p, &r) in bed.positions.iter().zip(&bed.radii) {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] - r);
            hi[a] = hi[a].max(p[a] + r);
        }
    }
    (lo, hi)
}

/// The solid volume of `bed`'s grains, m³.
fn solid_volume(bed: &SettledBed) -> f64 {
    bed.radii
        .iter()
        .map(|r| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3))
        .sum()
}

/// Every stage from copies of `bed`, then the readings.
fn load_stages(
    on: &TriaxialOn<'_>,
    bed: SettledBed,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<TriaxialRun, OnBedError> {
    let spec = on.spec;
    let started = Instant::now();
    let s = setup(spec, spec.soil_soil)?;
    let solid = solid_volume(&bed);
    let (lo, hi) = extent(&bed);
    let size = hi - lo;
    let prepared_void_ratio = size.x * size.y * size.z / solid - 1.0;
    let n = spec.confining_pressures_kpa.len();
    let mut stages = Vec::with_capacity(n);
    let mut sheared = Vec::new();
    let (mut simulated, mut steps) = (0.0, 0);
    for (k, &sigma) in spec.confining_pressures_kpa.iter().enumerate() {
        let mut stage_progress = |fraction: f64, phase: &'static str, backend: &mut dyn Backend| {
            check(
                spec,
                backend,
                started,
                phase,
                (k as f64 + fraction) / n as f64,
                progress,
            )
        };
        let (stage, grains) = run_stage(on, &s, &bed, sigma, solid, &mut stage_progress)?;
        simulated += stage.simulated_time_s;
        steps += stage.steps;
        stages.push(stage);
        sheared = grains;
    }
    let circles: Vec<(f64, f64)> = stages
        .iter()
        .map(|st| {
            (
                st.failure_confining_kpa,
                st.failure_confining_kpa + st.peak_deviator_kpa,
            )
        })
        .collect();
    let fit = envelope(&circles);
    let mean = |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let (status, message) = match (&fit, bed.settled, stages.iter().all(|s| s.consolidated)) {
        (Err(e), _, _) => (TriaxialStatus::MeasurementFailed, Some(e.to_string())),
        (Ok(_), false, _) => (
            TriaxialStatus::SpecimenNotPrepared,
            Some("the walls did not hold the preparation pressure within the time cap".into()),
        ),
        (Ok(_), true, false) => (
            TriaxialStatus::NotConsolidated,
            Some("a stage did not consolidate within its time cap (loaded anyway)".into()),
        ),
        (Ok(_), true, true) => (TriaxialStatus::Ok, None),
    };
    let envelope = fit.ok();
    let result = TriaxialResult {
        status,
        message,
        cohesion_kpa: envelope.map(|e| e.cohesion_kpa),
        friction_angle_deg: envelope.map(|e| e.friction_angle_deg),
        envelope,
        young_modulus_mpa: mean(stages.iter().filter_map(|s| s.young_modulus_mpa).collect()),
        poisson_ratio: mean(stages.iter().filter_map(|s| s.poisson_ratio).collect()),
        void_ratio: prepared_void_ratio,
        specimen: BedInfo::of(&bed),
        width_mm: 1e3 * 0.5 * (size.x + size.y),
        height_mm: 1e3 * size.z,
        grain_diameter_mm: 2e3 * bed.radii.iter().sum::<f64>() / bed.radii.len().max(1) as f64,
        particles: bed.positions.len(),
        time_step_s: s.dt,
        simulated_time_s: simulated,
        steps,
        wall_time_s: started.elapsed().as_secs_f64(),
        engine_version: Some(on.engine.engine_version()),
        stages,
    };
    Ok(TriaxialRun { result, sheared })
}

/// A stage's progress callback: the stage's fraction done, its phase, the backend (for the
/// grain count).
type StageProgress<'a> =
    dyn FnMut(f64, &'static str, &mut dyn Backend) -> Result<(), OnBedError> + 'a;

/// A grain's centre and radius, m.
pub type Grain = ([f64; 3], f64);

/// A stage's progress: consolidation is the first 30 % (against its time cap), loading the
/// rest (against the axial strain).
const CONSOLIDATION_SHARE: f64 = 0.3;

/// One confining pressure `sigma_kpa` on a copy of `bed`; the stage and its grains at the end.
fn run_stage(
    on: &TriaxialOn<'_>,
    s: &Setup,
    bed: &SettledBed,
    sigma_kpa: f64,
    solid: f64,
    progress: &mut StageProgress<'_>,
) -> Result<(TriaxialStage, Vec<Grain>), OnBedError> {
    let spec = on.spec;
    let (lo, hi) = extent(bed);
    let size = hi - lo;
    let r_max = s.size.max_radius();
    // Room for the lateral walls to move out (dilation, bulging) and the platens in.
    let room = Vec3::new(0.5 * size.x, 0.5 * size.y, 0.1 * size.z) + Vec3::repeat(4.0 * r_max);
    let (mut world, walls) = box_world(spec, s, lo, hi, (lo - room, hi + room), spec.seed)?;
    for k in 0..bed.positions.len() {
        let v = |x: [f64; 3]| Vec3::new(x[0], x[1], x[2]);
        world
            .add_particle(ParticleSpec {
                position: v(bed.positions[k]),
                velocity: v(bed.velocities[k]),
                angular_velocity: v(bed.angular_velocities[k]),
                radius: bed.radii[k],
                material: s.soil,
            })
            .map_err(|e| OnBedError::build("specimen", e))?;
    }
    let particles = world.particles().len();
    let backend = &mut *on.engine.start_movable(world, &walls.ids)?;
    let mut servo = Servo::new(spec, walls, s.dt);
    let target = 1e3 * sigma_kpa;
    let cap = spec.consolidation.time_cap;
    let held = consolidate(spec, &mut servo, backend, target, cap, &mut |f, backend| {
        progress(CONSOLIDATION_SHARE * f, "consolidating", backend)
    })?;
    let consolidation_time = backend.time();
    let ke = kinetic_energy_ratio(&backend.grains()?);
    let void_ratio = held.state.volume() / solid - 1.0;

    // Drained loading: the platens close at the strain rate of the height at the start.
    let h0 = held.state.size().z;
    let v0 = held.state.volume();
    let platen_rate = spec.loading.strain_rate;
    let mut state = held.state;
    let mut series = Vec::new();
    loop {
        // Each platen moves at half the rate of the height at the start of loading.
        let rate = platen_rate * h0 / state.size().z;
        servo.drive(backend, &state, target, 4, rate)?;
        advance_exactly(backend, servo.steps_per_control)?;
        let before = (state.lo, state.hi);
        state = servo.read(backend)?;
        let mid_size = 0.5 * ((before.1 - before.0) + state.size());
        let volume = mid_size.x * mid_size.y * mid_size.z;
        let axial_strain = (h0 - mid_size.z) / h0;
        series.push(TriaxialSample {
            axial_strain,
            deviator_kpa: 1e-3 * (state.axial() - state.lateral()),
            volumetric_strain: (v0 - volume) / v0,
            lateral_kpa: 1e-3 * state.lateral(),
        });
        let done = (h0 - state.size().z) / h0 >= spec.loading.axial_strain;
        progress(
            CONSOLIDATION_SHARE
                + (1.0 - CONSOLIDATION_SHARE) * (axial_strain / spec.loading.axial_strain),
            "loading",
            backend,
        )?;
        if done {
            break;
        }
    }
    let failed = failure(&series).ok_or_else(|| OnBedError::build("record", "no samples"))?;
    let stiff = stiffness(&series, &failed);
    let grains = backend.grains()?;
    let mean_d = 2.0 * grains.radius.iter().sum::<f64>() / grains.len().max(1) as f64;
    let sheared = (0..grains.len())
        .map(|k| {
            let p = grains.position[k];
            ([p.x, p.y, p.z], grains.radius[k])
        })
        .collect();
    let stage = TriaxialStage {
        confining_kpa: sigma_kpa,
        consolidated: held.consolidated,
        consolidation_time_s: consolidation_time,
        simulated_time_s: backend.time(),
        void_ratio,
        peak_deviator_kpa: failed.deviator_kpa,
        failure_confining_kpa: failed.confining_kpa,
        axial_strain_at_peak: failed.axial_strain,
        peaked: failed.peaked,
        young_modulus_mpa: stiff.map(|s| s.young_modulus_mpa),
        poisson_ratio: stiff.map(|s| s.poisson_ratio),
        volumetric_strain_at_peak: series[failed.index].volumetric_strain,
        inertial_number: platen_rate * mean_d * (s.density / target).sqrt(),
        kinetic_energy_ratio: ke,
        particles,
        escaped: backend.removed_count()?,
        steps: backend.steps(),
        series,
    };
    Ok((stage, sheared))
}
