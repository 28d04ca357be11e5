//! Opening the test GPU: any Vulkan/Metal/DX12 adapter (Mesa's lavapipe in CI).

use repose_engine_gpu::{Gpu, GpuError};

/// The GPU, or `None` with a message on stderr where no adapter can be created at all (the
/// test then checks nothing and says so). `REPOSE_REQUIRE_GPU=1` (set by `.ci/run`, which
/// installs lavapipe) turns that into a failure.
pub fn gpu() -> Option<Gpu> {
    match Gpu::open() {
        Ok(gpu) => {
            eprintln!("GPU: {}", gpu.describe());
            Some(gpu)
        }
        Err(e @ GpuError::NoAdapter(_)) => {
            if std::env::var("REPOSE_REQUIRE_GPU").is_ok_and(|v| v == "1") {
                panic!("REPOSE_REQUIRE_GPU=1 but {e}");
            }
            eprintln!("SKIPPED: {e}");
            None
        }
        Err(e) => panic!("{e}"),
    }
}
