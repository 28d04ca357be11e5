//! `--backend`: which engine runs a simulation; `--gpu`: a worker's GPU.

/// The DEM engine a command runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The CPU engine (the reference: deterministic for any thread count).
    Cpu,
    /// The GPU engine (wgpu compute: Vulkan, Metal, DX12); deterministic per adapter.
    Gpu,
}

/// A worker's GPU as `repose worker` and `repose up` are asked for it: `--gpu`, `--gpu-slots`
/// (which implies `--gpu`) and `--gpu-memory`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkerGpu {
    /// GPU jobs run at once, sharing the adapter.
    pub slots: usize,
    /// The device memory the runs may hold together, bytes; none: the engine's default (90 %
    /// of the device's, where known).
    pub memory_bytes: Option<u64>,
}

/// The largest `--gpu-memory`, GiB (beyond any device).
const MAX_GPU_MEMORY_GIB: f64 = 1_048_576.0;

/// `--gpu`, `--gpu-slots N` and `--gpu-memory GIB`, checked: none without a GPU.
pub fn worker_gpu(
    gpu: bool,
    slots: Option<usize>,
    memory_gib: Option<f64>,
) -> anyhow::Result<Option<WorkerGpu>> {
    if slots == Some(0) {
        anyhow::bail!("--gpu-slots must be at least 1 (leave out --gpu and --gpu-slots for a CPU-only worker)");
    }
    let memory_bytes = match memory_gib {
        None => None,
        Some(gib) if gib.is_finite() && gib > 0.0 && gib <= MAX_GPU_MEMORY_GIB => {
            Some((gib * f64::from(1u32 << 30)) as u64)
        }
        Some(gib) => anyhow::bail!("--gpu-memory must be a number of GiB above 0, got {gib}"),
    };
    if !gpu && slots.is_none() {
        if memory_bytes.is_some() {
            anyhow::bail!("--gpu-memory needs --gpu (or --gpu-slots)");
        }
        return Ok(None);
    }
    Ok(Some(WorkerGpu {
        slots: slots.unwrap_or(1),
        memory_bytes,
    }))
}

/// The GPU a worker (`repose worker --gpu`, `repose up --gpu`) runs `gpu` jobs on, opened once
/// at start (with its memory budget) and shared by its GPU slots; `None` without one. No
/// adapter is an error naming the problem: a worker asked for a GPU never runs as a CPU-only
/// one.
pub fn open_worker_gpu(
    settings: Option<WorkerGpu>,
) -> anyhow::Result<Option<std::sync::Arc<repose_experiments::backend::Gpu>>> {
    use anyhow::Context;
    let Some(settings) = settings else {
        return Ok(None);
    };
    let opened = repose_experiments::backend::Gpu::open().context(
        "--gpu: this worker cannot open a GPU adapter, so it cannot run gpu jobs (start it \
         without --gpu to run CPU jobs only)",
    )?;
    if let Some(bytes) = settings.memory_bytes {
        opened.set_memory_budget(bytes);
    }
    announce(&opened);
    match (opened.memory(), opened.memory_budget()) {
        (Some(memory), Some(budget)) => eprintln!(
            "GPU: {} GiB of memory; its {} GPU slot(s) may hold {} GiB",
            gib(memory),
            settings.slots,
            gib(budget)
        ),
        (None, Some(budget)) => eprintln!(
            "GPU: its {} GPU slot(s) may hold {} GiB (--gpu-memory)",
            settings.slots,
            gib(budget)
        ),
        _ => eprintln!(
            "GPU: this backend does not tell the device's memory: a world too large for it is \
             refused by the driver (--gpu-memory sets a budget)"
        ),
    }
    Ok(Some(std::sync::Arc::new(opened)))
}

fn gib(bytes: u64) -> String {
    format!("{:.1}", bytes as f64 / f64::from(1u32 << 30))
}

/// The GPU a command's `--backend gpu` runs on, opened (its adapter named on stderr); `None`
/// for the CPU. No adapter is an error naming the problem, never a fall-back to the CPU.
pub fn open_gpu(backend: Backend) -> anyhow::Result<Option<repose_experiments::backend::Gpu>> {
    use anyhow::Context;
    match backend {
        Backend::Cpu => Ok(None),
        Backend::Gpu => {
            let gpu = repose_experiments::backend::Gpu::open().context("--backend gpu")?;
            announce_and_log(&gpu);
            Ok(Some(gpu))
        }
    }
}

/// Names the adapter on stderr. With `REPOSE_GPU_PROFILE` set, says whether the adapter can
/// time its kernels: where it can, each GPU world logs its profile when dropped (target
/// `repose_engine_gpu::profile`, level info: a worker's log has it).
pub fn announce(gpu: &repose_engine_gpu::Gpu) {
    eprintln!("GPU: {}", gpu.describe());
    if std::env::var_os("REPOSE_GPU_PROFILE").is_some_and(|v| !v.is_empty() && v != "0") {
        if gpu.profiling() {
            eprintln!("GPU: timing every kernel (REPOSE_GPU_PROFILE): the run is slower");
        } else {
            eprintln!(
                "GPU: REPOSE_GPU_PROFILE is set, but this adapter cannot write timestamps \
                 inside compute passes: no profile"
            );
        }
    }
}

/// [`announce`], for a command that logs nothing else: a profile goes to stderr.
pub fn announce_and_log(gpu: &repose_engine_gpu::Gpu) {
    announce(gpu);
    if gpu.profiling() {
        crate::init_logging("warn,repose_engine_gpu::profile=info");
    }
}

/// The engine a command runs on: the GPU it opened, else the CPU.
pub fn engine(
    gpu: Option<&repose_experiments::backend::Gpu>,
) -> repose_experiments::backend::Engine<'_> {
    use repose_experiments::backend::Engine;
    gpu.map_or(Engine::Cpu, Engine::Gpu)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worker_gpu_settings_are_checked_and_gpu_slots_imply_a_gpu() {
        assert_eq!(worker_gpu(false, None, None).unwrap(), None);
        let one = worker_gpu(true, None, None).unwrap().unwrap();
        assert_eq!((one.slots, one.memory_bytes), (1, None));
        let four = worker_gpu(false, Some(4), Some(2.0)).unwrap().unwrap();
        assert_eq!((four.slots, four.memory_bytes), (4, Some(2 << 30)));
        for (gpu, slots, memory, named) in [
            (true, Some(0), None, "--gpu-slots"),
            (true, None, Some(0.0), "--gpu-memory"),
            (true, None, Some(f64::NAN), "--gpu-memory"),
            (false, None, Some(8.0), "--gpu-memory needs --gpu"),
        ] {
            let err = worker_gpu(gpu, slots, memory).unwrap_err().to_string();
            assert!(err.contains(named), "{err}");
        }
    }
}
