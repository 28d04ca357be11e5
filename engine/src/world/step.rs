//! The step loop, neighbour rebuilds and geometry placement.

use super::passes::SEQUENTIAL_BELOW;
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
        self.spawn_from_sources();
        if self.needs_rebuild {
            self.rebuild();
        }
        let t = self.time;
        let dt = self.config.time_step;
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
                    self.rebuild();
                }
                self.evaluate_forces(t + dt, AfterForces::HalfKick, record);
            }
        }
        self.time = t + dt;
        self.steps += 1;
    }

    /// Remove particles outside the domain, optionally re-sort, rebuild the pair list.
    pub(super) fn rebuild(&mut self) {
        let domain = self.config.domain;
        let p = &mut self.particles;
        let outside = p.position.iter().filter(|x| domain.is_outside(**x)).count();
        if outside > 0 {
            let keep: Vec<u32> = (0..p.len() as u32)
                .filter(|&k| !domain.is_outside(p.position[k as usize]))
                .collect();
            p.permute(&keep);
            self.removed += outside as u64;
        }
        let max_radius = p.radius.iter().copied().fold(0.0, f64::max);
        self.skin = self.config.skin_fraction * 2.0 * max_radius;
        let cell_size = 2.0 * max_radius + self.skin;
        let mut grid = CellGrid::build(&domain, cell_size, &p.position);
        let sort_every = self.config.sort_every_rebuilds as u64;
        if sort_every > 0 && self.rebuilds % sort_every == 0 {
            p.permute(&grid.sorted);
            grid.sorted = (0..p.len() as u32).collect();
        }
        let with_rolling = matches!(
            self.config.rolling_model,
            RollingModel::ElasticPlasticSpringDashpot { .. }
        );
        self.pairs = build_pair_list(p, &domain, &grid, self.skin, with_rolling, &self.pairs);
        for (k, index) in p.index_at_build.iter_mut().enumerate() {
            *index = k as u32;
        }
        p.position_at_build = p.position.iter().map(|&x| single(x)).collect();
        self.rolling_moment.resize(p.len(), 0.0);
        self.rebuilds += 1;
        self.needs_rebuild = false;
    }

    pub(super) fn place_geometries(&self, t: f64) -> Vec<PlacedGeometry> {
        self.geometries
            .iter()
            .map(|g| {
                let pose = g.motion.pose_at(t);
                let (lo, hi) = g.mesh.aabb();
                let mut aabb_min = Vec3::repeat(f64::INFINITY);
                let mut aabb_max = Vec3::repeat(f64::NEG_INFINITY);
                for corner in 0..8 {
                    let c = Vec3::new(
                        if corner & 1 == 0 { lo.x } else { hi.x },
                        if corner & 2 == 0 { lo.y } else { hi.y },
                        if corner & 4 == 0 { lo.z } else { hi.z },
                    );
                    let w = pose.transform_point(&c.into()).coords;
                    aabb_min = aabb_min.inf(&w);
                    aabb_max = aabb_max.sup(&w);
                }
                PlacedGeometry {
                    inverse: pose.inverse(),
                    pose,
                    aabb_min,
                    aabb_max,
                    angular_velocity: g.motion.angular_velocity_at(t),
                    reference_point: g.motion.reference_point_at(t),
                }
            })
            .collect()
    }

    /// Velocity Verlet: v += a Δt/2, ω += α Δt/2, x += v Δt.
    pub(super) fn kick_drift(&mut self) {
        let dt = self.config.time_step;
        let domain = self.config.domain;
        let half_skin2 = 0.25 * self.skin * self.skin;
        let p = &mut self.particles;
        let flags: Vec<bool> = p
            .position
            .par_chunks_mut(CHUNK)
            .zip(p.velocity.par_chunks_mut(CHUNK))
            .zip(p.angular_velocity.par_chunks_mut(CHUNK))
            .enumerate()
            .map(|(c, ((x, v), w))| {
                let base = c * CHUNK;
                let mut rebuild = false;
                for k in 0..x.len() {
                    let i = base + k;
                    v[k] += p.force[i] * (0.5 * dt / p.mass[i]);
                    w[k] += p.torque[i] * (0.5 * dt * p.inverse_inertia[i]);
                    x[k] = domain.wrap(x[k] + v[k] * dt);
                    let moved = domain.minimum_image(x[k] - double(p.position_at_build[i]));
                    rebuild |= moved.norm_squared() > half_skin2 || domain.is_outside(x[k]);
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
                self.fused_pass(t, spring_dt, &placed, after)
            } else {
                let wall_loads = self.contact_pass(t, spring_dt, &placed);
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
