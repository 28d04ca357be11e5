//! The service's own endpoints: `/healthz`, `/openapi.json` and `/metrics`.

use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::Json;
use repose_api::Health;

use crate::error::AppError;
use crate::AppState;

/// 200 when the database answers reads and commits a write through the writer; 503 otherwise
/// (and while the last real write failed for a storage reason such as a full disk).
pub(super) async fn health(State(state): State<AppState>) -> Result<Json<Health>, AppError> {
    state.db.ping().await.map_err(|err| match err {
        crate::db::DbError::Unavailable(message) => AppError::Unavailable(message),
        other => {
            tracing::warn!(error = %other, "health check failed");
            AppError::Unavailable("the database is not writable".into())
        }
    })?;
    Ok(Json(Health {
        status: "ok".into(),
        version: state.config.release.to_string(),
    }))
}

/// The API description (`api/openapi.json`).
pub(super) async fn openapi() -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        repose_api::OPENAPI_JSON,
    )
        .into_response()
}

/// Prometheus text format; see [`crate::metrics`].
pub(super) async fn metrics(State(state): State<AppState>) -> Result<Response, AppError> {
    let gauges = state.db.gauges(state.config.lease).await?;
    Ok((
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        state.metrics.render(&gauges),
    )
        .into_response())
}
