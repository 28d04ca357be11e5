//! Moving geometries on the GPU: a rigid mesh driven by a [`Motion`] (translations and a turn
//! about one body axis: the lifted cylinder's tube, an auger).
//!
//! A moving mesh's triangles stay in its body frame and are binned once, on the host, into a
//! grid of that frame ([`BodyGrid`]). Before each force evaluation the host evaluates the
//! motion at the evaluation's time in f64 (the CPU engine's [`Motion::pose_at`] and velocities)
//! and hands the shader a [`MoverFrame`]: the body origin as a voxel and an offset, the
//! rotation, the velocities and the reference point. A grain takes its centre into the body
//! frame (the voxel difference to the origin, rotated), looks up its body-grid cell and tests
//! the triangles listed there, as it tests the static triangles of its own voxel; the contact
//! goes back to the world frame and the wall's velocity at the contact point enters the
//! relative velocity.
//!
//! Precision: the body-frame vector from a triangle's corner to a grain is f32 arithmetic on
//! vectors of the mesh's size (the origin-to-grain vector, the rotation, f32 corners), so it is
//! resolved to about 1e-7 of the distance from the body origin: 1e-8 m at 0.1 m, 1 % of an
//! overlap of a thousandth of a 1 mm radius (static triangles, held as voxels, resolve it to
//! 0.1 %). The test `a_moving_plate_far_from_its_origin_resolves_a_thousandth_of_a_radius`
//! states the figure.

use bytemuck::{Pod, Zeroable};
use repose_engine::kinematics::Motion;
use repose_engine::math::Vec3;
use repose_engine::mesh::TriMesh;

use crate::grid::{bin_triangles, Grid};
use crate::GpuError;

/// Moving geometries a scene may hold (the shader's `MAX_MOVERS`).
pub const MAX_MOVERS: usize = 8;
/// Cells a moving geometry's body grid may have.
const MAX_BODY_CELLS: usize = 1 << 23;

/// One moving geometry as the shader sees it at one force evaluation.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default)]
pub(crate) struct MoverFrame {
    /// The body origin's voxel; w: where the geometry's body grid starts in the triangle lists.
    pub cell: [i32; 4],
    /// The body origin's offset in its voxel; w: the body grid's cell edge, m.
    pub off: [f32; 4],
    /// The rows of the body-to-world rotation.
    pub rot: [[f32; 4]; 3],
    /// Linear velocity, m/s.
    pub vel: [f32; 4],
    /// Angular velocity, rad/s.
    pub spin: [f32; 4],
    /// The reference point (about which the geometry turns) less the body origin, world frame.
    pub lever: [f32; 4],
    /// The body grid's low corner in the body frame; w: the geometry's index in the world.
    pub grid_min: [f32; 4],
    /// The body grid's cells per axis.
    pub grid_dims: [i32; 4],
}

/// A slab whose contacts' stress sums a force evaluation writes (`GpuWorld::run_sampling_slab`),
/// as the shader sees it: its low corner as a voxel and an offset (so a grain's height above
/// it is exact to the offsets' resolution) and its extent.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default)]
pub(crate) struct SlabFrame {
    /// The voxel of the corner (x0, y0, z0), not wrapped.
    pub cell: [i32; 4],
    /// The corner's offset in its voxel.
    pub off: [f32; 4],
    /// x1 - x0, y1 - y0, z1 - z0, m.
    pub size: [f32; 4],
}

/// The frames of one force evaluation: the shader's uniform block (one per evaluation of a
/// submission, at a dynamic offset).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(crate) struct Frames {
    /// x: the load record this evaluation writes (-1: none); y: 1 where this evaluation
    /// writes the slab's stress sums; the rest unused.
    pub head: [i32; 4],
    pub movers: [MoverFrame; MAX_MOVERS],
    /// The slab sampled where `head.y` is 1.
    pub slab: SlabFrame,
    /// To a multiple of 256 bytes (uniform offsets' alignment).
    pub pad: [[u32; 4]; 12],
}

/// A body-frame grid: cells of `edge` from `min`, `dims` per axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BodyGrid {
    pub min: Vec3,
    pub edge: f64,
    pub dims: [i32; 3],
}

impl BodyGrid {
    fn as_grid(&self) -> Grid {
        Grid {
            min: self.min,
            voxel: Vec3::repeat(self.edge),
            dims: self.dims,
            periodic: [false, false],
        }
    }

    pub fn cells(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }
}

/// A moving geometry of the scene: its motion, its body grid and where its lists start.
#[derive(Debug, Clone)]
pub(crate) struct Mover {
    /// The geometry's index in the world.
    pub geometry: usize,
    pub motion: Motion,
    pub grid: BodyGrid,
    /// Where its body grid's starts begin in the triangle lists (`tgrid`).
    pub lists_at: usize,
}

/// A moving mesh's triangles in its body frame (as [`crate::scene::Tri`] records: corner,
/// edges, normal, all f32 in the body frame) and its binned lists, triangle indices offset by
/// `first_triangle`.
pub(crate) struct BodyMesh {
    pub grid: BodyGrid,
    /// `grid.cells() + 1` starts, then the triangle indices.
    pub lists: Vec<u32>,
}

/// Bins `mesh`'s triangles into a body-frame grid of cells of `edge` around it, each listed in
/// every cell its bounding box grown by `reach` touches (as the static triangles are binned
/// into the world's voxels). A grain of radius up to `reach` that touches a triangle has its
/// body-frame centre in a cell listing it.
pub(crate) fn bin_body_mesh(
    mesh: &TriMesh,
    edge: f64,
    reach: f64,
    first_triangle: u32,
) -> Result<BodyMesh, GpuError> {
    let (lo, hi) = mesh.aabb();
    let min = lo - Vec3::repeat(reach);
    let mut dims = [0i32; 3];
    for a in 0..3 {
        dims[a] = ((hi[a] + reach - min[a]) / edge).floor() as i32 + 1;
    }
    let grid = BodyGrid { min, edge, dims };
    if grid.cells() > MAX_BODY_CELLS {
        return Err(GpuError::Capacity(format!(
            "a moving mesh spans {} cells of {edge} m (at most {MAX_BODY_CELLS})",
            grid.cells()
        )));
    }
    let corners: Vec<[Vec3; 3]> = (0..mesh.normals().len()).map(|t| mesh.corners(t)).collect();
    let mut lists = bin_triangles(&grid.as_grid(), &corners, reach);
    let starts = grid.cells() + 1;
    for entry in &mut lists[starts..] {
        *entry += first_triangle;
    }
    Ok(BodyMesh { grid, lists })
}

fn v4(v: Vec3, w: f32) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w]
}

impl Mover {
    /// The frame at time `t`, s: the motion evaluated in f64 as the CPU engine evaluates it.
    pub fn frame(&self, grid: &Grid, t: f64) -> MoverFrame {
        let pose = self.motion.pose_at(t);
        let origin = pose.translation.vector;
        let (cell, off) = grid.to_voxel_unwrapped(origin);
        let r = pose.rotation.to_rotation_matrix();
        let m = r.matrix();
        let row = |i: usize| [m[(i, 0)] as f32, m[(i, 1)] as f32, m[(i, 2)] as f32, 0.0];
        MoverFrame {
            cell: [cell[0], cell[1], cell[2], self.lists_at as i32],
            off: [off[0], off[1], off[2], self.grid.edge as f32],
            rot: [row(0), row(1), row(2)],
            vel: v4(self.motion.linear_velocity_at(t), 0.0),
            spin: v4(self.motion.angular_velocity_at(t), 0.0),
            lever: v4(self.motion.reference_point_at(t) - origin, 0.0),
            grid_min: v4(self.grid.min, self.geometry as f32),
            grid_dims: [self.grid.dims[0], self.grid.dims[1], self.grid.dims[2], 0],
        }
    }
}

/// The frames of `movers` at time `t`, writing load record `record` (none: -1) and, given a
/// slab, its stress sums.
pub(crate) fn frames_at(
    movers: &[Mover],
    grid: &Grid,
    t: f64,
    record: i32,
    slab: Option<&SlabFrame>,
) -> Frames {
    let mut frames = Frames::zeroed();
    frames.head[0] = record;
    if let Some(slab) = slab {
        frames.head[1] = 1;
        frames.slab = *slab;
    }
    for (slot, mover) in frames.movers.iter_mut().zip(movers) {
        *slot = mover.frame(grid, t);
    }
    frames
}

#[cfg(test)]
mod tests {
    use super::*;
    use repose_engine::kinematics::{RotationSegment, TranslationSegment};
    use repose_engine::math::Pose;
    use repose_engine::mesh::generators;

    fn world_grid() -> Grid {
        Grid {
            min: Vec3::repeat(-0.15),
            voxel: Vec3::repeat(2.5e-3),
            dims: [120, 120, 120],
            periodic: [false, false],
        }
    }

    /// The frame's rotation, origin, velocities and reference point are the motion's, from
    /// which a body point's world position and velocity follow as the CPU engine has them.
    #[test]
    fn a_frame_places_body_points_and_their_velocities_as_the_motion_does() {
        let placement = Pose::translation(0.01, -0.02, 0.03);
        let motion = Motion::new(
            placement,
            vec![TranslationSegment {
                velocity: Vec3::new(0.0, 0.0, 0.1),
                start: 0.0,
                stop: 1.0,
            }],
            vec![RotationSegment {
                axis: Vec3::new(0.0, 0.0, 1.0),
                axis_point: Vec3::new(0.005, 0.0, 0.0),
                rpm: 120.0,
                start: 0.0,
                stop: 1.0,
            }],
        )
        .unwrap();
        let mesh = generators::cuboid(0.02, 0.01, 0.04).unwrap();
        let grid = world_grid();
        let body = bin_body_mesh(&mesh, 2.5e-3, 1e-3, 0).unwrap();
        let mover = Mover {
            geometry: 3,
            motion: motion.clone(),
            grid: body.grid,
            lists_at: 7,
        };
        let t = 0.123;
        let f = mover.frame(&grid, t);
        let pose = motion.pose_at(t);
        let b = Vec3::new(0.01, -0.004, 0.02);
        // world = origin + R b, from the frame's f32 numbers.
        let origin = grid.to_position(
            [f.cell[0], f.cell[1], f.cell[2]],
            [f.off[0], f.off[1], f.off[2]],
        );
        let rb = Vec3::from_fn(|i, _| (0..3).map(|j| f.rot[i][j] as f64 * b[j]).sum::<f64>());
        let world = pose.transform_point(&b.into()).coords;
        assert!(((origin + rb) - world).norm() < 1e-8, "{:?}", origin + rb);
        let spin = Vec3::new(f.spin[0] as f64, f.spin[1] as f64, f.spin[2] as f64);
        let vel = Vec3::new(f.vel[0] as f64, f.vel[1] as f64, f.vel[2] as f64);
        let lever = Vec3::new(f.lever[0] as f64, f.lever[1] as f64, f.lever[2] as f64);
        let v = vel + spin.cross(&(rb - lever));
        let expected = motion.velocity_of_point(world, t);
        assert!(
            (v - expected).norm() < 1e-6 * expected.norm(),
            "{v:?} vs {expected:?}"
        );
        assert_eq!((f.cell[3], f.grid_min[3]), (7, 3.0));
    }

    /// Every body-frame point within the reach of a triangle lies in a body cell that lists it,
    /// the lists carry the triangle offset, and the grid spans the mesh grown by the reach.
    #[test]
    fn a_body_cell_lists_every_triangle_within_reach_of_its_points() {
        let mesh = generators::cylinder(0.02, 0.03, 16, false).unwrap();
        let reach = 1.2e-3;
        let body = bin_body_mesh(&mesh, 2.5e-3, reach, 100).unwrap();
        let g = body.grid;
        let ncells = g.cells();
        let (lo, hi) = mesh.aabb();
        for a in 0..3 {
            assert!(g.min[a] <= lo[a] - reach);
            assert!(g.min[a] + g.dims[a] as f64 * g.edge >= hi[a] + reach);
        }
        let listed = |p: Vec3| -> &[u32] {
            let k: [i32; 3] = std::array::from_fn(|a| ((p[a] - g.min[a]) / g.edge).floor() as i32);
            let c = (k[0] + g.dims[0] * (k[1] + g.dims[1] * k[2])) as usize;
            &body.lists
                [ncells + 1 + body.lists[c] as usize..ncells + 1 + body.lists[c + 1] as usize]
        };
        let mut state = 99u64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for t in 0..mesh.normals().len() {
            let [a, b, c] = mesh.corners(t);
            for _ in 0..200 {
                let (mut u, mut v) = (uniform(), uniform());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let on = a + (b - a) * u + (c - a) * v;
                let dir = Vec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.5);
                let p = on + dir.normalize() * (reach * uniform().sqrt());
                assert!(
                    listed(p).contains(&(t as u32 + 100)),
                    "triangle {t} at {p:?}"
                );
            }
        }
    }
}
