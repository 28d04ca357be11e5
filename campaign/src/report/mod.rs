//! The campaign report: a JSON document ([`report_json`]) and a self-contained HTML page
//! ([`report_html`]: inline CSS and SVG, no scripts). Fits are recomputed from the runs with the
//! same functions the decisions used.
//!
//! `json` writes the document; `html` the page's frame (summary, inputs, decisions, pictures,
//! provenance) and `chain` the `doe` chain's stages, both with maud, which escapes every text;
//! `bayes` the Bayesian strategy's section; `svg` the charts, whose text maud escapes too.

mod bayes;
mod chain;
mod html;
mod json;
mod svg;

use repose_api::{BatchRequest, RunState, RunView};
use serde_json::json;
use sha2::{Digest, Sha256};

use crate::{Campaign, IssuedBatch, StageKind, StageResult, Target};

pub use html::report_html;
pub use json::report_json;

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

fn response_of(run: &RunView, response: &str) -> Option<f64> {
    run.metrics.as_ref().and_then(|m| m.get(response)).copied()
}

/// Every run of every batch with a result, batch by batch in run order: the provenance table.
fn provenance<'a>(
    c: &'a Campaign,
    results: &'a [StageResult],
) -> Vec<(&'a IssuedBatch, &'a RunView)> {
    let mut out = Vec::new();
    for b in &c.batches {
        let Some(r) = result_for(results, b.index) else {
            continue;
        };
        let mut runs: Vec<&RunView> = r.runs.iter().collect();
        runs.sort_by_key(|r| r.run_index);
        out.extend(runs.into_iter().map(|run| (b, run)));
    }
    out
}

/// Why a run gave no result (its last failure), for runs that have none.
fn reason(run: &RunView) -> Option<&str> {
    (run.status != RunState::Completed)
        .then_some(run.last_error.as_deref())
        .flatten()
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
