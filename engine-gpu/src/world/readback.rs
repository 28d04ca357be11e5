//! Read-backs: the particles, the counters and the fastest speed, the moving geometries'
//! loads, the neighbour lists and the raw state, each copied to the host in one submission and
//! read after one wait for the queue; what a read-back of the particles saw is kept for later
//! questions about the same step.

use std::time::Instant;

use bytemuck::Pod;
use repose_engine::math::Vec3;
use repose_engine::world::GeometrySample;

use super::buffers::ctl;
use super::{lock, Counters, GpuParticles, GpuWorld, Seen};
use crate::scene::{Voxel, BIN_CAPACITY, NEIGHBOUR_CAPACITY};
use crate::GpuError;

/// Per buffer read, its slots' 16-byte records; then the control words.
type SlotsRead<const K: usize> = ([Vec<[f32; 4]>; K], Vec<u32>);

/// Whether a slot is empty: a removed grain's voxel record has a negative fourth word.
fn is_empty(cell: &[i32; 4]) -> bool {
    cell[3] < 0
}

/// The empty slots, ascending.
fn empty_of(cell: &[[i32; 4]]) -> Vec<usize> {
    (0..cell.len()).filter(|&k| is_empty(&cell[k])).collect()
}

impl GpuWorld {
    /// Waits for every queued step.
    pub fn finish(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::Wait)
            .map_err(|e| GpuError::Lost(e.to_string()))?;
        self.drained
            .store(true, std::sync::atomic::Ordering::Relaxed);
        Ok(())
    }

    fn read<T: Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>, GpuError> {
        self.read_prefix(buffer, buffer.size())
    }

    /// The first `size` bytes of `buffer`.
    pub(super) fn read_prefix<T: Pod>(
        &self,
        buffer: &wgpu::Buffer,
        size: u64,
    ) -> Result<Vec<T>, GpuError> {
        let bytes = self.read_prefixes(&[(buffer, size)])?;
        Ok(bytemuck::pod_collect_to_vec(&bytes[0]))
    }

    /// The first `size` bytes of each buffer, copied in one submission and read after one
    /// wait for the queue (each wait idles the GPU until the host submits again).
    fn read_prefixes(&self, parts: &[(&wgpu::Buffer, u64)]) -> Result<Vec<Vec<u8>>, GpuError> {
        let started = Instant::now();
        let total: u64 = parts.iter().map(|&(_, size)| size).sum();
        if total == 0 {
            return Ok(vec![Vec::new(); parts.len()]);
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size: total,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("read"),
            });
        let mut at = 0;
        for &(buffer, size) in parts {
            if size > 0 {
                encoder.copy_buffer_to_buffer(buffer, 0, &staging, at, size);
            }
            at += size;
        }
        let submitted = self.queue.submit([encoder.finish()]);
        let slice = staging.slice(..);
        let (sender, receiver) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = sender.send(r);
        });
        // This world's work up to the copy (the queue runs in order), not the submissions
        // other worlds sharing the device made since.
        self.device
            .poll(wgpu::PollType::WaitForSubmissionIndex(submitted))
            .map_err(|e| GpuError::Lost(e.to_string()))?;
        self.drained
            .store(true, std::sync::atomic::Ordering::Relaxed);
        receiver
            .recv()
            .map_err(|e| GpuError::Lost(e.to_string()))?
            .map_err(|e| GpuError::Lost(e.to_string()))?;
        let out = {
            let mapped = slice.get_mapped_range();
            let mut at = 0;
            parts
                .iter()
                .map(|&(_, size)| {
                    let bytes = mapped[at as usize..(at + size) as usize].to_vec();
                    at += size;
                    bytes
                })
                .collect()
        };
        staging.unmap();
        if let Some(profiler) = &self.profiler {
            lock(profiler).read_back(started.elapsed());
        }
        Ok(out)
    }

    /// The first [`GpuWorld::len`] slots' records of the particle buffers `buffers` (16 bytes
    /// a slot) and the control words, read back together.
    fn read_slots<const K: usize>(
        &self,
        buffers: [&wgpu::Buffer; K],
    ) -> Result<SlotsRead<K>, GpuError> {
        let size = self.n as u64 * 16;
        let ctl = &self.buffers.ctl;
        let parts: Vec<(&wgpu::Buffer, u64)> = (buffers.iter().map(|&b| (b, size)))
            .chain([(ctl, ctl.size())])
            .collect();
        let mut bytes = self.read_prefixes(&parts)?;
        let control = bytemuck::pod_collect_to_vec(&bytes.pop().expect("the control words"));
        let slots: Vec<Vec<[f32; 4]>> = bytes
            .iter()
            .map(|b| bytemuck::pod_collect_to_vec(b))
            .collect();
        let slots = slots.try_into().expect("one vector a buffer");
        Ok((slots, control))
    }

    /// The control words after the present step: those a read-back of the particles saw at
    /// this step, or read back now. An overflowed capacity is an error.
    fn control(&self) -> Result<Vec<u32>, GpuError> {
        let seen = lock(&self.seen)
            .as_ref()
            .filter(|seen| seen.steps == self.steps)
            .map(|seen| seen.control.clone());
        let words = match seen {
            Some(words) => words,
            None => self.read(&self.buffers.ctl)?,
        };
        Self::check_overflows(&words)?;
        Ok(words)
    }

    /// The empty slots (removed grains') after the present step, ascending: as a read-back of
    /// the particles saw them at this step, or read back now.
    pub(super) fn empty_slots(&self) -> Result<Vec<usize>, GpuError> {
        if let Some(seen) = lock(&self.seen).as_ref().filter(|s| s.steps == self.steps) {
            return Ok(seen.empty.clone());
        }
        let cell: Vec<[i32; 4]> = self.read_prefix(&self.buffers.cell, self.n as u64 * 16)?;
        Ok(empty_of(&cell))
    }

    /// Notes what a read-back of the particles (`cell` and the control words) saw now.
    fn note_seen(&self, cell: &[[i32; 4]], control: Vec<u32>) {
        *lock(&self.seen) = Some(Seen {
            steps: self.steps,
            control,
            empty: empty_of(cell),
        });
    }

    fn check_overflows(words: &[u32]) -> Result<(), GpuError> {
        let overflow = |word: usize, what: &str| -> Result<(), GpuError> {
            if words[word] > 0 {
                return Err(GpuError::Overflow(format!(
                    "{} times more {what} than the backend holds",
                    words[word]
                )));
            }
            Ok(())
        };
        overflow(
            ctl::NEIGHBOUR_OVERFLOW,
            &format!("neighbours within the skin ({NEIGHBOUR_CAPACITY} per particle)"),
        )?;
        overflow(
            ctl::BIN_OVERFLOW,
            &format!("particles in a neighbour cell ({BIN_CAPACITY} per cell)"),
        )?;
        overflow(
            ctl::WALL_OVERFLOW,
            "triangle contact candidates (16 per particle before merging)",
        )
    }

    /// The run's counters; an overflow of a fixed capacity is an error (the results are not
    /// valid). No read-back after [`GpuWorld::positions`] or [`GpuWorld::particles`] at the
    /// same step (they read the counters too).
    pub fn counters(&self) -> Result<Counters, GpuError> {
        let words = self.control()?;
        Ok(Counters {
            rebuilds: words[ctl::REBUILDS] as u64,
            removed: words[ctl::REMOVED] as u64,
        })
    }

    /// The fastest particle's speed now, m/s.
    pub fn fastest_speed(&self) -> Result<f64, GpuError> {
        self.write_control(ctl::FASTEST, 0);
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("fastest"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("fastest"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, &self.bindings.main, &[]);
            pass.set_bind_group(1, &self.bindings.step_params, &[]);
            pass.set_bind_group(2, &self.bindings.frames, &[0]);
            self.dispatch(&mut pass, &self.pipelines.fastest, self.n, "fastest");
        }
        self.queue.submit([encoder.finish()]);
        let words = self.control()?;
        Ok(f32::from_bits(words[ctl::FASTEST]) as f64)
    }

    /// Neighbour-list pairs (each pair once).
    pub fn pair_count(&self) -> Result<usize, GpuError> {
        let counts: Vec<u32> = self.read(&self.buffers.nbn)?;
        Ok(counts.iter().map(|&c| c as usize).sum::<usize>() / 2)
    }

    /// Each particle's neighbour list (partner slots, ascending) as of the last rebuild.
    pub fn neighbour_lists(&self) -> Result<Vec<Vec<u32>>, GpuError> {
        let counts: Vec<u32> = self.read(&self.buffers.nbn)?;
        let slots: Vec<u32> = self.read(&self.buffers.nbr)?;
        Ok(counts[..self.n]
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                (0..c as usize)
                    .map(|k| slots[k * self.capacity + i])
                    .collect()
            })
            .collect())
    }

    /// The particles' voxels and offsets (as the shader holds them), by slot.
    pub fn voxels(&self) -> Result<Vec<Voxel>, GpuError> {
        let cell: Vec<[i32; 4]> = self.read(&self.buffers.cell)?;
        let off: Vec<[f32; 4]> = self.read(&self.buffers.off)?;
        Ok(cell[..self.n]
            .iter()
            .zip(&off)
            .map(|(c, o)| ([c[0], c[1], c[2]], [o[0], o[1], o[2]]))
            .collect())
    }

    /// The particles' centres now and whether each slot is empty (its grain removed), by slot:
    /// one read-back of two buffers (and the counters) where [`GpuWorld::particles`] reads five
    /// (e.g. a host-side room test). An [`GpuWorld::insert`] at the same step then finds the
    /// removed grains' slots without a read-back.
    pub fn positions(&self) -> Result<(Vec<Vec3>, Vec<bool>), GpuError> {
        let ([cell, off], control) = self.read_slots([&self.buffers.cell, &self.buffers.off])?;
        let cell: Vec<[i32; 4]> = cell.into_iter().map(bytemuck::cast).collect();
        self.note_seen(&cell, control);
        Ok((
            cell.iter()
                .zip(&off)
                .map(|(c, o)| {
                    self.grid
                        .to_position([c[0], c[1], c[2]], [o[0], o[1], o[2]])
                })
                .collect(),
            cell.iter().map(is_empty).collect(),
        ))
    }

    /// The particles now, by slot (the first [`GpuWorld::len`] slots).
    pub fn particles(&self) -> Result<GpuParticles, GpuError> {
        let b = &self.buffers;
        let ([cell, off, vel, omg, trq], control) =
            self.read_slots([&b.cell, &b.off, &b.vel, &b.omg, &b.trq])?;
        let cell: Vec<[i32; 4]> = cell.into_iter().map(bytemuck::cast).collect();
        self.note_seen(&cell, control);
        let v3 = |v: &[f32; 4]| Vec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
        Ok(GpuParticles {
            position: cell
                .iter()
                .zip(&off)
                .map(|(c, o)| {
                    self.grid
                        .to_position([c[0], c[1], c[2]], [o[0], o[1], o[2]])
                })
                .collect(),
            velocity: vel.iter().map(v3).collect(),
            angular_velocity: omg.iter().map(v3).collect(),
            radius: self.radius.clone(),
            removed: cell.iter().map(is_empty).collect(),
            contacts: trq.iter().map(|t| t[3] as u32).collect(),
        })
    }

    /// The raw device state (voxels, offsets, velocities, spins, springs' list lengths), for
    /// bit-identity checks.
    pub fn state_bytes(&self) -> Result<Vec<u8>, GpuError> {
        let mut bytes: Vec<u8> = self.read(&self.buffers.cell)?;
        for buffer in [
            &self.buffers.off,
            &self.buffers.vel,
            &self.buffers.omg,
            &self.buffers.nbn,
        ] {
            bytes.extend(self.read::<u8>(buffer)?);
        }
        Ok(bytes)
    }

    /// Reads the pending load records back into the series.
    pub(super) fn read_loads(&mut self) -> Result<(), GpuError> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let movers = self.movers.len();
        let words: Vec<[f32; 4]> = self.read_prefix(
            &self.buffers.series,
            (self.pending.len() * movers * 32) as u64,
        )?;
        let v = |w: [f32; 4]| Vec3::new(w[0] as f64, w[1] as f64, w[2] as f64);
        for (r, &time) in self.pending.iter().enumerate() {
            for (m, series) in self.loads.iter_mut().enumerate() {
                let at = 2 * (r * movers + m);
                series.push(GeometrySample {
                    time,
                    force: v(words[at]),
                    torque: v(words[at + 1]),
                });
            }
        }
        self.pending.clear();
        Ok(())
    }

    /// The loads recorded on moving geometry `geometry` (its index in the world the GPU world
    /// was built from), as the CPU engine's `World::geometry_series` has them: every
    /// `geometry_record_interval` steps since the start or the last
    /// [`GpuWorld::clear_geometry_series`], the force the grains exert on it and its torque
    /// about its reference point, at the time of the force evaluation. Summed in f32 in a
    /// fixed order (the same bits on one adapter). The loads on a geometry baked into the
    /// voxels (still, and not listed as movable: [`GpuWorld::with_movers`]) are not summed on
    /// the GPU: an error naming it.
    pub fn geometry_series(&mut self, geometry: usize) -> Result<&[GeometrySample], GpuError> {
        let Some(m) = self.movers.iter().position(|m| m.geometry == geometry) else {
            return Err(GpuError::Unsupported(format!(
                "the loads on geometry {geometry}, which does not move"
            )));
        };
        self.read_loads()?;
        Ok(&self.loads[m])
    }

    /// Forgets the loads recorded so far.
    pub fn clear_geometry_series(&mut self) {
        self.pending.clear();
        for series in &mut self.loads {
            series.clear();
        }
    }
}
