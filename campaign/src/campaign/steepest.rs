//! Stage 2, the steepest path: [`lay_out`] turns the screening coefficients into Montgomery's
//! path toward the target, [`assess`] reads each dispatched batch and says whether to walk on
//! or which point becomes the response surface's centre.

use std::collections::BTreeMap;

use repose_api::{DesignRequest, ModelName};
use repose_doe::design::{Factor, PathClamp, PathDirection, SteepestPath};
use repose_doe::Goal;

use super::model::{candidate_factors, desirability, natural, observations, overall};
use super::outcome::{
    CornerSide, Decided, DirectionReason, PathEnd, PathPoint, PathState, ScreeningOutcome, Stop,
};
use super::{Campaign, Halt, Next, StageKind, StageResult};
use crate::error::CampaignError;
use crate::request::{CampaignRequest, PathDirectionSetting, PathStartSetting, Target, Tolerance};

/// What the last path batch means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PathVerdict {
    /// Send the next points.
    WalkOn,
    /// Centre the response surface on this point.
    Centre { centre: usize, end: PathEnd },
}

/// The direction of steepest ascent of the overall desirability `D = (Π dᵢ)^(1/n)` of the
/// screening models `ŷᵢ = aᵢ + bᵢ·x` at the centre (x = 0): `∇ln D ∝ Σᵢ ∇dᵢ / dᵢ` with
/// `∇dᵢ = sign(Tᵢ − aᵢ)·bᵢ / (distance from Tᵢ to the band's end on aᵢ's side)` for the
/// two-sided linear target desirability (dᵢ floored at 0.01 so a response at the band's edge
/// pulls hard but finitely). Returns the direction over `carried` and D at the centre.
pub(crate) fn desirability_direction(
    screening: &ScreeningOutcome,
    carried: &[usize],
    goals: &[Goal],
) -> (Vec<f64>, f64) {
    let mut g = vec![0.0; carried.len()];
    let mut ds = Vec::new();
    for (e, goal) in screening.responses.iter().zip(goals) {
        let Goal::Target {
            target,
            lower,
            upper,
        } = *goal
        else {
            unreachable!("campaign goals are targets")
        };
        let a = e.intercept;
        let d = desirability(goal, a);
        ds.push(d);
        let band = if a > target {
            upper - target
        } else {
            target - lower
        };
        let sign = if a == target {
            0.0
        } else {
            (target - a).signum()
        };
        let scale = sign / (band.max(f64::EPSILON) * d.max(0.01));
        for (gj, &i) in g.iter_mut().zip(carried) {
            *gj += scale * e.estimates[i];
        }
    }
    (g, overall(&ds))
}

/// Lays out the path from the screening outcome: for one target along the carried factors'
/// coefficients toward it, for several up the overall desirability
/// ([`desirability_direction`]; ascent from the corner it leaves, or from the centre).
pub(crate) fn lay_out(
    request: &CampaignRequest,
    screening: &ScreeningOutcome,
    all: &[Factor],
    goals: Vec<Goal>,
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
    let multi = !screening.responses.is_empty();
    let (coefficients, centre_d) = if multi {
        let (g, d) = desirability_direction(screening, &carried, &goals);
        (g, Some(d))
    } else {
        let b: Vec<f64> = carried.iter().map(|&i| screening.estimates[i]).collect();
        (b, None)
    };
    if coefficients.iter().all(|b| *b == 0.0) {
        return Err(Stop::NoDirection.into());
    }
    let intercept = screening.intercept;
    let path_factors: Vec<Factor> = carried.iter().map(|&i| all[i].clone()).collect();
    let settings = &request.steepest;
    let target = request.targets()[0].value;
    let predict =
        |c: &[f64]| intercept + coefficients.iter().zip(c).map(|(b, x)| b * x).sum::<f64>();
    let corner = |dir: PathDirection| -> Vec<f64> {
        coefficients
            .iter()
            .map(|b| if b * dir.sign() >= 0.0 { -1.0 } else { 1.0 })
            .collect()
    };
    let (direction, why) = match (settings.direction, settings.start) {
        _ if multi => (
            PathDirection::Ascent,
            DirectionReason::Desirability {
                centre: centre_d.unwrap_or(f64::NAN),
            },
        ),
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
        // With several targets `predicted` is the first target's screening prediction.
        let predicted = if multi {
            let e = &screening.responses[0];
            e.intercept
                + carried
                    .iter()
                    .zip(c)
                    .map(|(&i, x)| e.estimates[i] * x)
                    .sum::<f64>()
        } else {
            predict(c)
        };
        points.push(PathPoint {
            step: i + 1,
            natural: p.clone(),
            predicted,
            response: None,
            runs: 0,
            responses: Vec::new(),
            desirability: None,
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
        goals: if multi { goals } else { Vec::new() },
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

/// Several targets: records each point's mean responses (`per_target[t]` = (responses, design
/// rows) of target t) and their overall desirability, and decides: walk on while the
/// desirability still rises; centre on the most desirable point once it fell after its peak,
/// once a point has every response within tolerance (the most desirable of those), or when the
/// path is exhausted.
pub(crate) fn assess_desirability(
    path: &mut PathState,
    path_points: &[usize],
    per_target: &[(Vec<f64>, Vec<u32>)],
    targets: &[Target],
) -> Result<PathVerdict, Stop> {
    let n = per_target.len();
    let mut sums: BTreeMap<usize, Vec<(f64, usize)>> = BTreeMap::new();
    for (t, (y, rows)) in per_target.iter().enumerate() {
        for (v, row) in y.iter().zip(rows) {
            if let Some(&point) = path_points.get(*row as usize) {
                let e = sums.entry(point).or_insert_with(|| vec![(0.0, 0); n]);
                e[t].0 += v;
                e[t].1 += 1;
            }
        }
    }
    for (point, per) in sums {
        if per.iter().any(|(_, k)| *k == 0) {
            continue; // a response is missing: the point cannot be judged
        }
        let means: Vec<f64> = per.iter().map(|(s, k)| s / *k as f64).collect();
        let d: Vec<f64> = means
            .iter()
            .zip(&path.goals)
            .map(|(y, g)| desirability(g, *y))
            .collect();
        let p = &mut path.points[point];
        p.response = Some(means[0]);
        p.runs = per[0].1;
        p.desirability = Some(overall(&d));
        p.responses = means;
    }
    let evaluated: Vec<(usize, f64)> = path.points[..path.dispatched]
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.desirability.map(|d| (i, d)))
        .collect();
    let within = |i: usize| {
        targets
            .iter()
            .zip(&path.points[i].responses)
            .all(|(t, y)| t.tolerance.accepts(*y, t.value))
    };
    let hits: Vec<(usize, f64)> = evaluated.iter().copied().filter(|e| within(e.0)).collect();
    let best = |set: &[(usize, f64)]| {
        set.iter()
            .copied()
            .reduce(|a, b| if b.1 > a.1 { b } else { a })
    };
    let peak = best(&evaluated);
    let peaked = peak.is_some_and(|(i, d)| evaluated.iter().any(|e| e.0 > i && e.1 < d));
    let exhausted = path.dispatched >= path.points.len();
    if hits.is_empty() && !peaked && !exhausted {
        return Ok(PathVerdict::WalkOn);
    }
    let (centre, end) = if let Some((i, _)) = best(&hits) {
        (i, PathEnd::Hit)
    } else if let Some((i, _)) = peak {
        let end = if peaked {
            PathEnd::Peaked
        } else {
            PathEnd::NeverCrossed
        };
        (i, end)
    } else {
        return Err(Stop::NoPathRun);
    };
    path.centre = Some(centre);
    path.crossed = end != PathEnd::NeverCrossed;
    Ok(PathVerdict::Centre { centre, end })
}

impl Campaign {
    /// Lays out the path after screening and sends its first points.
    pub(super) fn start_path(
        &mut self,
        screening: &ScreeningOutcome,
        all: &[Factor],
        goals: Vec<Goal>,
    ) -> Result<Next, Halt> {
        let (state, why) = lay_out(&self.request, screening, all, goals)?;
        let s = &self.request.steepest;
        let (round_decimals, max_points) = (s.round_decimals, s.max_points);
        self.record(
            StageKind::Steepest,
            Decided::PathLaidOut {
                path: &state,
                why: &why,
                round_decimals,
                max_points,
            },
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
        let replicates = self.request.steepest.replicates;
        self.path.as_mut().expect("path").dispatched = to;
        self.issue_stage(
            StageKind::Steepest,
            specs,
            DesignRequest::Explicit { points },
            replicates,
            ModelName::None,
            indices,
        )
    }

    pub(super) fn after_path(&mut self, results: &[StageResult]) -> Result<Next, Halt> {
        let targets = self.request.targets();
        let target = targets[0].value;
        let tolerance = targets[0].tolerance;
        let issued = self.batches[results[0].batch].clone();
        let names = self.path.as_ref().expect("path").factors.clone();
        let mut per_target = Vec::new();
        for (t, finished) in self.results_by_target(results) {
            let (_, y, rows) = observations(finished.batch, &finished.runs, &names, &t.metric)?;
            per_target.push((y, rows));
        }
        let path = self.path.as_mut().expect("path");
        let verdict = if self.request.is_multi() {
            assess_desirability(path, &issued.path_points, &per_target, &targets)?
        } else {
            let (y, rows) = &per_target[0];
            assess(path, &issued.path_points, y, rows, target, tolerance)?
        };
        match verdict {
            PathVerdict::WalkOn => Ok(Next::Submit(self.dispatch_path()?)),
            PathVerdict::Centre { centre, end } => {
                let path = self.path.clone().expect("path");
                let decided = if self.request.is_multi() {
                    Decided::PathEndedOverall {
                        path: &path,
                        end,
                        centre,
                        targets: &targets,
                    }
                } else {
                    Decided::PathEnded {
                        path: &path,
                        end,
                        centre,
                        target,
                    }
                };
                self.record(StageKind::Steepest, decided);
                let centre_point = path.points[centre].natural.clone();
                let half: Vec<f64> = path.step_natural.iter().map(|s| s.abs()).collect();
                self.start_surface(centre_point, half)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::outcome::{CarryRule, ResponseEffects, RunCounts};

    fn effects(response: &str, intercept: f64, estimates: Vec<f64>) -> ResponseEffects {
        ResponseEffects {
            response: response.into(),
            t_values: vec![None; estimates.len()],
            p_values: vec![None; estimates.len()],
            estimates,
            intercept,
            t_critical: f64::NAN,
            significant: Vec::new(),
            counts: RunCounts {
                runs: 12,
                runs_used: 12,
                residual_df: 9,
            },
        }
    }

    #[test]
    fn the_path_direction_is_the_gradient_of_the_overall_desirability() {
        // Two linear screening models over three candidates, the second not carried.
        let responses = vec![
            effects("a.y1", 36.0, vec![4.0, 2.0, 9.0]),
            effects("b.y2", 2.2, vec![-0.1, 1.5, 9.0]),
        ];
        let screening = ScreeningOutcome {
            factors: vec!["A".into(), "X".into(), "B".into()],
            estimates: responses[0].estimates.clone(),
            t_values: vec![None; 3],
            p_values: vec![None; 3],
            intercept: 36.0,
            t_critical: f64::NAN,
            significant: Vec::new(),
            carried: vec!["A".into(), "B".into()],
            rule: CarryRule::Significant,
            held: Vec::new(),
            counts: RunCounts {
                runs: 12,
                runs_used: 12,
                residual_df: 9,
            },
            responses,
        };
        let carried = [0, 2];
        let goals = [
            Goal::Target {
                target: 34.0,
                lower: 28.0,
                upper: 44.0,
            },
            Goal::Target {
                target: 2.5,
                lower: 0.5,
                upper: 4.5,
            },
        ];
        let (g, d0) = desirability_direction(&screening, &carried, &goals);
        let ln_d = |x: &[f64]| {
            let d: Vec<f64> = screening
                .responses
                .iter()
                .zip(&goals)
                .map(|(e, goal)| {
                    let y = e.intercept
                        + carried
                            .iter()
                            .zip(x)
                            .map(|(&i, v)| e.estimates[i] * v)
                            .sum::<f64>();
                    desirability(goal, y)
                })
                .collect();
            overall(&d).ln()
        };
        assert!((d0 - ln_d(&[0.0, 0.0]).exp()).abs() < 1e-12);
        let h = 1e-6;
        let numeric: Vec<f64> = (0..2)
            .map(|j| {
                let mut up = [0.0, 0.0];
                let mut down = [0.0, 0.0];
                up[j] = h;
                down[j] = -h;
                (ln_d(&up) - ln_d(&down)) / (2.0 * h)
            })
            .collect();
        // Same direction (∇ln D = g / n with n = 2 responses).
        for (a, b) in g.iter().zip(&numeric) {
            assert!((a / 2.0 - b).abs() < 1e-6, "{g:?} vs {numeric:?}");
        }
    }
}
