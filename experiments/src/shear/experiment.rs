//! The direct shear kind (`shear`) in the catalog: the sample built or taken from the store,
//! the stages sheared, the result turned into metrics (or a failure), its pictures.

use serde_json::Value;

use super::run::{ShearError, ShearOn, ShearStatus};
use super::spec::{ShearSpec, PRESETS};
use crate::backend::{BackendKind, Engine};
use crate::experiment::{parse_spec, CheckpointStore, Experiment, ExperimentError, Kind, Outcome};
use crate::progress::Control;
use crate::soil::{run_on_bed, BedStore};
use crate::Spec;

/// The direct shear experiment.
#[derive(Debug, Clone, Copy)]
pub struct Shear;

impl Experiment for Shear {
    const KIND: Kind = Kind::Shear;
    type Spec = ShearSpec;
    const PRESETS: &'static [&'static str] = &PRESETS;

    fn preset(name: &str) -> Option<ShearSpec> {
        <ShearSpec as Spec>::preset(name).ok()
    }

    fn parse(spec: &Value) -> Result<ShearSpec, ExperimentError> {
        parse_spec(Kind::Shear, spec, ShearSpec::validate)
    }

    /// The sample is taken from `beds` when it holds one of this key, else built (in the first
    /// fifth of the progress) and kept there ([`run_on_bed`]). The outcome is the same, bit
    /// for bit, whether the sample was built or reused (`details.bed.reused` says which).
    fn run(
        spec: ShearSpec,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        Shear::run_on(spec, seed, Engine::Cpu, progress, beds, checkpoints)
    }

    /// Both engines run every shear spec (every contact law).
    const RUNS_ON_GPU: bool = true;

    /// [`Experiment::run`] on `engine`: the sample is settled on that engine too, and kept
    /// under its own key (a GPU sample's ends in `-gpu`), so a run never shears another
    /// engine's sample. A GPU failure during the run is this machine's
    /// ([`ExperimentError::Local`]).
    fn run_on(
        mut spec: ShearSpec,
        seed: u64,
        engine: Engine<'_>,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        _checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        spec.seed = seed;
        let on = ShearOn {
            spec: &spec,
            engine,
        };
        let run = run_on_bed(&on, beds, &mut |p| progress(p.fraction))
            .map_err(|e| run_error(engine.kind(), e))?;
        // The series thinned: a job server takes at most 64 KiB of details.
        let details =
            serde_json::to_value(run.result.for_details()).expect("ShearResult serialises");
        if run.result.status == ShearStatus::MeasurementFailed {
            return Err(ExperimentError::no_result(
                format!(
                    "shear test gave no strength: {}",
                    run.result.message.as_deref().unwrap_or("no fit")
                ),
                details,
            ));
        }
        Ok(Outcome {
            metrics: run.result.metrics(),
            details,
            pictures: vec![
                ("shear_curves.svg".to_owned(), run.curves_svg()),
                ("mohr_coulomb.svg".to_owned(), run.strength_svg()),
            ],
            hold_s: 0.0,
            engine_version: engine.engine_version(),
        })
    }

    /// [`sample_key`](super::sample_key) of the spec with the run's seed (on the CPU; a GPU
    /// run's ends in `-gpu`).
    fn bed_key(spec: &ShearSpec, seed: u64) -> Option<String> {
        let mut spec = spec.clone();
        spec.seed = seed;
        Some(super::sample_key(&spec))
    }
}

/// A run that could not start or failed on `backend`: cancelled; what the backend does not
/// simulate, or a GPU failure ([`ExperimentError::on_backend`]); else a spec the run refuses
/// (no field named).
fn run_error(backend: BackendKind, e: ShearError) -> ExperimentError {
    let message = e.to_string();
    match e {
        ShearError::Cancelled => ExperimentError::Cancelled,
        ShearError::Backend(b) => ExperimentError::on_backend(backend, b, message),
        other => ExperimentError::refused(&other),
    }
}
