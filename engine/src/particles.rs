//! Particle state as a structure of arrays.
//!
//! Each hot loop touches only the arrays it needs (the neighbour build reads positions and
//! radii; the contact loop positions, velocities, radii, masses, materials), which keeps the
//! memory traffic per particle low and the arrays streamable. Particles are spheres: their
//! orientation never enters the contact law, so it is not tracked.

use serde::{Deserialize, Serialize};

use crate::material::MaterialId;
use crate::math::Vec3;

/// The index of a particle at the last neighbour build, or this marker if it was added since.
pub(crate) const NEW_PARTICLE: u32 = u32::MAX;

/// A particle to be added to a world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParticleSpec {
    pub position: Vec3,
    pub velocity: Vec3,
    pub angular_velocity: Vec3,
    /// Radius, m.
    pub radius: f64,
    pub material: MaterialId,
}

impl ParticleSpec {
    /// A particle at rest.
    pub fn at_rest(position: Vec3, radius: f64, material: MaterialId) -> ParticleSpec {
        ParticleSpec {
            position,
            velocity: Vec3::zeros(),
            angular_velocity: Vec3::zeros(),
            radius,
            material,
        }
    }
}

/// Structure-of-arrays particle storage. Index `k` refers to the same particle in every array;
/// indices change when particles are removed or re-sorted, `id` never does.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Particles {
    /// Persistent identity, unique within a world, assigned in creation order.
    pub id: Vec<u64>,
    pub position: Vec<Vec3>,
    pub velocity: Vec<Vec3>,
    pub angular_velocity: Vec<Vec3>,
    /// Force and torque of the last force evaluation (N, N·m). CDT rolling friction is not in
    /// `torque`: it brakes the spin in the integration (`world::kernel::rolling_brake`).
    pub force: Vec<Vec3>,
    pub torque: Vec<Vec3>,
    pub radius: Vec<f64>,
    pub mass: Vec<f64>,
    /// 1 / I with I = 2/5 m R² (solid sphere).
    pub inverse_inertia: Vec<f64>,
    pub material: Vec<MaterialId>,
    /// Where each particle was at the last neighbour build and how far it may move before
    /// the pair list is stale (its own half skin).
    pub(crate) build_mark: Vec<BuildMark>,
    /// Index at the last neighbour build, or [`NEW_PARTICLE`]: lets the rebuild find each
    /// particle's previous contact histories after removal and re-sorting.
    pub(crate) index_at_build: Vec<u32>,
    /// Contact histories of this particle with geometries (usually empty: no allocation).
    pub(crate) wall_history: Vec<Vec<WallHistory>>,
}

/// Contact history of one particle-geometry contact. The owning triangle changes as a sphere
/// slides across a mesh, so the history is matched from step to step by geometry and by the
/// nearest previous contact normal instead.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) struct WallHistory {
    pub geometry: u32,
    pub normal: Vec3,
    pub tangential: Vec3,
    pub rolling: Vec3,
}

impl Particles {
    pub fn len(&self) -> usize {
        self.id.len()
    }

    pub fn is_empty(&self) -> bool {
        self.id.is_empty()
    }

    pub(crate) fn push(&mut self, id: u64, spec: &ParticleSpec, density: f64) {
        let mass = density * 4.0 / 3.0 * std::f64::consts::PI * spec.radius.powi(3);
        self.id.push(id);
        self.position.push(spec.position);
        self.velocity.push(spec.velocity);
        self.angular_velocity.push(spec.angular_velocity);
        self.force.push(Vec3::zeros());
        self.torque.push(Vec3::zeros());
        self.radius.push(spec.radius);
        self.mass.push(mass);
        self.inverse_inertia
            .push(1.0 / (0.4 * mass * spec.radius * spec.radius));
        self.material.push(spec.material);
        self.build_mark.push(BuildMark {
            position: single(spec.position),
            half_skin: 0.0,
        });
        self.index_at_build.push(NEW_PARTICLE);
        self.wall_history.push(Vec::new());
    }

    /// Reorder (and drop) particles: afterwards particle `k` is the former particle
    /// `order[k]`. Deterministic; used for removal (compaction keeping relative order) and for
    /// spatial sorting.
    pub(crate) fn permute(&mut self, order: &[u32]) {
        fn apply<T: Copy>(v: &mut Vec<T>, order: &[u32]) {
            let permuted: Vec<T> = order.iter().map(|&k| v[k as usize]).collect();
            *v = permuted;
        }
        apply(&mut self.id, order);
        apply(&mut self.position, order);
        apply(&mut self.velocity, order);
        apply(&mut self.angular_velocity, order);
        apply(&mut self.force, order);
        apply(&mut self.torque, order);
        apply(&mut self.radius, order);
        apply(&mut self.mass, order);
        apply(&mut self.inverse_inertia, order);
        apply(&mut self.material, order);
        apply(&mut self.build_mark, order);
        apply(&mut self.index_at_build, order);
        let mut old = std::mem::take(&mut self.wall_history);
        self.wall_history = order
            .iter()
            .map(|&k| std::mem::take(&mut old[k as usize]))
            .collect();
    }

    /// Kinetic energy (translational + rotational), J.
    pub fn kinetic_energy(&self) -> f64 {
        (0..self.len())
            .map(|k| {
                0.5 * self.mass[k] * self.velocity[k].norm_squared()
                    + 0.5 * self.angular_velocity[k].norm_squared() / self.inverse_inertia[k]
            })
            .sum()
    }

    /// Translational kinetic energy alone (½ m v²), J: what moves grains. A grain spinning on
    /// its spot carries rotational energy without moving anything (see the angle-of-repose rest
    /// rule, which tests this part).
    pub fn translational_kinetic_energy(&self) -> f64 {
        (0..self.len())
            .map(|k| 0.5 * self.mass[k] * self.velocity[k].norm_squared())
            .sum()
    }

    /// Total linear momentum, kg·m/s.
    pub fn momentum(&self) -> Vec3 {
        (0..self.len()).fold(Vec3::zeros(), |acc, k| {
            acc + self.velocity[k] * self.mass[k]
        })
    }

    /// Index of the particle with persistent id `id` (linear search).
    pub fn index_of(&self, id: u64) -> Option<usize> {
        self.id.iter().position(|&x| x == id)
    }

    /// Approximate heap bytes held by the arrays (lengths, not capacities).
    pub fn memory_bytes(&self) -> usize {
        self.len()
            * (8 + 5 * std::mem::size_of::<Vec3>()
                + 3 * 8
                + std::mem::size_of::<MaterialId>()
                + std::mem::size_of::<BuildMark>()
                + 4
                + std::mem::size_of::<Vec<WallHistory>>())
            + self
                .wall_history
                .iter()
                .map(|w| w.len() * std::mem::size_of::<WallHistory>())
                .sum::<usize>()
    }
}

/// A particle's state at the last neighbour build: its position, and its half skin h (it may
/// move up to h before the list is stale). Each particle has its own skin, chosen from its
/// speed: the list holds a pair whose surfaces are closer than h_i + h_j, so the gap of a pair
/// left out cannot close while both particles stay within their half skins. A fast stream
/// then gets wide skins (few rebuilds) while the settled bed it falls on keeps thin ones (few
/// listed pairs). Single precision is plenty (its rounding, ~1e-7 of the coordinates, is far
/// below any skin), and the pair test uses the same rounded h as the move test.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct BuildMark {
    pub position: [f32; 3],
    pub half_skin: f32,
}

impl BuildMark {
    /// Whether a particle now at `x` has moved further than its half skin since the build.
    #[inline]
    pub fn moved_too_far(&self, x: Vec3) -> bool {
        let h = self.half_skin as f64;
        (x - double(self.position)).norm_squared() > h * h
    }
}

/// A position rounded to single precision (for the skin bookkeeping).
#[inline]
pub(crate) fn single(p: Vec3) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

/// Back to double precision.
#[inline]
pub(crate) fn double(p: [f32; 3]) -> Vec3 {
    Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}
