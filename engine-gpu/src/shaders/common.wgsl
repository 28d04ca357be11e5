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
//
// The shader is this file and the ones after it joined in order (`world/pipelines.rs`):
// common.wgsl (the constants, the records, the bindings and the indexing every stage shares),
// contact.wgsl (the contact laws), neighbours.wgsl (the rebuild kernels), walls.wgsl (the
// triangle contacts), forces.wgsl (the force evaluation and the moving geometries' loads),
// integrate.wgsl (the integrators' kernels).

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
