//! Opening a GPU: an adapter and a device with the adapter's own limits (large buffers); the
//! device's memory and the admission of the worlds that share it; a lost device.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::GpuError;

/// An opened GPU: adapter, device and queue. Open once, share among runs: several worlds may
/// run on it at once, each from its own thread, and each gives the bits it gives alone.
///
/// Every world is admitted against the device's memory before anything is allocated
/// ([`Gpu::memory_budget`]): one that can never fit is refused at once, one that fits only
/// once others end waits for them up to [`Gpu::set_admission_wait`].
#[derive(Debug)]
pub struct Gpu {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    profiling: bool,
    /// Held while a world is built under the device's error scopes (one stack per device).
    pub(crate) error_scopes: std::sync::Mutex<()>,
    /// The largest device-local memory heap, bytes, where the backend tells (Vulkan).
    memory: Option<u64>,
    /// The worlds on the device and the memory they hold.
    pub(crate) ledger: Arc<Ledger>,
    /// Why the device was lost, once it was (wgpu's device-lost callback).
    lost: Arc<Mutex<Option<String>>>,
}

/// The share of the device's memory a budget takes by default: the rest is left to the
/// driver, the shader modules and what the estimate of a world's buffers does not see.
const DEFAULT_BUDGET_PERCENT: u64 = 90;

/// [`Gpu::set_admission_wait`]'s default.
pub const DEFAULT_ADMISSION_WAIT: Duration = Duration::from_secs(600);

/// The worlds admitted on one device and the memory they hold.
#[derive(Debug, Default)]
pub(crate) struct Ledger {
    books: Mutex<Books>,
    freed: Condvar,
}

#[derive(Debug, Default)]
struct Books {
    /// Bytes the worlds may hold together; none: no budget (the backend does not tell the
    /// device's memory), only the adapter's per-buffer limits apply.
    budget: Option<u64>,
    reserved: u64,
    worlds: usize,
    wait: Duration,
}

impl Ledger {
    fn books(&self) -> MutexGuard<'_, Books> {
        self.books.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A world's hold on its share of the device's memory, given back when it is dropped (with
/// the world).
#[derive(Debug)]
pub(crate) struct Admission {
    ledger: Arc<Ledger>,
    bytes: u64,
}

impl Drop for Admission {
    fn drop(&mut self) {
        let mut books = self.ledger.books();
        books.reserved -= self.bytes;
        books.worlds -= 1;
        drop(books);
        self.ledger.freed.notify_all();
    }
}

/// `bytes` in MiB (or KiB below one MiB), for messages.
pub(crate) fn mib(bytes: u64) -> String {
    if bytes < 1 << 20 {
        format!("{:.1} KiB", bytes as f64 / 1024.0)
    } else {
        format!("{:.1} MiB", bytes as f64 / f64::from(1u32 << 20))
    }
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
        let memory = device_memory(&adapter);
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
        let lost = Arc::new(Mutex::new(None));
        {
            let lost = lost.clone();
            device.set_device_lost_callback(move |reason, message| {
                let mut lost = lost.lock().unwrap_or_else(|e| e.into_inner());
                lost.get_or_insert_with(|| match message.trim() {
                    "" => format!("{reason:?}"),
                    message => format!("{reason:?}: {message}"),
                });
            });
        }
        let ledger = Arc::new(Ledger::default());
        {
            let mut books = ledger.books();
            books.budget = memory.map(|m| m / 100 * DEFAULT_BUDGET_PERCENT);
            books.wait = DEFAULT_ADMISSION_WAIT;
        }
        Ok(Gpu {
            device,
            queue,
            info,
            limits,
            profiling,
            error_scopes: std::sync::Mutex::new(()),
            memory,
            ledger,
            lost,
        })
    }

    /// The device's memory, bytes: its largest device-local heap, where the backend tells
    /// (Vulkan); none elsewhere.
    pub fn memory(&self) -> Option<u64> {
        self.memory
    }

    /// Bytes of device memory the worlds on this GPU may hold together: by default 90 % of
    /// [`Gpu::memory`]; none where the device's memory is not known (then only the adapter's
    /// per-buffer limits and the driver's own allocation errors refuse a world).
    pub fn memory_budget(&self) -> Option<u64> {
        self.ledger.books().budget
    }

    /// Lets the worlds on this GPU hold at most `bytes` together (a GPU shared with other
    /// processes: `repose worker --gpu-memory`). A budget above [`Gpu::memory`] is cut to it.
    pub fn set_memory_budget(&self, bytes: u64) {
        let budget = self.memory.map_or(bytes, |m| bytes.min(m));
        self.ledger.books().budget = Some(budget);
        self.ledger.freed.notify_all();
    }

    /// How long a world that fits the budget only once others end waits for them before it
    /// is refused (default [`DEFAULT_ADMISSION_WAIT`]).
    pub fn set_admission_wait(&self, wait: Duration) {
        self.ledger.books().wait = wait;
    }

    /// Worlds on this GPU now, and the bytes they hold.
    pub fn in_flight(&self) -> (usize, u64) {
        let books = self.ledger.books();
        (books.worlds, books.reserved)
    }

    /// Why the device was lost (a driver reset, an unplugged or destroyed device), once it
    /// was; none while it works. A lost device stays lost: open another.
    pub fn lost(&self) -> Option<String> {
        self.lost.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Destroys the device, as a driver reset would lose it: every world on it fails and
    /// [`Gpu::lost`] says why. For tests of what runs on it when a device is lost.
    pub fn destroy(&self) {
        self.device.destroy();
        let _ = self.device.poll(wgpu::PollType::Poll);
        let mut lost = self.lost.lock().unwrap_or_else(|e| e.into_inner());
        lost.get_or_insert_with(|| "Destroyed: the device was destroyed".to_owned());
    }

    /// Admits a world of `bytes` (`what` describes it) against the budget: refused at once
    /// when it exceeds the whole budget or the device is lost; waits for other worlds to end
    /// when it fits only beside fewer of them, and is refused after the admission wait.
    pub(crate) fn admit(&self, bytes: u64, what: &str) -> Result<Admission, GpuError> {
        if let Some(reason) = self.lost() {
            return Err(GpuError::Lost(format!("the device was lost: {reason}")));
        }
        let ledger = &self.ledger;
        let mut books = ledger.books();
        let started = Instant::now();
        if let Some(budget) = books.budget {
            if bytes > budget {
                return Err(GpuError::Capacity(format!(
                    "{what} needs {} of device memory; {} allows {}{}",
                    mib(bytes),
                    self.name(),
                    mib(budget),
                    self.memory.map_or(String::new(), |m| format!(
                        " of its {} (--gpu-memory sets it)",
                        mib(m)
                    )),
                )));
            }
            while books.reserved + bytes > books.budget.unwrap_or(u64::MAX) {
                let left = books.wait.saturating_sub(started.elapsed());
                if left.is_zero() {
                    return Err(GpuError::Capacity(format!(
                        "{what} needs {} of device memory; the {} other run(s) on {} hold {} \
                         of its budget of {} and none ended within {:.1} s",
                        mib(bytes),
                        books.worlds,
                        self.name(),
                        mib(books.reserved),
                        mib(books.budget.unwrap_or(0)),
                        books.wait.as_secs_f64(),
                    )));
                }
                books = ledger
                    .freed
                    .wait_timeout(books, left)
                    .map_or_else(|e| e.into_inner().0, |(b, _)| b);
            }
        }
        books.reserved += bytes;
        books.worlds += 1;
        Ok(Admission {
            ledger: ledger.clone(),
            bytes,
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

/// The largest device-local heap of a Vulkan adapter, bytes; none on another backend.
#[cfg(any(windows, target_os = "linux", target_os = "android"))]
fn device_memory(adapter: &wgpu::Adapter) -> Option<u64> {
    // SAFETY: the adapter's Vulkan handles are only read, while `adapter` keeps them alive;
    // the memory properties query has no other requirement.
    let heaps = unsafe {
        let hal = adapter.as_hal::<wgpu::hal::api::Vulkan>()?;
        hal.shared_instance()
            .raw_instance()
            .get_physical_device_memory_properties(hal.raw_physical_device())
    };
    heaps
        .memory_heaps_as_slice()
        .iter()
        .filter(|h| h.flags.contains(ash::vk::MemoryHeapFlags::DEVICE_LOCAL))
        .map(|h| h.size)
        .max()
}

#[cfg(not(any(windows, target_os = "linux", target_os = "android")))]
fn device_memory(_adapter: &wgpu::Adapter) -> Option<u64> {
    None
}
