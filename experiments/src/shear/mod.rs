//! The direct shear test: a split steel box filled with the soil, consolidated under a
//! servo-controlled lid at each normal stress, sheared at constant speed; the peak and residual
//! shear stress of each stage and the Mohr-Coulomb line through them (cohesion and friction
//! angle, with the fit's quality).
//!
//! * [`ShearSpec`]: the experiment as serde data, presets, dotted-path `set`, `validate`.
//! * [`build_sample`] / [`sample_key`]: the settled sample (the drilling test's bed recipe,
//!   [`BedRecipe`](crate::soil::BedRecipe), in the closed box, a
//!   [`SettledBed`](crate::soil::SettledBed)) and the key under which a
//!   caller may cache it; [`run_shear_on_bed`] runs the stages on a cached sample,
//!   [`run_shear`] builds it and runs them (the same outcome bit for bit), on the CPU engine.
//!   Every stage starts from the same sample. [`ShearOn`] names a spec and an engine (the CPU
//!   or a GPU) for [`run_on_bed`](crate::soil::run_on_bed): the sample is settled and
//!   sheared there.
//! * [`ShearResult`] (serde; [`ShearResult::metrics`] for a job server) and the pictures
//!   [`ShearRun::curves_svg`] / [`ShearRun::strength_svg`].
//! * The measurement ([`shear_strength`], [`mohr_coulomb_fit`]): pure functions of a force
//!   record, tested on synthetic records.
//!
//! No file I/O here. See docs/shear.md.

mod experiment;
mod measure;
mod picture;
mod run;
mod spec;

pub use crate::backend::{PlaneStress, Window};
pub use experiment::Shear;
pub use measure::{
    mohr_coulomb_fit, running_mean, shear_strength, MohrCoulomb, ShearMeasureError, ShearPoint,
    ShearRecord, StrengthPoint,
};
pub use picture::{curves_svg, strength_svg};
pub use run::{
    build_sample, run_shear, run_shear_on_bed, sample_key, Control, Progress, ShearError, ShearOn,
    ShearResult, ShearRun, ShearSample, ShearStage, ShearStatus,
};
pub use spec::{
    BoxSpec, ConsolidationSpec, SampleSpec, ServoSpec, ShearMotionSpec, ShearSpec, SpecError,
    WindowSpec, PRESETS,
};
