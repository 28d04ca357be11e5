//! Design of experiments and response-surface statistics.
pub mod design;

// Regression, ANOVA, diagnostics and optimum search (fit half of the crate).
pub mod anova;
pub mod diagnostics;
pub mod error;
pub mod fit;
pub mod model;
pub mod optimum;
pub mod report;
mod stats;

pub use anova::{AnovaRow, AnovaSource, FitStats};
pub use diagnostics::RunDiagnostics;
pub use error::{Alias, FitError, OptimumError};
pub use fit::{fit, fit_design, fit_with_options, Coefficient, EliminationStep, Fit, FitOptions};
pub use model::{Model, ModelKind, Term};
pub use optimum::{
    optimize, Goal, Objective, OptimumOptions, OptimumResult, PredictedResponse, Region, Solution,
};
