//! The triaxial rig: a world without gravity between six flat walls (x−, x+, y−, y+ and the
//! platens z−, z+), frictionless and moved along their normals only, and the servo that drives
//! them toward a stress ([`Servo`], [`consolidate`]); each wall's stress is the grains' force
//! on it along its normal over the face it bounds.

use std::time::Instant;

use repose_engine::distribution::SizeDistribution;
use repose_engine::kinematics::Motion;
use repose_engine::material::{rayleigh_time, Interaction, MaterialId, MaterialTable};
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::TriMesh;
use repose_engine::neighbor::Domain;
use repose_engine::world::{Geometry, GeometryId, World, WorldConfig};

use super::spec::TriaxialSpec;
use crate::backend::{advance_exactly, Backend};
use crate::progress::{Control, Progress};
use crate::soil::OnBedError;

/// Materials, grain sizes and time step of a world with `soil_soil` between the grains.
pub(super) struct Setup {
    pub table: MaterialTable,
    pub soil: MaterialId,
    pub steel: MaterialId,
    pub size: SizeDistribution,
    pub dt: f64,
    pub density: f64,
}

pub(super) fn setup(spec: &TriaxialSpec, soil_soil: Interaction) -> Result<Setup, OnBedError> {
    use crate::Spec;
    spec.validate()?;
    let table = spec
        .materials
        .material_set(soil_soil, spec.walls())
        .build()
        .map_err(|e| OnBedError::build("materials", e))?;
    let soil = table.id("soil").expect("the paper set has soil");
    let steel = table.id("steel").expect("the paper set has steel");
    let size = SizeDistribution::new(spec.particle.clone())
        .map_err(|e| OnBedError::build("particle", e))?;
    let dt =
        spec.time_step_rayleigh_fraction * rayleigh_time(size.min_radius(), table.material(soil));
    let density = table.material(soil).density;
    Ok(Setup {
        table,
        soil,
        steel,
        size,
        dt,
        density,
    })
}

/// The six walls: `lo` and `hi` are the box's faces (x−, y−, z− and x+, y+, z+).
#[derive(Debug, Clone, Copy)]
pub(super) struct Walls {
    pub ids: [GeometryId; 6],
}

/// The axis of wall `k` (0: x, 1: y, 2: z) and its side (−1: the lower face, +1: the upper).
fn axis_side(k: usize) -> (usize, f64) {
    (k / 2, if k % 2 == 0 { -1.0 } else { 1.0 })
}

/// A flat square of half-sizes `half[b]`, `half[c]` across axis `a`, centred on the origin.
fn wall_mesh(a: usize, half: Vec3) -> Result<TriMesh, OnBedError> {
    let (b, c) = ((a + 1) % 3, (a + 2) % 3);
    let vertices = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
        .iter()
        .map(|&(u, v)| {
            let mut p = Vec3::zeros();
            p[b] = u * half[b];
            p[c] = v * half[c];
            p
        })
        .collect();
    TriMesh::new(vertices, vec![[0, 1, 2], [0, 2, 3]]).map_err(|e| OnBedError::build("walls", e))
}

/// A world without gravity, its grains none yet, its six walls on the faces of the box
/// `lo`..`hi`, each as large as `domain` across (so the walls close the box at any size it
/// takes inside the domain).
pub(super) fn box_world(
    spec: &TriaxialSpec,
    s: &Setup,
    lo: Vec3,
    hi: Vec3,
    domain: (Vec3, Vec3),
    seed: u64,
) -> Result<(World, Walls), OnBedError> {
    let mut config = WorldConfig::new(s.dt, Domain::closed(domain.0, domain.1));
    config.gravity = Vec3::zeros();
    config.rolling_model = spec.engine_rolling_model();
    config.seed = seed;
    let mut world =
        World::new(s.table.clone(), config).map_err(|e| OnBedError::build("world", e))?;
    let centre = 0.5 * (domain.0 + domain.1);
    let half = 0.5 * (domain.1 - domain.0);
    let mut ids = [GeometryId(0); 6];
    for (k, id) in ids.iter_mut().enumerate() {
        let (a, side) = axis_side(k);
        let mut at = centre;
        at[a] = if side < 0.0 { lo[a] } else { hi[a] };
        *id = world
            .add_geometry(Geometry {
                name: ["x-", "x+", "y-", "y+", "z-", "z+"][k].into(),
                mesh: wall_mesh(a, half)?,
                motion: Motion::stationary(Pose::translation(at.x, at.y, at.z)),
                material: s.steel,
            })
            .map_err(|e| OnBedError::build("walls", e))?;
    }
    Ok((world, Walls { ids }))
}

/// Where the walls are and what they carry, read once per control interval.
pub(super) struct WallState {
    pub lo: Vec3,
    pub hi: Vec3,
    /// Each wall's stress (force along its outward normal over its face), Pa.
    pub stress: [f64; 6],
}

impl WallState {
    pub fn size(&self) -> Vec3 {
        self.hi - self.lo
    }

    pub fn volume(&self) -> f64 {
        let l = self.size();
        l.x * l.y * l.z
    }

    pub fn lateral(&self) -> f64 {
        self.stress[..4].iter().sum::<f64>() / 4.0
    }

    pub fn axial(&self) -> f64 {
        0.5 * (self.stress[4] + self.stress[5])
    }
}

/// The servo: each wall's filtered stress and the motion it sets.
pub(super) struct Servo<'a> {
    spec: &'a TriaxialSpec,
    walls: Walls,
    filtered: [f64; 6],
    smoothing: f64,
    pub steps_per_control: u64,
    pub control_time: f64,
}

impl<'a> Servo<'a> {
    pub fn new(spec: &'a TriaxialSpec, walls: Walls, dt: f64) -> Servo<'a> {
        let steps_per_control = ((spec.servo.interval / dt).round() as u64).max(1);
        let control_time = steps_per_control as f64 * dt;
        Servo {
            spec,
            walls,
            filtered: [0.0; 6],
            smoothing: (control_time / spec.servo.filter_time).min(1.0),
            steps_per_control,
            control_time,
        }
    }

    /// The walls' positions now and their mean stresses since the last call.
    pub fn read(&mut self, backend: &mut dyn Backend) -> Result<WallState, OnBedError> {
        let time = backend.time();
        let (mut lo, mut hi) = (Vec3::zeros(), Vec3::zeros());
        for (k, id) in self.walls.ids.iter().enumerate() {
            let (a, side) = axis_side(k);
            let at = backend.geometries()[id.0 as usize]
                .motion
                .pose_at(time)
                .translation
                .vector[a];
            if side < 0.0 {
                lo[a] = at;
            } else {
                hi[a] = at;
            }
        }
        let size = hi - lo;
        let mut stress = [0.0; 6];
        for (k, id) in self.walls.ids.iter().enumerate() {
            let (a, side) = axis_side(k);
            let series = backend.geometry_series(*id)?;
            let force = if series.is_empty() {
                0.0
            } else {
                series.iter().map(|s| s.force[a]).sum::<f64>() / series.len() as f64
            };
            let face = size[(a + 1) % 3] * size[(a + 2) % 3];
            stress[k] = side * force / face;
            self.filtered[k] += self.smoothing * (stress[k] - self.filtered[k]);
        }
        backend.clear_geometry_series();
        Ok(WallState { lo, hi, stress })
    }

    /// Whether every servo wall's filtered stress is within the tolerance of `target` (Pa).
    fn within(&self, target: f64, walls: usize) -> bool {
        self.filtered[..walls]
            .iter()
            .all(|s| ((s - target) / target).abs() <= self.spec.consolidation.tolerance)
    }

    /// Gives the first `servo_walls` walls the speed that moves their stress toward `target`
    /// (Pa), and the others (the platens while loading) `platen_rate` (1/s of the height,
    /// closing).
    pub fn drive(
        &self,
        backend: &mut dyn Backend,
        state: &WallState,
        target: f64,
        servo_walls: usize,
        platen_rate: f64,
    ) -> Result<(), OnBedError> {
        let servo = &self.spec.servo;
        let size = state.size();
        let time = backend.time();
        for (k, id) in self.walls.ids.iter().enumerate() {
            let (a, side) = axis_side(k);
            let rate = if k < servo_walls {
                (servo.gain * (target - self.filtered[k]) / target)
                    .clamp(-servo.max_strain_rate, servo.max_strain_rate)
            } else {
                platen_rate
            };
            let mut velocity = Vec3::zeros();
            velocity[a] = -side * 0.5 * rate * size[a];
            let pose = backend.geometries()[id.0 as usize].motion.pose_at(time);
            let motion = Motion::translating(pose, velocity, time)
                .map_err(|e| OnBedError::build("servo", e))?;
            backend.set_geometry_motion(*id, motion)?;
        }
        Ok(())
    }
}

/// Progress and the wall-time cap, checked once per control interval.
pub(super) fn check(
    spec: &TriaxialSpec,
    backend: &mut dyn Backend,
    started: Instant,
    phase: &'static str,
    fraction: f64,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<(), OnBedError> {
    if progress(Progress {
        fraction: fraction.clamp(0.0, 1.0),
        phase,
        time: backend.time(),
        particles: backend.grain_count()?,
    }) == Control::Cancel
    {
        return Err(OnBedError::Cancelled);
    }
    match spec.wall_time_cap {
        Some(cap) if started.elapsed().as_secs_f64() > cap => {
            Err(OnBedError::WallTimeCap { phase, cap_s: cap })
        }
        _ => Ok(()),
    }
}

/// How a consolidation (or the preparation) ended.
pub(super) struct Held {
    pub consolidated: bool,
    pub state: WallState,
}

/// Drives all six walls toward `target` (Pa) until every one holds it within the tolerance
/// for the hold time, or `time_cap` (s) has passed; `progress` hears the fraction of the cap.
pub(super) fn consolidate(
    spec: &TriaxialSpec,
    servo: &mut Servo<'_>,
    backend: &mut dyn Backend,
    target: f64,
    time_cap: f64,
    progress: &mut dyn FnMut(f64, &mut dyn Backend) -> Result<(), OnBedError>,
) -> Result<Held, OnBedError> {
    let t0 = backend.time();
    let mut held = 0.0;
    backend.clear_geometry_series();
    let mut state = servo.read(backend)?;
    loop {
        servo.drive(backend, &state, target, 6, 0.0)?;
        advance_exactly(backend, servo.steps_per_control)?;
        state = servo.read(backend)?;
        if servo.within(target, 6) {
            held += servo.control_time;
        } else {
            held = 0.0;
        }
        let elapsed = backend.time() - t0;
        progress((elapsed / time_cap).min(1.0), backend)?;
        if held >= spec.consolidation.hold_time {
            return Ok(Held {
                consolidated: true,
                state,
            });
        }
        if elapsed >= time_cap {
            return Ok(Held {
                consolidated: false,
                state,
            });
        }
    }
}
