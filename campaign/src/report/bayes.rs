//! The Bayesian strategy's part of the campaign report, rendered with maud (escaped markup and
//! inline SVG): the convergence (best joint misfit against simulations), each response's factor
//! influences, the region consistent with every measurement as pairwise projections with the
//! observed and the failed points, the trade-off between the targets and the failed points.

use maud::{html, Markup};

use crate::campaign::{
    fmt_num, BayesState, BayesianResult, Campaign, ConvergencePoint, Influence, Observation,
};

const BLUE: &str = "#2e86c1";
const RED: &str = "#c0392b";
const GREY: &str = "#7f8c8d";

/// The section, or nothing for a campaign of the `doe` chain.
pub(super) fn section(c: &Campaign) -> Markup {
    let Some(state) = &c.bayes else {
        return html! {};
    };
    let result = c.summary.as_ref().and_then(|s| s.bayesian.as_deref());
    let names: Vec<String> = c.request.factors.iter().map(|f| f.name.clone()).collect();
    let targets: Vec<String> = c.request.targets().into_iter().map(|t| t.label).collect();
    let ranges: Vec<(f64, f64)> = c.request.factors.iter().map(|f| (f.low, f.high)).collect();
    let best = c
        .summary
        .as_ref()
        .map(|s| s.parameters.iter().map(|p| p.value).collect::<Vec<f64>>());
    let verified = c.summary.as_ref().is_some_and(|s| s.within_tolerance);
    let influences: Vec<Influence> = match result {
        Some(r) => r.influences.clone(),
        None => state
            .assessment
            .as_ref()
            .map(|a| a.influences.clone())
            .unwrap_or_default(),
    };
    html! {
        h2 { "Bayesian search" }
        p {
            (state.simulations) " simulations issued (every experiment's runs and the \
             verification replicates), " (state.observations.len()) " points simulated, "
            (state.observations.iter().filter(|o| o.failed.is_some()).count()) " of them failed."
        }
        h3 { "Convergence" }
        p { "The smallest joint misfit Σ((mean − target)/half-width)² of the points simulated so \
             far, after each round (log scale; every target within tolerance needs each term ≤ 1)." }
        (convergence_chart(&state.convergence))
        @if !influences.is_empty() {
            h3 { "Factor influences" }
            p { "Each response's surrogate: every factor's share of the variation of its mean \
                 over the factor box (the factor's total-effect index, the shares summing to \
                 100 %), with its length-scale ℓ as a fraction of the range (long: the factor \
                 moves the response little) and, beside the response, the estimated run-to-run \
                 noise, the part of a run's variation over the box that the factors explain and \
                 the shortest length-scale its runs can resolve. A factor not written into the \
                 response's experiment is outside its surrogate: no share, by construction." }
            (influence_chart(&influences, &names))
        }
        @if let Some(r) = result {
            (region_part(r, &targets, state, &names, &ranges, best.as_deref(), verified))
        }
    }
}

/// Maps `v` in `[lo, hi]` to `[a, b]`.
fn scale(v: f64, lo: f64, hi: f64, a: f64, b: f64) -> f64 {
    if hi > lo {
        a + (v - lo) / (hi - lo) * (b - a)
    } else {
        0.5 * (a + b)
    }
}

fn convergence_chart(points: &[ConvergencePoint]) -> Markup {
    let known: Vec<(f64, f64)> = points
        .iter()
        .filter_map(|p| {
            p.best_misfit
                .map(|m| (p.simulations as f64, m.max(1e-3).log10()))
        })
        .collect();
    if known.is_empty() {
        return html! { p { "No point has every target's value yet." } };
    }
    let (w, h, left, bottom, top, right) = (520.0, 240.0, 56.0, 36.0, 12.0, 16.0);
    let x_max = known.iter().map(|p| p.0).fold(1.0, f64::max);
    let y_lo = known.iter().map(|p| p.1).fold(0.0, f64::min).floor();
    let y_hi = known.iter().map(|p| p.1).fold(1.0, f64::max).ceil();
    let px = |x: f64| scale(x, 0.0, x_max, left, w - right);
    let py = |y: f64| scale(y, y_lo, y_hi, h - bottom, top);
    let line: String = known
        .iter()
        .map(|(x, y)| format!("{:.1},{:.1}", px(*x), py(*y)))
        .collect::<Vec<_>>()
        .join(" ");
    let decades: Vec<i32> = (y_lo as i32..=y_hi as i32).collect();
    html! {
        svg xmlns="http://www.w3.org/2000/svg" width=(w) height=(h) viewBox=(format!("0 0 {w} {h}"))
            role="img" aria-label="Best joint misfit against simulations" {
            rect x=(left) y=(top) width=(w - left - right) height=(h - top - bottom)
                fill="none" stroke="#ccc" {}
            @for d in &decades {
                line x1=(left) x2=(w - right) y1=(py(f64::from(*d))) y2=(py(f64::from(*d)))
                    stroke="#eee" {}
                text x=(left - 6.0) y=(py(f64::from(*d)) + 4.0) font-size="11" text-anchor="end" {
                    (fmt_num(10f64.powi(*d)))
                }
            }
            line x1=(left) x2=(w - right) y1=(py(0.0)) y2=(py(0.0)) stroke=(RED)
                stroke-dasharray="4 3" {}
            polyline points=(line) fill="none" stroke=(BLUE) stroke-width="2" {}
            @for (x, y) in &known {
                circle cx=(px(*x)) cy=(py(*y)) r="3" fill=(BLUE) {}
            }
            text x=((left + w - right) / 2.0) y=(h - 6.0) font-size="12" text-anchor="middle" {
                "simulations issued"
            }
            text x=(left) y=(h - bottom + 14.0) font-size="11" text-anchor="middle" { "0" }
            text x=(w - right) y=(h - bottom + 14.0) font-size="11" text-anchor="middle" {
                (x_max)
            }
        }
    }
}

fn influence_chart(influences: &[Influence], names: &[String]) -> Markup {
    let bar = 14.0;
    let (label_w, plot_w) = (150.0, 300.0);
    let rows = influences.len() * (names.len() + 1);
    let h = rows as f64 * (bar + 4.0) + 10.0;
    let w = label_w + plot_w + 80.0;
    let mut y = 4.0;
    let mut items = Vec::new();
    for inf in influences {
        items.push((y, None, inf));
        y += bar + 4.0;
        for (j, _) in names.iter().enumerate() {
            items.push((y, Some(j), inf));
            y += bar + 4.0;
        }
    }
    html! {
        svg xmlns="http://www.w3.org/2000/svg" width=(w) height=(h) viewBox=(format!("0 0 {w} {h}"))
            role="img" aria-label="Factor influences per response" {
            @for (y, j, inf) in &items {
                @match j {
                    None => {
                        text x="2" y=(y + bar - 2.0) font-size="12" font-weight="bold" {
                            (inf.response) " (noise sd " (fmt_num(inf.noise_sd))
                            @if let Some(e) = inf.explained {
                                "; factors explain " (fmt_num(100.0 * e)) " %"
                            }
                            @if let Some(l) = inf.min_length_scale {
                                "; ℓ ≥ " (fmt_num(l))
                            }
                            ")"
                        }
                    }
                    Some(j) => {
                        text x=(label_w - 6.0) y=(y + bar - 3.0) font-size="11" text-anchor="end" {
                            @match inf.length_scales[*j] {
                                Some(l) => { (names[*j]) " (ℓ " (fmt_num(l)) ")" }
                                None => { (names[*j]) " (not given)" }
                            }
                        }
                        rect x=(label_w) y=(y) width=(inf.share[*j] * plot_w) height=(bar)
                            fill=(BLUE) {}
                        text x=(label_w + inf.share[*j] * plot_w + 4.0) y=(y + bar - 3.0)
                            font-size="11" { (fmt_num(100.0 * inf.share[*j])) " %" }
                    }
                }
            }
        }
    }
}

fn region_part(
    r: &BayesianResult,
    targets: &[String],
    state: &BayesState,
    names: &[String],
    ranges: &[(f64, f64)],
    best: Option<&[f64]>,
    verified: bool,
) -> Markup {
    let pairs: Vec<(usize, usize)> = (0..names.len())
        .flat_map(|i| (i + 1..names.len()).map(move |j| (i, j)))
        .collect();
    html! {
        h3 { "Region consistent with every measurement" }
        p {
            "Settings whose probability of meeting every target (feasibility included) is at \
             least " (fmt_num(100.0 * r.region.threshold)) " % under the surrogates: "
            (fmt_num(100.0 * r.region.fraction)) " % of a uniform sample of the box."
            @if let Some(p) = r.region.at_result {
                " The result's setting: " (fmt_num(100.0 * p)) " %"
                @if verified { ", and its replicates verified it." } @else { "." }
            }
            @if r.region.points.is_empty() {
                @if verified {
                    " No sampled setting reaches the threshold: the surrogates, which allow for \
                     the runs' noise, are less sure of the verified setting than its replicates \
                     are. The verification, not the region, is the evidence for the result."
                } @else {
                    " None: no setting is likely to meet them all."
                }
            }
        }
        @if !r.region.extent.is_empty() {
            table {
                tr { th.l { "factor" } th { "low" } th { "high" } th { "box low" } th { "box high" } }
                @for (j, (lo, hi)) in r.region.extent.iter().enumerate() {
                    tr {
                        td.l { (names[j]) } td { (fmt_num(*lo)) } td { (fmt_num(*hi)) }
                        td { (fmt_num(ranges[j].0)) } td { (fmt_num(ranges[j].1)) }
                    }
                }
            }
        }
        @if !pairs.is_empty() {
            p { "Pairwise projections: the region (blue), the points simulated (grey), failed \
                 points (red ×), the result (black ring)." }
            div {
                @for (i, j) in &pairs {
                    (pair_chart(*i, *j, r, &state.observations, names, ranges, best))
                }
            }
        }
        @if !r.out_of_reach.is_empty() {
            p.bad { "Out of reach in the factor box, even alone: " (r.out_of_reach.join(", ")) "." }
        }
        @if !r.at_edge.is_empty() {
            p.bad {
                "Met only at the edge of the factor box, not out of reach: "
                @for (k, e) in r.at_edge.iter().enumerate() {
                    @if k > 0 { "; " }
                    (e.response) " ("
                    @for (m, x) in e.edges.iter().enumerate() {
                        @if m > 0 { ", " }
                        (x.factor) " at its " (if x.high { "high" } else { "low" }) " edge, "
                        (fmt_num(x.value))
                    }
                    "; closest run " (fmt_num(e.closest)) ")"
                }
                ". A wider range beyond that edge may hold it."
            }
        }
        @if r.pareto.len() > 1 || !r.conflict.is_empty() {
            h3 { "Trade-off between the targets" }
            @if !r.conflict.is_empty() {
                p.bad { "In conflict: " (r.conflict.join(", ")) "." }
            }
            p { "The points simulated that no other beats on every target: each target's misfit \
                 |mean − target| / half-width (≤ 1 is within tolerance)." }
            table {
                tr {
                    @for n in names { th { (n) } }
                    @for n in targets { th { (n) " misfit" } }
                }
                @for p in &r.pareto {
                    tr {
                        @for v in &p.point { td { (fmt_num(*v)) } }
                        @for m in &p.misfits { td { (fmt_num(*m)) } }
                    }
                }
            }
        }
        @if !r.infeasible.is_empty() {
            h3 { "Failed points" }
            table {
                tr { @for n in names { th { (n) } } th.l { "why" } }
                @for p in &r.infeasible {
                    tr {
                        @for v in &p.point { td { (fmt_num(*v)) } }
                        td.l { (p.reason) }
                    }
                }
            }
        }
    }
}

fn pair_chart(
    i: usize,
    j: usize,
    r: &BayesianResult,
    observations: &[Observation],
    names: &[String],
    ranges: &[(f64, f64)],
    best: Option<&[f64]>,
) -> Markup {
    let (w, h, m) = (210.0, 210.0, 30.0);
    let px = |v: f64| scale(v, ranges[i].0, ranges[i].1, m, w - 6.0);
    let py = |v: f64| scale(v, ranges[j].0, ranges[j].1, h - m, 6.0);
    html! {
        svg xmlns="http://www.w3.org/2000/svg" width=(w) height=(h) viewBox=(format!("0 0 {w} {h}"))
            role="img" aria-label=(format!("{} against {}", names[j], names[i])) {
            rect x=(m) y="6" width=(w - m - 6.0) height=(h - m - 6.0) fill="none" stroke="#ccc" {}
            @for p in &r.region.points {
                circle cx=(px(p[i])) cy=(py(p[j])) r="2" fill=(BLUE) fill-opacity="0.35" {}
            }
            @for o in observations.iter().filter(|o| o.failed.is_none()) {
                circle cx=(px(o.point[i])) cy=(py(o.point[j])) r="2.5" fill=(GREY) {}
            }
            @for o in observations.iter().filter(|o| o.failed.is_some()) {
                path d=(cross(px(o.point[i]), py(o.point[j]))) stroke=(RED) stroke-width="1.5" {}
            }
            @if let Some(b) = best {
                circle cx=(px(b[i])) cy=(py(b[j])) r="5" fill="none" stroke="#000"
                    stroke-width="2" {}
            }
            text x=((m + w) / 2.0) y=(h - 8.0) font-size="11" text-anchor="middle" { (names[i]) }
            text x="10" y=(h / 2.0) font-size="11" text-anchor="middle"
                transform=(format!("rotate(-90 10 {})", h / 2.0)) { (names[j]) }
        }
    }
}

fn cross(x: f64, y: f64) -> String {
    let s = 3.5;
    format!(
        "M{:.1} {:.1}L{:.1} {:.1}M{:.1} {:.1}L{:.1} {:.1}",
        x - s,
        y - s,
        x + s,
        y + s,
        x - s,
        y + s,
        x + s,
        y - s
    )
}
