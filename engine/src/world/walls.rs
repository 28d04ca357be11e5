//! Particle-triangle candidate lists kept between neighbour rebuilds.
//!
//! Walking a mesh's grid for every particle every step cost a third of a funnel run. At each
//! rebuild, every particle instead records the triangles of each geometry that lie within its
//! radius plus its own half skin plus the geometry's *allowance* (in CSR form, like the pair
//! list). Until the next rebuild a particle moves at most its own half skin (the rebuild
//! criterion); as long as a geometry has moved at most its allowance since the build, no
//! triangle outside the list can come closer than the particle's radius, so testing the listed
//! triangles finds exactly the contacts the grid query would. A geometry that never moves has
//! no allowance (a settled grain on the plate lists only the triangles within 0.075 d of its
//! surface, not 0.5 d); a moving one is allowed half the largest skin, and once it has moved
//! further (a turning auger, a lifted cylinder) it is *live* until the next rebuild: its
//! contacts are found by the grid query, as before.

use rayon::prelude::*;

use super::*;

/// The candidate triangles of every particle, built at a neighbour rebuild.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub(super) struct WallCandidates {
    /// CSR offsets, length n + 1 (empty before the first build).
    pub(super) first: Vec<u32>,
    /// Geometry of each entry; entries of a particle are sorted by geometry, then triangle.
    pub(super) geometry: Vec<u32>,
    /// Triangle of each entry.
    pub(super) triangle: Vec<u32>,
    /// Each geometry's pose at the build.
    pub(super) build_pose: Vec<Pose>,
    /// Per geometry: how far it may move after the build while the candidates stay complete.
    /// A particle's candidates of geometry g hold every triangle within its radius + its half
    /// skin + `allowance[g]` of its centre at the build.
    pub(super) allowance: Vec<f64>,
}

impl WallCandidates {
    /// The candidates of particle `i` (geometry, triangle), in order.
    #[inline]
    pub(super) fn of(&self, i: usize) -> (&[u32], &[u32]) {
        if i + 1 >= self.first.len() {
            return (&[], &[]);
        }
        let range = self.first[i] as usize..self.first[i + 1] as usize;
        (&self.geometry[range.clone()], &self.triangle[range])
    }

    pub(super) fn memory_bytes(&self) -> usize {
        (self.first.len() + self.geometry.len() + self.triangle.len()) * 4
    }
}

/// How far any point of a mesh (of `extent` = largest vertex distance from the body origin)
/// can have moved between two poses: the translation of the origin plus the rotation angle
/// times the extent (a chord is never longer than its arc).
pub(super) fn displacement_bound(from: &Pose, to: &Pose, extent: f64) -> f64 {
    let translation = (to.translation.vector - from.translation.vector).norm();
    let turn = (to.rotation * from.rotation.inverse()).angle();
    translation + turn * extent
}

impl World {
    /// Build the candidate lists for the current positions, with the geometries' poses at
    /// time `t`, keeping every triangle within radius + skin of each particle.
    pub(super) fn build_wall_candidates(&mut self, t: f64) {
        let p = &self.particles;
        let n = p.len();
        let allowance: Vec<f64> = self
            .geometries
            .iter()
            .map(|g| {
                if g.motion.is_stationary() {
                    0.0
                } else {
                    0.5 * self.skin
                }
            })
            .collect();
        let poses: Vec<Pose> = self
            .geometries
            .iter()
            .map(|g| g.motion.pose_at(t))
            .collect();
        let inverses: Vec<Pose> = poses.iter().map(|q| q.inverse()).collect();
        let boxes: Vec<(Vec3, Vec3)> = self
            .geometries
            .iter()
            .zip(&poses)
            .map(|(g, pose)| world_aabb(&g.mesh, pose))
            .collect();
        let geometries = &self.geometries;
        let chunks: Vec<(Vec<u32>, Vec<u32>, Vec<u32>)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .with_max_len(1)
            .map(|chunk| {
                let range = chunk * CHUNK..((chunk + 1) * CHUNK).min(n);
                let mut counts = Vec::with_capacity(range.len());
                let mut geometry = Vec::new();
                let mut triangle = Vec::new();
                for i in range {
                    let start = triangle.len();
                    let x = p.position[i];
                    // The move test compares with the build position rounded to f32: allow
                    // for that rounding (a few 1e-8 m), far below any skin.
                    let rounding = 4.0 * f32::EPSILON as f64 * x.amax().max(1.0);
                    let own = p.radius[i] + p.build_mark[i].half_skin as f64 + rounding;
                    for (g, mesh_box) in boxes.iter().enumerate() {
                        let reach = own + allowance[g];
                        let r = Vec3::repeat(reach);
                        let (lo, hi) = (x - r, x + r);
                        if (0..3).any(|a| lo[a] > mesh_box.1[a] || hi[a] < mesh_box.0[a]) {
                            continue;
                        }
                        let body = inverses[g].transform_point(&x.into()).coords;
                        geometries[g]
                            .mesh
                            .triangles_near(body, reach, &mut triangle);
                        geometry.resize(triangle.len(), g as u32);
                    }
                    counts.push((triangle.len() - start) as u32);
                }
                (counts, geometry, triangle)
            })
            .collect();
        let total: usize = chunks.iter().map(|c| c.2.len()).sum();
        let walls = &mut self.walls;
        walls.first.clear();
        walls.first.reserve(n + 1);
        walls.first.push(0);
        walls.geometry.clear();
        walls.geometry.reserve(total);
        walls.triangle.clear();
        walls.triangle.reserve(total);
        let mut offset = 0u32;
        for (counts, geometry, triangle) in chunks {
            for c in counts {
                offset += c;
                walls.first.push(offset);
            }
            walls.geometry.extend_from_slice(&geometry);
            walls.triangle.extend_from_slice(&triangle);
        }
        walls.build_pose = poses;
        walls.allowance = allowance;
    }
}

/// The world-frame bounding box of a mesh placed at `pose` (its body box's eight corners).
pub(super) fn world_aabb(mesh: &TriMesh, pose: &Pose) -> (Vec3, Vec3) {
    mesh.aabb_corners().iter().fold(
        (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
        |(lo, hi), c| {
            let w = pose.transform_point(&(*c).into()).coords;
            (lo.inf(&w), hi.sup(&w))
        },
    )
}
