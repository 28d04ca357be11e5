//! Particle sources: factories that insert particles at a mass rate into a region, and explicit
//! lists.
//!
//! A factory keeps its own books: it knows how much mass it has inserted and how much the rate
//! allowed so far, and each [`Factory::spawn`] call inserts the difference. When the region is
//! too crowded to place a particle (after a bounded number of random attempts), the call stops
//! and the shortfall (the *deficit*) is simply carried over: the next call sees a larger
//! allowance and tries again. The mass rate is thus met on average whenever there is room, and
//! the total mass is never exceeded.
//!
//! The pending particle's radius is drawn once and kept until that particle is placed, so the
//! sequence of radii (and therefore the mass distribution) does not depend on how crowded the
//! region was. Everything random comes from the caller's RNG: same RNG state, same particles.

use std::collections::HashMap;
use std::f64::consts::{PI, TAU};

use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::distribution::SizeDistribution;
use crate::math::Vec3;

/// Why a factory was rejected; names the field and value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FactoryError {
    #[error("{field} = {value} must be finite and > 0")]
    NotPositive { field: &'static str, value: f64 },
    #[error("{field} = {value} must be finite and >= 0")]
    Negative { field: &'static str, value: f64 },
    #[error("{field} is not finite: {value:?}")]
    NotFinite {
        field: &'static str,
        value: [f64; 3],
    },
    #[error("region: {field} = {value} must exceed {other_field} = {other}")]
    EmptyRegion {
        field: &'static str,
        value: f64,
        other_field: &'static str,
        other: f64,
    },
    #[error("region is too small for the largest particle (radius {max_radius} m): {reason}")]
    RegionTooSmall { max_radius: f64, reason: String },
    #[error("max_attempts_per_particle must be at least 1")]
    NoAttempts,
    #[error("particles[{index}].{field} is invalid: {value:?} (must be finite; radius > 0)")]
    ListedParticle {
        index: usize,
        field: &'static str,
        value: [f64; 3],
    },
}

/// Where new particle centres go. The whole sphere is kept inside the region.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Region {
    /// Axis-aligned box (m).
    Box { min: Vec3, max: Vec3 },
    /// Vertical cylinder with axis through `(axis_x, axis_y)`, between `z_min` and `z_max`.
    Cylinder {
        axis_x: f64,
        axis_y: f64,
        radius: f64,
        z_min: f64,
        z_max: f64,
    },
}

impl Region {
    /// The axis-aligned box that holds the region (m): every sphere it places lies inside.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        match *self {
            Region::Box { min, max } => (min, max),
            Region::Cylinder {
                axis_x,
                axis_y,
                radius,
                z_min,
                z_max,
            } => (
                Vec3::new(axis_x - radius, axis_y - radius, z_min),
                Vec3::new(axis_x + radius, axis_y + radius, z_max),
            ),
        }
    }

    fn validate(&self) -> Result<(), FactoryError> {
        let finite = |field, v: Vec3| {
            if v.iter().all(|c| c.is_finite()) {
                Ok(())
            } else {
                Err(FactoryError::NotFinite {
                    field,
                    value: [v.x, v.y, v.z],
                })
            }
        };
        let above = |field, value: f64, other_field, other: f64| {
            if value > other {
                Ok(())
            } else {
                Err(FactoryError::EmptyRegion {
                    field,
                    value,
                    other_field,
                    other,
                })
            }
        };
        match *self {
            Region::Box { min, max } => {
                finite("region.min", min)?;
                finite("region.max", max)?;
                above("max.x", max.x, "min.x", min.x)?;
                above("max.y", max.y, "min.y", min.y)?;
                above("max.z", max.z, "min.z", min.z)
            }
            Region::Cylinder {
                axis_x,
                axis_y,
                radius,
                z_min,
                z_max,
            } => {
                finite("region.axis", Vec3::new(axis_x, axis_y, 0.0))?;
                finite("region.z", Vec3::new(z_min, z_max, 0.0))?;
                positive("region.radius", radius)?;
                above("z_max", z_max, "z_min", z_min)
            }
        }
    }

    /// Fails if a sphere of `max_radius` cannot fit, since the factory would then wait forever
    /// for its first large particle.
    fn check_fits(&self, max_radius: f64) -> Result<(), FactoryError> {
        let too_small = |reason: String| Err(FactoryError::RegionTooSmall { max_radius, reason });
        match *self {
            Region::Box { min, max } => {
                let size = max - min;
                if size.min() < 2.0 * max_radius {
                    return too_small(format!("box size {:?} m", [size.x, size.y, size.z]));
                }
            }
            Region::Cylinder {
                radius,
                z_min,
                z_max,
                ..
            } => {
                if radius < max_radius || z_max - z_min < 2.0 * max_radius {
                    return too_small(format!(
                        "cylinder radius {radius} m, height {} m",
                        z_max - z_min
                    ));
                }
            }
        }
        Ok(())
    }

    /// A uniformly random centre for a sphere of `radius` lying wholly inside, or `None` if
    /// the region is too small for it.
    fn sample_center(&self, radius: f64, rng: &mut impl Rng) -> Option<Vec3> {
        let mut within = |lo: f64, hi: f64| -> Option<f64> {
            let (lo, hi) = (lo + radius, hi - radius);
            (hi >= lo).then(|| lo + (hi - lo) * rng.gen::<f64>())
        };
        match *self {
            Region::Box { min, max } => Some(Vec3::new(
                within(min.x, max.x)?,
                within(min.y, max.y)?,
                within(min.z, max.z)?,
            )),
            Region::Cylinder {
                axis_x,
                axis_y,
                radius: cylinder_radius,
                z_min,
                z_max,
            } => {
                let z = within(z_min, z_max)?;
                let reach = cylinder_radius - radius;
                if reach < 0.0 {
                    return None;
                }
                // sqrt makes the density uniform over the disc's area.
                let r = reach * rng.gen::<f64>().sqrt();
                let phi = TAU * rng.gen::<f64>();
                Some(Vec3::new(axis_x + r * phi.cos(), axis_y + r * phi.sin(), z))
            }
        }
    }
}

fn positive(field: &'static str, value: f64) -> Result<(), FactoryError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(FactoryError::NotPositive { field, value })
    }
}

fn default_attempts() -> u32 {
    100
}

/// A factory as written in a configuration. The particle density comes from the material and is
/// passed to [`Factory::new`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FactorySpec {
    pub region: Region,
    /// Insertion rate (kg/s).
    pub mass_rate: f64,
    /// Mass after which the factory stops (kg).
    pub total_mass: f64,
    /// Time insertion begins (s).
    #[serde(default)]
    pub start_time: f64,
    /// Velocity given to every new particle (m/s).
    #[serde(default = "Vec3::zeros")]
    pub velocity: Vec3,
    pub size: SizeDistribution,
    /// Random positions tried for one particle before the region counts as full for this call.
    #[serde(default = "default_attempts")]
    pub max_attempts_per_particle: u32,
}

/// What one [`Factory::spawn`] call did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SpawnReport {
    /// Particles placed in this call.
    pub placed: usize,
    /// Their mass (kg).
    pub placed_mass: f64,
    /// Mass that was due by now but could not be placed (region full); carried over (kg).
    pub unplaced_mass: f64,
}

/// A new particle: centre (m), radius (m), velocity (m/s).
pub type NewParticle = (Vec3, f64, Vec3);

/// A mass-rate particle factory with its insertion state. Serialisable so a run can be
/// checkpointed; configurations should hold a [`FactorySpec`] and go through
/// [`Factory::new`], which validates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Factory {
    spec: FactorySpec,
    density: f64,
    inserted_mass: f64,
    inserted_count: u64,
    /// Radius of the next particle, drawn once and kept until it is placed.
    pending_radius: Option<f64>,
}

fn sphere_mass(density: f64, radius: f64) -> f64 {
    density * 4.0 / 3.0 * PI * radius.powi(3)
}

impl Factory {
    /// Validates the spec; `density` (kg/m³) is the material's particle density.
    pub fn new(spec: FactorySpec, density: f64) -> Result<Factory, FactoryError> {
        spec.region.validate()?;
        positive("mass_rate", spec.mass_rate)?;
        positive("total_mass", spec.total_mass)?;
        positive("density", density)?;
        if !spec.start_time.is_finite() {
            return Err(FactoryError::NotFinite {
                field: "start_time",
                value: [spec.start_time; 3],
            });
        }
        if !spec.velocity.iter().all(|c| c.is_finite()) {
            let v = spec.velocity;
            return Err(FactoryError::NotFinite {
                field: "velocity",
                value: [v.x, v.y, v.z],
            });
        }
        spec.region.check_fits(spec.size.max_radius())?;
        if spec.max_attempts_per_particle == 0 {
            return Err(FactoryError::NoAttempts);
        }
        Ok(Factory {
            spec,
            density,
            inserted_mass: 0.0,
            inserted_count: 0,
            pending_radius: None,
        })
    }

    pub fn spec(&self) -> &FactorySpec {
        &self.spec
    }

    /// The particle density its mass books use, kg/m³.
    pub fn density(&self) -> f64 {
        self.density
    }

    /// Mass inserted so far (kg).
    pub fn inserted_mass(&self) -> f64 {
        self.inserted_mass
    }

    pub fn inserted_count(&self) -> u64 {
        self.inserted_count
    }

    /// True once the next particle would exceed the total mass: the factory will insert
    /// nothing more. (The pending radius is only known after the first spawn call.)
    pub fn is_finished(&self) -> bool {
        self.pending_radius.is_some_and(|r| {
            self.inserted_mass + sphere_mass(self.density, r) > self.spec.total_mass
        })
    }

    /// Mass the rate allows by the end of the step `[t, t + dt]` (kg).
    pub fn allowed_mass(&self, t: f64, dt: f64) -> f64 {
        let elapsed = (t + dt - self.spec.start_time).max(0.0);
        (self.spec.mass_rate * elapsed).min(self.spec.total_mass)
    }

    /// Inserts the mass the rate allows by the end of the step `[t, t + dt]` that is not
    /// inserted yet, pushing new particles into `out`. A particle is placed only where
    /// `is_free(centre, radius)` (the caller's test against existing particles and walls) holds
    /// and it does not overlap particles placed earlier in this call. Gives up on the current
    /// particle after `max_attempts_per_particle` tries, leaving the rest as a deficit for the
    /// next call (reported as `unplaced_mass`).
    pub fn spawn(
        &mut self,
        t: f64,
        dt: f64,
        rng: &mut impl Rng,
        is_free: impl Fn(Vec3, f64) -> bool,
        out: &mut Vec<NewParticle>,
    ) -> SpawnReport {
        let mut report = SpawnReport::default();
        let allowed = self.allowed_mass(t, dt);
        // Spheres placed in this call, hashed by cell of twice the largest radius, so checking
        // a candidate visits at most 27 cells of nearby spheres.
        let cell = 2.0 * self.spec.size.max_radius();
        let key = |p: Vec3| -> [i64; 3] { [0, 1, 2].map(|a| (p[a] / cell).floor() as i64) };
        let mut placed: Vec<(Vec3, f64)> = Vec::new();
        let mut cells: HashMap<[i64; 3], Vec<usize>> = HashMap::new();

        loop {
            let radius = *self
                .pending_radius
                .get_or_insert_with(|| self.spec.size.sample(rng));
            let mass = sphere_mass(self.density, radius);
            if self.inserted_mass + mass > allowed {
                break;
            }
            let mut spot = None;
            for _ in 0..self.spec.max_attempts_per_particle {
                let Some(c) = self.spec.region.sample_center(radius, rng) else {
                    break; // region too small for this particle
                };
                let k = key(c);
                let clashes = (-1..=1).any(|dz| {
                    (-1..=1).any(|dy| {
                        (-1..=1).any(|dx| {
                            cells
                                .get(&[
                                    k[0].saturating_add(dx),
                                    k[1].saturating_add(dy),
                                    k[2].saturating_add(dz),
                                ])
                                .is_some_and(|list| {
                                    list.iter().any(|&i| {
                                        let (q, rq) = placed[i];
                                        (q - c).norm_squared() < (rq + radius).powi(2)
                                    })
                                })
                        })
                    })
                });
                if !clashes && is_free(c, radius) {
                    spot = Some(c);
                    break;
                }
            }
            let Some(center) = spot else {
                break; // region full for now: the deficit carries over
            };
            cells.entry(key(center)).or_default().push(placed.len());
            placed.push((center, radius));
            out.push((center, radius, self.spec.velocity));
            self.inserted_mass += mass;
            self.inserted_count += 1;
            self.pending_radius = None;
            report.placed += 1;
            report.placed_mass += mass;
        }
        // Only whole particles are inserted, so a deficit smaller than the pending particle is
        // normal rounding, not a failure to place.
        let pending_mass = self
            .pending_radius
            .map_or(0.0, |r| sphere_mass(self.density, r));
        let deficit = allowed - self.inserted_mass;
        if deficit >= pending_mass {
            report.unplaced_mass = deficit;
        }
        report
    }
}

/// One particle of an explicit list.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ListedParticle {
    pub center: Vec3,
    pub radius: f64,
    #[serde(default = "Vec3::zeros")]
    pub velocity: Vec3,
}

/// A fixed list of particles inserted all at once at `time` (e.g. a prepared packing). They
/// are inserted as given, without overlap checks: the list is the caller's responsibility.
/// Radii, positions and velocities are validated on construction (and deserialisation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "ParticleListData", into = "ParticleListData")]
pub struct ParticleList {
    time: f64,
    particles: Vec<ListedParticle>,
    inserted: bool,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct ParticleListData {
    time: f64,
    particles: Vec<ListedParticle>,
    #[serde(default)]
    inserted: bool,
}

impl TryFrom<ParticleListData> for ParticleList {
    type Error = FactoryError;
    fn try_from(d: ParticleListData) -> Result<Self, FactoryError> {
        let mut list = ParticleList::new(d.time, d.particles)?;
        list.inserted = d.inserted;
        Ok(list)
    }
}

impl From<ParticleList> for ParticleListData {
    fn from(l: ParticleList) -> Self {
        ParticleListData {
            time: l.time,
            particles: l.particles,
            inserted: l.inserted,
        }
    }
}

impl ParticleList {
    /// Validates every particle (finite centre and velocity, positive radius) and `time`.
    pub fn new(time: f64, particles: Vec<ListedParticle>) -> Result<ParticleList, FactoryError> {
        if !time.is_finite() {
            return Err(FactoryError::NotFinite {
                field: "time",
                value: [time; 3],
            });
        }
        for (index, p) in particles.iter().enumerate() {
            let bad = |field: &'static str, v: Vec3| FactoryError::ListedParticle {
                index,
                field,
                value: [v.x, v.y, v.z],
            };
            if !p.center.iter().all(|c| c.is_finite()) {
                return Err(bad("center", p.center));
            }
            if !p.velocity.iter().all(|c| c.is_finite()) {
                return Err(bad("velocity", p.velocity));
            }
            if !(p.radius.is_finite() && p.radius > 0.0) {
                return Err(bad("radius", Vec3::repeat(p.radius)));
            }
        }
        Ok(ParticleList {
            time,
            particles,
            inserted: false,
        })
    }

    pub fn time(&self) -> f64 {
        self.time
    }

    pub fn particles(&self) -> &[ListedParticle] {
        &self.particles
    }

    /// Whether the list has been inserted already.
    pub fn is_inserted(&self) -> bool {
        self.inserted
    }

    /// Pushes the whole list once, in the first step whose end `t + dt` reaches `time`.
    pub fn spawn(&mut self, t: f64, dt: f64, out: &mut Vec<NewParticle>) -> usize {
        if self.inserted || t + dt < self.time {
            return 0;
        }
        self.inserted = true;
        out.extend(
            self.particles
                .iter()
                .map(|p| (p.center, p.radius, p.velocity)),
        );
        self.particles.len()
    }
}

/// Any particle source (runtime state; configurations hold [`FactorySpec`]s and lists).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum ParticleSource {
    Factory(Factory),
    List(ParticleList),
}

impl ParticleSource {
    /// The box every particle it places lies in, for a source that tests for room (a
    /// factory); `None` for a list, which places its particles where they are listed.
    pub fn region_bounds(&self) -> Option<(Vec3, Vec3)> {
        match self {
            ParticleSource::Factory(f) => Some(f.spec.region.bounds()),
            ParticleSource::List(_) => None,
        }
    }

    /// The largest radius a factory may insert (0 for a list, which tests for no room).
    pub fn max_radius(&self) -> f64 {
        match self {
            ParticleSource::Factory(f) => f.spec.size.max_radius(),
            ParticleSource::List(_) => 0.0,
        }
    }

    /// Spawns what is due in the step `[t, t + dt]` (see [`Factory::spawn`]).
    pub fn spawn(
        &mut self,
        t: f64,
        dt: f64,
        rng: &mut impl Rng,
        is_free: impl Fn(Vec3, f64) -> bool,
        out: &mut Vec<NewParticle>,
    ) -> SpawnReport {
        match self {
            ParticleSource::Factory(f) => f.spawn(t, dt, rng, is_free, out),
            ParticleSource::List(list) => SpawnReport {
                placed: list.spawn(t, dt, out),
                placed_mass: 0.0, // a list knows no density; the world accounts for its mass
                unplaced_mass: 0.0,
            },
        }
    }
}
