//! The drilling kind (`drill`) in the catalog: a kind on a settled bed ([`BedKind`]), its
//! finished run turned into metrics (or a failure) and its pictures.

use super::run::{DrillOn, DrillRun, DrillStatus};
use super::spec::DrillSpec;
use crate::backend::Engine;
use crate::experiment::{BedKind, ExperimentError, Outcome};

/// The drilling experiment.
#[derive(Debug, Clone, Copy)]
pub struct Drill;

impl BedKind for Drill {
    const NAME: &'static str = "drill";
    type Spec = DrillSpec;
    type Run = DrillRun;
    type On<'a> = DrillOn<'a>;

    fn on<'a>(spec: &'a DrillSpec, engine: Engine<'a>) -> DrillOn<'a> {
        DrillOn { spec, engine }
    }

    fn set_seed(spec: &mut DrillSpec, seed: u64) {
        spec.seed = seed;
    }

    /// A run whose bed or soil did not settle is still measured; a run that ended otherwise
    /// (no hole measured, the wall-time cap) has no result.
    fn outcome(run: DrillRun, engine: Engine<'_>) -> Result<Outcome, ExperimentError> {
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
}
