//! Stage 3, the response surface: [`plan`] places the design around the path's centre (or the
//! last optimum) inside the allowed ranges; [`summarise`] reads the quadratic fit.

use repose_api::{CcdVariantName, DesignRequest, ModelName};
use repose_doe::design::{rotatable_alpha, Factor};
use repose_doe::{Fit, Region};

use super::model::{candidate_factors, natural, observations, surface_fit, target_goal};
use super::outcome::{
    Decided, FittedResponse, Stop, SurfaceFitSummary, SurfaceLayout, SurfaceNote, SurfaceRound,
};
use super::{Campaign, Halt, Next, StageKind, StageResult};
use crate::request::SurfaceDesign;

/// A planned response-surface round.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SurfacePlan {
    /// Factors with the design's levels (clamped to the allowed ranges).
    pub factors: Vec<Factor>,
    /// Half-ranges after the 5 % floor.
    pub half_ranges: Vec<f64>,
    pub design: DesignRequest,
    pub region: Region,
    pub layout: SurfaceLayout,
    pub notes: Vec<SurfaceNote>,
}

/// The design of a round centred on `centre` with half-ranges `half`, clamped to the allowed
/// ranges of `allowed`. `Err(EmptySurfaceRange)` when a clamped range is empty.
pub(crate) fn plan(
    allowed: &[Factor],
    centre: &[f64],
    half: Vec<f64>,
    setting: &SurfaceDesign,
) -> Result<SurfacePlan, Stop> {
    let k = allowed.len();
    let mut notes = Vec::new();
    let mut half = half;
    for (i, h) in half.iter_mut().enumerate() {
        let floor = 0.05 * allowed[i].half_range();
        if *h < floor {
            notes.push(SurfaceNote::HalfRangeRaised {
                factor: allowed[i].name.clone(),
                from: *h,
                to: floor,
            });
            *h = floor;
        }
    }
    let mut design_setting = setting.clone();
    let centre_points = design_setting.centre_points();
    let clamp = |h: &[f64], scale: f64| -> Vec<Factor> {
        allowed
            .iter()
            .zip(centre)
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
        let fits =
            star.iter().zip(centre).zip(&half).all(|((f, c), h)| {
                f.low <= c - alpha * h + 1e-12 && f.high >= c + alpha * h - 1e-12
            });
        if !fits {
            notes.push(SurfaceNote::InscribedInstead { alpha });
            design_setting = SurfaceDesign::CentralComposite {
                variant: CcdVariantName::Inscribed,
                centre_points,
            };
        }
    }
    let factors = clamp(&half, 1.0);
    if let Some(f) = factors.iter().find(|f| f.low >= f.high) {
        return Err(Stop::EmptySurfaceRange {
            factor: f.name.clone(),
        });
    }
    let (design, region, layout) = match (&design_setting, k) {
        (_, 1) => {
            let mut coded = vec![-1.0, -0.5, 0.5, 1.0];
            coded.extend(std::iter::repeat_n(0.0, centre_points.max(1)));
            let points = coded.iter().map(|c| natural(&factors, &[*c])).collect();
            (
                DesignRequest::Explicit { points },
                Region::Cube,
                SurfaceLayout::Line,
            )
        }
        (SurfaceDesign::BoxBehnken { .. }, 3..=7) => (
            DesignRequest::BoxBehnken {
                centre_points: Some(centre_points),
            },
            Region::Cube,
            SurfaceLayout::BoxBehnken { centre_points },
        ),
        (SurfaceDesign::BoxBehnken { .. }, _) => (
            DesignRequest::CentralComposite {
                variant: CcdVariantName::FaceCentred,
                centre_points,
            },
            Region::Cube,
            SurfaceLayout::FaceCentredForBoxBehnken { centre_points, k },
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
            SurfaceLayout::CentralComposite {
                variant: *variant,
                centre_points,
            },
        ),
    };
    Ok(SurfacePlan {
        factors,
        half_ranges: half,
        design,
        region,
        layout,
        notes,
    })
}

/// The fit's statistics the decisions and the report use.
pub(crate) fn summarise(fit: &Fit, alpha: f64) -> SurfaceFitSummary {
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
    let stats = fit.stats();
    SurfaceFitSummary {
        response: String::new(),
        r2: stats.r2,
        adj_r2: stats.adj_r2,
        pred_r2: stats.pred_r2,
        model_p: row_p("Model"),
        lack_of_fit_p: row_p("Lack of Fit"),
        significant_terms,
        coefficients: fit.coefficient_map(),
    }
}

impl Campaign {
    /// Plans a round around `centre` and issues its batch.
    pub(super) fn start_surface(&mut self, centre: Vec<f64>, half: Vec<f64>) -> Result<Next, Halt> {
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
        let plan = plan(
            &allowed,
            &centre,
            half,
            &self.request.response_surface.design,
        )?;
        self.record(
            StageKind::ResponseSurface,
            Decided::SurfacePlanned {
                round: self.round,
                layout: &plan.layout,
                factors: &plan.factors,
                notes: &plan.notes,
            },
        );
        self.surfaces.push(SurfaceRound {
            round: self.round,
            factors: plan.factors.clone(),
            centre,
            half_ranges: plan.half_ranges,
            design: plan.design.clone(),
            region: plan.region,
            fit: None,
            optimum: None,
            fits: Vec::new(),
        });
        let specs = self.factor_specs(&plan.factors);
        let replicates = self.request.response_surface.replicates;
        Ok(Next::Submit(self.issue_stage(
            StageKind::ResponseSurface,
            specs,
            plan.design,
            replicates,
            ModelName::Quadratic,
            Vec::new(),
        )?))
    }

    /// Fits one quadratic per target (`results` in experiment order), then the optimum.
    pub(super) fn after_surface(&mut self, results: &[StageResult]) -> Result<Next, Halt> {
        let round = self.surfaces.last().expect("surface round").clone();
        let names: Vec<String> = round.factors.iter().map(|f| f.name.clone()).collect();
        let multi = self.request.is_multi();
        let mut fitted = Vec::new();
        for (target, finished) in self.results_by_target(results) {
            let fit = surface_fit(
                &self.request,
                &target,
                &round,
                finished.batch,
                &finished.runs,
            )?;
            let mut summary = summarise(&fit, self.request.alpha);
            if multi {
                summary.response = target.label.clone();
            }
            self.record(
                StageKind::ResponseSurface,
                Decided::SurfaceFitted {
                    summary: &summary,
                    alpha: self.request.alpha,
                },
            );
            let (_, y, _) = observations(finished.batch, &finished.runs, &names, &target.metric)?;
            fitted.push(FittedResponse {
                goal: target_goal(target.value, &y),
                target,
                fit,
                summary,
            });
        }
        self.choose_optimum(&round, fitted)
    }
}
