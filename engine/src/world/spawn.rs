//! Particle sources: asking them for new grains and the overlap test they use.

use super::*;

/// The existing particles a grain inserted by one source could touch: those within `reach`
/// of the source's region box (all of them in a periodic domain, where the minimum image can
/// bring a far grain near), with a cell grid over just those. Built once per source and step,
/// and only if the source tries a spot: a pour's factory region holds a few dozen of the
/// world's grains, so the overlap tests no longer cost a grid over every grain.
pub(super) struct NearSource {
    grid: CellGrid,
    /// World index of each particle the grid knows (the grid's indices point into this).
    index: Vec<u32>,
    /// Largest existing radius plus the largest radius the source inserts.
    reach: f64,
}

impl NearSource {
    fn new(world: &World, bounds: Option<(Vec3, Vec3)>, max_new_radius: f64) -> NearSource {
        let p = &world.particles;
        let domain = &world.config.domain;
        let reach = world.max_radius() + max_new_radius;
        let bounds = bounds.filter(|_| !domain.periodic_x && !domain.periodic_y);
        let near = |x: &Vec3| match bounds {
            Some((lo, hi)) => (0..3).all(|a| x[a] >= lo[a] - reach && x[a] <= hi[a] + reach),
            None => true,
        };
        let (index, positions): (Vec<u32>, Vec<Vec3>) = (p.position.iter().enumerate())
            .filter(|(_, x)| near(x))
            .map(|(k, x)| (k as u32, *x))
            .unzip();
        let grid = CellGrid::build(domain, reach, &positions, SORT_CELLS);
        NearSource { grid, index, reach }
    }
}

impl World {
    /// True if a sphere at `centre` with `radius` (lying inside the source's region) overlaps
    /// no particle and no geometry at the current time.
    pub(super) fn is_free(&self, centre: Vec3, radius: f64, near: &NearSource) -> bool {
        let p = &self.particles;
        let domain = &self.config.domain;
        let mut clear = true;
        near.grid.for_each_near(centre, near.reach, |g| {
            let k = near.index[g as usize] as usize;
            let reach = radius + p.radius[k];
            clear &= domain.minimum_image(p.position[k] - centre).norm_squared() >= reach * reach;
        });
        clear && self.clear_of_geometries(centre, radius)
    }

    /// True if a sphere at `centre` with `radius` touches no geometry at the current time (the
    /// geometry half of a source's room test, also for a caller that serves sources itself).
    pub fn clear_of_geometries(&self, centre: Vec3, radius: f64) -> bool {
        self.clear_of_geometries_at(centre, radius, self.time)
    }

    /// [`World::clear_of_geometries`] with the geometries where their motions put them at
    /// `time`, s: for a caller that steps the scene elsewhere (the GPU backend).
    pub fn clear_of_geometries_at(&self, centre: Vec3, radius: f64, time: f64) -> bool {
        let mut contacts = Vec::new();
        self.geometries.iter().all(|g| {
            let pose = g.motion.pose_at(time);
            let body = pose.inverse_transform_point(&centre.into()).coords;
            contacts.clear();
            g.mesh.sphere_contacts(body, radius, &mut contacts);
            contacts.is_empty()
        })
    }

    pub(super) fn max_radius(&self) -> f64 {
        self.particles.radius.iter().copied().fold(0.0, f64::max)
    }

    /// Ask every source, in order, for the particles due in this step and add them. Each
    /// source sees the particles added by the sources before it.
    pub(super) fn spawn_from_sources(&mut self) {
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
            let (bounds, max_new_radius) = (source.region_bounds(), source.max_radius());
            // The overlap-test grid is built only if the source actually tries a spot.
            let near: std::cell::OnceCell<NearSource> = std::cell::OnceCell::new();
            let report = source.spawn(
                t,
                dt,
                &mut rng,
                |centre, radius| {
                    let near = near
                        .get_or_init(|| NearSource::new(self, bounds, max_new_radius.max(radius)));
                    self.is_free(centre, radius, near)
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
}
