//! The triaxial kind (`triaxial`) in the catalog: a kind on a settled bed ([`BedKind`]; its
//! bed is the prepared specimen), its finished run turned into metrics (or a failure) and its
//! pictures.

use super::run::{TriaxialOn, TriaxialRun, TriaxialStatus};
use super::spec::TriaxialSpec;
use crate::backend::Engine;
use crate::experiment::{BedKind, ExperimentError, Outcome};

/// The triaxial compression experiment.
#[derive(Debug, Clone, Copy)]
pub struct Triaxial;

impl BedKind for Triaxial {
    const NAME: &'static str = "triaxial";
    type Spec = TriaxialSpec;
    type Run = TriaxialRun;
    type On<'a> = TriaxialOn<'a>;

    fn on<'a>(spec: &'a TriaxialSpec, engine: Engine<'a>) -> TriaxialOn<'a> {
        TriaxialOn { spec, engine }
    }

    fn set_seed(spec: &mut TriaxialSpec, seed: u64) {
        spec.seed = seed;
    }

    /// A run whose specimen or stages did not settle is still measured; one with no envelope
    /// has no result.
    fn outcome(run: TriaxialRun, engine: Engine<'_>) -> Result<Outcome, ExperimentError> {
        // The records thinned: a job server takes at most 64 KiB of details.
        let details =
            serde_json::to_value(run.result.for_details()).expect("TriaxialResult serialises");
        if run.result.status == TriaxialStatus::MeasurementFailed {
            return Err(ExperimentError::no_result(
                format!(
                    "triaxial test gave no envelope: {}",
                    run.result.message.as_deref().unwrap_or("no fit")
                ),
                details,
            ));
        }
        Ok(Outcome {
            metrics: run.result.metrics(),
            details,
            pictures: vec![
                ("mohr_circles.svg".to_owned(), run.mohr_svg()),
                ("triaxial_curves.svg".to_owned(), run.curves_svg()),
                ("specimen.svg".to_owned(), run.specimen_svg()),
            ],
            hold_s: 0.0,
            engine_version: engine.engine_version(),
        })
    }
}
