//! The one place a campaign's outcomes become plain words: every sentence of the decision log
//! (and every stop reason) is written here from a typed outcome. The stage modules decide; this
//! module only describes, so the prose can change without touching the logic.

use repose_api::DesignRequest;
use repose_doe::design::{Factor, PathDirection};

use super::outcome::{
    CarryRule, CornerSide, Decided, DirectionReason, DrillingOutcome, ModelRole, OptimumFound,
    PathEnd, PathState, RunCounts, ScreeningOutcome, Stop, SurfaceFitSummary, SurfaceLayout,
    SurfaceNote, VerificationNext, VerificationOutcome,
};
use super::CalibratedValue;
use crate::request::{relative_error_pct, DrillingValidation, Target};

/// Formats a number with 4 significant digits for decision texts.
pub(crate) fn fmt_num(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        s
    }
}

/// A p-value as the ANOVA tables print it.
pub(crate) fn fmt_p(p: Option<f64>) -> String {
    match p {
        Some(p) if p < 1e-4 => "< 0.0001".to_owned(),
        Some(p) => format!("{p:.4}"),
        None => "n/a".to_owned(),
    }
}

/// `a`, `a and b`, `a, b and c`; `none` for an empty list.
pub(crate) fn list(names: &[String]) -> String {
    match names.len() {
        0 => "none".to_owned(),
        1 => names[0].clone(),
        n => format!("{} and {}", names[..n - 1].join(", "), names[n - 1]),
    }
}

fn describe_design(design: &DesignRequest) -> String {
    match design {
        DesignRequest::Factorial => "two-level full factorial".into(),
        DesignRequest::PlackettBurman { runs: Some(n) } => format!("{n}-run Plackett–Burman"),
        DesignRequest::PlackettBurman { runs: None } => "Plackett–Burman (smallest size)".into(),
        DesignRequest::BoxBehnken { .. } => "Box–Behnken".into(),
        DesignRequest::CentralComposite { .. } => "central composite".into(),
        DesignRequest::Explicit { points } => format!("{}-run explicit", points.len()),
    }
}

/// `name value, name value` for a setting.
pub(crate) fn setting(names: &[String], values: &[f64]) -> String {
    names
        .iter()
        .zip(values)
        .map(|(n, v)| format!("{n} {}", fmt_num(*v)))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Why the campaign stopped for a person to look.
pub(crate) fn stop(stop: &Stop) -> String {
    match stop {
        Stop::ModelUnavailable(reason) => reason.clone(),
        Stop::FitFailed {
            model,
            runs,
            reason,
        } => format!(
            "the {} model could not be fitted to the {runs} completed runs: {reason}",
            match model {
                ModelRole::Screening => "screening",
                ModelRole::Quadratic => "quadratic",
            }
        ),
        Stop::NoDirection => {
            "every carried coefficient is zero: the screening model has no direction".into()
        }
        Stop::NoPathRun => "no steepest-path run completed, so there is no point to centre the \
                            response surface on"
            .into(),
        Stop::EmptySurfaceRange { factor } => format!(
            "the response-surface range of {factor} is empty after clamping to the allowed range"
        ),
        Stop::OptimumSearchFailed(reason) => format!("optimum search failed: {reason}"),
        Stop::NoOptimum => "the optimum search found no solution".into(),
        Stop::NoVerificationRun => {
            "no verification run completed; resubmit the verification batch".into()
        }
        Stop::TargetsStillOutside { rounds, outside } => format!(
            "verification is still outside the tolerance after {rounds} response-surface rounds \
             for {}. The model's optimum does not reproduce in simulation for every target: \
             check the responses' noise (replicates), the allowed ranges, or whether the targets \
             can be met together.",
            outside
                .iter()
                .map(|c| format!(
                    "{} (mean {}, relative error {}%)",
                    c.response,
                    fmt_num(c.mean),
                    fmt_num(c.relative_error_pct)
                ))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        Stop::StillOutside {
            rounds,
            mean,
            relative_error_pct,
        } => format!(
            "verification is still outside the tolerance after {rounds} response-surface rounds \
             (last mean {}, relative error {}%). The model's optimum does not reproduce in \
             simulation: check the response's noise (replicates), the allowed ranges, or whether \
             the target is reachable.",
            fmt_num(*mean),
            fmt_num(*relative_error_pct)
        ),
    }
}

/// An entry of the decision log in words.
pub(crate) fn decided(what: &Decided) -> String {
    match *what {
        Decided::ScreeningPlan {
            factors,
            design,
            alpha,
            experiments,
        } => screening_plan(factors, design, alpha, experiments),
        Decided::Screened {
            outcome,
            alpha,
            max_factors,
        } => screening(outcome, alpha, max_factors),
        Decided::PathLaidOut {
            path,
            why,
            round_decimals,
            max_points,
        } => path_layout(path, why, round_decimals, max_points),
        Decided::PathEnded {
            path,
            end,
            centre,
            target,
        } => path_end(path, &end, centre, target),
        Decided::PathEndedOverall {
            path,
            end,
            centre,
            targets,
        } => path_end_desirability(path, &end, centre, targets),
        Decided::SurfacePlanned {
            round,
            layout,
            factors,
            notes,
        } => surface_plan(round, layout, factors, notes),
        Decided::SurfaceFitted { summary, alpha } => surface_fit(summary, alpha),
        Decided::Optimum {
            found,
            factors,
            target,
        } => optimum(found, factors, target),
        Decided::OptimumOverall {
            found,
            factors,
            targets,
        } => optimum_overall(found, factors, targets),
        Decided::VerificationPlanned {
            replicates,
            targets,
        } => verification_plan(replicates, targets),
        Decided::Verified {
            outcome,
            targets,
            next,
        } => verification(outcome, targets, &next),
        Decided::DrillingPlanned {
            drilling,
            unverified,
        } => drilling_plan(drilling, unverified),
        Decided::Drilled {
            outcome,
            several_targets,
            unverified,
        } => drilling(outcome, several_targets, unverified),
    }
}

/// The line logged when a stop is decided.
pub(crate) fn stopped(reason: &str) -> String {
    format!("Stopped: {reason}")
}

/// Stage 1 plan.
fn screening_plan(
    names: &[String],
    design: &DesignRequest,
    alpha: f64,
    experiments: &[String],
) -> String {
    let mut text = format!(
        "Screen {} candidate factors ({}) with a {} design, linear model, significance α = {}.",
        names.len(),
        list(names),
        describe_design(design),
        alpha
    );
    if experiments.len() > 1 {
        text.push_str(&format!(
            " Every stage runs each experiment the targets need ({}) at every design point, one \
             batch per experiment, and decides when the last has finished.",
            list(experiments)
        ));
    }
    text
}

/// Runs of a stage that gave a response no value (a failed run, e.g. a funnel that arched),
/// and what that leaves the fit; `None` when every run counted (or the counts predate them).
fn runs_without_value(counts: RunCounts) -> Option<String> {
    let RunCounts {
        runs,
        runs_used: used,
        residual_df,
    } = counts;
    if runs == 0 || used >= runs {
        return None;
    }
    Some(format!(
        "{} of {runs} runs gave no value, so the fit has {residual_df} residual degree{} of \
         freedom{}",
        runs - used,
        if residual_df == 1 { "" } else { "s" },
        if residual_df < 3 {
            ": too few to tell an effect from noise"
        } else {
            ""
        }
    ))
}

/// Stage 1 outcome: what was significant, what is carried and why, what is held.
fn screening(s: &ScreeningOutcome, alpha: f64, max_factors: usize) -> String {
    if !s.responses.is_empty() {
        return screening_overall(s, alpha, max_factors);
    }
    let index = |name: &String| s.factors.iter().position(|f| f == name).expect("a factor");
    let sig_text = |names: &[String]| -> String {
        names
            .iter()
            .map(|n| {
                let i = index(n);
                format!(
                    "{} (p {}, t {})",
                    n,
                    fmt_p(s.p_values[i]),
                    fmt_num(s.t_values[i].unwrap_or(f64::NAN))
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut text = match &s.rule {
        CarryRule::Significant => format!(
            "{} significant at α = {}: {}. They are carried forward.",
            list(&s.carried),
            alpha,
            sig_text(&s.significant)
        ),
        CarryRule::TopOfSignificant { dropped } => format!(
            "{} factors are significant at α = {} ({}), more than the {} a response surface is \
             planned for; the {} with the largest |t| are carried ({}), {} is/are held like the \
             non-significant ones.",
            s.significant.len(),
            alpha,
            sig_text(&s.significant),
            max_factors,
            max_factors,
            list(&s.carried),
            list(dropped)
        ),
        CarryRule::NoneSignificant => format!(
            "No factor is significant at α = {} (smallest p {}): the screening cannot separate \
             any effect from noise. Fallback: the {} with the largest |t| ({}) are carried \
             anyway; consider more replicates or wider ranges if the path does not move the \
             response.",
            alpha,
            fmt_p(s.p_values.iter().flatten().copied().reduce(f64::min)),
            s.carried.len(),
            sig_text(&s.carried)
        ),
    };
    if let Some(note) = runs_without_value(s.counts) {
        text.push_str(&format!(" {note}."));
    }
    if !s.held.is_empty() {
        let held_names: Vec<String> = s.held.iter().map(|h| h.name.clone()).collect();
        let values: Vec<String> = s
            .held
            .iter()
            .map(|h| {
                format!(
                    "{}{}",
                    fmt_num(h.value),
                    if h.user_value { " (user value)" } else { "" }
                )
            })
            .collect();
        text.push_str(&format!(
            " {} held at {} (mid-range unless the user fixed a value).",
            list(&held_names),
            values.join(", ")
        ));
    }
    text
}

/// Stage 1 with several targets: each response's significant factors, then the factors carried
/// over all of them.
fn screening_overall(s: &ScreeningOutcome, alpha: f64, max_factors: usize) -> String {
    let per: Vec<String> = s
        .responses
        .iter()
        .map(|e| {
            let sig: Vec<String> = e
                .significant
                .iter()
                .map(|n| {
                    let i = s.factors.iter().position(|f| f == n).expect("a factor");
                    format!(
                        "{n} (p {}, t {})",
                        fmt_p(e.p_values[i]),
                        fmt_num(e.t_values[i].unwrap_or(f64::NAN))
                    )
                })
                .collect();
            format!(
                "{}: {}{}",
                e.response,
                if sig.is_empty() {
                    "none".to_owned()
                } else {
                    sig.join(", ")
                },
                runs_without_value(e.counts).map_or(String::new(), |note| format!(" ({note})"))
            )
        })
        .collect();
    let mut text = format!(
        "Significant at α = {alpha}, per response — {}. ",
        per.join("; ")
    );
    text.push_str(&match &s.rule {
        CarryRule::Significant => format!(
            "{} significant for at least one response; carried forward.",
            list(&s.carried)
        ),
        CarryRule::TopOfSignificant { dropped } => format!(
            "{} factors are significant for at least one response, more than the {max_factors} a \
             response surface is planned for; the {max_factors} with the largest |t| over the \
             responses are carried ({}), {} is/are held like the non-significant ones.",
            s.significant.len(),
            list(&s.carried),
            list(dropped)
        ),
        CarryRule::NoneSignificant => format!(
            "No factor is significant for any response: the screening cannot separate any effect \
             from noise. Fallback: the {} with the largest |t| over the responses ({}) are \
             carried anyway; consider more replicates or wider ranges if the path does not move \
             the responses.",
            s.carried.len(),
            list(&s.carried)
        ),
    });
    if !s.held.is_empty() {
        let held_names: Vec<String> = s.held.iter().map(|h| h.name.clone()).collect();
        let values: Vec<String> = s
            .held
            .iter()
            .map(|h| {
                format!(
                    "{}{}",
                    fmt_num(h.value),
                    if h.user_value { " (user value)" } else { "" }
                )
            })
            .collect();
        text.push_str(&format!(
            " {} held at {} (mid-range unless the user fixed a value).",
            list(&held_names),
            values.join(", ")
        ));
    }
    text
}

/// Stage 2 plan: the direction and why, the steps, the points.
fn path_layout(
    path: &PathState,
    why: &DirectionReason,
    round_decimals: Option<u32>,
    max_points: usize,
) -> String {
    let why = match why {
        DirectionReason::Requested => "as requested".to_owned(),
        DirectionReason::Centre {
            target,
            intercept,
            above,
        } => format!(
            "the target {} is {} the centre prediction {}",
            fmt_num(*target),
            if *above { "above" } else { "below" },
            fmt_num(*intercept)
        ),
        DirectionReason::Desirability { centre } => format!(
            "of the overall desirability, the geometric mean of every target's desirability; the \
             direction is its gradient under the screening models at the centre of the screening \
             region, where it is predicted {}",
            fmt_num(*centre)
        ),
        DirectionReason::Corner {
            low_corner,
            high_corner,
            side,
            target,
            maybe_unreachable,
        } => {
            format!(
                "the model predicts {} at the low-response corner and {} at the high-response \
                 corner; the path starts from the corner {} the target {} and walks toward it",
                fmt_num(*low_corner),
                fmt_num(*high_corner),
                match side {
                    CornerSide::Nearer => "nearer",
                    CornerSide::Below => "below",
                    CornerSide::Above => "above",
                },
                fmt_num(*target)
            ) + if *maybe_unreachable {
                " (the target lies beyond both corners' predictions, so the path may not \
                 reach it)"
            } else {
                ""
            }
        }
    };
    let base = path
        .factors
        .iter()
        .position(|f| *f == path.base_factor)
        .expect("the base factor is carried");
    let dir_name = match path.direction {
        PathDirection::Ascent => "ascent",
        PathDirection::Descent => "descent",
    };
    let mut text = format!(
        "Steepest {dir_name} ({why}). Base factor {} (largest |coefficient| {}) moves one \
         half-range per step; the others move in proportion to their coefficients{}: steps {}. \
         The path has {} points within the allowed ranges",
        path.base_factor,
        fmt_num(path.coefficients[base].abs()),
        round_decimals.map_or(String::new(), |d| format!(", rounded to {d} decimals")),
        setting(&path.factors, &path.step_natural),
        path.points.len(),
    );
    if path.points.len() < max_points {
        text.push_str(" (it ends where every factor sits at its bound)");
    }
    text.push('.');
    text
}

/// Stage 2 outcome: the responses along the path and the point chosen as the centre.
fn path_end(path: &PathState, end: &PathEnd, centre: usize, target: f64) -> String {
    let responses: Vec<String> = path.points[..path.dispatched]
        .iter()
        .filter_map(|p| {
            p.response.map(|r| {
                format!(
                    "step {}: {} ({}%)",
                    p.step,
                    fmt_num(r),
                    fmt_num(relative_error_pct(r, target))
                )
            })
        })
        .collect();
    let centre_point = &path.points[centre];
    let best = centre_point.response.expect("the centre was run");
    let point_text = setting(&path.factors, &centre_point.natural);
    match end {
        PathEnd::Crossed { from, to } => format!(
            "Responses along the path: {}. The response crosses the target {} between steps {} \
             and {}; step {} is the closest up to the crossing ({}, relative error {}%; later \
             steps do not count) and becomes the centre of the response surface ({}).",
            responses.join(", "),
            fmt_num(target),
            path.points[*from].step,
            path.points[*to].step,
            centre_point.step,
            fmt_num(best),
            fmt_num(relative_error_pct(best, target)),
            point_text
        ),
        PathEnd::Hit => format!(
            "Responses along the path: {}. Step {} is already within tolerance of the target \
             and becomes the centre of the response surface ({}).",
            responses.join(", "),
            centre_point.step,
            point_text
        ),
        // One target never peaks (that is the several-targets ending).
        PathEnd::NeverCrossed | PathEnd::Peaked => format!(
            "Responses along the path: {}. The path never crossed the target {} within its {} \
             points (the allowed ranges or max_points end it). Fallback: the closest point, \
             step {} ({}, relative error {}%; {}), becomes the centre anyway; the response surface \
             may not contain the target, in which case the optimum stage reports the closest \
             reachable setting and verification decides.",
            responses.join(", "),
            fmt_num(target),
            path.points.len(),
            centre_point.step,
            fmt_num(best),
            fmt_num(relative_error_pct(best, target)),
            point_text
        ),
    }
}

/// Stage 2 outcome with several targets: the overall desirability along the path and the point
/// chosen as the centre.
fn path_end_desirability(
    path: &PathState,
    end: &PathEnd,
    centre: usize,
    targets: &[Target],
) -> String {
    let along: Vec<String> = path.points[..path.dispatched]
        .iter()
        .filter_map(|p| {
            p.desirability.map(|d| {
                let values: Vec<String> = targets
                    .iter()
                    .zip(&p.responses)
                    .map(|(t, y)| format!("{} {}", t.label, fmt_num(*y)))
                    .collect();
                format!("step {}: {} ({})", p.step, fmt_num(d), values.join(", "))
            })
        })
        .collect();
    let c = &path.points[centre];
    let point_text = setting(&path.factors, &c.natural);
    let d = fmt_num(c.desirability.unwrap_or(f64::NAN));
    let head = format!("Overall desirability along the path: {}.", along.join("; "));
    match end {
        PathEnd::Hit => format!(
            "{head} Step {} has every response within its tolerance (desirability {d}) and \
             becomes the centre of the response surface ({point_text}).",
            c.step
        ),
        PathEnd::Peaked | PathEnd::Crossed { .. } => format!(
            "{head} It peaks at step {} ({d}) and falls after it; step {} becomes the centre of \
             the response surface ({point_text}).",
            c.step, c.step
        ),
        PathEnd::NeverCrossed => format!(
            "{head} It did not peak within the path's {} points (the allowed ranges or \
             max_points end it). Fallback: the most desirable point, step {} ({d}), becomes the \
             centre anyway ({point_text}); the response surface may not contain a setting that \
             meets every target, in which case the optimum stage reports the most desirable \
             reachable setting and verification decides.",
            path.points.len(),
            c.step
        ),
    }
}

/// Stage 3 plan: the design, its levels and anything adjusted.
fn surface_plan(
    round: u32,
    layout: &SurfaceLayout,
    factors: &[Factor],
    notes: &[SurfaceNote],
) -> String {
    let label = match layout {
        SurfaceLayout::Line => "a five-level line (one factor)".to_owned(),
        SurfaceLayout::BoxBehnken { centre_points } => {
            format!("a Box–Behnken design with {centre_points} centre points")
        }
        SurfaceLayout::FaceCentredForBoxBehnken { centre_points, k } => format!(
            "a face-centred central composite design with {centre_points} centre points \
             (Box–Behnken needs 3 to 7 factors, {k} are carried)"
        ),
        SurfaceLayout::CentralComposite {
            variant,
            centre_points,
        } => format!("a {variant:?} central composite design with {centre_points} centre points"),
    };
    let levels: Vec<String> = factors
        .iter()
        .map(|f| format!("{} {}..{}", f.name, fmt_num(f.low), fmt_num(f.high)))
        .collect();
    let mut text = if round == 0 {
        format!(
            "Response surface: {label} around the path's centre point, half-ranges = the path \
             steps, clamped to the allowed ranges: {}; full quadratic model.",
            levels.join(", ")
        )
    } else {
        format!(
            "Response surface round {}: {label} centred at the last optimum (half-ranges as \
             the verification decided), clamped to the allowed ranges: {}; full quadratic \
             model.",
            round + 1,
            levels.join(", ")
        )
    };
    for n in notes {
        let note = match n {
            SurfaceNote::HalfRangeRaised { factor, from, to } => format!(
                "{factor}'s half-range {} is below 5 % of its allowed half-range and was raised \
                 to {}",
                fmt_num(*from),
                fmt_num(*to)
            ),
            SurfaceNote::InscribedInstead { alpha } => format!(
                "circumscribed star points (α = {}) would leave the allowed ranges, so the \
                 design is inscribed instead",
                fmt_num(*alpha)
            ),
        };
        text.push_str(&format!(" Note: {note}."));
    }
    text
}

/// Stage 3 outcome: the quadratic fit in a sentence.
fn surface_fit(summary: &SurfaceFitSummary, alpha: f64) -> String {
    let mut text = format!(
        "Quadratic model: p(model) {}, R² {}, adjusted R² {}, predicted R² {}; terms \
         significant at α = {}: {}.",
        fmt_p(summary.model_p),
        fmt_num(summary.r2),
        fmt_num(summary.adj_r2),
        summary.pred_r2.map_or("n/a".into(), fmt_num),
        alpha,
        list(&summary.significant_terms)
    );
    match summary.lack_of_fit_p {
        Some(p) if p < alpha => text.push_str(&format!(
            " Lack of fit is significant (p {}): the quadratic model misses structure; \
             verification will tell whether the optimum holds.",
            fmt_p(Some(p))
        )),
        Some(p) => text.push_str(&format!(
            " Lack of fit not significant (p {}).",
            fmt_p(Some(p))
        )),
        None => {}
    }
    if summary.model_p.is_some_and(|p| p >= alpha) {
        text.push_str(
            " The model as a whole is not significant: the optimum below rests on a weak fit.",
        );
    }
    if summary.response.is_empty() {
        text
    } else {
        format!("{}: {text}", summary.response)
    }
}

/// Stage 4 outcome: where the target is met (a point, a level set, or not at all).
fn optimum(found: &OptimumFound, names: &[String], target: f64) -> String {
    let choice = &found.choice;
    let chosen = setting(names, &choice.natural);
    let extent: Vec<String> = names
        .iter()
        .enumerate()
        .filter(|(i, _)| *i < choice.natural_min.len())
        .map(|(i, n)| {
            format!(
                "{n} {}..{}",
                fmt_num(choice.natural_min[i]),
                fmt_num(choice.natural_max[i])
            )
        })
        .collect();
    if choice.level_set {
        format!(
            "The target {} is met on a whole level set, not at one point: {} of {} starts \
             reached desirability {} at {} distinct settings spread over {} coded units \
             (natural extent {}). Chosen: the tied setting closest to the design centre (the \
             least extrapolating), {}, predicted {}.",
            fmt_num(target),
            choice.starts_at_best,
            choice.starts,
            fmt_num(found.best_desirability),
            choice.distinct_at_best,
            fmt_num(choice.spread),
            extent.join(", "),
            chosen,
            fmt_num(choice.predicted)
        )
    } else if found.target_met() {
        format!(
            "The target {} is met at a single setting: {}, predicted {}.",
            fmt_num(target),
            chosen,
            fmt_num(choice.predicted)
        )
    } else {
        format!(
            "The target {} is not reachable inside the design region (best desirability {}); \
             the closest setting is {}, predicted {}. Verification will measure the gap.",
            fmt_num(target),
            fmt_num(found.best_desirability),
            chosen,
            fmt_num(choice.predicted)
        )
    }
}

/// Stage 4 with several targets: the setting of best overall desirability, every response's
/// prediction there, and the level set.
fn optimum_overall(found: &OptimumFound, names: &[String], targets: &[Target]) -> String {
    let choice = &found.choice;
    let chosen = setting(names, &choice.natural);
    let predicted: Vec<String> = targets
        .iter()
        .zip(&choice.predictions)
        .map(|(t, p)| format!("{} {} (target {})", t.label, fmt_num(*p), fmt_num(t.value)))
        .collect();
    let predicted = predicted.join(", ");
    if choice.level_set {
        let extent: Vec<String> = names
            .iter()
            .enumerate()
            .filter(|(i, _)| *i < choice.natural_min.len())
            .map(|(i, n)| {
                format!(
                    "{n} {}..{}",
                    fmt_num(choice.natural_min[i]),
                    fmt_num(choice.natural_max[i])
                )
            })
            .collect();
        format!(
            "Every target is met on a whole level set, not at one point: {} of {} starts reached \
             overall desirability {} at {} distinct settings spread over {} coded units (natural \
             extent {}). Chosen: the tied setting closest to the design centre (the least \
             extrapolating), {chosen}; predicted {predicted}.",
            choice.starts_at_best,
            choice.starts,
            fmt_num(found.best_desirability),
            choice.distinct_at_best,
            fmt_num(choice.spread),
            extent.join(", ")
        )
    } else if found.target_met() {
        format!(
            "Every target is met at a single setting (overall desirability {}): {chosen}; \
             predicted {predicted}.",
            fmt_num(found.best_desirability)
        )
    } else {
        format!(
            "The targets cannot all be met inside the design region (best overall desirability \
             {}); the most desirable setting is {chosen}, predicted {predicted}. Verification will \
             measure the gaps.",
            fmt_num(found.best_desirability)
        )
    }
}

/// Stage 5 plan.
fn verification_plan(replicates: u32, targets: &[Target]) -> String {
    if let [t] = targets {
        return format!(
            "Verify with {replicates} replicate simulations at the optimum, fresh seeds; accepted \
             if the mean is within {}.",
            t.tolerance.describe()
        );
    }
    let each: Vec<String> = targets
        .iter()
        .map(|t| format!("{} within {}", t.label, t.tolerance.describe()))
        .collect();
    format!(
        "Verify with {replicates} replicate simulations of each experiment at the optimum, fresh \
         seeds; accepted if every response's mean is within its tolerance: {}.",
        list(&each)
    )
}

/// Stage 5 outcome and what follows it.
fn verification(v: &VerificationOutcome, targets: &[Target], next: &VerificationNext) -> String {
    let base = if v.checks.is_empty() {
        let (target, tolerance) = (targets[0].value, &targets[0].tolerance);
        format!(
            "Verification: {} runs, mean {} (sd {}), target {}, relative error {}% — {} the \
         tolerance of {}.",
            v.responses.len(),
            fmt_num(v.mean),
            fmt_num(v.std),
            fmt_num(target),
            fmt_num(v.relative_error_pct),
            if v.within_tolerance {
                "within"
            } else {
                "outside"
            },
            tolerance.describe()
        )
    } else {
        let each: Vec<String> = v
            .checks
            .iter()
            .zip(targets)
            .map(|(c, t)| {
                format!(
                    "{}: {} runs, mean {} (sd {}), target {}, relative error {}% — {} {}",
                    c.response,
                    c.responses.len(),
                    fmt_num(c.mean),
                    fmt_num(c.std),
                    fmt_num(c.target),
                    fmt_num(c.relative_error_pct),
                    if c.within_tolerance {
                        "within"
                    } else {
                        "outside"
                    },
                    t.tolerance.describe()
                )
            })
            .collect();
        format!(
            "Verification: {}. {}",
            each.join("; "),
            if v.within_tolerance {
                "Every response is within its tolerance."
            } else {
                "Not every response is within its tolerance."
            }
        )
    };
    match next {
        VerificationNext::Accept | VerificationNext::GiveUp => base,
        VerificationNext::AnotherRound {
            reachable,
            round,
            max_rounds,
        } => {
            let how = if *reachable {
                "with half the half-ranges"
            } else {
                "with the same half-ranges (the target was not reachable inside the last \
                 region, so the region moves toward it instead of shrinking)"
            };
            format!(
                "{base} Next step: a further response-surface round centred at this optimum \
                 {how} (round {round} of at most {max_rounds})."
            )
        }
    }
}

/// Stage 6 plan.
fn drilling_plan(d: &DrillingValidation, unverified: bool) -> String {
    let at = if unverified {
        "the most desirable setting found, which no verification accepted (so this is not a \
         calibrated prediction: it shows how far that setting is from the measurement; the \
         campaign stops for attention after it)"
    } else {
        "the calibrated parameters"
    };
    format!(
        "Drilling validation: {} run(s) of the drilling experiment at {at}, compared with the \
         measured {} (tolerance {} %).",
        d.replicates,
        list(&d.measured.keys().cloned().collect::<Vec<_>>()),
        d.tolerance_pct
    )
}

/// Stage 6 outcome: each metric measured against simulated.
fn drilling(outcome: &DrillingOutcome, several_targets: bool, unverified: bool) -> String {
    let lines: Vec<String> = outcome
        .metrics
        .iter()
        .map(|m| {
            format!(
                "{}: measured {}, simulated {}{}",
                m.name,
                fmt_num(m.measured),
                m.simulated.map_or("n/a".into(), fmt_num),
                m.relative_error_pct
                    .map_or(String::new(), |e| format!(" ({}%)", fmt_num(e)))
            )
        })
        .collect();
    format!(
        "Drilling validation {}: {}.",
        match (unverified, outcome.passed, several_targets) {
            (true, true, _) => "within tolerance, at a setting that does not reproduce the targets",
            (true, false, _) =>
                "outside tolerance, at a setting that does not reproduce the targets",
            (false, true, _) => "passed",
            (false, false, true) => {
                "FAILED — the parameters reproduce the targets but not the drilled hole"
            }
            (false, false, false) => {
                "FAILED — the parameters reproduce the angle of repose but not the drilled hole"
            }
        },
        lines.join("; ")
    )
}

/// The last line: every parameter's final value.
pub(crate) fn finished(parameters: &[CalibratedValue]) -> String {
    let params: Vec<String> = parameters
        .iter()
        .map(|p| {
            format!(
                "{} = {}{}",
                p.name,
                fmt_num(p.value),
                if p.calibrated { "" } else { " (held)" }
            )
        })
        .collect();
    format!("Finished: {}.", params.join(", "))
}

#[cfg(test)]
mod tests {
    use super::{runs_without_value, RunCounts};

    fn counts(runs: usize, runs_used: usize, residual_df: usize) -> RunCounts {
        RunCounts {
            runs,
            runs_used,
            residual_df,
        }
    }

    #[test]
    fn failed_runs_are_named_with_the_degrees_of_freedom_they_leave() {
        assert_eq!(runs_without_value(counts(12, 12, 4)), None);
        assert_eq!(
            runs_without_value(counts(0, 0, 0)),
            None,
            "counts from before they existed"
        );
        assert_eq!(
            runs_without_value(counts(12, 9, 1)).as_deref(),
            Some(
                "3 of 12 runs gave no value, so the fit has 1 residual degree of freedom: too \
                 few to tell an effect from noise"
            )
        );
        assert_eq!(
            runs_without_value(counts(12, 11, 3)).as_deref(),
            Some("1 of 12 runs gave no value, so the fit has 3 residual degrees of freedom")
        );
    }
}
