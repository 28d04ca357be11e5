//! All SQL of the server.
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
    apply_factor_values, AnalysisView, BatchState, BatchStatus, BatchSummary, ClaimResponse,
    Completion, FactorValue, JobView, ModelName, RunState, RunView, StateCounts,
    WorkerRegistration, WorkerView,
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

use crate::auth::TokenRole;
use crate::error::AppError;
use crate::metrics::Gauges;
use crate::submit::PlannedBatch;
use crate::tokens::TokenInfo;

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
    /// The factors' spec paths, in factor order.
    paths: Vec<String>,
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

/// The most recent write failure, cleared by the next successful write transaction.
#[derive(Debug, Default)]
struct WriterHealth {
    last_failure: Mutex<Option<String>>,
}

impl WriterHealth {
    fn record_failure(&self, err: &sqlx::Error) {
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
    async fn finish<T>(mut self, result: Result<T, AppError>) -> Result<T, AppError> {
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
            Err(AppError::Database(err)) => {
                self.health.record_failure(&err);
                Err(AppError::Database(err))
            }
            Err(err) if err.is_server_fault() => Err(err),
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
    async fn finish_probe(mut self, result: Result<(), AppError>) -> Result<(), AppError> {
        if let Err(err) = result {
            if let AppError::Database(db) = &err {
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

/// What the analysis needs to know about a batch.
#[derive(Debug, Clone)]
pub struct AnalysisInput {
    /// Batch id.
    pub batch_id: Uuid,
    /// Life cycle state.
    pub state: BatchState,
    /// Factors in column order.
    pub factors: Vec<Factor>,
    /// How the design was built.
    pub design_kind: DesignKind,
    /// Response metric.
    pub response: String,
    /// Model family.
    pub model: ModelName,
    /// Target response, if any.
    pub target: Option<f64>,
    /// Base seed (reused for the optimum search).
    pub base_seed: u64,
    /// Coded settings and metrics of every completed run.
    pub completed: Vec<(Vec<f64>, BTreeMap<String, f64>)>,
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

/// The owner of a batch: `None` if it does not exist, `Some(None)` if it has none (from before
/// access control).
impl Db {
    pub async fn batch_owner(&self, batch_id: Uuid) -> Result<Option<Option<String>>, AppError> {
        let owner: Option<Option<String>> =
            sqlx::query_scalar("SELECT owner FROM batches WHERE id = ?")
                .bind(batch_id.to_string())
                .fetch_optional(&self.reader)
                .await?;
        Ok(owner)
    }
}

/// Result of a completion, failure or release.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JobUpdate {
    /// The job's batch.
    pub batch_id: Uuid,
    /// State of the run afterwards.
    pub status: RunState,
    /// This update finished the batch (its last unfinished job), so the analysis is due.
    pub batch_finished: bool,
    /// A job became claimable again.
    pub requeued: bool,
}

/// Result of a heartbeat that was accepted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeartbeatOutcome {
    /// The worker should stop.
    pub cancel: bool,
    /// Seconds until the lease expires.
    pub lease_expires_in_s: f64,
}

/// The lease named by a worker, looked up together with its job and run.
struct LeaseLookup {
    outcome: Option<String>,
    worker_id: String,
    job_state: String,
    current_token: Option<String>,
    attempts: i64,
    run_id: String,
    batch_id: String,
    has_result: bool,
    response: String,
    /// The batch is still active (not completed or cancelled).
    batch_active: bool,
}

impl Db {
    /// Opens or creates the database at `path` and applies the migrations.
    pub async fn open(path: &Path) -> Result<Self, crate::ServeError> {
        Self::open_with(path, &OpenOptions::default()).await
    }

    /// [`Db::open`] with the server's storage settings.
    pub async fn open_with(path: &Path, settings: &OpenOptions) -> Result<Self, crate::ServeError> {
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
    pub async fn ping(&self) -> Result<(), AppError> {
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
            Some(error) => Err(AppError::Unavailable(format!(
                "the database cannot store writes: {error}"
            ))),
            None => Ok(()),
        }
    }

    /// Starts a write transaction on the single writer connection (`BEGIN IMMEDIATE`, so the
    /// write lock is taken up front and never upgraded).
    async fn begin_write(&self) -> Result<WriteTx, AppError> {
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

    // -----------------------------------------------------------------------------------------
    // Batches
    // -----------------------------------------------------------------------------------------

    /// Stores a validated batch with one run and one queued job per planned run.
    pub async fn insert_batch(&self, plan: &PlannedBatch, owner: &str) -> Result<Uuid, AppError> {
        let mut tx = self.begin_write().await?;
        let result: Result<Uuid, AppError> = async {
            let batch_id = insert_batch_tx(&mut tx, plan, owner).await?;
            Ok(batch_id)
        }
        .await;
        tx.finish(result).await
    }

    /// The most recent batches, newest first.
    /// Only batches of `owner` when given.
    pub async fn list_batches(
        &self,
        limit: u32,
        owner: Option<&str>,
    ) -> Result<Vec<BatchSummary>, AppError> {
        let rows = sqlx::query(&format!(
            "{SUMMARY_SELECT} WHERE (?1 IS NULL OR b.owner = ?1)
             GROUP BY b.id ORDER BY b.created_at DESC, b.rowid DESC LIMIT ?2"
        ))
        .bind(owner)
        .bind(i64::from(limit))
        .fetch_all(&self.reader)
        .await?;
        rows.iter().map(summary_from_row).collect()
    }

    /// Progress of one batch, or `None` if it does not exist.
    pub async fn batch_status(&self, batch_id: Uuid) -> Result<Option<BatchStatus>, AppError> {
        let Some(row) = sqlx::query(&format!("{SUMMARY_SELECT} WHERE b.id = ? GROUP BY b.id"))
            .bind(batch_id.to_string())
            .fetch_optional(&self.reader)
            .await?
        else {
            return Ok(None);
        };
        let summary = summary_from_row(&row)?;
        let extra = sqlx::query(
            "SELECT b.response, b.model,
                    (SELECT AVG(wall_time_s) FROM runs WHERE batch_id = b.id
                                                        AND metrics IS NOT NULL) AS mean_wall,
                    EXISTS (SELECT 1 FROM analyses WHERE batch_id = b.id) AS analysed
             FROM batches b WHERE b.id = ?",
        )
        .bind(batch_id.to_string())
        .fetch_one(&self.reader)
        .await?;
        let mean_wall_time_s: Option<f64> = extra.try_get("mean_wall")?;
        let remaining = summary.counts.queued + summary.counts.running;
        let eta_s = match (mean_wall_time_s, summary.state) {
            (Some(mean), BatchState::Active) if remaining > 0 => {
                Some(mean * remaining as f64 / summary.counts.running.max(1) as f64)
            }
            _ => None,
        };
        Ok(Some(BatchStatus {
            response: extra.try_get("response")?,
            model: model_from_db(extra.try_get("model")?)?,
            mean_wall_time_s,
            eta_s,
            analysis_ready: extra.try_get("analysed")?,
            summary,
        }))
    }

    /// A run's complete experiment spec: stored whole for batches from before templates, else
    /// the batch's template with the run's natural values written at the factor paths.
    async fn run_spec(
        &self,
        batch_id: Uuid,
        stored_spec: &str,
        natural: &str,
    ) -> Result<Value, AppError> {
        if !stored_spec.is_empty() {
            return Ok(serde_json::from_str(stored_spec)?);
        }
        let template = self.template(batch_id).await?;
        let natural: Vec<f64> = serde_json::from_str(natural)?;
        apply_factor_values(
            &template.template,
            template
                .paths
                .iter()
                .map(String::as_str)
                .zip(natural.iter().copied()),
        )
        .map_err(|err| AppError::Internal(format!("stored run spec of batch {batch_id}: {err}")))
    }

    /// The template of a batch, from the cache or the database.
    async fn template(&self, batch_id: Uuid) -> Result<Arc<RunTemplate>, AppError> {
        if let Some(found) = self
            .templates
            .lock()
            .ok()
            .and_then(|cache| cache.get(&batch_id).cloned())
        {
            return Ok(found);
        }
        let row = sqlx::query("SELECT template, request FROM batches WHERE id = ?")
            .bind(batch_id.to_string())
            .fetch_one(&self.reader)
            .await?;
        let template: Option<String> = row.try_get("template")?;
        let template = template.ok_or_else(|| {
            AppError::Internal(format!(
                "batch {batch_id} has neither run specs nor a template"
            ))
        })?;
        let request: repose_api::BatchRequest = serde_json::from_str(row.try_get("request")?)?;
        let loaded = Arc::new(RunTemplate {
            template: serde_json::from_str(&template)?,
            paths: request.factors.into_iter().map(|f| f.path).collect(),
        });
        if let Ok(mut cache) = self.templates.lock() {
            if cache.len() >= TEMPLATE_CACHE {
                cache.clear();
            }
            cache.insert(batch_id, Arc::clone(&loaded));
        }
        Ok(loaded)
    }

    /// Every run of a batch in run order, or `None` if the batch does not exist.
    pub async fn list_runs(
        &self,
        batch_id: Uuid,
    ) -> Result<Option<(Vec<String>, Vec<RunView>)>, AppError> {
        let Some(batch) = sqlx::query("SELECT factors FROM batches WHERE id = ?")
            .bind(batch_id.to_string())
            .fetch_optional(&self.reader)
            .await?
        else {
            return Ok(None);
        };
        let factors: Vec<Factor> = serde_json::from_str(batch.try_get("factors")?)?;
        let names: Vec<String> = factors.into_iter().map(|f| f.name).collect();
        let rows = sqlx::query(
            "SELECT r.id, r.run_index, r.design_row, r.replicate, r.coded, r.natural, r.seed,
                    r.spec, r.engine_version,
                    r.metrics, r.wall_time_s, COALESCE(r.worker_id, j.worker_id) AS worker_id,
                    j.state, j.attempts, j.last_error
             FROM runs r JOIN jobs j ON j.run_id = r.id
             WHERE r.batch_id = ? ORDER BY r.run_index",
        )
        .bind(batch_id.to_string())
        .fetch_all(&self.reader)
        .await?;
        let mut spec_texts = Vec::with_capacity(rows.len());
        for row in &rows {
            let stored: &str = row.try_get("spec")?;
            spec_texts.push(if stored.is_empty() {
                let spec = self
                    .run_spec(batch_id, stored, row.try_get("natural")?)
                    .await?;
                serde_json::to_string(&spec)?
            } else {
                stored.to_owned()
            });
        }
        let runs = rows
            .iter()
            .enumerate()
            .map(|(index, row)| -> Result<RunView, AppError> {
                // Lenient: batches stored before non-finite values were refused hold `null`s
                // here; they read back as NaN (`null` in JSON) instead of failing the request.
                let lenient = |column: &str| -> Result<Vec<f64>, AppError> {
                    let values: Vec<Option<f64>> = serde_json::from_str(row.try_get(column)?)?;
                    Ok(values.into_iter().map(|v| v.unwrap_or(f64::NAN)).collect())
                };
                let coded = lenient("coded")?;
                let natural = lenient("natural")?;
                let factors = names
                    .iter()
                    .zip(coded.iter().zip(&natural))
                    .map(|(name, (&coded, &natural))| FactorValue {
                        name: name.clone(),
                        coded,
                        natural,
                    })
                    .collect();
                let metrics: Option<String> = row.try_get("metrics")?;
                let worker_id: Option<String> = row.try_get("worker_id")?;
                Ok(RunView {
                    id: parse_uuid(row.try_get("id")?)?,
                    run_index: row.try_get::<i64, _>("run_index")? as u32,
                    design_row: row.try_get::<i64, _>("design_row")? as u32,
                    replicate: row.try_get::<i64, _>("replicate")? as u32,
                    factors,
                    seed: row.try_get::<i64, _>("seed")? as u64,
                    status: run_state_from_job(row.try_get("state")?)?,
                    attempts: row.try_get::<i64, _>("attempts")? as u32,
                    metrics: metrics.map(|m| serde_json::from_str(&m)).transpose()?,
                    wall_time_s: row.try_get("wall_time_s")?,
                    worker_id: worker_id.as_deref().map(parse_uuid).transpose()?,
                    last_error: row.try_get("last_error")?,
                    spec_sha256: Some(short_sha256(&spec_texts[index])),
                    engine_version: row.try_get("engine_version")?,
                })
            })
            .collect::<Result<Vec<_>, AppError>>()?;
        Ok(Some((names, runs)))
    }

    /// The stored pictures of a batch's first completed run that has any (run order), by
    /// file name; empty if the batch keeps none.
    pub async fn first_run_pictures(
        &self,
        batch_id: Uuid,
    ) -> Result<BTreeMap<String, String>, AppError> {
        let pictures: Option<String> = sqlx::query_scalar(
            "SELECT pictures FROM runs WHERE batch_id = ? AND pictures IS NOT NULL
             ORDER BY run_index LIMIT 1",
        )
        .bind(batch_id.to_string())
        .fetch_optional(&self.reader)
        .await?;
        Ok(match pictures {
            Some(text) => serde_json::from_str(&text)?,
            None => BTreeMap::new(),
        })
    }

    /// Cancels an active batch on behalf of the user token `caller`: its unfinished jobs will
    /// not run. Returns the state afterwards, or `None` if the batch does not exist. Completed
    /// batches are left alone; a batch owned by another token is [`AppError::Forbidden`].
    pub async fn cancel_batch(
        &self,
        batch_id: Uuid,
        caller: &str,
    ) -> Result<Option<BatchState>, AppError> {
        let mut tx = self.begin_write().await?;
        let result = cancel_batch_in(&mut tx, batch_id, caller).await;
        tx.finish(result).await
    }

    // -----------------------------------------------------------------------------------------
    // Workers and jobs
    // -----------------------------------------------------------------------------------------

    /// Records (or refreshes) a worker on behalf of the worker token `token`. A worker id
    /// registered by another token is [`AppError::Forbidden`]: worker rows belong to the token
    /// that made them.
    pub async fn register_worker(
        &self,
        worker: &WorkerRegistration,
        token: &str,
    ) -> Result<(), AppError> {
        let now = now_ms();
        let mut tx = self.begin_write().await?;
        let result = async {
            let changed = sqlx::query(
                "INSERT INTO workers (id, host, threads, version, registered_at, last_seen_at,
                                      token)
                 VALUES (?, ?, ?, ?, ?, ?, ?)
                 ON CONFLICT (id) DO UPDATE SET host = excluded.host,
                     threads = excluded.threads, version = excluded.version,
                     last_seen_at = excluded.last_seen_at, token = excluded.token
                 WHERE workers.token IS NULL OR workers.token = excluded.token",
            )
            .bind(worker.instance_id.to_string())
            .bind(&worker.host)
            .bind(i64::from(worker.threads))
            .bind(&worker.version)
            .bind(now)
            .bind(now)
            .bind(token)
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if changed == 0 {
                return Err(AppError::Forbidden(format!(
                    "worker {} was registered by another token",
                    worker.instance_id
                )));
            }
            Ok(())
        }
        .await;
        tx.finish(result).await
    }

    /// Leases the oldest available job to `worker_id`, first returning expired leases to the
    /// queue (or marking their jobs dead after `max_attempts`). `Ok(None)`: nothing to do.
    /// Also reports the batches that the expiries finished.
    pub async fn claim(
        &self,
        worker_id: Uuid,
        caller: &str,
        lease: Duration,
        max_attempts: u32,
    ) -> Result<(Option<ClaimResponse>, Vec<Uuid>), AppError> {
        let now = now_ms();
        let mut tx = self.begin_write().await?;
        let result: Result<(Option<ClaimResponse>, Vec<Uuid>), AppError> = async {
            let seen_recently = self
                .seen_workers
                .lock()
                .map(|seen| {
                    seen.get(&worker_id).is_some_and(|(token, at)| {
                        token == caller && now - at < LAST_SEEN_RESOLUTION_MS
                    })
                })
                .unwrap_or(false);
            if !seen_recently {
                let worker_known =
                    sqlx::query("UPDATE workers SET last_seen_at = ? WHERE id = ? AND token = ?")
                        .bind(now)
                        .bind(worker_id.to_string())
                        .bind(caller)
                        .execute(&mut *tx)
                        .await?
                        .rows_affected()
                        == 1;
                if !worker_known {
                    return Err(AppError::invalid(
                        "worker_id",
                        format!(
                            "worker {worker_id} is not registered with this token; \
                             POST /v1/workers/register first"
                        ),
                    ));
                }
                if let Ok(mut seen) = self.seen_workers.lock() {
                    seen.insert(worker_id, (caller.to_owned(), now));
                }
            }
            let next_check = self.next_expiry_check_ms.load(Ordering::Relaxed);
            let finished = if now >= next_check
                && self
                    .next_expiry_check_ms
                    .compare_exchange(
                        next_check,
                        now + EXPIRY_CHECK_INTERVAL_MS,
                        Ordering::Relaxed,
                        Ordering::Relaxed,
                    )
                    .is_ok()
            {
                expire_leases(&mut tx, now, max_attempts).await?
            } else {
                Vec::new()
            };

            let token = Uuid::new_v4();
            let expires_at = now + duration_ms(lease);
            // One round trip: record the lease for the oldest available job, then lease that job
            // (found through its new lease) and return what the worker needs. Plain `?`
            // placeholders, bound in order across both statements.
            let claimed = sqlx::query(
                "INSERT INTO leases (token, job_id, worker_id, attempt, granted_at)
                 SELECT ?, id, ?, attempts + 1, ? FROM jobs
                 WHERE id = (SELECT id FROM jobs WHERE state = 'queued' AND available_at <= ?
                             ORDER BY available_at, rowid LIMIT 1);
                 UPDATE jobs SET state = 'leased', attempts = attempts + 1, lease_token = ?,
                                 lease_expires_at = ?, worker_id = ?, progress = 0, updated_at = ?
                 WHERE id = (SELECT job_id FROM leases WHERE token = ?)
                 RETURNING id, run_id, batch_id, attempts,
                           (SELECT spec FROM runs WHERE runs.id = jobs.run_id) AS spec,
                           (SELECT natural FROM runs WHERE runs.id = jobs.run_id) AS natural,
                           (SELECT seed FROM runs WHERE runs.id = jobs.run_id) AS seed,
                           (SELECT kind FROM batches WHERE batches.id = jobs.batch_id) AS kind,
                           (SELECT keep_pictures FROM batches WHERE batches.id = jobs.batch_id)
                               AS keep_pictures",
            )
            .bind(token.to_string())
            .bind(worker_id.to_string())
            .bind(now)
            .bind(now)
            .bind(token.to_string())
            .bind(expires_at)
            .bind(worker_id.to_string())
            .bind(now)
            .bind(token.to_string())
            .fetch_optional(&mut *tx)
            .await?;
            let Some(claimed) = claimed else {
                return Ok((None, finished));
            };
            let job_id: String = claimed.try_get("id")?;
            let run_id: String = claimed.try_get("run_id")?;
            let attempt: i64 = claimed.try_get("attempts")?;
            let batch_id = parse_uuid(claimed.try_get("batch_id")?)?;
            let spec = self
                .run_spec(
                    batch_id,
                    claimed.try_get("spec")?,
                    claimed.try_get("natural")?,
                )
                .await?;
            Ok((
                Some(ClaimResponse {
                    job_id: parse_uuid(&job_id)?,
                    lease_token: token,
                    lease_expires_in_s: lease.as_secs_f64(),
                    run_id: parse_uuid(&run_id)?,
                    batch_id,
                    kind: claimed.try_get("kind")?,
                    spec,
                    seed: claimed.try_get::<i64, _>("seed")? as u64,
                    attempt: attempt as u32,
                    keep_pictures: claimed.try_get("keep_pictures")?,
                }),
                finished,
            ))
        }
        .await;
        tx.finish(result).await
    }

    /// Returns expired leases to the queue (or marks their jobs dead after `max_attempts`);
    /// the server calls this on a timer so an expired job does not wait for a claim. Returns
    /// the batches this finished.
    pub async fn reclaim_expired(&self, max_attempts: u32) -> Result<Vec<Uuid>, AppError> {
        let now = now_ms();
        let mut tx = self.begin_write().await?;
        let result = expire_leases(&mut tx, now, max_attempts).await;
        tx.finish(result).await
    }

    /// Renews a current lease and records progress. A lease that ended because the batch was
    /// cancelled or another lease delivered the result answers `cancel`; other stale leases
    /// are a conflict.
    pub async fn heartbeat(
        &self,
        job_id: Uuid,
        token: Uuid,
        progress: f64,
        lease: Duration,
    ) -> Result<HeartbeatOutcome, AppError> {
        let mut tx = self.begin_write().await?;
        let result = heartbeat_in(&mut tx, job_id, token, progress, lease).await;
        tx.finish(result).await
    }

    /// Stores a result. Accepted from the current lease, and from an *expired* earlier lease
    /// as long as the run has no result yet (a late DEM result is too expensive to discard);
    /// any other lease, or a second result, is a conflict and changes nothing.
    pub async fn complete(
        &self,
        job_id: Uuid,
        token: Uuid,
        completion: &Completion,
    ) -> Result<JobUpdate, AppError> {
        let mut tx = self.begin_write().await?;
        let result = complete_in(&mut tx, job_id, token, completion).await;
        tx.finish(result).await
    }

    /// Records a failed attempt: the job is retried after `backoff × 2^(attempt-1)`, or marked
    /// dead once it has used `max_attempts` leases.
    pub async fn fail(
        &self,
        job_id: Uuid,
        token: Uuid,
        error: &str,
        max_attempts: u32,
        backoff: Duration,
    ) -> Result<JobUpdate, AppError> {
        let mut tx = self.begin_write().await?;
        let result = fail_in(&mut tx, job_id, token, error, max_attempts, backoff).await;
        tx.finish(result).await
    }

    /// Gives a job back to the queue at once without counting the attempt.
    pub async fn release(&self, job_id: Uuid, token: Uuid) -> Result<JobUpdate, AppError> {
        let mut tx = self.begin_write().await?;
        let result = release_in(&mut tx, job_id, token).await;
        tx.finish(result).await
    }

    /// Registered workers, most recently seen first, with the number of leases each holds.
    pub async fn list_workers(&self, limit: u32) -> Result<Vec<WorkerView>, AppError> {
        let rows = sqlx::query(
            "SELECT w.id, w.host, w.threads, w.version, w.registered_at, w.last_seen_at,
                    (SELECT COUNT(*) FROM jobs j
                     WHERE j.worker_id = w.id AND j.state = 'leased') AS running_jobs
             FROM workers w ORDER BY w.last_seen_at DESC, w.rowid DESC LIMIT ?",
        )
        .bind(i64::from(limit))
        .fetch_all(&self.reader)
        .await?;
        rows.iter()
            .map(|row| {
                Ok(WorkerView {
                    id: parse_uuid(row.try_get("id")?)?,
                    host: row.try_get("host")?,
                    threads: row.try_get::<i64, _>("threads")? as u32,
                    version: row.try_get("version")?,
                    registered_at_ms: row.try_get("registered_at")?,
                    last_seen_at_ms: row.try_get("last_seen_at")?,
                    running_jobs: row.try_get::<i64, _>("running_jobs")? as u64,
                })
            })
            .collect()
    }

    /// Jobs, most recently changed first, optionally only those in `status` or of `batch_id`,
    /// and only those `scope` may see.
    pub async fn list_jobs(
        &self,
        status: Option<RunState>,
        batch_id: Option<Uuid>,
        limit: u32,
        scope: ReadScope<'_>,
    ) -> Result<Vec<JobView>, AppError> {
        let (owner, worker_token) = match scope {
            ReadScope::All => (None, None),
            ReadScope::User(name) => (Some(name), None),
            ReadScope::Worker(name) => (None, Some(name)),
        };
        let rows = sqlx::query(
            "SELECT j.id, j.run_id, j.batch_id, r.run_index, j.state, j.attempts, j.worker_id,
                    j.progress, j.lease_expires_at, j.available_at, j.last_error, j.updated_at
             FROM jobs j JOIN runs r ON r.id = j.run_id
             WHERE (?1 IS NULL OR j.state = ?1) AND (?2 IS NULL OR j.batch_id = ?2)
               AND (?4 IS NULL OR j.batch_id IN (SELECT id FROM batches WHERE owner = ?4))
               AND (?5 IS NULL OR j.worker_id IN (SELECT id FROM workers WHERE token = ?5))
             ORDER BY j.updated_at DESC, j.rowid DESC LIMIT ?3",
        )
        .bind(status.map(job_state_to_db))
        .bind(batch_id.map(|id| id.to_string()))
        .bind(i64::from(limit))
        .bind(owner)
        .bind(worker_token)
        .fetch_all(&self.reader)
        .await?;
        rows.iter()
            .map(|row| {
                let worker_id: Option<String> = row.try_get("worker_id")?;
                Ok(JobView {
                    id: parse_uuid(row.try_get("id")?)?,
                    run_id: parse_uuid(row.try_get("run_id")?)?,
                    batch_id: parse_uuid(row.try_get("batch_id")?)?,
                    run_index: row.try_get::<i64, _>("run_index")? as u32,
                    status: run_state_from_job(row.try_get("state")?)?,
                    attempts: row.try_get::<i64, _>("attempts")? as u32,
                    worker_id: worker_id.as_deref().map(parse_uuid).transpose()?,
                    progress: row.try_get("progress")?,
                    lease_expires_at_ms: row.try_get("lease_expires_at")?,
                    available_at_ms: row.try_get("available_at")?,
                    last_error: row.try_get("last_error")?,
                    updated_at_ms: row.try_get("updated_at")?,
                })
            })
            .collect()
    }

    /// The database-derived gauges of `GET /metrics`; workers count as active when seen
    /// within `lease`.
    pub async fn gauges(&self, lease: Duration) -> Result<Gauges, AppError> {
        let count_by = |sql: &'static str| async move {
            let rows = sqlx::query(sql).fetch_all(&self.reader).await?;
            rows.iter()
                .map(|row| Ok((row.try_get::<String, _>(0)?, row.try_get::<i64, _>(1)?)))
                .collect::<Result<Vec<_>, AppError>>()
        };
        let mut jobs = count_by("SELECT state, COUNT(*) FROM jobs GROUP BY state").await?;
        let mut batches = count_by("SELECT state, COUNT(*) FROM batches GROUP BY state").await?;
        // Every state appears, with 0 when empty, so series do not vanish.
        for (all, found) in [
            (
                &["queued", "leased", "completed", "dead", "cancelled"][..],
                &mut jobs,
            ),
            (&["active", "completed", "cancelled"][..], &mut batches),
        ] {
            for state in all {
                if !found.iter().any(|(s, _)| s == state) {
                    found.push(((*state).to_owned(), 0));
                }
            }
            found.sort();
        }
        let workers = sqlx::query(
            "SELECT COUNT(*) AS registered, COALESCE(SUM(last_seen_at >= ?), 0) AS active
             FROM workers",
        )
        .bind(now_ms() - duration_ms(lease))
        .fetch_one(&self.reader)
        .await?;
        Ok(Gauges {
            jobs,
            batches,
            workers_active: workers.try_get("active")?,
            workers_registered: workers.try_get("registered")?,
        })
    }

    // -----------------------------------------------------------------------------------------
    // Tokens
    // -----------------------------------------------------------------------------------------

    /// Stores a new token; `false` (and nothing stored) when the name is taken.
    pub async fn insert_token(
        &self,
        name: &str,
        role: TokenRole,
        hash: &str,
    ) -> Result<bool, sqlx::Error> {
        let inserted = sqlx::query(
            "INSERT INTO tokens (id, name, role, hash, created_at) VALUES (?, ?, ?, ?, ?)
             ON CONFLICT (name) DO NOTHING",
        )
        .bind(Uuid::new_v4().to_string())
        .bind(name)
        .bind(role.as_str())
        .bind(hash)
        .bind(now_ms())
        .execute(&self.writer)
        .await?
        .rows_affected();
        Ok(inserted == 1)
    }

    /// Every token, oldest first (revoked ones included).
    pub async fn list_tokens(&self) -> Result<Vec<TokenInfo>, sqlx::Error> {
        let rows = sqlx::query(
            "SELECT name, role, created_at, revoked_at FROM tokens ORDER BY created_at, rowid",
        )
        .fetch_all(&self.reader)
        .await?;
        rows.iter().map(token_from_row).collect()
    }

    /// The token with SHA-256 `hash`, revoked or not.
    pub async fn find_token(&self, hash: &str) -> Result<Option<TokenInfo>, sqlx::Error> {
        let row =
            sqlx::query("SELECT name, role, created_at, revoked_at FROM tokens WHERE hash = ?")
                .bind(hash)
                .fetch_optional(&self.reader)
                .await?;
        row.as_ref().map(token_from_row).transpose()
    }

    /// Revokes the token `name` (a no-op if it already is); `None` if there is no such token.
    pub async fn revoke_token(&self, name: &str) -> Result<Option<TokenInfo>, sqlx::Error> {
        let row = sqlx::query(
            "UPDATE tokens SET revoked_at = COALESCE(revoked_at, ?) WHERE name = ?
             RETURNING name, role, created_at, revoked_at",
        )
        .bind(now_ms())
        .bind(name)
        .fetch_optional(&self.writer)
        .await?;
        row.as_ref().map(token_from_row).transpose()
    }

    // -----------------------------------------------------------------------------------------
    // Analyses
    // -----------------------------------------------------------------------------------------

    /// The inputs of a batch's analysis, or `None` if the batch does not exist.
    pub async fn analysis_input(&self, batch_id: Uuid) -> Result<Option<AnalysisInput>, AppError> {
        let Some(batch) = sqlx::query(
            "SELECT state, factors, design_kind, response, model, target, base_seed
             FROM batches WHERE id = ?",
        )
        .bind(batch_id.to_string())
        .fetch_optional(&self.reader)
        .await?
        else {
            return Ok(None);
        };
        let rows = sqlx::query(
            "SELECT coded, metrics FROM runs
             WHERE batch_id = ? AND metrics IS NOT NULL ORDER BY run_index",
        )
        .bind(batch_id.to_string())
        .fetch_all(&self.reader)
        .await?;
        let completed = rows
            .iter()
            .map(
                |row| -> Result<(Vec<f64>, BTreeMap<String, f64>), AppError> {
                    let coded: Vec<f64> = serde_json::from_str(row.try_get("coded")?)?;
                    let metrics: BTreeMap<String, f64> =
                        serde_json::from_str(row.try_get("metrics")?)?;
                    Ok((coded, metrics))
                },
            )
            .collect::<Result<Vec<_>, AppError>>()?;
        Ok(Some(AnalysisInput {
            batch_id,
            state: batch_state_from_db(batch.try_get("state")?)?,
            factors: serde_json::from_str(batch.try_get("factors")?)?,
            design_kind: serde_json::from_str(batch.try_get("design_kind")?)?,
            response: batch.try_get("response")?,
            model: model_from_db(batch.try_get("model")?)?,
            target: batch.try_get("target")?,
            base_seed: batch.try_get::<i64, _>("base_seed")? as u64,
            completed,
        }))
    }

    /// The stored analysis of a batch, if computed.
    pub async fn analysis(&self, batch_id: Uuid) -> Result<Option<AnalysisView>, AppError> {
        let stored: Option<String> =
            sqlx::query_scalar("SELECT result FROM analyses WHERE batch_id = ?")
                .bind(batch_id.to_string())
                .fetch_optional(&self.reader)
                .await?;
        Ok(stored.map(|s| serde_json::from_str(&s)).transpose()?)
    }

    /// Stores an analysis unless one exists, and returns the stored one: whoever computed
    /// first wins, so every reader sees the same result.
    pub async fn store_analysis(&self, analysis: &AnalysisView) -> Result<AnalysisView, AppError> {
        let mut tx = self.begin_write().await?;
        let result: Result<AnalysisView, AppError> = async {
            sqlx::query(
                "INSERT INTO analyses (batch_id, computed_at, result) VALUES (?, ?, ?)
                 ON CONFLICT (batch_id) DO NOTHING",
            )
            .bind(analysis.batch_id.to_string())
            .bind(analysis.computed_at_ms)
            .bind(serde_json::to_string(analysis)?)
            .execute(&mut *tx)
            .await?;
            let stored: String =
                sqlx::query_scalar("SELECT result FROM analyses WHERE batch_id = ?")
                    .bind(analysis.batch_id.to_string())
                    .fetch_one(&mut *tx)
                    .await?;
            Ok(serde_json::from_str(&stored)?)
        }
        .await;
        tx.finish(result).await
    }
}

impl LeaseLookup {
    fn is_current(&self, token: Uuid) -> bool {
        self.job_state == "leased"
            && self.outcome.is_none()
            && self.current_token.as_deref() == Some(token.to_string().as_str())
    }

    fn stale_conflict(&self) -> AppError {
        let why = match self.outcome.as_deref() {
            Some("completed") => "this lease already delivered its result".to_owned(),
            Some("superseded") => "the run already has a result".to_owned(),
            Some("cancelled") => "the batch was cancelled".to_owned(),
            Some("expired") if self.has_result => {
                "the lease expired and the run already has a result".to_owned()
            }
            Some("expired") if !self.batch_active => {
                "the lease expired and the batch has finished without this run".to_owned()
            }
            Some(outcome) => format!("the lease is no longer valid ({outcome})"),
            None => "the lease is no longer valid".to_owned(),
        };
        AppError::Conflict(why)
    }
}

/// Inserts a batch, its runs and their jobs inside the caller's transaction.
async fn insert_batch_tx(
    tx: &mut WriteTx,
    plan: &PlannedBatch,
    owner: &str,
) -> Result<Uuid, AppError> {
    let batch_id = Uuid::new_v4();
    let now = now_ms();
    let request = &plan.request;
    sqlx::query(
        "INSERT INTO batches (id, name, kind, request, factors, design_kind, response, model,
                                  target, base_seed, state, created_at, owner, keep_pictures,
                                  template)
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 'active', ?, ?, ?, ?)",
    )
    .bind(batch_id.to_string())
    .bind(&request.name)
    .bind(&request.experiment.kind)
    .bind(serde_json::to_string(request)?)
    .bind(serde_json::to_string(&plan.factors)?)
    .bind(serde_json::to_string(&plan.design_kind)?)
    .bind(&request.response)
    .bind(model_to_db(request.model))
    .bind(request.target)
    .bind(plan.base_seed as i64)
    .bind(now)
    .bind(owner)
    .bind(request.keep_pictures)
    .bind(serde_json::to_string(&plan.template)?)
    .execute(&mut **tx)
    .await?;
    // Multi-row inserts: a 10,000-run batch is 100 statements, not 20,000, and holds the
    // writer briefly. Runs store no spec of their own ('': the batch's template plus `natural`).
    let batch_text = batch_id.to_string();
    for chunk in plan.runs.chunks(INSERT_CHUNK) {
        let run_ids: Vec<String> = chunk.iter().map(|_| Uuid::new_v4().to_string()).collect();
        let mut runs = sqlx::QueryBuilder::<Sqlite>::new(
            "INSERT INTO runs (id, batch_id, run_index, design_row, replicate, coded, natural,
                               seed, spec) ",
        );
        let mut encoded = Vec::with_capacity(chunk.len());
        for run in chunk {
            encoded.push((
                serde_json::to_string(&run.coded)?,
                serde_json::to_string(&run.natural)?,
            ));
        }
        runs.push_values(
            chunk.iter().zip(&run_ids).zip(&encoded),
            |mut row, ((run, run_id), (coded, natural))| {
                row.push_bind(run_id)
                    .push_bind(&batch_text)
                    .push_bind(run.run_index as i64)
                    .push_bind(run.design_row as i64)
                    .push_bind(run.replicate as i64)
                    .push_bind(coded)
                    .push_bind(natural)
                    .push_bind(run.seed as i64)
                    .push_bind("");
            },
        );
        runs.build().execute(&mut **tx).await?;
        let mut jobs = sqlx::QueryBuilder::<Sqlite>::new(
            "INSERT INTO jobs (id, run_id, batch_id, state, attempts, available_at, updated_at) ",
        );
        jobs.push_values(&run_ids, |mut row, run_id| {
            row.push_bind(Uuid::new_v4().to_string())
                .push_bind(run_id)
                .push_bind(&batch_text)
                .push_bind("queued")
                .push_bind(0_i64)
                .push_bind(now)
                .push_bind(now);
        });
        jobs.build().execute(&mut **tx).await?;
    }
    Ok(batch_id)
}

/// Finds the lease `token` of job `job_id`: 404 if the job does not exist, 409 if the token was
/// never issued for it.
async fn lookup_lease(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
) -> Result<LeaseLookup, AppError> {
    let row = sqlx::query(
        "SELECT l.outcome, l.worker_id, j.state, j.lease_token, j.attempts, j.run_id, j.batch_id,
                r.metrics IS NOT NULL AS has_result, b.response, b.state AS batch_state
         FROM leases l
         JOIN jobs j ON j.id = l.job_id
         JOIN runs r ON r.id = j.run_id
         JOIN batches b ON b.id = j.batch_id
         WHERE l.token = ? AND l.job_id = ?",
    )
    .bind(token.to_string())
    .bind(job_id.to_string())
    .fetch_optional(&mut **tx)
    .await?;
    let Some(row) = row else {
        let job_exists = sqlx::query("SELECT 1 FROM jobs WHERE id = ?")
            .bind(job_id.to_string())
            .fetch_optional(&mut **tx)
            .await?
            .is_some();
        return Err(if job_exists {
            AppError::Conflict(format!("lease {token} was not issued for job {job_id}"))
        } else {
            AppError::NotFound(format!("job {job_id} not found"))
        });
    };
    Ok(LeaseLookup {
        outcome: row.try_get("outcome")?,
        worker_id: row.try_get("worker_id")?,
        job_state: row.try_get("state")?,
        current_token: row.try_get("lease_token")?,
        attempts: row.try_get("attempts")?,
        run_id: row.try_get("run_id")?,
        batch_id: row.try_get("batch_id")?,
        has_result: row.try_get("has_result")?,
        response: row.try_get("response")?,
        batch_active: row.try_get::<&str, _>("batch_state")? == "active",
    })
}

/// Ends every lease past its expiry: the job is queued again, or dead when it has used up its
/// attempts. Returns the batches this finished.
async fn expire_leases(
    tx: &mut WriteTx,
    now: i64,
    max_attempts: u32,
) -> Result<Vec<Uuid>, AppError> {
    sqlx::query(
        "UPDATE leases SET outcome = 'expired', ended_at = ?
         WHERE token IN (SELECT lease_token FROM jobs
                         WHERE state = 'leased' AND lease_expires_at <= ?)",
    )
    .bind(now)
    .bind(now)
    .execute(&mut **tx)
    .await?;
    let expired = sqlx::query(
        "UPDATE jobs SET state = CASE WHEN attempts >= ? THEN 'dead' ELSE 'queued' END,
                         last_error = 'lease expired (attempt ' || attempts || ')',
                         lease_token = NULL, lease_expires_at = NULL, worker_id = NULL,
                         available_at = ?, updated_at = ?
         WHERE state = 'leased' AND lease_expires_at <= ?
         RETURNING batch_id, state",
    )
    .bind(i64::from(max_attempts))
    .bind(now)
    .bind(now)
    .bind(now)
    .fetch_all(&mut **tx)
    .await?;
    let mut finished = Vec::new();
    for row in &expired {
        let state: String = row.try_get("state")?;
        let batch_id: String = row.try_get("batch_id")?;
        if state == "dead" && finish_batch_if_done(tx, &batch_id, now).await? {
            finished.push(parse_uuid(&batch_id)?);
        }
    }
    Ok(finished)
}

/// Marks an active batch completed when none of its jobs is queued or leased; true if this call
/// did it (so exactly one caller triggers the analysis).
async fn finish_batch_if_done(
    tx: &mut WriteTx,
    batch_id: &str,
    now: i64,
) -> Result<bool, AppError> {
    let done = sqlx::query(
        "UPDATE batches SET state = 'completed', finished_at = ?
         WHERE id = ? AND state = 'active'
           AND NOT EXISTS (SELECT 1 FROM jobs WHERE batch_id = ? AND state IN ('queued', 'leased'))",
    )
    .bind(now)
    .bind(batch_id)
    .bind(batch_id)
    .execute(&mut **tx)
    .await?
    .rows_affected();
    Ok(done == 1)
}

const SUMMARY_SELECT: &str = "SELECT b.id, b.name, b.kind, b.state, b.created_at, b.owner,
        COALESCE(SUM(j.state = 'queued'), 0) AS queued,
        COALESCE(SUM(j.state = 'leased'), 0) AS running,
        COALESCE(SUM(j.state = 'completed'), 0) AS completed,
        COALESCE(SUM(j.state = 'dead'), 0) AS dead,
        COALESCE(SUM(j.state = 'cancelled'), 0) AS cancelled
    FROM batches b LEFT JOIN jobs j ON j.batch_id = b.id";

fn summary_from_row(row: &SqliteRow) -> Result<BatchSummary, AppError> {
    let count = |name: &str| -> Result<u64, AppError> { Ok(row.try_get::<i64, _>(name)? as u64) };
    let counts = StateCounts {
        queued: count("queued")?,
        running: count("running")?,
        completed: count("completed")?,
        dead: count("dead")?,
        cancelled: count("cancelled")?,
    };
    let percent_done = if counts.total() == 0 {
        100.0
    } else {
        100.0 * counts.finished() as f64 / counts.total() as f64
    };
    Ok(BatchSummary {
        id: parse_uuid(row.try_get("id")?)?,
        name: row.try_get("name")?,
        kind: row.try_get("kind")?,
        state: batch_state_from_db(row.try_get("state")?)?,
        created_at_ms: row.try_get("created_at")?,
        counts,
        percent_done,
        owner: row.try_get("owner")?,
    })
}

fn token_from_row(row: &SqliteRow) -> Result<TokenInfo, sqlx::Error> {
    let role: String = row.try_get("role")?;
    Ok(TokenInfo {
        name: row.try_get("name")?,
        role: role
            .parse()
            .map_err(|err| sqlx::Error::Decode(Box::new(err)))?,
        created_at_ms: row.try_get("created_at")?,
        revoked_at_ms: row.try_get("revoked_at")?,
    })
}

/// First 16 hex digits of the SHA-256 of `text`.
fn short_sha256(text: &str) -> String {
    use sha2::{Digest, Sha256};
    Sha256::digest(text.as_bytes())[..8]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

fn parse_uuid(text: &str) -> Result<Uuid, AppError> {
    Uuid::from_str(text).map_err(|err| AppError::Internal(format!("stored id {text:?}: {err}")))
}

fn batch_state_from_db(text: &str) -> Result<BatchState, AppError> {
    match text {
        "active" => Ok(BatchState::Active),
        "completed" => Ok(BatchState::Completed),
        "cancelled" => Ok(BatchState::Cancelled),
        other => Err(AppError::Internal(format!("stored batch state {other:?}"))),
    }
}

fn job_state_to_db(state: RunState) -> &'static str {
    match state {
        RunState::Queued => "queued",
        RunState::Running => "leased",
        RunState::Completed => "completed",
        RunState::Dead => "dead",
        RunState::Cancelled => "cancelled",
    }
}

fn run_state_from_job(text: &str) -> Result<RunState, AppError> {
    match text {
        "queued" => Ok(RunState::Queued),
        "leased" => Ok(RunState::Running),
        "completed" => Ok(RunState::Completed),
        "dead" => Ok(RunState::Dead),
        "cancelled" => Ok(RunState::Cancelled),
        other => Err(AppError::Internal(format!("stored job state {other:?}"))),
    }
}

fn model_to_db(model: ModelName) -> &'static str {
    crate::submit::model_label(model)
}

fn model_from_db(text: &str) -> Result<ModelName, AppError> {
    match text {
        "linear" => Ok(ModelName::Linear),
        "2fi" => Ok(ModelName::TwoFactorInteraction),
        "quadratic" => Ok(ModelName::Quadratic),
        "none" => Ok(ModelName::None),
        other => Err(AppError::Internal(format!("stored model {other:?}"))),
    }
}

/// A stored campaign.
#[derive(Debug, Clone)]
pub struct CampaignRecord {
    pub id: Uuid,
    pub name: String,
    pub owner: Option<String>,
    pub status: String,
    pub stage: String,
    /// The `repose_campaign::Campaign` document.
    pub state: String,
    pub batches_issued: i64,
    pub created_at_ms: i64,
    pub updated_at_ms: i64,
    /// Batch ids in issue order.
    pub batch_ids: Vec<Uuid>,
}

/// What a campaign advance writes.
#[derive(Debug)]
pub struct CampaignUpdate<'a> {
    pub status: &'a str,
    pub stage: &'a str,
    pub state: String,
    /// The next batch to issue, if any.
    pub next: Option<&'a PlannedBatch>,
}

// Campaigns: the chain of batches is written here; decisions are made by `repose-campaign`.
impl Db {
    /// Stores a new campaign with its first batch, in one transaction; returns the batch id.
    pub async fn insert_campaign(
        &self,
        id: Uuid,
        name: &str,
        owner: &str,
        update: CampaignUpdate<'_>,
    ) -> Result<Uuid, AppError> {
        let now = now_ms();
        let first = update
            .next
            .ok_or_else(|| AppError::Internal("a campaign starts with a batch".into()))?;
        let mut tx = self.begin_write().await?;
        let result: Result<Uuid, AppError> = async {
            sqlx::query(
                "INSERT INTO campaigns (id, name, owner, status, stage, state, batches_issued,
                                        created_at, updated_at)
                 VALUES (?, ?, ?, ?, ?, ?, 1, ?, ?)",
            )
            .bind(id.to_string())
            .bind(name)
            .bind(owner)
            .bind(update.status)
            .bind(update.stage)
            .bind(&update.state)
            .bind(now)
            .bind(now)
            .execute(&mut *tx)
            .await?;
            let batch_id = insert_batch_tx(&mut tx, first, owner).await?;
            link_batch(&mut tx, batch_id, id, 0).await?;
            Ok(batch_id)
        }
        .await;
        tx.finish(result).await
    }

    /// Records a campaign step if nobody advanced it since `issued_before` batches were issued;
    /// `Ok(None)` when someone did (nothing written). Returns the new batch's id, if one.
    pub async fn advance_campaign(
        &self,
        id: Uuid,
        issued_before: i64,
        owner: Option<&str>,
        update: CampaignUpdate<'_>,
    ) -> Result<Option<Option<Uuid>>, AppError> {
        let now = now_ms();
        let mut tx = self.begin_write().await?;
        let result: Result<Option<Option<Uuid>>, AppError> = async {
            let issued_after = issued_before + i64::from(update.next.is_some());
            let changed = sqlx::query(
                "UPDATE campaigns SET status = ?, stage = ?, state = ?, batches_issued = ?,
                                      updated_at = ?
                 WHERE id = ? AND batches_issued = ?",
            )
            .bind(update.status)
            .bind(update.stage)
            .bind(&update.state)
            .bind(issued_after)
            .bind(now)
            .bind(id.to_string())
            .bind(issued_before)
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if changed != 1 {
                return Ok(None);
            }
            let batch_id = match update.next {
                Some(plan) => {
                    let batch_id = insert_batch_tx(&mut tx, plan, owner.unwrap_or("")).await?;
                    link_batch(&mut tx, batch_id, id, issued_before).await?;
                    Some(batch_id)
                }
                None => None,
            };
            Ok(Some(batch_id))
        }
        .await;
        tx.finish(result).await
    }

    /// The campaign a batch belongs to and the batch's position in it.
    pub async fn campaign_of_batch(&self, batch_id: Uuid) -> Result<Option<(Uuid, i64)>, AppError> {
        let row = sqlx::query(
            "SELECT campaign_id, campaign_index FROM batches
             WHERE id = ? AND campaign_id IS NOT NULL",
        )
        .bind(batch_id.to_string())
        .fetch_optional(&self.reader)
        .await?;
        row.map(|row| -> Result<(Uuid, i64), AppError> {
            Ok((
                parse_uuid(&row.try_get::<String, _>("campaign_id")?)?,
                row.try_get("campaign_index")?,
            ))
        })
        .transpose()
    }

    /// One campaign with its batch ids.
    pub async fn campaign(&self, id: Uuid) -> Result<Option<CampaignRecord>, AppError> {
        let Some(row) = sqlx::query("SELECT * FROM campaigns WHERE id = ?")
            .bind(id.to_string())
            .fetch_optional(&self.reader)
            .await?
        else {
            return Ok(None);
        };
        let batch_rows =
            sqlx::query("SELECT id FROM batches WHERE campaign_id = ? ORDER BY campaign_index")
                .bind(id.to_string())
                .fetch_all(&self.reader)
                .await?;
        let batch_ids = batch_rows
            .iter()
            .map(|r| parse_uuid(&r.try_get::<String, _>("id")?))
            .collect::<Result<Vec<_>, AppError>>()?;
        Ok(Some(campaign_from_row(&row, batch_ids)?))
    }

    /// The newest campaigns (without their batch ids), newest first; only `owner`'s if given.
    pub async fn list_campaigns(
        &self,
        limit: u32,
        owner: Option<&str>,
    ) -> Result<Vec<CampaignRecord>, AppError> {
        let rows = sqlx::query(
            "SELECT * FROM campaigns WHERE (?1 IS NULL OR owner = ?1)
             ORDER BY created_at DESC LIMIT ?2",
        )
        .bind(owner)
        .bind(i64::from(limit))
        .fetch_all(&self.reader)
        .await?;
        rows.iter()
            .map(|row| campaign_from_row(row, Vec::new()))
            .collect()
    }

    /// Ids of the campaigns still running (resumed at start-up).
    pub async fn running_campaigns(&self) -> Result<Vec<Uuid>, AppError> {
        let rows = sqlx::query("SELECT id FROM campaigns WHERE status = 'running'")
            .fetch_all(&self.reader)
            .await?;
        rows.iter()
            .map(|r| parse_uuid(&r.try_get::<String, _>("id")?))
            .collect()
    }
}

async fn link_batch(
    tx: &mut WriteTx,
    batch_id: Uuid,
    campaign_id: Uuid,
    index: i64,
) -> Result<(), AppError> {
    sqlx::query("UPDATE batches SET campaign_id = ?, campaign_index = ? WHERE id = ?")
        .bind(campaign_id.to_string())
        .bind(index)
        .bind(batch_id.to_string())
        .execute(&mut **tx)
        .await?;
    Ok(())
}

fn campaign_from_row(row: &SqliteRow, batch_ids: Vec<Uuid>) -> Result<CampaignRecord, AppError> {
    Ok(CampaignRecord {
        id: parse_uuid(&row.try_get::<String, _>("id")?)?,
        name: row.try_get("name")?,
        owner: row.try_get("owner")?,
        status: row.try_get("status")?,
        stage: row.try_get("stage")?,
        state: row.try_get("state")?,
        batches_issued: row.try_get("batches_issued")?,
        created_at_ms: row.try_get("created_at")?,
        updated_at_ms: row.try_get("updated_at")?,
        batch_ids,
    })
}

// Write transactions' bodies; each runs inside the caller's `WriteTx`.

async fn cancel_batch_in(
    tx: &mut WriteTx,
    batch_id: Uuid,
    caller: &str,
) -> Result<Option<BatchState>, AppError> {
    let now = now_ms();
    let id = batch_id.to_string();
    let Some(row) = sqlx::query("SELECT state, owner FROM batches WHERE id = ?")
        .bind(&id)
        .fetch_optional(&mut **tx)
        .await?
    else {
        return Ok(None);
    };
    let owner: Option<String> = row.try_get("owner")?;
    if let Some(owner) = owner.filter(|owner| owner != caller) {
        return Err(AppError::Forbidden(format!(
            "batch {batch_id} belongs to `{owner}`; only its owner may cancel it"
        )));
    }
    let state = batch_state_from_db(row.try_get("state")?)?;
    if state != BatchState::Active {
        return Ok(Some(state));
    }
    sqlx::query(
        "UPDATE leases SET outcome = 'cancelled', ended_at = ?
         WHERE token IN (SELECT lease_token FROM jobs WHERE batch_id = ? AND state = 'leased')",
    )
    .bind(now)
    .bind(&id)
    .execute(&mut **tx)
    .await?;
    sqlx::query(
        "UPDATE jobs SET state = 'cancelled', lease_token = NULL, lease_expires_at = NULL,
                         updated_at = ?
         WHERE batch_id = ? AND state IN ('queued', 'leased')",
    )
    .bind(now)
    .bind(&id)
    .execute(&mut **tx)
    .await?;
    sqlx::query("UPDATE batches SET state = 'cancelled', finished_at = ? WHERE id = ?")
        .bind(now)
        .bind(&id)
        .execute(&mut **tx)
        .await?;

    Ok(Some(BatchState::Cancelled))
}

async fn heartbeat_in(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
    progress: f64,
    lease: Duration,
) -> Result<HeartbeatOutcome, AppError> {
    let now = now_ms();
    let found = lookup_lease(tx, job_id, token).await?;
    if found.is_current(token) {
        sqlx::query(
            "UPDATE jobs SET lease_expires_at = ?, progress = ?, updated_at = ? WHERE id = ?",
        )
        .bind(now + duration_ms(lease))
        .bind(progress.clamp(0.0, 1.0))
        .bind(now)
        .bind(job_id.to_string())
        .execute(&mut **tx)
        .await?;
        sqlx::query("UPDATE workers SET last_seen_at = ? WHERE id = ?")
            .bind(now)
            .bind(&found.worker_id)
            .execute(&mut **tx)
            .await?;
        return Ok(HeartbeatOutcome {
            cancel: false,
            lease_expires_in_s: lease.as_secs_f64(),
        });
    }
    match found.outcome.as_deref() {
        Some("cancelled" | "superseded") => Ok(HeartbeatOutcome {
            cancel: true,
            lease_expires_in_s: 0.0,
        }),
        _ => Err(found.stale_conflict()),
    }
}

async fn complete_in(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
    completion: &Completion,
) -> Result<JobUpdate, AppError> {
    let now = now_ms();
    let found = lookup_lease(tx, job_id, token).await?;
    let current = found.is_current(token);
    // A late result is accepted only while its batch is still active: once the batch has
    // finished, its analysis may be stored and a campaign may have moved on, and neither may
    // silently disagree with the counts.
    let late = found.outcome.as_deref() == Some("expired")
        && !found.has_result
        && found.batch_active
        && matches!(found.job_state.as_str(), "queued" | "leased" | "dead");
    if !(current || late) {
        return Err(found.stale_conflict());
    }
    match completion.metrics.get(&found.response) {
        Some(value) if value.is_finite() => {}
        _ => {
            return Err(AppError::invalid(
                format!("metrics.{}", found.response),
                format!(
                    "the batch's response metric `{}` is missing or not finite",
                    found.response
                ),
            ))
        }
    }
    if !(completion.wall_time_s.is_finite() && completion.wall_time_s >= 0.0) {
        return Err(AppError::invalid(
            "wall_time_s",
            "must be a non-negative number",
        ));
    }
    let stored = sqlx::query(
        "UPDATE runs SET metrics = ?, details = ?, wall_time_s = ?, worker_id = ?,
                         completed_at = ?, engine_version = ?,
                         pictures = CASE WHEN (SELECT keep_pictures FROM batches
                                               WHERE batches.id = runs.batch_id)
                                         THEN ? END
         WHERE id = ? AND metrics IS NULL",
    )
    .bind(serde_json::to_string(&completion.metrics)?)
    .bind(serde_json::to_string(&completion.details)?)
    .bind(completion.wall_time_s)
    .bind(&found.worker_id)
    .bind(now)
    .bind(&completion.engine_version)
    .bind(if completion.pictures.is_empty() {
        None
    } else {
        Some(serde_json::to_string(&completion.pictures)?)
    })
    .bind(&found.run_id)
    .execute(&mut **tx)
    .await?
    .rows_affected();
    if stored != 1 {
        return Err(AppError::Conflict("the run already has a result".into()));
    }
    // The rest of the bookkeeping in one round trip to SQLite (the statements run in
    // order inside this transaction; the last one reports whether the batch finished).
    // Someone else holding the job now (a late result of an expired lease won): their
    // lease is superseded, their work moot.
    let superseded = match (current, &found.current_token) {
        (false, Some(other)) => Some(other.clone()),
        _ => None,
    };
    let batch_finished: i64 = sqlx::query_scalar(
        "UPDATE leases SET outcome = 'completed', ended_at = ? WHERE token = ?;
         UPDATE leases SET outcome = 'superseded', ended_at = ? WHERE token = ?;
         UPDATE jobs SET state = 'completed', lease_token = NULL, lease_expires_at = NULL,
                         progress = 1, updated_at = ?
         WHERE id = ?;
         UPDATE batches SET state = 'completed', finished_at = ?
         WHERE id = ? AND state = 'active'
           AND NOT EXISTS (SELECT 1 FROM jobs
                           WHERE batch_id = ? AND state IN ('queued', 'leased'));
         SELECT changes();",
    )
    // Plain `?` placeholders, bound in order across the statements.
    .bind(now)
    .bind(token.to_string())
    .bind(now)
    .bind(superseded)
    .bind(now)
    .bind(job_id.to_string())
    .bind(now)
    .bind(&found.batch_id)
    .bind(&found.batch_id)
    .fetch_one(&mut **tx)
    .await?;
    let batch_finished = batch_finished == 1;

    Ok(JobUpdate {
        batch_id: parse_uuid(&found.batch_id)?,
        status: RunState::Completed,
        batch_finished,
        requeued: false,
    })
}

async fn fail_in(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
    error: &str,
    max_attempts: u32,
    backoff: Duration,
) -> Result<JobUpdate, AppError> {
    let now = now_ms();
    let found = lookup_lease(tx, job_id, token).await?;
    if !found.is_current(token) {
        return Err(found.stale_conflict());
    }
    let dead = found.attempts >= i64::from(max_attempts);
    let exponent = u32::try_from(found.attempts.saturating_sub(1).clamp(0, 20)).unwrap_or(20);
    let retry_at = now.saturating_add(duration_ms(backoff).saturating_mul(1 << exponent));
    sqlx::query("UPDATE leases SET outcome = 'failed', ended_at = ? WHERE token = ?")
        .bind(now)
        .bind(token.to_string())
        .execute(&mut **tx)
        .await?;
    sqlx::query(
        "UPDATE jobs SET state = ?, lease_token = NULL, lease_expires_at = NULL,
                         available_at = ?, last_error = ?, updated_at = ?
         WHERE id = ?",
    )
    .bind(if dead { "dead" } else { "queued" })
    .bind(retry_at)
    .bind(error)
    .bind(now)
    .bind(job_id.to_string())
    .execute(&mut **tx)
    .await?;
    let batch_finished = dead && finish_batch_if_done(tx, &found.batch_id, now).await?;

    Ok(JobUpdate {
        batch_id: parse_uuid(&found.batch_id)?,
        status: if dead {
            RunState::Dead
        } else {
            RunState::Queued
        },
        batch_finished,
        requeued: !dead,
    })
}

async fn release_in(tx: &mut WriteTx, job_id: Uuid, token: Uuid) -> Result<JobUpdate, AppError> {
    let now = now_ms();
    let found = lookup_lease(tx, job_id, token).await?;
    if !found.is_current(token) {
        return Err(found.stale_conflict());
    }
    sqlx::query("UPDATE leases SET outcome = 'released', ended_at = ? WHERE token = ?")
        .bind(now)
        .bind(token.to_string())
        .execute(&mut **tx)
        .await?;
    sqlx::query(
        "UPDATE jobs SET state = 'queued', attempts = MAX(attempts - 1, 0), lease_token = NULL,
                         lease_expires_at = NULL, worker_id = NULL, available_at = ?,
                         updated_at = ?
         WHERE id = ?",
    )
    .bind(now)
    .bind(now)
    .bind(job_id.to_string())
    .execute(&mut **tx)
    .await?;

    Ok(JobUpdate {
        batch_id: parse_uuid(&found.batch_id)?,
        status: RunState::Queued,
        batch_finished: false,
        requeued: true,
    })
}
