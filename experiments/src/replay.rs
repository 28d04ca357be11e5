//! The `table_lookup` experiment kind: a **replay and test aid**, not a simulation.
//!
//! Its spec holds a table of already-measured runs (e.g. the paper's Tables 3, 5 and 6) and
//! the factor values of the run to "perform"; the result is the matching row's responses. It
//! lets a whole calibration campaign, or the job server's plumbing, be exercised in seconds
//! with known answers. When several rows match (replicated centre points), the run's seed picks
//! one, so a replicate gets a different row as a real re-run would give a different value.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::experiment::{
    parse_spec, start, CheckpointStore, Experiment, ExperimentError, InvalidField, Outcome,
};
use crate::progress::Control;
use crate::soil::BedStore;

/// Why a replay spec is unusable or has no row for the requested values.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReplayError {
    /// A field has an impossible value.
    #[error("{path}: {reason}")]
    Invalid { path: String, reason: String },
    /// No row matches the requested values.
    #[error("table_lookup has no row matching {values}")]
    NoMatch { values: String },
}

/// A table of known results and the factor values to look up.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplaySpec {
    /// The run's factor values (a batch writes its factors here, e.g. `values.N2`).
    pub values: BTreeMap<String, f64>,
    /// Known runs: factor columns plus response columns.
    pub rows: Vec<BTreeMap<String, f64>>,
    /// Two values match when they differ by at most this much (absolute).
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    /// Seconds a worker holds the job before reporting (to emulate simulation time in tests).
    #[serde(default)]
    pub hold_s: f64,
    /// Seconds the run blocks its thread without reporting progress and without heeding a
    /// cancel, as a simulation stuck in a GPU driver does (to test a worker's stall watchdog).
    #[serde(default)]
    pub stall_s: f64,
}

fn default_tolerance() -> f64 {
    1e-6
}

impl ReplaySpec {
    /// Checks the table is usable: rows exist, every requested value is a column, numbers are finite.
    pub fn validate(&self) -> Result<(), ReplayError> {
        let invalid = |path: &str, reason: &str| ReplayError::Invalid {
            path: path.into(),
            reason: reason.into(),
        };
        if self.rows.is_empty() {
            return Err(invalid("rows", "must hold at least one row"));
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return Err(invalid("tolerance", "must be a non-negative number"));
        }
        if !(self.hold_s.is_finite() && (0.0..=3600.0).contains(&self.hold_s)) {
            return Err(invalid("hold_s", "must be between 0 and 3600 s"));
        }
        if !(self.stall_s.is_finite() && (0.0..=3600.0).contains(&self.stall_s)) {
            return Err(invalid("stall_s", "must be between 0 and 3600 s"));
        }
        for (name, value) in &self.values {
            if !value.is_finite() {
                return Err(invalid(
                    &format!("values.{name}"),
                    "must be a finite number",
                ));
            }
            if self.rows.iter().all(|row| !row.contains_key(name)) {
                return Err(invalid(
                    &format!("values.{name}"),
                    "no row of the table has this column",
                ));
            }
        }
        Ok(())
    }

    /// The responses of the row matching `values` (every column not among `values`); among
    /// several matching rows the one at `seed mod count`.
    pub fn look_up(&self, seed: u64) -> Result<BTreeMap<String, f64>, ReplayError> {
        let matches: Vec<&BTreeMap<String, f64>> = self
            .rows
            .iter()
            .filter(|row| {
                self.values.iter().all(|(name, want)| {
                    row.get(name)
                        .is_some_and(|have| (have - want).abs() <= self.tolerance)
                })
            })
            .collect();
        if matches.is_empty() {
            return Err(ReplayError::NoMatch {
                values: format!("{:?}", self.values),
            });
        }
        let row = matches[(seed % matches.len() as u64) as usize];
        Ok(row
            .iter()
            .filter(|(name, _)| !self.values.contains_key(*name))
            .map(|(name, value)| (name.clone(), *value))
            .collect())
    }
}

impl InvalidField for ReplayError {
    fn path(&self) -> Option<&str> {
        match self {
            ReplayError::Invalid { path, .. } => Some(path),
            ReplayError::NoMatch { .. } => None,
        }
    }
}

/// The `table_lookup` kind: no presets, a spec is given whole.
#[derive(Debug, Clone, Copy)]
pub struct TableLookup;

impl Experiment for TableLookup {
    const NAME: &'static str = "table_lookup";
    type Spec = ReplaySpec;

    fn parse(spec: &Value) -> Result<ReplaySpec, ExperimentError> {
        parse_spec(Self::NAME, spec, ReplaySpec::validate)
    }

    /// The matching row's responses; no row matching is no result (under any seed).
    fn run(
        spec: ReplaySpec,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        _beds: &mut dyn BedStore,
        _checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        start(progress)?;
        std::thread::sleep(std::time::Duration::from_secs_f64(spec.stall_s));
        let metrics = spec
            .look_up(seed)
            .map_err(|e| ExperimentError::no_result(e.to_string(), Value::Null))?;
        Ok(Outcome {
            details: serde_json::json!({ "replay": true, "values": spec.values }),
            metrics,
            pictures: Vec::new(),
            hold_s: spec.hold_s,
            // A test aid runs no engine; it answers for this build's.
            engine_version: crate::ENGINE_VERSION.to_owned(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(values: &[(&str, f64)]) -> ReplaySpec {
        let row = |a: f64, y: f64| BTreeMap::from([("a".to_owned(), a), ("y".to_owned(), y)]);
        ReplaySpec {
            values: values.iter().map(|(k, v)| ((*k).to_owned(), *v)).collect(),
            rows: vec![row(0.0, 10.0), row(1.0, 20.0), row(0.0, 12.0)],
            tolerance: 1e-9,
            hold_s: 0.0,
            stall_s: 0.0,
        }
    }

    #[test]
    fn replicated_rows_are_chosen_by_seed() {
        let s = spec(&[("a", 0.0)]);
        assert_eq!(s.look_up(0).unwrap()["y"], 10.0);
        assert_eq!(s.look_up(1).unwrap()["y"], 12.0);
        assert_eq!(
            s.look_up(1).unwrap().len(),
            1,
            "factor columns are not responses"
        );
    }

    #[test]
    fn unknown_columns_and_misses_are_errors() {
        assert!(matches!(
            spec(&[("b", 0.0)]).validate(),
            Err(ReplayError::Invalid { path, .. }) if path == "values.b"
        ));
        assert!(matches!(
            spec(&[("a", 0.5)]).look_up(0),
            Err(ReplayError::NoMatch { .. })
        ));
    }
}
