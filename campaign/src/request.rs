//! What a person submits: [`CampaignRequest`] and its stage settings, with defaults.

use std::collections::BTreeMap;

use repose_api::{BackendKind, CcdVariantName, DesignRequest, ExperimentTemplate, FactorSpec};
use serde::{Deserialize, Serialize};

use crate::error::CampaignError;

/// One calibration campaign: the experiment(s), the candidate parameters, the measured
/// target(s) and how each stage is run. Every stage setting has a default; the smallest request
/// names the experiment, the factors and the target.
///
/// Two forms, told apart by `targets`:
/// - **one target** (the original form): `experiment`, `response` (a metric of it), `target`,
///   `tolerance`, optionally `stage_experiments`;
/// - **several targets**: `experiments` (templates by name) and `targets`, each
///   `{"response": "<experiment>.<metric>", "target": value, "tolerance": ...}`; `experiment`,
///   `response`, `target`, `tolerance` and `stage_experiments` are then not given.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignRequest {
    /// Label; every batch of the campaign is named `<name>: <stage>`.
    pub name: String,
    /// How the campaign searches: `{"type": "doe"}` (the default: screening → steepest path →
    /// response surface → optimum → verification) or `{"type": "bayesian", ...}` (Gaussian-process
    /// surrogates of every response over all candidate factors at once; see
    /// [`BayesianSettings`]).
    #[serde(default, skip_serializing_if = "Strategy::is_doe")]
    pub strategy: Strategy,
    /// The simulation every run starts from (e.g. kind `aor`, preset `fast`); one-target form.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub experiment: Option<ExperimentTemplate>,
    /// Several-targets form: the experiments by name (by convention the kind, e.g. `aor`,
    /// `shear`); a target's response `aor.angle_deg` is metric `angle_deg` of `experiments.aor`.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub experiments: BTreeMap<String, ExperimentTemplate>,
    /// Several-targets form: every measured response with its tolerance.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub targets: Vec<TargetSetting>,
    /// Optional per-stage replacements of `experiment` (e.g. a cheaper preset for screening, a
    /// finer one for verification). The replay test uses them to give each of the paper's
    /// tables its own lookup experiment.
    #[serde(default)]
    pub stage_experiments: StageExperiments,
    /// Candidate parameters (the paper's Table 1/2), screened in the first stage.
    pub factors: Vec<CandidateFactor>,
    /// Metric the campaign calibrates (default `angle_deg`).
    #[serde(default = "default_response")]
    pub response: String,
    /// Measured value of the response (e.g. 34.85°); one-target form.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<f64>,
    /// How close a verified mean must come to the target (default 5 % relative).
    #[serde(default)]
    pub tolerance: Tolerance,
    /// Significance level of the screening and of the response-surface ANOVA (default 0.05).
    #[serde(default = "default_alpha")]
    pub alpha: f64,
    /// Base seed; batch `i` of the campaign gets a seed derived from it so every batch (and
    /// thus every verification replicate) has fresh simulation seeds. `None` leaves the seeds
    /// to the server.
    #[serde(default)]
    pub seed: Option<u64>,
    /// Stage 1.
    #[serde(default)]
    pub screening: ScreeningSettings,
    /// Stage 2.
    #[serde(default)]
    pub steepest: SteepestSettings,
    /// Stages 3 and 4.
    #[serde(default)]
    pub response_surface: SurfaceSettings,
    /// Stage 5.
    #[serde(default)]
    pub verification: VerificationSettings,
    /// Optional stage 6: a validation experiment that is not a target (the drilling test) at
    /// the calibrated parameters against its measured metrics. `validation` is accepted as
    /// another name for it.
    #[serde(default, alias = "validation")]
    pub drilling: Option<DrillingValidation>,
    /// The engine of every experiment that names none of its own (`cpu` or `gpu`), the
    /// drilling validation's included; none: those run on the CPU.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backend: Option<BackendKind>,
}

/// The campaign strategy, chosen in the campaign file by `type`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Strategy {
    /// The Design-Expert chain of the paper (screening, steepest path, response surface,
    /// optimum, verification), each stage with its own settings.
    #[default]
    Doe,
    /// Sequential Bayesian calibration: a space-filling start, then rounds of `batch_size`
    /// points chosen where every target is most likely met, until one is verified.
    Bayesian(BayesianSettings),
}

impl Strategy {
    /// Whether this is the default chain.
    pub fn is_doe(&self) -> bool {
        matches!(self, Strategy::Doe)
    }

    /// The Bayesian settings, when that strategy is chosen.
    pub fn bayesian(&self) -> Option<&BayesianSettings> {
        match self {
            Strategy::Doe => None,
            Strategy::Bayesian(b) => Some(b),
        }
    }
}

/// Settings of the Bayesian strategy; every one has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BayesianSettings {
    /// Simulations the campaign may issue in all (every experiment's runs and the verification
    /// replicates; the drilling validation not). Default 60.
    pub max_runs: usize,
    /// Points proposed per round (each run by every experiment the targets need). Default 4.
    pub batch_size: usize,
    /// Points of the space-filling start (a maximin Latin hypercube); default `2·factors + 2`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_points: Option<usize>,
    /// Verify once the best point's probability of meeting every tolerance (under the
    /// surrogates, for the mean of the verification replicates) reaches this. Default 0.8.
    pub stop_probability: f64,
    /// Declare the targets in conflict when every target alone is met with probability ≥ 0.5
    /// somewhere in the box but all of them together nowhere above this, two rounds running.
    /// Default 0.02.
    pub conflict_probability: f64,
    /// Candidate points scored per proposal (quasi-random plus local perturbations of the best
    /// points). Default 2000.
    pub candidates: usize,
}

impl Default for BayesianSettings {
    fn default() -> Self {
        Self {
            max_runs: 60,
            batch_size: 4,
            initial_points: None,
            stop_probability: 0.8,
            conflict_probability: 0.02,
            candidates: 2000,
        }
    }
}

impl BayesianSettings {
    /// Points of the space-filling start for `factors` candidate factors.
    pub fn initial_points_for(&self, factors: usize) -> usize {
        self.initial_points.unwrap_or(2 * factors + 2)
    }
}

/// One measured response of the several-targets form.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSetting {
    /// `<experiment>.<metric>`, e.g. `aor.angle_deg` or `shear.cohesion_kpa`.
    pub response: String,
    /// Measured value.
    pub target: f64,
    /// How close the verified mean must come (default 5 % relative).
    #[serde(default)]
    pub tolerance: Tolerance,
}

/// A target as the stages use it, whichever form the request had.
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    /// Name in decisions and the report (`angle_deg` in the one-target form, `aor.angle_deg`
    /// in the other).
    pub label: String,
    /// Experiment key (empty in the one-target form: `experiment` and `stage_experiments`).
    pub experiment: String,
    /// Metric of the experiment's runs.
    pub metric: String,
    /// Measured value.
    pub value: f64,
    /// Acceptance band of the verified mean.
    pub tolerance: Tolerance,
}

fn default_response() -> String {
    "angle_deg".to_owned()
}

fn default_alpha() -> f64 {
    0.05
}

/// Per-stage experiment templates; a stage without one uses the campaign's `experiment`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageExperiments {
    /// Screening batch.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub screening: Option<ExperimentTemplate>,
    /// Steepest-ascent batches.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steepest: Option<ExperimentTemplate>,
    /// Response-surface batches (every round).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub response_surface: Option<ExperimentTemplate>,
    /// Verification batches.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub verification: Option<ExperimentTemplate>,
}

/// A parameter that may matter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CandidateFactor {
    /// Name used in designs, models and the report (e.g. `N2`).
    pub name: String,
    /// Dotted path into the experiment spec (e.g. `soil_soil.static_friction`).
    pub path: String,
    /// Lowest allowed value; also the screening design's low level.
    pub low: f64,
    /// Highest allowed value; also the screening design's high level.
    pub high: f64,
    /// Value the factor is held at when screening does not carry it forward (default: the
    /// middle of `[low, high]`). The paper holds N6 at 0.50.
    #[serde(default)]
    pub fixed_at: Option<f64>,
    /// The experiments (keys of `experiments`) whose spec this factor is written into; absent:
    /// all of them. The others still run the same design rows, the factor's column unwritten
    /// (e.g. a cohesion energy for the shear test only, the angle of repose poured dry as the
    /// paper's was). The drilling validation writes every factor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub experiments: Option<Vec<String>>,
}

impl CandidateFactor {
    /// The factor over its whole allowed range, as a batch names it.
    pub(crate) fn spec(&self) -> FactorSpec {
        FactorSpec {
            name: self.name.clone(),
            path: Some(self.path.clone()),
            low: self.low,
            high: self.high,
        }
    }
}

impl CandidateFactor {
    /// The value used when the factor is not varied.
    pub fn hold_value(&self) -> f64 {
        self.fixed_at.unwrap_or(0.5 * (self.low + self.high))
    }

    /// Whether the factor is written into experiment `key`'s spec.
    pub fn acts_on(&self, key: &str) -> bool {
        self.experiments
            .as_ref()
            .is_none_or(|keys| keys.iter().any(|k| k == key))
    }
}

/// Acceptance band of a verified mean around the target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Tolerance {
    /// `|mean - target| / |target| · 100 <= pct`, e.g. `{"relative_pct": 5}`.
    RelativePct(f64),
    /// `|mean - target| <= value` in response units, e.g. `{"absolute": 1.0}`.
    Absolute(f64),
}

impl Default for Tolerance {
    fn default() -> Self {
        Tolerance::RelativePct(5.0)
    }
}

impl Tolerance {
    /// Half-width of the acceptance band around `target`, in response units.
    pub fn half_width(&self, target: f64) -> f64 {
        match *self {
            Tolerance::RelativePct(pct) => pct / 100.0 * target.abs(),
            Tolerance::Absolute(abs) => abs,
        }
    }

    /// Whether `value` is accepted for `target`.
    pub fn accepts(&self, value: f64, target: f64) -> bool {
        match *self {
            Tolerance::RelativePct(pct) => relative_error_pct(value, target) <= pct,
            Tolerance::Absolute(abs) => (value - target).abs() <= abs,
        }
    }

    /// Plain-language form, e.g. `5 % of the target`.
    pub fn describe(&self) -> String {
        match *self {
            Tolerance::RelativePct(pct) => format!("{pct} % of the target"),
            Tolerance::Absolute(abs) => format!("±{abs} (absolute)"),
        }
    }
}

/// `|value - target| / |target| · 100`.
pub fn relative_error_pct(value: f64, target: f64) -> f64 {
    (value - target).abs() / target.abs() * 100.0
}

/// Stage 1 settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScreeningSettings {
    /// Screening design over all candidates: Plackett–Burman (default, smallest size), a
    /// factorial, or explicit points in natural units (e.g. the paper's Table 3 rows).
    pub design: DesignRequest,
    /// Copies of every design point.
    pub replicates: u32,
    /// At most this many factors are carried forward; when more are significant, the largest
    /// |t| are kept (default 3, what a Box–Behnken design handles economically).
    pub max_factors: usize,
    /// When no factor is significant, this many factors with the largest |t| are carried
    /// anyway (default 2), and the report says the screening could not separate them from noise.
    pub fallback_factors: usize,
}

impl Default for ScreeningSettings {
    fn default() -> Self {
        Self {
            design: DesignRequest::PlackettBurman { runs: None },
            replicates: 1,
            max_factors: 3,
            fallback_factors: 2,
        }
    }
}

/// Where the steepest path starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PathStartSetting {
    /// The corner of the screening region the path leaves from (each factor at the end it
    /// moves away from), as the paper does: the path crosses the whole region.
    Corner,
    /// The centre of the screening region.
    Centre,
}

/// Which way the path goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PathDirectionSetting {
    /// Toward the target: from the centre, the side the target is on; from a corner, the
    /// corner whose prediction is nearer the target, walking toward it.
    Auto,
    /// Always ascent.
    Ascent,
    /// Always descent.
    Descent,
}

/// Stage 2 settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SteepestSettings {
    /// Path points simulated per batch (default 5).
    pub points_per_dispatch: usize,
    /// Path points at most, start included (default 10).
    pub max_points: usize,
    /// Non-base steps are rounded to this many decimals (default 2, as the paper).
    pub round_decimals: Option<u32>,
    /// Start point (default corner, as the paper).
    pub start: PathStartSetting,
    /// Direction (default auto).
    pub direction: PathDirectionSetting,
    /// Copies of every path point.
    pub replicates: u32,
}

impl Default for SteepestSettings {
    fn default() -> Self {
        Self {
            points_per_dispatch: 5,
            max_points: 10,
            round_decimals: Some(2),
            start: PathStartSetting::Corner,
            direction: PathDirectionSetting::Auto,
            replicates: 1,
        }
    }
}

/// Response-surface design family.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum SurfaceDesign {
    /// Box–Behnken (3 to 7 factors; with 2 factors a face-centred CCD is used, with 1 a
    /// five-level line, and the report says so).
    BoxBehnken {
        /// Centre runs (default 5).
        #[serde(default = "default_centre_points")]
        centre_points: usize,
    },
    /// Central composite. Circumscribed star points that would leave the allowed ranges turn
    /// the design inscribed (said in the decisions).
    CentralComposite {
        /// Star point placement.
        variant: CcdVariantName,
        /// Centre runs (default 5).
        #[serde(default = "default_centre_points")]
        centre_points: usize,
    },
}

fn default_centre_points() -> usize {
    5
}

impl SurfaceDesign {
    /// Centre runs of the design.
    pub fn centre_points(&self) -> usize {
        match self {
            SurfaceDesign::BoxBehnken { centre_points }
            | SurfaceDesign::CentralComposite { centre_points, .. } => *centre_points,
        }
    }
}

/// Stages 3 and 4 settings. The model is always the full quadratic.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SurfaceSettings {
    /// Design (default Box–Behnken with 5 centre points).
    pub design: SurfaceDesign,
    /// Copies of every design point.
    pub replicates: u32,
    /// Further response-surface rounds allowed after a failed verification (default 2); each is
    /// centred at the last optimum, with half the previous half-ranges (the target was reachable)
    /// or the same ones (it was not: the region moves toward it).
    pub max_extra_rounds: u32,
    /// Starting points of the desirability search (default 64).
    pub optimum_starts: usize,
}

impl Default for SurfaceSettings {
    fn default() -> Self {
        Self {
            design: SurfaceDesign::BoxBehnken {
                centre_points: default_centre_points(),
            },
            replicates: 1,
            max_extra_rounds: 2,
            optimum_starts: 64,
        }
    }
}

/// Stage 5 settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VerificationSettings {
    /// Replicate simulations at the optimum, each with its own seed (default 3).
    pub replicates: u32,
}

impl Default for VerificationSettings {
    fn default() -> Self {
        Self { replicates: 3 }
    }
}

/// Optional stage 6: simulate the drilling experiment at the calibrated parameters and compare
/// its metrics with measurements. The campaign issues the batch and compares the means; running
/// the drill kind is the workers' business like any other batch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DrillingValidation {
    /// The drilling experiment.
    pub experiment: ExperimentTemplate,
    /// Path of each calibrated factor in the drilling spec, by factor name; factors not listed
    /// use their `path` from the campaign.
    #[serde(default)]
    pub paths: BTreeMap<String, String>,
    /// Measured metrics (e.g. `{"hole_diameter_mm": 52.0}`); the first (alphabetically) is the
    /// batch's response, all are compared.
    pub measured: BTreeMap<String, f64>,
    /// Accepted relative error of each simulated mean, percent (default 10).
    #[serde(default = "default_drill_tolerance")]
    pub tolerance_pct: f64,
    /// Replicate simulations (default 1).
    #[serde(default = "default_one")]
    pub replicates: u32,
}

fn default_drill_tolerance() -> f64 {
    10.0
}

fn default_one() -> u32 {
    1
}

impl CampaignRequest {
    /// The targets in request order (one in the one-target form). Call after [`Self::validate`].
    pub fn targets(&self) -> Vec<Target> {
        if self.targets.is_empty() {
            return vec![Target {
                label: self.response.clone(),
                experiment: String::new(),
                metric: self.response.clone(),
                value: self.target.unwrap_or(f64::NAN),
                tolerance: self.tolerance,
            }];
        }
        self.targets
            .iter()
            .map(|t| {
                let (experiment, metric) = t.response.split_once('.').unwrap_or(("", ""));
                Target {
                    label: t.response.clone(),
                    experiment: experiment.to_owned(),
                    metric: metric.to_owned(),
                    value: t.target,
                    tolerance: t.tolerance,
                }
            })
            .collect()
    }

    /// Whether the request has several targets (the several-targets form).
    pub fn is_multi(&self) -> bool {
        !self.targets.is_empty()
    }

    /// The experiments the targets need, each once, in order of first use: every stage runs
    /// each of them at each design point (one batch per experiment).
    pub fn experiment_keys(&self) -> Vec<String> {
        let mut keys: Vec<String> = Vec::new();
        for t in self.targets() {
            if !keys.contains(&t.experiment) {
                keys.push(t.experiment);
            }
        }
        keys
    }

    /// The template a stage's batch of experiment `key` starts from: in the one-target form
    /// the stage's entry of `stage_experiments` or `experiment`, else `experiments[key]`.
    pub fn template_for(&self, stage: StageTemplate, key: &str) -> ExperimentTemplate {
        if !self.is_multi() {
            let s = &self.stage_experiments;
            let specific = match stage {
                StageTemplate::Screening => s.screening.as_ref(),
                StageTemplate::Steepest => s.steepest.as_ref(),
                StageTemplate::ResponseSurface => s.response_surface.as_ref(),
                StageTemplate::Verification => s.verification.as_ref(),
            };
            return specific
                .or(self.experiment.as_ref())
                .cloned()
                .expect("validated: the one-target form has an experiment");
        }
        self.experiments
            .get(key)
            .cloned()
            .expect("validated: every target's experiment is listed")
    }

    /// `template` with the campaign's `backend` when it names none of its own.
    pub fn with_backend(&self, mut template: ExperimentTemplate) -> ExperimentTemplate {
        template.backend = template.backend.or(self.backend);
        template
    }

    /// Checks what the statistics cannot check later, naming the offending field.
    pub fn validate(&self) -> Result<(), CampaignError> {
        let bad = |field: &str, reason: String| CampaignError::InvalidRequest {
            field: field.to_owned(),
            reason,
        };
        if self.name.trim().is_empty() {
            return Err(bad("name", "must not be empty".into()));
        }
        if self.factors.is_empty() {
            return Err(bad(
                "factors",
                "at least one candidate factor is needed".into(),
            ));
        }
        for (i, f) in self.factors.iter().enumerate() {
            if f.name.trim().is_empty() {
                return Err(bad(
                    &format!("factors[{i}].name"),
                    "must not be empty".into(),
                ));
            }
            if self.factors[..i].iter().any(|g| g.name == f.name) {
                return Err(bad(
                    &format!("factors[{i}].name"),
                    format!("`{}` is listed twice", f.name),
                ));
            }
            if !(f.low.is_finite() && f.high.is_finite() && f.low < f.high) {
                return Err(bad(
                    &format!("factors[{i}].low"),
                    format!(
                        "need finite low < high for `{}`, got {} and {}",
                        f.name, f.low, f.high
                    ),
                ));
            }
            if let Some(v) = f.fixed_at {
                if !v.is_finite() {
                    return Err(bad(
                        &format!("factors[{i}].fixed_at"),
                        "must be a finite number".into(),
                    ));
                }
            }
            if let Some(keys) = &f.experiments {
                let field = format!("factors[{i}].experiments");
                if self.experiments.is_empty() {
                    return Err(bad(
                        &field,
                        "only a campaign with several `experiments` can scope a factor".into(),
                    ));
                }
                if keys.is_empty() {
                    return Err(bad(
                        &field,
                        "must name at least one experiment (leave it out for all)".into(),
                    ));
                }
                if let Some(k) = keys.iter().find(|k| !self.experiments.contains_key(*k)) {
                    return Err(bad(
                        &field,
                        format!(
                            "`{k}` is not one of the campaign's experiments ({})",
                            self.experiments
                                .keys()
                                .map(String::as_str)
                                .collect::<Vec<_>>()
                                .join(", ")
                        ),
                    ));
                }
            }
        }
        self.validate_targets()?;
        if let Some(b) = self.strategy.bayesian() {
            self.validate_bayesian(b)?;
        }
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            return Err(bad(
                "alpha",
                format!("must be in (0, 1), got {}", self.alpha),
            ));
        }
        let s = &self.screening;
        if s.replicates == 0 {
            return Err(bad("screening.replicates", "must be at least 1".into()));
        }
        if s.max_factors == 0 {
            return Err(bad("screening.max_factors", "must be at least 1".into()));
        }
        if s.fallback_factors == 0 {
            return Err(bad(
                "screening.fallback_factors",
                "must be at least 1".into(),
            ));
        }
        if matches!(
            s.design,
            DesignRequest::BoxBehnken { .. } | DesignRequest::CentralComposite { .. }
        ) {
            return Err(bad(
                "screening.design",
                "a screening design is two-level: plackett_burman, factorial or explicit".into(),
            ));
        }
        if let DesignRequest::Explicit { points } = &s.design {
            for (r, p) in points.iter().enumerate() {
                if p.len() != self.factors.len() {
                    return Err(bad(
                        &format!("screening.design.points[{r}]"),
                        format!(
                            "has {} values, need one per factor ({})",
                            p.len(),
                            self.factors.len()
                        ),
                    ));
                }
            }
        }
        let p = &self.steepest;
        if p.points_per_dispatch == 0 {
            return Err(bad(
                "steepest.points_per_dispatch",
                "must be at least 1".into(),
            ));
        }
        if p.max_points < 2 {
            return Err(bad("steepest.max_points", "must be at least 2".into()));
        }
        if p.replicates == 0 {
            return Err(bad("steepest.replicates", "must be at least 1".into()));
        }
        if let Some(d) = p.round_decimals {
            if d > 12 {
                return Err(bad(
                    "steepest.round_decimals",
                    format!("at most 12, got {d}"),
                ));
            }
        }
        if self.response_surface.replicates == 0 {
            return Err(bad(
                "response_surface.replicates",
                "must be at least 1".into(),
            ));
        }
        if self.response_surface.optimum_starts == 0 {
            return Err(bad(
                "response_surface.optimum_starts",
                "must be at least 1".into(),
            ));
        }
        if self.verification.replicates == 0 {
            return Err(bad("verification.replicates", "must be at least 1".into()));
        }
        if let Some(d) = &self.drilling {
            if d.measured.is_empty() {
                return Err(bad("drilling.measured", "needs at least one metric".into()));
            }
            if let Some((k, v)) = d
                .measured
                .iter()
                .find(|(_, v)| !v.is_finite() || **v == 0.0)
            {
                return Err(bad(
                    &format!("drilling.measured.{k}"),
                    format!("must be finite and non-zero, got {v}"),
                ));
            }
            if !(d.tolerance_pct.is_finite() && d.tolerance_pct > 0.0) {
                return Err(bad("drilling.tolerance_pct", "must be positive".into()));
            }
            if d.replicates == 0 {
                return Err(bad("drilling.replicates", "must be at least 1".into()));
            }
            if let Some(name) = d
                .paths
                .keys()
                .find(|n| !self.factors.iter().any(|f| &f.name == *n))
            {
                return Err(bad(
                    &format!("drilling.paths.{name}"),
                    "is not a candidate factor".into(),
                ));
            }
        }
        Ok(())
    }

    /// The Bayesian strategy's settings, and the chain's stage settings it has no use for.
    fn validate_bayesian(&self, b: &BayesianSettings) -> Result<(), CampaignError> {
        let bad = |field: &str, reason: String| CampaignError::InvalidRequest {
            field: field.to_owned(),
            reason,
        };
        let unused = "is a setting of the `doe` chain; the bayesian strategy varies every \
                      candidate factor at once and has no stages (leave it out)";
        for (field, given) in [
            ("screening", self.screening != ScreeningSettings::default()),
            ("steepest", self.steepest != SteepestSettings::default()),
            (
                "response_surface",
                self.response_surface != SurfaceSettings::default(),
            ),
            (
                "stage_experiments",
                self.stage_experiments != StageExperiments::default(),
            ),
        ] {
            if given {
                return Err(bad(field, unused.into()));
            }
        }
        if b.batch_size == 0 {
            return Err(bad("strategy.batch_size", "must be at least 1".into()));
        }
        let initial = b.initial_points_for(self.factors.len());
        if initial < 2 {
            return Err(bad(
                "strategy.initial_points",
                format!("must be at least 2, got {initial}"),
            ));
        }
        let experiments = self.experiment_keys().len();
        let least = (initial + self.verification.replicates as usize) * experiments;
        if b.max_runs < least {
            return Err(bad(
                "strategy.max_runs",
                format!(
                    "must be at least {least} (the {initial} start points and the {} \
                     verification replicates, each run by {experiments} experiment(s)), got {}",
                    self.verification.replicates, b.max_runs
                ),
            ));
        }
        if !(b.stop_probability > 0.0 && b.stop_probability < 1.0) {
            return Err(bad(
                "strategy.stop_probability",
                format!("must be in (0, 1), got {}", b.stop_probability),
            ));
        }
        if !(b.conflict_probability > 0.0 && b.conflict_probability < b.stop_probability) {
            return Err(bad(
                "strategy.conflict_probability",
                format!(
                    "must be in (0, stop_probability), got {}",
                    b.conflict_probability
                ),
            ));
        }
        if !(100..=100_000).contains(&b.candidates) {
            return Err(bad(
                "strategy.candidates",
                format!("must be between 100 and 100000, got {}", b.candidates),
            ));
        }
        Ok(())
    }

    /// The target fields of either form.
    fn validate_targets(&self) -> Result<(), CampaignError> {
        let bad = |field: &str, reason: String| CampaignError::InvalidRequest {
            field: field.to_owned(),
            reason,
        };
        let check_value = |field: &str, v: f64| {
            if !v.is_finite() || v == 0.0 {
                return Err(bad(
                    field,
                    format!(
                        "must be a finite non-zero number (relative errors divide by it), got {v}"
                    ),
                ));
            }
            Ok(())
        };
        let check_tolerance = |field: &str, t: Tolerance| match t {
            Tolerance::RelativePct(v) | Tolerance::Absolute(v) if !(v.is_finite() && v > 0.0) => {
                Err(bad(field, format!("must be positive, got {v}")))
            }
            _ => Ok(()),
        };
        if !self.is_multi() {
            if self.experiment.is_none() {
                return Err(bad(
                    "experiment",
                    "is needed (or `experiments` and `targets` for several targets)".into(),
                ));
            }
            if !self.experiments.is_empty() {
                return Err(bad(
                    "experiments",
                    "goes with `targets`; a one-target request names `experiment`".into(),
                ));
            }
            let Some(target) = self.target else {
                return Err(bad("target", "is needed (the measured value)".into()));
            };
            check_value("target", target)?;
            check_tolerance("tolerance", self.tolerance)?;
            if self.response.trim().is_empty() {
                return Err(bad("response", "must not be empty".into()));
            }
            return Ok(());
        }
        for (field, given) in [
            ("experiment", self.experiment.is_some()),
            ("target", self.target.is_some()),
            (
                "stage_experiments",
                self.stage_experiments != StageExperiments::default(),
            ),
            ("tolerance", self.tolerance != Tolerance::default()),
            ("response", self.response != default_response()),
        ] {
            if given {
                return Err(bad(
                    field,
                    "belongs to the one-target form; with `targets`, each target has its own \
                     response and tolerance and `experiments` names the experiments"
                        .into(),
                ));
            }
        }
        if self.steepest.direction != PathDirectionSetting::Auto {
            return Err(bad(
                "steepest.direction",
                "with several targets the path always climbs the overall desirability; leave \
                 it `auto`"
                    .into(),
            ));
        }
        for (i, t) in self.targets.iter().enumerate() {
            let field = format!("targets[{i}]");
            let Some((key, metric)) = t.response.split_once('.') else {
                return Err(bad(
                    &format!("{field}.response"),
                    format!("`{}` is not `<experiment>.<metric>`", t.response),
                ));
            };
            if metric.is_empty() {
                return Err(bad(
                    &format!("{field}.response"),
                    format!("`{}` names no metric", t.response),
                ));
            }
            if !self.experiments.contains_key(key) {
                return Err(bad(
                    &format!("{field}.response"),
                    format!("experiment `{key}` is not in `experiments`"),
                ));
            }
            if self.targets[..i].iter().any(|u| u.response == t.response) {
                return Err(bad(
                    &format!("{field}.response"),
                    format!("`{}` is listed twice", t.response),
                ));
            }
            check_value(&format!("{field}.target"), t.target)?;
            check_tolerance(&format!("{field}.tolerance"), t.tolerance)?;
        }
        if let Some(key) = self.experiments.keys().find(|k| {
            !self
                .targets
                .iter()
                .any(|t| t.response.split_once('.').map(|p| p.0) == Some(k.as_str()))
        }) {
            return Err(bad(
                &format!("experiments.{key}"),
                "no target uses it".into(),
            ));
        }
        Ok(())
    }
}

/// Which stage's template [`CampaignRequest::template_for`] gives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StageTemplate {
    /// Stage 1.
    Screening,
    /// Stage 2.
    Steepest,
    /// Stages 3 and 4.
    ResponseSurface,
    /// Stage 5.
    Verification,
}
