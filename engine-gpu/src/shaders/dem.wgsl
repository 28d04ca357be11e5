// repose's DEM step on the GPU: Hertz-Mindlin no-slip with tangential history and the Coulomb
// cap, constant-directional-torque rolling friction applied as a brake on the new spin (or
// EPSD's rolling spring per contact), against
// other particles and static and moving triangles; symplectic Euler or velocity Verlet.
//
// Positions are integer voxel indices plus f32 offsets inside the voxel (`cell`, `off`): the
// vector between two nearby particles is (integer difference) * voxel + (offset difference),
// exact to the offsets' resolution (~1e-10 m for mm voxels) anywhere in the domain.
//
// Determinism: no float atomics. Integer atomics fill the cell bins in any order, but every
// particle's neighbour list is sorted by index before use, each pair's force is computed in
// one canonical orientation (lower index first) by both of its particles, and every particle
// sums its own contacts in list order, then its triangles in mesh order (static, then moving).

const CAP: u32 = 32u;      // neighbours per particle (within the skin)
const BIN: u32 = 16u;      // particles per grid cell
const WCAP: u32 = 4u;      // triangle contacts (with history) per particle
const WCAND: u32 = 16u;    // triangle contact candidates before merging
const WG: u32 = 128u;
const DAMPING_FACTOR: f32 = 1.8257418583505538;
const PI: f32 = 3.141592653589793;

// What the world's scene holds, fixed when its pipelines are made: a law or a loop the scene
// cannot use is left out of the compiled kernels (smaller kernels, fewer registers). Each only
// gates the run-time test that decides the same thing (a pair's constants, the rolling model,
// the moving geometries' count), so a kernel made with every one true gives the same forces.
override JKR: bool = true;              // some material pair has JKR cohesion
override LINEAR_COHESION: bool = true;  // some material pair has linear cohesion
override EPSD: bool = true;             // the rolling model is EPSD
override MOVERS: bool = true;           // some geometry moves (or is listed as movable)

struct Params {
    n: u32,
    ncells: u32,
    nmat: u32,
    ntris: u32,
    // nx, ny, nz, periodic bits (1: x, 2: y)
    dims: vec4<i32>,
    // voxel edge per axis, m (w unused)
    csize: vec4<f32>,
    // gravity (xyz), time step (w)
    gravity: vec4<f32>,
    // spring time step, half skin, skin, cos of the distinct angle
    misc: vec4<f32>,
    // duplicate-point tolerance of the triangle contacts, m; rolling model: 1 CDT (a brake on
    // the new spin), 0 EPSD (a rolling spring per contact); EPSD's viscous damping ratio
    misc2: vec4<f32>,
    // moving geometries (x)
    movers: vec4<u32>,
}

struct PairC {
    // E*, G*, beta, sqrt(4 G*/E*)
    a: vec4<f32>,
    // mu_s, mu_r, linear cohesion energy density k (J/m^3, 0: none), 0
    b: vec4<f32>,
    // JKR cohesion: surface energy gamma (J/m^2, 0: none), 2 pi gamma / E* (m), 0, 0
    c: vec4<f32>,
}

// A static triangle in the world frame (its first corner as a voxel and an offset); a moving
// one in its body frame (voxel zero, the corner's body coordinates).
struct Tri {
    // the first corner's voxel (xyz) and the triangle's material (w)
    cell: vec4<i32>,
    // the first corner's offset in its voxel; w: the triangle's geometry
    v0: vec4<f32>,
    e1: vec4<f32>,
    e2: vec4<f32>,
    normal: vec4<f32>,
}

@group(0) @binding(0) var<storage, read_write> cell: array<vec4<i32>>;
@group(0) @binding(1) var<storage, read_write> off: array<vec4<f32>>;    // w: radius
@group(0) @binding(2) var<storage, read_write> vel: array<vec4<f32>>;    // w: mass
@group(0) @binding(3) var<storage, read_write> omg: array<vec4<f32>>;    // w: 1 / inertia
@group(0) @binding(4) var<storage, read_write> frc: array<vec4<f32>>;    // w: CDT moment
@group(0) @binding(5) var<storage, read_write> trq: array<vec4<f32>>;    // w: contacts
// xyz: displacement since the build; w: 1 for a grain inserted since the build
@group(0) @binding(6) var<storage, read_write> disp: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> nbr: array<u32>;
@group(0) @binding(8) var<storage, read_write> nbn: array<u32>;
@group(0) @binding(9) var<storage, read_write> spr: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> nbr2: array<u32>;
@group(0) @binding(11) var<storage, read_write> binned: array<u32>; // cell at the last binning
@group(0) @binding(12) var<storage, read_write> spr2: array<vec4<f32>>;
@group(0) @binding(13) var<storage, read_write> bins: array<u32>;
@group(0) @binding(14) var<storage, read_write> binn: array<atomic<u32>>;
@group(0) @binding(15) var<storage, read_write> walls: array<vec4<f32>>;
@group(0) @binding(16) var<storage, read_write> tris: array<Tri>;
@group(0) @binding(17) var<storage, read_write> pc: array<PairC>;
// 0 rebuild wanted, 1 rebuilds, 2 neighbour overflow, 3 bin overflow, 4 removed,
// 5 fastest speed (f32 bits, max), 6 triangle contact overflow, 7 rebuilding this step
@group(0) @binding(18) var<storage, read_write> ctl: array<atomic<u32>>;
// The static triangles binned into the grid's voxels: ncells + 1 starts, then the triangle
// indices (each voxel's ascending). A triangle is listed in every voxel its bounding box, grown
// by the largest radius (and 1 %), touches: a grain's own voxel lists every triangle it can
// touch (its centre is within its radius of the triangle, so inside that grown box).
@group(0) @binding(19) var<storage, read_write> tgrid: array<u32>;
// Each grain's force (slot 2m) and torque about the reference point (2m + 1) on moving
// geometry m at a recorded force evaluation; their sums, two vec4 per geometry per record.
@group(0) @binding(20) var<storage, read_write> wload: array<vec4<f32>>;
@group(0) @binding(21) var<storage, read_write> series: array<vec4<f32>>;
// Each grain's share of the sampled slab's stress sums (xyz) at a sampling force evaluation:
// from its contacts with the grains of higher slots (`slab_share`).
@group(0) @binding(22) var<storage, read_write> slab_sums: array<vec4<f32>>;
@group(1) @binding(0) var<uniform> P: Params;

const MAX_MOVERS: u32 = 8u;

// A moving geometry at this force evaluation (the host evaluates its motion in f64).
struct Mover {
    // the body origin's voxel (xyz); w: where its body grid starts in `tgrid`
    cell: vec4<i32>,
    // the body origin's offset (xyz); w: the body grid's cell edge, m
    off: vec4<f32>,
    // rows of the body-to-world rotation
    rot0: vec4<f32>,
    rot1: vec4<f32>,
    rot2: vec4<f32>,
    vel: vec4<f32>,
    spin: vec4<f32>,
    // the reference point less the body origin, world frame
    lever: vec4<f32>,
    // the body grid's low corner, body frame; w: the geometry's index
    grid_min: vec4<f32>,
    grid_dims: vec4<i32>,
}

// A slab sampled at this force evaluation: its low corner (x0, y0, z0) as a voxel (not
// wrapped) and an offset, and its extent x1 - x0, y1 - y0, z1 - z0.
struct Slab {
    cell: vec4<i32>,
    off: vec4<f32>,
    size: vec4<f32>,
}

struct Frames {
    // x: the load record this force evaluation writes (-1: none); y: 1 where it samples the
    // slab
    head: vec4<i32>,
    m: array<Mover, MAX_MOVERS>,
    slab: Slab,
}

@group(2) @binding(0) var<uniform> F: Frames;

// Slot k of particle i's neighbour list (and springs, wall histories): column-major, so the
// threads of a workgroup read consecutive words.
fn slot(i: u32, k: u32) -> u32 {
    return k * P.n + i;
}

fn alive(i: u32) -> bool {
    return cell[i].w >= 0;
}

fn wrap_axis(d: i32, n: i32, periodic: bool) -> i32 {
    if (!periodic) {
        return d;
    }
    var r = d;
    if (r > n / 2) {
        r -= n;
    } else if (r < -(n / 2)) {
        r += n;
    }
    return r;
}

// Minimum image of a voxel difference across the periodic faces.
fn min_image(dc: vec3<i32>) -> vec3<i32> {
    return vec3<i32>(
        wrap_axis(dc.x, P.dims.x, (P.dims.w & 1) != 0),
        wrap_axis(dc.y, P.dims.y, (P.dims.w & 2) != 0),
        dc.z,
    );
}

// The vector from particle j's centre to particle i's.
fn rel(i: u32, j: u32) -> vec3<f32> {
    let dc = min_image(cell[i].xyz - cell[j].xyz);
    return vec3<f32>(dc) * P.csize.xyz + (off[i].xyz - off[j].xyz);
}

fn cell_index(c: vec3<i32>) -> u32 {
    let cc = clamp(c, vec3<i32>(0), P.dims.xyz - vec3<i32>(1));
    return u32(cc.x + P.dims.x * (cc.y + P.dims.y * cc.z));
}

fn pair_constants(a: i32, b: i32) -> PairC {
    return pc[u32(a) * P.nmat + u32(b)];
}

fn rotate_into_tangent_plane(s: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let old_len2 = dot(s, s);
    let along = dot(n, s);
    let projected = s - n * along;
    if (along * along <= 1e-12 * old_len2) {
        return projected;
    }
    let new_len2 = dot(projected, projected);
    if (new_len2 > 0.0) {
        return projected * sqrt(old_len2 / new_len2);
    }
    return vec3<f32>(0.0);
}

struct Hertz {
    force: vec3<f32>,
    normal_force: f32,
    // the tangent normal stiffness 2 E* sqrt(R* overlap)
    stiffness: f32,
    spring: vec3<f32>,
}

fn hertz_mindlin(c: PairC, r_star: f32, m_star: f32, overlap: f32, n: vec3<f32>,
                 vrel: vec3<f32>, spring_in: vec3<f32>) -> Hertz {
    let srd = sqrt(r_star * overlap);
    let sn = 2.0 * c.a.x * srd;
    let st = 8.0 * c.a.y * srd;
    let normal_dashpot = -DAMPING_FACTOR * c.a.z * sqrt(sn * m_star);
    let tangential_dashpot = normal_dashpot * c.a.w;
    let vn = dot(vrel, n);
    let fn_elastic = (2.0 / 3.0) * sn * overlap;
    let fn_damping = -normal_dashpot * vn;
    let normal_force = max(fn_elastic + fn_damping, 0.0);
    let vt = vrel - n * vn;
    var s = rotate_into_tangent_plane(spring_in, n) + vt * P.misc.x;
    var ft = -s * st - vt * tangential_dashpot;
    let cap = c.b.x * normal_force;
    let ft2 = dot(ft, ft);
    if (ft2 > cap * cap) {
        if (ft2 > 0.0) {
            ft = ft * (cap / sqrt(ft2));
        }
        if (st > 0.0) {
            s = ft * (-1.0 / st);
        } else {
            s = vec3<f32>(0.0);
        }
    }
    var h: Hertz;
    h.force = n * normal_force + ft;
    h.normal_force = normal_force;
    h.stiffness = sn;
    h.spring = s;
    return h;
}

// EPSD rolling (the CPU engine's rolling model `ElasticPlasticSpringDashpot`): the rolling
// spring per contact, its words after the tangential springs (`spr` slot CAP + k, `walls`
// slot 2 WCAP + h).
fn epsd() -> bool {
    return EPSD && P.misc2.y == 0.0;
}

// Words of a grain's triangle histories: normal and spring, and the rolling spring with EPSD.
fn wall_words() -> u32 {
    return select(2u, 3u, epsd()) * WCAP;
}

struct Rolling {
    torque: vec3<f32>,
    spring: vec3<f32>,
}

// The EPSD rolling torque (the CPU engine's `epsd_rolling_torque`): the spring follows the
// relative rolling velocity at stiffness kr up to the plastic torque, with a dashpot while
// elastic; kr = 2.25 (2/3 stiffness) mu_r^2 R*^2 (`epsd_rolling_stiffness`).
fn epsd_rolling(n: vec3<f32>, w_rel: vec3<f32>, stiffness: f32, mu_r: f32, r_star: f32,
                normal_force: f32, inertia: f32, spring_in: vec3<f32>) -> Rolling {
    let kr = 2.25 * (stiffness * (2.0 / 3.0)) * mu_r * mu_r * r_star * r_star;
    let max_torque = mu_r * r_star * normal_force;
    let damping = P.misc2.z * 2.0 * sqrt(inertia * kr);
    let omega_r = w_rel - n * dot(n, w_rel);
    var s = rotate_into_tangent_plane(spring_in, n) - omega_r * (kr * P.misc.x);
    var out: Rolling;
    let len2 = dot(s, s);
    if (len2 > max_torque * max_torque) {
        s = s * (max_torque / sqrt(len2));
        out.torque = s;
    } else {
        out.torque = s - omega_r * damping;
    }
    out.spring = s;
    return out;
}

// s = sqrt(a / a0) on JKR's stable branch for D = overlap R* / a0^2: the largest root of
// s^4 - s = D (the CPU engine's `jkr_root`): Newton from 1 + D^(1/4), which decreases onto it.
fn jkr_root(d: f32) -> f32 {
    var s = 1.0;
    if (d > 0.0) {
        s = 1.0 + sqrt(sqrt(d));
    }
    for (var k = 0; k < 40; k++) {
        let g = s * s * s * s - s - d;
        let slope = 4.0 * s * s * s - 1.0;
        if (g <= 0.0 || slope <= 0.0) {
            break;
        }
        let step = g / slope;
        s -= step;
        if (step <= 1e-7 * s) {
            break;
        }
    }
    return s;
}

// JKR's contact length a0^2 / R* for the pair (a0^3 = 2 pi gamma R*^2 / E*).
fn jkr_unit(c: PairC, r_star: f32) -> f32 {
    let a0 = pow(c.c.y * r_star * r_star, 1.0 / 3.0);
    return a0 * a0 / r_star;
}

// JKR's attraction at a positive overlap (the CPU engine's `CohesionLaw::attraction`): Hertz's
// force less JKR's, 2 pi gamma R* (4/3 (D^1.5 - s^6) + 2 s^3).
fn jkr_attraction(c: PairC, r_star: f32, overlap: f32) -> f32 {
    let d = overlap / jkr_unit(c, r_star);
    let s = jkr_root(d);
    let s3 = s * s * s;
    return 2.0 * PI * c.c.x * r_star * (4.0 / 3.0 * (d * sqrt(d) - s3 * s3) + 2.0 * s3);
}

// The separation of a JKR contact, D = -0.4725 (x^1.5 = 1/4).
const JKR_SEPARATION: f32 = -0.4724704;

struct PairOut {
    touching: bool,
    // a JKR contact is on (touching, or necking past zero overlap): kept in the spring's w
    in_contact: bool,
    // force on a (b gets minus it)
    force: vec3<f32>,
    torque_a: vec3<f32>,
    torque_b: vec3<f32>,
    moment_a: f32,
    moment_b: f32,
    spring: vec3<f32>,
    rolling: vec3<f32>,
}

// The contact of a and b (a < b), from a's side: both particles call it with the same
// arguments, so both get the same bits.
fn pair_contact(a: u32, b: u32, spring_in: vec4<f32>, rolling_in: vec3<f32>) -> PairOut {
    var o: PairOut;
    o.touching = false;
    o.force = vec3<f32>(0.0);
    o.torque_a = vec3<f32>(0.0);
    o.torque_b = vec3<f32>(0.0);
    o.moment_a = 0.0;
    o.moment_b = 0.0;
    o.spring = vec3<f32>(0.0);
    o.rolling = vec3<f32>(0.0);
    o.in_contact = false;
    let d = rel(a, b);
    let ra = off[a].w;
    let rb = off[b].w;
    let rsum = ra + rb;
    let dist2 = dot(d, d);
    if (dist2 >= rsum * rsum) {
        // A JKR contact outlives zero overlap (necking) until its separation: only JKR's
        // attraction acts there, no Hertz load, so no friction (the CPU engine's kernel).
        // Most listed pairs are apart and were apart: only one that touched reads its constants.
        if (!JKR || spring_in.w == 0.0) {
            return o;
        }
        let c = pair_constants(cell[a].w, cell[b].w);
        if (c.c.x > 0.0) {
            let dist = sqrt(dist2);
            let r_star = ra * rb / rsum;
            let dd = (rsum - dist) / jkr_unit(c, r_star);
            if (dd >= JKR_SEPARATION) {
                let s3 = pow(jkr_root(dd), 3.0);
                let pull = 2.0 * PI * c.c.x * r_star * (4.0 / 3.0 * s3 * s3 - 2.0 * s3);
                o.touching = true;
                o.in_contact = true;
                o.force = d * (pull / dist);
            }
        }
        return o;
    }
    o.touching = true;
    o.in_contact = true;
    let dist = sqrt(dist2);
    let n = d * (1.0 / dist);
    let overlap = rsum - dist;
    let lever_a = ra - 0.5 * overlap;
    let lever_b = rb - 0.5 * overlap;
    let va = vel[a];
    let vb = vel[b];
    let wa = omg[a].xyz;
    let wb = omg[b].xyz;
    let vrel = va.xyz - vb.xyz - cross(wa * lever_a + wb * lever_b, n);
    let r_star = ra * rb / rsum;
    let m_star = va.w * vb.w / (va.w + vb.w);
    let c = pair_constants(cell[a].w, cell[b].w);
    let h = hertz_mindlin(c, r_star, m_star, overlap, n, vrel, spring_in.xyz);
    var force = h.force;
    if (LINEAR_COHESION && c.b.z > 0.0) {
        // Linear cohesion, k times the area of the circle where the undeformed spheres cut;
        // friction and rolling keep the Hertz load (the CPU engine's `CohesionLaw`).
        let a2 = overlap * (2.0 * ra - overlap) * (2.0 * rb - overlap)
            * (2.0 * rsum - overlap) / (4.0 * dist2);
        force -= n * (c.b.z * PI * a2);
    } else if (JKR && c.c.x > 0.0) {
        force -= n * jkr_attraction(c, r_star, overlap);
    }
    let n_cross_f = cross(n, force);
    o.force = force;
    o.torque_a = -n_cross_f * lever_a;
    o.torque_b = -n_cross_f * lever_b;
    o.spring = h.spring;
    if (epsd()) {
        let inertia_a = 1.0 / omg[a].w + va.w * ra * ra;
        let inertia_b = 1.0 / omg[b].w + vb.w * rb * rb;
        let r = epsd_rolling(n, wa - wb, h.stiffness, c.b.y, r_star, h.normal_force,
            inertia_a * inertia_b / (inertia_a + inertia_b), rolling_in);
        o.torque_a += r.torque;
        o.torque_b -= r.torque;
        o.rolling = r.spring;
    } else {
        let m = c.b.y * h.normal_force;
        o.moment_a = m * lever_a;
        o.moment_b = m * lever_b;
    }
    return o;
}

// ---- neighbour rebuild: dispatched every step, a no-op unless a grain moved half a skin ----
//
// `drift` (or the host, after an insertion) sets ctl[0]; the rebuild kernels read it and the
// step's `forces` resets it (counting the rebuild), so no kernel of its own decides.

fn rebuilding() -> bool {
    return atomicLoad(&ctl[0]) != 0u;
}

@compute @workgroup_size(WG)
fn bin(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (!rebuilding() || i >= P.n || !alive(i)) {
        return;
    }
    let c = cell_index(cell[i].xyz);
    binned[i] = c;
    let slot = atomicAdd(&binn[c], 1u);
    if (slot < BIN) {
        bins[c * BIN + slot] = i;
    } else {
        atomicAdd(&ctl[3], 1u);
    }
}

@compute @workgroup_size(WG)
fn build(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (!rebuilding() || i >= P.n) {
        return;
    }
    var list: array<u32, CAP>;
    var count = 0u;
    if (alive(i)) {
        let ci = cell[i].xyz;
        let ri = off[i].w;
        let skin = P.misc.z;
        for (var dz = -1; dz <= 1; dz++) {
            let z = ci.z + dz;
            if (z < 0 || z >= P.dims.z) {
                continue;
            }
            for (var dy = -1; dy <= 1; dy++) {
                var y = ci.y + dy;
                if ((P.dims.w & 2) != 0) {
                    y = (y + P.dims.y) % P.dims.y;
                } else if (y < 0 || y >= P.dims.y) {
                    continue;
                }
                for (var dx = -1; dx <= 1; dx++) {
                    var x = ci.x + dx;
                    if ((P.dims.w & 1) != 0) {
                        x = (x + P.dims.x) % P.dims.x;
                    } else if (x < 0 || x >= P.dims.x) {
                        continue;
                    }
                    let c = u32(x + P.dims.x * (y + P.dims.y * z));
                    let m = min(atomicLoad(&binn[c]), BIN);
                    for (var s = 0u; s < m; s++) {
                        let j = bins[c * BIN + s];
                        if (j == i) {
                            continue;
                        }
                        let d = rel(i, j);
                        let reach = ri + off[j].w + skin;
                        if (dot(d, d) < reach * reach) {
                            if (count < CAP) {
                                list[count] = j;
                                count++;
                            } else {
                                atomicAdd(&ctl[2], 1u);
                            }
                        }
                    }
                }
            }
        }
    }
    // Sort by index: the gather order does not depend on the bins' fill order.
    for (var a = 1u; a < count; a++) {
        let v = list[a];
        var b = a;
        while (b > 0u && list[b - 1u] > v) {
            list[b] = list[b - 1u];
            b--;
        }
        list[b] = v;
    }
    // Carry the springs of pairs that were already listed (both lists are sorted). A grain
    // inserted since the last build starts without history: its slot's old list and the
    // springs others hold for the slot belonged to a removed grain.
    let fresh = disp[i].w != 0.0;
    if (fresh) {
        for (var h = 0u; h < wall_words(); h++) {
            walls[slot(i, h)] = vec4<f32>(0.0);
        }
    }
    let old_count = select(nbn[i], 0u, fresh);
    var k = 0u;
    for (var a = 0u; a < count; a++) {
        let j = list[a];
        while (k < old_count && nbr[slot(i, k)] < j) {
            k++;
        }
        var s = vec4<f32>(0.0);
        var r = vec4<f32>(0.0);
        if (k < old_count && nbr[slot(i, k)] == j && disp[j].w == 0.0) {
            s = spr[slot(i, k)];
            if (epsd()) {
                r = spr[slot(i, CAP + k)];
            }
        }
        nbr2[slot(i, a)] = j;
        spr2[slot(i, a)] = s;
        if (epsd()) {
            spr2[slot(i, CAP + a)] = r;
        }
    }
    nbn[i] = count; // its old count was read above; `commit` reads the new one
}

@compute @workgroup_size(WG)
fn commit(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (!rebuilding() || i >= P.n) {
        return;
    }
    disp[i] = vec4<f32>(0.0);
    // Empty the bins for the next rebuild (`build` has read them): each slot clears the cell
    // it was binned in. A slot whose grain was removed or never binned clears a cell that is
    // empty or cleared anyway, so the grid's cells cost nothing.
    atomicStore(&binn[binned[i]], 0u);
    let count = nbn[i];
    for (var a = 0u; a < count; a++) {
        nbr[slot(i, a)] = nbr2[slot(i, a)];
        spr[slot(i, a)] = spr2[slot(i, a)];
        if (epsd()) {
            spr[slot(i, CAP + a)] = spr2[slot(i, CAP + a)];
        }
    }
}

// ---- forces ----

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
