//! What every experiment kind is to the catalog: what it reports ([`Outcome`],
//! [`ExperimentError`]), the checkpoint store a run may use ([`CheckpointStore`]; settled beds
//! have [`BedStore`]), the [`Experiment`] trait each kind implements in its own folder, and
//! [`BedKind`], the shorter form of it for a kind that runs on a settled bed.
//!
//! A leaf module: the kinds import it, it imports no kind (the catalog's registry, above them
//! all, names them and puts them behind one interface).

use std::collections::BTreeMap;
use std::time::Duration;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::backend::{BackendError, BackendKind, Engine};
use crate::progress::Control;
use crate::soil::{run_on_bed, BedStore, OnBed, OnBedError};
use crate::Spec;

/// One experiment kind, implemented in the kind's own folder: its spec, presets, parsing and
/// checking, the run, and the keys under which a run keeps what outlives it. The catalog
/// dispatches to it with one line per kind.
pub trait Experiment {
    /// The name a job gives (the registry's name for the kind).
    const NAME: &'static str;
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

    /// The engines that run every spec of this kind. A kind that names another than the CPU
    /// overrides [`Experiment::run_on`].
    const BACKENDS: &'static [BackendKind] = &[BackendKind::Cpu];

    /// Ok if the `backend` engine runs `spec`; else why not, naming what it does not simulate
    /// ([`ExperimentError::Unsupported`]). The default: the engines of
    /// [`Experiment::BACKENDS`].
    fn check_backend(_spec: &Self::Spec, backend: BackendKind) -> Result<(), ExperimentError> {
        if Self::BACKENDS.contains(&backend) {
            Ok(())
        } else {
            Err(ExperimentError::not_on(Self::NAME, Self::BACKENDS, backend))
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
            Engine::Gpu(_) => Err(ExperimentError::not_on(
                Self::NAME,
                Self::BACKENDS,
                engine.kind(),
            )),
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

/// A kind that runs on a settled bed (the drilling, shear and triaxial tests): it writes what
/// differs (its spec, its run on an engine as an [`OnBed`], how a finished run reads) and is an
/// [`Experiment`] through the impl below: the run's seed written into the spec, the bed built
/// or reused ([`run_on_bed`]), the run's errors mapped once ([`ExperimentError::on_bed`]), the
/// CPU run and the bed key.
pub trait BedKind {
    /// The name a job gives.
    const NAME: &'static str;
    /// The engines that run every spec of the kind.
    const BACKENDS: &'static [BackendKind] = &[BackendKind::Cpu, BackendKind::Gpu];
    /// The kind's spec (its presets and checks are the [`Spec`]'s).
    type Spec: Spec;
    /// A finished run.
    type Run;
    /// The spec on an engine: how it names, builds and runs on its bed.
    type On<'a>: OnBed<Run = Self::Run, Error = OnBedError>
    where
        Self: 'a;

    /// `spec` run on `engine`.
    fn on<'a>(spec: &'a Self::Spec, engine: Engine<'a>) -> Self::On<'a>;

    /// Writes the run's seed into `spec`.
    fn set_seed(spec: &mut Self::Spec, seed: u64);

    /// The outcome of a finished run on `engine`: its metrics, details and pictures, or why
    /// it gave no result.
    fn outcome(run: Self::Run, engine: Engine<'_>) -> Result<Outcome, ExperimentError>;
}

impl<K: BedKind> Experiment for K {
    const NAME: &'static str = K::NAME;
    type Spec = K::Spec;
    const PRESETS: &'static [&'static str] = <K::Spec as Spec>::PRESETS;
    const BACKENDS: &'static [BackendKind] = K::BACKENDS;

    fn preset(name: &str) -> Option<K::Spec> {
        <K::Spec as Spec>::preset(name).ok()
    }

    fn parse(spec: &Value) -> Result<K::Spec, ExperimentError> {
        parse_spec(K::NAME, spec, <K::Spec as Spec>::validate)
    }

    /// The bed is taken from `beds` when it holds one of this key, else built (in the first
    /// part of the progress, [`OnBed::BED_SHARE`]) and kept there ([`run_on_bed`]). The
    /// outcome is the same, bit for bit, whether the bed was built or reused
    /// (`details.bed.reused` says which).
    fn run(
        spec: K::Spec,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        Self::run_on(spec, seed, Engine::Cpu, progress, beds, checkpoints)
    }

    /// [`Experiment::run`] on `engine`: the bed is settled on that engine too, and kept under
    /// its own key (a GPU bed's ends in `-gpu`), so a run never uses another engine's bed. A
    /// GPU failure during the run is this machine's ([`ExperimentError::Local`]). No
    /// checkpoints.
    fn run_on(
        mut spec: K::Spec,
        seed: u64,
        engine: Engine<'_>,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        _checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        K::set_seed(&mut spec, seed);
        let run = run_on_bed(&K::on(&spec, engine), beds, &mut |p| progress(p.fraction))
            .map_err(|e| ExperimentError::on_bed(engine.kind(), e))?;
        K::outcome(run, engine)
    }

    /// The key of the bed the CPU run with `seed` uses (a GPU run's ends in `-gpu`).
    fn bed_key(spec: &K::Spec, seed: u64) -> Option<String> {
        let mut spec = spec.clone();
        K::set_seed(&mut spec, seed);
        let key = K::on(&spec, Engine::Cpu).bed_key();
        Some(key)
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
    kind: &str,
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
    /// Not one of the registry's kinds (`known`, the catalog's `KINDS`).
    #[error("unknown experiment kind {kind:?} (kinds: {})", known.join(", "))]
    UnknownKind {
        kind: String,
        known: &'static [&'static str],
    },
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

    /// The kind `kind`, which runs on the engines `runs_on` only, asked to run on `backend`.
    pub fn not_on(kind: &str, runs_on: &[BackendKind], backend: BackendKind) -> ExperimentError {
        let engines: Vec<&str> = runs_on.iter().map(|b| b.label()).collect();
        let only = if engines.len() == 1 { " only" } else { "" };
        ExperimentError::Unsupported {
            backend,
            message: format!(
                "the `{kind}` experiment runs on the {} backend{only}, not the {} backend",
                engines.join(" and "),
                backend.label()
            ),
        }
    }

    /// A run on a settled bed that could not start or failed on `backend`: cancelled; what
    /// the backend does not simulate, or a GPU failure ([`ExperimentError::on_backend`]);
    /// else a spec the run refuses (no field named).
    pub fn on_bed(backend: BackendKind, e: OnBedError) -> ExperimentError {
        let message = e.to_string();
        match e {
            OnBedError::Cancelled => ExperimentError::Cancelled,
            OnBedError::Backend(b) => ExperimentError::on_backend(backend, b, message),
            other => ExperimentError::refused(&other),
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
