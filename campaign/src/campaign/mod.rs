//! The campaign state machine: [`Campaign::start`] issues the screening batch, every
//! [`Campaign::advance`] turns a finished batch into a decision and the next batch.
//!
//! One file per stage, each deciding with a typed outcome and no prose: `screening`,
//! `steepest`, `surface` (the response surface), `optimum`, `verification`, `drilling`. The
//! outcomes, every [`Stop`] and every `Decided` entry of the decision log are types in
//! `outcome`, a leaf; `wording` is the one module that turns them into sentences, and this
//! module hands a stage's `Decided` to it (`Campaign::record`). No stage imports `wording`
//! and `wording` imports no stage. `model` holds what all stages share: observations, coding,
//! fits and the desirability search.

mod bayes;
mod drilling;
mod model;
mod optimum;
mod outcome;
mod screening;
mod steepest;
mod surface;
mod verification;
mod wording;

use repose_api::{BatchRequest, DesignRequest, ExperimentTemplate, FactorSpec, ModelName, RunView};
use repose_doe::design::{splitmix64, Factor};
use serde::{Deserialize, Serialize};

pub use bayes::{
    Assessment, BayesState, BayesVerification, BayesianResult, ConvergencePoint, Edge, EdgeReach,
    InfeasiblePoint, Influence, Observation, ParetoPoint, Region,
};
pub(crate) use model::{screening_fit, surface_fit};
pub use outcome::{
    CarryRule, DrillMetric, DrillingOutcome, HeldFactor, LevelSetPoint, OptimumChoice, PathPoint,
    PathState, ResponseCheck, ResponseEffects, ScreeningOutcome, SurfaceFitSummary, SurfaceRound,
    VerificationOutcome,
};
use outcome::{Decided, Stop};
pub(crate) use wording::{fmt_num, fmt_p};

use crate::error::CampaignError;
use crate::request::{CampaignRequest, StageTemplate};
use model::set_path;

/// The stages of a campaign, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StageKind {
    /// 1: which factors matter.
    Screening,
    /// 2: walk toward the target.
    Steepest,
    /// 3: quadratic model around the best path point.
    ResponseSurface,
    /// 4: settings predicted to give the target (no batch of its own).
    Optimum,
    /// 5: replicate simulations at the optimum.
    Verification,
    /// 6: optional drilling simulation against measured hole metrics.
    Drilling,
    /// Bayesian strategy: the space-filling start.
    Design,
    /// Bayesian strategy: a round of proposals.
    Search,
}

impl StageKind {
    /// Name used in batch names and the report.
    pub fn label(self) -> &'static str {
        match self {
            StageKind::Screening => "screening",
            StageKind::Steepest => "steepest path",
            StageKind::ResponseSurface => "response surface",
            StageKind::Optimum => "optimum",
            StageKind::Verification => "verification",
            StageKind::Drilling => "drilling validation",
            StageKind::Design => "space-filling start",
            StageKind::Search => "search round",
        }
    }
}

/// Where the campaign stands.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum Status {
    /// A batch is outstanding.
    Running,
    /// Done; see [`Campaign::summary`].
    Finished,
    /// Stopped on something a person must look at.
    NeedsAttention {
        /// Why, in plain words.
        reason: String,
    },
}

/// One batch the campaign issued.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IssuedBatch {
    /// Position in [`Campaign::batches`]; pass it back in [`StageResult::batch`].
    pub index: usize,
    /// Stage it belongs to.
    pub stage: StageKind,
    /// Response-surface round (0 for the first; later rounds follow failed verifications).
    pub round: u32,
    /// What to submit.
    pub request: BatchRequest,
    /// Steepest stage: the path point (index into [`PathState::points`]) of each design row.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub path_points: Vec<usize>,
    /// Several-targets form: the experiment (key of `experiments`) this batch runs. A stage
    /// issues one batch per experiment the targets need, one after the other, with the same
    /// design; it decides when the last one has finished.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub experiment: String,
}

/// A decision and why, in plain words.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Decision {
    /// Stage that decided.
    pub stage: StageKind,
    /// Response-surface round.
    pub round: u32,
    /// The explanation.
    pub text: String,
}

/// A finished batch handed back to [`Campaign::advance`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageResult {
    /// Index of the batch in [`Campaign::batches`].
    pub batch: usize,
    /// Its runs (completed ones carry metrics; dead or cancelled ones are ignored).
    pub runs: Vec<RunView>,
    /// The server's analysis of the batch, if any. Decisions never depend on it (they are
    /// recomputed from the runs); the JSON report carries it along.
    #[serde(default)]
    pub analysis: Option<repose_api::AnalysisView>,
}

/// What to do after [`Campaign::step`]: the general form, for strategies that keep several
/// batches outstanding at once.
#[derive(Debug, Clone, PartialEq)]
pub enum Step {
    /// Submit these batches (all at once); call `step` with each when it finishes.
    Submit(Vec<BatchRequest>),
    /// Other batches of the round are still running; nothing to submit yet.
    Wait,
    /// The campaign is complete.
    Finished(Summary),
    /// Stopped: a person must look (reason in plain words). The state says the same, and
    /// [`Campaign::summary`] may carry the best point found.
    NeedsAttention(String),
}

/// What to do after [`Campaign::advance`].
#[derive(Debug, Clone, PartialEq)]
pub enum Next {
    /// Submit this batch; when it finishes, call `advance` with its runs.
    Submit(BatchRequest),
    /// The campaign is complete.
    Finished(Summary),
    /// Stopped: a person must look (reason in plain words). The state says the same.
    NeedsAttention(String),
}
/// A calibrated parameter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibratedValue {
    /// Factor name.
    pub name: String,
    /// Spec path.
    pub path: String,
    /// Value.
    pub value: f64,
    /// `true` if calibrated, `false` if held after screening.
    pub calibrated: bool,
}

/// The result of a finished campaign.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Campaign name.
    pub name: String,
    /// Every candidate factor's final value.
    pub parameters: Vec<CalibratedValue>,
    /// Target.
    pub target: f64,
    /// Model prediction at the optimum.
    pub predicted: f64,
    /// Verified mean.
    pub verified_mean: f64,
    /// Verified relative error, percent.
    pub verified_relative_error_pct: f64,
    /// Whether the verified mean is within tolerance.
    pub within_tolerance: bool,
    /// Response-surface rounds used.
    pub surface_rounds: u32,
    /// Batches issued.
    pub batches: usize,
    /// Optional drilling validation.
    pub drilling: Option<DrillingOutcome>,
    /// Several targets: every response's verification (the fields above are the first
    /// target's, except `within_tolerance`, which is over all).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub targets: Vec<ResponseCheck>,
    /// Bayesian strategy: simulations issued (every experiment's runs and the verification
    /// replicates; the drilling validation not).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simulations: Option<usize>,
    /// Bayesian strategy: the region, the influences, the convergence, the Pareto front and
    /// the failed points. Without a verified calibration the fields above describe the best
    /// point observed (`within_tolerance` false).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bayesian: Option<Box<BayesianResult>>,
}

/// A campaign's whole state. Serialises to JSON so a server can store it and resume after a
/// restart: load it, and call [`Campaign::advance`] when the outstanding batch finishes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Campaign {
    /// What was asked.
    pub request: CampaignRequest,
    /// Running, finished or stopped.
    pub status: Status,
    /// Stage of the outstanding batch (or the last stage reached).
    pub stage: StageKind,
    /// Current response-surface round.
    pub round: u32,
    /// Batches issued so far; the last one is outstanding while running.
    pub batches: Vec<IssuedBatch>,
    /// Decisions and why, in order.
    pub decisions: Vec<Decision>,
    /// Stage 1.
    pub screening: Option<ScreeningOutcome>,
    /// Stage 2.
    pub path: Option<PathState>,
    /// Stages 3-4, one per round.
    pub surfaces: Vec<SurfaceRound>,
    /// Stage 5, one per round.
    pub verifications: Vec<VerificationOutcome>,
    /// Stage 6.
    pub drilling: Option<DrillingOutcome>,
    /// Set when finished.
    pub summary: Option<Summary>,
    /// Finished batches of the current stage whose other experiments' batches are still to
    /// run (several-targets form with more than one experiment).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pending: Vec<StageResult>,
    /// Why verification gave up, while the drilling validation runs anyway at the most
    /// desirable setting found; the campaign stops with this reason once it is in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unverified: Option<String>,
    /// Bayesian strategy: its whole state (observations, outstanding batches, assessments).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bayes: Option<BayesState>,
}

/// How a stage ends early: misuse (an error to the caller) or a stop (a state the campaign
/// records as needing attention).
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Halt {
    Misuse(CampaignError),
    Stop(Stop),
}

impl From<CampaignError> for Halt {
    fn from(e: CampaignError) -> Self {
        Halt::Misuse(e)
    }
}

impl From<Stop> for Halt {
    fn from(s: Stop) -> Self {
        Halt::Stop(s)
    }
}

/// A fit for the report: the fit, the stop's words when it could not be made, `None` on misuse
/// (a run without a designed factor).
pub(crate) fn fit_or_reason(
    fit: Result<repose_doe::Fit, Halt>,
) -> Option<Result<repose_doe::Fit, String>> {
    match fit {
        Ok(fit) => Some(Ok(fit)),
        Err(Halt::Stop(stop)) => Some(Err(wording::stop(&stop))),
        Err(Halt::Misuse(_)) => None,
    }
}

impl Campaign {
    /// Validates the request and issues the screening batch. For a strategy that issues
    /// several batches at once (the Bayesian one with more than one experiment) use
    /// [`Campaign::begin`].
    pub fn start(request: CampaignRequest) -> Result<(Campaign, BatchRequest), CampaignError> {
        let (campaign, mut batches) = Campaign::begin(request)?;
        if batches.len() != 1 {
            return Err(CampaignError::SeveralBatches);
        }
        Ok((campaign, batches.remove(0)))
    }

    /// Validates the request and issues the first batches: the screening batch of the `doe`
    /// chain, or the space-filling start of the Bayesian strategy (one batch per experiment,
    /// all to be submitted at once).
    pub fn begin(request: CampaignRequest) -> Result<(Campaign, Vec<BatchRequest>), CampaignError> {
        request.validate()?;
        let mut campaign = Campaign {
            request,
            status: Status::Running,
            stage: StageKind::Screening,
            round: 0,
            batches: Vec::new(),
            decisions: Vec::new(),
            screening: None,
            path: None,
            surfaces: Vec::new(),
            verifications: Vec::new(),
            drilling: None,
            summary: None,
            pending: Vec::new(),
            unverified: None,
            bayes: None,
        };
        if campaign.request.strategy.is_doe() {
            let batch = campaign.start_screening()?;
            return Ok((campaign, vec![batch]));
        }
        let batches = campaign.start_bayes();
        Ok((campaign, batches))
    }

    /// Index of the outstanding batch, if any (the first, when several are).
    pub fn outstanding(&self) -> Option<usize> {
        self.outstanding_batches().first().copied()
    }

    /// Indices of every outstanding batch (one in the `doe` chain; a whole round in the
    /// Bayesian strategy).
    pub fn outstanding_batches(&self) -> Vec<usize> {
        match (&self.status, &self.bayes) {
            (Status::Running, Some(state)) => state.waiting.clone(),
            (Status::Running, None) => self.batches.len().checked_sub(1).into_iter().collect(),
            _ => Vec::new(),
        }
    }

    /// Feeds a finished outstanding batch and returns what to do next; the general form of
    /// [`Campaign::advance`] for strategies that keep several batches outstanding.
    pub fn step(&mut self, finished: &StageResult) -> Result<Step, CampaignError> {
        if self.bayes.is_none() || !matches!(self.status, Status::Running) {
            return Ok(match self.advance_chain(finished)? {
                Next::Submit(batch) => Step::Submit(vec![batch]),
                Next::Finished(summary) => Step::Finished(summary),
                Next::NeedsAttention(reason) => Step::NeedsAttention(reason),
            });
        }
        self.step_bayes(finished)
    }

    /// Feeds the finished outstanding batch and returns what to do next. For a campaign that
    /// keeps several batches outstanding (the Bayesian strategy with more than one experiment)
    /// use [`Campaign::step`].
    pub fn advance(&mut self, finished: &StageResult) -> Result<Next, CampaignError> {
        if self.bayes.is_none() {
            return self.advance_chain(finished);
        }
        if self.request.experiment_keys().len() > 1 {
            return Err(CampaignError::SeveralBatches);
        }
        match self.step(finished)? {
            Step::Submit(mut batches) if batches.len() == 1 => Ok(Next::Submit(batches.remove(0))),
            Step::Submit(_) | Step::Wait => Err(CampaignError::SeveralBatches),
            Step::Finished(summary) => Ok(Next::Finished(summary)),
            Step::NeedsAttention(reason) => Ok(Next::NeedsAttention(reason)),
        }
    }

    /// The `doe` chain's advance (and the not-running errors of both strategies).
    fn advance_chain(&mut self, finished: &StageResult) -> Result<Next, CampaignError> {
        let expected = match &self.status {
            Status::Running => self.batches.len() - 1,
            Status::Finished => {
                return Err(CampaignError::NotRunning {
                    state: "finished".into(),
                })
            }
            Status::NeedsAttention { .. } => {
                return Err(CampaignError::NotRunning {
                    state: "stopped (needs attention)".into(),
                })
            }
        };
        if finished.batch != expected {
            return Err(CampaignError::UnexpectedBatch {
                got: finished.batch,
                expected,
            });
        }
        let stage = self.batches[expected].stage;
        let keys = self.request.experiment_keys();
        let part = keys
            .iter()
            .position(|k| *k == self.batches[expected].experiment)
            .unwrap_or(0);
        if stage != StageKind::Drilling && part + 1 < keys.len() {
            // The stage's next experiment runs the same design before anything is decided.
            let batch = self.issue_part(&keys[part + 1])?;
            self.pending.push(finished.clone());
            return Ok(Next::Submit(batch));
        }
        let mut results = std::mem::take(&mut self.pending);
        results.push(finished.clone());
        let next = match stage {
            StageKind::Screening => self.after_screening(&results),
            StageKind::Steepest => self.after_path(&results),
            StageKind::ResponseSurface => self.after_surface(&results),
            StageKind::Verification => self.after_verification(&results),
            StageKind::Drilling => self.after_drilling(finished),
            StageKind::Optimum | StageKind::Design | StageKind::Search => {
                unreachable!("the chain issues no batch of this stage")
            }
        };
        match next {
            Ok(next) => Ok(next),
            Err(Halt::Misuse(e)) => Err(e),
            Err(Halt::Stop(stop)) => Ok(self.stop_with(wording::stop(&stop))),
        }
    }

    /// Ends the campaign as needing a person's attention, for `reason`.
    fn stop_with(&mut self, reason: String) -> Next {
        self.status = Status::NeedsAttention {
            reason: reason.clone(),
        };
        self.decide(self.stage, wording::stopped(&reason));
        Next::NeedsAttention(reason)
    }

    fn decide(&mut self, stage: StageKind, text: String) {
        self.decisions.push(Decision {
            stage,
            round: self.round,
            text,
        });
    }

    /// Logs what a stage decided, in `wording`'s words.
    fn record(&mut self, stage: StageKind, what: Decided) {
        self.decide(stage, wording::decided(&what));
    }

    /// Verification gave up but the drilling validation runs anyway: remembers why, in words,
    /// for the stop after it.
    fn hold_unverified(&mut self, stop: &Stop) {
        self.unverified = Some(wording::stop(stop));
    }

    /// Issues a stage's batch for its first experiment (the only one in the one-target form);
    /// [`Self::advance`] issues the others with the same design.
    fn issue_stage(
        &mut self,
        stage: StageKind,
        factors: Vec<FactorSpec>,
        design: DesignRequest,
        replicates: u32,
        model: ModelName,
        path_points: Vec<usize>,
    ) -> Result<BatchRequest, CampaignError> {
        let key = self.request.experiment_keys().remove(0);
        let experiment = self.part_template(stage, &key)?;
        Ok(self.issue(
            stage,
            key,
            experiment,
            factors,
            design,
            replicates,
            model,
            path_points,
        ))
    }

    /// The last batch's design again, for experiment `key`.
    fn issue_part(&mut self, key: &str) -> Result<BatchRequest, CampaignError> {
        let last = self.batches.last().expect("a batch was issued").clone();
        let experiment = self.part_template(last.stage, key)?;
        Ok(self.issue(
            last.stage,
            key.to_owned(),
            experiment,
            last.request.factors,
            last.request.design,
            last.request.replicates,
            last.request.model,
            last.path_points,
        ))
    }

    /// A stage's template for experiment `key`: the screening one as given, the later ones with
    /// the held factors written in.
    fn part_template(
        &self,
        stage: StageKind,
        key: &str,
    ) -> Result<ExperimentTemplate, CampaignError> {
        match stage {
            StageKind::Screening => Ok(self.request.template_for(StageTemplate::Screening, key)),
            _ => self.held_template(stage, key),
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn issue(
        &mut self,
        stage: StageKind,
        key: String,
        experiment: ExperimentTemplate,
        factors: Vec<FactorSpec>,
        design: DesignRequest,
        replicates: u32,
        model: ModelName,
        path_points: Vec<usize>,
    ) -> BatchRequest {
        let index = self.batches.len();
        let r = &self.request;
        // A factor that does not act on this experiment stays a column of its design (the
        // experiments' batches share their rows) but is not written into its spec.
        let factors = if stage == StageKind::Drilling {
            factors
        } else {
            factors
                .into_iter()
                .map(|mut f| {
                    let candidate = r.factors.iter().find(|c| c.name == f.name);
                    f.path = candidate
                        .filter(|c| c.acts_on(&key))
                        .map(|c| c.path.clone());
                    f
                })
                .collect()
        };
        let mut name = match stage {
            StageKind::Search | StageKind::Verification if self.bayes.is_some() => {
                format!("{}: {} {}", r.name, stage.label(), self.round)
            }
            StageKind::ResponseSurface | StageKind::Verification if self.round > 0 => {
                format!("{}: {} (round {})", r.name, stage.label(), self.round + 1)
            }
            StageKind::Steepest if path_points.first().is_some_and(|p| *p > 0) => {
                format!(
                    "{}: {} (points {}+)",
                    r.name,
                    stage.label(),
                    path_points[0] + 1
                )
            }
            _ => format!("{}: {}", r.name, stage.label()),
        };
        if stage != StageKind::Drilling && r.experiment_keys().len() > 1 {
            name.push_str(&format!(" [{key}]"));
        }
        let (response, target) = match (stage, &r.drilling) {
            (StageKind::Drilling, Some(d)) => {
                let (k, v) = d.measured.iter().next().expect("validated non-empty");
                (k.clone(), Some(*v))
            }
            _ => {
                let t = r
                    .targets()
                    .into_iter()
                    .find(|t| t.experiment == key)
                    .expect("every experiment has a target");
                (t.metric, Some(t.value))
            }
        };
        let request = BatchRequest {
            name,
            // A template without its own engine runs on the campaign's.
            experiment: r.with_backend(experiment),
            factors,
            design,
            replicates,
            response,
            model,
            target,
            seed: r
                .seed
                .map(|s| splitmix64(s ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))),
            // The report shows a verification pile and the drilled hole.
            keep_pictures: matches!(stage, StageKind::Verification | StageKind::Drilling),
        };
        self.stage = stage;
        self.batches.push(IssuedBatch {
            index,
            stage,
            round: self.round,
            request: request.clone(),
            path_points,
            experiment: if stage == StageKind::Drilling {
                String::new()
            } else {
                key
            },
        });
        request
    }

    /// Each target with the stage's batch of its experiment (`results` in
    /// [`CampaignRequest::experiment_keys`] order).
    fn results_by_target<'a>(
        &self,
        results: &'a [StageResult],
    ) -> Vec<(crate::request::Target, &'a StageResult)> {
        let keys = self.request.experiment_keys();
        self.request
            .targets()
            .into_iter()
            .map(|t| {
                let i = keys.iter().position(|k| *k == t.experiment).expect("a key");
                (t, &results[i])
            })
            .collect()
    }

    /// Template of a post-screening stage with the held factors written at their paths.
    fn held_template(
        &self,
        stage: StageKind,
        key: &str,
    ) -> Result<ExperimentTemplate, CampaignError> {
        let r = &self.request;
        let which = match stage {
            StageKind::Steepest => StageTemplate::Steepest,
            StageKind::ResponseSurface => StageTemplate::ResponseSurface,
            _ => StageTemplate::Verification,
        };
        let mut template = r.template_for(which, key);
        if let Some(s) = &self.screening {
            for h in &s.held {
                let candidate = r
                    .factors
                    .iter()
                    .find(|f| f.name == h.name)
                    .expect("held factors are candidates");
                if !candidate.acts_on(key) {
                    continue;
                }
                set_path(&mut template.spec, &candidate.path, h.value).map_err(|reason| {
                    CampaignError::InvalidRequest {
                        field: format!("factors.{}.path", h.name),
                        reason,
                    }
                })?;
            }
        }
        Ok(template)
    }

    fn factor_specs(&self, factors: &[Factor]) -> Vec<FactorSpec> {
        factors
            .iter()
            .map(|f| FactorSpec {
                name: f.name.clone(),
                path: self
                    .request
                    .factors
                    .iter()
                    .find(|c| c.name == f.name)
                    .map(|c| c.path.clone()),
                low: f.low,
                high: f.high,
            })
            .collect()
    }

    // ----------------------------------------------------------------------------------------
    // Stage 1

    fn final_parameters(&self) -> Vec<CalibratedValue> {
        let round = self.surfaces.last();
        let optimum = round.and_then(|r| r.optimum.as_ref());
        self.request
            .factors
            .iter()
            .map(|f| {
                let calibrated = round.and_then(|r| {
                    r.factors
                        .iter()
                        .position(|g| g.name == f.name)
                        .and_then(|i| optimum.map(|o| o.natural[i]))
                });
                let held = self
                    .screening
                    .as_ref()
                    .and_then(|s| s.held.iter().find(|h| h.name == f.name))
                    .map(|h| h.value);
                CalibratedValue {
                    name: f.name.clone(),
                    path: f.path.clone(),
                    value: calibrated.or(held).unwrap_or(f.hold_value()),
                    calibrated: calibrated.is_some(),
                }
            })
            .collect()
    }

    fn finish(&mut self) -> Next {
        let v = self.verifications.last().expect("verified").clone();
        let summary = Summary {
            name: self.request.name.clone(),
            parameters: self.final_parameters(),
            target: self.request.targets()[0].value,
            predicted: v.predicted,
            verified_mean: v.mean,
            verified_relative_error_pct: v.relative_error_pct,
            within_tolerance: v.within_tolerance,
            surface_rounds: self.round + 1,
            batches: self.batches.len(),
            drilling: self.drilling.clone(),
            targets: v.checks.clone(),
            simulations: None,
            bayesian: None,
        };
        self.decide(self.stage, wording::finished(&summary.parameters));
        self.status = Status::Finished;
        self.summary = Some(summary.clone());
        Next::Finished(summary)
    }
}
