//! Workers, claims, leases and job updates (heartbeat, complete, fail, release).

use super::*;

/// How recently a worker with a GPU must have been seen (registered, claimed or heartbeated)
/// for the `gpu` batches not to be flagged as waiting for one ([`GpuWait`]).
pub const GPU_WORKER_WINDOW: Duration = Duration::from_secs(600);

/// Whether and how a failed job runs again.
#[derive(Debug, Clone, Copy)]
pub enum Rerun {
    /// Never: the run is dead at once.
    Never,
    /// As it was, after `backoff` doubled per attempt so far, until `max_attempts`.
    Retry {
        max_attempts: u32,
        backoff: Duration,
    },
    /// At once under the seed `next_seed` makes of the run's current one, until `max_attempts`.
    WithAnotherSeed {
        max_attempts: u32,
        next_seed: fn(u64) -> u64,
    },
}

/// What a sweep of expired leases did.
#[derive(Debug, Clone, Default)]
pub struct Expired {
    /// Some job went back to the queue.
    pub requeued: bool,
    /// Batches the sweep finished (their last jobs died).
    pub finished: Vec<Uuid>,
}

/// Result of a completion, failure or release.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JobUpdate {
    /// The job's batch.
    pub batch_id: Uuid,
    /// The run's position in its batch's run order.
    pub run_index: u32,
    /// The run's new seed, when a failure ran it again under another seed.
    pub reseeded: Option<u64>,
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
pub(super) struct LeaseLookup {
    outcome: Option<LeaseOutcome>,
    worker_id: String,
    job_state: JobState,
    current_token: Option<String>,
    attempts: i64,
    run_id: String,
    run_index: i64,
    /// The run's seed (stored bit for bit as i64).
    seed: i64,
    batch_id: String,
    has_result: bool,
    response: String,
    /// The batch is still active (not completed or cancelled).
    batch_active: bool,
}

impl Db {
    /// Records (or refreshes) a worker on behalf of the worker token `token`. A worker id
    /// registered by another token is [`DbError::Forbidden`]: worker rows belong to the token
    /// that made them.
    ///
    /// A worker registers when it starts, so a job still leased to its instance id is one the
    /// worker ran before it was stopped or killed and is not running any more: it goes back to
    /// the queue at once, as if released (its attempt not counted), rather than waiting out its
    /// lease. Returns how many jobs went back.
    pub async fn register_worker(
        &self,
        worker: &WorkerRegistration,
        token: &str,
    ) -> Result<u64, DbError> {
        let now = now_ms();
        let mut tx = self.begin_write().await?;
        let result = async {
            let changed = sqlx::query(
                "INSERT INTO workers (id, host, threads, version, registered_at, last_seen_at,
                                      token, gpu, gpu_memory_bytes, gpu_slots)
                 VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)
                 ON CONFLICT (id) DO UPDATE SET host = excluded.host,
                     threads = excluded.threads, version = excluded.version,
                     last_seen_at = excluded.last_seen_at, token = excluded.token,
                     gpu = excluded.gpu, gpu_memory_bytes = excluded.gpu_memory_bytes,
                     gpu_slots = excluded.gpu_slots
                 WHERE workers.token IS NULL OR workers.token = excluded.token",
            )
            .bind(worker.instance_id.to_string())
            .bind(&worker.host)
            .bind(i64::from(worker.threads))
            .bind(&worker.version)
            .bind(now)
            .bind(now)
            .bind(token)
            .bind(worker.gpu.as_deref())
            .bind(
                worker
                    .gpu_memory_bytes
                    .map(|b| i64::try_from(b).unwrap_or(i64::MAX)),
            )
            .bind(worker.gpu_slots.map(i64::from))
            .execute(&mut *tx)
            .await?
            .rows_affected();
            if changed == 0 {
                return Err(DbError::Forbidden(format!(
                    "worker {} was registered by another token",
                    worker.instance_id
                )));
            }
            release_leases_of(&mut tx, &worker.instance_id.to_string(), now).await
        }
        .await;
        tx.finish(result).await
    }

    /// Leases the oldest available job to `worker_id` that its slot can run (`backend`: only
    /// jobs of batches on that engine; none: any the worker can run), first returning expired
    /// leases to the queue (or marking their jobs dead after `max_attempts`). `Ok(None)`:
    /// nothing to do. Also reports the batches that the expiries finished. A worker whose
    /// registered version `release` does not accept is refused (field `version`), and a GPU
    /// slot's claim from a worker that registered no GPU (field `backend`).
    pub async fn claim(
        &self,
        worker_id: Uuid,
        caller: &str,
        backend: Option<BackendKind>,
        lease: Duration,
        max_attempts: u32,
        release: repose_api::ReleaseVersion,
    ) -> Result<(Option<ClaimResponse>, Vec<Uuid>), DbError> {
        let now = now_ms();
        let mut tx = self.begin_write().await?;
        let result: Result<(Option<ClaimResponse>, Vec<Uuid>), DbError> = async {
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
                let registered: Option<(String, bool)> = sqlx::query_as(
                    "UPDATE workers SET last_seen_at = ? WHERE id = ? AND token = ?
                     RETURNING version, gpu IS NOT NULL",
                )
                .bind(now)
                .bind(worker_id.to_string())
                .bind(caller)
                .fetch_optional(&mut *tx)
                .await?;
                let Some((version, has_gpu)) = registered else {
                    return Err(DbError::invalid(
                        "worker_id",
                        format!(
                            "worker {worker_id} is not registered with this token; \
                             POST /v1/workers/register first"
                        ),
                    ));
                };
                // A worker registered with an older server (before an upgrade) is refused
                // at its first claim here, as a registration would be.
                repose_api::check_worker_version(release, &version)
                    .map_err(|refusal| DbError::invalid("version", refusal.to_string()))?;
                if backend == Some(BackendKind::Gpu) && !has_gpu {
                    return Err(DbError::invalid(
                        "backend",
                        format!(
                            "worker {worker_id} registered no GPU adapter, so it cannot claim \
                             gpu jobs; register with `gpu` first"
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
                expire_leases(&mut tx, now, max_attempts).await?.finished
            } else {
                Vec::new()
            };

            let token = Uuid::new_v4();
            let expires_at = now + duration_ms(lease);
            // One round trip: record the lease for the oldest available job this slot can
            // run (a `gpu` batch's only if the worker registered a GPU adapter; of one engine
            // only when the slot names it), then lease that job (found through its new lease)
            // and return what the worker needs. Plain `?` placeholders, bound in order across
            // both statements.
            let claimed = sqlx::query(
                "INSERT INTO leases (token, job_id, worker_id, attempt, granted_at)
                 SELECT ?, id, ?, attempts + 1, ? FROM jobs
                 WHERE id = (SELECT id FROM jobs WHERE state = 'queued' AND available_at <= ?
                               AND ((SELECT gpu FROM workers WHERE workers.id = ?) IS NOT NULL
                                    OR (SELECT backend FROM batches
                                        WHERE batches.id = jobs.batch_id) = 'cpu')
                               AND (? IS NULL OR (SELECT backend FROM batches
                                                  WHERE batches.id = jobs.batch_id) = ?)
                             ORDER BY available_at, rowid LIMIT 1);
                 UPDATE jobs SET state = 'leased', attempts = attempts + 1, lease_token = ?,
                                 lease_expires_at = ?, worker_id = ?, progress = 0, updated_at = ?
                 WHERE id = (SELECT job_id FROM leases WHERE token = ?)
                 RETURNING id, run_id, batch_id, attempts,
                           (SELECT spec FROM runs WHERE runs.id = jobs.run_id) AS spec,
                           (SELECT natural FROM runs WHERE runs.id = jobs.run_id) AS natural,
                           (SELECT seed FROM runs WHERE runs.id = jobs.run_id) AS seed,
                           (SELECT kind FROM batches WHERE batches.id = jobs.batch_id) AS kind,
                           (SELECT backend FROM batches WHERE batches.id = jobs.batch_id)
                               AS backend,
                           (SELECT keep_pictures FROM batches WHERE batches.id = jobs.batch_id)
                               AS keep_pictures",
            )
            .bind(token.to_string())
            .bind(worker_id.to_string())
            .bind(now)
            .bind(now)
            .bind(worker_id.to_string())
            .bind(backend.map(BackendKind::name))
            .bind(backend.map(BackendKind::name))
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
                    backend: backend_from_db(claimed.try_get("backend")?)?,
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
    pub async fn reclaim_expired(&self, max_attempts: u32) -> Result<Expired, DbError> {
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
    ) -> Result<HeartbeatOutcome, DbError> {
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
    ) -> Result<JobUpdate, DbError> {
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
        rerun: Rerun,
    ) -> Result<JobUpdate, DbError> {
        let mut tx = self.begin_write().await?;
        let result = fail_in(&mut tx, job_id, token, error, rerun).await;
        tx.finish(result).await
    }

    /// Gives a job back to the queue at once without counting the attempt.
    pub async fn release(&self, job_id: Uuid, token: Uuid) -> Result<JobUpdate, DbError> {
        let mut tx = self.begin_write().await?;
        let result = release_in(&mut tx, job_id, token).await;
        tx.finish(result).await
    }

    /// Registered workers, most recently seen first, with the number of leases each holds.
    pub async fn list_workers(&self, limit: u32) -> Result<Vec<WorkerView>, DbError> {
        let rows = sqlx::query(
            "SELECT w.id, w.host, w.threads, w.version, w.gpu, w.gpu_memory_bytes, w.gpu_slots,
                    w.registered_at, w.last_seen_at,
                    (SELECT COUNT(*) FROM jobs j
                     WHERE j.worker_id = w.id AND j.state = 'leased') AS running_jobs,
                    (SELECT COUNT(*) FROM jobs j JOIN batches b ON b.id = j.batch_id
                     WHERE j.worker_id = w.id AND j.state = 'leased' AND b.backend = 'gpu')
                        AS gpu_running_jobs
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
                    gpu: row.try_get("gpu")?,
                    gpu_memory_bytes: row
                        .try_get::<Option<i64>, _>("gpu_memory_bytes")?
                        .map(|b| b.max(0) as u64),
                    gpu_slots: row
                        .try_get::<Option<i64>, _>("gpu_slots")?
                        .map(|s| s.clamp(0, i64::from(u32::MAX)) as u32),
                    registered_at_ms: row.try_get("registered_at")?,
                    last_seen_at_ms: row.try_get("last_seen_at")?,
                    running_jobs: row.try_get::<i64, _>("running_jobs")? as u64,
                    gpu_running_jobs: row.try_get::<i64, _>("gpu_running_jobs")? as u64,
                })
            })
            .collect()
    }

    /// `Some` while no worker that registered a GPU adapter was seen within
    /// [`GPU_WORKER_WINDOW`]: a `gpu` batch's jobs then wait for one.
    pub async fn gpu_wait(&self) -> Result<Option<GpuWait>, DbError> {
        let seen: bool = sqlx::query_scalar(
            "SELECT EXISTS (SELECT 1 FROM workers WHERE gpu IS NOT NULL AND last_seen_at >= ?)",
        )
        .bind(now_ms() - duration_ms(GPU_WORKER_WINDOW))
        .fetch_one(&self.reader)
        .await?;
        Ok((!seen).then_some(GpuWait {
            minutes: (GPU_WORKER_WINDOW.as_secs() / 60) as u32,
        }))
    }

    /// Jobs, most recently changed first, optionally only those in `status` or of `batch_id`,
    /// and only those `scope` may see.
    pub async fn list_jobs(
        &self,
        status: Option<RunState>,
        batch_id: Option<Uuid>,
        limit: u32,
        scope: ReadScope<'_>,
    ) -> Result<Vec<JobView>, DbError> {
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
        .bind(status.map(|state| JobState::from(state).as_db()))
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
    pub async fn gauges(&self, lease: Duration) -> Result<Gauges, DbError> {
        let count_by = |sql: &'static str| async move {
            let rows = sqlx::query(sql).fetch_all(&self.reader).await?;
            rows.iter()
                .map(|row| Ok((row.try_get::<String, _>(0)?, row.try_get::<i64, _>(1)?)))
                .collect::<Result<Vec<_>, DbError>>()
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
            "SELECT COUNT(*) AS registered, COALESCE(SUM(last_seen_at >= ?), 0) AS active,
                    MAX(last_seen_at) AS last_seen
             FROM workers",
        )
        .bind(now_ms() - duration_ms(lease))
        .fetch_one(&self.reader)
        .await?;
        let gpu_rows = sqlx::query(
            "SELECT w.id, w.gpu, w.gpu_memory_bytes, w.gpu_slots,
                    (SELECT COUNT(*) FROM jobs j JOIN batches b ON b.id = j.batch_id
                     WHERE j.worker_id = w.id AND j.state = 'leased' AND b.backend = 'gpu')
                        AS running
             FROM workers w WHERE w.gpu IS NOT NULL AND w.last_seen_at >= ?
             ORDER BY w.id",
        )
        .bind(now_ms() - duration_ms(GPU_WORKER_WINDOW))
        .fetch_all(&self.reader)
        .await?;
        let gpu_workers = gpu_rows
            .iter()
            .map(|row| {
                Ok(GpuWorkerGauge {
                    worker: row.try_get("id")?,
                    adapter: row.try_get("gpu")?,
                    memory_bytes: row.try_get("gpu_memory_bytes")?,
                    slots: row.try_get("gpu_slots")?,
                    running: row.try_get("running")?,
                })
            })
            .collect::<Result<Vec<_>, DbError>>()?;
        let batches_waiting_for_gpu = if gpu_workers.is_empty() {
            sqlx::query_scalar(
                "SELECT COUNT(*) FROM batches WHERE state = 'active' AND backend = 'gpu'",
            )
            .fetch_one(&self.reader)
            .await?
        } else {
            0
        };
        let database_bytes: i64 = sqlx::query_scalar(
            "SELECT page_count * page_size FROM pragma_page_count(), pragma_page_size()",
        )
        .fetch_one(&self.reader)
        .await?;
        Ok(Gauges {
            jobs,
            batches,
            workers_active: workers.try_get("active")?,
            workers_registered: workers.try_get("registered")?,
            worker_last_seen_ms: workers.try_get("last_seen")?,
            database_bytes,
            write_failures: self.writer_health.failures.load(Ordering::Relaxed),
            writes_failing: self.writer_health.failing().is_some(),
            gpu_workers,
            batches_waiting_for_gpu,
        })
    }
}

impl LeaseLookup {
    fn is_current(&self, token: Uuid) -> bool {
        self.job_state == JobState::Leased
            && self.outcome.is_none()
            && self.current_token.as_deref() == Some(token.to_string().as_str())
    }

    fn stale_conflict(&self) -> DbError {
        let why = match self.outcome {
            Some(LeaseOutcome::Completed) => "this lease already delivered its result".to_owned(),
            Some(LeaseOutcome::Superseded) => "the run already has a result".to_owned(),
            Some(LeaseOutcome::Cancelled) => "the batch was cancelled".to_owned(),
            Some(LeaseOutcome::Expired) if self.has_result => {
                "the lease expired and the run already has a result".to_owned()
            }
            Some(LeaseOutcome::Expired) if !self.batch_active => {
                "the lease expired and the batch has finished without this run".to_owned()
            }
            Some(outcome) => format!("the lease is no longer valid ({})", outcome.as_db()),
            None => "the lease is no longer valid".to_owned(),
        };
        DbError::Conflict(why)
    }
}

/// Finds the lease `token` of job `job_id`: 404 if the job does not exist, 409 if the token was
/// never issued for it.
pub(super) async fn lookup_lease(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
) -> Result<LeaseLookup, DbError> {
    let row = sqlx::query(
        "SELECT l.outcome, l.worker_id, j.state, j.lease_token, j.attempts, j.run_id, j.batch_id,
                r.run_index, r.seed, r.metrics IS NOT NULL AS has_result, b.response, b.state AS batch_state
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
            DbError::Conflict(format!("lease {token} was not issued for job {job_id}"))
        } else {
            DbError::NotFound(format!("job {job_id} not found"))
        });
    };
    Ok(LeaseLookup {
        outcome: row
            .try_get::<Option<&str>, _>("outcome")?
            .map(LeaseOutcome::from_db)
            .transpose()?,
        worker_id: row.try_get("worker_id")?,
        job_state: JobState::from_db(row.try_get("state")?)?,
        current_token: row.try_get("lease_token")?,
        attempts: row.try_get("attempts")?,
        run_id: row.try_get("run_id")?,
        run_index: row.try_get("run_index")?,
        seed: row.try_get("seed")?,
        batch_id: row.try_get("batch_id")?,
        has_result: row.try_get("has_result")?,
        response: row.try_get("response")?,
        batch_active: row.try_get::<&str, _>("batch_state")? == "active",
    })
}

/// Ends every lease past its expiry: the job is queued again, or dead when it has used up its
/// attempts. Returns the batches this finished.
pub(super) async fn expire_leases(
    tx: &mut WriteTx,
    now: i64,
    max_attempts: u32,
) -> Result<Expired, DbError> {
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
    let mut swept = Expired::default();
    for row in &expired {
        let state = JobState::from_db(row.try_get("state")?)?;
        let batch_id: String = row.try_get("batch_id")?;
        if state == JobState::Queued {
            swept.requeued = true;
        } else if finish_batch_if_done(tx, &batch_id, now).await? {
            swept.finished.push(parse_uuid(&batch_id)?);
        }
    }
    Ok(swept)
}

pub(super) async fn heartbeat_in(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
    progress: f64,
    lease: Duration,
) -> Result<HeartbeatOutcome, DbError> {
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
    match found.outcome {
        Some(LeaseOutcome::Cancelled | LeaseOutcome::Superseded) => Ok(HeartbeatOutcome {
            cancel: true,
            lease_expires_in_s: 0.0,
        }),
        _ => Err(found.stale_conflict()),
    }
}

pub(super) async fn complete_in(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
    completion: &Completion,
) -> Result<JobUpdate, DbError> {
    let now = now_ms();
    let found = lookup_lease(tx, job_id, token).await?;
    let current = found.is_current(token);
    // A late result is accepted only while its batch is still active: once the batch has
    // finished, its analysis may be stored and a campaign may have moved on, and neither may
    // silently disagree with the counts.
    let late = found.outcome == Some(LeaseOutcome::Expired)
        && !found.has_result
        && found.batch_active
        && matches!(
            found.job_state,
            JobState::Queued | JobState::Leased | JobState::Dead
        );
    if !(current || late) {
        return Err(found.stale_conflict());
    }
    match completion.metrics.get(&found.response) {
        Some(value) if value.is_finite() => {}
        _ => {
            return Err(DbError::invalid(
                format!("metrics.{}", found.response),
                format!(
                    "the batch's response metric `{}` is missing or not finite",
                    found.response
                ),
            ))
        }
    }
    if !(completion.wall_time_s.is_finite() && completion.wall_time_s >= 0.0) {
        return Err(DbError::invalid(
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
        return Err(DbError::Conflict("the run already has a result".into()));
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
        run_index: found.run_index as u32,
        reseeded: None,
        status: RunState::Completed,
        batch_finished,
        requeued: false,
    })
}

pub(super) async fn fail_in(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
    error: &str,
    rerun: Rerun,
) -> Result<JobUpdate, DbError> {
    let now = now_ms();
    let found = lookup_lease(tx, job_id, token).await?;
    if !found.is_current(token) {
        return Err(found.stale_conflict());
    }
    let (max_attempts, retry_at) = match rerun {
        Rerun::Never => (0, now),
        Rerun::Retry {
            max_attempts,
            backoff,
        } => {
            let exponent =
                u32::try_from(found.attempts.saturating_sub(1).clamp(0, 20)).unwrap_or(20);
            let retry_at = now.saturating_add(duration_ms(backoff).saturating_mul(1 << exponent));
            (max_attempts, retry_at)
        }
        Rerun::WithAnotherSeed { max_attempts, .. } => (max_attempts, now),
    };
    let dead = found.attempts >= i64::from(max_attempts);
    let state = if dead {
        JobState::Dead
    } else {
        JobState::Queued
    };
    let mut reseeded = None;
    if let (false, Rerun::WithAnotherSeed { next_seed, .. }) = (dead, rerun) {
        let seed = next_seed(found.seed as u64);
        reseeded = Some(seed);
        // Seeds are stored bit for bit as i64.
        sqlx::query("UPDATE runs SET seed = ? WHERE id = ?")
            .bind(seed as i64)
            .bind(&found.run_id)
            .execute(&mut **tx)
            .await?;
        // An expired earlier lease ran the old seed: its late result no longer belongs to
        // the run (it is refused, and its worker told to stop).
        sqlx::query(
            "UPDATE leases SET outcome = 'superseded' WHERE job_id = ? AND outcome = 'expired'",
        )
        .bind(job_id.to_string())
        .execute(&mut **tx)
        .await?;
    }
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
    .bind(state.as_db())
    .bind(retry_at)
    .bind(error)
    .bind(now)
    .bind(job_id.to_string())
    .execute(&mut **tx)
    .await?;
    let batch_finished = dead && finish_batch_if_done(tx, &found.batch_id, now).await?;

    Ok(JobUpdate {
        batch_id: parse_uuid(&found.batch_id)?,
        run_index: found.run_index as u32,
        reseeded,
        status: state.into(),
        batch_finished,
        requeued: !dead,
    })
}

/// Returns every job leased to `worker_id` to the queue, as [`release_in`] does for one.
async fn release_leases_of(tx: &mut WriteTx, worker_id: &str, now: i64) -> Result<u64, DbError> {
    sqlx::query(
        "UPDATE leases SET outcome = 'released', ended_at = ?
         WHERE token IN (SELECT lease_token FROM jobs WHERE worker_id = ? AND state = 'leased')",
    )
    .bind(now)
    .bind(worker_id)
    .execute(&mut **tx)
    .await?;
    requeue_released(tx, "worker_id", worker_id, now).await
}

/// Puts the leased jobs whose `column` (`id` or `worker_id`) is `value` back in the queue as
/// released: at once, the attempt not counted.
async fn requeue_released(
    tx: &mut WriteTx,
    column: &'static str,
    value: &str,
    now: i64,
) -> Result<u64, DbError> {
    let released = sqlx::query(&format!(
        "UPDATE jobs SET state = 'queued', attempts = MAX(attempts - 1, 0), lease_token = NULL,
                         lease_expires_at = NULL, worker_id = NULL, available_at = ?,
                         updated_at = ?
         WHERE {column} = ? AND state = 'leased'"
    ))
    .bind(now)
    .bind(now)
    .bind(value)
    .execute(&mut **tx)
    .await?
    .rows_affected();
    Ok(released)
}

pub(super) async fn release_in(
    tx: &mut WriteTx,
    job_id: Uuid,
    token: Uuid,
) -> Result<JobUpdate, DbError> {
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
    requeue_released(tx, "id", &job_id.to_string(), now).await?;

    Ok(JobUpdate {
        batch_id: parse_uuid(&found.batch_id)?,
        run_index: found.run_index as u32,
        reseeded: None,
        status: RunState::Queued,
        batch_finished: false,
        requeued: true,
    })
}
