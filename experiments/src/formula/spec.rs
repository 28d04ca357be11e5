//! The formula spec: inputs, one expression per response, optional noise and failure
//! condition. Parsed and compiled once ([`FormulaSpec::from_json`]); its JSON form is the
//! document it was parsed from.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize, Serializer};
use serde_json::Value;

use super::error::FormulaError;
use super::expr::{Expression, Grammar, FUNCTIONS};

/// The document as a job carries it (expressions as text).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FormulaDoc {
    inputs: BTreeMap<String, f64>,
    responses: BTreeMap<String, String>,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    noise_sd: BTreeMap<String, f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fails_when: Option<String>,
}

/// A closed-form experiment: each response an expression over the inputs (a batch's factors
/// write into `inputs.<name>`), plus Gaussian noise of `noise_sd` drawn from the run's seed;
/// where `fails_when` holds the run gives no result.
///
/// Every identifier of every expression is an input (checked when parsed), so evaluating never
/// meets an unknown name.
#[derive(Debug, Clone, PartialEq)]
pub struct FormulaSpec {
    inputs: BTreeMap<String, f64>,
    responses: BTreeMap<String, Expression>,
    noise_sd: BTreeMap<String, f64>,
    fails_when: Option<Expression>,
}

/// A name an input or a response may have: an identifier (`[A-Za-z_][A-Za-z0-9_]*`).
fn is_identifier(name: &str) -> bool {
    let mut chars = name.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

fn invalid(path: impl Into<String>, reason: impl Into<String>) -> FormulaError {
    FormulaError::Invalid {
        path: path.into(),
        reason: reason.into(),
    }
}

impl FormulaSpec {
    /// Parses, checks and compiles a spec document; the error names the offending field
    /// (e.g. `responses.angle_deg: unknown variable 'mu_x' …`).
    pub fn from_json(spec: &Value) -> Result<FormulaSpec, FormulaError> {
        let doc: FormulaDoc = serde_path_to_error::deserialize(spec).map_err(|e| {
            let path = e.path().to_string();
            let reason = format!("not a valid formula spec: {}", e.inner());
            // serde_path_to_error names the document itself ".".
            invalid(if path == "." { String::new() } else { path }, reason)
        })?;
        FormulaSpec::from_doc(doc)
    }

    fn from_doc(doc: FormulaDoc) -> Result<FormulaSpec, FormulaError> {
        for (name, value) in &doc.inputs {
            let path = format!("inputs.{name}");
            if !is_identifier(name) {
                return Err(invalid(
                    path,
                    "an input's name must be an identifier (letters, digits, _; not starting with a digit)",
                ));
            }
            if FUNCTIONS.contains(&name.as_str()) {
                return Err(invalid(
                    path,
                    format!(
                        "'{name}' is a function's name (functions: {})",
                        FUNCTIONS.join(", ")
                    ),
                ));
            }
            if !value.is_finite() {
                return Err(invalid(path, "must be a finite number"));
            }
        }
        if doc.responses.is_empty() {
            return Err(invalid(
                "responses",
                "must name at least one response and its expression",
            ));
        }
        let mut responses = BTreeMap::new();
        for (metric, source) in &doc.responses {
            let path = format!("responses.{metric}");
            if !is_identifier(metric) {
                return Err(invalid(
                    path,
                    "a response's name must be an identifier (letters, digits, _; not starting with a digit)",
                ));
            }
            responses.insert(
                metric.clone(),
                Expression::compile(source, &path, Grammar::Response, &doc.inputs)?,
            );
        }
        for (metric, sd) in &doc.noise_sd {
            let path = format!("noise_sd.{metric}");
            if !doc.responses.contains_key(metric) {
                let names: Vec<&str> = doc.responses.keys().map(String::as_str).collect();
                return Err(invalid(
                    path,
                    format!("not a response (responses: {})", names.join(", ")),
                ));
            }
            if !(sd.is_finite() && *sd >= 0.0) {
                return Err(invalid(
                    path,
                    "must be a non-negative number (a standard deviation)",
                ));
            }
        }
        let fails_when = doc
            .fails_when
            .as_deref()
            .map(|source| {
                Expression::compile(source, "fails_when", Grammar::Condition, &doc.inputs)
            })
            .transpose()?;
        Ok(FormulaSpec {
            inputs: doc.inputs,
            responses,
            noise_sd: doc.noise_sd,
            fails_when,
        })
    }

    fn to_doc(&self) -> FormulaDoc {
        FormulaDoc {
            inputs: self.inputs.clone(),
            responses: self
                .responses
                .iter()
                .map(|(metric, formula)| (metric.clone(), formula.source().to_owned()))
                .collect(),
            noise_sd: self.noise_sd.clone(),
            fails_when: self.fails_when.as_ref().map(|c| c.source().to_owned()),
        }
    }

    /// The inputs' values.
    pub fn inputs(&self) -> &BTreeMap<String, f64> {
        &self.inputs
    }

    /// The responses (the run's metrics) and their expressions.
    pub fn responses(&self) -> &BTreeMap<String, Expression> {
        &self.responses
    }

    /// The standard deviation of `metric`'s noise (0 where none is given).
    pub fn noise_sd(&self, metric: &str) -> f64 {
        self.noise_sd.get(metric).copied().unwrap_or(0.0)
    }

    /// The failure condition, if any.
    pub fn fails_when(&self) -> Option<&Expression> {
        self.fails_when.as_ref()
    }
}

impl Serialize for FormulaSpec {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.to_doc().serialize(serializer)
    }
}
