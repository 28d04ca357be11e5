//! Numerical optimisation of fitted response surfaces with Derringer–Suich
//! desirability, the way Design-Expert's "Optimization → Numerical" does it.
//!
//! Each response gets a goal and an individual desirability `d ∈ [0, 1]`;
//! the overall desirability is the importance-weighted geometric mean
//! `D = (∏ d_i^{r_i})^{1/Σ r_i}`. `InRange` goals act as constraints (d is 0
//! or 1) and, like in Design-Expert, do not enter the mean.
//!
//! The search is a deterministic multi-start: the design centre plus a
//! seeded Latin hypercube of starting points, each polished by a projected
//! Nelder–Mead simplex (the region constraint is enforced by projecting onto
//! the cube or sphere, with a small quadratic penalty for the unprojected
//! point so the simplex stays near the region). Where D = 0 the search
//! climbs on the negative normalised distance of the predictions to their
//! acceptable intervals instead, so starts in infeasible corners still move.
//!
//! Why report a *level set*: with a single target goal on a smooth surface
//! the set `ŷ(x) = target` is a (k-1)-dimensional surface, so there is no
//! unique optimum (the paper notes that many parameter combinations give the
//! measured 34.85°). We then say so (`level_set = true`), report how many
//! starts reached the top desirability and how far apart those solutions
//! are, and order tied solutions by the documented tie-break: closest to the
//! design centre first (the least extrapolating choice). Because the starts
//! only sample the tied set, the few most central tied points are then
//! refined (when the goals are fully met, D ≈ 1) by minimising `|x|²`
//! subject to keeping the desirability tied
//! (exact-penalty Nelder–Mead), so the first solution is the tied point
//! nearest the design centre, independent of the seed up to the optimiser's
//! tolerance.

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::design::Factor;
use crate::error::OptimumError;
use crate::fit::Fit;

/// Goal for one response. `lower`/`upper` are the limits outside which the
/// response is unacceptable (desirability 0) or fully satisfactory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "goal", rename_all = "snake_case")]
pub enum Goal {
    /// d = 0 below `lower`, 1 above `upper`, `((y-L)/(U-L))^w` between.
    Maximize {
        /// Unacceptable below this.
        lower: f64,
        /// Fully satisfactory above this.
        upper: f64,
    },
    /// d = 1 below `lower`, 0 above `upper`, `((U-y)/(U-L))^w` between.
    Minimize {
        /// Fully satisfactory below this.
        lower: f64,
        /// Unacceptable above this.
        upper: f64,
    },
    /// d = 1 at `target`, falling to 0 at `lower` (shape `weight`) and at
    /// `upper` (shape `weight_upper`); 0 outside `[lower, upper]`.
    Target {
        /// Desired value.
        target: f64,
        /// Unacceptable below this.
        lower: f64,
        /// Unacceptable above this.
        upper: f64,
    },
    /// Constraint: d = 1 inside `[lower, upper]`, 0 outside; not part of the mean.
    InRange {
        /// Lower limit.
        lower: f64,
        /// Upper limit.
        upper: f64,
    },
}

impl Goal {
    fn limits(&self) -> (f64, f64) {
        match *self {
            Goal::Maximize { lower, upper }
            | Goal::Minimize { lower, upper }
            | Goal::InRange { lower, upper }
            | Goal::Target { lower, upper, .. } => (lower, upper),
        }
    }

    /// Individual desirability of value `y`; `weight` is the shape exponent
    /// (the lower-side one for a target), `weight_upper` the upper-side
    /// exponent of a target goal.
    pub fn desirability(&self, y: f64, weight: f64, weight_upper: f64) -> f64 {
        if !y.is_finite() {
            return 0.0;
        }
        match *self {
            Goal::Maximize { lower, upper } => {
                if y <= lower {
                    0.0
                } else if y >= upper {
                    1.0
                } else {
                    ((y - lower) / (upper - lower)).powf(weight)
                }
            }
            Goal::Minimize { lower, upper } => {
                if y <= lower {
                    1.0
                } else if y >= upper {
                    0.0
                } else {
                    ((upper - y) / (upper - lower)).powf(weight)
                }
            }
            Goal::Target {
                target,
                lower,
                upper,
            } => {
                if y < lower || y > upper {
                    0.0
                } else if y == target {
                    1.0
                } else if y < target {
                    ((y - lower) / (target - lower)).powf(weight)
                } else {
                    ((upper - y) / (upper - target)).powf(weight_upper)
                }
            }
            Goal::InRange { lower, upper } => {
                if (lower..=upper).contains(&y) {
                    1.0
                } else {
                    0.0
                }
            }
        }
    }

    /// Normalised distance of `y` from the region where d > 0 (0 inside).
    fn violation(&self, y: f64) -> f64 {
        let (lower, upper) = self.limits();
        let width = (upper - lower).abs().max(f64::MIN_POSITIVE);
        let below = (lower - y).max(0.0) / width;
        let above = (y - upper).max(0.0) / width;
        match self {
            Goal::Maximize { .. } => below,
            Goal::Minimize { .. } => above,
            Goal::Target { .. } | Goal::InRange { .. } => below + above,
        }
    }
}

/// One response to optimise: its fitted model, goal, shape weights and
/// importance.
#[derive(Debug, Clone)]
pub struct Objective<'a> {
    /// Name shown in the result (defaults to the fit's response name).
    pub name: String,
    /// Fitted model predicting the response from coded factors.
    pub model: &'a Fit,
    /// Goal.
    pub goal: Goal,
    /// Shape exponent (for a target: below the target). Default 1.
    pub weight: f64,
    /// Shape exponent above the target (target goals only). Default 1.
    pub weight_upper: f64,
    /// Importance 1..=5 (relative weight in the geometric mean). Default 3.
    pub importance: u8,
}

impl<'a> Objective<'a> {
    /// Objective with weights 1 and importance 3 (Design-Expert's defaults).
    pub fn new(model: &'a Fit, goal: Goal) -> Self {
        Self {
            name: model.response().to_owned(),
            model,
            goal,
            weight: 1.0,
            weight_upper: 1.0,
            importance: 3,
        }
    }

    /// Set both shape exponents.
    pub fn with_weights(mut self, weight: f64, weight_upper: f64) -> Self {
        self.weight = weight;
        self.weight_upper = weight_upper;
        self
    }

    /// Set the importance (1..=5).
    pub fn with_importance(mut self, importance: u8) -> Self {
        self.importance = importance;
        self
    }

    /// Individual desirability of a predicted value.
    pub fn desirability(&self, y: f64) -> f64 {
        self.goal.desirability(y, self.weight, self.weight_upper)
    }
}

/// Search region in coded units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "snake_case")]
pub enum Region {
    /// The cube `[-1, 1]^k` (factorial, Box–Behnken, face-centred designs).
    Cube,
    /// The ball of the given radius, e.g. `alpha` of a rotatable CCD.
    Sphere {
        /// Radius in coded units.
        radius: f64,
    },
}

impl Region {
    fn project(&self, x: &mut [f64]) {
        match *self {
            Region::Cube => x.iter_mut().for_each(|v| *v = v.clamp(-1.0, 1.0)),
            Region::Sphere { radius } => {
                let n = x.iter().map(|v| v * v).sum::<f64>().sqrt();
                if n > radius {
                    x.iter_mut().for_each(|v| *v *= radius / n);
                }
            }
        }
    }

    fn extent(&self) -> f64 {
        match *self {
            Region::Cube => 1.0,
            Region::Sphere { radius } => radius,
        }
    }

    /// True if `x` lies in the region (with a small tolerance).
    pub fn contains(&self, x: &[f64]) -> bool {
        match *self {
            Region::Cube => x.iter().all(|v| v.abs() <= 1.0 + 1e-12),
            Region::Sphere { radius } => {
                x.iter().map(|v| v * v).sum::<f64>().sqrt() <= radius * (1.0 + 1e-12)
            }
        }
    }
}

/// Options of [`optimize`]. Deserialisable (missing fields take the
/// defaults) so a command line or config file can carry them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct OptimumOptions {
    /// Search region (default the cube).
    pub region: Region,
    /// Number of starting points including the centre (default 64).
    pub starts: usize,
    /// Seed of the Latin-hypercube starts; the search is deterministic for a seed.
    pub seed: u64,
    /// Natural ranges of the factors, to report solutions in natural units.
    pub factor_ranges: Option<Vec<Factor>>,
    /// Maximum number of solutions returned (default 10).
    pub max_solutions: usize,
    /// Solutions closer than this (Euclidean, coded units) are the same
    /// solution (default 0.05).
    pub distinct_tol: f64,
    /// Desirabilities within this of the best count as tied (default 1e-4).
    pub tie_tol: f64,
    /// Maximum objective evaluations per start (default 4000).
    pub max_evals: usize,
}

impl Default for OptimumOptions {
    fn default() -> Self {
        Self {
            region: Region::Cube,
            starts: 64,
            seed: 0,
            factor_ranges: None,
            max_solutions: 10,
            distinct_tol: 0.05,
            tie_tol: 1e-4,
            max_evals: 4000,
        }
    }
}

/// Prediction of one response at a solution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PredictedResponse {
    /// Response name.
    pub name: String,
    /// Predicted value.
    pub value: f64,
    /// Its individual desirability.
    pub desirability: f64,
}

/// One optimum found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Solution {
    /// Factor settings in coded units.
    pub coded: Vec<f64>,
    /// Factor settings in natural units (if factor ranges were given).
    pub natural: Option<Vec<f64>>,
    /// Predicted responses.
    pub responses: Vec<PredictedResponse>,
    /// Overall desirability.
    pub desirability: f64,
    /// Euclidean distance from the design centre (coded units).
    pub distance_from_center: f64,
}

/// Result of [`optimize`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OptimumResult {
    /// Factor names.
    pub factors: Vec<String>,
    /// Distinct solutions: first those tied with the best desirability
    /// (within `tie_tol`), closest to the design centre first; then the
    /// others by decreasing desirability. At most `max_solutions`.
    pub solutions: Vec<Solution>,
    /// Best overall desirability found.
    pub best_desirability: f64,
    /// True when the best desirability is ≈ 1 and is reached at two or more
    /// distinct points: the goals are met on a whole set of factor settings
    /// (e.g. a level set of a target), not at a unique optimum.
    pub level_set: bool,
    /// Number of starting points used.
    pub starts: usize,
    /// Number of starts that ended tied with the best desirability.
    pub starts_at_best: usize,
    /// Number of distinct tied points found (those starts plus the
    /// centre-ward refinements of the tie-break).
    pub distinct_at_best: usize,
    /// Largest distance (coded units) between two tied-best solutions.
    pub spread: f64,
    /// Per-factor minimum over the tied-best solutions (coded); empty when
    /// no point has a desirability above 0.
    pub coded_min: Vec<f64>,
    /// Per-factor maximum over the tied-best solutions (coded).
    pub coded_max: Vec<f64>,
    /// Per-factor minimum over the tied-best solutions (natural), if ranges given.
    pub natural_min: Option<Vec<f64>>,
    /// Per-factor maximum over the tied-best solutions (natural), if ranges given.
    pub natural_max: Option<Vec<f64>>,
    /// One-sentence summary, including the tie-break used.
    pub note: String,
}

fn validate(objectives: &[Objective<'_>], options: &OptimumOptions) -> Result<usize, OptimumError> {
    let first = objectives.first().ok_or(OptimumError::NoResponses)?;
    let k = first.model.model().factors().len();
    for o in objectives {
        let kk = o.model.model().factors().len();
        if kk != k {
            return Err(OptimumError::FactorCountMismatch {
                response: o.name.clone(),
                expected: k,
                found: kk,
            });
        }
        let bad = |reason: String| OptimumError::InvalidGoal {
            response: o.name.clone(),
            reason,
        };
        let (lower, upper) = o.goal.limits();
        if !(lower.is_finite() && upper.is_finite() && lower < upper) {
            return Err(bad(format!(
                "limits must be finite with lower < upper (got lower {lower}, upper {upper})"
            )));
        }
        if let Goal::Target { target, .. } = o.goal {
            if !(target.is_finite() && lower <= target && target <= upper) {
                return Err(bad(format!(
                    "target {target} must lie within [lower {lower}, upper {upper}]"
                )));
            }
        }
        if !(o.weight.is_finite()
            && o.weight > 0.0
            && o.weight_upper.is_finite()
            && o.weight_upper > 0.0)
        {
            return Err(bad(format!(
                "weights must be positive and finite (got {} and {})",
                o.weight, o.weight_upper
            )));
        }
        if !(1..=5).contains(&o.importance) {
            return Err(OptimumError::InvalidImportance {
                response: o.name.clone(),
                importance: o.importance,
            });
        }
    }
    if let Some(r) = &options.factor_ranges {
        if r.len() != k {
            return Err(OptimumError::FactorRangesLength {
                expected: k,
                found: r.len(),
            });
        }
        for f in r {
            if f.validate().is_err() {
                return Err(OptimumError::InvalidFactorRange {
                    factor: f.name.clone(),
                    low: f.low,
                    high: f.high,
                });
            }
        }
    }
    if let Region::Sphere { radius } = options.region {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(OptimumError::InvalidOption {
                option: "region.radius",
                reason: format!("{radius} is not a positive finite radius"),
            });
        }
    }
    let checks: [(&'static str, bool, String); 4] = [
        (
            "starts",
            options.starts >= 1,
            format!("{} (need at least 1)", options.starts),
        ),
        (
            "distinct_tol",
            options.distinct_tol.is_finite() && options.distinct_tol > 0.0,
            format!("{} (need > 0)", options.distinct_tol),
        ),
        (
            "tie_tol",
            options.tie_tol.is_finite() && options.tie_tol >= 0.0,
            format!("{} (need >= 0)", options.tie_tol),
        ),
        (
            "max_evals",
            options.max_evals >= 10,
            format!("{} (need >= 10)", options.max_evals),
        ),
    ];
    for (option, ok, reason) in checks {
        if !ok {
            return Err(OptimumError::InvalidOption { option, reason });
        }
    }
    Ok(k)
}

/// Overall desirability and total violation at `x`.
fn overall(objectives: &[Objective<'_>], x: &[f64]) -> (f64, f64, Vec<PredictedResponse>) {
    let mut log_sum = 0.0;
    let mut weight_sum = 0.0;
    let mut feasible = true;
    let mut violation = 0.0;
    let mut preds = Vec::with_capacity(objectives.len());
    for o in objectives {
        let y = o.model.predict(x);
        let d = o.desirability(y);
        violation += o.goal.violation(y);
        if d <= 0.0 {
            feasible = false;
        } else if !matches!(o.goal, Goal::InRange { .. }) {
            let r = f64::from(o.importance);
            log_sum += r * d.ln();
            weight_sum += r;
        }
        preds.push(PredictedResponse {
            name: o.name.clone(),
            value: y,
            desirability: d,
        });
    }
    let d = if !feasible {
        0.0
    } else if weight_sum == 0.0 {
        1.0
    } else {
        (log_sum / weight_sum).exp()
    };
    (d, violation, preds)
}

/// Derringer–Suich multi-response optimisation inside the coded region.
///
/// Deterministic for a given `options.seed`. See the module docs for the
/// algorithm, the level-set report and the tie-break.
pub fn optimize(
    objectives: &[Objective<'_>],
    options: &OptimumOptions,
) -> Result<OptimumResult, OptimumError> {
    let k = validate(objectives, options)?;
    let region = options.region;
    // Minimised by Nelder–Mead: -D where feasible, violation where not, plus
    // the squared distance to the region of the unprojected point.
    let objective = |z: &[f64]| -> f64 {
        let mut x = z.to_vec();
        region.project(&mut x);
        let out: f64 = z.iter().zip(&x).map(|(a, b)| (a - b) * (a - b)).sum();
        let (d, viol, _) = overall(objectives, &x);
        let s = if d > 0.0 { -d } else { viol };
        s + out
    };

    let mut starts = vec![vec![0.0; k]];
    starts.extend(latin_hypercube(
        options.starts.saturating_sub(1),
        k,
        options.seed,
        region.extent(),
    ));
    for s in &mut starts {
        region.project(s);
    }

    // (coded point, desirability, violation)
    let mut ends: Vec<(Vec<f64>, f64, f64)> = Vec::with_capacity(starts.len());
    for s in &starts {
        let mut step = 0.25 * region.extent();
        let mut x = s.clone();
        let mut fx = objective(&x);
        for _ in 0..4 {
            let (nx, nf) = nelder_mead(&objective, &x, step, options.max_evals);
            let improved = nf < fx - 1e-15;
            x = nx;
            fx = nf.min(fx);
            if !improved {
                break;
            }
            step *= 0.1;
        }
        region.project(&mut x);
        let (d, viol, _) = overall(objectives, &x);
        ends.push((x, d, viol));
    }

    let best = ends.iter().map(|e| e.1).fold(0.0_f64, f64::max);
    let centre_dist = |x: &[f64]| x.iter().map(|v| v * v).sum::<f64>().sqrt();
    let dist = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f64>()
            .sqrt()
    };

    // Tied with the best (only meaningful when something is feasible).
    let mut tied: Vec<(Vec<f64>, f64, f64)> = if best > 0.0 {
        ends.iter()
            .filter(|e| e.1 >= best - options.tie_tol)
            .cloned()
            .collect()
    } else {
        Vec::new()
    };
    let starts_at_best = tied.len();
    tied.sort_by(|a, b| centre_dist(&a.0).total_cmp(&centre_dist(&b.0)));
    // Tie-break refinement: when several points tie, move the most central
    // ones towards the centre *along* the tied set, so that the first
    // solution really is (close to) the tied point nearest the centre and
    // not just the most central end point of a random start.
    // Only when the goals are fully met (D ≈ 1): below 1 a tie band of
    // `tie_tol` around a unique optimum must not be traded for centrality.
    if tied.len() >= 2 && best >= 1.0 - options.tie_tol {
        let refined: Vec<(Vec<f64>, f64, f64)> = tied
            .iter()
            .take(REFINE_STARTS)
            .filter_map(|e| {
                let x = refine_towards_centre(objectives, region, &e.0, best, options);
                let (d, viol, _) = overall(objectives, &x);
                (d >= best - options.tie_tol).then_some((x, d, viol))
            })
            .collect();
        tied.extend(refined);
        tied.sort_by(|a, b| centre_dist(&a.0).total_cmp(&centre_dist(&b.0)));
    }
    let mut chosen: Vec<Vec<f64>> = Vec::new();
    for e in &tied {
        if chosen.iter().all(|c| dist(c, &e.0) > options.distinct_tol) {
            chosen.push(e.0.clone());
        }
    }
    let distinct_at_best = chosen.len();
    let mut spread = 0.0_f64;
    for (i, a) in chosen.iter().enumerate() {
        for b in &chosen[i + 1..] {
            spread = spread.max(dist(a, b));
        }
    }
    // Bounding box of the tied set (empty when nothing is feasible).
    let (mut coded_min, mut coded_max) = match tied.first() {
        Some(first) => (first.0.clone(), first.0.clone()),
        None => (Vec::new(), Vec::new()),
    };
    for e in &tied {
        for j in 0..k {
            coded_min[j] = coded_min[j].min(e.0[j]);
            coded_max[j] = coded_max[j].max(e.0[j]);
        }
    }
    // The rest: by decreasing desirability (then smaller violation).
    let mut rest: Vec<&(Vec<f64>, f64, f64)> = ends
        .iter()
        .filter(|e| !(best > 0.0 && e.1 >= best - options.tie_tol))
        .collect();
    rest.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.2.total_cmp(&b.2)));
    for e in rest {
        if chosen.iter().all(|c| dist(c, &e.0) > options.distinct_tol) {
            chosen.push(e.0.clone());
        }
    }
    chosen.truncate(options.max_solutions.max(1));

    let ranges = options.factor_ranges.as_ref();
    let to_natural = |x: &[f64]| -> Option<Vec<f64>> {
        ranges.map(|r| {
            r.iter()
                .zip(x)
                .map(|(f, v)| f.to_natural(*v).unwrap_or(f64::NAN))
                .collect()
        })
    };
    let solutions: Vec<Solution> = chosen
        .into_iter()
        .map(|x| {
            let (d, _, responses) = overall(objectives, &x);
            Solution {
                natural: to_natural(&x),
                distance_from_center: centre_dist(&x),
                responses,
                desirability: d,
                coded: x,
            }
        })
        .collect();
    let natural_pair = |a: &[f64], b: &[f64]| -> (Option<Vec<f64>>, Option<Vec<f64>>) {
        match (to_natural(a), to_natural(b)) {
            (Some(lo), Some(hi)) => {
                let (l, h): (Vec<f64>, Vec<f64>) = lo
                    .iter()
                    .zip(&hi)
                    .map(|(l, h)| (l.min(*h), l.max(*h)))
                    .unzip();
                (Some(l), Some(h))
            }
            _ => (None, None),
        }
    };
    let (natural_min, natural_max) = if tied.is_empty() {
        (None, None)
    } else {
        natural_pair(&coded_min, &coded_max)
    };
    let level_set = best >= 1.0 - options.tie_tol && distinct_at_best >= 2;
    let starts_n = starts.len();
    let note = if best <= 0.0 {
        format!(
            "no point of the region reaches a desirability above 0 ({starts_n} starts); \
             solutions are ordered by smallest violation of the goal limits"
        )
    } else if level_set {
        format!(
            "level set: {starts_at_best} of {starts_n} starts reached desirability {best:.4}, \
             giving {distinct_at_best} distinct points up to {spread:.3} coded units apart, so \
             the optimum is not unique; tied solutions are ordered by distance from the design \
             centre (closest first)"
        )
    } else if distinct_at_best >= 2 {
        format!(
            "{starts_at_best} of {starts_n} starts reached the best desirability {best:.4} at \
             {distinct_at_best} distinct points; tied solutions are ordered by distance from \
             the design centre (closest first)"
        )
    } else {
        format!(
            "{starts_at_best} of {starts_n} starts reached the best desirability {best:.4} at a \
             single point"
        )
    };
    Ok(OptimumResult {
        factors: objectives[0].model.model().factors().to_vec(),
        solutions,
        best_desirability: best,
        level_set,
        starts: starts_n,
        starts_at_best,
        distinct_at_best,
        spread,
        coded_min,
        coded_max,
        natural_min,
        natural_max,
        note,
    })
}

/// How many of the most central tied solutions are refined towards the centre.
const REFINE_STARTS: usize = 5;

/// Minimise `|x|²` over the region subject to `D(x) >= best - tie_tol/100`,
/// by Nelder–Mead on an exact (non-smooth) penalty, restarted with shrinking
/// steps. Returns the projected end point (the caller re-checks D).
fn refine_towards_centre(
    objectives: &[Objective<'_>],
    region: Region,
    from: &[f64],
    best: f64,
    options: &OptimumOptions,
) -> Vec<f64> {
    let threshold = best - 0.01 * options.tie_tol;
    let penalised = |z: &[f64]| -> f64 {
        let mut x = z.to_vec();
        region.project(&mut x);
        let out: f64 = z.iter().zip(&x).map(|(a, b)| (a - b) * (a - b)).sum();
        let (d, _, _) = overall(objectives, &x);
        let norm2: f64 = x.iter().map(|v| v * v).sum();
        norm2 + 1e4 * (threshold - d).max(0.0) + out
    };
    let mut x = from.to_vec();
    let mut fx = penalised(&x);
    let mut step = 0.1 * region.extent();
    for _ in 0..6 {
        let (nx, nf) = nelder_mead(&penalised, &x, step, options.max_evals);
        if nf < fx {
            x = nx;
            fx = nf;
        }
        step *= 0.3;
    }
    region.project(&mut x);
    x
}

/// `n` Latin-hypercube points in `[-extent, extent]^k`.
fn latin_hypercube(n: usize, k: usize, seed: u64, extent: f64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let columns: Vec<Vec<f64>> = (0..k)
        .map(|_| {
            let mut strata: Vec<usize> = (0..n).collect();
            strata.shuffle(&mut rng);
            strata
                .into_iter()
                .map(|s| {
                    let u: f64 = rng.gen();
                    extent * (2.0 * (s as f64 + u) / n as f64 - 1.0)
                })
                .collect()
        })
        .collect();
    (0..n)
        .map(|i| columns.iter().map(|c| c[i]).collect())
        .collect()
}

/// Plain Nelder–Mead minimisation (reflection 1, expansion 2, contraction
/// 1/2, shrink 1/2) from `x0` with initial step `step` along each axis.
fn nelder_mead<F: Fn(&[f64]) -> f64>(
    f: &F,
    x0: &[f64],
    step: f64,
    max_evals: usize,
) -> (Vec<f64>, f64) {
    let k = x0.len();
    let mut simplex: Vec<(Vec<f64>, f64)> = Vec::with_capacity(k + 1);
    simplex.push((x0.to_vec(), f(x0)));
    for i in 0..k {
        let mut x = x0.to_vec();
        x[i] += if x[i] + step > 1e300 { -step } else { step };
        let fx = f(&x);
        simplex.push((x, fx));
    }
    let mut evals = k + 1;
    let point = |a: &[f64], b: &[f64], t: f64| -> Vec<f64> {
        a.iter().zip(b).map(|(a, b)| a + t * (b - a)).collect()
    };
    while evals < max_evals {
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        let fbest = simplex[0].1;
        let fworst = simplex[k].1;
        let size = simplex[1..]
            .iter()
            .map(|(x, _)| {
                x.iter()
                    .zip(&simplex[0].0)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        if (fworst - fbest).abs() <= 1e-14 * (1.0 + fbest.abs()) && size < 1e-9 {
            break;
        }
        if size < 1e-12 {
            break;
        }
        let mut centroid = vec![0.0; k];
        for (x, _) in &simplex[..k] {
            for (c, v) in centroid.iter_mut().zip(x) {
                *c += v / k as f64;
            }
        }
        let worst = simplex[k].0.clone();
        let xr = point(&centroid, &worst, -1.0);
        let fr = f(&xr);
        evals += 1;
        if fr < fbest {
            let xe = point(&centroid, &worst, -2.0);
            let fe = f(&xe);
            evals += 1;
            simplex[k] = if fe < fr { (xe, fe) } else { (xr, fr) };
        } else if fr < simplex[k - 1].1 {
            simplex[k] = (xr, fr);
        } else {
            let (xc, fc) = if fr < fworst {
                let xc = point(&centroid, &xr, 0.5);
                let fc = f(&xc);
                (xc, fc)
            } else {
                let xc = point(&centroid, &worst, 0.5);
                let fc = f(&xc);
                (xc, fc)
            };
            evals += 1;
            if fc < fr.min(fworst) {
                simplex[k] = (xc, fc);
            } else {
                let best = simplex[0].0.clone();
                for item in simplex.iter_mut().skip(1) {
                    let x = point(&best, &item.0, 0.5);
                    let fx = f(&x);
                    *item = (x, fx);
                }
                evals += k;
            }
        }
    }
    simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (x, fx) = simplex.swap_remove(0);
    (x, fx)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn desirability_shapes() {
        let g = Goal::Target {
            target: 10.0,
            lower: 0.0,
            upper: 20.0,
        };
        assert_eq!(g.desirability(10.0, 1.0, 1.0), 1.0);
        assert!((g.desirability(5.0, 1.0, 1.0) - 0.5).abs() < 1e-15);
        assert!((g.desirability(15.0, 1.0, 2.0) - 0.25).abs() < 1e-15);
        assert_eq!(g.desirability(21.0, 1.0, 1.0), 0.0);
        let m = Goal::Maximize {
            lower: 0.0,
            upper: 4.0,
        };
        assert!((m.desirability(1.0, 0.5, 1.0) - 0.5).abs() < 1e-15);
        let n = Goal::Minimize {
            lower: 0.0,
            upper: 4.0,
        };
        assert!((n.desirability(1.0, 1.0, 1.0) - 0.75).abs() < 1e-15);
    }

    #[test]
    fn nelder_mead_finds_quadratic_minimum() {
        let f = |x: &[f64]| (x[0] - 0.3).powi(2) + 2.0 * (x[1] + 0.2).powi(2);
        let (x, _) = nelder_mead(&f, &[0.0, 0.0], 0.25, 2000);
        assert!(
            (x[0] - 0.3).abs() < 1e-6 && (x[1] + 0.2).abs() < 1e-6,
            "{x:?}"
        );
    }
}
