//! Triangle-mesh geometry: walls, funnels, augers; sphere–mesh contact detection.
//!
//! A [`TriMesh`] lives in its own body frame. The world places it with a pose; contact queries
//! take the sphere centre already transformed into the body frame, so the mesh's precomputed
//! data (normals, adjacency, broad-phase grid) never has to be rebuilt while the geometry moves.
//!
//! Meshes are two-sided: a sphere on either side of a triangle is pushed away from it. This is
//! what DEM walls want (thin sheets such as the auger flight or the funnel wall are touched from
//! both sides) and it makes open meshes (a funnel, an open box) behave without an inside/outside.

mod closest;
pub mod generators;
mod grid;
pub mod stl;

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use crate::math::{Pose, Vec3};
use closest::{closest_point_on_triangle, Feature};
use grid::Grid;

pub use generators::{AugerSpec, FunnelSpec, FunnelTop, MeshSpec};
pub use stl::StlError;

/// Why a mesh (or a generator's parameters) was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshError {
    #[error("mesh has no triangles")]
    NoTriangles,
    #[error("vertex {index} has a non-finite coordinate: ({x}, {y}, {z})")]
    NonFiniteVertex {
        index: usize,
        x: f64,
        y: f64,
        z: f64,
    },
    #[error("triangle {triangle} refers to vertex {vertex}, but the mesh has only {vertex_count} vertices")]
    VertexIndexOutOfRange {
        triangle: usize,
        vertex: u32,
        vertex_count: usize,
    },
    #[error("triangle {triangle} is degenerate (area {area:e} m², its corners coincide or are collinear)")]
    DegenerateTriangle { triangle: usize, area: f64 },
    #[error("too many vertices ({count}); triangle indices are 32-bit")]
    TooManyVertices { count: usize },
    /// A generator or import parameter is out of range; `name` is the parameter's name.
    #[error("invalid parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        name: &'static str,
        value: f64,
        reason: String,
    },
    #[error(transparent)]
    Stl(#[from] StlError),
}

impl MeshError {
    pub(crate) fn parameter(name: &'static str, value: f64, reason: impl Into<String>) -> Self {
        MeshError::InvalidParameter {
            name,
            value,
            reason: reason.into(),
        }
    }
}

/// One sphere–mesh contact, in the mesh's body frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshContact {
    /// Closest point on the surface to the sphere centre (body frame, m).
    pub point: Vec3,
    /// Unit normal from the surface point toward the sphere centre.
    pub normal: Vec3,
    /// Penetration depth `radius - distance` (m), always > 0.
    pub overlap: f64,
    /// Triangle that owns the contact (for diagnostics; for an edge or vertex contact it is one
    /// of the triangles sharing that feature).
    pub triangle: u32,
}

/// The serialised form of a mesh: just its geometry. Derived data is rebuilt (and the geometry
/// re-validated) on deserialisation, so a stored mesh can never carry a stale grid.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct TriMeshData {
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    #[serde(default = "default_smooth_angle")]
    smooth_angle_deg: f64,
}

fn default_smooth_angle() -> f64 {
    DEFAULT_SMOOTH_ANGLE_DEG
}

/// A triangle mesh with the precomputed data needed for fast sphere contacts.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(try_from = "TriMeshData", into = "TriMeshData")]
pub struct TriMesh {
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    /// Unit face normals, right-handed with the corner order.
    normals: Vec<Vec3>,
    /// Per-triangle axis-aligned bounds.
    triangle_bounds: Vec<(Vec3, Vec3)>,
    /// Corners of each triangle as *welded* vertex ids. Adjacency uses these, so two triangles
    /// that share an edge geometrically are neighbours even if the caller duplicated vertices.
    welded_triangles: Vec<[u32; 3]>,
    /// Triangles around each welded vertex: `vertex_triangles[vertex_triangle_starts[v]..
    /// vertex_triangle_starts[v + 1]]`.
    vertex_triangle_starts: Vec<u32>,
    vertex_triangles: Vec<u32>,
    lo: Vec3,
    hi: Vec3,
    /// Length below which two points count as the same (welding, contact de-duplication).
    tolerance: f64,
    /// Contacts whose normals differ by less than this angle (degrees) belong to one smooth
    /// surface and are merged into the deepest; cosine cached below.
    smooth_angle_deg: f64,
    smooth_cos: f64,
    grid: Grid,
}

impl TryFrom<TriMeshData> for TriMesh {
    type Error = MeshError;
    fn try_from(data: TriMeshData) -> Result<Self, MeshError> {
        TriMesh::new(data.vertices, data.triangles)?.with_smooth_angle(data.smooth_angle_deg)
    }
}

impl From<TriMesh> for TriMeshData {
    fn from(mesh: TriMesh) -> Self {
        TriMeshData {
            vertices: mesh.vertices,
            triangles: mesh.triangles,
            smooth_angle_deg: mesh.smooth_angle_deg,
        }
    }
}

/// Default for [`TriMesh::with_smooth_angle`]. Facetted curved walls have small dihedral angles
/// between neighbouring facets (a 64-facet funnel: 5.6°, a 24-facet cylinder: 15°), while the
/// corners of a soil bin or the flight/shaft junction are 90°.
pub const DEFAULT_SMOOTH_ANGLE_DEG: f64 = 25.0;

/// Relative tolerance (times the mesh's bounding-box diagonal) for "the same point".
const RELATIVE_TOLERANCE: f64 = 1e-9;

impl TriMesh {
    /// Validates the geometry and builds normals, adjacency and the broad-phase grid.
    ///
    /// Rejects: no triangles, non-finite vertices, indices out of range, and degenerate
    /// (zero-area) triangles, since those have no normal. Vertices that coincide within a tiny
    /// tolerance are treated as one for adjacency purposes (the vertex list itself is kept).
    pub fn new(vertices: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Result<TriMesh, MeshError> {
        if triangles.is_empty() {
            return Err(MeshError::NoTriangles);
        }
        if vertices.len() > u32::MAX as usize {
            return Err(MeshError::TooManyVertices {
                count: vertices.len(),
            });
        }
        for (index, v) in vertices.iter().enumerate() {
            if !(v.x.is_finite() && v.y.is_finite() && v.z.is_finite()) {
                return Err(MeshError::NonFiniteVertex {
                    index,
                    x: v.x,
                    y: v.y,
                    z: v.z,
                });
            }
        }
        for (triangle, tri) in triangles.iter().enumerate() {
            for &vertex in tri {
                if vertex as usize >= vertices.len() {
                    return Err(MeshError::VertexIndexOutOfRange {
                        triangle,
                        vertex,
                        vertex_count: vertices.len(),
                    });
                }
            }
        }

        let mut lo = Vec3::repeat(f64::INFINITY);
        let mut hi = Vec3::repeat(f64::NEG_INFINITY);
        for tri in &triangles {
            for &v in tri {
                lo = lo.inf(&vertices[v as usize]);
                hi = hi.sup(&vertices[v as usize]);
            }
        }
        let diagonal = (hi - lo).norm();
        let tolerance = RELATIVE_TOLERANCE * diagonal.max(f64::MIN_POSITIVE);

        let mut normals = Vec::with_capacity(triangles.len());
        let mut triangle_bounds = Vec::with_capacity(triangles.len());
        for (triangle, tri) in triangles.iter().enumerate() {
            let [a, b, c] = tri.map(|i| vertices[i as usize]);
            let cross = (b - a).cross(&(c - a));
            let double_area = cross.norm();
            // Relative to the mesh size, so a 1 mm triangle in a 1 m mesh is fine while a
            // sliver that is collinear up to rounding is not.
            if double_area.is_nan() || double_area <= tolerance * diagonal {
                return Err(MeshError::DegenerateTriangle {
                    triangle,
                    area: 0.5 * double_area,
                });
            }
            normals.push(cross / double_area);
            triangle_bounds.push((a.inf(&b).inf(&c), a.sup(&b).sup(&c)));
        }

        let (_, weld_map) = weld_vertices(&vertices, tolerance);
        let welded_triangles: Vec<[u32; 3]> = triangles
            .iter()
            .map(|t| t.map(|i| weld_map[i as usize]))
            .collect();
        let welded_count = weld_map.iter().map(|&w| w as usize + 1).max().unwrap_or(0);
        let mut vertex_triangle_starts = vec![0u32; welded_count + 1];
        for tri in &welded_triangles {
            for &v in tri {
                vertex_triangle_starts[v as usize + 1] += 1;
            }
        }
        for v in 0..welded_count {
            vertex_triangle_starts[v + 1] += vertex_triangle_starts[v];
        }
        let mut cursor = vertex_triangle_starts.clone();
        let mut vertex_triangles = vec![0u32; vertex_triangle_starts[welded_count] as usize];
        for (t, tri) in welded_triangles.iter().enumerate() {
            for &v in tri {
                vertex_triangles[cursor[v as usize] as usize] = t as u32;
                cursor[v as usize] += 1;
            }
        }

        let grid = Grid::build(&triangle_bounds, lo, hi);
        Ok(TriMesh {
            vertices,
            triangles,
            normals,
            triangle_bounds,
            welded_triangles,
            vertex_triangle_starts,
            vertex_triangles,
            lo,
            hi,
            tolerance,
            smooth_angle_deg: DEFAULT_SMOOTH_ANGLE_DEG,
            smooth_cos: DEFAULT_SMOOTH_ANGLE_DEG.to_radians().cos(),
            grid,
        })
    }

    pub fn vertices(&self) -> &[Vec3] {
        &self.vertices
    }

    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Unit face normals (right-handed with the corner order), one per triangle.
    pub fn normals(&self) -> &[Vec3] {
        &self.normals
    }

    /// The three corners of triangle `t`.
    ///
    /// # Panics
    /// If `t` is out of range, like slice indexing.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.vertices[i as usize])
    }

    /// The welded vertices of triangle `t` (corners within the mesh's tolerance share one),
    /// as the contact query's local-minimum test sees them.
    ///
    /// # Panics
    /// If `t` is out of range, like slice indexing.
    pub fn welded_corners(&self, t: usize) -> [u32; 3] {
        self.welded_triangles[t]
    }

    /// Welded vertices (`welded_corners` are below this).
    pub fn welded_vertex_count(&self) -> usize {
        self.vertex_triangle_starts.len() - 1
    }

    /// The triangles around welded vertex `v`, ascending.
    ///
    /// # Panics
    /// If `v` is out of range, like slice indexing.
    pub fn triangles_around(&self, v: u32) -> &[u32] {
        let v = v as usize;
        &self.vertex_triangles
            [self.vertex_triangle_starts[v] as usize..self.vertex_triangle_starts[v + 1] as usize]
    }

    /// Axis-aligned bounds in the body frame (of the vertices used by triangles).
    pub fn aabb(&self) -> (Vec3, Vec3) {
        (self.lo, self.hi)
    }

    /// Total surface area (m²).
    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }

    /// Number of broad-phase grid cells (diagnostics).
    pub fn grid_cell_count(&self) -> usize {
        self.grid.cell_count()
    }

    /// A copy of this mesh with every vertex moved by `pose` (e.g. to place a generated wall).
    pub fn transformed(&self, pose: &Pose) -> Result<TriMesh, MeshError> {
        let vertices = self
            .vertices
            .iter()
            .map(|v| pose.transform_point(&(*v).into()).coords)
            .collect();
        TriMesh::new(vertices, self.triangles.clone())?.with_smooth_angle(self.smooth_angle_deg)
    }

    /// Concatenates meshes into one (e.g. a funnel plus its support plate).
    pub fn merged(parts: &[&TriMesh]) -> Result<TriMesh, MeshError> {
        let mut vertices = Vec::new();
        let mut triangles = Vec::new();
        for part in parts {
            let offset = u32::try_from(vertices.len()).map_err(|_| MeshError::TooManyVertices {
                count: vertices.len(),
            })?;
            vertices.extend_from_slice(&part.vertices);
            triangles.extend(part.triangles.iter().map(|t| t.map(|i| i + offset)));
        }
        TriMesh::new(vertices, triangles)
    }

    /// All contacts of a sphere with this mesh, in the mesh's BODY frame (the caller transforms
    /// the sphere centre into the body frame with the geometry's pose and the results back).
    ///
    /// A sphere touching several triangles of one flat or smoothly-joined surface gets ONE
    /// contact. An edge or vertex contact is kept only if its point is a local minimum of the
    /// distance over the triangles sharing that edge or vertex (so it is dropped when a
    /// neighbour reaches closer, e.g. because the neighbour produced a face contact), and any
    /// contact whose point coincides (within tolerance) with one already found is dropped.
    /// Finally contacts whose normals are within the smooth angle (default
    /// [`DEFAULT_SMOOTH_ANGLE_DEG`]) are merged into the deepest, so a sphere in a shallow
    /// concave crease of a facetted curved wall gets one contact. This gives one contact per
    /// flat or smoothly curved region, one per convex edge or corner, and one per wall in a
    /// concave corner. The result does not depend on triangle order, so the broad phase and
    /// [`TriMesh::sphere_contacts_brute_force`] agree.
    ///
    /// Pushes into `out` (does not clear it). A non-finite centre or a radius that is not
    /// positive yields no contacts.
    ///
    /// ```
    /// use repose_engine::math::{Pose, Vec3};
    /// use repose_engine::mesh::generators::plane;
    ///
    /// // A floor 1 m × 1 m, lifted to z = 0.5 m in the world.
    /// let floor = plane(1.0, 1.0, 4, 4).unwrap();
    /// let pose = Pose::translation(0.0, 0.0, 0.5);
    /// let (centre, radius) = (Vec3::new(0.1, 0.2, 0.509), 0.01);
    ///
    /// let body_centre = pose.inverse_transform_point(&centre.into()).coords;
    /// let mut contacts = Vec::new();
    /// floor.sphere_contacts(body_centre, radius, &mut contacts);
    /// assert_eq!(contacts.len(), 1);
    /// let world_point = pose.transform_point(&contacts[0].point.into()).coords;
    /// let world_normal = pose.rotation * contacts[0].normal;
    /// assert!((world_point - Vec3::new(0.1, 0.2, 0.5)).norm() < 1e-12);
    /// assert!((world_normal - Vec3::z()).norm() < 1e-12);
    /// assert!((contacts[0].overlap - 0.001).abs() < 1e-12);
    /// ```
    pub fn sphere_contacts(&self, center: Vec3, radius: f64, out: &mut Vec<MeshContact>) {
        if !Self::query_is_valid(center, radius) {
            return;
        }
        let start = out.len();
        let mut rejected = RejectedFeatures::default();
        let reach = Vec3::repeat(radius);
        let (lo, hi) = (center - reach, center + reach);
        self.grid.for_each_candidate(lo, hi, |t| {
            let (tlo, thi) = self.triangle_bounds[t as usize];
            if boxes_overlap(lo, hi, tlo, thi) {
                self.add_triangle_contact(t, center, radius, start, &mut rejected, out);
            }
        });
        self.merge_smooth(start, out);
    }

    /// Appends, in ascending order, the triangles whose closest point to `center` is nearer
    /// than `reach`: every triangle a sphere of radius `r` can touch while its centre stays
    /// within `reach - r` of `center`. The world keeps these lists between neighbour rebuilds
    /// so that a step tests a few triangles instead of walking the grid.
    pub fn triangles_near(&self, center: Vec3, reach: f64, out: &mut Vec<u32>) {
        if !Self::query_is_valid(center, reach) {
            return;
        }
        let start = out.len();
        let r = Vec3::repeat(reach);
        let (lo, hi) = (center - r, center + r);
        let reach2 = reach * reach;
        self.grid.for_each_candidate(lo, hi, |t| {
            let (tlo, thi) = self.triangle_bounds[t as usize];
            if boxes_overlap(lo, hi, tlo, thi) {
                let [a, b, c] = self.corners(t as usize);
                let (point, _) = closest_point_on_triangle(center, a, b, c);
                if (center - point).norm_squared() < reach2 {
                    out.push(t);
                }
            }
        });
        out[start..].sort_unstable();
    }

    /// [`TriMesh::sphere_contacts`] testing only `candidates`, which must hold every triangle
    /// within `radius` of `center` (from [`TriMesh::triangles_near`] with a large enough
    /// reach). Same contacts as the grid query: the triangles it would find are all among the
    /// candidates, and the result does not depend on the order they are visited.
    pub fn sphere_contacts_among(
        &self,
        center: Vec3,
        radius: f64,
        candidates: &[u32],
        out: &mut Vec<MeshContact>,
    ) {
        if !Self::query_is_valid(center, radius) {
            return;
        }
        let start = out.len();
        let mut rejected = RejectedFeatures::default();
        let reach = Vec3::repeat(radius);
        let (lo, hi) = (center - reach, center + reach);
        let radius2 = radius * radius;
        for &t in candidates {
            let (tlo, thi) = self.triangle_bounds[t as usize];
            if !boxes_overlap(lo, hi, tlo, thi) {
                continue;
            }
            // The triangle's plane is no farther than any point of it: a sphere clear of the
            // plane is clear of the triangle (one dot product instead of the closest point).
            let a = self.vertices[self.triangles[t as usize][0] as usize];
            let height = self.normals[t as usize].dot(&(center - a));
            if height * height >= radius2 {
                continue;
            }
            self.add_triangle_contact(t, center, radius, start, &mut rejected, out);
        }
        self.merge_smooth(start, out);
    }

    /// The eight corners of [`TriMesh::aabb`], in the body frame.
    pub fn aabb_corners(&self) -> [Vec3; 8] {
        let (lo, hi) = self.aabb();
        std::array::from_fn(|corner| {
            Vec3::new(
                if corner & 1 == 0 { lo.x } else { hi.x },
                if corner & 2 == 0 { lo.y } else { hi.y },
                if corner & 4 == 0 { lo.z } else { hi.z },
            )
        })
    }

    /// An upper bound of any vertex's distance from the body origin (the farthest corner of
    /// the bounding box): bounds how far a point of the mesh moves when the body turns.
    pub fn max_vertex_distance(&self) -> f64 {
        self.aabb_corners()
            .iter()
            .map(|c| c.norm())
            .fold(0.0, f64::max)
    }

    /// Same result as [`TriMesh::sphere_contacts`] by testing every triangle: the reference
    /// the broad phase is checked against, O(triangles) per query.
    pub fn sphere_contacts_brute_force(
        &self,
        center: Vec3,
        radius: f64,
        out: &mut Vec<MeshContact>,
    ) {
        if !Self::query_is_valid(center, radius) {
            return;
        }
        let start = out.len();
        let mut rejected = RejectedFeatures::default();
        for t in 0..self.triangles.len() as u32 {
            self.add_triangle_contact(t, center, radius, start, &mut rejected, out);
        }
        self.merge_smooth(start, out);
    }

    /// Sets the angle (degrees, in [0, 90)) below which two contacts' normals count as the
    /// same smooth surface (see [`TriMesh::sphere_contacts`]). 0 disables merging.
    pub fn with_smooth_angle(mut self, degrees: f64) -> Result<TriMesh, MeshError> {
        if !(degrees.is_finite() && (0.0..90.0).contains(&degrees)) {
            return Err(MeshError::parameter(
                "smooth_angle_deg",
                degrees,
                "must be in [0, 90) degrees",
            ));
        }
        self.smooth_angle_deg = degrees;
        // Contacts merge when the cosine between their normals exceeds this; a cosine never
        // exceeds 2, so 0° disables merging altogether.
        self.smooth_cos = if degrees == 0.0 {
            2.0
        } else {
            degrees.to_radians().cos()
        };
        Ok(self)
    }

    pub fn smooth_angle_deg(&self) -> f64 {
        self.smooth_angle_deg
    }

    /// Keeps, among contacts whose normals are within the smooth angle of each other, only the
    /// deepest. A sphere in a shallow concave crease of a facetted curved wall (inside a
    /// funnel or cylinder) touches two facets' faces at distinct points; both are genuine local
    /// minima, but they are one surface, and reporting both would double the wall force.
    /// Deepest-first makes the result independent of the order triangles were visited, and
    /// keeps the overlap continuous as a sphere slides across the crease.
    fn merge_smooth(&self, start: usize, out: &mut Vec<MeshContact>) {
        if out.len() - start < 2 {
            return;
        }
        out[start..].sort_unstable_by(|a, b| {
            b.overlap
                .total_cmp(&a.overlap)
                .then(a.point.x.total_cmp(&b.point.x))
                .then(a.point.y.total_cmp(&b.point.y))
                .then(a.point.z.total_cmp(&b.point.z))
        });
        let mut kept = start;
        for i in start..out.len() {
            let candidate = out[i];
            if out[start..kept]
                .iter()
                .all(|k| k.normal.dot(&candidate.normal) <= self.smooth_cos)
            {
                out[kept] = candidate;
                kept += 1;
            }
        }
        out.truncate(kept);
    }

    fn query_is_valid(center: Vec3, radius: f64) -> bool {
        radius > 0.0 && radius.is_finite() && center.iter().all(|c| c.is_finite())
    }

    fn add_triangle_contact(
        &self,
        t: u32,
        center: Vec3,
        radius: f64,
        start: usize,
        rejected: &mut RejectedFeatures,
        out: &mut Vec<MeshContact>,
    ) {
        let [a, b, c] = self.corners(t as usize);
        let (point, feature) = closest_point_on_triangle(center, a, b, c);
        let offset = center - point;
        let distance_squared = offset.norm_squared();
        if distance_squared.is_nan() || distance_squared >= radius * radius {
            return;
        }
        // The cheap duplicate test first: at a vertex shared by k triangles each of them finds
        // the same point, and running the O(k) local-minimum test for each would cost O(k²).
        if out[start..]
            .iter()
            .any(|existing| (existing.point - point).norm() <= self.tolerance)
        {
            return;
        }
        if feature != Feature::Face {
            // Every triangle around a rejected edge or vertex finds the same point there, and
            // the answer is the same for all of them: remember it rather than recompute.
            let key = self.feature_key(t, feature);
            if rejected.contains(key) {
                return;
            }
            if !self.is_local_minimum(t, feature, point, center) {
                rejected.insert(key);
                return;
            }
        }
        let distance = distance_squared.sqrt();
        let face_normal = self.normals[t as usize];
        let oriented_face_normal = if face_normal.dot(&offset) >= 0.0 {
            face_normal
        } else {
            -face_normal
        };
        // On a face the exact face normal is better conditioned than offset / distance; at an
        // edge or vertex the direction to the centre is the only meaningful normal, unless the
        // centre sits on the surface, where it is undefined and the face normal stands in.
        let normal = if feature == Feature::Face || distance <= self.tolerance {
            oriented_face_normal
        } else {
            offset / distance
        };
        out.push(MeshContact {
            point,
            normal,
            overlap: radius - distance,
            triangle: t,
        });
    }

    /// Welded vertex ids identifying an edge (sorted pair) or a vertex (`(v, u32::MAX)`).
    fn feature_key(&self, t: u32, feature: Feature) -> (u32, u32) {
        let welded = self.welded_triangles[t as usize];
        match feature {
            Feature::Face => (u32::MAX, t),
            Feature::Edge(k) => {
                let (u, w) = (welded[k as usize], welded[(k as usize + 1) % 3]);
                (u.min(w), u.max(w))
            }
            Feature::Vertex(k) => (welded[k as usize], u32::MAX),
        }
    }

    /// Whether `point` (on an edge or at a vertex of triangle `t`) is also the closest point of
    /// every other triangle sharing that edge or vertex. If a neighbour reaches closer, the
    /// sphere's real contact is with that neighbour (which reports it itself), and reporting
    /// this one too would double the force on a flat or concave surface.
    fn is_local_minimum(&self, t: u32, feature: Feature, point: Vec3, center: Vec3) -> bool {
        let welded = self.welded_triangles[t as usize];
        let (pivot, other) = match feature {
            Feature::Face => return true,
            Feature::Edge(k) => (welded[k as usize], Some(welded[(k as usize + 1) % 3])),
            Feature::Vertex(k) => (welded[k as usize], None),
        };
        let around = &self.vertex_triangles[self.vertex_triangle_starts[pivot as usize] as usize
            ..self.vertex_triangle_starts[pivot as usize + 1] as usize];
        around.iter().all(|&n| {
            if n == t {
                return true;
            }
            if let Some(other) = other {
                if !self.welded_triangles[n as usize].contains(&other) {
                    return true; // shares the vertex but not this edge
                }
            }
            let [a, b, c] = self.corners(n as usize);
            let (q, _) = closest_point_on_triangle(center, a, b, c);
            (q - point).norm() <= self.tolerance
        })
    }
}

/// A few edges/vertices already found not to be local minima in the current query, so a vertex
/// shared by k triangles (a fan closing a disc, a cone tip) costs O(k) per query, not O(k²).
/// Fixed size and overwritten round-robin: no allocation in the contact query.
#[derive(Debug, Default)]
struct RejectedFeatures {
    keys: [(u32, u32); 8],
    len: usize,
    next: usize,
}

impl RejectedFeatures {
    fn contains(&self, key: (u32, u32)) -> bool {
        self.keys[..self.len].contains(&key)
    }

    fn insert(&mut self, key: (u32, u32)) {
        self.keys[self.next] = key;
        self.next = (self.next + 1) % self.keys.len();
        self.len = (self.len + 1).min(self.keys.len());
    }
}

fn boxes_overlap(alo: Vec3, ahi: Vec3, blo: Vec3, bhi: Vec3) -> bool {
    alo.x <= bhi.x
        && blo.x <= ahi.x
        && alo.y <= bhi.y
        && blo.y <= ahi.y
        && alo.z <= bhi.z
        && blo.z <= ahi.z
}

/// Merges vertices closer than `tolerance`. Returns the unique vertices and, for every input
/// vertex, its index among them. Uses a hash grid of cell size `tolerance`, checking the 27
/// neighbouring cells, so near-coincident points on either side of a cell boundary still merge.
pub(crate) fn weld_vertices(vertices: &[Vec3], tolerance: f64) -> (Vec<Vec3>, Vec<u32>) {
    let tolerance = tolerance.max(f64::MIN_POSITIVE);
    let key = |v: &Vec3| -> [i64; 3] {
        // `as i64` saturates for huge values, so this is total (inputs are finite).
        [
            (v.x / tolerance).floor() as i64,
            (v.y / tolerance).floor() as i64,
            (v.z / tolerance).floor() as i64,
        ]
    };
    let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::with_capacity(vertices.len());
    let mut unique: Vec<Vec3> = Vec::new();
    let mut map = Vec::with_capacity(vertices.len());
    for v in vertices {
        let k = key(v);
        let mut found = None;
        'search: for dz in -1..=1i64 {
            for dy in -1..=1i64 {
                for dx in -1..=1i64 {
                    let neighbour = [
                        k[0].saturating_add(dx),
                        k[1].saturating_add(dy),
                        k[2].saturating_add(dz),
                    ];
                    if let Some(list) = cells.get(&neighbour) {
                        if let Some(&u) = list
                            .iter()
                            .find(|&&u| (unique[u as usize] - v).norm() <= tolerance)
                        {
                            found = Some(u);
                            break 'search;
                        }
                    }
                }
            }
        }
        let index = match found {
            Some(u) => u,
            None => {
                let u = unique.len() as u32;
                unique.push(*v);
                cells.entry(k).or_default().push(u);
                u
            }
        };
        map.push(index);
    }
    (unique, map)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_triangle_square() -> TriMesh {
        TriMesh::new(
            vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
        .unwrap()
    }

    #[test]
    fn rejects_bad_input() {
        assert_eq!(
            TriMesh::new(vec![], vec![]).unwrap_err(),
            MeshError::NoTriangles
        );
        let v = vec![Vec3::zeros(), Vec3::x(), Vec3::y()];
        assert!(matches!(
            TriMesh::new(v.clone(), vec![[0, 1, 3]]),
            Err(MeshError::VertexIndexOutOfRange { vertex: 3, .. })
        ));
        assert!(matches!(
            TriMesh::new(v.clone(), vec![[0, 1, 1]]),
            Err(MeshError::DegenerateTriangle { triangle: 0, .. })
        ));
        let mut nan = v;
        nan[1].y = f64::NAN;
        assert!(matches!(
            TriMesh::new(nan, vec![[0, 1, 2]]),
            Err(MeshError::NonFiniteVertex { index: 1, .. })
        ));
    }

    #[test]
    fn diagonal_edge_gives_one_contact_from_either_side() {
        let mesh = two_triangle_square();
        for z in [0.05, -0.05] {
            let mut out = Vec::new();
            mesh.sphere_contacts(Vec3::new(0.5, 0.5, z), 0.1, &mut out);
            assert_eq!(out.len(), 1, "{out:?}");
            assert!((out[0].overlap - 0.05).abs() < 1e-12);
            assert!((out[0].normal - Vec3::new(0.0, 0.0, z.signum())).norm() < 1e-12);
        }
    }

    #[test]
    fn serde_round_trip_rebuilds_derived_data() {
        let mesh = two_triangle_square();
        let json = serde_json::to_string(&mesh).unwrap();
        let back: TriMesh = serde_json::from_str(&json).unwrap();
        assert_eq!(back.vertices(), mesh.vertices());
        assert_eq!(back.normals(), mesh.normals());
        let bad = r#"{"vertices":[[0,0,0]],"triangles":[[0,0,0]]}"#;
        assert!(serde_json::from_str::<TriMesh>(bad).is_err());
    }

    #[test]
    fn weld_merges_near_duplicates_only() {
        let (unique, map) = weld_vertices(
            &[
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1e-12, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
            ],
            1e-9,
        );
        assert_eq!(unique.len(), 2);
        assert_eq!(map, vec![0, 0, 1]);
    }
}
