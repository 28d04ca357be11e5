//! The contact law: Hertz-Mindlin (no slip) with tangential history, and rolling friction.
//!
//! Everything here is a pure function of one contact's kinematics and its history, so the same
//! code serves particle-particle and particle-geometry contacts and can be tested in isolation.
//! Sign convention: `normal` is the unit vector pointing from the other body (particle j, or the
//! geometry surface) towards particle i, and every returned force/torque acts on particle i.

use serde::{Deserialize, Serialize};

use crate::material::PairConstants;
use crate::math::Vec3;

/// 2 sqrt(5/6), the factor of EDEM's Hertz-Mindlin damping terms.
const DAMPING_FACTOR: f64 = 1.825_741_858_350_553_8;

/// How rolling resistance is modelled.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum RollingModel {
    /// EDEM's default "constant directional torque": τi = -μr Fn Ri ω̂i, with ω̂i particle i's own
    /// angular velocity direction and Ri the distance from its centre to the contact point.
    ///
    /// The torque does not vanish as ω → 0, so applied naively it flips ω's sign every step
    /// (chatter). We limit the total rolling torque on a particle so that on its own it can at
    /// most bring ω to zero within one step, never reverse it (|τ| <= I |ω| / Δt).
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
    /// Magnitude of the normal force (elastic + damping, clamped at >= 0), N.
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

    // Coulomb cap. We use the TOTAL normal force (elastic + damping, clamped at 0), not the
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

/// EPSD rolling stiffness kr = 2.25 kn μr² R*² (Ai et al. 2011, after Iwashita & Oda), with kn
/// the Hertz normal tangent stiffness.
#[inline]
pub fn epsd_rolling_stiffness(normal_stiffness: f64, rolling_friction: f64, r_star: f64) -> f64 {
    2.25 * normal_stiffness * rolling_friction * rolling_friction * r_star * r_star
}
