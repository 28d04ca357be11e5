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

use crate::grid::bin_triangles;
pub use crate::grid::{Grid, Voxel};
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
        let moves = moving_geometries(world, movable)?;
        check_capacity(world, capacity)?;
        let p = world.particles();
        let max_radius = capacity.max_radius;
        let min_radius = p.radius.iter().copied().fold(max_radius, f64::min);
        // One fixed skin (the CPU engine adapts its own per particle): half the CPU's widest,
        // so a settled bed lists few pairs and a pour at ~1 m/s rebuilds every ~10 steps.
        let skin = config.skin_fraction_max * max_radius;
        let grid = Grid::new(world, 2.0 * max_radius + skin)?;
        let pairs = pair_table(world);
        let mesh = Triangles::of(world, &grid, &moves, 1.01 * max_radius)?;
        let slots = capacity.particles;
        let (cell, off, vel, omg) = particle_columns(world, &grid, slots);

        let dt = config.time_step;
        let smooth_cos = repose_engine::mesh::DEFAULT_SMOOTH_ANGLE_DEG
            .to_radians()
            .cos();
        let params = Params {
            n: slots as u32,
            ncells: grid.cells() as u32,
            nmat: world.materials().len() as u32,
            ntris: mesh.tris.len() as u32,
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
            movers: [
                mesh.movers.len() as u32,
                mesh.around_at as u32,
                mesh.vertices as u32,
                0,
            ],
        };
        Ok(Scene {
            grid,
            integrator: config.integrator,
            params,
            cell,
            off,
            vel,
            omg,
            tris: mesh.tris,
            tri_grid: mesh.tri_grid,
            pairs,
            radius: p.radius.clone(),
            movers: mesh.movers,
        })
    }
}

/// Which of `world`'s geometries are moving meshes: those that move and those listed in
/// `movable`. Refuses particle sources, a `movable` index that is not a geometry of the world
/// and more than [`MAX_MOVERS`] moving meshes.
fn moving_geometries(world: &World, movable: &[usize]) -> Result<Vec<bool>, GpuError> {
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
    Ok(moves)
}

/// Refuses a capacity with no slots, fewer slots than `world` has particles, or a largest
/// radius that is not positive or below the world's largest.
fn check_capacity(world: &World, capacity: Capacity) -> Result<(), GpuError> {
    let n = world.particles().len();
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
    Ok(())
}

/// Every material pair's contact constants, row by row (the shader's `pc`).
fn pair_table(world: &World) -> Vec<PairC> {
    let materials = world.materials();
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
    pairs
}

/// The scene's triangles and their lists: the static triangles first, in the world's frame
/// and binned into its voxels; then each moving mesh's in its body frame, binned into its
/// body grid; then the triangles around each welded vertex (`Around`).
struct Triangles {
    tris: Vec<Tri>,
    /// The voxels' lists, each moving mesh's body-grid lists, then `Around`'s.
    tri_grid: Vec<u32>,
    movers: Vec<Mover>,
    /// Where `Around`'s starts begin in `tri_grid`.
    around_at: usize,
    /// Welded vertices.
    vertices: usize,
}

impl Triangles {
    /// `world`'s geometries, those `moves` marks as moving meshes, triangles binned with
    /// `reach`.
    fn of(world: &World, grid: &Grid, moves: &[bool], reach: f64) -> Result<Triangles, GpuError> {
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
        let mut tri_grid = bin_triangles(grid, &corners, reach);
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
        let around_at = tri_grid.len();
        let vertices = around.starts.len() - 1;
        tri_grid.extend_from_slice(&around.starts);
        tri_grid.extend_from_slice(&around.triangles);
        Ok(Triangles {
            tris,
            tri_grid,
            movers,
            around_at,
            vertices,
        })
    }
}

/// The particle buffers' records (`cell`, `off`, `vel`, `omg`) of `slots` slots: `world`'s
/// particles first; the empty slots have material -1 (dead), the rest zero.
type Columns = (Vec<[i32; 4]>, Vec<[f32; 4]>, Vec<[f32; 4]>, Vec<[f32; 4]>);

fn particle_columns(world: &World, grid: &Grid, slots: usize) -> Columns {
    let p = world.particles();
    let mut cell = vec![[0, 0, 0, -1]; slots];
    let mut off = vec![[0.0; 4]; slots];
    let mut vel = vec![[0.0; 4]; slots];
    let mut omg = vec![[0.0; 4]; slots];
    for k in 0..p.len() {
        let (c, o) = grid.to_voxel(p.position[k]);
        cell[k] = [c[0], c[1], c[2], p.material[k].0 as i32];
        off[k] = [o[0], o[1], o[2], p.radius[k] as f32];
        vel[k] = v4(p.velocity[k], p.mass[k] as f32);
        omg[k] = v4(p.angular_velocity[k], p.inverse_inertia[k] as f32);
    }
    (cell, off, vel, omg)
}
