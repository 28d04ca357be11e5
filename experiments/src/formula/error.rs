//! What can go wrong with a formula: a spec that cannot be used (named by its field), and a run
//! that gives no measurement (the same under every seed: a closed form has no chance in it).

use std::collections::BTreeMap;

use serde_json::{json, Value};

use crate::experiment::{ExperimentError, InvalidField};

/// Why a formula spec cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FormulaError {
    /// The field at `path` (dotted, within the spec) is unusable.
    #[error("{path}: {reason}")]
    Invalid { path: String, reason: String },
}

impl InvalidField for FormulaError {
    /// The field's path; none for the document itself (its path is empty).
    fn path(&self) -> Option<&str> {
        match self {
            FormulaError::Invalid { path, .. } => Some(path.as_str()).filter(|p| !p.is_empty()),
        }
    }
}

/// Why a formula run gave no measurement.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FormulaFailure {
    /// The failure condition holds at the run's inputs.
    #[error("fails_when holds: `{condition}` at {}", show(inputs))]
    FailsWhen {
        condition: String,
        inputs: BTreeMap<String, f64>,
    },
    /// A response (`field` `responses.<metric>`) has no finite value at the inputs.
    #[error(
        "{field} is {value} at {}: `{expression}` has no finite value there",
        show(inputs)
    )]
    NotFinite {
        field: String,
        expression: String,
        value: f64,
        inputs: BTreeMap<String, f64>,
    },
    /// The expression crate could not evaluate the expression.
    #[error("{field}: cannot evaluate `{expression}`: {message}")]
    Evaluation {
        field: String,
        expression: String,
        message: String,
    },
}

fn show(inputs: &BTreeMap<String, f64>) -> String {
    let pairs: Vec<String> = inputs.iter().map(|(k, v)| format!("{k} = {v}")).collect();
    pairs.join(", ")
}

impl FormulaFailure {
    /// The failure as a run's result document.
    pub fn details(&self) -> Value {
        match self {
            FormulaFailure::FailsWhen { condition, inputs } => {
                json!({"failure": "fails_when", "condition": condition, "inputs": inputs})
            }
            FormulaFailure::NotFinite {
                field,
                expression,
                inputs,
                ..
            } => json!({"failure": "not_finite", "field": field, "expression": expression,
                        "inputs": inputs}),
            FormulaFailure::Evaluation {
                field,
                expression,
                message,
            } => json!({"failure": "evaluation", "field": field, "expression": expression,
                        "message": message}),
        }
    }
}

impl From<FormulaFailure> for ExperimentError {
    /// Permanent: the same inputs fail under every seed, so a job server does not reseed it.
    fn from(failure: FormulaFailure) -> ExperimentError {
        ExperimentError::no_result(failure.to_string(), failure.details())
    }
}
