//! The GPU engine (`repose-engine-gpu`) as a [`Backend`].
//!
//! The scene's world (particles, static and moving geometries, materials, configuration) is
//! uploaded to
//! a [`GpuWorld`] with a slot for every grain its particle sources can insert. The sources are
//! taken out of the world ([`World::take_sources`]) and served from the host by the engine's
//! own code ([`ParticleSource::spawn`], with the world's random stream, as the CPU world serves
//! them), before the first step and then every [`SERVE_EVERY`] steps: a grain enters at most
//! that many steps after it falls due (the CPU engine: 10), the mass rate is the factory's
//! books either way. A source's room test reads the grains near its region back from the GPU
//! and tests the walls where they are then with [`World::clear_of_geometries_at`]; its new
//! grains go in with [`GpuWorld::insert`] (into removed grains' slots first). Grains that leave
//! the box are removed on the GPU.
//!
//! Deterministic on one adapter: the same scene gives the same steps, read-backs, draws and
//! insertions, so the same bits (tested).

use std::cell::OnceCell;
use std::collections::HashMap;

use rand_chacha::ChaCha8Rng;
use repose_engine::factory::{NewParticle, ParticleSource};
use repose_engine::kinematics::Motion;
use repose_engine::material::MaterialId;
use repose_engine::math::Vec3;
use repose_engine::neighbor::Domain;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, GeometryId, GeometrySample, World};
use repose_engine_gpu::{Capacity, Gpu, GpuWorld, Slab};

use super::{first_factory, Backend, BackendError, FactoryBooks, Grains, PlaneStress, Window};

/// Steps between two servings of the particle sources (each one that places grains reads the
/// grains back: a pipeline stall). 100 steps of the `fast` funnel are 3.7 ms, in which the
/// inlet stream moves 2 mm, less than a grain: the factory's region never runs short of room.
pub const SERVE_EVERY: u64 = 100;

/// The GPU engine running a scene built as a CPU [`World`].
pub struct GpuBackend {
    gpu_world: GpuWorld,
    /// The scene without its sources: materials, geometries, configuration.
    scene: World,
    sources: Vec<(ParticleSource, MaterialId)>,
    rng: ChaCha8Rng,
    /// Per slot: the grain's material, radius and mass (the CPU engine's, in f64).
    material: Vec<MaterialId>,
    radius: Vec<f64>,
    mass: Vec<f64>,
    /// Grains ever placed (the scene's and the sources').
    placed: u64,
    /// Steps since the sources were last served.
    since_serve: u64,
    engine_version: String,
    /// The last read-back of the grains and the step it was taken at.
    cache: Option<(u64, Snapshot)>,
}

impl std::fmt::Debug for GpuBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuBackend")
            .field("gpu_world", &self.gpu_world)
            .field("engine_version", &self.engine_version)
            .field("placed", &self.placed)
            .finish_non_exhaustive()
    }
}

/// The present grains, read back (removed slots left out).
#[derive(Debug, Default)]
struct Snapshot {
    position: Vec<Vec3>,
    velocity: Vec<Vec3>,
    angular_velocity: Vec<Vec3>,
    radius: Vec<f64>,
    mass: Vec<f64>,
    inverse_inertia: Vec<f64>,
    material: Vec<MaterialId>,
}

fn sphere_mass(density: f64, radius: f64) -> f64 {
    density * 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3)
}

/// Slots and largest radius for `world`'s particles and everything `sources` can insert: a
/// factory at most its total mass in its smallest grains, a list its particles.
fn capacity(world: &World, sources: &[(ParticleSource, MaterialId)]) -> Capacity {
    let p = world.particles();
    let mut slots = p.len();
    let mut max_radius = p.radius.iter().copied().fold(0.0, f64::max);
    for (source, _) in sources {
        match source {
            ParticleSource::Factory(f) => {
                let size = &f.spec().size;
                let smallest = sphere_mass(f.density(), size.min_radius());
                slots += (f.spec().total_mass / smallest).floor() as usize + 1;
                max_radius = max_radius.max(size.max_radius());
            }
            ParticleSource::List(list) => {
                slots += list.particles().len();
                max_radius = list
                    .particles()
                    .iter()
                    .map(|l| l.radius)
                    .fold(max_radius, f64::max);
            }
        }
    }
    Capacity {
        particles: slots,
        max_radius,
    }
}

/// The grains a source's new grain could touch, hashed by cells of `cell` (at least the sum of
/// two radii), with the domain's minimum image where it is periodic (then every grain).
struct Near {
    cell: f64,
    domain: Domain,
    grains: Vec<(Vec3, f64)>,
    cells: HashMap<[i64; 3], Vec<usize>>,
}

impl Near {
    fn key(&self, x: Vec3) -> [i64; 3] {
        [0, 1, 2].map(|a| (x[a] / self.cell).floor() as i64)
    }

    fn new(domain: Domain, cell: f64, grains: Vec<(Vec3, f64)>) -> Near {
        let mut near = Near {
            cell,
            domain,
            grains,
            cells: HashMap::new(),
        };
        if !near.periodic() {
            for k in 0..near.grains.len() {
                let key = near.key(near.grains[k].0);
                near.cells.entry(key).or_default().push(k);
            }
        }
        near
    }

    fn periodic(&self) -> bool {
        self.domain.periodic_x || self.domain.periodic_y
    }

    /// True if a sphere at `centre` with `radius` (no larger than the cell's half) overlaps
    /// none of the grains.
    fn is_free(&self, centre: Vec3, radius: f64) -> bool {
        let clear = |&(x, r): &(Vec3, f64)| {
            minimum_image(&self.domain, x - centre).norm_squared() >= (r + radius) * (r + radius)
        };
        if self.periodic() {
            return self.grains.iter().all(clear);
        }
        let k = self.key(centre);
        (-1..=1).all(|dz| {
            (-1..=1).all(|dy| {
                (-1..=1).all(|dx| {
                    self.cells
                        .get(&[k[0] + dx, k[1] + dy, k[2] + dz])
                        .is_none_or(|list| list.iter().all(|&g| clear(&self.grains[g])))
                })
            })
        })
    }
}

/// `d` shifted by whole box lengths along the periodic axes to its shortest image.
fn minimum_image(domain: &Domain, mut d: Vec3) -> Vec3 {
    for (a, periodic) in [domain.periodic_x, domain.periodic_y]
        .into_iter()
        .enumerate()
    {
        if periodic {
            let length = domain.max[a] - domain.min[a];
            d[a] -= length * (d[a] / length).round();
        }
    }
    d
}

impl GpuBackend {
    /// Uploads `world` to `gpu`, the geometries `movable` as moving meshes whatever their
    /// motion now ([`GpuWorld::with_movers`]), and serves its sources for the first step.
    /// Errors: a scene that does not fit the adapter (its capacities, its limits).
    pub fn new(
        gpu: &Gpu,
        mut world: World,
        movable: &[GeometryId],
    ) -> Result<GpuBackend, BackendError> {
        let sources = world.take_sources();
        let rng = world.rng().clone();
        let capacity = capacity(&world, &sources);
        let movable: Vec<usize> = movable.iter().map(|id| id.0 as usize).collect();
        let gpu_world = GpuWorld::with_movers(gpu, &world, capacity, &movable)?;
        let p = world.particles();
        let mut backend = GpuBackend {
            gpu_world,
            material: p.material.clone(),
            radius: p.radius.clone(),
            mass: p.mass.clone(),
            placed: p.len() as u64,
            scene: world,
            sources,
            rng,
            since_serve: 0,
            engine_version: repose_engine_gpu::engine_version(gpu),
            cache: None,
        };
        backend.serve()?;
        Ok(backend)
    }

    /// The grains within reach of a new grain in `bounds` (all of them in a periodic domain).
    fn near(
        &self,
        bounds: Option<(Vec3, Vec3)>,
        max_new_radius: f64,
    ) -> Result<Near, BackendError> {
        let (position, removed) = self.gpu_world.positions()?;
        let domain = self.scene.config().domain;
        let largest = self.radius.iter().copied().fold(0.0, f64::max);
        let reach = largest + max_new_radius;
        let bounds = bounds.filter(|_| !domain.periodic_x && !domain.periodic_y);
        let inside = |x: &Vec3| match bounds {
            Some((lo, hi)) => (0..3).all(|a| x[a] >= lo[a] - reach && x[a] <= hi[a] + reach),
            None => true,
        };
        let grains = (0..position.len())
            .filter(|&k| !removed[k] && inside(&position[k]))
            .map(|k| (position[k], self.radius[k]))
            .collect();
        Ok(Near::new(domain, reach.max(f64::MIN_POSITIVE), grains))
    }

    /// Asks every source, in order, for the grains due in the coming step and inserts them
    /// (each source sees the grains the sources before it inserted).
    fn serve(&mut self) -> Result<(), BackendError> {
        let t = self.gpu_world.time();
        let dt = self.scene.config().time_step;
        let mut sources = std::mem::take(&mut self.sources);
        let mut rng = self.rng.clone();
        let mut spawned: Vec<NewParticle> = Vec::new();
        let mut result = Ok(());
        for (source, material) in &mut sources {
            if matches!(source, ParticleSource::Factory(f) if f.is_finished()) {
                continue;
            }
            spawned.clear();
            let (bounds, max_new_radius) = (source.region_bounds(), source.max_radius());
            let near: OnceCell<Result<Near, BackendError>> = OnceCell::new();
            source.spawn(
                t,
                dt,
                &mut rng,
                |centre, radius| match near
                    .get_or_init(|| self.near(bounds, max_new_radius.max(radius)))
                {
                    Ok(near) => {
                        near.is_free(centre, radius)
                            && self.scene.clear_of_geometries_at(centre, radius, t)
                    }
                    Err(_) => false,
                },
                &mut spawned,
            );
            if let Some(Err(e)) = near.into_inner() {
                result = Err(e);
                break;
            }
            if let Err(e) = self.insert(&spawned, *material) {
                result = Err(e);
                break;
            }
        }
        self.sources = sources;
        self.rng = rng;
        result
    }

    fn insert(
        &mut self,
        spawned: &[NewParticle],
        material: MaterialId,
    ) -> Result<(), BackendError> {
        if spawned.is_empty() {
            return Ok(());
        }
        let specs: Vec<ParticleSpec> = spawned
            .iter()
            .map(|&(position, radius, velocity)| ParticleSpec {
                position,
                velocity,
                angular_velocity: Vec3::zeros(),
                radius,
                material,
            })
            .collect();
        let density = self.scene.materials().material(material).density;
        let slots = self.gpu_world.insert(&specs)?;
        for (&slot, spec) in slots.iter().zip(&specs) {
            if slot >= self.radius.len() {
                self.material.resize(slot + 1, material);
                self.radius.resize(slot + 1, 0.0);
                self.mass.resize(slot + 1, 0.0);
            }
            self.material[slot] = material;
            self.radius[slot] = spec.radius;
            self.mass[slot] = sphere_mass(density, spec.radius);
        }
        self.placed += specs.len() as u64;
        self.cache = None;
        Ok(())
    }

    /// Notes `steps` steps taken and serves the sources when they fall due.
    fn served_after(&mut self, steps: u64) -> Result<(), BackendError> {
        self.since_serve += steps;
        if self.since_serve == SERVE_EVERY {
            self.since_serve = 0;
            self.serve()?;
        }
        Ok(())
    }

    /// The grains now, read back once per step.
    fn snapshot(&mut self) -> Result<&Snapshot, BackendError> {
        let steps = self.gpu_world.steps();
        if self.cache.as_ref().is_none_or(|(at, _)| *at != steps) {
            let p = self.gpu_world.particles()?;
            // Overflowed capacities make the state invalid: an error, not a result (the
            // counters of the step just read back: no read-back of their own).
            self.gpu_world.counters()?;
            let mut s = Snapshot::default();
            for k in (0..p.position.len()).filter(|&k| !p.removed[k]) {
                s.position.push(p.position[k]);
                s.velocity.push(p.velocity[k]);
                s.angular_velocity.push(p.angular_velocity[k]);
                s.radius.push(self.radius[k]);
                s.mass.push(self.mass[k]);
                // The CPU engine's solid sphere.
                s.inverse_inertia
                    .push(1.0 / (0.4 * self.mass[k] * self.radius[k] * self.radius[k]));
                s.material.push(self.material[k]);
            }
            self.cache = Some((steps, s));
        }
        Ok(&self.cache.as_ref().expect("just filled").1)
    }
}

impl Backend for GpuBackend {
    fn engine_version(&self) -> String {
        self.engine_version.clone()
    }

    fn time(&self) -> f64 {
        self.gpu_world.time()
    }

    fn steps(&self) -> u64 {
        self.gpu_world.steps()
    }

    fn time_step(&self) -> f64 {
        self.scene.config().time_step
    }

    /// 2,000 steps: a fraction of a second on a GPU, a read-back each.
    fn steps_between_reports(&self) -> u64 {
        2_000
    }

    fn advance(&mut self, max_steps: u64) -> Result<u64, BackendError> {
        let steps = max_steps.clamp(1, SERVE_EVERY - self.since_serve);
        self.gpu_world.run(steps)?;
        self.served_after(steps)?;
        Ok(steps)
    }

    fn advance_sampling(
        &mut self,
        steps: u64,
        window: &Window,
    ) -> Result<PlaneStress, BackendError> {
        let slab = Slab {
            x: window.x,
            y: window.y,
            z: window.z,
        };
        let mut left = steps.max(1);
        loop {
            let chunk = left.min(SERVE_EVERY - self.since_serve);
            if chunk == left {
                let sum = self.gpu_world.run_sampling_slab(chunk, &slab)?;
                self.served_after(chunk)?;
                return Ok(window.stress_of_sum(sum));
            }
            self.gpu_world.run(chunk)?;
            self.served_after(chunk)?;
            left -= chunk;
        }
    }

    fn grains(&mut self) -> Result<Grains<'_>, BackendError> {
        let s = self.snapshot()?;
        Ok(Grains {
            position: &s.position,
            velocity: &s.velocity,
            angular_velocity: &s.angular_velocity,
            radius: &s.radius,
            mass: &s.mass,
            inverse_inertia: &s.inverse_inertia,
        })
    }

    fn grain_count(&mut self) -> Result<usize, BackendError> {
        Ok((self.placed - self.removed_count()?) as usize)
    }

    fn removed_count(&mut self) -> Result<u64, BackendError> {
        Ok(self.gpu_world.counters()?.removed)
    }

    fn factory(&self) -> Option<FactoryBooks> {
        first_factory(self.sources.iter().map(|(s, _)| s))
    }

    fn geometries(&self) -> &[Geometry] {
        self.scene.geometries()
    }

    fn geometry_series(&mut self, id: GeometryId) -> Result<Vec<GeometrySample>, BackendError> {
        Ok(self.gpu_world.geometry_series(id.0 as usize)?.to_vec())
    }

    fn clear_geometry_series(&mut self) {
        self.gpu_world.clear_geometry_series();
    }

    fn set_geometry_motion(&mut self, id: GeometryId, motion: Motion) -> Result<(), BackendError> {
        self.gpu_world.set_motion(id.0 as usize, motion.clone())?;
        self.scene.set_geometry_motion(id, motion);
        Ok(())
    }

    fn checkpoint_world(&self) -> Option<&World> {
        None
    }

    fn into_world(mut self: Box<Self>) -> Result<World, BackendError> {
        self.snapshot()?;
        let (_, snapshot) = self.cache.take().expect("just read back");
        let GpuBackend {
            scene: mut world,
            sources,
            ..
        } = *self;
        for k in 0..snapshot.position.len() {
            world
                .add_particle(ParticleSpec {
                    position: snapshot.position[k],
                    velocity: snapshot.velocity[k],
                    angular_velocity: snapshot.angular_velocity[k],
                    radius: snapshot.radius[k],
                    material: snapshot.material[k],
                })
                .map_err(|e| BackendError::Gpu(format!("copying the grains out: {e}")))?;
        }
        for (source, material) in sources {
            world
                .add_source(source, material)
                .map_err(|e| BackendError::Gpu(format!("copying the sources out: {e}")))?;
        }
        Ok(world)
    }
}
