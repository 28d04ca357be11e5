//! Evaluating a formula run: the condition, each response, and its seeded noise.

use std::collections::BTreeMap;

use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use rand_distr::{Distribution, Normal};
use serde_json::{json, Value};

use super::error::FormulaFailure;
use super::spec::FormulaSpec;
use crate::experiment::{start, CheckpointStore, Experiment, ExperimentError, Outcome};
use crate::progress::Control;
use crate::soil::BedStore;

/// A formula run's values.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// Each response's expression at the inputs.
    pub noise_free: BTreeMap<String, f64>,
    /// Each response's noise draw (0 where it has none).
    pub noise: BTreeMap<String, f64>,
    /// `noise_free + noise`: the run's metrics.
    pub metrics: BTreeMap<String, f64>,
}

/// The noise of `metric` for the run with `seed`: N(0, `sd`) from a ChaCha stream of its own
/// (the seed's stream numbered by the metric's name), so metrics draw independently of each
/// other and of which other metrics a spec has, and a seed always draws the same.
pub fn noise(seed: u64, metric: &str, sd: f64) -> f64 {
    if sd <= 0.0 {
        return 0.0;
    }
    let mut rng = ChaCha20Rng::seed_from_u64(seed);
    rng.set_stream(crate::fnv1a(metric.as_bytes()));
    match Normal::new(0.0, sd) {
        Ok(normal) => normal.sample(&mut rng),
        // A spec checks its standard deviations are finite and non-negative.
        Err(_) => f64::NAN,
    }
}

impl FormulaSpec {
    /// The run with `seed`: a failure if `fails_when` holds at the inputs or a response has no
    /// finite value there (both the same under every seed), else every response with its noise.
    pub fn evaluate(&self, seed: u64) -> Result<Evaluation, FormulaFailure> {
        let inputs = self.inputs();
        if let Some(condition) = self.fails_when() {
            let value = condition
                .eval(inputs)
                .map_err(|message| FormulaFailure::Evaluation {
                    field: "fails_when".into(),
                    expression: condition.source().to_owned(),
                    message,
                })?;
            if value != 0.0 {
                return Err(FormulaFailure::FailsWhen {
                    condition: condition.source().to_owned(),
                    inputs: inputs.clone(),
                });
            }
        }
        let mut evaluation = Evaluation {
            noise_free: BTreeMap::new(),
            noise: BTreeMap::new(),
            metrics: BTreeMap::new(),
        };
        for (metric, formula) in self.responses() {
            let field = format!("responses.{metric}");
            let value = formula
                .eval(inputs)
                .map_err(|message| FormulaFailure::Evaluation {
                    field: field.clone(),
                    expression: formula.source().to_owned(),
                    message,
                })?;
            if !value.is_finite() {
                return Err(FormulaFailure::NotFinite {
                    field,
                    expression: formula.source().to_owned(),
                    value,
                    inputs: inputs.clone(),
                });
            }
            let noise = noise(seed, metric, self.noise_sd(metric));
            evaluation.noise_free.insert(metric.clone(), value);
            evaluation.noise.insert(metric.clone(), noise);
            evaluation.metrics.insert(metric.clone(), value + noise);
        }
        Ok(evaluation)
    }
}

/// The `formula` kind: no presets, a spec is given whole.
#[derive(Debug, Clone, Copy)]
pub struct Formula;

impl Experiment for Formula {
    const NAME: &'static str = "formula";
    type Spec = FormulaSpec;

    fn parse(spec: &Value) -> Result<FormulaSpec, ExperimentError> {
        FormulaSpec::from_json(spec).map_err(|e| ExperimentError::invalid_spec(&e))
    }

    /// Every response with its noise, or no result where the formula fails (under any seed).
    fn run(
        spec: FormulaSpec,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        _beds: &mut dyn BedStore,
        _checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        start(progress)?;
        let evaluation = spec.evaluate(seed)?;
        Ok(Outcome {
            details: json!({
                "inputs": spec.inputs(),
                "noise_free": evaluation.noise_free,
                "noise": evaluation.noise,
            }),
            metrics: evaluation.metrics,
            pictures: Vec::new(),
            hold_s: 0.0,
            // A test aid runs no engine; it answers for this build's.
            engine_version: crate::ENGINE_VERSION.to_owned(),
        })
    }
}
