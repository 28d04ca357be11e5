//! The report as JSON: inputs, status, decisions, per-stage outcomes with the full fits, the
//! summary and the provenance of every run.

use repose_api::RunState;
use repose_doe::Fit;
use serde_json::{json, Value};

use super::{batch_of, provenance, reason, response_of, result_for, spec_hash};
use crate::campaign::{fit_or_reason, screening_fit, surface_fit};
use crate::{Campaign, StageKind, StageResult};

fn fit_json(fit: &Result<Fit, String>) -> Value {
    match fit {
        Ok(f) => serde_json::to_value(f).unwrap_or(Value::Null),
        Err(e) => json!({"error": e}),
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
    let provenance: Vec<Value> = provenance(c, results)
        .into_iter()
        .map(|(b, run)| {
            json!({
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
                "reason": reason(run),
            })
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
        "provenance": provenance,
    })
}
