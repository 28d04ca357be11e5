//! The `doe` chain's part of the page: screening, the steepest path, and per response-surface
//! round the surface, the optimum and the verification, each with its design table, ANOVA and
//! charts. Fits are recomputed from the runs with the functions the decisions used.

use maud::{html, Markup, Render};
use repose_api::{BatchRequest, RunView};
use repose_doe::Fit;

use super::html::{num_or_dash, table, verdict};
use super::svg::{contour, desirability_chart, normal_quantile, pareto, path_chart, scatter};
use super::{batch_of, response_of, result_for};
use crate::campaign::{fmt_num, fmt_p, screening_fit, surface_fit};
use crate::{
    relative_error_pct, Campaign, OptimumChoice, PathState, ScreeningOutcome, StageKind,
    StageResult, SurfaceRound, Target, VerificationOutcome,
};

/// The campaign, its batches' results and its targets, for the stage sections.
pub(super) struct Chain<'a> {
    c: &'a Campaign,
    results: &'a [StageResult],
    targets: Vec<Target>,
}

impl<'a> Chain<'a> {
    pub(super) fn new(c: &'a Campaign, results: &'a [StageResult]) -> Self {
        Chain {
            c,
            results,
            targets: c.request.targets(),
        }
    }

    /// Several targets: each response's tables and fits sit under its own heading.
    fn multi(&self) -> bool {
        self.targets.len() > 1
    }

    /// The stages reached, in order (nothing for a Bayesian campaign).
    pub(super) fn stages(&self) -> Markup {
        html! {
            @if let Some(sc) = &self.c.screening {
                (self.screening(sc))
            }
            @if let Some(p) = &self.c.path {
                (self.path(p))
            }
            @for round in &self.c.surfaces {
                (self.round(round))
            }
        }
    }

    fn heading(&self, t: &Target) -> Markup {
        html! {
            @if self.multi() {
                h3 { (t.label) " (target " (fmt_num(t.value)) ")" }
            }
        }
    }

    fn batch_of(
        &self,
        stage: StageKind,
        round: u32,
        t: &Target,
    ) -> Option<(&BatchRequest, &[RunView], usize)> {
        batch_of(self.c, self.results, stage, round, t)
            .map(|(b, res)| (&b.request, res.runs.as_slice(), res.batch))
    }

    /// Stage 1.
    fn screening(&self, sc: &ScreeningOutcome) -> Markup {
        let r = &self.c.request;
        let held: Vec<String> = sc
            .held
            .iter()
            .map(|h| format!("{} = {}", h.name, fmt_num(h.value)))
            .collect();
        html! {
            h2 { "1. Screening" }
            @for (i, t) in self.targets.iter().enumerate() {
                (self.heading(t))
                @if let Some((batch, runs, index)) = self.batch_of(StageKind::Screening, 0, t) {
                    (design_table(batch, runs, None))
                    @if let Ok(fit) = screening_fit(r, t, index, runs) {
                        (anova_table(&fit, r.alpha))
                    }
                }
                @let (t_values, t_critical) = match sc.responses.get(i) {
                    Some(e) => (&e.t_values, e.t_critical),
                    None => (&sc.t_values, sc.t_critical),
                };
                @let abs_t: Vec<f64> = t_values.iter().map(|t| t.map_or(0.0, f64::abs)).collect();
                div.figs { (pareto(&sc.factors, &abs_t, t_critical)) }
            }
            p {
                "Carried forward: " b { (sc.carried.join(", ")) } ". Held: "
                @if held.is_empty() { "none" } @else { (held.join(", ")) }
                "."
            }
        }
    }

    /// Stage 2.
    fn path(&self, p: &PathState) -> Markup {
        let targets = &self.targets;
        let t0 = &targets[0];
        let multi = self.multi();
        let mut header = vec!["step".to_owned()];
        header.extend(p.factors.iter().cloned());
        if multi {
            header.push(format!("predicted {}", t0.label));
            header.extend(targets.iter().map(|t| t.label.clone()));
            header.extend(["overall desirability", "runs"].map(String::from));
        } else {
            header.extend(["predicted", "simulated", "rel. error %", "runs"].map(String::from));
        }
        let rows: Vec<Vec<Markup>> = p
            .points
            .iter()
            .enumerate()
            .map(|(i, pt)| {
                let mut row = vec![if p.centre == Some(i) {
                    html! { b { (pt.step) " (centre)" } }
                } else {
                    pt.step.render()
                }];
                row.extend(pt.natural.iter().map(|v| fmt_num(*v).render()));
                row.push(fmt_num(pt.predicted).render());
                let not_run = if i < p.dispatched { "—" } else { "not run" };
                if multi {
                    for k in 0..targets.len() {
                        row.push(
                            pt.responses
                                .get(k)
                                .map_or(not_run.to_owned(), |y| fmt_num(*y))
                                .render(),
                        );
                    }
                    row.push(pt.desirability.map_or(String::new(), fmt_num).render());
                } else {
                    row.push(pt.response.map_or(not_run.to_owned(), fmt_num).render());
                    row.push(
                        pt.response
                            .map_or(String::new(), |y| fmt_num(relative_error_pct(y, t0.value)))
                            .render(),
                    );
                }
                row.push(pt.runs.render());
                row
            })
            .collect();
        let steps: Vec<String> = p
            .factors
            .iter()
            .zip(&p.step_natural)
            .map(|(n, s)| format!("{n} {}", fmt_num(*s)))
            .collect();
        let xs: Vec<f64> = p.points.iter().map(|pt| pt.step as f64).collect();
        let ys: Vec<f64> = p
            .points
            .iter()
            .map(|pt| pt.response.unwrap_or(f64::NAN))
            .collect();
        let predicted: Vec<f64> = p.points.iter().map(|pt| pt.predicted).collect();
        let desirability: Vec<f64> = p
            .points
            .iter()
            .map(|pt| pt.desirability.unwrap_or(f64::NAN))
            .collect();
        html! {
            h2 { "2. Steepest path" }
            p {
                (format!("{:?}", p.direction)) " from the "
                (format!("{:?}", p.start).to_lowercase()) "; base factor " (p.base_factor)
                "; steps " (steps.join(", ")) "."
            }
            (table(&header, &rows, 1))
            div.figs {
                (path_chart(&xs, &ys, &predicted, t0.value))
                @if multi {
                    (desirability_chart(&xs, &desirability))
                }
            }
        }
    }

    /// Stages 3 to 5 of one round.
    fn round(&self, round: &SurfaceRound) -> Markup {
        let r = &self.c.request;
        let levels: Vec<String> = round
            .factors
            .iter()
            .map(|f| format!("{} {}..{}", f.name, fmt_num(f.low), fmt_num(f.high)))
            .collect();
        html! {
            h2 {
                "3. Response surface"
                @if round.round > 0 { " — round " (round.round + 1) }
            }
            p { "Levels: " (levels.join(", ")) "." }
            @for t in &self.targets {
                (self.heading(t))
                @let batch = self.batch_of(StageKind::ResponseSurface, round.round, t);
                @if let Some((b, runs, _)) = batch {
                    (design_table(b, runs, None))
                }
                @let fit = batch.and_then(|(_, runs, index)| surface_fit(r, t, round, index, runs).ok());
                @if let Some(fit) = &fit {
                    (anova_table(fit, r.alpha))
                }
                @if let (Some(fit), Some(opt)) = (&fit, &round.optimum) {
                    h3 { "Contour plots" }
                    p { small { "Other factors at the optimum." } }
                    div.figs { (contours(round, fit, opt, t)) }
                    h3 { "Residual diagnostics" }
                    (diagnostics(fit))
                }
            }
            @if let Some(opt) = &round.optimum {
                (self.optimum(round, opt))
            }
            @for v in self.c.verifications.iter().filter(|v| v.round == round.round) {
                (self.verification(v))
            }
        }
    }

    /// Stage 4.
    fn optimum(&self, round: &SurfaceRound, opt: &OptimumChoice) -> Markup {
        let targets = &self.targets;
        let multi = self.multi();
        let predicted: Vec<String> = targets
            .iter()
            .zip(&opt.predictions)
            .map(|(t, p)| format!("{} {} (target {})", t.label, fmt_num(*p), fmt_num(t.value)))
            .collect();
        let mut header = vec!["#".to_owned()];
        header.extend(round.factors.iter().map(|f| f.name.clone()));
        if multi {
            header.extend(targets.iter().map(|t| format!("predicted {}", t.label)));
            header.push("overall desirability".to_owned());
        } else {
            header.extend(["predicted", "desirability"].map(String::from));
        }
        let rows: Vec<Vec<Markup>> = opt
            .solutions
            .iter()
            .enumerate()
            .map(|(i, sol)| {
                let mut row = vec![if i == 0 {
                    html! { b { "chosen" } }
                } else {
                    (i + 1).render()
                }];
                row.extend(sol.natural.iter().map(|v| fmt_num(*v).render()));
                if multi {
                    row.extend(sol.predictions.iter().map(|v| fmt_num(*v).render()));
                } else {
                    row.push(fmt_num(sol.predicted).render());
                }
                row.push(fmt_num(sol.desirability).render());
                row
            })
            .collect();
        let extent: Vec<String> = round
            .factors
            .iter()
            .zip(opt.natural_min.iter().zip(&opt.natural_max))
            .map(|(f, (lo, hi))| format!("{} {}..{}", f.name, fmt_num(*lo), fmt_num(*hi)))
            .collect();
        html! {
            h2 { "4. Optimum" }
            p { (opt.note) }
            @if multi {
                p {
                    "Overall desirability " (fmt_num(opt.desirability))
                    " at the chosen setting; predicted " (predicted.join(", ")) "."
                }
            }
            (table(&header, &rows, 1))
            @if !opt.natural_min.is_empty() {
                p {
                    "Level set: " (opt.starts_at_best) " of " (opt.starts)
                    " starts at the best desirability, " (opt.distinct_at_best)
                    " distinct settings, spread " (fmt_num(opt.spread)) " coded units; extent "
                    (extent.join(", ")) "."
                }
            }
        }
    }

    /// Stage 5 of one round.
    fn verification(&self, v: &VerificationOutcome) -> Markup {
        let t0 = &self.targets[0];
        let point: Vec<String> = v
            .factors
            .iter()
            .zip(&v.point)
            .map(|(n, x)| format!("{n} = {}", fmt_num(*x)))
            .collect();
        // One target: the round's verification batch.
        let batch = self
            .c
            .batches
            .iter()
            .find(|b| b.stage == StageKind::Verification && b.round == v.round)
            .and_then(|b| result_for(self.results, b.index).map(|res| (b, res)));
        html! {
            h2 { "5. Verification" }
            p { "At " (point.join(", ")) " (predicted " (fmt_num(v.predicted)) "):" }
            @if self.multi() {
                @for (t, check) in self.targets.iter().zip(&v.checks) {
                    (self.heading(t))
                    @if let Some((b, runs, _)) = self.batch_of(StageKind::Verification, v.round, t) {
                        (design_table(b, runs, Some(t.value)))
                    }
                    p {
                        "Predicted " (fmt_num(check.predicted)) " · mean " (fmt_num(check.mean))
                        " (sd " (fmt_num(check.std)) ", n = " (check.responses.len())
                        ") · target " (fmt_num(check.target)) " · relative error "
                        (fmt_num(check.relative_error_pct)) " % · " (verdict(check.within_tolerance))
                        " (tolerance " (t.tolerance.describe()) ")."
                    }
                }
            } @else {
                @if let Some((b, res)) = batch {
                    (design_table(&b.request, &res.runs, Some(t0.value)))
                }
                p {
                    "Mean " (fmt_num(v.mean)) " (sd " (fmt_num(v.std)) ", n = "
                    (v.responses.len()) ") · target " (fmt_num(t0.value)) " · relative error "
                    (fmt_num(v.relative_error_pct)) " % · " (verdict(v.within_tolerance))
                    " (tolerance " (t0.tolerance.describe()) ")."
                }
            }
        }
    }
}

/// A batch's runs in design order: run, row, replicate, factor values, the response (and its
/// relative error to `target`), status.
fn design_table(batch: &BatchRequest, runs: &[RunView], target: Option<f64>) -> Markup {
    let mut header = vec!["run".to_owned(), "row".to_owned(), "rep".to_owned()];
    header.extend(batch.factors.iter().map(|f| f.name.clone()));
    header.push(batch.response.clone());
    if target.is_some() {
        header.push("rel. error %".to_owned());
    }
    header.push("status".to_owned());
    let mut sorted: Vec<&RunView> = runs.iter().collect();
    sorted.sort_by_key(|r| (r.design_row, r.replicate));
    let rows: Vec<Vec<Markup>> = sorted
        .iter()
        .map(|r| {
            let mut row = vec![
                (r.run_index + 1).render(),
                (r.design_row + 1).render(),
                r.replicate.render(),
            ];
            for f in &batch.factors {
                row.push(
                    r.factors
                        .iter()
                        .find(|v| v.name == f.name)
                        .map_or("?".to_owned(), |v| fmt_num(v.natural))
                        .render(),
                );
            }
            let y = response_of(r, &batch.response);
            row.push(num_or_dash(y));
            if let Some(t) = target {
                row.push(num_or_dash(y.map(|y| relative_error_pct(y, t))));
            }
            row.push(r.status.as_str().render());
            row
        })
        .collect();
    table(&header, &rows, 0)
}

/// The ANOVA (significant sources in bold), the fit statistics and the coded equation.
fn anova_table(fit: &Fit, alpha: f64) -> Markup {
    let header = [
        "Source",
        "Sum of Squares",
        "df",
        "Mean Square",
        "F-value",
        "p-value",
    ];
    let rows: Vec<Vec<Markup>> = fit
        .anova()
        .iter()
        .map(|r| {
            vec![
                if r.p.is_some_and(|p| p < alpha) {
                    html! { b { (r.source) } }
                } else {
                    r.source.render()
                },
                fmt_num(r.sum_sq).render(),
                r.df.render(),
                r.mean_sq.map_or(String::new(), fmt_num).render(),
                r.f.map_or(String::new(), fmt_num).render(),
                r.p.map_or(String::new(), |p| fmt_p(Some(p))).render(),
            ]
        })
        .collect();
    let st = fit.stats();
    let or_na = |v: Option<f64>| v.map_or("n/a".to_owned(), fmt_num);
    let equation: Vec<String> = fit
        .coefficients()
        .iter()
        .map(|c| {
            if c.term == "Intercept" {
                fmt_num(c.estimate)
            } else {
                format!(
                    "{} {}·{}",
                    if c.estimate < 0.0 { "−" } else { "+" },
                    fmt_num(c.estimate.abs()),
                    c.term
                )
            }
        })
        .collect();
    html! {
        (table(&header, &rows, 1))
        p {
            small {
                "R² " (fmt_num(st.r2)) " · adjusted R² " (fmt_num(st.adj_r2))
                " · predicted R² " (or_na(st.pred_r2)) " · adequate precision "
                (or_na(st.adeq_precision)) " · std. dev. " (fmt_num(st.std_dev)) " · C.V. "
                (or_na(st.cv_percent)) " % · " (st.n_runs) " runs"
            }
        }
        p { "Coded equation: " (fit.response()) " = " (equation.join(" ")) }
    }
}

/// One contour plot per pair of the round's factors, the others at the optimum.
fn contours(round: &SurfaceRound, fit: &Fit, opt: &OptimumChoice, t: &Target) -> Markup {
    let k = round.factors.len();
    let pairs = (0..k).flat_map(|i| (i + 1..k).map(move |j| (i, j)));
    html! {
        @for (i, j) in pairs {
            @let (fi, fj) = (&round.factors[i], &round.factors[j]);
            @let z = |x: f64, y: f64| {
                let mut c = opt.coded.clone();
                c[i] = (x - fi.centre()) / fi.half_range();
                c[j] = (y - fj.centre()) / fj.half_range();
                fit.predict(&c)
            };
            (contour(
                &format!("{} over {} × {}", fit.response(), fi.name, fj.name),
                &fi.name,
                &fj.name,
                (fi.low, fi.high),
                (fj.low, fj.high),
                &z,
                t.value,
                &[(opt.natural[i], opt.natural[j], "optimum")],
            ))
        }
    }
}

/// The residual diagnostics: normal probability plot, residuals against predicted, predicted
/// against actual.
fn diagnostics(fit: &Fit) -> Markup {
    let d = fit.diagnostics();
    let mut res: Vec<f64> = d
        .iter()
        .map(|r| r.internally_studentized.unwrap_or(r.residual))
        .collect();
    res.sort_by(f64::total_cmp);
    let n = res.len() as f64;
    let normal: Vec<(f64, f64)> = res
        .iter()
        .enumerate()
        .map(|(i, r)| (*r, normal_quantile((i as f64 + 1.0 - 0.375) / (n + 0.25))))
        .collect();
    let rv: Vec<(f64, f64)> = d
        .iter()
        .map(|r| (r.predicted, r.internally_studentized.unwrap_or(r.residual)))
        .collect();
    let pa: Vec<(f64, f64)> = d.iter().map(|r| (r.actual, r.predicted)).collect();
    html! {
        div.figs {
            (scatter(
                "Normal probability plot",
                "studentized residual",
                "normal quantile",
                &normal,
                false,
                false,
            ))
            (scatter(
                "Residuals vs predicted",
                "predicted",
                "studentized residual",
                &rv,
                false,
                true,
            ))
            (scatter("Predicted vs actual", "actual", "predicted", &pa, true, false))
        }
    }
}
