//! Runs a [`DrillSpec`] on a settled bed: the auger turns and feeds into the soil, is withdrawn
//! still turning, is lifted clear, the soil settles, and the hole is measured.
//!
//! Frame: z up, bin floor at z = 0, drill axis = z axis. The auger's tip starts
//! `drill.start_clearance` above the bed's surface level and is fed `drill.depth` below it.

use crate::Spec;
use std::collections::BTreeMap;
use std::time::Instant;

use repose_engine::kinematics::{Motion, RotationSegment, TranslationSegment};
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::generators::{auger, AugerSpec};
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, GeometrySample, World};
use serde::{Deserialize, Serialize};

use super::measure::{measure_hole, solid_volume_in_cylinder, HoleMeasurement};
use super::picture::{forces_svg, section_svg};
use super::spec::DrillSpec;
use crate::backend::{Engine, Grains};
pub use crate::progress::{Control, Progress};
use crate::soil::advance_to_check;
use crate::soil::{
    bin_world, height_field, is_stable, kinetic_energy_ratio, run_on_bed, setup, surface_level,
    BedInfo, HeightField, NoBedStore, On, OnBed, OnBedError, SettledBed, SettledBy, SplitMix,
};

/// Why a run could not start or was stopped before it could report: the error of every kind
/// that runs on a settled bed ([`OnBedError`]; a finished run that did not go as planned is a
/// [`DrillResult`] with a non-`ok` status, not an error).
pub type DrillError = OnBedError;

fn build_error(part: &'static str, e: impl std::fmt::Display) -> DrillError {
    OnBedError::build(part, e)
}

/// Overall outcome. Hole metrics are reported for `ok` and `not_settled` (see
/// [`DrillResult::metrics`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DrillStatus {
    Ok,
    /// The bed or the soil after withdrawal did not come to rest within the time cap.
    NotSettled,
    /// The wall-clock cap ended the run.
    WallTimeCap,
    Cancelled,
    /// The grains could not be measured.
    MeasurementFailed,
}

/// One point of the drill's load series (averaged over `measure.series_interval`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoadSample {
    /// s since the feed started.
    pub time_s: f64,
    /// Depth of the tip below the original surface, mm (negative above it).
    pub tip_depth_mm: f64,
    /// Torque the drive must supply about the axis in the turning sense, N·m (positive: the
    /// soil resists the rotation).
    pub torque_nm: f64,
    /// Vertical force of the soil on the auger, N (positive: upward, resisting the feed).
    pub axial_force_n: f64,
}

/// The result of one drilling run (serde; what `result.json` holds). Hole lengths in mm,
/// forces in N, torques in N·m, energies in J, times in s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DrillResult {
    pub status: DrillStatus,
    pub message: Option<String>,
    /// Diameter of the circle with the opening's area, at the original surface level.
    pub opening_diameter_mm: Option<f64>,
    /// Widths of the opening along x and y through the axis.
    pub opening_diameter_x_mm: Option<f64>,
    pub opening_diameter_y_mm: Option<f64>,
    pub opening_area_mm2: Option<f64>,
    /// From the original surface level down to the surface on the axis.
    pub effective_depth_mm: Option<f64>,
    /// The depth the tip was fed to below the original surface.
    pub feed_depth_mm: f64,
    /// `effective_depth_mm / feed_depth_mm`: how the scaled-down presets compare with the
    /// paper (603.66 / 600 measured, 601.23 / 600 simulated).
    pub depth_ratio: Option<f64>,
    /// Solid volume of grains back in the drilled cylinder (auger diameter, from the original
    /// surface to the feed depth) after settling, over the solid volume there before drilling.
    pub backfill_ratio: Option<f64>,
    /// Highest spoil around the hole above the original surface.
    pub rim_height_mm: Option<f64>,
    /// How far the surface away from the hole sank during the run: the original surface level
    /// minus the settled one (the median height of the final surface away from the walls,
    /// [`super::surface_level`]; negative if it rose).
    #[serde(default)]
    pub surface_subsidence_mm: Option<f64>,
    /// The opening measured against the *settled* surface level instead of the original one:
    /// the mouth of the hole as one measures it standing by the bin. When the whole surface
    /// sinks by more than `measure.open_depth_diameters` (a cohesive bed that pulls itself
    /// together while the auger stirs it), the original-level opening takes in the sunken
    /// surface far from the hole and reads the bin, not the hole; this one does not.
    #[serde(default)]
    pub settled_opening_diameter_mm: Option<f64>,
    pub auger_diameter_mm: f64,
    /// Drive torque and axial force: peak (of the `measure.series_interval` averages) and mean
    /// over the feed.
    pub peak_torque_nm: f64,
    pub mean_feed_torque_nm: f64,
    pub peak_axial_force_n: f64,
    pub mean_feed_axial_force_n: f64,
    /// Work done by the drive (rotation) and by the feed/lift (translation), and their sum.
    pub rotation_energy_j: f64,
    pub feed_energy_j: f64,
    pub energy_j: f64,
    pub series: Vec<LoadSample>,
    pub bed: BedInfo,
    pub grain_diameter_mm: f64,
    pub particles: usize,
    /// Grains that left the bin (flung over the walls).
    pub escaped: u64,
    /// Grains still on the lifted auger at the end (carried out; not measured).
    pub carried_out: usize,
    pub kinetic_energy_ratio: f64,
    /// What ended the settling after withdrawal.
    pub settled_by: SettledBy,
    /// Simulated time of the drilling run (after the bed), s.
    pub simulated_time_s: f64,
    pub steps: u64,
    pub time_step_s: f64,
    /// Wall time of this call (bed included if it was built here), s.
    pub wall_time_s: f64,
    /// The engine that computed the run: the CPU engine's version, or
    /// `<version>+gpu:<adapter>` for the GPU backend ([`Engine::engine_version`]). None in
    /// results written before the field existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub engine_version: Option<String>,
}

impl DrillResult {
    /// Scalar results for a job server: `opening_diameter_mm`, `opening_diameter_x_mm`,
    /// `opening_diameter_y_mm`, `opening_area_mm2`, `effective_depth_mm`, `depth_ratio`,
    /// `backfill_ratio`, `rim_height_mm`, `surface_subsidence_mm`, `settled_opening_diameter_mm`,
    /// `peak_torque_nm`, `mean_feed_torque_nm`,
    /// `peak_axial_force_n`, `mean_feed_axial_force_n`, `energy_j`, `rotation_energy_j`,
    /// `feed_energy_j`, `simulated_time_s`, `particles`, and `came_to_rest` (1 or 0). Like the
    /// angle-of-repose runs, a run that did not come to rest within the time cap
    /// (`not_settled`) is measured as it stands and flagged `came_to_rest = 0`; other statuses
    /// (cancelled, wall-time cap, measurement failed) give no metrics.
    pub fn metrics(&self) -> BTreeMap<String, f64> {
        let mut m = BTreeMap::new();
        if !matches!(self.status, DrillStatus::Ok | DrillStatus::NotSettled) {
            return m;
        }
        m.insert(
            "came_to_rest".to_owned(),
            if self.status == DrillStatus::Ok {
                1.0
            } else {
                0.0
            },
        );
        let values = [
            ("opening_diameter_mm", self.opening_diameter_mm),
            ("opening_diameter_x_mm", self.opening_diameter_x_mm),
            ("opening_diameter_y_mm", self.opening_diameter_y_mm),
            ("opening_area_mm2", self.opening_area_mm2),
            ("effective_depth_mm", self.effective_depth_mm),
            ("depth_ratio", self.depth_ratio),
            ("backfill_ratio", self.backfill_ratio),
            ("rim_height_mm", self.rim_height_mm),
            ("surface_subsidence_mm", self.surface_subsidence_mm),
            (
                "settled_opening_diameter_mm",
                self.settled_opening_diameter_mm,
            ),
            ("peak_torque_nm", Some(self.peak_torque_nm)),
            ("mean_feed_torque_nm", Some(self.mean_feed_torque_nm)),
            ("peak_axial_force_n", Some(self.peak_axial_force_n)),
            (
                "mean_feed_axial_force_n",
                Some(self.mean_feed_axial_force_n),
            ),
            ("energy_j", Some(self.energy_j)),
            ("rotation_energy_j", Some(self.rotation_energy_j)),
            ("feed_energy_j", Some(self.feed_energy_j)),
            ("simulated_time_s", Some(self.simulated_time_s)),
            ("particles", Some(self.particles as f64)),
        ];
        for (k, v) in values {
            if let Some(v) = v.filter(|v| v.is_finite()) {
                m.insert(k.to_owned(), v);
            }
        }
        m
    }
}

/// A finished run: the result plus what a caller may want to draw or save.
#[derive(Debug)]
pub struct DrillRun {
    pub result: DrillResult,
    pub measurement: Option<HoleMeasurement>,
    /// Surface after settling (probe height field).
    pub surface: Option<HeightField>,
    /// Grains measured (those left on the auger excluded).
    pub positions: Vec<[f64; 3]>,
    pub radii: Vec<f64>,
    /// The bed the run started from.
    pub bed: SettledBed,
    /// The spec that ran.
    pub spec: DrillSpec,
    /// The final world (e.g. for `write_particles_csv`).
    pub world: World,
}

impl DrillRun {
    /// Vertical section (x-z) through the hole axis: grains cut by the plane y = 0, the
    /// original surface, the final surface profile, the auger outline at full depth.
    pub fn section_svg(&self) -> String {
        section_svg(self)
    }

    /// Torque and axial force against time (and the tip depth).
    pub fn forces_svg(&self) -> String {
        forces_svg(&self.result)
    }

    /// The series as CSV text: `time_s,tip_depth_mm,torque_nm,axial_force_n`.
    pub fn forces_csv(&self) -> String {
        let mut s = String::from("time_s,tip_depth_mm,torque_nm,axial_force_n\n");
        for p in &self.result.series {
            s.push_str(&format!(
                "{},{},{},{}\n",
                p.time_s, p.tip_depth_mm, p.torque_nm, p.axial_force_n
            ));
        }
        s
    }
}

/// Builds the bed and drills it: [`build_bed`](super::build_bed) then [`run_drill_on_bed`]
/// ([`run_on_bed`] without a store), on the CPU engine. The bed takes the first quarter of the
/// progress fraction.
pub fn run_drill(
    spec: &DrillSpec,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<DrillRun, DrillError> {
    run_on_bed(&DrillOn::cpu(spec), &mut NoBedStore, progress)
}

/// Drills a bed built earlier by [`build_bed`](super::build_bed) for a spec with the same
/// [`bed_key`](super::bed_key) (e.g. read back from a cache), on the CPU engine. Same outcome,
/// bit for bit, as [`run_drill`] on that spec, but for `bed.reused` (true here) and the wall
/// time (without the bed's).
pub fn run_drill_on_bed(
    spec: &DrillSpec,
    bed: SettledBed,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<DrillRun, DrillError> {
    DrillOn::cpu(spec).run_on_bed(bed, progress)
}

/// A drilling spec on an engine: its bed is settled and drilled there ([`On`]).
pub type DrillOn<'a> = On<'a, DrillSpec>;

/// The drilling test runs on a settled bed, built in the first quarter of the progress.
impl OnBed for DrillOn<'_> {
    type Run = DrillRun;
    type Error = DrillError;
    const BED_SHARE: f64 = 0.25;

    fn bed_key(&self) -> String {
        self.spec.bed_recipe().key_on(self.engine.kind())
    }

    fn build_bed(
        &self,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<SettledBed, DrillError> {
        Ok(self.spec.bed_recipe().build_on(self.engine, &mut |p| {
            progress(Progress {
                fraction: p.fraction,
                phase: "bed",
                time: p.time,
                particles: p.particles,
            })
        })?)
    }

    fn run_on_matching_bed(
        &self,
        bed: SettledBed,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<DrillRun, DrillError> {
        drill(self.engine, self.spec, bed, progress)
    }

    fn bed_of(run: &mut DrillRun) -> (&mut BedInfo, &mut f64) {
        (&mut run.result.bed, &mut run.result.wall_time_s)
    }
}

/// Angle the auger starts at, from the seed (replicates on one shared bed still differ).
fn start_angle(seed: u64) -> f64 {
    let mut rng = SplitMix(seed ^ 0xa0_6e12_0000_0002);
    (rng.symmetric() + 1.0) * std::f64::consts::PI
}

/// Drills `bed` on `engine` (handed in: `bed.reused` is true until [`run_on_bed`] says
/// otherwise).
fn drill(
    engine: Engine<'_>,
    spec: &DrillSpec,
    bed: SettledBed,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<DrillRun, DrillError> {
    let started = Instant::now();
    spec.validate()?;
    let recipe = spec.bed_recipe();
    let s = setup(&recipe)?;
    let a = &spec.auger;
    let d = &spec.drill;
    let surface = bed.surface_z;
    let start_z = surface + d.start_clearance;
    let travel = d.depth + d.start_clearance;

    // Auger: the flight starts above the tip and reaches `flight_above_surface` above the
    // original surface at full depth; the shaft goes one pitch further.
    let flight_length = (d.depth - a.tip_length + a.flight_above_surface).max(a.pitch);
    let shaft_length = a.tip_length + flight_length + 0.5 * a.flight_thickness + a.pitch;
    let generated = || {
        auger(&AugerSpec {
            shaft_diameter: a.shaft_diameter,
            flight_outer_diameter: a.outer_diameter,
            pitch: a.pitch,
            flight_length,
            flight_thickness: a.flight_thickness,
            shaft_length,
            tip_length: a.tip_length,
            segments_per_turn: a.segments_per_turn,
            right_handed: true,
        })
        .map_err(|e| build_error("auger", e))
    };
    let mesh = match &spec.auger_stl {
        Some(stl) => stl.mesh().map_err(|e| build_error("auger_stl", e))?,
        None => generated()?,
    };
    let t_feed = travel / d.feed_speed;
    let t_withdraw = t_feed + travel / d.withdraw_speed;
    let t_lift = t_withdraw + d.lift_height / d.lift_speed;
    let rpm = if d.clockwise { -d.rpm } else { d.rpm };
    let motion = Motion::new(
        Pose::new(
            Vec3::new(0.0, 0.0, start_z),
            Vec3::new(0.0, 0.0, start_angle(spec.seed)),
        ),
        vec![
            TranslationSegment {
                velocity: Vec3::new(0.0, 0.0, -d.feed_speed),
                start: 0.0,
                stop: t_feed,
            },
            TranslationSegment {
                velocity: Vec3::new(0.0, 0.0, d.withdraw_speed),
                start: t_feed,
                stop: t_withdraw,
            },
            TranslationSegment {
                velocity: Vec3::new(0.0, 0.0, d.lift_speed),
                start: t_withdraw,
                stop: t_lift,
            },
        ],
        vec![RotationSegment {
            axis: Vec3::z(),
            axis_point: Vec3::zeros(),
            rpm,
            start: 0.0,
            stop: t_withdraw,
        }],
    )
    .map_err(|e| build_error("drill", e))?;

    // Room above the surface for flung grains; grains leaving the domain are counted escaped.
    let top = spec.bin.height.max(surface) + 0.1 + d.lift_height;
    let mut world = bin_world(&recipe, &s, top, spec.seed)?;
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
            .map_err(|e| build_error("bed", e))?;
    }
    let auger_id = world
        .add_geometry(Geometry {
            name: "auger".into(),
            mesh,
            motion: motion.clone(),
            material: s.steel,
        })
        .map_err(|e| build_error("auger", e))?;

    // Run: the motion, then settling checks.
    let mean_r = bed.radii.iter().sum::<f64>() / bed.radii.len().max(1) as f64;
    let settle = &spec.settle;
    let first_check = t_lift + settle.min_time;
    let deadline = t_lift + settle.time_cap;
    let nominal_end = first_check;
    let mut next_check = first_check;
    let mut ke = f64::INFINITY;
    let mut settled_by = SettledBy::TimeCap;
    let (mut depths, mut openings) = (Vec::new(), Vec::new());
    let mut stopped: Option<DrillStatus> = None;
    let mut backend = engine.start(world)?;
    loop {
        let t = advance_to_check(backend.as_mut(), next_check)?;
        let is_check = t >= next_check;
        if is_check {
            next_check += settle.check_interval;
            let grains = backend.grains()?;
            ke = kinetic_energy_ratio(&grains);
            let now = measure_grains(spec, &grains, t, &motion, surface, mean_r);
            if let Some(hole) = &now.hole {
                depths.push(hole.effective_depth);
                openings.push(hole.opening_diameter);
            }
            let d = 2.0 * mean_r;
            if ke < settle.kinetic_energy_threshold {
                settled_by = SettledBy::KineticEnergy;
            } else if depths.len() == openings.len()
                && is_stable(&depths, settle, d)
                && is_stable(&openings, settle, d)
            {
                settled_by = SettledBy::Stable;
            }
        }
        let came_to_rest = settled_by != SettledBy::TimeCap;
        if backend.steps() % backend.steps_between_reports() == 0 || is_check {
            let phase = if t < t_feed {
                "feeding"
            } else if t < t_withdraw {
                "withdrawing"
            } else if t < t_lift {
                "lifting"
            } else {
                "settling"
            };
            let fraction = if came_to_rest {
                1.0
            } else {
                0.99 * (t / nominal_end).min(1.0)
            };
            let control = progress(Progress {
                fraction,
                phase,
                time: t,
                particles: backend.grain_count()?,
            });
            if control == Control::Cancel {
                stopped = Some(DrillStatus::Cancelled);
                break;
            }
            if let Some(cap) = spec.wall_time_cap {
                if started.elapsed().as_secs_f64() > cap {
                    stopped = Some(DrillStatus::WallTimeCap);
                    break;
                }
            }
        }
        if came_to_rest || t >= deadline {
            break;
        }
    }
    let came_to_rest = settled_by != SettledBy::TimeCap;
    let (time, steps, time_step) = (backend.time(), backend.steps(), backend.time_step());
    let _ = progress(Progress {
        fraction: 1.0,
        phase: "measuring",
        time,
        particles: backend.grain_count()?,
    });

    // Loads.
    let samples = backend.geometry_series(auger_id)?;
    let loads = load_series(&samples, time_step, &motion, surface, spec);
    let escaped = backend.removed_count()?;
    let particles = backend.grain_count()?;

    let Measured {
        positions,
        radii,
        carried_out,
        hole: measurement,
        field: surface_field,
        error: measure_error,
    } = measure_grains(spec, &backend.grains()?, time, &motion, surface, mean_r);
    let reach = 0.5 * a.outer_diameter;
    let cylinder = |pos: &[[f64; 3]], r: &[f64]| {
        solid_volume_in_cylinder(pos, r, [0.0, 0.0], reach, surface - d.depth, surface)
    };
    let before = cylinder(&bed.positions, &bed.radii);
    let after = cylinder(&positions, &radii);
    let backfill = (before > 0.0).then(|| after / before);

    let (status, message) = match stopped {
        Some(DrillStatus::Cancelled) => (DrillStatus::Cancelled, Some("cancelled".to_owned())),
        Some(status) => (
            status,
            Some(format!(
                "wall_time_cap ({} s) reached at t = {:.3} s",
                spec.wall_time_cap.unwrap_or_default(),
                time
            )),
        ),
        None => {
            if let Some(e) = measure_error {
                (DrillStatus::MeasurementFailed, Some(e))
            } else if !bed.settled {
                (
                    DrillStatus::NotSettled,
                    Some(format!(
                        "the bed did not come to rest (kinetic energy ratio {:.2e} > {:.2e})",
                        bed.kinetic_energy_ratio, spec.bed.settle.kinetic_energy_threshold
                    )),
                )
            } else if !came_to_rest {
                (
                    DrillStatus::NotSettled,
                    Some(format!(
                        "the soil did not come to rest after withdrawal (kinetic energy ratio \
                         {ke:.2e} > {:.2e})",
                        settle.kinetic_energy_threshold
                    )),
                )
            } else {
                (DrillStatus::Ok, None)
            }
        }
    };
    let report = matches!(status, DrillStatus::Ok | DrillStatus::NotSettled);
    let hole = measurement.as_ref().filter(|_| report);
    // The same hole against the settled surface: once, here (the checks above need only the
    // original-level measurement).
    let settled_hole = surface_field.as_ref().map(|hf| {
        let m = &spec.measure;
        let settled = surface_level(hf, m.wall_margin_diameters * 2.0 * mean_r);
        let open_depth = m.open_depth_diameters * 2.0 * mean_r;
        measure_hole(hf, settled, [0.0, 0.0], open_depth, reach)
    });
    let settled = settled_hole.as_ref();
    let mm = |f: &dyn Fn(&HoleMeasurement) -> f64| hole.map(|h| 1e3 * f(h));
    let result = DrillResult {
        status,
        message,
        opening_diameter_mm: mm(&|h| h.opening_diameter),
        opening_diameter_x_mm: mm(&|h| h.opening_x),
        opening_diameter_y_mm: mm(&|h| h.opening_y),
        opening_area_mm2: hole.map(|h| 1e6 * h.opening_area),
        effective_depth_mm: mm(&|h| h.effective_depth),
        feed_depth_mm: 1e3 * d.depth,
        depth_ratio: hole.map(|h| h.effective_depth / d.depth),
        backfill_ratio: backfill.filter(|_| report),
        rim_height_mm: mm(&|h| h.rim_height),
        surface_subsidence_mm: settled
            .filter(|_| report)
            .map(|h| 1e3 * (surface - h.surface_z)),
        settled_opening_diameter_mm: settled.filter(|_| report).map(|h| 1e3 * h.opening_diameter),
        auger_diameter_mm: 1e3 * a.outer_diameter,
        peak_torque_nm: loads.peak_torque,
        mean_feed_torque_nm: loads.mean_feed_torque,
        peak_axial_force_n: loads.peak_axial,
        mean_feed_axial_force_n: loads.mean_feed_axial,
        rotation_energy_j: loads.rotation_energy,
        feed_energy_j: loads.feed_energy,
        energy_j: loads.rotation_energy + loads.feed_energy,
        series: loads.series,
        bed: BedInfo::of(&bed),
        grain_diameter_mm: 2e3 * mean_r,
        particles,
        escaped,
        carried_out,
        kinetic_energy_ratio: ke,
        settled_by,
        simulated_time_s: time,
        steps,
        time_step_s: time_step,
        wall_time_s: started.elapsed().as_secs_f64(),
        engine_version: Some(engine.engine_version()),
    };
    let world = backend.into_world()?;
    Ok(DrillRun {
        result,
        measurement,
        surface: surface_field,
        positions,
        radii,
        bed,
        spec: spec.clone(),
        world,
    })
}

/// The grains and the hole at one moment.
struct Measured {
    /// Grains not resting on the auger.
    positions: Vec<[f64; 3]>,
    radii: Vec<f64>,
    /// Grains on the auger (above its tip, within its radius).
    carried_out: usize,
    hole: Option<HoleMeasurement>,
    field: Option<HeightField>,
    error: Option<String>,
}

/// The grains `p` and the hole at time `time`, s.
fn measure_grains(
    spec: &DrillSpec,
    p: &Grains<'_>,
    time: f64,
    motion: &Motion,
    surface: f64,
    mean_r: f64,
) -> Measured {
    let tip_z = motion.reference_point_at(time).z;
    let reach = 0.5 * spec.auger.outer_diameter;
    let mut positions = Vec::with_capacity(p.len());
    let mut radii = Vec::with_capacity(p.len());
    let mut carried_out = 0;
    for k in 0..p.len() {
        let x = p.position[k];
        if x.z > tip_z && x.x.hypot(x.y) < reach + p.radius[k] {
            carried_out += 1;
            continue;
        }
        positions.push([x.x, x.y, x.z]);
        radii.push(p.radius[k]);
    }
    let m = &spec.measure;
    let hf = height_field(
        &positions,
        &radii,
        0.5 * spec.bin.size_x,
        0.5 * spec.bin.size_y,
        m.cell_fraction * mean_r,
        m.probe_fraction * mean_r,
        0.0,
    );
    let (hole, field, error) = match hf {
        Ok(hf) if !positions.is_empty() => {
            let open_depth = m.open_depth_diameters * 2.0 * mean_r;
            let hole = measure_hole(&hf, surface, [0.0, 0.0], open_depth, reach);
            (Some(hole), Some(hf), None)
        }
        Ok(_) => (None, None, Some("no grains left to measure".to_owned())),
        Err(e) => (None, None, Some(e.to_string())),
    };
    Measured {
        positions,
        radii,
        carried_out,
        hole,
        field,
        error,
    }
}

struct Loads {
    series: Vec<LoadSample>,
    peak_torque: f64,
    mean_feed_torque: f64,
    peak_axial: f64,
    mean_feed_axial: f64,
    rotation_energy: f64,
    feed_energy: f64,
}

/// The auger's recorded loads (`samples`, every step of `dt`, s): energies integrated step by
/// step, the series averaged over `measure.series_interval`.
fn load_series(
    samples: &[GeometrySample],
    dt: f64,
    motion: &Motion,
    surface: f64,
    spec: &DrillSpec,
) -> Loads {
    let d = &spec.drill;
    let t_feed = (d.depth + d.start_clearance) / d.feed_speed;
    // Unit vector of the spin (world frame): the drive torque is the soil's torque against it.
    let spin = Vec3::new(0.0, 0.0, if d.clockwise { -1.0 } else { 1.0 });
    let mut out = Loads {
        series: Vec::new(),
        peak_torque: 0.0,
        mean_feed_torque: 0.0,
        peak_axial: 0.0,
        mean_feed_axial: 0.0,
        rotation_energy: 0.0,
        feed_energy: 0.0,
    };
    let mut feed_n = 0usize;
    let interval = spec.measure.series_interval;
    let (mut bin_start, mut acc_t, mut acc_f, mut acc_n) = (0.0, 0.0, 0.0, 0usize);
    for s in samples {
        let torque = -s.torque.dot(&spin);
        let axial = s.force.z;
        let omega = motion.angular_velocity_at(s.time);
        let v = motion.linear_velocity_at(s.time);
        // Drive power: -(soil torque)·ω; feed power: -(soil force)·v.
        out.rotation_energy += -s.torque.dot(&omega) * dt;
        out.feed_energy += -s.force.dot(&v) * dt;
        if s.time < t_feed {
            out.mean_feed_torque += torque;
            out.mean_feed_axial += axial;
            feed_n += 1;
        }
        if s.time >= bin_start + interval && acc_n > 0 {
            let mid = bin_start + 0.5 * interval;
            out.series.push(LoadSample {
                time_s: mid,
                tip_depth_mm: 1e3 * (surface - motion.reference_point_at(mid).z),
                torque_nm: acc_t / acc_n as f64,
                axial_force_n: acc_f / acc_n as f64,
            });
            bin_start += interval * ((s.time - bin_start) / interval).floor();
            (acc_t, acc_f, acc_n) = (0.0, 0.0, 0);
        }
        acc_t += torque;
        acc_f += axial;
        acc_n += 1;
    }
    if acc_n > 0 {
        let mid = bin_start + 0.5 * interval;
        out.series.push(LoadSample {
            time_s: mid,
            tip_depth_mm: 1e3 * (surface - motion.reference_point_at(mid).z),
            torque_nm: acc_t / acc_n as f64,
            axial_force_n: acc_f / acc_n as f64,
        });
    }
    // Peaks of the interval averages (single steps are dominated by contact noise).
    for p in &out.series {
        out.peak_torque = out.peak_torque.max(p.torque_nm);
        out.peak_axial = out.peak_axial.max(p.axial_force_n);
    }
    if feed_n > 0 {
        out.mean_feed_torque /= feed_n as f64;
        out.mean_feed_axial /= feed_n as f64;
    }
    out
}
