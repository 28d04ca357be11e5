// ---- forces: a grain's pairs, then its triangle contacts; the moving geometries' loads ----

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

// What a grain sums at a force evaluation, in this order: gravity, its pairs in list order,
// then its triangle contacts in the order they were kept.
struct Sums {
    force: vec3<f32>,
    torque: vec3<f32>,
    // CDT's rolling moment (the brake `kick_spin` applies)
    moment: f32,
    // particle-particle contacts
    touching: f32,
    // the grain's share of the sampled slab's stress sums
    sampled: vec3<f32>,
}

// Adds grain i's pair contacts to `sums`, in its list order, and writes back their springs;
// with `sampling`, its share of the slab's sums from the pairs it leads.
fn pair_sums(i: u32, sampling: bool, sums: Sums) -> Sums {
    var s = sums;
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
            s.force += select(-o.force, o.force, lower);
            s.torque += select(o.torque_b, o.torque_a, lower);
            s.moment += select(o.moment_b, o.moment_a, lower);
            s.touching += 1.0;
            if (sampling && lower) {
                s.sampled += slab_share(i, j, o.force);
            }
        }
        spr[slot(i, k)] = vec4<f32>(o.spring, select(0.0, 1.0, o.in_contact));
        if (epsd()) {
            spr[slot(i, CAP + k)] = vec4<f32>(o.rolling, 0.0);
        }
    }
    return s;
}

// A grain's triangle contacts at the last evaluation (`walls`), read before this one
// overwrites them: each one's normal (w: its geometry + 1, 0 for none), spring and rolling
// spring.
struct WallHistory {
    n: array<vec4<f32>, WCAP>,
    s: array<vec4<f32>, WCAP>,
    r: array<vec4<f32>, WCAP>,
}

fn wall_history(i: u32) -> WallHistory {
    var old: WallHistory;
    for (var h = 0u; h < WCAP; h++) {
        old.n[h] = walls[slot(i, 2u * h)];
        old.s[h] = walls[slot(i, 2u * h + 1u)];
        if (epsd()) {
            old.r[h] = walls[slot(i, 2u * WCAP + h)];
        }
    }
    return old;
}

// The springs contact `tc` carries on: those of the previous contact with the same geometry
// whose normal is closest (> 0.9), or none.
struct WallSprings {
    spring: vec3<f32>,
    rolling: vec3<f32>,
}

fn carried_springs(old: ptr<function, WallHistory>, tc: TriContact) -> WallSprings {
    var best = 0.9;
    var out: WallSprings;
    out.spring = vec3<f32>(0.0);
    out.rolling = vec3<f32>(0.0);
    for (var h = 0u; h < WCAP; h++) {
        if ((*old).n[h].w == f32(tc.geometry + 1)) {
            let dn = dot((*old).n[h].xyz, tc.normal);
            if (dn > best) {
                best = dn;
                out.spring = (*old).s[h].xyz;
                out.rolling = (*old).r[h].xyz;
            }
        }
    }
    return out;
}

// Adds grain i's triangle contact `tc`, kept as its `a`th, to `sums` and writes its history;
// with `recording`, subtracts its force and torque from the grain's shares of a moving
// geometry's load.
fn wall_sums(i: u32, a: u32, tc: TriContact, springs: WallSprings, recording: bool,
             sums: Sums) -> Sums {
    var s = sums;
    let vi = vel[i];
    let mi = vi.w;
    let ri = off[i].w;
    let wi = omg[i].xyz;
    let arm = tc.point;
    let motion = wall_motion(tc, cell[i].xyz, off[i].xyz);
    let vrel = vi.xyz + cross(wi, arm) - motion.velocity;
    let c = pair_constants(cell[i].w, tc.material);
    let h = hertz_mindlin(c, ri, mi, tc.overlap, tc.normal, vrel, springs.spring);
    var force = h.force;
    if (LINEAR_COHESION && c.b.z > 0.0) {
        // Linear cohesion over the circle where the sphere cuts the wall's plane.
        force -= tc.normal * (c.b.z * PI * tc.overlap * (2.0 * ri - tc.overlap));
    } else if (JKR && c.c.x > 0.0) {
        // JKR against a wall: no necking (a wall contact ends at zero overlap, as on the
        // CPU).
        force -= tc.normal * jkr_attraction(c, ri, tc.overlap);
    }
    s.force += force;
    s.torque += cross(arm, force);
    if (epsd()) {
        let r = epsd_rolling(tc.normal, wi - motion.spin, h.stiffness, c.b.y, ri,
            h.normal_force, 1.0 / omg[i].w + mi * ri * ri, springs.rolling);
        s.torque += r.torque;
        walls[slot(i, 2u * WCAP + a)] = vec4<f32>(r.spring, 0.0);
    } else {
        s.moment += c.b.y * h.normal_force * length(arm);
    }
    if (recording && tc.mover >= 0) {
        let m = u32(tc.mover);
        wload[slot(i, 2u * m)] -= vec4<f32>(force, 0.0);
        wload[slot(i, 2u * m + 1u)] -= vec4<f32>(cross(motion.from_axis, force), 0.0);
    }
    walls[slot(i, 2u * a)] = vec4<f32>(tc.normal, f32(tc.geometry + 1));
    walls[slot(i, 2u * a + 1u)] = vec4<f32>(h.spring, 0.0);
    return s;
}

// Adds grain i's `kept` triangle contacts (the first of `cand`) to `sums`, in order; clears
// the history slots past them.
fn wall_contacts(i: u32, cand: ptr<function, array<TriContact, WCAND>>, kept: u32,
                 sums: Sums) -> Sums {
    var s = sums;
    var old = wall_history(i);
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
        let tc = (*cand)[a];
        s = wall_sums(i, a, tc, carried_springs(&old, tc), recording, s);
    }
    return s;
}

// Each grain's force, torque and rolling moment by stage: gravity, its pairs, its triangle
// contacts (the candidates of its voxel's static triangles and of each moving geometry's body
// cell, merged); its contacts' springs and histories carried on; the moving geometries' load
// shares and the slab's at a recorded or sampling evaluation.
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
    var s: Sums;
    s.force = P.gravity.xyz * vel[i].w;
    s.torque = vec3<f32>(0.0);
    s.moment = 0.0;
    s.touching = 0.0;
    s.sampled = vec3<f32>(0.0);
    s = pair_sums(i, sampling, s);
    var cand: array<TriContact, WCAND>;
    var nc = 0u;
    offer_static(&cand, &nc, i);
    offer_moving(&cand, &nc, i);
    let kept = keep_distinct(&cand, nc);
    s = wall_contacts(i, &cand, kept, s);
    frc[i] = vec4<f32>(s.force, s.moment);
    trq[i] = vec4<f32>(s.torque, s.touching);
    if (sampling) {
        slab_sums[i] = vec4<f32>(s.sampled, 0.0);
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
