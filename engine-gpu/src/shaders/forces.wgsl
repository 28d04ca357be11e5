// ---- forces ----

// The slab's share of the contact of i and j (i < j) whose force on i is `force_on_i`: the
// force on the upper grain (the higher centre) from the lower one times the length of the
// branch's vertical extent inside the slab, where the branch's midpoint lies in the slab's x
// and y ranges (the CPU's shear window, `Window::add`). Heights and the midpoint are taken
// from the slab's corner as voxel differences plus offsets, exact to the offsets' resolution.
fn slab_share(i: u32, j: u32, force_on_i: vec3<f32>) -> vec3<f32> {
    let s = F.slab;
    let branch = -rel(i, j);
    let from_corner = vec3<f32>(cell[i].xyz - s.cell.xyz) * P.csize.xyz
        + (off[i].xyz - s.off.xyz);
    let mid = from_corner.xy + 0.5 * branch.xy;
    if (any(mid < vec2<f32>(0.0)) || any(mid >= s.size.xy)) {
        return vec3<f32>(0.0);
    }
    let zi = from_corner.z;
    let zj = zi + branch.z;
    let inside = max(min(max(zi, zj), s.size.z) - max(min(zi, zj), 0.0), 0.0);
    if (inside == 0.0) {
        return vec3<f32>(0.0);
    }
    // j's force (minus i's) where j is at least as high.
    return select(force_on_i, -force_on_i, branch.z >= 0.0) * inside;
}

@compute @workgroup_size(WG)
fn forces(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    // The rebuild kernels before this one have read the request: reset it for the step's
    // moves, counting the rebuild.
    if (i == 0u && atomicExchange(&ctl[0], 0u) != 0u) {
        atomicAdd(&ctl[1], 1u);
    }
    if (i >= P.n) {
        return;
    }
    // A sampling evaluation: the grain's share of the slab's sums, in its own slot.
    let sampling = F.head.y != 0;
    if (!alive(i)) {
        frc[i] = vec4<f32>(0.0);
        trq[i] = vec4<f32>(0.0);
        if (sampling) {
            slab_sums[i] = vec4<f32>(0.0);
        }
        return;
    }
    let vi = vel[i];
    let mi = vi.w;
    let ri = off[i].w;
    var f = P.gravity.xyz * mi;
    var tq = vec3<f32>(0.0);
    var moment = 0.0;
    var touching = 0.0;
    var sampled = vec3<f32>(0.0);
    let count = nbn[i];
    for (var k = 0u; k < count; k++) {
        let j = nbr[slot(i, k)];
        if (!alive(j)) {
            spr[slot(i, k)] = vec4<f32>(0.0);
            if (epsd()) {
                spr[slot(i, CAP + k)] = vec4<f32>(0.0);
            }
            continue;
        }
        // One call site for both orientations: the two particles of a pair run the same
        // instructions on the same arguments (lower index first), so their copies of the pair's
        // force and spring are the same bits.
        let lower = i < j;
        var rolling_in = vec3<f32>(0.0);
        if (epsd()) {
            rolling_in = spr[slot(i, CAP + k)].xyz;
        }
        let o = pair_contact(min(i, j), max(i, j), spr[slot(i, k)], rolling_in);
        if (o.touching) {
            f += select(-o.force, o.force, lower);
            tq += select(o.torque_b, o.torque_a, lower);
            moment += select(o.moment_b, o.moment_a, lower);
            touching += 1.0;
            if (sampling && lower) {
                sampled += slab_share(i, j, o.force);
            }
        }
        spr[slot(i, k)] = vec4<f32>(o.spring, select(0.0, 1.0, o.in_contact));
        if (epsd()) {
            spr[slot(i, CAP + k)] = vec4<f32>(o.rolling, 0.0);
        }
    }

    // The static triangles listed in the grain's voxel, in mesh order, then each moving
    // geometry's listed in the grain's cell of its body grid; within a geometry a point found
    // twice (a shared edge or corner) counts once, and of contacts whose normals are within the
    // distinct angle the deepest is kept.
    var cand: array<TriContact, WCAND>;
    var nc = 0u;
    let ci = cell[i].xyz;
    let oi = off[i].xyz;
    let voxel = cell_index(ci);
    let listed = P.ncells + 1u;
    let last = tgrid[voxel + 1u];
    let fixed = static_wall();
    for (var e = tgrid[voxel]; e < last; e++) {
        let t = tgrid[listed + e];
        offer(&cand, &nc, t, tris[t], ci, oi, vec3<f32>(0.0), fixed, ri);
    }
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
            offer(&cand, &nc, t, tris[t], ci, oi, body, w, ri);
        }
    }
    // Deepest first (ties by point), then drop those within the distinct angle of a kept one.
    for (var a = 1u; a < nc; a++) {
        let v = cand[a];
        var b = a;
        while (b > 0u && (cand[b - 1u].overlap < v.overlap
                || (cand[b - 1u].overlap == v.overlap && cand[b - 1u].point.x > v.point.x))) {
            cand[b] = cand[b - 1u];
            b--;
        }
        cand[b] = v;
    }
    var kept = 0u;
    for (var a = 0u; a < nc; a++) {
        var distinct = true;
        for (var b = 0u; b < kept; b++) {
            if (cand[b].geometry == cand[a].geometry
                && dot(cand[b].normal, cand[a].normal) > P.misc.w) {
                distinct = false;
            }
        }
        if (distinct && kept < WCAP) {
            cand[kept] = cand[a];
            kept++;
        }
    }
    // Each contact takes the spring of the previous contact with the same geometry whose normal
    // is closest (> 0.9).
    var old_n: array<vec4<f32>, WCAP>;
    var old_s: array<vec4<f32>, WCAP>;
    var old_r: array<vec4<f32>, WCAP>;
    for (var h = 0u; h < WCAP; h++) {
        old_n[h] = walls[slot(i, 2u * h)];
        old_s[h] = walls[slot(i, 2u * h + 1u)];
        if (epsd()) {
            old_r[h] = walls[slot(i, 2u * WCAP + h)];
        }
    }
    let wi = omg[i].xyz;
    // A recorded evaluation: the grain's shares of the moving geometries' loads, summed in its
    // own slots (only this thread writes them) and by `reduce_loads` after.
    let recording = MOVERS && F.head.x >= 0;
    if (recording) {
        for (var m = 0u; m < P.movers.x; m++) {
            wload[slot(i, 2u * m)] = vec4<f32>(0.0);
            wload[slot(i, 2u * m + 1u)] = vec4<f32>(0.0);
        }
    }
    for (var a = 0u; a < WCAP; a++) {
        if (a >= kept) {
            walls[slot(i, 2u * a)] = vec4<f32>(0.0);
            walls[slot(i, 2u * a + 1u)] = vec4<f32>(0.0);
            if (epsd()) {
                walls[slot(i, 2u * WCAP + a)] = vec4<f32>(0.0);
            }
            continue;
        }
        let tc = cand[a];
        var best = 0.9;
        var spring = vec3<f32>(0.0);
        var rolling = vec3<f32>(0.0);
        for (var h = 0u; h < WCAP; h++) {
            if (old_n[h].w == f32(tc.geometry + 1)) {
                let dn = dot(old_n[h].xyz, tc.normal);
                if (dn > best) {
                    best = dn;
                    spring = old_s[h].xyz;
                    rolling = old_r[h].xyz;
                }
            }
        }
        let arm = tc.point;
        let motion = wall_motion(tc, ci, oi);
        let vrel = vi.xyz + cross(wi, arm) - motion.velocity;
        let c = pair_constants(cell[i].w, tc.material);
        let h = hertz_mindlin(c, ri, mi, tc.overlap, tc.normal, vrel, spring);
        var force = h.force;
        if (LINEAR_COHESION && c.b.z > 0.0) {
            // Linear cohesion over the circle where the sphere cuts the wall's plane.
            force -= tc.normal * (c.b.z * PI * tc.overlap * (2.0 * ri - tc.overlap));
        } else if (JKR && c.c.x > 0.0) {
            // JKR against a wall: no necking (a wall contact ends at zero overlap, as on the
            // CPU).
            force -= tc.normal * jkr_attraction(c, ri, tc.overlap);
        }
        f += force;
        tq += cross(arm, force);
        if (epsd()) {
            let r = epsd_rolling(tc.normal, wi - motion.spin, h.stiffness, c.b.y, ri,
                h.normal_force, 1.0 / omg[i].w + mi * ri * ri, rolling);
            tq += r.torque;
            walls[slot(i, 2u * WCAP + a)] = vec4<f32>(r.spring, 0.0);
        } else {
            moment += c.b.y * h.normal_force * length(arm);
        }
        if (recording && tc.mover >= 0) {
            let m = u32(tc.mover);
            wload[slot(i, 2u * m)] -= vec4<f32>(force, 0.0);
            wload[slot(i, 2u * m + 1u)] -= vec4<f32>(cross(motion.from_axis, force), 0.0);
        }
        walls[slot(i, 2u * a)] = vec4<f32>(tc.normal, f32(tc.geometry + 1));
        walls[slot(i, 2u * a + 1u)] = vec4<f32>(h.spring, 0.0);
    }
    frc[i] = vec4<f32>(f, moment);
    trq[i] = vec4<f32>(tq, touching);
    if (sampling) {
        slab_sums[i] = vec4<f32>(sampled, 0.0);
    }
}

// ---- loads on the moving geometries ----

const RWG: u32 = 256u;
var<workgroup> red_f: array<vec3<f32>, RWG>;
var<workgroup> red_t: array<vec3<f32>, RWG>;

// Workgroup m sums the grains' loads on moving geometry m into the evaluation's record: each
// thread its grains t, t + 256, ... in order, then a fixed tree. The same bits every time.
@compute @workgroup_size(RWG)
fn reduce_loads(@builtin(workgroup_id) wg: vec3<u32>,
                @builtin(local_invocation_id) lid: vec3<u32>) {
    let m = wg.x;
    let t = lid.x;
    var f = vec3<f32>(0.0);
    var q = vec3<f32>(0.0);
    for (var i = t; i < P.n; i += RWG) {
        if (alive(i)) {
            f += wload[slot(i, 2u * m)].xyz;
            q += wload[slot(i, 2u * m + 1u)].xyz;
        }
    }
    red_f[t] = f;
    red_t[t] = q;
    workgroupBarrier();
    for (var s = RWG / 2u; s > 0u; s = s / 2u) {
        if (t < s) {
            red_f[t] += red_f[t + s];
            red_t[t] += red_t[t + s];
        }
        workgroupBarrier();
    }
    if (t == 0u) {
        let r = u32(F.head.x) * P.movers.x + m;
        series[2u * r] = vec4<f32>(red_f[0], 0.0);
        series[2u * r + 1u] = vec4<f32>(red_t[0], 0.0);
    }
}
