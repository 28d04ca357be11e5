//! Batches and their runs: submission, status views, run tables, cancellation.

use super::*;

impl Db {
    /// Stores a validated batch with one run and one queued job per planned run.
    pub async fn insert_batch(&self, plan: &PlannedBatch, owner: &str) -> Result<Uuid, DbError> {
        let mut tx = self.begin_write().await?;
        let result: Result<Uuid, DbError> = async {
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
    ) -> Result<Vec<BatchSummary>, DbError> {
        let rows = sqlx::query(&format!(
            "{SUMMARY_SELECT} WHERE (?1 IS NULL OR b.owner = ?1)
             GROUP BY b.id ORDER BY b.created_at DESC, b.rowid DESC LIMIT ?2"
        ))
        .bind(owner)
        .bind(i64::from(limit))
        .fetch_all(&self.reader)
        .await?;
        let mut summaries = rows
            .iter()
            .map(summary_from_row)
            .collect::<Result<Vec<_>, _>>()?;
        self.flag_gpu_waits(&mut summaries).await?;
        Ok(summaries)
    }

    /// Sets `gpu_wait` on the active `gpu` batches among `summaries` while no worker with a
    /// GPU was seen lately ([`Db::gpu_wait`]).
    async fn flag_gpu_waits(&self, summaries: &mut [BatchSummary]) -> Result<(), DbError> {
        let waiting =
            |s: &BatchSummary| s.backend == BackendKind::Gpu && s.state == BatchState::Active;
        if !summaries.iter().any(waiting) {
            return Ok(());
        }
        let wait = self.gpu_wait().await?;
        for summary in summaries.iter_mut().filter(|s| waiting(s)) {
            summary.gpu_wait = wait;
        }
        Ok(())
    }

    /// Progress of one batch, or `None` if it does not exist.
    pub async fn batch_status(&self, batch_id: Uuid) -> Result<Option<BatchStatus>, DbError> {
        let Some(row) = sqlx::query(&format!("{SUMMARY_SELECT} WHERE b.id = ? GROUP BY b.id"))
            .bind(batch_id.to_string())
            .fetch_optional(&self.reader)
            .await?
        else {
            return Ok(None);
        };
        let mut summary = summary_from_row(&row)?;
        self.flag_gpu_waits(std::slice::from_mut(&mut summary))
            .await?;
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
    pub(super) async fn run_spec(
        &self,
        batch_id: Uuid,
        stored_spec: &str,
        natural: &str,
    ) -> Result<Value, DbError> {
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
                .zip(natural.iter().copied())
                .filter_map(|(p, v)| Some((p.as_deref()?, v))),
        )
        .map_err(|err| DbError::Corrupt(format!("stored run spec of batch {batch_id}: {err}")))
    }

    /// The template of a batch, from the cache or the database.
    pub(super) async fn template(&self, batch_id: Uuid) -> Result<Arc<RunTemplate>, DbError> {
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
            DbError::Corrupt(format!(
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
    ) -> Result<Option<(Vec<String>, Vec<RunView>)>, DbError> {
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
                // A run whose spec cannot be rebuilt (values stored by an older server that
                // did not refuse overflowing ranges) is listed without a hash, not a 500.
                match self
                    .run_spec(batch_id, stored, row.try_get("natural")?)
                    .await
                {
                    Ok(spec) => Some(serde_json::to_string(&spec)?),
                    Err(DbError::Corrupt(why)) => {
                        tracing::warn!(batch = %batch_id, %why, "run spec cannot be rebuilt");
                        None
                    }
                    Err(err) => return Err(err),
                }
            } else {
                Some(stored.to_owned())
            });
        }
        let runs = rows
            .iter()
            .enumerate()
            .map(|(index, row)| -> Result<RunView, DbError> {
                // Lenient: batches stored before non-finite values were refused hold `null`s
                // here; they read back as NaN (`null` in JSON) instead of failing the request.
                let lenient = |column: &str| -> Result<Vec<f64>, DbError> {
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
                    spec_sha256: spec_texts[index].as_deref().map(short_sha256),
                    engine_version: row.try_get("engine_version")?,
                })
            })
            .collect::<Result<Vec<_>, DbError>>()?;
        Ok(Some((names, runs)))
    }

    /// The stored pictures of a batch's first completed run that has any (run order), by
    /// file name; empty if the batch keeps none.
    pub async fn first_run_pictures(
        &self,
        batch_id: Uuid,
    ) -> Result<BTreeMap<String, String>, DbError> {
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
    /// batches are left alone; a batch owned by another token is [`DbError::Forbidden`].
    pub async fn cancel_batch(
        &self,
        batch_id: Uuid,
        caller: &str,
    ) -> Result<Option<BatchState>, DbError> {
        let mut tx = self.begin_write().await?;
        let result = cancel_batch_in(&mut tx, batch_id, caller).await;
        tx.finish(result).await
    }
}

impl Db {
    /// The owner of a batch: `None` if it does not exist, `Some(None)` if it has none (from
    /// before access control).
    pub async fn batch_owner(&self, batch_id: Uuid) -> Result<Option<Option<String>>, DbError> {
        let owner: Option<Option<String>> =
            sqlx::query_scalar("SELECT owner FROM batches WHERE id = ?")
                .bind(batch_id.to_string())
                .fetch_optional(&self.reader)
                .await?;
        Ok(owner)
    }
}

/// Inserts a batch, its runs and their jobs inside the caller's transaction.
pub(super) async fn insert_batch_tx(
    tx: &mut WriteTx,
    plan: &PlannedBatch,
    owner: &str,
) -> Result<Uuid, DbError> {
    let batch_id = Uuid::new_v4();
    let now = now_ms();
    let request = &plan.request;
    sqlx::query(
        "INSERT INTO batches (id, name, kind, request, factors, design_kind, response, model,
                                  target, base_seed, state, created_at, owner, keep_pictures,
                                  template, backend)
             VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 'active', ?, ?, ?, ?, ?)",
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
    .bind(request.experiment.backend().name())
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
                .push_bind(JobState::Queued.as_db())
                .push_bind(0_i64)
                .push_bind(now)
                .push_bind(now);
        });
        jobs.build().execute(&mut **tx).await?;
    }
    Ok(batch_id)
}

/// Marks an active batch completed when none of its jobs is queued or leased; true if this call
/// did it (so exactly one caller triggers the analysis).
pub(super) async fn finish_batch_if_done(
    tx: &mut WriteTx,
    batch_id: &str,
    now: i64,
) -> Result<bool, DbError> {
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

pub(super) const SUMMARY_SELECT: &str =
    "SELECT b.id, b.name, b.kind, b.state, b.created_at, b.owner, b.backend,
        COALESCE(SUM(j.state = 'queued'), 0) AS queued,
        COALESCE(SUM(j.state = 'leased'), 0) AS running,
        COALESCE(SUM(j.state = 'completed'), 0) AS completed,
        COALESCE(SUM(j.state = 'dead'), 0) AS dead,
        COALESCE(SUM(j.state = 'cancelled'), 0) AS cancelled
    FROM batches b LEFT JOIN jobs j ON j.batch_id = b.id";

pub(super) fn summary_from_row(row: &SqliteRow) -> Result<BatchSummary, DbError> {
    let count = |name: &str| -> Result<u64, DbError> { Ok(row.try_get::<i64, _>(name)? as u64) };
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
        backend: backend_from_db(row.try_get("backend")?)?,
        gpu_wait: None,
    })
}

pub(super) async fn cancel_batch_in(
    tx: &mut WriteTx,
    batch_id: Uuid,
    caller: &str,
) -> Result<Option<BatchState>, DbError> {
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
        return Err(DbError::Forbidden(format!(
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
