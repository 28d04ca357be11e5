//! The server's one error type and its mapping to HTTP status codes.
//!
//! Every handler returns `Result<_, AppError>`; the status code of each failure is decided here
//! and nowhere else, and internal failures are logged and answered with a generic message so
//! SQL, file paths and the like never leak to clients.

use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use repose_api::ApiError;

/// Everything a request can fail with.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// The request is malformed in a way no field can be blamed for (bad JSON, bad id, …): 400.
    #[error("{0}")]
    BadRequest(String),
    /// A well-formed request with an unacceptable value: 422, naming the field when known.
    #[error("{message}")]
    Invalid {
        /// Dotted path of the offending field, e.g. `factors[0].low`.
        field: Option<String>,
        /// What is wrong with it.
        message: String,
    },
    /// No valid token (missing, malformed, unknown or revoked): 401 with `WWW-Authenticate`.
    #[error("{0}")]
    Unauthorized(String),
    /// A valid token without the right to do this (wrong role, another user's batch): 403.
    #[error("{0}")]
    Forbidden(String),
    /// The addressed batch, job or run does not exist: 404.
    #[error("{0}")]
    NotFound(String),
    /// The path exists but not with this method: 405.
    #[error("{0}")]
    MethodNotAllowed(String),
    /// The request conflicts with the current state (stale lease, duplicate completion, …): 409.
    #[error("{0}")]
    Conflict(String),
    /// The body could not be read (too large, wrong encoding): status chosen by axum.
    #[error("{message}")]
    Body {
        /// Status axum assigned to the rejection, e.g. 413.
        status: StatusCode,
        /// Axum's explanation.
        message: String,
    },
    /// The server cannot serve this right now (the database cannot store writes): 503 with
    /// `Retry-After`.
    #[error("{0}")]
    Unavailable(String),
    /// A database failure: 503 when storage is the cause (disk full, I/O error, busy), else
    /// 500; details only in the log.
    #[error("database error: {0}")]
    Database(#[from] sqlx::Error),
    /// Any other server-side failure: 500, details only in the log.
    #[error("internal error: {0}")]
    Internal(String),
}

impl AppError {
    /// A 422 blaming `field`.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        AppError::Invalid {
            field: Some(field.into()),
            message: message.into(),
        }
    }
}

/// Whether a database error is the storage's condition (full, I/O, locked, no connection),
/// which a client may retry later, rather than a bug.
fn is_storage_condition(err: &sqlx::Error) -> bool {
    match err {
        sqlx::Error::Database(db) => {
            // SQLite primary result codes: BUSY 5, LOCKED 6, NOMEM 7, READONLY 8, IOERR 10,
            // FULL 13, CANTOPEN 14.
            let code = db
                .code()
                .and_then(|code| code.parse::<i32>().ok())
                .map(|code| code & 0xff);
            matches!(code, Some(5..=8 | 10 | 13 | 14))
        }
        sqlx::Error::Io(_) | sqlx::Error::PoolTimedOut | sqlx::Error::PoolClosed => true,
        _ => false,
    }
}

impl From<crate::db::DbError> for AppError {
    /// The storage layer's failures and refusals, as HTTP: the one place they are mapped.
    fn from(err: crate::db::DbError) -> Self {
        use crate::db::DbError;
        match err {
            DbError::NotFound(message) => AppError::NotFound(message),
            DbError::Conflict(message) => AppError::Conflict(message),
            DbError::Forbidden(message) => AppError::Forbidden(message),
            DbError::Invalid { field, message } => AppError::Invalid {
                field: Some(field),
                message,
            },
            DbError::Unavailable(message) => AppError::Unavailable(message),
            DbError::Sqlx(err) => AppError::Database(err),
            DbError::Corrupt(message) => AppError::Internal(message),
        }
    }
}

impl From<serde_json::Error> for AppError {
    /// JSON round trips of values the server itself stored; failing means a bug or corruption.
    fn from(err: serde_json::Error) -> Self {
        AppError::Internal(format!("stored JSON: {err}"))
    }
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let (status, field, message) = match self {
            AppError::BadRequest(message) => (StatusCode::BAD_REQUEST, None, message),
            AppError::Invalid { field, message } => {
                (StatusCode::UNPROCESSABLE_ENTITY, field, message)
            }
            AppError::Unauthorized(message) => {
                let body = Json(ApiError {
                    error: message,
                    field: None,
                });
                // RFC 6750: a 401 names the scheme the client should use.
                let challenge = HeaderValue::from_static("Bearer realm=\"repose\"");
                return (
                    StatusCode::UNAUTHORIZED,
                    [(header::WWW_AUTHENTICATE, challenge)],
                    body,
                )
                    .into_response();
            }
            AppError::Forbidden(message) => (StatusCode::FORBIDDEN, None, message),
            AppError::NotFound(message) => (StatusCode::NOT_FOUND, None, message),
            AppError::Conflict(message) => (StatusCode::CONFLICT, None, message),
            AppError::MethodNotAllowed(message) => (StatusCode::METHOD_NOT_ALLOWED, None, message),
            AppError::Body { status, message } => (status, None, message),
            AppError::Unavailable(message) => {
                tracing::warn!(error = %message, "service unavailable");
                return unavailable("the server cannot store writes right now; retry later");
            }
            AppError::Database(err) if is_storage_condition(&err) => {
                tracing::error!(error = %err, "storage failure");
                return unavailable("the server cannot store writes right now; retry later");
            }
            internal @ (AppError::Database(_) | AppError::Internal(_)) => {
                tracing::error!(error = %internal, "request failed");
                (
                    StatusCode::INTERNAL_SERVER_ERROR,
                    None,
                    "internal error".to_owned(),
                )
            }
        };
        (
            status,
            Json(ApiError {
                error: message,
                field,
            }),
        )
            .into_response()
    }
}

/// 503 with a `Retry-After` of a few seconds.
fn unavailable(message: &str) -> Response {
    (
        StatusCode::SERVICE_UNAVAILABLE,
        [(header::RETRY_AFTER, HeaderValue::from_static("5"))],
        Json(ApiError {
            error: message.to_owned(),
            field: None,
        }),
    )
        .into_response()
}
