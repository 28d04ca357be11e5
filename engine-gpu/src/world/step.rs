//! Stepping: the kernels' dispatch order in a step, the submissions of steps, the moving
//! geometries' frames for each force evaluation, a sampled slab and a geometry's new motion.

use std::time::Instant;

use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::math::Vec3;

use super::buffers::{FRAME_BYTES, SERIES_RECORDS, STEPS_PER_SUBMIT};
use super::{groups, lock, GpuWorld, Slab};
use crate::movers::{frames_at, SlabFrame};
use crate::GpuError;

/// Steps of the first submission after a read-back, which found the queue empty: the GPU
/// waits while the host encodes them (about 30 µs a step on the H200's host), so they are few.
const STEPS_AFTER_READ_BACK: u64 = 4;

impl GpuWorld {
    /// Runs `pipeline` over `count` threads (kernel `name` in a profile).
    pub(super) fn dispatch(
        &self,
        pass: &mut wgpu::ComputePass,
        pipeline: &wgpu::ComputePipeline,
        count: usize,
        name: &'static str,
    ) {
        self.dispatch_groups(pass, pipeline, groups(count), name);
    }

    fn dispatch_groups(
        &self,
        pass: &mut wgpu::ComputePass,
        pipeline: &wgpu::ComputePipeline,
        workgroups: u32,
        name: &'static str,
    ) {
        pass.set_pipeline(pipeline);
        pass.dispatch_workgroups(workgroups, 1, 1);
        if let Some(profiler) = &self.profiler {
            lock(profiler).after(pass, name);
        }
    }

    /// The rebuild kernels: each a no-op unless a grain moved half a skin since the last
    /// rebuild or grains were inserted (the request word the step's `forces` resets; no
    /// GPU-written dispatch sizes, no read-back). `commit` also empties the bins `bin` filled,
    /// so no kernel runs over the grid's cells.
    fn rebuild_phase(&self, pass: &mut wgpu::ComputePass) {
        let p = &self.pipelines;
        for (pipeline, name) in [(&p.bin, "bin"), (&p.build, "build"), (&p.commit, "commit")] {
            self.dispatch(pass, pipeline, self.n, name);
        }
    }

    /// Advances `steps` steps (queued: call [`GpuWorld::finish`] or read something back to
    /// wait for them). Errors: the device was lost while the moving geometries' load records
    /// were read back (every 16 384 records).
    pub fn run(&mut self, steps: u64) -> Result<(), GpuError> {
        self.run_steps(steps, None)
    }

    /// Advances `steps` (at least one) steps, as [`GpuWorld::run`] does (the moving geometries'
    /// loads recorded alike), and returns the stress sum of `slab` at the last step's force
    /// evaluation: over the particle-particle contacts, each pair once, whose branch's midpoint
    /// has its x and y in `[x0, x1) × [y0, y1)`, Σ (the contact's force on the pair's upper
    /// grain from the lower one) × (the length of the branch's vertical extent inside
    /// `[z0, z1]`), N·m; components x, y, z. The force is the whole contact force (elastic,
    /// damping, tangential, cohesion), not its torques; the upper grain is the one with the
    /// higher centre, and a contact with no length inside the slab does not count (the
    /// shear test's measurement window: its normal stress is `sum.z / V`, its shear stress
    /// `-sum.x / V`, V the slab's volume). The branch is the one of the force evaluation (the
    /// CPU engine's, read after a symplectic Euler step, is one drift later) and its midpoint
    /// is taken from the pair's lower slot (in a periodic domain, the image next to it).
    ///
    /// Each grain sums its shares of its pairs with higher slots in f32 in its list order; the
    /// host sums the grains in f64 in slot order: the same bits every time on one adapter.
    /// Waits for the steps. Errors: no steps, or a slab bound that is not finite or a range
    /// whose low end is above its high end ([`GpuError::Invalid`]); a lost device.
    pub fn run_sampling_slab(&mut self, steps: u64, slab: &Slab) -> Result<[f64; 3], GpuError> {
        if steps == 0 {
            return Err(GpuError::Invalid(
                "sampling a slab takes at least one step".into(),
            ));
        }
        let frame = self.slab_frame(slab)?;
        self.run_steps(steps, Some(frame))?;
        if self.n == 0 {
            return Ok([0.0; 3]);
        }
        let shares: Vec<[f32; 4]> = self.read_prefix(&self.buffers.slab, self.n as u64 * 16)?;
        let mut sum = [0.0f64; 3];
        for share in &shares {
            for (s, &v) in sum.iter_mut().zip(share) {
                *s += v as f64;
            }
        }
        Ok(sum)
    }

    /// `slab` as the shader takes it: its low corner as a voxel and an offset, and its extent.
    /// A bound farther than the grid's span outside it is moved to that distance (no grain
    /// or branch midpoint lies there: the same sums).
    fn slab_frame(&self, slab: &Slab) -> Result<SlabFrame, GpuError> {
        let ranges = [slab.x, slab.y, slab.z];
        for (axis, r) in ["x", "y", "z"].iter().zip(&ranges) {
            if !(r[0].is_finite() && r[1].is_finite()) || r[0] > r[1] {
                return Err(GpuError::Invalid(format!(
                    "the slab's {axis} range [{}, {}] is not a finite range, low end first",
                    r[0], r[1]
                )));
            }
        }
        let g = &self.grid;
        let clamp = |a: usize, v: f64| {
            let span = g.dims[a] as f64 * g.voxel[a];
            v.clamp(g.min[a] - span, g.min[a] + 2.0 * span)
        };
        let lo = Vec3::from_fn(|a, _| clamp(a, ranges[a][0]));
        let hi = Vec3::from_fn(|a, _| clamp(a, ranges[a][1]));
        let (cell, off) = g.to_voxel_unwrapped(lo);
        Ok(SlabFrame {
            cell: [cell[0], cell[1], cell[2], 0],
            off: [off[0], off[1], off[2], 0.0],
            size: [
                (hi.x - lo.x) as f32,
                (hi.y - lo.y) as f32,
                (hi.z - lo.z) as f32,
                0.0,
            ],
        })
    }

    /// [`GpuWorld::run`]; given a slab, the last step's force evaluation writes its shares.
    fn run_steps(&mut self, steps: u64, slab: Option<SlabFrame>) -> Result<(), GpuError> {
        let mut left = steps;
        while left > 0 {
            let encoding = Instant::now();
            let drained = self
                .drained
                .swap(false, std::sync::atomic::Ordering::Relaxed);
            let chunk = left.min(if drained {
                STEPS_AFTER_READ_BACK
            } else {
                STEPS_PER_SUBMIT
            });
            // The CPU engine records a step's loads when its count after the step is a
            // multiple of the interval (and never the Verlet start-up's).
            let records: Vec<bool> = (1..=chunk)
                .map(|k| !self.movers.is_empty() && (self.steps + k) % self.record_interval == 0)
                .collect();
            let recorded = records.iter().filter(|&&r| r).count();
            if self.pending.len() + recorded > SERIES_RECORDS {
                self.read_loads()?;
            }
            let startup = self.integrator == Integrator::VelocityVerlet && !self.forces_current;
            let sample = if left == chunk { slab.as_ref() } else { None };
            self.write_frames(&records, startup, sample);
            self.submit(&records, startup);
            if let Some(profiler) = &self.profiler {
                let encoding = encoding.elapsed();
                lock(profiler).end(&self.device, &self.queue, chunk, encoding)?;
            }
            for _ in 0..chunk {
                self.time += self.time_step;
            }
            self.steps += chunk;
            left -= chunk;
        }
        Ok(())
    }

    /// Encodes and submits the steps of one submission (`records`: whether each records its
    /// loads), after a Verlet start-up's force evaluation where `startup` asks for one.
    fn submit(&mut self, records: &[bool], startup: bool) {
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("steps"),
            });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("steps"),
                timestamp_writes: None,
            });
            if let Some(profiler) = &self.profiler {
                lock(profiler).begin(&mut pass);
            }
            pass.set_bind_group(0, &self.bindings.main, &[]);
            let mut evaluation = 0;
            if startup {
                pass.set_bind_group(1, &self.bindings.start_params, &[]);
                self.set_frames(&mut pass, &mut evaluation);
                self.rebuild_phase(&mut pass);
                self.dispatch(&mut pass, &self.pipelines.forces, self.n, "forces");
            }
            self.forces_current = true;
            pass.set_bind_group(1, &self.bindings.step_params, &[]);
            for &record in records {
                self.encode_step(&mut pass, &mut evaluation, record);
            }
        }
        self.queue.submit([encoder.finish()]);
    }

    /// Replaces moving geometry `geometry`'s motion (its index in the world the GPU world was
    /// built from) from the present time on, as the CPU engine's `World::set_geometry_motion`:
    /// the host evaluates the new motion for the following force evaluations, and a velocity
    /// Verlet run evaluates the forces again with it before its next step. The mesh stays in
    /// its body frame (its body grid is valid for any pose); the new motion should start at the
    /// pose the geometry has now (e.g. `Motion::translating(pose, velocity, time)`), or the
    /// geometry jumps. Errors: a geometry that is not one of the world's
    /// ([`GpuError::Invalid`]) or is baked into the voxels, neither moving nor listed as
    /// movable at creation ([`GpuWorld::with_movers`]; [`GpuError::Unsupported`]).
    pub fn set_motion(&mut self, geometry: usize, motion: Motion) -> Result<(), GpuError> {
        if geometry >= self.geometries {
            return Err(GpuError::Invalid(format!(
                "geometry {geometry}: the world has {} geometries",
                self.geometries
            )));
        }
        let Some(mover) = self.movers.iter_mut().find(|m| m.geometry == geometry) else {
            return Err(GpuError::Unsupported(format!(
                "a new motion for geometry {geometry}, which was still and not listed as \
                 movable when the GPU world was built"
            )));
        };
        mover.motion = motion;
        self.forces_current = false;
        Ok(())
    }

    /// Writes the moving geometries' frames for the force evaluations of the next steps
    /// (`records`: whether each step records its loads), in the order they run: a Verlet
    /// start-up's at the present time, then one per step, at the step's start (symplectic
    /// Euler) or end (velocity Verlet), the times the CPU engine evaluates its forces at; the
    /// last step's samples `slab`, if any. Notes the recorded evaluations' times as pending.
    fn write_frames(&mut self, records: &[bool], startup: bool, slab: Option<&SlabFrame>) {
        // Nothing moves and nothing is sampled: one blank block serves every evaluation (it
        // also clears a sampling flag an earlier submission left in the first block).
        self.frames_per_evaluation = !self.movers.is_empty() || slab.is_some();
        if !self.frames_per_evaluation {
            let blank = frames_at(&[], &self.grid, self.time, -1, None);
            self.queue
                .write_buffer(&self.buffers.frames, 0, bytemuck::bytes_of(&blank));
            return;
        }
        let mut frames = Vec::with_capacity(records.len() + 1);
        let mut t = self.time;
        if startup {
            frames.push(frames_at(&self.movers, &self.grid, t, -1, None));
        }
        for (k, &record) in records.iter().enumerate() {
            let sample = if k + 1 == records.len() { slab } else { None };
            let end = t + self.time_step;
            let at = match self.integrator {
                Integrator::SymplecticEuler => t,
                Integrator::VelocityVerlet => end,
            };
            let slot = if record {
                self.pending.push(at);
                self.pending.len() as i32 - 1
            } else {
                -1
            };
            frames.push(frames_at(&self.movers, &self.grid, at, slot, sample));
            t = end;
        }
        self.queue
            .write_buffer(&self.buffers.frames, 0, bytemuck::cast_slice(&frames));
    }

    /// Binds the frames of the next force evaluation.
    fn set_frames(&self, pass: &mut wgpu::ComputePass, evaluation: &mut u32) {
        let offset = if self.frames_per_evaluation {
            *evaluation * FRAME_BYTES as u32
        } else {
            0
        };
        pass.set_bind_group(2, &self.bindings.frames, &[offset]);
        *evaluation += 1;
    }

    /// Advances until the world's time reaches `time` (the CPU engine's `run_until`).
    pub fn run_until(&mut self, time: f64) -> Result<(), GpuError> {
        let mut t = self.time;
        let mut steps = 0;
        while t < time {
            t += self.time_step;
            steps += 1;
        }
        self.run(steps)
    }

    /// One step's kernels; `record`: sum the moving geometries' loads after its forces.
    fn encode_step(&self, pass: &mut wgpu::ComputePass, evaluation: &mut u32, record: bool) {
        let p = &self.pipelines;
        self.set_frames(pass, evaluation);
        if self.integrator == Integrator::VelocityVerlet {
            self.dispatch(pass, &p.kick_drift, self.n, "kick_drift");
        }
        self.rebuild_phase(pass);
        self.dispatch(pass, &p.forces, self.n, "forces");
        if record {
            let movers = self.movers.len() as u32;
            self.dispatch_groups(pass, &p.reduce_loads, movers, "reduce_loads");
        }
        match self.integrator {
            Integrator::SymplecticEuler => self.dispatch(pass, &p.euler, self.n, "euler"),
            Integrator::VelocityVerlet => self.dispatch(pass, &p.half_kick, self.n, "half_kick"),
        }
    }
}
