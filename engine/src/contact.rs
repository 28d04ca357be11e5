//! The contact law: Hertz-Mindlin (no slip) with tangential history, and rolling friction.
//!
//! Everything here is a pure function of one contact's kinematics and its history, so the same
//! code serves particle-particle and particle-geometry contacts and can be tested in isolation.
//! Sign convention: `normal` is the unit vector pointing from the other body (particle j, or the
//! geometry surface) towards particle i, and every returned force/torque acts on particle i.

use serde::{Deserialize, Serialize};

use crate::material::{Cohesion, PairConstants};
use crate::math::Vec3;

/// 2 sqrt(5/6), the factor of EDEM's Hertz-Mindlin damping terms.
pub(crate) const DAMPING_FACTOR: f64 = 1.825_741_858_350_553_8;

/// How rolling resistance is modelled.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum RollingModel {
    /// EDEM's default "constant directional torque": τi = -μr Fn Ri ω̂i, with ω̂i particle i's own
    /// angular velocity direction and Ri the distance from its centre to the contact point.
    ///
    /// The torque does not vanish as ω → 0, so applied naively it flips ω's sign every step
    /// (chatter). We apply it as a brake on the new spin (the world's `rolling_brake`): after
    /// the contact torques, |ω| is reduced by at most μr Fn Ri Δt / I and never reversed, so a
    /// grain whose contact torque stays below the rolling moment does not turn at all.
    #[default]
    ConstantDirectionalTorque,
    /// Elastic-plastic spring-dashpot (Ai, Chen, Rotter & Ooi 2011, "model C"): a rolling
    /// spring kr = 2.25 kn μr² R*² loaded incrementally by the relative rolling rotation and
    /// capped at μr R* Fn, plus a viscous dashpot Cr = ηr · 2 sqrt(Ir kr) that is switched off
    /// while the spring is at its cap (full mobilisation).
    ElasticPlasticSpringDashpot {
        /// Ai's ηr: the dashpot as a fraction of critical rolling damping (default 0.3).
        viscous_damping: f64,
    },
}

impl RollingModel {
    /// EPSD with Ai et al.'s recommended ηr = 0.3.
    pub fn epsd() -> RollingModel {
        RollingModel::ElasticPlasticSpringDashpot {
            viscous_damping: 0.3,
        }
    }
}

/// Result of the normal + tangential law for one contact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactForce {
    /// Total force on particle i (normal + tangential), N.
    pub force: Vec3,
    /// Magnitude of the Hertz normal force (elastic + damping, clamped at >= 0), N: without
    /// cohesion the whole normal force; with it, the repulsive part that the Coulomb cap and the
    /// rolling torque use (see [`CohesionLaw`]). `force` does not include cohesion.
    pub normal_force: f64,
    /// Hertz normal tangent stiffness Sn = dFn/dδ = 2 E* sqrt(R* δ), N/m.
    pub normal_stiffness: f64,
}

/// Hertz-Mindlin no-slip normal and tangential force.
///
/// * `overlap` δ > 0, `normal` unit (other body → i), `relative_velocity` = velocity of i's
///   material point at the contact minus the other body's, m/s.
/// * `spring` is the stored tangential displacement δt of this contact (m), updated in place:
///   first rotated into the current tangent plane (projected, then rescaled to keep its
///   magnitude, so a rotating contact neither loses nor gains stored elastic energy), then
///   incremented by vt Δt.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn hertz_mindlin(
    constants: &PairConstants,
    r_star: f64,
    m_star: f64,
    overlap: f64,
    normal: Vec3,
    relative_velocity: Vec3,
    dt: f64,
    spring: &mut Vec3,
) -> ContactForce {
    let sqrt_r_delta = (r_star * overlap).sqrt();
    let sn = 2.0 * constants.e_star * sqrt_r_delta;
    let st = 8.0 * constants.g_star * sqrt_r_delta;
    // Dashpot coefficients 2 sqrt(5/6) (-β) sqrt(S m*); the tangential one is the normal one
    // times sqrt(St/Sn) = sqrt(4 G*/E*), a material-pair constant (saves a square root).
    let normal_dashpot = -DAMPING_FACTOR * constants.beta * (sn * m_star).sqrt();
    let tangential_dashpot = normal_dashpot * constants.tangential_to_normal_damping;

    // Normal: 4/3 E* sqrt(R*) δ^1.5 = (2/3) Sn δ.
    let vn = relative_velocity.dot(&normal);
    let fn_elastic = (2.0 / 3.0) * sn * overlap;
    let fn_damping = -normal_dashpot * vn;
    // No attraction: a separating contact with strong damping would otherwise pull.
    let normal_force = (fn_elastic + fn_damping).max(0.0);

    // Tangential spring, kept in the tangent plane.
    let vt = relative_velocity - normal * vn;
    rotate_into_tangent_plane(spring, normal);
    *spring += vt * dt;
    let mut ft = -*spring * st - vt * tangential_dashpot;

    // Coulomb cap (with cohesion too: see `CohesionLaw`). We use the TOTAL normal force (elastic + damping, clamped at 0), not the
    // elastic part alone: friction is bounded by the load the contact actually transmits. With
    // the elastic part only, a contact that is unloading quickly (damping pulling the total
    // towards 0) could carry more friction than normal load, i.e. friction without pressure.
    let cap = constants.static_friction * normal_force;
    let ft_len2 = ft.norm_squared();
    if ft_len2 > cap * cap {
        if ft_len2 > 0.0 {
            ft *= cap / ft_len2.sqrt();
        }
        // Sliding: the spring is reset so that its elastic force alone equals the cap (the
        // damping part is dropped while sliding), which makes stick resume smoothly.
        *spring = if st > 0.0 {
            ft * (-1.0 / st)
        } else {
            Vec3::zeros()
        };
    }
    ContactForce {
        force: normal * normal_force + ft,
        normal_force,
        normal_stiffness: sn,
    }
}

/// A pair's cohesion law as the contact loop uses it, built once from the user's
/// [`Cohesion`] and the pair's E* ([`CohesionLaw::new`]; a zero coefficient is `None`).
///
/// Cohesion is an attractive normal force added to Hertz-Mindlin's. **Which normal force the
/// Coulomb cap and the rolling torque use with cohesion on: the repulsive Hertz part alone**
/// (elastic + damping, clamped at 0: [`ContactForce::normal_force`], the same number as
/// without cohesion), never the net force. Reasons: (1) Coulomb's law bounds friction by the
/// compressive load pressing the surfaces together over the contact area, and cohesion raises
/// that load (the overlap grows until Hertz balances the attraction plus the external load);
/// the net force would make a cohesive contact at rest under no external load frictionless
/// (net 0), so cohesion would weaken a soil's shear resistance instead of adding to it, and a
/// net tension would give a negative cap (LIGGGHTS takes its absolute value, which lets a
/// contact pulled apart hold more friction the harder it is pulled); (2) with cohesion `none`
/// the contact law is then unchanged bit for bit. The damping stays in the clamped part, so
/// the dashpot itself never pulls and the restitution calibration is unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum CohesionLaw {
    None,
    /// F = k π a², a the radius of the circle where the undeformed bodies intersect
    /// (LIGGGHTS 3.8 `cohesion sjkr`: its `Acont`; ≈ 2 π R* δ for small overlaps).
    Linear {
        /// k, J/m³.
        energy_density: f64,
    },
    /// JKR: with a0³ = 2 π γ R*² / E* (the contact radius at zero overlap), x = a / a0 and
    /// δ R* / a0² = x² − √x, the elastic normal force is 2 π γ R* (4/3 x³ − 2 x^1.5): its
    /// minimum, the pull-off force, is −1.5 π γ R* (at x^1.5 = 3/4, a negative overlap), and
    /// particle pairs separate at δ = −0.4725 a0² / R* (x^1.5 = 1/4, necking). Hertz's damping
    /// and tangential stiffness are kept (as EDEM's JKR does).
    Jkr {
        /// γ, J/m².
        surface_energy: f64,
        /// 2 π γ / E*, m: a0³ = this times R*².
        length: f64,
    },
}

/// δ R* / a0² at which a JKR pair separates (x^1.5 = 1/4: −0.75 · 4^(−1/3)).
pub const JKR_SEPARATION: f64 = -0.472_470_393_710_577_4;

impl CohesionLaw {
    pub fn new(cohesion: &Cohesion, e_star: f64) -> CohesionLaw {
        match *cohesion {
            Cohesion::None => CohesionLaw::None,
            Cohesion::Linear { energy_density } if energy_density > 0.0 => {
                CohesionLaw::Linear { energy_density }
            }
            Cohesion::Jkr { surface_energy } if surface_energy > 0.0 => CohesionLaw::Jkr {
                surface_energy,
                length: 2.0 * std::f64::consts::PI * surface_energy / e_star,
            },
            Cohesion::Linear { .. } | Cohesion::Jkr { .. } => CohesionLaw::None,
        }
    }

    /// Whether the pair has cohesion (the contact loop's one test per contact).
    #[inline(always)]
    pub fn is_on(&self) -> bool {
        !matches!(self, CohesionLaw::None)
    }

    /// The attractive normal force (N, > 0 pulls the bodies together) to subtract from
    /// Hertz-Mindlin's at overlap δ > 0. `contact_radius2` gives a², the squared radius of the
    /// circle where the undeformed bodies intersect (called by the linear law only).
    #[inline]
    pub fn attraction(
        &self,
        r_star: f64,
        overlap: f64,
        contact_radius2: impl FnOnce() -> f64,
    ) -> f64 {
        match *self {
            CohesionLaw::None => 0.0,
            CohesionLaw::Linear { energy_density } => {
                energy_density * std::f64::consts::PI * contact_radius2()
            }
            CohesionLaw::Jkr {
                surface_energy,
                length,
            } => {
                let a0 = (length * r_star * r_star).cbrt();
                let d = overlap * r_star / (a0 * a0);
                let s = jkr_root(d);
                let s3 = s * s * s;
                // F_Hertz(δ) − F_JKR(δ), both in units of 2 π γ R*.
                2.0 * std::f64::consts::PI
                    * surface_energy
                    * r_star
                    * (4.0 / 3.0 * (d * d.sqrt() - s3 * s3) + 2.0 * s3)
            }
        }
    }

    /// The JKR force (N, negative: attractive) of a contact at negative overlap δ <= 0 that is
    /// still necking, or `None` once it has separated (or for a law that has no necking).
    #[inline]
    pub fn necking_force(&self, r_star: f64, overlap: f64) -> Option<f64> {
        let CohesionLaw::Jkr {
            surface_energy,
            length,
        } = *self
        else {
            return None;
        };
        let a0 = (length * r_star * r_star).cbrt();
        let d = overlap * r_star / (a0 * a0);
        if d < JKR_SEPARATION {
            return None;
        }
        let s3 = jkr_root(d).powi(3);
        Some(
            2.0 * std::f64::consts::PI * surface_energy * r_star * (4.0 / 3.0 * s3 * s3 - 2.0 * s3),
        )
    }
}

/// s = √(a/a0) on JKR's stable branch for D = δ R*/a0²: the largest root of s⁴ − s = D
/// (D >= [`JKR_SEPARATION`]). Newton from s = 1 + D^¼ (right of the root: s⁴ − s is convex
/// and (1 + t)⁴ − (1 + t) >= t⁴), so it decreases monotonically onto the root.
#[inline]
fn jkr_root(d: f64) -> f64 {
    let mut s = if d > 0.0 { 1.0 + d.sqrt().sqrt() } else { 1.0 };
    for _ in 0..100 {
        let g = s * s * s * s - s - d;
        let slope = 4.0 * s * s * s - 1.0;
        if g <= 0.0 || slope <= 0.0 {
            break;
        }
        let step = g / slope;
        s -= step;
        if step <= 1e-15 * s {
            break;
        }
    }
    s
}

/// a² of the circle where two undeformed spheres (radii `ri`, `rj`, centre distance² `dist2`,
/// overlap δ = ri + rj − dist) intersect: δ (2ri − δ)(2rj − δ)(2(ri + rj) − δ) / (4 dist²),
/// LIGGGHTS' `Acont / π`.
#[inline]
pub fn sphere_sphere_contact_radius2(ri: f64, rj: f64, dist2: f64, overlap: f64) -> f64 {
    overlap * (2.0 * ri - overlap) * (2.0 * rj - overlap) * (2.0 * (ri + rj) - overlap)
        / (4.0 * dist2)
}

/// a² of the circle where a sphere of radius `r` cuts a plane at overlap δ: δ (2r − δ)
/// (LIGGGHTS: r² − d², d the centre's distance to the wall).
#[inline]
pub fn sphere_wall_contact_radius2(r: f64, overlap: f64) -> f64 {
    overlap * (2.0 * r - overlap)
}

/// Project a stored spring onto the tangent plane of `normal` and restore its length, so a
/// contact that rotates carries its spring along without gaining or losing elastic energy.
#[inline(always)]
fn rotate_into_tangent_plane(spring: &mut Vec3, normal: Vec3) {
    let old_len2 = spring.norm_squared();
    let along = normal.dot(spring);
    // The rescale factor is 1/sqrt(1 - along²/old_len2) ≈ 1 + along²/(2 old_len2): when that
    // correction is below double-precision resolution, the projection alone is exact.
    if along * along <= 1e-16 * old_len2 {
        *spring -= normal * along;
        return;
    }
    let projected = *spring - normal * along;
    let new_len2 = projected.norm_squared();
    *spring = if new_len2 > 0.0 {
        projected * (old_len2 / new_len2).sqrt()
    } else {
        Vec3::zeros()
    };
}

/// EPSD rolling torque on particle i (Ai et al. 2011, model C).
///
/// * `rolling_velocity` = ωi - ωj (the other body's angular velocity; 0 for a fixed wall).
///   Only its tangent-plane part rolls; the normal part (twisting) is ignored.
/// * `rolling_stiffness` kr, `max_torque` μr R* Fn, `damping_coefficient` Cr = ηr 2 sqrt(Ir kr).
/// * `spring` is the stored elastic rolling torque, kept in the tangent plane like the
///   tangential spring.
#[inline]
pub fn epsd_rolling_torque(
    normal: Vec3,
    rolling_velocity: Vec3,
    rolling_stiffness: f64,
    max_torque: f64,
    damping_coefficient: f64,
    dt: f64,
    spring: &mut Vec3,
) -> Vec3 {
    let omega_r = rolling_velocity - normal * normal.dot(&rolling_velocity);
    rotate_into_tangent_plane(spring, normal);
    *spring -= omega_r * (rolling_stiffness * dt);
    let len2 = spring.norm_squared();
    if len2 > max_torque * max_torque {
        // Fully mobilised: plastic rolling at constant torque, dashpot off (Ai's f = 0).
        *spring *= max_torque / len2.sqrt();
        *spring
    } else {
        *spring - omega_r * damping_coefficient
    }
}

/// EPSD rolling stiffness kr = 2.25 kn μr² R*² (Ai et al. 2011, after Iwashita & Oda). Ai's
/// kn is a linear spring's stiffness; for Hertz contacts we take the secant stiffness
/// kn = Fn / δ = 4/3 E* √(R* δ), which is 2/3 of the tangent stiffness `normal_stiffness`
/// (2 E* √(R* δ)) that the contact law reports, as LIGGGHTS' `rolling_friction epsd` does
/// (its `cdata.kn`), so that the two codes' EPSD models are the same law.
#[inline]
pub fn epsd_rolling_stiffness(normal_stiffness: f64, rolling_friction: f64, r_star: f64) -> f64 {
    let secant = normal_stiffness * (2.0 / 3.0);
    2.25 * secant * rolling_friction * rolling_friction * r_star * r_star
}
