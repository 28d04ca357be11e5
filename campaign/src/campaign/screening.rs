//! Stage 1, screening: which candidate factors matter. [`screen`] reads the first-order fit
//! and returns a [`ScreeningOutcome`]; the campaign then lays out the steepest path.

use repose_api::ModelName;
use repose_doe::Fit;
use serde::{Deserialize, Serialize};

use super::model::{candidate_factors, observations, screening_fit, target_goal};
use super::{wording, Campaign, Halt, Next, StageKind, StageResult};
use crate::error::CampaignError;
use crate::request::{CampaignRequest, CandidateFactor};

/// Why factors were carried forward from screening.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "rule", rename_all = "snake_case")]
pub enum CarryRule {
    /// Exactly the significant factors.
    Significant,
    /// More were significant than `max_factors`; the largest |t| were kept.
    TopOfSignificant {
        /// Significant factors not carried.
        dropped: Vec<String>,
    },
    /// None was significant; the largest |t| were carried anyway.
    NoneSignificant,
}

/// A factor held constant after screening.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeldFactor {
    /// Factor name.
    pub name: String,
    /// Value written into the spec.
    pub value: f64,
    /// Whether the value was the user's `fixed_at` (else mid-range).
    pub user_value: bool,
}

/// Stage 1 outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScreeningOutcome {
    /// All candidate factors, in request order.
    pub factors: Vec<String>,
    /// Coded first-order coefficients.
    pub estimates: Vec<f64>,
    /// t values (standardized effects).
    pub t_values: Vec<Option<f64>>,
    /// p values.
    pub p_values: Vec<Option<f64>>,
    /// Intercept (prediction at the centre).
    pub intercept: f64,
    /// Two-sided critical t at `alpha` with the residual degrees of freedom.
    pub t_critical: f64,
    /// Factors with p < alpha, largest |t| first.
    pub significant: Vec<String>,
    /// Factors carried to the next stages, in request order.
    pub carried: Vec<String>,
    /// Why those.
    pub rule: CarryRule,
    /// The others and their values.
    pub held: Vec<HeldFactor>,
    /// The first target's run counts.
    #[serde(flatten)]
    pub counts: RunCounts,
    /// Several targets: each response's own effects (the fields above are the first
    /// target's; `significant`, `carried` and `rule` are over all responses).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub responses: Vec<ResponseEffects>,
}

/// One response's screening effects (several-targets form).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResponseEffects {
    /// `<experiment>.<metric>`.
    pub response: String,
    /// Coded first-order coefficients, in candidate order.
    pub estimates: Vec<f64>,
    /// t values.
    pub t_values: Vec<Option<f64>>,
    /// p values.
    pub p_values: Vec<Option<f64>>,
    /// Prediction at the centre.
    pub intercept: f64,
    /// Two-sided critical t.
    pub t_critical: f64,
    /// Factors with p < alpha for this response, largest |t| first.
    pub significant: Vec<String>,
    /// How many runs the fit rests on.
    #[serde(flatten)]
    pub counts: RunCounts,
}

/// How many runs a response's screening fit rests on (all 0 in campaigns stored before these
/// fields existed).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct RunCounts {
    /// Runs the stage issued for the response's experiment.
    #[serde(default)]
    pub runs: usize,
    /// Runs that gave the response a value (the others failed, e.g. a funnel that arched).
    #[serde(default)]
    pub runs_used: usize,
    /// The fit's residual degrees of freedom: what is left to judge significance with.
    #[serde(default)]
    pub residual_df: usize,
}

impl ResponseEffects {
    /// Reads one response's first-order fit.
    fn of(screened: &ScreeningFit, names: &[String], alpha: f64) -> ResponseEffects {
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
        .map(|f| ResponseEffects::of(f, &names, r.alpha))
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
        let text = wording::screening_plan(&names, &design, r.alpha, &r.experiment_keys());
        self.decide(StageKind::Screening, text);
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
        self.decide(
            StageKind::Screening,
            wording::screening(
                &outcome,
                self.request.alpha,
                self.request.screening.max_factors,
            ),
        );
        self.screening = Some(outcome.clone());
        let all = candidate_factors(&self.request);
        self.start_path(&outcome, &all, goals)
    }
}
