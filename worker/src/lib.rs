//! The repose worker: leases jobs from a job server over HTTP, runs each experiment on its own
//! rayon pool (off the async runtime), heartbeats from a separate task and reports the result.
//!
//! Robustness rules, in the order they matter:
//! - a finished result is never dropped because the server is unreachable: it is re-sent with
//!   back-off until the server answers (a 409 then means someone else's result won);
//! - a lost lease (409 on a heartbeat, or `cancel` in the reply) stops the simulation;
//! - on shutdown the worker stops claiming, cancels what it is running and releases those jobs
//!   so another worker starts them at once (no attempt is counted);
//! - a server that refuses the worker's release (at registration or at a claim after a server
//!   upgrade) stops the worker with [`WorkerError::IncompatibleVersion`] instead of retrying;
//! - CPU slots ([`WorkerConfig::slots`]) claim CPU jobs only and GPU slots
//!   ([`WorkerConfig::gpu_slots`]) GPU jobs only, so a GPU worker never takes more CPU jobs than
//!   its cores serve; the GPU slots share one adapter;
//! - a run that stalls, or a GPU that is lost, fails the jobs it held (they run again
//!   elsewhere) and stops the worker with [`WorkerError::Stalled`] or
//!   [`WorkerError::GpuFailed`], for its service manager to start it again;
//! - with [`WorkerConfig::exit_when_idle`], the worker stops by itself once no job was
//!   available for that long (batch schedulers: an array task ends when the queue is empty).
//!
//! ```no_run
//! # async fn run() -> Result<(), repose_worker::WorkerError> {
//! let config = repose_worker::WorkerConfig::new("http://127.0.0.1:8080");
//! let summary = repose_worker::run(config, async {
//!     let _ = tokio::signal::ctrl_c().await;
//! })
//! .await?;
//! println!("{} jobs done", summary.completed);
//! # Ok(())
//! # }
//! ```

use std::future::Future;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rand::Rng;
use repose_api::BackendKind;
use repose_api::{ClaimResponse, Completion, Failure, Heartbeat, Release, WorkerRegistration};
use repose_experiments::backend::{Engine, Gpu, DEFAULT_ADMISSION_WAIT};
use repose_experiments::catalog::{
    BedStore, CheckpointStore, ExperimentError, ExperimentSpec, NoBedStore, NoCheckpoints, Outcome,
};
use repose_experiments::progress::Control;
use tokio::sync::watch;
use uuid::Uuid;

mod client;

pub use client::{CallError, Client};
use repose_stores::{FileBedStore, FileCheckpointStore};

/// Worker settings; the command line fills this from its flags.
#[derive(Debug, Clone)]
pub struct WorkerConfig {
    /// Server base URL, e.g. `http://10.0.0.5:8080`.
    pub server: String,
    /// Worker token, sent as `Authorization: Bearer`.
    pub token: Option<String>,
    /// CPU jobs run at the same time (CPU slots; 0: a worker for GPU jobs only).
    pub slots: usize,
    /// GPU jobs run at the same time on [`WorkerConfig::gpu`] (GPU slots), besides the CPU
    /// slots; at least 1 with a GPU, 0 without.
    pub gpu_slots: usize,
    /// Threads each job's simulation uses.
    pub threads: usize,
    /// Host name reported at registration.
    pub host: String,
    /// The id this worker registers under; none: a fresh random one each start. A worker that
    /// keeps one id across restarts gets the jobs it held before a crash or kill put back in
    /// the queue when it registers again, instead of after their lease runs out.
    pub instance_id: Option<Uuid>,
    /// Long-poll wait of each claim.
    pub claim_wait: Duration,
    /// Longest pause between retries when the server is unreachable.
    pub max_backoff: Duration,
    /// Where to write each run's pictures (`<dir>/<run id>/…`); none: not kept.
    pub artifacts_dir: Option<PathBuf>,
    /// Directory of settled drilling beds reused across runs; none: every run builds its bed.
    pub bed_cache: Option<PathBuf>,
    /// Directory of checkpoints of long runs (angle of repose): a run stopped by a crash, a
    /// kill or a shutdown goes on from its last checkpoint when its job comes back to a worker
    /// using this directory; none: runs start over.
    pub checkpoint_dir: Option<PathBuf>,
    /// Wall-clock time between two checkpoints of a run.
    pub checkpoint_every: Duration,
    /// Stop (like a shutdown, with nothing to release) once no slot had a job for this long;
    /// none: wait for jobs forever.
    pub exit_when_idle: Option<Duration>,
    /// Release reported at registration; the server accepts only its own `MAJOR.MINOR`.
    /// Always this build's release ([`repose_api::version::RELEASE`]) except in tests.
    pub version: String,
    /// The GPU this worker runs `gpu` jobs on, opened once by its caller ([`Gpu::open`];
    /// `repose worker --gpu`) and shared by its GPU slots: the worker names its adapter at
    /// registration, so the server hands its GPU slots `gpu` jobs. None: CPU jobs only (the
    /// server gives it no `gpu` job).
    pub gpu: Option<Arc<Gpu>>,
    /// A run that reports no progress for this long is stuck (a thread hung in a GPU driver,
    /// an endless loop): its job is reported failed as this worker's (it runs again elsewhere)
    /// and the worker stops with [`WorkerError::Stalled`], for its supervisor to restart it
    /// (the stuck thread cannot be ended from inside). None: no watchdog.
    pub stall_timeout: Option<Duration>,
}

/// [`WorkerConfig::stall_timeout`]'s default: 15 minutes. Every experiment reports progress at
/// least every 200 steps or every servo interval, seconds apart even at 200 000 grains.
pub const DEFAULT_STALL_TIMEOUT: Duration = Duration::from_secs(900);

impl WorkerConfig {
    /// One slot using every core, 20 s long-polls, back-off up to 30 s.
    pub fn new(server: impl Into<String>) -> WorkerConfig {
        WorkerConfig {
            server: server.into(),
            token: None,
            slots: 1,
            gpu_slots: 0,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            host: hostname(),
            instance_id: None,
            claim_wait: Duration::from_secs(20),
            max_backoff: Duration::from_secs(30),
            artifacts_dir: None,
            bed_cache: None,
            checkpoint_dir: None,
            checkpoint_every: Duration::from_secs(300),
            exit_when_idle: None,
            version: repose_api::version::RELEASE.to_owned(),
            gpu: None,
            stall_timeout: Some(DEFAULT_STALL_TIMEOUT),
        }
    }
}

/// Best-effort host name (for the run table only).
pub fn hostname() -> String {
    std::env::var("HOSTNAME")
        .ok()
        .filter(|h| !h.is_empty())
        .or_else(|| {
            std::fs::read_to_string("/etc/hostname")
                .ok()
                .map(|h| h.trim().to_owned())
        })
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "unknown".to_owned())
}

/// Why the worker stopped abnormally.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// The settings are unusable.
    #[error("invalid worker configuration: {0}")]
    Config(String),
    /// The server refused the registration (e.g. a bad token).
    #[error("registration refused: {0}")]
    Registration(#[source] CallError),
    /// The server does not accept this worker's release; the message names both versions.
    #[error("the server refuses this worker's version: {0}")]
    IncompatibleVersion(String),
    /// The HTTP client could not be built.
    #[error("HTTP client: {0}")]
    Http(#[from] reqwest::Error),
    /// A run reported no progress for [`WorkerConfig::stall_timeout`]: its job was reported
    /// failed (it runs again elsewhere) and the worker stopped. Its thread is still stuck:
    /// the process should end without waiting for it, and be started again.
    #[error(
        "job {job}: the simulation reported no progress for {seconds:.0} s (a thread hung in \
         a GPU driver, or an endless loop); its job was handed back and this worker stopped: \
         start it again"
    )]
    Stalled { job: Uuid, seconds: f64 },
    /// The GPU was lost (a driver reset, a device gone): the GPU jobs in flight were reported
    /// failed (they run again elsewhere) and the worker stopped. Start it again, on a GPU
    /// that works.
    #[error(
        "the GPU was lost ({reason}); its jobs were handed back and this worker stopped: start \
         it again"
    )]
    GpuFailed { reason: String },
}

/// What a worker did before it stopped.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WorkerSummary {
    /// Results the server accepted.
    pub completed: u64,
    /// Attempts reported as failed.
    pub failed: u64,
    /// Jobs given back at shutdown.
    pub released: u64,
    /// Jobs abandoned because the lease was lost (cancelled batch, expired lease).
    pub abandoned: u64,
    /// The worker stopped because no job came for [`WorkerConfig::exit_when_idle`].
    pub exited_idle: bool,
}

/// Runs the worker until `shutdown` resolves; then releases running jobs and returns.
pub async fn run(
    config: WorkerConfig,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<WorkerSummary, WorkerError> {
    if config.slots + config.gpu_slots == 0 {
        return Err(WorkerError::Config(
            "slots and gpu_slots must not both be 0".into(),
        ));
    }
    match (&config.gpu, config.gpu_slots) {
        (Some(_), 0) => {
            return Err(WorkerError::Config(
                "gpu_slots must be at least 1 with a GPU".into(),
            ))
        }
        (None, n) if n > 0 => {
            return Err(WorkerError::Config(
                "gpu_slots need a GPU (WorkerConfig::gpu)".into(),
            ))
        }
        _ => {}
    }
    if config.threads == 0 {
        return Err(WorkerError::Config("threads must be at least 1".into()));
    }
    if config.exit_when_idle.is_some_and(|idle| idle.is_zero()) {
        return Err(WorkerError::Config(
            "exit_when_idle must be longer than zero".into(),
        ));
    }
    let client = Client::new(&config.server, config.token.clone())?;
    let (stop_sender, stop) = watch::channel(false);
    let stop_sender = Arc::new(stop_sender);
    {
        let stop_sender = stop_sender.clone();
        tokio::spawn(async move {
            shutdown.await;
            stop_sender.send_replace(true);
        });
    }

    let registration = WorkerRegistration {
        instance_id: config.instance_id.unwrap_or_else(Uuid::new_v4),
        host: config.host.clone(),
        threads: u32::try_from(config.threads).unwrap_or(u32::MAX),
        version: config.version.clone(),
        gpu: config.gpu.as_ref().map(|gpu| gpu.name().to_owned()),
        gpu_memory_bytes: config.gpu.as_ref().and_then(|gpu| gpu.memory()),
        gpu_slots: config
            .gpu
            .as_ref()
            .map(|_| u32::try_from(config.gpu_slots).unwrap_or(u32::MAX)),
    };
    let registered = {
        let mut backoff = Backoff::new(config.max_backoff);
        loop {
            match client.register(&registration).await {
                Ok(r) => break r,
                Err(e) if e.is_transient() => {
                    tracing::warn!(error = %e, server = %config.server, "cannot register yet; retrying");
                    if backoff.wait(&stop).await {
                        return Ok(WorkerSummary::default());
                    }
                }
                Err(e) if e.is_version_refusal() => {
                    return Err(WorkerError::IncompatibleVersion(e.to_string()))
                }
                Err(e) => return Err(WorkerError::Registration(e)),
            }
        }
    };
    // The server's value, clamped: never a panic on a strange number.
    let lease = Duration::try_from_secs_f64(registered.lease_s.clamp(1.0, 86_400.0))
        .unwrap_or(Duration::from_secs(60));
    tracing::info!(worker = %registered.worker_id, server = %config.server, slots = config.slots,
        gpu_slots = config.gpu_slots, threads = config.threads,
        gpu = config.gpu.as_ref().map_or("none".into(), |g| g.describe()),
        gpu_memory_budget = config.gpu.as_ref().and_then(|g| g.memory_budget()),
        "worker registered");
    if let Some(gpu) = &config.gpu {
        // A world that fits the GPU only once other runs end waits for them, well within the
        // stall watchdog's limit (the wait reports no progress).
        gpu.set_admission_wait(
            config
                .stall_timeout
                .map_or(DEFAULT_ADMISSION_WAIT, |limit| limit / 2),
        );
    }

    let context = Arc::new(SlotContext {
        client,
        worker_id: registered.worker_id,
        lease,
        config,
        stop,
        stop_sender,
        fatal: Mutex::new(None),
        busy: AtomicUsize::new(0),
        idle_since: Mutex::new(Instant::now()),
        exited_idle: AtomicBool::new(false),
        gpu_failed: watch::channel(None).0,
    });
    if let Some(gpu) = context.config.gpu.clone() {
        tokio::spawn(watch_gpu(context.clone(), gpu));
    }
    let (cpu, gpu) = (context.config.slots, context.config.gpu_slots);
    let slots: Vec<_> = (0..cpu)
        .map(|slot| (slot, BackendKind::Cpu))
        .chain((cpu..cpu + gpu).map(|slot| (slot, BackendKind::Gpu)))
        .map(|(slot, backend)| tokio::spawn(slot_loop(context.clone(), slot, backend)))
        .collect();
    let mut summary = WorkerSummary::default();
    for slot in slots {
        if let Ok(s) = slot.await {
            summary.completed += s.completed;
            summary.failed += s.failed;
            summary.released += s.released;
            summary.abandoned += s.abandoned;
        }
    }
    summary.exited_idle = context.exited_idle.load(Ordering::SeqCst);
    tracing::info!(?summary, "worker stopped");
    if let Some(refusal) = context.fatal.lock().ok().and_then(|mut f| f.take()) {
        return Err(refusal);
    }
    Ok(summary)
}

#[derive(Debug)]
struct SlotContext {
    client: Client,
    worker_id: Uuid,
    lease: Duration,
    config: WorkerConfig,
    stop: watch::Receiver<bool>,
    /// Stops every slot: for a refusal that no retry can fix, and for the idle exit.
    stop_sender: Arc<watch::Sender<bool>>,
    /// Why the worker stopped by itself, if it was an error.
    fatal: Mutex<Option<WorkerError>>,
    /// Slots running a job now.
    busy: AtomicUsize,
    /// When the last job ended (or the worker started).
    idle_since: Mutex<Instant>,
    /// Set when the idle exit stopped the worker.
    exited_idle: AtomicBool,
    /// Why the GPU failed (lost, or a run on it stalled), once it did: every GPU job in
    /// flight is then reported failed.
    gpu_failed: watch::Sender<Option<String>>,
}

/// How often the worker asks its GPU whether it was lost.
const GPU_CHECK: Duration = Duration::from_millis(250);

/// Watches `gpu` until the worker stops: a lost device fails the GPU jobs in flight and stops
/// the worker ([`SlotContext::gpu_failed`]).
async fn watch_gpu(context: Arc<SlotContext>, gpu: Arc<Gpu>) {
    let mut stop = context.stop.clone();
    loop {
        tokio::select! {
            () = tokio::time::sleep(GPU_CHECK) => {}
            _ = stop.wait_for(|s| *s) => return,
        }
        if let Some(reason) = gpu.lost() {
            context.gpu_failed(
                format!("the device was lost: {reason}"),
                WorkerError::GpuFailed { reason },
            );
            return;
        }
    }
}

impl SlotContext {
    /// The GPU failed (`reason`): every GPU job in flight is reported failed, and the worker
    /// stops with `error` (unless it stopped for another reason first).
    fn gpu_failed(&self, reason: String, error: WorkerError) {
        let first = self.gpu_failed.send_if_modified(|failed| {
            let first = failed.is_none();
            failed.get_or_insert(reason.clone());
            first
        });
        if first {
            tracing::error!(%reason, "the GPU failed; failing its jobs and stopping this worker");
        }
        if let Ok(mut fatal) = self.fatal.lock() {
            fatal.get_or_insert(error);
        }
        self.stop_sender.send_replace(true);
    }

    /// The long-poll wait of a claim: never longer than the idle limit, so an idle worker
    /// notices it in time.
    fn claim_wait(&self) -> Duration {
        match self.config.exit_when_idle {
            Some(idle) => self.config.claim_wait.min(idle),
            None => self.config.claim_wait,
        }
    }

    /// After a claim found nothing: stops the worker if every slot has been idle for
    /// [`WorkerConfig::exit_when_idle`].
    fn stop_if_idle(&self, slot: usize) {
        let Some(idle) = self.config.exit_when_idle else {
            return;
        };
        if self.busy.load(Ordering::SeqCst) > 0 {
            return;
        }
        let idle_for = self
            .idle_since
            .lock()
            .map_or(Duration::ZERO, |since| since.elapsed());
        if idle_for >= idle && !self.exited_idle.swap(true, Ordering::SeqCst) {
            tracing::info!(
                slot,
                idle_s = idle_for.as_secs_f64(),
                "no job for the idle limit (--exit-when-idle); stopping"
            );
            self.stop_sender.send_replace(true);
        }
    }
}

/// One slot: claims jobs of `backend` (a CPU slot CPU jobs, a GPU slot GPU jobs) one at a time
/// until the worker stops.
async fn slot_loop(context: Arc<SlotContext>, slot: usize, backend: BackendKind) -> WorkerSummary {
    let mut summary = WorkerSummary::default();
    let mut backoff = Backoff::new(context.config.max_backoff);
    while !*context.stop.borrow() {
        let mut stop = context.stop.clone();
        let claim = context
            .client
            .claim(context.worker_id, context.claim_wait(), Some(backend));
        let claimed = tokio::select! {
            claimed = claim => claimed,
            _ = stop.wait_for(|s| *s) => break,
        };
        match claimed {
            Ok(Some(job)) => {
                backoff.reset();
                context.busy.fetch_add(1, Ordering::SeqCst);
                tracing::info!(slot, job = %job.job_id, run = %job.run_id, kind = %job.kind,
                    backend = %job.backend, attempt = job.attempt, "job leased");
                let end = run_job(&context, job).await;
                if let Ok(mut since) = context.idle_since.lock() {
                    *since = Instant::now();
                }
                context.busy.fetch_sub(1, Ordering::SeqCst);
                match end {
                    JobEnd::Completed => summary.completed += 1,
                    JobEnd::Failed => summary.failed += 1,
                    JobEnd::Released => summary.released += 1,
                    JobEnd::Abandoned => summary.abandoned += 1,
                }
            }
            Ok(None) => {
                backoff.reset();
                context.stop_if_idle(slot);
            }
            Err(e) if e.is_version_refusal() => {
                // The server was upgraded under this worker: no retry can fix that. Stop every
                // slot (running jobs are released) and report it.
                tracing::error!(slot, error = %e, "the server refuses this worker's version; stopping");
                if let Ok(mut fatal) = context.fatal.lock() {
                    fatal.get_or_insert(WorkerError::IncompatibleVersion(e.to_string()));
                }
                context.stop_sender.send_replace(true);
                break;
            }
            Err(e) if e.is_transient() => {
                tracing::warn!(slot, error = %e, "claim failed; retrying");
                if backoff.wait(&context.stop).await {
                    break;
                }
            }
            Err(e) => {
                // A refused claim (bad token, unknown worker) will not fix itself quickly;
                // wait long and try again rather than spin.
                tracing::error!(slot, error = %e, "claim refused");
                backoff.fail_hard();
                if backoff.wait(&context.stop).await {
                    break;
                }
            }
        }
    }
    summary
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum JobEnd {
    Completed,
    Failed,
    Released,
    Abandoned,
}

/// Shared between the simulation thread and the heartbeat task.
#[derive(Debug, Default)]
struct JobSignals {
    /// Fraction done as `f64` bits.
    progress: AtomicU64,
    /// Set to stop the simulation.
    cancel: AtomicBool,
    /// Progress reports so far: the stall watchdog's sign of life.
    beats: AtomicU64,
    /// Why it was cancelled: the lease is gone (don't report) or the worker is stopping
    /// (release).
    lease_lost: AtomicBool,
}

async fn run_job(context: &SlotContext, job: ClaimResponse) -> JobEnd {
    let signals = Arc::new(JobSignals::default());
    let started = Instant::now();
    // The job's kind and spec, parsed once: the run and its checkpoint's key both use it (a
    // spec this build cannot parse fails the job like a run that cannot start).
    let parsed = ExperimentSpec::parse_job(&job.kind, &job.spec);
    let checkpoint_key = parsed
        .as_ref()
        .ok()
        .and_then(|spec| spec.checkpoint_key_on(job.backend, job.seed));

    let heartbeat = tokio::spawn(heartbeat_loop(
        context.client.clone(),
        job.job_id,
        job.lease_token,
        context.lease,
        signals.clone(),
    ));
    let stopper = {
        let signals = signals.clone();
        let mut stop = context.stop.clone();
        tokio::spawn(async move {
            if stop.wait_for(|s| *s).await.is_ok() {
                signals.cancel.store(true, Ordering::SeqCst);
            }
        })
    };

    let outcome = match parsed {
        Ok(spec) => {
            let signals = signals.clone();
            let (threads, seed) = (context.config.threads, job.seed);
            let engine = Runner {
                backend: job.backend,
                gpu: context.config.gpu.clone(),
            };
            let stores = Stores {
                bed_cache: context.config.bed_cache.clone(),
                checkpoint_dir: context.config.checkpoint_dir.clone(),
                checkpoint_every: context.config.checkpoint_every,
            };
            let watched = signals.clone();
            let simulation = tokio::task::spawn_blocking(move || {
                simulate(spec, engine, seed, threads, stores, &signals)
            });
            let on_gpu = job.backend == BackendKind::Gpu;
            let gpu_failed = gpu_failure(context.gpu_failed.subscribe());
            tokio::select! {
                joined = simulation => joined,
                seconds = stalled(&watched, context.config.stall_timeout) => {
                    stopper.abort();
                    heartbeat.abort();
                    return give_up_stalled(context, &job, seconds).await;
                }
                // Another run on this worker's GPU stalled, or the device was lost: this run's
                // thread may never come back; its job goes to another worker now.
                reason = gpu_failed, if on_gpu => {
                    stopper.abort();
                    heartbeat.abort();
                    return report_gpu_failure(context, &job, &reason).await;
                }
            }
        }
        Err(error) => Ok(Err(error)),
    };
    // A GPU run that failed on a lost device: the device's fault, not the run's.
    if job.backend == BackendKind::Gpu && !matches!(outcome, Ok(Ok(_))) {
        if let Some(reason) = context.config.gpu.as_ref().and_then(|gpu| gpu.lost()) {
            stopper.abort();
            heartbeat.abort();
            let failure = format!("the device was lost: {reason}");
            context.gpu_failed(failure.clone(), WorkerError::GpuFailed { reason });
            return report_gpu_failure(context, &job, &failure).await;
        }
    }
    // A test aid (`table_lookup`) may ask to hold the job as if it were simulating.
    if let Ok(Ok(outcome)) = &outcome {
        let hold =
            Duration::try_from_secs_f64(outcome.hold_s.clamp(0.0, 86_400.0)).unwrap_or_default();
        let deadline = tokio::time::Instant::now() + hold;
        while tokio::time::Instant::now() < deadline && !signals.cancel.load(Ordering::SeqCst) {
            tokio::time::sleep(Duration::from_millis(50).min(hold)).await;
        }
    }
    stopper.abort();
    heartbeat.abort();
    let wall_time_s = started.elapsed().as_secs_f64();

    if signals.lease_lost.load(Ordering::SeqCst) {
        tracing::warn!(job = %job.job_id, "lease lost (batch cancelled or lease expired); result dropped");
        // The server said stop: the batch was cancelled or the run has its result from
        // elsewhere, so nobody will continue this run from its checkpoint.
        drop_checkpoint(context, &job, checkpoint_key.as_deref());
        return JobEnd::Abandoned;
    }
    if signals.cancel.load(Ordering::SeqCst) {
        // The worker is stopping: give the job back so another worker starts it at once.
        let release = Release {
            lease_token: job.lease_token,
        };
        let _ = context.client.release(job.job_id, &release).await;
        tracing::info!(job = %job.job_id, "job released at shutdown");
        return JobEnd::Released;
    }
    match outcome {
        Ok(Ok(outcome)) => {
            if let Some(dir) = &context.config.artifacts_dir {
                save_pictures(dir, job.run_id, &outcome);
            }
            let pictures = if job.keep_pictures {
                outcome.pictures.into_iter().collect()
            } else {
                Default::default()
            };
            let completion = Completion {
                lease_token: job.lease_token,
                metrics: outcome.metrics,
                wall_time_s,
                details: outcome.details,
                engine_version: Some(outcome.engine_version),
                pictures,
            };
            deliver(context, job.job_id, "complete", |c| {
                let completion = completion.clone();
                async move { c.complete(job.job_id, &completion).await }
            })
            .await
            .map_or(JobEnd::Abandoned, |()| JobEnd::Completed)
        }
        Ok(Err(error)) => {
            // A bad spec or a run without a result fails the job (a run that failed by its
            // seed's chance may run again under another); a failure of this worker's own (it
            // cannot start its threads) or a cancel hands the job back.
            let rerun = if error.another_seed_may_help() {
                Rerun::WithAnotherSeed
            } else if error.is_permanent() {
                Rerun::Never
            } else {
                Rerun::Retry
            };
            report_failure(context, &job, error.to_string(), rerun).await
        }
        Err(join_error) => {
            let message = if join_error.is_panic() {
                format!("the simulation panicked: {join_error}")
            } else {
                format!("the simulation task stopped: {join_error}")
            };
            report_failure(context, &job, message, Rerun::Retry).await
        }
    }
}

/// Completes with the reason once the worker's GPU failed ([`SlotContext::gpu_failed`]); never
/// while it works.
async fn gpu_failure(mut failed: watch::Receiver<Option<String>>) -> String {
    // The channel's value is read locked while the reference lives: copied out at once.
    let reason = failed
        .wait_for(Option::is_some)
        .await
        .ok()
        .map(|reason| reason.clone().unwrap_or_default());
    match reason {
        Some(reason) => reason,
        None => std::future::pending().await,
    }
}

/// Completes (with the seconds since the last one) once the run has reported no progress for
/// `limit`; never without a limit.
async fn stalled(signals: &JobSignals, limit: Option<Duration>) -> f64 {
    let Some(limit) = limit else {
        return std::future::pending().await;
    };
    let poll = (limit / 10).clamp(Duration::from_millis(50), Duration::from_secs(5));
    let mut seen = signals.beats.load(Ordering::Relaxed);
    let mut since = Instant::now();
    loop {
        tokio::time::sleep(poll).await;
        let beats = signals.beats.load(Ordering::Relaxed);
        if beats != seen {
            (seen, since) = (beats, Instant::now());
        } else if since.elapsed() >= limit {
            return since.elapsed().as_secs_f64();
        }
    }
}

/// A run stuck for `seconds`: its job goes back to the server as this worker's failure (it
/// runs again elsewhere) and the worker stops with [`WorkerError::Stalled`]; the stuck thread
/// is left behind (it cannot be ended from inside: its process must end). A GPU run's stall
/// is its device's: the other GPU jobs in flight fail too.
async fn give_up_stalled(context: &SlotContext, job: &ClaimResponse, seconds: f64) -> JobEnd {
    tracing::error!(job = %job.job_id, run = %job.run_id, seconds,
        "the simulation reported no progress; handing its job back and stopping this worker");
    let stalled = WorkerError::Stalled {
        job: job.job_id,
        seconds,
    };
    if job.backend == BackendKind::Gpu {
        context.gpu_failed(
            format!(
                "run {} on it reported no progress for {seconds:.0} s (a hung device)",
                job.run_id
            ),
            stalled,
        );
    } else {
        if let Ok(mut fatal) = context.fatal.lock() {
            fatal.get_or_insert(stalled);
        }
        context.stop_sender.send_replace(true);
    }
    let error = format!(
        "the simulation reported no progress for {seconds:.0} s (a thread hung in a GPU \
         driver, or an endless loop) on worker {}; it runs again elsewhere",
        context.worker_id
    );
    report_failure(context, job, error, Rerun::Retry).await
}

/// A GPU job whose device failed (`reason`): reported failed as this worker's (it runs again
/// elsewhere); the worker is stopping.
async fn report_gpu_failure(context: &SlotContext, job: &ClaimResponse, reason: &str) -> JobEnd {
    let adapter = context.config.gpu.as_ref().map_or("", |gpu| gpu.name());
    let error = format!(
        "the GPU ({adapter}) of worker {} failed: {reason}; the worker stopped and the run \
         goes to another",
        context.worker_id
    );
    report_failure(context, job, error, Rerun::Retry).await
}

/// Whether a failed job is worth running again, as the worker tells the server.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Rerun {
    /// As it was (after a back-off): the failure may not happen again.
    Retry,
    /// Never: the same spec gives the same failure whatever the seed.
    Never,
    /// Under another seed: this seed gives the same failure, another may not.
    WithAnotherSeed,
}

async fn report_failure(
    context: &SlotContext,
    job: &ClaimResponse,
    error: String,
    rerun: Rerun,
) -> JobEnd {
    // INFO: the server logs what became of the run (in `repose up` that line alone shows).
    tracing::info!(job = %job.job_id, run = %job.run_id, %error, ?rerun, "job failed");
    let failure = Failure {
        lease_token: job.lease_token,
        error,
        permanent: rerun == Rerun::Never,
        another_seed: rerun == Rerun::WithAnotherSeed,
    };
    deliver(context, job.job_id, "fail", |c| {
        let failure = failure.clone();
        async move { c.fail(job.job_id, &failure).await }
    })
    .await
    .map_or(JobEnd::Abandoned, |()| JobEnd::Failed)
}

/// How long a stopping worker keeps trying to deliver a finished result.
const DELIVERY_GRACE_AT_SHUTDOWN: Duration = Duration::from_secs(30);

/// Sends a final report until the server answers. Transient errors are retried with back-off
/// (the result is the expensive part) while the worker runs, and for at most
/// [`DELIVERY_GRACE_AT_SHUTDOWN`] once it is asked to stop; a 4xx answer ends the attempt
/// (`Err`): the server has decided (e.g. another result won, 409).
async fn deliver<F, Fut>(context: &SlotContext, job_id: Uuid, what: &str, call: F) -> Result<(), ()>
where
    F: Fn(Client) -> Fut,
    Fut: Future<Output = Result<repose_api::JobUpdateResponse, CallError>>,
{
    let mut backoff = Backoff::new(context.config.max_backoff);
    let mut stop = context.stop.clone();
    let mut give_up_at: Option<tokio::time::Instant> = None;
    loop {
        if give_up_at.is_none() && *stop.borrow() {
            give_up_at = Some(tokio::time::Instant::now() + DELIVERY_GRACE_AT_SHUTDOWN);
        }
        if give_up_at.is_some_and(|at| tokio::time::Instant::now() >= at) {
            tracing::error!(job = %job_id, "{what} not delivered before shutdown; giving up");
            return Err(());
        }
        match call(context.client.clone()).await {
            Ok(update) => {
                tracing::info!(job = %job_id, status = ?update.status, "{what} accepted");
                return Ok(());
            }
            Err(e) if e.is_transient() => {
                tracing::warn!(job = %job_id, error = %e, "{what} not delivered; keeping it and retrying");
                let delay = backoff.next_delay();
                match give_up_at {
                    // Stopping: retry until the grace runs out.
                    Some(at) => {
                        tokio::time::sleep_until(at.min(tokio::time::Instant::now() + delay)).await
                    }
                    // Running: a stop request starts the grace period early.
                    None => {
                        let sender_gone = tokio::select! {
                            () = tokio::time::sleep(delay) => false,
                            stopped = stop.wait_for(|s| *s) => stopped.is_err(),
                        };
                        // No stop sender any more: just wait out the delay.
                        if sender_gone {
                            tokio::time::sleep(delay).await;
                        }
                    }
                }
            }
            Err(e) => {
                tracing::warn!(job = %job_id, error = %e, "{what} refused");
                return Err(());
            }
        }
    }
}

/// The longest time between two heartbeats of a running job.
const MAX_HEARTBEAT_PERIOD: Duration = Duration::from_secs(30);

/// Renews the lease with the current progress every lease/3, and at least every
/// [`MAX_HEARTBEAT_PERIOD`], so that under a long lease (hours, for runs that take hours) a job
/// still shows its progress and hears a cancel within half a minute; flags a lost lease.
async fn heartbeat_loop(
    client: Client,
    job_id: Uuid,
    lease_token: Uuid,
    lease: Duration,
    signals: Arc<JobSignals>,
) {
    let period = (lease / 3).min(MAX_HEARTBEAT_PERIOD);
    loop {
        tokio::time::sleep(period).await;
        let progress = f64::from_bits(signals.progress.load(Ordering::Relaxed));
        let beat = Heartbeat {
            lease_token,
            progress,
        };
        match client.heartbeat(job_id, &beat).await {
            Ok(reply) if reply.cancel => {
                signals.lease_lost.store(true, Ordering::SeqCst);
                signals.cancel.store(true, Ordering::SeqCst);
                return;
            }
            Ok(_) => {}
            Err(e) if e.is_lost_lease() => {
                // The lease expired (or was never this worker's): stop renewing it but keep
                // simulating. The server still takes the result as a late one if no other
                // worker delivered first and the batch is still running; it says 409 if not.
                tracing::warn!(job = %job_id, error = %e,
                    "lease no longer renewable; the result will be offered as a late result");
                return;
            }
            // Unreachable: keep simulating; the result will be re-sent until accepted, and a
            // late result of an expired lease is still taken if nobody else finished first.
            Err(e) => tracing::warn!(job = %job_id, error = %e, "heartbeat not delivered"),
        }
    }
}

/// Deletes the checkpoint `job`'s run keeps in the checkpoint directory under `key`, if any.
fn drop_checkpoint(context: &SlotContext, job: &ClaimResponse, key: Option<&str>) {
    let (Some(dir), Some(key)) = (&context.config.checkpoint_dir, key) else {
        return;
    };
    FileCheckpointStore::new(dir, context.config.checkpoint_every).remove(key);
    tracing::info!(job = %job.job_id, key, "dropped the checkpoint (if any) of a run nobody will continue");
}

/// Where a job's simulation keeps what outlives it.
#[derive(Debug, Clone, Default)]
struct Stores {
    bed_cache: Option<PathBuf>,
    checkpoint_dir: Option<PathBuf>,
    checkpoint_every: Duration,
}

/// The engine a job asks for, and this worker's GPU if it opened one.
#[derive(Debug, Clone, Default)]
struct Runner {
    backend: BackendKind,
    gpu: Option<Arc<Gpu>>,
}

/// Runs the experiment on the job's engine, on a fresh pool of `threads` threads (results do
/// not depend on it). A `gpu` job on a worker without a GPU (a server that does not sort jobs
/// by backend) is this worker's failure, never a run on the CPU.
fn simulate(
    spec: ExperimentSpec,
    runner: Runner,
    seed: u64,
    threads: usize,
    stores: Stores,
    signals: &JobSignals,
) -> Result<Outcome, ExperimentError> {
    let engine = match (runner.backend, &runner.gpu) {
        (BackendKind::Cpu, _) => Engine::Cpu,
        (BackendKind::Gpu, Some(gpu)) => Engine::Gpu(gpu),
        (BackendKind::Gpu, None) => {
            return Err(ExperimentError::Local {
                message: "a gpu job, but this worker opened no GPU (start it with --gpu)".into(),
            })
        }
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| ExperimentError::Local {
            message: format!("cannot start {threads} simulation threads: {e}"),
        })?;
    let mut beds: Box<dyn BedStore + Send> = match stores.bed_cache {
        Some(dir) => Box::new(FileBedStore::new(dir)),
        None => Box::new(NoBedStore),
    };
    let mut checkpoints: Box<dyn CheckpointStore + Send> = match stores.checkpoint_dir {
        Some(dir) => Box::new(FileCheckpointStore::new(dir, stores.checkpoint_every)),
        None => Box::new(NoCheckpoints),
    };
    pool.install(|| {
        spec.run_on(
            engine,
            seed,
            &mut |fraction| {
                signals
                    .progress
                    .store(fraction.clamp(0.0, 1.0).to_bits(), Ordering::Relaxed);
                signals.beats.fetch_add(1, Ordering::Relaxed);
                if signals.cancel.load(Ordering::Relaxed) {
                    Control::Cancel
                } else {
                    Control::Continue
                }
            },
            beds.as_mut(),
            checkpoints.as_mut(),
        )
    })
}

fn save_pictures(dir: &std::path::Path, run_id: Uuid, outcome: &Outcome) {
    if outcome.pictures.is_empty() {
        return;
    }
    let run_dir = dir.join(run_id.to_string());
    let written = std::fs::create_dir_all(&run_dir).and_then(|()| {
        outcome
            .pictures
            .iter()
            .try_for_each(|(name, svg)| std::fs::write(run_dir.join(name), svg))
    });
    if let Err(e) = written {
        tracing::warn!(dir = %run_dir.display(), error = %e, "cannot save pictures");
    }
}

/// Jittered exponential back-off: 0.25 s doubling up to the cap, ±25 %.
#[derive(Debug)]
struct Backoff {
    next: Duration,
    cap: Duration,
}

impl Backoff {
    const FIRST: Duration = Duration::from_millis(250);

    fn new(cap: Duration) -> Backoff {
        Backoff {
            next: Self::FIRST,
            cap: cap.max(Self::FIRST),
        }
    }

    fn reset(&mut self) {
        self.next = Self::FIRST;
    }

    fn fail_hard(&mut self) {
        self.next = self.cap;
    }

    fn next_delay(&mut self) -> Duration {
        let base = self.next;
        self.next = (self.next * 2).min(self.cap);
        base.mul_f64(rand::thread_rng().gen_range(0.75..1.25))
    }

    /// Sleeps the next delay; `true` if the worker was told to stop meanwhile.
    async fn wait(&mut self, stop: &watch::Receiver<bool>) -> bool {
        let delay = self.next_delay();
        let mut watcher = stop.clone();
        tokio::select! {
            () = tokio::time::sleep(delay) => *stop.borrow(),
            _ = watcher.wait_for(|s| *s) => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_to_the_cap_with_jitter() {
        let mut b = Backoff::new(Duration::from_secs(2));
        let delays: Vec<f64> = (0..8).map(|_| b.next_delay().as_secs_f64()).collect();
        assert!((0.18..0.32).contains(&delays[0]), "{delays:?}");
        assert!(delays[7] <= 2.5 && delays[7] >= 1.5, "{delays:?}");
        b.reset();
        assert!(b.next_delay() < Duration::from_millis(320));
    }

    #[test]
    fn simulate_runs_a_replay_and_honours_cancel() {
        let spec = serde_json::json!({"values": {"a": 1.0}, "rows": [{"a": 1.0, "y": 2.0}]});
        let spec = ExperimentSpec::parse_job("table_lookup", &spec).unwrap();
        let signals = JobSignals::default();
        let cpu = Runner::default();
        let outcome = simulate(spec.clone(), cpu.clone(), 0, 1, Stores::default(), &signals);
        assert_eq!(outcome.unwrap().metrics["y"], 2.0);
        signals.cancel.store(true, Ordering::SeqCst);
        assert!(matches!(
            simulate(spec, cpu, 0, 1, Stores::default(), &signals),
            Err(ExperimentError::Cancelled)
        ));
    }

    /// The GPU tests' adapter (lavapipe in CI), or none with a message where none can be
    /// opened (`REPOSE_REQUIRE_GPU=1`, which `.ci/run` sets where lavapipe is installed,
    /// makes that a failure).
    fn test_gpu() -> Option<Arc<Gpu>> {
        match Gpu::open() {
            Ok(gpu) => Some(Arc::new(gpu)),
            Err(e) if std::env::var("REPOSE_REQUIRE_GPU").is_ok_and(|v| v == "1") => {
                panic!("REPOSE_REQUIRE_GPU=1 but {e}")
            }
            Err(e) => {
                eprintln!("SKIPPED: {e}");
                None
            }
        }
    }

    /// Several GPU runs at once on one adapter, as a worker's GPU slots run them (its
    /// `simulate`, each on its own thread), give the lone run's results to the bit.
    #[test]
    fn gpu_runs_sharing_one_adapter_give_the_results_of_a_lone_run() {
        let Some(gpu) = test_gpu() else { return };
        // The small funnel of the GPU tests at half its mass: about 280 grains of 4 mm, a few
        // seconds on lavapipe.
        let overrides = serde_json::json!({
            "particle": {"radius": 0.002},
            "total_mass": 0.025,
            "mass_rate": 0.25,
            "funnel": {"outlet_diameter": 0.04},
            "base": {"size": 0.15},
            "materials": {"soil": {"youngs_modulus": 1e6}},
            "soil_soil": {"rolling_friction": 0.3, "static_friction": 0.442},
            "settle": {"min_time": 0.1, "check_interval": 0.05, "creep_window_s": 0.15},
            "time_cap": 1.5
        });
        let spec = repose_experiments::catalog::prepare_spec("aor", Some("fast"), &overrides)
            .and_then(|spec| ExperimentSpec::parse_job("aor", &spec))
            .unwrap();
        let runner = Runner {
            backend: BackendKind::Gpu,
            gpu: Some(gpu.clone()),
        };
        let run = || {
            let signals = JobSignals::default();
            let mut outcome = simulate(
                spec.clone(),
                runner.clone(),
                7,
                1,
                Stores::default(),
                &signals,
            )
            .unwrap();
            // The one figure a run's own clock gives.
            outcome.details["wall_time_s"] = serde_json::Value::Null;
            outcome
        };
        let started = Instant::now();
        let alone = run();
        let lone_s = started.elapsed().as_secs_f64();
        let started = Instant::now();
        let together: Vec<Outcome> = std::thread::scope(|s| {
            let runs: Vec<_> = (0..2).map(|_| s.spawn(run)).collect();
            runs.into_iter().map(|r| r.join().unwrap()).collect()
        });
        println!(
            "one run alone {lone_s:.1} s, two at once {:.1} s; angle {:?}",
            started.elapsed().as_secs_f64(),
            alone.metrics.get("angle_deg")
        );
        assert!(
            alone.metrics.contains_key("angle_deg"),
            "{:?}",
            alone.metrics
        );
        assert!(
            alone.engine_version.contains("+gpu:"),
            "{}",
            alone.engine_version
        );
        for (k, outcome) in together.iter().enumerate() {
            assert_eq!(outcome.metrics, alone.metrics, "run {k} of 2");
            assert_eq!(outcome.details, alone.details, "run {k} of 2");
        }
        assert_eq!(gpu.in_flight(), (0, 0), "every world gave its memory back");
    }

    #[test]
    fn a_gpu_job_without_a_gpu_is_this_workers_failure_not_a_cpu_run() {
        let spec = serde_json::json!({"values": {"a": 1.0}, "rows": [{"a": 1.0, "y": 2.0}]});
        let spec = ExperimentSpec::parse_job("table_lookup", &spec).unwrap();
        let no_gpu = Runner {
            backend: BackendKind::Gpu,
            gpu: None,
        };
        let err = simulate(
            spec,
            no_gpu,
            0,
            1,
            Stores::default(),
            &JobSignals::default(),
        )
        .unwrap_err();
        assert!(matches!(err, ExperimentError::Local { .. }), "{err:?}");
        assert!(!err.is_permanent());
        assert!(err.to_string().contains("--gpu"), "{err}");
    }
}
