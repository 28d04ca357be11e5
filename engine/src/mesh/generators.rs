//! Mesh generators for the test rigs: plane, open box (soil bin), cuboid, cylinder, funnel and
//! helical auger.
//!
//! All generators work in metres with z up and document their body frame. Each validates its
//! parameters and returns [`MeshError::InvalidParameter`] naming the offending one. Adjacent
//! surfaces share vertices, so edge adjacency (and thus contact de-duplication) works across
//! them.

use std::f64::consts::TAU;

use serde::{Deserialize, Serialize};

use super::{MeshError, StlError, TriMesh};
use crate::math::Vec3;

fn default_segments() -> usize {
    64
}

fn default_scale() -> f64 {
    1.0
}

fn default_true() -> bool {
    true
}

/// Upper bound on any subdivision count: protects against absurd allocations from a typo.
const MAX_SUBDIVISIONS: usize = 100_000;

fn require_positive(name: &'static str, value: f64) -> Result<(), MeshError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(MeshError::parameter(name, value, "must be finite and > 0"))
    }
}

fn require_non_negative(name: &'static str, value: f64) -> Result<(), MeshError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(MeshError::parameter(name, value, "must be finite and >= 0"))
    }
}

fn require_count(name: &'static str, value: usize, min: usize) -> Result<(), MeshError> {
    if (min..=MAX_SUBDIVISIONS).contains(&value) {
        Ok(())
    } else {
        Err(MeshError::parameter(
            name,
            value as f64,
            format!("must be an integer in [{min}, {MAX_SUBDIVISIONS}]"),
        ))
    }
}

/// Subdivisions so that pieces of `length` are about `target` long (at least 1).
fn divisions(length: f64, target: f64) -> usize {
    ((length / target).round() as usize).clamp(1, 2_000)
}

/// Accumulates vertices and triangles.
#[derive(Debug, Default)]
struct Builder {
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
}

impl Builder {
    fn vertex(&mut self, v: Vec3) -> u32 {
        self.vertices.push(v);
        (self.vertices.len() - 1) as u32
    }

    /// Two triangles for the quad `a b c d` (in order around its boundary).
    fn quad(&mut self, a: u32, b: u32, c: u32, d: u32) {
        self.triangles.push([a, b, c]);
        self.triangles.push([a, c, d]);
    }

    /// A `(nu + 1) × (nv + 1)` grid of vertices `point(i / nu, j / nv)`, quads between them.
    /// Returns the vertex ids, row-major in `j`: `ids[j * (nu + 1) + i]`.
    fn sheet(&mut self, nu: usize, nv: usize, point: impl Fn(f64, f64) -> Vec3) -> Vec<u32> {
        let mut ids = Vec::with_capacity((nu + 1) * (nv + 1));
        for j in 0..=nv {
            for i in 0..=nu {
                ids.push(self.vertex(point(i as f64 / nu as f64, j as f64 / nv as f64)));
            }
        }
        let at = |i: usize, j: usize| ids[j * (nu + 1) + i];
        for j in 0..nv {
            for i in 0..nu {
                self.quad(at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            }
        }
        ids
    }

    /// A surface of revolution about z: `rings + 1` circles of `segments` vertices each, ring
    /// `k` at `(radius(k / rings), z(k / rings))`. Returns the ids of ring `k` at `[k]`.
    fn revolution(
        &mut self,
        segments: usize,
        rings: usize,
        radius_z: impl Fn(f64) -> (f64, f64),
    ) -> Vec<Vec<u32>> {
        let ring_ids: Vec<Vec<u32>> = (0..=rings)
            .map(|k| {
                let (r, z) = radius_z(k as f64 / rings as f64);
                (0..segments)
                    .map(|s| {
                        let phi = TAU * s as f64 / segments as f64;
                        self.vertex(Vec3::new(r * phi.cos(), r * phi.sin(), z))
                    })
                    .collect()
            })
            .collect();
        for k in 0..rings {
            for s in 0..segments {
                let s1 = (s + 1) % segments;
                self.quad(
                    ring_ids[k][s],
                    ring_ids[k][s1],
                    ring_ids[k + 1][s1],
                    ring_ids[k + 1][s],
                );
            }
        }
        ring_ids
    }

    /// Closes a ring with a fan around `center`.
    fn fan(&mut self, ring: &[u32], center: Vec3) {
        let c = self.vertex(center);
        for s in 0..ring.len() {
            self.triangles
                .push([c, ring[(s + 1) % ring.len()], ring[s]]);
        }
    }

    fn build(self) -> Result<TriMesh, MeshError> {
        TriMesh::new(self.vertices, self.triangles)
    }
}

/// A flat rectangle in the plane z = 0, centred on the origin, spanning
/// `[-size_x/2, size_x/2] × [-size_y/2, size_y/2]`, normal +z, split into
/// `cells_x × cells_y` cells of two triangles each (all diagonals in the same direction, so an
/// interior vertex is shared by 6 triangles).
pub fn plane(
    size_x: f64,
    size_y: f64,
    cells_x: usize,
    cells_y: usize,
) -> Result<TriMesh, MeshError> {
    require_positive("size_x", size_x)?;
    require_positive("size_y", size_y)?;
    require_count("cells_x", cells_x, 1)?;
    require_count("cells_y", cells_y, 1)?;
    let mut b = Builder::default();
    b.sheet(cells_x, cells_y, |u, v| {
        Vec3::new((u - 0.5) * size_x, (v - 0.5) * size_y, 0.0)
    });
    b.build()
}

/// Axis-aligned box walls: floor at z = 0 spanning `[-size_x/2, size_x/2] × [-size_y/2,
/// size_y/2]`, four vertical walls up to z = `height`, and a lid at z = `height` only if `lid`.
/// Corners are shared between floor and walls. Each face is two triangles.
fn box_mesh(size_x: f64, size_y: f64, height: f64, lid: bool) -> Result<TriMesh, MeshError> {
    require_positive("size_x", size_x)?;
    require_positive("size_y", size_y)?;
    require_positive("height", height)?;
    let (hx, hy) = (0.5 * size_x, 0.5 * size_y);
    let mut b = Builder::default();
    let corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)];
    let bottom: Vec<u32> = corners
        .iter()
        .map(|&(x, y)| b.vertex(Vec3::new(x, y, 0.0)))
        .collect();
    let top: Vec<u32> = corners
        .iter()
        .map(|&(x, y)| b.vertex(Vec3::new(x, y, height)))
        .collect();
    // Normals point into the box (irrelevant for contacts, which are two-sided).
    b.quad(bottom[0], bottom[1], bottom[2], bottom[3]);
    for k in 0..4 {
        let k1 = (k + 1) % 4;
        b.quad(bottom[k], top[k], top[k1], bottom[k1]);
    }
    if lid {
        b.quad(top[0], top[3], top[2], top[1]);
    }
    b.build()
}

/// Soil bin: floor at z = 0 spanning `[-size_x/2, size_x/2] × [-size_y/2, size_y/2]` and four
/// vertical walls up to z = `height`, no lid.
pub fn open_box(size_x: f64, size_y: f64, height: f64) -> Result<TriMesh, MeshError> {
    box_mesh(size_x, size_y, height, false)
}

/// Closed box, frame as [`open_box`] (base at z = 0, lid at z = `height`).
pub fn cuboid(size_x: f64, size_y: f64, height: f64) -> Result<TriMesh, MeshError> {
    box_mesh(size_x, size_y, height, true)
}

/// Open tube of `radius` about the z axis from z = 0 to z = `height`, approximated by
/// `segments` flat facets around (vertices lie on the circle), with a flat bottom disc at
/// z = 0 if `bottom`. The tube is split along z so facets are roughly square.
pub fn cylinder(
    radius: f64,
    height: f64,
    segments: usize,
    bottom: bool,
) -> Result<TriMesh, MeshError> {
    require_positive("radius", radius)?;
    require_positive("height", height)?;
    require_count("segments", segments, 3)?;
    let mut b = Builder::default();
    let rings = divisions(height, TAU * radius / segments as f64);
    let ids = b.revolution(segments, rings, |f| (radius, f * height));
    if bottom {
        b.fan(&ids[0], Vec3::zeros());
    }
    b.build()
}

/// How the top of a funnel is specified.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FunnelTop {
    /// Inner diameter of the top rim (m).
    Diameter(f64),
    /// Vertical height of the cone from outlet to top rim (m).
    ConeHeight(f64),
}

/// A conical funnel (cone frustum, outlet at the bottom) for the angle-of-repose test.
///
/// Body frame: z up along the funnel axis; z = 0 is the base on which the heap forms (not part
/// of the mesh); the outlet rim is the circle of diameter `outlet_diameter` at
/// z = `outlet_height`; the wall rises outward at `wall_inclination_deg` from the horizontal
/// up to the top rim.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FunnelSpec {
    /// Wall angle from the horizontal, degrees, in (0, 90). The paper's funnel is 60°.
    pub wall_inclination_deg: f64,
    /// Diameter of the outlet (m).
    pub outlet_diameter: f64,
    /// Height of the outlet above the base z = 0 (m).
    pub outlet_height: f64,
    /// Top rim diameter or cone height.
    pub top: FunnelTop,
    /// Facets around the axis (at least 8; 64 is smooth enough for mm-sized grains).
    #[serde(default = "default_segments")]
    pub segments: usize,
}

impl FunnelSpec {
    /// `(top diameter, cone height)` implied by the spec, validated.
    pub fn top_diameter_and_height(&self) -> Result<(f64, f64), MeshError> {
        let angle = self.wall_inclination_deg;
        if !(angle.is_finite() && angle > 0.0 && angle < 90.0) {
            return Err(MeshError::parameter(
                "wall_inclination_deg",
                angle,
                "must be strictly between 0 and 90 degrees",
            ));
        }
        require_positive("outlet_diameter", self.outlet_diameter)?;
        require_non_negative("outlet_height", self.outlet_height)?;
        let tan = angle.to_radians().tan();
        match self.top {
            FunnelTop::Diameter(d) => {
                require_positive("top_diameter", d)?;
                if d <= self.outlet_diameter {
                    return Err(MeshError::parameter(
                        "top_diameter",
                        d,
                        format!(
                            "must be larger than outlet_diameter = {}",
                            self.outlet_diameter
                        ),
                    ));
                }
                Ok((d, 0.5 * (d - self.outlet_diameter) * tan))
            }
            FunnelTop::ConeHeight(h) => {
                require_positive("cone_height", h)?;
                Ok((self.outlet_diameter + 2.0 * h / tan, h))
            }
        }
    }
}

/// Cone-frustum funnel; see [`FunnelSpec`] for the frame.
pub fn funnel(spec: &FunnelSpec) -> Result<TriMesh, MeshError> {
    let (top_diameter, cone_height) = spec.top_diameter_and_height()?;
    require_count("segments", spec.segments, 8)?;
    let (r0, r1) = (0.5 * spec.outlet_diameter, 0.5 * top_diameter);
    let slant = (r1 - r0).hypot(cone_height);
    let rings = divisions(slant, TAU * r0.max(0.5 * r1) / spec.segments as f64);
    let z0 = spec.outlet_height;
    let mut b = Builder::default();
    b.revolution(spec.segments, rings, |f| {
        (r0 + f * (r1 - r0), z0 + f * cone_height)
    });
    b.build()
}

/// Helical auger (drill) for the auger test.
///
/// Body frame: the auger axis is z; the tip is at z = 0 and the shaft goes up to
/// z = `shaft_length`. The drill tip (if any) is a cone from the apex at z = 0 up to the shaft
/// at z = `tip_length`; without a tip the shaft's bottom is a flat disc at z = 0. The flight
/// starts at the top of the tip (angle 0 on the +x axis) and winds up for `flight_length`.
/// The flight is a helicoid between the shaft and `flight_outer_diameter`, thickened
/// axially by `flight_thickness` (two helicoid faces, an outer rim band and two end caps).
///
/// `right_handed = true` is the usual drill flight: the flight rises counter-clockwise seen from
/// above, so turning the auger clockwise seen from above (negative rpm about +z, see
/// `kinematics`) lifts the soil.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AugerSpec {
    pub shaft_diameter: f64,
    pub flight_outer_diameter: f64,
    /// Axial advance of the flight per turn (m).
    pub pitch: f64,
    /// Axial length of the flighted part (m).
    pub flight_length: f64,
    /// Axial thickness of the flight (m), less than the pitch.
    pub flight_thickness: f64,
    /// Total length of the shaft from the tip (m), at least tip + flight length.
    pub shaft_length: f64,
    /// Length of the conical drill tip (m); 0 for a flat-ended shaft.
    #[serde(default)]
    pub tip_length: f64,
    /// Facets per turn around the axis (at least 12; 64 is a good default).
    #[serde(default = "default_segments")]
    pub segments_per_turn: usize,
    #[serde(default = "default_true")]
    pub right_handed: bool,
}

impl AugerSpec {
    fn validate(&self) -> Result<(), MeshError> {
        require_positive("shaft_diameter", self.shaft_diameter)?;
        require_positive("flight_outer_diameter", self.flight_outer_diameter)?;
        if self.flight_outer_diameter <= self.shaft_diameter {
            return Err(MeshError::parameter(
                "flight_outer_diameter",
                self.flight_outer_diameter,
                format!("must exceed shaft_diameter = {}", self.shaft_diameter),
            ));
        }
        require_positive("pitch", self.pitch)?;
        require_positive("flight_length", self.flight_length)?;
        require_positive("flight_thickness", self.flight_thickness)?;
        if self.flight_thickness >= self.pitch {
            return Err(MeshError::parameter(
                "flight_thickness",
                self.flight_thickness,
                format!(
                    "must be less than pitch = {} (successive turns would overlap)",
                    self.pitch
                ),
            ));
        }
        require_non_negative("tip_length", self.tip_length)?;
        require_positive("shaft_length", self.shaft_length)?;
        let needed = self.tip_length + self.flight_length + 0.5 * self.flight_thickness;
        if self.shaft_length < needed {
            return Err(MeshError::parameter(
                "shaft_length",
                self.shaft_length,
                format!(
                    "must be at least tip_length + flight_length + flight_thickness/2 = {needed}"
                ),
            ));
        }
        require_count("segments_per_turn", self.segments_per_turn, 12)?;
        let turns = self.flight_length / self.pitch;
        if turns * self.segments_per_turn as f64 > MAX_SUBDIVISIONS as f64 {
            return Err(MeshError::parameter(
                "flight_length",
                self.flight_length,
                format!(
                    "too many flight segments ({turns:.0} turns × {} per turn)",
                    self.segments_per_turn
                ),
            ));
        }
        Ok(())
    }
}

/// Builds the auger: shaft + optional conical tip + thick helical flight.
pub fn auger(spec: &AugerSpec) -> Result<TriMesh, MeshError> {
    spec.validate()?;
    let rs = 0.5 * spec.shaft_diameter;
    let ro = 0.5 * spec.flight_outer_diameter;
    let n = spec.segments_per_turn;
    // Shaft facets as long as the flight's outer facets are wide: squarer facets on the thin
    // shaft would multiply its triangle count without making contacts any smoother.
    let segment_length = TAU * ro / n as f64;
    let mut b = Builder::default();

    // Shaft from the top of the tip to the top, then the tip (or a flat end) below it.
    let shaft_rings = divisions(spec.shaft_length - spec.tip_length, segment_length);
    let shaft = b.revolution(n, shaft_rings, |f| {
        (
            rs,
            spec.tip_length + f * (spec.shaft_length - spec.tip_length),
        )
    });
    b.fan(&shaft[shaft_rings], Vec3::new(0.0, 0.0, spec.shaft_length));
    if spec.tip_length > 0.0 {
        let apex = b.vertex(Vec3::zeros());
        let ring = &shaft[0];
        for s in 0..n {
            b.triangles.push([apex, ring[(s + 1) % n], ring[s]]);
        }
    } else {
        b.fan(&shaft[0].clone(), Vec3::zeros());
    }

    // Flight: angle φ ∈ [0, φ_end], mid-surface height z(φ) = z0 + pitch φ / 2π; the two faces
    // are at z(φ) ± t/2. Radial subdivisions keep the faces' triangles roughly square.
    let handed = if spec.right_handed { 1.0 } else { -1.0 };
    let turns = spec.flight_length / spec.pitch;
    let steps = ((turns * n as f64).ceil() as usize).max(1);
    let radial = divisions(ro - rs, TAU * ro / n as f64).min(16);
    let half_t = 0.5 * spec.flight_thickness;
    let z0 = spec.tip_length + half_t;
    let point = |u: f64, v: f64, dz: f64| {
        // u: fraction of the flight length, v: fraction from shaft to outer edge.
        let phi = u * turns * TAU;
        let r = rs + v * (ro - rs);
        Vec3::new(
            r * phi.cos(),
            handed * r * phi.sin(),
            z0 + u * spec.flight_length + dz,
        )
    };
    let lower = b.sheet(steps, radial, |u, v| point(u, v, -half_t));
    let upper = b.sheet(steps, radial, |u, v| point(u, v, half_t));
    let at = |ids: &[u32], i: usize, j: usize| ids[j * (steps + 1) + i];
    // Outer rim band joins the outer edges of both faces.
    for i in 0..steps {
        b.quad(
            at(&lower, i, radial),
            at(&lower, i + 1, radial),
            at(&upper, i + 1, radial),
            at(&upper, i, radial),
        );
    }
    // End caps close the flight's start and end.
    for &i in &[0, steps] {
        for j in 0..radial {
            b.quad(
                at(&lower, i, j),
                at(&lower, i, j + 1),
                at(&upper, i, j + 1),
                at(&upper, i, j),
            );
        }
    }
    b.build()
}

/// Any generated or imported geometry, as written in a run configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum MeshSpec {
    Plane {
        size_x: f64,
        size_y: f64,
        cells_x: usize,
        cells_y: usize,
    },
    OpenBox {
        size_x: f64,
        size_y: f64,
        height: f64,
    },
    Cuboid {
        size_x: f64,
        size_y: f64,
        height: f64,
    },
    Cylinder {
        radius: f64,
        height: f64,
        segments: usize,
        bottom: bool,
    },
    Funnel(FunnelSpec),
    Auger(AugerSpec),
    /// An STL file; `scale` converts its units to metres (0.001 for millimetres). The engine
    /// does no file I/O: [`MeshSpec::build`] asks its caller for the file's bytes.
    Stl {
        path: std::path::PathBuf,
        #[serde(default = "default_scale")]
        scale: f64,
    },
}

impl MeshSpec {
    /// Generates the mesh (in its documented body frame). `read_file` supplies the bytes of an
    /// STL path (the caller's file system, an archive, a test's memory): the engine itself
    /// reads no files.
    pub fn build(
        &self,
        read_file: &dyn Fn(&std::path::Path) -> Result<Vec<u8>, String>,
    ) -> Result<TriMesh, MeshError> {
        match self {
            MeshSpec::Plane {
                size_x,
                size_y,
                cells_x,
                cells_y,
            } => plane(*size_x, *size_y, *cells_x, *cells_y),
            MeshSpec::OpenBox {
                size_x,
                size_y,
                height,
            } => open_box(*size_x, *size_y, *height),
            MeshSpec::Cuboid {
                size_x,
                size_y,
                height,
            } => cuboid(*size_x, *size_y, *height),
            MeshSpec::Cylinder {
                radius,
                height,
                segments,
                bottom,
            } => cylinder(*radius, *height, *segments, *bottom),
            MeshSpec::Funnel(spec) => funnel(spec),
            MeshSpec::Auger(spec) => auger(spec),
            MeshSpec::Stl { path, scale } => {
                let name = path.display().to_string();
                let bytes = read_file(path).map_err(|reason| {
                    MeshError::Stl(StlError {
                        source_name: name.clone(),
                        reason: format!("cannot read file: {reason}"),
                    })
                })?;
                TriMesh::from_stl_bytes_named(&bytes, *scale, &name)
            }
        }
    }
}
