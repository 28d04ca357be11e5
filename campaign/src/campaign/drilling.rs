//! Stage 6 (optional), the drilling validation: the drilling experiment at the calibrated
//! parameters, each measured hole metric against the simulated mean ([`compare`]).

use repose_api::{DesignRequest, FactorSpec, ModelName, RunState, RunView};

use super::model::set_path;
use super::outcome::{Decided, DrillMetric, DrillingOutcome};
use super::{Campaign, Halt, Next, StageKind, StageResult};
use crate::error::CampaignError;
use crate::request::{relative_error_pct, DrillingValidation};

/// Each measured metric against the mean of the completed runs.
pub(crate) fn compare(drilling: &DrillingValidation, runs: &[RunView]) -> DrillingOutcome {
    let mut metrics = Vec::new();
    for (name, measured) in &drilling.measured {
        let values: Vec<f64> = runs
            .iter()
            .filter(|r| r.status == RunState::Completed)
            .filter_map(|r| r.metrics.as_ref().and_then(|m| m.get(name)).copied())
            .filter(|v| v.is_finite())
            .collect();
        let simulated =
            (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64);
        let err = simulated.map(|s| relative_error_pct(s, *measured));
        metrics.push(DrillMetric {
            name: name.clone(),
            measured: *measured,
            simulated,
            relative_error_pct: err,
            within_tolerance: err.is_some_and(|e| e <= drilling.tolerance_pct),
        });
    }
    let passed = metrics.iter().all(|m| m.within_tolerance);
    DrillingOutcome { metrics, passed }
}

impl Campaign {
    /// Issues the drilling batch at the last optimum (verified, or the most desirable setting
    /// found when verification gave up: then [`Campaign::unverified`] is set).
    pub(super) fn start_drilling(&mut self) -> Result<Next, Halt> {
        let drilling = self.request.drilling.clone().expect("drilling requested");
        let round = self.surfaces.last().expect("round").clone();
        let optimum = round.optimum.clone().expect("optimum");
        let path_of = |name: &str| -> String {
            drilling.paths.get(name).cloned().unwrap_or_else(|| {
                self.request
                    .factors
                    .iter()
                    .find(|f| f.name == name)
                    .map(|f| f.path.clone())
                    .unwrap_or_default()
            })
        };
        let mut template = drilling.experiment.clone();
        if let Some(s) = &self.screening {
            for h in &s.held {
                set_path(&mut template.spec, &path_of(&h.name), h.value).map_err(|reason| {
                    CampaignError::InvalidRequest {
                        field: format!("drilling.paths.{}", h.name),
                        reason,
                    }
                })?;
            }
        }
        let specs: Vec<FactorSpec> = round
            .factors
            .iter()
            .map(|f| FactorSpec {
                name: f.name.clone(),
                path: Some(path_of(&f.name)),
                low: f.low,
                high: f.high,
            })
            .collect();
        self.record(
            StageKind::Drilling,
            Decided::DrillingPlanned {
                drilling: &drilling,
                unverified: self.unverified.is_some(),
            },
        );
        Ok(Next::Submit(self.issue(
            StageKind::Drilling,
            String::new(),
            template,
            specs,
            DesignRequest::Explicit {
                points: vec![optimum.natural],
            },
            drilling.replicates,
            ModelName::None,
            Vec::new(),
        )))
    }

    pub(super) fn after_drilling(&mut self, finished: &StageResult) -> Result<Next, Halt> {
        let drilling = self.request.drilling.as_ref().expect("drilling requested");
        let outcome = compare(drilling, &finished.runs);
        self.record(
            StageKind::Drilling,
            Decided::Drilled {
                outcome: &outcome,
                several_targets: self.request.is_multi(),
                unverified: self.unverified.is_some(),
            },
        );
        self.drilling = Some(outcome);
        match self.unverified.take() {
            // Validated at a setting verification did not accept: the campaign still stops.
            Some(reason) => Ok(self.stop_with(reason)),
            None => Ok(self.finish()),
        }
    }
}
