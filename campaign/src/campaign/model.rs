//! What every stage needs from the runs and the statistics: observations of a batch, coded ↔
//! natural values, the screening and quadratic fits, the desirability search, and writing a
//! value into a spec. No decisions and no sentences live here.

use repose_api::{RunState, RunView};
use repose_doe::design::Factor;
use repose_doe::{
    fit_with_options, optimize, Fit, FitOptions, Goal, Model, ModelKind, Objective, OptimumOptions,
    OptimumResult, Region,
};
use serde_json::Value;

use super::outcome::{ModelRole, Stop, SurfaceRound};
use super::Halt;
use crate::error::CampaignError;
use crate::request::{CampaignRequest, Target};

/// Natural factor values, responses and design rows of the completed runs.
pub(crate) type Observations = (Vec<Vec<f64>>, Vec<f64>, Vec<u32>);

/// Completed runs as (natural values of `names`, response, design row).
pub(crate) fn observations(
    batch: usize,
    runs: &[RunView],
    names: &[String],
    response: &str,
) -> Result<Observations, CampaignError> {
    let mut x = Vec::new();
    let mut y = Vec::new();
    let mut rows = Vec::new();
    for run in runs {
        if run.status != RunState::Completed {
            continue;
        }
        let Some(value) = run.metrics.as_ref().and_then(|m| m.get(response)).copied() else {
            continue;
        };
        if !value.is_finite() {
            continue;
        }
        let mut point = Vec::with_capacity(names.len());
        for name in names {
            let f = run
                .factors
                .iter()
                .find(|f| &f.name == name)
                .ok_or_else(|| CampaignError::MissingFactor {
                    batch,
                    run: run.run_index,
                    factor: name.clone(),
                })?;
            point.push(f.natural);
        }
        x.push(point);
        y.push(value);
        rows.push(run.design_row);
    }
    Ok((x, y, rows))
}

pub(crate) fn coded(factors: &[Factor], natural: &[f64]) -> Vec<f64> {
    factors
        .iter()
        .zip(natural)
        .map(|(f, v)| (v - f.centre()) / f.half_range())
        .collect()
}

/// Coded → natural in the weighted form of `Factor::to_natural`, so that coded ±1 land exactly
/// on `low`/`high` (`centre + c·half_range` gives 0.29999999999999993 for 0.3, which a clamp to
/// the allowed range then rejects).
pub(crate) fn natural(factors: &[Factor], coded: &[f64]) -> Vec<f64> {
    factors
        .iter()
        .zip(coded)
        .map(|(f, c)| 0.5 * ((1.0 - c) * f.low + (1.0 + c) * f.high))
        .collect()
}

/// Writes `value` at a dotted path, creating objects on the way (a spec override need not
/// hold the key yet; merged over a preset it lands where the factor path points): the
/// workspace's one walker, `repose_api::locate_mut`, in its `CreateObjects` mode.
pub(crate) fn set_path(spec: &mut Value, path: &str, value: f64) -> Result<(), String> {
    let slot = repose_api::locate_mut(spec, path, repose_api::PathMode::CreateObjects)
        .map_err(|e| e.to_string())?;
    *slot = repose_api::spec_path::number(value);
    Ok(())
}

/// Fits the first-order screening model over all candidates.
/// Fits the first-order screening model of one target over all candidates.
pub(crate) fn screening_fit(
    request: &CampaignRequest,
    target: &Target,
    batch: usize,
    runs: &[RunView],
) -> Result<Fit, Halt> {
    let names: Vec<String> = request.factors.iter().map(|f| f.name.clone()).collect();
    let factors = candidate_factors(request);
    let (x, y, _) = observations(batch, runs, &names, &target.metric)?;
    let coded_rows: Vec<Vec<f64>> = x.iter().map(|p| coded(&factors, p)).collect();
    let model = Model::linear(&names).map_err(|e| Stop::ModelUnavailable(e.to_string()))?;
    let options = FitOptions {
        response_name: target.label.clone(),
        confidence: 1.0 - request.alpha,
        backward_alpha: None,
    };
    fit_with_options(&model, &coded_rows, &y, &options).map_err(|e| {
        Halt::Stop(Stop::FitFailed {
            model: ModelRole::Screening,
            runs: y.len(),
            reason: e.to_string(),
        })
    })
}

/// Fits the quadratic model of one target in a response-surface round.
pub(crate) fn surface_fit(
    request: &CampaignRequest,
    target: &Target,
    round: &SurfaceRound,
    batch: usize,
    runs: &[RunView],
) -> Result<Fit, Halt> {
    let names: Vec<String> = round.factors.iter().map(|f| f.name.clone()).collect();
    let (x, y, _) = observations(batch, runs, &names, &target.metric)?;
    let coded_rows: Vec<Vec<f64>> = x.iter().map(|p| coded(&round.factors, p)).collect();
    let model = Model::new(&names, ModelKind::Quadratic)
        .map_err(|e| Stop::ModelUnavailable(e.to_string()))?;
    let options = FitOptions {
        response_name: target.label.clone(),
        confidence: 1.0 - request.alpha,
        backward_alpha: None,
    };
    fit_with_options(&model, &coded_rows, &y, &options).map_err(|e| {
        Halt::Stop(Stop::FitFailed {
            model: ModelRole::Quadratic,
            runs: y.len(),
            reason: e.to_string(),
        })
    })
}

pub(crate) fn candidate_factors(request: &CampaignRequest) -> Vec<Factor> {
    request
        .factors
        .iter()
        .map(|f| Factor {
            name: f.name.clone(),
            low: f.low,
            high: f.high,
        })
        .collect()
}

/// A target's desirability goal, as `repose analyze` sets it: desirability 1 at the target,
/// falling to 0 at the observed range widened by 5 % (and to include the target).
pub(crate) fn target_goal(target: f64, observed: &[f64]) -> Goal {
    let (min, max) = observed
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| {
            (a.min(y), b.max(y))
        });
    let span = (max - min).max(f64::EPSILON);
    Goal::Target {
        target,
        lower: min.min(target) - 0.05 * span,
        upper: max.max(target) + 0.05 * span,
    }
}

/// The desirability search on fitted surfaces, one objective per target (`goals[i]` for
/// `fits[i]`): the overall desirability is their geometric mean (Derringer–Suich).
pub(crate) fn search_targets(
    fits: &[&Fit],
    goals: &[Goal],
    factors: &[Factor],
    region: Region,
    starts: usize,
) -> Result<OptimumResult, String> {
    let options = OptimumOptions {
        region,
        starts,
        factor_ranges: Some(factors.to_vec()),
        ..OptimumOptions::default()
    };
    let objectives: Vec<Objective> = fits
        .iter()
        .zip(goals)
        .map(|(fit, goal)| Objective::new(fit, goal.clone()))
        .collect();
    optimize(&objectives, &options).map_err(|e| e.to_string())
}

/// A goal's desirability of `y` (weights 1).
pub(crate) fn desirability(goal: &Goal, y: f64) -> f64 {
    goal.desirability(y, 1.0, 1.0)
}

/// Geometric mean of the desirabilities (0 if any is 0).
pub(crate) fn overall(d: &[f64]) -> f64 {
    if d.iter().any(|v| *v <= 0.0) || d.is_empty() {
        return 0.0;
    }
    (d.iter().map(|v| v.ln()).sum::<f64>() / d.len() as f64).exp()
}

#[cfg(test)]
mod natural_tests {
    use super::*;

    #[test]
    fn coded_corners_are_exactly_the_range_ends() {
        // 0.45 + (-1)(0.15) is 0.29999999999999993 in floating point; the corner must be 0.3.
        let factors = vec![Factor::new("mu_w", 0.3, 0.6).unwrap()];
        assert_eq!(natural(&factors, &[-1.0]), vec![0.3]);
        assert_eq!(natural(&factors, &[1.0]), vec![0.6]);
    }
}
