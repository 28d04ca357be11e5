//! Geometry side of the engine: meshes and sphere contacts, STL, generators, kinematics, size
//! distributions and particle factories.

use std::f64::consts::{PI, TAU};

use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use repose_engine::distribution::{
    DistributionError, SieveRow, SizeDistribution, SizeDistributionSpec,
};
use repose_engine::factory::{Factory, FactorySpec, ListedParticle, ParticleList, Region};
use repose_engine::kinematics::{Motion, MotionError, RotationSegment, TranslationSegment};
use repose_engine::math::{Pose, Rotation, Vec3};
use repose_engine::mesh::generators::{
    auger, cuboid, cylinder, funnel, open_box, plane, AugerSpec, FunnelSpec, FunnelTop, MeshSpec,
};
use repose_engine::mesh::{MeshContact, MeshError, TriMesh};

fn contacts(mesh: &TriMesh, center: Vec3, radius: f64) -> Vec<MeshContact> {
    let mut out = Vec::new();
    mesh.sphere_contacts(center, radius, &mut out);
    out
}

fn assert_close(a: Vec3, b: Vec3, tol: f64, what: &str) {
    assert!((a - b).norm() <= tol, "{what}: {a:?} != {b:?}");
}

/// Same contacts up to order and to which triangle reports a shared edge/vertex contact.
fn assert_same_contacts(mut a: Vec<MeshContact>, mut b: Vec<MeshContact>, context: &str) {
    assert_eq!(a.len(), b.len(), "{context}: {a:?} vs {b:?}");
    let key = |c: &MeshContact| (c.point.x, c.point.y, c.point.z);
    a.sort_by(|x, y| key(x).partial_cmp(&key(y)).unwrap());
    b.sort_by(|x, y| key(x).partial_cmp(&key(y)).unwrap());
    for (x, y) in a.iter().zip(&b) {
        assert_close(x.point, y.point, 1e-9, context);
        assert_close(x.normal, y.normal, 1e-9, context);
        assert!((x.overlap - y.overlap).abs() < 1e-9, "{context}");
    }
}

fn test_auger_spec() -> AugerSpec {
    AugerSpec {
        shaft_diameter: 0.02,
        flight_outer_diameter: 0.06,
        pitch: 0.04,
        flight_length: 0.2,
        flight_thickness: 0.003,
        shaft_length: 0.5,
        tip_length: 0.03,
        segments_per_turn: 48,
        right_handed: true,
    }
}

fn paper_funnel_spec() -> FunnelSpec {
    FunnelSpec {
        wall_inclination_deg: 60.0,
        outlet_diameter: 0.02,
        outlet_height: 0.05,
        top: FunnelTop::Diameter(0.1),
        segments: 64,
    }
}

// ---------------------------------------------------------------------------------------------
// Sphere contacts
// ---------------------------------------------------------------------------------------------

/// 1 m × 1 m plane in 4 × 4 cells: cell edges at x, y ∈ {-0.5, -0.25, 0, 0.25, 0.5}; diagonals
/// run from (x, y) to (x + 0.25, y + 0.25).
fn test_plane() -> TriMesh {
    plane(1.0, 1.0, 4, 4).unwrap()
}

#[test]
fn sphere_on_shared_edges_of_a_plane_gets_one_contact() {
    let mesh = test_plane();
    let radius = 0.01;
    let height = 0.009; // overlap 1 mm
                        // On an axis-aligned cell edge, on a diagonal, and from below (two-sided).
    for (x, y, z) in [
        (0.0, 0.1, height),
        (0.1, 0.1, height),
        (0.25, -0.3, height),
        (0.0, 0.1, -height),
    ] {
        let c = contacts(&mesh, Vec3::new(x, y, z), radius);
        assert_eq!(c.len(), 1, "at ({x}, {y}, {z}): {c:?}");
        assert!((c[0].overlap - 0.001).abs() < 1e-12);
        assert_close(
            c[0].normal,
            Vec3::new(0.0, 0.0, z.signum()),
            1e-12,
            "normal",
        );
        assert_close(c[0].point, Vec3::new(x, y, 0.0), 1e-12, "point");
    }
}

#[test]
fn sphere_on_shared_vertices_of_a_plane_gets_one_contact() {
    let mesh = test_plane();
    let shared_by = |p: Vec3| {
        mesh.triangles()
            .iter()
            .filter(|t| {
                t.iter()
                    .any(|&i| (mesh.vertices()[i as usize] - p).norm() < 1e-12)
            })
            .count()
    };
    // Interior vertices (6 triangles) and a boundary vertex (3 triangles).
    for (x, y, expected_sharing) in [(0.0, 0.0, 6), (0.25, -0.25, 6), (-0.5, 0.0, 3)] {
        let p = Vec3::new(x, y, 0.0);
        assert_eq!(shared_by(p), expected_sharing);
        let c = contacts(&mesh, p + Vec3::new(0.0, 0.0, 0.009), 0.01);
        assert_eq!(c.len(), 1, "at ({x}, {y}): {c:?}");
        assert!((c[0].overlap - 0.001).abs() < 1e-12);
        assert_close(c[0].normal, Vec3::z(), 1e-12, "normal");
    }
}

#[test]
fn sliding_across_a_plane_is_continuous() {
    let mesh = test_plane();
    let radius = 0.02;
    // A diagonal-ish path crossing cell edges, diagonals and vertices (passes (0, 0) exactly).
    let steps = 2000;
    for i in 0..=steps {
        let s = -0.4 + 0.8 * i as f64 / steps as f64;
        let center = Vec3::new(s, 0.5 * s, 0.015);
        let c = contacts(&mesh, center, radius);
        assert_eq!(c.len(), 1, "at {center:?}: {c:?}");
        assert!((c[0].overlap - 0.005).abs() < 1e-12, "at {center:?}");
        assert_close(c[0].normal, Vec3::z(), 1e-12, "normal");
        assert_close(c[0].point, Vec3::new(s, 0.5 * s, 0.0), 1e-12, "point");
    }
}

#[test]
fn sphere_rolling_over_a_convex_box_edge_has_continuous_contact() {
    let mesh = cuboid(1.0, 1.0, 1.0).unwrap();
    // Edge between the top face (z = 1) and the +x wall (x = 0.5), along y.
    let edge_point = Vec3::new(0.5, 0.1, 1.0);
    let (radius, distance) = (0.01, 0.008);
    let mut previous_normal: Option<Vec3> = None;
    // From above the top face, around the edge, to beside the wall.
    for i in -50..=150 {
        let angle = i as f64 / 100.0 * PI / 2.0; // 0 = straight up, π/2 = straight out in +x
        let center = if angle < 0.0 {
            edge_point + Vec3::new(angle * 0.01, 0.0, distance)
        } else if angle > PI / 2.0 {
            edge_point + Vec3::new(distance, 0.0, -(angle - PI / 2.0) * 0.01)
        } else {
            edge_point + distance * Vec3::new(angle.sin(), 0.0, angle.cos())
        };
        let c = contacts(&mesh, center, radius);
        assert_eq!(c.len(), 1, "angle {angle}: {c:?}");
        assert!(
            (c[0].overlap - (radius - distance)).abs() < 1e-12,
            "angle {angle}"
        );
        if let Some(n) = previous_normal {
            assert!(
                (c[0].normal - n).norm() < 0.02,
                "normal jumps at angle {angle}"
            );
        }
        previous_normal = Some(c[0].normal);
    }
}

#[test]
fn sphere_against_convex_box_edge_and_corner_gets_one_contact() {
    let mesh = cuboid(1.0, 1.0, 1.0).unwrap();
    let d = 0.004; // per axis, distance 0.004·√2 ≈ 5.7 mm < radius
    let edge = contacts(&mesh, Vec3::new(0.5 + d, 0.2, 1.0 + d), 0.01);
    assert_eq!(edge.len(), 1, "{edge:?}");
    assert_close(edge[0].point, Vec3::new(0.5, 0.2, 1.0), 1e-12, "edge point");
    assert_close(
        edge[0].normal,
        Vec3::new(1.0, 0.0, 1.0).normalize(),
        1e-12,
        "edge normal",
    );
    assert!((edge[0].overlap - (0.01 - d * 2f64.sqrt())).abs() < 1e-12);

    // Vertical edge between two walls (outside the open box too).
    let wall_edge = contacts(
        &open_box(1.0, 1.0, 1.0).unwrap(),
        Vec3::new(0.5 + d, 0.5 + d, 0.5),
        0.01,
    );
    assert_eq!(wall_edge.len(), 1, "{wall_edge:?}");
    assert_close(
        wall_edge[0].point,
        Vec3::new(0.5, 0.5, 0.5),
        1e-12,
        "wall edge point",
    );

    let corner = contacts(&mesh, Vec3::new(-0.5 - d, 0.5 + d, 1.0 + d), 0.01);
    assert_eq!(corner.len(), 1, "{corner:?}");
    assert_close(
        corner[0].point,
        Vec3::new(-0.5, 0.5, 1.0),
        1e-12,
        "corner point",
    );
    assert_close(
        corner[0].normal,
        Vec3::new(-1.0, 1.0, 1.0).normalize(),
        1e-12,
        "corner normal",
    );
}

#[test]
fn sphere_in_inner_corners_of_the_open_box_gets_one_contact_per_wall() {
    let mesh = open_box(1.0, 0.8, 0.5).unwrap();
    let (radius, gap) = (0.01, 0.009);
    // Floor/wall edge: floor and +x wall.
    let two = contacts(&mesh, Vec3::new(0.5 - gap, 0.1, gap), radius);
    assert_eq!(two.len(), 2, "{two:?}");
    let mut normals: Vec<Vec3> = two.iter().map(|c| c.normal).collect();
    normals.sort_by(|a, b| a.x.partial_cmp(&b.x).unwrap());
    assert_close(normals[0], Vec3::new(-1.0, 0.0, 0.0), 1e-12, "wall normal");
    assert_close(normals[1], Vec3::z(), 1e-12, "floor normal");
    for c in &two {
        assert!((c.overlap - 0.001).abs() < 1e-12);
    }
    // Floor + two walls.
    let three = contacts(&mesh, Vec3::new(-0.5 + gap, 0.4 - gap, gap), radius);
    assert_eq!(three.len(), 3, "{three:?}");
    let sum: Vec3 = three.iter().map(|c| c.normal).sum();
    assert_close(sum, Vec3::new(1.0, -1.0, 1.0), 1e-12, "corner normals");
    // Two walls, well above the floor.
    let walls = contacts(&mesh, Vec3::new(-0.5 + gap, 0.4 - gap, 0.25), radius);
    assert_eq!(walls.len(), 2, "{walls:?}");
}

#[test]
fn sphere_sliding_inside_facetted_walls_gets_one_continuous_contact() {
    // Inside a 24-facet cylinder (15° creases) and along the inner wall of the funnel the
    // sphere meets concave creases; it must still see one contact whose overlap is continuous.
    let tube = cylinder(0.1, 0.2, 24, true).unwrap();
    let radius = 0.01;
    let mut previous: Option<f64> = None;
    for i in 0..=3600 {
        let phi = TAU * i as f64 / 3600.0;
        let center = Vec3::new(0.092 * phi.cos(), 0.092 * phi.sin(), 0.1);
        let c = contacts(&tube, center, radius);
        assert_eq!(c.len(), 1, "at φ = {phi}: {c:?}");
        if let Some(p) = previous {
            assert!(
                (c[0].overlap - p).abs() < 1e-4,
                "overlap jumps at φ = {phi}"
            );
        }
        previous = Some(c[0].overlap);
    }
    // In the bottom corner of the tube: wall + floor.
    let corner = contacts(&tube, Vec3::new(0.092, 0.0, 0.008), radius);
    assert_eq!(corner.len(), 2, "{corner:?}");

    let f = funnel(&paper_funnel_spec()).unwrap();
    let tan = 60f64.to_radians().tan();
    let mut previous: Option<f64> = None;
    for i in 0..=720 {
        let phi = TAU * i as f64 / 720.0;
        // 2 mm above the wall (vertically) at radius 30 mm.
        let (r, z) = (0.03, 0.05 + 0.02 * tan + 0.002);
        let c = contacts(&f, Vec3::new(r * phi.cos(), r * phi.sin(), z), 0.002);
        assert_eq!(c.len(), 1, "funnel at φ = {phi}: {c:?}");
        if let Some(p) = previous {
            assert!(
                (c[0].overlap - p).abs() < 1e-4,
                "funnel overlap jumps at φ = {phi}"
            );
        }
        previous = Some(c[0].overlap);
    }
}

#[test]
fn smooth_angle_can_be_disabled() {
    let tube = cylinder(0.1, 0.2, 24, false)
        .unwrap()
        .with_smooth_angle(0.0)
        .unwrap();
    // Exactly on a crease between two facets (vertices at multiples of 15°), well inside.
    let phi = 7.5f64.to_radians();
    let r_crease = 0.1 * 7.5f64.to_radians().cos(); // facet midline distance
    let center = Vec3::new(
        (r_crease - 0.005) * phi.cos(),
        (r_crease - 0.005) * phi.sin(),
        0.1,
    );
    // Off the facet midline toward the crease at 15°: two facets in reach with 0° merging.
    let at_crease = Vec3::new(
        0.093 * 15f64.to_radians().cos(),
        0.093 * 15f64.to_radians().sin(),
        0.1,
    );
    assert_eq!(contacts(&tube, center, 0.01).len(), 1);
    assert_eq!(contacts(&tube, at_crease, 0.01).len(), 2);
    let merged = cylinder(0.1, 0.2, 24, false).unwrap();
    assert_eq!(contacts(&merged, at_crease, 0.01).len(), 1);
    assert!(cylinder(0.1, 0.2, 24, false)
        .unwrap()
        .with_smooth_angle(90.0)
        .is_err());
}

#[test]
fn no_contact_when_apart_and_invalid_queries_are_empty() {
    let mesh = test_plane();
    assert!(contacts(&mesh, Vec3::new(0.0, 0.0, 0.0101), 0.01).is_empty());
    assert!(contacts(&mesh, Vec3::new(3.0, 0.0, 0.0), 0.01).is_empty());
    assert!(contacts(&mesh, Vec3::new(f64::NAN, 0.0, 0.0), 0.01).is_empty());
    assert!(contacts(&mesh, Vec3::zeros(), -1.0).is_empty());
    assert!(contacts(&mesh, Vec3::zeros(), f64::NAN).is_empty());
    // Appends, does not clear.
    let mut out = contacts(&mesh, Vec3::new(0.1, 0.1, 0.005), 0.01);
    mesh.sphere_contacts(Vec3::new(0.2, 0.1, 0.005), 0.01, &mut out);
    assert_eq!(out.len(), 2);
}

#[test]
fn contact_with_a_thin_flight_from_both_sides() {
    let mesh = auger(&test_auger_spec()).unwrap();
    // Just above and below the flight's mid-surface at φ = π/2, r = 2 cm (between shaft 1 cm
    // and outer edge 3 cm).
    let spec = test_auger_spec();
    let phi = PI / 2.0;
    let z_mid = spec.tip_length + 0.5 * spec.flight_thickness + spec.pitch * phi / TAU;
    let half = 0.5 * spec.flight_thickness;
    for side in [1.0, -1.0] {
        let center = Vec3::new(0.0, 0.02, z_mid + side * (half + 0.0005));
        let c = contacts(&mesh, center, 0.001);
        assert_eq!(c.len(), 1, "side {side}: {c:?}");
        // The helicoid is tilted (pitch / 2πr), so the distance is the vertical gap × n_z.
        let expected = 0.001 - 0.0005 * c[0].normal.z.abs();
        assert!((c[0].overlap - expected).abs() < 2e-6, "{c:?}");
        assert!(c[0].normal.z * side > 0.9, "{c:?}");
    }
}

fn meshes_for_comparison() -> Vec<TriMesh> {
    vec![
        test_plane(),
        open_box(1.0, 0.8, 0.5).unwrap(),
        funnel(&paper_funnel_spec()).unwrap(),
        auger(&test_auger_spec()).unwrap(),
        cylinder(0.05, 0.2, 24, true).unwrap(),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn broad_phase_matches_brute_force(
        which in 0usize..5,
        u in 0.0..1.0f64, v in 0.0..1.0f64, w in 0.0..1.0f64,
        radius_fraction in 0.001..0.3f64,
    ) {
        thread_local! {
            static MESHES: Vec<TriMesh> = meshes_for_comparison();
        }
        MESHES.with(|meshes| {
            let mesh = &meshes[which];
            let (lo, hi) = mesh.aabb();
            let size = hi - lo;
            let margin = 0.1 * size.max();
            let center = lo - Vec3::repeat(margin)
                + Vec3::new(u, v, w).component_mul(&(size + Vec3::repeat(2.0 * margin)));
            let radius = radius_fraction * size.max();
            let mut fast = Vec::new();
            mesh.sphere_contacts(center, radius, &mut fast);
            let mut slow = Vec::new();
            mesh.sphere_contacts_brute_force(center, radius, &mut slow);
            assert_same_contacts(fast.clone(), slow, &format!("mesh {which} at {center:?} r {radius}"));
            for c in &fast {
                prop_assert!(c.overlap > 0.0 && c.overlap <= radius);
                prop_assert!((c.normal.norm() - 1.0).abs() < 1e-9);
                // The normal points from the surface point toward the centre.
                let d = center - c.point;
                prop_assert!((d.norm() - (radius - c.overlap)).abs() < 1e-9);
                if d.norm() > 1e-9 {
                    prop_assert!((d.normalize() - c.normal).norm() < 1e-6);
                }
            }
            Ok(())
        })?;
    }

    /// The world's cached wall candidates: a sphere whose distance to the mesh has changed by
    /// less than `skin` since its candidates were listed (radius + skin; in the world, the
    /// particle's own half skin plus the geometry's allowance) finds, among them, exactly the
    /// contacts of the full search.
    #[test]
    fn candidate_triangles_find_the_same_contacts_as_the_full_search(
        which in 0usize..5,
        u in 0.0..1.0f64, v in 0.0..1.0f64, w in 0.0..1.0f64,
        radius_fraction in 0.001..0.3f64,
        skin_fraction in 0.0..1.0f64,
        dx in -1.0..1.0f64, dy in -1.0..1.0f64, dz in -1.0..1.0f64,
    ) {
        thread_local! {
            static MESHES: Vec<TriMesh> = meshes_for_comparison();
        }
        MESHES.with(|meshes| {
            let mesh = &meshes[which];
            let (lo, hi) = mesh.aabb();
            let size = hi - lo;
            let margin = 0.1 * size.max();
            let listed_at = lo - Vec3::repeat(margin)
                + Vec3::new(u, v, w).component_mul(&(size + Vec3::repeat(2.0 * margin)));
            let radius = radius_fraction * size.max();
            let skin = skin_fraction * radius;
            let mut candidates = Vec::new();
            mesh.triangles_near(listed_at, radius + skin, &mut candidates);
            prop_assert!(candidates.windows(2).all(|p| p[0] < p[1]));
            let step = Vec3::new(dx, dy, dz);
            let center = listed_at + step * (0.999 * skin / step.norm().max(1.0));
            let mut among = Vec::new();
            mesh.sphere_contacts_among(center, radius, &candidates, &mut among);
            let mut full = Vec::new();
            mesh.sphere_contacts(center, radius, &mut full);
            assert_same_contacts(among, full, &format!("mesh {which} at {center:?} r {radius}"));
            Ok(())
        })?;
    }

    #[test]
    fn facetted_tube_wall_gives_exactly_one_contact_inside_and_outside(
        phi in 0.0..TAU,
        gap in -0.004..0.004f64,
        z in 0.02..0.18f64,
        radius in 0.0046..0.005f64,
    ) {
        // 32 facets (11.25° creases), facet planes at 0.1·cos(π/32) from the axis; the sphere
        // centre is within ±4 mm of the circle (at most 4.5 mm from the facets), inside (gap < 0) or outside.
        thread_local! {
            static TUBE: TriMesh = cylinder(0.1, 0.2, 32, false).unwrap();
        }
        let r_centre = 0.1 + gap;
        let center = Vec3::new(r_centre * phi.cos(), r_centre * phi.sin(), z);
        let c = TUBE.with(|tube| contacts(tube, center, radius));
        prop_assert_eq!(c.len(), 1, "{:?}", c);
        prop_assert!(c[0].normal.z.abs() < 1e-9);
    }

    #[test]
    fn flat_plane_always_gives_exactly_one_contact(
        x in -0.45..0.45f64, y in -0.45..0.45f64, h in -0.0099..0.0099f64,
    ) {
        let mesh = plane(1.0, 1.0, 7, 5).unwrap();
        let c = contacts(&mesh, Vec3::new(x, y, h), 0.01);
        prop_assert_eq!(c.len(), 1);
        prop_assert!((c[0].overlap - (0.01 - h.abs())).abs() < 1e-12);
    }
}

// ---------------------------------------------------------------------------------------------
// Mesh construction and STL
// ---------------------------------------------------------------------------------------------

#[test]
fn mesh_rejects_invalid_geometry_with_named_errors() {
    let v = vec![Vec3::zeros(), Vec3::x(), Vec3::y()];
    let e = TriMesh::new(v.clone(), vec![[0, 1, 7]]).unwrap_err();
    assert!(e.to_string().contains("vertex 7"), "{e}");
    let e = TriMesh::new(
        vec![Vec3::zeros(), Vec3::x(), Vec3::x() * 2.0],
        vec![[0, 1, 2]],
    )
    .unwrap_err();
    assert!(
        matches!(e, MeshError::DegenerateTriangle { triangle: 0, .. }),
        "{e}"
    );
    let mut inf = v;
    inf[2].z = f64::INFINITY;
    let e = TriMesh::new(inf, vec![[0, 1, 2]]).unwrap_err();
    assert!(e.to_string().contains("vertex 2"), "{e}");
}

#[test]
fn adjacency_works_with_duplicated_vertices() {
    // Two triangles of a square that do not share vertex indices: still one contact on the
    // diagonal, because adjacency is found geometrically.
    let mesh = TriMesh::new(
        vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ],
        vec![[0, 1, 2], [3, 4, 5]],
    )
    .unwrap();
    for x in [0.49, 0.5, 0.51] {
        let c = contacts(&mesh, Vec3::new(x, 0.5, 0.05), 0.1);
        assert_eq!(c.len(), 1, "{c:?}");
        let c = contacts(&mesh, Vec3::new(x, 0.5 + 1e-7, 0.05), 0.1);
        assert_eq!(c.len(), 1, "{c:?}");
    }
}

#[test]
fn stl_binary_round_trip() {
    let mesh = auger(&test_auger_spec()).unwrap();
    let bytes = mesh.to_stl_binary();
    assert_eq!(bytes.len(), 84 + 50 * mesh.triangles().len());
    let back = TriMesh::from_stl_bytes(&bytes, 1.0).unwrap();
    assert_eq!(back.triangles().len(), mesh.triangles().len());
    // Every corner survives up to f32 precision, and shared corners are welded again (the
    // generator leaves one coincident pair: flight start on the shaft's bottom ring).
    let distinct: std::collections::HashSet<[i64; 3]> = mesh
        .vertices()
        .iter()
        .map(|v| [0, 1, 2].map(|a| (v[a] * 1e8).round() as i64))
        .collect();
    assert_eq!(back.vertices().len(), distinct.len());
    for t in 0..mesh.triangles().len() {
        for (a, b) in mesh.corners(t).iter().zip(back.corners(t).iter()) {
            assert_close(*a, *b, 1e-7, "corner");
        }
    }
    assert!((back.area() - mesh.area()).abs() < 1e-6 * mesh.area());
}

#[test]
fn stl_ascii_round_trip_with_scale() {
    let mesh = funnel(&paper_funnel_spec()).unwrap();
    // Write in millimetres, read back with scale 0.001.
    let mm = mesh.transformed(&Pose::identity()).unwrap();
    let text_mm = {
        let scaled = TriMesh::new(
            mm.vertices().iter().map(|v| v * 1000.0).collect(),
            mm.triangles().to_vec(),
        )
        .unwrap();
        scaled.to_stl_ascii("funnel in mm")
    };
    let back = TriMesh::from_stl_bytes(text_mm.as_bytes(), 0.001).unwrap();
    assert_eq!(back.triangles().len(), mesh.triangles().len());
    assert_eq!(back.vertices().len(), mesh.vertices().len());
    for t in 0..mesh.triangles().len() {
        for (a, b) in mesh.corners(t).iter().zip(back.corners(t).iter()) {
            assert_close(*a, *b, 1e-12, "corner");
        }
    }
    // Contacts agree after the round trip.
    let center = Vec3::new(0.03, 0.0, 0.08);
    assert_same_contacts(
        contacts(&mesh, center, 0.01),
        contacts(&back, center, 0.01),
        "funnel",
    );
}

#[test]
fn binary_stl_whose_header_starts_with_solid_is_read_as_binary() {
    let mut bytes = plane(1.0, 1.0, 2, 2).unwrap().to_stl_binary();
    bytes[..14].copy_from_slice(b"solid exported");
    let mesh = TriMesh::from_stl_bytes(&bytes, 1.0).unwrap();
    assert_eq!(mesh.triangles().len(), 8);
    assert_eq!(mesh.vertices().len(), 9);
}

#[test]
fn an_stl_mesh_spec_asks_its_caller_for_the_bytes_and_errors_name_the_file() {
    use repose_engine::mesh::MeshSpec;
    let spec = |path: &str| MeshSpec::Stl {
        path: path.into(),
        scale: 1.0,
    };
    // The engine reads no file itself: the caller's reader is asked, and its refusal named.
    let refuse = |_: &std::path::Path| -> Result<Vec<u8>, String> { Err("no such file".into()) };
    let e = spec("parts/missing.stl").build(&refuse).unwrap_err();
    let message = e.to_string();
    assert!(message.contains("parts/missing.stl"), "{message}");
    assert!(message.contains("no such file"), "{message}");

    let truncated = |_: &std::path::Path| -> Result<Vec<u8>, String> {
        Ok(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nendloop\n".to_vec())
    };
    let message = spec("parts/broken.stl")
        .build(&truncated)
        .unwrap_err()
        .to_string();
    assert!(message.contains("parts/broken.stl"), "{message}");
    assert!(message.contains("line 5"), "{message}");

    let plate = plane(1.0, 1.0, 2, 2).unwrap().to_stl_binary();
    let read = |p: &std::path::Path| -> Result<Vec<u8>, String> {
        assert_eq!(p, std::path::Path::new("plate.stl"));
        Ok(plate.clone())
    };
    assert_eq!(spec("plate.stl").build(&read).unwrap().triangles().len(), 8);
}

#[test]
fn malformed_stl_is_an_error() {
    let good = plane(1.0, 1.0, 2, 2).unwrap().to_stl_binary();
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("empty", Vec::new()),
        ("short", b"abc".to_vec()),
        ("truncated binary", good[..good.len() - 7].to_vec()),
        ("count too high", {
            let mut b = good.clone();
            b[80..84].copy_from_slice(&1000u32.to_le_bytes());
            b
        }),
        ("zero triangles", {
            let mut b = good[..84].to_vec();
            b[80..84].copy_from_slice(&0u32.to_le_bytes());
            b
        }),
        ("NaN vertex", {
            let mut b = good.clone();
            b[84 + 12..84 + 16].copy_from_slice(&f32::NAN.to_le_bytes());
            b
        }),
        ("all degenerate", {
            let mut b = good[..84 + 50].to_vec();
            b[80..84].copy_from_slice(&1u32.to_le_bytes());
            b[84 + 12..84 + 48].fill(0);
            b
        }),
        (
            "ascii two vertices",
            b"solid a\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n vertex 1 0 0\n endloop\n endfacet\nendsolid a\n".to_vec(),
        ),
        (
            "ascii bad number",
            b"solid a\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n vertex 1 x 0\n vertex 0 1 0\n endloop\n endfacet\nendsolid\n".to_vec(),
        ),
        (
            "ascii nan",
            b"solid a\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n vertex 1 NaN 0\n vertex 0 1 0\n endloop\n endfacet\nendsolid\n".to_vec(),
        ),
        (
            "ascii truncated",
            b"solid a\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n vertex 1 0 0".to_vec(),
        ),
        ("ascii no facets", b"solid a\nendsolid a\n".to_vec()),
        ("ascii not utf8", b"solid \xff\xfe\n".to_vec()),
    ];
    for (name, bytes) in cases {
        match TriMesh::from_stl_bytes(&bytes, 1.0) {
            Err(MeshError::Stl(e)) => assert!(!e.reason.is_empty(), "{name}"),
            other => panic!("{name}: expected an STL error, got {other:?}"),
        }
    }
    let e = TriMesh::from_stl_bytes(&good, 0.0).unwrap_err();
    assert!(e.to_string().contains("scale"), "{e}");
    let e = TriMesh::from_stl_bytes(&good, 1e308 * 10.0).unwrap_err();
    assert!(e.to_string().contains("scale"), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = TriMesh::from_stl_bytes(&bytes, 1.0);
        let mut ascii = b"solid ".to_vec();
        ascii.extend_from_slice(&bytes);
        let _ = TriMesh::from_stl_bytes(&ascii, 1.0);
    }

    #[test]
    fn corrupted_stl_never_panics(
        cut in 0usize..2000,
        flips in proptest::collection::vec((0usize..2000, any::<u8>()), 0..8),
        ascii in any::<bool>(),
        scale in prop_oneof![Just(1.0), Just(1e300), Just(1e-300), -1.0..1.0f64],
    ) {
        let mesh = plane(1.0, 1.0, 3, 3).unwrap();
        let mut bytes = if ascii { mesh.to_stl_ascii("p").into_bytes() } else { mesh.to_stl_binary() };
        for (at, value) in flips {
            if !bytes.is_empty() {
                let n = bytes.len();
                bytes[at % n] = value;
            }
        }
        bytes.truncate(cut.min(bytes.len()));
        if let Ok(m) = TriMesh::from_stl_bytes(&bytes, scale) {
            prop_assert!(m.vertices().iter().all(|v| v.iter().all(|c| c.is_finite())));
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Generators
// ---------------------------------------------------------------------------------------------

#[test]
fn funnel_has_requested_outlet_and_wall_angle() {
    let spec = paper_funnel_spec();
    let mesh = funnel(&spec).unwrap();
    let radial = |v: &Vec3| v.x.hypot(v.y);
    let min_r = mesh
        .vertices()
        .iter()
        .map(radial)
        .fold(f64::INFINITY, f64::min);
    let max_r = mesh.vertices().iter().map(radial).fold(0.0, f64::max);
    assert!(
        (2.0 * min_r - 0.02).abs() < 1e-12,
        "outlet diameter {}",
        2.0 * min_r
    );
    assert!(
        (2.0 * max_r - 0.1).abs() < 1e-12,
        "top diameter {}",
        2.0 * max_r
    );
    let (lo, hi) = mesh.aabb();
    assert!((lo.z - 0.05).abs() < 1e-12, "outlet height {}", lo.z);
    // All outlet-ring vertices at the outlet height; wall angle from every vertex.
    for v in mesh.vertices() {
        let r = radial(v);
        if (r - min_r).abs() < 1e-12 {
            assert!((v.z - 0.05).abs() < 1e-12);
        } else {
            let angle = ((v.z - 0.05) / (r - min_r)).atan().to_degrees();
            assert!((angle - 60.0).abs() < 1e-9, "wall angle {angle}");
        }
    }
    let expected_height = 0.04 * 60f64.to_radians().tan();
    assert!((hi.z - 0.05 - expected_height).abs() < 1e-12);
    // Specifying the cone height instead gives the same funnel.
    let by_height = FunnelSpec {
        top: FunnelTop::ConeHeight(expected_height),
        ..spec
    };
    let (d, h) = by_height.top_diameter_and_height().unwrap();
    assert!((d - 0.1).abs() < 1e-12 && (h - expected_height).abs() < 1e-15);
    // A particle resting on the inner wall is pushed along the wall normal (up and inward).
    let mid_r = 0.03;
    let wall_z = 0.05 + (mid_r - 0.01) * 60f64.to_radians().tan();
    let c = contacts(&mesh, Vec3::new(mid_r, 0.0, wall_z + 0.001), 0.002);
    assert_eq!(c.len(), 1, "{c:?}");
    let n = c[0].normal;
    assert!((n.z - 0.5).abs() < 0.02 && n.x < -0.8, "normal {n:?}");
}

#[test]
fn generators_reject_bad_parameters_naming_them() {
    let check = |r: Result<TriMesh, MeshError>, name: &str| {
        let e = r.unwrap_err();
        assert!(
            matches!(&e, MeshError::InvalidParameter { name: n, .. } if *n == name),
            "expected {name}: {e}"
        );
        assert!(e.to_string().contains(name));
    };
    let f = paper_funnel_spec();
    check(
        funnel(&FunnelSpec {
            wall_inclination_deg: 90.0,
            ..f
        }),
        "wall_inclination_deg",
    );
    check(
        funnel(&FunnelSpec {
            wall_inclination_deg: 0.0,
            ..f
        }),
        "wall_inclination_deg",
    );
    check(
        funnel(&FunnelSpec {
            outlet_diameter: -0.01,
            ..f
        }),
        "outlet_diameter",
    );
    check(
        funnel(&FunnelSpec {
            top: FunnelTop::Diameter(0.01),
            ..f
        }),
        "top_diameter",
    );
    check(
        funnel(&FunnelSpec {
            outlet_height: f64::NAN,
            ..f
        }),
        "outlet_height",
    );
    check(funnel(&FunnelSpec { segments: 3, ..f }), "segments");
    let a = test_auger_spec();
    check(
        auger(&AugerSpec {
            flight_outer_diameter: 0.01,
            ..a
        }),
        "flight_outer_diameter",
    );
    check(
        auger(&AugerSpec {
            flight_thickness: 0.05,
            ..a
        }),
        "flight_thickness",
    );
    check(auger(&AugerSpec { pitch: 0.0, ..a }), "pitch");
    check(
        auger(&AugerSpec {
            shaft_length: 0.1,
            ..a
        }),
        "shaft_length",
    );
    check(
        auger(&AugerSpec {
            segments_per_turn: 4,
            ..a
        }),
        "segments_per_turn",
    );
    check(plane(0.0, 1.0, 1, 1), "size_x");
    check(plane(1.0, 1.0, 0, 1), "cells_x");
    check(open_box(1.0, 1.0, -1.0), "height");
    check(cylinder(0.1, 1.0, 2, false), "segments");
}

#[test]
fn auger_flight_radius_and_pitch_measured_from_vertices() {
    let spec = test_auger_spec();
    let mesh = auger(&spec).unwrap();
    let radial = |v: &Vec3| v.x.hypot(v.y);
    let outer = mesh.vertices().iter().map(radial).fold(0.0, f64::max);
    assert!((outer - 0.03).abs() < 1e-12, "outer radius {outer}");
    let (lo, hi) = mesh.aabb();
    assert!(
        lo.z.abs() < 1e-15 && (hi.z - 0.5).abs() < 1e-12,
        "{lo:?} {hi:?}"
    );

    // Outer-edge vertices at angle 0 (+x axis): one per face per turn, spaced by the pitch.
    let mut lower_face: Vec<f64> = Vec::new();
    let mut at_zero: Vec<f64> = mesh
        .vertices()
        .iter()
        .filter(|v| (radial(v) - outer).abs() < 1e-12 && v.x > 0.0 && v.y.abs() < 1e-9)
        .map(|v| v.z)
        .collect();
    at_zero.sort_by(f64::total_cmp);
    at_zero.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
    // Pairs (lower, upper face) separated by the thickness.
    assert_eq!(at_zero.len(), 2 * 6, "{at_zero:?}"); // 5 turns → 6 crossings of angle 0
    for pair in at_zero.chunks(2) {
        assert!((pair[1] - pair[0] - spec.flight_thickness).abs() < 1e-12);
        lower_face.push(pair[0]);
    }
    for w in lower_face.windows(2) {
        assert!(
            (w[1] - w[0] - spec.pitch).abs() < 1e-12,
            "pitch {}",
            w[1] - w[0]
        );
    }
    assert!((lower_face[0] - spec.tip_length).abs() < 1e-12);
    // Right-handed: rising counter-clockwise seen from above.
    let step = TAU / spec.segments_per_turn as f64;
    let next = mesh
        .vertices()
        .iter()
        .find(|v| {
            (radial(v) - outer).abs() < 1e-12
                && (v.y.atan2(v.x) - step).abs() < 1e-9
                && v.z < lower_face[0] + 0.01
        })
        .expect("vertex one segment counter-clockwise");
    assert!(next.z > lower_face[0]);
}

#[test]
fn mesh_spec_builds_from_json() {
    let json = r#"{"kind":"funnel","wall_inclination_deg":60,"outlet_diameter":0.02,
                   "outlet_height":0.05,"top":{"diameter":0.1},"segments":64}"#;
    let spec: MeshSpec = serde_json::from_str(json).unwrap();
    let no_files = |p: &std::path::Path| -> Result<Vec<u8>, String> {
        Err(format!("{} is not here", p.display()))
    };
    let mesh = spec.build(&no_files).unwrap();
    assert_eq!(
        mesh.vertices(),
        funnel(&paper_funnel_spec()).unwrap().vertices()
    );
    let bin: MeshSpec =
        serde_json::from_str(r#"{"kind":"open_box","size_x":1,"size_y":1,"height":0.5}"#).unwrap();
    assert_eq!(bin.build(&no_files).unwrap().triangles().len(), 10);
    let auger_json = r#"{"kind":"auger","shaft_diameter":0.02,"flight_outer_diameter":0.06,
        "pitch":0.04,"flight_length":0.2,"flight_thickness":0.003,"shaft_length":0.5}"#;
    let spec: MeshSpec = serde_json::from_str(auger_json).unwrap();
    let MeshSpec::Auger(a) = &spec else {
        panic!("not an auger: {spec:?}")
    };
    assert!(a.right_handed && a.segments_per_turn == 64 && a.tip_length == 0.0);
    assert!(spec.build(&no_files).is_ok());
    let missing: MeshSpec =
        serde_json::from_str(r#"{"kind":"stl","path":"/nonexistent/wall.stl","scale":0.001}"#)
            .unwrap();
    let e = missing.build(&no_files).unwrap_err();
    assert!(e.to_string().contains("/nonexistent/wall.stl"), "{e}");
}

#[test]
fn transformed_mesh_moves_contacts_with_it() {
    let mesh = test_plane();
    let pose = Pose::from_parts(
        Vec3::new(0.0, 0.0, 1.0).into(),
        Rotation::from_euler_angles(0.0, PI / 2.0, 0.0),
    );
    let moved = mesh.transformed(&pose).unwrap();
    let body_center = Vec3::new(0.1, 0.1, 0.005);
    let world_center = pose.transform_point(&body_center.into()).coords;
    let a = contacts(&mesh, body_center, 0.01);
    let b = contacts(&moved, world_center, 0.01);
    assert_eq!(a.len(), 1);
    assert_eq!(b.len(), 1);
    assert_close(pose.rotation * a[0].normal, b[0].normal, 1e-12, "normal");
    assert!((a[0].overlap - b[0].overlap).abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------------
// Kinematics
// ---------------------------------------------------------------------------------------------

#[test]
fn drilling_pose_after_feed_down_and_withdraw() {
    // 400 rpm clockwise from above, feed down 20 mm/s to 600 mm, withdraw at 20 mm/s.
    let start_height = Vec3::new(0.0, 0.0, 0.7);
    let placement = Pose::from_parts(start_height.into(), Rotation::identity());
    let m = Motion::drilling(placement, 1.0, -400.0, 0.02, 0.6, 0.02).unwrap();
    assert!((m.end_time() - 61.0).abs() < 1e-12);
    let z_at = |t: f64| m.pose_at(t).translation.vector.z;
    assert!((z_at(0.0) - 0.7).abs() < 1e-12);
    assert!((z_at(1.0) - 0.7).abs() < 1e-12);
    assert!((z_at(16.0) - 0.4).abs() < 1e-12);
    assert!((z_at(31.0) - 0.1).abs() < 1e-12, "deepest {}", z_at(31.0));
    assert!((z_at(46.0) - 0.4).abs() < 1e-12);
    assert!((z_at(61.0) - 0.7).abs() < 1e-12);
    assert!((z_at(100.0) - 0.7).abs() < 1e-12);
    // A quarter turn (0.0375 s at 400 rpm) clockwise takes body +x to world -y.
    let t = 1.0 + 0.0375;
    let p = m
        .pose_at(t)
        .transform_point(&Vec3::new(0.1, 0.0, 0.0).into())
        .coords;
    assert_close(
        p,
        Vec3::new(0.0, -0.1, 0.7 - 0.02 * 0.0375),
        1e-12,
        "quarter turn",
    );
    // Angle after the feed: 400/60 rev/s × 30 s = 200 turns, clockwise.
    assert!((m.angle_at(31.0) + 200.0 * TAU).abs() < 1e-9);

    let omega = m.angular_velocity_at(5.0);
    assert_close(
        omega,
        Vec3::new(0.0, 0.0, -400.0 * TAU / 60.0),
        1e-12,
        "omega",
    );
    assert_close(
        m.linear_velocity_at(5.0),
        Vec3::new(0.0, 0.0, -0.02),
        1e-15,
        "feed",
    );
    assert_close(
        m.linear_velocity_at(40.0),
        Vec3::new(0.0, 0.0, 0.02),
        1e-15,
        "withdraw",
    );
    assert_close(
        m.linear_velocity_at(0.5),
        Vec3::zeros(),
        0.0,
        "before start",
    );
    assert_close(m.angular_velocity_at(70.0), Vec3::zeros(), 0.0, "after end");
    // Flight edge at radius 30 mm moves at ω r = 1.2566 m/s tangentially, plus the feed.
    let reference = m.reference_point_at(5.0);
    assert_close(
        reference,
        Vec3::new(0.0, 0.0, 0.7 - 0.08),
        1e-12,
        "reference point",
    );
    let v = m.velocity_of_point(reference + Vec3::new(0.03, 0.0, 0.0), 5.0);
    assert_close(
        v,
        Vec3::new(0.0, -0.03 * 400.0 * TAU / 60.0, -0.02),
        1e-12,
        "point velocity",
    );
}

#[test]
fn point_velocity_matches_finite_difference_of_pose() {
    // Tilted placement, off-origin axis, overlapping translation segments.
    let placement = Pose::from_parts(
        Vec3::new(0.3, -0.2, 1.0).into(),
        Rotation::from_euler_angles(0.3, -0.2, 0.7),
    );
    let m = Motion::new(
        placement,
        vec![
            TranslationSegment {
                velocity: Vec3::new(0.1, 0.0, -0.05),
                start: 0.0,
                stop: 2.0,
            },
            TranslationSegment {
                velocity: Vec3::new(0.0, 0.2, 0.0),
                start: 1.0,
                stop: 3.0,
            },
        ],
        vec![
            RotationSegment {
                axis: Vec3::new(1.0, 1.0, 0.0),
                axis_point: Vec3::new(0.0, 0.1, 0.2),
                rpm: 30.0,
                start: 0.5,
                stop: 2.5,
            },
            RotationSegment {
                axis: Vec3::new(-2.0, -2.0, 0.0),
                axis_point: Vec3::new(0.1, 0.2, 0.2),
                rpm: 12.0,
                start: 1.5,
                stop: 4.0,
            },
        ],
    )
    .unwrap();
    let body_point = Vec3::new(0.05, -0.3, 0.4);
    let h = 1e-6;
    for t in [0.25, 0.75, 1.25, 1.75, 2.25, 2.75, 3.5, 5.0] {
        let at = |t: f64| m.pose_at(t).transform_point(&body_point.into()).coords;
        let numeric = (at(t + h) - at(t - h)) / (2.0 * h);
        let analytic = m.velocity_of_point(at(t), t);
        assert_close(numeric, analytic, 1e-7, &format!("t = {t}"));
        // The axis point stays on the axis: its world position is the reference point.
        let axis_world = m
            .pose_at(t)
            .transform_point(&Vec3::new(0.0, 0.1, 0.2).into())
            .coords;
        assert_close(axis_world, m.reference_point_at(t), 1e-12, "reference");
    }
    // Serde round trip keeps the motion.
    let json = serde_json::to_string(&m).unwrap();
    let back: Motion = serde_json::from_str(&json).unwrap();
    assert_eq!(back, m);
}

#[test]
fn motion_validation_names_the_problem() {
    let seg = |start, stop| TranslationSegment {
        velocity: Vec3::x(),
        start,
        stop,
    };
    let e = Motion::new(Pose::identity(), vec![seg(0.0, 1.0), seg(2.0, 2.0)], vec![]).unwrap_err();
    assert!(
        matches!(e, MotionError::EmptyInterval { segment: 1, .. }),
        "{e}"
    );
    assert!(e.to_string().contains("translations[1]"));
    let e = Motion::new(Pose::identity(), vec![seg(0.0, f64::INFINITY)], vec![]).unwrap_err();
    assert!(e.to_string().contains("stop"), "{e}");
    let rot = |axis: Vec3, rpm: f64| RotationSegment {
        axis,
        axis_point: Vec3::zeros(),
        rpm,
        start: 0.0,
        stop: 1.0,
    };
    let e = Motion::new(Pose::identity(), vec![], vec![rot(Vec3::z(), f64::NAN)]).unwrap_err();
    assert!(e.to_string().contains("rpm"), "{e}");
    let e = Motion::new(Pose::identity(), vec![], vec![rot(Vec3::zeros(), 1.0)]).unwrap_err();
    assert!(matches!(e, MotionError::ZeroAxis { segment: 0 }));
    let e = Motion::new(
        Pose::identity(),
        vec![],
        vec![rot(Vec3::z(), 1.0), rot(Vec3::x(), 1.0)],
    )
    .unwrap_err();
    assert!(matches!(e, MotionError::DifferentAxis { segment: 1 }));
    let e = Motion::drilling(Pose::identity(), 0.0, -400.0, 0.0, 0.6, 0.02).unwrap_err();
    assert!(e.to_string().contains("feed_speed"), "{e}");
    let bad: Result<Motion, _> =
        serde_json::from_str(r#"{"translations":[{"velocity":[0,0,1],"start":3,"stop":1}]}"#);
    assert!(bad.unwrap_err().to_string().contains("stop"));
}

// ---------------------------------------------------------------------------------------------
// Size distributions
// ---------------------------------------------------------------------------------------------

fn desert_sand_table() -> Vec<SieveRow> {
    // Sieve sizes in metres, cumulative mass fraction passing.
    [
        (0.075e-3, 0.02),
        (0.15e-3, 0.10),
        (0.25e-3, 0.35),
        (0.425e-3, 0.80),
        (0.6e-3, 0.95),
        (1.18e-3, 1.0),
    ]
    .iter()
    .map(|&(size, passing)| SieveRow { size, passing })
    .collect()
}

#[test]
fn sieve_table_sampling_reproduces_mass_fractions() {
    let rows = desert_sand_table();
    let dist =
        SizeDistribution::new(SizeDistributionSpec::SieveTable { rows: rows.clone() }).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut mass_per_bin = vec![0.0; rows.len()];
    for _ in 0..100_000 {
        let r = dist.sample(&mut rng);
        let d = 2.0 * r;
        assert!(
            d >= rows[0].size * (1.0 - 1e-12) && d <= rows[rows.len() - 1].size * (1.0 + 1e-12)
        );
        // Bin 0 is the pan (≤ first size); bin i is (size[i-1], size[i]].
        let bin = rows
            .iter()
            .position(|row| d <= row.size * (1.0 + 1e-12))
            .unwrap();
        mass_per_bin[bin] += d.powi(3);
    }
    let total: f64 = mass_per_bin.iter().sum();
    for (i, row) in rows.iter().enumerate() {
        let expected = row.passing - if i == 0 { 0.0 } else { rows[i - 1].passing };
        let got = mass_per_bin[i] / total;
        assert!(
            (got - expected).abs() < 0.01,
            "bin {i}: mass fraction {got} vs {expected}"
        );
    }
}

#[test]
fn simple_distributions_sample_within_bounds() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let fixed = SizeDistribution::new(SizeDistributionSpec::Fixed { radius: 1e-3 }).unwrap();
    assert_eq!(fixed.sample(&mut rng), 1e-3);
    let uniform = SizeDistribution::new(SizeDistributionSpec::Uniform {
        min_radius: 1e-3,
        max_radius: 2e-3,
    })
    .unwrap();
    let samples: Vec<f64> = (0..20_000).map(|_| uniform.sample(&mut rng)).collect();
    assert!(samples.iter().all(|r| (1e-3..=2e-3).contains(r)));
    let mean = samples.iter().sum::<f64>() / samples.len() as f64;
    assert!((mean - 1.5e-3).abs() < 1e-5, "uniform mean {mean}");
    let normal = SizeDistribution::new(SizeDistributionSpec::Normal {
        mean_radius: 1e-3,
        std_dev: 0.2e-3,
        min_radius: 0.8e-3,
        max_radius: 1.6e-3,
    })
    .unwrap();
    let samples: Vec<f64> = (0..20_000).map(|_| normal.sample(&mut rng)).collect();
    assert!(samples.iter().all(|r| (0.8e-3..=1.6e-3).contains(r)));
    // Truncated at -1σ and +3σ: mean = μ + σ (φ(-1) - φ(3)) / (Φ(3) - Φ(-1)) ≈ μ + 0.2848 σ.
    let mean = samples.iter().sum::<f64>() / samples.len() as f64;
    assert!(
        (mean - (1e-3 + 0.2848 * 0.2e-3)).abs() < 4e-6,
        "normal mean {mean}"
    );
    assert_eq!(normal.min_radius(), 0.8e-3);
    assert_eq!(normal.max_radius(), 1.6e-3);
}

#[test]
fn mean_cubed_diameter_is_what_sampling_gives() {
    let specs = [
        SizeDistributionSpec::Fixed { radius: 1e-3 },
        SizeDistributionSpec::Uniform {
            min_radius: 1e-3,
            max_radius: 2e-3,
        },
        SizeDistributionSpec::Normal {
            mean_radius: 1e-3,
            std_dev: 0.2e-3,
            min_radius: 0.8e-3,
            max_radius: 1.6e-3,
        },
        SizeDistributionSpec::SieveTable {
            rows: desert_sand_table(),
        },
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for spec in specs {
        let dist = SizeDistribution::new(spec.clone()).unwrap();
        let n = 200_000;
        let sampled = (0..n)
            .map(|_| (2.0 * dist.sample(&mut rng)).powi(3))
            .sum::<f64>()
            / n as f64;
        let exact = dist.mean_cubed_diameter();
        assert!(
            (sampled / exact - 1.0).abs() < 0.01,
            "{spec:?}: sampled E[d³] {sampled:e}, computed {exact:e}"
        );
    }
    // Fixed and uniform in closed form.
    let fixed = SizeDistribution::new(SizeDistributionSpec::Fixed { radius: 1e-3 }).unwrap();
    assert!((fixed.mean_cubed_diameter() - 8e-9).abs() < 1e-21);
}

#[test]
fn distribution_validation_and_serde() {
    let err = |spec| SizeDistribution::new(spec).unwrap_err();
    let rows = desert_sand_table();
    let mut decreasing = rows.clone();
    decreasing[3].passing = 0.3;
    assert!(matches!(
        err(SizeDistributionSpec::SieveTable { rows: decreasing }),
        DistributionError::FractionsDecreasing { row: 3, .. }
    ));
    let mut unsorted = rows.clone();
    unsorted[2].size = 0.1e-3;
    assert!(matches!(
        err(SizeDistributionSpec::SieveTable { rows: unsorted }),
        DistributionError::SizesNotIncreasing { row: 2, .. }
    ));
    let mut not_one = rows.clone();
    not_one[5].passing = 0.97;
    assert!(matches!(
        err(SizeDistributionSpec::SieveTable { rows: not_one }),
        DistributionError::LastFractionNotOne { .. }
    ));
    let mut too_big = rows.clone();
    too_big[5].passing = 1.5;
    assert!(matches!(
        err(SizeDistributionSpec::SieveTable { rows: too_big }),
        DistributionError::FractionOutOfRange { row: 5, .. }
    ));
    let mut negative = rows.clone();
    negative[0].size = -1.0;
    assert!(err(SizeDistributionSpec::SieveTable { rows: negative })
        .to_string()
        .contains("rows[0].size"));
    assert!(matches!(
        err(SizeDistributionSpec::SieveTable { rows: vec![] }),
        DistributionError::EmptyTable
    ));
    assert!(err(SizeDistributionSpec::Fixed { radius: 0.0 })
        .to_string()
        .contains("radius"));
    assert!(err(SizeDistributionSpec::Uniform {
        min_radius: 2e-3,
        max_radius: 1e-3
    })
    .to_string()
    .contains("max_radius"));
    assert!(matches!(
        err(SizeDistributionSpec::Normal {
            mean_radius: 1e-3,
            std_dev: 1e-5,
            min_radius: 2e-3,
            max_radius: 3e-3
        }),
        DistributionError::EmptyWindow { .. }
    ));

    let json =
        r#"{"kind":"sieve_table","rows":[{"size":1e-4,"passing":0},{"size":2e-4,"passing":1}]}"#;
    let d: SizeDistribution = serde_json::from_str(json).unwrap();
    assert!((d.max_radius() - 1e-4).abs() < 1e-18);
    let back: SizeDistribution = serde_json::from_str(&serde_json::to_string(&d).unwrap()).unwrap();
    assert_eq!(back, d);
    let bad = r#"{"kind":"sieve_table","rows":[{"size":1e-4,"passing":0.5}]}"#;
    assert!(serde_json::from_str::<SizeDistribution>(bad).is_err());
}

// ---------------------------------------------------------------------------------------------
// Factories
// ---------------------------------------------------------------------------------------------

const SAND_DENSITY: f64 = 2650.0;

fn sphere_mass(r: f64) -> f64 {
    SAND_DENSITY * 4.0 / 3.0 * PI * r.powi(3)
}

fn factory_spec(region: Region, mass_rate: f64, total_mass: f64) -> FactorySpec {
    FactorySpec {
        region,
        mass_rate,
        total_mass,
        start_time: 0.1,
        velocity: Vec3::new(0.0, 0.0, -0.5),
        size: SizeDistribution::new(SizeDistributionSpec::Uniform {
            min_radius: 1e-3,
            max_radius: 2e-3,
        })
        .unwrap(),
        max_attempts_per_particle: 50,
    }
}

/// Runs a factory for `steps` steps of `dt`, with `is_free` checking all particles so far.
fn run_factory(
    factory: &mut Factory,
    seed: u64,
    dt: f64,
    steps: usize,
) -> (Vec<(Vec3, f64, Vec3)>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut all: Vec<(Vec3, f64, Vec3)> = Vec::new();
    let mut unplaced = Vec::new();
    for step in 0..steps {
        let t = step as f64 * dt;
        let mut new = Vec::new();
        let existing = all.clone();
        let report = factory.spawn(
            t,
            dt,
            &mut rng,
            |c, r| existing.iter().all(|(q, rq, _)| (q - c).norm() >= r + rq),
            &mut new,
        );
        assert_eq!(report.placed, new.len());
        unplaced.push(report.unplaced_mass);
        all.extend(new);
    }
    (all, unplaced)
}

fn assert_no_overlaps(particles: &[(Vec3, f64, Vec3)]) {
    for (i, (a, ra, _)) in particles.iter().enumerate() {
        for (b, rb, _) in &particles[i + 1..] {
            assert!(
                (a - b).norm() >= ra + rb - 1e-15,
                "overlap between {a:?} and {b:?}"
            );
        }
    }
}

#[test]
fn factory_follows_mass_rate_and_stops_at_total_mass() {
    let region = Region::Box {
        min: Vec3::new(-0.1, -0.1, 0.0),
        max: Vec3::new(0.1, 0.1, 0.2),
    };
    let (rate, total) = (0.5, 0.1); // kg/s, kg: 0.2 s of insertion after start 0.1 s
    let mut factory = Factory::new(factory_spec(region, rate, total), SAND_DENSITY).unwrap();
    let dt = 1e-3;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut all: Vec<(Vec3, f64, Vec3)> = Vec::new();
    let max_particle_mass = sphere_mass(2e-3);
    for step in 0..400 {
        let t = step as f64 * dt;
        let existing = all.clone();
        let mut new = Vec::new();
        factory.spawn(
            t,
            dt,
            &mut rng,
            |c, r| existing.iter().all(|(q, rq, _)| (q - c).norm() >= r + rq),
            &mut new,
        );
        all.extend(new);
        let inserted: f64 = all.iter().map(|p| sphere_mass(p.1)).sum();
        assert!((inserted - factory.inserted_mass()).abs() < 1e-12);
        let allowed = (rate * (t + dt - 0.1)).clamp(0.0, total);
        assert!(inserted <= allowed + 1e-12, "t {t}: {inserted} > {allowed}");
        assert!(
            inserted > allowed - max_particle_mass,
            "t {t}: {inserted} lags {allowed}"
        );
    }
    assert!(factory.is_finished());
    let inserted = factory.inserted_mass();
    assert!(
        inserted <= total && inserted > total - max_particle_mass,
        "{inserted}"
    );
    assert_no_overlaps(&all);
    for (c, r, v) in &all {
        assert!(c.x - r >= -0.1 && c.x + r <= 0.1 && c.z - r >= 0.0 && c.z + r <= 0.2);
        assert_eq!(*v, Vec3::new(0.0, 0.0, -0.5));
    }
}

#[test]
fn full_cylinder_region_carries_the_deficit_over() {
    // A small cylinder cannot hold the requested mass: the factory reports the deficit, and
    // inserts more once the caller frees space (here: by forgetting earlier particles).
    let region = Region::Cylinder {
        axis_x: 0.0,
        axis_y: 0.0,
        radius: 0.01,
        z_min: 0.0,
        z_max: 0.01,
    };
    let mut factory = Factory::new(factory_spec(region, 10.0, 1.0), SAND_DENSITY).unwrap();
    let (placed, unplaced) = run_factory(&mut factory, 11, 1e-3, 200);
    assert!(!placed.is_empty());
    assert_no_overlaps(&placed);
    for (c, r, _) in &placed {
        assert!(c.x.hypot(c.y) + r <= 0.01 + 1e-15 && c.z - r >= 0.0 && c.z + r <= 0.01);
    }
    assert!(
        *unplaced.last().unwrap() > 0.5,
        "deficit {:?}",
        unplaced.last()
    );
    let before = factory.inserted_mass();
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let mut new = Vec::new();
    let report = factory.spawn(0.2, 1e-3, &mut rng, |_, _| true, &mut new);
    assert!(report.placed > 0 && factory.inserted_mass() > before);
}

#[test]
fn factory_is_deterministic_for_a_seed() {
    let region = Region::Box {
        min: Vec3::zeros(),
        max: Vec3::new(0.05, 0.05, 0.05),
    };
    let spec = factory_spec(region, 0.2, 0.05);
    let mut a = Factory::new(spec.clone(), SAND_DENSITY).unwrap();
    let mut b = Factory::new(spec.clone(), SAND_DENSITY).unwrap();
    let (pa, _) = run_factory(&mut a, 5, 1e-3, 150);
    let (pb, _) = run_factory(&mut b, 5, 1e-3, 150);
    assert_eq!(pa, pb);
    let mut c = Factory::new(spec, SAND_DENSITY).unwrap();
    let (pc, _) = run_factory(&mut c, 6, 1e-3, 150);
    assert_ne!(pa, pc);
}

#[test]
fn factory_validation_names_the_field() {
    let region = Region::Box {
        min: Vec3::zeros(),
        max: Vec3::new(1.0, 1.0, 1.0),
    };
    let e = Factory::new(factory_spec(region, -1.0, 1.0), SAND_DENSITY).unwrap_err();
    assert!(e.to_string().contains("mass_rate"), "{e}");
    let e = Factory::new(factory_spec(region, 1.0, 1.0), 0.0).unwrap_err();
    assert!(e.to_string().contains("density"), "{e}");
    let flat = Region::Box {
        min: Vec3::zeros(),
        max: Vec3::new(1.0, 1.0, 0.0),
    };
    let e = Factory::new(factory_spec(flat, 1.0, 1.0), SAND_DENSITY).unwrap_err();
    assert!(e.to_string().contains("max.z"), "{e}");
    let thin = Region::Box {
        min: Vec3::zeros(),
        max: Vec3::new(1.0, 1.0, 0.003),
    };
    let e = Factory::new(factory_spec(thin, 1.0, 1.0), SAND_DENSITY).unwrap_err();
    assert!(e.to_string().contains("too small"), "{e}");
    let json = r#"{"region":{"kind":"cylinder","axis_x":0,"axis_y":0,"radius":0.1,"z_min":0,"z_max":0.3},
                   "mass_rate":0.1,"total_mass":1,"size":{"kind":"fixed","radius":0.001}}"#;
    let spec: FactorySpec = serde_json::from_str(json).unwrap();
    assert_eq!(spec.max_attempts_per_particle, 100);
    assert!(Factory::new(spec, SAND_DENSITY).is_ok());
}

#[test]
fn explicit_list_is_inserted_once_at_its_time() {
    let particles = vec![
        ListedParticle {
            center: Vec3::zeros(),
            radius: 1e-3,
            velocity: Vec3::zeros(),
        },
        ListedParticle {
            center: Vec3::x(),
            radius: 2e-3,
            velocity: Vec3::z(),
        },
    ];
    let bad = vec![ListedParticle {
        center: Vec3::zeros(),
        radius: 0.0,
        velocity: Vec3::zeros(),
    }];
    let e = ParticleList::new(0.5, bad).unwrap_err();
    assert!(e.to_string().contains("particles[0].radius"), "{e}");
    let mut list = ParticleList::new(0.5, particles).unwrap();
    let mut out = Vec::new();
    assert_eq!(list.spawn(0.0, 0.1, &mut out), 0);
    assert_eq!(list.spawn(0.45, 0.1, &mut out), 2);
    assert_eq!(list.spawn(0.55, 0.1, &mut out), 0);
    assert_eq!(out.len(), 2);
    assert_eq!(out[1], (Vec3::x(), 2e-3, Vec3::z()));
}

/// Broad-phase cost: `cargo test -p repose-engine --test engine geometry:: -- --ignored --nocapture`.
#[test]
#[ignore = "timing report, not a check"]
fn broad_phase_query_cost() {
    use rand::Rng;
    let meshes = [
        ("auger", auger(&test_auger_spec()).unwrap()),
        ("plane 200x200", plane(1.0, 1.0, 200, 200).unwrap()),
    ];
    for (name, mesh) in &meshes {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (lo, hi) = mesh.aabb();
        let queries: Vec<Vec3> = (0..2000)
            .map(|_| {
                let v = mesh.vertices()[rng.gen_range(0..mesh.vertices().len())];
                v + Vec3::new(rng.gen(), rng.gen(), rng.gen()) * 0.002
            })
            .collect();
        let radius = 0.001;
        let time = |f: &dyn Fn(Vec3, &mut Vec<MeshContact>)| {
            let mut out = Vec::new();
            let start = std::time::Instant::now();
            let mut found = 0;
            for _ in 0..5 {
                for &q in &queries {
                    out.clear();
                    f(q, &mut out);
                    found += out.len();
                }
            }
            (
                start.elapsed().as_secs_f64() / (5 * queries.len()) as f64,
                found,
            )
        };
        let (fast, nf) = time(&|q, out| mesh.sphere_contacts(q, radius, out));
        let (slow, ns) = time(&|q, out| mesh.sphere_contacts_brute_force(q, radius, out));
        assert_eq!(nf, ns);
        println!(
            "{name}: {} triangles, {} cells, bounds {:?}..{:?}: grid {:.2} µs/query, brute force {:.1} µs/query ({:.0}×)",
            mesh.triangles().len(),
            mesh.grid_cell_count(),
            lo,
            hi,
            fast * 1e6,
            slow * 1e6,
            slow / fast
        );
    }
}

#[test]
fn fine_fan_disc_builds_a_bounded_grid_and_answers_correctly() {
    // 20 000 long thin triangles around one centre: their bounding boxes overlap heavily, the
    // case where a naive grid would list every triangle in thousands of cells.
    let n = 20_000u32;
    let mut vertices = vec![Vec3::zeros()];
    vertices.extend((0..n).map(|k| {
        let phi = TAU * k as f64 / n as f64;
        Vec3::new(0.1 * phi.cos(), 0.1 * phi.sin(), 0.0)
    }));
    let triangles = (0..n).map(|k| [0, 1 + k, 1 + (k + 1) % n]).collect();
    let start = std::time::Instant::now();
    let disc = TriMesh::new(vertices, triangles).unwrap();
    let build = start.elapsed().as_secs_f64();
    assert!(build < 5.0, "grid build took {build} s");
    assert!(disc.grid_cell_count() <= 4 * n as usize);
    // At the hub exactly, just off it (the hub vertex is then rejected by every triangle),
    // in the middle and at the rim.
    let start = std::time::Instant::now();
    for (x, y) in [
        (0.0, 0.0),
        (1e-4, 2e-5),
        (0.05, 0.01),
        (-0.07, 0.06),
        (0.0999, 0.0),
    ] {
        let center = Vec3::new(x, y, 0.001);
        let fast = contacts(&disc, center, 0.002);
        let mut slow = Vec::new();
        disc.sphere_contacts_brute_force(center, 0.002, &mut slow);
        assert_eq!(fast.len(), 1, "at ({x}, {y}): {fast:?}");
        assert_same_contacts(fast, slow, "disc");
    }
    let queries = start.elapsed().as_secs_f64();
    assert!(queries < 2.0, "queries took {queries} s");
}
