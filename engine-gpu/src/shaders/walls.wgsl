// ---- triangle contacts: a grain's candidates against the static and moving triangles ----

struct TriContact {
    point: vec3<f32>,   // relative to the particle's centre (the lever arm), world frame
    normal: vec3<f32>,  // from the surface towards the centre
    overlap: f32,
    material: i32,
    geometry: i32,
    mover: i32,                // the moving geometry's slot (-1: static)
}

// A triangle's frame as the grain sees it: its moving geometry's slot (-1: static) and the
// rotation to the world frame (columns: the rows of the body-to-world rotation, so
// `v * to_world` is the world vector). The wall's motion is read from the mover's frame only
// for the contacts kept (`WallMotion`), not carried by every candidate.
struct Wall {
    mover: i32,
    to_world: mat3x3<f32>,
}

fn static_wall() -> Wall {
    var w: Wall;
    w.mover = -1;
    w.to_world = mat3x3<f32>(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0),
        vec3<f32>(0.0, 0.0, 1.0));
    return w;
}

// A kept wall contact's motion: the wall's velocity at the contact point, its spin, and the
// contact point less the wall's reference point (the lever of its load's torque).
struct WallMotion {
    velocity: vec3<f32>,
    spin: vec3<f32>,
    from_axis: vec3<f32>,
}

// The motion of contact `tc` of the grain at voxel `ci`, offset `oi` (a static wall: none).
fn wall_motion(tc: TriContact, ci: vec3<i32>, oi: vec3<f32>) -> WallMotion {
    var w: WallMotion;
    w.velocity = vec3<f32>(0.0);
    w.spin = vec3<f32>(0.0);
    w.from_axis = tc.point;
    if (tc.mover >= 0) {
        let g = F.m[u32(tc.mover)];
        let from_origin = vec3<f32>(ci - g.cell.xyz) * P.csize.xyz + (oi - g.off.xyz);
        w.from_axis = tc.point + (from_origin - g.lever.xyz);
        w.velocity = g.vel.xyz + cross(g.spin.xyz, w.from_axis);
        w.spin = g.spin.xyz;
    }
    return w;
}

// Where on a triangle its closest point lies (`Closest.feature`): a corner (a, b, c), an
// edge (ab, ac, bc) or the face.
const AT_A: u32 = 0u;
const AT_B: u32 = 1u;
const AT_C: u32 = 2u;
const ON_AB: u32 = 3u;
const ON_AC: u32 = 4u;
const ON_BC: u32 = 5u;
const ON_FACE: u32 = 6u;

struct Closest {
    q: vec3<f32>,
    feature: u32,
}

fn closest(q: vec3<f32>, feature: u32) -> Closest {
    var c: Closest;
    c.q = q;
    c.feature = feature;
    return c;
}

// The closest point of a triangle to p (p relative to its first corner a, its edges ab and
// ac), relative to a, and where it lies (Ericson, Real-Time Collision Detection 5.1.5).
fn closest_on_triangle(p: vec3<f32>, ab: vec3<f32>, ac: vec3<f32>) -> Closest {
    let ap = p;
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if (d1 <= 0.0 && d2 <= 0.0) {
        return closest(vec3<f32>(0.0), AT_A);
    }
    let bp = p - ab;
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if (d3 >= 0.0 && d4 <= d3) {
        return closest(ab, AT_B);
    }
    let vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
        return closest(ab * (d1 / (d1 - d3)), ON_AB);
    }
    let cp = p - ac;
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if (d6 >= 0.0 && d5 <= d6) {
        return closest(ac, AT_C);
    }
    let vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
        return closest(ac * (d2 / (d2 - d6)), ON_AC);
    }
    let va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
        return closest(ab + (ac - ab) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))), ON_BC);
    }
    let denom = 1.0 / (va + vb + vc);
    return closest(ab * (vb * denom) + ac * (vc * denom), ON_FACE);
}

// The grain's centre relative to triangle `tri`'s first corner, in the triangle's frame: for
// a static triangle from the grain's voxel `ci` and offset `oi`; for a moving one (`mover` at
// least 0) from its body-frame centre `body`.
fn centre_from(tri: Tri, mover: i32, ci: vec3<i32>, oi: vec3<f32>, body: vec3<f32>) -> vec3<f32> {
    if (mover >= 0) {
        return body - tri.v0.xyz;
    }
    return vec3<f32>(ci - tri.cell.xyz) * P.csize.xyz + (oi - tri.v0.xyz);
}

// The CPU engine's local-minimum test (`TriMesh::is_local_minimum`): a contact on an edge or
// at a corner of triangle `t` counts only if every other triangle sharing that edge or corner
// (by welded vertex) has its closest point there too, within `tol`; where a neighbour reaches
// closer, the grain's contact is with that neighbour, which offers it itself. `to_point`: from
// the grain's centre to the contact point, in the triangle's frame.
fn is_local_minimum(t: u32, tri: Tri, feature: u32, to_point: vec3<f32>, mover: i32,
                    ci: vec3<i32>, oi: vec3<f32>, body: vec3<f32>, tol: f32) -> bool {
    let ids = vec3<u32>(u32(tri.e1.w), u32(tri.e2.w), u32(tri.normal.w));
    var pivot = ids.x;
    var other = 0xffffffffu;
    switch feature {
        case AT_B: { pivot = ids.y; }
        case AT_C: { pivot = ids.z; }
        case ON_AB: { other = ids.y; }
        case ON_AC: { other = ids.z; }
        case ON_BC: { pivot = ids.y; other = ids.z; }
        default: {}
    }
    let at = P.movers.y;
    let listed = at + P.movers.z + 1u;
    let end = tgrid[at + pivot + 1u];
    for (var k = tgrid[at + pivot]; k < end; k++) {
        let n = tgrid[listed + k];
        if (n == t) {
            continue;
        }
        let nt = tris[n];
        if (other != 0xffffffffu && u32(nt.e1.w) != other && u32(nt.e2.w) != other
                && u32(nt.normal.w) != other) {
            continue;
        }
        let pn = centre_from(nt, mover, ci, oi, body);
        let d = (closest_on_triangle(pn, nt.e1.xyz, nt.e2.xyz).q - pn) - to_point;
        if (dot(d, d) > tol * tol) {
            return false;
        }
    }
    return true;
}

// Offers triangle `t`'s (`tri`) contact with the grain of radius `ri` to the candidates: the
// grain's centre is at voxel `ci` and offset `oi`, or at `body` in a moving triangle's body
// frame (`wall`).
fn offer(cand: ptr<function, array<TriContact, WCAND>>, nc: ptr<function, u32>, t: u32,
         tri: Tri, ci: vec3<i32>, oi: vec3<f32>, body: vec3<f32>, wall: Wall, ri: f32) {
    let p = centre_from(tri, wall.mover, ci, oi, body);
    let found = closest_on_triangle(p, tri.e1.xyz, tri.e2.xyz);
    let q = found.q;
    let d = p - q;
    let dist2 = dot(d, d);
    if (!(dist2 < ri * ri)) {
        return;
    }
    let geometry = i32(tri.v0.w);
    let point = (q - p) * wall.to_world;
    let tol = P.misc2.x;
    for (var c = 0u; c < *nc; c++) {
        let e = (*cand)[c].point - point;
        if ((*cand)[c].geometry == geometry && dot(e, e) <= tol * tol) {
            return;
        }
    }
    if (found.feature != ON_FACE
            && !is_local_minimum(t, tri, found.feature, q - p, wall.mover, ci, oi, body, tol)) {
        return;
    }
    if (*nc == WCAND) {
        atomicAdd(&ctl[6], 1u);
        return;
    }
    let dist = sqrt(dist2);
    var n = tri.normal.xyz;
    if (dot(n, d) < 0.0) {
        n = -n;
    }
    if (dist > 1e-6 * ri) {
        // At an edge or a corner the direction to the centre is the normal (on the face
        // both agree).
        let to_centre = d * (1.0 / dist);
        if (dot(to_centre, n) < 0.9999) {
            n = to_centre;
        }
    }
    var tc: TriContact;
    tc.point = point;
    tc.normal = n * wall.to_world;
    tc.overlap = ri - dist;
    tc.material = tri.cell.w;
    tc.geometry = geometry;
    tc.mover = wall.mover;
    (*cand)[*nc] = tc;
    *nc += 1u;
}

// Offers grain i the static triangles listed in its voxel, in mesh order.
fn offer_static(cand: ptr<function, array<TriContact, WCAND>>, nc: ptr<function, u32>, i: u32) {
    let ci = cell[i].xyz;
    let oi = off[i].xyz;
    let ri = off[i].w;
    let voxel = cell_index(ci);
    let listed = P.ncells + 1u;
    let last = tgrid[voxel + 1u];
    let fixed = static_wall();
    for (var e = tgrid[voxel]; e < last; e++) {
        let t = tgrid[listed + e];
        offer(cand, nc, t, tris[t], ci, oi, vec3<f32>(0.0), fixed, ri);
    }
}

// Offers grain i each moving geometry's triangles listed in the grain's cell of its body grid,
// geometry by geometry, each in mesh order.
fn offer_moving(cand: ptr<function, array<TriContact, WCAND>>, nc: ptr<function, u32>, i: u32) {
    let ci = cell[i].xyz;
    let oi = off[i].xyz;
    let ri = off[i].w;
    for (var m = 0u; MOVERS && m < P.movers.x; m++) {
        let g = F.m[m];
        // The grain's centre from the body origin, world frame, then body frame.
        let from_origin = vec3<f32>(ci - g.cell.xyz) * P.csize.xyz + (oi - g.off.xyz);
        var w: Wall;
        w.mover = i32(m);
        w.to_world = mat3x3<f32>(g.rot0.xyz, g.rot1.xyz, g.rot2.xyz);
        let body = w.to_world * from_origin;
        let u = (body - g.grid_min.xyz) / g.off.w;
        if (any(u < vec3<f32>(0.0)) || any(u >= vec3<f32>(g.grid_dims.xyz))) {
            continue;
        }
        let k = vec3<u32>(u);
        let dims = vec3<u32>(g.grid_dims.xyz);
        let c = u32(g.cell.w) + k.x + dims.x * (k.y + dims.y * k.z);
        let entries = u32(g.cell.w) + dims.x * dims.y * dims.z + 1u;
        let end = tgrid[c + 1u];
        for (var e = tgrid[c]; e < end; e++) {
            let t = tgrid[entries + e];
            offer(cand, nc, t, tris[t], ci, oi, body, w, ri);
        }
    }
}

// Sorts the `nc` candidates deepest first (ties by point), then keeps, in that order, those
// not within the distinct angle of a kept one of the same geometry, at most WCAP, moved to the
// front; returns how many.
fn keep_distinct(cand: ptr<function, array<TriContact, WCAND>>, nc: u32) -> u32 {
    for (var a = 1u; a < nc; a++) {
        let v = (*cand)[a];
        var b = a;
        while (b > 0u && ((*cand)[b - 1u].overlap < v.overlap
                || ((*cand)[b - 1u].overlap == v.overlap && (*cand)[b - 1u].point.x > v.point.x))) {
            (*cand)[b] = (*cand)[b - 1u];
            b--;
        }
        (*cand)[b] = v;
    }
    var kept = 0u;
    for (var a = 0u; a < nc; a++) {
        var distinct = true;
        for (var b = 0u; b < kept; b++) {
            if ((*cand)[b].geometry == (*cand)[a].geometry
                && dot((*cand)[b].normal, (*cand)[a].normal) > P.misc.w) {
                distinct = false;
            }
        }
        if (distinct && kept < WCAP) {
            (*cand)[kept] = (*cand)[a];
            kept++;
        }
    }
    return kept;
}
