//! Stage 2, the steepest path: [`lay_out`] turns the screening coefficients into Montgomery's
//! path toward the target, [`assess`] reads each dispatched batch and says whether to walk on
//! or which point becomes the response surface's centre.

use std::collections::BTreeMap;

use repose_api::{DesignRequest, ModelName};
use repose_doe::design::{Factor, PathClamp, PathDirection, SteepestPath};
use serde::{Deserialize, Serialize};

use super::model::{candidate_factors, natural, observations};
use super::screening::ScreeningOutcome;
use super::{wording, Campaign, Halt, Next, StageKind, StageResult, Stop};
use crate::error::CampaignError;
use crate::request::{CampaignRequest, PathDirectionSetting, PathStartSetting, Tolerance};

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
}

/// What the last path batch means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PathVerdict {
    /// Send the next points.
    WalkOn,
    /// Centre the response surface on this point.
    Centre { centre: usize, end: PathEnd },
}

/// Lays out the path from the screening outcome (the carried factors' coefficients).
pub(crate) fn lay_out(
    request: &CampaignRequest,
    screening: &ScreeningOutcome,
    all: &[Factor],
) -> Result<(PathState, DirectionReason), Halt> {
    let carried: Vec<usize> = screening
        .carried
        .iter()
        .map(|n| {
            screening
                .factors
                .iter()
                .position(|f| f == n)
                .expect("a candidate")
        })
        .collect();
    let coefficients: Vec<f64> = carried.iter().map(|&i| screening.estimates[i]).collect();
    if coefficients.iter().all(|b| *b == 0.0) {
        return Err(Stop::NoDirection.into());
    }
    let intercept = screening.intercept;
    let path_factors: Vec<Factor> = carried.iter().map(|&i| all[i].clone()).collect();
    let settings = &request.steepest;
    let target = request.target;
    let predict =
        |c: &[f64]| intercept + coefficients.iter().zip(c).map(|(b, x)| b * x).sum::<f64>();
    let corner = |dir: PathDirection| -> Vec<f64> {
        coefficients
            .iter()
            .map(|b| if b * dir.sign() >= 0.0 { -1.0 } else { 1.0 })
            .collect()
    };
    let (direction, why) = match (settings.direction, settings.start) {
        (PathDirectionSetting::Ascent, _) => (PathDirection::Ascent, DirectionReason::Requested),
        (PathDirectionSetting::Descent, _) => (PathDirection::Descent, DirectionReason::Requested),
        (PathDirectionSetting::Auto, PathStartSetting::Centre) => {
            let above = target >= intercept;
            (
                if above {
                    PathDirection::Ascent
                } else {
                    PathDirection::Descent
                },
                DirectionReason::Centre {
                    target,
                    intercept,
                    above,
                },
            )
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
                DirectionReason::Corner {
                    low_corner: pa,
                    high_corner: pd,
                    side: match (ascent_ok && descent_ok, ascent) {
                        (true, _) => CornerSide::Nearer,
                        (false, true) => CornerSide::Below,
                        (false, false) => CornerSide::Above,
                    },
                    target,
                    maybe_unreachable: ascent_ok != descent_ok,
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
    let state = PathState {
        factors: screening.carried.clone(),
        coefficients,
        base_factor: path.factor_names[path.base_factor].clone(),
        direction,
        start: settings.start,
        step_natural: path.step_natural.clone(),
        points,
        dispatched: 0,
        centre: None,
        crossed: false,
    };
    Ok((state, why))
}

/// Records the batch's mean responses on their path points and decides: walk on, or centre.
/// `Err(NoPathRun)` when the walk is over and no point has a response.
pub(crate) fn assess(
    path: &mut PathState,
    path_points: &[usize],
    y: &[f64],
    rows: &[u32],
    target: f64,
    tolerance: Tolerance,
) -> Result<PathVerdict, Stop> {
    let mut sums: BTreeMap<usize, (f64, usize)> = BTreeMap::new();
    for (v, row) in y.iter().zip(rows) {
        if let Some(&point) = path_points.get(*row as usize) {
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
        return Ok(PathVerdict::WalkOn);
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
    let Some(&(centre, _)) = candidates
        .iter()
        .min_by(|a, b| (a.1 - target).abs().total_cmp(&(b.1 - target).abs()))
    else {
        return Err(Stop::NoPathRun);
    };
    path.centre = Some(centre);
    path.crossed = hit || crossing.is_some();
    let end = match crossing {
        Some(w) => PathEnd::Crossed {
            from: w[0].0,
            to: w[1].0,
        },
        None if hit => PathEnd::Hit,
        None => PathEnd::NeverCrossed,
    };
    Ok(PathVerdict::Centre { centre, end })
}

impl Campaign {
    /// Lays out the path after screening and sends its first points.
    pub(super) fn start_path(
        &mut self,
        screening: &ScreeningOutcome,
        all: &[Factor],
    ) -> Result<Next, Halt> {
        let (state, why) = lay_out(&self.request, screening, all)?;
        let s = &self.request.steepest;
        self.decide(
            StageKind::Steepest,
            wording::path_layout(&state, &why, s.round_decimals, s.max_points),
        );
        self.path = Some(state);
        Ok(Next::Submit(self.dispatch_path()?))
    }

    fn dispatch_path(&mut self) -> Result<repose_api::BatchRequest, CampaignError> {
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

    pub(super) fn after_path(&mut self, finished: &StageResult) -> Result<Next, Halt> {
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
        match assess(path, &issued.path_points, &y, &rows, target, tolerance)? {
            PathVerdict::WalkOn => Ok(Next::Submit(self.dispatch_path()?)),
            PathVerdict::Centre { centre, end } => {
                let path = self.path.as_ref().expect("path");
                let text = wording::path_end(path, &end, centre, target);
                let centre_point = path.points[centre].natural.clone();
                let half: Vec<f64> = path.step_natural.iter().map(|s| s.abs()).collect();
                self.decide(StageKind::Steepest, text);
                self.start_surface(centre_point, half)
            }
        }
    }
}
