//! Plain data types shared by the storage layer ([`crate::db`]) and the layers above it (access
//! control, token administration, metrics, submissions, start-up). This module imports nothing
//! from the rest of the server, so `db` can use these types without depending on those layers;
//! each is re-exported where its users expect it ([`crate::auth::TokenRole`],
//! [`crate::tokens::TokenInfo`], [`crate::ServeError`], …).

use std::fmt;
use std::str::FromStr;

use repose_api::{BatchRequest, ModelName};
use repose_doe::design::{DesignKind, Factor};
use serde_json::Value;

/// What a token may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TokenRole {
    /// A person or script using the API: submits, reads and cancels batches.
    User,
    /// A worker process: registers, claims and reports jobs.
    Worker,
}

impl TokenRole {
    /// The spelling used on the command line, in the database and in token texts.
    pub fn as_str(self) -> &'static str {
        match self {
            TokenRole::User => "user",
            TokenRole::Worker => "worker",
        }
    }
}

impl fmt::Display for TokenRole {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A role name that is neither `user` nor `worker`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown token role `{0}` (expected user or worker)")]
pub struct UnknownRole(pub String);

impl FromStr for TokenRole {
    type Err = UnknownRole;

    fn from_str(text: &str) -> Result<Self, UnknownRole> {
        match text {
            "user" => Ok(TokenRole::User),
            "worker" => Ok(TokenRole::Worker),
            other => Err(UnknownRole(other.to_owned())),
        }
    }
}

/// A token as listed (the secret itself is never stored, so never shown again).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TokenInfo {
    /// Unique name; recorded as the owner of the batches the token submits.
    pub name: String,
    /// What the token may do.
    pub role: TokenRole,
    /// Creation time, Unix milliseconds.
    pub created_at_ms: i64,
    /// Revocation time, Unix milliseconds; `None` while the token is valid.
    pub revoked_at_ms: Option<i64>,
}

/// Database-derived gauges of one scrape.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Gauges {
    /// Jobs per database state (`queued`, `leased`, `completed`, `dead`, `cancelled`).
    pub jobs: Vec<(String, i64)>,
    /// Batches per state (`active`, `completed`, `cancelled`).
    pub batches: Vec<(String, i64)>,
    /// Workers whose last registration, claim or heartbeat is within one lease period.
    pub workers_active: i64,
    /// Workers ever registered.
    pub workers_registered: i64,
    /// Most recent registration, claim or heartbeat of any worker (Unix ms); `None`: no worker
    /// ever registered.
    pub worker_last_seen_ms: Option<i64>,
    /// Size of the database's pages (`page_count × page_size`, without the WAL).
    pub database_bytes: i64,
    /// Write transactions that failed with a database error since the server started.
    pub write_failures: u64,
    /// Whether the last write transaction failed and none succeeded since (`/healthz` is 503).
    pub writes_failing: bool,
    /// The workers with a GPU seen within [`GPU_WORKER_WINDOW`](crate::db::GPU_WORKER_WINDOW).
    pub gpu_workers: Vec<GpuWorkerGauge>,
    /// Active `gpu` batches while no worker with a GPU was seen within that window.
    pub batches_waiting_for_gpu: i64,
}

/// What a worker with a GPU reported of it, and the runs in flight on it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GpuWorkerGauge {
    pub worker: String,
    pub adapter: String,
    pub memory_bytes: Option<i64>,
    pub slots: Option<i64>,
    /// Leases it holds on jobs of `gpu` batches.
    pub running: i64,
}

/// One run ready to be stored.
#[derive(Debug, Clone)]
pub struct PlannedRun {
    /// Position in the randomised run order (claim order).
    pub run_index: usize,
    /// Row of the design in standard order.
    pub design_row: usize,
    /// Replicate number, from 0.
    pub replicate: usize,
    /// Coded factor values, factor order.
    pub coded: Vec<f64>,
    /// Natural factor values, factor order.
    pub natural: Vec<f64>,
    /// DEM seed, distinct for every run of the batch.
    pub seed: u64,
}

/// A validated submission.
#[derive(Debug, Clone)]
pub struct PlannedBatch {
    /// The request as received.
    pub request: BatchRequest,
    /// Factors in column order.
    pub factors: Vec<Factor>,
    /// Which construction produced the design (the analysis needs α of a CCD).
    pub design_kind: DesignKind,
    /// Seed the run order and run seeds derive from.
    pub base_seed: u64,
    /// The complete experiment spec before factor values are written in (stored once).
    pub template: Value,
    /// The runs, in claim order.
    pub runs: Vec<PlannedRun>,
}

/// The wire spelling of a model name.
pub fn model_label(model: ModelName) -> &'static str {
    match model {
        ModelName::Linear => "linear",
        ModelName::TwoFactorInteraction => "2fi",
        ModelName::Quadratic => "quadratic",
        ModelName::None => "none",
    }
}

/// Why the server could not start or stopped abnormally.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// Opening the database failed.
    #[error("opening the database: {0}")]
    Database(#[from] sqlx::Error),
    /// Applying the schema migrations failed.
    #[error("migrating the database: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    /// The listener failed.
    #[error("serving HTTP: {0}")]
    Io(#[from] std::io::Error),
    /// A token name that cannot be used.
    #[error("invalid token name `{name}`: {reason}")]
    InvalidTokenName {
        /// The name given.
        name: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A token with this name exists already (names stay taken after revocation).
    #[error("a token named `{0}` already exists")]
    TokenNameTaken(String),
    /// No token has this name.
    #[error("no token named `{0}`")]
    TokenNotFound(String),
}
