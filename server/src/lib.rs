//! The repose job server: batches of DEM runs submitted over REST, leased to workers over HTTP,
//! analysed when the last run finishes.
//!
//! Structure follows the axum examples: [`Config`] → [`AppState::open`] (database + migrations)
//! → [`app`] (the router) → [`serve`] (listener + graceful shutdown). Only the `db` module touches SQL.
//!
//! ```no_run
//! # async fn run() -> Result<(), repose_server::ServeError> {
//! let config = repose_server::Config::new("repose.sqlite");
//! let listener = tokio::net::TcpListener::bind(config.listen).await?;
//! repose_server::serve(config, listener, async {
//!     let _ = tokio::signal::ctrl_c().await;
//! })
//! .await
//! # }
//! ```

use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::net::TcpListener;
use tokio::sync::{watch, Notify};

mod analysis;
pub mod auth;
mod campaigns;
mod db;
mod error;
mod metrics;
mod orchestrate;
mod page;
mod routes;
mod submit;
pub mod tokens;
mod types;

pub use auth::{Access, TokenRole};
pub use db::{backup, BackupError, BackupReport};
pub use error::AppError;
pub use orchestrate::RUNS_LOG_TARGET;
pub use routes::{app, Endpoint, Verb, ENDPOINTS};
pub use tokens::{create_token, list_tokens, revoke_token, TokenInfo};
pub use types::ServeError;

/// Server settings; the command line fills this from its flags.
#[derive(Debug, Clone)]
pub struct Config {
    /// Address the command line binds; [`serve`] itself takes a ready listener.
    pub listen: SocketAddr,
    /// SQLite database file, created (with its schema) if missing.
    pub db_path: PathBuf,
    /// How long a claim or heartbeat keeps a job leased.
    pub lease: Duration,
    /// Leases a job may use up (failures and expiries) before it is marked dead.
    pub max_attempts: u32,
    /// Delay before the first retry of a failed job; doubles with each further attempt.
    pub retry_backoff: Duration,
    /// Largest accepted request body.
    pub body_limit_bytes: usize,
    /// Upper bound of a claim's long-poll wait.
    pub max_claim_wait: Duration,
    /// Let requests without a token use the read-only (GET) endpoints; everything else still
    /// needs a token.
    pub open_read: bool,
    /// Users read only their own batches and campaigns (and the jobs of their batches); worker
    /// tokens read only the jobs of the workers they registered. Off: any token reads all.
    pub private_reads: bool,
    /// `synchronous=FULL`: every acknowledged write survives a power loss (see the README's
    /// durability section); the default `NORMAL` survives a crash of the server process.
    pub durability_full: bool,
    /// Cap on the database's size in SQLite pages (`max_page_count`); writes beyond it fail as
    /// on a full disk. `None`: no cap. The fault-injection tests use it to fill the "disk".
    pub max_db_pages: Option<u64>,
    /// A client must send a request's headers within this time, or its connection is closed.
    pub header_read_timeout: Duration,
    /// After the shutdown signal, in-flight requests get this long to finish; connections
    /// still open then are dropped.
    pub shutdown_grace: Duration,
    /// How often expired leases are returned to the queue even when no worker claims.
    pub reclaim_interval: Duration,
    /// The release this server reports (`/healthz`) and accepts workers of (same
    /// `MAJOR.MINOR`, see [`repose_api::version`]). Always this build's release, except in
    /// tests that pretend an upgrade.
    pub release: repose_api::ReleaseVersion,
}

impl Config {
    /// Defaults: listen on 127.0.0.1:8080, 60 s leases, 3 attempts, 5 s first back-off,
    /// 8 MiB bodies, 30 s long-poll, every endpoint but `/healthz` behind a token.
    pub fn new(db_path: impl Into<PathBuf>) -> Self {
        Config {
            listen: SocketAddr::from(([127, 0, 0, 1], 8080)),
            db_path: db_path.into(),
            lease: Duration::from_secs(60),
            max_attempts: 3,
            retry_backoff: Duration::from_secs(5),
            body_limit_bytes: 8 * 1024 * 1024,
            max_claim_wait: Duration::from_secs(30),
            open_read: false,
            private_reads: false,
            durability_full: false,
            max_db_pages: None,
            header_read_timeout: Duration::from_secs(30),
            shutdown_grace: Duration::from_secs(10),
            reclaim_interval: Duration::from_secs(1),
            release: repose_api::ReleaseVersion::current(),
        }
    }
}

/// Shared by every request handler; cheap to clone.
#[derive(Debug, Clone)]
pub struct AppState {
    pub(crate) db: db::Db,
    pub(crate) config: Arc<Config>,
    /// Woken when jobs become claimable (submission, release, failure), ending long-polls early.
    pub(crate) jobs_available: Arc<Notify>,
    /// Flips to `true` at shutdown so long-polls return instead of holding the server open.
    pub(crate) shutdown: watch::Receiver<bool>,
    /// Counters served by `GET /metrics`.
    pub(crate) metrics: Arc<metrics::Metrics>,
    shutdown_sender: Arc<watch::Sender<bool>>,
}

impl AppState {
    /// Opens (creating and migrating if needed) the database named in `config`.
    pub async fn open(config: Config) -> Result<Self, ServeError> {
        let db = db::Db::open_with(
            &config.db_path,
            &db::OpenOptions {
                durability_full: config.durability_full,
                max_pages: config.max_db_pages,
            },
        )
        .await?;
        let (shutdown_sender, shutdown) = watch::channel(false);
        Ok(AppState {
            db,
            config: Arc::new(config),
            jobs_available: Arc::new(Notify::new()),
            shutdown,
            metrics: Arc::default(),
            shutdown_sender: Arc::new(shutdown_sender),
        })
    }

    /// Ends pending long-polls; called by [`serve`] when its shutdown future resolves.
    pub fn begin_shutdown(&self) {
        self.shutdown_sender.send_replace(true);
    }

    /// Closes the database pools (flushing the WAL) once no request uses them any more.
    pub async fn close(&self) {
        self.db.close().await;
    }
}

/// Runs the server on `listener` until `shutdown` resolves, then stops accepting, gives
/// in-flight requests up to [`Config::shutdown_grace`] to finish, ends long-polls and closes the
/// database. A client that does not send its headers within [`Config::header_read_timeout`]
/// is disconnected, so no connection can hold the server open.
pub async fn serve(
    config: Config,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServeError> {
    use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
    use hyper_util::server::conn::auto::Builder;
    use hyper_util::service::TowerToHyperService;

    let state = AppState::open(config).await?;
    if let Ok(addr) = listener.local_addr() {
        tracing::info!(%addr, db = %state.config.db_path.display(), "repose server listening");
    }
    // Campaigns whose batch finished while the server was down continue now.
    let resuming = state.clone();
    tokio::spawn(async move { campaigns::resume_all(&resuming).await });
    let reclaimer = tokio::spawn(orchestrate::reclaim_expired_leases(state.clone()));

    let router = app(state.clone());
    let mut builder = Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(state.config.header_read_timeout);
    let graceful = hyper_util::server::graceful::GracefulShutdown::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            accepted = listener.accept() => {
                let stream = match accepted {
                    Ok((stream, _)) => stream,
                    Err(err) => {
                        // Out of file descriptors and the like: back off instead of spinning.
                        tracing::warn!(error = %err, "accepting a connection failed");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                let service = TowerToHyperService::new(router.clone());
                let connection = builder
                    .serve_connection_with_upgrades(TokioIo::new(stream), service)
                    .into_owned();
                let connection = graceful.watch(connection);
                tokio::spawn(async move {
                    if let Err(err) = connection.await {
                        tracing::debug!(error = %err, "connection ended with an error");
                    }
                });
            }
            () = &mut shutdown => break,
        }
    }
    drop(listener);
    state.begin_shutdown();
    reclaimer.abort();
    if tokio::time::timeout(state.config.shutdown_grace, graceful.shutdown())
        .await
        .is_err()
    {
        tracing::warn!(
            grace_s = state.config.shutdown_grace.as_secs_f64(),
            "connections still open after the shutdown grace period; dropping them"
        );
    }
    state.close().await;
    Ok(())
}
