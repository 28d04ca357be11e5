//! The two dispatch paths of a force evaluation: the fused sequential sweep, and the parallel
//! contact pass + parallel gather pass. Both call the same kernel functions.

use super::kernel::*;
use super::lanes::PairPath;
use super::*;

impl World {
    pub(super) fn contact_context<'a>(
        &'a self,
        spring_dt: f64,
        placed: &'a [PlacedGeometry],
    ) -> ContactContext<'a> {
        ContactContext {
            dt: spring_dt,
            gravity: self.config.gravity,
            domain: self.config.domain,
            rolling_model: self.config.rolling_model,
            materials: &self.materials,
            any_jkr: self.materials.any_jkr(),
            pair_path: PairPath::for_world(self.kernel, &self.materials, self.config.rolling_model),
            geometries: &self.geometries,
            placed,
            walls: &self.walls,
        }
    }

    pub(super) fn gather_context(&self, after: AfterForces) -> GatherContext {
        GatherContext {
            dt: self.config.time_step,
            domain: self.config.domain,
            cdt: matches!(
                self.config.rolling_model,
                RollingModel::ConstantDirectionalTorque
            ),
            after,
        }
    }

    /// The contact and gather passes in one sequential sweep: particle i computes its own
    /// pairs, then immediately gathers its shares (all written earlier in this sweep, by lower
    /// indices, so still in cache) and integrates. Integrating i early is safe: only lower
    /// indices (already done) read its state. Returns the per-chunk geometry loads (summed per
    /// chunk exactly as the parallel contact pass does) and whether a rebuild is needed.
    pub(super) fn fused_pass(
        &mut self,
        spring_dt: f64,
        placed: &[PlacedGeometry],
        after: AfterForces,
    ) -> (Vec<Vec<(Vec3, Vec3)>>, bool) {
        let mut particles = std::mem::take(&mut self.particles);
        let mut pairs = std::mem::take(&mut self.pairs);
        let ctx = self.contact_context(spring_dt, placed);
        let gather = self.gather_context(after);
        let n = particles.len();
        let use_rolling_spring = !pairs.rolling.is_empty();
        let mut all_loads = Vec::with_capacity(n.div_ceil(CHUNK));
        let mut rebuild = false;
        let p = &mut particles;
        let pl = &mut pairs;
        let mut force = vec![Vec3::zeros(); CHUNK.min(n)];
        let mut torque = vec![Vec3::zeros(); CHUNK.min(n)];
        let mut moment = vec![0.0; CHUNK.min(n)];
        for chunk_start in (0..n).step_by(CHUNK) {
            let mut loads = vec![(Vec3::zeros(), Vec3::zeros()); ctx.geometries.len()];
            let chunk_end = (chunk_start + CHUNK).min(n);
            let size = chunk_end - chunk_start;
            let own = pl.first_pair[chunk_start] as usize..pl.first_pair[chunk_end] as usize;
            let reads = ParticleReads {
                position: &p.position,
                velocity: &p.velocity,
                angular_velocity: &p.angular_velocity,
                radius: &p.radius,
                mass: &p.mass,
                inverse_inertia: &p.inverse_inertia,
                material: &p.material,
            };
            let rolling: &mut [Vec3] = if use_rolling_spring {
                &mut pl.rolling[own.clone()]
            } else {
                &mut []
            };
            with_scratch(|scratch| {
                chunk_contacts(
                    &ctx,
                    &reads,
                    &pl.first_pair,
                    ChunkOut {
                        start: chunk_start,
                        partner: &mut pl.partner[own.clone()],
                        tangential: &mut pl.tangential[own.clone()],
                        rolling,
                        share: &mut pl.partner_share[own],
                        walls: &mut p.wall_history[chunk_start..chunk_end],
                        force: &mut force[..size],
                        torque: &mut torque[..size],
                        moment: &mut moment[..size],
                    },
                    scratch,
                    &mut loads,
                )
            });
            for i in chunk_start..chunk_end {
                let k = i - chunk_start;
                let incident = pl.incidence_start[i] as usize..pl.incidence_start[i + 1] as usize;
                let state = ParticleState {
                    force: &mut p.force[i],
                    torque: &mut p.torque[i],
                    position: &mut p.position[i],
                    velocity: &mut p.velocity[i],
                    angular_velocity: &mut p.angular_velocity[i],
                };
                rebuild |= gather_particle(
                    &gather,
                    force[k],
                    torque[k],
                    moment[k],
                    &pl.incidence_pair[incident],
                    &pl.partner_share,
                    p.mass[i],
                    p.inverse_inertia[i],
                    p.build_mark[i],
                    state,
                );
            }
            all_loads.push(loads);
        }
        self.particles = particles;
        self.pairs = pairs;
        (all_loads, rebuild)
    }

    /// Every particle computes its own pairs (i < j) and its geometry contacts. Returns, per
    /// chunk, the (force, torque) each geometry received from that chunk's particles.
    pub(super) fn contact_pass(
        &mut self,
        spring_dt: f64,
        placed: &[PlacedGeometry],
    ) -> Vec<Vec<(Vec3, Vec3)>> {
        let mut particles = std::mem::take(&mut self.particles);
        let mut pairs = std::mem::take(&mut self.pairs);
        let mut rolling_moment = std::mem::take(&mut self.rolling_moment);
        let ctx = self.contact_context(spring_dt, placed);
        let n = particles.len();
        let p = &mut particles;
        let first_pair = &pairs.first_pair;
        let use_rolling_spring = !pairs.rolling.is_empty();

        // Split the per-pair and per-particle output arrays into per-chunk slices.
        struct Task<'a> {
            start: usize,
            tangential: &'a mut [Vec3],
            rolling: &'a mut [Vec3],
            share: &'a mut [PartnerShare],
            partner: &'a mut [u32],
            force: &'a mut [Vec3],
            torque: &'a mut [Vec3],
            moment: &'a mut [f64],
            walls: &'a mut [Vec<WallHistory>],
        }
        let mut tasks = Vec::with_capacity(n.div_ceil(CHUNK));
        {
            let mut tangential: &mut [Vec3] = &mut pairs.tangential;
            let mut rolling: &mut [Vec3] = &mut pairs.rolling;
            let mut share: &mut [PartnerShare] = &mut pairs.partner_share;
            let mut partner: &mut [u32] = &mut pairs.partner;
            let mut force: &mut [Vec3] = &mut p.force;
            let mut torque: &mut [Vec3] = &mut p.torque;
            let mut moment: &mut [f64] = &mut rolling_moment;
            let mut walls: &mut [Vec<WallHistory>] = &mut p.wall_history;
            let mut start = 0;
            while start < n {
                let end = (start + CHUNK).min(n);
                let pair_count = (first_pair[end] - first_pair[start]) as usize;
                let (a, rest) = std::mem::take(&mut tangential).split_at_mut(pair_count);
                tangential = rest;
                let (b, rest) = std::mem::take(&mut rolling).split_at_mut(if use_rolling_spring {
                    pair_count
                } else {
                    0
                });
                rolling = rest;
                let (c, rest) = std::mem::take(&mut share).split_at_mut(pair_count);
                share = rest;
                let (h, rest) = std::mem::take(&mut partner).split_at_mut(pair_count);
                partner = rest;
                let (d, rest) = std::mem::take(&mut force).split_at_mut(end - start);
                force = rest;
                let (e, rest) = std::mem::take(&mut torque).split_at_mut(end - start);
                torque = rest;
                let (f, rest) = std::mem::take(&mut moment).split_at_mut(end - start);
                moment = rest;
                let (g, rest) = std::mem::take(&mut walls).split_at_mut(end - start);
                walls = rest;
                tasks.push(Task {
                    start,
                    tangential: a,
                    rolling: b,
                    share: c,
                    partner: h,
                    force: d,
                    torque: e,
                    moment: f,
                    walls: g,
                });
                start = end;
            }
        }

        let reads = ParticleReads {
            position: &p.position,
            velocity: &p.velocity,
            angular_velocity: &p.angular_velocity,
            radius: &p.radius,
            mass: &p.mass,
            inverse_inertia: &p.inverse_inertia,
            material: &p.material,
        };

        // One chunk per rayon job, here and in every per-chunk pass: chunks do not cost the
        // same (a floor, a funnel wall, a dense or a dilute region), and rayon's adaptive split
        // otherwise hands each thread a few large pieces, so one thread waited for the other
        // at the end of each pass (20 000 grains on 2 threads: 10.7-13.0 -> 13.6-14.5 M
        // particle-steps/s, BENCHMARKS.md). Which thread runs a chunk never changes a result.
        let loads = tasks
            .into_par_iter()
            .with_max_len(1)
            .map(|task| {
                let mut loads = vec![(Vec3::zeros(), Vec3::zeros()); ctx.geometries.len()];
                with_scratch(|scratch| {
                    chunk_contacts(
                        &ctx,
                        &reads,
                        first_pair,
                        ChunkOut {
                            start: task.start,
                            partner: task.partner,
                            tangential: task.tangential,
                            rolling: task.rolling,
                            share: task.share,
                            walls: task.walls,
                            force: task.force,
                            torque: task.torque,
                            moment: task.moment,
                        },
                        scratch,
                        &mut loads,
                    )
                });
                loads
            })
            .collect();
        self.particles = particles;
        self.pairs = pairs;
        self.rolling_moment = rolling_moment;
        loads
    }

    /// Each particle adds the shares of the pairs it is the higher index of, applies CDT
    /// rolling friction, then integrates. Returns whether a rebuild is needed.
    pub(super) fn gather_pass(&mut self, after: AfterForces) -> bool {
        let gather = self.gather_context(after);
        let pairs = &self.pairs;
        let moment = &self.rolling_moment;
        let p = &mut self.particles;
        let mass = &p.mass;
        let inverse_inertia = &p.inverse_inertia;
        let build_mark = &p.build_mark;
        let flags: Vec<bool> = p
            .force
            .par_chunks_mut(CHUNK)
            .zip(p.torque.par_chunks_mut(CHUNK))
            .zip(p.position.par_chunks_mut(CHUNK))
            .zip(p.velocity.par_chunks_mut(CHUNK))
            .zip(p.angular_velocity.par_chunks_mut(CHUNK))
            .enumerate()
            .with_max_len(1)
            .map(|(c, ((((f, tq), x), v), w))| {
                let base = c * CHUNK;
                let mut rebuild = false;
                for k in 0..f.len() {
                    let i = base + k;
                    let range =
                        pairs.incidence_start[i] as usize..pairs.incidence_start[i + 1] as usize;
                    let (force, torque) = (f[k], tq[k]);
                    let state = ParticleState {
                        force: &mut f[k],
                        torque: &mut tq[k],
                        position: &mut x[k],
                        velocity: &mut v[k],
                        angular_velocity: &mut w[k],
                    };
                    rebuild |= gather_particle(
                        &gather,
                        force,
                        torque,
                        moment[i],
                        &pairs.incidence_pair[range],
                        &pairs.partner_share,
                        mass[i],
                        inverse_inertia[i],
                        build_mark[i],
                        state,
                    );
                }
                rebuild
            })
            .collect();
        flags.iter().any(|&f| f)
    }
}

/// Below this many chunks the step runs sequentially even with several threads (the
/// per-step scheduling overhead would exceed the work; results are identical either way).
pub(super) const SEQUENTIAL_BELOW: usize = 4;
