// ---- integration ----

// The spin after a kick of h seconds, CDT's rolling moment braking it with a whole step's
// impulse, never reversing it.
fn kick_spin(w: vec3<f32>, torque: vec3<f32>, moment: f32, inv_i: f32, h: f32) -> vec3<f32> {
    let spin = w + torque * (h * inv_i);
    if (P.misc2.y > 0.0 && moment > 0.0) {
        let limit = moment * P.gravity.w * inv_i;
        let speed2 = dot(spin, spin);
        if (speed2 <= limit * limit) {
            return vec3<f32>(0.0);
        }
        return spin * (1.0 - limit / sqrt(speed2));
    }
    return spin;
}

// c modulo n in [0, n). Only non-negative operands reach `%`: NVIDIA's Vulkan driver (580) gave
// the remainder of a negative i32 as if its bits were unsigned (-1 % 9 came out 3, not -1), so a
// grain leaving through a periodic face at 0 landed four voxels into the box.
fn wrap_index(c: i32, n: i32) -> i32 {
    if (c < 0) {
        return n - 1 - (-(c + 1)) % n;
    }
    return c % n;
}

// Moves particle i by dx: the offset stays inside its voxel, periodic voxels wrap, a particle
// leaving the domain is removed. Wants a rebuild when it moved half a skin since the last.
fn drift(i: u32, dx: vec3<f32>) {
    var o = off[i].xyz + dx;
    var c = cell[i].xyz;
    let k = floor(o / P.csize.xyz);
    o = o - k * P.csize.xyz;
    // Rounding can leave an offset a hair outside [0, voxel).
    o = clamp(o, vec3<f32>(0.0), P.csize.xyz * 0.99999994);
    c = c + vec3<i32>(k);
    if ((P.dims.w & 1) != 0) {
        c.x = wrap_index(c.x, P.dims.x);
    }
    if ((P.dims.w & 2) != 0) {
        c.y = wrap_index(c.y, P.dims.y);
    }
    var m = cell[i].w;
    if (any(c < vec3<i32>(0)) || any(c >= P.dims.xyz)) {
        m = -1;
        atomicAdd(&ctl[4], 1u);
        atomicStore(&ctl[0], 1u);
    }
    cell[i] = vec4<i32>(c, m);
    off[i] = vec4<f32>(o, off[i].w);
    let moved = disp[i].xyz + dx;
    disp[i] = vec4<f32>(moved, disp[i].w);
    if (dot(moved, moved) > P.misc.y * P.misc.y) {
        atomicStore(&ctl[0], 1u);
    }
}

// v += F h / m; returns the new velocity.
fn kick(i: u32, h: f32) -> vec3<f32> {
    let v = vel[i];
    let nv = v.xyz + frc[i].xyz * (h / v.w);
    vel[i] = vec4<f32>(nv, v.w);
    return nv;
}

// Symplectic Euler: v += F dt / m, spin, x += v dt.
@compute @workgroup_size(WG)
fn euler(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= P.n || !alive(i)) {
        return;
    }
    let dt = P.gravity.w;
    let nv = kick(i, dt);
    let w = omg[i];
    omg[i] = vec4<f32>(kick_spin(w.xyz, trq[i].xyz, frc[i].w, w.w, dt), w.w);
    drift(i, nv * dt);
}

// Velocity Verlet, first half: v += a dt/2, w += alpha dt/2, x += v dt.
@compute @workgroup_size(WG)
fn kick_drift(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= P.n || !alive(i)) {
        return;
    }
    let dt = P.gravity.w;
    let nv = kick(i, 0.5 * dt);
    let w = omg[i];
    omg[i] = vec4<f32>(w.xyz + trq[i].xyz * (0.5 * dt * w.w), w.w);
    drift(i, nv * dt);
}

// Velocity Verlet, second half: v += a dt/2, spin with the rolling brake.
@compute @workgroup_size(WG)
fn half_kick(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= P.n || !alive(i)) {
        return;
    }
    let dt = P.gravity.w;
    kick(i, 0.5 * dt);
    let w = omg[i];
    omg[i] = vec4<f32>(kick_spin(w.xyz, trq[i].xyz, frc[i].w, w.w, 0.5 * dt), w.w);
}

// The fastest particle's speed, as the bits of a non-negative f32 (ordered like the value).
@compute @workgroup_size(WG)
fn fastest(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= P.n || !alive(i)) {
        return;
    }
    atomicMax(&ctl[5], bitcast<u32>(length(vel[i].xyz)));
}
