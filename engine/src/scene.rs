//! Scene documents: everything one simulation needs, as serde data (TOML or JSON), validated
//! into a ready-to-run [`World`] before the first step.
//!
//! A scene names materials by their `name`; geometries, factories and particle lists refer to
//! those names. Every validation error carries the path of the offending field
//! (`geometries[1].mesh: ...`, `factories[0].material: unknown material "sand"`), so a user can
//! find it in the file.

use serde::{Deserialize, Serialize};

use crate::contact::RollingModel;
use crate::factory::{Factory, FactorySpec, ListedParticle, ParticleList, ParticleSource};
use crate::integrate::Integrator;
use crate::kinematics::{Motion, RotationSegment, TranslationSegment};
use crate::material::{check_time_step, rayleigh_time, MaterialSet, TimeStepWarning};
use crate::math::{Pose, Rotation, Vec3};
use crate::mesh::MeshSpec;
use crate::neighbor::Domain;
use crate::world::{Geometry, World, WorldConfig};

/// A complete simulation description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Materials and the pair table (restitution, static and rolling friction per pair).
    pub materials: MaterialSet,
    /// Rigid triangle meshes with their motion.
    #[serde(default)]
    pub geometries: Vec<GeometryEntry>,
    /// Particle factories (mass-rate insertion in a region).
    #[serde(default)]
    pub factories: Vec<FactoryEntry>,
    /// Explicit particle lists.
    #[serde(default)]
    pub particles: Vec<ParticleListEntry>,
    /// Simulation box; particles leaving it are removed and counted.
    pub domain: Domain,
    /// Simulated time, s.
    pub duration: f64,
    /// Time step (default: 20 % of the Rayleigh time of the smallest particle, like the paper).
    #[serde(default)]
    pub time_step: TimeStepSpec,
    #[serde(default = "default_gravity")]
    pub gravity: Vec3,
    #[serde(default)]
    pub integrator: Integrator,
    #[serde(default)]
    pub rolling_model: RollingModel,
    /// Seed of the factories' random placement and size sampling.
    #[serde(default)]
    pub seed: u64,
    /// Expected fastest impact speed, m/s, for the time-step check (default 2 m/s: a fall of
    /// about 20 cm).
    #[serde(default = "default_impact_speed")]
    pub max_impact_speed: f64,
    #[serde(default)]
    pub output: OutputSpec,
}

fn default_gravity() -> Vec3 {
    Vec3::new(0.0, 0.0, -9.81)
}

fn default_impact_speed() -> f64 {
    2.0
}

/// How the time step is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum TimeStepSpec {
    /// A fraction of the Rayleigh time of the smallest particle (EDEM's rule; 0.2 = 20 %).
    RayleighFraction(f64),
    /// A fixed step, s.
    Fixed(f64),
}

impl Default for TimeStepSpec {
    fn default() -> Self {
        TimeStepSpec::RayleighFraction(0.2)
    }
}

/// Where the results go and how often. Paths are decided by the caller (the command line);
/// the scene only says what to write.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// Write a particle snapshot (VTK) every this many simulated seconds; none if absent.
    #[serde(default)]
    pub snapshot_interval: Option<f64>,
    /// Record geometry forces and torques every this many steps.
    #[serde(default = "default_record_interval")]
    pub geometry_record_interval: u64,
}

fn default_record_interval() -> u64 {
    100
}

impl Default for OutputSpec {
    fn default() -> Self {
        OutputSpec {
            snapshot_interval: None,
            geometry_record_interval: default_record_interval(),
        }
    }
}

/// A geometry: a mesh, its material, where it is at t = 0 and how it moves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeometryEntry {
    pub name: String,
    pub mesh: MeshSpec,
    pub material: String,
    /// Position of the mesh's body origin at t = 0, m.
    #[serde(default = "Vec3::zeros")]
    pub position: Vec3,
    /// Initial rotation: axis (any length) and angle in degrees; none if absent.
    #[serde(default)]
    pub rotation: Option<AxisAngle>,
    /// Constant-velocity translation segments.
    #[serde(default)]
    pub translations: Vec<TranslationSegment>,
    /// Constant-speed rotation segments about one body axis.
    #[serde(default)]
    pub rotations: Vec<RotationSegment>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisAngle {
    pub axis: Vec3,
    pub angle_deg: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FactoryEntry {
    pub material: String,
    #[serde(flatten)]
    pub spec: FactorySpec,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParticleListEntry {
    pub material: String,
    /// Insertion time, s.
    #[serde(default)]
    pub time: f64,
    pub particles: Vec<ListedParticle>,
}

/// Why a scene cannot run; the message starts with the path of the offending field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct SceneError {
    pub path: String,
    pub reason: String,
}

fn scene_error(path: impl Into<String>, reason: impl std::fmt::Display) -> SceneError {
    SceneError {
        path: path.into(),
        reason: reason.to_string(),
    }
}

/// A scene turned into a world, with what the caller should know before running it.
#[derive(Debug)]
pub struct PreparedScene {
    pub world: World,
    /// The geometry names, in [`crate::world::GeometryId`] order.
    pub geometry_names: Vec<String>,
    pub duration: f64,
    pub time_step: f64,
    /// Set when the time step resolves the fastest expected impact too coarsely.
    pub time_step_warning: Option<TimeStepWarning>,
}

impl Scene {
    /// Validates every part of the scene and builds the world. Nothing is simulated.
    /// `read_file` supplies the bytes of the STL files the scene names (the engine does no
    /// file I/O; the CLI passes `std::fs::read`).
    pub fn prepare(
        &self,
        read_file: &dyn Fn(&std::path::Path) -> Result<Vec<u8>, String>,
    ) -> Result<PreparedScene, SceneError> {
        let table = self.materials.build().map_err(|e| {
            // Material errors already carry their path (materials.soil.poisson ...).
            scene_error("materials", e)
        })?;
        let material_id = |path: String, name: &str| {
            table.id(name).ok_or_else(|| {
                let known: Vec<&str> = table.materials().iter().map(|m| m.name.as_str()).collect();
                scene_error(
                    path,
                    format!(
                        "unknown material {name:?} (materials: {})",
                        known.join(", ")
                    ),
                )
            })
        };
        check_positive("duration", self.duration)?;
        check_positive("max_impact_speed", self.max_impact_speed)?;
        if !self.gravity.iter().all(|g| g.is_finite()) {
            return Err(scene_error("gravity", "must be finite"));
        }
        check_domain(&self.domain)?;

        // The smallest particle sets the time step.
        let mut smallest: Option<(f64, String)> = None;
        let mut consider = |radius: f64, material: &str| {
            if smallest.as_ref().is_none_or(|(r, _)| radius < *r) {
                smallest = Some((radius, material.to_owned()));
            }
        };
        let mut sources = Vec::new();
        for (i, entry) in self.factories.iter().enumerate() {
            let path = format!("factories[{i}]");
            let id = material_id(format!("{path}.material"), &entry.material)?;
            let density = table.material(id).density;
            let factory = Factory::new(entry.spec.clone(), density)
                .map_err(|e| scene_error(path.clone(), e))?;
            consider(entry.spec.size.min_radius(), &entry.material);
            sources.push((ParticleSource::Factory(factory), id));
        }
        for (i, entry) in self.particles.iter().enumerate() {
            let path = format!("particles[{i}]");
            let id = material_id(format!("{path}.material"), &entry.material)?;
            let list = ParticleList::new(entry.time, entry.particles.clone())
                .map_err(|e| scene_error(path.clone(), e))?;
            for p in &entry.particles {
                consider(p.radius, &entry.material);
            }
            sources.push((ParticleSource::List(list), id));
        }
        let Some((min_radius, min_material)) = smallest else {
            return Err(scene_error(
                "factories",
                "the scene has no particles: add a factory or a particle list",
            ));
        };
        let small_material = table.material(table.id(&min_material).expect("checked above"));
        let time_step = match self.time_step {
            TimeStepSpec::RayleighFraction(f) => {
                if !(f > 0.0 && f <= 1.0) {
                    return Err(scene_error(
                        "time_step.rayleigh_fraction",
                        format!("must be in (0, 1], got {f}"),
                    ));
                }
                f * rayleigh_time(min_radius, small_material)
            }
            TimeStepSpec::Fixed(dt) => {
                check_positive("time_step.fixed", dt)?;
                dt
            }
        };
        let time_step_warning =
            check_time_step(time_step, min_radius, small_material, self.max_impact_speed);

        let mut config = WorldConfig::new(time_step, self.domain);
        config.gravity = self.gravity;
        config.integrator = self.integrator;
        config.rolling_model = self.rolling_model;
        config.seed = self.seed;
        if self.output.geometry_record_interval == 0 {
            return Err(scene_error(
                "output.geometry_record_interval",
                "must be >= 1",
            ));
        }
        config.geometry_record_interval = self.output.geometry_record_interval;
        if let Some(every) = self.output.snapshot_interval {
            check_positive("output.snapshot_interval", every)?;
        }
        let mut world = World::new(table.clone(), config).map_err(|e| scene_error("scene", e))?;

        let mut geometry_names = Vec::new();
        for (i, entry) in self.geometries.iter().enumerate() {
            let path = format!("geometries[{i}]");
            if geometry_names.contains(&entry.name) {
                return Err(scene_error(
                    format!("{path}.name"),
                    format!("{:?} is used by another geometry", entry.name),
                ));
            }
            let material = material_id(format!("{path}.material"), &entry.material)?;
            let mesh = entry
                .mesh
                .build(read_file)
                .map_err(|e| scene_error(format!("{path}.mesh"), e))?;
            if !entry.position.iter().all(|v| v.is_finite()) {
                return Err(scene_error(format!("{path}.position"), "must be finite"));
            }
            let rotation = match entry.rotation {
                None => Rotation::identity(),
                Some(AxisAngle { axis, angle_deg }) => {
                    let unit = nalgebra::Unit::try_new(axis, 1e-12).ok_or_else(|| {
                        scene_error(format!("{path}.rotation.axis"), "must be a non-zero vector")
                    })?;
                    if !angle_deg.is_finite() {
                        return Err(scene_error(
                            format!("{path}.rotation.angle_deg"),
                            "must be finite",
                        ));
                    }
                    Rotation::from_axis_angle(&unit, angle_deg.to_radians())
                }
            };
            let placement = Pose::from_parts(entry.position.into(), rotation);
            let motion = Motion::new(
                placement,
                entry.translations.clone(),
                entry.rotations.clone(),
            )
            .map_err(|e| scene_error(path.clone(), e))?;
            world
                .add_geometry(Geometry {
                    name: entry.name.clone(),
                    mesh,
                    motion,
                    material,
                })
                .map_err(|e| scene_error(path.clone(), e))?;
            geometry_names.push(entry.name.clone());
        }
        for (source, material) in sources {
            world
                .add_source(source, material)
                .map_err(|e| scene_error("factories", e))?;
        }
        Ok(PreparedScene {
            world,
            geometry_names,
            duration: self.duration,
            time_step,
            time_step_warning,
        })
    }
}

fn check_positive(path: &str, value: f64) -> Result<(), SceneError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(scene_error(
            path,
            format!("must be a positive number, got {value}"),
        ))
    }
}

fn check_domain(domain: &Domain) -> Result<(), SceneError> {
    for (axis, (lo, hi)) in ["x", "y", "z"]
        .iter()
        .zip(domain.min.iter().zip(domain.max.iter()))
    {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(scene_error(
                format!("domain.max.{axis}"),
                format!("must be finite and greater than domain.min.{axis} ({lo}), got {hi}"),
            ));
        }
    }
    Ok(())
}
