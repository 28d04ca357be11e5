//! The drilling kind (`drill`) in the catalog: the bed built or taken from the store, the hole
//! drilled, its result turned into metrics (or a failure), its pictures.

use serde_json::Value;

use super::bed::bed_key;
use super::run::{DrillError, DrillOn, DrillStatus};
use super::spec::{DrillSpec, PRESETS};
use crate::backend::{BackendKind, Engine};
use crate::experiment::{parse_spec, CheckpointStore, Experiment, ExperimentError, Kind, Outcome};
use crate::progress::Control;
use crate::soil::{run_on_bed, BedStore};
use crate::Spec;

/// The drilling experiment.
#[derive(Debug, Clone, Copy)]
pub struct Drill;

impl Experiment for Drill {
    const KIND: Kind = Kind::Drill;
    type Spec = DrillSpec;
    const PRESETS: &'static [&'static str] = &PRESETS;

    fn preset(name: &str) -> Option<DrillSpec> {
        <DrillSpec as Spec>::preset(name).ok()
    }

    fn parse(spec: &Value) -> Result<DrillSpec, ExperimentError> {
        parse_spec(Kind::Drill, spec, DrillSpec::validate)
    }

    /// The bed is taken from `beds` when it holds one of this key, else built (in the first
    /// quarter of the progress) and kept there ([`run_on_bed`]). The outcome is the same, bit
    /// for bit, whether the bed was built or reused (`details.bed.reused` says which).
    fn run(
        spec: DrillSpec,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        Drill::run_on(spec, seed, Engine::Cpu, progress, beds, checkpoints)
    }

    /// Both engines run every drilling spec (every contact law).
    const RUNS_ON_GPU: bool = true;

    /// [`Experiment::run`] on `engine`: the bed is settled on that engine too, and kept under
    /// its own key (a GPU bed's ends in `-gpu`), so a run never drills another engine's bed. A
    /// GPU failure during the run is this machine's ([`ExperimentError::Local`]).
    fn run_on(
        mut spec: DrillSpec,
        seed: u64,
        engine: Engine<'_>,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        _checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        spec.seed = seed;
        let on = DrillOn {
            spec: &spec,
            engine,
        };
        let run = run_on_bed(&on, beds, &mut |p| progress(p.fraction))
            .map_err(|e| run_error(engine.kind(), e))?;
        let details = serde_json::to_value(&run.result).expect("DrillResult serialises");
        match run.result.status {
            DrillStatus::Ok | DrillStatus::NotSettled => {}
            DrillStatus::Cancelled => return Err(ExperimentError::Cancelled),
            status => {
                return Err(ExperimentError::no_result(
                    format!(
                        "drilling run ended {status:?}: {}",
                        run.result.message.as_deref().unwrap_or("no hole measured")
                    ),
                    details,
                ))
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
            engine_version: engine.engine_version(),
        })
    }

    /// [`bed_key`] of the spec with the run's seed (on the CPU; a GPU run's ends in `-gpu`).
    fn bed_key(spec: &DrillSpec, seed: u64) -> Option<String> {
        let mut spec = spec.clone();
        spec.seed = seed;
        Some(bed_key(&spec))
    }
}

/// A run that could not start or failed on `backend`: cancelled; what the backend does not
/// simulate, or a GPU failure ([`ExperimentError::on_backend`]); else a spec the run refuses
/// (no field named).
fn run_error(backend: BackendKind, e: DrillError) -> ExperimentError {
    let message = e.to_string();
    match e {
        DrillError::Cancelled => ExperimentError::Cancelled,
        DrillError::Backend(b) => ExperimentError::on_backend(backend, b, message),
        other => ExperimentError::refused(&other),
    }
}
