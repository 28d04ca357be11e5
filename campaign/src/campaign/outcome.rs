//! What the chain's stages decide, as types: every stage's outcome (kept in the campaign's state
//! and shown in the report), the details a decision is worded from, every [`Stop`], and
//! [`Decided`], an entry of the decision log before it is words.
//!
//! A leaf: it imports no stage and not `wording`. The stages build these values, `wording`
//! words them, and the campaign (`mod.rs`) hands one to the other, so the imports run one way:
//! stages → outcome ← wording.

use std::collections::BTreeMap;

use repose_api::{CcdVariantName, DesignRequest};
use repose_doe::design::{Factor, PathDirection};
use repose_doe::{Fit, Goal, Region};
use serde::{Deserialize, Serialize};

use crate::request::{DrillingValidation, PathStartSetting, Target};

// ----------------------------------------------------------------------------------------
// Stage 1, screening

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

// ----------------------------------------------------------------------------------------
// Stage 2, the steepest path

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
    /// Several targets: each target's mean simulated response, once run (target order).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub responses: Vec<f64>,
    /// Several targets: the overall desirability of `responses`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub desirability: Option<f64>,
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
    /// Whether the simulated responses bracketed (or hit) the target; with several targets,
    /// whether the overall desirability peaked (or every response was within tolerance).
    pub crossed: bool,
    /// Several targets: each target's desirability goal (its band from the screening runs),
    /// which the path's overall desirability is measured with.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub goals: Vec<Goal>,
}

/// Which corner the path starts from, relative to the target.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum CornerSide {
    /// Both corners' predictions bracket the target; the nearer one was taken.
    Nearer,
    /// Only the low-response corner lies below the target.
    Below,
    /// Only the high-response corner lies above the target (or neither corner works).
    Above,
}

/// Why the path goes the way it goes.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum DirectionReason {
    /// The request fixed the direction.
    Requested,
    /// From the centre, toward the side the target is on.
    Centre {
        target: f64,
        intercept: f64,
        above: bool,
    },
    /// Several targets: up the gradient of the overall desirability of the screening models at
    /// the centre of the screening region.
    Desirability {
        /// Predicted overall desirability at the centre.
        centre: f64,
    },
    /// From a corner, chosen by the corners' predictions.
    Corner {
        /// Prediction at the ascent's start corner (the low-response corner).
        low_corner: f64,
        /// Prediction at the descent's start corner (the high-response corner).
        high_corner: f64,
        side: CornerSide,
        target: f64,
        /// Only one corner lies on the near side: the path may not reach the target.
        maybe_unreachable: bool,
    },
}

/// How the walk along the path ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PathEnd {
    /// Two consecutive responses bracket the target (point indices).
    Crossed { from: usize, to: usize },
    /// A response is within tolerance (and nothing crossed).
    Hit,
    /// Neither; the path is exhausted.
    NeverCrossed,
    /// Several targets: the overall desirability rose to this point and fell after it.
    Peaked,
}

// ----------------------------------------------------------------------------------------
// Stage 3, the response surface

/// Quadratic fit summary of one response-surface round.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SurfaceFitSummary {
    /// Several targets: the response this fit is of.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub response: String,
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
    /// Several targets: one fit per target, in target order (`fit` is the first's).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fits: Vec<SurfaceFitSummary>,
}

/// Something the plan adjusted, said in the decision.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum SurfaceNote {
    /// A half-range below 5 % of the allowed half-range was raised to it.
    HalfRangeRaised { factor: String, from: f64, to: f64 },
    /// Circumscribed star points would leave the allowed ranges.
    InscribedInstead { alpha: f64 },
}

/// Which design the plan uses for the carried factors.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum SurfaceLayout {
    /// One factor: a five-level line.
    Line,
    /// Box–Behnken (3 to 7 factors).
    BoxBehnken { centre_points: usize },
    /// Box–Behnken was asked for but `k` factors are carried: a face-centred CCD.
    FaceCentredForBoxBehnken { centre_points: usize, k: usize },
    /// The central composite design asked for.
    CentralComposite {
        variant: CcdVariantName,
        centre_points: usize,
    },
}

/// One target's quadratic in a round.
pub(crate) struct FittedResponse {
    pub target: Target,
    pub fit: Fit,
    pub summary: SurfaceFitSummary,
    /// Its desirability goal (band from the round's runs).
    pub goal: repose_doe::Goal,
}

// ----------------------------------------------------------------------------------------
// Stage 4, the optimum

/// One solution on the level set, for the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelSetPoint {
    /// Coded settings.
    pub coded: Vec<f64>,
    /// Natural settings.
    pub natural: Vec<f64>,
    /// Predicted response.
    pub predicted: f64,
    /// Desirability (overall, with several targets).
    pub desirability: f64,
    /// Several targets: each target's prediction (target order); `predicted` is the first's.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub predictions: Vec<f64>,
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
    /// Several targets: each target's predicted value at the chosen setting (target order);
    /// `predicted` is the first's and `desirability` the overall one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub predictions: Vec<f64>,
}

/// The search's result: the choice and the best desirability any start reached.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct OptimumFound {
    pub choice: OptimumChoice,
    pub best_desirability: f64,
}

impl OptimumFound {
    /// The target is met (desirability 1 up to the search's precision).
    pub fn target_met(&self) -> bool {
        self.best_desirability > 0.999
    }
}

// ----------------------------------------------------------------------------------------
// Stage 5, verification

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
    /// Within the tolerance (with several targets: every response within its own).
    pub within_tolerance: bool,
    /// Several targets: each response's check, in target order (the fields above are the
    /// first target's, except `within_tolerance`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub checks: Vec<ResponseCheck>,
}

/// One response verified against its target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResponseCheck {
    /// `<experiment>.<metric>` (the metric in the one-target form).
    pub response: String,
    /// Measured value.
    pub target: f64,
    /// The quadratic's prediction at the optimum.
    pub predicted: f64,
    /// Responses of the completed replicates.
    pub responses: Vec<f64>,
    /// Their mean.
    pub mean: f64,
    /// Their sample standard deviation (0 for one run).
    pub std: f64,
    /// `|mean - target| / |target|`, percent.
    pub relative_error_pct: f64,
    /// Within the target's tolerance.
    pub within_tolerance: bool,
}

/// What follows a verification.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum VerificationNext {
    /// Within tolerance: the calibration is done (a drilling validation may follow).
    Accept,
    /// Outside: a further round centred at this optimum.
    AnotherRound {
        /// The target was reachable in the last region (half the half-ranges), else the region
        /// moves with the same half-ranges.
        reachable: bool,
        /// 1-based number of the next round.
        round: u32,
        /// Rounds at most.
        max_rounds: u32,
    },
    /// Outside, and no round is left.
    GiveUp,
}

impl VerificationNext {
    /// Factor of the next round's half-ranges.
    pub fn half_range_scale(self) -> f64 {
        match self {
            VerificationNext::AnotherRound {
                reachable: true, ..
            } => 0.5,
            _ => 1.0,
        }
    }
}

// ----------------------------------------------------------------------------------------
// Stage 6, the drilling validation

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

// ----------------------------------------------------------------------------------------
// Stops

/// Which model a fit was for (the stop sentence names it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ModelRole {
    /// The first-order screening model.
    Screening,
    /// The full quadratic of a response-surface round.
    Quadratic,
}

/// Why a campaign stops for a person to look: statistical dead ends, not misuse. The words are
/// `wording::stop`'s.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Stop {
    /// The model could not be built (the design library's reason).
    ModelUnavailable(String),
    /// The fit failed on the completed runs.
    FitFailed {
        model: ModelRole,
        runs: usize,
        reason: String,
    },
    /// Every carried screening coefficient is zero.
    NoDirection,
    /// No steepest-path run completed.
    NoPathRun,
    /// A response-surface range is empty after clamping.
    EmptySurfaceRange { factor: String },
    /// The desirability search failed (its reason).
    OptimumSearchFailed(String),
    /// The desirability search returned no solution.
    NoOptimum,
    /// No verification run completed.
    NoVerificationRun,
    /// Several targets: verification failed in the last round allowed; the responses outside.
    TargetsStillOutside {
        rounds: u32,
        outside: Vec<ResponseCheck>,
    },
    /// Verification failed in the last round allowed.
    StillOutside {
        rounds: u32,
        mean: f64,
        relative_error_pct: f64,
    },
}

// ----------------------------------------------------------------------------------------
// The decision log

/// What a stage of the chain decided, for the decision log: `wording::decided` words it.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Decided<'a> {
    /// Stage 1 plan: the candidates, the design, α, and the experiments every stage runs.
    ScreeningPlan {
        factors: &'a [String],
        design: &'a DesignRequest,
        alpha: f64,
        experiments: &'a [String],
    },
    /// Stage 1 outcome: what was significant, what is carried and why, what is held.
    Screened {
        outcome: &'a ScreeningOutcome,
        alpha: f64,
        max_factors: usize,
    },
    /// Stage 2 plan: the direction and why, the steps, the points.
    PathLaidOut {
        path: &'a PathState,
        why: &'a DirectionReason,
        round_decimals: Option<u32>,
        max_points: usize,
    },
    /// Stage 2 outcome: the responses along the path and the point chosen as the centre.
    PathEnded {
        path: &'a PathState,
        end: PathEnd,
        centre: usize,
        target: f64,
    },
    /// Stage 2 outcome with several targets: the overall desirability along the path and the
    /// point chosen as the centre.
    PathEndedOverall {
        path: &'a PathState,
        end: PathEnd,
        centre: usize,
        targets: &'a [Target],
    },
    /// Stage 3 plan: the design, its levels and anything adjusted.
    SurfacePlanned {
        round: u32,
        layout: &'a SurfaceLayout,
        factors: &'a [Factor],
        notes: &'a [SurfaceNote],
    },
    /// Stage 3 outcome: one response's quadratic fit.
    SurfaceFitted {
        summary: &'a SurfaceFitSummary,
        alpha: f64,
    },
    /// Stage 4 outcome: where the target is met (a point, a level set, or not at all).
    Optimum {
        found: &'a OptimumFound,
        factors: &'a [String],
        target: f64,
    },
    /// Stage 4 with several targets: the setting of best overall desirability.
    OptimumOverall {
        found: &'a OptimumFound,
        factors: &'a [String],
        targets: &'a [Target],
    },
    /// Stage 5 plan.
    VerificationPlanned {
        replicates: u32,
        targets: &'a [Target],
    },
    /// Stage 5 outcome and what follows it.
    Verified {
        outcome: &'a VerificationOutcome,
        targets: &'a [Target],
        next: VerificationNext,
    },
    /// Stage 6 plan; `unverified` when it runs at a setting verification did not accept.
    DrillingPlanned {
        drilling: &'a DrillingValidation,
        unverified: bool,
    },
    /// Stage 6 outcome: each metric measured against simulated.
    Drilled {
        outcome: &'a DrillingOutcome,
        several_targets: bool,
        unverified: bool,
    },
}
