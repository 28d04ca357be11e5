//! The step loop, neighbour rebuilds and geometry placement.

use super::passes::SEQUENTIAL_BELOW;
use super::walls::{displacement_bound, world_aabb};
use super::*;

impl World {
    /// Advance `n` steps.
    pub fn run(&mut self, n: u64) {
        for _ in 0..n {
            self.step();
        }
    }

    /// Advance until `time` (at least until the world time reaches it).
    pub fn run_until(&mut self, time: f64) {
        while self.time < time {
            self.step();
        }
    }

    /// Advance one time step.
    pub fn step(&mut self) {
        self.steps_since_spawn += 1;
        if self.needs_rebuild || self.steps_since_spawn >= self.config.insertion_interval {
            self.steps_since_spawn = 0;
            self.spawn_from_sources();
        }
        let t = self.time;
        let dt = self.config.time_step;
        if self.needs_rebuild {
            self.rebuild(t);
        }
        let record = (self.steps + 1) % self.config.geometry_record_interval == 0;
        match self.config.integrator {
            Integrator::SymplecticEuler => {
                self.evaluate_forces(t, AfterForces::EulerUpdate, record);
            }
            Integrator::VelocityVerlet => {
                if !self.forces_current {
                    self.evaluate_forces(t, AfterForces::Nothing, false);
                }
                self.kick_drift();
                if self.needs_rebuild {
                    self.rebuild(t + dt);
                }
                self.evaluate_forces(t + dt, AfterForces::HalfKick, record);
            }
        }
        self.time = t + dt;
        self.steps += 1;
    }

    /// Remove particles outside the domain, optionally re-sort, rebuild the pair list and the
    /// wall candidates (positions are those of time `t`).
    pub(super) fn rebuild(&mut self, t: f64) {
        let domain = self.config.domain;
        let p = &mut self.particles;
        // Positions move continuously between builds; they come back into the box here, and
        // the new pair list marks the pairs closest across a periodic face (`WRAPS`).
        if domain.periodic_x || domain.periodic_y {
            for x in &mut p.position {
                *x = domain.wrap(*x);
            }
        }
        let outside = p.position.iter().filter(|x| domain.is_outside(**x)).count();
        if outside > 0 {
            let keep: Vec<u32> = (0..p.len() as u32)
                .filter(|&k| !domain.is_outside(p.position[k as usize]))
                .collect();
            p.permute(&keep);
            self.removed += outside as u64;
        }
        let max_radius = p.radius.iter().copied().fold(0.0, f64::max);
        let half_skin = self.half_skins(max_radius);
        self.skin = 2.0 * half_skin.iter().copied().fold(0.0f32, f32::max) as f64;
        let p = &mut self.particles;
        let cell_size = 2.0 * max_radius + self.skin;
        let sort_every = self.config.sort_every_rebuilds as u64;
        let (half_skin, sort_grid) = if sort_every > 0 && self.rebuilds % sort_every == 0 {
            let mut grid = CellGrid::build(&domain, cell_size, &p.position, SORT_CELLS);
            p.permute(&grid.sorted);
            let order = std::mem::replace(&mut grid.sorted, (0..p.len() as u32).collect());
            let half_skin = order.iter().map(|&k| half_skin[k as usize]).collect();
            // Cells the sort budget did not widen are the search's cells too: in the new
            // order, each cell's particles are the grid's, in order.
            (half_skin, (!grid.widened).then_some(grid))
        } else {
            (half_skin, None)
        };
        let grid = sort_grid
            .unwrap_or_else(|| CellGrid::build(&domain, cell_size, &p.position, SEARCH_CELLS));
        let with_rolling = matches!(
            self.config.rolling_model,
            RollingModel::ElasticPlasticSpringDashpot { .. }
        );
        self.pairs = build_pair_list(p, &domain, &grid, &half_skin, with_rolling, &self.pairs);
        for (k, index) in p.index_at_build.iter_mut().enumerate() {
            *index = k as u32;
        }
        p.build_mark = p
            .position
            .iter()
            .zip(&half_skin)
            .map(|(&x, &half_skin)| BuildMark {
                position: single(x),
                half_skin,
            })
            .collect();
        self.rolling_moment.resize(p.len(), 0.0);
        self.build_wall_candidates(t);
        self.rebuilds += 1;
        self.needs_rebuild = false;
    }

    /// Each particle's half skin for the next pair list (see [`BuildMark`]): wide enough that
    /// it needs about `rebuild_target_steps` steps at its present speed to cross it, within
    /// half the configured fractions of the largest diameter. Per particle, so the same for
    /// any thread count.
    fn half_skins(&self, max_radius: f64) -> Vec<f32> {
        let c = &self.config;
        let (lo, hi) = (
            c.skin_fraction * max_radius,
            c.skin_fraction_max * max_radius,
        );
        let v = &self.particles.velocity;
        if c.rebuild_target_steps == 0 || hi <= lo {
            return vec![lo as f32; v.len()];
        }
        let reach = c.time_step * c.rebuild_target_steps as f64;
        v.iter()
            .map(|v| (v.norm() * reach).clamp(lo, hi) as f32)
            .collect()
    }

    pub(super) fn place_geometries(&self, t: f64) -> Vec<PlacedGeometry> {
        let walls = &self.walls;
        let have_candidates = walls.build_pose.len() == self.geometries.len()
            && walls.first.len() == self.particles.len() + 1;
        self.geometries
            .iter()
            .enumerate()
            .map(|(g, geometry)| {
                let pose = geometry.motion.pose_at(t);
                let (aabb_min, aabb_max) = world_aabb(&geometry.mesh, &pose);
                // Particles move at most their own half skin between rebuilds; the candidates
                // hold every triangle within radius + half skin + the geometry's allowance, so
                // they stay complete while the geometry has moved at most its allowance.
                let cached = have_candidates
                    && displacement_bound(
                        &walls.build_pose[g],
                        &pose,
                        geometry.mesh.max_vertex_distance(),
                    ) <= walls.allowance[g];
                PlacedGeometry {
                    inverse: pose.inverse(),
                    pose,
                    aabb_min,
                    aabb_max,
                    linear_velocity: geometry.motion.linear_velocity_at(t),
                    angular_velocity: geometry.motion.angular_velocity_at(t),
                    reference_point: geometry.motion.reference_point_at(t),
                    cached,
                }
            })
            .collect()
    }

    /// Velocity Verlet: v += a Δt/2, ω += α Δt/2, x += v Δt.
    pub(super) fn kick_drift(&mut self) {
        let dt = self.config.time_step;
        let domain = self.config.domain;
        let p = &mut self.particles;
        let flags: Vec<bool> = p
            .position
            .par_chunks_mut(CHUNK)
            .zip(p.velocity.par_chunks_mut(CHUNK))
            .zip(p.angular_velocity.par_chunks_mut(CHUNK))
            .enumerate()
            .with_max_len(1)
            .map(|(c, ((x, v), w))| {
                let base = c * CHUNK;
                let mut rebuild = false;
                for k in 0..x.len() {
                    let i = base + k;
                    v[k] += p.force[i] * (0.5 * dt / p.mass[i]);
                    w[k] += p.torque[i] * (0.5 * dt * p.inverse_inertia[i]);
                    x[k] += v[k] * dt;
                    rebuild |= p.build_mark[i].moved_too_far(x[k]) || domain.is_outside(x[k]);
                }
                rebuild
            })
            .collect();
        if flags.iter().any(|&f| f) {
            self.needs_rebuild = true;
        }
    }

    /// Contact pass + gather pass (+ integration), recording geometry loads if `record`.
    pub(super) fn evaluate_forces(&mut self, t: f64, after: AfterForces, record: bool) {
        let placed = self.place_geometries(t);
        // The Verlet start-up evaluation only wants forces: it must not advance the contact
        // springs (they are advanced once per step, by the evaluation that ends the step).
        let spring_dt = match after {
            AfterForces::Nothing => 0.0,
            _ => self.config.time_step,
        };
        // One thread (or a scene of a few chunks): a single fused sweep. Its arithmetic per
        // particle is exactly that of the two parallel passes, so the results do not change.
        let n = self.particles.len();
        let (wall_loads, rebuild) =
            if rayon::current_num_threads() == 1 || n <= SEQUENTIAL_BELOW * CHUNK {
                self.fused_pass(spring_dt, &placed, after)
            } else {
                let wall_loads = self.contact_pass(spring_dt, &placed);
                (wall_loads, self.gather_pass(after))
            };
        if rebuild {
            self.needs_rebuild = true;
        }
        self.forces_current = true;
        if record {
            for (g, series) in self.series.iter_mut().enumerate() {
                let (force, torque) = wall_loads
                    .iter()
                    .fold((Vec3::zeros(), Vec3::zeros()), |(f, m), chunk| {
                        (f + chunk[g].0, m + chunk[g].1)
                    });
                series.push(GeometrySample {
                    time: t,
                    force,
                    torque,
                });
            }
        }
    }
}
