//! Time integration schemes. The update loops themselves are fused into the world's gather
//! pass (one sweep over the particle arrays per step instead of two); this module defines the
//! choice and documents the schemes.

use serde::{Deserialize, Serialize};

/// How positions and velocities are advanced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// First-order symplectic (semi-implicit) Euler, EDEM's default:
    /// F(x_n, v_n); v_{n+1} = v_n + F/m Δt; x_{n+1} = x_n + v_{n+1} Δt. One force evaluation
    /// per step, bounded energy error for conservative forces.
    #[default]
    SymplecticEuler,
    /// Velocity Verlet (kick-drift-kick), second order for position-only forces:
    /// v_{n+1/2} = v_n + F_n/m Δt/2; x_{n+1} = x_n + v_{n+1/2} Δt;
    /// F_{n+1} = F(x_{n+1}, v_{n+1/2}); v_{n+1} = v_{n+1/2} + F_{n+1}/m Δt/2.
    ///
    /// The Hertz elastic force depends on positions only and gets the full second-order
    /// accuracy. Velocity-dependent terms (normal/tangential damping, the tangential spring
    /// increment vt Δt, the CDT torque direction) are evaluated with the half-step velocity
    /// v_{n+1/2} instead of the unknown v_{n+1}: an O(Δt) approximation in those terms only,
    /// which vanishes for undamped, frictionless contacts (the energy-conservation test).
    VelocityVerlet,
}
