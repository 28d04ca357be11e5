//! The experiment kinds a job can name, behind one interface: the server uses
//! [`prepare_spec`] and [`validate_spec`] at submission (so a bad spec is a 422, not a dead
//! job), a worker uses [`run_experiment`] to turn a leased job into metrics.
//!
//! Specs travel as JSON because the job server stores and edits them (factor values are
//! written at dotted paths) without knowing each kind's Rust type.

use crate::Spec;
use std::collections::BTreeMap;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::aor::{
    checkpoint_key, run_aor_with_checkpoints, AorCheckpoint, AorSpec, Checkpoints, RunStatus,
};
use crate::drill::{
    bed_key, build_bed, run_drill_on_bed, DrillError, DrillSpec, DrillStatus, SettledBed,
};
use crate::formula::FormulaSpec;
use crate::progress::Control;
use crate::replay::{ReplayError, ReplaySpec};
use crate::shear::{
    build_sample, run_shear_on_bed, sample_key, ShearError, ShearSpec, ShearStatus,
};

/// Settled drilling beds (and shear samples, which are drilling beds in the shear box) kept
/// between runs under their [`bed_key`]: a worker keeps them on disk so that runs whose bed
/// inputs are equal (e.g. a batch varying only the auger, with `bed.seed` fixed) do not rebuild
/// the bed every time.
pub trait BedStore {
    /// The bed stored under `key`, if there is one.
    fn get(&mut self, key: &str) -> Option<SettledBed>;
    /// Keeps `bed` under `bed.key`; failing to keep it must not fail the run.
    fn put(&mut self, bed: &SettledBed);
}

/// No store: every drilling run builds its own bed.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoBedStore;

impl BedStore for NoBedStore {
    fn get(&mut self, _key: &str) -> Option<SettledBed> {
        None
    }
    fn put(&mut self, _bed: &SettledBed) {}
}

/// Checkpoints of long runs kept between attempts: a worker keeps them on disk, so a run whose
/// worker was killed or stopped (and whose job comes back to a worker sharing the store) goes
/// on from its last checkpoint instead of starting over. Only angle-of-repose runs checkpoint.
pub trait CheckpointStore {
    /// The bytes kept under `key`, if any (bytes that are not a checkpoint of the run are
    /// ignored by the run).
    fn get(&mut self, key: &str) -> Option<Vec<u8>>;
    /// Keeps `bytes` under `key`, replacing what was there; failing must not fail the run.
    fn put(&mut self, key: &str, bytes: &[u8]);
    /// Forgets `key` (the run has finished).
    fn remove(&mut self, key: &str);
    /// The bytes under `key` cannot be continued from (`reason`: e.g. written by a build whose
    /// format this one cannot read): the run starts over, so a store keeps them elsewhere
    /// rather than letting the new run's first checkpoint replace them.
    fn reject(&mut self, key: &str, reason: &str);
    /// Wall-clock time between two checkpoints of a run.
    fn every(&self) -> Duration;
}

/// No store: runs start from the beginning and keep nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoCheckpoints;

impl CheckpointStore for NoCheckpoints {
    fn get(&mut self, _key: &str) -> Option<Vec<u8>> {
        None
    }
    fn put(&mut self, _key: &str, _bytes: &[u8]) {}
    fn remove(&mut self, _key: &str) {}
    fn reject(&mut self, _key: &str, _reason: &str) {}
    fn every(&self) -> Duration {
        Duration::MAX
    }
}

/// An experiment kind, parsed once from its name ([`Kind::parse`]) and dispatched by `match`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    /// Angle of repose (`aor`).
    Aor,
    /// The drilling (pore-forming) test (`drill`).
    Drill,
    /// The direct shear test (`shear`).
    Shear,
    /// The test aid that answers from a table of known results (`table_lookup`).
    TableLookup,
    /// The test aid that answers with closed forms and seeded noise (`formula`).
    Formula,
}

impl Kind {
    /// Every kind, in the order [`KINDS`] names them.
    pub const ALL: [Kind; 5] = [
        Kind::Aor,
        Kind::Drill,
        Kind::Shear,
        Kind::TableLookup,
        Kind::Formula,
    ];

    /// The kind called `name`.
    pub fn parse(name: &str) -> Result<Kind, ExperimentError> {
        Kind::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| ExperimentError::UnknownKind { kind: name.into() })
    }

    /// The name a job gives.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Aor => "aor",
            Kind::Drill => "drill",
            Kind::Shear => "shear",
            Kind::TableLookup => "table_lookup",
            Kind::Formula => "formula",
        }
    }

    /// Presets the kind offers (the first is its default).
    pub fn presets(self) -> &'static [&'static str] {
        match self {
            Kind::Aor => &crate::aor::PRESETS,
            Kind::Drill => &crate::drill::PRESETS,
            Kind::Shear => &crate::shear::PRESETS,
            Kind::TableLookup => &[],
            Kind::Formula => &[],
        }
    }
}

impl std::str::FromStr for Kind {
    type Err = ExperimentError;
    fn from_str(name: &str) -> Result<Kind, ExperimentError> {
        Kind::parse(name)
    }
}

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Names of the kinds understood by [`run_experiment`] (`Kind::ALL`'s names).
pub const KINDS: [&str; 5] = ["aor", "drill", "shear", "table_lookup", "formula"];

/// A spec parsed and checked for its kind: the typed form every entry point works on (parsed
/// once, like mini-redis's `Command`), then dispatched by `match`.
#[derive(Debug, Clone, PartialEq)]
pub enum ExperimentSpec {
    Aor(AorSpec),
    Drill(DrillSpec),
    Shear(ShearSpec),
    TableLookup(ReplaySpec),
    Formula(FormulaSpec),
}

impl ExperimentSpec {
    /// Parses and validates `spec` as a complete spec of `kind`.
    pub fn parse(kind: Kind, spec: &Value) -> Result<ExperimentSpec, ExperimentError> {
        Ok(match kind {
            Kind::Aor => ExperimentSpec::Aor(parse_aor(spec)?),
            Kind::Drill => ExperimentSpec::Drill(parse_drill(spec)?),
            Kind::Shear => ExperimentSpec::Shear(parse_shear(spec)?),
            Kind::TableLookup => ExperimentSpec::TableLookup(parse_replay(spec)?),
            Kind::Formula => ExperimentSpec::Formula(FormulaSpec::from_json(spec)?),
        })
    }

    pub fn kind(&self) -> Kind {
        match self {
            ExperimentSpec::Aor(_) => Kind::Aor,
            ExperimentSpec::Drill(_) => Kind::Drill,
            ExperimentSpec::Shear(_) => Kind::Shear,
            ExperimentSpec::TableLookup(_) => Kind::TableLookup,
            ExperimentSpec::Formula(_) => Kind::Formula,
        }
    }

    /// The JSON form a job carries.
    pub fn to_value(&self) -> Value {
        match self {
            ExperimentSpec::Aor(s) => serde_json::to_value(s).expect("AorSpec serialises"),
            ExperimentSpec::Drill(s) => serde_json::to_value(s).expect("DrillSpec serialises"),
            ExperimentSpec::Shear(s) => serde_json::to_value(s).expect("ShearSpec serialises"),
            ExperimentSpec::TableLookup(s) => {
                serde_json::to_value(s).expect("ReplaySpec serialises")
            }
            ExperimentSpec::Formula(s) => serde_json::to_value(s).expect("FormulaSpec serialises"),
        }
    }
}

/// Why a spec cannot be used or a run could not produce a result.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExperimentError {
    /// Not one of [`KINDS`].
    #[error("unknown experiment kind {kind:?} (kinds: {})", KINDS.join(", "))]
    UnknownKind { kind: String },
    /// The kind has no such preset.
    #[error("unknown preset {preset:?} for kind {kind:?} (presets: {valid})")]
    UnknownPreset {
        kind: String,
        preset: String,
        valid: String,
    },
    /// The spec document is not valid for its kind; `path` names the offending field when known.
    #[error("{message}")]
    InvalidSpec {
        path: Option<String>,
        message: String,
    },
    /// The experiment ran but gave no usable result. Rerunning the same spec and seed gives the
    /// same outcome, so a job server should not retry it as it was.
    #[error("{message}")]
    NoResult {
        message: String,
        /// The kind's full result document, for the run record.
        details: Value,
        /// The failure is a matter of this seed's chance, not of the spec: a run with another
        /// seed may give a result (grains that arched over the funnel's outlet in this pour).
        another_seed_may_help: bool,
    },
    /// The progress callback cancelled the run.
    #[error("cancelled")]
    Cancelled,
    /// The machine running the experiment could not run it, for a reason of its own (e.g. a
    /// worker cannot start its simulation threads): not the spec's fault, so the run may
    /// succeed elsewhere or later.
    #[error("{message}")]
    Local { message: String },
}

impl ExperimentError {
    /// Whether running the same spec again anywhere gives the same failure (a bad spec, or a
    /// run that gives no result): a job server should then not retry it. An unknown kind or
    /// preset met when running is this machine's catalog lacking it (a worker of another
    /// build may have it), so it is not permanent; at submission the server refuses both.
    pub fn is_permanent(&self) -> bool {
        // (A failure another seed may cure is permanent for this seed all the same.)
        match self {
            ExperimentError::InvalidSpec { .. } | ExperimentError::NoResult { .. } => true,
            ExperimentError::UnknownKind { .. }
            | ExperimentError::UnknownPreset { .. }
            | ExperimentError::Cancelled
            | ExperimentError::Local { .. } => false,
        }
    }

    /// Whether the same spec with another seed may give a result where this run gave none: a
    /// job server may then run it again under a new seed.
    pub fn another_seed_may_help(&self) -> bool {
        matches!(
            self,
            ExperimentError::NoResult {
                another_seed_may_help: true,
                ..
            }
        )
    }
}

/// What a finished experiment reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    /// Scalar results, e.g. `angle_deg`; a batch's response is one of these.
    pub metrics: BTreeMap<String, f64>,
    /// The kind's full result document.
    pub details: Value,
    /// Pictures worth keeping, `(file name, SVG text)`.
    #[serde(skip)]
    pub pictures: Vec<(String, String)>,
    /// Seconds a worker should keep the job before reporting (the table-lookup test aid's
    /// stand-in for simulation time); 0 for real experiments.
    pub hold_s: f64,
}

/// Presets a kind offers (the first is its default).
pub fn presets(kind: &str) -> Result<&'static [&'static str], ExperimentError> {
    Ok(Kind::parse(kind)?.presets())
}

/// The complete spec for `kind`: `overrides` merged over `preset` (objects key by key, see
/// [`merge_json`]), checked. Without a preset the overrides must be a complete spec, except for
/// `aor`, whose default preset fills in what is missing.
pub fn prepare_spec(
    kind: &str,
    preset: Option<&str>,
    overrides: &Value,
) -> Result<Value, ExperimentError> {
    let kind = Kind::parse(kind)?;
    let unknown_preset = |valid: String| ExperimentError::UnknownPreset {
        kind: kind.name().into(),
        preset: preset.unwrap_or_default().into(),
        valid,
    };
    let base = match kind {
        Kind::Aor => {
            let base = AorSpec::preset(preset.unwrap_or("default"))
                .map_err(|_| unknown_preset(kind.presets().join(", ")))?;
            Some(serde_json::to_value(base).expect("AorSpec serialises"))
        }
        Kind::Drill => {
            let base = DrillSpec::preset(preset.unwrap_or("default"))
                .map_err(|_| unknown_preset(kind.presets().join(", ")))?;
            Some(serde_json::to_value(base).expect("DrillSpec serialises"))
        }
        Kind::Shear => {
            let base = ShearSpec::preset(preset.unwrap_or("default"))
                .map_err(|_| unknown_preset(kind.presets().join(", ")))?;
            Some(serde_json::to_value(base).expect("ShearSpec serialises"))
        }
        Kind::TableLookup | Kind::Formula => {
            if preset.is_some() {
                return Err(unknown_preset("(none)".into()));
            }
            None
        }
    };
    let merged = match base {
        Some(base) => merge_json(base, overrides.clone()),
        None => overrides.clone(),
    };
    Ok(ExperimentSpec::parse(kind, &merged)?.to_value())
}

/// Checks a complete spec (e.g. after factor values were written into it).
pub fn validate_spec(kind: &str, spec: &Value) -> Result<(), ExperimentError> {
    ExperimentSpec::parse(Kind::parse(kind)?, spec).map(drop)
}

/// Runs one experiment with `seed` (overriding any seed in the spec). `progress` receives the
/// fraction done (0..1) and may cancel. Heavy kinds run on the current rayon pool.
pub fn run_experiment(
    kind: &str,
    spec: &Value,
    seed: u64,
    progress: &mut dyn FnMut(f64) -> Control,
) -> Result<Outcome, ExperimentError> {
    run_experiment_with_beds(kind, spec, seed, progress, &mut NoBedStore)
}

/// [`run_experiment`], with drilling beds taken from and kept in `beds`. The outcome is the
/// same, bit for bit, whether the bed was built or reused (`details.bed.reused` says which).
pub fn run_experiment_with_beds(
    kind: &str,
    spec: &Value,
    seed: u64,
    progress: &mut dyn FnMut(f64) -> Control,
    beds: &mut dyn BedStore,
) -> Result<Outcome, ExperimentError> {
    run_experiment_with_stores(kind, spec, seed, progress, beds, &mut NoCheckpoints)
}

/// The key under which [`run_experiment_with_stores`] keeps this run's checkpoint, for a kind
/// that keeps checkpoints (angle of repose); `None` for the others. A worker uses it to drop the
/// checkpoint of a run nobody will continue (its batch was cancelled, or its result came from
/// elsewhere).
pub fn checkpoint_key_of_run(
    kind: &str,
    spec: &Value,
    seed: u64,
) -> Result<Option<String>, ExperimentError> {
    match ExperimentSpec::parse(Kind::parse(kind)?, spec)? {
        ExperimentSpec::Aor(mut spec) => {
            spec.seed = seed;
            Ok(Some(checkpoint_key(&spec)))
        }
        ExperimentSpec::Drill(_)
        | ExperimentSpec::Shear(_)
        | ExperimentSpec::TableLookup(_)
        | ExperimentSpec::Formula(_) => Ok(None),
    }
}

/// [`run_experiment_with_beds`], with angle-of-repose runs continued from and checkpointed to
/// `checkpoints` (under [`checkpoint_key`]). The outcome is the same, bit for bit, whether the
/// run went through in one go or was continued (`details.resumed_at_step` says which); a run
/// that finishes (in any state but cancelled) removes its checkpoint.
pub fn run_experiment_with_stores(
    kind: &str,
    spec: &Value,
    seed: u64,
    progress: &mut dyn FnMut(f64) -> Control,
    beds: &mut dyn BedStore,
    checkpoints: &mut dyn CheckpointStore,
) -> Result<Outcome, ExperimentError> {
    match ExperimentSpec::parse(Kind::parse(kind)?, spec)? {
        ExperimentSpec::Aor(mut spec) => {
            spec.seed = seed;
            let key = checkpoint_key(&spec);
            let resume = checkpoints.get(&key).and_then(|bytes| {
                let saved = AorCheckpoint::from_bytes(&bytes)
                    .and_then(|saved| saved.check_spec(&spec).map(|()| saved));
                saved
                    .map_err(|e| checkpoints.reject(&key, &e.to_string()))
                    .ok()
            });
            let every = checkpoints.every();
            let mut keep = |bytes: &[u8]| checkpoints.put(&key, bytes);
            let run = run_aor_with_checkpoints(
                &spec,
                &mut |p| progress(p.fraction),
                Checkpoints {
                    resume,
                    save: Some(&mut keep),
                    every,
                },
            )
            .map_err(|e| ExperimentError::InvalidSpec {
                path: None,
                message: e.to_string(),
            })?;
            if run.result.status != RunStatus::Cancelled {
                checkpoints.remove(&key);
            }
            let details = serde_json::to_value(&run.result).expect("AorResult serialises");
            // A heap still creeping when the time cap ends the run (constant-torque rolling
            // friction never quite stops) is measured as it stands and flagged
            // `came_to_rest = 0`; only a run with no measurable heap has no result.
            let capped_angle = match run.result.status {
                RunStatus::NotSettled if run.result.insertion_end_s.is_some() => {
                    run.result.last_angle_deg
                }
                _ => None,
            };
            match run.result.status {
                RunStatus::Ok => {}
                RunStatus::NotSettled if capped_angle.is_some() => {}
                RunStatus::Cancelled => return Err(ExperimentError::Cancelled),
                status => {
                    return Err(ExperimentError::NoResult {
                        message: format!(
                            "angle-of-repose run ended {status:?}: {}",
                            run.result.message.as_deref().unwrap_or("no heap measured")
                        ),
                        details,
                        // Whether grains arch over the outlet is a matter of the pour.
                        another_seed_may_help: status == RunStatus::HeldUp,
                    });
                }
            }
            let mut metrics = BTreeMap::new();
            let r = &run.result;
            let scalars = [
                ("angle_deg", r.angle_deg.or(capped_angle)),
                ("came_to_rest", Some(if r.came_to_rest { 1.0 } else { 0.0 })),
                (
                    "creep_deg_per_s",
                    r.rest.as_ref().and_then(|s| s.creep_deg_per_s),
                ),
                ("left_deg", r.left_deg),
                ("right_deg", r.right_deg),
                ("projection_mean_deg", r.projection_mean_deg),
                ("spread_std_deg", r.spread_std_deg),
                ("pile_height_m", r.pile_height_m),
                ("base_diameter_m", r.base_diameter_m),
                ("simulated_time_s", Some(r.simulated_time_s)),
                ("grains_inserted", Some(r.grains.inserted.count as f64)),
                ("escaped_mass_kg", Some(r.grains.escaped.mass)),
            ];
            for (name, value) in scalars {
                if let Some(v) = value.filter(|v| v.is_finite()) {
                    metrics.insert(name.to_owned(), v);
                }
            }
            let pictures = run
                .pile_svg()
                .map(|svg| vec![("pile.svg".to_owned(), svg)])
                .unwrap_or_default();
            Ok(Outcome {
                metrics,
                details,
                pictures,
                hold_s: 0.0,
            })
        }
        ExperimentSpec::Drill(mut spec) => {
            spec.seed = seed;
            let drill_error = |e: DrillError| match e {
                DrillError::Cancelled => ExperimentError::Cancelled,
                other => ExperimentError::InvalidSpec {
                    path: None,
                    message: other.to_string(),
                },
            };
            let key = bed_key(&spec);
            let cached = beds.get(&key).filter(|bed| bed.key == key);
            let reused = cached.is_some();
            // Building the bed takes the first quarter of the progress.
            let bed_share = if reused { 0.0 } else { 0.25 };
            let bed = match cached {
                Some(bed) => bed,
                None => {
                    let bed = build_bed(&spec, &mut |p| progress(bed_share * p.fraction))
                        .map_err(drill_error)?;
                    beds.put(&bed);
                    bed
                }
            };
            let bed_wall_s = if reused { 0.0 } else { bed.wall_time_s };
            let mut run = run_drill_on_bed(&spec, bed, &mut |p| {
                progress(bed_share + (1.0 - bed_share) * p.fraction)
            })
            .map_err(drill_error)?;
            run.result.bed.reused = reused;
            run.result.wall_time_s += bed_wall_s;
            let details = serde_json::to_value(&run.result).expect("DrillResult serialises");
            match run.result.status {
                DrillStatus::Ok | DrillStatus::NotSettled => {}
                DrillStatus::Cancelled => return Err(ExperimentError::Cancelled),
                status => {
                    return Err(ExperimentError::NoResult {
                        message: format!(
                            "drilling run ended {status:?}: {}",
                            run.result.message.as_deref().unwrap_or("no hole measured")
                        ),
                        details,
                        another_seed_may_help: false,
                    })
                }
            }
            Ok(Outcome {
                metrics: run.result.metrics(),
                details,
                pictures: vec![
                    ("section.svg".to_owned(), run.section_svg()),
                    ("forces.svg".to_owned(), run.forces_svg()),
                ],
                hold_s: 0.0,
            })
        }
        ExperimentSpec::Shear(mut spec) => {
            spec.seed = seed;
            let shear_error = |e: ShearError| match e {
                ShearError::Cancelled => ExperimentError::Cancelled,
                other => ExperimentError::InvalidSpec {
                    path: None,
                    message: other.to_string(),
                },
            };
            let key = sample_key(&spec);
            let cached = beds.get(&key).filter(|bed| bed.key == key);
            let reused = cached.is_some();
            // Building the sample takes the first fifth of the progress.
            let bed_share = if reused { 0.0 } else { 0.2 };
            let bed = match cached {
                Some(bed) => bed,
                None => {
                    let bed = build_sample(&spec, &mut |p| progress(bed_share * p.fraction))
                        .map_err(shear_error)?;
                    beds.put(&bed);
                    bed
                }
            };
            let bed_wall_s = if reused { 0.0 } else { bed.wall_time_s };
            let mut run = run_shear_on_bed(&spec, bed, &mut |p| {
                progress(bed_share + (1.0 - bed_share) * p.fraction)
            })
            .map_err(shear_error)?;
            run.result.bed.reused = reused;
            run.result.wall_time_s += bed_wall_s;
            // The series thinned: a job server takes at most 64 KiB of details.
            let details =
                serde_json::to_value(run.result.for_details()).expect("ShearResult serialises");
            if run.result.status == ShearStatus::MeasurementFailed {
                return Err(ExperimentError::NoResult {
                    message: format!(
                        "shear test gave no strength: {}",
                        run.result.message.as_deref().unwrap_or("no fit")
                    ),
                    details,
                    another_seed_may_help: false,
                });
            }
            Ok(Outcome {
                metrics: run.result.metrics(),
                details,
                pictures: vec![
                    ("shear_curves.svg".to_owned(), run.curves_svg()),
                    ("mohr_coulomb.svg".to_owned(), run.strength_svg()),
                ],
                hold_s: 0.0,
            })
        }
        ExperimentSpec::TableLookup(spec) => {
            if progress(0.0) == Control::Cancel {
                return Err(ExperimentError::Cancelled);
            }
            let metrics = spec.look_up(seed).map_err(|e| match e {
                ReplayError::NoMatch { .. } | ReplayError::Invalid { .. } => {
                    ExperimentError::NoResult {
                        message: e.to_string(),
                        details: Value::Null,
                        another_seed_may_help: false,
                    }
                }
            })?;
            Ok(Outcome {
                details: serde_json::json!({ "replay": true, "values": spec.values }),
                metrics,
                pictures: Vec::new(),
                hold_s: spec.hold_s,
            })
        }
        ExperimentSpec::Formula(spec) => crate::formula::run(&spec, seed, progress),
    }
}

fn parse_aor(spec: &Value) -> Result<AorSpec, ExperimentError> {
    let spec: AorSpec =
        serde_json::from_value(spec.clone()).map_err(|e| ExperimentError::InvalidSpec {
            path: None,
            message: format!("not a valid aor spec: {e}"),
        })?;
    spec.validate().map_err(|e| ExperimentError::InvalidSpec {
        path: match &e {
            crate::aor::SpecError::Invalid { path, .. } => Some(path.clone()),
            _ => None,
        },
        message: e.to_string(),
    })?;
    Ok(spec)
}

fn parse_drill(spec: &Value) -> Result<DrillSpec, ExperimentError> {
    let spec: DrillSpec =
        serde_json::from_value(spec.clone()).map_err(|e| ExperimentError::InvalidSpec {
            path: None,
            message: format!("not a valid drill spec: {e}"),
        })?;
    spec.validate().map_err(|e| ExperimentError::InvalidSpec {
        path: match &e {
            crate::drill::SpecError::Invalid { path, .. } => Some(path.clone()),
            _ => None,
        },
        message: e.to_string(),
    })?;
    Ok(spec)
}

fn parse_shear(spec: &Value) -> Result<ShearSpec, ExperimentError> {
    let spec: ShearSpec =
        serde_json::from_value(spec.clone()).map_err(|e| ExperimentError::InvalidSpec {
            path: None,
            message: format!("not a valid shear spec: {e}"),
        })?;
    spec.validate().map_err(|e| ExperimentError::InvalidSpec {
        path: match &e {
            crate::shear::SpecError::Invalid { path, .. } => Some(path.clone()),
            _ => None,
        },
        message: e.to_string(),
    })?;
    Ok(spec)
}

fn parse_replay(spec: &Value) -> Result<ReplaySpec, ExperimentError> {
    let spec: ReplaySpec =
        serde_json::from_value(spec.clone()).map_err(|e| ExperimentError::InvalidSpec {
            path: None,
            message: format!("not a valid table_lookup spec: {e}"),
        })?;
    spec.validate().map_err(|e| ExperimentError::InvalidSpec {
        path: match &e {
            ReplayError::Invalid { path, .. } => Some(path.clone()),
            ReplayError::NoMatch { .. } => None,
        },
        message: e.to_string(),
    })?;
    Ok(spec)
}

/// `over` merged into `base`: objects merge key by key, so a spec may give only what differs
/// from its preset; anything else (numbers, arrays, a tagged enum such as a size distribution
/// given whole with its `kind`, or a cohesion law with its `model`) replaces the base value.
pub fn merge_json(base: Value, over: Value) -> Value {
    match (base, over) {
        (Value::Object(mut b), Value::Object(o)) => {
            for (k, v) in o {
                let merged = match b.remove(&k) {
                    Some(old) if v.get("kind").is_none() && v.get("model").is_none() => {
                        merge_json(old, v)
                    }
                    _ => v,
                };
                b.insert(k, merged);
            }
            Value::Object(b)
        }
        (_, o) => o,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn aor_overrides_merge_over_the_preset() {
        let spec = prepare_spec(
            "aor",
            Some("fast"),
            &json!({"soil_soil": {"rolling_friction": 0.3}}),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["rolling_friction"], json!(0.3));
        assert_eq!(spec["soil_soil"]["static_friction"], json!(0.442));
        assert_eq!(spec["total_mass"], json!(0.03), "fast preset kept");
        validate_spec("aor", &spec).unwrap();
    }

    #[test]
    fn bad_specs_name_the_problem() {
        let err = prepare_spec(
            "aor",
            None,
            &json!({"soil_soil": {"static_friction": -1.0}}),
        )
        .unwrap_err();
        match err {
            ExperimentError::InvalidSpec { path, .. } => {
                assert_eq!(path.as_deref(), Some("soil_soil.static_friction"))
            }
            other => panic!("unexpected {other:?}"),
        }
        let err = prepare_spec("aor", None, &json!({"funnel": {"no_such": 1}})).unwrap_err();
        assert!(err.to_string().contains("no_such"), "{err}");
        assert!(matches!(
            prepare_spec("aor", Some("huge"), &json!({})),
            Err(ExperimentError::UnknownPreset { .. })
        ));
        assert!(matches!(
            prepare_spec("cook", None, &json!({})),
            Err(ExperimentError::UnknownKind { .. })
        ));
    }

    #[test]
    fn drill_specs_complete_from_their_preset_and_share_the_aor_factor_paths() {
        let spec = prepare_spec(
            "drill",
            Some("fast"),
            &json!({"soil_soil": {"static_friction": 0.5}}),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["static_friction"], json!(0.5));
        validate_spec("drill", &spec).unwrap();
        let mut bad = spec.clone();
        bad["soil_soil"]["rolling_friction"] = json!(-1.0);
        assert!(validate_spec("drill", &bad).is_err());
    }

    #[test]
    fn kinds_parse_once_and_round_trip_their_names() {
        for (kind, name) in Kind::ALL.into_iter().zip(KINDS) {
            assert_eq!(kind.name(), name);
            assert_eq!(Kind::parse(name).unwrap(), kind);
            assert_eq!(name.parse::<Kind>().unwrap(), kind);
            assert_eq!(presets(name).unwrap(), kind.presets());
        }
        assert!(matches!(
            Kind::parse("Aor"),
            Err(ExperimentError::UnknownKind { .. })
        ));
        let spec = prepare_spec("drill", Some("fast"), &json!({})).unwrap();
        let parsed = ExperimentSpec::parse(Kind::Drill, &spec).unwrap();
        assert_eq!(parsed.kind(), Kind::Drill);
        assert_eq!(parsed.to_value(), spec);
        assert!(ExperimentSpec::parse(Kind::Aor, &spec).is_err());
    }

    #[test]
    fn a_cohesion_law_is_given_whole_and_replaces_the_presets_whole() {
        let linear = json!({"model": "linear", "energy_density": 3.0e5});
        let spec = prepare_spec(
            "aor",
            Some("fast"),
            &json!({"soil_soil": {"cohesion": linear}}),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["cohesion"], linear);
        assert_eq!(spec["soil_steel"]["cohesion"], json!({"model": "none"}));
        // A different model over it replaces it (no leftover energy_density).
        let jkr = json!({"model": "jkr", "surface_energy": 0.1});
        let spec = prepare_spec(
            "aor",
            Some("fast"),
            &merge_json(
                json!({"soil_soil": {"cohesion": linear}}),
                json!({"soil_soil": {"cohesion": jkr}}),
            ),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["cohesion"], jkr);
        let mut bad = spec.clone();
        bad["soil_soil"]["cohesion"]["surface_energy"] = json!(-1.0);
        match validate_spec("aor", &bad) {
            Err(ExperimentError::InvalidSpec { path, .. }) => {
                assert_eq!(path.as_deref(), Some("soil_soil.cohesion.surface_energy"))
            }
            other => panic!("unexpected {other:?}"),
        }
    }

    #[test]
    fn shear_specs_complete_from_their_preset_and_name_bad_fields() {
        let spec = prepare_spec(
            "shear",
            Some("fast"),
            &json!({"soil_soil": {"static_friction": 0.5}, "normal_stresses_kpa": [5.0, 10.0]}),
        )
        .unwrap();
        assert_eq!(spec["soil_soil"]["static_friction"], json!(0.5));
        assert_eq!(spec["normal_stresses_kpa"], json!([5.0, 10.0]));
        assert_eq!(spec["box"]["side"], json!(0.05), "fast preset kept");
        let parsed = ExperimentSpec::parse(Kind::Shear, &spec).unwrap();
        assert_eq!(parsed.kind(), Kind::Shear);
        assert_eq!(parsed.to_value(), spec);
        let mut bad = spec.clone();
        bad["normal_stresses_kpa"] = json!([5.0]);
        match validate_spec("shear", &bad) {
            Err(ExperimentError::InvalidSpec { path, .. }) => {
                assert_eq!(path.as_deref(), Some("normal_stresses_kpa"))
            }
            other => panic!("unexpected {other:?}"),
        }
        assert!(matches!(
            prepare_spec("shear", Some("full"), &json!({})),
            Err(ExperimentError::UnknownPreset { .. })
        ));
    }

    #[test]
    fn a_local_failure_is_not_permanent_and_a_bad_spec_is() {
        let local = ExperimentError::Local {
            message: "cannot start 4 simulation threads".into(),
        };
        assert!(!local.is_permanent());
        assert!(!ExperimentError::Cancelled.is_permanent());
        let bad = prepare_spec("aor", None, &json!({"total_mass": -1.0})).unwrap_err();
        assert!(bad.is_permanent(), "{bad:?}");
    }

    /// Every preset's prepared JSON, and the bed key of each drilling and shear preset, by
    /// hash: moving the spec types between modules must not change a field name, a default or
    /// a cached bed's key. (Recorded before the experiment layer's refactoring, issue 37.)
    #[test]
    fn presets_and_bed_keys_are_as_before() {
        use crate::Spec;
        let mut seen = Vec::new();
        for kind in Kind::ALL {
            for preset in kind.presets() {
                let spec = prepare_spec(kind.name(), Some(preset), &json!({})).unwrap();
                let text = serde_json::to_string(&spec).unwrap();
                let hash = crate::fnv1a(text.as_bytes());
                seen.push(format!("{kind}/{preset} {hash:016x}"));
            }
        }
        for preset in crate::drill::PRESETS {
            let spec = crate::drill::DrillSpec::preset(preset).unwrap();
            seen.push(format!("drill/{preset} {}", crate::drill::bed_key(&spec)));
        }
        for preset in crate::shear::PRESETS {
            let spec = crate::shear::ShearSpec::preset(preset).unwrap();
            seen.push(format!(
                "shear/{preset} {}",
                crate::shear::sample_key(&spec)
            ));
        }
        let pinned = [
            "aor/default c39391d40047b07c",
            "aor/fast 1ca7e71ba5b310c5",
            "aor/paper-scale 04208fdc4585c385",
            "aor/fine 7600fa2547a9d803",
            "aor/size-2.5mm a88c712f8f779d58",
            "aor/size-1.5mm 571ff0accde9c8be",
            "aor/mass-100g 751a52a818f9b08f",
            "aor/paper-scale-sieve afc50a5568886834",
            "drill/default 0500a8a97dc1855b",
            "drill/fast 1feba4a402b7cfd3",
            "drill/full b96e263b8828df22",
            "shear/default 4ceedad5d6ae2b0d",
            "shear/fast 85a596c68357ea10",
            "drill/default bed-v2-c799c2efba703217",
            "drill/fast bed-v2-a59bd87c59242559",
            "drill/full bed-v2-268f918f70a4d81b",
            "shear/default bed-v2-6f5f776c5d93f0b2",
            "shear/fast bed-v2-dc77c0cdb4ec1e60",
        ];
        assert_eq!(seen, pinned, "{seen:#?}");
    }

    #[test]
    fn table_lookup_runs_and_reports_misses_as_no_result() {
        let spec = json!({
            "values": {"a": 1.0},
            "rows": [{"a": 1.0, "y": 5.0}, {"a": 2.0, "y": 7.0}]
        });
        let spec = prepare_spec("table_lookup", None, &spec).unwrap();
        let out = run_experiment("table_lookup", &spec, 3, &mut |_| Control::Continue).unwrap();
        assert_eq!(out.metrics["y"], 5.0);
        let mut missing = spec.clone();
        missing["values"]["a"] = json!(1.5);
        let err = run_experiment("table_lookup", &missing, 3, &mut |_| Control::Continue);
        assert!(matches!(err, Err(ExperimentError::NoResult { .. })));
        let err = err.unwrap_err();
        assert!(err.is_permanent() && !err.another_seed_may_help());
    }
}
