//! A chunk's own pairs, four contacts at a time: the same Hertz-Mindlin + constant directional
//! torque law as the scalar loop in [`super::kernel`], written on `wide::f64x4` lanes (packed
//! SSE2 arithmetic on any x86-64, portable code elsewhere). An AVX2 build of the same code,
//! chosen at run time, was measured and dropped: `wide` picks its instructions when the crate
//! is compiled, so it still ran SSE2, and no faster (5.42/5.38 vs 5.43/5.34 M particle-steps/s).
//!
//! Invariants:
//! - **Bit-identical to the scalar loop.** Every lane performs the scalar loop's operations in
//!   the scalar loop's order (nalgebra's `dot` is `(x·x' + y·y') + z·z'`, its `cross` the
//!   textbook formula); both branches of the Coulomb cap and of the spring's rotation are
//!   computed and one is selected, which changes no result; negation is a sign flip, as in
//!   scalar code (`wide`'s `-x` is `0 − x`); no fused multiply-add is used. Forces are summed
//!   onto particle i in pair order, as the scalar loop does. Tested: a pour ends bit-identical
//!   on both paths, and the angle of repose of `aor --preset fast` is unchanged to the last bit.
//! - **Only the plain law.** The lane path serves tables without cohesion and the CDT rolling
//!   model (the experiments' defaults); anything else takes the scalar loop
//!   ([`PairPath::for_world`]).
//!
//! Layout: a chunk's pairs are scanned first and the touching ones compacted (without a
//! branch on touching / not touching, which is poorly predicted: ~40 % of listed pairs are
//! near misses), then computed in groups of [`LANES`] across particles (a particle has only
//! ~2-3 touching pairs of its own: grouping per particle left most lanes idle and was 30 %
//! slower than the scalar loop); a short last group repeats its last contact in the spare
//! lanes and discards them. The chunk's particles then sum their pairs' terms in pair order.

use wide::{f64x4, CmpGt, CmpLe};

use super::kernel::{ContactContext, ParticleReads};
use super::*;

/// Contacts computed together.
const LANES: usize = 4;

type Lane = [f64; LANES];

/// Which code computes a chunk's own pairs (fixed per force evaluation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum PairPath {
    /// The per-pair loop of [`super::kernel`] (every law).
    Scalar,
    /// The lane kernel (no cohesion, CDT rolling).
    Lanes,
}

impl PairPath {
    pub(super) fn for_world(
        choice: KernelChoice,
        materials: &MaterialTable,
        rolling: RollingModel,
    ) -> PairPath {
        let plain =
            !materials.any_cohesion() && matches!(rolling, RollingModel::ConstantDirectionalTorque);
        match choice {
            KernelChoice::Auto if plain => PairPath::Lanes,
            KernelChoice::Auto | KernelChoice::Scalar => PairPath::Scalar,
        }
    }
}

/// A chunk's touching pairs and their results, in pair order (kept between chunks so that
/// their storage is reused).
#[derive(Default)]
pub(super) struct ChunkPairs {
    /// Per particle of the chunk: the end of its touching pairs in the arrays below.
    pub(super) end: Vec<u32>,
    /// The pair's index from the chunk's first pair, and its lower particle i.
    local: Vec<u32>,
    owner: Vec<u32>,
    /// Separation d = xi − xj and |d|².
    dx: Vec<f64>,
    dy: Vec<f64>,
    dz: Vec<f64>,
    dist2: Vec<f64>,
    /// Results: the force on i, the torque `(n × F) lever_i` i loses, i's CDT moment.
    fx: Vec<f64>,
    fy: Vec<f64>,
    fz: Vec<f64>,
    tx: Vec<f64>,
    ty: Vec<f64>,
    tz: Vec<f64>,
    moment: Vec<f64>,
}

impl ChunkPairs {
    /// Touching pair t's force on i, the torque to subtract from i's, and i's CDT moment.
    #[inline(always)]
    pub(super) fn result(&self, t: usize) -> (Vec3, Vec3, f64) {
        (
            Vec3::new(self.fx[t], self.fy[t], self.fz[t]),
            Vec3::new(self.tx[t], self.ty[t], self.tz[t]),
            self.moment[t],
        )
    }

    fn reserve(&mut self, particles: usize, pairs: usize) {
        self.end.resize(particles, 0);
        for v in [&mut self.local, &mut self.owner] {
            if v.len() < pairs {
                v.resize(pairs, 0);
            }
        }
        for v in [
            &mut self.dx,
            &mut self.dy,
            &mut self.dz,
            &mut self.dist2,
            &mut self.fx,
            &mut self.fy,
            &mut self.fz,
            &mut self.tx,
            &mut self.ty,
            &mut self.tz,
            &mut self.moment,
        ] {
            if v.len() < pairs {
                v.resize(pairs, 0.0);
            }
        }
    }
}

/// The chunk's own pairs (no cohesion, CDT rolling): flags and resets each pair's contact
/// state, computes every touching pair's law (four at a time), writes its spring and its
/// share for j, and leaves i's terms in `out` in pair order.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn chunk_pairs(
    ctx: &ContactContext,
    r: &ParticleReads,
    particles: std::ops::Range<usize>,
    first_pair: &[u32],
    partner: &mut [u32],
    tangential: &mut [Vec3],
    share: &mut [PartnerShare],
    out: &mut ChunkPairs,
) {
    let n = r.position.len();
    let (position, radius) = (&r.position[..n], &r.radius[..n]);
    let pair_count = partner.len();
    let tangential = &mut tangential[..pair_count];
    let share = &mut share[..pair_count];
    out.reserve(particles.len(), pair_count);
    let base = first_pair[particles.start] as usize;

    // Compact the touching pairs (no branch on touching: ~40 % of listed pairs are near
    // misses, a poorly predicted branch).
    let mut count = 0;
    {
        let local_out = &mut out.local[..pair_count];
        let owner_out = &mut out.owner[..pair_count];
        let (sx, sy, sz, s2) = (
            &mut out.dx[..pair_count],
            &mut out.dy[..pair_count],
            &mut out.dz[..pair_count],
            &mut out.dist2[..pair_count],
        );
        for (k, i) in particles.clone().enumerate() {
            let xi = position[i];
            let ri = radius[i];
            for local in first_pair[i] as usize - base..first_pair[i + 1] as usize - base {
                let entry = partner[local];
                let j = (entry & PARTNER_INDEX) as usize;
                let raw = xi - position[j];
                let d = if entry & WRAPS != 0 {
                    ctx.domain.minimum_image(raw)
                } else {
                    raw
                };
                let dist2 = d.norm_squared();
                let rsum = ri + radius[j];
                #[allow(clippy::neg_cmp_op_on_partial_ord)] // the scalar loop's test, NaN included
                let touching = !(dist2 >= rsum * rsum);
                local_out[count] = local as u32;
                owner_out[count] = i as u32;
                sx[count] = d.x;
                sy[count] = d.y;
                sz[count] = d.z;
                s2[count] = dist2;
                count += touching as usize;
                let was = entry & IN_CONTACT != 0;
                if was & !touching {
                    // Separated since the last step: the history and the share are reset
                    // (the gather adds every share, so a pair out of contact holds zeros).
                    tangential[local] = Vec3::zeros();
                    share[local] = PartnerShare::default();
                }
                partner[local] = (entry & !IN_CONTACT) | ((touching as u32) * IN_CONTACT);
            }
            out.end[k] = count as u32;
        }
    }

    // The law, four touching pairs at a time (a short last group repeats its last pair).
    let mut g = 0;
    while g < count {
        let k = (count - g).min(LANES);
        let lane = |l: usize| g + l.min(k - 1);
        let local: [usize; LANES] = std::array::from_fn(|l| out.local[lane(l)] as usize);
        let input = LaneInput {
            owner: std::array::from_fn(|l| out.owner[lane(l)] as usize),
            partner: std::array::from_fn(|l| (partner[local[l]] & PARTNER_INDEX) as usize),
            dx: lanes(|l| out.dx[lane(l)]),
            dy: lanes(|l| out.dy[lane(l)]),
            dz: lanes(|l| out.dz[lane(l)]),
            dist2: lanes(|l| out.dist2[lane(l)]),
            spring: std::array::from_fn(|l| tangential[local[l]]),
        };
        let o = contact_lanes(ctx, r, &input);
        for l in 0..k {
            let t = g + l;
            out.fx[t] = o.fx[l];
            out.fy[t] = o.fy[l];
            out.fz[t] = o.fz[l];
            out.tx[t] = o.ti_x[l];
            out.ty[t] = o.ti_y[l];
            out.tz[t] = o.ti_z[l];
            out.moment[t] = o.moment_i[l];
            tangential[local[l]] = Vec3::new(o.spring_x[l], o.spring_y[l], o.spring_z[l]);
            share[local[l]] = PartnerShare {
                force: -Vec3::new(o.fx[l], o.fy[l], o.fz[l]),
                torque: Vec3::new(o.tj_x[l], o.tj_y[l], o.tj_z[l]),
                rolling_moment: o.moment_j[l],
            };
        }
        g += LANES;
    }
}

/// One group's inputs: the pair (i, j), separation d = xi − xj, |d|², the stored spring.
struct LaneInput {
    owner: [usize; LANES],
    partner: [usize; LANES],
    dx: Lane,
    dy: Lane,
    dz: Lane,
    dist2: Lane,
    spring: [Vec3; LANES],
}

/// One group's results: the force on i, the torque `n × F · lever_i` to subtract from i's,
/// j's torque, both CDT moments and the updated spring.
struct LaneOutput {
    fx: Lane,
    fy: Lane,
    fz: Lane,
    ti_x: Lane,
    ti_y: Lane,
    ti_z: Lane,
    tj_x: Lane,
    tj_y: Lane,
    tj_z: Lane,
    moment_i: Lane,
    moment_j: Lane,
    spring_x: Lane,
    spring_y: Lane,
    spring_z: Lane,
}

#[inline(always)]
fn lanes(f: impl Fn(usize) -> f64) -> Lane {
    [f(0), f(1), f(2), f(3)]
}

/// `hertz_mindlin` + the CDT moments of `particle_contacts`, lane by lane, in the scalar
/// code's operation order.
#[inline(always)]
fn contact_lanes(ctx: &ContactContext, r: &ParticleReads, input: &LaneInput) -> LaneOutput {
    let n = r.position.len();
    let (velocity, angular_velocity, radius, mass, material) = (
        &r.velocity[..n],
        &r.angular_velocity[..n],
        &r.radius[..n],
        &r.mass[..n],
        &r.material[..n],
    );
    let (i, j) = (input.owner, input.partner);
    let v = |f: &dyn Fn(usize) -> f64| f64x4::new(lanes(f));
    let splat = f64x4::splat;
    let zero = f64x4::ZERO;
    let dt = splat(ctx.dt);
    // Negation as the sign flip (`wide`'s `-x` is `0 - x`, which is +0 for x = 0).
    let neg = |x: f64x4| x ^ splat(-0.0);

    // Gathers.
    let ri = v(&|l| radius[i[l]]);
    let mi = v(&|l| mass[i[l]]);
    let vix = v(&|l| velocity[i[l]].x);
    let viy = v(&|l| velocity[i[l]].y);
    let viz = v(&|l| velocity[i[l]].z);
    let wix = v(&|l| angular_velocity[i[l]].x);
    let wiy = v(&|l| angular_velocity[i[l]].y);
    let wiz = v(&|l| angular_velocity[i[l]].z);
    let rj = v(&|l| radius[j[l]]);
    let mj = v(&|l| mass[j[l]]);
    let vjx = v(&|l| velocity[j[l]].x);
    let vjy = v(&|l| velocity[j[l]].y);
    let vjz = v(&|l| velocity[j[l]].z);
    let wjx = v(&|l| angular_velocity[j[l]].x);
    let wjy = v(&|l| angular_velocity[j[l]].y);
    let wjz = v(&|l| angular_velocity[j[l]].z);
    let constants: [&crate::material::PairConstants; LANES] =
        std::array::from_fn(|l| ctx.materials.pair(material[i[l]], material[j[l]]));
    let e_star = v(&|l| constants[l].e_star);
    let g_star = v(&|l| constants[l].g_star);
    let beta = v(&|l| constants[l].beta);
    let mu = v(&|l| constants[l].static_friction);
    let mu_r = v(&|l| constants[l].rolling_friction);
    let t_to_n = v(&|l| constants[l].tangential_to_normal_damping);
    let spx = v(&|l| input.spring[l].x);
    let spy = v(&|l| input.spring[l].y);
    let spz = v(&|l| input.spring[l].z);
    let (dx, dy, dz) = (
        f64x4::new(input.dx),
        f64x4::new(input.dy),
        f64x4::new(input.dz),
    );

    // Geometry of the contact.
    let dist = f64x4::new(input.dist2).sqrt();
    let inv = splat(1.0) / dist;
    let (nx, ny, nz) = (dx * inv, dy * inv, dz * inv);
    let rsum = ri + rj;
    let overlap = rsum - dist;
    let half = splat(0.5);
    let lever_i = ri - half * overlap;
    let lever_j = rj - half * overlap;
    // relative velocity = vi − vj − (wi lever_i + wj lever_j) × n
    let ax = wix * lever_i + wjx * lever_j;
    let ay = wiy * lever_i + wjy * lever_j;
    let az = wiz * lever_i + wjz * lever_j;
    let rvx = (vix - vjx) - (ay * nz - az * ny);
    let rvy = (viy - vjy) - (az * nx - ax * nz);
    let rvz = (viz - vjz) - (ax * ny - ay * nx);
    let r_star = ri * rj / rsum;
    let m_star = mi * mj / (mi + mj);

    // Hertz-Mindlin (`contact::hertz_mindlin`).
    let sqrt_r_delta = (r_star * overlap).sqrt();
    let sn = splat(2.0) * e_star * sqrt_r_delta;
    let st = splat(8.0) * g_star * sqrt_r_delta;
    let normal_dashpot = splat(-crate::contact::DAMPING_FACTOR) * beta * (sn * m_star).sqrt();
    let tangential_dashpot = normal_dashpot * t_to_n;
    let vn = rvx * nx + rvy * ny + rvz * nz;
    let fn_elastic = splat(2.0 / 3.0) * sn * overlap;
    let fn_damping = neg(normal_dashpot) * vn;
    // `f64::max(x, 0.0)`: 0 for a NaN x, as `max` here.
    let normal_force = (fn_elastic + fn_damping).max(zero);
    let vtx = rvx - nx * vn;
    let vty = rvy - ny * vn;
    let vtz = rvz - nz * vn;

    // The spring rotated into the tangent plane (`rotate_into_tangent_plane`): both of its
    // branches, one selected.
    let old_len2 = spx * spx + spy * spy + spz * spz;
    let along = nx * spx + ny * spy + nz * spz;
    let px = spx - nx * along;
    let py = spy - ny * along;
    let pz = spz - nz * along;
    let new_len2 = px * px + py * py + pz * pz;
    let scale = (old_len2 / new_len2).sqrt();
    let exact = (along * along).cmp_le(splat(1e-16) * old_len2);
    let positive = new_len2.cmp_gt(zero);
    let rotate = |p: f64x4| exact.blend(p, positive.blend(p * scale, zero));
    let spx = rotate(px) + vtx * dt;
    let spy = rotate(py) + vty * dt;
    let spz = rotate(pz) + vtz * dt;
    let ftx = neg(spx) * st - vtx * tangential_dashpot;
    let fty = neg(spy) * st - vty * tangential_dashpot;
    let ftz = neg(spz) * st - vtz * tangential_dashpot;

    // Coulomb cap: sliding lanes scale the force and reset the spring.
    let cap = mu * normal_force;
    let ft_len2 = ftx * ftx + fty * fty + ftz * ftz;
    let slide = ft_len2.cmp_gt(cap * cap);
    let cut = cap / ft_len2.sqrt();
    let scaled = slide & ft_len2.cmp_gt(zero);
    let ftx = scaled.blend(ftx * cut, ftx);
    let fty = scaled.blend(fty * cut, fty);
    let ftz = scaled.blend(ftz * cut, ftz);
    let inv_st = splat(-1.0) / st;
    let stiff = st.cmp_gt(zero);
    let reset = |ft: f64x4, spring: f64x4| slide.blend(stiff.blend(ft * inv_st, zero), spring);
    let spring_x = reset(ftx, spx);
    let spring_y = reset(fty, spy);
    let spring_z = reset(ftz, spz);
    let fx = nx * normal_force + ftx;
    let fy = ny * normal_force + fty;
    let fz = nz * normal_force + ftz;

    // Torques and CDT moments (`particle_contacts`).
    let cx = ny * fz - nz * fy;
    let cy = nz * fx - nx * fz;
    let cz = nx * fy - ny * fx;
    let m = mu_r * normal_force;
    LaneOutput {
        fx: fx.to_array(),
        fy: fy.to_array(),
        fz: fz.to_array(),
        ti_x: (cx * lever_i).to_array(),
        ti_y: (cy * lever_i).to_array(),
        ti_z: (cz * lever_i).to_array(),
        tj_x: (neg(cx) * lever_j).to_array(),
        tj_y: (neg(cy) * lever_j).to_array(),
        tj_z: (neg(cz) * lever_j).to_array(),
        moment_i: (m * lever_i).to_array(),
        moment_j: (m * lever_j).to_array(),
        spring_x: spring_x.to_array(),
        spring_y: spring_y.to_array(),
        spring_z: spring_z.to_array(),
    }
}
