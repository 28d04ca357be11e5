//! Where a GPU world's time goes, when [`Gpu::open`](crate::Gpu::open) was asked to profile
//! (`REPOSE_GPU_PROFILE`) and the adapter can write timestamps inside compute passes.
//!
//! Every submission of steps then writes a timestamp before its first kernel and after each
//! one, and is waited for and read back at once: the run is slower and each kernel's interval
//! (its own time and the barrier before the next) is measured. The host's time to encode the
//! steps and its waits for read-backs are counted beside them.

use std::fmt;
use std::time::Duration;

use crate::GpuError;

/// Timestamps one submission can hold: a step writes at most seven, a submission holds 25
/// steps and a velocity Verlet start-up.
const QUERIES: u32 = 1024;

/// One kernel's share of a [`Profile`].
#[derive(Debug, Clone, PartialEq)]
pub struct KernelTime {
    pub name: &'static str,
    pub dispatches: u64,
    /// GPU seconds between the timestamp before its dispatches and the one after them.
    pub seconds: f64,
}

/// Where the time of a GPU world's steps went, as far as it was profiled.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Profile {
    /// The kernels in the order they first ran.
    pub kernels: Vec<KernelTime>,
    pub steps: u64,
    /// Submissions of steps (each profiled).
    pub submissions: u64,
    /// GPU seconds from each submission's first timestamp to its last, summed.
    pub gpu_seconds: f64,
    /// Host seconds spent encoding and submitting the steps.
    pub encode_seconds: f64,
    /// Read-backs of device data (particles, counters, loads, slab sums) and the host's
    /// seconds in them, waiting for the queue included.
    pub read_backs: u64,
    pub read_back_seconds: f64,
}

impl Profile {
    fn add(&mut self, name: &'static str, seconds: f64) {
        match self.kernels.iter_mut().find(|k| k.name == name) {
            Some(k) => {
                k.dispatches += 1;
                k.seconds += seconds;
            }
            None => self.kernels.push(KernelTime {
                name,
                dispatches: 1,
                seconds,
            }),
        }
    }
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let per_step = |s: f64| 1e6 * s / self.steps.max(1) as f64;
        writeln!(
            f,
            "GPU profile: {} steps in {} submissions; GPU {:.3} s ({:.1} µs a step), host \
             encoding {:.3} s, {} read-backs {:.3} s",
            self.steps,
            self.submissions,
            self.gpu_seconds,
            per_step(self.gpu_seconds),
            self.encode_seconds,
            self.read_backs,
            self.read_back_seconds
        )?;
        for k in &self.kernels {
            writeln!(
                f,
                "  {:<13} {:>9} dispatches {:>9.3} s {:>8.2} µs a step {:>8.2} µs a dispatch",
                k.name,
                k.dispatches,
                k.seconds,
                per_step(k.seconds),
                1e6 * k.seconds / k.dispatches.max(1) as f64
            )?;
        }
        Ok(())
    }
}

/// The timestamps of the submission being encoded and the totals so far.
pub(crate) struct Profiler {
    queries: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// Nanoseconds a timestamp tick.
    period_ns: f64,
    /// The kernel each interval of the submission being encoded ends with.
    labels: Vec<&'static str>,
    /// A submission of steps is being encoded (other passes are not stamped).
    active: bool,
    totals: Profile,
}

impl Profiler {
    pub(crate) fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Profiler {
        let bytes = QUERIES as u64 * 8;
        Profiler {
            queries: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("profile"),
                ty: wgpu::QueryType::Timestamp,
                count: QUERIES,
            }),
            resolve: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("profile resolve"),
                size: bytes,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            readback: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("profile read back"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            period_ns: queue.get_timestamp_period() as f64,
            labels: Vec::new(),
            active: false,
            totals: Profile::default(),
        }
    }

    /// The first timestamp of a submission, before its first kernel.
    pub(crate) fn begin(&mut self, pass: &mut wgpu::ComputePass) {
        self.labels.clear();
        self.active = true;
        pass.write_timestamp(&self.queries, 0);
    }

    /// The timestamp after kernel `name`'s dispatch (none once the set is full: that
    /// kernel's time then counts in the next stamped one).
    pub(crate) fn after(&mut self, pass: &mut wgpu::ComputePass, name: &'static str) {
        let index = self.labels.len() as u32 + 1;
        if self.active && index < QUERIES {
            self.labels.push(name);
            pass.write_timestamp(&self.queries, index);
        }
    }

    /// Waits for the submission just made, reads its timestamps and adds them up.
    pub(crate) fn end(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        steps: u64,
        encoding: Duration,
    ) -> Result<(), GpuError> {
        self.active = false;
        let count = self.labels.len() as u32 + 1;
        let bytes = count as u64 * 8;
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("profile"),
        });
        encoder.resolve_query_set(&self.queries, 0..count, &self.resolve, 0);
        encoder.copy_buffer_to_buffer(&self.resolve, 0, &self.readback, 0, bytes);
        queue.submit([encoder.finish()]);
        let slice = self.readback.slice(..bytes);
        let (sender, receiver) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = sender.send(r);
        });
        let lost = |e: String| GpuError::Lost(format!("reading the profile's timestamps: {e}"));
        device
            .poll(wgpu::PollType::Wait)
            .map_err(|e| lost(e.to_string()))?;
        receiver
            .recv()
            .map_err(|e| lost(e.to_string()))?
            .map_err(|e| lost(e.to_string()))?;
        let ticks: Vec<u64> = bytemuck::cast_slice(&slice.get_mapped_range()).to_vec();
        self.readback.unmap();
        let seconds = |a: u64, b: u64| b.saturating_sub(a) as f64 * self.period_ns * 1e-9;
        for (k, &name) in self.labels.iter().enumerate() {
            self.totals.add(name, seconds(ticks[k], ticks[k + 1]));
        }
        let t = &mut self.totals;
        t.gpu_seconds += seconds(ticks[0], ticks[count as usize - 1]);
        t.steps += steps;
        t.submissions += 1;
        t.encode_seconds += encoding.as_secs_f64();
        Ok(())
    }

    /// A read-back of device data that took `took` on the host.
    pub(crate) fn read_back(&mut self, took: Duration) {
        self.totals.read_backs += 1;
        self.totals.read_back_seconds += took.as_secs_f64();
    }

    pub(crate) fn totals(&self) -> &Profile {
        &self.totals
    }
}
