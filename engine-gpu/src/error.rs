//! What can go wrong on the GPU backend.

use thiserror::Error;

#[derive(Debug, Error)]
pub enum GpuError {
    /// No Vulkan, Metal or DX12 adapter could be opened (no driver, no ICD, a container
    /// without the device): the message names what was tried.
    #[error("no GPU adapter: {0}")]
    NoAdapter(String),
    /// The adapter opened but refused a device with the limits the engine needs.
    #[error("the GPU adapter {adapter} refused a device: {reason}")]
    Device { adapter: String, reason: String },
    /// The scene uses something this backend does not simulate yet.
    #[error("the GPU backend does not support {0} yet")]
    Unsupported(String),
    /// The scene does not fit the backend's fixed capacities or the adapter's limits.
    #[error("the scene does not fit the GPU backend: {0}")]
    Capacity(String),
    /// An argument that is not valid for the world: a geometry index that is not one of its
    /// geometries, a slab that is not finite, no steps to sample.
    #[error("invalid argument: {0}")]
    Invalid(String),
    /// A particle to insert is not valid for the world (material, radius, place).
    #[error("cannot insert a particle: {0}")]
    Particle(String),
    /// A per-particle capacity overflowed during the run (the run's results are not valid).
    #[error("GPU run overflowed: {0}")]
    Overflow(String),
    /// The device was lost or a buffer could not be read back.
    #[error("GPU device error: {0}")]
    Lost(String),
}
