//! What the storage layer can fail with. It knows nothing of HTTP: `crate::error` maps each
//! variant to a status code, in one place.

/// A storage failure or a refusal decided by the stored state.
#[derive(Debug, thiserror::Error)]
pub enum DbError {
    /// The addressed batch, job, run or campaign does not exist.
    #[error("{0}")]
    NotFound(String),
    /// The request conflicts with the stored state (stale lease, duplicate result, …).
    #[error("{0}")]
    Conflict(String),
    /// The caller may not change this (another user's batch, another token's worker).
    #[error("{0}")]
    Forbidden(String),
    /// A value the stored state refuses, naming the request field.
    #[error("{message}")]
    Invalid {
        /// Dotted path of the offending request field.
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// Writes currently fail (disk full, I/O error): retry later.
    #[error("{0}")]
    Unavailable(String),
    /// SQLite or the connection pool failed.
    #[error("database: {0}")]
    Sqlx(#[from] sqlx::Error),
    /// Something stored cannot be decoded (a bug or corruption).
    #[error("stored data: {0}")]
    Corrupt(String),
}

impl DbError {
    /// A refusal blaming the request field `field`.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        DbError::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }
}

impl From<serde_json::Error> for DbError {
    /// JSON the server itself stored that does not decode.
    fn from(err: serde_json::Error) -> Self {
        DbError::Corrupt(format!("JSON: {err}"))
    }
}
