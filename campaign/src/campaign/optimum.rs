//! Stage 4, the optimum: the Derringer–Suich desirability search for the target on a round's
//! quadratic, the whole level set, and the chosen setting ([`find`]).

use repose_doe::design::Factor;
use repose_doe::{Fit, Goal};

use super::model::{natural, search_targets};
use super::outcome::{
    Decided, FittedResponse, LevelSetPoint, OptimumChoice, OptimumFound, Stop, SurfaceFitSummary,
    SurfaceRound,
};
use super::{Campaign, Halt, Next, StageKind};

/// Searches the round's quadratic for the target; `observed` are the round's responses (they
/// set the desirability's range).
pub(crate) fn find(
    fits: &[&Fit],
    goals: &[Goal],
    round: &SurfaceRound,
    starts: usize,
) -> Result<OptimumFound, Stop> {
    let result = search_targets(fits, goals, &round.factors, round.region, starts)
        .map_err(Stop::OptimumSearchFailed)?;
    let best = result.solutions.first().ok_or(Stop::NoOptimum)?;
    let factors: &[Factor] = &round.factors;
    let to_point = |s: &repose_doe::Solution| LevelSetPoint {
        coded: s.coded.clone(),
        natural: s
            .natural
            .clone()
            .unwrap_or_else(|| natural(factors, &s.coded)),
        predicted: s.responses.first().map_or(f64::NAN, |r| r.value),
        desirability: s.desirability,
        predictions: if fits.len() > 1 {
            s.responses.iter().map(|r| r.value).collect()
        } else {
            Vec::new()
        },
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
        predictions: if fits.len() > 1 {
            best.responses.iter().map(|r| r.value).collect()
        } else {
            Vec::new()
        },
    };
    Ok(OptimumFound {
        choice,
        best_desirability: result.best_desirability,
    })
}

impl Campaign {
    /// Finds the round's optimum, records it with the fit, and starts the verification.
    pub(super) fn choose_optimum(
        &mut self,
        round: &SurfaceRound,
        fitted: Vec<FittedResponse>,
    ) -> Result<Next, Halt> {
        let fits: Vec<&Fit> = fitted.iter().map(|f| &f.fit).collect();
        let goals: Vec<Goal> = fitted.iter().map(|f| f.goal.clone()).collect();
        let found = find(
            &fits,
            &goals,
            round,
            self.request.response_surface.optimum_starts,
        )?;
        let names: Vec<String> = round.factors.iter().map(|f| f.name.clone()).collect();
        let targets: Vec<_> = fitted.iter().map(|f| f.target.clone()).collect();
        let summaries: Vec<SurfaceFitSummary> = fitted.into_iter().map(|f| f.summary).collect();
        let last = self.surfaces.last_mut().expect("round");
        last.fit = summaries.first().cloned();
        if summaries.len() > 1 {
            last.fits = summaries;
        }
        last.optimum = Some(found.choice.clone());
        let decided = if targets.len() > 1 {
            Decided::OptimumOverall {
                found: &found,
                factors: &names,
                targets: &targets,
            }
        } else {
            Decided::Optimum {
                found: &found,
                factors: &names,
                target: targets[0].value,
            }
        };
        self.record(StageKind::Optimum, decided);
        self.start_verification(round, found.choice)
    }
}
