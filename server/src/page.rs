//! The status page at `/`: server-rendered HTML (no scripts, no front-end build) showing
//! batches with progress and time left, campaigns with their stage and report, workers with
//! what they run, and dead runs with their errors. Plus its sign-in and sign-out.
//!
//! Who may read it is decided by [`crate::auth::page_reader`] under the same rules as the API's
//! reads (`open_read`, `private_reads`); this module gathers what that reader may see through
//! the `db` module's reads, and words everything. All text is written through `maud`, which
//! escapes it, so a batch name or an error message is shown as text, never as markup.
//!
//! Sign-in (`POST /sign-in`, a form with one `token` field) stores an accepted token in the
//! [`SESSION_COOKIE`] with `HttpOnly` and `SameSite=Strict`; the token never appears in a URL.
//! A refused token gets the form again with 401 and no cookie. Both forms refuse a cross-site
//! post (an `Origin` that is not this server's).

use std::collections::HashMap;

use axum::extract::rejection::FormRejection;
use axum::extract::State;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Form, Router};
use maud::{html, Markup, PreEscaped, DOCTYPE};
use repose_api::{BackendKind, BatchState, BatchSummary, JobView, RunState, WorkerView};
use serde::Deserialize;
use uuid::Uuid;

use crate::auth::{cookie_token, page_reader, Caller, PageReader, SignInReason, SESSION_COOKIE};
use crate::db::{now_ms, CampaignRecord, ReadScope};
use crate::error::AppError;
use crate::routes::scope_of;
use crate::AppState;

/// Batches shown, newest first.
const PAGE_BATCHES: u32 = 50;
/// Active batches whose time left is looked up (one query each).
const PAGE_ETA_LOOKUPS: usize = 20;
/// Campaigns shown, newest first.
const PAGE_CAMPAIGNS: u32 = 20;
/// Workers shown, most recently seen first.
const PAGE_WORKERS: u32 = 100;
/// Running jobs looked up to say what each worker runs.
const PAGE_RUNNING_JOBS: u32 = 1000;
/// Dead runs shown, most recent first.
const PAGE_DEAD_RUNS: u32 = 50;
/// Characters of a dead run's error shown on the page (the whole text is in `GET /v1/jobs`).
const PAGE_ERROR_CHARS: usize = 600;
/// How long the sign-in cookie lives, seconds (revoking the token ends it at once anyway).
const COOKIE_MAX_AGE_S: u64 = 30 * 24 * 3600;
/// The page reloads itself this often, seconds.
const REFRESH_S: u32 = 15;

/// The page's routes; merged into the API router by [`crate::routes::app`].
pub(crate) fn routes() -> Router<AppState> {
    Router::new()
        .route("/", get(status_page))
        .route("/sign-in", post(sign_in))
        .route("/sign-out", post(sign_out))
}

/// The token a page request presents: an `Authorization: Bearer` header (for scripts), else
/// the sign-in cookie.
fn presented_token(headers: &HeaderMap) -> Option<&str> {
    match crate::auth::bearer(headers) {
        Ok(Some(token)) => Some(token),
        _ => cookie_token(headers),
    }
}

async fn status_page(
    State(state): State<AppState>,
    headers: HeaderMap,
) -> Result<Response, AppError> {
    let token = presented_token(&headers);
    match page_reader(&state, token).await? {
        PageReader::Allowed(caller) => {
            let data = gather(&state, caller.as_ref()).await?;
            let signed_in = cookie_token(&headers).is_some() && caller.is_some();
            Ok(html_response(
                StatusCode::OK,
                render_status(&data, caller.as_ref(), signed_in),
            ))
        }
        PageReader::SignIn(reason) => {
            let mut response = sign_in_response(reason);
            // A cookie whose token is no longer accepted is dropped.
            if reason == SignInReason::Refused && cookie_token(&headers).is_some() {
                response
                    .headers_mut()
                    .insert(header::SET_COOKIE, clear_cookie());
            }
            Ok(response)
        }
    }
}

#[derive(Debug, Deserialize)]
struct SignInForm {
    token: String,
}

async fn sign_in(
    State(state): State<AppState>,
    headers: HeaderMap,
    form: Result<Form<SignInForm>, FormRejection>,
) -> Result<Response, AppError> {
    if !same_origin(&headers) {
        return Ok(cross_site_response());
    }
    let Form(form) = form.map_err(|rejection| {
        AppError::BadRequest(format!(
            "the sign-in form needs a `token` field (application/x-www-form-urlencoded): {}",
            rejection.body_text()
        ))
    })?;
    let token = form.token.trim();
    match page_reader(&state, Some(token)).await? {
        PageReader::Allowed(Some(caller)) => {
            tracing::info!(token = %caller.name, "signed in to the status page");
            let mut response = redirect_home();
            response
                .headers_mut()
                .insert(header::SET_COOKIE, session_cookie(token, &headers)?);
            Ok(response)
        }
        // Not reachable with a token; treated as a refusal all the same.
        PageReader::Allowed(None) => Ok(sign_in_response(SignInReason::Refused)),
        PageReader::SignIn(reason) => Ok(sign_in_response(reason)),
    }
}

async fn sign_out(headers: HeaderMap) -> Response {
    if !same_origin(&headers) {
        return cross_site_response();
    }
    let mut response = redirect_home();
    response
        .headers_mut()
        .insert(header::SET_COOKIE, clear_cookie());
    response
}

/// Whether a form post comes from this server's own page: no `Origin` (not a browser, or an
/// old one) or an `Origin` naming the `Host` the request was sent to.
fn same_origin(headers: &HeaderMap) -> bool {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return true;
    };
    let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
    let authority = origin
        .to_str()
        .ok()
        .and_then(|o| o.split_once("://"))
        .map(|(_, authority)| authority);
    matches!((authority, host), (Some(a), Some(h)) if a.eq_ignore_ascii_case(h))
}

/// The `Set-Cookie` value keeping `token` (already accepted, so made of `[a-z0-9_]` only).
/// `Secure` is added when a TLS-terminating proxy says the page was fetched over HTTPS.
fn session_cookie(token: &str, headers: &HeaderMap) -> Result<HeaderValue, AppError> {
    let https = headers
        .get("x-forwarded-proto")
        .and_then(|v| v.to_str().ok())
        .is_some_and(|proto| proto.eq_ignore_ascii_case("https"));
    let secure = if https { "; Secure" } else { "" };
    HeaderValue::from_str(&format!(
        "{SESSION_COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict; Max-Age={COOKIE_MAX_AGE_S}{secure}"
    ))
    .map_err(|_| AppError::Internal("an accepted token is not a header value".into()))
}

fn clear_cookie() -> HeaderValue {
    HeaderValue::from_static("repose_token=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0")
}

fn redirect_home() -> Response {
    (StatusCode::SEE_OTHER, [(header::LOCATION, "/")]).into_response()
}

fn html_response(status: StatusCode, markup: Markup) -> Response {
    (
        status,
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        markup.into_string(),
    )
        .into_response()
}

/// The sign-in form, with the status that fits `reason`.
fn sign_in_response(reason: SignInReason) -> Response {
    let status = match reason {
        SignInReason::NoToken => StatusCode::OK,
        SignInReason::Refused => StatusCode::UNAUTHORIZED,
        SignInReason::WorkerToken => StatusCode::FORBIDDEN,
    };
    let mut response = html_response(status, render_sign_in(reason));
    if status == StatusCode::UNAUTHORIZED {
        response.headers_mut().insert(
            header::WWW_AUTHENTICATE,
            HeaderValue::from_static("Bearer realm=\"repose\""),
        );
    }
    response
}

fn cross_site_response() -> Response {
    html_response(
        StatusCode::FORBIDDEN,
        layout(
            "repose: refused",
            None,
            html! {
                h1 { "repose" }
                p.notice { "This form was posted from another site, so it was refused. \
                            Open the status page of this server and use its form." }
                p { a href="/" { "Status page" } }
            },
        ),
    )
}

// ---------------------------------------------------------------------------------------------
// What the page shows
// ---------------------------------------------------------------------------------------------

/// Everything the status page shows, as read for one reader.
#[derive(Debug)]
struct StatusData {
    now_ms: i64,
    lease_ms: i64,
    open_read: bool,
    batches: Vec<BatchLine>,
    campaigns: Vec<CampaignRecord>,
    workers: Vec<WorkerLine>,
    dead: Vec<JobView>,
    /// Names of the batches listed, for the jobs that point at them.
    batch_names: HashMap<Uuid, String>,
}

#[derive(Debug)]
struct BatchLine {
    summary: BatchSummary,
    eta_s: Option<f64>,
}

#[derive(Debug)]
struct WorkerLine {
    view: WorkerView,
    running: Vec<JobView>,
}

/// Reads what `caller` may see: the batches and campaigns of its scope (its own with private
/// reads), all workers (as `GET /v1/workers`), and the running and dead jobs of its scope.
async fn gather(state: &AppState, caller: Option<&Caller>) -> Result<StatusData, AppError> {
    let scope = scope_of(state, caller);
    let owner = match scope {
        ReadScope::User(name) => Some(name),
        _ => None,
    };
    let summaries = state.db.list_batches(PAGE_BATCHES, owner).await?;
    let mut batches = Vec::with_capacity(summaries.len());
    let mut eta_lookups = 0;
    for summary in summaries {
        let eta_s = if summary.state == BatchState::Active && eta_lookups < PAGE_ETA_LOOKUPS {
            eta_lookups += 1;
            state
                .db
                .batch_status(summary.id)
                .await?
                .and_then(|status| status.eta_s)
        } else {
            None
        };
        batches.push(BatchLine { summary, eta_s });
    }
    let campaigns = state.db.list_campaigns(PAGE_CAMPAIGNS, owner).await?;
    let running = state
        .db
        .list_jobs(Some(RunState::Running), None, PAGE_RUNNING_JOBS, scope)
        .await?;
    let workers = state
        .db
        .list_workers(PAGE_WORKERS)
        .await?
        .into_iter()
        .map(|view| WorkerLine {
            running: running
                .iter()
                .filter(|job| job.worker_id == Some(view.id))
                .cloned()
                .collect(),
            view,
        })
        .collect();
    let dead = state
        .db
        .list_jobs(Some(RunState::Dead), None, PAGE_DEAD_RUNS, scope)
        .await?;
    let batch_names = batches
        .iter()
        .map(|line| (line.summary.id, line.summary.name.clone()))
        .collect();
    Ok(StatusData {
        now_ms: now_ms(),
        lease_ms: i64::try_from(state.config.lease.as_millis()).unwrap_or(i64::MAX),
        open_read: state.config.open_read && !state.config.private_reads,
        batches,
        campaigns,
        workers,
        dead,
        batch_names,
    })
}

// ---------------------------------------------------------------------------------------------
// Rendering (pure; every word of the page is here)
// ---------------------------------------------------------------------------------------------

const STYLE: &str = "
body{font:14px/1.4 system-ui,sans-serif;margin:1.5em auto;max-width:76em;padding:0 1em;color:#1d2330}
h1{font-size:1.5em;margin:0}h2{font-size:1.15em;margin:1.6em 0 .4em}
header{display:flex;justify-content:space-between;align-items:baseline;border-bottom:1px solid #ccd;padding-bottom:.4em}
table{border-collapse:collapse;width:100%}th,td{text-align:left;padding:.3em .6em;border-bottom:1px solid #e4e6ee;vertical-align:top}
th{font-weight:600;color:#4a5163;background:#f5f6fa}td.num{text-align:right;font-variant-numeric:tabular-nums}
.bar{display:flex;width:12em;height:.8em;background:#e4e6ee;border-radius:3px;overflow:hidden;margin-top:.25em}
.bar .completed{background:#2e8b57}.bar .dead{background:#c0392b}.bar .running{background:#3b7dd8}
.muted{color:#6b7285}.state-active{color:#3b7dd8}.state-completed{color:#2e8b57}.state-cancelled{color:#6b7285}
.state-needs_attention,.error{color:#a02a1e}pre.error{white-space:pre-wrap;margin:0;font-size:.9em;max-width:40em}
.notice{background:#fff6e0;border:1px solid #e8c770;padding:.6em .8em;border-radius:4px}
td.nowrap{white-space:nowrap}form.inline{display:inline}input[type=password]{width:26em;padding:.3em}button{padding:.3em .9em}
";

/// A whole page; `refresh_s`: reload itself this often.
fn layout(title: &str, refresh_s: Option<u32>, body: Markup) -> Markup {
    html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                meta name="viewport" content="width=device-width, initial-scale=1";
                @if let Some(seconds) = refresh_s { meta http-equiv="refresh" content=(seconds); }
                title { (title) }
                style { (PreEscaped(STYLE)) }
            }
            body { (body) }
        }
    }
}

/// The sign-in form, saying why it is shown.
fn render_sign_in(reason: SignInReason) -> Markup {
    let notice = match reason {
        SignInReason::NoToken => None,
        SignInReason::Refused => Some(
            "That token was not accepted: it is malformed, unknown or revoked. \
             Check it and try again.",
        ),
        SignInReason::WorkerToken => Some(
            "This server keeps reads private, and a worker token reads only its own jobs. \
             Sign in with a user token.",
        ),
    };
    layout(
        "repose: sign in",
        None,
        html! {
            header { h1 { "repose" } span.muted { "job server " (env!("CARGO_PKG_VERSION")) } }
            h2 { "Sign in" }
            @if let Some(notice) = notice { p.notice { (notice) } }
            p { "This server shows its batches to token holders. Paste your token \
                 (from " code { "repose token create NAME" } "); it is kept in a cookie \
                 of this browser that scripts cannot read." }
            form method="post" action="/sign-in" {
                label { "Token " input type="password" name="token" autocomplete="off"
                    placeholder="rp_user_…" required; }
                " "
                button type="submit" { "Sign in" }
            }
        },
    )
}

/// The status page for `caller` (`None`: anonymous under open reads).
fn render_status(data: &StatusData, caller: Option<&Caller>, signed_in: bool) -> Markup {
    let active = data
        .batches
        .iter()
        .filter(|b| b.summary.state == BatchState::Active)
        .count();
    let live_workers = data
        .workers
        .iter()
        .filter(|w| data.now_ms - w.view.last_seen_at_ms <= data.lease_ms)
        .count();
    layout(
        "repose: status",
        Some(REFRESH_S),
        html! {
            header {
                h1 { "repose" }
                span.muted {
                    "job server " (env!("CARGO_PKG_VERSION")) " · "
                    @match caller {
                        Some(caller) => { "reading as " strong { (caller.name) } " (" (caller.role) " token)" }
                        None => { "open for reading" }
                    }
                    @if signed_in {
                        " · "
                        form.inline method="post" action="/sign-out" {
                            button type="submit" { "Sign out" }
                        }
                    }
                }
            }
            p {
                (count(active, "active batch", "active batches")) " · "
                (count(live_workers, "worker", "workers")) " seen within a lease · "
                (count(data.dead.len(), "dead run", "dead runs")) " listed"
                span.muted { " · refreshes every " (REFRESH_S) " s" }
            }
            (batches_section(data))
            (campaigns_section(data))
            (workers_section(data))
            (dead_section(data))
            @if data.open_read && caller.is_none() {
                p.muted { "Anyone may read this server. To act on it, use the API with a token." }
            }
        },
    )
}

fn batches_section(data: &StatusData) -> Markup {
    html! {
        h2 { "Batches" }
        @if data.batches.is_empty() {
            p.muted { "No batches yet." }
        } @else {
            table {
                tr { th { "Name" } th { "Kind" } th { "State" } th { "Progress" } th { "Time left" }
                     th { "Submitted" } th { "Owner" } th { "Data" } }
                @for line in &data.batches {
                    @let b = &line.summary;
                    tr {
                        td { (b.name) br; span.muted { code { (short_id(b.id)) } } }
                        td { (b.kind) @if b.backend == BackendKind::Gpu { br; span.muted { "on the GPU" } } }
                        td {
                            span class=(format!("state-{}", batch_state_word(b.state))) { (batch_state_word(b.state)) }
                            @if let Some(wait) = b.gpu_wait { br; span.error { (wait) } }
                        }
                        td { (progress(b)) }
                        td.nowrap { (time_left(line)) }
                        td { (ago(data.now_ms, b.created_at_ms)) }
                        td { (b.owner.as_deref().unwrap_or("—")) }
                        td.nowrap {
                            a href=(format!("/v1/batches/{}/runs?format=csv", b.id)) { "runs (CSV)" }
                            @if b.state == BatchState::Completed {
                                br;
                                a href=(format!("/v1/batches/{}/analysis?format=text", b.id)) { "analysis" }
                            }
                        }
                    }
                }
            }
        }
    }
}

/// A stacked bar (completed, dead, running) and the counts in words.
fn progress(b: &BatchSummary) -> Markup {
    let total = b.counts.total().max(1) as f64;
    let width = |n: u64| format!("width:{:.1}%", 100.0 * n as f64 / total);
    html! {
        (b.counts.finished()) " of " (b.counts.total()) " runs finished (" (format!("{:.0}", b.percent_done)) " %)"
        @if b.counts.running > 0 { ", " (b.counts.running) " running" }
        @if b.counts.dead > 0 { ", " span.error { (b.counts.dead) " dead" } }
        @if b.counts.cancelled > 0 { ", " (b.counts.cancelled) " cancelled" }
        div.bar title=(format!("{:.0} % finished", b.percent_done)) {
            span.completed style=(width(b.counts.completed)) {}
            span.dead style=(width(b.counts.dead)) {}
            span.running style=(width(b.counts.running)) {}
        }
    }
}

fn time_left(line: &BatchLine) -> Markup {
    match (line.summary.state, line.eta_s) {
        (BatchState::Active, Some(eta)) => html! { "about " (duration(eta)) },
        (BatchState::Active, None) => html! { span.muted { "after the first result" } },
        _ => html! { span.muted { "—" } },
    }
}

fn campaigns_section(data: &StatusData) -> Markup {
    html! {
        h2 { "Campaigns" }
        @if data.campaigns.is_empty() {
            p.muted { "No campaigns." }
        } @else {
            table {
                tr { th { "Name" } th { "Status" } th { "Stage" } th { "Batches" } th { "Last change" } th { "Report" } }
                @for c in &data.campaigns {
                    tr {
                        td { (c.name) br; span.muted { code { (short_id(c.id)) } } }
                        td {
                            span class=(format!("state-{}", c.status)) { (c.status.replace('_', " ")) }
                            @if let Some(wait) = c.gpu_wait { br; span.error { (wait) } }
                        }
                        td { (c.stage.replace('_', " ")) }
                        td.num { (c.batches_issued) }
                        td { (ago(data.now_ms, c.updated_at_ms)) }
                        td { a href=(format!("/v1/campaigns/{}/report", c.id)) { "report" } }
                    }
                }
            }
        }
    }
}

fn workers_section(data: &StatusData) -> Markup {
    html! {
        h2 { "Workers" }
        @if data.workers.is_empty() {
            p.muted { "No worker has registered." }
        } @else {
            table {
                tr { th { "Host" } th { "Threads" } th { "Version" } th { "Last seen" } th { "Running" } }
                @for w in &data.workers {
                    tr {
                        td { (w.view.host) br; span.muted { code { (short_id(w.view.id)) } } }
                        td.num {
                            (w.view.threads)
                            @if let Some(gpu) = &w.view.gpu {
                                br; span.muted {
                                    "GPU " (gpu)
                                    @if let Some(bytes) = w.view.gpu_memory_bytes {
                                        ", " (format!("{:.0}", bytes as f64 / f64::from(1u32 << 30))) " GiB"
                                    }
                                    @if let Some(slots) = w.view.gpu_slots {
                                        ", " (w.view.gpu_running_jobs) " of " (slots) " GPU slots busy"
                                    }
                                }
                            }
                        }
                        td { (w.view.version) }
                        td {
                            (ago(data.now_ms, w.view.last_seen_at_ms))
                            @if data.now_ms - w.view.last_seen_at_ms > data.lease_ms {
                                br; span.muted { "silent for longer than a lease" }
                            }
                        }
                        td {
                            @if w.running.is_empty() {
                                @if w.view.running_jobs > 0 {
                                    (count(w.view.running_jobs as usize, "run", "runs")) " of other users"
                                } @else {
                                    span.muted { "idle" }
                                }
                            }
                            @for (i, job) in w.running.iter().enumerate() {
                                @if i > 0 { br; }
                                (batch_name(data, job.batch_id)) ", run " (job.run_index)
                                @if let Some(p) = job.progress { " — " (format!("{:.0}", 100.0 * p)) " %" }
                            }
                        }
                    }
                }
            }
        }
    }
}

fn dead_section(data: &StatusData) -> Markup {
    html! {
        h2 { "Dead runs" }
        @if data.dead.is_empty() {
            p.muted { "None: every failed run was retried successfully or is still being retried." }
        } @else {
            table {
                tr { th { "Batch" } th { "Run" } th { "Attempts" } th { "Died" } th { "Last error" } }
                @for job in &data.dead {
                    tr {
                        td { (batch_name(data, job.batch_id)) }
                        td.num { (job.run_index) }
                        td.num { (job.attempts) }
                        td { (ago(data.now_ms, job.updated_at_ms)) }
                        td { pre.error { (clip(job.last_error.as_deref().unwrap_or("(no message)"), PAGE_ERROR_CHARS)) } }
                    }
                }
            }
        }
    }
}

fn batch_name(data: &StatusData, id: Uuid) -> String {
    data.batch_names
        .get(&id)
        .cloned()
        .unwrap_or_else(|| format!("batch {}", short_id(id)))
}

fn batch_state_word(state: BatchState) -> &'static str {
    match state {
        BatchState::Active => "active",
        BatchState::Completed => "completed",
        BatchState::Cancelled => "cancelled",
    }
}

fn short_id(id: Uuid) -> String {
    id.simple().to_string()[..8].to_owned()
}

fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// At most `max` characters of `text`, with "…" when cut.
fn clip(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        Some((cut, _)) => format!("{}…", &text[..cut]),
        None => text.to_owned(),
    }
}

/// "12 s", "4 min 10 s", "3 h 5 min", "2 d 4 h".
fn duration(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match s {
        0..60 => format!("{s} s"),
        60..3600 => format!("{} min {} s", s / 60, s % 60),
        3600..86_400 => format!("{} h {} min", s / 3600, (s % 3600) / 60),
        _ => format!("{} d {} h", s / 86_400, (s % 86_400) / 3600),
    }
}

fn ago(now_ms: i64, then_ms: i64) -> String {
    let seconds = (now_ms - then_ms) as f64 / 1000.0;
    if seconds < 2.0 {
        "just now".to_owned()
    } else {
        format!("{} ago", duration(seconds))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_naturally() {
        assert_eq!(duration(0.4), "0 s");
        assert_eq!(duration(59.4), "59 s");
        assert_eq!(duration(250.0), "4 min 10 s");
        assert_eq!(duration(3.0 * 3600.0 + 300.0), "3 h 5 min");
        assert_eq!(duration(2.0 * 86_400.0 + 4.0 * 3600.0), "2 d 4 h");
        assert_eq!(ago(10_000, 9_500), "just now");
        assert_eq!(ago(100_000, 10_000), "1 min 30 s ago");
    }

    #[test]
    fn clipping_respects_characters() {
        assert_eq!(clip("abc", 5), "abc");
        assert_eq!(clip("äöüß", 2), "äö…");
    }

    #[test]
    fn cross_site_posts_are_recognised() {
        let mut headers = HeaderMap::new();
        assert!(same_origin(&headers), "no Origin: not a browser form");
        headers.insert(header::HOST, "127.0.0.1:8080".parse().unwrap());
        headers.insert(header::ORIGIN, "http://127.0.0.1:8080".parse().unwrap());
        assert!(same_origin(&headers));
        headers.insert(header::ORIGIN, "https://evil.example".parse().unwrap());
        assert!(!same_origin(&headers));
        headers.insert(header::ORIGIN, "null".parse().unwrap());
        assert!(!same_origin(&headers));
    }

    #[test]
    fn sign_in_page_has_the_form_and_the_reason() {
        let page = render_sign_in(SignInReason::Refused).into_string();
        assert!(page.contains("action=\"/sign-in\""));
        assert!(page.contains("type=\"password\""));
        assert!(page.contains("not accepted"));
    }
}
