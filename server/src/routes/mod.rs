//! The HTTP API: the route table [`ENDPOINTS`] (the one list of paths, handlers and access
//! rules: the router is built from it, and the OpenAPI test checks `api/openapi.json` against
//! it), the router, and what the handlers share: the JSON body and path-id extractors and the
//! read policy (who may read what). The handlers and their request types live by resource:
//! [`batches`], [`jobs`] (listing, the claim long-poll, heartbeats and results), [`workers`],
//! [`campaigns`], and [`service`] (health, the API description, metrics). State changes are
//! delegated to [`crate::db`], validation of submissions to [`crate::submit`]; every error,
//! storage failures included, becomes an HTTP status in one place, [`crate::error`].

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{DefaultBodyLimit, FromRequest, Path, Request};
use axum::middleware;
use axum::routing::{on, MethodFilter, MethodRouter};
use axum::{Extension, Router};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use uuid::Uuid;

use crate::auth::{authorize, Access, Caller};
use crate::db::ReadScope;
use crate::error::AppError;
use crate::AppState;

mod batches;
mod campaigns;
mod jobs;
mod service;
mod workers;

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
    ep(Verb::Get, "/healthz", Access::Public, |m| {
        on(m, service::health)
    }),
    ep(Verb::Get, "/openapi.json", Access::Public, |m| {
        on(m, service::openapi)
    }),
    ep(Verb::Get, "/metrics", Access::Read, |m| {
        on(m, service::metrics)
    }),
    ep(Verb::Post, "/v1/batches", Access::User, |m| {
        on(m, batches::create_batch)
    }),
    ep(Verb::Get, "/v1/batches", Access::Read, |m| {
        on(m, batches::list_batches)
    }),
    ep(Verb::Get, "/v1/batches/{id}", Access::Read, |m| {
        on(m, batches::batch_status)
    }),
    ep(Verb::Get, "/v1/batches/{id}/runs", Access::Read, |m| {
        on(m, batches::batch_runs)
    }),
    ep(Verb::Post, "/v1/batches/{id}/cancel", Access::User, |m| {
        on(m, batches::cancel_batch)
    }),
    ep(Verb::Get, "/v1/batches/{id}/analysis", Access::Read, |m| {
        on(m, batches::batch_analysis)
    }),
    ep(Verb::Post, "/v1/campaigns", Access::User, |m| {
        on(m, campaigns::create_campaign)
    }),
    ep(Verb::Get, "/v1/campaigns", Access::Read, |m| {
        on(m, campaigns::list_campaigns)
    }),
    ep(Verb::Get, "/v1/campaigns/{id}", Access::Read, |m| {
        on(m, campaigns::campaign_status)
    }),
    ep(Verb::Get, "/v1/campaigns/{id}/report", Access::Read, |m| {
        on(m, campaigns::campaign_report)
    }),
    ep(Verb::Get, "/v1/workers", Access::Read, |m| {
        on(m, workers::list_workers)
    }),
    ep(Verb::Get, "/v1/jobs", Access::Read, |m| {
        on(m, jobs::list_jobs)
    }),
    ep(Verb::Post, "/v1/workers/register", Access::Worker, |m| {
        on(m, workers::register_worker)
    }),
    ep(Verb::Post, "/v1/jobs/claim", Access::Worker, |m| {
        on(m, jobs::claim_job)
    }),
    ep(Verb::Post, "/v1/jobs/{id}/heartbeat", Access::Worker, |m| {
        on(m, jobs::heartbeat)
    }),
    ep(Verb::Post, "/v1/jobs/{id}/complete", Access::Worker, |m| {
        on(m, jobs::complete_job)
    }),
    ep(Verb::Post, "/v1/jobs/{id}/fail", Access::Worker, |m| {
        on(m, jobs::fail_job)
    }),
    ep(Verb::Post, "/v1/jobs/{id}/release", Access::Worker, |m| {
        on(m, jobs::release_job)
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

/// With private reads, the user a list of batches or campaigns is narrowed to.
fn owner_filter<'a>(state: &AppState, reader: &'a Reader) -> Option<&'a str> {
    match read_scope(state, reader) {
        ReadScope::User(name) => Some(name),
        _ => None,
    }
}

/// `?format=` of the endpoints that answer in more than one format.
#[derive(Debug, Deserialize)]
struct FormatQuery {
    format: Option<String>,
}
