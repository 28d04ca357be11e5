//! `/v1/jobs`: the job list, and a worker's side of a job: the claim long-poll, heartbeats,
//! and the result (completion, failure or release).

use std::time::Duration;

use axum::extract::{Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use repose_api::{
    ClaimRequest, Completion, Failure, Heartbeat, HeartbeatResponse, Release, RunState,
};
use serde::Deserialize;
use tokio::time::Instant;

use super::{parse_id, read_scope, PathId, Reader, ValidJson};
use crate::auth::Caller;
use crate::db::Rerun;
use crate::error::AppError;
use crate::{orchestrate, submit, AppState};

/// How often a waiting claim re-checks the queue even without a notification, so retry
/// back-offs and expired leases are picked up without a background task.
const CLAIM_RECHECK: Duration = Duration::from_millis(500);

/// Longest error text a worker may report for a failed run, in bytes.
const MAX_ERROR_BYTES: usize = 16 * 1024;

/// Largest `details` document of a completion (serialized), in bytes.
const MAX_DETAILS_BYTES: usize = 64 * 1024;

/// Most metrics one completion may report.
const MAX_METRICS: usize = 256;

/// Largest single picture of a completion, in bytes.
const MAX_PICTURE_BYTES: usize = 2 * 1024 * 1024;

/// Default and largest `limit` of `GET /v1/jobs`.
const JOB_LIST_DEFAULT: u32 = 100;
const JOB_LIST_MAX: u32 = 10_000;

/// The query of `GET /v1/jobs`, kept as text: [`list_jobs`] parses it, so a bad value is
/// answered in the server's error format.
#[derive(Debug, Deserialize)]
pub(super) struct JobsQuery {
    state: Option<String>,
    batch: Option<String>,
    limit: Option<String>,
}

/// Jobs, most recently changed first: `?state=queued|running|completed|dead|cancelled`,
/// `?batch=<id>`, `?limit=` (default 100, at most 10 000).
pub(super) async fn list_jobs(
    State(state): State<AppState>,
    reader: Reader,
    Query(query): Query<JobsQuery>,
) -> Result<impl IntoResponse, AppError> {
    let status = query
        .state
        .as_deref()
        .map(|text| {
            serde_json::from_value::<RunState>(serde_json::Value::String(text.to_owned())).map_err(
                |_| {
                    AppError::BadRequest(format!(
                        "unknown state `{text}` (expected queued, running, completed, dead or \
                         cancelled)"
                    ))
                },
            )
        })
        .transpose()?;
    let batch = query
        .batch
        .as_deref()
        .map(|raw| parse_id(raw, "batch"))
        .transpose()?;
    let limit = match query.limit.as_deref() {
        None => JOB_LIST_DEFAULT,
        Some(text) => text.parse().unwrap_or(0),
    };
    if limit == 0 || limit > JOB_LIST_MAX {
        return Err(AppError::BadRequest(format!(
            "limit must be between 1 and {JOB_LIST_MAX}"
        )));
    }
    let scope = read_scope(&state, &reader);
    Ok(Json(state.db.list_jobs(status, batch, limit, scope).await?))
}

/// Leases a job, waiting up to `wait_s` for one; 204 when none arrives in time.
pub(super) async fn claim_job(
    State(state): State<AppState>,
    caller: Caller,
    ValidJson(request): ValidJson<ClaimRequest>,
) -> Result<Response, AppError> {
    if !(request.wait_s.is_finite() && request.wait_s >= 0.0) {
        return Err(AppError::invalid("wait_s", "must be a non-negative number"));
    }
    // Clamped before converting: any finite wait is allowed, and waits at most the maximum.
    let wait = Duration::try_from_secs_f64(
        request
            .wait_s
            .min(state.config.max_claim_wait.as_secs_f64()),
    )
    .unwrap_or(state.config.max_claim_wait);
    let deadline = Instant::now() + wait;
    let mut shutdown = state.shutdown.clone();
    loop {
        // Register interest before looking, so a submission between the look and the wait
        // is not missed.
        let notified = state.jobs_available.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();

        let started = std::time::Instant::now();
        let (claimed, finished) = state
            .db
            .claim(
                request.worker_id,
                &caller.name,
                request.backend,
                state.config.lease,
                state.config.max_attempts,
                state.config.release,
            )
            .await?;
        orchestrate::batches_finished(&state, finished);
        if let Some(job) = claimed {
            state.metrics.claimed(started.elapsed());
            tracing::debug!(job = %job.job_id, worker = %request.worker_id, "job leased");
            return Ok(Json(job).into_response());
        }
        let now = Instant::now();
        if now >= deadline || *shutdown.borrow() {
            state.metrics.claim_empty();
            return Ok(StatusCode::NO_CONTENT.into_response());
        }
        let recheck = (now + CLAIM_RECHECK).min(deadline);
        tokio::select! {
            _ = &mut notified => {}
            _ = tokio::time::sleep_until(recheck) => {}
            _ = shutdown.changed() => {}
        }
    }
}

pub(super) async fn heartbeat(
    State(state): State<AppState>,
    PathId(job_id): PathId,
    ValidJson(beat): ValidJson<Heartbeat>,
) -> Result<impl IntoResponse, AppError> {
    if !beat.progress.is_finite() {
        return Err(AppError::invalid("progress", "must be a number in 0..1"));
    }
    let outcome = state
        .db
        .heartbeat(job_id, beat.lease_token, beat.progress, state.config.lease)
        .await?;
    Ok(Json(HeartbeatResponse {
        cancel: outcome.cancel,
        lease_expires_in_s: outcome.lease_expires_in_s,
    }))
}

pub(super) async fn complete_job(
    State(state): State<AppState>,
    PathId(job_id): PathId,
    ValidJson(completion): ValidJson<Completion>,
) -> Result<impl IntoResponse, AppError> {
    check_completion_sizes(&completion)?;
    let update = state
        .db
        .complete(job_id, completion.lease_token, &completion)
        .await?;
    state.metrics.completed();
    Ok(orchestrate::job_updated(&state, job_id, update))
}

pub(super) async fn fail_job(
    State(state): State<AppState>,
    PathId(job_id): PathId,
    ValidJson(failure): ValidJson<Failure>,
) -> Result<impl IntoResponse, AppError> {
    if failure.error.len() > MAX_ERROR_BYTES {
        return Err(AppError::invalid(
            "error",
            format!("at most {MAX_ERROR_BYTES} bytes of error text"),
        ));
    }
    let max_attempts = state.config.max_attempts;
    let rerun = match (failure.permanent, failure.another_seed) {
        (true, true) => {
            return Err(AppError::invalid(
                "another_seed",
                "a failure is either permanent or worth another seed, not both",
            ))
        }
        // Same spec and seed, same outcome: not worth a retry.
        (true, false) => Rerun::Never,
        (false, true) => Rerun::WithAnotherSeed {
            max_attempts,
            next_seed: repose_doe::design::next_seed,
        },
        (false, false) => Rerun::Retry {
            max_attempts,
            backoff: state.config.retry_backoff,
        },
    };
    let update = state
        .db
        .fail(job_id, failure.lease_token, &failure.error, rerun)
        .await?;
    state.metrics.failed();
    orchestrate::job_failed(job_id, &update, &failure.error);
    Ok(orchestrate::job_updated(&state, job_id, update))
}

pub(super) async fn release_job(
    State(state): State<AppState>,
    PathId(job_id): PathId,
    ValidJson(release): ValidJson<Release>,
) -> Result<impl IntoResponse, AppError> {
    let update = state.db.release(job_id, release.lease_token).await?;
    state.metrics.released(1);
    Ok(orchestrate::job_updated(&state, job_id, update))
}

/// Bounds every free-form part of a result, naming the field that is too large.
fn check_completion_sizes(completion: &Completion) -> Result<(), AppError> {
    if completion.metrics.len() > MAX_METRICS {
        return Err(AppError::invalid(
            "metrics",
            format!("at most {MAX_METRICS} metrics"),
        ));
    }
    for name in completion.metrics.keys() {
        submit::check_name_length("metrics", name)?;
    }
    if let Some(version) = &completion.engine_version {
        submit::check_name_length("engine_version", version)?;
    }
    let details = serde_json::to_string(&completion.details)?;
    if details.len() > MAX_DETAILS_BYTES {
        return Err(AppError::invalid(
            "details",
            format!("at most {MAX_DETAILS_BYTES} bytes of details"),
        ));
    }
    for (name, picture) in &completion.pictures {
        submit::check_name_length("pictures", name)?;
        if picture.len() > MAX_PICTURE_BYTES {
            return Err(AppError::invalid(
                format!("pictures.{name}"),
                format!("at most {MAX_PICTURE_BYTES} bytes per picture"),
            ));
        }
    }
    Ok(())
}
