//! What every experiment kind is to the catalog: its name ([`Kind`]), what it reports
//! ([`Outcome`], [`ExperimentError`]), the checkpoint store a run may use
//! ([`CheckpointStore`]; settled beds have [`BedStore`]) and the [`Experiment`] trait each
//! kind implements in its own folder.
//!
//! A leaf module: the kinds import it, it imports no kind (the catalog, above them all, puts
//! them behind one interface).

use std::collections::BTreeMap;
use std::time::Duration;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::backend::{BackendError, BackendKind, Engine};
use crate::progress::Control;
use crate::soil::BedStore;

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

/// Names of the kinds a job may give (`Kind::ALL`'s names).
pub const KINDS: [&str; 5] = ["aor", "drill", "shear", "table_lookup", "formula"];

/// One experiment kind, implemented in the kind's own folder: its spec, presets, parsing and
/// checking, the run, and the keys under which a run keeps what outlives it. The catalog
/// dispatches to it with one line per kind.
pub trait Experiment {
    /// The kind this is.
    const KIND: Kind;
    /// The kind's spec, as a job carries it (its JSON form is what a job server stores).
    type Spec: Serialize;
    /// The presets [`Experiment::preset`] offers, the default first; empty (the default):
    /// none, a job gives the spec whole.
    const PRESETS: &'static [&'static str] = &[];

    /// The preset called `name` (one of [`Experiment::PRESETS`] or an alias of one), if any.
    fn preset(_name: &str) -> Option<Self::Spec> {
        None
    }

    /// Parses and checks a complete spec document; the error names the offending field where
    /// it can ([`parse_spec`] does this for a serde spec with a `validate`).
    fn parse(spec: &Value) -> Result<Self::Spec, ExperimentError>;

    /// Runs `spec` with `seed` (overriding any seed in it). `progress` receives the fraction
    /// done (0..1) and may cancel; settled beds come from and go to `beds`, checkpoints to
    /// `checkpoints` (kinds that keep none ignore them).
    fn run(
        spec: Self::Spec,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError>;

    /// Whether the GPU engine runs every spec of this kind. A kind that says so overrides
    /// [`Experiment::run_on`].
    const RUNS_ON_GPU: bool = false;

    /// Ok if the `backend` engine runs `spec`; else why not, naming what it does not simulate
    /// ([`ExperimentError::Unsupported`]). The default: the CPU engine, and the GPU's for a
    /// kind that [runs on it](Experiment::RUNS_ON_GPU).
    fn check_backend(_spec: &Self::Spec, backend: BackendKind) -> Result<(), ExperimentError> {
        match backend {
            BackendKind::Cpu => Ok(()),
            BackendKind::Gpu if Self::RUNS_ON_GPU => Ok(()),
            other => Err(ExperimentError::cpu_only(Self::KIND, other)),
        }
    }

    /// [`Experiment::run`] on `engine`. The default runs on the CPU engine only and refuses
    /// any other ([`Experiment::check_backend`]'s refusal): never a silent run on the CPU.
    fn run_on(
        spec: Self::Spec,
        seed: u64,
        engine: Engine<'_>,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        match engine {
            Engine::Cpu => Self::run(spec, seed, progress, beds, checkpoints),
            Engine::Gpu(_) => Err(ExperimentError::cpu_only(Self::KIND, engine.kind())),
        }
    }

    /// The key of the settled bed the run with `seed` builds or reuses, for a kind that runs
    /// on one.
    fn bed_key(_spec: &Self::Spec, _seed: u64) -> Option<String> {
        None
    }

    /// The key under which the run with `seed` keeps its checkpoint, for a kind that keeps
    /// checkpoints.
    fn checkpoint_key(_spec: &Self::Spec, _seed: u64) -> Option<String> {
        None
    }
}

/// `Err(Cancelled)` if `progress`, told that the run starts, cancels it: the first thing a
/// kind that runs in an instant does.
pub fn start(progress: &mut dyn FnMut(f64) -> Control) -> Result<(), ExperimentError> {
    match progress(0.0) {
        Control::Continue => Ok(()),
        Control::Cancel => Err(ExperimentError::Cancelled),
    }
}

/// A spec's own error that may name the offending field (its dotted path within the spec).
pub trait InvalidField: std::fmt::Display {
    /// The field's dotted path, when the error names one.
    fn path(&self) -> Option<&str>;
}

/// The spec of `kind` in `spec`: deserialised, then checked by `validate`. Either failure is an
/// [`ExperimentError::InvalidSpec`] (with the field's path where `validate` names it).
pub fn parse_spec<S, E>(
    kind: Kind,
    spec: &Value,
    validate: impl FnOnce(&S) -> Result<(), E>,
) -> Result<S, ExperimentError>
where
    S: DeserializeOwned,
    E: InvalidField,
{
    let parsed: S =
        serde_json::from_value(spec.clone()).map_err(|e| ExperimentError::InvalidSpec {
            path: None,
            message: format!("not a valid {kind} spec: {e}"),
        })?;
    validate(&parsed).map_err(|e| ExperimentError::invalid_spec(&e))?;
    Ok(parsed)
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
    /// The spec cannot run on the engine the job names: the kind runs on the CPU only, or the
    /// `backend` engine does not simulate part of the spec (named). Permanent: no worker's
    /// engine of that kind runs it.
    #[error("{message}")]
    Unsupported {
        backend: BackendKind,
        message: String,
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
    /// [`ExperimentError::InvalidSpec`] for a spec's own error, with the field's path.
    /// A run the spec refused when it started, naming no field (its message says why).
    pub fn refused(e: &impl std::fmt::Display) -> ExperimentError {
        ExperimentError::InvalidSpec {
            path: None,
            message: e.to_string(),
        }
    }

    /// A kind that runs on the CPU engine only, asked to run on `backend`.
    pub fn cpu_only(kind: Kind, backend: BackendKind) -> ExperimentError {
        ExperimentError::Unsupported {
            backend,
            message: format!(
                "the `{kind}` experiment runs on the CPU backend only, not the {} backend",
                backend.label()
            ),
        }
    }

    /// A run on `backend` that it refused or that failed there: what the backend does not
    /// simulate is [`ExperimentError::Unsupported`] (with `message`, the run's own wording),
    /// a GPU failure this machine's ([`ExperimentError::Local`]), so the job may run again.
    pub fn on_backend(backend: BackendKind, e: BackendError, message: String) -> ExperimentError {
        match e {
            BackendError::Unsupported { .. } => ExperimentError::Unsupported { backend, message },
            BackendError::Gpu(failure) => ExperimentError::Local {
                message: format!("the {} backend failed: {failure}", backend.label()),
            },
        }
    }

    /// A run that gave no result, and would give none under another seed either.
    pub fn no_result(message: String, details: Value) -> ExperimentError {
        ExperimentError::NoResult {
            message,
            details,
            another_seed_may_help: false,
        }
    }

    pub fn invalid_spec(e: &impl InvalidField) -> ExperimentError {
        ExperimentError::InvalidSpec {
            path: e.path().map(str::to_owned),
            message: e.to_string(),
        }
    }

    /// Whether running the same spec again anywhere gives the same failure (a bad spec, or a
    /// run that gives no result): a job server should then not retry it. An unknown kind or
    /// preset met when running is this machine's catalog lacking it (a worker of another
    /// build may have it), so it is not permanent; at submission the server refuses both.
    pub fn is_permanent(&self) -> bool {
        // (A failure another seed may cure is permanent for this seed all the same.)
        match self {
            ExperimentError::InvalidSpec { .. }
            | ExperimentError::NoResult { .. }
            | ExperimentError::Unsupported { .. } => true,
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
    /// The engine that computed it, for provenance: the CPU engine's version, or
    /// `<version>+gpu:<adapter>` ([`Engine::engine_version`]).
    pub engine_version: String,
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
