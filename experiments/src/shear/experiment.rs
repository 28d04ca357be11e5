//! The direct shear kind (`shear`) in the catalog: a kind on a settled bed ([`BedKind`]; its
//! bed is the sample poured into the box), its finished run turned into metrics (or a
//! failure) and its pictures.

use super::run::{ShearOn, ShearRun, ShearStatus};
use super::spec::ShearSpec;
use crate::backend::Engine;
use crate::experiment::{BedKind, ExperimentError, Outcome};

/// The direct shear experiment.
#[derive(Debug, Clone, Copy)]
pub struct Shear;

impl BedKind for Shear {
    const NAME: &'static str = "shear";
    type Spec = ShearSpec;
    type Run = ShearRun;
    type On<'a> = ShearOn<'a>;

    fn on<'a>(spec: &'a ShearSpec, engine: Engine<'a>) -> ShearOn<'a> {
        ShearOn { spec, engine }
    }

    fn set_seed(spec: &mut ShearSpec, seed: u64) {
        spec.seed = seed;
    }

    /// A run whose stages did not all consolidate is still measured; one with no
    /// Mohr-Coulomb fit has no result.
    fn outcome(run: ShearRun, engine: Engine<'_>) -> Result<Outcome, ExperimentError> {
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
}
