//! `--backend`: which engine runs a simulation.

/// The DEM engine a command runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The CPU engine (the reference: deterministic for any thread count).
    Cpu,
    /// The GPU engine (wgpu compute: Vulkan, Metal, DX12); deterministic per adapter.
    Gpu,
}
