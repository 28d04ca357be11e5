//! What happens after a state change, in one place: waking waiting claims, analysing batches
//! that finished, and advancing the campaigns they belong to. Routes, the lease-reclaim timer
//! and campaigns call these; the database only reports what changed ([`JobUpdate`], the batches
//! an expiry finished).

use axum::Json;
use repose_api::{JobUpdateResponse, RunState};
use uuid::Uuid;

use crate::db::JobUpdate;
use crate::error::AppError;
use crate::{analysis, campaigns, AppState};

/// Jobs became claimable (a submission, a release, a retry): end waiting long-polls.
pub fn jobs_available(state: &AppState) {
    state.jobs_available.notify_waiters();
}

/// After a job update: wakes waiting claims if the job is claimable again, and analyses the
/// batch (then advances its campaign) if this update finished it.
pub fn job_updated(state: &AppState, job_id: Uuid, update: JobUpdate) -> Json<JobUpdateResponse> {
    if update.requeued {
        jobs_available(state);
    }
    if update.batch_finished {
        tracing::info!(job = %job_id, "last run of a batch finished");
        batches_finished(state, vec![update.batch_id]);
    }
    Json(JobUpdateResponse {
        status: update.status,
    })
}

/// The target of the server's lines about runs that failed: one line per failed attempt,
/// naming the run, so that `repose up` (whose own workers report the same failures) can show
/// these alone.
pub const RUNS_LOG_TARGET: &str = "repose::runs";

/// Logs a failed attempt once, as what became of the run: run again under another seed (a
/// seed-dependent failure such as an arch: INFO), queued for a retry (INFO), or dead (WARN).
pub fn job_failed(job_id: Uuid, update: &JobUpdate, error: &str) {
    let (batch, run) = (update.batch_id, update.run_index);
    match (update.reseeded, update.status) {
        (Some(seed), _) => tracing::info!(target: RUNS_LOG_TARGET, %batch, %job_id, %error,
            "run {run} runs again under seed {seed}: this seed gave no result"),
        (None, RunState::Dead) => {
            tracing::warn!(target: RUNS_LOG_TARGET, %batch, %job_id, %error, "run {run} is dead")
        }
        (None, _) => tracing::info!(target: RUNS_LOG_TARGET, %batch, %job_id, %error,
            "run {run} failed; it will be retried"),
    }
}

/// A batch was cancelled: a campaign waiting on it stops and says why.
pub async fn batch_cancelled(state: &AppState, batch_id: Uuid) {
    if let Err(err) = campaigns::advance_after_batch(state, batch_id).await {
        tracing::error!(batch = %batch_id, error = %err, "campaign could not record the cancel");
    }
}

/// Fits the batch and stores the result unless another task already did.
pub async fn compute_and_store_analysis(
    state: &AppState,
    batch_id: Uuid,
) -> Result<repose_api::AnalysisView, AppError> {
    let input = state
        .db
        .analysis_input(batch_id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("batch {batch_id} not found")))?;
    let view = tokio::task::spawn_blocking(move || analysis::analyse(&input))
        .await
        .map_err(|err| AppError::Internal(format!("analysis task: {err}")))?;
    Ok(state.db.store_analysis(&view).await?)
}

/// Runs the analysis of freshly finished batches in the background so the worker that
/// delivered the last result is answered at once.
pub fn batches_finished(state: &AppState, batches: Vec<Uuid>) {
    for batch_id in batches {
        let state = state.clone();
        tokio::spawn(async move {
            match compute_and_store_analysis(&state, batch_id).await {
                Ok(view) => {
                    tracing::info!(batch = %batch_id, error = ?view.error, "batch analysed")
                }
                Err(err) => tracing::error!(batch = %batch_id, error = %err, "analysis failed"),
            }
            // A campaign's next stage is generated from this batch.
            if let Err(err) = campaigns::advance_after_batch(&state, batch_id).await {
                tracing::error!(batch = %batch_id, error = %err, "campaign could not advance");
            }
        });
    }
}

/// Returns expired leases to the queue every [`crate::Config::reclaim_interval`], so a job
/// whose worker vanished is claimable (or dead, finishing its batch) even when no worker polls.
pub async fn reclaim_expired_leases(state: AppState) {
    let mut ticks = tokio::time::interval(state.config.reclaim_interval);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        ticks.tick().await;
        match state.db.reclaim_expired(state.config.max_attempts).await {
            Ok(expired) => {
                // Only when something changed: waking every long-poll each second would turn
                // idle workers into a stream of empty claims.
                if expired.requeued {
                    jobs_available(&state);
                }
                batches_finished(&state, expired.finished);
            }
            Err(err) => tracing::warn!(error = %err, "reclaiming expired leases failed"),
        }
    }
}
