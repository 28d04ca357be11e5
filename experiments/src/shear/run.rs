//! Runs a [`ShearSpec`]: the sample is poured into the closed box and settled (once; a caller
//! may cache it), then for each normal stress, from that same sample: the lid is lowered and
//! servo-controlled until it holds the normal stress (consolidation), the upper half and the
//! lid move along +x at constant speed while the lid keeps holding the stress (shearing), and
//! the shear force is recorded against the displacement.
//!
//! Frame: z up, the box's floor at z = 0 centred on the z axis, the shear plane at
//! z = `box.half_height`. Geometries (all steel):
//! - the lower half: floor and walls up to the shear plane, with a ledge at the plane's height
//!   beyond its +x wall (as wide as the displacement plus two grains) on which the part of the
//!   upper sample that moves past the lower half rests instead of falling out;
//! - the upper half: four walls from the shear plane up `box.upper_height`;
//! - the lid: a square as wide as the inside, driven by [`World::set_geometry_motion`].
//!
//! The shear force is the force of the grains on the lower half along x: quasi-statically the
//! lower sample is in equilibrium, so it is the force carried across the shear plane (it does
//! not include the lid's or the upper half's wall friction). The normal stress on the plane is
//! measured too: the lid's force plus the weight of the grains above the plane (at the start of
//! shearing) less the vertical load the upper half's walls take by friction, over the box's
//! inside area (the nominal area, not corrected for the displacement; so is the shear stress).

use crate::Spec;
use std::time::Instant;

use repose_engine::kinematics::Motion;
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::generators::{open_box, plane};
use repose_engine::mesh::TriMesh;
use repose_engine::neighbor::Domain;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, GeometryId, World, WorldConfig};
use serde::{Deserialize, Serialize};

use super::measure::{
    mohr_coulomb_fit, running_mean, shear_strength, MohrCoulomb, ShearRecord, StrengthPoint,
};
use super::picture::{curves_svg, strength_svg};
use super::spec::ShearSpec;
use crate::backend::{advance_exactly, time_after, Backend, Engine, PlaneStress, Window};
pub use crate::progress::{Control, Progress};
use crate::soil::{
    kinetic_energy_ratio, run_on_bed, setup, BedInfo, NoBedStore, On, OnBed, OnBedError,
    SettledBed, Setup,
};

/// Why a run could not start or was stopped before it could report: the error of every kind
/// that runs on a settled bed ([`OnBedError`]; a finished run that did not go as planned is a
/// [`ShearResult`] with a non-`ok` status, not an error).
pub type ShearError = OnBedError;

fn build_error(part: &'static str, e: impl std::fmt::Display) -> ShearError {
    OnBedError::build(part, e)
}

/// Overall outcome. The strength is reported for every status but `measurement_failed`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShearStatus {
    Ok,
    /// The poured sample did not come to rest within its time cap (sheared as it stood).
    SampleNotSettled,
    /// A stage's lid did not hold its force within the tolerance before the time cap (that
    /// stage was sheared anyway).
    NotConsolidated,
    /// No Mohr-Coulomb fit could be made.
    MeasurementFailed,
}

/// One recorded point of a stage's shearing (means over one servo interval).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ShearSample {
    /// Displacement of the upper half at the interval's middle, mm.
    pub displacement_mm: f64,
    /// Shear force on the lower half over the box's area, kPa.
    pub shear_stress_kpa: f64,
    /// The lid's force over the box's area, kPa (its target is the stage's normal stress).
    pub lid_stress_kpa: f64,
    /// Height of the lid above the floor, mm (its rise is the sample's dilation).
    pub lid_z_mm: f64,
    /// The soil's own shear and normal stress on the plane, in the measurement window away
    /// from the walls (`window.*`), kPa.
    #[serde(default)]
    pub window_shear_kpa: f64,
    #[serde(default)]
    pub window_normal_kpa: f64,
}

/// One normal stress: consolidation and shearing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShearStage {
    /// The lid's target, kPa.
    pub normal_stress_kpa: f64,
    /// On the shear plane, the Mohr-Coulomb fit's σ: the mean while shearing of the lid's force,
    /// plus the weight of the grains above the plane, less what the upper half's walls carry by
    /// friction, over the box's area, kPa.
    pub plane_normal_stress_kpa: f64,
    pub consolidated: bool,
    /// Simulated time from the lid's start to consolidation (or the cap), s.
    pub consolidation_time_s: f64,
    /// Largest shear stress and the displacement where it occurred.
    pub peak_kpa: f64,
    pub peak_displacement_mm: f64,
    /// Mean shear stress over the last `shear.residual_fraction` of the displacement.
    pub residual_kpa: f64,
    /// The soil's own normal stress on the plane in the measurement window (mean while
    /// shearing), and its shear stress's peak (of the record smoothed over a twentieth of the
    /// displacement) and residual, kPa.
    #[serde(default)]
    pub window_normal_stress_kpa: f64,
    #[serde(default)]
    pub window_peak_kpa: f64,
    #[serde(default)]
    pub window_residual_kpa: f64,
    /// The lid's mean stress while shearing (how well the servo held it), kPa.
    pub mean_lid_stress_kpa: f64,
    /// Rise of the lid from the start to the end of shearing, mm (positive: dilation).
    pub dilation_mm: f64,
    /// Mean kinetic energy per grain over m g d at the end of consolidation.
    pub kinetic_energy_ratio: f64,
    /// Grains in the box (poured grains resting on a wall's rim are left out).
    pub particles: usize,
    /// Grains that left the box during the stage.
    pub escaped: u64,
    pub steps: u64,
    pub series: Vec<ShearSample>,
}

/// The result of one shear test (serde; what `result.json` holds). Stresses in kPa, lengths in
/// mm, times in s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShearResult {
    pub status: ShearStatus,
    pub message: Option<String>,
    /// The soil's strength: of `window_fit`.
    pub cohesion_kpa: Option<f64>,
    pub friction_angle_deg: Option<f64>,
    /// The Mohr-Coulomb fit of the soil's own stresses in the measurement window, away from
    /// the box's walls: each stage's window normal stress and window peak.
    #[serde(default)]
    pub window_fit: Option<MohrCoulomb>,
    /// The Mohr-Coulomb fits of what the box's forces read (the lid's and the lower half's,
    /// as a lab's box reads them): through the peaks and through the residuals. The walls'
    /// share is in them (docs/shear.md, "Where the strength is read").
    pub peak_fit: Option<MohrCoulomb>,
    pub residual_fit: Option<MohrCoulomb>,
    pub stages: Vec<ShearStage>,
    pub bed: BedInfo,
    pub box_side_mm: f64,
    pub shear_plane_mm: f64,
    pub grain_diameter_mm: f64,
    /// Grains in the box (the sample's grains resting on a wall's rim left out).
    pub particles: usize,
    pub time_step_s: f64,
    /// Over all stages (the sample's own time is in `bed`).
    pub simulated_time_s: f64,
    pub steps: u64,
    /// Wall time of this call (the sample included if it was built here), s.
    pub wall_time_s: f64,
    /// The engine that computed the run: the CPU engine's version, or
    /// `<version>+gpu:<adapter>` for the GPU backend ([`Engine::engine_version`]). None in
    /// results written before the field existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub engine_version: Option<String>,
}

impl ShearResult {
    /// Samples kept over all stages in a job's `details` ([`Self::for_details`]).
    pub const DETAILS_SAMPLES: usize = 180;

    /// The copy a job's `details` hold: [`Self::thinned`] to [`Self::DETAILS_SAMPLES`] over
    /// all stages (at least 3 a stage), about 200 bytes of JSON a sample.
    pub fn for_details(&self) -> ShearResult {
        self.thinned((Self::DETAILS_SAMPLES / self.stages.len().max(1)).max(3))
    }

    /// A copy whose stage series keep at most `max_per_stage` samples, evenly spaced, the
    /// first, the last and the peak's included (`max_per_stage` at least 3). A job server
    /// bounds a result's details (64 KiB): the default preset records every servo interval,
    /// 2 000 samples a stage, about 0.5 MB for its four stages. The peaks, residuals and
    /// fits are computed from the full series before and are unchanged.
    pub fn thinned(&self, max_per_stage: usize) -> ShearResult {
        let mut out = self.clone();
        for stage in &mut out.stages {
            stage.series = thin_series(&stage.series, max_per_stage);
        }
        out
    }

    /// Scalar results for a job server: the soil's strength (the window's line)
    /// `cohesion_kpa`, `friction_angle_deg`, `r_squared`, `rmse_kpa`, `cohesion_std_error_kpa`
    /// (with three or more stresses); the box's peak line (`box_cohesion_kpa`,
    /// `box_friction_angle_deg`, `box_r_squared`) and residual line (`residual_cohesion_kpa`,
    /// `residual_friction_angle_deg`, `residual_r_squared`); `max_peak_kpa` (the box's),
    /// `mean_dilation_mm`, `particles`,
    /// `simulated_time_s`, and `came_to_rest` (1 when the sample settled and every stage
    /// consolidated, else 0; such a run is still measured, like the angle-of-repose runs).
    pub fn metrics(&self) -> std::collections::BTreeMap<String, f64> {
        let mut m = std::collections::BTreeMap::new();
        let Some(peak) = &self.window_fit else {
            return m;
        };
        let ok = self.status == ShearStatus::Ok;
        let mut values = vec![
            ("came_to_rest", Some(if ok { 1.0 } else { 0.0 })),
            ("cohesion_kpa", Some(peak.cohesion_kpa)),
            ("friction_angle_deg", Some(peak.friction_angle_deg)),
            ("r_squared", Some(peak.r_squared)),
            ("rmse_kpa", Some(peak.rmse_kpa)),
            ("cohesion_std_error_kpa", peak.cohesion_std_error_kpa),
            (
                "max_peak_kpa",
                self.stages.iter().map(|s| s.peak_kpa).reduce(f64::max),
            ),
            (
                "mean_dilation_mm",
                Some(
                    self.stages.iter().map(|s| s.dilation_mm).sum::<f64>()
                        / self.stages.len().max(1) as f64,
                ),
            ),
            ("particles", Some(self.particles as f64)),
            ("simulated_time_s", Some(self.simulated_time_s)),
        ];
        if let Some(b) = &self.peak_fit {
            values.push(("box_cohesion_kpa", Some(b.cohesion_kpa)));
            values.push(("box_friction_angle_deg", Some(b.friction_angle_deg)));
            values.push(("box_r_squared", Some(b.r_squared)));
        }
        if let Some(r) = &self.residual_fit {
            values.push(("residual_cohesion_kpa", Some(r.cohesion_kpa)));
            values.push(("residual_friction_angle_deg", Some(r.friction_angle_deg)));
            values.push(("residual_r_squared", Some(r.r_squared)));
        }
        for (k, v) in values {
            if let Some(v) = v.filter(|v| v.is_finite()) {
                m.insert(k.to_owned(), v);
            }
        }
        m
    }
}

/// At most `max` (at least 3) of `series`, evenly spaced, the first, the last and the highest
/// shear stress included.
fn thin_series(series: &[ShearSample], max: usize) -> Vec<ShearSample> {
    let n = series.len();
    let max = max.max(3);
    if n <= max {
        return series.to_vec();
    }
    let peak = series
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.shear_stress_kpa.total_cmp(&b.1.shear_stress_kpa))
        .map_or(0, |(i, _)| i);
    // max - 1 evenly spaced indices from 0 to n - 1, then the peak's.
    let mut keep: Vec<usize> = (0..max - 1).map(|k| k * (n - 1) / (max - 2)).collect();
    keep.push(peak);
    keep.sort_unstable();
    keep.dedup();
    keep.into_iter().map(|i| series[i]).collect()
}

/// A finished run: the result and what a caller may want to draw or keep.
#[derive(Debug, Clone)]
pub struct ShearRun {
    pub result: ShearResult,
    /// The sample the stages started from.
    pub bed: SettledBed,
    pub spec: ShearSpec,
}

impl ShearRun {
    /// Shear stress against displacement, one curve per normal stress.
    pub fn curves_svg(&self) -> String {
        curves_svg(&self.result)
    }

    /// The Mohr-Coulomb lines (peak and residual) with their points.
    pub fn strength_svg(&self) -> String {
        strength_svg(&self.result)
    }

    /// Every stage's record as CSV: `normal_stress_kpa,displacement_mm,shear_stress_kpa,
    /// lid_stress_kpa,lid_z_mm,window_shear_kpa,window_normal_kpa`.
    pub fn curves_csv(&self) -> String {
        let mut s = String::from(
            "normal_stress_kpa,displacement_mm,shear_stress_kpa,lid_stress_kpa,lid_z_mm,\
             window_shear_kpa,window_normal_kpa\n",
        );
        for stage in &self.result.stages {
            for p in &stage.series {
                s.push_str(&format!(
                    "{},{},{},{},{},{},{}\n",
                    stage.normal_stress_kpa,
                    p.displacement_mm,
                    p.shear_stress_kpa,
                    p.lid_stress_kpa,
                    p.lid_z_mm,
                    p.window_shear_kpa,
                    p.window_normal_kpa
                ));
            }
        }
        s
    }
}

/// The sample's cache key: the key of [`ShearSpec::bed_recipe`].
pub fn sample_key(spec: &ShearSpec) -> String {
    spec.bed_recipe().key()
}

/// Pours and settles the sample of `spec` (the drilling bed recipe in the closed box) on the
/// CPU engine.
pub fn build_sample(
    spec: &ShearSpec,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<SettledBed, ShearError> {
    ShearOn::cpu(spec).build_bed(progress)
}

/// A shear spec on an engine: its sample is settled and sheared there ([`On`]).
pub type ShearOn<'a> = On<'a, ShearSpec>;

/// Builds the sample and runs every stage on it ([`run_on_bed`] without a store), on the CPU
/// engine. The sample takes the first fifth of the progress fraction.
pub fn run_shear(
    spec: &ShearSpec,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<ShearRun, ShearError> {
    run_on_bed(&ShearOn::cpu(spec), &mut NoBedStore, progress)
}

/// Runs every stage on a sample built earlier by [`build_sample`] for a spec with the same
/// [`sample_key`] (e.g. from a cache), on the CPU engine. Same outcome, bit for bit, as
/// [`run_shear`], but for `bed.reused` (true here) and the wall time (without the sample's).
pub fn run_shear_on_bed(
    spec: &ShearSpec,
    bed: SettledBed,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<ShearRun, ShearError> {
    ShearOn::cpu(spec).run_on_bed(bed, progress)
}

/// The shear test runs on a settled sample, built in the first fifth of the progress.
impl OnBed for ShearOn<'_> {
    type Run = ShearRun;
    type Error = ShearError;
    const BED_SHARE: f64 = 0.2;

    fn bed_key(&self) -> String {
        self.spec.bed_recipe().key_on(self.engine.kind())
    }

    fn build_bed(
        &self,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<SettledBed, ShearError> {
        self.spec.validate()?;
        Ok(self.spec.bed_recipe().build_on(self.engine, &mut |p| {
            progress(Progress {
                fraction: p.fraction,
                phase: "sample",
                time: p.time,
                particles: p.particles,
            })
        })?)
    }

    fn run_on_matching_bed(
        &self,
        bed: SettledBed,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<ShearRun, ShearError> {
        shear(self.engine, self.spec, bed, progress)
    }

    fn bed_of(run: &mut ShearRun) -> (&mut BedInfo, &mut f64) {
        (&mut run.result.bed, &mut run.result.wall_time_s)
    }
}

/// Runs every stage on `bed` on `engine` (handed in: `bed.reused` is true until
/// [`run_on_bed`] says otherwise).
fn shear(
    engine: Engine<'_>,
    spec: &ShearSpec,
    bed: SettledBed,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<ShearRun, ShearError> {
    let started = Instant::now();
    spec.validate()?;
    // The sample's setup (grain sizes, time step) with the spec's own contacts: the sample was
    // poured without cohesion, the stages have it.
    let mut s = setup(&spec.bed_recipe())?;
    s.table = spec
        .material_set()
        .build()
        .map_err(|e| build_error("materials", e))?;
    let n = spec.normal_stresses_kpa.len();
    let mut stages = Vec::with_capacity(n);
    let (mut simulated, mut steps) = (0.0, 0);
    for (k, &sigma) in spec.normal_stresses_kpa.iter().enumerate() {
        let stage = run_stage(engine, spec, &s, &bed, sigma, started, &mut |p| {
            progress(Progress {
                fraction: (k as f64 + p.fraction) / n as f64,
                ..p
            })
        })?;
        simulated += stage.steps as f64 * s.dt;
        steps += stage.steps;
        stages.push(stage);
    }
    let _ = progress(Progress {
        fraction: 1.0,
        phase: "measuring",
        time: simulated,
        particles: bed.positions.len(),
    });

    // A Mohr-Coulomb line through each stage's (σ, τ), kPa.
    let fit = |point: fn(&ShearStage) -> (f64, f64)| {
        let points: Vec<StrengthPoint> = stages
            .iter()
            .map(|st| {
                let (sigma, tau) = point(st);
                StrengthPoint {
                    normal_stress_pa: 1e3 * sigma,
                    shear_stress_pa: 1e3 * tau,
                }
            })
            .collect();
        mohr_coulomb_fit(&points)
    };
    let box_peak = fit(|st| (st.plane_normal_stress_kpa, st.peak_kpa)).ok();
    let residual = fit(|st| (st.plane_normal_stress_kpa, st.residual_kpa)).ok();
    // The soil's strength: the window's stresses (see `window`), not the box's forces.
    let peak = fit(|st| (st.window_normal_stress_kpa, st.window_peak_kpa));
    let (status, message) = match &peak {
        Err(e) => (ShearStatus::MeasurementFailed, Some(e.to_string())),
        Ok(_) if !bed.settled => (
            ShearStatus::SampleNotSettled,
            Some(format!(
                "the poured sample did not come to rest (kinetic energy ratio {:.2e} > {:.2e})",
                bed.kinetic_energy_ratio, spec.bed.settle.kinetic_energy_threshold
            )),
        ),
        Ok(_) => match stages.iter().find(|st| !st.consolidated) {
            Some(st) => (
                ShearStatus::NotConsolidated,
                Some(format!(
                    "the lid did not hold {} kPa within {} % for {} s within {} s",
                    st.normal_stress_kpa,
                    100.0 * spec.consolidation.tolerance,
                    spec.consolidation.hold_time,
                    spec.consolidation.time_cap
                )),
            ),
            None => (ShearStatus::Ok, None),
        },
    };
    let peak = peak.ok();
    let particles = stages.first().map_or(0, |st| st.particles);
    let mean_r = bed.radii.iter().sum::<f64>() / bed.radii.len().max(1) as f64;
    let result = ShearResult {
        status,
        message,
        cohesion_kpa: peak.map(|f| f.cohesion_kpa),
        friction_angle_deg: peak.map(|f| f.friction_angle_deg),
        window_fit: peak,
        peak_fit: box_peak,
        residual_fit: residual,
        stages,
        bed: BedInfo::of(&bed),
        box_side_mm: 1e3 * spec.shear_box.side,
        shear_plane_mm: 1e3 * spec.shear_box.half_height,
        grain_diameter_mm: 2e3 * mean_r,
        particles,
        time_step_s: s.dt,
        simulated_time_s: simulated,
        steps,
        wall_time_s: started.elapsed().as_secs_f64(),
        engine_version: Some(engine.engine_version()),
    };
    Ok(ShearRun {
        result,
        bed,
        spec: spec.clone(),
    })
}

/// Four vertical walls around `[-side/2, side/2]²` from z = `bottom` to z = `top`, open at both
/// ends.
fn walls(side: f64, bottom: f64, top: f64) -> Result<TriMesh, ShearError> {
    let h = 0.5 * side;
    let corners = [(-h, -h), (h, -h), (h, h), (-h, h)];
    let mut vertices = Vec::with_capacity(8);
    for z in [bottom, top] {
        for &(x, y) in &corners {
            vertices.push(Vec3::new(x, y, z));
        }
    }
    let mut triangles = Vec::with_capacity(8);
    for k in 0..4u32 {
        let k1 = (k + 1) % 4;
        triangles.push([k, k1, 4 + k1]);
        triangles.push([k, 4 + k1, 4 + k]);
    }
    TriMesh::new(vertices, triangles).map_err(|e| build_error("upper half", e))
}

/// The lower half: the open box up to the shear plane and the ledge beyond its +x wall.
fn lower_half(side: f64, plane_z: f64, ledge: f64) -> Result<TriMesh, ShearError> {
    let cup = open_box(side, side, plane_z).map_err(|e| build_error("lower half", e))?;
    let strip = plane(ledge, side, 1, 1)
        .and_then(|m| m.transformed(&Pose::translation(0.5 * side + 0.5 * ledge, 0.0, plane_z)))
        .map_err(|e| build_error("lower half", e))?;
    TriMesh::merged(&[&cup, &strip]).map_err(|e| build_error("lower half", e))
}

/// Mean force on `id` over the samples recorded since the series were last cleared.
fn mean_force(backend: &mut dyn Backend, id: GeometryId) -> Result<Vec3, ShearError> {
    let series = backend.geometry_series(id)?;
    if series.is_empty() {
        return Ok(Vec3::zeros());
    }
    Ok(series.iter().map(|s| s.force).sum::<Vec3>() / series.len() as f64)
}

/// A stage's progress: consolidation is the first 30 % (against its time cap), shearing the
/// rest (against the displacement).
const CONSOLIDATION_SHARE: f64 = 0.3;

/// Samples of the window's stresses per servo interval (each a pass over the contacts).
const WINDOW_SAMPLES_PER_INTERVAL: u64 = 4;

/// The window's shear record is smoothed over 1/this of its samples before its peak is taken.
const WINDOW_SMOOTHING_DIVISOR: usize = 20;

fn run_stage(
    engine: Engine<'_>,
    spec: &ShearSpec,
    s: &Setup,
    bed: &SettledBed,
    sigma_kpa: f64,
    started: Instant,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<ShearStage, ShearError> {
    let side = spec.shear_box.side;
    let h = spec.shear_box.half_height;
    let area = side * side;
    let r_max = s.size.max_radius();
    let ledge = spec.shear.displacement + 4.0 * r_max;
    let upper_top = h + spec.shear_box.upper_height;
    let margin = 4.0 * r_max;
    let domain = Domain::closed(
        Vec3::new(-0.5 * side - margin, -0.5 * side - margin, -0.02),
        Vec3::new(
            0.5 * side + ledge + spec.shear.displacement + margin,
            0.5 * side + margin,
            upper_top + 0.05,
        ),
    );
    let mut config = WorldConfig::new(s.dt, domain);
    config.rolling_model = spec.engine_rolling_model();
    config.seed = spec.seed;
    let mut world = World::new(s.table.clone(), config).map_err(|e| build_error("world", e))?;
    let add = |name: &str, mesh: TriMesh, pose: Pose, world: &mut World| {
        world
            .add_geometry(Geometry {
                name: name.into(),
                mesh,
                motion: Motion::stationary(pose),
                material: s.steel,
            })
            .map_err(|e| build_error("box", e))
    };
    let lower = add(
        "lower half",
        lower_half(side, h, ledge)?,
        Pose::identity(),
        &mut world,
    )?;
    let upper = add(
        "upper half",
        walls(side, h, upper_top)?,
        Pose::identity(),
        &mut world,
    )?;
    // Grains poured onto a wall's rim (or over it) are not part of the sample.
    let inside = |p: &[f64; 3]| {
        p[0].abs() < 0.5 * side && p[1].abs() < 0.5 * side && p[2] > 0.0 && p[2] < upper_top
    };
    let top_grain = bed
        .positions
        .iter()
        .zip(&bed.radii)
        .filter(|(p, _)| inside(p))
        .map(|(p, r)| p[2] + r)
        .fold(0.0, f64::max);
    let lid_mesh = plane(side, side, 1, 1).map_err(|e| build_error("lid", e))?;
    let lid = add(
        "lid",
        lid_mesh,
        Pose::translation(0.0, 0.0, top_grain + 0.25 * r_max),
        &mut world,
    )?;
    for k in 0..bed.positions.len() {
        if !inside(&bed.positions[k]) {
            continue;
        }
        let v = |x: [f64; 3]| Vec3::new(x[0], x[1], x[2]);
        world
            .add_particle(ParticleSpec {
                position: v(bed.positions[k]),
                velocity: v(bed.velocities[k]),
                angular_velocity: v(bed.angular_velocities[k]),
                radius: bed.radii[k],
                material: s.soil,
            })
            .map_err(|e| build_error("sample", e))?;
    }

    let particles = world.particles().len();
    let gravity = world.config().gravity.z;
    let backend = &mut *engine.start_movable(world, &[lower, upper, lid])?;
    let servo = &spec.servo;
    let steps_per_control = ((servo.interval / s.dt).round() as u64).max(1);
    let control_time = steps_per_control as f64 * s.dt;
    let target = 1e3 * sigma_kpa * area;
    // The lid's force is low-pass filtered (first order, `servo.filter_time`) before it sets
    // the speed: the raw force of a few hundred contacts jitters by several per cent from one
    // interval to the next, and a lid that follows the jitter shakes the sample.
    let smoothing = (control_time / servo.filter_time).min(1.0);
    let lid_speed = |force: f64| {
        (servo.gain * (force - target) / target).clamp(-servo.max_speed, servo.max_speed)
    };
    let pose_of = |backend: &dyn Backend, id: GeometryId| {
        backend.geometries()[id.0 as usize]
            .motion
            .pose_at(backend.time())
    };
    let set_motion = |backend: &mut dyn Backend, id: GeometryId, velocity: Vec3| {
        let motion = Motion::translating(pose_of(backend, id), velocity, backend.time())
            .map_err(|e| build_error("servo", e))?;
        backend.set_geometry_motion(id, motion)?;
        Ok::<(), ShearError>(())
    };
    let lid_z = |backend: &dyn Backend| pose_of(backend, lid).translation.z;
    let check = |backend: &mut dyn Backend,
                 phase: &'static str,
                 fraction: f64,
                 progress: &mut dyn FnMut(Progress<'_>) -> Control| {
        if progress(Progress {
            fraction,
            phase,
            time: backend.time(),
            particles: backend.grain_count()?,
        }) == Control::Cancel
        {
            return Err(ShearError::Cancelled);
        }
        match spec.wall_time_cap {
            Some(cap) if started.elapsed().as_secs_f64() > cap => {
                Err(ShearError::WallTimeCap { phase, cap_s: cap })
            }
            _ => Ok(()),
        }
    };

    // Consolidation: the lid comes down and holds the target force.
    let c = &spec.consolidation;
    set_motion(backend, lid, Vec3::new(0.0, 0.0, -servo.max_speed))?;
    backend.clear_geometry_series();
    let mut held = 0.0;
    let mut force = 0.0;
    let consolidated = loop {
        advance_exactly(backend, steps_per_control)?;
        force += smoothing * (mean_force(backend, lid)?.z - force);
        backend.clear_geometry_series();
        if ((force - target) / target).abs() <= c.tolerance {
            held += control_time;
        } else {
            held = 0.0;
        }
        let t = backend.time();
        check(
            backend,
            "consolidating",
            CONSOLIDATION_SHARE * (t / c.time_cap).min(1.0),
            progress,
        )?;
        if held >= c.hold_time {
            break true;
        }
        if t >= c.time_cap {
            break false;
        }
        set_motion(backend, lid, Vec3::new(0.0, 0.0, lid_speed(force)))?;
    };
    let consolidation_time = backend.time();
    let grains = backend.grains()?;
    let kinetic_energy_ratio = kinetic_energy_ratio(&grains);

    // Shearing: the upper half and the lid move along +x; the lid keeps the stress.
    let above: f64 = (0..grains.len())
        .filter(|&k| grains.position[k].z > h)
        .map(|k| grains.mass[k])
        .sum();
    let weight_above = above * gravity.abs();
    let v = spec.shear.speed;
    let t_start = backend.time();
    let z_start = lid_z(backend);
    set_motion(backend, upper, Vec3::new(v, 0.0, 0.0))?;
    let mut series = Vec::new();
    let mut plane_force = 0.0;
    // The soil's own stresses (`Window`): the window follows the part of the plane the two
    // halves still share, inset from its walls; sampled a few times per interval.
    let d = 2.0 * r_max;
    let inset = spec.window.margin_grains * d;
    let half_slab = 0.5 * spec.window.thickness_grains * d;
    let window_at = |u: f64| Window {
        x: [-0.5 * side + u + inset, 0.5 * side - inset],
        y: [-0.5 * side + inset, 0.5 * side - inset],
        z: [h - half_slab, h + half_slab],
    };
    let per_sample = (steps_per_control / WINDOW_SAMPLES_PER_INTERVAL).max(1);
    loop {
        set_motion(backend, lid, Vec3::new(v, 0.0, lid_speed(force)))?;
        let (mut ran, mut samples, mut inner) = (0, 0.0, PlaneStress::default());
        while ran < steps_per_control {
            let k = per_sample.min(steps_per_control - ran);
            // The window where it is at the sample's time, the end of these steps.
            let end = time_after(backend.time(), backend.time_step(), k);
            let sample = backend.advance_sampling(k, &window_at(v * (end - t_start)))?;
            ran += k;
            inner.normal_pa += sample.normal_pa;
            inner.shear_pa += sample.shear_pa;
            samples += 1.0;
        }
        let lid_force = mean_force(backend, lid)?.z;
        force += smoothing * (lid_force - force);
        let shear_force = mean_force(backend, lower)?.x;
        // What the upper half's walls carry by friction (negative: they hold the soil up).
        let wall_load = mean_force(backend, upper)?.z;
        plane_force += lid_force + wall_load + weight_above;
        backend.clear_geometry_series();
        let t = backend.time();
        let displacement = v * (t - t_start - 0.5 * control_time);
        series.push(ShearSample {
            displacement_mm: 1e3 * displacement,
            shear_stress_kpa: 1e-3 * shear_force / area,
            lid_stress_kpa: 1e-3 * lid_force / area,
            lid_z_mm: 1e3 * lid_z(backend),
            window_shear_kpa: 1e-3 * inner.shear_pa / samples,
            window_normal_kpa: 1e-3 * inner.normal_pa / samples,
        });
        let done = v * (t - t_start) >= spec.shear.displacement;
        check(
            backend,
            "shearing",
            CONSOLIDATION_SHARE
                + (1.0 - CONSOLIDATION_SHARE)
                    * (v * (t - t_start) / spec.shear.displacement).min(1.0),
            progress,
        )?;
        if done {
            break;
        }
    }
    let plane_sigma_kpa = 1e-3 * plane_force / series.len() as f64 / area;
    let record = ShearRecord {
        normal_stress_pa: 1e3 * plane_sigma_kpa,
        area_m2: area,
        displacement_m: series.iter().map(|p| 1e-3 * p.displacement_mm).collect(),
        shear_force_n: series
            .iter()
            .map(|p| 1e3 * p.shear_stress_kpa * area)
            .collect(),
    };
    let strength = shear_strength(&record, spec.shear.residual_fraction)
        .map_err(|e| build_error("shear record", e))?;
    // The window's record: its mean normal stress, and its shear stress smoothed over a
    // twentieth of the displacement before the peak is taken (a few hundred contacts cross
    // the window's planes; their sum jitters by several per cent from sample to sample, and
    // the largest of a jittering record overstates the peak).
    let n = series.len();
    let window_normal_kpa = series.iter().map(|p| p.window_normal_kpa).sum::<f64>() / n as f64;
    let raw: Vec<f64> = series.iter().map(|p| 1e3 * p.window_shear_kpa).collect();
    let window = shear_strength(
        &ShearRecord {
            normal_stress_pa: 1e3 * window_normal_kpa,
            area_m2: 1.0,
            displacement_m: record.displacement_m.clone(),
            shear_force_n: running_mean(&raw, (n / WINDOW_SMOOTHING_DIVISOR).max(1)),
        },
        spec.shear.residual_fraction,
    )
    .map_err(|e| build_error("window record", e))?;
    let mean_lid = series.iter().map(|p| p.lid_stress_kpa).sum::<f64>() / series.len() as f64;
    Ok(ShearStage {
        normal_stress_kpa: sigma_kpa,
        plane_normal_stress_kpa: plane_sigma_kpa,
        consolidated,
        consolidation_time_s: consolidation_time,
        peak_kpa: 1e-3 * strength.peak_pa,
        peak_displacement_mm: 1e3 * strength.peak_displacement_m,
        residual_kpa: 1e-3 * strength.residual_pa,
        window_normal_stress_kpa: window_normal_kpa,
        window_peak_kpa: 1e-3 * window.peak_pa,
        window_residual_kpa: 1e-3 * window.residual_pa,
        mean_lid_stress_kpa: mean_lid,
        dilation_mm: 1e3 * (lid_z(backend) - z_start),
        kinetic_energy_ratio,
        particles,
        escaped: backend.removed_count()?,
        steps: backend.steps(),
        series,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(i: usize) -> ShearSample {
        let x = i as f64;
        ShearSample {
            displacement_mm: x * 0.005_123_456_789,
            shear_stress_kpa: 8.0 * (1.0 - (-x / 300.0).exp()) + 0.3 * (x * 0.37).sin(),
            lid_stress_kpa: 20.0 + 0.1 * (x * 0.11).cos(),
            lid_z_mm: 71.234_567_891 - x * 1.0e-4,
            window_shear_kpa: 8.1 * (1.0 - (-x / 300.0).exp()) + 0.4 * (x * 0.29).sin(),
            window_normal_kpa: 21.0 + 0.5 * (x * 0.13).cos(),
        }
    }

    #[test]
    fn thinning_keeps_the_ends_and_the_peak_and_fits_a_job_servers_details() {
        // The default preset: 10 mm at 5 mm/s, one sample a millisecond.
        let series: Vec<ShearSample> = (0..2000).map(sample).collect();
        let peak = series
            .iter()
            .map(|s| s.shear_stress_kpa)
            .fold(f64::MIN, f64::max);
        let max = ShearResult::DETAILS_SAMPLES / 4;
        let thin = thin_series(&series, max);
        assert!(thin.len() <= max && thin.len() >= max - 2, "{}", thin.len());
        assert_eq!(thin[0], series[0]);
        assert_eq!(thin.last(), series.last());
        assert!(thin.iter().any(|s| s.shear_stress_kpa == peak));
        assert!(thin
            .windows(2)
            .all(|w| w[0].displacement_mm < w[1].displacement_mm));
        // Four stages of it stay well inside the server's 64 KiB (the rest of a result is
        // about 2 KB); the full series are about 0.6 MB.
        let four = serde_json::to_string(&vec![thin.clone(); 4]).unwrap();
        assert!(four.len() < 40 * 1024, "{}", four.len());
        let full = serde_json::to_string(&vec![series.clone(); 4]).unwrap();
        assert!(full.len() > 64 * 1024, "{}", full.len());
        // Short series are kept whole.
        assert_eq!(thin_series(&series[..10], max), series[..10].to_vec());
    }
}
