//! The report as one self-contained HTML page, rendered with maud: the frame (status, summary,
//! inputs, decisions, pictures, provenance) and the tables every part shares. Every text goes
//! through maud's escaping once; the charts and the stage sections come in as markup.

use base64::prelude::{Engine as _, BASE64_STANDARD};
use maud::{html, Markup, PreEscaped, Render, DOCTYPE};
use serde_json::json;

use super::chain::Chain;
use super::{bayes, provenance, reason, response_of, spec_hash, ReportPictures};
use crate::campaign::fmt_num;
use crate::{Campaign, CampaignRequest, DrillingOutcome, StageResult, Status, Summary, Target};

const CSS: &str = "body{font-family:system-ui,sans-serif;margin:24px auto;max-width:1120px;color:#222;line-height:1.4}\
h1{margin-bottom:4px}h2{border-bottom:2px solid #2c3e50;padding-bottom:3px;margin-top:34px}\
table{border-collapse:collapse;margin:8px 0 14px;font-size:13px}td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}\
th{background:#f0f3f6}td.l,th.l{text-align:left}.ok{color:#1e8449;font-weight:bold}.bad{color:#c0392b;font-weight:bold}\
.box{background:#f7f9fb;border:1px solid #d5dde5;padding:10px 14px;border-radius:6px}.figs{display:flex;flex-wrap:wrap;gap:10px}\
.figs svg,.figs img{border:1px solid #ddd}ol.dec li{margin-bottom:6px}pre{background:#f7f7f7;padding:8px;overflow:auto;font-size:12px}\
.sig{background:#fdecea}small{color:#666}";

/// The report as one self-contained HTML page.
pub fn report_html(c: &Campaign, results: &[StageResult], pictures: &ReportPictures) -> String {
    let r = &c.request;
    let chain = Chain::new(c, results);
    let mut page = html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                title { "Calibration campaign: " (r.name) }
                style { (PreEscaped(CSS)) }
            }
            body {
                h1 { "Calibration campaign: " (r.name) }
                p { "Status: " (status(c)) ". " (c.batches.len()) " batches issued." }
                @if let Some(sum) = &c.summary {
                    (summary(c, sum))
                }
                (inputs(r))
                (decisions(c))
                (bayes::section(c))
                (chain.stages())
                (picture("Verification pile", pictures.verification_pile.as_deref()))
                @if r.drilling.is_some() {
                    h2 { "6. Drilling validation" }
                    @match &c.drilling {
                        Some(d) => (validation_table(d)),
                        None => p { "Not run yet." },
                    }
                    (picture("Drilled hole", pictures.drilled_hole.as_deref()))
                }
                (provenance_table(c, results))
            }
        }
    }
    .into_string();
    page.push('\n');
    page
}

fn status(c: &Campaign) -> Markup {
    html! {
        @match &c.status {
            Status::Running => { "running — stage " (c.stage.label()) }
            Status::Finished => "finished",
            Status::NeedsAttention { reason } => { span.bad { "needs attention" } ": " (reason) }
        }
    }
}

/// `within tolerance` in green or `outside tolerance` in red.
pub(super) fn verdict(within: bool) -> Markup {
    html! {
        @if within {
            span.ok { "within tolerance" }
        } @else {
            span.bad { "outside tolerance" }
        }
    }
}

/// A table whose first `left` columns are left-aligned; the cells are markup (texts rendered
/// with [`Render::render`], which escapes them).
pub(super) fn table<S: AsRef<str>>(header: &[S], rows: &[Vec<Markup>], left: usize) -> Markup {
    let align = |i: usize| (i < left).then_some("l");
    html! {
        table {
            tr {
                @for (i, h) in header.iter().enumerate() {
                    th class=[align(i)] { (h.as_ref()) }
                }
            }
            @for row in rows {
                tr {
                    @for (i, cell) in row.iter().enumerate() {
                        td class=[align(i)] { (cell) }
                    }
                }
            }
        }
    }
}

/// A number as a table cell; `—` for none.
pub(super) fn num_or_dash(v: Option<f64>) -> Markup {
    v.map_or("—".to_owned(), fmt_num).render()
}

fn summary(c: &Campaign, sum: &Summary) -> Markup {
    let parameters: Vec<Vec<Markup>> = sum
        .parameters
        .iter()
        .map(|p| {
            vec![
                p.name.render(),
                p.path.render(),
                fmt_num(p.value).render(),
                if p.calibrated {
                    "calibrated"
                } else {
                    "held after screening"
                }
                .render(),
            ]
        })
        .collect();
    let responses: Vec<Vec<Markup>> = sum
        .targets
        .iter()
        .map(|t| {
            vec![
                t.response.render(),
                fmt_num(t.target).render(),
                fmt_num(t.predicted).render(),
                fmt_num(t.mean).render(),
                fmt_num(t.relative_error_pct).render(),
                if t.within_tolerance { "ok" } else { "outside" }.render(),
            ]
        })
        .collect();
    let optimum = c.surfaces.last().and_then(|r| r.optimum.as_ref());
    html! {
        div.box {
            h3 { "Calibrated parameters" }
            (table(&["factor", "path", "value", ""], &parameters, 2))
            p {
                "Target " (fmt_num(sum.target)) " · predicted " (fmt_num(sum.predicted))
                " · verified mean " (fmt_num(sum.verified_mean)) " · relative error "
                (fmt_num(sum.verified_relative_error_pct)) " % · " (verdict(sum.within_tolerance))
                " (" (sum.surface_rounds) " response-surface round(s))"
            }
            @if !sum.targets.is_empty() {
                (table(
                    &["response", "target", "predicted", "verified mean", "rel. error %", ""],
                    &responses,
                    1,
                ))
                @if let Some(opt) = optimum {
                    p {
                        "Overall desirability at the optimum (predicted): "
                        (fmt_num(opt.desirability)) "."
                    }
                }
            }
            @if let Some(d) = &sum.drilling {
                h3 { "Validation (not a target): predicted at the optimum against measured" }
                (validation_table(d))
            }
        }
    }
}

/// An experiment: its kind, and its preset when it has one.
fn experiment(e: &repose_api::ExperimentTemplate) -> Markup {
    html! {
        b { (e.kind) }
        @if let Some(p) = &e.preset {
            " (preset " (p) ")"
        }
    }
}

/// The inputs' first line: the experiment, response, target and tolerance (one target), or the
/// experiments and every target with its tolerance.
fn inputs_line(r: &CampaignRequest, targets: &[Target]) -> Markup {
    match (&r.experiment, targets) {
        (Some(e), [t]) => html! {
            "Experiment " (experiment(e)) " · response " b { (t.label) } " · target "
            b { (fmt_num(t.value)) } " · tolerance " (t.tolerance.describe())
        },
        _ => html! {
            "Experiments "
            @for (i, (k, e)) in r.experiments.iter().enumerate() {
                @if i > 0 { ", " }
                (k) " = " (experiment(e))
            }
            " · targets "
            @for (i, t) in targets.iter().enumerate() {
                @if i > 0 { ", " }
                b { (t.label) } " = " b { (fmt_num(t.value)) }
                " (tolerance " (t.tolerance.describe()) ")"
            }
        },
    }
}

fn inputs(r: &CampaignRequest) -> Markup {
    let factors: Vec<Vec<Markup>> = r
        .factors
        .iter()
        .map(|f| {
            vec![
                f.name.render(),
                f.path.render(),
                fmt_num(f.low).render(),
                fmt_num(f.high).render(),
                f.fixed_at.map_or("mid-range".to_owned(), fmt_num).render(),
            ]
        })
        .collect();
    let settings = json!({
        "screening": r.screening, "steepest": r.steepest, "response_surface": r.response_surface,
        "verification": r.verification, "drilling": r.drilling, "seed": r.seed,
    });
    html! {
        h2 { "Inputs" }
        p { (inputs_line(r, &r.targets())) " · α = " (r.alpha) }
        (table(&["factor", "path", "low", "high", "held at"], &factors, 2))
        details {
            summary { "Stage settings" }
            pre { (serde_json::to_string_pretty(&settings).unwrap_or_default()) }
        }
    }
}

fn decisions(c: &Campaign) -> Markup {
    html! {
        h2 { "Decisions" }
        ol.dec {
            @for d in &c.decisions {
                li {
                    b {
                        (d.stage.label())
                        @if d.round > 0 { " (round " (d.round + 1) ")" }
                    }
                    ": " (d.text)
                }
            }
        }
    }
}

/// The validation's measured metrics next to the simulation at the calibrated parameters (the
/// paper's Table 8).
fn validation_table(d: &DrillingOutcome) -> Markup {
    let rows: Vec<Vec<Markup>> = d
        .metrics
        .iter()
        .map(|m| {
            vec![
                m.name.render(),
                fmt_num(m.measured).render(),
                num_or_dash(m.simulated),
                num_or_dash(m.relative_error_pct),
                if m.within_tolerance { "ok" } else { "outside" }.render(),
            ]
        })
        .collect();
    table(
        &["metric", "measured", "simulated", "rel. error %", ""],
        &rows,
        1,
    )
}

/// A caller's picture under its title, as a `data:` image (scripts in it do not run).
fn picture(title: &str, svg_doc: Option<&str>) -> Markup {
    html! {
        h3 { (title) }
        @match svg_doc {
            Some(doc) => div.figs { (image(title, doc)) },
            None => p { small { "No picture supplied." } },
        }
    }
}

/// `<img alt=… src="data:image/svg+xml;base64,…"/>`. Written here because maud closes void
/// elements HTML-style (`<img>`), and the page is kept well-formed XML; the alt text is escaped
/// by maud, the base64 alphabet needs no escaping.
fn image(alt: &str, svg_doc: &str) -> Markup {
    PreEscaped(format!(
        "<img alt=\"{}\" src=\"data:image/svg+xml;base64,{}\"/>",
        html! { (alt) }.into_string(),
        BASE64_STANDARD.encode(svg_doc.as_bytes())
    ))
}

fn provenance_table(c: &Campaign, results: &[StageResult]) -> Markup {
    let rows: Vec<Vec<Markup>> = provenance(c, results)
        .into_iter()
        .map(|(b, run)| {
            // Non-finite numbers show as `—`, as the JSON (which has none) gives them.
            let finite = |v: Option<f64>| v.filter(|v| v.is_finite());
            vec![
                b.request.name.render(),
                run.run_index.render(),
                run.seed.render(),
                run.status.as_str().render(),
                run.worker_id
                    .map_or("—".to_owned(), |w| {
                        let w = w.to_string();
                        w[..8.min(w.len())].to_owned()
                    })
                    .render(),
                num_or_dash(finite(run.wall_time_s)),
                run.attempts.render(),
                run.engine_version.as_deref().unwrap_or("—").render(),
                html! { code { (spec_hash(&b.request, run)) } },
                num_or_dash(finite(response_of(run, &b.request.response))),
                reason(run).unwrap_or("—").render(),
            ]
        })
        .collect();
    html! {
        h2 { "Provenance of every run" }
        p {
            small {
                "spec = first 16 hex digits of the SHA-256 of the exact spec the workers received \
                 (equal hashes simulated the same document); engine = the DEM engine version \
                 that computed the result."
            }
        }
        (table(
            &[
                "batch", "run", "seed", "status", "worker", "wall s", "attempts", "engine", "spec",
                "response", "reason",
            ],
            &rows,
            1,
        ))
    }
}
