//! Opening a GPU: an adapter and a device with the adapter's own limits (large buffers).

use crate::GpuError;

/// An opened GPU: adapter, device and queue. Open once, share among runs.
#[derive(Debug)]
pub struct Gpu {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    profiling: bool,
    /// Held while a world is built under the device's error scopes (one stack per device).
    pub(crate) error_scopes: std::sync::Mutex<()>,
}

/// The features a profile needs: timestamps between the kernels of a compute pass.
fn profile_features() -> wgpu::Features {
    wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES
}

/// Whether `REPOSE_GPU_PROFILE` asks for a profile (set, not empty, not `0`).
fn profile_asked() -> bool {
    std::env::var("REPOSE_GPU_PROFILE").is_ok_and(|v| !v.is_empty() && v != "0")
}

/// The backends the engine uses: native compute APIs only (no GL, no WebGPU).
fn backends() -> wgpu::Backends {
    wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12
}

impl Gpu {
    /// The first high-performance adapter of Vulkan, Metal or DX12 (`WGPU_ADAPTER_NAME`, a
    /// substring of the adapter's name, picks another), with a device that has the adapter's
    /// own limits. No adapter is an error naming the backends tried, never a fall-back.
    ///
    /// `REPOSE_GPU_PROFILE=1` asks the worlds stepped on it to time their kernels
    /// ([`GpuWorld::profile`](crate::GpuWorld::profile)), where the adapter can write
    /// timestamps inside compute passes ([`Gpu::profiling`] says whether it could).
    pub fn open() -> Result<Gpu, GpuError> {
        let instance = wgpu::Instance::new(&wgpu::InstanceDescriptor {
            backends: backends(),
            ..Default::default()
        });
        let adapter = match std::env::var("WGPU_ADAPTER_NAME") {
            Ok(name) if !name.is_empty() => {
                let wanted = name.to_lowercase();
                instance
                    .enumerate_adapters(backends())
                    .into_iter()
                    .find(|a| a.get_info().name.to_lowercase().contains(&wanted))
                    .ok_or_else(|| {
                        GpuError::NoAdapter(format!(
                            "no Vulkan/Metal/DX12 adapter's name contains {name:?} (WGPU_ADAPTER_NAME)"
                        ))
                    })?
            }
            _ => pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                force_fallback_adapter: false,
                compatible_surface: None,
            }))
            .map_err(|e| {
                GpuError::NoAdapter(format!(
                    "no Vulkan, Metal or DX12 adapter ({e}); on Linux install a Vulkan driver \
                     (a GPU vendor's, or Mesa's lavapipe: mesa-vulkan-drivers) and the loader \
                     (libvulkan1)"
                ))
            })?,
        };
        let info = adapter.get_info();
        let limits = adapter.limits();
        let profiling = profile_asked() && adapter.features().contains(profile_features());
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("repose-engine-gpu"),
            required_features: if profiling {
                profile_features()
            } else {
                wgpu::Features::empty()
            },
            required_limits: limits.clone(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device {
            adapter: info.name.clone(),
            reason: e.to_string(),
        })?;
        Ok(Gpu {
            device,
            queue,
            info,
            limits,
            profiling,
            error_scopes: std::sync::Mutex::new(()),
        })
    }

    /// Whether the worlds stepped on this GPU time their kernels (`REPOSE_GPU_PROFILE` asked
    /// and the adapter can).
    pub fn profiling(&self) -> bool {
        self.profiling
    }

    /// The adapter's name, backend and driver, e.g. "NVIDIA H200 (Vulkan, NVIDIA 570.x)".
    pub fn describe(&self) -> String {
        let i = &self.info;
        let driver = [i.driver.as_str(), i.driver_info.as_str()]
            .iter()
            .filter(|s| !s.is_empty())
            .copied()
            .collect::<Vec<_>>()
            .join(" ");
        format!("{} ({:?}, {})", i.name, i.backend, driver)
    }

    /// The adapter's name.
    pub fn name(&self) -> &str {
        &self.info.name
    }

    pub(crate) fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }
}
