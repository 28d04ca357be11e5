//! The simulation world: particles, geometries, the step loop.
//!
//! The world's `impl` spans files by concern:
//! - `mod.rs`: the world's state, construction and read-only API;
//! - [`spawn`]: particle sources and the insertion overlap test;
//! - [`step`]: the step loop (spawn → rebuild → forces → integrate), neighbour rebuilds,
//!   geometry placement;
//! - [`passes`]: the two ways a force evaluation is dispatched: one fused sequential sweep, or
//!   a parallel contact pass followed by a parallel gather pass;
//! - [`kernel`]: the per-particle work both dispatch paths share: a particle's own pairs and
//!   geometry contacts (`particle_contacts`) and its gather + integration (`gather_particle`);
//! - [`lanes`]: the same pair law four contacts at a time across a chunk (the cohesionless
//!   CDT case), chosen per force evaluation by [`KernelChoice`], bit-identical to the scalar
//!   loop.
//!
//! One step (symplectic Euler) is: [rebuild the pair list if needed] → contact pass → gather +
//! integrate pass. Velocity Verlet adds a half-kick + drift pass before the force evaluation.
//!
//! Invariants (stated once here, relied on by every file of the module):
//! - **Fixed gather order.** Every floating-point sum runs in an order fixed by the data (pair
//!   order, incidence order, chunk order), never by thread scheduling. The contact pass runs
//!   over particles, each computing the pairs it owns (i < j) and its geometry contacts; the
//!   pair's share for j is stored with the pair and gathered by j, in ascending pair order, via
//!   a CSR incidence list. No atomics, no locks.
//! - **Determinism.** Every parallel loop works on fixed chunks of [`CHUNK`] particles, so
//!   results are bit-identical for any thread count, and the fused and parallel dispatch
//!   paths call the same kernel functions with the same arguments (tested).
//! - **Continuous positions between builds.** Integration never wraps a position across a
//!   periodic face; the rebuild does, and marks the pairs that are closest across a face
//!   (`WRAPS`). Between builds every other pair's separation is the plain difference, so the
//!   contact loop takes the minimum image only for the marked pairs (tested against the same
//!   collision in open space).
//! - **No I/O.** The engine reads and writes no files; callers hand it meshes and bytes.

mod kernel;
mod lanes;
mod passes;
mod spawn;
mod step;
mod walls;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::contact::RollingModel;
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
    SEARCH_CELLS, SORT_CELLS, WRAPS,
};
use crate::particles::{single, BuildMark, ParticleSpec, Particles, WallHistory};

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
    /// Upper bound of the adaptive skin, as a fraction of the largest particle diameter. At a
    /// rebuild each particle gets its own skin, chosen so that at its present speed it needs
    /// about `rebuild_target_steps` steps to cross half of it, within [`Self::skin_fraction`,
    /// `skin_fraction_max`]: a fast stream (a pour) then rebuilds every ~10 steps instead of
    /// every 2-3, while the slow bed it falls on keeps thin skins (fewer listed pairs). Equal
    /// to `skin_fraction` (or `rebuild_target_steps` 0): one fixed skin.
    #[serde(default = "default_skin_fraction_max")]
    pub skin_fraction_max: f64,
    /// See [`Self::skin_fraction_max`]; 0 disables the adaptive skin.
    #[serde(default = "default_rebuild_target_steps")]
    pub rebuild_target_steps: u32,
    /// Particle sources are served when the pair list is rebuilt anyway, and at least every
    /// this many steps (a source's particles then all enter together and force one rebuild).
    /// Inserting a grain means a rebuild; serving sources every step made a pour rebuild every
    /// 2-3 steps. Sources keep their own books, so the mass rate is unchanged; a grain enters
    /// at most this many steps after it was due. 1: every step.
    #[serde(default = "default_insertion_interval")]
    pub insertion_interval: u32,
    /// Spatially re-sort the particle arrays (cell order) every this many pair-list rebuilds;
    /// 0 never sorts.
    pub sort_every_rebuilds: u32,
    /// Record geometry forces every this many steps (>= 1).
    pub geometry_record_interval: u64,
    /// Seed of the world's random number generator (used by particle factories).
    pub seed: u64,
}

fn default_skin_fraction_max() -> f64 {
    0.5
}

fn default_rebuild_target_steps() -> u32 {
    12
}

fn default_insertion_interval() -> u32 {
    10
}

impl WorldConfig {
    /// Defaults: standard gravity, symplectic Euler, CDT rolling friction, skin 0.15 d growing
    /// up to 0.5 d for fast particles, sources served at least every 10 steps.
    pub fn new(time_step: f64, domain: Domain) -> WorldConfig {
        WorldConfig {
            time_step,
            gravity: Vec3::new(0.0, 0.0, -9.81),
            domain,
            integrator: Integrator::SymplecticEuler,
            rolling_model: RollingModel::ConstantDirectionalTorque,
            skin_fraction: 0.15,
            skin_fraction_max: default_skin_fraction_max(),
            rebuild_target_steps: default_rebuild_target_steps(),
            insertion_interval: default_insertion_interval(),
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
    /// The pair list keeps particle indices in 30 bits.
    #[error("a world holds at most {max} particles")]
    TooManyParticles { max: usize },
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

/// The most particles a world holds (the pair list's index bits).
pub const MAX_PARTICLES: usize = PARTNER_INDEX as usize;

/// Index of a geometry in its world (order of [`World::add_geometry`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct GeometryId(pub u32);

/// A rigid, kinematically driven triangle mesh.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
    /// The motion's velocities and reference point at this evaluation's time (once per step,
    /// not once per contact).
    linear_velocity: Vec3,
    angular_velocity: Vec3,
    reference_point: Vec3,
    /// The particles' candidate triangles of this geometry are complete (it has not moved
    /// far since the last rebuild); otherwise its contacts are found by the grid query.
    cached: bool,
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

/// A DEM simulation. Cloning copies the complete state, and so does serde: a world written with
/// any lossless serde format (one that keeps every f64's bits) and read back continues bit for
/// bit (tested), so a caller can checkpoint a long run to bytes.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
    /// Candidate triangles of each particle, built with the pair list.
    walls: walls::WallCandidates,
    /// Scratch: CDT rolling moment sum per particle (own pairs + walls).
    rolling_moment: Vec<f64>,
    time: f64,
    steps: u64,
    next_id: u64,
    removed: u64,
    rebuilds: u64,
    /// Steps since the sources were last served.
    steps_since_spawn: u32,
    needs_rebuild: bool,
    forces_current: bool,
    skin: f64,
    rng: ChaCha8Rng,
    kernel: KernelChoice,
}

/// One particle-particle contact as [`World::for_each_contact`] reports it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactForce {
    /// The pair's particles (indices into [`World::particles`]), `i < j`.
    pub i: usize,
    pub j: usize,
    /// The force particle i exerts on particle j (the contact law with its cohesion), N; j
    /// exerts the opposite on i.
    pub force_on_j: Vec3,
    /// From i's centre to j's (the minimum image across periodic faces), m.
    pub branch: Vec3,
}

/// Which code computes the particle-particle contacts. Both give bit-identical results
/// (tested); the choice exists to test and measure that.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum KernelChoice {
    /// The lane kernel where the law allows it (no cohesion, CDT rolling), the scalar loop
    /// otherwise.
    #[default]
    Auto,
    /// Always the per-pair scalar loop.
    Scalar,
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
        require(
            "skin_fraction_max",
            config.skin_fraction_max,
            config.skin_fraction_max >= config.skin_fraction,
            ">= skin_fraction",
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
                insertion_interval: config.insertion_interval.max(1),
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
            walls: walls::WallCandidates::default(),
            rolling_moment: Vec::new(),
            time: 0.0,
            steps: 0,
            next_id: 0,
            removed: 0,
            rebuilds: 0,
            steps_since_spawn: 0,
            needs_rebuild: true,
            forces_current: false,
            skin: 0.0,
            rng,
            kernel: KernelChoice::Auto,
        })
    }

    /// Choose the code that computes particle-particle contacts (results do not depend on it).
    pub fn set_kernel(&mut self, kernel: KernelChoice) {
        self.kernel = kernel;
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
        if self.particles.len() >= MAX_PARTICLES {
            return Err(WorldError::TooManyParticles { max: MAX_PARTICLES });
        }
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
        // The wall candidates cover the geometries present at the last rebuild.
        self.needs_rebuild = true;
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

    /// Removes the sources and returns them, in the order added, each with the material of its
    /// particles: for a caller that serves them itself (another engine backend driving a
    /// factory from the host, then [`World::add_source`] to hand them back).
    pub fn take_sources(&mut self) -> Vec<(ParticleSource, MaterialId)> {
        self.spawn_reports.clear();
        std::mem::take(&mut self.sources)
    }

    /// What each source did in the last step.
    pub fn last_spawn_reports(&self) -> &[SpawnReport] {
        &self.spawn_reports
    }

    pub fn geometry(&self, id: GeometryId) -> &Geometry {
        &self.geometries[id.0 as usize]
    }

    /// Every geometry, in the order they were added (index = [`GeometryId`]).
    pub fn geometries(&self) -> &[Geometry] {
        &self.geometries
    }

    /// Replaces the prescribed motion of geometry `id` from now on (servo control: a lid held
    /// at a normal force, a shear box moved at a set speed). The new motion should start at
    /// the pose the geometry has now (`geometry(id).motion.pose_at(time())`, e.g.
    /// [`Motion::translating`] from it), or the geometry jumps. The wall candidates stay valid
    /// (they are checked against the pose at every step) and the force series continues.
    pub fn set_geometry_motion(&mut self, id: GeometryId, motion: Motion) {
        self.geometries[id.0 as usize].motion = motion;
        // A Verlet step must evaluate the forces again with the new wall velocity.
        self.forces_current = false;
    }

    /// The last recorded load of geometry `id` (the resultant of the particle contact forces
    /// at the last recorded force evaluation), if one was recorded since the series was last
    /// cleared.
    pub fn last_geometry_sample(&self, id: GeometryId) -> Option<GeometrySample> {
        self.series[id.0 as usize].last().copied()
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

    /// Every particle-particle pair in contact at the last force evaluation, with the force
    /// it carried then (cohesion included), in pair-list order: the same sequence for any
    /// thread count. The branch vector is taken at the current positions (one step after the
    /// forces under symplectic Euler). Before the first step after particles were added or
    /// removed there is no pair list for them and nothing is visited.
    ///
    /// This is what a stress measurement inside a granular sample needs (the Love-Weber
    /// average `Σ f ⊗ l / V`, or the force across a plane), away from the walls whose loads
    /// [`World::geometry_series`] records.
    pub fn for_each_contact(&self, mut visit: impl FnMut(ContactForce)) {
        let p = &self.particles;
        let pl = &self.pairs;
        if pl.first_pair.len() != p.len() + 1 {
            return;
        }
        let d = &self.config.domain;
        for i in 0..p.len() {
            for k in pl.first_pair[i] as usize..pl.first_pair[i + 1] as usize {
                let entry = pl.partner[k];
                if entry & IN_CONTACT == 0 {
                    continue;
                }
                let j = (entry & PARTNER_INDEX) as usize;
                visit(ContactForce {
                    i,
                    j,
                    force_on_j: pl.partner_share[k].force,
                    branch: d.minimum_image(p.position[j] - p.position[i]),
                });
            }
        }
    }

    /// Bytes of particle arrays, pair list and histories (lengths, not capacities).
    pub fn memory_bytes(&self) -> usize {
        self.particles.memory_bytes()
            + self.pairs.memory_bytes()
            + self.walls.memory_bytes()
            + self.rolling_moment.len() * 8
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
    use crate::material::{Cohesion, Interaction, MaterialSet};

    /// `f` on a rayon pool of `threads` threads.
    fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(f)
    }

    /// The paper's soil and steel, every pair with μs 0.5, μr 0.1 and the given restitution.
    fn frictional_paper_table(restitution: f64) -> MaterialTable {
        let interaction = Interaction {
            restitution,
            static_friction: 0.5,
            rolling_friction: 0.1,
            cohesion: Cohesion::None,
        };
        MaterialSet::paper(interaction, interaction)
            .build()
            .unwrap()
    }

    /// A flat steel floor at z = 0 over [-0.01, hi]² (two triangles).
    fn add_floor(world: &mut World, steel: MaterialId, hi: f64) {
        let floor = TriMesh::new(
            vec![
                Vec3::new(-0.01, -0.01, 0.0),
                Vec3::new(hi, -0.01, 0.0),
                Vec3::new(hi, hi, 0.0),
                Vec3::new(-0.01, hi, 0.0),
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
    }

    /// A dense, frictional, falling cloud over a floor: 3000 particles (six chunks).
    fn cloud(rolling_model: RollingModel, integrator: Integrator) -> World {
        let materials = frictional_paper_table(0.4);
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
        add_floor(&mut world, steel, 0.04);
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

    /// Two grains collide (with a sliding component) across one periodic face while drifting
    /// fast through another: positions move on past the face between builds and are wrapped at the next build,
    /// and the pair is found through the minimum image only if it was marked at a build. The
    /// forces must be those of the same collision away from any face, step for step.
    #[test]
    fn a_collision_across_a_periodic_face_matches_one_in_open_space() {
        // `centre`: where the pair meets, `y0`: where it starts across the drift.
        let run = |centre: f64, y0: f64| {
            let materials = frictional_paper_table(0.5);
            let soil = materials.id("soil").unwrap();
            let (r, side) = (1e-3, 0.02);
            let domain = Domain {
                min: Vec3::new(0.0, 0.0, -0.01),
                max: Vec3::new(side, side, 0.01),
                periodic_x: true,
                periodic_y: true,
            };
            let dt = materials.rayleigh_time_step(soil, r, 0.2);
            let mut config = WorldConfig::new(dt, domain);
            config.gravity = Vec3::zeros();
            let mut world = World::new(materials, config).unwrap();
            // Approaching in x at 0.1 m/s from a 50 µm gap, sliding in z, drifting at 5 m/s
            // in y: the contact starts after 0.5 ms, 2.5 mm downstream.
            for side_of in [-1.0, 1.0] {
                let x = centre + side_of * (r + 25e-6);
                world
                    .add_particle(ParticleSpec {
                        position: Vec3::new(x.rem_euclid(side), y0, 0.0),
                        velocity: Vec3::new(-0.05 * side_of, 5.0, 0.02 * side_of),
                        angular_velocity: Vec3::zeros(),
                        radius: r,
                        material: soil,
                    })
                    .unwrap();
            }
            let steps = (1.5e-3 / dt) as usize;
            let mut record = Vec::with_capacity(steps);
            for _ in 0..steps {
                world.step();
                let p = world.particles();
                // Builds may re-sort the particles: follow the first one by its id.
                let k = p.id.iter().position(|&id| id == 0).unwrap();
                record.push((
                    p.force[k],
                    p.torque[k],
                    p.position[k].y,
                    world.contact_count(),
                ));
            }
            (record, world.rebuild_count())
        };
        let side = 0.02;
        // The pair meets across the face x = 0 and, mid-contact (≈ 0.75 ms, 3.75 mm
        // downstream), drifts through the face y = side.
        let (across, rebuilds) = run(0.0, side - 3.75e-3);
        let (open, _) = run(0.5 * side, 0.25 * side);
        let crossing_in_contact = across
            .windows(2)
            .any(|w| w[0].3 == 1 && w[1].3 == 1 && w[1].2 < w[0].2);
        assert!(
            crossing_in_contact,
            "the pair did not cross the face in contact"
        );
        assert!(rebuilds > 10, "only {rebuilds} builds");
        let peak = open.iter().map(|s| s.0.norm()).fold(0.0, f64::max);
        assert!(peak > 0.0, "no collision");
        for (k, (a, b)) in across.iter().zip(&open).enumerate() {
            assert_eq!(a.3, b.3, "contact count differs at step {k}");
            let (df, dt) = ((a.0 - b.0).norm(), (a.1 - b.1).norm());
            assert!(
                df <= 1e-6 * peak && dt <= 1e-6 * peak * 1e-3,
                "step {k}: force {:?} vs {:?}, torque {:?} vs {:?}",
                a.0,
                b.0,
                a.1,
                b.1
            );
        }
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

    /// A pour: grains inserted by a factory (at the deferred insertion points, with the
    /// adaptive skin and the wall candidate lists) while the 3000-grain cloud flows onto the
    /// floor, 400 steps with the given contact code on `threads` threads: the state hash, the
    /// grain count and the rebuild count.
    fn pour(threads: usize, kernel: KernelChoice) -> (u64, usize, u64) {
        use crate::distribution::{SizeDistribution, SizeDistributionSpec};
        use crate::factory::{Factory, FactorySpec, Region};
        on_threads(threads, || {
            let mut world = cloud(
                RollingModel::ConstantDirectionalTorque,
                Integrator::SymplecticEuler,
            );
            world.set_kernel(kernel);
            let soil = world.materials().id("soil").unwrap();
            let size = SizeDistribution::new(SizeDistributionSpec::Uniform {
                min_radius: 0.0009,
                max_radius: 0.0011,
            })
            .unwrap();
            let density = world.materials().material(soil).density;
            let factory = Factory::new(
                FactorySpec {
                    region: Region::Box {
                        min: Vec3::new(0.002, 0.002, 0.15),
                        max: Vec3::new(0.028, 0.028, 0.19),
                    },
                    mass_rate: 2.0,
                    total_mass: 0.01,
                    start_time: 0.0,
                    velocity: Vec3::new(0.0, 0.0, -1.5),
                    size,
                    max_attempts_per_particle: 50,
                },
                density,
            )
            .unwrap();
            world
                .add_source(ParticleSource::Factory(factory), soil)
                .unwrap();
            world.run(400);
            (
                world.state_hash(),
                world.particles().len(),
                world.rebuild_count(),
            )
        })
    }

    /// One thread (fused sweep) and two threads (parallel passes) must agree bit for bit on
    /// the pour, insertions included.
    #[test]
    fn a_pour_is_bit_identical_for_one_and_two_threads() {
        let (one, n_one, rebuilds) = pour(1, KernelChoice::Auto);
        let (two, n_two, _) = pour(2, KernelChoice::Auto);
        assert!(n_one > 3100, "the factory inserted {} grains", n_one - 3000);
        assert!(rebuilds > 5, "{rebuilds} rebuilds");
        assert_eq!(n_one, n_two);
        assert_eq!(one, two);
    }

    /// The gather adds every incident share without reading the pair's flag, so a pair out of
    /// contact must hold a zero share: after every step of a falling, colliding cloud, on both
    /// pair paths and both dispatch paths, while pairs touch and separate.
    #[test]
    fn a_pair_out_of_contact_holds_a_zero_share() {
        for kernel in [KernelChoice::Auto, KernelChoice::Scalar] {
            for threads in [1, 2] {
                on_threads(threads, || {
                    let mut world = cloud(
                        RollingModel::ConstantDirectionalTorque,
                        Integrator::SymplecticEuler,
                    );
                    world.set_kernel(kernel);
                    let mut separations = 0;
                    let mut was_touching: Vec<bool> = Vec::new();
                    for step in 0..300 {
                        world.step();
                        let pairs = &world.pairs;
                        let touching: Vec<bool> =
                            pairs.partner.iter().map(|e| e & IN_CONTACT != 0).collect();
                        // Pair indices only compare between rebuilds.
                        if touching.len() == was_touching.len() {
                            separations += was_touching
                                .iter()
                                .zip(&touching)
                                .filter(|&(&was, &is)| was && !is)
                                .count();
                        }
                        for (k, &is) in touching.iter().enumerate() {
                            let share = pairs.partner_share[k];
                            if !is {
                                assert!(
                                    share.force == Vec3::zeros()
                                        && share.torque == Vec3::zeros()
                                        && share.rolling_moment == 0.0,
                                    "{kernel:?}, {threads} threads, step {step}: pair {k} is \
                                     out of contact with the share {share:?}"
                                );
                            }
                        }
                        was_touching = touching;
                    }
                    assert!(
                        separations > 100,
                        "{kernel:?}: only {separations} separations"
                    );
                });
            }
        }
    }

    /// The lane kernel and the scalar loop give the same pour bit for bit (dense, sliding,
    /// spinning contacts across periodic faces), on one thread and two.
    #[test]
    fn the_lane_kernel_is_bit_identical_to_the_scalar_loop() {
        let table = frictional_paper_table(0.4);
        let cdt = RollingModel::ConstantDirectionalTorque;
        assert_eq!(
            lanes::PairPath::for_world(KernelChoice::Auto, &table, cdt),
            lanes::PairPath::Lanes
        );
        assert_eq!(
            lanes::PairPath::for_world(KernelChoice::Auto, &table, RollingModel::epsd()),
            lanes::PairPath::Scalar
        );
        let scalar = pour(1, KernelChoice::Scalar);
        assert_eq!(pour(1, KernelChoice::Auto), scalar);
        assert_eq!(pour(2, KernelChoice::Auto), scalar);
        assert_eq!(pour(2, KernelChoice::Scalar), scalar);
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
                on_threads(threads, || {
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

    /// An empty world of the frictional paper table over a `side` × `side` square, periodic
    /// in x and y, from z = -10 mm to 100 mm, stepping at 0.2 Rayleigh times of grains of
    /// radius `r`; with the soil's and the steel's ids.
    fn periodic_square(side: f64, r: f64) -> (World, MaterialId, MaterialId) {
        let materials = frictional_paper_table(0.4);
        let soil = materials.id("soil").unwrap();
        let steel = materials.id("steel").unwrap();
        let domain = Domain {
            min: Vec3::new(0.0, 0.0, -0.01),
            max: Vec3::new(side, side, 0.1),
            periodic_x: true,
            periodic_y: true,
        };
        let dt = materials.rayleigh_time_step(soil, r, 0.2);
        let world = World::new(materials, WorldConfig::new(dt, domain)).unwrap();
        (world, soil, steel)
    }

    /// A slow bed of 4 layers of 25 grains (radius 0.9-1.0 `r`) from z = r over a
    /// `side` × `side` square, and a fast stream of 2 layers 16 mm up falling at 2.5 m/s.
    fn add_bed_and_stream(world: &mut World, soil: MaterialId, side: f64, r: f64) {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let per = 5;
        let spacing = side / per as f64;
        let mut add = |k: usize, z0: f64, speed: f64| {
            let (x, y, z) = (k % per, (k / per) % per, k / (per * per));
            let jitter = Vec3::new(rng.gen(), rng.gen(), 0.0) * (0.1 * spacing);
            let position = Vec3::new(x as f64, y as f64, z as f64 * 0.9) * spacing
                + Vec3::new(0.5 * spacing, 0.5 * spacing, z0)
                + jitter;
            let velocity = Vec3::new(rng.gen::<f64>() - 0.5, rng.gen::<f64>() - 0.5, 0.0) * 0.02
                + Vec3::new(0.0, 0.0, -speed);
            world
                .add_particle(ParticleSpec {
                    position,
                    velocity,
                    angular_velocity: Vec3::zeros(),
                    radius: r * (0.9 + 0.1 * rng.gen::<f64>()),
                    material: soil,
                })
                .unwrap();
        };
        for k in 0..4 * per * per {
            add(k, r, 0.0);
        }
        for k in 0..2 * per * per {
            add(k, 0.016, 2.5);
        }
    }

    /// Per-particle skins (`BuildMark`): a fast stream falls into a slow bed; after every
    /// step every touching pair (brute force over all pairs) is in the pair list, and the
    /// stream's skins are wider than the bed's.
    #[test]
    fn per_particle_skins_never_miss_a_touching_pair() {
        let (r, side) = (1e-3, 0.012);
        let (mut world, soil, steel) = periodic_square(side, r);
        let domain = world.config.domain;
        add_floor(&mut world, steel, 0.03);
        add_bed_and_stream(&mut world, soil, side, r);
        let mut widest = (f32::INFINITY, 0.0f32);
        let mut most_contacts = 0;
        for step in 0..300 {
            world.step();
            most_contacts = most_contacts.max(world.contact_count());
            let p = &world.particles;
            let skins = p.build_mark.iter().map(|m| m.half_skin);
            let (lo, hi) = skins.fold((f32::INFINITY, 0.0f32), |(lo, hi), h| {
                (lo.min(h), hi.max(h))
            });
            if hi / lo > widest.1 / widest.0 {
                widest = (lo, hi);
            }
            for i in 0..p.len() {
                for j in i + 1..p.len() {
                    let d = domain.minimum_image(p.position[j] - p.position[i]);
                    if d.norm() < p.radius[i] + p.radius[j] {
                        assert!(
                            world.pairs.find(i as u32, j as u32).is_some(),
                            "step {step}: touching pair ({i}, {j}) is not listed"
                        );
                    }
                }
            }
        }
        assert!(most_contacts > 100, "{most_contacts} contacts at most");
        assert!(
            widest.1 > 2.0 * widest.0,
            "the stream's skins ({}) should be wider than the bed's ({})",
            widest.1,
            widest.0
        );
    }

    /// Wall candidates (`WallCandidates`): a spray of grains falls onto a static floor of 128
    /// triangles, past a block moving sideways and a turning paddle. After every step that
    /// does not call for a rebuild, for every grain and every geometry whose candidates are in
    /// use, the listed triangles give exactly the contacts a query over the whole mesh gives.
    /// (Fails if the candidates' reach leaves out the grain's own half skin: checked.)
    #[test]
    fn wall_candidates_find_every_contact_a_whole_mesh_query_finds() {
        use crate::kinematics::RotationSegment;
        use crate::mesh::generators::{cuboid, plane};
        let (r, side) = (1e-3, 0.012);
        let (mut world, soil, steel) = periodic_square(side, r);
        let at = |x: f64, y: f64, z: f64| Pose::translation(x, y, z);
        let geometries = [
            (
                "floor",
                plane(0.03, 0.03, 8, 8).unwrap(),
                Motion::stationary(at(-0.009, -0.009, 0.0)),
            ),
            (
                "block",
                cuboid(0.003, 0.003, 0.004).unwrap(),
                Motion::translating(at(0.001, 0.004, 0.0005), Vec3::new(1.0, 0.0, 0.0), 0.0)
                    .unwrap(),
            ),
            (
                "paddle",
                cuboid(0.008, 0.001, 0.002).unwrap(),
                Motion::new(
                    at(0.006, 0.006, 0.001),
                    Vec::new(),
                    vec![RotationSegment {
                        axis: Vec3::z(),
                        axis_point: Vec3::new(0.004, 0.0005, 0.0),
                        rpm: 3000.0,
                        start: 0.0,
                        stop: 1.0,
                    }],
                )
                .unwrap(),
            ),
        ];
        for (name, mesh, motion) in geometries {
            world
                .add_geometry(Geometry {
                    name: name.into(),
                    mesh,
                    motion,
                    material: steel,
                })
                .unwrap();
        }
        // A spray: 4 layers of 25 grains from 1.5 mm up, thrown down and sideways at up to
        // 0.6 m/s.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let spacing = side / 5.0;
        for k in 0..100 {
            let mut u = || rng.gen::<f64>();
            let (x, y, z) = ((k % 5) as f64, ((k / 5) % 5) as f64, (k / 25) as f64);
            let position = Vec3::new(x + 0.5, y + 0.5, 0.0) * spacing
                + Vec3::new(0.0, 0.0, 0.0015 + z * spacing);
            let velocity = Vec3::new(u() - 0.5, u() - 0.5, -u()) * 0.6;
            let radius = r * (0.8 + 0.2 * u());
            world
                .add_particle(ParticleSpec {
                    position,
                    velocity,
                    angular_velocity: Vec3::zeros(),
                    radius,
                    material: soil,
                })
                .unwrap();
        }
        let (mut compared, mut touching, mut live) = (0usize, [0usize; 3], 0usize);
        let (mut among, mut whole) = (Vec::new(), Vec::new());
        for step in 0..1500 {
            world.step();
            if world.needs_rebuild {
                continue;
            }
            let placed = world.place_geometries(world.time);
            let p = &world.particles;
            for i in 0..p.len() {
                let (geometry_of, triangle_of) = world.walls.of(i);
                for (g, (geometry, placement)) in world.geometries.iter().zip(&placed).enumerate() {
                    if !placement.cached {
                        live += 1;
                        continue;
                    }
                    let listed: Vec<u32> = geometry_of
                        .iter()
                        .zip(triangle_of)
                        .filter(|(&of, _)| of == g as u32)
                        .map(|(_, &t)| t)
                        .collect();
                    let centre = placement
                        .inverse
                        .transform_point(&p.position[i].into())
                        .coords;
                    among.clear();
                    whole.clear();
                    geometry
                        .mesh
                        .sphere_contacts_among(centre, p.radius[i], &listed, &mut among);
                    geometry
                        .mesh
                        .sphere_contacts(centre, p.radius[i], &mut whole);
                    let key = |c: &MeshContact| (c.triangle, c.overlap.to_bits());
                    let mut a: Vec<_> = among.iter().map(key).collect();
                    let mut b: Vec<_> = whole.iter().map(key).collect();
                    a.sort_unstable();
                    b.sort_unstable();
                    assert_eq!(a, b, "step {step}, grain {i}, geometry {}", geometry.name);
                    compared += 1;
                    touching[g] += b.len();
                }
            }
        }
        assert!(compared > 50_000, "{compared} comparisons");
        assert!(
            touching.iter().all(|&n| n > 100),
            "contacts compared per geometry: {touching:?}"
        );
        assert!(
            live > 0,
            "the paddle should outrun its allowance between rebuilds"
        );
    }
}
