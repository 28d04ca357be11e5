//! The Bayesian strategy (`"strategy": {"type": "bayesian", ...}`): every candidate factor at
//! once over its whole range, a space-filling start, then rounds of `batch_size` points chosen
//! where every target is most likely met, until the best point is likely enough to be verified.
//!
//! - `design`: the maximin Latin hypercube start and the candidate points of a proposal;
//! - `surrogate`: one Gaussian process per response, over the factors written into its own
//!   experiment, and one for feasibility (the `friedrich` crate; an anisotropic kernel with
//!   length-scales bounded by what the runs resolve, inputs in `[0, 1]`, outputs standardised,
//!   noise estimated), and each factor's total-effect share of a response's variation;
//! - `acquisition`: the probability that every target's verified mean lands within tolerance,
//!   the feasibility probability that multiplies it, and the exploration term (the same
//!   probability at an optimistic mean);
//! - `edge`: whether the runs that met a target the surrogates put out of reach lie only at an
//!   edge of the factor box;
//! - `assess` (here): the round's assessment (best point, each target alone and all together,
//!   conflicts, out of reach or met only at an edge), the batch by kriging believer with its
//!   exploring points, the region, the Pareto front;
//! - `wording`: the sentences of the decision log.
//!
//! Every experiment the targets need runs the same points; a round's batches are issued
//! together and the round is decided when the last has finished. Failed runs (dead, or without
//! a target's metric) mark their point infeasible. All randomness comes from the campaign seed
//! and the round, and the state holds every observation, so a campaign resumed from its stored
//! JSON decides exactly as an uninterrupted one.

mod acquisition;
mod design;
mod edge;
mod surrogate;
mod wording;

use std::collections::BTreeMap;

use repose_api::{BatchRequest, DesignRequest, FactorSpec, ModelName, RunState};
use serde::{Deserialize, Serialize};

use super::drilling::compare;
use super::model::set_path;
use super::outcome::Decided;
use super::{
    wording as chain_wording, CalibratedValue, Campaign, ResponseCheck, StageKind, StageResult,
    Status, Step, Summary,
};
use crate::error::CampaignError;
use crate::request::{
    relative_error_pct, BayesianSettings, CandidateFactor, StageTemplate, Target,
};
use acquisition::{ln_p_feasible, ln_p_within, ln_p_within_optimistic, misfit, Band};
use surrogate::{Prediction, Smoothness, Surrogate};

/// Seed of the campaign's own draws when the request gives none.
const DEFAULT_SEED: u64 = 0x5EED_BA7E;
/// Purposes of the random streams (see [`design::rng`]).
const PURPOSE_START: u64 = 1;
const PURPOSE_CANDIDATES: u64 = 2;
const PURPOSE_REGION: u64 = 3;
const PURPOSE_FILL: u64 = 4;
/// Fewest values of a response before its surrogate is fitted.
const MIN_VALUES: usize = 3;
/// Consecutive assessments in conflict before the campaign stops on it.
const CONFLICT_ROUNDS: u32 = 2;
/// A target counts as reachable alone when some point meets it with this probability.
const REACHABLE_ALONE: f64 = 0.5;
/// Consecutive assessments with a target out of reach alone before the campaign stops on it.
const OUT_OF_REACH_ROUNDS: u32 = 2;
/// Points kept in the reported region.
const REGION_POINTS: usize = 300;
/// Candidates scored for the region.
const REGION_CANDIDATES: usize = 4000;

/// The Bayesian strategy's state, stored with the campaign.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BayesState {
    /// Rounds issued (the start design is round 0).
    pub round: u32,
    /// Simulations issued so far (every experiment's runs and the verification replicates).
    pub simulations: usize,
    /// Batches of the current round still running.
    pub waiting: Vec<usize>,
    /// Batches of the current round already finished.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub received: Vec<StageResult>,
    /// Every simulated point (one per design row and replicate), in the order they came in.
    pub observations: Vec<Observation>,
    /// Every verification, in order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub verifications: Vec<BayesVerification>,
    /// Best joint misfit of the observed points against the simulations spent.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub convergence: Vec<ConvergencePoint>,
    /// The latest round's assessment.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub assessment: Option<Assessment>,
    /// Consecutive assessments that found the targets in conflict.
    #[serde(default)]
    pub conflict_rounds: u32,
    /// Consecutive assessments that found some target out of reach alone.
    #[serde(default)]
    pub out_of_reach_rounds: u32,
    /// The verified point the drilling validation runs at.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drilling_point: Option<Vec<f64>>,
    /// The responses named as conflicting by a stop that waits for the drilling validation at
    /// the compromise ([`Campaign::unverified`] holds the stop's reason meanwhile).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub stop_conflict: Vec<String>,
    /// The responses named as out of reach by such a stop.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub stop_out_of_reach: Vec<String>,
}

/// One simulated point: its setting and what each target's experiment measured there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    /// Every candidate factor's value (natural units, request order).
    pub point: Vec<f64>,
    /// Round it was issued in.
    pub round: u32,
    /// Start design, search round or verification.
    pub stage: StageKind,
    /// Each target's value (by label) where its run completed.
    pub values: BTreeMap<String, f64>,
    /// Why the point failed (a dead run, or a run without a target's metric).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failed: Option<String>,
}

/// One entry of the convergence history.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ConvergencePoint {
    /// Simulations issued when the round was decided.
    pub simulations: usize,
    /// Smallest `Σ ((mean − target) / half-width)²` over the observed points (the mean over a
    /// point's replicates); `None` before any point has every target's value.
    pub best_misfit: Option<f64>,
}

/// What the surrogates said after a round.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Assessment {
    /// Round assessed.
    pub round: u32,
    /// The point most likely to verify (natural units).
    pub best: Vec<f64>,
    /// Its probability that every target's verified mean lands within tolerance, feasibility
    /// included.
    pub probability: f64,
    /// Each target's predicted value there, in target order.
    pub predicted: Vec<f64>,
    /// Each target alone: the highest probability of meeting it (feasibility included)
    /// anywhere among the candidates.
    pub alone: Vec<f64>,
    /// Pairs of targets (labels) that are each reachable but not together.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub conflicts: Vec<(String, String)>,
    /// Targets (labels) that no candidate meets even alone with probability 0.5, and no run
    /// met within its noise at an edge of the box.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub out_of_reach: Vec<String>,
    /// Targets that no candidate meets alone with probability 0.5 but runs met within their
    /// noise, only at an edge of the box: not out of reach.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub at_edge: Vec<EdgeReach>,
    /// Each response's factor influences.
    pub influences: Vec<Influence>,
}

/// One end of a factor's range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Edge {
    /// Factor name.
    pub factor: String,
    /// The high end (else the low one).
    pub high: bool,
    /// The end's value (natural units).
    pub value: f64,
}

/// A target met only at the edge of the factor box: the runs that met it within their noise
/// all lie at these edges, and the surrogates put it out of reach alone inside the box.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EdgeReach {
    /// Target label.
    pub response: String,
    /// The edges (the factors whose trend points out of the box there, or every edge the runs
    /// share where none does).
    pub edges: Vec<Edge>,
    /// Runs that met it: within the band or within two noise standard deviations of it.
    pub runs: usize,
    /// The estimated run noise that "within" used (response units).
    pub noise_sd: f64,
    /// The closest run's value.
    pub closest: f64,
    /// Its setting (natural units).
    pub point: Vec<f64>,
}

/// How strongly each factor moves one response under its surrogate. A factor that the
/// response's experiment is not given has no length-scale and no share: the surrogate does not
/// range over it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Influence {
    /// Target label.
    pub response: String,
    /// Fitted length-scale of each factor (fraction of its range; long = little influence);
    /// `None` for a factor not written into the response's experiment.
    pub length_scales: Vec<Option<f64>>,
    /// Each factor's share of the variation of the surrogate's mean over the box: its
    /// total-effect (Sobol) index, normalised to sum to 1 (every share 0 where the mean is
    /// flat, and for a factor not written into the response's experiment).
    pub share: Vec<f64>,
    /// Estimated standard deviation of one run's noise, in response units.
    pub noise_sd: f64,
    /// The shortest length-scale the response's data support (see `surrogate`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_length_scale: Option<f64>,
    /// The part of one run's variance over the box that the factors explain, the rest being
    /// run noise: `Var(mean) / (Var(mean) + noise_sd²)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub explained: Option<f64>,
}

/// One verification of the Bayesian strategy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BayesVerification {
    /// Round it ran in.
    pub round: u32,
    /// Setting (natural units).
    pub point: Vec<f64>,
    /// The surrogates' probability that it would pass.
    pub probability: f64,
    /// Each target's check.
    pub checks: Vec<ResponseCheck>,
    /// Replicates that failed.
    pub failed_runs: usize,
    /// Every target within its tolerance and no replicate failed.
    pub within_tolerance: bool,
}

/// The answer as a region, with what a reader needs to trust it; in the campaign's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BayesianResult {
    /// Factor names, the order of every point below.
    pub factors: Vec<String>,
    /// Settings consistent with every measurement under the surrogates.
    pub region: Region,
    /// Each response's factor influences.
    pub influences: Vec<Influence>,
    /// Best joint misfit against simulations.
    pub convergence: Vec<ConvergencePoint>,
    /// The trade-off between the targets: the observed points no other beats on every
    /// target's misfit `|mean − target| / half-width`.
    pub pareto: Vec<ParetoPoint>,
    /// Points whose runs failed.
    pub infeasible: Vec<InfeasiblePoint>,
    /// Targets found in conflict (labels); empty when none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub conflict: Vec<String>,
    /// Targets found out of reach in the factor box even alone (labels); empty when none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub out_of_reach: Vec<String>,
    /// Targets met only at the edge of the factor box (a campaign that ended without a
    /// verified calibration); empty when none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub at_edge: Vec<EdgeReach>,
}

/// The region of settings consistent with every measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Region {
    /// A point belongs when its probability of meeting every target (feasibility included)
    /// is at least this.
    pub threshold: f64,
    /// Sampled members (natural units), at most a few hundred.
    pub points: Vec<Vec<f64>>,
    /// Each factor's `[min, max]` over the members (empty when none).
    pub extent: Vec<(f64, f64)>,
    /// Share of the box's uniform sample that belongs.
    pub fraction: f64,
    /// The result's own probability under the same surrogates (its setting: the verified one,
    /// or the best observed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_result: Option<f64>,
}

/// A non-dominated observed point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParetoPoint {
    /// Setting (natural units).
    pub point: Vec<f64>,
    /// Each target's misfit `|mean − target| / half-width` (≤ 1 within tolerance).
    pub misfits: Vec<f64>,
}

/// A point whose runs failed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InfeasiblePoint {
    /// Setting (natural units).
    pub point: Vec<f64>,
    /// Why.
    pub reason: String,
}

/// A round's points (natural units): those aimed at every target together, then those that
/// explore, each with the targets it explores for (empty: all of them).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Proposal {
    pub exploit: Vec<Vec<f64>>,
    pub explore: Vec<(Vec<String>, Vec<f64>)>,
}

/// How a Bayesian campaign ends without a verified calibration.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum BayesStop {
    /// Each target is reachable alone, not together.
    Conflict { pairs: Vec<(String, String)> },
    /// Some targets cannot be met anywhere in the factor box, even alone: each with its best
    /// probability alone and the observed values closest to it (lowest, highest).
    OutOfReach { targets: Vec<OutOfReach> },
    /// The budget is spent.
    BudgetSpent { simulations: usize },
    /// No run of the start design completed.
    NothingCompleted,
}

/// A target out of reach in the factor box, with the evidence.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct OutOfReach {
    /// The target's label (`experiment.metric`).
    pub label: String,
    /// The target's value and the half-width of its tolerance band.
    pub band: Band,
    /// The surrogates' best probability of meeting it alone, anywhere among the candidates.
    pub alone: f64,
    /// The lowest and highest value observed (`None` before any).
    pub observed: Option<(f64, f64)>,
}

/// One response's surrogate and the factors it ranges over.
struct Response {
    surrogate: Surrogate,
    /// Indices (request order) of the factors written into the response's experiment.
    columns: Vec<usize>,
}

impl Response {
    /// The points restricted to the response's own factors.
    fn project(&self, u: &[Vec<f64>]) -> Vec<Vec<f64>> {
        u.iter()
            .map(|p| self.columns.iter().map(|&j| p[j]).collect())
            .collect()
    }

    fn predict(&self, u: &[Vec<f64>]) -> Vec<Prediction> {
        self.surrogate.predict(&self.project(u))
    }
}

/// The fitted surrogates of one decision.
struct Models {
    responses: Vec<Response>,
    feasibility: Option<Surrogate>,
    bands: Vec<Band>,
    replicates: u32,
}

/// Scores of candidate points.
struct Scores {
    /// `ln P(target within)` per candidate, per target.
    each: Vec<Vec<f64>>,
    /// `ln P(feasible)` per candidate.
    feasible: Vec<f64>,
    /// Predicted mean per candidate, per target.
    means: Vec<Vec<f64>>,
    /// `ln P(target within)` at the optimistic mean (the exploration term), per candidate,
    /// per target.
    optimistic: Vec<Vec<f64>>,
}

impl Scores {
    fn joint(&self, i: usize) -> f64 {
        self.each.iter().map(|e| e[i]).sum::<f64>() + self.feasible[i]
    }

    /// The exploration term of candidate `i` for the targets `aims` (indices).
    fn optimistic(&self, i: usize, aims: &[usize]) -> f64 {
        aims.iter().map(|&t| self.optimistic[t][i]).sum::<f64>() + self.feasible[i]
    }
}

impl Models {
    fn predict(&self, u: &[Vec<f64>]) -> (Vec<Vec<Prediction>>, Vec<f64>) {
        let responses = self.responses.iter().map(|r| r.predict(u)).collect();
        let feasible = match &self.feasibility {
            Some(f) => f.predict(u).iter().map(ln_p_feasible).collect(),
            None => vec![0.0; u.len()],
        };
        (responses, feasible)
    }

    fn score(&self, u: &[Vec<f64>]) -> Scores {
        let (predictions, feasible) = self.predict(u);
        let each = predictions
            .iter()
            .zip(&self.bands)
            .map(|(ps, band)| {
                ps.iter()
                    .map(|p| ln_p_within(p, *band, self.replicates))
                    .collect()
            })
            .collect();
        let means = predictions
            .iter()
            .map(|ps| ps.iter().map(|p| p.mean).collect())
            .collect();
        let optimistic = predictions
            .iter()
            .zip(&self.bands)
            .map(|(ps, band)| {
                ps.iter()
                    .map(|p| ln_p_within_optimistic(p, *band, self.replicates))
                    .collect()
            })
            .collect();
        Scores {
            each,
            feasible,
            means,
            optimistic,
        }
    }

    /// Each response's influences over the `factors` of the request.
    fn influences(&self, targets: &[Target], factors: usize) -> Vec<Influence> {
        self.responses
            .iter()
            .zip(targets)
            .map(|(r, t)| {
                let own_scales = r.surrogate.length_scales();
                let effects = r.surrogate.total_effects();
                let total: f64 = effects.total.iter().sum();
                let mut length_scales = vec![None; factors];
                let mut share = vec![0.0; factors];
                for (k, &j) in r.columns.iter().enumerate() {
                    length_scales[j] = Some(own_scales[k]);
                    if total > 0.0 {
                        share[j] = effects.total[k] / total;
                    }
                }
                let noise_sd = r.surrogate.noise_sd();
                Influence {
                    response: t.label.clone(),
                    length_scales,
                    share,
                    noise_sd,
                    min_length_scale: Some(r.surrogate.min_length_scale()),
                    explained: Some(effects.variance / (effects.variance + noise_sd * noise_sd)),
                }
            })
            .collect()
    }
}

fn argmax(values: impl Iterator<Item = f64>) -> Option<(usize, f64)> {
    values
        .enumerate()
        .filter(|(_, v)| !v.is_nan())
        .fold(None, |best, (i, v)| match best {
            Some((_, b)) if b >= v => best,
            _ => Some((i, v)),
        })
}

impl Campaign {
    fn bayes_settings(&self) -> BayesianSettings {
        self.request
            .strategy
            .bayesian()
            .cloned()
            .expect("the bayesian strategy")
    }

    fn bayes_seed(&self) -> u64 {
        self.request.seed.unwrap_or(DEFAULT_SEED)
    }

    fn state(&self) -> &BayesState {
        self.bayes.as_ref().expect("bayesian state")
    }

    fn state_mut(&mut self) -> &mut BayesState {
        self.bayes.as_mut().expect("bayesian state")
    }

    fn to_natural(&self, u: &[f64]) -> Vec<f64> {
        self.request
            .factors
            .iter()
            .zip(u)
            .map(|(f, v)| f.low + v * (f.high - f.low))
            .collect()
    }

    fn to_unit(&self, x: &[f64]) -> Vec<f64> {
        self.request
            .factors
            .iter()
            .zip(x)
            .map(|(f, v)| (v - f.low) / (f.high - f.low))
            .collect()
    }

    fn bands(&self) -> Vec<Band> {
        self.request
            .targets()
            .iter()
            .map(|t| Band {
                target: t.value,
                half_width: t.tolerance.half_width(t.value),
            })
            .collect()
    }

    /// Starts the Bayesian strategy: the space-filling design, one batch per experiment.
    pub(super) fn start_bayes(&mut self) -> Vec<BatchRequest> {
        let settings = self.bayes_settings();
        let d = self.request.factors.len();
        let n = settings.initial_points_for(d);
        let u = design::maximin_start(n, d, &mut design::rng(self.bayes_seed(), 0, PURPOSE_START));
        let points: Vec<Vec<f64>> = u.iter().map(|p| self.to_natural(p)).collect();
        self.bayes = Some(BayesState::default());
        let experiments = self.request.experiment_keys().len();
        self.decide(
            StageKind::Design,
            wording::start(n, d, experiments, &settings),
        );
        self.issue_round(StageKind::Design, points, 1)
    }

    /// Issues one batch per experiment with the same points; the round waits for all of them.
    fn issue_round(
        &mut self,
        stage: StageKind,
        points: Vec<Vec<f64>>,
        replicates: u32,
    ) -> Vec<BatchRequest> {
        let keys = self.request.experiment_keys();
        let specs: Vec<FactorSpec> = self
            .request
            .factors
            .iter()
            .map(CandidateFactor::spec)
            .collect();
        self.round = self.state().round;
        let mut batches = Vec::new();
        for key in &keys {
            let template = self.request.template_for(StageTemplate::Verification, key);
            let index = self.batches.len();
            batches.push(self.issue(
                stage,
                key.clone(),
                template,
                specs.clone(),
                DesignRequest::Explicit {
                    points: points.clone(),
                },
                replicates,
                ModelName::None,
                Vec::new(),
            ));
            self.state_mut().waiting.push(index);
        }
        self.state_mut().simulations += points.len() * replicates as usize * keys.len();
        batches
    }

    /// Takes a finished batch of the current round; decides once the round is complete.
    pub(super) fn step_bayes(&mut self, finished: &StageResult) -> Result<Step, CampaignError> {
        let state = self.state_mut();
        let Some(position) = state.waiting.iter().position(|&i| i == finished.batch) else {
            return Err(CampaignError::UnexpectedBatch {
                got: finished.batch,
                expected: state.waiting.first().copied().unwrap_or(usize::MAX),
            });
        };
        state.waiting.remove(position);
        state.received.push(finished.clone());
        if !state.waiting.is_empty() {
            return Ok(Step::Wait);
        }
        let mut results = std::mem::take(&mut state.received);
        results.sort_by_key(|r| r.batch);
        let stage = self.batches[results[0].batch].stage;
        match stage {
            StageKind::Drilling => Ok(self.bayes_after_drilling(&results[0])),
            StageKind::Verification => {
                self.ingest(&results);
                self.judge_verification()
            }
            _ => {
                self.ingest(&results);
                self.plan_round()
            }
        }
    }

    /// Adds a round's runs to the observations: one per design row and replicate, with every
    /// experiment's value of its targets.
    fn ingest(&mut self, results: &[StageResult]) {
        let targets = self.request.targets();
        let mut points: BTreeMap<(u32, u32), Observation> = BTreeMap::new();
        let round = self.state().round;
        for result in results {
            let issued = &self.batches[result.batch];
            let DesignRequest::Explicit { points: rows } = &issued.request.design else {
                continue;
            };
            let mine: Vec<&Target> = targets
                .iter()
                .filter(|t| t.experiment == issued.experiment)
                .collect();
            for run in &result.runs {
                if matches!(
                    run.status,
                    RunState::Cancelled | RunState::Queued | RunState::Running
                ) {
                    continue;
                }
                let Some(point) = rows.get(run.design_row as usize) else {
                    continue;
                };
                let entry = points
                    .entry((run.design_row, run.replicate))
                    .or_insert_with(|| Observation {
                        point: point.clone(),
                        round,
                        stage: issued.stage,
                        values: BTreeMap::new(),
                        failed: None,
                    });
                if run.status == RunState::Dead {
                    let reason = run
                        .last_error
                        .clone()
                        .unwrap_or_else(|| "the run failed".to_owned());
                    entry.failed.get_or_insert(reason);
                    continue;
                }
                for t in &mine {
                    match run.metrics.as_ref().and_then(|m| m.get(&t.metric)) {
                        Some(v) if v.is_finite() => {
                            entry.values.insert(t.label.clone(), *v);
                        }
                        _ => {
                            entry
                                .failed
                                .get_or_insert(wording::missing_metric(&t.metric));
                        }
                    }
                }
            }
        }
        self.state_mut().observations.extend(points.into_values());
    }

    /// Fits a surrogate per target (and for feasibility when some point failed); `None` names a
    /// target with too few values yet.
    fn fit_models(&self) -> Result<Models, String> {
        let targets = self.request.targets();
        let observations = &self.state().observations;
        let mut responses = Vec::new();
        for t in &targets {
            // The surrogate ranges over the factors written into the target's experiment only:
            // the others cannot move it.
            let columns: Vec<usize> = (0..self.request.factors.len())
                .filter(|&j| self.request.factors[j].acts_on(&t.experiment))
                .collect();
            let (u, y): (Vec<Vec<f64>>, Vec<f64>) = observations
                .iter()
                .filter_map(|o| {
                    o.values.get(&t.label).map(|v| {
                        let unit = self.to_unit(&o.point);
                        (columns.iter().map(|&j| unit[j]).collect(), *v)
                    })
                })
                .unzip();
            if y.len() < MIN_VALUES {
                return Err(t.label.clone());
            }
            let surrogate =
                Surrogate::fit(&u, &y, Smoothness::Response).ok_or_else(|| t.label.clone())?;
            responses.push(Response { surrogate, columns });
        }
        let feasibility = if observations.iter().any(|o| o.failed.is_some()) {
            let (u, y): (Vec<Vec<f64>>, Vec<f64>) = observations
                .iter()
                .map(|o| {
                    (
                        self.to_unit(&o.point),
                        if o.failed.is_some() { -1.0 } else { 1.0 },
                    )
                })
                .unzip();
            Surrogate::fit(&u, &y, Smoothness::Feasibility)
        } else {
            None
        };
        Ok(Models {
            responses,
            feasibility,
            bands: self.bands(),
            replicates: self.request.verification.replicates,
        })
    }

    /// Points grouped by setting: (point, mean of each target's values, any failure).
    fn point_means(&self) -> Vec<(Vec<f64>, Vec<Option<f64>>, bool)> {
        let targets = self.request.targets();
        let mut groups: Vec<(Vec<f64>, Vec<Vec<f64>>, bool)> = Vec::new();
        for o in &self.state().observations {
            let i = match groups.iter().position(|g| g.0 == o.point) {
                Some(i) => i,
                None => {
                    groups.push((o.point.clone(), vec![Vec::new(); targets.len()], false));
                    groups.len() - 1
                }
            };
            groups[i].2 |= o.failed.is_some();
            for (j, t) in targets.iter().enumerate() {
                if let Some(v) = o.values.get(&t.label) {
                    groups[i].1[j].push(*v);
                }
            }
        }
        groups
            .into_iter()
            .map(|(p, values, failed)| {
                let means = values
                    .iter()
                    .map(|v| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64))
                    .collect();
                (p, means, failed)
            })
            .collect()
    }

    /// The observed (feasible, complete) point with the smallest joint misfit.
    fn best_observed(&self) -> Option<(Vec<f64>, Vec<f64>, f64)> {
        let bands = self.bands();
        self.point_means()
            .into_iter()
            .filter(|(_, _, failed)| !failed)
            .filter_map(|(p, means, _)| {
                let means: Option<Vec<f64>> = means.into_iter().collect();
                means.map(|m| {
                    let score = misfit(&m, &bands);
                    (p, m, score)
                })
            })
            .min_by(|a, b| a.2.total_cmp(&b.2))
    }

    /// The targets the assessment found out of reach, with the values observed for each.
    fn out_of_reach(&self, assessment: &Assessment) -> Vec<OutOfReach> {
        let bands = self.bands();
        self.request
            .targets()
            .iter()
            .enumerate()
            .filter(|(_, t)| assessment.out_of_reach.contains(&t.label))
            .map(|(i, t)| OutOfReach {
                label: t.label.clone(),
                band: bands[i],
                alone: assessment.alone[i],
                observed: self
                    .state()
                    .observations
                    .iter()
                    .filter_map(|o| o.values.get(&t.label).copied())
                    .fold(None, |r: Option<(f64, f64)>, v| match r {
                        None => Some((v, v)),
                        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
                    }),
            })
            .collect()
    }

    /// After a start or search round: assess, then verify, stop, or propose the next round.
    fn plan_round(&mut self) -> Result<Step, CampaignError> {
        let settings = self.bayes_settings();
        let best_misfit = self.best_observed().map(|b| b.2);
        let simulations = self.state().simulations;
        self.state_mut().convergence.push(ConvergencePoint {
            simulations,
            best_misfit,
        });
        let experiments = self.request.experiment_keys().len();
        let replicates = self.request.verification.replicates as usize;
        let remaining = settings.max_runs.saturating_sub(simulations);
        let reserve = replicates * experiments;
        let room = remaining.saturating_sub(reserve) / experiments;
        let models = match self.fit_models() {
            Ok(models) => models,
            Err(label) => {
                // Too few completed runs for a surrogate: more space-filling points.
                if self
                    .state()
                    .observations
                    .iter()
                    .all(|o| o.values.is_empty())
                    && room == 0
                {
                    return self.bayes_stop(BayesStop::NothingCompleted);
                }
                let k = settings.batch_size.min(room);
                if k == 0 {
                    return self.bayes_stop(BayesStop::BudgetSpent { simulations });
                }
                let d = self.request.factors.len();
                let round = self.state().round + 1;
                let u = design::maximin_start(
                    k,
                    d,
                    &mut design::rng(self.bayes_seed(), round, PURPOSE_FILL),
                );
                let points: Vec<Vec<f64>> = u.iter().map(|p| self.to_natural(p)).collect();
                self.state_mut().round = round;
                self.decide(StageKind::Search, wording::too_few_values(&label, k));
                return Ok(Step::Submit(self.issue_round(StageKind::Search, points, 1)));
            }
        };
        let candidates = self.candidates(&models, settings.candidates);
        let scores = models.score(&candidates);
        let assessment = self.assess(&models, &candidates, &scores, &settings);
        let stop_p = settings.stop_probability;
        let conflict = !assessment.conflicts.is_empty();
        self.state_mut().conflict_rounds = if conflict {
            self.state().conflict_rounds + 1
        } else {
            0
        };
        self.decide(
            StageKind::Search,
            wording::assessment(&assessment, &self.request.targets(), &self.factor_names()),
        );
        self.state_mut().assessment = Some(assessment.clone());
        if assessment.probability >= stop_p && remaining >= reserve {
            return Ok(self.issue_verification(assessment.best.clone(), false));
        }
        self.state_mut().out_of_reach_rounds = if assessment.out_of_reach.is_empty() {
            0
        } else {
            self.state().out_of_reach_rounds + 1
        };
        if self.state().conflict_rounds >= CONFLICT_ROUNDS {
            return self.bayes_stop(BayesStop::Conflict {
                pairs: assessment.conflicts.clone(),
            });
        }
        if self.state().out_of_reach_rounds >= OUT_OF_REACH_ROUNDS {
            let targets = self.out_of_reach(&assessment);
            return self.bayes_stop(BayesStop::OutOfReach { targets });
        }
        let k = settings.batch_size.min(room);
        if k == 0 {
            if remaining >= reserve && !conflict {
                // Budget for the verification only: try the best point.
                return Ok(self.issue_verification(assessment.best.clone(), true));
            }
            return self.bayes_stop(BayesStop::BudgetSpent { simulations });
        }
        let labels: Vec<String> = self
            .request
            .targets()
            .into_iter()
            .map(|t| t.label)
            .collect();
        let flagged: Vec<usize> = (0..labels.len())
            .filter(|&t| {
                assessment.out_of_reach.contains(&labels[t])
                    || assessment.at_edge.iter().any(|e| e.response == labels[t])
            })
            .collect();
        let proposal = self.propose(models, candidates, scores, k, &flagged);
        let round = self.state().round + 1;
        self.state_mut().round = round;
        self.decide(
            StageKind::Search,
            wording::proposal(&proposal, &self.factor_names()),
        );
        let mut points = proposal.exploit;
        points.extend(proposal.explore.into_iter().map(|(_, p)| p));
        Ok(Step::Submit(self.issue_round(StageKind::Search, points, 1)))
    }

    fn factor_names(&self) -> Vec<String> {
        self.request
            .factors
            .iter()
            .map(|f| f.name.clone())
            .collect()
    }

    /// Candidates of this round (normalised): the box and the neighbourhoods of the best
    /// observed points, of each target's closest run and of the surrogates' most promising
    /// ones.
    fn candidates(&self, models: &Models, total: usize) -> Vec<Vec<f64>> {
        let d = self.request.factors.len();
        let round = self.state().round;
        let mut rng = design::rng(self.bayes_seed(), round, PURPOSE_CANDIDATES);
        let bands = self.bands();
        let mut observed: Vec<(Vec<f64>, f64)> = self
            .point_means()
            .into_iter()
            .filter(|(_, _, failed)| !failed)
            .filter_map(|(p, means, _)| {
                let m: Option<Vec<f64>> = means.into_iter().collect();
                m.map(|m| (self.to_unit(&p), misfit(&m, &bands)))
            })
            .collect();
        observed.sort_by(|a, b| a.1.total_cmp(&b.1));
        let mut centres: Vec<Vec<f64>> = observed.into_iter().take(4).map(|o| o.0).collect();
        // Each target's own closest run (where a target met only at an edge was met).
        for (t, band) in self.request.targets().iter().zip(&bands) {
            let closest = self
                .state()
                .observations
                .iter()
                .filter_map(|o| o.values.get(&t.label).map(|v| (o, (v - band.target).abs())))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((o, _)) = closest {
                let u = self.to_unit(&o.point);
                if !centres.contains(&u) {
                    centres.push(u);
                }
            }
        }
        // The most promising points of a first, global look.
        let global = design::latin_hypercube(total / 2, d, &mut rng);
        let scores = models.score(&global);
        let mut ranked: Vec<(usize, f64)> =
            (0..global.len()).map(|i| (i, scores.joint(i))).collect();
        ranked.sort_by(|a, b| b.1.total_cmp(&a.1));
        centres.extend(ranked.iter().take(4).map(|(i, _)| global[*i].clone()));
        let mut all = global;
        all.extend(design::candidates(total - total / 2, d, &centres, &mut rng));
        all
    }

    fn assess(
        &self,
        models: &Models,
        candidates: &[Vec<f64>],
        scores: &Scores,
        settings: &BayesianSettings,
    ) -> Assessment {
        let targets = self.request.targets();
        let (best, ln_p) = argmax((0..candidates.len()).map(|i| scores.joint(i)))
            .expect("candidates are never empty");
        let alone: Vec<f64> = scores
            .each
            .iter()
            .map(|e| {
                argmax(e.iter().zip(&scores.feasible).map(|(a, f)| a + f))
                    .map(|(_, v)| v.exp())
                    .unwrap_or(0.0)
            })
            .collect();
        let mut conflicts = Vec::new();
        let together = ln_p.exp();
        if targets.len() > 1
            && together < settings.conflict_probability
            && alone.iter().all(|a| *a >= REACHABLE_ALONE)
        {
            for i in 0..targets.len() {
                for j in i + 1..targets.len() {
                    let pair = argmax(
                        (0..candidates.len())
                            .map(|c| scores.each[i][c] + scores.each[j][c] + scores.feasible[c]),
                    )
                    .map(|(_, v)| v.exp())
                    .unwrap_or(0.0);
                    if pair < settings.conflict_probability {
                        conflicts.push((targets[i].label.clone(), targets[j].label.clone()));
                    }
                }
            }
            if conflicts.is_empty() {
                // Every pair can be met, all of them not: name them all.
                for i in 0..targets.len() {
                    for j in i + 1..targets.len() {
                        conflicts.push((targets[i].label.clone(), targets[j].label.clone()));
                    }
                }
            }
        }
        let mut out_of_reach = Vec::new();
        let mut at_edge = Vec::new();
        for (i, t) in targets.iter().enumerate() {
            if alone[i] >= REACHABLE_ALONE {
                continue;
            }
            match self.edge_reach(models, i, t) {
                Some(reach) => at_edge.push(reach),
                None => out_of_reach.push(t.label.clone()),
            }
        }
        Assessment {
            round: self.state().round,
            best: self.to_natural(&candidates[best]),
            probability: together,
            predicted: scores.means.iter().map(|m| m[best]).collect(),
            alone,
            conflicts,
            out_of_reach,
            at_edge,
            influences: models.influences(&targets, self.request.factors.len()),
        }
    }

    /// Target `i` (`t`) met within the runs' noise only at an edge of the box, or `None`.
    fn edge_reach(&self, models: &Models, i: usize, t: &Target) -> Option<EdgeReach> {
        let observed: Vec<(&Observation, f64)> = self
            .state()
            .observations
            .iter()
            .filter_map(|o| o.values.get(&t.label).map(|v| (o, *v)))
            .collect();
        let runs: Vec<(Vec<f64>, f64)> = observed
            .iter()
            .map(|(o, v)| (self.to_unit(&o.point), *v))
            .collect();
        let response = &models.responses[i];
        let found = edge::at_edge(&runs, models.bands[i], response)?;
        let factors = &self.request.factors;
        Some(EdgeReach {
            response: t.label.clone(),
            edges: found
                .edges
                .iter()
                .map(|e| Edge {
                    factor: factors[e.factor].name.clone(),
                    high: e.high,
                    value: if e.high {
                        factors[e.factor].high
                    } else {
                        factors[e.factor].low
                    },
                })
                .collect(),
            runs: found.runs,
            noise_sd: response.surrogate.noise_sd(),
            closest: observed[found.closest].1,
            point: observed[found.closest].0.point.clone(),
        })
    }

    /// `k` points by kriging believer: the best candidate, then the surrogates believe their own
    /// prediction there and the next is chosen, away from the ones already taken. The last
    /// ones explore: one for each target in `flagged` (out of reach alone, or met only at an
    /// edge), or else one for all targets together when `k` is 2 or more, each where the
    /// exploration term (the probability at an optimistic mean) is highest.
    fn propose(
        &self,
        mut models: Models,
        candidates: Vec<Vec<f64>>,
        mut scores: Scores,
        k: usize,
        flagged: &[usize],
    ) -> Proposal {
        let d = self.request.factors.len();
        let targets = self.request.targets();
        let spacing = 0.05 * (d as f64).sqrt();
        let aims: Vec<Vec<usize>> = if !flagged.is_empty() {
            flagged.iter().take(k).map(|&t| vec![t]).collect()
        } else if k >= 2 {
            vec![(0..targets.len()).collect()]
        } else {
            Vec::new()
        };
        let mut chosen: Vec<Vec<f64>> = Vec::new();
        let mut proposal = Proposal {
            exploit: Vec::new(),
            explore: Vec::new(),
        };
        for slot in 0..k {
            let aim = slot.checked_sub(k - aims.len()).map(|e| &aims[e]);
            let pick = argmax((0..candidates.len()).map(|i| {
                if chosen
                    .iter()
                    .any(|c| design::distance(c, &candidates[i]) < spacing)
                {
                    f64::NEG_INFINITY
                } else {
                    match aim {
                        None => scores.joint(i),
                        Some(aim) => scores.optimistic(i, aim),
                    }
                }
            }));
            let Some((i, _)) = pick else { break };
            let u = candidates[i].clone();
            for (r, means) in models.responses.iter_mut().zip(&scores.means) {
                let own = r.project(std::slice::from_ref(&u)).remove(0);
                r.surrogate.believe(&own, means[i]);
            }
            let natural = self.to_natural(&u);
            match aim {
                None => proposal.exploit.push(natural),
                Some(aim) => proposal.explore.push((
                    if aim.len() == targets.len() && flagged.is_empty() {
                        Vec::new()
                    } else {
                        aim.iter().map(|&t| targets[t].label.clone()).collect()
                    },
                    natural,
                )),
            }
            chosen.push(u);
            scores = models.score(&candidates);
        }
        proposal
    }

    fn issue_verification(&mut self, point: Vec<f64>, last_chance: bool) -> Step {
        let replicates = self.request.verification.replicates;
        let probability = self
            .state()
            .assessment
            .as_ref()
            .map(|a| a.probability)
            .unwrap_or(0.0);
        let round = self.state().round + 1;
        self.state_mut().round = round;
        self.decide(
            StageKind::Verification,
            wording::verify(
                &point,
                &self.factor_names(),
                probability,
                replicates,
                last_chance,
            ),
        );
        Step::Submit(self.issue_round(StageKind::Verification, vec![point], replicates))
    }

    fn judge_verification(&mut self) -> Result<Step, CampaignError> {
        let round = self.state().round;
        let targets = self.request.targets();
        let runs: Vec<&Observation> = self
            .state()
            .observations
            .iter()
            .filter(|o| o.round == round && o.stage == StageKind::Verification)
            .collect();
        let Some(point) = runs.first().map(|o| o.point.clone()) else {
            // Nothing came back (every run cancelled): search on.
            return self.plan_round();
        };
        let failed_runs = runs.iter().filter(|o| o.failed.is_some()).count();
        let assessment = self.state().assessment.clone();
        let checks: Vec<ResponseCheck> = targets
            .iter()
            .enumerate()
            .map(|(j, t)| {
                let values: Vec<f64> = runs
                    .iter()
                    .filter_map(|o| o.values.get(&t.label).copied())
                    .collect();
                check(t, values, assessment.as_ref().map(|a| a.predicted[j]))
            })
            .collect();
        let within = failed_runs == 0 && checks.iter().all(|c| c.within_tolerance);
        let verification = BayesVerification {
            round,
            point: point.clone(),
            probability: assessment.as_ref().map(|a| a.probability).unwrap_or(0.0),
            checks,
            failed_runs,
            within_tolerance: within,
        };
        self.decide(
            StageKind::Verification,
            wording::verification(&verification),
        );
        self.state_mut().verifications.push(verification);
        if !within {
            return self.plan_round();
        }
        if self.request.drilling.is_some() {
            return self.issue_bayes_drilling(point, false);
        }
        Ok(self.bayes_finish())
    }

    /// Issues the drilling validation at `point`: the verified calibration, or (`unverified`)
    /// the best point or compromise of a campaign that stops without one.
    fn issue_bayes_drilling(
        &mut self,
        point: Vec<f64>,
        unverified: bool,
    ) -> Result<Step, CampaignError> {
        let drilling = self.request.drilling.clone().expect("drilling requested");
        let specs: Vec<FactorSpec> = self
            .request
            .factors
            .iter()
            .map(|f| FactorSpec {
                name: f.name.clone(),
                path: Some(
                    drilling
                        .paths
                        .get(&f.name)
                        .cloned()
                        .unwrap_or_else(|| f.path.clone()),
                ),
                low: f.low,
                high: f.high,
            })
            .collect();
        // Paths are checked here so a bad one is named before anything runs.
        let mut probe = drilling.experiment.spec.clone();
        for (f, s) in self.request.factors.iter().zip(&specs) {
            let path = s.path.as_deref().unwrap_or_default();
            set_path(&mut probe, path, f.low).map_err(|reason| CampaignError::InvalidRequest {
                field: format!("drilling.paths.{}", f.name),
                reason,
            })?;
        }
        self.record(
            StageKind::Drilling,
            Decided::DrillingPlanned {
                drilling: &drilling,
                unverified,
            },
        );
        self.state_mut().drilling_point = Some(point.clone());
        let index = self.batches.len();
        let batch = self.issue(
            StageKind::Drilling,
            String::new(),
            drilling.experiment.clone(),
            specs,
            DesignRequest::Explicit {
                points: vec![point],
            },
            drilling.replicates,
            ModelName::None,
            Vec::new(),
        );
        self.state_mut().waiting.push(index);
        Ok(Step::Submit(vec![batch]))
    }

    fn bayes_after_drilling(&mut self, finished: &StageResult) -> Step {
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
            // Drilled at the compromise of a stop: the campaign still stops.
            Some(reason) => {
                let conflict = std::mem::take(&mut self.state_mut().stop_conflict);
                let out_of_reach = std::mem::take(&mut self.state_mut().stop_out_of_reach);
                let summary = self.bayes_summary(conflict, out_of_reach);
                self.stop_with_summary(summary, reason)
            }
            None => self.bayes_finish(),
        }
    }

    /// The region, influences, Pareto front and failures, from surrogates fitted on all data.
    fn bayes_result(
        &self,
        point: &[f64],
        conflict: Vec<String>,
        out_of_reach: Vec<String>,
        at_edge: Vec<EdgeReach>,
    ) -> BayesianResult {
        let targets = self.request.targets();
        let state = self.state();
        let d = self.request.factors.len();
        let (region, influences) = match self.fit_models() {
            Ok(models) => {
                let mut rng = design::rng(self.bayes_seed(), state.round, PURPOSE_REGION);
                let u = design::latin_hypercube(REGION_CANDIDATES, d, &mut rng);
                let scores = models.score(&u);
                let threshold = 0.5;
                let members: Vec<Vec<f64>> = (0..u.len())
                    .filter(|&i| scores.joint(i).exp() >= threshold)
                    .map(|i| self.to_natural(&u[i]))
                    .collect();
                let fraction = members.len() as f64 / u.len() as f64;
                let extent = if members.is_empty() {
                    Vec::new()
                } else {
                    (0..d)
                        .map(|j| {
                            members
                                .iter()
                                .fold((f64::INFINITY, f64::NEG_INFINITY), |a, p| {
                                    (a.0.min(p[j]), a.1.max(p[j]))
                                })
                        })
                        .collect()
                };
                let step = members.len().div_ceil(REGION_POINTS).max(1);
                let at_result = models.score(&[self.to_unit(point)]).joint(0).exp();
                (
                    Region {
                        threshold,
                        points: members.into_iter().step_by(step).collect(),
                        extent,
                        fraction,
                        at_result: Some(at_result),
                    },
                    models.influences(&targets, self.request.factors.len()),
                )
            }
            Err(_) => (
                Region {
                    threshold: 0.5,
                    points: Vec::new(),
                    extent: Vec::new(),
                    fraction: 0.0,
                    at_result: None,
                },
                Vec::new(),
            ),
        };
        BayesianResult {
            factors: self.factor_names(),
            region,
            influences,
            convergence: state.convergence.clone(),
            pareto: self.pareto(),
            infeasible: state
                .observations
                .iter()
                .filter_map(|o| {
                    o.failed.as_ref().map(|reason| InfeasiblePoint {
                        point: o.point.clone(),
                        reason: reason.clone(),
                    })
                })
                .collect(),
            conflict,
            out_of_reach,
            at_edge,
        }
    }

    /// The observed points no other beats on every target's misfit.
    fn pareto(&self) -> Vec<ParetoPoint> {
        let bands = self.bands();
        let points: Vec<ParetoPoint> = self
            .point_means()
            .into_iter()
            .filter(|(_, _, failed)| !failed)
            .filter_map(|(p, means, _)| {
                let means: Option<Vec<f64>> = means.into_iter().collect();
                means.map(|m| ParetoPoint {
                    point: p,
                    misfits: m
                        .iter()
                        .zip(&bands)
                        .map(|(v, b)| (v - b.target).abs() / b.half_width)
                        .collect(),
                })
            })
            .collect();
        let dominated = |a: &ParetoPoint, b: &ParetoPoint| {
            b.misfits.iter().zip(&a.misfits).all(|(x, y)| x <= y)
                && b.misfits.iter().zip(&a.misfits).any(|(x, y)| x < y)
        };
        let mut front: Vec<ParetoPoint> = points
            .iter()
            .filter(|a| !points.iter().any(|b| dominated(a, b)))
            .cloned()
            .collect();
        front.sort_by(|a, b| a.misfits[0].total_cmp(&b.misfits[0]));
        front.dedup_by(|a, b| a.misfits == b.misfits);
        front
    }

    /// The summary of a Bayesian campaign: the verified point, or else the best observed one.
    fn bayes_summary(&self, conflict: Vec<String>, out_of_reach: Vec<String>) -> Summary {
        let targets = self.request.targets();
        let state = self.state();
        let verified = state
            .verifications
            .iter()
            .rev()
            .find(|v| v.within_tolerance);
        let (point, checks) = match verified {
            Some(v) => (v.point.clone(), v.checks.clone()),
            None => {
                let (point, _, _) = self.best_observed().unwrap_or_else(|| {
                    (
                        self.to_natural(&vec![0.5; self.request.factors.len()]),
                        vec![],
                        0.0,
                    )
                });
                let observed: Vec<&Observation> = state
                    .observations
                    .iter()
                    .filter(|o| o.point == point && o.failed.is_none())
                    .collect();
                let predicted = self.fit_models().ok().map(|m| {
                    let (p, _) = m.predict(&[self.to_unit(&point)]);
                    p.iter().map(|v| v[0].mean).collect::<Vec<f64>>()
                });
                let checks = targets
                    .iter()
                    .enumerate()
                    .map(|(j, t)| {
                        let values = observed
                            .iter()
                            .filter_map(|o| o.values.get(&t.label).copied())
                            .collect();
                        let mut c = check(t, values, predicted.as_ref().map(|p| p[j]));
                        c.within_tolerance = false;
                        c
                    })
                    .collect();
                (point, checks)
            }
        };
        // A target met only at an edge is reported with a result no verification accepted.
        let at_edge = match (verified, &state.assessment) {
            (None, Some(a)) => a.at_edge.clone(),
            _ => Vec::new(),
        };
        let first: &ResponseCheck = &checks[0];
        Summary {
            name: self.request.name.clone(),
            parameters: self
                .request
                .factors
                .iter()
                .zip(&point)
                .map(|(f, v)| CalibratedValue {
                    name: f.name.clone(),
                    path: f.path.clone(),
                    value: *v,
                    calibrated: true,
                })
                .collect(),
            target: first.target,
            predicted: first.predicted,
            verified_mean: first.mean,
            verified_relative_error_pct: first.relative_error_pct,
            within_tolerance: verified.is_some(),
            surface_rounds: 0,
            batches: self.batches.len(),
            drilling: self.drilling.clone(),
            targets: if self.request.is_multi() {
                checks.clone()
            } else {
                Vec::new()
            },
            simulations: Some(state.simulations),
            bayesian: Some(Box::new(self.bayes_result(
                &point,
                conflict,
                out_of_reach,
                at_edge,
            ))),
        }
    }

    fn bayes_finish(&mut self) -> Step {
        let summary = self.bayes_summary(Vec::new(), Vec::new());
        self.decide(self.stage, chain_wording::finished(&summary.parameters));
        self.status = Status::Finished;
        self.summary = Some(summary.clone());
        Step::Finished(summary)
    }

    /// Ends without a verified calibration; the result still carries the best point. With a
    /// drilling validation, it first runs at that point (the compromise, when targets
    /// conflict), so the result says what the setting predicts for the held-back measurement.
    fn bayes_stop(&mut self, stop: BayesStop) -> Result<Step, CampaignError> {
        let conflict: Vec<String> = match &stop {
            BayesStop::Conflict { pairs } => {
                let mut names: Vec<String> = Vec::new();
                for (a, b) in pairs {
                    for n in [a, b] {
                        if !names.contains(n) {
                            names.push(n.clone());
                        }
                    }
                }
                names
            }
            _ => Vec::new(),
        };
        let out_of_reach: Vec<String> = match &stop {
            BayesStop::OutOfReach { targets } => targets.iter().map(|t| t.label.clone()).collect(),
            _ => Vec::new(),
        };
        let summary = self.bayes_summary(conflict.clone(), out_of_reach.clone());
        let reason = wording::stop(&stop, &summary, &self.factor_names());
        let drill_at = match stop {
            BayesStop::NothingCompleted => None,
            BayesStop::Conflict { .. }
            | BayesStop::OutOfReach { .. }
            | BayesStop::BudgetSpent { .. } => self
                .request
                .drilling
                .as_ref()
                .filter(|_| self.drilling.is_none())
                .and_then(|_| self.best_observed()),
        };
        if let Some((point, _, _)) = drill_at {
            self.unverified = Some(reason);
            self.state_mut().stop_conflict = conflict;
            self.state_mut().stop_out_of_reach = out_of_reach;
            return self.issue_bayes_drilling(point, true);
        }
        Ok(self.stop_with_summary(summary, reason))
    }

    fn stop_with_summary(&mut self, summary: Summary, reason: String) -> Step {
        self.summary = Some(summary);
        self.status = Status::NeedsAttention {
            reason: reason.clone(),
        };
        self.decide(self.stage, chain_wording::stopped(&reason));
        Step::NeedsAttention(reason)
    }
}

/// One target's verification check from the values of its completed replicates.
fn check(t: &Target, values: Vec<f64>, predicted: Option<f64>) -> ResponseCheck {
    let n = values.len();
    let mean = if n == 0 {
        0.0
    } else {
        values.iter().sum::<f64>() / n as f64
    };
    let std = if n > 1 {
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
    } else {
        0.0
    };
    ResponseCheck {
        response: t.label.clone(),
        target: t.value,
        predicted: predicted.unwrap_or(mean),
        within_tolerance: n > 0 && t.tolerance.accepts(mean, t.value),
        relative_error_pct: if n > 0 {
            relative_error_pct(mean, t.value)
        } else {
            100.0
        },
        responses: values,
        mean,
        std,
    }
}
