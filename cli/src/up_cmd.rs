//! `repose up`: the whole service on one machine — a job server on an SQLite file and N local
//! workers in one process — optionally submitting batch files and following them to their
//! analysis.
//!
//! Shutdown order matters: workers stop first (they release the jobs they hold, so nothing is
//! half-done in the database), then the server drains and closes the database. After a crash
//! or a kill there was no such release: the local workers keep their ids from one start to the
//! next, and registering again puts the jobs they held back in the queue; the ids of workers an
//! earlier start had beyond this start's `--workers` are registered once at start-up for the
//! same reason.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::Args;
use repose_api::BatchState;
use repose_server::{serve, Config};
use repose_worker::WorkerConfig;
use tokio::sync::watch;

use crate::client::{progress_bar, read_batch_file, UserClient};

#[derive(Debug, Args)]
pub struct UpArgs {
    /// Local workers to start (each runs one job at a time).
    #[arg(long, env = "REPOSE_WORKERS", default_value_t = 2)]
    pub workers: usize,
    /// Threads per worker (default: cores / workers, at least 1).
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// SQLite database file (created and migrated if missing).
    #[arg(long, env = "REPOSE_DB", default_value = "repose.db")]
    pub db: PathBuf,
    /// Address to listen on (port 0: any free port).
    #[arg(long, env = "REPOSE_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// Lease length, seconds.
    #[arg(long, env = "REPOSE_LEASE_S", default_value_t = 60.0)]
    pub lease_s: f64,
    /// Attempts a run gets before it is dead: retries of a failure that may not happen again,
    /// and pours under a new seed of a run whose grains arched over the funnel's outlet.
    #[arg(long, env = "REPOSE_MAX_ATTEMPTS", default_value_t = 3)]
    pub max_attempts: u32,
    /// Batch file to submit once the service is up (repeatable; followed in order).
    #[arg(long, value_name = "FILE")]
    pub submit: Vec<PathBuf>,
    /// Campaign file to start once the service is up (repeatable; followed in order after the
    /// batches).
    #[arg(long, value_name = "FILE")]
    pub campaign: Vec<PathBuf>,
    /// Stop once every submitted batch and campaign has finished (default: serve until Ctrl-C).
    /// Without --submit or --campaign: once the batches and campaigns the database already
    /// holds unfinished have finished (e.g. after a restart in the middle of a long run).
    #[arg(long)]
    pub exit_when_done: bool,
    /// Keep each run's pictures under DIR/<run id>/.
    #[arg(long)]
    pub artifacts: Option<PathBuf>,
    /// Write the tokens `repose up` creates here as `export` lines (default: next to the
    /// database, `<db>.tokens.env`).
    #[arg(long)]
    pub tokens_file: Option<PathBuf>,
    /// Settled drilling beds, reused across runs with the same bed inputs (default: next to
    /// the database, `<db>.beds/`, created when the first bed is built).
    #[arg(long, value_name = "DIR")]
    pub bed_cache: Option<PathBuf>,
    /// Checkpoints of long runs: a run cut by a crash, a kill or Ctrl-C goes on from its last
    /// checkpoint when `repose up` is started again on the same database (default: next to the
    /// database, `<db>.checkpoints/`).
    #[arg(long, value_name = "DIR")]
    pub checkpoints: Option<PathBuf>,
    /// Wall-clock seconds between two checkpoints of a run.
    #[arg(long, value_name = "SECONDS", default_value_t = 300.0)]
    pub checkpoint_every: f64,
    /// Open a GPU at start and let the first local worker run the jobs of `"backend": "gpu"`
    /// batches on it, in its GPU slots (--gpu-slots), besides its CPU slot. No adapter is an
    /// error at start.
    #[arg(long)]
    pub gpu: bool,
    /// GPU jobs run at the same time on the GPU, sharing it (implies --gpu; default 1 with
    /// --gpu).
    #[arg(long, value_name = "N")]
    pub gpu_slots: Option<usize>,
    /// Device memory the GPU slots' runs may hold together, GiB (default: 90 % of the GPU's,
    /// where the driver tells it).
    #[arg(long, value_name = "GIB")]
    pub gpu_memory: Option<f64>,
    /// A run that reports no progress for SECONDS is stuck (a thread hung in a GPU driver): its
    /// job goes back to the queue and its local worker starts again (the stuck thread is left
    /// behind; a lost GPU is opened again). 0: never.
    #[arg(long, value_name = "SECONDS", default_value_t = 900.0)]
    pub stall_timeout: f64,
}

/// Validated settings.
#[derive(Debug)]
struct UpConfig {
    server: Config,
    workers: usize,
    threads: usize,
    submit: Vec<(PathBuf, serde_json::Value)>,
    campaigns: Vec<(PathBuf, serde_json::Value)>,
    exit_when_done: bool,
    artifacts: Option<PathBuf>,
    tokens_file: PathBuf,
    bed_cache: PathBuf,
    checkpoints: PathBuf,
    checkpoint_every: Duration,
    gpu_settings: Option<crate::backend::WorkerGpu>,
    gpu: Option<std::sync::Arc<repose_experiments::backend::Gpu>>,
    stall_timeout: Option<Duration>,
}

fn config(args: &UpArgs) -> Result<UpConfig> {
    if args.workers == 0 {
        bail!("--workers must be at least 1");
    }
    let max_lease = crate::server_cmd::MAX_LEASE_S;
    if !(args.lease_s.is_finite() && (1.0..=max_lease).contains(&args.lease_s)) {
        bail!(
            "--lease-s must be between 1 and {max_lease} seconds, got {}",
            args.lease_s
        );
    }
    if args.max_attempts == 0 {
        bail!("--max-attempts must be at least 1");
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = match args.threads {
        Some(0) => bail!("--threads must be at least 1"),
        Some(t) => t,
        None => (cores / args.workers).max(1),
    };
    // Read every batch file before starting anything, so a typo fails fast.
    let submit = args
        .submit
        .iter()
        .map(|path| Ok((path.clone(), read_batch_file(path)?)))
        .collect::<Result<Vec<_>>>()?;
    let campaigns = args
        .campaign
        .iter()
        .map(|path| Ok((path.clone(), read_batch_file(path)?)))
        .collect::<Result<Vec<_>>>()?;
    let mut server = Config::new(args.db.clone());
    server.listen = args.listen;
    server.lease = Duration::from_secs_f64(args.lease_s);
    server.max_attempts = args.max_attempts;
    let tokens_file = args.tokens_file.clone().unwrap_or_else(|| {
        let mut name = args.db.as_os_str().to_owned();
        name.push(".tokens.env");
        PathBuf::from(name)
    });
    let bed_cache = args.bed_cache.clone().unwrap_or_else(|| {
        let mut name = args.db.as_os_str().to_owned();
        name.push(".beds");
        PathBuf::from(name)
    });
    let checkpoints = args.checkpoints.clone().unwrap_or_else(|| {
        let mut name = args.db.as_os_str().to_owned();
        name.push(".checkpoints");
        PathBuf::from(name)
    });
    Ok(UpConfig {
        checkpoints,
        checkpoint_every: crate::worker_cmd::checkpoint_interval(args.checkpoint_every)?,
        bed_cache,
        server,
        workers: args.workers,
        threads,
        submit,
        campaigns,
        exit_when_done: args.exit_when_done,
        artifacts: args.artifacts.clone(),
        tokens_file,
        gpu_settings: crate::backend::worker_gpu(args.gpu, args.gpu_slots, args.gpu_memory)?,
        gpu: None,
        stall_timeout: crate::worker_cmd::stall_timeout(args.stall_timeout)?,
    })
}

pub fn run(args: &UpArgs) -> Result<()> {
    let mut config = config(args)?;
    config.gpu = crate::backend::open_worker_gpu(config.gpu_settings)?;
    // Warnings, and the server's one line per failed run, by default: the progress bar and the
    // analysis are the output here. The local workers' own lines about the same failures are
    // INFO under their crate's target, so each event shows once.
    crate::init_logging(&format!("warn,{}=info", repose_server::RUNS_LOG_TARGET));
    let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    let outcome = runtime.block_on(up(config));
    // A stalled run's thread never returns: end without waiting for it.
    runtime.shutdown_background();
    outcome
}

async fn up(config: UpConfig) -> Result<()> {
    let listener = tokio::net::TcpListener::bind(config.server.listen)
        .await
        .with_context(|| format!("cannot listen on {}", config.server.listen))?;
    let address = listener.local_addr()?;
    let url = format!("http://{address}");
    let tokens = local_tokens(&config.server.db_path, &config.tokens_file, &url)
        .await
        .context("cannot create the local tokens")?;

    let (stop_server, server_stopped) = watch::channel(false);
    let server = tokio::spawn(serve(config.server.clone(), listener, async move {
        let mut stopped = server_stopped;
        let _ = stopped.wait_for(|s| *s).await;
    }));

    let client = UserClient::new(&url, Some(tokens.user.clone()))?;
    let retired = take_back_retired_workers_jobs(&client, &url, &tokens.worker, &config)
        .await
        .context("cannot take back the jobs of an earlier start's workers")?;

    let (stop_workers, workers_stopped) = watch::channel(false);
    let mut workers = Vec::with_capacity(config.workers);
    for index in 0..config.workers {
        let mut worker = WorkerConfig::new(url.clone());
        worker.instance_id = Some(local_worker_id(&tokens.worker, index));
        worker.token = Some(tokens.worker.clone());
        worker.threads = config.threads;
        worker.artifacts_dir = config.artifacts.clone();
        worker.bed_cache = Some(config.bed_cache.clone());
        worker.checkpoint_dir = Some(config.checkpoints.clone());
        worker.checkpoint_every = config.checkpoint_every;
        if index == 0 {
            // The first local worker carries the GPU slots, beside its CPU slot.
            worker.gpu = config.gpu.clone();
            worker.gpu_slots = config.gpu_settings.map_or(0, |gpu| gpu.slots);
        }
        worker.stall_timeout = config.stall_timeout;
        let gpu_settings = config.gpu_settings;
        let stopped = workers_stopped.clone();
        workers.push(tokio::spawn(async move {
            // A local worker whose run stalled (its thread is stuck for good) or whose GPU was
            // lost has handed its jobs back and stopped: start it again, as a service manager
            // would (on a GPU opened again).
            loop {
                let mut stop = stopped.clone();
                let outcome = repose_worker::run(worker.clone(), async move {
                    let _ = stop.wait_for(|s| *s).await;
                })
                .await;
                match outcome {
                    Err(
                        failed @ (repose_worker::WorkerError::Stalled { .. }
                        | repose_worker::WorkerError::GpuFailed { .. }),
                    ) if !*stopped.borrow() => {
                        eprintln!("local worker {index}: {failed}; starting it again");
                        if worker.gpu.as_ref().is_some_and(|gpu| gpu.lost().is_some()) {
                            worker.gpu = tokio::task::spawn_blocking(move || {
                                crate::backend::open_worker_gpu(gpu_settings)
                            })
                            .await
                            .map_err(|e| {
                                repose_worker::WorkerError::Config(format!(
                                    "reopening the GPU: {e}"
                                ))
                            })?
                            .map_err(|e| repose_worker::WorkerError::Config(format!("{e:#}")))?;
                        }
                    }
                    other => return other,
                }
            }
        }));
    }
    // stdout: where things are, in a form a shell can use.
    println!(
        "repose up: server {url}, database {}",
        config.server.db_path.display()
    );
    println!(
        "  {} workers × {} threads; tokens in {} (source it for curl and repose submit/status)",
        config.workers,
        config.threads,
        config.tokens_file.display()
    );
    if let (Some(gpu), Some(settings)) = (&config.gpu, config.gpu_settings) {
        println!(
            "  worker 0 also runs GPU jobs on {} in {} GPU slot(s)",
            gpu.name(),
            settings.slots
        );
    }
    println!("  export REPOSE_SERVER={url}");
    println!("  export REPOSE_TOKEN={}", tokens.user);
    if retired > 0 {
        println!(
            "  {retired} job(s) held by local workers of an earlier start that this one does not \
             start (--workers {}) are back in the queue",
            config.workers
        );
    }

    let (outcome, interrupted) = tokio::select! {
        outcome = follow_submissions(&client, &config) => (outcome, false),
        () = crate::server_cmd::shutdown_signal() => (Ok(()), true),
    };
    if outcome.is_ok() && !interrupted && !config.exit_when_done {
        if !config.submit.is_empty() || !config.campaigns.is_empty() {
            println!("still serving at {url}; Ctrl-C to stop");
        }
        crate::server_cmd::shutdown_signal().await;
    }

    eprintln!("stopping workers (running jobs are released) …");
    stop_workers.send_replace(true);
    for worker in workers {
        match worker.await {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => eprintln!("a worker stopped with an error: {e}"),
            Err(e) => eprintln!("a worker task failed: {e}"),
        }
    }
    stop_server.send_replace(true);
    server
        .await
        .context("server task failed")?
        .context("server failed")?;
    outcome
}

/// The id of local worker `index`: the same every time `repose up` starts on this database
/// with its tokens file, so when it comes back after a crash or a kill the jobs its workers
/// held go back to the queue as they register (see `WorkerRegistration`), instead of waiting
/// out their lease. Derived from the local worker token (a name-based UUID, which does not
/// reveal the token), so a new token, which could not re-register the old ids, gets new ones.
fn local_worker_id(worker_token: &str, index: usize) -> uuid::Uuid {
    uuid::Uuid::new_v5(
        &uuid::Uuid::NAMESPACE_OID,
        format!("repose up local worker {index} {worker_token}").as_bytes(),
    )
}

/// Local worker indices looked at above `--workers` when taking back an earlier start's jobs.
const RETIRED_WORKER_SCAN: usize = 1024;

/// A start with fewer `--workers` than the last one: the jobs that the earlier start's
/// workers beyond this count held when it was killed go back to the queue now (each such id
/// is registered once, which releases its leases, as its own worker would on coming back),
/// instead of waiting out their lease. Only ids of this database's local worker token are
/// touched, so workers started elsewhere with their own ids keep their jobs. Returns the
/// number of jobs released.
async fn take_back_retired_workers_jobs(
    client: &UserClient,
    url: &str,
    worker_token: &str,
    config: &UpConfig,
) -> Result<u64> {
    let ids: std::collections::HashSet<uuid::Uuid> = (config.workers
        ..config.workers + RETIRED_WORKER_SCAN)
        .map(|index| local_worker_id(worker_token, index))
        .collect();
    let retired: Vec<_> = client
        .workers()
        .await?
        .into_iter()
        .filter(|w| w.running_jobs > 0 && ids.contains(&w.id))
        .collect();
    if retired.is_empty() {
        return Ok(0);
    }
    let worker = repose_worker::Client::new(url, Some(worker_token.to_owned()))?;
    for retired in &retired {
        worker
            .register(&repose_api::WorkerRegistration {
                instance_id: retired.id,
                host: retired.host.clone(),
                threads: retired.threads,
                version: repose_api::version::RELEASE.to_owned(),
                gpu: None,
                gpu_memory_bytes: None,
                gpu_slots: None,
            })
            .await?;
    }
    Ok(retired.iter().map(|w| w.running_jobs).sum())
}

/// Submits the batch files in order, follows each to its end and prints its analysis.
async fn follow_submissions(client: &UserClient, config: &UpConfig) -> Result<()> {
    let mut ids = Vec::new();
    for (path, batch) in &config.submit {
        let created = client
            .submit(batch)
            .await
            .with_context(|| format!("submitting {}", path.display()))?;
        println!(
            "submitted {} as batch {} ({} runs)",
            path.display(),
            created.id,
            created.run_count
        );
        ids.push(created.id);
    }
    let mut campaign_ids = Vec::new();
    for (path, document) in &config.campaigns {
        let created = client
            .start_campaign(document)
            .await
            .with_context(|| format!("starting the campaign {}", path.display()))?;
        println!(
            "started campaign {} from {} (first batch {})",
            created.id,
            path.display(),
            created.first_batch
        );
        campaign_ids.push(created.id);
    }
    if config.exit_when_done && ids.is_empty() && campaign_ids.is_empty() {
        // A restart: wait for what the database holds unfinished.
        ids = client
            .batches()
            .await?
            .into_iter()
            .filter(|b| b.state == BatchState::Active)
            .map(|b| b.id)
            .collect();
        campaign_ids = client
            .campaigns()
            .await?
            .into_iter()
            .filter(|c| c.status == "running")
            .map(|c| c.id)
            .collect();
        println!(
            "following {} unfinished batch(es) and {} campaign(s) of {}",
            ids.len(),
            campaign_ids.len(),
            config.server.db_path.display()
        );
    }
    let mut failed = Vec::new();
    for id in ids {
        let bar = progress_bar(false);
        let (status, analysis) = client.watch(id, Duration::from_millis(500), &bar).await?;
        let counts = status.summary.counts;
        println!(
            "batch {id} ({}) {:?}: {} completed, {} dead",
            status.summary.name, status.summary.state, counts.completed, counts.dead
        );
        if counts.dead > 0 {
            client.print_dead_runs(id).await?;
        }
        if let Some(text) = analysis {
            println!("{text}");
        }
        if status.summary.state != BatchState::Completed || counts.dead > 0 {
            failed.push(id);
        }
    }
    for id in campaign_ids {
        let view = client
            .follow_campaign(id, Duration::from_millis(500))
            .await?;
        crate::client::print_campaign_end(&view, client.base());
        if view.summary.status != "finished" {
            failed.push(id);
        }
    }
    if !failed.is_empty() && config.exit_when_done {
        bail!(
            "{} batch(es) or campaign(s) did not finish cleanly: {}",
            failed.len(),
            failed
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(())
}

/// The tokens `repose up` hands to its workers and prints for the person at the keyboard.
#[derive(Debug)]
struct LocalTokens {
    user: String,
    worker: String,
}

/// The user and worker tokens of the last start, read back from `file`, if the database still
/// holds both unrevoked with their roles.
async fn tokens_in_file(db: &std::path::Path, file: &std::path::Path) -> Option<LocalTokens> {
    use repose_server::tokens::find_secret;
    use repose_server::TokenRole;
    let text = std::fs::read_to_string(file).ok()?;
    let value = |key: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(&format!("export {key}=")))
            .map(|v| v.trim().to_owned())
    };
    let (user, worker) = (value("REPOSE_TOKEN")?, value("REPOSE_WORKER_TOKEN")?);
    for (secret, role) in [(&user, TokenRole::User), (&worker, TokenRole::Worker)] {
        let token = find_secret(db, secret).await.ok()??;
        if token.role != role || token.revoked_at_ms.is_some() {
            return None;
        }
    }
    Some(LocalTokens { user, worker })
}

/// The user and worker tokens of this database's `repose up`, written to `file` as `export`
/// lines (owner-only permissions), so `source FILE` makes the README's curl examples work. A
/// start reuses the tokens `file` holds while the database holds them unrevoked, so the batches
/// submitted before a restart stay the same user's (who alone may cancel them); otherwise it
/// creates new ones (names carry the time).
async fn local_tokens(
    db: &std::path::Path,
    file: &std::path::Path,
    url: &str,
) -> Result<LocalTokens> {
    use repose_server::tokens::create_token;
    use repose_server::TokenRole;
    let (user, worker) = match tokens_in_file(db, file).await {
        Some(kept) => (kept.user, kept.worker),
        None => {
            let stamp = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_millis());
            let user = create_token(db, &format!("local-user-{stamp}"), TokenRole::User).await?;
            let worker =
                create_token(db, &format!("local-worker-{stamp}"), TokenRole::Worker).await?;
            (user, worker)
        }
    };
    let text = format!(
        "# written by `repose up`; `source` this file to use the API from a shell\n\
         export REPOSE_SERVER={url}\nexport REPOSE_TOKEN={user}\nexport REPOSE_WORKER_TOKEN={worker}\n"
    );
    write_private(file, &text).with_context(|| format!("cannot write {}", file.display()))?;
    Ok(LocalTokens { user, worker })
}

#[cfg(unix)]
fn write_private(path: &std::path::Path, text: &str) -> std::io::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(path)?;
    file.write_all(text.as_bytes())
}

#[cfg(not(unix))]
fn write_private(path: &std::path::Path, text: &str) -> std::io::Result<()> {
    std::fs::write(path, text)
}
