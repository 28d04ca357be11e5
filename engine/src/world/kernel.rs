//! The per-particle work shared by both dispatch paths: one particle's own pairs and geometry
//! contacts, and its gather + integration.

use super::lanes::PairPath;
use super::walls::WallCandidates;
use super::*;
use crate::contact::{
    epsd_rolling_stiffness, epsd_rolling_torque, hertz_mindlin, sphere_sphere_contact_radius2,
    sphere_wall_contact_radius2,
};

/// Step-constant inputs of the contact law.
pub(super) struct ContactContext<'a> {
    /// Spring time step (0 for the Verlet start-up evaluation).
    pub(super) dt: f64,
    pub(super) gravity: Vec3,
    pub(super) domain: Domain,
    pub(super) rolling_model: RollingModel,
    pub(super) materials: &'a MaterialTable,
    /// Some pair has JKR cohesion (`MaterialTable::any_jkr`): contacts may neck.
    pub(super) any_jkr: bool,
    /// The code that computes a particle's own pairs.
    pub(super) pair_path: PairPath,
    pub(super) geometries: &'a [Geometry],
    pub(super) placed: &'a [PlacedGeometry],
    pub(super) walls: &'a WallCandidates,
}

/// The particle arrays the contact law reads.
pub(super) struct ParticleReads<'a> {
    pub(super) position: &'a [Vec3],
    pub(super) velocity: &'a [Vec3],
    pub(super) angular_velocity: &'a [Vec3],
    pub(super) radius: &'a [f64],
    pub(super) mass: &'a [f64],
    pub(super) inverse_inertia: &'a [f64],
    pub(super) material: &'a [MaterialId],
}

/// Reusable buffers of the geometry contacts.
#[derive(Default)]
pub(super) struct Scratch {
    pub(super) mesh_contacts: Vec<MeshContact>,
    pub(super) new_walls: Vec<WallHistory>,
    /// The lane path's per-chunk pair buffers.
    pub(super) pairs: super::lanes::ChunkPairs,
}

thread_local! {
    /// Each thread's reusable buffers. Their contents never outlive one particle's or one
    /// chunk's use, so results do not depend on which thread ran what.
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// `f` with this thread's scratch buffers (kept across steps: no allocation or zeroing).
pub(super) fn with_scratch<T>(f: impl FnOnce(&mut Scratch) -> T) -> T {
    SCRATCH.with_borrow_mut(f)
}

/// Step-constant inputs of the gather + integrate step.
pub(super) struct GatherContext {
    pub(super) dt: f64,
    pub(super) domain: Domain,
    pub(super) cdt: bool,
    pub(super) after: AfterForces,
}

/// The state one particle's gather + integrate step writes.
pub(super) struct ParticleState<'a> {
    pub(super) force: &'a mut Vec3,
    pub(super) torque: &'a mut Vec3,
    pub(super) position: &'a mut Vec3,
    pub(super) velocity: &'a mut Vec3,
    pub(super) angular_velocity: &'a mut Vec3,
}

/// The particle arrays of one chunk (particles `start..start + force.len()`): its pairs
/// (indexed from the chunk's first pair), wall histories, and the force, torque and CDT
/// rolling moment its particles receive from their own pairs and geometry contacts.
pub(super) struct ChunkOut<'a> {
    pub(super) start: usize,
    pub(super) partner: &'a mut [u32],
    pub(super) tangential: &'a mut [Vec3],
    pub(super) rolling: &'a mut [Vec3],
    pub(super) share: &'a mut [PartnerShare],
    pub(super) walls: &'a mut [Vec<WallHistory>],
    pub(super) force: &'a mut [Vec3],
    pub(super) torque: &'a mut [Vec3],
    pub(super) moment: &'a mut [f64],
}

/// A chunk's own pairs and geometry contacts: every particle i's force, torque and CDT
/// moment, with its pairs' terms summed in pair order, then its geometry contacts. The lane
/// path computes the whole chunk's touching pairs first, four at a time; the scalar path goes
/// particle by particle. Either way the sums run in the same order (bit-identical).
#[inline(always)]
pub(super) fn chunk_contacts(
    ctx: &ContactContext,
    r: &ParticleReads,
    first_pair: &[u32],
    c: ChunkOut,
    scratch: &mut Scratch,
    loads: &mut [(Vec3, Vec3)],
) {
    let base = first_pair[c.start] as usize;
    let lanes = ctx.pair_path == PairPath::Lanes;
    if lanes {
        super::lanes::chunk_pairs(
            ctx,
            r,
            c.start..c.start + c.force.len(),
            first_pair,
            c.partner,
            c.tangential,
            c.share,
            &mut scratch.pairs,
        );
    }
    let mut t = 0;
    for k in 0..c.force.len() {
        let i = c.start + k;
        let sums = if lanes {
            // The lane results of i's touching pairs, in pair order.
            let (mut f, mut tq, mut moment) = (ctx.gravity * r.mass[i], Vec3::zeros(), 0.0);
            let stop = scratch.pairs.end[k] as usize;
            while t < stop {
                let (force, torque, m) = scratch.pairs.result(t);
                f += force;
                tq -= torque;
                moment += m;
                t += 1;
            }
            (f, tq, moment)
        } else {
            let range = first_pair[i] as usize - base..first_pair[i + 1] as usize - base;
            let rolling: &mut [Vec3] = if c.rolling.is_empty() {
                &mut []
            } else {
                &mut c.rolling[range.clone()]
            };
            pairs_scalar(
                ctx,
                r,
                i,
                &mut c.partner[range.clone()],
                &mut c.tangential[range.clone()],
                rolling,
                &mut c.share[range],
            )
        };
        let (f, tq, moment) = geometry_contacts(ctx, r, i, sums, &mut c.walls[k], scratch, loads);
        c.force[k] = f;
        c.torque[k] = tq;
        c.moment[k] = moment;
    }
}

/// Particle i's geometry contacts, added to `sums` (its force, torque and CDT moment from
/// its pairs). Returns the totals.
#[inline(always)]
fn geometry_contacts(
    ctx: &ContactContext,
    r: &ParticleReads,
    i: usize,
    sums: (Vec3, Vec3, f64),
    walls: &mut Vec<WallHistory>,
    scratch: &mut Scratch,
    loads: &mut [(Vec3, Vec3)],
) -> (Vec3, Vec3, f64) {
    let (mut f, mut tq, mut moment) = sums;
    let dt = ctx.dt;
    let materials = ctx.materials;
    let rolling_model = ctx.rolling_model;
    let xi = r.position[i];
    let vi = r.velocity[i];
    let wi = r.angular_velocity[i];
    let ri = r.radius[i];
    let mi = r.mass[i];
    let mat_i = r.material[i];

    // Geometry contacts, geometry by geometry, in mesh order.
    if ctx.geometries.is_empty() {
        return (f, tq, moment);
    }
    let Scratch {
        mesh_contacts,
        new_walls,
        ..
    } = scratch;
    new_walls.clear();
    // Candidates are sorted by geometry: one cursor walks them alongside the geometries.
    let (candidate_geometry, candidate_triangle) = ctx.walls.of(i);
    let mut cursor = 0;
    for (g, (geometry, placement)) in ctx.geometries.iter().zip(ctx.placed).enumerate() {
        let first = cursor;
        while cursor < candidate_geometry.len() && candidate_geometry[cursor] == g as u32 {
            cursor += 1;
        }
        let candidates = &candidate_triangle[first..cursor];
        let far = if placement.cached {
            candidates.is_empty()
        } else {
            let reach = Vec3::repeat(ri);
            let (lo, hi) = (xi - reach, xi + reach);
            (0..3).any(|a| lo[a] > placement.aabb_max[a] || hi[a] < placement.aabb_min[a])
        };
        if far {
            continue;
        }
        mesh_contacts.clear();
        let body_centre = placement.inverse.transform_point(&xi.into()).coords;
        if placement.cached {
            geometry
                .mesh
                .sphere_contacts_among(body_centre, ri, candidates, mesh_contacts);
        } else {
            geometry
                .mesh
                .sphere_contacts(body_centre, ri, mesh_contacts);
        }
        for mc in mesh_contacts.iter() {
            let point = placement.pose.transform_point(&mc.point.into()).coords;
            let normal = placement.pose.rotation * mc.normal;
            // The previous contact with this geometry whose normal is closest.
            let previous = walls
                .iter()
                .filter(|h| h.geometry == g as u32)
                .map(|h| (h.normal.dot(&normal), h))
                .filter(|(dot, _)| *dot > 0.9)
                .max_by(|a, b| a.0.total_cmp(&b.0))
                .map(|(_, h)| *h);
            let mut history = previous.unwrap_or(WallHistory {
                geometry: g as u32,
                normal,
                tangential: Vec3::zeros(),
                rolling: Vec3::zeros(),
            });
            history.normal = normal;
            let arm = point - xi;
            // `Motion::velocity_of_point` with the step's velocities.
            let wall_velocity = placement.linear_velocity
                + placement
                    .angular_velocity
                    .cross(&(point - placement.reference_point));
            let relative_velocity = vi + wi.cross(&arm) - wall_velocity;
            let constants = materials.pair(mat_i, geometry.material);
            let mut contact = hertz_mindlin(
                constants,
                ri,
                mi,
                mc.overlap,
                normal,
                relative_velocity,
                dt,
                &mut history.tangential,
            );
            if constants.cohesion.is_on() {
                // A wall contact ends at zero overlap (the mesh query finds overlapping
                // triangles only): no JKR necking against geometry.
                let pull = constants.cohesion.attraction(ri, mc.overlap, || {
                    sphere_wall_contact_radius2(ri, mc.overlap)
                });
                contact.force -= normal * pull;
            }
            f += contact.force;
            tq += arm.cross(&contact.force);
            match rolling_model {
                RollingModel::ConstantDirectionalTorque => {
                    moment += constants.rolling_friction * contact.normal_force * arm.norm();
                }
                RollingModel::ElasticPlasticSpringDashpot { viscous_damping } => {
                    let kr = epsd_rolling_stiffness(
                        contact.normal_stiffness,
                        constants.rolling_friction,
                        ri,
                    );
                    let inertia_r = 1.0 / r.inverse_inertia[i] + mi * ri * ri;
                    tq += epsd_rolling_torque(
                        normal,
                        wi - placement.angular_velocity,
                        kr,
                        constants.rolling_friction * ri * contact.normal_force,
                        viscous_damping * 2.0 * (inertia_r * kr).sqrt(),
                        dt,
                        &mut history.rolling,
                    );
                }
            }
            let load = &mut loads[g];
            load.0 -= contact.force;
            load.1 += (point - placement.reference_point).cross(&-contact.force);
            new_walls.push(history);
        }
    }
    if !new_walls.is_empty() || !walls.is_empty() {
        walls.clear();
        walls.extend_from_slice(new_walls);
    }
    (f, tq, moment)
}

/// Particle i's own pairs, one at a time (every law): returns i's force (with gravity),
/// torque and CDT rolling moment from them, writes each touching pair's share for j.
#[inline(always)]
fn pairs_scalar(
    ctx: &ContactContext,
    r: &ParticleReads,
    i: usize,
    partner: &mut [u32],
    tangential: &mut [Vec3],
    rolling: &mut [Vec3],
    share: &mut [PartnerShare],
) -> (Vec3, Vec3, f64) {
    let dt = ctx.dt;
    let domain = &ctx.domain;
    let materials = ctx.materials;
    let rolling_model = ctx.rolling_model;
    let use_rolling_spring = !rolling.is_empty();
    let xi = r.position[i];
    let vi = r.velocity[i];
    let wi = r.angular_velocity[i];
    let ri = r.radius[i];
    let mi = r.mass[i];
    let mat_i = r.material[i];
    let mut f = ctx.gravity * mi;
    let mut tq = Vec3::zeros();
    let mut moment = 0.0;
    // The partner reads, cut to one length so that one bounds check covers them all.
    let n = r.position.len();
    let (position, velocity, angular_velocity, radius, mass, material) = (
        &r.position[..n],
        &r.velocity[..n],
        &r.angular_velocity[..n],
        &r.radius[..n],
        &r.mass[..n],
        &r.material[..n],
    );
    for (local, entry) in partner.iter_mut().enumerate() {
        let j = (*entry & PARTNER_INDEX) as usize;
        let rj = radius[j];
        let raw = xi - position[j];
        let d = if *entry & WRAPS != 0 {
            domain.minimum_image(raw)
        } else {
            raw
        };
        let dist2 = d.norm_squared();
        let rsum = ri + rj;
        if dist2 >= rsum * rsum {
            // A JKR contact outlives zero overlap (necking) until its separation distance,
            // while the pair stays in the list (gap < skin at the last build; JKR's
            // separation gap is microns for soils, the skin a sizeable part of a diameter).
            // Only an attractive normal force acts there: no Hertz load, so no friction.
            if ctx.any_jkr && *entry & IN_CONTACT != 0 {
                let constants = materials.pair(mat_i, material[j]);
                let r_star = ri * rj / rsum;
                let dist = dist2.sqrt();
                if let Some(pull) = constants.cohesion.necking_force(r_star, rsum - dist) {
                    let force = d * (pull / dist);
                    f += force;
                    tangential[local] = Vec3::zeros();
                    if use_rolling_spring {
                        rolling[local] = Vec3::zeros();
                    }
                    share[local] = PartnerShare {
                        force: -force,
                        torque: Vec3::zeros(),
                        rolling_moment: 0.0,
                    };
                    continue;
                }
            }
            // Not touching: histories and the share are reset (only if set: a pair out of
            // contact holds zeros, see `IN_CONTACT`).
            if *entry & IN_CONTACT != 0 {
                *entry &= !IN_CONTACT;
                tangential[local] = Vec3::zeros();
                share[local] = PartnerShare::default();
                if use_rolling_spring {
                    rolling[local] = Vec3::zeros();
                }
            }
            continue;
        }
        *entry |= IN_CONTACT;
        let dist = dist2.sqrt();
        // One division, not nalgebra's three for `d / dist`.
        let normal = d * (1.0 / dist);
        let overlap = rsum - dist;
        // Contact point halfway through the overlap.
        let lever_i = ri - 0.5 * overlap;
        let lever_j = rj - 0.5 * overlap;
        let wj = angular_velocity[j];
        let relative_velocity = vi - velocity[j] - (wi * lever_i + wj * lever_j).cross(&normal);
        let mj = mass[j];
        let r_star = ri * rj / rsum;
        let m_star = mi * mj / (mi + mj);
        let constants = materials.pair(mat_i, material[j]);
        let mut contact = hertz_mindlin(
            constants,
            r_star,
            m_star,
            overlap,
            normal,
            relative_velocity,
            dt,
            &mut tangential[local],
        );
        if constants.cohesion.is_on() {
            // Attraction along the normal; friction and rolling keep the Hertz load.
            let pull = constants.cohesion.attraction(r_star, overlap, || {
                sphere_sphere_contact_radius2(ri, rj, dist2, overlap)
            });
            contact.force -= normal * pull;
        }
        let n_cross_f = normal.cross(&contact.force);
        f += contact.force;
        tq -= n_cross_f * lever_i;
        let mut torque_j = -n_cross_f * lever_j;
        let mut moment_j = 0.0;
        match rolling_model {
            RollingModel::ConstantDirectionalTorque => {
                let m = constants.rolling_friction * contact.normal_force;
                moment += m * lever_i;
                moment_j = m * lever_j;
            }
            RollingModel::ElasticPlasticSpringDashpot { viscous_damping } => {
                let kr = epsd_rolling_stiffness(
                    contact.normal_stiffness,
                    constants.rolling_friction,
                    r_star,
                );
                let inertia_i = 1.0 / r.inverse_inertia[i] + mi * ri * ri;
                let inertia_j = 1.0 / r.inverse_inertia[j] + mj * rj * rj;
                let inertia_r = inertia_i * inertia_j / (inertia_i + inertia_j);
                let mr = epsd_rolling_torque(
                    normal,
                    wi - wj,
                    kr,
                    constants.rolling_friction * r_star * contact.normal_force,
                    viscous_damping * 2.0 * (inertia_r * kr).sqrt(),
                    dt,
                    &mut rolling[local],
                );
                tq += mr;
                torque_j -= mr;
            }
        }
        share[local] = PartnerShare {
            force: -contact.force,
            torque: torque_j,
            rolling_moment: moment_j,
        };
    }

    (f, tq, moment)
}

/// Particle i adds the shares of the pairs it is the higher index of (`incident`; a pair out
/// of contact holds a zero share) to its own force, torque and CDT moment, applies CDT rolling
/// friction, then integrates. Returns whether it moved far enough (or out of the domain) to
/// need a rebuild.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn gather_particle(
    g: &GatherContext,
    mut force: Vec3,
    mut torque: Vec3,
    mut rolling: f64,
    incident: &[u32],
    shares: &[PartnerShare],
    mass: f64,
    inv_i: f64,
    mark: BuildMark,
    s: ParticleState,
) -> bool {
    let dt = g.dt;
    let domain = &g.domain;
    // Every incident pair's share, without testing its flag: a pair out of contact holds a
    // zero share, and adding +0 changes no sum (the flag test was a poorly predicted branch
    // and a scattered read of `partner`).
    for &pair in incident {
        let share = &shares[pair as usize];
        force += share.force;
        torque += share.torque;
        rolling += share.rolling_moment;
    }
    let w = s.angular_velocity;
    // The spin's change over `h` seconds: the torque's kick, then CDT's rolling moment as a
    // brake (`rolling_brake`) with a whole step's impulse. `torque` stays the contacts' alone
    // (Verlet's next opening half kick applies it again), so the brake acts once per step.
    let kick_spin = |w: &mut Vec3, h: f64| {
        let spin = *w + torque * (h * inv_i);
        *w = if g.cdt && rolling > 0.0 {
            rolling_brake(spin, rolling * dt * inv_i)
        } else {
            spin
        };
    };
    *s.force = force;
    *s.torque = torque;
    let (x, v) = (s.position, s.velocity);
    match g.after {
        AfterForces::EulerUpdate => {
            *v += force * (dt / mass);
            kick_spin(w, dt);
            // No periodic wrap here: positions move continuously between builds (see
            // `WRAPS`), and the rebuild wraps them.
            *x += *v * dt;
            mark.moved_too_far(*x) || domain.is_outside(*x)
        }
        AfterForces::HalfKick => {
            *v += force * (0.5 * dt / mass);
            kick_spin(w, 0.5 * dt);
            false
        }
        AfterForces::Nothing => false,
    }
}

/// Constant-directional-torque rolling friction as a brake on the new spin: `spin` is ω after
/// this step's contact torques, `limit` = M Δt / I the most the rolling moment M can take off
/// |ω| in one step. The brake opposes `spin` and stops at zero: below the limit the grain does
/// not turn at all (rolling friction holds it, as static friction holds a sliding contact).
///
/// Why implicit (the direction is the new spin's, not the old): taken from the old ω, the
/// torque vanishes at ω = 0, so a grain under a steady contact torque τ below M turns by
/// τ Δt / I every step, a creep proportional to Δt that never stops (it slumped every heap, and
/// with cohesion's stiff contacts it fed an unstable rotation-shear mode that made heaps
/// boil at Δt = 0.2 Rayleigh times). Braking the new spin has neither: it is the Δt → 0 limit of
/// the explicit rule, reached at any Δt, it never reverses ω and never adds energy.
#[inline(always)]
pub(super) fn rolling_brake(spin: Vec3, limit: f64) -> Vec3 {
    let speed2 = spin.norm_squared();
    if speed2 <= limit * limit {
        Vec3::zeros()
    } else {
        spin * (1.0 - limit / speed2.sqrt())
    }
}
