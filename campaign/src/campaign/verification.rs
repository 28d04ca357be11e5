//! Stage 5, verification: replicate simulations at the optimum; [`judge`] accepts the mean or
//! says whether another response-surface round follows (and with which half-ranges).

use repose_api::{DesignRequest, ModelName};

use super::model::observations;
use super::outcome::{
    Decided, OptimumChoice, ResponseCheck, Stop, SurfaceRound, VerificationNext,
    VerificationOutcome,
};
use super::{Campaign, Halt, Next, StageKind, StageResult};
use crate::request::{relative_error_pct, Target};

/// Judges the replicates at `optimum` in `round` (0-based) with `max_extra` further rounds
/// allowed: `measured` holds each target with its completed responses (target order).
/// `Err(NoVerificationRun)` when a target has no completed run.
pub(crate) fn judge(
    optimum: &OptimumChoice,
    factors: Vec<String>,
    measured: Vec<(Target, Vec<f64>)>,
    round: u32,
    max_extra: u32,
) -> Result<(VerificationOutcome, VerificationNext), Stop> {
    if measured.iter().any(|(_, y)| y.is_empty()) {
        return Err(Stop::NoVerificationRun);
    }
    let multi = measured.len() > 1;
    let checks: Vec<ResponseCheck> = measured
        .into_iter()
        .enumerate()
        .map(|(i, (t, y))| {
            let n = y.len() as f64;
            let mean = y.iter().sum::<f64>() / n;
            let std = if y.len() > 1 {
                (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
            } else {
                0.0
            };
            ResponseCheck {
                response: t.label,
                target: t.value,
                predicted: if multi {
                    optimum.predictions.get(i).copied().unwrap_or(f64::NAN)
                } else {
                    optimum.predicted
                },
                responses: y,
                mean,
                std,
                relative_error_pct: relative_error_pct(mean, t.value),
                within_tolerance: t.tolerance.accepts(mean, t.value),
            }
        })
        .collect();
    let within = checks.iter().all(|c| c.within_tolerance);
    let first = checks[0].clone();
    let outcome = VerificationOutcome {
        round,
        factors,
        point: optimum.natural.clone(),
        predicted: first.predicted,
        responses: first.responses,
        mean: first.mean,
        std: first.std,
        relative_error_pct: first.relative_error_pct,
        error: first.mean - first.target,
        within_tolerance: within,
        checks: if multi { checks } else { Vec::new() },
    };
    let next = if within {
        VerificationNext::Accept
    } else if round < max_extra {
        // A target the model could not reach means the region is in the wrong place, not
        // too coarse: move it (same size) so the optimum on its edge becomes its centre.
        // Shrinking it there would only box the search in further from the target.
        VerificationNext::AnotherRound {
            reachable: optimum.desirability > 0.999,
            round: round + 2,
            max_rounds: max_extra + 1,
        }
    } else {
        VerificationNext::GiveUp
    };
    Ok((outcome, next))
}

impl Campaign {
    /// Issues the verification batch at the round's optimum.
    pub(super) fn start_verification(
        &mut self,
        round: &SurfaceRound,
        optimum: OptimumChoice,
    ) -> Result<Next, Halt> {
        let specs = self.factor_specs(&round.factors);
        let replicates = self.request.verification.replicates;
        let targets = self.request.targets();
        self.record(
            StageKind::Verification,
            Decided::VerificationPlanned {
                replicates,
                targets: &targets,
            },
        );
        Ok(Next::Submit(self.issue_stage(
            StageKind::Verification,
            specs,
            DesignRequest::Explicit {
                points: vec![optimum.natural],
            },
            replicates,
            ModelName::None,
            Vec::new(),
        )?))
    }

    pub(super) fn after_verification(&mut self, results: &[StageResult]) -> Result<Next, Halt> {
        let round = self.surfaces.last().expect("round").clone();
        let optimum = round.optimum.clone().expect("optimum before verification");
        let names: Vec<String> = round.factors.iter().map(|f| f.name.clone()).collect();
        let mut measured = Vec::new();
        for (target, finished) in self.results_by_target(results) {
            let (_, y, _) = observations(finished.batch, &finished.runs, &names, &target.metric)?;
            measured.push((target, y));
        }
        let r = &self.request;
        let targets = r.targets();
        let (outcome, next) = judge(
            &optimum,
            names,
            measured,
            self.round,
            r.response_surface.max_extra_rounds,
        )?;
        self.verifications.push(outcome.clone());
        self.record(
            StageKind::Verification,
            Decided::Verified {
                outcome: &outcome,
                targets: &targets,
                next,
            },
        );
        match next {
            VerificationNext::Accept => {
                if self.request.drilling.is_some() {
                    return self.start_drilling();
                }
                Ok(self.finish())
            }
            VerificationNext::AnotherRound { .. } => {
                self.round += 1;
                let scale = next.half_range_scale();
                let half: Vec<f64> = round.half_ranges.iter().map(|h| h * scale).collect();
                self.start_surface(optimum.natural, half)
            }
            VerificationNext::GiveUp => {
                let stop = if outcome.checks.is_empty() {
                    Stop::StillOutside {
                        rounds: self.round + 1,
                        mean: outcome.mean,
                        relative_error_pct: outcome.relative_error_pct,
                    }
                } else {
                    Stop::TargetsStillOutside {
                        rounds: self.round + 1,
                        outside: outcome
                            .checks
                            .into_iter()
                            .filter(|c| !c.within_tolerance)
                            .collect(),
                    }
                };
                if self.request.drilling.is_some() {
                    // The validation still tells the lab how far the best setting found is
                    // from its held-back measurement; the campaign stops after it.
                    self.hold_unverified(&stop);
                    return self.start_drilling();
                }
                Err(stop.into())
            }
        }
    }
}
