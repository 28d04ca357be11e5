//! The direct shear test's measurement: the peak and residual shear stress of each shear
//! record, and the Mohr-Coulomb line through them (cohesion and friction angle, with the fit's
//! quality). Pure functions of the recorded forces, so they are tested on synthetic records.
//!
//! The simulated test (the split box, its filling, consolidation and shearing) is not here yet:
//! see docs/shear.md.

mod measure;

pub use measure::{
    mohr_coulomb_fit, shear_strength, MohrCoulomb, ShearMeasureError, ShearPoint, ShearRecord,
    StrengthPoint,
};
