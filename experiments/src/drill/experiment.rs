//! The drilling kind (`drill`) in the catalog: the bed built or taken from the store, the hole
//! drilled, its result turned into metrics (or a failure), its pictures.

use serde_json::Value;

use super::bed::bed_key;
use super::run::{DrillError, DrillStatus};
use super::spec::{DrillSpec, PRESETS};
use crate::backend::Engine;
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
        mut spec: DrillSpec,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        _checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        spec.seed = seed;
        let run = run_on_bed(&spec, beds, &mut |p| progress(p.fraction))?;
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
            engine_version: Engine::Cpu.engine_version(),
        })
    }

    /// [`bed_key`] of the spec with the run's seed.
    fn bed_key(spec: &DrillSpec, seed: u64) -> Option<String> {
        let mut spec = spec.clone();
        spec.seed = seed;
        Some(bed_key(&spec))
    }
}

/// A run that cannot start or report: cancelled, or a spec the run refuses (no field named).
impl From<DrillError> for ExperimentError {
    fn from(e: DrillError) -> ExperimentError {
        match e {
            DrillError::Cancelled => ExperimentError::Cancelled,
            other => ExperimentError::refused(&other),
        }
    }
}
