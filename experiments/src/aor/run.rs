//! Runs an [`AorSpec`]: builds the world (base plate, funnel or tube, factory), pours, waits for
//! the heap to come to rest, measures it, and reports an [`AorResult`].
//!
//! Frame: z up, the top face of the base plate is z = 0, the funnel (or tube) axis is the z axis.
//! Grains that leave the plate fall out of the simulation box and are counted as escaped.
//!
//! Only grains below the funnel outlet (or below the lifted tube) are measured, so grains held up
//! in the funnel never count as part of the heap.

use crate::Spec;
use std::time::{Duration, Instant};

use repose_engine::distribution::SizeDistribution;
use repose_engine::factory::{Factory, FactorySpec, ParticleSource, Region};
use repose_engine::kinematics::{Motion, TranslationSegment};
use repose_engine::material::rayleigh_time;
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::generators::{cylinder, funnel, plane};
use repose_engine::mesh::{FunnelSpec, FunnelTop, TriMesh};
use repose_engine::neighbor::Domain;
use repose_engine::world::{Geometry, World, WorldConfig};
use serde::{Deserialize, Serialize};

use super::checkpoint::{encode, AorCheckpoint, CheckpointError, LoopState};
use super::measure::{measure_angle_of_repose, AngleOfRepose, MeasureError, MeasureSettings};
use super::picture::{side_view_svg, PictureOptions};
use super::rest::{rest_decision, rest_state, NotYet, RestDecision, RestState};
use super::spec::{AorSpec, Protocol, SpecError};
use crate::backend::{steps_until, Backend, BackendError, BackendKind, Engine, Grains};
// The progress callback's types (phases here: `filling`, `lifting`, `settling`, `measuring`;
// filling is the first half of the fraction, settling the second).
pub use crate::progress::{Control, Progress};

/// Why a run could not start (a finished run that found no heap is an [`AorResult`] with a
/// non-`ok` status, not an error).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AorError {
    #[error(transparent)]
    Spec(#[from] SpecError),
    /// The engine rejected the world built from the spec (materials, mesh, factory).
    #[error("{part}: {reason}")]
    Build { part: &'static str, reason: String },
    /// The checkpoint to resume from does not belong to this spec.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// The engine backend cannot run this spec (named), or failed during the run.
    #[error(transparent)]
    Backend(#[from] BackendError),
}

fn build_error(part: &'static str, e: impl std::fmt::Display) -> AorError {
    AorError::Build {
        part,
        reason: e.to_string(),
    }
}

/// Why the simulation stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EndedBy {
    /// The heap came to rest by the rule of [`super::SettleSpec`] ([`super::rest_decision`]):
    /// low kinetic energy, a stable angle and no creep over the last checks.
    AtRest,
    /// Legacy, read from results written before the rest rule of issue 13 (never produced
    /// now): the kinetic energy alone fell below the threshold, which a creeping heap can do.
    KineticEnergy,
    /// Legacy, as `KineticEnergy`: three angles alone lay within the tolerance, which a heap
    /// in a slow slump can do.
    AngleStable,
    /// Simulated-time cap.
    TimeCap,
    /// Wall-clock cap.
    WallTimeCap,
    /// The progress callback asked to stop.
    Cancelled,
}

/// Overall outcome. Only `ok` carries an angle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunStatus {
    Ok,
    /// More than `max_escaped_fraction` of the mass left the plate.
    Escaped,
    /// An arch over the outlet: more than `max_held_up_fraction` of the mass was still in the
    /// funnel or tube when the run ended, or the pour could never end, and the funnel's outlet
    /// passed less than a tenth of `mass_rate` at the end (the message gives the rate). The
    /// heap under it holds only part of the mass.
    HeldUp,
    /// The heap never came to rest within the caps, or the cap came while the funnel was still
    /// filling or draining at a tenth of `mass_rate` or more (raise `time_cap`).
    NotSettled,
    /// The grains do not form a measurable heap.
    MeasurementFailed,
    Cancelled,
}

/// Grain count and mass of one group.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Amount {
    pub count: u64,
    /// kg
    pub mass: f64,
}

/// Where the grains ended.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct GrainBudget {
    /// Everything the factory inserted.
    pub inserted: Amount,
    /// Grains below the outlet (or below the lifted tube): the heap region.
    pub on_base: Amount,
    /// Grains the measurement took as the heap (count; mass estimated from the mean grain mass
    /// of the heap region).
    pub on_pile: Amount,
    /// Grains still in (or above) the funnel or tube.
    pub held_up: Amount,
    /// Grains that left the simulation box (fell off the plate).
    pub escaped: Amount,
}

/// One at-rest check.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SettleCheck {
    /// s
    pub time: f64,
    /// Mean kinetic energy per grain / (m g d).
    pub kinetic_energy_ratio: f64,
    /// Angle at this check (none if not measurable).
    pub angle_deg: Option<f64>,
    /// Grains in the heap region.
    pub on_base: u64,
}

/// The result of one experiment (serde; what the worker returns and `result.json` holds).
/// Angles in degrees, lengths in metres, masses in kg, times in seconds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AorResult {
    pub status: RunStatus,
    /// Why the status is not `ok`.
    pub message: Option<String>,
    /// Mean of the half-plane flank angles (only when `status` is `ok`).
    pub angle_deg: Option<f64>,
    /// Flank angle in each of the K half-planes.
    pub per_direction_deg: Vec<f64>,
    /// Side-projection (photograph) flank angles and their mean.
    pub left_deg: Option<f64>,
    pub right_deg: Option<f64>,
    pub projection_mean_deg: Option<f64>,
    /// Standard deviation and range across directions.
    pub spread_std_deg: Option<f64>,
    pub spread_min_deg: Option<f64>,
    pub spread_max_deg: Option<f64>,
    pub pile_height_m: Option<f64>,
    pub base_diameter_m: Option<f64>,
    /// The last measured angle even when the run did not settle (diagnostics only).
    pub last_angle_deg: Option<f64>,
    pub grains: GrainBudget,
    pub grain_diameter_m: f64,
    pub simulated_time_s: f64,
    /// Time at which the factory had inserted all the mass (none if it never did).
    pub insertion_end_s: Option<f64>,
    pub steps: u64,
    pub time_step_s: f64,
    /// Wall-clock time of the whole run, s (summed over its segments if it was resumed).
    pub wall_time_s: f64,
    /// The step the run was last resumed at from a checkpoint (none: it ran in one go).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resumed_at_step: Option<u64>,
    pub ended_by: EndedBy,
    /// `ended_by` is `at_rest`.
    pub came_to_rest: bool,
    /// How far from rest the heap was at its last check, whether or not it came to rest: the
    /// angle's creep rate over the last checks, their angle range and the last kinetic energy,
    /// each with its limit. None only when no check ran (cancelled or capped before the pour
    /// ended); results written before the field existed parse with none.
    #[serde(default)]
    pub rest: Option<RestState>,
    pub checks: Vec<SettleCheck>,
    /// The engine that computed the run: the CPU engine's version, or
    /// `<version>+gpu:<adapter>` for the GPU backend ([`crate::backend::Engine::engine_version`]).
    /// None in results written before the field existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub engine_version: Option<String>,
}

/// A finished run: the result plus what the caller may want to draw or save.
#[derive(Debug)]
pub struct AorRun {
    pub result: AorResult,
    /// The full measurement (none if it failed).
    pub measurement: Option<AngleOfRepose>,
    /// The grains that were measured (the heap region).
    pub positions: Vec<[f64; 3]>,
    pub radii: Vec<f64>,
    /// The final world (e.g. for `write_particles_csv`). On a backend other than the CPU: the
    /// rig with that backend's final grains copied in ([`Backend::into_world`]).
    pub world: World,
}

impl AorRun {
    /// Side view with the fitted flank lines and angles (x-z projection), if measured.
    pub fn pile_svg(&self) -> Option<String> {
        let m = self.measurement.as_ref()?;
        let options = PictureOptions {
            title: Some(format!(
                "angle of repose {:.2}° (left {:.2}°, right {:.2}°), status {:?}",
                m.angle_deg, m.left_deg, m.right_deg, self.result.status
            )),
            ..PictureOptions::default()
        };
        Some(side_view_svg(m, &self.positions, &self.radii, &options))
    }
}

/// The built world and what the run loop needs to know about it.
#[derive(Debug)]
struct Rig {
    world: World,
    /// Grains whose centre is below this height are in the heap region, m.
    heap_top: f64,
    /// Time from which the at-rest checks may start (besides the end of insertion), s.
    ready_after: f64,
}

fn build_rig(spec: &AorSpec) -> Result<Rig, AorError> {
    spec.validate()?;
    let table = spec
        .material_set()
        .build()
        .map_err(|e| build_error("materials", e))?;
    let soil = table.id("soil").expect("the paper set has soil");
    let base_material = table.id(&spec.base.material).expect("validated");
    let steel = table.id("steel").expect("the paper set has steel");
    let size =
        SizeDistribution::new(spec.particle.clone()).map_err(|e| build_error("particle", e))?;
    let (r_min, r_max) = (size.min_radius(), size.max_radius());
    let d = 2.0 * r_max;
    let dt = spec.time_step_rayleigh_fraction * rayleigh_time(r_min, table.material(soil));
    let g = 9.81;

    let half = 0.5 * spec.base.size;
    let base = Geometry {
        name: "base".into(),
        mesh: base_mesh(spec)?,
        motion: Motion::stationary(Pose::identity()),
        material: base_material,
    };

    let (vessel, region, heap_top, ready_after, top_of_box) = match spec.protocol {
        Protocol::Funnel => {
            let f = &spec.funnel;
            let mesh = funnel_mesh(spec)?;
            let rim_z = f.outlet_height + f.cone_height;
            let z_min = rim_z + 0.5 * d;
            let z_max = z_min + (4.0 * d).max(0.01);
            let region = Region::Cylinder {
                axis_x: 0.0,
                axis_y: 0.0,
                radius: 0.35 * f.top_diameter(),
                z_min,
                z_max,
            };
            let heap_top = heap_region_top(spec, d);
            // The last grains need to fall through the funnel and onto the heap.
            let ready = (2.0 * z_max / g).sqrt();
            (mesh, region, heap_top, ready, z_max)
        }
        Protocol::LiftedCylinder => {
            let c = &spec.cylinder;
            let radius = 0.5 * c.inner_diameter;
            let mesh = cylinder(radius, c.height, c.segments, false)
                .map_err(|e| build_error("cylinder", e))?;
            let z_min = c.height + 0.5 * d;
            let z_max = z_min + (4.0 * d).max(0.01);
            let region = Region::Cylinder {
                axis_x: 0.0,
                axis_y: 0.0,
                radius: 0.8 * radius,
                z_min,
                z_max,
            };
            let fill_time = spec.total_mass / spec.mass_rate + (2.0 * z_max / g).sqrt();
            let lift_start = fill_time + c.fill_settle_time;
            let lift_end = lift_start + c.lift_height / c.lift_speed;
            (
                mesh,
                region,
                f64::INFINITY,
                lift_end,
                z_max.max(2.0 * c.height),
            )
        }
    };
    let motion = match spec.protocol {
        Protocol::Funnel => Motion::stationary(Pose::identity()),
        Protocol::LiftedCylinder => {
            let c = &spec.cylinder;
            let start = ready_after - c.lift_height / c.lift_speed;
            Motion::new(
                Pose::identity(),
                vec![TranslationSegment {
                    velocity: Vec3::new(0.0, 0.0, c.lift_speed),
                    start,
                    stop: ready_after,
                }],
                Vec::new(),
            )
            .map_err(|e| build_error("cylinder", e))?
        }
    };
    let vessel = Geometry {
        name: match spec.protocol {
            Protocol::Funnel => "funnel".into(),
            Protocol::LiftedCylinder => "cylinder".into(),
        },
        mesh: vessel,
        motion,
        material: steel,
    };

    // A tight box around the rig keeps the neighbour grid small; its floor is below the plate
    // so grains that roll off the edge fall out and are counted as escaped.
    let margin = 2.0 * d;
    let domain = Domain::closed(
        Vec3::new(-half - margin, -half - margin, -0.02),
        Vec3::new(half + margin, half + margin, top_of_box + 0.01),
    );
    let mut config = WorldConfig::new(dt, domain);
    config.rolling_model = spec.engine_rolling_model();
    config.seed = spec.seed;
    config.geometry_record_interval = 1000;
    let mut world = World::new(table.clone(), config).map_err(|e| build_error("world", e))?;
    world
        .add_geometry(base)
        .map_err(|e| build_error("base", e))?;
    world
        .add_geometry(vessel)
        .map_err(|e| build_error("vessel", e))?;
    let factory = Factory::new(
        FactorySpec {
            region,
            mass_rate: spec.mass_rate,
            total_mass: spec.total_mass,
            start_time: 0.0,
            velocity: Vec3::new(0.0, 0.0, -spec.inlet_speed),
            size,
            max_attempts_per_particle: 100,
        },
        table.material(soil).density,
    )
    .map_err(|e| build_error("factory", e))?;
    world
        .add_source(ParticleSource::Factory(factory), soil)
        .map_err(|e| build_error("factory", e))?;
    Ok(Rig {
        world,
        heap_top,
        ready_after,
    })
}

/// The base plate: a square of side `base.size`, top face at z = 0.
fn base_mesh(spec: &AorSpec) -> Result<TriMesh, AorError> {
    let cells = ((spec.base.size / 0.02).round() as usize).clamp(1, 64);
    plane(spec.base.size, spec.base.size, cells, cells).map_err(|e| build_error("base", e))
}

/// The funnel around the z axis, outlet `funnel.outlet_height` above the plate.
fn funnel_mesh(spec: &AorSpec) -> Result<TriMesh, AorError> {
    let f = &spec.funnel;
    funnel(&FunnelSpec {
        wall_inclination_deg: f.wall_inclination_deg,
        outlet_diameter: f.outlet_diameter,
        outlet_height: f.outlet_height,
        top: FunnelTop::ConeHeight(f.cone_height),
        segments: f.segments,
    })
    .map_err(|e| build_error("funnel", e))
}

/// Top of the heap region for grains of (largest) diameter `d`: for the funnel a grain below
/// the outlet (grains resting in the outlet are held up by the funnel, not by the heap); the
/// tube's region is bounded by the tube's bottom as it lifts instead.
fn heap_region_top(spec: &AorSpec, d: f64) -> f64 {
    match spec.protocol {
        Protocol::Funnel => spec.funnel.outlet_height - d,
        Protocol::LiftedCylinder => f64::INFINITY,
    }
}

/// The run's measurement settings: plate top at z = 0, the axis at x = y = 0.
fn rig_measure_settings(spec: &AorSpec) -> MeasureSettings {
    let mut settings = spec.measure.clone();
    settings.base_z_m = 0.0;
    settings.axis_xy_m = Some([0.0, 0.0]);
    settings
}

/// The rig's static meshes in the run's frame (plate top at z = 0, axis x = y = 0), named
/// `base` and `funnel`, e.g. to give a peer engine the same walls as STL. Funnel protocol only
/// (the tube moves).
pub fn rig_meshes(spec: &AorSpec) -> Result<Vec<(&'static str, TriMesh)>, AorError> {
    spec.validate()?;
    if spec.protocol != Protocol::Funnel {
        return Err(AorError::Spec(SpecError::Invalid {
            path: "protocol".into(),
            reason: "only the funnel rig has static meshes to export".into(),
        }));
    }
    Ok(vec![
        ("base", base_mesh(spec)?),
        ("funnel", funnel_mesh(spec)?),
    ])
}

/// Measures a heap given as grain centres and radii in the run's frame (plate top at z = 0,
/// funnel axis at x = y = 0) exactly as [`run_aor`] measures its own: only grains whose centre
/// lies below the heap region's top (for the funnel, a largest-grain diameter below the outlet)
/// count, with the spec's measurement settings. For particle files from elsewhere: a saved
/// `final.csv`, a peer engine's dump.
pub fn measure_heap(
    spec: &AorSpec,
    positions: &[[f64; 3]],
    radii: &[f64],
) -> Result<AngleOfRepose, MeasureError> {
    let d = 2.0 * radii.iter().copied().fold(0.0, f64::max);
    let top = heap_region_top(spec, d);
    let (heap, heap_radii): (Vec<[f64; 3]>, Vec<f64>) = positions
        .iter()
        .zip(radii)
        .filter(|(p, _)| p[2] < top)
        .map(|(p, r)| (*p, *r))
        .unzip();
    measure_angle_of_repose(&heap, &heap_radii, &rig_measure_settings(spec))
}

/// The factory's books: finished, inserted mass, inserted count (finished and empty without
/// a factory).
fn factory_state(backend: &dyn Backend) -> (bool, f64, u64) {
    match backend.factory() {
        Some(f) => (f.finished, f.inserted_mass, f.inserted_count),
        None => (true, 0.0, 0),
    }
}

/// The heap region's grains: centres, radii and their total mass.
type HeapRegion = (Vec<[f64; 3]>, Vec<f64>, f64);

/// The grains of the heap region: centres below `heap_top` (and, for the tube, below the tube's
/// current bottom).
fn heap_region(
    backend: &mut dyn Backend,
    heap_top: f64,
    spec: &AorSpec,
) -> Result<HeapRegion, BackendError> {
    let top = match spec.protocol {
        Protocol::Funnel => heap_top,
        Protocol::LiftedCylinder => {
            let bottom = backend.geometries()[1].motion.offset_at(backend.time()).z;
            // Before the lift the whole fill counts (it is measured only after the lift).
            if bottom <= 0.0 {
                f64::INFINITY
            } else {
                bottom
            }
        }
    }
    .min(heap_top);
    let p = backend.grains()?;
    let mut positions = Vec::new();
    let mut radii = Vec::new();
    let mut mass = 0.0;
    for k in 0..p.len() {
        let x = p.position[k];
        if x.z < top {
            positions.push([x.x, x.y, x.z]);
            radii.push(p.radius[k]);
            mass += p.mass[k];
        }
    }
    Ok((positions, radii, mass))
}

/// An outflow below this fraction of the mass rate, with grains left to pass, is a jam.
const JAMMED_OUTFLOW: f64 = 0.1;

/// What the funnel's outlet passed over the last `settle.creep_window_s` of a run (g/s).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Outflow {
    /// Less than [`JAMMED_OUTFLOW`] of the mass rate: an arch (perhaps with a trickle).
    Jammed(f64),
    Flowing(f64),
}

/// The outflow at the end of a funnel run from its samples of (time, kg below the outlet),
/// over the last `settle.creep_window_s` (or the whole run, if shorter); none for the lifted
/// cylinder or a run with fewer than two samples.
fn funnel_outflow(spec: &AorSpec, below_outlet: &[(f64, f64)]) -> Option<Outflow> {
    let window = spec.settle.creep_window_s;
    let &(end, mass) = below_outlet.last()?;
    let &(start, before) = below_outlet
        .iter()
        .rev()
        .find(|&&(t, _)| t <= end - window)
        .or(below_outlet.first())?;
    if end <= start {
        return None;
    }
    let rate = (mass - before) / (end - start);
    Some(if rate < JAMMED_OUTFLOW * spec.mass_rate {
        Outflow::Jammed(1e3 * rate)
    } else {
        Outflow::Flowing(1e3 * rate)
    })
}

/// The rest rule's kinetic energy: **translational only**, per grain, over m g d. Rotation is
/// left out because neither EPSD rolling friction (here and in LIGGGHTS) nor the tangential
/// force resists a twist about the contact normal: a lone grain on the plate keeps spinning
/// about the vertical for ever without moving. Measured (2026-11-24, default preset, EPSD and
/// EDEM damping): the heap's angle flat for 0.5 s, translational ratio 7e-30, rotational 2.5e-3
/// (grains spinning at 170-330 rad/s), so every EPSD run ended `not_settled` at the time cap;
/// LIGGGHTS's own run of the same test sat at the same plateau (2.4e-3). A rolling or sliding
/// grain translates, so nothing that changes the heap is missed.
fn kinetic_energy_ratio(p: &Grains<'_>, g: f64) -> f64 {
    if p.is_empty() {
        return 0.0;
    }
    let n = p.len() as f64;
    let mean_mass = p.mass.iter().sum::<f64>() / n;
    let mean_d = 2.0 * p.radius.iter().sum::<f64>() / n;
    p.translational_kinetic_energy() / n / (mean_mass * g * mean_d)
}

/// Runs the experiment. `progress` is called every few hundred steps and at every check; if it
/// returns [`Control::Cancel`] the run stops and is reported as `cancelled`.
pub fn run_aor(
    spec: &AorSpec,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<AorRun, AorError> {
    run_aor_with_checkpoints(spec, progress, Checkpoints::default())
}

/// What receives a checkpoint's bytes ([`super::AorCheckpoint::from_bytes`] reads them back).
pub type SaveCheckpoint<'a> = dyn FnMut(&[u8]) + 'a;

/// Where a run starts and how it hands out checkpoints ([`run_aor_with_checkpoints`]).
#[derive(Default)]
pub struct Checkpoints<'a> {
    /// Continue this saved run instead of starting afresh (it must be a run of the same spec).
    pub resume: Option<AorCheckpoint>,
    /// Called with a checkpoint's bytes every [`Self::every`] of wall-clock time, and once more
    /// if the run is cancelled; none: no checkpoints. Keeping the bytes is the caller's
    /// business (a failed write must not stop the run).
    pub save: Option<&'a mut SaveCheckpoint<'a>>,
    /// Wall-clock time between checkpoints (checked every few hundred steps).
    pub every: Duration,
}

impl std::fmt::Debug for Checkpoints<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Checkpoints")
            .field("resume_at_step", &self.resume.as_ref().map(|c| c.steps()))
            .field("save", &self.save.is_some())
            .field("every", &self.every)
            .finish()
    }
}

/// [`run_aor`], resumable: it may start from a checkpoint and hands out checkpoints as it goes.
/// A resumed run ends exactly as the uninterrupted run would have (same steps, same angle to
/// the last bit); only its `wall_time_s` (the sum over all segments) and `resumed_at_step`
/// tell them apart.
pub fn run_aor_with_checkpoints(
    spec: &AorSpec,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
    checkpoints: Checkpoints<'_>,
) -> Result<AorRun, AorError> {
    run_aor_on(Engine::Cpu, spec, progress, checkpoints)
}

/// [`run_aor_with_checkpoints`] on `engine`: the same rig, run loop, rest rule and
/// measurement on any backend ([`crate::backend`]); the result names the engine
/// (`engine_version`). On the CPU it is [`run_aor_with_checkpoints`], bit for bit.
///
/// The GPU backend runs both protocols with every contact law (the factory is served from the
/// host, see [`crate::backend::GpuBackend`]; the lifted tube is a moving geometry) and refuses
/// checkpoints by name (a GPU run is not continued from a saved state: `checkpoints` must be
/// the default).
pub fn run_aor_on(
    engine: Engine<'_>,
    spec: &AorSpec,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
    mut checkpoints: Checkpoints<'_>,
) -> Result<AorRun, AorError> {
    let started = Instant::now();
    let g = 9.81;
    spec.validate()?;
    if engine.kind() != BackendKind::Cpu
        && (checkpoints.resume.is_some() || checkpoints.save.is_some())
    {
        return Err(AorError::Backend(BackendError::Unsupported {
            backend: engine.kind().label(),
            what: "checkpoints (a GPU run cannot be continued from a saved state)".into(),
        }));
    }
    let settings = rig_measure_settings(spec);
    let nominal_fill = spec.total_mass / spec.mass_rate;
    let (mut boxed, mut state, resumed_at_step) = match checkpoints.resume.take() {
        Some(saved) => {
            spec.validate()?;
            saved.check_spec(spec)?;
            let steps = saved.world.steps();
            (engine.start(saved.world)?, saved.state, Some(steps))
        }
        None => {
            let Rig {
                world,
                heap_top,
                ready_after,
            } = build_rig(spec)?;
            let state = LoopState {
                heap_top,
                ready_after,
                insertion_end: None,
                checks: Vec::new(),
                decision: RestDecision::NotYet(NotYet::TooFewChecks),
                next_check: f64::INFINITY,
                deadline: nominal_fill + ready_after + spec.time_cap,
                below_outlet: Vec::new(),
                wall_time_s: 0.0,
            };
            (engine.start(world)?, state, None)
        }
    };
    let backend: &mut dyn Backend = boxed.as_mut();
    let (heap_top, ready_after) = (state.heap_top, state.ready_after);
    let spent_before = state.wall_time_s;
    let wall_time = || spent_before + started.elapsed().as_secs_f64();
    let mut last_save = Instant::now();
    let mut ended_by: Option<EndedBy> = None;
    let report_every = backend.steps_between_reports();

    while ended_by.is_none() {
        // The loop looks at the state after the steps below (a report, an outflow sample, a
        // check, the deadline); a backend may take the steps up to the first of them at once.
        let next_report = report_every - backend.steps() % report_every;
        let (t, dt) = (backend.time(), backend.time_step());
        let mut at_most = next_report;
        if spec.protocol == Protocol::Funnel {
            at_most = match state.below_outlet.last() {
                None => 1,
                Some(&(last, _)) => steps_until(t, dt, last + spec.settle.check_interval, at_most),
            };
        }
        at_most = steps_until(t, dt, state.next_check, at_most);
        at_most = steps_until(t, dt, state.deadline, at_most);
        backend.advance(at_most)?;
        let t = backend.time();
        if state.insertion_end.is_none() {
            let (finished, _, _) = factory_state(backend);
            if finished {
                state.insertion_end = Some(t);
                let ready = t.max(ready_after);
                state.next_check = ready + spec.settle.min_time;
                state.deadline = ready + spec.time_cap;
            }
        }
        if spec.protocol == Protocol::Funnel
            && state
                .below_outlet
                .last()
                .is_none_or(|&(last, _)| t >= last + spec.settle.check_interval)
        {
            let below = heap_region(backend, heap_top, spec)?.2;
            state.below_outlet.push((t, below));
        }
        let is_check = t >= state.next_check;
        if backend.steps() % report_every == 0 || is_check {
            let (phase, fraction) = match state.insertion_end {
                None => {
                    let (_, mass, _) = factory_state(backend);
                    ("filling", 0.5 * (mass / spec.total_mass).min(1.0))
                }
                Some(end) => {
                    let ready = end.max(ready_after);
                    let phase = if t < ready && spec.protocol == Protocol::LiftedCylinder {
                        "lifting"
                    } else {
                        "settling"
                    };
                    (
                        phase,
                        0.5 + 0.5 * ((t - end) / (state.deadline - end)).clamp(0.0, 1.0),
                    )
                }
            };
            let control = progress(Progress {
                fraction,
                phase,
                time: t,
                particles: backend.grain_count()?,
            });
            if control == Control::Cancel {
                ended_by = Some(EndedBy::Cancelled);
                // The state after this step is whole: keep it, so a cancelled run can go on.
                if let (Some(save), Some(world)) =
                    (checkpoints.save.as_mut(), backend.checkpoint_world())
                {
                    state.wall_time_s = wall_time();
                    save(&encode(spec, &state, world));
                }
                break;
            }
        }
        if is_check {
            state.next_check += spec.settle.check_interval;
            let ke = kinetic_energy_ratio(&backend.grains()?, g);
            let (positions, radii, _) = heap_region(backend, heap_top, spec)?;
            let angle = measure_angle_of_repose(&positions, &radii, &settings)
                .ok()
                .map(|m| m.angle_deg);
            state.checks.push(SettleCheck {
                time: t,
                kinetic_energy_ratio: ke,
                angle_deg: angle,
                on_base: positions.len() as u64,
            });
            state.decision = rest_decision(&state.checks, &spec.settle);
            if state.decision == RestDecision::AtRest {
                ended_by = Some(EndedBy::AtRest);
            }
            if ended_by.is_none() {
                if let Some(cap) = spec.wall_time_cap {
                    if wall_time() > cap {
                        ended_by = Some(EndedBy::WallTimeCap);
                    }
                }
            }
        }
        if ended_by.is_none() && t >= state.deadline {
            ended_by = Some(EndedBy::TimeCap);
        }
        if ended_by.is_none() && backend.steps() % report_every == 0 {
            if let Some(cap) = spec.wall_time_cap {
                if wall_time() > cap {
                    ended_by = Some(EndedBy::WallTimeCap);
                }
            }
            if let (Some(save), Some(world)) =
                (checkpoints.save.as_mut(), backend.checkpoint_world())
            {
                if last_save.elapsed() >= checkpoints.every {
                    state.wall_time_s = wall_time();
                    save(&encode(spec, &state, world));
                    last_save = Instant::now();
                }
            }
        }
    }
    let LoopState {
        insertion_end,
        checks,
        decision,
        below_outlet,
        ..
    } = state;
    let ended_by = ended_by.expect("loop ends with a reason");
    let _ = progress(Progress {
        fraction: 1.0,
        phase: "measuring",
        time: backend.time(),
        particles: backend.grain_count()?,
    });

    // Bookkeeping.
    let (_, inserted_mass, inserted_count) = factory_state(backend);
    let (positions, radii, on_base_mass) = heap_region(backend, heap_top, spec)?;
    let removed = backend.removed_count()?;
    let p = backend.grains()?;
    let present_mass: f64 = p.mass.iter().sum();
    let on_base_count = positions.len() as u64;
    let escaped = Amount {
        count: removed,
        mass: (inserted_mass - present_mass).max(0.0),
    };
    let held_up = Amount {
        count: p.len() as u64 - on_base_count,
        mass: present_mass - on_base_mass,
    };
    let grain_diameter_m = if radii.is_empty() {
        2.0 * p.radius.iter().sum::<f64>() / (p.len().max(1) as f64)
    } else {
        2.0 * radii.iter().sum::<f64>() / radii.len() as f64
    };
    let measured = measure_angle_of_repose(&positions, &radii, &settings);
    let mean_grain_mass = on_base_mass / (on_base_count.max(1) as f64);
    let on_pile = match &measured {
        Ok(m) => Amount {
            count: m.particles_considered as u64,
            mass: m.particles_considered as f64 * mean_grain_mass,
        },
        Err(_) => Amount::default(),
    };
    let of_inserted = |mass: f64| {
        if inserted_mass > 0.0 {
            mass / inserted_mass
        } else {
            0.0
        }
    };
    let escaped_fraction = of_inserted(escaped.mass);
    let held_up_fraction = of_inserted(held_up.mass);
    let came_to_rest = ended_by == EndedBy::AtRest;
    let rest = rest_state(&checks, &spec.settle);
    let outflow = funnel_outflow(spec, &below_outlet);
    let draining = match outflow {
        Some(Outflow::Flowing(rate)) => Some(rate),
        _ => None,
    };
    let (status, message) = if ended_by == EndedBy::Cancelled {
        (RunStatus::Cancelled, Some("cancelled".to_owned()))
    } else if insertion_end.is_none() {
        match outflow {
            Some(Outflow::Jammed(rate)) => (
                RunStatus::HeldUp,
                Some(format!(
                    "the funnel jammed: {rate:.1} g/s passed the outlet at the end, against \
                     the {:.0} g/s poured in, and only {:.4} of {:.4} kg was inserted by the \
                     cap (an arch over the outlet, the funnel above it full)",
                    1e3 * spec.mass_rate,
                    inserted_mass,
                    spec.total_mass
                )),
            ),
            _ => (
                RunStatus::NotSettled,
                Some(format!(
                    "only {:.4} of {:.4} kg inserted before the cap{}: the {} took grains \
                     slower than mass_rate (raise time_cap)",
                    inserted_mass,
                    spec.total_mass,
                    draining.map_or(String::new(), |rate| format!(
                        ", with {rate:.1} g/s still passing the outlet"
                    )),
                    match spec.protocol {
                        Protocol::Funnel => "funnel",
                        Protocol::LiftedCylinder => "tube",
                    }
                )),
            ),
        }
    } else if escaped_fraction > spec.max_escaped_fraction {
        (
            RunStatus::Escaped,
            Some(format!(
                "{:.1} % of the mass left the plate (limit {:.1} %)",
                100.0 * escaped_fraction,
                100.0 * spec.max_escaped_fraction
            )),
        )
    } else if let (true, Some(rate)) = (held_up_fraction > spec.max_held_up_fraction, draining) {
        (
            RunStatus::NotSettled,
            Some(format!(
                "{:.1} % of the mass was still in the funnel when the run ended \
                 ({ended_by:?}), draining at {rate:.1} g/s: the cap came before the pour was \
                 through (raise time_cap)",
                100.0 * held_up_fraction,
            )),
        )
    } else if held_up_fraction > spec.max_held_up_fraction {
        (
            RunStatus::HeldUp,
            Some(format!(
                "{:.1} % of the mass ({} grains) was still in the funnel or tube when the run \
                 ended ({ended_by:?}; limit {:.1} %): an arch over the outlet; the heap under \
                 it holds {:.1} % of the mass",
                100.0 * held_up_fraction,
                held_up.count,
                100.0 * spec.max_held_up_fraction,
                100.0 * of_inserted(on_base_mass),
            )),
        )
    } else if let Err(e) = &measured {
        (RunStatus::MeasurementFailed, Some(e.to_string()))
    } else if !came_to_rest {
        (
            RunStatus::NotSettled,
            Some(match (&rest, decision) {
                (Some(state), RestDecision::NotYet(why)) => {
                    format!("the heap did not come to rest ({ended_by:?}; {why}): {state}")
                }
                _ => format!("the heap did not come to rest ({ended_by:?})"),
            }),
        )
    } else {
        (RunStatus::Ok, None)
    };
    let ok = status == RunStatus::Ok;
    let m = measured.as_ref().ok();
    let when_ok = |f: &dyn Fn(&AngleOfRepose) -> f64| if ok { m.map(f) } else { None };
    let result = AorResult {
        status,
        message,
        angle_deg: when_ok(&|m| m.angle_deg),
        per_direction_deg: if ok {
            m.map(|m| m.per_direction_deg.clone()).unwrap_or_default()
        } else {
            Vec::new()
        },
        left_deg: when_ok(&|m| m.left_deg),
        right_deg: when_ok(&|m| m.right_deg),
        projection_mean_deg: when_ok(&|m| m.projection_mean_deg),
        spread_std_deg: when_ok(&|m| m.std_dev_deg),
        spread_min_deg: when_ok(&|m| m.min_deg),
        spread_max_deg: when_ok(&|m| m.max_deg),
        pile_height_m: when_ok(&|m| m.pile_height_m),
        base_diameter_m: when_ok(&|m| m.base_diameter_m),
        last_angle_deg: m.map(|m| m.angle_deg),
        grains: GrainBudget {
            inserted: Amount {
                count: inserted_count,
                mass: inserted_mass,
            },
            on_base: Amount {
                count: on_base_count,
                mass: on_base_mass,
            },
            on_pile,
            held_up,
            escaped,
        },
        grain_diameter_m,
        simulated_time_s: backend.time(),
        insertion_end_s: insertion_end,
        steps: backend.steps(),
        time_step_s: backend.time_step(),
        wall_time_s: wall_time(),
        resumed_at_step,
        ended_by,
        came_to_rest,
        rest,
        checks,
        engine_version: Some(backend.engine_version()),
    };
    Ok(AorRun {
        result,
        measurement: measured.ok(),
        positions,
        radii,
        world: boxed.into_world()?,
    })
}
