//! `/v1/workers`: a worker's registration, and the list of workers.

use axum::extract::State;
use axum::response::IntoResponse;
use axum::Json;
use repose_api::{WorkerRegistered, WorkerRegistration};

use super::ValidJson;
use crate::auth::Caller;
use crate::error::AppError;
use crate::{orchestrate, submit, AppState};

/// Workers listed by `GET /v1/workers`.
const WORKER_LIST_LIMIT: u32 = 1000;

pub(super) async fn list_workers(
    State(state): State<AppState>,
) -> Result<impl IntoResponse, AppError> {
    Ok(Json(state.db.list_workers(WORKER_LIST_LIMIT).await?))
}

pub(super) async fn register_worker(
    State(state): State<AppState>,
    caller: Caller,
    ValidJson(registration): ValidJson<WorkerRegistration>,
) -> Result<impl IntoResponse, AppError> {
    submit::check_name_length("host", &registration.host)?;
    submit::check_name_length("version", &registration.version)?;
    if let Some(gpu) = &registration.gpu {
        if gpu.trim().is_empty() {
            return Err(AppError::invalid(
                "gpu",
                "must name the adapter (leave it out for a CPU-only worker)",
            ));
        }
        submit::check_name_length("gpu", gpu)?;
        if registration.gpu_slots == Some(0) {
            return Err(AppError::invalid(
                "gpu_slots",
                "must be at least 1 for a worker with a GPU",
            ));
        }
    } else {
        for (field, given) in [
            ("gpu_slots", registration.gpu_slots.is_some()),
            ("gpu_memory_bytes", registration.gpu_memory_bytes.is_some()),
        ] {
            if given {
                return Err(AppError::invalid(
                    field,
                    "only a worker with a GPU (`gpu`) reports it",
                ));
            }
        }
    }
    repose_api::check_worker_version(state.config.release, &registration.version)
        .map_err(|refusal| AppError::invalid("version", refusal.to_string()))?;
    let released = state
        .db
        .register_worker(&registration, &caller.name)
        .await?;
    tracing::info!(worker = %registration.instance_id, host = %registration.host,
        gpu = registration.gpu.as_deref().unwrap_or("none"),
        gpu_slots = registration.gpu_slots.unwrap_or(0), "worker registered");
    if released > 0 {
        tracing::info!(worker = %registration.instance_id, jobs = released,
            "jobs the worker held before it restarted went back to the queue");
        state.metrics.released(released);
        orchestrate::jobs_available(&state);
    }
    Ok(Json(WorkerRegistered {
        worker_id: registration.instance_id,
        lease_s: state.config.lease.as_secs_f64(),
    }))
}
