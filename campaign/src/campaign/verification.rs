//! Stage 5, verification: replicate simulations at the optimum; [`judge`] accepts the mean or
//! says whether another response-surface round follows (and with which half-ranges).

use repose_api::{DesignRequest, ModelName};
use serde::{Deserialize, Serialize};

use super::model::observations;
use super::optimum::OptimumChoice;
use super::surface::SurfaceRound;
use super::{wording, Campaign, Halt, Next, StageKind, StageResult, Stop};
use crate::request::{relative_error_pct, Tolerance};

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

/// Judges the replicates `y` at `optimum` in `round` (0-based) with `max_extra` further rounds
/// allowed. `Err(NoVerificationRun)` without a completed run.
#[allow(clippy::too_many_arguments)]
pub(crate) fn judge(
    optimum: &OptimumChoice,
    factors: Vec<String>,
    y: Vec<f64>,
    target: f64,
    tolerance: Tolerance,
    round: u32,
    max_extra: u32,
) -> Result<(VerificationOutcome, VerificationNext), Stop> {
    if y.is_empty() {
        return Err(Stop::NoVerificationRun);
    }
    let n = y.len() as f64;
    let mean = y.iter().sum::<f64>() / n;
    let std = if y.len() > 1 {
        (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    let within = tolerance.accepts(mean, target);
    let outcome = VerificationOutcome {
        round,
        factors,
        point: optimum.natural.clone(),
        predicted: optimum.predicted,
        responses: y,
        mean,
        std,
        relative_error_pct: relative_error_pct(mean, target),
        error: mean - target,
        within_tolerance: within,
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
        let experiment = self.held_template(StageKind::Verification)?;
        let replicates = self.request.verification.replicates;
        self.decide(
            StageKind::Verification,
            wording::verification_plan(replicates, &self.request.tolerance),
        );
        Ok(Next::Submit(self.issue(
            StageKind::Verification,
            experiment,
            specs,
            DesignRequest::Explicit {
                points: vec![optimum.natural],
            },
            replicates,
            ModelName::None,
            Vec::new(),
        )))
    }

    pub(super) fn after_verification(&mut self, finished: &StageResult) -> Result<Next, Halt> {
        let round = self.surfaces.last().expect("round").clone();
        let optimum = round.optimum.clone().expect("optimum before verification");
        let names: Vec<String> = round.factors.iter().map(|f| f.name.clone()).collect();
        let (_, y, _) = observations(
            finished.batch,
            &finished.runs,
            &names,
            &self.request.response,
        )?;
        let r = &self.request;
        let (outcome, next) = judge(
            &optimum,
            names,
            y,
            r.target,
            r.tolerance,
            self.round,
            r.response_surface.max_extra_rounds,
        )?;
        let text = wording::verification(&outcome, r.target, &r.tolerance, &next);
        self.verifications.push(outcome.clone());
        self.decide(StageKind::Verification, text);
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
            VerificationNext::GiveUp => Err(Stop::StillOutside {
                rounds: self.round + 1,
                mean: outcome.mean,
                relative_error_pct: outcome.relative_error_pct,
            }
            .into()),
        }
    }
}
