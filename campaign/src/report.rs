//! The campaign report: a JSON document and a self-contained HTML page (inline CSS and SVG).
//! Fits are recomputed from the runs with the same functions the decisions used.

use std::fmt::Write;

use base64::prelude::{Engine as _, BASE64_STANDARD};
use repose_api::{BatchRequest, RunState, RunView};
use repose_doe::Fit;
use serde_json::{json, Value};
use sha2::{Digest, Sha256};

use crate::campaign::{fit_or_reason, fmt_num, fmt_p, screening_fit, surface_fit};
use crate::svg::{contour, desirability_chart, esc, normal_quantile, pareto, path_chart, scatter};
use crate::{relative_error_pct, Campaign, IssuedBatch, StageKind, StageResult, Status, Target};

/// Pictures the caller may add (SVG documents, e.g. the `aor` kind's side view of a
/// verification pile and a drilled hole). They are embedded as `data:` images, so scripts in
/// them do not run.
#[derive(Debug, Clone, Default)]
pub struct ReportPictures {
    /// A verification pile.
    pub verification_pile: Option<String>,
    /// The drilled hole of the drilling validation.
    pub drilled_hole: Option<String>,
}

fn result_for(results: &[StageResult], batch: usize) -> Option<&StageResult> {
    results.iter().find(|r| r.batch == batch)
}

/// Short SHA-256 of the run's spec: the server's hash of the exact document the workers
/// received when it sent one, else a hash of the kind, preset, template and the run's factor
/// values (paths and values). Two runs with equal hashes simulated the same document.
fn spec_hash(batch: &BatchRequest, run: &RunView) -> String {
    if let Some(hash) = &run.spec_sha256 {
        return hash.clone();
    }
    let values: Vec<(&str, f64)> = batch
        .factors
        .iter()
        .filter_map(|f| {
            run.factors
                .iter()
                .find(|v| v.name == f.name)
                .and_then(|v| Some((f.path.as_deref()?, v.natural)))
        })
        .collect();
    let doc = json!({
        "kind": batch.experiment.kind,
        "preset": batch.experiment.preset,
        "spec": batch.experiment.spec,
        "values": values,
    });
    let digest = Sha256::digest(doc.to_string().as_bytes());
    digest[..8].iter().map(|b| format!("{b:02x}")).collect()
}

fn response_of(run: &RunView, response: &str) -> Option<f64> {
    run.metrics.as_ref().and_then(|m| m.get(response)).copied()
}

fn provenance(c: &Campaign, results: &[StageResult]) -> Vec<Value> {
    let mut out = Vec::new();
    for b in &c.batches {
        let Some(r) = result_for(results, b.index) else {
            continue;
        };
        let mut runs: Vec<&RunView> = r.runs.iter().collect();
        runs.sort_by_key(|r| r.run_index);
        for run in runs {
            out.push(json!({
                "batch": b.index,
                "batch_name": b.request.name,
                "run_index": run.run_index,
                "design_row": run.design_row,
                "replicate": run.replicate,
                "seed": run.seed,
                "status": run.status.as_str(),
                "worker_id": run.worker_id,
                "wall_time_s": run.wall_time_s,
                "attempts": run.attempts,
                "spec_sha256": spec_hash(&b.request, run),
                "engine_version": run.engine_version,
                "response": response_of(run, &b.request.response),
                // Why a run gave no result (its last failure), for runs that have none.
                "reason": (run.status != RunState::Completed).then_some(run.last_error.as_deref()).flatten(),
            }));
        }
    }
    out
}

fn fit_json(fit: &Result<Fit, String>) -> Value {
    match fit {
        Ok(f) => serde_json::to_value(f).unwrap_or(Value::Null),
        Err(e) => json!({"error": e}),
    }
}

/// The inputs' first line: the experiment, response, target and tolerance (one target), or the
/// experiments and every target with its tolerance.
fn inputs_line(r: &crate::CampaignRequest, targets: &[crate::Target]) -> String {
    let experiment = |e: &repose_api::ExperimentTemplate| {
        format!(
            "<b>{}</b>{}",
            esc(&e.kind),
            e.preset
                .as_ref()
                .map_or(s(""), |p| format!(" (preset {})", esc(p)))
        )
    };
    match (&r.experiment, targets) {
        (Some(e), [t]) => format!(
            "Experiment {} · response <b>{}</b> · target <b>{}</b> · tolerance {}",
            experiment(e),
            esc(&t.label),
            fmt_num(t.value),
            esc(&t.tolerance.describe())
        ),
        _ => {
            let experiments: Vec<String> = r
                .experiments
                .iter()
                .map(|(k, e)| format!("{} = {}", esc(k), experiment(e)))
                .collect();
            let each: Vec<String> = targets
                .iter()
                .map(|t| {
                    format!(
                        "<b>{}</b> = <b>{}</b> (tolerance {})",
                        esc(&t.label),
                        fmt_num(t.value),
                        esc(&t.tolerance.describe())
                    )
                })
                .collect();
            format!(
                "Experiments {} · targets {}",
                experiments.join(", "),
                each.join(", ")
            )
        }
    }
}

/// The report as JSON: inputs, status, decisions, per-stage outcomes with the full fits,
/// the summary and the provenance of every run.
pub fn report_json(c: &Campaign, results: &[StageResult]) -> Value {
    let targets = c.request.targets();
    let mut stages = serde_json::Map::new();
    if let Some(s) = &c.screening {
        let mut v = serde_json::to_value(s).unwrap_or(Value::Null);
        let mut fits = Vec::new();
        for t in &targets {
            if let Some((_, r)) = batch_of(c, results, StageKind::Screening, 0, t) {
                if let Some(fit) = fit_or_reason(screening_fit(&c.request, t, r.batch, &r.runs)) {
                    fits.push(json!({"response": t.label, "fit": fit_json(&fit)}));
                }
            }
        }
        // One target: `fit`; several: `fits`, one per response.
        if targets.len() == 1 {
            if let Some(f) = fits.pop() {
                v["fit"] = f["fit"].clone();
            }
        } else {
            v["fits"] = Value::Array(fits);
        }
        stages.insert("screening".into(), v);
    }
    if let Some(p) = &c.path {
        stages.insert(
            "steepest".into(),
            serde_json::to_value(p).unwrap_or(Value::Null),
        );
    }
    let mut rounds = Vec::new();
    for round in &c.surfaces {
        let mut v = serde_json::to_value(round).unwrap_or(Value::Null);
        let mut fits = Vec::new();
        for t in &targets {
            if let Some((_, r)) = batch_of(c, results, StageKind::ResponseSurface, round.round, t) {
                if let Some(fit) =
                    fit_or_reason(surface_fit(&c.request, t, round, r.batch, &r.runs))
                {
                    fits.push(json!({"response": t.label, "fit": fit_json(&fit)}));
                }
            }
        }
        // One target: `fit_full`; several: `fits_full`, one per response.
        if targets.len() == 1 {
            if let Some(f) = fits.pop() {
                v["fit_full"] = f["fit"].clone();
            }
        } else {
            v["fits_full"] = Value::Array(fits);
        }
        rounds.push(v);
    }
    stages.insert("response_surfaces".into(), Value::Array(rounds));
    stages.insert("verification".into(), json!(c.verifications));
    stages.insert("drilling".into(), json!(c.drilling));
    let analyses: Vec<Value> = results
        .iter()
        .filter_map(|r| {
            r.analysis
                .as_ref()
                .map(|a| json!({"batch": r.batch, "analysis": a}))
        })
        .collect();
    json!({
        "campaign": c.request.name,
        "status": c.status,
        "stage": c.stage,
        "inputs": c.request,
        "decisions": c.decisions,
        "batches": c.batches.iter().map(|b| json!({
            "index": b.index,
            "name": b.request.name,
            "stage": b.stage,
            "round": b.round,
            "request": b.request,
            "runs": result_for(results, b.index).map(|r| r.runs.len()),
            "completed": result_for(results, b.index)
                .map(|r| r.runs.iter().filter(|x| x.status == RunState::Completed).count()),
        })).collect::<Vec<_>>(),
        "stages": stages,
        "summary": c.summary,
        "server_analyses": analyses,
        "provenance": provenance(c, results),
    })
}

/// The batch of `stage` in `round` that ran target `t`'s experiment, with its result.
fn batch_of<'a>(
    c: &'a Campaign,
    results: &'a [StageResult],
    stage: StageKind,
    round: u32,
    t: &Target,
) -> Option<(&'a IssuedBatch, &'a StageResult)> {
    c.batches
        .iter()
        .find(|b| b.stage == stage && b.round == round && b.experiment == t.experiment)
        .and_then(|b| result_for(results, b.index).map(|res| (b, res)))
}

/// The validation's measured metrics next to the simulation at the calibrated parameters (the
/// paper's Table 8).
fn validation_table(o: &mut String, d: &crate::DrillingOutcome) {
    let rows: Vec<Vec<String>> = d
        .metrics
        .iter()
        .map(|m| {
            vec![
                esc(&m.name),
                fmt_num(m.measured),
                m.simulated.map_or(s("—"), fmt_num),
                m.relative_error_pct.map_or(s("—"), fmt_num),
                s(if m.within_tolerance { "ok" } else { "outside" }),
            ]
        })
        .collect();
    table(
        o,
        &["metric", "measured", "simulated", "rel. error %", ""].map(s),
        &rows,
        1,
    );
}

const CSS: &str = "body{font-family:system-ui,sans-serif;margin:24px auto;max-width:1120px;color:#222;line-height:1.4}\
h1{margin-bottom:4px}h2{border-bottom:2px solid #2c3e50;padding-bottom:3px;margin-top:34px}\
table{border-collapse:collapse;margin:8px 0 14px;font-size:13px}td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}\
th{background:#f0f3f6}td.l,th.l{text-align:left}.ok{color:#1e8449;font-weight:bold}.bad{color:#c0392b;font-weight:bold}\
.box{background:#f7f9fb;border:1px solid #d5dde5;padding:10px 14px;border-radius:6px}.figs{display:flex;flex-wrap:wrap;gap:10px}\
.figs svg,.figs img{border:1px solid #ddd}ol.dec li{margin-bottom:6px}pre{background:#f7f7f7;padding:8px;overflow:auto;font-size:12px}\
.sig{background:#fdecea}small{color:#666}";

fn table(out: &mut String, header: &[String], rows: &[Vec<String>], left: usize) {
    out.push_str("<table><tr>");
    for (i, h) in header.iter().enumerate() {
        let _ = write!(
            out,
            "<th{}>{}</th>",
            if i < left { " class=\"l\"" } else { "" },
            esc(h)
        );
    }
    out.push_str("</tr>");
    for r in rows {
        out.push_str("<tr>");
        for (i, cell) in r.iter().enumerate() {
            let _ = write!(
                out,
                "<td{}>{}</td>",
                if i < left { " class=\"l\"" } else { "" },
                cell
            );
        }
        out.push_str("</tr>");
    }
    out.push_str("</table>");
}

fn s(v: impl Into<String>) -> String {
    v.into()
}

fn design_table(out: &mut String, batch: &BatchRequest, runs: &[RunView], target: Option<f64>) {
    let mut header = vec![s("run"), s("row"), s("rep")];
    header.extend(batch.factors.iter().map(|f| f.name.clone()));
    header.push(batch.response.clone());
    if target.is_some() {
        header.push(s("rel. error %"));
    }
    header.push(s("status"));
    let mut sorted: Vec<&RunView> = runs.iter().collect();
    sorted.sort_by_key(|r| (r.design_row, r.replicate));
    let rows: Vec<Vec<String>> = sorted
        .iter()
        .map(|r| {
            let mut row = vec![
                (r.run_index + 1).to_string(),
                (r.design_row + 1).to_string(),
                r.replicate.to_string(),
            ];
            for f in &batch.factors {
                row.push(
                    r.factors
                        .iter()
                        .find(|v| v.name == f.name)
                        .map_or(s("?"), |v| fmt_num(v.natural)),
                );
            }
            let y = response_of(r, &batch.response);
            row.push(y.map_or(s("—"), fmt_num));
            if let Some(t) = target {
                row.push(y.map_or(s("—"), |y| fmt_num(relative_error_pct(y, t))));
            }
            row.push(s(r.status.as_str()));
            row
        })
        .collect();
    table(out, &header, &rows, 0);
}

fn anova_table(out: &mut String, fit: &Fit, alpha: f64) {
    let header = [
        "Source",
        "Sum of Squares",
        "df",
        "Mean Square",
        "F-value",
        "p-value",
    ]
    .map(s)
    .to_vec();
    let rows: Vec<Vec<String>> = fit
        .anova()
        .iter()
        .map(|r| {
            vec![
                if r.p.is_some_and(|p| p < alpha) {
                    format!("<b>{}</b>", esc(&r.source))
                } else {
                    esc(&r.source)
                },
                fmt_num(r.sum_sq),
                r.df.to_string(),
                r.mean_sq.map_or(s(""), fmt_num),
                r.f.map_or(s(""), fmt_num),
                r.p.map_or(s(""), |p| esc(&fmt_p(Some(p)))),
            ]
        })
        .collect();
    table(out, &header, &rows, 1);
    let st = fit.stats();
    let _ = write!(
        out,
        "<p><small>R² {} · adjusted R² {} · predicted R² {} · adequate precision {} · std. dev. {} · C.V. {} % · {} runs</small></p>",
        fmt_num(st.r2),
        fmt_num(st.adj_r2),
        st.pred_r2.map_or(s("n/a"), fmt_num),
        st.adeq_precision.map_or(s("n/a"), fmt_num),
        fmt_num(st.std_dev),
        st.cv_percent.map_or(s("n/a"), fmt_num),
        st.n_runs
    );
    let eq: Vec<String> = fit
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
                    esc(&c.term)
                )
            }
        })
        .collect();
    let _ = write!(
        out,
        "<p>Coded equation: {} = {}</p>",
        esc(fit.response()),
        eq.join(" ")
    );
}

fn diagnostics(out: &mut String, fit: &Fit) {
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
    out.push_str("<div class=\"figs\">");
    out.push_str(&scatter(
        "Normal probability plot",
        "studentized residual",
        "normal quantile",
        &normal,
        false,
        false,
    ));
    out.push_str(&scatter(
        "Residuals vs predicted",
        "predicted",
        "studentized residual",
        &rv,
        false,
        true,
    ));
    out.push_str(&scatter(
        "Predicted vs actual",
        "actual",
        "predicted",
        &pa,
        true,
        false,
    ));
    out.push_str("</div>");
}

fn picture(out: &mut String, title: &str, svg_doc: &Option<String>) {
    let _ = write!(out, "<h3>{}</h3>", esc(title));
    match svg_doc {
        Some(doc) => {
            let _ = write!(
                out,
                "<div class=\"figs\"><img alt=\"{}\" src=\"data:image/svg+xml;base64,{}\"/></div>",
                esc(title),
                BASE64_STANDARD.encode(doc.as_bytes())
            );
        }
        None => out.push_str("<p><small>No picture supplied.</small></p>"),
    }
}

/// The report as one self-contained HTML page.
pub fn report_html(c: &Campaign, results: &[StageResult], pictures: &ReportPictures) -> String {
    let r = &c.request;
    let targets = r.targets();
    let t0 = &targets[0];
    let multi = targets.len() > 1;
    // With several targets, each response's tables and fits sit under its own heading.
    let heading = |o: &mut String, t: &Target| {
        if multi {
            let _ = write!(
                o,
                "<h3>{} (target {})</h3>",
                esc(&t.label),
                fmt_num(t.value)
            );
        }
    };
    let mut o = String::new();
    let _ = write!(
        o,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>Calibration campaign: {}</title><style>{CSS}</style></head><body>",
        esc(&r.name)
    );
    let _ = write!(o, "<h1>Calibration campaign: {}</h1>", esc(&r.name));
    let status = match &c.status {
        Status::Running => format!("running — stage {}", c.stage.label()),
        Status::Finished => s("finished"),
        Status::NeedsAttention { reason } => format!(
            "<span class=\"bad\">needs attention</span>: {}",
            esc(reason)
        ),
    };
    let _ = write!(
        o,
        "<p>Status: {status}. {} batches issued.</p>",
        c.batches.len()
    );

    // Result summary.
    if let Some(sum) = &c.summary {
        o.push_str("<div class=\"box\"><h3>Calibrated parameters</h3>");
        let rows: Vec<Vec<String>> = sum
            .parameters
            .iter()
            .map(|p| {
                vec![
                    esc(&p.name),
                    esc(&p.path),
                    fmt_num(p.value),
                    s(if p.calibrated {
                        "calibrated"
                    } else {
                        "held after screening"
                    }),
                ]
            })
            .collect();
        table(&mut o, &["factor", "path", "value", ""].map(s), &rows, 2);
        let _ = write!(
            o,
            "<p>Target {} · predicted {} · verified mean {} · relative error {} % · <span class=\"{}\">{}</span> ({} response-surface round(s))</p>",
            fmt_num(sum.target),
            fmt_num(sum.predicted),
            fmt_num(sum.verified_mean),
            fmt_num(sum.verified_relative_error_pct),
            if sum.within_tolerance { "ok" } else { "bad" },
            if sum.within_tolerance { "within tolerance" } else { "outside tolerance" },
            sum.surface_rounds
        );
        if !sum.targets.is_empty() {
            let rows: Vec<Vec<String>> = sum
                .targets
                .iter()
                .map(|t| {
                    vec![
                        esc(&t.response),
                        fmt_num(t.target),
                        fmt_num(t.predicted),
                        fmt_num(t.mean),
                        fmt_num(t.relative_error_pct),
                        s(if t.within_tolerance { "ok" } else { "outside" }),
                    ]
                })
                .collect();
            table(
                &mut o,
                &[
                    "response",
                    "target",
                    "predicted",
                    "verified mean",
                    "rel. error %",
                    "",
                ]
                .map(s),
                &rows,
                1,
            );
            if let Some(opt) = c.surfaces.last().and_then(|r| r.optimum.as_ref()) {
                let _ = write!(
                    o,
                    "<p>Overall desirability at the optimum (predicted): {}.</p>",
                    fmt_num(opt.desirability)
                );
            }
        }
        if let Some(d) = &sum.drilling {
            o.push_str(
                "<h3>Validation (not a target): predicted at the optimum against measured</h3>",
            );
            validation_table(&mut o, d);
        }
        o.push_str("</div>");
    }

    // Inputs.
    o.push_str("<h2>Inputs</h2>");
    let _ = write!(o, "<p>{} · α = {}</p>", inputs_line(r, &targets), r.alpha);
    let rows: Vec<Vec<String>> = r
        .factors
        .iter()
        .map(|f| {
            vec![
                esc(&f.name),
                esc(&f.path),
                fmt_num(f.low),
                fmt_num(f.high),
                f.fixed_at.map_or(s("mid-range"), fmt_num),
            ]
        })
        .collect();
    table(
        &mut o,
        &["factor", "path", "low", "high", "held at"].map(s),
        &rows,
        2,
    );
    let settings = json!({
        "screening": r.screening, "steepest": r.steepest, "response_surface": r.response_surface,
        "verification": r.verification, "drilling": r.drilling, "seed": r.seed,
    });
    let _ = write!(
        o,
        "<details><summary>Stage settings</summary><pre>{}</pre></details>",
        esc(&serde_json::to_string_pretty(&settings).unwrap_or_default())
    );

    // Decisions.
    o.push_str("<h2>Decisions</h2><ol class=\"dec\">");
    for d in &c.decisions {
        let _ = write!(
            o,
            "<li><b>{}{}</b>: {}</li>",
            esc(d.stage.label()),
            if d.round > 0 {
                format!(" (round {})", d.round + 1)
            } else {
                s("")
            },
            esc(&d.text)
        );
    }
    o.push_str("</ol>");
    o.push_str(&crate::bayes_report::section(c));

    // Stage 1.
    if let Some(sc) = &c.screening {
        o.push_str("<h2>1. Screening</h2>");
        for (i, t) in targets.iter().enumerate() {
            heading(&mut o, t);
            if let Some((b, res)) = batch_of(c, results, StageKind::Screening, 0, t) {
                design_table(&mut o, &b.request, &res.runs, None);
                if let Ok(fit) = screening_fit(r, t, res.batch, &res.runs) {
                    anova_table(&mut o, &fit, r.alpha);
                }
            }
            let (t_values, t_critical) = match sc.responses.get(i) {
                Some(e) => (&e.t_values, e.t_critical),
                None => (&sc.t_values, sc.t_critical),
            };
            let abs_t: Vec<f64> = t_values.iter().map(|t| t.map_or(0.0, f64::abs)).collect();
            o.push_str("<div class=\"figs\">");
            o.push_str(&pareto(&sc.factors, &abs_t, t_critical));
            o.push_str("</div>");
        }
        let held: Vec<String> = sc
            .held
            .iter()
            .map(|h| format!("{} = {}", esc(&h.name), fmt_num(h.value)))
            .collect();
        let _ = write!(
            o,
            "<p>Carried forward: <b>{}</b>. Held: {}.</p>",
            esc(&sc.carried.join(", ")),
            if held.is_empty() {
                s("none")
            } else {
                held.join(", ")
            }
        );
    }

    // Stage 2.
    if let Some(p) = &c.path {
        o.push_str("<h2>2. Steepest path</h2>");
        let mut header = vec![s("step")];
        header.extend(p.factors.iter().cloned());
        if multi {
            header.push(format!("predicted {}", t0.label));
            header.extend(targets.iter().map(|t| t.label.clone()));
            header.extend(["overall desirability", "runs"].map(s));
        } else {
            header.extend(["predicted", "simulated", "rel. error %", "runs"].map(s));
        }
        let rows: Vec<Vec<String>> = p
            .points
            .iter()
            .enumerate()
            .map(|(i, pt)| {
                let mut row = vec![if p.centre == Some(i) {
                    format!("<b>{} (centre)</b>", pt.step)
                } else {
                    pt.step.to_string()
                }];
                row.extend(pt.natural.iter().map(|v| fmt_num(*v)));
                row.push(fmt_num(pt.predicted));
                if multi {
                    let not_run = s(if i < p.dispatched { "—" } else { "not run" });
                    for k in 0..targets.len() {
                        row.push(pt.responses.get(k).map_or(not_run.clone(), |y| fmt_num(*y)));
                    }
                    row.push(pt.desirability.map_or(s(""), fmt_num));
                    row.push(pt.runs.to_string());
                    return row;
                }
                row.push(
                    pt.response
                        .map_or(s(if i < p.dispatched { "—" } else { "not run" }), fmt_num),
                );
                row.push(
                    pt.response
                        .map_or(s(""), |y| fmt_num(relative_error_pct(y, t0.value))),
                );
                row.push(pt.runs.to_string());
                row
            })
            .collect();
        let steps: Vec<String> = p
            .factors
            .iter()
            .zip(&p.step_natural)
            .map(|(n, s)| format!("{} {}", esc(n), fmt_num(*s)))
            .collect();
        let _ = write!(
            o,
            "<p>{:?} from the {}; base factor {}; steps {}.</p>",
            p.direction,
            format!("{:?}", p.start).to_lowercase(),
            esc(&p.base_factor),
            steps.join(", ")
        );
        table(&mut o, &header, &rows, 1);
        let xs: Vec<f64> = p.points.iter().map(|pt| pt.step as f64).collect();
        let ys: Vec<f64> = p
            .points
            .iter()
            .map(|pt| pt.response.unwrap_or(f64::NAN))
            .collect();
        let pr: Vec<f64> = p.points.iter().map(|pt| pt.predicted).collect();
        o.push_str("<div class=\"figs\">");
        o.push_str(&path_chart(&xs, &ys, &pr, t0.value));
        if multi {
            let d: Vec<f64> = p
                .points
                .iter()
                .map(|pt| pt.desirability.unwrap_or(f64::NAN))
                .collect();
            o.push_str(&desirability_chart(&xs, &d));
        }
        o.push_str("</div>");
    }

    // Stages 3-5 per round.
    for round in &c.surfaces {
        let _ = write!(
            o,
            "<h2>3. Response surface{}</h2>",
            if round.round > 0 {
                format!(" — round {}", round.round + 1)
            } else {
                s("")
            }
        );
        let levels: Vec<String> = round
            .factors
            .iter()
            .map(|f| format!("{} {}..{}", esc(&f.name), fmt_num(f.low), fmt_num(f.high)))
            .collect();
        let _ = write!(o, "<p>Levels: {}.</p>", levels.join(", "));
        for t in &targets {
            heading(&mut o, t);
            let fit = batch_of(c, results, StageKind::ResponseSurface, round.round, t).and_then(
                |(b, res)| {
                    design_table(&mut o, &b.request, &res.runs, None);
                    surface_fit(r, t, round, res.batch, &res.runs).ok()
                },
            );
            if let Some(fit) = &fit {
                anova_table(&mut o, fit, r.alpha);
            }
            if let (Some(fit), Some(opt)) = (&fit, &round.optimum) {
                o.push_str("<h3>Contour plots</h3><p><small>Other factors at the optimum.</small></p><div class=\"figs\">");
                let k = round.factors.len();
                for i in 0..k {
                    for j in i + 1..k {
                        let (fi, fj) = (&round.factors[i], &round.factors[j]);
                        let z = |x: f64, y: f64| {
                            let mut c = opt.coded.clone();
                            c[i] = (x - fi.centre()) / fi.half_range();
                            c[j] = (y - fj.centre()) / fj.half_range();
                            fit.predict(&c)
                        };
                        o.push_str(&contour(
                            &format!("{} over {} × {}", fit.response(), fi.name, fj.name),
                            &fi.name,
                            &fj.name,
                            (fi.low, fi.high),
                            (fj.low, fj.high),
                            &z,
                            t.value,
                            &[(opt.natural[i], opt.natural[j], "optimum")],
                        ));
                    }
                }
                o.push_str("</div><h3>Residual diagnostics</h3>");
                diagnostics(&mut o, fit);
            }
        }
        if let Some(opt) = &round.optimum {
            o.push_str("<h2>4. Optimum</h2>");
            let _ = write!(o, "<p>{}</p>", esc(&opt.note));
            if multi {
                let each: Vec<String> = targets
                    .iter()
                    .zip(&opt.predictions)
                    .map(|(t, p)| {
                        format!(
                            "{} {} (target {})",
                            esc(&t.label),
                            fmt_num(*p),
                            fmt_num(t.value)
                        )
                    })
                    .collect();
                let _ = write!(
                    o,
                    "<p>Overall desirability {} at the chosen setting; predicted {}.</p>",
                    fmt_num(opt.desirability),
                    each.join(", ")
                );
            }
            let mut header = vec![s("#")];
            header.extend(round.factors.iter().map(|f| f.name.clone()));
            if multi {
                header.extend(targets.iter().map(|t| format!("predicted {}", t.label)));
                header.push(s("overall desirability"));
            } else {
                header.extend(["predicted", "desirability"].map(s));
            }
            let rows: Vec<Vec<String>> = opt
                .solutions
                .iter()
                .enumerate()
                .map(|(i, sol)| {
                    let mut row = vec![if i == 0 {
                        s("<b>chosen</b>")
                    } else {
                        (i + 1).to_string()
                    }];
                    row.extend(sol.natural.iter().map(|v| fmt_num(*v)));
                    if multi {
                        row.extend(sol.predictions.iter().map(|v| fmt_num(*v)));
                    } else {
                        row.push(fmt_num(sol.predicted));
                    }
                    row.push(fmt_num(sol.desirability));
                    row
                })
                .collect();
            table(&mut o, &header, &rows, 1);
            if !opt.natural_min.is_empty() {
                let ext: Vec<String> = round
                    .factors
                    .iter()
                    .enumerate()
                    .map(|(i, f)| {
                        format!(
                            "{} {}..{}",
                            esc(&f.name),
                            fmt_num(opt.natural_min[i]),
                            fmt_num(opt.natural_max[i])
                        )
                    })
                    .collect();
                let _ = write!(
                    o,
                    "<p>Level set: {} of {} starts at the best desirability, {} distinct settings, spread {} coded units; extent {}.</p>",
                    opt.starts_at_best,
                    opt.starts,
                    opt.distinct_at_best,
                    fmt_num(opt.spread),
                    ext.join(", ")
                );
            }
        }
        for v in c.verifications.iter().filter(|v| v.round == round.round) {
            o.push_str("<h2>5. Verification</h2>");
            let point: Vec<String> = v
                .factors
                .iter()
                .zip(&v.point)
                .map(|(n, x)| format!("{} = {}", esc(n), fmt_num(*x)))
                .collect();
            let _ = write!(
                o,
                "<p>At {} (predicted {}):</p>",
                point.join(", "),
                fmt_num(v.predicted)
            );
            if multi {
                for (t, check) in targets.iter().zip(&v.checks) {
                    heading(&mut o, t);
                    if let Some((b, res)) =
                        batch_of(c, results, StageKind::Verification, v.round, t)
                    {
                        design_table(&mut o, &b.request, &res.runs, Some(t.value));
                    }
                    let _ = write!(
                        o,
                        "<p>Predicted {} · mean {} (sd {}, n = {}) · target {} · relative error {} % · <span class=\"{}\">{}</span> (tolerance {}).</p>",
                        fmt_num(check.predicted),
                        fmt_num(check.mean),
                        fmt_num(check.std),
                        check.responses.len(),
                        fmt_num(check.target),
                        fmt_num(check.relative_error_pct),
                        if check.within_tolerance { "ok" } else { "bad" },
                        if check.within_tolerance { "within tolerance" } else { "outside tolerance" },
                        esc(&t.tolerance.describe())
                    );
                }
                continue;
            }
            if let Some((b, res)) = c
                .batches
                .iter()
                .find(|b| b.stage == StageKind::Verification && b.round == v.round)
                .and_then(|b| result_for(results, b.index).map(|res| (b, res)))
            {
                design_table(&mut o, &b.request, &res.runs, Some(t0.value));
            }
            let _ = write!(
                o,
                "<p>Mean {} (sd {}, n = {}) · target {} · relative error {} % · <span class=\"{}\">{}</span> (tolerance {}).</p>",
                fmt_num(v.mean),
                fmt_num(v.std),
                v.responses.len(),
                fmt_num(t0.value),
                fmt_num(v.relative_error_pct),
                if v.within_tolerance { "ok" } else { "bad" },
                if v.within_tolerance { "within tolerance" } else { "outside tolerance" },
                esc(&t0.tolerance.describe())
            );
        }
    }
    picture(&mut o, "Verification pile", &pictures.verification_pile);

    // Stage 6.
    if r.drilling.is_some() {
        o.push_str("<h2>6. Drilling validation</h2>");
        match &c.drilling {
            Some(d) => validation_table(&mut o, d),
            None => o.push_str("<p>Not run yet.</p>"),
        }
        picture(&mut o, "Drilled hole", &pictures.drilled_hole);
    }

    // Provenance.
    o.push_str("<h2>Provenance of every run</h2><p><small>spec = first 16 hex digits of the SHA-256 of the exact spec the workers received (equal hashes simulated the same document); engine = the DEM engine version that computed the result.</small></p>");
    let rows: Vec<Vec<String>> = provenance(c, results)
        .iter()
        .map(|p| {
            vec![
                esc(p["batch_name"].as_str().unwrap_or("")),
                p["run_index"].to_string(),
                p["seed"].to_string(),
                esc(p["status"].as_str().unwrap_or("")),
                p["worker_id"]
                    .as_str()
                    .map_or(s("—"), |w| esc(&w[..8.min(w.len())])),
                p["wall_time_s"].as_f64().map_or(s("—"), fmt_num),
                p["attempts"].to_string(),
                esc(p["engine_version"].as_str().unwrap_or("—")),
                format!(
                    "<code>{}</code>",
                    esc(p["spec_sha256"].as_str().unwrap_or(""))
                ),
                p["response"].as_f64().map_or(s("—"), fmt_num),
                p["reason"].as_str().map_or(s("—"), esc),
            ]
        })
        .collect();
    table(
        &mut o,
        &[
            "batch", "run", "seed", "status", "worker", "wall s", "attempts", "engine", "spec",
            "response", "reason",
        ]
        .map(s),
        &rows,
        1,
    );
    o.push_str("</body></html>\n");
    o
}
