//! `--backend`: which engine runs a simulation; `--gpu`: a worker's GPU.

/// The DEM engine a command runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The CPU engine (the reference: deterministic for any thread count).
    Cpu,
    /// The GPU engine (wgpu compute: Vulkan, Metal, DX12); deterministic per adapter.
    Gpu,
}

/// The GPU a worker (`repose worker --gpu`, `repose up --gpu`) runs `gpu` jobs on, opened once
/// at start and shared by its slots; `None` without the flag. No adapter is an error naming
/// the problem: a worker asked for a GPU never runs as a CPU-only one.
pub fn open_worker_gpu(
    gpu: bool,
) -> anyhow::Result<Option<std::sync::Arc<repose_experiments::backend::Gpu>>> {
    use anyhow::Context;
    if !gpu {
        return Ok(None);
    }
    let opened = repose_experiments::backend::Gpu::open().context(
        "--gpu: this worker cannot open a GPU adapter, so it cannot run gpu jobs (start it \
         without --gpu to run CPU jobs only)",
    )?;
    announce(&opened);
    Ok(Some(std::sync::Arc::new(opened)))
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
