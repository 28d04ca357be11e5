//! Closest point on a triangle, together with the feature (face, edge or vertex) it lies on.
//!
//! The feature matters for contact de-duplication: a point on an edge or vertex is shared with
//! neighbouring triangles, so the same physical contact can be reported by several triangles.

use crate::math::Vec3;

/// Which part of a triangle the closest point lies on.
///
/// Edge `k` joins corner `k` to corner `(k + 1) % 3`; vertex `k` is corner `k`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Feature {
    Face,
    Edge(u8),
    Vertex(u8),
}

/// Closest point of triangle `(a, b, c)` to `p` (Ericson, *Real-Time Collision Detection*, 5.1.5).
///
/// Works on Voronoi regions of the triangle's features, so the returned feature is exact
/// (up to rounding) rather than guessed from barycentric coordinates afterwards. The triangle
/// must be non-degenerate (guaranteed by `TriMesh::new`).
pub(crate) fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> (Vec3, Feature) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, Feature::Vertex(0));
    }

    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return (b, Feature::Vertex(1));
    }

    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (a + ab * v, Feature::Edge(0));
    }

    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return (c, Feature::Vertex(2));
    }

    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (a + ac * w, Feature::Edge(2));
    }

    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (b + (c - b) * w, Feature::Edge(1));
    }

    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    (a + ab * v + ac * w, Feature::Face)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri() -> (Vec3, Vec3, Vec3) {
        (
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        )
    }

    #[test]
    fn classifies_every_region() {
        let (a, b, c) = tri();
        let cases = [
            (
                Vec3::new(0.2, 0.2, 1.0),
                Feature::Face,
                Vec3::new(0.2, 0.2, 0.0),
            ),
            (Vec3::new(-1.0, -1.0, 0.5), Feature::Vertex(0), a),
            (Vec3::new(2.0, -0.1, 0.0), Feature::Vertex(1), b),
            (Vec3::new(-0.1, 2.0, 0.0), Feature::Vertex(2), c),
            (
                Vec3::new(0.5, -1.0, 0.0),
                Feature::Edge(0),
                Vec3::new(0.5, 0.0, 0.0),
            ),
            (
                Vec3::new(1.0, 1.0, -3.0),
                Feature::Edge(1),
                Vec3::new(0.5, 0.5, 0.0),
            ),
            (
                Vec3::new(-1.0, 0.5, 0.0),
                Feature::Edge(2),
                Vec3::new(0.0, 0.5, 0.0),
            ),
        ];
        for (p, feature, expected) in cases {
            let (q, f) = closest_point_on_triangle(p, a, b, c);
            assert_eq!(f, feature, "query {p:?}");
            assert!((q - expected).norm() < 1e-12, "query {p:?}: got {q:?}");
        }
    }
}
