//! The CPU engine's scene as the GPU holds it: positions as integer voxels plus f32 offsets,
//! per-particle records packed in vec4s, the static triangles and the material pair table.
//! Pure data (no device), so the conversion and its precision are tested without a GPU.

use bytemuck::{Pod, Zeroable};
use repose_engine::contact::{CohesionLaw, RollingModel};
use repose_engine::integrate::Integrator;
use repose_engine::material::MaterialId;
use repose_engine::math::Vec3;
use repose_engine::mesh::TriMesh;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::World;

use crate::movers::{bin_body_mesh, Mover, MAX_MOVERS};
use crate::GpuError;

/// Neighbours per particle within the skin (the shader's `CAP`).
pub const NEIGHBOUR_CAPACITY: usize = 32;
/// Particles per grid cell (the shader's `BIN`).
pub const BIN_CAPACITY: usize = 16;
/// Triangle contacts with history per particle (the shader's `WCAP`).
pub const WALL_CAPACITY: usize = 4;
/// Threads per workgroup (the shader's `WG`).
pub const WORKGROUP: u32 = 128;

/// A position as the GPU holds it: an integer voxel and the f32 offset inside it.
pub type Voxel = ([i32; 3], [f32; 3]);

/// The voxel grid: it places positions (integer voxel + offset) and bins the neighbour search.
/// Periodic axes hold a whole number of voxels, so wrapping is an integer operation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub min: Vec3,
    pub voxel: Vec3,
    pub dims: [i32; 3],
    pub periodic: [bool; 2],
}

impl Grid {
    /// A grid over `world`'s domain with voxels at least `min_voxel` wide.
    pub fn new(world: &World, min_voxel: f64) -> Result<Grid, GpuError> {
        let domain = world.config().domain;
        let extent = domain.max - domain.min;
        let periodic = [domain.periodic_x, domain.periodic_y];
        let mut dims = [0i32; 3];
        let mut voxel = Vec3::zeros();
        for a in 0..3 {
            let whole = a < 2 && periodic[a];
            let n = if whole {
                (extent[a] / min_voxel).floor()
            } else {
                (extent[a] / min_voxel).ceil()
            };
            if whole && n < 3.0 {
                return Err(GpuError::Capacity(format!(
                    "a periodic axis holds {n} neighbour cells; at least 3 are needed \
                     (domain {:.4} m, cells {min_voxel:.4} m)",
                    extent[a]
                )));
            }
            if !(1.0..=65_536.0).contains(&n) {
                return Err(GpuError::Capacity(format!(
                    "the domain is {n} neighbour cells along axis {a} (at most 65536)"
                )));
            }
            dims[a] = n as i32;
            voxel[a] = if whole { extent[a] / n } else { min_voxel };
        }
        Ok(Grid {
            min: domain.min,
            voxel,
            dims,
            periodic,
        })
    }

    /// Cells in the grid.
    pub fn cells(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    /// `x` as a voxel and an offset in it (periodic axes wrapped into the grid).
    pub fn to_voxel(&self, x: Vec3) -> Voxel {
        self.voxel_of(x, true)
    }

    /// `x` as a voxel and an offset, not wrapped: geometry stays where it is (a particle
    /// sees a triangle at its place, not at a periodic image).
    pub fn to_voxel_unwrapped(&self, x: Vec3) -> Voxel {
        self.voxel_of(x, false)
    }

    fn voxel_of(&self, x: Vec3, wrap: bool) -> Voxel {
        let mut cell = [0i32; 3];
        let mut offset = [0f32; 3];
        for a in 0..3 {
            let u = x[a] - self.min[a];
            let k = (u / self.voxel[a]).floor();
            let mut o = (u - k * self.voxel[a]) as f32;
            // Rounding to f32 may reach the voxel's far face.
            if o >= self.voxel[a] as f32 {
                o = (self.voxel[a] as f32).next_down_f32();
            }
            let mut k = k as i64;
            if wrap && a < 2 && self.periodic[a] {
                k = k.rem_euclid(self.dims[a] as i64);
            }
            cell[a] = k as i32;
            offset[a] = o.max(0.0);
        }
        (cell, offset)
    }

    /// The position of a voxel and offset, m.
    pub fn to_position(&self, cell: [i32; 3], offset: [f32; 3]) -> Vec3 {
        Vec3::from_fn(|a, _| self.min[a] + cell[a] as f64 * self.voxel[a] + offset[a] as f64)
    }

    /// The vector from `b` to `a` as the shader computes it (minimum image across periodic
    /// faces, integer voxel difference times the voxel plus the offsets' difference, in f32).
    pub fn difference(&self, a: Voxel, b: Voxel) -> [f32; 3] {
        std::array::from_fn(|k| {
            let mut dc = a.0[k] - b.0[k];
            if k < 2 && self.periodic[k] {
                let n = self.dims[k];
                if dc > n / 2 {
                    dc -= n;
                } else if dc < -(n / 2) {
                    dc += n;
                }
            }
            dc as f32 * self.voxel[k] as f32 + (a.1[k] - b.1[k])
        })
    }
}

/// `next_down` for f32 on the toolchains this crate supports.
trait NextDown {
    fn next_down_f32(self) -> f32;
}

impl NextDown for f32 {
    fn next_down_f32(self) -> f32 {
        if self > 0.0 {
            f32::from_bits(self.to_bits() - 1)
        } else {
            self
        }
    }
}

/// The shader's uniform block.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(crate) struct Params {
    pub n: u32,
    pub ncells: u32,
    pub nmat: u32,
    pub ntris: u32,
    pub dims: [i32; 4],
    pub voxel: [f32; 4],
    pub gravity: [f32; 4],
    pub misc: [f32; 4],
    pub misc2: [f32; 4],
    /// Moving geometries (x); where the triangles around each welded vertex start in the
    /// triangle lists (y) and the welded vertices (z); w unused.
    pub movers: [u32; 4],
}

impl Params {
    /// EPSD rolling (a rolling spring per contact) rather than CDT's brake: the shader's
    /// `epsd()`.
    pub fn epsd(&self) -> bool {
        self.misc2[1] == 0.0
    }
}

/// One material pair's contact constants.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(crate) struct PairC {
    pub a: [f32; 4],
    pub b: [f32; 4],
    pub c: [f32; 4],
}

/// One triangle. A static one: its first corner as a voxel and an offset, its two edges and
/// the face normal in the world frame. A moving one ([`crate::movers`]): the corner, edges and
/// normal in its body frame (voxel zero). The offset's w is the triangle's geometry; the w of
/// `e1`, `e2` and `normal` are its three corners' welded vertex ids in the scene (`Around`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(crate) struct Tri {
    pub cell: [i32; 4],
    pub v0: [f32; 4],
    pub e1: [f32; 4],
    pub e2: [f32; 4],
    pub normal: [f32; 4],
}

/// Room for particles inserted during a run, fixed when a [`crate::GpuWorld`] is created: the
/// particle slots and the largest radius (the neighbour grid's voxel and the triangles' reach
/// are sized by it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Capacity {
    pub particles: usize,
    pub max_radius: f64,
}

impl Capacity {
    /// Exactly the world's particles (no insertion beyond reusing removed grains' slots).
    pub fn of(world: &World) -> Capacity {
        let p = world.particles();
        Capacity {
            particles: p.len(),
            max_radius: p.radius.iter().copied().fold(0.0, f64::max),
        }
    }
}

/// The static triangles binned into the neighbour grid's voxels, in one array: `ncells + 1`
/// starts, then the triangle indices (each voxel's ascending). Triangle `t` is listed in voxel
/// `c` iff `t`'s bounding box, grown by the reach, touches `c`.
///
/// One voxel suffices for a grain: a grain of radius r touches a triangle only if its centre
/// lies within r of the triangle, hence inside the triangle's bounding box grown by r; with r
/// no larger than the reach, the voxel holding the centre touches that grown box, so the
/// triangle is listed there. The reach is the largest radius plus 1 % (f32 rounding of the
/// contact test) and the grain's voxel is its current one (updated every step), so no skin.
pub(crate) fn bin_triangles(grid: &Grid, corners: &[[Vec3; 3]], reach: f64) -> Vec<u32> {
    let ncells = grid.cells();
    let range = |corners: &[Vec3; 3]| -> Option<[[i32; 2]; 3]> {
        let mut r = [[0i32; 2]; 3];
        for a in 0..3 {
            let lo = corners.iter().map(|c| c[a]).fold(f64::INFINITY, f64::min) - reach;
            let hi = corners
                .iter()
                .map(|c| c[a])
                .fold(f64::NEG_INFINITY, f64::max)
                + reach;
            let lo = ((lo - grid.min[a]) / grid.voxel[a]).floor().max(0.0);
            let hi = ((hi - grid.min[a]) / grid.voxel[a])
                .floor()
                .min(grid.dims[a] as f64 - 1.0);
            if lo > hi {
                return None; // wholly outside the grid: no grain can reach it
            }
            r[a] = [lo as i32, hi as i32];
        }
        Some(r)
    };
    let index = |x: i32, y: i32, z: i32| (x + grid.dims[0] * (y + grid.dims[1] * z)) as usize;
    let ranges: Vec<_> = corners.iter().map(range).collect();
    let mut count = vec![0u32; ncells + 1];
    for r in ranges.iter().flatten() {
        for z in r[2][0]..=r[2][1] {
            for y in r[1][0]..=r[1][1] {
                for x in r[0][0]..=r[0][1] {
                    count[index(x, y, z) + 1] += 1;
                }
            }
        }
    }
    for c in 0..ncells {
        count[c + 1] += count[c];
    }
    let entries = count[ncells] as usize;
    let mut out = count.clone();
    out.resize(ncells + 1 + entries, 0);
    let mut next = count;
    // Triangles in ascending order: each voxel's list is ascending.
    for (t, r) in ranges.iter().enumerate() {
        let Some(r) = r else { continue };
        for z in r[2][0]..=r[2][1] {
            for y in r[1][0]..=r[1][1] {
                for x in r[0][0]..=r[0][1] {
                    let c = index(x, y, z);
                    out[ncells + 1 + next[c] as usize] = t as u32;
                    next[c] += 1;
                }
            }
        }
    }
    out
}

/// One particle's GPU record: voxel and material, offset and radius, velocity and mass, spin
/// and inverse inertia.
pub(crate) type Record = ([i32; 4], [f32; 4], [f32; 4], [f32; 4]);

/// `spec`'s [`Record`], mass and inertia as the CPU engine sets them (a solid sphere of the
/// material's density).
pub(crate) fn particle_record(grid: &Grid, spec: &ParticleSpec, density: f64) -> Record {
    let mass = density * 4.0 / 3.0 * std::f64::consts::PI * spec.radius.powi(3);
    let inverse_inertia = 1.0 / (0.4 * mass * spec.radius * spec.radius);
    let (c, o) = grid.to_voxel(spec.position);
    (
        [c[0], c[1], c[2], spec.material.0 as i32],
        [o[0], o[1], o[2], spec.radius as f32],
        v4(spec.velocity, mass as f32),
        v4(spec.angular_velocity, inverse_inertia as f32),
    )
}

/// Everything uploaded at the start of a run.
#[derive(Debug, Clone)]
pub(crate) struct Scene {
    pub grid: Grid,
    pub integrator: Integrator,
    pub params: Params,
    pub cell: Vec<[i32; 4]>,
    pub off: Vec<[f32; 4]>,
    pub vel: Vec<[f32; 4]>,
    pub omg: Vec<[f32; 4]>,
    pub tris: Vec<Tri>,
    /// [`bin_triangles`]' voxel lists.
    pub tri_grid: Vec<u32>,
    pub pairs: Vec<PairC>,
    /// The world's particles' radii (not the empty slots').
    pub radius: Vec<f64>,
    /// The moving geometries, in the world's order.
    pub movers: Vec<Mover>,
}

impl Scene {
    /// The shader's pipeline-overridable constants for this scene (1: may happen, 0: cannot):
    /// JKR or linear cohesion in some material pair, EPSD rolling, moving geometries.
    pub fn pipeline_constants(&self) -> [(&'static str, f64); 4] {
        let flag = |b: bool| if b { 1.0 } else { 0.0 };
        [
            ("JKR", flag(self.pairs.iter().any(|p| p.c[0] > 0.0))),
            (
                "LINEAR_COHESION",
                flag(self.pairs.iter().any(|p| p.b[2] > 0.0)),
            ),
            ("EPSD", flag(self.params.epsd())),
            ("MOVERS", flag(!self.movers.is_empty())),
        ]
    }
}

/// The linear (SJKR) cohesion's energy density k, J/m³, for the shader (0: none).
fn linear_cohesion(law: CohesionLaw) -> f32 {
    match law {
        CohesionLaw::Linear { energy_density } => energy_density as f32,
        CohesionLaw::None | CohesionLaw::Jkr { .. } => 0.0,
    }
}

/// JKR's surface energy γ (J/m², 0: none) and length 2 π γ / E* (m), for the shader.
fn jkr_cohesion(law: CohesionLaw) -> [f32; 4] {
    match law {
        CohesionLaw::Jkr {
            surface_energy,
            length,
        } => [surface_energy as f32, length as f32, 0.0, 0.0],
        CohesionLaw::None | CohesionLaw::Linear { .. } => [0.0; 4],
    }
}

/// Vertex ids a triangle record can carry exactly (as f32 integers).
const MAX_VERTICES: usize = 1 << 24;

/// The scene's welded vertices and the triangles around each, over all its meshes (each mesh's
/// vertices numbered after the previous mesh's, its triangles by their index in the scene's
/// triangle records): what the shader's local-minimum test walks (`is_local_minimum`).
/// `starts[v]..starts[v + 1]` index `triangles`.
struct Around {
    starts: Vec<u32>,
    triangles: Vec<u32>,
}

impl Default for Around {
    fn default() -> Around {
        Around {
            starts: vec![0],
            triangles: Vec::new(),
        }
    }
}

impl Around {
    /// Adds `mesh`, its triangles recorded from `first_triangle` on; returns each triangle's
    /// welded corners as scene vertex ids (f32 integers, as the triangle records carry them).
    fn add(&mut self, mesh: &TriMesh, first_triangle: usize) -> Result<Vec<[f32; 3]>, GpuError> {
        let base = self.starts.len() - 1;
        let count = mesh.welded_vertex_count();
        if base + count > MAX_VERTICES || first_triangle + mesh.normals().len() > MAX_VERTICES {
            return Err(GpuError::Capacity(format!(
                "more than {MAX_VERTICES} mesh vertices or triangles in the scene"
            )));
        }
        for v in 0..count {
            let around = mesh.triangles_around(v as u32);
            self.triangles
                .extend(around.iter().map(|&t| first_triangle as u32 + t));
            self.starts.push(self.triangles.len() as u32);
        }
        Ok((0..mesh.normals().len())
            .map(|t| mesh.welded_corners(t).map(|v| (base + v as usize) as f32))
            .collect())
    }
}

fn v4(v: Vec3, w: f32) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w]
}

impl Scene {
    /// The GPU form of `world` now, with room for `capacity` (slots past the world's
    /// particles are empty). The geometries that move, and those listed in `movable` (indices
    /// into the world's geometries, still or not), are moving meshes ([`crate::movers`]); the
    /// others are baked into the voxels. Refuses what this backend does not simulate yet
    /// (particle sources), naming it, a `movable` index that is not a geometry of the world,
    /// and more than [`MAX_MOVERS`] moving meshes.
    pub fn from_world(
        world: &World,
        capacity: Capacity,
        movable: &[usize],
    ) -> Result<Scene, GpuError> {
        let config = world.config();
        let materials = world.materials();
        if world.sources().next().is_some() {
            return Err(GpuError::Unsupported("particle factories (sources)".into()));
        }
        let geometries = world.geometries().len();
        if let Some(&index) = movable.iter().find(|&&g| g >= geometries) {
            return Err(GpuError::Invalid(format!(
                "movable geometry {index}: the world has {geometries} geometries"
            )));
        }
        let moves: Vec<bool> = world
            .geometries()
            .iter()
            .enumerate()
            .map(|(index, g)| !g.motion.is_stationary() || movable.contains(&index))
            .collect();
        let moving = moves.iter().filter(|&&m| m).count();
        if moving > MAX_MOVERS {
            return Err(GpuError::Capacity(format!(
                "{moving} moving or movable geometries (at most {MAX_MOVERS})"
            )));
        }
        let p = world.particles();
        let n = p.len();
        let world_max = Capacity::of(world).max_radius;
        if capacity.particles == 0 {
            return Err(GpuError::Capacity(
                "the world has no particles and no room for any".into(),
            ));
        }
        if capacity.particles < n {
            return Err(GpuError::Capacity(format!(
                "the world has {n} particles, more than the capacity of {}",
                capacity.particles
            )));
        }
        if !(capacity.max_radius > 0.0 && capacity.max_radius.is_finite())
            || capacity.max_radius < world_max
        {
            return Err(GpuError::Capacity(format!(
                "the capacity's largest radius {} m is not positive or below the world's \
                 largest, {world_max} m",
                capacity.max_radius
            )));
        }
        let max_radius = capacity.max_radius;
        let min_radius = p.radius.iter().copied().fold(max_radius, f64::min);
        // One fixed skin (the CPU engine adapts its own per particle): half the CPU's widest,
        // so a settled bed lists few pairs and a pour at ~1 m/s rebuilds every ~10 steps.
        let skin = config.skin_fraction_max * max_radius;
        let grid = Grid::new(world, 2.0 * max_radius + skin)?;
        let nmat = materials.len();
        let mut pairs = Vec::with_capacity(nmat * nmat);
        for a in 0..nmat {
            for b in 0..nmat {
                let c = materials.pair(MaterialId(a as u16), MaterialId(b as u16));
                pairs.push(PairC {
                    a: [
                        c.e_star as f32,
                        c.g_star as f32,
                        c.beta as f32,
                        c.tangential_to_normal_damping as f32,
                    ],
                    b: [
                        c.static_friction as f32,
                        c.rolling_friction as f32,
                        linear_cohesion(c.cohesion),
                        0.0,
                    ],
                    c: jkr_cohesion(c.cohesion),
                });
            }
        }
        // The static triangles first, in the world's frame and binned into its voxels; then
        // each moving mesh's in its body frame, binned into its body grid.
        let reach = 1.01 * max_radius;
        let mut tris = Vec::new();
        let mut corners = Vec::new();
        let mut around = Around::default();
        for (index, g) in world.geometries().iter().enumerate() {
            if moves[index] {
                continue;
            }
            let pose = g.motion.pose_at(world.time());
            let ids = around.add(&g.mesh, tris.len())?;
            for (t, normal) in g.mesh.normals().iter().enumerate() {
                let [a, b, c] = g
                    .mesh
                    .corners(t)
                    .map(|v| pose.transform_point(&v.into()).coords);
                corners.push([a, b, c]);
                let (cell, v0) = grid.to_voxel_unwrapped(a);
                let [ia, ib, ic] = ids[t];
                tris.push(Tri {
                    cell: [cell[0], cell[1], cell[2], g.material.0 as i32],
                    v0: [v0[0], v0[1], v0[2], index as f32],
                    e1: v4(b - a, ia),
                    e2: v4(c - a, ib),
                    normal: v4(pose.rotation * normal, ic),
                });
            }
        }
        let mut tri_grid = bin_triangles(&grid, &corners, reach);
        let mut movers = Vec::new();
        for (index, g) in world.geometries().iter().enumerate() {
            if !moves[index] {
                continue;
            }
            let body = bin_body_mesh(&g.mesh, grid.voxel.min(), reach, tris.len() as u32)?;
            let ids = around.add(&g.mesh, tris.len())?;
            for (t, normal) in g.mesh.normals().iter().enumerate() {
                let [a, b, c] = g.mesh.corners(t);
                let [ia, ib, ic] = ids[t];
                tris.push(Tri {
                    cell: [0, 0, 0, g.material.0 as i32],
                    v0: v4(a, index as f32),
                    e1: v4(b - a, ia),
                    e2: v4(c - a, ib),
                    normal: v4(*normal, ic),
                });
            }
            movers.push(Mover {
                geometry: index,
                motion: g.motion.clone(),
                grid: body.grid,
                lists_at: tri_grid.len(),
            });
            tri_grid.extend_from_slice(&body.lists);
        }
        // The triangles around each welded vertex, after the lists (`Around`).
        let around_at = tri_grid.len();
        let vertices = around.starts.len() - 1;
        tri_grid.extend_from_slice(&around.starts);
        tri_grid.extend_from_slice(&around.triangles);
        let slots = capacity.particles;
        // Empty slots: material -1 (dead), the rest zero.
        let mut cell = vec![[0, 0, 0, -1]; slots];
        let mut off = vec![[0.0; 4]; slots];
        let mut vel = vec![[0.0; 4]; slots];
        let mut omg = vec![[0.0; 4]; slots];
        for k in 0..n {
            let (c, o) = grid.to_voxel(p.position[k]);
            cell[k] = [c[0], c[1], c[2], p.material[k].0 as i32];
            off[k] = [o[0], o[1], o[2], p.radius[k] as f32];
            vel[k] = v4(p.velocity[k], p.mass[k] as f32);
            omg[k] = v4(p.angular_velocity[k], p.inverse_inertia[k] as f32);
        }

        let dt = config.time_step;
        let smooth_cos = repose_engine::mesh::DEFAULT_SMOOTH_ANGLE_DEG
            .to_radians()
            .cos();
        let params = Params {
            n: slots as u32,
            ncells: grid.cells() as u32,
            nmat: nmat as u32,
            ntris: tris.len() as u32,
            dims: [
                grid.dims[0],
                grid.dims[1],
                grid.dims[2],
                grid.periodic[0] as i32 | (grid.periodic[1] as i32) << 1,
            ],
            voxel: v4(grid.voxel, 0.0),
            gravity: v4(config.gravity, dt as f32),
            misc: [dt as f32, 0.5 * skin as f32, skin as f32, smooth_cos as f32],
            misc2: match config.rolling_model {
                RollingModel::ConstantDirectionalTorque => {
                    [1e-3 * min_radius as f32, 1.0, 0.0, 0.0]
                }
                RollingModel::ElasticPlasticSpringDashpot { viscous_damping } => {
                    [1e-3 * min_radius as f32, 0.0, viscous_damping as f32, 0.0]
                }
            },
            movers: [movers.len() as u32, around_at as u32, vertices as u32, 0],
        };
        Ok(Scene {
            grid,
            integrator: config.integrator,
            params,
            cell,
            off,
            vel,
            omg,
            tris,
            tri_grid,
            pairs,
            radius: p.radius.clone(),
            movers,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use repose_engine::material::{Interaction, MaterialSet};
    use repose_engine::neighbor::Domain;
    use repose_engine::world::WorldConfig;

    fn grid(periodic: bool) -> Grid {
        let materials = MaterialSet::paper(
            Interaction::new(0.5, 0.5, 0.1),
            Interaction::new(0.5, 0.5, 0.1),
        )
        .build()
        .unwrap();
        let mut domain = Domain::closed(Vec3::zeros(), Vec3::repeat(0.3));
        domain.periodic_x = periodic;
        domain.periodic_y = periodic;
        let world = World::new(materials, WorldConfig::new(1e-6, domain)).unwrap();
        Grid::new(&world, 2.75e-3).unwrap()
    }

    #[test]
    fn an_overlap_of_a_thousandth_of_a_radius_is_resolved_anywhere_in_a_03_m_domain() {
        let r = 1.0e-3;
        let overlap = 1e-3 * r;
        for periodic in [false, true] {
            let g = grid(periodic);
            for corner in [0.001, 0.15, 0.2987] {
                for axis in 0..3 {
                    let a = Vec3::repeat(corner);
                    let mut b = a;
                    b[axis] += 2.0 * r - overlap;
                    let d = g.difference(g.to_voxel(b), g.to_voxel(a));
                    let dist = (d[0] as f64).hypot(d[1] as f64).hypot(d[2] as f64);
                    let error = ((2.0 * r - dist) - overlap).abs();
                    // Plain f32 positions near 0.3 m are spaced 3e-8 m: 3 % of this overlap.
                    assert!(
                        error < 1e-3 * overlap,
                        "at {corner} m along {axis}: overlap error {error:e} m"
                    );
                }
            }
        }
    }

    #[test]
    fn positions_round_trip_through_voxels_to_the_offsets_resolution() {
        let g = grid(false);
        for x in [0.0, 1e-9, 0.123_456_789, 0.299_999] {
            let p = Vec3::new(x, 0.3 - x, x / 2.0);
            let (c, o) = g.to_voxel(p);
            let back = g.to_position(c, o);
            assert!((back - p).norm() < 1e-9, "{p:?} -> {back:?}");
            assert!(o
                .iter()
                .zip(g.voxel.iter())
                .all(|(&o, &v)| o >= 0.0 && (o as f64) < v));
        }
    }

    /// Every point within the reach of a triangle (a point of the triangle plus an offset no
    /// longer than the reach) lies in a voxel that lists the triangle; each voxel's list is
    /// ascending and a triangle outside the grid is in none.
    #[test]
    fn a_voxel_lists_every_triangle_within_reach_of_its_points() {
        let g = grid(false);
        let reach = 1.0e-3;
        let corners = vec![
            // flat, small; slanted across many voxels; a sliver; one wholly outside the grid
            [
                Vec3::new(0.1, 0.1, 0.05),
                Vec3::new(0.104, 0.1, 0.05),
                Vec3::new(0.1, 0.103, 0.05),
            ],
            [
                Vec3::new(0.02, 0.03, 0.01),
                Vec3::new(0.05, 0.02, 0.04),
                Vec3::new(0.03, 0.06, 0.02),
            ],
            [
                Vec3::new(0.2, 0.2, 0.2),
                Vec3::new(0.2101, 0.2, 0.2),
                Vec3::new(0.21, 0.2, 0.2001),
            ],
            [
                Vec3::new(0.5, 0.5, 0.5),
                Vec3::new(0.6, 0.5, 0.5),
                Vec3::new(0.5, 0.6, 0.5),
            ],
        ];
        let lists = bin_triangles(&g, &corners, reach);
        let ncells = g.cells();
        let listed = |c: [i32; 3]| -> &[u32] {
            let v = (c[0] + g.dims[0] * (c[1] + g.dims[1] * c[2])) as usize;
            &lists[ncells + 1 + lists[v] as usize..ncells + 1 + lists[v + 1] as usize]
        };
        for v in 0..ncells {
            let l = &lists[ncells + 1 + lists[v] as usize..ncells + 1 + lists[v + 1] as usize];
            assert!(l.windows(2).all(|w| w[0] < w[1]), "voxel {v}: {l:?}");
            assert!(!l.contains(&3), "the triangle outside the grid is listed");
        }
        let mut state = 12345u64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for (t, [a, b, c]) in corners.iter().take(3).enumerate() {
            for _ in 0..2000 {
                let (mut u, mut v) = (uniform(), uniform());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let on = a + (b - a) * u + (c - a) * v;
                let dir = Vec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.5);
                let p = on + dir.normalize() * (reach * uniform().sqrt());
                let (cell, _) = g.to_voxel(p);
                assert!(
                    listed(cell).contains(&(t as u32)),
                    "triangle {t} not listed at {p:?} (voxel {cell:?})"
                );
            }
        }
    }

    #[test]
    fn periodic_axes_wrap_positions_and_take_the_minimum_image() {
        let g = grid(true);
        let (c, _) = g.to_voxel(Vec3::new(-0.001, 0.301, 0.1));
        assert!(c[0] == g.dims[0] - 1 && c[1] == 0, "{c:?}");
        let a = g.to_voxel(Vec3::new(0.0005, 0.1, 0.1));
        let b = g.to_voxel(Vec3::new(0.2995, 0.1, 0.1));
        let d = g.difference(a, b);
        assert!((d[0] as f64 - 0.001).abs() < 1e-9, "{d:?}");
    }
}
