//! The drained triaxial compression test, the paper's own strength test (TSZ-2 apparatus,
//! "Triaxial compression test", Eqs. 1-2): a specimen between six servo-controlled rigid walls
//! (as YADE's `TriaxialStressController` and LIGGGHTS' servo walls), consolidated
//! isotropically to each confining pressure and loaded axially at a constant strain rate while
//! the lateral walls hold the pressure; the Mohr-Coulomb envelope of the failure circles gives
//! c and φ, the stress-strain curve E and ν. docs/triaxial.md says what each choice follows.
//!
//! * [`TriaxialSpec`]: the experiment as serde data, presets, dotted-path `set`, `validate`.
//! * [`TriaxialOn`]: the spec on an engine, a kind on a settled bed ([`crate::soil::OnBed`]):
//!   its bed is the prepared specimen, cached under [`specimen_key`]; every stage starts from
//!   a copy of it.
//! * [`TriaxialResult`] (serde; [`TriaxialResult::metrics`] for a job server), the readings
//!   ([`measure`]) and the pictures.
//!
//! No file I/O here: the specimen and the pictures are returned as data and text.

mod experiment;
pub mod measure;
mod picture;
mod rig;
mod run;
mod spec;

pub use crate::progress::{Control, Progress};
pub use experiment::Triaxial;
pub use measure::{Envelope, Failure, Stiffness, TriaxialSample};
pub use picture::{curves_svg, mohr_svg, specimen_svg, PAPER_COHESION_KPA, PAPER_FRICTION_DEG};
pub use run::{
    specimen_key, TriaxialError, TriaxialOn, TriaxialResult, TriaxialRun, TriaxialStage,
    TriaxialStatus,
};
pub use spec::{
    LoadingSpec, PreparationSpec, SpecError, SpecimenSpec, TriaxialConsolidationSpec,
    TriaxialServoSpec, TriaxialSpec, PRESETS,
};

/// Runs `spec` on the CPU engine without a specimen store (prepares the specimen, then every
/// stage).
pub fn run_triaxial(
    spec: &TriaxialSpec,
    progress: &mut dyn FnMut(crate::progress::Progress<'_>) -> crate::progress::Control,
) -> Result<TriaxialRun, TriaxialError> {
    crate::soil::run_on_bed(
        &TriaxialOn::cpu(spec),
        &mut crate::soil::NoBedStore,
        progress,
    )
}
