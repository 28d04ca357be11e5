//! Grains inserted between runs of steps into free slots: removed grains' first, then unused
//! ones (the CPU engine's insertion, without its sources: the caller serves them).

use repose_engine::math::Vec3;
use repose_engine::particles::ParticleSpec;

use super::buffers::ctl;
use super::{lock, GpuWorld};
use crate::scene::{particle_record, Record};
use crate::GpuError;

impl GpuWorld {
    /// Inserts `specs` into free slots (removed grains' slots first, lowest first, then unused
    /// ones in order) before the next step; returns their slots, in `specs`' order. Mass and
    /// inertia are the CPU engine's (a solid sphere of the material's density); the grains start
    /// without contact history and the next step rebuilds the neighbour lists (with velocity
    /// Verlet it first evaluates the forces, as the CPU engine does after an insertion). Reads
    /// back the control words, and the particle records when grains were removed, unless
    /// [`GpuWorld::positions`] or [`GpuWorld::particles`] read them at this step.
    ///
    /// Errors: a spec with an unknown material, a radius not in (0, the capacity's largest], a
    /// centre outside the domain ([`GpuError::Particle`]); more grains than free slots
    /// ([`GpuError::Capacity`]). Nothing is inserted on error.
    pub fn insert(&mut self, specs: &[ParticleSpec]) -> Result<Vec<usize>, GpuError> {
        let records = specs
            .iter()
            .enumerate()
            .map(|(k, spec)| self.record_of(k, spec))
            .collect::<Result<Vec<Record>, GpuError>>()?;
        if records.is_empty() {
            return Ok(Vec::new());
        }
        // Slots of removed grains not refilled yet, lowest first, then the unused ones.
        let removed = self.counters()?.removed;
        let mut slots = Vec::with_capacity(records.len());
        if removed > self.refilled {
            slots.extend(self.empty_slots()?.into_iter().take(records.len()));
        }
        let reused = slots.len();
        slots.extend(self.n..(self.n + records.len() - reused).min(self.capacity));
        if slots.len() < records.len() {
            return Err(GpuError::Capacity(format!(
                "inserting {} particles: only {} of the {} particle slots (the capacity) are \
                 free",
                records.len(),
                slots.len(),
                self.capacity
            )));
        }
        self.write_records(&slots, &records);
        self.refilled += reused as u64;
        if let Some(seen) = lock(&self.seen).as_mut().filter(|s| s.steps == self.steps) {
            seen.empty.drain(..reused);
        }
        self.n = self.n.max(slots.iter().max().map_or(0, |&k| k + 1));
        self.radius.resize(self.n, 0.0);
        for (&k, spec) in slots.iter().zip(specs) {
            self.radius[k] = spec.radius;
        }
        self.write_control(ctl::REBUILD, 1);
        self.forces_current = false;
        Ok(slots)
    }

    /// Spec `k`'s record. Errors: an unknown material, a radius not in (0, the capacity's
    /// largest], a position, velocity or spin that is not finite, a centre outside the domain.
    fn record_of(&self, k: usize, spec: &ParticleSpec) -> Result<Record, GpuError> {
        let m = spec.material.0 as usize;
        let Some(&density) = self.densities.get(m) else {
            return Err(GpuError::Particle(format!(
                "particle {k}: material {m} is not one of the world's {}",
                self.densities.len()
            )));
        };
        if !(spec.radius > 0.0 && spec.radius <= self.max_radius) {
            return Err(GpuError::Particle(format!(
                "particle {k}: radius {} m is not in (0, {}] m (the capacity's largest)",
                spec.radius, self.max_radius
            )));
        }
        let finite = |v: Vec3| v.iter().all(|c| c.is_finite());
        if !(finite(spec.position) && finite(spec.velocity) && finite(spec.angular_velocity)) {
            return Err(GpuError::Particle(format!(
                "particle {k}: a position, velocity or spin that is not finite"
            )));
        }
        let record = particle_record(&self.grid, spec, density);
        let c = record.0;
        if (0..3).any(|a| c[a] < 0 || c[a] >= self.grid.dims[a]) {
            return Err(GpuError::Particle(format!(
                "particle {k}: centre {:?} is outside the domain",
                spec.position
            )));
        }
        Ok(record)
    }

    /// Writes `records` into their `slots`: one write per buffer and run of consecutive slots.
    /// Inserted since the build, they carry no history into the new lists.
    fn write_records(&self, slots: &[usize], records: &[Record]) {
        let mut start = 0;
        while start < slots.len() {
            let mut end = start + 1;
            while end < slots.len() && slots[end] == slots[end - 1] + 1 {
                end += 1;
            }
            let run = &records[start..end];
            let at = slots[start] as u64 * 16;
            let write = |buffer: &wgpu::Buffer, data: &[u8]| {
                self.queue.write_buffer(buffer, at, data);
            };
            let column = |f: fn(&Record) -> [u8; 16]| run.iter().flat_map(f).collect::<Vec<u8>>();
            write(&self.buffers.cell, &column(|r| bytemuck::cast(r.0)));
            write(&self.buffers.off, &column(|r| bytemuck::cast(r.1)));
            write(&self.buffers.vel, &column(|r| bytemuck::cast(r.2)));
            write(&self.buffers.omg, &column(|r| bytemuck::cast(r.3)));
            // Inserted since the build: no history carried into the new lists.
            let fresh: Vec<[f32; 4]> = vec![[0.0, 0.0, 0.0, 1.0]; run.len()];
            write(&self.buffers.disp, bytemuck::cast_slice(&fresh));
            start = end;
        }
    }
}
