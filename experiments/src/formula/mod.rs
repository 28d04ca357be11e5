//! The `formula` experiment kind: a **test aid**, not a simulation. Each response is a closed
//! form over the spec's inputs, plus Gaussian noise drawn from the run's seed, so calibration
//! strategies can be compared in seconds where the answer is known:
//!
//! ```json
//! {"inputs": {"mu_s": 0.5, "mu_r": 0.1},
//!  "responses": {"angle_deg": "22 + 30*tanh(4*mu_r) + 8*(mu_s - 0.44)"},
//!  "noise_sd": {"angle_deg": 0.8},
//!  "fails_when": "mu_r > 0.3 && mu_s > 0.6"}
//! ```
//!
//! A batch's factors write into `inputs.<name>`; the run's metrics are the keys of
//! `responses`. Expressions know `+ - * / ^`, parentheses and the functions of
//! [`expr::FUNCTIONS`]; `fails_when` also knows `< <= > >= == != && ||`. Expressions are parsed
//! and compiled once, when the spec is, and a name that is not an input is an error naming the
//! field. A run where `fails_when` holds, or whose response has no finite value, gives no result
//! under any seed. No presets.

mod error;
pub mod expr;
mod run;
mod spec;

pub use error::{FormulaError, FormulaFailure};
pub use run::{noise, Evaluation, Formula};
pub use spec::FormulaSpec;

#[cfg(test)]
mod tests;
