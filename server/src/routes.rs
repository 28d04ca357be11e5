//! HTTP routes: request parsing, id validation and the claim long-poll. State changes are
//! delegated to [`crate::db`], validation of submissions to [`crate::submit`].

use std::fmt::Write as _;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{DefaultBodyLimit, FromRequest, Path, Query, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware;
use axum::response::{IntoResponse, Response};
use axum::routing::{on, MethodFilter, MethodRouter};
use axum::{Extension, Json, Router};
use repose_api::{
    BatchCreated, BatchRequest, BatchState, CampaignBatch, CampaignCreated, CampaignDecision,
    CampaignSummary, CampaignView, ClaimRequest, Completion, Failure, Health, Heartbeat,
    HeartbeatResponse, Release, RunState, RunView, WorkerRegistered, WorkerRegistration,
};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use tokio::time::Instant;
use uuid::Uuid;

use crate::auth::{authorize, Access, Caller};
use crate::db::{ReadScope, Rerun};
use crate::error::AppError;
use crate::{analysis, campaigns, orchestrate, submit, AppState};

/// How often a waiting claim re-checks the queue even without a notification, so retry
/// back-offs and expired leases are picked up without a background task.
const CLAIM_RECHECK: Duration = Duration::from_millis(500);

/// Batches listed by `GET /v1/batches`.
const BATCH_LIST_LIMIT: u32 = 500;

/// Workers listed by `GET /v1/workers`.
const WORKER_LIST_LIMIT: u32 = 1000;

/// Longest error text a worker may report for a failed run, in bytes.
const MAX_ERROR_BYTES: usize = 16 * 1024;

/// Largest `details` document of a completion (serialized), in bytes.
const MAX_DETAILS_BYTES: usize = 64 * 1024;

/// Most metrics one completion may report.
const MAX_METRICS: usize = 256;

/// Largest single picture of a completion, in bytes.
const MAX_PICTURE_BYTES: usize = 2 * 1024 * 1024;

/// Default and largest `limit` of `GET /v1/jobs`.
const JOB_LIST_DEFAULT: u32 = 100;
const JOB_LIST_MAX: u32 = 10_000;

/// HTTP methods the API uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verb {
    /// Reads.
    Get,
    /// Everything that changes state.
    Post,
}

impl Verb {
    /// Lower-case name, as in OpenAPI path items.
    pub fn as_str(self) -> &'static str {
        match self {
            Verb::Get => "get",
            Verb::Post => "post",
        }
    }

    fn filter(self) -> MethodFilter {
        match self {
            Verb::Get => MethodFilter::GET,
            Verb::Post => MethodFilter::POST,
        }
    }
}

/// One endpoint of the API: the route table below is the single source of the paths, their
/// handlers and who may call them (the router is built from it, and the OpenAPI test compares
/// `api/openapi.json` against it).
#[derive(Debug, Clone, Copy)]
pub struct Endpoint {
    /// Method.
    pub verb: Verb,
    /// Path in axum syntax (`{id}` for a parameter, as in OpenAPI).
    pub path: &'static str,
    /// Who may call it.
    pub access: Access,
    /// Builds the method router for the endpoint's method.
    handler: fn(MethodFilter) -> MethodRouter<AppState>,
}

const fn ep(
    verb: Verb,
    path: &'static str,
    access: Access,
    handler: fn(MethodFilter) -> MethodRouter<AppState>,
) -> Endpoint {
    Endpoint {
        verb,
        path,
        access,
        handler,
    }
}

/// Every endpoint of the API. The HTML status page and its sign-in (`/`, `/sign-in`,
/// `/sign-out`) are not API and are routed by [`crate::page`].
pub const ENDPOINTS: &[Endpoint] = &[
    ep(Verb::Get, "/healthz", Access::Public, |m| on(m, health)),
    ep(Verb::Get, "/openapi.json", Access::Public, |m| {
        on(m, openapi)
    }),
    ep(Verb::Get, "/metrics", Access::Read, |m| on(m, metrics)),
    ep(Verb::Post, "/v1/batches", Access::User, |m| {
        on(m, create_batch)
    }),
    ep(Verb::Get, "/v1/batches", Access::Read, |m| {
        on(m, list_batches)
    }),
    ep(Verb::Get, "/v1/batches/{id}", Access::Read, |m| {
        on(m, batch_status)
    }),
    ep(Verb::Get, "/v1/batches/{id}/runs", Access::Read, |m| {
        on(m, batch_runs)
    }),
    ep(Verb::Post, "/v1/batches/{id}/cancel", Access::User, |m| {
        on(m, cancel_batch)
    }),
    ep(Verb::Get, "/v1/batches/{id}/analysis", Access::Read, |m| {
        on(m, batch_analysis)
    }),
    ep(Verb::Post, "/v1/campaigns", Access::User, |m| {
        on(m, create_campaign)
    }),
    ep(Verb::Get, "/v1/campaigns", Access::Read, |m| {
        on(m, list_campaigns)
    }),
    ep(Verb::Get, "/v1/campaigns/{id}", Access::Read, |m| {
        on(m, campaign_status)
    }),
    ep(Verb::Get, "/v1/campaigns/{id}/report", Access::Read, |m| {
        on(m, campaign_report)
    }),
    ep(Verb::Get, "/v1/workers", Access::Read, |m| {
        on(m, list_workers)
    }),
    ep(Verb::Get, "/v1/jobs", Access::Read, |m| on(m, list_jobs)),
    ep(Verb::Post, "/v1/workers/register", Access::Worker, |m| {
        on(m, register_worker)
    }),
    ep(Verb::Post, "/v1/jobs/claim", Access::Worker, |m| {
        on(m, claim_job)
    }),
    ep(Verb::Post, "/v1/jobs/{id}/heartbeat", Access::Worker, |m| {
        on(m, heartbeat)
    }),
    ep(Verb::Post, "/v1/jobs/{id}/complete", Access::Worker, |m| {
        on(m, complete_job)
    }),
    ep(Verb::Post, "/v1/jobs/{id}/fail", Access::Worker, |m| {
        on(m, fail_job)
    }),
    ep(Verb::Post, "/v1/jobs/{id}/release", Access::Worker, |m| {
        on(m, release_job)
    }),
];

/// The router with every endpoint of [`ENDPOINTS`], each behind its access check;
/// `state` comes from [`AppState::open`].
pub fn app(state: AppState) -> Router {
    let body_limit = state.config.body_limit_bytes;
    let mut router = Router::new();
    for endpoint in ENDPOINTS {
        let guard = middleware::from_fn_with_state((state.clone(), endpoint.access), authorize);
        router = router.route(
            endpoint.path,
            (endpoint.handler)(endpoint.verb.filter()).route_layer(guard),
        );
    }
    router
        .merge(crate::page::routes())
        .fallback(|| async { AppError::NotFound("no such endpoint".into()) })
        .method_not_allowed_fallback(|| async {
            AppError::MethodNotAllowed("method not allowed on this endpoint".into())
        })
        .layer(DefaultBodyLimit::max(body_limit))
        .layer(middleware::from_fn_with_state(
            state.metrics.clone(),
            crate::metrics::count_responses,
        ))
        .with_state(state)
}

/// JSON body extractor whose errors name the offending field (`factors[1].low`) and use the
/// server's error format instead of axum's plain-text rejections.
struct ValidJson<T>(T);

impl<S, T> FromRequest<S> for ValidJson<T>
where
    S: Send + Sync,
    T: DeserializeOwned,
{
    type Rejection = AppError;

    async fn from_request(request: Request, state: &S) -> Result<Self, AppError> {
        let bytes =
            Bytes::from_request(request, state)
                .await
                .map_err(|rejection: BytesRejection| AppError::Body {
                    status: rejection.status(),
                    message: rejection.body_text(),
                })?;
        let mut deserializer = serde_json::Deserializer::from_slice(&bytes);
        let value = serde_path_to_error::deserialize(&mut deserializer).map_err(|err| {
            let field = err.path().to_string();
            let inner = err.into_inner();
            if inner.is_syntax() || inner.is_eof() {
                AppError::BadRequest(format!("malformed JSON: {inner}"))
            } else {
                AppError::Invalid {
                    field: (field != "." && !field.is_empty()).then_some(field),
                    message: inner.to_string(),
                }
            }
        })?;
        deserializer
            .end()
            .map_err(|err| AppError::BadRequest(format!("malformed JSON: {err}")))?;
        Ok(ValidJson(value))
    }
}

/// The `{id}` of a path, as a UUID: the one place path ids are parsed (axum's
/// `customize-path-rejection` pattern). A malformed id is the client's mistake, a 400 naming
/// what kind of id it should have been (`invalid batch id `x``), in the server's error format.
#[derive(Debug, Clone, Copy)]
struct PathId(Uuid);

impl<S: Send + Sync> axum::extract::FromRequestParts<S> for PathId {
    type Rejection = AppError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        state: &S,
    ) -> Result<Self, AppError> {
        // `/v1/batches/{id}/…` holds a batch id, `/v1/jobs/{id}/…` a job id, and so on.
        let what = match parts.uri.path().split('/').nth(2) {
            Some("batches") => "batch",
            Some("jobs") => "job",
            Some("campaigns") => "campaign",
            _ => "path",
        };
        let Path(raw) = Path::<String>::from_request_parts(parts, state)
            .await
            .map_err(|rejection| AppError::BadRequest(rejection.body_text()))?;
        parse_id(&raw, what).map(PathId)
    }
}

/// Parses an id; a malformed one is the client's mistake (400), not ours.
fn parse_id(raw: &str, what: &str) -> Result<Uuid, AppError> {
    Uuid::parse_str(raw)
        .map_err(|_| AppError::BadRequest(format!("invalid {what} id `{raw}`: expected a UUID")))
}

/// The authenticated reader of a GET, if any (anonymous with `--open-read`).
type Reader = Option<Extension<Caller>>;

/// What `reader` may see under the server's read policy.
fn read_scope<'a>(state: &AppState, reader: &'a Reader) -> ReadScope<'a> {
    scope_of(state, reader.as_ref().map(|Extension(caller)| caller))
}

/// What `caller` (`None`: an anonymous reader) may see under the server's read policy; the
/// status page uses it too.
pub(crate) fn scope_of<'a>(state: &AppState, caller: Option<&'a Caller>) -> ReadScope<'a> {
    match caller {
        Some(caller) if state.config.private_reads => match caller.role {
            crate::TokenRole::User => ReadScope::User(&caller.name),
            crate::TokenRole::Worker => ReadScope::Worker(&caller.name),
        },
        _ => ReadScope::All,
    }
}

/// With private reads, a user reads only what it owns (403 otherwise).
fn check_owner(
    state: &AppState,
    reader: &Reader,
    owner: Option<&str>,
    what: &str,
) -> Result<(), AppError> {
    match read_scope(state, reader) {
        ReadScope::All => Ok(()),
        ReadScope::User(name) if owner == Some(name) => Ok(()),
        _ => Err(AppError::Forbidden(format!(
            "{what} belongs to another user; this server keeps reads private"
        ))),
    }
}

/// [`check_owner`] for a batch, looked up by id (404 if it does not exist).
async fn check_batch_owner(state: &AppState, reader: &Reader, id: Uuid) -> Result<(), AppError> {
    if read_scope(state, reader) == ReadScope::All {
        return Ok(());
    }
    let owner = state
        .db
        .batch_owner(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
    check_owner(state, reader, owner.as_deref(), &format!("batch {id}"))
}

fn owner_filter<'a>(state: &AppState, reader: &'a Reader) -> Option<&'a str> {
    match read_scope(state, reader) {
        ReadScope::User(name) => Some(name),
        _ => None,
    }
}

#[derive(Debug, Deserialize)]
struct FormatQuery {
    format: Option<String>,
}

/// 200 when the database answers reads and commits a write through the writer; 503 otherwise
/// (and while the last real write failed for a storage reason such as a full disk).
async fn health(State(state): State<AppState>) -> Result<Json<Health>, AppError> {
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
async fn openapi() -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        repose_api::OPENAPI_JSON,
    )
        .into_response()
}

/// Prometheus text format; see [`crate::metrics`].
async fn metrics(State(state): State<AppState>) -> Result<Response, AppError> {
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

async fn create_batch(
    State(state): State<AppState>,
    caller: Caller,
    ValidJson(request): ValidJson<BatchRequest>,
) -> Result<(StatusCode, Json<BatchCreated>), AppError> {
    let fallback_seed = Uuid::new_v4().as_u64_pair().0;
    // Design generation and the estimability check are CPU work; keep them off the reactor.
    let plan = tokio::task::spawn_blocking(move || submit::plan_batch(request, fallback_seed))
        .await
        .map_err(|err| AppError::Internal(format!("planning task: {err}")))??;
    let id = state.db.insert_batch(&plan, &caller.name).await?;
    orchestrate::jobs_available(&state);
    tracing::info!(batch = %id, runs = plan.runs.len(), "batch submitted");
    Ok((
        StatusCode::CREATED,
        Json(BatchCreated {
            id,
            run_count: plan.runs.len(),
        }),
    ))
}

async fn list_batches(
    State(state): State<AppState>,
    reader: Reader,
) -> Result<impl IntoResponse, AppError> {
    let owner = owner_filter(&state, &reader);
    Ok(Json(state.db.list_batches(BATCH_LIST_LIMIT, owner).await?))
}

async fn batch_status(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
) -> Result<impl IntoResponse, AppError> {
    check_batch_owner(&state, &reader, id).await?;
    let status = state
        .db
        .batch_status(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
    Ok(Json(status))
}

async fn batch_runs(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
    Query(query): Query<FormatQuery>,
) -> Result<Response, AppError> {
    check_batch_owner(&state, &reader, id).await?;
    let (factor_names, runs) = state
        .db
        .list_runs(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
    match query.format.as_deref() {
        None | Some("json") => Ok(Json(runs).into_response()),
        Some("csv") => Ok((
            [(header::CONTENT_TYPE, "text/csv; charset=utf-8")],
            runs_csv(&factor_names, &runs),
        )
            .into_response()),
        Some(other) => Err(AppError::BadRequest(format!(
            "unknown format `{other}` (expected json or csv)"
        ))),
    }
}

async fn cancel_batch(
    State(state): State<AppState>,
    caller: Caller,
    PathId(id): PathId,
) -> Result<impl IntoResponse, AppError> {
    match state.db.cancel_batch(id, &caller.name).await? {
        None => Err(AppError::NotFound(format!("batch {id} not found"))),
        Some(BatchState::Completed) => {
            Err(AppError::Conflict(format!("batch {id} already completed")))
        }
        Some(_) => {
            let status = state
                .db
                .batch_status(id)
                .await?
                .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
            orchestrate::batch_cancelled(&state, id).await;
            Ok(Json(status))
        }
    }
}

async fn batch_analysis(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
    Query(query): Query<FormatQuery>,
) -> Result<Response, AppError> {
    check_batch_owner(&state, &reader, id).await?;
    let view = match state.db.analysis(id).await? {
        Some(view) => view,
        None => {
            // Normally computed when the last run completes; this covers a restart in between.
            let input = state
                .db
                .analysis_input(id)
                .await?
                .ok_or_else(|| AppError::NotFound(format!("batch {id} not found")))?;
            match input.state {
                BatchState::Completed => {
                    orchestrate::compute_and_store_analysis(&state, id).await?
                }
                BatchState::Active => {
                    return Err(AppError::Conflict(format!(
                        "batch {id} is still running; the analysis is computed when its last \
                         run finishes"
                    )))
                }
                BatchState::Cancelled => {
                    return Err(AppError::Conflict(format!(
                        "batch {id} was cancelled; it has no analysis"
                    )))
                }
            }
        }
    };
    match query.format.as_deref() {
        None | Some("json") => Ok(Json(view).into_response()),
        Some("text") => Ok((
            [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
            analysis::render_text(&view),
        )
            .into_response()),
        Some(other) => Err(AppError::BadRequest(format!(
            "unknown format `{other}` (expected json or text)"
        ))),
    }
}

async fn list_workers(State(state): State<AppState>) -> Result<impl IntoResponse, AppError> {
    Ok(Json(state.db.list_workers(WORKER_LIST_LIMIT).await?))
}

#[derive(Debug, Deserialize)]
struct JobsQuery {
    state: Option<String>,
    batch: Option<String>,
    limit: Option<String>,
}

/// Jobs, most recently changed first: `?state=queued|running|completed|dead|cancelled`,
/// `?batch=<id>`, `?limit=` (default 100, at most 10 000).
async fn list_jobs(
    State(state): State<AppState>,
    reader: Reader,
    Query(query): Query<JobsQuery>,
) -> Result<impl IntoResponse, AppError> {
    let status = query
        .state
        .as_deref()
        .map(|text| {
            serde_json::from_value::<RunState>(serde_json::Value::String(text.to_owned())).map_err(
                |_| {
                    AppError::BadRequest(format!(
                        "unknown state `{text}` (expected queued, running, completed, dead or \
                         cancelled)"
                    ))
                },
            )
        })
        .transpose()?;
    let batch = query
        .batch
        .as_deref()
        .map(|raw| parse_id(raw, "batch"))
        .transpose()?;
    let limit = match query.limit.as_deref() {
        None => JOB_LIST_DEFAULT,
        Some(text) => text.parse().unwrap_or(0),
    };
    if limit == 0 || limit > JOB_LIST_MAX {
        return Err(AppError::BadRequest(format!(
            "limit must be between 1 and {JOB_LIST_MAX}"
        )));
    }
    let scope = read_scope(&state, &reader);
    Ok(Json(state.db.list_jobs(status, batch, limit, scope).await?))
}

async fn register_worker(
    State(state): State<AppState>,
    caller: Caller,
    ValidJson(registration): ValidJson<WorkerRegistration>,
) -> Result<impl IntoResponse, AppError> {
    submit::check_name_length("host", &registration.host)?;
    submit::check_name_length("version", &registration.version)?;
    repose_api::check_worker_version(state.config.release, &registration.version)
        .map_err(|refusal| AppError::invalid("version", refusal.to_string()))?;
    let released = state
        .db
        .register_worker(&registration, &caller.name)
        .await?;
    tracing::info!(worker = %registration.instance_id, host = %registration.host, "worker registered");
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

/// Leases a job, waiting up to `wait_s` for one; 204 when none arrives in time.
async fn claim_job(
    State(state): State<AppState>,
    caller: Caller,
    ValidJson(request): ValidJson<ClaimRequest>,
) -> Result<Response, AppError> {
    if !(request.wait_s.is_finite() && request.wait_s >= 0.0) {
        return Err(AppError::invalid("wait_s", "must be a non-negative number"));
    }
    // Clamped before converting: any finite wait is allowed, and waits at most the maximum.
    let wait = Duration::try_from_secs_f64(
        request
            .wait_s
            .min(state.config.max_claim_wait.as_secs_f64()),
    )
    .unwrap_or(state.config.max_claim_wait);
    let deadline = Instant::now() + wait;
    let mut shutdown = state.shutdown.clone();
    loop {
        // Register interest before looking, so a submission between the look and the wait
        // is not missed.
        let notified = state.jobs_available.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();

        let started = std::time::Instant::now();
        let (claimed, finished) = state
            .db
            .claim(
                request.worker_id,
                &caller.name,
                state.config.lease,
                state.config.max_attempts,
                state.config.release,
            )
            .await?;
        orchestrate::batches_finished(&state, finished);
        if let Some(job) = claimed {
            state.metrics.claimed(started.elapsed());
            tracing::debug!(job = %job.job_id, worker = %request.worker_id, "job leased");
            return Ok(Json(job).into_response());
        }
        let now = Instant::now();
        if now >= deadline || *shutdown.borrow() {
            state.metrics.claim_empty();
            return Ok(StatusCode::NO_CONTENT.into_response());
        }
        let recheck = (now + CLAIM_RECHECK).min(deadline);
        tokio::select! {
            _ = &mut notified => {}
            _ = tokio::time::sleep_until(recheck) => {}
            _ = shutdown.changed() => {}
        }
    }
}

async fn heartbeat(
    State(state): State<AppState>,
    PathId(job_id): PathId,
    ValidJson(beat): ValidJson<Heartbeat>,
) -> Result<impl IntoResponse, AppError> {
    if !beat.progress.is_finite() {
        return Err(AppError::invalid("progress", "must be a number in 0..1"));
    }
    let outcome = state
        .db
        .heartbeat(job_id, beat.lease_token, beat.progress, state.config.lease)
        .await?;
    Ok(Json(HeartbeatResponse {
        cancel: outcome.cancel,
        lease_expires_in_s: outcome.lease_expires_in_s,
    }))
}

async fn complete_job(
    State(state): State<AppState>,
    PathId(job_id): PathId,
    ValidJson(completion): ValidJson<Completion>,
) -> Result<impl IntoResponse, AppError> {
    check_completion_sizes(&completion)?;
    let update = state
        .db
        .complete(job_id, completion.lease_token, &completion)
        .await?;
    state.metrics.completed();
    Ok(orchestrate::job_updated(&state, job_id, update))
}

async fn fail_job(
    State(state): State<AppState>,
    PathId(job_id): PathId,
    ValidJson(failure): ValidJson<Failure>,
) -> Result<impl IntoResponse, AppError> {
    if failure.error.len() > MAX_ERROR_BYTES {
        return Err(AppError::invalid(
            "error",
            format!("at most {MAX_ERROR_BYTES} bytes of error text"),
        ));
    }
    let max_attempts = state.config.max_attempts;
    let rerun = match (failure.permanent, failure.another_seed) {
        (true, true) => {
            return Err(AppError::invalid(
                "another_seed",
                "a failure is either permanent or worth another seed, not both",
            ))
        }
        // Same spec and seed, same outcome: not worth a retry.
        (true, false) => Rerun::Never,
        (false, true) => Rerun::WithAnotherSeed {
            max_attempts,
            next_seed: repose_doe::design::next_seed,
        },
        (false, false) => Rerun::Retry {
            max_attempts,
            backoff: state.config.retry_backoff,
        },
    };
    let update = state
        .db
        .fail(job_id, failure.lease_token, &failure.error, rerun)
        .await?;
    state.metrics.failed();
    orchestrate::job_failed(job_id, &update, &failure.error);
    Ok(orchestrate::job_updated(&state, job_id, update))
}

async fn release_job(
    State(state): State<AppState>,
    PathId(job_id): PathId,
    ValidJson(release): ValidJson<Release>,
) -> Result<impl IntoResponse, AppError> {
    let update = state.db.release(job_id, release.lease_token).await?;
    state.metrics.released(1);
    Ok(orchestrate::job_updated(&state, job_id, update))
}

/// Bounds every free-form part of a result, naming the field that is too large.
fn check_completion_sizes(completion: &Completion) -> Result<(), AppError> {
    if completion.metrics.len() > MAX_METRICS {
        return Err(AppError::invalid(
            "metrics",
            format!("at most {MAX_METRICS} metrics"),
        ));
    }
    for name in completion.metrics.keys() {
        submit::check_name_length("metrics", name)?;
    }
    if let Some(version) = &completion.engine_version {
        submit::check_name_length("engine_version", version)?;
    }
    let details = serde_json::to_string(&completion.details)?;
    if details.len() > MAX_DETAILS_BYTES {
        return Err(AppError::invalid(
            "details",
            format!("at most {MAX_DETAILS_BYTES} bytes of details"),
        ));
    }
    for (name, picture) in &completion.pictures {
        submit::check_name_length("pictures", name)?;
        if picture.len() > MAX_PICTURE_BYTES {
            return Err(AppError::invalid(
                format!("pictures.{name}"),
                format!("at most {MAX_PICTURE_BYTES} bytes per picture"),
            ));
        }
    }
    Ok(())
}

/// The run table as CSV: one column per factor (natural units), per metric and the bookkeeping.
fn runs_csv(factor_names: &[String], runs: &[RunView]) -> String {
    let mut metric_names: Vec<&String> = runs
        .iter()
        .filter_map(|run| run.metrics.as_ref())
        .flat_map(|metrics| metrics.keys())
        .collect();
    metric_names.sort();
    metric_names.dedup();
    let mut header_fields: Vec<String> = vec!["run_index".into(), "replicate".into()];
    header_fields.extend(factor_names.iter().cloned());
    header_fields.extend(["seed".into(), "status".into(), "attempts".into()]);
    header_fields.extend(metric_names.iter().map(|m| (*m).clone()));
    header_fields.extend(["worker_id".into(), "wall_time_s".into(), "run_id".into()]);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}",
        header_fields
            .iter()
            .map(|f| csv_field(f))
            .collect::<Vec<_>>()
            .join(",")
    );
    for run in runs {
        let mut fields: Vec<String> = vec![run.run_index.to_string(), run.replicate.to_string()];
        fields.extend(run.factors.iter().map(|f| f.natural.to_string()));
        fields.extend([
            run.seed.to_string(),
            run.status.as_str().to_owned(),
            run.attempts.to_string(),
        ]);
        fields.extend(metric_names.iter().map(|name| {
            run.metrics
                .as_ref()
                .and_then(|m| m.get(*name))
                .map(f64::to_string)
                .unwrap_or_default()
        }));
        fields.extend([
            run.worker_id.map(|w| w.to_string()).unwrap_or_default(),
            run.wall_time_s.map(|w| w.to_string()).unwrap_or_default(),
            run.id.to_string(),
        ]);
        let _ = writeln!(
            out,
            "{}",
            fields
                .iter()
                .map(|f| csv_field(f))
                .collect::<Vec<_>>()
                .join(",")
        );
    }
    out
}

/// Quotes a CSV field when it contains a separator, quote or line break (RFC 4180).
fn csv_field(field: &str) -> String {
    if field.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", field.replace('"', "\"\""))
    } else {
        field.to_owned()
    }
}

/// Campaigns listed by `GET /v1/campaigns`.
const CAMPAIGN_LIST_LIMIT: u32 = 200;

async fn create_campaign(
    State(state): State<AppState>,
    caller: Caller,
    ValidJson(request): ValidJson<repose_campaign::CampaignRequest>,
) -> Result<(StatusCode, Json<CampaignCreated>), AppError> {
    let (id, first_batch) = campaigns::create(&state, request, &caller.name).await?;
    tracing::info!(campaign = %id, batch = %first_batch, "campaign started");
    Ok((
        StatusCode::CREATED,
        Json(CampaignCreated { id, first_batch }),
    ))
}

async fn list_campaigns(
    State(state): State<AppState>,
    reader: Reader,
) -> Result<impl IntoResponse, AppError> {
    let owner = owner_filter(&state, &reader);
    let records = state.db.list_campaigns(CAMPAIGN_LIST_LIMIT, owner).await?;
    Ok(Json(
        records
            .iter()
            .map(campaign_summary)
            .collect::<Vec<CampaignSummary>>(),
    ))
}

fn campaign_summary(record: &crate::db::CampaignRecord) -> CampaignSummary {
    CampaignSummary {
        id: record.id,
        name: record.name.clone(),
        status: record.status.clone(),
        stage: record.stage.clone(),
        batches: u64::try_from(record.batches_issued).unwrap_or(0),
        created_at_ms: record.created_at_ms,
        updated_at_ms: record.updated_at_ms,
    }
}

async fn campaign_status(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
) -> Result<impl IntoResponse, AppError> {
    let record = state
        .db
        .campaign(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("campaign {id} not found")))?;
    check_owner(
        &state,
        &reader,
        record.owner.as_deref(),
        &format!("campaign {id}"),
    )?;
    let campaign = campaigns::decode(&record)?;
    let mut batch_list = Vec::new();
    for (index, batch_id) in record.batch_ids.iter().enumerate() {
        let Some(status) = state.db.batch_status(*batch_id).await? else {
            continue;
        };
        let stage = campaign
            .batches
            .get(index)
            .map_or_else(|| "unknown".to_owned(), |b| campaigns::stage_id(b.stage));
        batch_list.push(CampaignBatch {
            index: index as u64,
            stage,
            batch_id: *batch_id,
            state: status.summary.state,
            percent_done: status.summary.percent_done,
        });
    }
    let stage_percent_done = campaign
        .outstanding()
        .and_then(|i| batch_list.get(i))
        .map(|b| b.percent_done);
    let reason = match &campaign.status {
        repose_campaign::Status::NeedsAttention { reason } => Some(reason.clone()),
        _ => None,
    };
    Ok(Json(CampaignView {
        summary: campaign_summary(&record),
        reason,
        stage_percent_done,
        batch_list,
        decisions: campaign
            .decisions
            .iter()
            .map(|d| CampaignDecision {
                stage: campaigns::stage_id(d.stage),
                round: d.round,
                text: d.text.clone(),
            })
            .collect(),
        result: campaign
            .summary
            .as_ref()
            .and_then(|summary| serde_json::to_value(summary).ok()),
    }))
}

/// The campaign report: a self-contained HTML page, or `?format=json`.
async fn campaign_report(
    State(state): State<AppState>,
    reader: Reader,
    PathId(id): PathId,
    Query(query): Query<FormatQuery>,
) -> Result<Response, AppError> {
    let record = state
        .db
        .campaign(id)
        .await?
        .ok_or_else(|| AppError::NotFound(format!("campaign {id} not found")))?;
    check_owner(
        &state,
        &reader,
        record.owner.as_deref(),
        &format!("campaign {id}"),
    )?;
    let campaign = campaigns::decode(&record)?;
    let results = campaigns::stage_results(&state, &record).await?;
    let pictures = campaigns::report_pictures(&state, &campaign, &record).await?;
    match query.format.as_deref() {
        Some("json") => Ok(Json(repose_campaign::report_json(&campaign, &results)).into_response()),
        None | Some("html") => {
            let html = tokio::task::spawn_blocking(move || {
                repose_campaign::report_html(&campaign, &results, &pictures)
            })
            .await
            .map_err(|err| AppError::Internal(format!("report task: {err}")))?;
            Ok(([(header::CONTENT_TYPE, "text/html; charset=utf-8")], html).into_response())
        }
        Some(other) => Err(AppError::BadRequest(format!(
            "unknown format `{other}` (expected html or json)"
        ))),
    }
}
