//! All SQL of the server, by concern: [`batches`] (batches and runs), [`jobs`] (workers,
//! claims, leases and job updates), [`campaigns`], [`tokens`], [`analyses`], [`backup`] (a
//! consistent copy of a live database); this file holds the
//! connection handling shared by all of them (the writer's [`WriteTx`], the health probe).
//!
//! SQLite in WAL mode with two pools: a single-connection *writer* pool, so write transactions
//! queue inside the process instead of racing for SQLite's lock ("database is locked" never
//! reaches a user), and a small read-only pool for the status views, which WAL lets run
//! alongside the writer. Times are Unix milliseconds; JSON documents are stored as TEXT.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::str::FromStr;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use repose_api::{
    apply_factor_values, AnalysisView, BackendKind, BatchState, BatchStatus, BatchSummary,
    ClaimResponse, Completion, FactorValue, GpuWait, JobView, ModelName, RunState, RunView,
    StateCounts, WorkerRegistration, WorkerView,
};
use repose_doe::design::{DesignKind, Factor};
use serde_json::Value;
use sqlx::pool::PoolConnection;
use sqlx::sqlite::{
    SqliteConnectOptions, SqliteJournalMode, SqlitePool, SqlitePoolOptions, SqliteRow,
    SqliteSynchronous,
};
use sqlx::{Row, Sqlite, SqliteConnection};
use uuid::Uuid;

use crate::types::{
    model_label, Gauges, GpuWorkerGauge, PlannedBatch, ServeError, TokenInfo, TokenRole,
};

mod analyses;
mod backup;
mod batches;
mod campaigns;
mod error;
mod jobs;
mod tokens;

pub use analyses::AnalysisInput;
pub use backup::{backup, BackupError, BackupReport};
use batches::*;
pub use campaigns::{CampaignRecord, CampaignUpdate};
pub use error::DbError;
pub use jobs::{JobUpdate, Rerun, GPU_WORKER_WINDOW};

/// How long a connection waits for SQLite's lock (another process, a checkpoint) before failing.
const BUSY_TIMEOUT: Duration = Duration::from_secs(10);

/// Read connections; status views are cheap, so a few suffice.
const READ_CONNECTIONS: u32 = 4;

/// Current time in Unix milliseconds.
pub fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

fn duration_ms(duration: Duration) -> i64 {
    i64::try_from(duration.as_millis()).unwrap_or(i64::MAX)
}

/// Expired leases are looked for by claims at most this often (a claim that finds nothing
/// re-checks within `CLAIM_RECHECK` anyway), so the hot claim path is usually one statement.
const EXPIRY_CHECK_INTERVAL_MS: i64 = 100;

/// Runs per multi-row INSERT (9 parameters each, well under SQLite's 32,766).
const INSERT_CHUNK: usize = 100;

/// Batch templates kept in memory for building run specs; the cache is emptied when full.
const TEMPLATE_CACHE: usize = 64;

/// What a batch's run specs are built from.
#[derive(Debug)]
struct RunTemplate {
    /// The experiment spec without factor values.
    template: Value,
    /// The factors' spec paths, in factor order (`None`: a design column not written).
    paths: Vec<Option<String>>,
}

/// A worker's `last_seen_at` is rewritten by claims at most this often.
const LAST_SEEN_RESOLUTION_MS: i64 = 1000;

/// Handle to the database; cheap to clone.
#[derive(Debug, Clone)]
pub struct Db {
    writer: SqlitePool,
    reader: SqlitePool,
    /// Earliest time (Unix ms) the next claim looks for expired leases.
    next_expiry_check_ms: Arc<AtomicI64>,
    /// Registered workers and when a claim last wrote their `last_seen_at` (Unix ms).
    seen_workers: Arc<Mutex<HashMap<Uuid, (String, i64)>>>,
    /// Whether writes currently fail, for the health check.
    writer_health: Arc<WriterHealth>,
    /// Templates of recently claimed batches (immutable once stored).
    templates: Arc<Mutex<HashMap<Uuid, Arc<RunTemplate>>>>,
}

/// Storage settings of [`Db::open_with`].
#[derive(Debug, Clone, Default)]
pub struct OpenOptions {
    /// `synchronous=FULL` instead of `NORMAL`: a result acknowledged is on disk even after a
    /// power loss, at the cost of an fsync per write transaction.
    pub durability_full: bool,
    /// SQLite's `max_page_count` on the writer: writes beyond this many pages fail with
    /// "database or disk is full" (a size cap; the fault-injection tests fill the disk with it).
    pub max_pages: Option<u64>,
}

/// The most recent write failure, cleared by the next successful write transaction, and how
/// many write transactions failed since the server started.
#[derive(Debug, Default)]
struct WriterHealth {
    last_failure: Mutex<Option<String>>,
    failures: std::sync::atomic::AtomicU64,
}

impl WriterHealth {
    fn record_failure(&self, err: &sqlx::Error) {
        self.failures.fetch_add(1, Ordering::Relaxed);
        if let Ok(mut last) = self.last_failure.lock() {
            *last = Some(err.to_string());
        }
    }

    fn record_success(&self) {
        if let Ok(mut last) = self.last_failure.lock() {
            *last = None;
        }
    }

    fn failing(&self) -> Option<String> {
        self.last_failure.lock().ok().and_then(|last| last.clone())
    }
}

/// A write transaction on the writer connection; end it with [`WriteTx::finish`].
///
/// Architecture Invariant: a writer connection that saw an error is never used again. SQLite
/// may roll a transaction back by itself when a statement or COMMIT fails with SQLITE_FULL or
/// SQLITE_IOERR; a connection reused after that can run later statements outside the
/// transaction its user thinks it is in, and acknowledge writes that never commit. So any
/// database error, a failed COMMIT or ROLLBACK, and a transaction dropped unfinished (a client
/// that went away mid-request) close the connection, and the pool opens a fresh one. Only a
/// refusal decided by the server's own logic (409, 404, …) rolls back and keeps it.
struct WriteTx {
    conn: PoolConnection<Sqlite>,
    health: Arc<WriterHealth>,
    finished: bool,
}

impl std::fmt::Debug for WriteTx {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WriteTx")
            .field("finished", &self.finished)
            .finish()
    }
}

impl std::ops::Deref for WriteTx {
    type Target = SqliteConnection;
    fn deref(&self) -> &SqliteConnection {
        &self.conn
    }
}

impl std::ops::DerefMut for WriteTx {
    fn deref_mut(&mut self) -> &mut SqliteConnection {
        &mut self.conn
    }
}

impl WriteTx {
    /// Commits on `Ok`; rolls back on a refusal; discards the connection on any database
    /// error (including a failed COMMIT). Returns `result`, or the COMMIT's error.
    async fn finish<T>(mut self, result: Result<T, DbError>) -> Result<T, DbError> {
        match result {
            Ok(value) => match sqlx::query("COMMIT").execute(&mut *self.conn).await {
                Ok(_) => {
                    self.finished = true;
                    self.health.record_success();
                    Ok(value)
                }
                Err(err) => {
                    self.health.record_failure(&err);
                    Err(err.into())
                }
            },
            Err(DbError::Sqlx(err)) => {
                self.health.record_failure(&err);
                Err(DbError::Sqlx(err))
            }
            Err(err @ (DbError::Corrupt(_) | DbError::Unavailable(_))) => Err(err),
            Err(refusal) => {
                if sqlx::query("ROLLBACK")
                    .execute(&mut *self.conn)
                    .await
                    .is_ok()
                {
                    self.finished = true;
                }
                Err(refusal)
            }
        }
    }

    /// [`WriteTx::finish`] for the health probe: a successful probe does not clear the
    /// failure of a real write (the probe's in-place update may fit where an insert did not).
    async fn finish_probe(mut self, result: Result<(), DbError>) -> Result<(), DbError> {
        if let Err(err) = result {
            if let DbError::Sqlx(db) = &err {
                self.health.record_failure(db);
            }
            return Err(err);
        }
        match sqlx::query("COMMIT").execute(&mut *self.conn).await {
            Ok(_) => {
                self.finished = true;
                Ok(())
            }
            Err(err) => {
                self.health.record_failure(&err);
                Err(err.into())
            }
        }
    }
}

impl Drop for WriteTx {
    fn drop(&mut self) {
        if !self.finished {
            // Closing a connection rolls back whatever it had open.
            self.conn.close_on_drop();
        }
    }
}

/// Creates the database file readable and writable by its owner only (0600) if it does not
/// exist; SQLite gives its `-wal` and `-shm` files the same permissions.
fn create_private(path: &Path) -> std::io::Result<()> {
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    match options.open(path) {
        Ok(_) => Ok(()),
        Err(err) if err.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(err) => Err(err),
    }
}

/// What a reader may see (see `Config::private_reads`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadScope<'a> {
    /// Everything.
    All,
    /// The batches, campaigns and jobs of this user token.
    User(&'a str),
    /// The jobs of the workers this worker token registered.
    Worker(&'a str),
}

impl Db {
    /// Opens or creates the database at `path` and applies the migrations.
    pub async fn open(path: &Path) -> Result<Self, ServeError> {
        Self::open_with(path, &OpenOptions::default()).await
    }

    /// [`Db::open`] with the server's storage settings.
    pub async fn open_with(path: &Path, settings: &OpenOptions) -> Result<Self, ServeError> {
        create_private(path)?;
        let mut options = SqliteConnectOptions::new()
            .filename(path)
            .create_if_missing(true)
            .journal_mode(SqliteJournalMode::Wal)
            .synchronous(if settings.durability_full {
                SqliteSynchronous::Full
            } else {
                SqliteSynchronous::Normal
            })
            .busy_timeout(BUSY_TIMEOUT)
            .foreign_keys(true);
        if let Some(pages) = settings.max_pages {
            options = options.pragma("max_page_count", pages.to_string());
        }
        let writer = SqlitePoolOptions::new()
            .max_connections(1)
            // A writer connection that failed is closed, never reused (see `WriteTx`).
            .test_before_acquire(false)
            .connect_with(options.clone())
            .await?;
        sqlx::migrate!("../migrations").run(&writer).await?;
        let reader = SqlitePoolOptions::new()
            .max_connections(READ_CONNECTIONS)
            .connect_with(options.read_only(true))
            .await?;
        Ok(Db {
            writer,
            reader,
            writer_health: Arc::default(),
            templates: Arc::default(),
            next_expiry_check_ms: Arc::new(AtomicI64::new(0)),
            seen_workers: Arc::default(),
        })
    }

    /// Closes both pools.
    pub async fn close(&self) {
        self.reader.close().await;
        self.writer.close().await;
    }

    /// The health check: a read, and a committed write through the writer connection; fails
    /// while the last write transaction failed for a storage reason (disk full, I/O error)
    /// and none has succeeded since, so a full disk shows as unhealthy even when the probe's
    /// tiny in-place write still fits.
    pub async fn ping(&self) -> Result<(), DbError> {
        sqlx::query("SELECT 1").execute(&self.reader).await?;
        let mut tx = self.begin_write().await?;
        let result = async {
            sqlx::query("UPDATE health SET probed_at = ? WHERE id = 1")
                .bind(now_ms())
                .execute(&mut *tx)
                .await?;
            Ok(())
        }
        .await;
        tx.finish_probe(result).await?;
        match self.writer_health.failing() {
            Some(error) => Err(DbError::Unavailable(format!(
                "the database cannot store writes: {error}"
            ))),
            None => Ok(()),
        }
    }

    /// Starts a write transaction on the single writer connection (`BEGIN IMMEDIATE`, so the
    /// write lock is taken up front and never upgraded).
    async fn begin_write(&self) -> Result<WriteTx, DbError> {
        let mut conn = match self.writer.acquire().await {
            Ok(conn) => conn,
            Err(err) => {
                self.writer_health.record_failure(&err);
                return Err(err.into());
            }
        };
        if let Err(err) = sqlx::query("BEGIN IMMEDIATE").execute(&mut *conn).await {
            conn.close_on_drop();
            self.writer_health.record_failure(&err);
            return Err(err.into());
        }
        Ok(WriteTx {
            conn,
            health: Arc::clone(&self.writer_health),
            finished: false,
        })
    }
}

/// First 16 hex digits of the SHA-256 of `text`.
fn short_sha256(text: &str) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(text.as_bytes())[..8]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

fn parse_uuid(text: &str) -> Result<Uuid, DbError> {
    Uuid::from_str(text).map_err(|err| DbError::Corrupt(format!("stored id {text:?}: {err}")))
}

fn batch_state_from_db(text: &str) -> Result<BatchState, DbError> {
    match text {
        "active" => Ok(BatchState::Active),
        "completed" => Ok(BatchState::Completed),
        "cancelled" => Ok(BatchState::Cancelled),
        other => Err(DbError::Corrupt(format!("stored batch state {other:?}"))),
    }
}

/// A job's state as stored. The one text codec of job states, and the one documented mapping
/// to the wire: the database says `leased` where the API says `running` (a job is leased to a
/// worker; its run is running); every other state is spelled the same in both.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum JobState {
    Queued,
    Leased,
    Completed,
    Dead,
    Cancelled,
}

impl JobState {
    /// The stored spelling (the `jobs.state` CHECK constraint lists exactly these).
    pub(crate) fn as_db(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Leased => "leased",
            JobState::Completed => "completed",
            JobState::Dead => "dead",
            JobState::Cancelled => "cancelled",
        }
    }

    /// Decodes a stored state.
    pub(crate) fn from_db(text: &str) -> Result<Self, DbError> {
        Ok(match text {
            "queued" => JobState::Queued,
            "leased" => JobState::Leased,
            "completed" => JobState::Completed,
            "dead" => JobState::Dead,
            "cancelled" => JobState::Cancelled,
            other => return Err(DbError::Corrupt(format!("stored job state {other:?}"))),
        })
    }
}

impl From<JobState> for RunState {
    fn from(state: JobState) -> RunState {
        match state {
            JobState::Queued => RunState::Queued,
            JobState::Leased => RunState::Running,
            JobState::Completed => RunState::Completed,
            JobState::Dead => RunState::Dead,
            JobState::Cancelled => RunState::Cancelled,
        }
    }
}

impl From<RunState> for JobState {
    fn from(state: RunState) -> JobState {
        match state {
            RunState::Queued => JobState::Queued,
            RunState::Running => JobState::Leased,
            RunState::Completed => JobState::Completed,
            RunState::Dead => JobState::Dead,
            RunState::Cancelled => JobState::Cancelled,
        }
    }
}

/// How a lease ended, as stored in `leases.outcome` (NULL while current).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LeaseOutcome {
    Completed,
    Failed,
    Released,
    Expired,
    Superseded,
    Cancelled,
}

impl LeaseOutcome {
    /// Decodes a stored outcome.
    pub(crate) fn from_db(text: &str) -> Result<Self, DbError> {
        Ok(match text {
            "completed" => LeaseOutcome::Completed,
            "failed" => LeaseOutcome::Failed,
            "released" => LeaseOutcome::Released,
            "expired" => LeaseOutcome::Expired,
            "superseded" => LeaseOutcome::Superseded,
            "cancelled" => LeaseOutcome::Cancelled,
            other => return Err(DbError::Corrupt(format!("stored lease outcome {other:?}"))),
        })
    }

    /// The stored spelling.
    pub(crate) fn as_db(self) -> &'static str {
        match self {
            LeaseOutcome::Completed => "completed",
            LeaseOutcome::Failed => "failed",
            LeaseOutcome::Released => "released",
            LeaseOutcome::Expired => "expired",
            LeaseOutcome::Superseded => "superseded",
            LeaseOutcome::Cancelled => "cancelled",
        }
    }
}

fn run_state_from_job(text: &str) -> Result<RunState, DbError> {
    JobState::from_db(text).map(RunState::from)
}

fn backend_from_db(text: &str) -> Result<BackendKind, DbError> {
    match text {
        "cpu" => Ok(BackendKind::Cpu),
        "gpu" => Ok(BackendKind::Gpu),
        other => Err(DbError::Corrupt(format!("stored backend {other:?}"))),
    }
}

fn model_to_db(model: ModelName) -> &'static str {
    model_label(model)
}

fn model_from_db(text: &str) -> Result<ModelName, DbError> {
    match text {
        "linear" => Ok(ModelName::Linear),
        "2fi" => Ok(ModelName::TwoFactorInteraction),
        "quadratic" => Ok(ModelName::Quadratic),
        "none" => Ok(ModelName::None),
        other => Err(DbError::Corrupt(format!("stored model {other:?}"))),
    }
}
