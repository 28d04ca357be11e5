//! `/v1/batches`: submission, listing, progress, the run table (JSON or CSV), cancellation
//! and the analysis.

use std::fmt::Write as _;

use axum::extract::{Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use repose_api::{BatchCreated, BatchRequest, BatchState, RunView};
use uuid::Uuid;

use super::{check_owner, owner_filter, read_scope, FormatQuery, PathId, Reader, ValidJson};
use crate::auth::Caller;
use crate::db::ReadScope;
use crate::error::AppError;
use crate::{analysis, orchestrate, submit, AppState};

/// Batches listed by `GET /v1/batches`.
const BATCH_LIST_LIMIT: u32 = 500;

pub(super) async fn create_batch(
    State(state): State<AppState>,
    caller: Caller,
    ValidJson(request): ValidJson<BatchRequest>,
) -> Result<(StatusCode, Json<BatchCreated>), AppError> {
    let fallback_seed = Uuid::new_v4().as_u64_pair().0;
    // Design generation and the estimability check are CPU work; keep them off the reactor.
    let plan = tokio::task::spawn_blocking(move || submit::plan_batch(request, fallback_seed))
        .await
        .map_err(|err| AppError::Internal(format!("planning task: {err}")))??;
    let id = state.db.insert_batch(&plan, &caller.name).await?;
    orchestrate::jobs_available(&state);
    tracing::info!(batch = %id, runs = plan.runs.len(), "batch submitted");
    Ok((
        StatusCode::CREATED,
        Json(BatchCreated {
            id,
            run_count: plan.runs.len(),
        }),
    ))
}

pub(super) async fn list_batches(
    State(state): State<AppState>,
    reader: Reader,
) -> Result<impl IntoResponse, AppError> {
    let owner = owner_filter(&state, &reader);
    Ok(Json(state.db.list_batches(BATCH_LIST_LIMIT, owner).await?))
}

pub(super) async fn batch_status(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
) -> Result<impl IntoResponse, AppError> {
    check_batch_owner(&state, &reader, id).await?;
    let status = state
        .db
        .batch_status(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
    Ok(Json(status))
}

pub(super) async fn batch_runs(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
    Query(query): Query<FormatQuery>,
) -> Result<Response, AppError> {
    check_batch_owner(&state, &reader, id).await?;
    let (factor_names, runs) = state
        .db
        .list_runs(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
    match query.format.as_deref() {
        None | Some("json") => Ok(Json(runs).into_response()),
        Some("csv") => Ok((
            [(header::CONTENT_TYPE, "text/csv; charset=utf-8")],
            runs_csv(&factor_names, &runs),
        )
            .into_response()),
        Some(other) => Err(AppError::BadRequest(format!(
            "unknown format `{other}` (expected json or csv)"
        ))),
    }
}

pub(super) async fn cancel_batch(
    State(state): State<AppState>,
    caller: Caller,
    PathId(id): PathId,
) -> Result<impl IntoResponse, AppError> {
    match state.db.cancel_batch(id, &caller.name).await? {
        None => Err(AppError::NotFound(format!("batch {id} not found"))),
        Some(BatchState::Completed) => {
            Err(AppError::Conflict(format!("batch {id} already completed")))
        }
        Some(_) => {
            let status = state
                .db
                .batch_status(id)
                .await?
                .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
            orchestrate::batch_cancelled(&state, id).await;
            Ok(Json(status))
        }
    }
}

pub(super) async fn batch_analysis(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
    Query(query): Query<FormatQuery>,
) -> Result<Response, AppError> {
    check_batch_owner(&state, &reader, id).await?;
    let view = match state.db.analysis(id).await? {
        Some(view) => view,
        None => {
            // Normally computed when the last run completes; this covers a restart in between.
            let input = state
                .db
                .analysis_input(id)
                .await?
                .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
            match input.state {
                BatchState::Completed => {
                    orchestrate::compute_and_store_analysis(&state, id).await?
                }
                BatchState::Active => {
                    return Err(AppError::Conflict(format!(
                        "batch {id} is still running; the analysis is computed when its last \
                         run finishes"
                    )))
                }
                BatchState::Cancelled => {
                    return Err(AppError::Conflict(format!(
                        "batch {id} was cancelled; it has no analysis"
                    )))
                }
            }
        }
    };
    match query.format.as_deref() {
        None | Some("json") => Ok(Json(view).into_response()),
        Some("text") => Ok((
            [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
            analysis::render_text(&view),
        )
            .into_response()),
        Some(other) => Err(AppError::BadRequest(format!(
            "unknown format `{other}` (expected json or text)"
        ))),
    }
}

/// [`check_owner`] for a batch, looked up by id (404 if it does not exist).
async fn check_batch_owner(state: &AppState, reader: &Reader, id: Uuid) -> Result<(), AppError> {
    if read_scope(state, reader) == ReadScope::All {
        return Ok(());
    }
    let owner = state
        .db
        .batch_owner(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
    check_owner(state, reader, owner.as_deref(), &format!("batch {id}"))
}

/// The run table as CSV: one column per factor (natural units), per metric and the bookkeeping.
fn runs_csv(factor_names: &[String], runs: &[RunView]) -> String {
    let mut metric_names: Vec<&String> = runs
        .iter()
        .filter_map(|run| run.metrics.as_ref())
        .flat_map(|metrics| metrics.keys())
        .collect();
    metric_names.sort();
    metric_names.dedup();
    let mut header_fields: Vec<String> = vec!["run_index".into(), "replicate".into()];
    header_fields.extend(factor_names.iter().cloned());
    header_fields.extend(["seed".into(), "status".into(), "attempts".into()]);
    header_fields.extend(metric_names.iter().map(|m| (*m).clone()));
    header_fields.extend(["worker_id".into(), "wall_time_s".into(), "run_id".into()]);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}",
        header_fields
            .iter()
            .map(|f| csv_field(f))
            .collect::<Vec<_>>()
            .join(",")
    );
    for run in runs {
        let mut fields: Vec<String> = vec![run.run_index.to_string(), run.replicate.to_string()];
        fields.extend(run.factors.iter().map(|f| f.natural.to_string()));
        fields.extend([
            run.seed.to_string(),
            run.status.as_str().to_owned(),
            run.attempts.to_string(),
        ]);
        fields.extend(metric_names.iter().map(|name| {
            run.metrics
                .as_ref()
                .and_then(|m| m.get(*name))
                .map(f64::to_string)
                .unwrap_or_default()
        }));
        fields.extend([
            run.worker_id.map(|w| w.to_string()).unwrap_or_default(),
            run.wall_time_s.map(|w| w.to_string()).unwrap_or_default(),
            run.id.to_string(),
        ]);
        let _ = writeln!(
            out,
            "{}",
            fields
                .iter()
                .map(|f| csv_field(f))
                .collect::<Vec<_>>()
                .join(",")
        );
    }
    out
}

/// Quotes a CSV field when it contains a separator, quote or line break (RFC 4180).
fn csv_field(field: &str) -> String {
    if field.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", field.replace('"', "\"\""))
    } else {
        field.to_owned()
    }
}
