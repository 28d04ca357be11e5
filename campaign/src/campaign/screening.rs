//! Stage 1, screening: which candidate factors matter. [`screen`] reads the first-order fit
//! and returns a [`ScreeningOutcome`]; the campaign then lays out the steepest path.

use repose_api::ModelName;
use repose_doe::Fit;

use super::model::{candidate_factors, observations, screening_fit, target_goal};
use super::outcome::{
    CarryRule, Decided, HeldFactor, ResponseEffects, RunCounts, ScreeningOutcome,
};
use super::{Campaign, Halt, Next, StageKind, StageResult};
use crate::error::CampaignError;
use crate::request::{CampaignRequest, CandidateFactor};

/// Reads one response's first-order fit.
fn response_effects(screened: &ScreeningFit, names: &[String], alpha: f64) -> ResponseEffects {
    let ScreeningFit {
        label: response,
        fit,
        runs,
    } = screened;
    let coefs: Vec<_> = names
        .iter()
        .map(|n| {
            fit.coefficient(n)
                .cloned()
                .expect("linear model has every factor")
        })
        .collect();
    let t_values: Vec<Option<f64>> = coefs.iter().map(|c| c.t_value).collect();
    let p_values: Vec<Option<f64>> = names
        .iter()
        .map(|n| fit.term_anova(n).and_then(|row| row.p))
        .collect();
    let abs_t = |i: usize| t_values[i].map_or(0.0, f64::abs);
    let mut by_t: Vec<usize> = (0..names.len()).collect();
    by_t.sort_by(|&a, &b| abs_t(b).total_cmp(&abs_t(a)));
    let significant = by_t
        .iter()
        .filter(|&&i| p_values[i].is_some_and(|p| p < alpha))
        .map(|&i| names[i].clone())
        .collect();
    ResponseEffects {
        response: response.to_owned(),
        estimates: coefs.iter().map(|c| c.estimate).collect(),
        t_critical: coefs
            .iter()
            .find(|c| c.std_error > 0.0)
            .map_or(f64::NAN, |c| (c.ci_high - c.estimate) / c.std_error),
        intercept: fit.coefficient("Intercept").map_or(0.0, |c| c.estimate),
        t_values,
        p_values,
        significant,
        counts: RunCounts {
            runs: *runs,
            runs_used: fit.n_runs(),
            residual_df: fit.residual_df(),
        },
    }
}

/// One target's screening fit: its label, the fit, and how many runs the stage issued for it.
pub(crate) struct ScreeningFit {
    pub label: String,
    pub fit: Fit,
    pub runs: usize,
}

/// Significance, carried and held factors from the screening fits, one per target. A factor is
/// significant if it is for any response, and ranks by its largest |t| over the responses.
pub(crate) fn screen(r: &CampaignRequest, fits: &[ScreeningFit]) -> ScreeningOutcome {
    let names: Vec<String> = r.factors.iter().map(|f| f.name.clone()).collect();
    let effects: Vec<ResponseEffects> = fits
        .iter()
        .map(|f| response_effects(f, &names, r.alpha))
        .collect();
    let abs_t = |i: usize| {
        effects
            .iter()
            .map(|e| e.t_values[i].map_or(0.0, f64::abs))
            .fold(0.0, f64::max)
    };
    let mut by_t: Vec<usize> = (0..names.len()).collect();
    by_t.sort_by(|&a, &b| abs_t(b).total_cmp(&abs_t(a)));
    let significant: Vec<usize> = by_t
        .iter()
        .copied()
        .filter(|&i| {
            effects
                .iter()
                .any(|e| e.p_values[i].is_some_and(|p| p < r.alpha))
        })
        .collect();
    let max = r.screening.max_factors;
    let (mut carried, rule) = if significant.is_empty() {
        let n = r.screening.fallback_factors.min(names.len());
        (by_t[..n].to_vec(), CarryRule::NoneSignificant)
    } else if significant.len() > max {
        (
            significant[..max].to_vec(),
            CarryRule::TopOfSignificant {
                dropped: significant[max..]
                    .iter()
                    .map(|&i| names[i].clone())
                    .collect(),
            },
        )
    } else {
        (significant.clone(), CarryRule::Significant)
    };
    carried.sort_unstable();
    let held: Vec<HeldFactor> = (0..names.len())
        .filter(|i| !carried.contains(i))
        .map(|i| HeldFactor {
            name: names[i].clone(),
            value: r.factors[i].hold_value(),
            user_value: r.factors[i].fixed_at.is_some(),
        })
        .collect();
    let first = effects[0].clone();
    ScreeningOutcome {
        factors: names.clone(),
        estimates: first.estimates,
        t_values: first.t_values,
        p_values: first.p_values,
        intercept: first.intercept,
        t_critical: first.t_critical,
        significant: significant.iter().map(|&i| names[i].clone()).collect(),
        carried: carried.iter().map(|&i| names[i].clone()).collect(),
        rule,
        held,
        counts: first.counts,
        responses: if effects.len() > 1 {
            effects
        } else {
            Vec::new()
        },
    }
}

impl Campaign {
    /// Issues the screening batch over every candidate.
    pub(super) fn start_screening(&mut self) -> Result<repose_api::BatchRequest, CampaignError> {
        let r = &self.request;
        let factors = r.factors.iter().map(CandidateFactor::spec).collect();
        let design = r.screening.design.clone();
        let replicates = r.screening.replicates;
        let names: Vec<String> = r.factors.iter().map(|f| f.name.clone()).collect();
        let (alpha, experiments) = (r.alpha, r.experiment_keys());
        self.record(
            StageKind::Screening,
            Decided::ScreeningPlan {
                factors: &names,
                design: &design,
                alpha,
                experiments: &experiments,
            },
        );
        self.issue_stage(
            StageKind::Screening,
            factors,
            design,
            replicates,
            ModelName::Linear,
            Vec::new(),
        )
    }

    /// `results`: the stage's batches, one per experiment in
    /// [`CampaignRequest::experiment_keys`] order.
    pub(super) fn after_screening(&mut self, results: &[StageResult]) -> Result<Next, Halt> {
        let mut fits = Vec::new();
        let mut goals = Vec::new();
        let names: Vec<String> = self
            .request
            .factors
            .iter()
            .map(|f| f.name.clone())
            .collect();
        for (target, finished) in self.results_by_target(results) {
            let fit = screening_fit(&self.request, &target, finished.batch, &finished.runs)?;
            let (_, y, _) = observations(finished.batch, &finished.runs, &names, &target.metric)?;
            goals.push(target_goal(target.value, &y));
            fits.push(ScreeningFit {
                label: target.label,
                fit,
                runs: finished.runs.len(),
            });
        }
        let outcome = screen(&self.request, &fits);
        self.record(
            StageKind::Screening,
            Decided::Screened {
                outcome: &outcome,
                alpha: self.request.alpha,
                max_factors: self.request.screening.max_factors,
            },
        );
        self.screening = Some(outcome.clone());
        let all = candidate_factors(&self.request);
        self.start_path(&outcome, &all, goals)
    }
}
