//! The campaign state machine: [`Campaign::start`] issues the screening batch, every
//! [`Campaign::advance`] turns a finished batch into a decision and the next batch.

use std::collections::BTreeMap;

use repose_api::{
    BatchRequest, CcdVariantName, DesignRequest, ExperimentTemplate, FactorSpec, ModelName,
    RunState, RunView,
};
use repose_doe::design::{
    rotatable_alpha, splitmix64, Factor, PathClamp, PathDirection, SteepestPath,
};
use repose_doe::{
    fit_with_options, optimize, Fit, FitOptions, Goal, Model, ModelKind, Objective, OptimumOptions,
    OptimumResult, Region,
};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::error::CampaignError;
use crate::request::{
    relative_error_pct, CampaignRequest, PathDirectionSetting, PathStartSetting, SurfaceDesign,
};

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
}

/// One point of the steepest path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PathPoint {
    /// 1-based step number (1 = start point), as the paper's Table 5.
    pub step: usize,
    /// Natural values of the carried factors.
    pub natural: Vec<f64>,
    /// Screening model's prediction.
    pub predicted: f64,
    /// Mean simulated response, once run.
    pub response: Option<f64>,
    /// Completed runs behind `response`.
    pub runs: usize,
}

/// Stage 2 state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PathState {
    /// Carried factors.
    pub factors: Vec<String>,
    /// Their coded screening coefficients.
    pub coefficients: Vec<f64>,
    /// The factor with the largest |coefficient|, which moves one half-range per step.
    pub base_factor: String,
    /// Ascent or descent.
    pub direction: PathDirection,
    /// Start rule used.
    pub start: PathStartSetting,
    /// Natural step of every carried factor (the paper's Eqs. 13-15).
    pub step_natural: Vec<f64>,
    /// All points the path may visit (up to `max_points`, cut where every factor is stuck at
    /// its bound).
    pub points: Vec<PathPoint>,
    /// Points sent out so far.
    pub dispatched: usize,
    /// Index of the point chosen as the response-surface centre.
    pub centre: Option<usize>,
    /// Whether the simulated responses bracketed (or hit) the target.
    pub crossed: bool,
}

/// Quadratic fit summary of one response-surface round.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceFitSummary {
    /// R².
    pub r2: f64,
    /// Adjusted R².
    pub adj_r2: f64,
    /// Predicted R².
    pub pred_r2: Option<f64>,
    /// Model p-value.
    pub model_p: Option<f64>,
    /// Lack-of-fit p-value (needs replicated points).
    pub lack_of_fit_p: Option<f64>,
    /// Terms with p < alpha.
    pub significant_terms: Vec<String>,
    /// Coded coefficients by term.
    pub coefficients: BTreeMap<String, f64>,
}

/// One solution on the level set, for the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelSetPoint {
    /// Coded settings.
    pub coded: Vec<f64>,
    /// Natural settings.
    pub natural: Vec<f64>,
    /// Predicted response.
    pub predicted: f64,
    /// Desirability.
    pub desirability: f64,
}

/// Stage 4 outcome of one round.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OptimumChoice {
    /// Chosen setting, coded.
    pub coded: Vec<f64>,
    /// Chosen setting, natural.
    pub natural: Vec<f64>,
    /// Predicted response there.
    pub predicted: f64,
    /// Its desirability.
    pub desirability: f64,
    /// Whether the target is met on a whole set of settings.
    pub level_set: bool,
    /// Starts of the search.
    pub starts: usize,
    /// Starts that ended tied with the best.
    pub starts_at_best: usize,
    /// Distinct tied settings found.
    pub distinct_at_best: usize,
    /// Largest coded distance between tied settings.
    pub spread: f64,
    /// Natural per-factor extent of the tied settings.
    pub natural_min: Vec<f64>,
    /// Natural per-factor extent of the tied settings.
    pub natural_max: Vec<f64>,
    /// Coded per-factor extent of the tied settings.
    pub coded_min: Vec<f64>,
    /// Coded per-factor extent of the tied settings.
    pub coded_max: Vec<f64>,
    /// Solutions listed (closest to the design centre first).
    pub solutions: Vec<LevelSetPoint>,
    /// The optimiser's one-sentence summary.
    pub note: String,
}

/// Stages 3 and 4 of one round.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceRound {
    /// 0 for the first round.
    pub round: u32,
    /// Carried factors with the design's low/high levels (clamped to the allowed ranges).
    pub factors: Vec<Factor>,
    /// Point the design is centred on (natural).
    pub centre: Vec<f64>,
    /// Requested half-ranges before clamping (natural).
    pub half_ranges: Vec<f64>,
    /// Design submitted.
    pub design: DesignRequest,
    /// Region searched for the optimum (coded).
    pub region: Region,
    /// Fit summary once the batch finished.
    pub fit: Option<SurfaceFitSummary>,
    /// Optimum once computed.
    pub optimum: Option<OptimumChoice>,
}

/// Stage 5 outcome of one round.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VerificationOutcome {
    /// Response-surface round verified.
    pub round: u32,
    /// Factor names.
    pub factors: Vec<String>,
    /// Setting simulated (natural).
    pub point: Vec<f64>,
    /// Prediction of the quadratic model there.
    pub predicted: f64,
    /// Responses of the completed replicates.
    pub responses: Vec<f64>,
    /// Their mean.
    pub mean: f64,
    /// Their sample standard deviation (0 for one run).
    pub std: f64,
    /// `|mean - target| / |target|`, percent.
    pub relative_error_pct: f64,
    /// `mean - target`.
    pub error: f64,
    /// Within the tolerance.
    pub within_tolerance: bool,
}

/// One compared drilling metric.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DrillMetric {
    /// Metric name.
    pub name: String,
    /// Measured value.
    pub measured: f64,
    /// Mean over the completed runs (None if no run reported it).
    pub simulated: Option<f64>,
    /// Relative error, percent.
    pub relative_error_pct: Option<f64>,
    /// Within `tolerance_pct`.
    pub within_tolerance: bool,
}

/// Stage 6 outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DrillingOutcome {
    /// Per metric.
    pub metrics: Vec<DrillMetric>,
    /// All metrics within tolerance.
    pub passed: bool,
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
}

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

fn coded(factors: &[Factor], natural: &[f64]) -> Vec<f64> {
    factors
        .iter()
        .zip(natural)
        .map(|(f, v)| (v - f.centre()) / f.half_range())
        .collect()
}

/// Coded → natural in the weighted form of `Factor::to_natural`, so that coded ±1 land exactly
/// on `low`/`high` (`centre + c·half_range` gives 0.29999999999999993 for 0.3, which a clamp to
/// the allowed range then rejects).
fn natural(factors: &[Factor], coded: &[f64]) -> Vec<f64> {
    factors
        .iter()
        .zip(coded)
        .map(|(f, c)| 0.5 * ((1.0 - c) * f.low + (1.0 + c) * f.high))
        .collect()
}

/// Formats a number with 4 significant digits for decision texts.
pub(crate) fn fmt_num(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        s
    }
}

pub(crate) fn fmt_p(p: Option<f64>) -> String {
    match p {
        Some(p) if p < 1e-4 => "< 0.0001".to_owned(),
        Some(p) => format!("{p:.4}"),
        None => "n/a".to_owned(),
    }
}

fn list(names: &[String]) -> String {
    match names.len() {
        0 => "none".to_owned(),
        1 => names[0].clone(),
        n => format!("{} and {}", names[..n - 1].join(", "), names[n - 1]),
    }
}

/// Writes `value` at a dotted path, creating objects on the way (a spec override need not
/// hold the key yet; merged over a preset it lands where the factor path points).
fn set_path(spec: &mut Value, path: &str, value: f64) -> Result<(), String> {
    let mut current = spec;
    let segments: Vec<&str> = path.split('.').collect();
    if segments.iter().any(|s| s.is_empty()) {
        return Err(format!("path `{path}` is empty or has an empty segment"));
    }
    for (i, seg) in segments.iter().enumerate() {
        let last = i + 1 == segments.len();
        current = match current {
            Value::Object(map) => {
                if last {
                    map.insert(
                        (*seg).to_owned(),
                        serde_json::Number::from_f64(value)
                            .map(Value::Number)
                            .unwrap_or(Value::Null),
                    );
                    return Ok(());
                }
                map.entry((*seg).to_owned())
                    .or_insert_with(|| Value::Object(serde_json::Map::new()))
            }
            Value::Array(items) => {
                let index: usize = seg
                    .parse()
                    .map_err(|_| format!("path `{path}`: `{seg}` is not an array index"))?;
                let slot = items
                    .get_mut(index)
                    .ok_or_else(|| format!("path `{path}`: index {index} out of range"))?;
                if last {
                    *slot = serde_json::Number::from_f64(value)
                        .map(Value::Number)
                        .unwrap_or(Value::Null);
                    return Ok(());
                }
                slot
            }
            _ => return Err(format!("path `{path}`: `{seg}` is under a non-object")),
        };
    }
    Ok(())
}

/// Fits the first-order screening model over all candidates.
pub(crate) fn screening_fit(
    request: &CampaignRequest,
    batch: usize,
    runs: &[RunView],
) -> Result<Result<Fit, String>, CampaignError> {
    let names: Vec<String> = request.factors.iter().map(|f| f.name.clone()).collect();
    let factors = candidate_factors(request);
    let (x, y, _) = observations(batch, runs, &names, &request.response)?;
    let coded_rows: Vec<Vec<f64>> = x.iter().map(|p| coded(&factors, p)).collect();
    let model = match Model::linear(&names) {
        Ok(m) => m,
        Err(e) => return Ok(Err(e.to_string())),
    };
    let options = FitOptions {
        response_name: request.response.clone(),
        confidence: 1.0 - request.alpha,
        backward_alpha: None,
    };
    Ok(
        fit_with_options(&model, &coded_rows, &y, &options).map_err(|e| {
            format!(
                "the screening model could not be fitted to the {} completed runs: {e}",
                y.len()
            )
        }),
    )
}

/// Fits the quadratic model of a response-surface round.
pub(crate) fn surface_fit(
    request: &CampaignRequest,
    round: &SurfaceRound,
    batch: usize,
    runs: &[RunView],
) -> Result<Result<Fit, String>, CampaignError> {
    let names: Vec<String> = round.factors.iter().map(|f| f.name.clone()).collect();
    let (x, y, _) = observations(batch, runs, &names, &request.response)?;
    let coded_rows: Vec<Vec<f64>> = x.iter().map(|p| coded(&round.factors, p)).collect();
    let model = match Model::new(&names, ModelKind::Quadratic) {
        Ok(m) => m,
        Err(e) => return Ok(Err(e.to_string())),
    };
    let options = FitOptions {
        response_name: request.response.clone(),
        confidence: 1.0 - request.alpha,
        backward_alpha: None,
    };
    Ok(
        fit_with_options(&model, &coded_rows, &y, &options).map_err(|e| {
            format!(
                "the quadratic model could not be fitted to the {} completed runs: {e}",
                y.len()
            )
        }),
    )
}

fn candidate_factors(request: &CampaignRequest) -> Vec<Factor> {
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

/// The desirability search for the target on a fitted surface, as `repose analyze` does it:
/// desirability 1 at the target, falling to 0 at the observed range widened by 5 % (and to
/// include the target).
pub(crate) fn search_target(
    fit: &Fit,
    target: f64,
    observed: &[f64],
    factors: &[Factor],
    region: Region,
    starts: usize,
) -> Result<OptimumResult, String> {
    let (min, max) = observed
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| {
            (a.min(y), b.max(y))
        });
    let span = (max - min).max(f64::EPSILON);
    let goal = Goal::Target {
        target,
        lower: min.min(target) - 0.05 * span,
        upper: max.max(target) + 0.05 * span,
    };
    let options = OptimumOptions {
        region,
        starts,
        factor_ranges: Some(factors.to_vec()),
        ..OptimumOptions::default()
    };
    optimize(&[Objective::new(fit, goal)], &options).map_err(|e| e.to_string())
}

impl Campaign {
    /// Validates the request and issues the screening batch.
    pub fn start(request: CampaignRequest) -> Result<(Campaign, BatchRequest), CampaignError> {
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
        };
        let r = &campaign.request;
        let factors = r
            .factors
            .iter()
            .map(|f| FactorSpec {
                name: f.name.clone(),
                path: f.path.clone(),
                low: f.low,
                high: f.high,
            })
            .collect();
        let experiment = r
            .stage_experiments
            .screening
            .clone()
            .unwrap_or_else(|| r.experiment.clone());
        let design = r.screening.design.clone();
        let replicates = r.screening.replicates;
        let names: Vec<String> = r.factors.iter().map(|f| f.name.clone()).collect();
        let text = format!(
            "Screen {} candidate factors ({}) with a {} design, linear model, significance α = {}.",
            names.len(),
            list(&names),
            describe_design(&design),
            r.alpha
        );
        campaign.decide(StageKind::Screening, text);
        let batch = campaign.issue(
            StageKind::Screening,
            experiment,
            factors,
            design,
            replicates,
            ModelName::Linear,
            Vec::new(),
        );
        Ok((campaign, batch))
    }

    /// Index of the outstanding batch, if any.
    pub fn outstanding(&self) -> Option<usize> {
        match self.status {
            Status::Running => self.batches.len().checked_sub(1),
            _ => None,
        }
    }

    /// Feeds the finished outstanding batch and returns what to do next.
    pub fn advance(&mut self, finished: &StageResult) -> Result<Next, CampaignError> {
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
        let next = match self.batches[expected].stage {
            StageKind::Screening => self.after_screening(finished)?,
            StageKind::Steepest => self.after_path(finished)?,
            StageKind::ResponseSurface => self.after_surface(finished)?,
            StageKind::Verification => self.after_verification(finished)?,
            StageKind::Drilling => self.after_drilling(finished)?,
            StageKind::Optimum => unreachable!("the optimum stage issues no batch"),
        };
        if let Next::NeedsAttention(reason) = &next {
            self.status = Status::NeedsAttention {
                reason: reason.clone(),
            };
            self.decide(self.stage, format!("Stopped: {reason}"));
        }
        Ok(next)
    }

    fn decide(&mut self, stage: StageKind, text: String) {
        self.decisions.push(Decision {
            stage,
            round: self.round,
            text,
        });
    }

    #[allow(clippy::too_many_arguments)]
    fn issue(
        &mut self,
        stage: StageKind,
        experiment: ExperimentTemplate,
        factors: Vec<FactorSpec>,
        design: DesignRequest,
        replicates: u32,
        model: ModelName,
        path_points: Vec<usize>,
    ) -> BatchRequest {
        let index = self.batches.len();
        let r = &self.request;
        let name = match stage {
            StageKind::ResponseSurface | StageKind::Verification if self.round > 0 => {
                format!("{}: {} (round {})", r.name, stage.label(), self.round + 1)
            }
            StageKind::Steepest if index > 1 => {
                format!(
                    "{}: {} (points {}+)",
                    r.name,
                    stage.label(),
                    path_points[0] + 1
                )
            }
            _ => format!("{}: {}", r.name, stage.label()),
        };
        let (response, target) = match (stage, &r.drilling) {
            (StageKind::Drilling, Some(d)) => {
                let (k, v) = d.measured.iter().next().expect("validated non-empty");
                (k.clone(), Some(*v))
            }
            _ => (r.response.clone(), Some(r.target)),
        };
        let request = BatchRequest {
            name,
            experiment,
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
        });
        request
    }

    /// Template of a post-screening stage with the held factors written at their paths.
    fn held_template(&self, stage: StageKind) -> Result<ExperimentTemplate, CampaignError> {
        let r = &self.request;
        let base = match stage {
            StageKind::Steepest => r.stage_experiments.steepest.as_ref(),
            StageKind::ResponseSurface => r.stage_experiments.response_surface.as_ref(),
            StageKind::Verification => r.stage_experiments.verification.as_ref(),
            _ => None,
        }
        .unwrap_or(&r.experiment);
        let mut template = base.clone();
        if let Some(s) = &self.screening {
            for h in &s.held {
                let path = &r
                    .factors
                    .iter()
                    .find(|f| f.name == h.name)
                    .expect("held factors are candidates")
                    .path;
                set_path(&mut template.spec, path, h.value).map_err(|reason| {
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
                    .map(|c| c.path.clone())
                    .unwrap_or_default(),
                low: f.low,
                high: f.high,
            })
            .collect()
    }

    // ----------------------------------------------------------------------------------------
    // Stage 1
    // ----------------------------------------------------------------------------------------

    fn after_screening(&mut self, finished: &StageResult) -> Result<Next, CampaignError> {
        let fit = match screening_fit(&self.request, finished.batch, &finished.runs)? {
            Ok(fit) => fit,
            Err(reason) => return Ok(Next::NeedsAttention(reason)),
        };
        let r = &self.request;
        let names: Vec<String> = r.factors.iter().map(|f| f.name.clone()).collect();
        let coefs: Vec<_> = names
            .iter()
            .map(|n| {
                fit.coefficient(n)
                    .cloned()
                    .expect("linear model has every factor")
            })
            .collect();
        let estimates: Vec<f64> = coefs.iter().map(|c| c.estimate).collect();
        let t_values: Vec<Option<f64>> = coefs.iter().map(|c| c.t_value).collect();
        let p_values: Vec<Option<f64>> = names
            .iter()
            .map(|n| fit.term_anova(n).and_then(|row| row.p))
            .collect();
        let intercept = fit.coefficient("Intercept").map_or(0.0, |c| c.estimate);
        let t_critical = coefs
            .iter()
            .find(|c| c.std_error > 0.0)
            .map_or(f64::NAN, |c| (c.ci_high - c.estimate) / c.std_error);
        let abs_t = |i: usize| t_values[i].map_or(0.0, f64::abs);
        let mut by_t: Vec<usize> = (0..names.len()).collect();
        by_t.sort_by(|&a, &b| abs_t(b).total_cmp(&abs_t(a)));
        let significant: Vec<usize> = by_t
            .iter()
            .copied()
            .filter(|&i| p_values[i].is_some_and(|p| p < r.alpha))
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

        let sig_text = |idx: &[usize]| -> String {
            idx.iter()
                .map(|&i| {
                    format!(
                        "{} (p {}, t {})",
                        names[i],
                        fmt_p(p_values[i]),
                        fmt_num(t_values[i].unwrap_or(f64::NAN))
                    )
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        let carried_names: Vec<String> = carried.iter().map(|&i| names[i].clone()).collect();
        let mut text = match &rule {
            CarryRule::Significant => format!(
                "{} significant at α = {}: {}. They are carried forward.",
                list(&carried_names),
                r.alpha,
                sig_text(&significant)
            ),
            CarryRule::TopOfSignificant { dropped } => format!(
                "{} factors are significant at α = {} ({}), more than the {} a response surface is \
                 planned for; the {} with the largest |t| are carried ({}), {} is/are held like the \
                 non-significant ones.",
                significant.len(),
                r.alpha,
                sig_text(&significant),
                max,
                max,
                list(&carried_names),
                list(dropped)
            ),
            CarryRule::NoneSignificant => format!(
                "No factor is significant at α = {} (smallest p {}): the screening cannot separate \
                 any effect from noise. Fallback: the {} with the largest |t| ({}) are carried \
                 anyway; consider more replicates or wider ranges if the path does not move the \
                 response.",
                r.alpha,
                fmt_p(p_values.iter().flatten().copied().reduce(f64::min)),
                carried.len(),
                sig_text(&carried)
            ),
        };
        if !held.is_empty() {
            let held_names: Vec<String> = held.iter().map(|h| h.name.clone()).collect();
            let values: Vec<String> = held
                .iter()
                .map(|h| {
                    format!(
                        "{}{}",
                        fmt_num(h.value),
                        if h.user_value { " (user value)" } else { "" }
                    )
                })
                .collect();
            text.push_str(&format!(
                " {} held at {} (mid-range unless the user fixed a value).",
                list(&held_names),
                values.join(", ")
            ));
        }
        self.decide(StageKind::Screening, text);
        self.screening = Some(ScreeningOutcome {
            factors: names.clone(),
            estimates: estimates.clone(),
            t_values,
            p_values,
            intercept,
            t_critical,
            significant: significant.iter().map(|&i| names[i].clone()).collect(),
            carried: carried_names.clone(),
            rule,
            held,
        });

        // Stage 2: lay out the path.
        let coefficients: Vec<f64> = carried.iter().map(|&i| estimates[i]).collect();
        if coefficients.iter().all(|b| *b == 0.0) {
            return Ok(Next::NeedsAttention(
                "every carried coefficient is zero: the screening model has no direction".into(),
            ));
        }
        let all = candidate_factors(&self.request);
        let path_factors: Vec<Factor> = carried.iter().map(|&i| all[i].clone()).collect();
        let settings = self.request.steepest.clone();
        let target = self.request.target;
        let predict =
            |c: &[f64]| intercept + coefficients.iter().zip(c).map(|(b, x)| b * x).sum::<f64>();
        let corner = |dir: PathDirection| -> Vec<f64> {
            coefficients
                .iter()
                .map(|b| if b * dir.sign() >= 0.0 { -1.0 } else { 1.0 })
                .collect()
        };
        let (direction, why) = match (settings.direction, settings.start) {
            (PathDirectionSetting::Ascent, _) => (PathDirection::Ascent, "as requested".to_owned()),
            (PathDirectionSetting::Descent, _) => {
                (PathDirection::Descent, "as requested".to_owned())
            }
            (PathDirectionSetting::Auto, PathStartSetting::Centre) => {
                if target >= intercept {
                    (
                        PathDirection::Ascent,
                        format!(
                            "the target {} is above the centre prediction {}",
                            fmt_num(target),
                            fmt_num(intercept)
                        ),
                    )
                } else {
                    (
                        PathDirection::Descent,
                        format!(
                            "the target {} is below the centre prediction {}",
                            fmt_num(target),
                            fmt_num(intercept)
                        ),
                    )
                }
            }
            (PathDirectionSetting::Auto, PathStartSetting::Corner) => {
                let pa = predict(&corner(PathDirection::Ascent));
                let pd = predict(&corner(PathDirection::Descent));
                let ascent_ok = pa < target;
                let descent_ok = pd > target;
                let ascent = match (ascent_ok, descent_ok) {
                    (true, true) => (target - pa).abs() <= (pd - target).abs(),
                    (a, _) => a,
                };
                let dir = if ascent {
                    PathDirection::Ascent
                } else {
                    PathDirection::Descent
                };
                (
                    dir,
                    format!(
                        "the model predicts {} at the low-response corner and {} at the high-response \
                         corner; the path starts from the corner {} the target {} and walks toward it",
                        fmt_num(pa),
                        fmt_num(pd),
                        match (ascent_ok && descent_ok, ascent) {
                            (true, _) => "nearer",
                            (false, true) => "below",
                            (false, false) => "above",
                        },
                        fmt_num(target)
                    ) + if ascent_ok != descent_ok {
                        " (the target lies beyond both corners' predictions, so the path may not \
                         reach it)"
                    } else {
                        ""
                    },
                )
            }
        };
        let mut spec = SteepestPath::spec(coefficients.clone(), path_factors.clone(), direction)
            .steps(settings.max_points - 1)
            .clamp(PathClamp::FactorRange);
        if settings.start == PathStartSetting::Corner {
            spec = spec.start_at(natural(&path_factors, &corner(direction)));
        }
        if let Some(d) = settings.round_decimals {
            spec = spec.round_steps_to(d);
        }
        let path = spec.build().map_err(|e| CampaignError::Design {
            stage: "steepest path".into(),
            reason: e.to_string(),
        })?;
        let mut points: Vec<PathPoint> = Vec::new();
        for (i, (p, c)) in path.points.iter().zip(&path.coded_points).enumerate() {
            if let Some(prev) = points.last() {
                if prev
                    .natural
                    .iter()
                    .zip(p)
                    .all(|(a, b)| (a - b).abs() <= 1e-12)
                {
                    break; // every factor is stuck at its bound
                }
            }
            points.push(PathPoint {
                step: i + 1,
                natural: p.clone(),
                predicted: predict(c),
                response: None,
                runs: 0,
            });
        }
        let base = path.factor_names[path.base_factor].clone();
        let steps: Vec<String> = path
            .factor_names
            .iter()
            .zip(&path.step_natural)
            .map(|(n, s)| format!("{n} {}", fmt_num(*s)))
            .collect();
        let dir_name = match direction {
            PathDirection::Ascent => "ascent",
            PathDirection::Descent => "descent",
        };
        let mut text = format!(
            "Steepest {dir_name} ({why}). Base factor {base} (largest |coefficient| {}) moves one \
             half-range per step; the others move in proportion to their coefficients{}: steps {}. \
             The path has {} points within the allowed ranges",
            fmt_num(coefficients[path.base_factor].abs()),
            settings
                .round_decimals
                .map_or(String::new(), |d| format!(", rounded to {d} decimals")),
            steps.join(", "),
            points.len(),
        );
        if points.len() < settings.max_points {
            text.push_str(" (it ends where every factor sits at its bound)");
        }
        text.push('.');
        self.decide(StageKind::Steepest, text);
        self.path = Some(PathState {
            factors: carried_names,
            coefficients,
            base_factor: base,
            direction,
            start: settings.start,
            step_natural: path.step_natural.clone(),
            points,
            dispatched: 0,
            centre: None,
            crossed: false,
        });
        self.dispatch_path().map(Next::Submit)
    }

    // ----------------------------------------------------------------------------------------
    // Stage 2
    // ----------------------------------------------------------------------------------------

    fn dispatch_path(&mut self) -> Result<BatchRequest, CampaignError> {
        let per = self.request.steepest.points_per_dispatch;
        let path = self.path.as_ref().expect("path laid out");
        let from = path.dispatched;
        let to = (from + per).min(path.points.len());
        let indices: Vec<usize> = (from..to).collect();
        let points: Vec<Vec<f64>> = indices
            .iter()
            .map(|&i| path.points[i].natural.clone())
            .collect();
        let all = candidate_factors(&self.request);
        let factors: Vec<Factor> = path
            .factors
            .iter()
            .map(|n| {
                all.iter()
                    .find(|f| &f.name == n)
                    .cloned()
                    .expect("candidate")
            })
            .collect();
        let specs = self.factor_specs(&factors);
        let experiment = self.held_template(StageKind::Steepest)?;
        let replicates = self.request.steepest.replicates;
        self.path.as_mut().expect("path").dispatched = to;
        Ok(self.issue(
            StageKind::Steepest,
            experiment,
            specs,
            DesignRequest::Explicit { points },
            replicates,
            ModelName::None,
            indices,
        ))
    }

    fn after_path(&mut self, finished: &StageResult) -> Result<Next, CampaignError> {
        let target = self.request.target;
        let tolerance = self.request.tolerance;
        let issued = self.batches[finished.batch].clone();
        let names = self.path.as_ref().expect("path").factors.clone();
        let (_, y, rows) = observations(
            finished.batch,
            &finished.runs,
            &names,
            &self.request.response,
        )?;
        let path = self.path.as_mut().expect("path");
        let mut sums: BTreeMap<usize, (f64, usize)> = BTreeMap::new();
        for (v, row) in y.iter().zip(&rows) {
            if let Some(&point) = issued.path_points.get(*row as usize) {
                let e = sums.entry(point).or_insert((0.0, 0));
                e.0 += v;
                e.1 += 1;
            }
        }
        for (point, (sum, n)) in sums {
            path.points[point].response = Some(sum / n as f64);
            path.points[point].runs = n;
        }
        let evaluated: Vec<(usize, f64)> = path.points[..path.dispatched]
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.response.map(|r| (i, r)))
            .collect();
        let hit = evaluated.iter().any(|(_, r)| tolerance.accepts(*r, target));
        let crossing = evaluated
            .windows(2)
            .find(|w| (w[0].1 - target).signum() != (w[1].1 - target).signum());
        let exhausted = path.dispatched >= path.points.len();
        if !(hit || crossing.is_some() || exhausted) {
            return self.dispatch_path().map(Next::Submit);
        }
        // The paper's path stops at the crossing; points beyond it were only run because
        // several are dispatched at once. They do not compete for the centre: with noise one
        // of them can look closest and put the response surface past the target.
        let candidates: &[(usize, f64)] = match crossing {
            Some(w) if !hit => {
                let end = evaluated
                    .iter()
                    .position(|e| e.0 == w[1].0)
                    .expect("in evaluated");
                &evaluated[..=end]
            }
            _ => &evaluated,
        };
        let Some(&(centre, best)) = candidates
            .iter()
            .min_by(|a, b| (a.1 - target).abs().total_cmp(&(b.1 - target).abs()))
        else {
            return Ok(Next::NeedsAttention(
                "no steepest-path run completed, so there is no point to centre the response \
                 surface on"
                    .into(),
            ));
        };
        path.centre = Some(centre);
        path.crossed = hit || crossing.is_some();
        let responses: Vec<String> = evaluated
            .iter()
            .map(|(i, r)| {
                format!(
                    "step {}: {} ({}%)",
                    path.points[*i].step,
                    fmt_num(*r),
                    fmt_num(relative_error_pct(*r, target))
                )
            })
            .collect();
        let centre_point = path.points[centre].clone();
        let point_text: Vec<String> = names
            .iter()
            .zip(&centre_point.natural)
            .map(|(n, v)| format!("{n} {}", fmt_num(*v)))
            .collect();
        let text = if let Some(w) = crossing {
            format!(
                "Responses along the path: {}. The response crosses the target {} between steps {} \
                 and {}; step {} is the closest up to the crossing ({}, relative error {}%; later \
                 steps do not count) and becomes the centre of the response surface ({}).",
                responses.join(", "),
                fmt_num(target),
                path.points[w[0].0].step,
                path.points[w[1].0].step,
                centre_point.step,
                fmt_num(best),
                fmt_num(relative_error_pct(best, target)),
                point_text.join(", ")
            )
        } else if hit {
            format!(
                "Responses along the path: {}. Step {} is already within tolerance of the target \
                 and becomes the centre of the response surface ({}).",
                responses.join(", "),
                centre_point.step,
                point_text.join(", ")
            )
        } else {
            format!(
                "Responses along the path: {}. The path never crossed the target {} within its {} \
                 points (the allowed ranges or max_points end it). Fallback: the closest point, \
                 step {} ({}, relative error {}%; {}), becomes the centre anyway; the response surface \
                 may not contain the target, in which case the optimum stage reports the closest \
                 reachable setting and verification decides.",
                responses.join(", "),
                fmt_num(target),
                path.points.len(),
                centre_point.step,
                fmt_num(best),
                fmt_num(relative_error_pct(best, target)),
                point_text.join(", ")
            )
        };
        let half: Vec<f64> = path.step_natural.iter().map(|s| s.abs()).collect();
        self.decide(StageKind::Steepest, text);
        self.start_surface(centre_point.natural, half)
    }

    // ----------------------------------------------------------------------------------------
    // Stage 3
    // ----------------------------------------------------------------------------------------

    fn start_surface(&mut self, centre: Vec<f64>, half: Vec<f64>) -> Result<Next, CampaignError> {
        let names = self.path.as_ref().expect("path").factors.clone();
        let allowed: Vec<Factor> = names
            .iter()
            .map(|n| {
                candidate_factors(&self.request)
                    .into_iter()
                    .find(|f| &f.name == n)
                    .expect("candidate")
            })
            .collect();
        let k = names.len();
        let mut notes = Vec::new();
        let mut half = half;
        for (i, h) in half.iter_mut().enumerate() {
            let floor = 0.05 * allowed[i].half_range();
            if *h < floor {
                notes.push(format!(
                    "{}'s half-range {} is below 5 % of its allowed half-range and was raised to {}",
                    names[i],
                    fmt_num(*h),
                    fmt_num(floor)
                ));
                *h = floor;
            }
        }
        let mut design_setting = self.request.response_surface.design.clone();
        let centre_points = design_setting.centre_points();
        let clamp = |h: &[f64], scale: f64| -> Vec<Factor> {
            allowed
                .iter()
                .zip(&centre)
                .zip(h)
                .map(|((a, c), h)| Factor {
                    name: a.name.clone(),
                    low: (c - scale * h).max(a.low),
                    high: (c + scale * h).min(a.high),
                })
                .collect()
        };
        if let SurfaceDesign::CentralComposite {
            variant: CcdVariantName::Circumscribed,
            centre_points,
        } = design_setting
        {
            let alpha = rotatable_alpha(k.max(2));
            let star = clamp(&half, alpha);
            let fits = star.iter().zip(&centre).zip(&half).all(|((f, c), h)| {
                f.low <= c - alpha * h + 1e-12 && f.high >= c + alpha * h - 1e-12
            });
            if !fits {
                notes.push(format!(
                    "circumscribed star points (α = {}) would leave the allowed ranges, so the \
                     design is inscribed instead",
                    fmt_num(alpha)
                ));
                design_setting = SurfaceDesign::CentralComposite {
                    variant: CcdVariantName::Inscribed,
                    centre_points,
                };
            }
        }
        let factors = clamp(&half, 1.0);
        for f in &factors {
            if f.low >= f.high {
                return Ok(Next::NeedsAttention(format!(
                    "the response-surface range of {} is empty after clamping to the allowed range",
                    f.name
                )));
            }
        }
        let (design, region, label) = match (&design_setting, k) {
            (_, 1) => {
                let mut coded = vec![-1.0, -0.5, 0.5, 1.0];
                coded.extend(std::iter::repeat_n(0.0, centre_points.max(1)));
                let points = coded.iter().map(|c| natural(&factors, &[*c])).collect();
                (
                    DesignRequest::Explicit { points },
                    Region::Cube,
                    "a five-level line (one factor)".to_owned(),
                )
            }
            (SurfaceDesign::BoxBehnken { .. }, 3..=7) => (
                DesignRequest::BoxBehnken {
                    centre_points: Some(centre_points),
                },
                Region::Cube,
                format!("a Box–Behnken design with {centre_points} centre points"),
            ),
            (SurfaceDesign::BoxBehnken { .. }, _) => (
                DesignRequest::CentralComposite {
                    variant: CcdVariantName::FaceCentred,
                    centre_points,
                },
                Region::Cube,
                format!(
                    "a face-centred central composite design with {centre_points} centre points \
                     (Box–Behnken needs 3 to 7 factors, {k} are carried)"
                ),
            ),
            (SurfaceDesign::CentralComposite { variant, .. }, _) => (
                DesignRequest::CentralComposite {
                    variant: *variant,
                    centre_points,
                },
                match variant {
                    CcdVariantName::Circumscribed => Region::Sphere {
                        radius: rotatable_alpha(k),
                    },
                    _ => Region::Cube,
                },
                format!(
                    "a {variant:?} central composite design with {centre_points} centre points"
                ),
            ),
        };
        let levels: Vec<String> = factors
            .iter()
            .map(|f| format!("{} {}..{}", f.name, fmt_num(f.low), fmt_num(f.high)))
            .collect();
        let mut text = if self.round == 0 {
            format!(
                "Response surface: {label} around the path's centre point, half-ranges = the path \
                 steps, clamped to the allowed ranges: {}; full quadratic model.",
                levels.join(", ")
            )
        } else {
            format!(
                "Response surface round {}: {label} centred at the last optimum (half-ranges as \
                 the verification decided), clamped to the allowed ranges: {}; full quadratic \
                 model.",
                self.round + 1,
                levels.join(", ")
            )
        };
        for n in notes {
            text.push_str(&format!(" Note: {n}."));
        }
        self.decide(StageKind::ResponseSurface, text);
        self.surfaces.push(SurfaceRound {
            round: self.round,
            factors: factors.clone(),
            centre,
            half_ranges: half,
            design: design.clone(),
            region,
            fit: None,
            optimum: None,
        });
        let specs = self.factor_specs(&factors);
        let experiment = self.held_template(StageKind::ResponseSurface)?;
        let replicates = self.request.response_surface.replicates;
        Ok(Next::Submit(self.issue(
            StageKind::ResponseSurface,
            experiment,
            specs,
            design,
            replicates,
            ModelName::Quadratic,
            Vec::new(),
        )))
    }

    fn after_surface(&mut self, finished: &StageResult) -> Result<Next, CampaignError> {
        let round = self.surfaces.last().expect("surface round").clone();
        let fit = match surface_fit(&self.request, &round, finished.batch, &finished.runs)? {
            Ok(fit) => fit,
            Err(reason) => return Ok(Next::NeedsAttention(reason)),
        };
        let alpha = self.request.alpha;
        let target = self.request.target;
        let row_p = |s: &str| fit.anova_row(s).and_then(|r| r.p);
        let significant_terms: Vec<String> = fit
            .model()
            .terms()
            .iter()
            .filter(|t| !t.is_intercept())
            .filter(|t| {
                fit.term_anova(t.name())
                    .and_then(|r| r.p)
                    .is_some_and(|p| p < alpha)
            })
            .map(|t| t.name().to_owned())
            .collect();
        let stats = fit.stats().clone();
        let summary = SurfaceFitSummary {
            r2: stats.r2,
            adj_r2: stats.adj_r2,
            pred_r2: stats.pred_r2,
            model_p: row_p("Model"),
            lack_of_fit_p: row_p("Lack of Fit"),
            significant_terms: significant_terms.clone(),
            coefficients: fit.coefficient_map(),
        };
        let mut text = format!(
            "Quadratic model: p(model) {}, R² {}, adjusted R² {}, predicted R² {}; terms \
             significant at α = {}: {}.",
            fmt_p(summary.model_p),
            fmt_num(stats.r2),
            fmt_num(stats.adj_r2),
            stats.pred_r2.map_or("n/a".into(), fmt_num),
            alpha,
            list(&significant_terms)
        );
        match summary.lack_of_fit_p {
            Some(p) if p < alpha => text.push_str(&format!(
                " Lack of fit is significant (p {}): the quadratic model misses structure; \
                 verification will tell whether the optimum holds.",
                fmt_p(Some(p))
            )),
            Some(p) => text.push_str(&format!(
                " Lack of fit not significant (p {}).",
                fmt_p(Some(p))
            )),
            None => {}
        }
        if summary.model_p.is_some_and(|p| p >= alpha) {
            text.push_str(
                " The model as a whole is not significant: the optimum below rests on a weak fit.",
            );
        }
        self.decide(StageKind::ResponseSurface, text);
        let names: Vec<String> = round.factors.iter().map(|f| f.name.clone()).collect();
        let (_, y, _) = observations(
            finished.batch,
            &finished.runs,
            &names,
            &self.request.response,
        )?;
        let result = match search_target(
            &fit,
            target,
            &y,
            &round.factors,
            round.region,
            self.request.response_surface.optimum_starts,
        ) {
            Ok(r) => r,
            Err(reason) => {
                return Ok(Next::NeedsAttention(format!(
                    "optimum search failed: {reason}"
                )))
            }
        };
        let Some(best) = result.solutions.first() else {
            return Ok(Next::NeedsAttention(
                "the optimum search found no solution".into(),
            ));
        };
        let to_point = |s: &repose_doe::Solution| LevelSetPoint {
            coded: s.coded.clone(),
            natural: s
                .natural
                .clone()
                .unwrap_or_else(|| natural(&round.factors, &s.coded)),
            predicted: s.responses.first().map_or(f64::NAN, |r| r.value),
            desirability: s.desirability,
        };
        let chosen = to_point(best);
        let choice = OptimumChoice {
            coded: chosen.coded.clone(),
            natural: chosen.natural.clone(),
            predicted: chosen.predicted,
            desirability: chosen.desirability,
            level_set: result.level_set,
            starts: result.starts,
            starts_at_best: result.starts_at_best,
            distinct_at_best: result.distinct_at_best,
            spread: result.spread,
            natural_min: result.natural_min.clone().unwrap_or_default(),
            natural_max: result.natural_max.clone().unwrap_or_default(),
            coded_min: result.coded_min.clone(),
            coded_max: result.coded_max.clone(),
            solutions: result.solutions.iter().map(to_point).collect(),
            note: result.note.clone(),
        };
        let setting: Vec<String> = names
            .iter()
            .zip(&choice.natural)
            .map(|(n, v)| format!("{n} {}", fmt_num(*v)))
            .collect();
        let extent: Vec<String> = names
            .iter()
            .enumerate()
            .filter(|(i, _)| *i < choice.natural_min.len())
            .map(|(i, n)| {
                format!(
                    "{n} {}..{}",
                    fmt_num(choice.natural_min[i]),
                    fmt_num(choice.natural_max[i])
                )
            })
            .collect();
        let text = if choice.level_set {
            format!(
                "The target {} is met on a whole level set, not at one point: {} of {} starts \
                 reached desirability {} at {} distinct settings spread over {} coded units \
                 (natural extent {}). Chosen: the tied setting closest to the design centre (the \
                 least extrapolating), {}, predicted {}.",
                fmt_num(target),
                choice.starts_at_best,
                choice.starts,
                fmt_num(result.best_desirability),
                choice.distinct_at_best,
                fmt_num(choice.spread),
                extent.join(", "),
                setting.join(", "),
                fmt_num(choice.predicted)
            )
        } else if result.best_desirability > 0.999 {
            format!(
                "The target {} is met at a single setting: {}, predicted {}.",
                fmt_num(target),
                setting.join(", "),
                fmt_num(choice.predicted)
            )
        } else {
            format!(
                "The target {} is not reachable inside the design region (best desirability {}); \
                 the closest setting is {}, predicted {}. Verification will measure the gap.",
                fmt_num(target),
                fmt_num(result.best_desirability),
                setting.join(", "),
                fmt_num(choice.predicted)
            )
        };
        let last = self.surfaces.last_mut().expect("round");
        last.fit = Some(summary);
        last.optimum = Some(choice.clone());
        self.decide(StageKind::Optimum, text);

        // Stage 5.
        let specs = self.factor_specs(&round.factors);
        let experiment = self.held_template(StageKind::Verification)?;
        let replicates = self.request.verification.replicates;
        self.decide(
            StageKind::Verification,
            format!(
                "Verify with {replicates} replicate simulations at the optimum, fresh seeds; \
                 accepted if the mean is within {}.",
                self.request.tolerance.describe()
            ),
        );
        Ok(Next::Submit(self.issue(
            StageKind::Verification,
            experiment,
            specs,
            DesignRequest::Explicit {
                points: vec![choice.natural],
            },
            replicates,
            ModelName::None,
            Vec::new(),
        )))
    }

    // ----------------------------------------------------------------------------------------
    // Stage 5
    // ----------------------------------------------------------------------------------------

    fn after_verification(&mut self, finished: &StageResult) -> Result<Next, CampaignError> {
        let round = self.surfaces.last().expect("round").clone();
        let optimum = round.optimum.clone().expect("optimum before verification");
        let names: Vec<String> = round.factors.iter().map(|f| f.name.clone()).collect();
        let (_, y, _) = observations(
            finished.batch,
            &finished.runs,
            &names,
            &self.request.response,
        )?;
        if y.is_empty() {
            return Ok(Next::NeedsAttention(
                "no verification run completed; resubmit the verification batch".into(),
            ));
        }
        let target = self.request.target;
        let n = y.len() as f64;
        let mean = y.iter().sum::<f64>() / n;
        let std = if y.len() > 1 {
            (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
        } else {
            0.0
        };
        let within = self.request.tolerance.accepts(mean, target);
        let outcome = VerificationOutcome {
            round: self.round,
            factors: names.clone(),
            point: optimum.natural.clone(),
            predicted: optimum.predicted,
            responses: y.clone(),
            mean,
            std,
            relative_error_pct: relative_error_pct(mean, target),
            error: mean - target,
            within_tolerance: within,
        };
        self.verifications.push(outcome.clone());
        let base = format!(
            "Verification: {} runs, mean {} (sd {}), target {}, relative error {}% — {} the \
             tolerance of {}.",
            y.len(),
            fmt_num(mean),
            fmt_num(std),
            fmt_num(target),
            fmt_num(outcome.relative_error_pct),
            if within { "within" } else { "outside" },
            self.request.tolerance.describe()
        );
        if within {
            self.decide(StageKind::Verification, base);
            if self.request.drilling.is_some() {
                return self.start_drilling();
            }
            return Ok(self.finish());
        }
        let max = self.request.response_surface.max_extra_rounds;
        if self.round < max {
            // A target the model could not reach means the region is in the wrong place, not
            // too coarse: move it (same size) so the optimum on its edge becomes its centre.
            // Shrinking it there would only box the search in further from the target.
            let reachable = optimum.desirability > 0.999;
            let (how, scale) = if reachable {
                ("with half the half-ranges", 0.5)
            } else {
                (
                    "with the same half-ranges (the target was not reachable inside the last \
                     region, so the region moves toward it instead of shrinking)",
                    1.0,
                )
            };
            self.decide(
                StageKind::Verification,
                format!(
                    "{base} Next step: a further response-surface round centred at this optimum \
                     {how} (round {} of at most {}).",
                    self.round + 2,
                    max + 1
                ),
            );
            self.round += 1;
            let half: Vec<f64> = round.half_ranges.iter().map(|h| h * scale).collect();
            return self.start_surface(optimum.natural, half);
        }
        self.decide(StageKind::Verification, base);
        Ok(Next::NeedsAttention(format!(
            "verification is still outside the tolerance after {} response-surface rounds (last \
             mean {}, relative error {}%). The model's optimum does not reproduce in simulation: \
             check the response's noise (replicates), the allowed ranges, or whether the target \
             is reachable.",
            self.round + 1,
            fmt_num(mean),
            fmt_num(outcome.relative_error_pct)
        )))
    }

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
            target: self.request.target,
            predicted: v.predicted,
            verified_mean: v.mean,
            verified_relative_error_pct: v.relative_error_pct,
            within_tolerance: v.within_tolerance,
            surface_rounds: self.round + 1,
            batches: self.batches.len(),
            drilling: self.drilling.clone(),
        };
        let params: Vec<String> = summary
            .parameters
            .iter()
            .map(|p| {
                format!(
                    "{} = {}{}",
                    p.name,
                    fmt_num(p.value),
                    if p.calibrated { "" } else { " (held)" }
                )
            })
            .collect();
        self.decide(self.stage, format!("Finished: {}.", params.join(", ")));
        self.status = Status::Finished;
        self.summary = Some(summary.clone());
        Next::Finished(summary)
    }

    // ----------------------------------------------------------------------------------------
    // Stage 6
    // ----------------------------------------------------------------------------------------

    fn start_drilling(&mut self) -> Result<Next, CampaignError> {
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
                path: path_of(&f.name),
                low: f.low,
                high: f.high,
            })
            .collect();
        self.decide(
            StageKind::Drilling,
            format!(
                "Drilling validation: {} run(s) of the drilling experiment at the calibrated \
                 parameters, compared with the measured {} (tolerance {} %).",
                drilling.replicates,
                list(&drilling.measured.keys().cloned().collect::<Vec<_>>()),
                drilling.tolerance_pct
            ),
        );
        Ok(Next::Submit(self.issue(
            StageKind::Drilling,
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

    fn after_drilling(&mut self, finished: &StageResult) -> Result<Next, CampaignError> {
        let drilling = self.request.drilling.clone().expect("drilling requested");
        let mut metrics = Vec::new();
        for (name, measured) in &drilling.measured {
            let values: Vec<f64> = finished
                .runs
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
        let lines: Vec<String> = metrics
            .iter()
            .map(|m| {
                format!(
                    "{}: measured {}, simulated {}{}",
                    m.name,
                    fmt_num(m.measured),
                    m.simulated.map_or("n/a".into(), fmt_num),
                    m.relative_error_pct
                        .map_or(String::new(), |e| format!(" ({}%)", fmt_num(e)))
                )
            })
            .collect();
        self.decide(
            StageKind::Drilling,
            format!(
                "Drilling validation {}: {}.",
                if passed {
                    "passed"
                } else {
                    "FAILED — the parameters reproduce the angle of repose but not the drilled hole"
                },
                lines.join("; ")
            ),
        );
        self.drilling = Some(DrillingOutcome { metrics, passed });
        Ok(self.finish())
    }
}

fn describe_design(design: &DesignRequest) -> String {
    match design {
        DesignRequest::Factorial => "two-level full factorial".into(),
        DesignRequest::PlackettBurman { runs: Some(n) } => format!("{n}-run Plackett–Burman"),
        DesignRequest::PlackettBurman { runs: None } => "Plackett–Burman (smallest size)".into(),
        DesignRequest::BoxBehnken { .. } => "Box–Behnken".into(),
        DesignRequest::CentralComposite { .. } => "central composite".into(),
        DesignRequest::Explicit { points } => format!("{}-run explicit", points.len()),
    }
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
