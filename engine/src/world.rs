//! The simulation world: particles, geometries, the step loop.
//!
//! One step (symplectic Euler) is: [rebuild the pair list if needed] → contact pass → gather +
//! integrate pass. Velocity Verlet adds a half-kick + drift pass before the force evaluation.
//!
//! Determinism: every parallel loop works on fixed chunks of [`CHUNK`] particles and every
//! floating-point sum runs in an order fixed by the data (pair order, incidence order, chunk
//! order), never by thread scheduling, so results are bit-identical for any thread count.
//! The contact pass runs over particles, each computing the pairs it owns (i < j) and the
//! contacts with geometries; the pair's share for j is stored with the pair and gathered by j
//! in the gather pass via a CSR incidence list. No atomics, no locks.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::contact::{epsd_rolling_stiffness, epsd_rolling_torque, hertz_mindlin, RollingModel};
use crate::factory::{NewParticle, ParticleSource, SpawnReport};
use crate::integrate::Integrator;
use crate::kinematics::Motion;
use crate::material::{
    check_time_step, rayleigh_time, MaterialError, MaterialId, MaterialTable, TimeStepWarning,
};
use crate::math::{Pose, Vec3};
use crate::mesh::{MeshContact, TriMesh};
use crate::neighbor::{
    build_pair_list, CellGrid, Domain, PairList, PartnerShare, CHUNK, IN_CONTACT, PARTNER_INDEX,
};
use crate::particles::{double, single, ParticleSpec, Particles, WallHistory};

/// Simulation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorldConfig {
    /// Time step Δt, s. See [`MaterialTable::rayleigh_time_step`] for EDEM's rule.
    pub time_step: f64,
    /// Gravitational acceleration, m/s².
    pub gravity: Vec3,
    pub domain: Domain,
    pub integrator: Integrator,
    pub rolling_model: RollingModel,
    /// Verlet skin as a fraction of the largest particle diameter. Larger: fewer rebuilds,
    /// more pairs to test (and store) each step. 0.1-0.3 is typical; the default 0.15 keeps
    /// about 4.3 pairs per particle in a dense bed while a particle at 1 m/s with a Rayleigh
    /// step still travels ~5 steps per rebuild.
    pub skin_fraction: f64,
    /// Spatially re-sort the particle arrays (cell order) every this many pair-list rebuilds;
    /// 0 never sorts.
    pub sort_every_rebuilds: u32,
    /// Record geometry forces every this many steps (>= 1).
    pub geometry_record_interval: u64,
    /// Seed of the world's random number generator (used by particle factories).
    pub seed: u64,
}

impl WorldConfig {
    /// Defaults: standard gravity, symplectic Euler, CDT rolling friction, skin 0.15 d.
    pub fn new(time_step: f64, domain: Domain) -> WorldConfig {
        WorldConfig {
            time_step,
            gravity: Vec3::new(0.0, 0.0, -9.81),
            domain,
            integrator: Integrator::SymplecticEuler,
            rolling_model: RollingModel::ConstantDirectionalTorque,
            skin_fraction: 0.15,
            sort_every_rebuilds: 4,
            geometry_record_interval: 1,
            seed: 0,
        }
    }
}

/// Why a world could not be created or changed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WorldError {
    #[error(transparent)]
    Material(#[from] MaterialError),
    #[error("{field} must be {requirement} (got {value})")]
    InvalidSetting {
        field: &'static str,
        requirement: &'static str,
        value: f64,
    },
    #[error("unknown material id {0}")]
    UnknownMaterial(u16),
}

fn require(
    field: &'static str,
    value: f64,
    ok: bool,
    requirement: &'static str,
) -> Result<(), WorldError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(WorldError::InvalidSetting {
            field,
            requirement,
            value,
        })
    }
}

/// Index of a geometry in its world (order of [`World::add_geometry`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct GeometryId(pub u32);

/// A rigid, kinematically driven triangle mesh.
#[derive(Debug, Clone)]
pub struct Geometry {
    pub name: String,
    /// The mesh in its body frame.
    pub mesh: TriMesh,
    /// Prescribed motion (pose of the body frame over time).
    pub motion: Motion,
    pub material: MaterialId,
}

/// Resultant of all particle contact forces on a geometry at one time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeometrySample {
    /// Time of the force evaluation, s.
    pub time: f64,
    /// Force exerted by the particles on the geometry, N.
    pub force: Vec3,
    /// Torque of those forces about the geometry's reference point, N·m.
    pub torque: Vec3,
}

/// Per-step, per-geometry data computed once before the contact pass.
#[derive(Debug, Clone)]
struct PlacedGeometry {
    pose: Pose,
    inverse: Pose,
    aabb_min: Vec3,
    aabb_max: Vec3,
    angular_velocity: Vec3,
    reference_point: Vec3,
}

#[derive(Debug, Clone, Copy)]
enum AfterForces {
    /// Symplectic Euler: v += a Δt, then x += v Δt.
    EulerUpdate,
    /// Velocity Verlet's closing half kick.
    HalfKick,
    /// Only the forces are wanted (Verlet start-up).
    Nothing,
}

/// A DEM simulation. Cloning copies the complete state (a checkpoint).
#[derive(Debug, Clone)]
pub struct World {
    config: WorldConfig,
    materials: MaterialTable,
    particles: Particles,
    geometries: Vec<Geometry>,
    series: Vec<Vec<GeometrySample>>,
    sources: Vec<(ParticleSource, MaterialId)>,
    spawn_reports: Vec<SpawnReport>,
    spawned: Vec<NewParticle>,
    pairs: PairList,
    /// Scratch: CDT rolling moment sum per particle (own pairs + walls).
    rolling_moment: Vec<f64>,
    time: f64,
    steps: u64,
    next_id: u64,
    removed: u64,
    rebuilds: u64,
    needs_rebuild: bool,
    forces_current: bool,
    skin: f64,
    rng: ChaCha8Rng,
}

impl World {
    pub fn new(materials: MaterialTable, config: WorldConfig) -> Result<World, WorldError> {
        require("time_step", config.time_step, config.time_step > 0.0, "> 0")?;
        require(
            "skin_fraction",
            config.skin_fraction,
            config.skin_fraction > 0.0,
            "> 0",
        )?;
        for a in 0..3 {
            require(
                "domain.max",
                config.domain.max[a],
                config.domain.max[a] > config.domain.min[a],
                "> domain.min in every axis",
            )?;
        }
        if config.gravity.iter().any(|g| !g.is_finite()) {
            return Err(WorldError::InvalidSetting {
                field: "gravity",
                requirement: "finite",
                value: f64::NAN,
            });
        }
        if let RollingModel::ElasticPlasticSpringDashpot { viscous_damping } = config.rolling_model
        {
            require(
                "rolling_model.viscous_damping",
                viscous_damping,
                viscous_damping >= 0.0,
                ">= 0",
            )?;
        }
        let rng = ChaCha8Rng::seed_from_u64(config.seed);
        Ok(World {
            config: WorldConfig {
                geometry_record_interval: config.geometry_record_interval.max(1),
                ..config
            },
            materials,
            particles: Particles::default(),
            geometries: Vec::new(),
            series: Vec::new(),
            sources: Vec::new(),
            spawn_reports: Vec::new(),
            spawned: Vec::new(),
            pairs: PairList::default(),
            rolling_moment: Vec::new(),
            time: 0.0,
            steps: 0,
            next_id: 0,
            removed: 0,
            rebuilds: 0,
            needs_rebuild: true,
            forces_current: false,
            skin: 0.0,
            rng,
        })
    }

    pub fn config(&self) -> &WorldConfig {
        &self.config
    }

    pub fn materials(&self) -> &MaterialTable {
        &self.materials
    }

    /// Add a particle; returns its persistent id.
    pub fn add_particle(&mut self, spec: ParticleSpec) -> Result<u64, WorldError> {
        if spec.material.0 as usize >= self.materials.len() {
            return Err(WorldError::UnknownMaterial(spec.material.0));
        }
        require("radius", spec.radius, spec.radius > 0.0, "> 0")?;
        let density = self.materials.material(spec.material).density;
        let id = self.next_id;
        self.next_id += 1;
        self.particles.push(id, &spec, density);
        self.rolling_moment.push(0.0);
        self.needs_rebuild = true;
        self.forces_current = false;
        Ok(id)
    }

    /// Add a geometry; its force series starts empty.
    pub fn add_geometry(&mut self, geometry: Geometry) -> Result<GeometryId, WorldError> {
        if geometry.material.0 as usize >= self.materials.len() {
            return Err(WorldError::UnknownMaterial(geometry.material.0));
        }
        self.geometries.push(geometry);
        self.series.push(Vec::new());
        self.forces_current = false;
        Ok(GeometryId(self.geometries.len() as u32 - 1))
    }

    /// Add a particle source (factory or list) producing particles of `material`. Sources
    /// are asked for particles at the start of every step, in the order they were added.
    pub fn add_source(
        &mut self,
        source: ParticleSource,
        material: MaterialId,
    ) -> Result<usize, WorldError> {
        if material.0 as usize >= self.materials.len() {
            return Err(WorldError::UnknownMaterial(material.0));
        }
        self.sources.push((source, material));
        self.spawn_reports.push(SpawnReport::default());
        Ok(self.sources.len() - 1)
    }

    /// The sources, in the order added (to read their insertion state).
    pub fn sources(&self) -> impl Iterator<Item = &ParticleSource> {
        self.sources.iter().map(|(s, _)| s)
    }

    /// What each source did in the last step.
    pub fn last_spawn_reports(&self) -> &[SpawnReport] {
        &self.spawn_reports
    }

    /// True if a sphere at `centre` with `radius` overlaps no particle and no geometry at the
    /// current time. O(particles) unless `grid` is given.
    fn is_free(&self, centre: Vec3, radius: f64, grid: Option<&CellGrid>) -> bool {
        let p = &self.particles;
        let domain = &self.config.domain;
        let clear_of = |k: usize| {
            let reach = radius + p.radius[k];
            domain.minimum_image(p.position[k] - centre).norm_squared() >= reach * reach
        };
        let particles_clear = match grid {
            Some(grid) => {
                let mut clear = true;
                grid.for_each_near(centre, radius + self.max_radius(), |k| {
                    clear &= clear_of(k as usize);
                });
                clear
            }
            None => (0..p.len()).all(clear_of),
        };
        if !particles_clear {
            return false;
        }
        let mut contacts = Vec::new();
        self.geometries.iter().all(|g| {
            let pose = g.motion.pose_at(self.time);
            let body = pose.inverse_transform_point(&centre.into()).coords;
            contacts.clear();
            g.mesh.sphere_contacts(body, radius, &mut contacts);
            contacts.is_empty()
        })
    }

    fn max_radius(&self) -> f64 {
        self.particles.radius.iter().copied().fold(0.0, f64::max)
    }

    /// Ask every source, in order, for the particles due in this step and add them. Each
    /// source sees the particles added by the sources before it.
    fn spawn_from_sources(&mut self) {
        if self.sources.is_empty() {
            return;
        }
        let t = self.time;
        let dt = self.config.time_step;
        let mut sources = std::mem::take(&mut self.sources);
        let mut spawned = std::mem::take(&mut self.spawned);
        for (k, (source, material)) in sources.iter_mut().enumerate() {
            spawned.clear();
            let mut rng = self.rng.clone();
            // The overlap-test grid is built only if the source actually tries a spot.
            let grid: std::cell::OnceCell<CellGrid> = std::cell::OnceCell::new();
            let report = source.spawn(
                t,
                dt,
                &mut rng,
                |centre, radius| {
                    let grid = grid.get_or_init(|| {
                        let size = 2.0 * self.max_radius().max(radius);
                        CellGrid::build(&self.config.domain, size, &self.particles.position)
                    });
                    self.is_free(centre, radius, Some(grid))
                },
                &mut spawned,
            );
            self.rng = rng;
            self.spawn_reports[k] = report;
            for &(position, radius, velocity) in &spawned {
                let spec = ParticleSpec {
                    position,
                    velocity,
                    angular_velocity: Vec3::zeros(),
                    radius,
                    material: *material,
                };
                // Sources validate their radii, so this cannot fail for a valid source.
                let _ = self.add_particle(spec);
            }
        }
        self.sources = sources;
        self.spawned = spawned;
    }

    pub fn geometry(&self, id: GeometryId) -> &Geometry {
        &self.geometries[id.0 as usize]
    }

    /// Recorded force/torque samples of a geometry, oldest first.
    pub fn geometry_series(&self, id: GeometryId) -> &[GeometrySample] {
        &self.series[id.0 as usize]
    }

    /// Forget the recorded geometry series (e.g. after a settling phase).
    pub fn clear_geometry_series(&mut self) {
        self.series.iter_mut().for_each(Vec::clear);
    }

    pub fn particles(&self) -> &Particles {
        &self.particles
    }

    /// Mutable access to particle state (e.g. to set velocities). Changing positions by more
    /// than the skin requires [`World::invalidate_neighbours`].
    pub fn particles_mut(&mut self) -> &mut Particles {
        self.forces_current = false;
        &mut self.particles
    }

    /// Force a neighbour-list rebuild before the next force evaluation.
    pub fn invalidate_neighbours(&mut self) {
        self.needs_rebuild = true;
    }

    /// The world's random number generator (deterministic from `config.seed`).
    pub fn rng(&mut self) -> &mut ChaCha8Rng {
        &mut self.rng
    }

    pub fn time(&self) -> f64 {
        self.time
    }

    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Number of particles removed because they left the domain.
    pub fn removed_count(&self) -> u64 {
        self.removed
    }

    /// Number of neighbour-list builds so far.
    pub fn rebuild_count(&self) -> u64 {
        self.rebuilds
    }

    /// Number of pairs in the current neighbour list.
    pub fn pair_count(&self) -> usize {
        self.pairs.pair_count()
    }

    /// Number of particle-particle pairs currently in contact (overlapping).
    pub fn contact_count(&self) -> usize {
        let p = &self.particles;
        let d = &self.config.domain;
        (0..p.len())
            .map(|i| {
                let range =
                    self.pairs.first_pair[i] as usize..self.pairs.first_pair[i + 1] as usize;
                self.pairs.partner[range]
                    .iter()
                    .filter(|&&j| {
                        let j = (j & PARTNER_INDEX) as usize;
                        let dist = d.minimum_image(p.position[i] - p.position[j]).norm();
                        dist < p.radius[i] + p.radius[j]
                    })
                    .count()
            })
            .sum()
    }

    /// Bytes of particle arrays, pair list and histories (lengths, not capacities).
    pub fn memory_bytes(&self) -> usize {
        self.particles.memory_bytes() + self.pairs.memory_bytes() + self.rolling_moment.len() * 8
    }

    /// Time-step warnings for the smallest particle present, given the fastest expected impact
    /// speed (m/s). Returns `None` if the step resolves that impact (or there are no particles).
    pub fn time_step_warning(&self, max_impact_speed: f64) -> Option<TimeStepWarning> {
        let k = (0..self.particles.len())
            .min_by(|&a, &b| self.particles.radius[a].total_cmp(&self.particles.radius[b]))?;
        let material = self.materials.material(self.particles.material[k]);
        check_time_step(
            self.config.time_step,
            self.particles.radius[k],
            material,
            max_impact_speed,
        )
    }

    /// A 64-bit hash of the exact bits of every particle's id, position, velocity and angular
    /// velocity (FNV-1a): equal hashes mean bit-identical states.
    pub fn state_hash(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |x: u64| {
            for b in x.to_le_bytes() {
                h ^= b as u64;
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        let p = &self.particles;
        for k in 0..p.len() {
            eat(p.id[k]);
            for v in [p.position[k], p.velocity[k], p.angular_velocity[k]] {
                for c in v.iter() {
                    eat(c.to_bits());
                }
            }
        }
        h
    }

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
    fn rebuild(&mut self) {
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

    fn place_geometries(&self, t: f64) -> Vec<PlacedGeometry> {
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
    fn kick_drift(&mut self) {
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
    fn evaluate_forces(&mut self, t: f64, after: AfterForces, record: bool) {
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

    fn contact_context<'a>(
        &'a self,
        t: f64,
        spring_dt: f64,
        placed: &'a [PlacedGeometry],
    ) -> ContactContext<'a> {
        ContactContext {
            t,
            dt: spring_dt,
            gravity: self.config.gravity,
            domain: self.config.domain,
            rolling_model: self.config.rolling_model,
            materials: &self.materials,
            geometries: &self.geometries,
            placed,
        }
    }

    fn gather_context(&self, after: AfterForces) -> GatherContext {
        GatherContext {
            dt: self.config.time_step,
            domain: self.config.domain,
            half_skin2: 0.25 * self.skin * self.skin,
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
    fn fused_pass(
        &mut self,
        t: f64,
        spring_dt: f64,
        placed: &[PlacedGeometry],
        after: AfterForces,
    ) -> (Vec<Vec<(Vec3, Vec3)>>, bool) {
        let mut particles = std::mem::take(&mut self.particles);
        let mut pairs = std::mem::take(&mut self.pairs);
        let ctx = self.contact_context(t, spring_dt, placed);
        let gather = self.gather_context(after);
        let n = particles.len();
        let use_rolling_spring = !pairs.rolling.is_empty();
        let mut scratch = Scratch::default();
        let mut all_loads = Vec::with_capacity(n.div_ceil(CHUNK));
        let mut rebuild = false;
        let p = &mut particles;
        let pl = &mut pairs;
        for chunk_start in (0..n).step_by(CHUNK) {
            let mut loads = vec![(Vec3::zeros(), Vec3::zeros()); ctx.geometries.len()];
            for i in chunk_start..(chunk_start + CHUNK).min(n) {
                let own = pl.first_pair[i] as usize..pl.first_pair[i + 1] as usize;
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
                let (f, tq, moment) = particle_contacts(
                    &ctx,
                    &reads,
                    i,
                    &mut pl.partner[own.clone()],
                    &mut pl.tangential[own.clone()],
                    rolling,
                    &mut pl.partner_share[own],
                    &mut p.wall_history[i],
                    &mut scratch,
                    &mut loads,
                );
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
                    f,
                    tq,
                    moment,
                    &pl.incidence_pair[incident],
                    &pl.partner,
                    &pl.partner_share,
                    p.mass[i],
                    p.inverse_inertia[i],
                    p.position_at_build[i],
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
    fn contact_pass(
        &mut self,
        t: f64,
        spring_dt: f64,
        placed: &[PlacedGeometry],
    ) -> Vec<Vec<(Vec3, Vec3)>> {
        let mut particles = std::mem::take(&mut self.particles);
        let mut pairs = std::mem::take(&mut self.pairs);
        let mut rolling_moment = std::mem::take(&mut self.rolling_moment);
        let ctx = self.contact_context(t, spring_dt, placed);
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

        let loads = tasks
            .into_par_iter()
            .map(|task| {
                let mut loads = vec![(Vec3::zeros(), Vec3::zeros()); ctx.geometries.len()];
                let pair_base = first_pair[task.start] as usize;
                let mut scratch = Scratch::default();
                for k in 0..task.force.len() {
                    let i = task.start + k;
                    let own =
                        first_pair[i] as usize - pair_base..first_pair[i + 1] as usize - pair_base;
                    let rolling: &mut [Vec3] = if use_rolling_spring {
                        &mut task.rolling[own.clone()]
                    } else {
                        &mut []
                    };
                    let (f, tq, moment) = particle_contacts(
                        &ctx,
                        &reads,
                        i,
                        &mut task.partner[own.clone()],
                        &mut task.tangential[own.clone()],
                        rolling,
                        &mut task.share[own],
                        &mut task.walls[k],
                        &mut scratch,
                        &mut loads,
                    );
                    task.force[k] = f;
                    task.torque[k] = tq;
                    task.moment[k] = moment;
                }
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
    fn gather_pass(&mut self, after: AfterForces) -> bool {
        let gather = self.gather_context(after);
        let pairs = &self.pairs;
        let moment = &self.rolling_moment;
        let p = &mut self.particles;
        let mass = &p.mass;
        let inverse_inertia = &p.inverse_inertia;
        let position_at_build = &p.position_at_build;
        let flags: Vec<bool> = p
            .force
            .par_chunks_mut(CHUNK)
            .zip(p.torque.par_chunks_mut(CHUNK))
            .zip(p.position.par_chunks_mut(CHUNK))
            .zip(p.velocity.par_chunks_mut(CHUNK))
            .zip(p.angular_velocity.par_chunks_mut(CHUNK))
            .enumerate()
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
                        &pairs.partner,
                        &pairs.partner_share,
                        mass[i],
                        inverse_inertia[i],
                        position_at_build[i],
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
const SEQUENTIAL_BELOW: usize = 4;

/// Step-constant inputs of the contact law.
struct ContactContext<'a> {
    t: f64,
    /// Spring time step (0 for the Verlet start-up evaluation).
    dt: f64,
    gravity: Vec3,
    domain: Domain,
    rolling_model: RollingModel,
    materials: &'a MaterialTable,
    geometries: &'a [Geometry],
    placed: &'a [PlacedGeometry],
}

/// The particle arrays the contact law reads.
struct ParticleReads<'a> {
    position: &'a [Vec3],
    velocity: &'a [Vec3],
    angular_velocity: &'a [Vec3],
    radius: &'a [f64],
    mass: &'a [f64],
    inverse_inertia: &'a [f64],
    material: &'a [MaterialId],
}

/// Reusable buffers of the geometry contacts.
#[derive(Default)]
struct Scratch {
    mesh_contacts: Vec<MeshContact>,
    new_walls: Vec<WallHistory>,
}

/// Step-constant inputs of the gather + integrate step.
struct GatherContext {
    dt: f64,
    domain: Domain,
    half_skin2: f64,
    cdt: bool,
    after: AfterForces,
}

/// The state one particle's gather + integrate step writes.
struct ParticleState<'a> {
    force: &'a mut Vec3,
    torque: &'a mut Vec3,
    position: &'a mut Vec3,
    velocity: &'a mut Vec3,
    angular_velocity: &'a mut Vec3,
}

/// Particle i's own pairs (`partner`, with their histories and partner shares) and its
/// geometry contacts. Returns i's force, torque and CDT rolling moment from these.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn particle_contacts(
    ctx: &ContactContext,
    r: &ParticleReads,
    i: usize,
    partner: &mut [u32],
    tangential: &mut [Vec3],
    rolling: &mut [Vec3],
    share: &mut [PartnerShare],
    walls: &mut Vec<WallHistory>,
    scratch: &mut Scratch,
    loads: &mut [(Vec3, Vec3)],
) -> (Vec3, Vec3, f64) {
    let dt = ctx.dt;
    let domain = &ctx.domain;
    let materials = ctx.materials;
    let rolling_model = ctx.rolling_model;
    let use_rolling_spring = !rolling.is_empty();
    let xi = r.position[i];
    let vi = r.velocity[i];
    let wi = r.angular_velocity[i];
    let ri = r.radius[i];
    let mi = r.mass[i];
    let mat_i = r.material[i];
    let mut f = ctx.gravity * mi;
    let mut tq = Vec3::zeros();
    let mut moment = 0.0;
    for (local, entry) in partner.iter_mut().enumerate() {
        let j = (*entry & PARTNER_INDEX) as usize;
        let rj = r.radius[j];
        let d = domain.minimum_image(xi - r.position[j]);
        let dist2 = d.norm_squared();
        let rsum = ri + rj;
        if dist2 >= rsum * rsum {
            // Not touching: histories are reset (only if set), the share is left stale.
            if *entry & IN_CONTACT != 0 {
                *entry &= PARTNER_INDEX;
                tangential[local] = Vec3::zeros();
                if use_rolling_spring {
                    rolling[local] = Vec3::zeros();
                }
            }
            continue;
        }
        *entry |= IN_CONTACT;
        let dist = dist2.sqrt();
        // One division, not nalgebra's three for `d / dist`.
        let normal = d * (1.0 / dist);
        let overlap = rsum - dist;
        // Contact point halfway through the overlap.
        let lever_i = ri - 0.5 * overlap;
        let lever_j = rj - 0.5 * overlap;
        let wj = r.angular_velocity[j];
        let relative_velocity = vi - r.velocity[j] - (wi * lever_i + wj * lever_j).cross(&normal);
        let mj = r.mass[j];
        let r_star = ri * rj / rsum;
        let m_star = mi * mj / (mi + mj);
        let constants = materials.pair(mat_i, r.material[j]);
        let contact = hertz_mindlin(
            constants,
            r_star,
            m_star,
            overlap,
            normal,
            relative_velocity,
            dt,
            &mut tangential[local],
        );
        let n_cross_f = normal.cross(&contact.force);
        f += contact.force;
        tq -= n_cross_f * lever_i;
        let mut torque_j = -n_cross_f * lever_j;
        let mut moment_j = 0.0;
        match rolling_model {
            RollingModel::ConstantDirectionalTorque => {
                let m = constants.rolling_friction * contact.normal_force;
                moment += m * lever_i;
                moment_j = m * lever_j;
            }
            RollingModel::ElasticPlasticSpringDashpot { viscous_damping } => {
                let kr = epsd_rolling_stiffness(
                    contact.normal_stiffness,
                    constants.rolling_friction,
                    r_star,
                );
                let inertia_i = 1.0 / r.inverse_inertia[i] + mi * ri * ri;
                let inertia_j = 1.0 / r.inverse_inertia[j] + mj * rj * rj;
                let inertia_r = inertia_i * inertia_j / (inertia_i + inertia_j);
                let mr = epsd_rolling_torque(
                    normal,
                    wi - wj,
                    kr,
                    constants.rolling_friction * r_star * contact.normal_force,
                    viscous_damping * 2.0 * (inertia_r * kr).sqrt(),
                    dt,
                    &mut rolling[local],
                );
                tq += mr;
                torque_j -= mr;
            }
        }
        share[local] = PartnerShare {
            force: -contact.force,
            torque: torque_j,
            rolling_moment: moment_j,
        };
    }

    // Geometry contacts, geometry by geometry, in mesh order.
    if ctx.geometries.is_empty() {
        return (f, tq, moment);
    }
    let Scratch {
        mesh_contacts,
        new_walls,
    } = scratch;
    new_walls.clear();
    for (g, (geometry, placement)) in ctx.geometries.iter().zip(ctx.placed).enumerate() {
        let reach = Vec3::repeat(ri);
        let (lo, hi) = (xi - reach, xi + reach);
        if (0..3).any(|a| lo[a] > placement.aabb_max[a] || hi[a] < placement.aabb_min[a]) {
            continue;
        }
        mesh_contacts.clear();
        let body_centre = placement.inverse.transform_point(&xi.into()).coords;
        geometry
            .mesh
            .sphere_contacts(body_centre, ri, mesh_contacts);
        for mc in mesh_contacts.iter() {
            let point = placement.pose.transform_point(&mc.point.into()).coords;
            let normal = placement.pose.rotation * mc.normal;
            // The previous contact with this geometry whose normal is closest.
            let previous = walls
                .iter()
                .filter(|h| h.geometry == g as u32)
                .map(|h| (h.normal.dot(&normal), h))
                .filter(|(dot, _)| *dot > 0.9)
                .max_by(|a, b| a.0.total_cmp(&b.0))
                .map(|(_, h)| *h);
            let mut history = previous.unwrap_or(WallHistory {
                geometry: g as u32,
                normal,
                tangential: Vec3::zeros(),
                rolling: Vec3::zeros(),
            });
            history.normal = normal;
            let arm = point - xi;
            let wall_velocity = geometry.motion.velocity_of_point(point, ctx.t);
            let relative_velocity = vi + wi.cross(&arm) - wall_velocity;
            let constants = materials.pair(mat_i, geometry.material);
            let contact = hertz_mindlin(
                constants,
                ri,
                mi,
                mc.overlap,
                normal,
                relative_velocity,
                dt,
                &mut history.tangential,
            );
            f += contact.force;
            tq += arm.cross(&contact.force);
            match rolling_model {
                RollingModel::ConstantDirectionalTorque => {
                    moment += constants.rolling_friction * contact.normal_force * arm.norm();
                }
                RollingModel::ElasticPlasticSpringDashpot { viscous_damping } => {
                    let kr = epsd_rolling_stiffness(
                        contact.normal_stiffness,
                        constants.rolling_friction,
                        ri,
                    );
                    let inertia_r = 1.0 / r.inverse_inertia[i] + mi * ri * ri;
                    tq += epsd_rolling_torque(
                        normal,
                        wi - placement.angular_velocity,
                        kr,
                        constants.rolling_friction * ri * contact.normal_force,
                        viscous_damping * 2.0 * (inertia_r * kr).sqrt(),
                        dt,
                        &mut history.rolling,
                    );
                }
            }
            let load = &mut loads[g];
            load.0 -= contact.force;
            load.1 += (point - placement.reference_point).cross(&-contact.force);
            new_walls.push(history);
        }
    }
    if !new_walls.is_empty() || !walls.is_empty() {
        walls.clear();
        walls.extend_from_slice(new_walls);
    }
    (f, tq, moment)
}

/// Particle i adds the shares of the pairs in contact it is the higher index of (`incident`,
/// flagged in `partner`) to its own
/// force, torque and CDT moment, applies CDT rolling friction, then integrates. Returns
/// whether it moved far enough (or out of the domain) to need a rebuild.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn gather_particle(
    g: &GatherContext,
    mut force: Vec3,
    mut torque: Vec3,
    mut rolling: f64,
    incident: &[u32],
    partner: &[u32],
    shares: &[PartnerShare],
    mass: f64,
    inv_i: f64,
    position_at_build: [f32; 3],
    s: ParticleState,
) -> bool {
    let dt = g.dt;
    let domain = &g.domain;
    for &pair in incident {
        if partner[pair as usize] & IN_CONTACT == 0 {
            continue;
        }
        let share = &shares[pair as usize];
        force += share.force;
        torque += share.torque;
        rolling += share.rolling_moment;
    }
    let w = s.angular_velocity;
    if g.cdt && rolling > 0.0 {
        // Constant directional torque against ω, limited so that on its own it can at most
        // stop the rotation within this step (no chatter).
        let speed = w.norm();
        if speed > 0.0 {
            let magnitude = rolling.min(speed / (inv_i * dt));
            torque -= *w * (magnitude / speed);
        }
    }
    *s.force = force;
    *s.torque = torque;
    let (x, v) = (s.position, s.velocity);
    match g.after {
        AfterForces::EulerUpdate => {
            *v += force * (dt / mass);
            *w += torque * (dt * inv_i);
            *x = domain.wrap(*x + *v * dt);
            let moved = domain.minimum_image(*x - double(position_at_build));
            moved.norm_squared() > g.half_skin2 || domain.is_outside(*x)
        }
        AfterForces::HalfKick => {
            *v += force * (0.5 * dt / mass);
            *w += torque * (0.5 * dt * inv_i);
            false
        }
        AfterForces::Nothing => false,
    }
}

impl MaterialTable {
    /// EDEM's time step rule: `fraction` × the Rayleigh time of a particle of `radius` made of
    /// `material` (use the smallest particle; the paper uses fraction = 0.2).
    pub fn rayleigh_time_step(&self, material: MaterialId, radius: f64, fraction: f64) -> f64 {
        fraction * rayleigh_time(radius, self.material(material))
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;
    use crate::kinematics::Motion;
    use crate::material::{Interaction, MaterialSet};

    /// A dense, frictional, falling cloud over a floor: 3000 particles (six chunks).
    fn cloud(rolling_model: RollingModel, integrator: Integrator) -> World {
        let interaction = Interaction {
            restitution: 0.4,
            static_friction: 0.5,
            rolling_friction: 0.1,
        };
        let materials = MaterialSet::paper(interaction, interaction)
            .build()
            .unwrap();
        let soil = materials.id("soil").unwrap();
        let steel = materials.id("steel").unwrap();
        let r = 1e-3;
        let side = 0.03;
        let domain = Domain {
            min: Vec3::new(0.0, 0.0, -0.01),
            max: Vec3::new(side, side, 0.2),
            periodic_x: true,
            periodic_y: true,
        };
        let dt = materials.rayleigh_time_step(soil, 0.9 * r, 0.2);
        let mut config = WorldConfig::new(dt, domain);
        config.rolling_model = rolling_model;
        config.integrator = integrator;
        let mut world = World::new(materials, config).unwrap();
        let floor = TriMesh::new(
            vec![
                Vec3::new(-0.01, -0.01, 0.0),
                Vec3::new(0.04, -0.01, 0.0),
                Vec3::new(0.04, 0.04, 0.0),
                Vec3::new(-0.01, 0.04, 0.0),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
        .unwrap();
        world
            .add_geometry(Geometry {
                name: "floor".into(),
                mesh: floor,
                motion: Motion::stationary(Pose::identity()),
                material: steel,
            })
            .unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let per = 14;
        let spacing = side / per as f64;
        for k in 0..3000 {
            let (x, y, z) = (k % per, (k / per) % per, k / (per * per));
            let jitter = Vec3::new(rng.gen(), rng.gen(), rng.gen()) * (0.1 * spacing);
            let position = Vec3::new(x as f64, y as f64, z as f64 * 0.9) * spacing
                + Vec3::new(0.5 * spacing, 0.5 * spacing, r)
                + jitter;
            let velocity = Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 0.2;
            world
                .add_particle(ParticleSpec {
                    position,
                    velocity,
                    angular_velocity: Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 50.0,
                    radius: r * rng.gen_range(0.9..1.1),
                    material: soil,
                })
                .unwrap();
        }
        world
    }

    /// Per-step cost of a tiny scene (44 particles over a floor): `cargo test --release -p
    /// repose-engine --lib small_scene_step_cost -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn small_scene_step_cost() {
        let mut world = cloud(
            RollingModel::ConstantDirectionalTorque,
            Integrator::SymplecticEuler,
        );
        let keep: Vec<u32> = (0..44).collect();
        world.particles.permute(&keep);
        world.rolling_moment.truncate(44);
        world.needs_rebuild = true;
        world.run(100);
        let start = std::time::Instant::now();
        let steps = 20_000;
        world.run(steps);
        let per_step = start.elapsed().as_secs_f64() / steps as f64;
        println!(
            "44 particles: {:.2} us per step (wall), {} rebuilds",
            per_step * 1e6,
            world.rebuild_count()
        );
    }

    /// The fused sequential sweep (one thread) and the parallel passes (two threads, more
    /// than `SEQUENTIAL_BELOW` chunks) must give bit-identical states and geometry loads.
    #[test]
    fn fused_and_parallel_passes_agree_bit_for_bit() {
        for (rolling, integrator) in [
            (
                RollingModel::ConstantDirectionalTorque,
                Integrator::SymplecticEuler,
            ),
            (RollingModel::epsd(), Integrator::VelocityVerlet),
        ] {
            let run = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                pool.install(|| {
                    let mut world = cloud(rolling, integrator);
                    world.run(300);
                    let floor = world.geometry_series(GeometryId(0)).to_vec();
                    (world.state_hash(), world.contact_count(), floor)
                })
            };
            let (one, contacts, floor_one) = run(1);
            let (two, _, floor_two) = run(2);
            assert!(contacts > 100, "{contacts} contacts");
            assert!(floor_one.iter().any(|s| s.force.z != 0.0));
            assert_eq!(one, two, "{rolling:?}");
            assert_eq!(floor_one, floor_two);
        }
    }
}
