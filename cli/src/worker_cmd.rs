//! `repose worker`: leases jobs from a job server and runs them until Ctrl-C or SIGTERM (or,
//! with `--exit-when-idle`, until the queue stays empty).

use anyhow::{bail, Context, Result};
use clap::Args;
use repose_worker::{run, WorkerConfig, WorkerError};
use std::path::PathBuf;
use std::time::Duration;

/// Exit status of a worker whose run stalled (`--stall-timeout`) or whose GPU was lost: its
/// service manager restarts it (the systemd unit's `RestartPreventExitStatus=2` spares only
/// refusals).
pub const STALLED_EXIT: i32 = 3;

/// Longest accepted `--exit-when-idle`: a week.
const MAX_IDLE_S: f64 = 7.0 * 86_400.0;

#[derive(Debug, Args)]
pub struct WorkerArgs {
    /// Job server URL.
    #[arg(long, env = "REPOSE_SERVER", default_value = "http://127.0.0.1:8080")]
    pub server: String,
    /// Worker token (`repose token create NAME --role worker`).
    #[arg(long, env = "REPOSE_WORKER_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// CPU jobs run at the same time (CPU slots; 0: GPU jobs only, with --gpu-slots).
    #[arg(long, env = "REPOSE_SLOTS", default_value_t = 1)]
    pub slots: usize,
    /// GPU jobs run at the same time on this worker's GPU, sharing it (GPU slots; implies
    /// --gpu; default 1 with --gpu). They claim only GPU jobs and the CPU slots only CPU jobs.
    #[arg(long, env = "REPOSE_GPU_SLOTS", value_name = "N")]
    pub gpu_slots: Option<usize>,
    /// Device memory the GPU slots' runs may hold together, GiB (default: 90 % of the GPU's,
    /// where the driver tells it). A run whose world needs more is refused at admission;
    /// one that fits only once others end waits for them.
    #[arg(long, env = "REPOSE_GPU_MEMORY", value_name = "GIB")]
    pub gpu_memory: Option<f64>,
    /// Threads per job (default: all cores divided among the CPU slots). Results do not depend
    /// on it.
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// Keep each run's pictures (e.g. pile.svg) under DIR/<run id>/.
    #[arg(long, env = "REPOSE_ARTIFACTS")]
    pub artifacts: Option<PathBuf>,
    /// Keep settled drilling beds under DIR and reuse them for runs with the same bed inputs
    /// (may be shared by several workers on one machine).
    #[arg(long, env = "REPOSE_BED_CACHE", value_name = "DIR")]
    pub bed_cache: Option<PathBuf>,
    /// Keep checkpoints of long runs (angle of repose) under DIR: a run stopped by a crash, a
    /// kill or a shutdown goes on from its last checkpoint when its job comes back to a worker
    /// using DIR (may be shared by several workers on one machine). Default: runs start over.
    #[arg(long, env = "REPOSE_CHECKPOINTS", value_name = "DIR")]
    pub checkpoint_dir: Option<PathBuf>,
    /// Wall-clock seconds between two checkpoints of a run.
    #[arg(
        long,
        env = "REPOSE_CHECKPOINT_EVERY",
        value_name = "SECONDS",
        default_value_t = 300.0
    )]
    pub checkpoint_every: f64,
    /// Register under this id (a UUID) instead of a random one each start. Give a worker that
    /// a service manager restarts its own fixed id, and the jobs it held when it crashed or was
    /// killed go back to the queue as soon as it starts again, not when their lease runs out.
    /// Two workers running at the same time must not share an id.
    #[arg(long, env = "REPOSE_WORKER_ID", value_name = "UUID")]
    pub instance_id: Option<uuid::Uuid>,
    /// Exit (status 0) once no job was available for SECONDS, e.g. so a batch-scheduler task
    /// ends when the queue is empty instead of holding its allocation. Default: wait forever.
    #[arg(long, env = "REPOSE_EXIT_WHEN_IDLE", value_name = "SECONDS")]
    pub exit_when_idle: Option<f64>,
    /// Open a GPU (Vulkan, Metal, DX12; `WGPU_ADAPTER_NAME` picks one) at start and run the
    /// jobs of `"backend": "gpu"` batches on it in its GPU slots (--gpu-slots), besides CPU
    /// jobs in its CPU slots. No adapter is an error at start, never a CPU-only worker.
    #[arg(long, env = "REPOSE_GPU")]
    pub gpu: bool,
    /// A run that reports no progress for SECONDS is stuck (a thread hung in a GPU driver): its
    /// job is handed back to run elsewhere (a GPU run's: every GPU job) and the worker exits
    /// (status 3, as for a lost GPU) for its service manager to start it again. 0: never.
    #[arg(
        long,
        env = "REPOSE_STALL_TIMEOUT",
        value_name = "SECONDS",
        default_value_t = 900.0
    )]
    pub stall_timeout: f64,
}

/// `--stall-timeout`: seconds up to a week; 0 turns the watchdog off.
pub(crate) fn stall_timeout(seconds: f64) -> Result<Option<Duration>> {
    if !(seconds.is_finite() && (0.0..=MAX_IDLE_S).contains(&seconds)) {
        bail!("--stall-timeout must be between 0 and {MAX_IDLE_S} seconds, got {seconds}");
    }
    Ok((seconds > 0.0).then(|| Duration::from_secs_f64(seconds)))
}

/// The validated worker configuration (the GPU, if asked for, is opened by the caller:
/// [`gpu_settings`]).
pub fn config(args: &WorkerArgs) -> Result<WorkerConfig> {
    let gpu_slots = gpu_settings(args)?.map_or(0, |gpu| gpu.slots);
    if args.slots == 0 && gpu_slots == 0 {
        bail!("--slots must be at least 1 (0 only beside --gpu-slots)");
    }
    if !(args.server.starts_with("http://") || args.server.starts_with("https://")) {
        bail!(
            "--server must be an http:// or https:// URL, got {:?}",
            args.server
        );
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = match args.threads {
        Some(0) => bail!("--threads must be at least 1"),
        Some(t) => t,
        None => (cores / args.slots.max(1)).max(1),
    };
    let exit_when_idle = match args.exit_when_idle {
        None => None,
        Some(s) if s.is_finite() && s > 0.0 && s <= MAX_IDLE_S => Some(Duration::from_secs_f64(s)),
        Some(s) => bail!("--exit-when-idle must be between 0 and {MAX_IDLE_S} seconds, got {s}"),
    };
    let checkpoint_every = checkpoint_interval(args.checkpoint_every)?;
    let mut config = WorkerConfig::new(args.server.clone());
    config.exit_when_idle = exit_when_idle;
    config.stall_timeout = stall_timeout(args.stall_timeout)?;
    config.token = args.token.clone();
    config.slots = args.slots;
    config.gpu_slots = gpu_slots;
    config.instance_id = args.instance_id;
    config.threads = threads;
    config.artifacts_dir = args.artifacts.clone();
    config.bed_cache = args.bed_cache.clone();
    config.checkpoint_dir = args.checkpoint_dir.clone();
    config.checkpoint_every = checkpoint_every;
    Ok(config)
}

/// `--checkpoint-every`: whole seconds or fractions, at most a day.
pub(crate) fn checkpoint_interval(seconds: f64) -> Result<Duration> {
    if seconds.is_finite() && (0.0..=86_400.0).contains(&seconds) {
        Ok(Duration::from_secs_f64(seconds))
    } else {
        bail!("--checkpoint-every must be between 0 and 86400 seconds, got {seconds}")
    }
}

/// The GPU the flags ask for (`--gpu`, `--gpu-slots`, `--gpu-memory`), checked.
pub fn gpu_settings(args: &WorkerArgs) -> Result<Option<crate::backend::WorkerGpu>> {
    crate::backend::worker_gpu(args.gpu, args.gpu_slots, args.gpu_memory)
}

pub fn run_worker(args: &WorkerArgs) -> Result<()> {
    let mut config = config(args)?;
    // Before logging starts: the Vulkan loader's INFO lines about opening a device are noise.
    config.gpu = crate::backend::open_worker_gpu(gpu_settings(args)?)?;
    crate::init_logging("info,wgpu_core=warn,wgpu_hal=warn,naga=warn");
    let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    let outcome = runtime.block_on(run(config, crate::server_cmd::shutdown_signal()));
    // A stalled run's thread never returns: end without waiting for it.
    runtime.shutdown_background();
    if let Err(stalled @ (WorkerError::Stalled { .. } | WorkerError::GpuFailed { .. })) = &outcome {
        // Not status 2 (a refusal a person must fix, which the service manager leaves alone):
        // a stalled worker, or one whose GPU was lost, is to be started again.
        eprintln!("error: worker failed: {stalled}");
        std::process::exit(STALLED_EXIT);
    }
    let summary = outcome.context("worker failed")?;
    if summary.exited_idle {
        eprintln!(
            "no job for the idle limit; exiting after {} completed, {} failed",
            summary.completed, summary.failed
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        worker: WorkerArgs,
    }

    #[test]
    fn exit_when_idle_is_checked_and_reaches_the_worker_config() {
        let cli = Cli::try_parse_from(["repose", "--exit-when-idle", "90"]).unwrap();
        let parsed = config(&cli.worker).unwrap();
        assert_eq!(parsed.exit_when_idle, Some(Duration::from_secs(90)));
        let cli = Cli::try_parse_from(["repose"]).unwrap();
        assert_eq!(config_of(&cli).exit_when_idle, None);
        for bad in ["0", "nan", "inf", "1e9"] {
            let cli = Cli::try_parse_from(["repose", "--exit-when-idle", bad]).unwrap();
            let err = config(&cli.worker).unwrap_err();
            assert!(err.to_string().contains("--exit-when-idle"), "{bad}: {err}");
        }
        let cli = Cli::try_parse_from(["repose", "--exit-when-idle=-5"]).unwrap();
        assert!(config(&cli.worker).is_err());
    }

    #[test]
    fn stall_timeout_defaults_to_a_quarter_hour_zero_turns_it_off_and_bad_values_are_named() {
        let cli = Cli::try_parse_from(["repose"]).unwrap();
        assert_eq!(
            config_of(&cli).stall_timeout,
            Some(repose_worker::DEFAULT_STALL_TIMEOUT)
        );
        let cli = Cli::try_parse_from(["repose", "--stall-timeout", "0"]).unwrap();
        assert_eq!(config_of(&cli).stall_timeout, None);
        let cli = Cli::try_parse_from(["repose", "--stall-timeout", "2.5"]).unwrap();
        assert_eq!(
            config_of(&cli).stall_timeout,
            Some(Duration::from_secs_f64(2.5))
        );
        for bad in ["nan", "inf", "1e9", "-1"] {
            let arg = format!("--stall-timeout={bad}");
            let cli = Cli::try_parse_from(["repose", arg.as_str()]).unwrap();
            let err = config(&cli.worker).unwrap_err();
            assert!(err.to_string().contains("--stall-timeout"), "{bad}: {err}");
        }
    }

    #[test]
    fn gpu_slots_are_counted_apart_from_the_cpu_slots() {
        let cli = Cli::try_parse_from(["repose"]).unwrap();
        assert_eq!((config_of(&cli).slots, config_of(&cli).gpu_slots), (1, 0));
        let cli = Cli::try_parse_from(["repose", "--gpu"]).unwrap();
        assert_eq!((config_of(&cli).slots, config_of(&cli).gpu_slots), (1, 1));
        let cli = Cli::try_parse_from(["repose", "--slots", "0", "--gpu-slots", "4"]).unwrap();
        let parsed = config_of(&cli);
        assert_eq!((parsed.slots, parsed.gpu_slots), (0, 4));
        assert!(parsed.threads >= 1);
        let cli = Cli::try_parse_from(["repose", "--slots", "0"]).unwrap();
        let err = config(&cli.worker).unwrap_err();
        assert!(err.to_string().contains("--slots"), "{err}");
    }

    fn config_of(cli: &Cli) -> WorkerConfig {
        config(&cli.worker).unwrap()
    }
}
