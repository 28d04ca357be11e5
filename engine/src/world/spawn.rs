//! Particle sources: asking them for new grains and the overlap test they use.

use super::*;

impl World {
    /// True if a sphere at `centre` with `radius` overlaps no particle and no geometry at the
    /// current time. O(particles) unless `grid` is given.
    pub(super) fn is_free(&self, centre: Vec3, radius: f64, grid: Option<&CellGrid>) -> bool {
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
}
