//! Stage 4, the optimum: the Derringer–Suich desirability search for the target on a round's
//! quadratic, the whole level set, and the chosen setting ([`find`]).

use repose_doe::design::Factor;
use repose_doe::{Fit, Goal};
use serde::{Deserialize, Serialize};

use super::model::{natural, search_targets};
use super::surface::{FittedResponse, SurfaceFitSummary, SurfaceRound};
use super::{wording, Campaign, Halt, Next, StageKind, Stop};

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
        let text = if fitted.len() > 1 {
            let targets: Vec<_> = fitted.iter().map(|f| f.target.clone()).collect();
            wording::optimum_overall(&found, &names, &targets)
        } else {
            wording::optimum(&found, &names, fitted[0].target.value)
        };
        let summaries: Vec<SurfaceFitSummary> = fitted.into_iter().map(|f| f.summary).collect();
        let last = self.surfaces.last_mut().expect("round");
        last.fit = summaries.first().cloned();
        if summaries.len() > 1 {
            last.fits = summaries;
        }
        last.optimum = Some(found.choice.clone());
        self.decide(StageKind::Optimum, text);
        self.start_verification(round, found.choice)
    }
}
