//! The soil as every experiment's spec gives it, under the same field names in each (so a
//! calibration's factor paths apply to all three): the bulk properties of soil and steel
//! ([`Materials`]), the rolling model ([`RollingSpec`]), the paper's calibrated contact pairs
//! ([`paper_soil_soil`], [`paper_soil_steel`]), the grains of the drilling and shear tests
//! ([`coarse_grains`]), when a bed is at rest ([`SettleSpec`]), the defaults the specs share
//! and the checks that name a bad field.

use repose_engine::contact::RollingModel;
use repose_engine::distribution::SizeDistributionSpec;
use repose_engine::material::{Cohesion, Interaction, Material, MaterialSet};
use serde::{Deserialize, Serialize};

use crate::spec_path::{invalid, SpecError};

/// Rolling-resistance model (see [`repose_engine::contact::RollingModel`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RollingSpec {
    /// EDEM's default constant directional torque, lever arm = particle radius.
    Cdt,
    /// Elastic-plastic spring-dashpot (Ai et al. 2011), with `epsd_viscous_damping`.
    Epsd,
}

/// Bulk properties of one material (Table 1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialProps {
    /// kg/m³
    pub density: f64,
    /// Young's modulus, Pa.
    pub youngs_modulus: f64,
    /// Poisson's ratio.
    pub poisson: f64,
}

/// The two materials of the test.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Materials {
    pub soil: MaterialProps,
    pub steel: MaterialProps,
}

impl Default for Materials {
    fn default() -> Self {
        let props = |m: Material| MaterialProps {
            density: m.density,
            youngs_modulus: m.youngs_modulus,
            poisson: m.poisson,
        };
        Materials {
            soil: props(Material::paper_soil()),
            steel: props(Material::paper_steel()),
        }
    }
}

impl Materials {
    /// The engine material set (soil = material 0, steel = material 1) with these bulk
    /// properties and the given contact pairs.
    pub fn material_set(&self, soil_soil: Interaction, soil_steel: Interaction) -> MaterialSet {
        let mut set = MaterialSet::paper(soil_soil, soil_steel);
        for (m, props) in set.materials.iter_mut().zip([self.soil, self.steel]) {
            m.density = props.density;
            m.youngs_modulus = props.youngs_modulus;
            m.poisson = props.poisson;
        }
        set
    }
}

impl RollingSpec {
    /// The engine's rolling model (`epsd_viscous_damping` is used by EPSD only).
    pub fn engine_model(self, epsd_viscous_damping: f64) -> RollingModel {
        match self {
            RollingSpec::Cdt => RollingModel::ConstantDirectionalTorque,
            RollingSpec::Epsd => RollingModel::ElasticPlasticSpringDashpot {
                viscous_damping: epsd_viscous_damping,
            },
        }
    }
}

/// Checks the contact coefficients and bulk properties every soil experiment shares (the
/// engine would reject them later, without naming the spec field): restitution in (0, 1],
/// frictions and cohesion finite and >= 0, density and Young's modulus > 0, Poisson's ratio in
/// (-1, 0.5). The error names the field.
pub(crate) fn check_contacts(
    materials: &Materials,
    soil_soil: &Interaction,
    soil_steel: &Interaction,
) -> Result<(), SpecError> {
    for (name, pair) in [("soil_soil", soil_soil), ("soil_steel", soil_steel)] {
        let e = pair.restitution;
        if !(e > 0.0 && e <= 1.0) {
            return Err(invalid(
                &format!("{name}.restitution"),
                format!("must be in (0, 1], got {e}"),
            ));
        }
        for (field, v) in [
            ("static_friction", pair.static_friction),
            ("rolling_friction", pair.rolling_friction),
        ] {
            non_negative(&format!("{name}.{field}"), v)?;
        }
        let cohesion = match pair.cohesion {
            Cohesion::None => None,
            Cohesion::Linear { energy_density } => Some(("energy_density", energy_density)),
            Cohesion::Jkr { surface_energy } => Some(("surface_energy", surface_energy)),
        };
        if let Some((field, v)) = cohesion {
            non_negative(&format!("{name}.cohesion.{field}"), v)?;
        }
    }
    for (name, m) in [("soil", &materials.soil), ("steel", &materials.steel)] {
        for (field, v) in [("density", m.density), ("youngs_modulus", m.youngs_modulus)] {
            positive(&format!("materials.{name}.{field}"), v)?;
        }
        if !(m.poisson > -1.0 && m.poisson < 0.5) {
            return Err(invalid(
                &format!("materials.{name}.poisson"),
                format!("must be in (-1, 0.5), got {}", m.poisson),
            ));
        }
    }
    Ok(())
}

/// `v` must be finite and > 0; the error names `path`.
pub(crate) fn positive(path: &str, v: f64) -> Result<(), SpecError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(path, format!("must be finite and > 0, got {v}")))
    }
}

/// `v` must be finite and >= 0; the error names `path`.
pub(crate) fn non_negative(path: &str, v: f64) -> Result<(), SpecError> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(invalid(path, format!("must be finite and >= 0, got {v}")))
    }
}

/// The time step's fraction of the Rayleigh time must be in (0, 1].
/// Checks a strength test's stresses at `path` (kPa; `what` names them in messages, e.g.
/// "normal stresses"): at least two, each positive, at least two different, as a Mohr-Coulomb
/// fit needs.
pub(crate) fn check_stress_list(path: &str, values: &[f64], what: &str) -> Result<(), SpecError> {
    if values.len() < 2 {
        return Err(invalid(
            path,
            format!(
                "needs at least two {what} for the Mohr-Coulomb fit, got {}",
                values.len()
            ),
        ));
    }
    for (k, &v) in values.iter().enumerate() {
        positive(&format!("{path}[{k}]"), v)?;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted.dedup();
    if sorted.len() < 2 {
        return Err(invalid(
            path,
            format!("needs at least two different {what}"),
        ));
    }
    Ok(())
}

pub(crate) fn check_rayleigh_fraction(f: f64) -> Result<(), SpecError> {
    if f > 0.0 && f <= 1.0 {
        Ok(())
    } else {
        Err(invalid(
            "time_step_rayleigh_fraction",
            format!("must be in (0, 1], got {f}"),
        ))
    }
}

/// The EPSD rolling dashpot's damping when a spec does not give it (`epsd_viscous_damping`).
pub(crate) fn default_epsd_damping() -> f64 {
    0.3
}

/// Δt as a fraction of the Rayleigh time of the smallest grain when a spec does not give it
/// (`time_step_rayleigh_fraction`; EDEM's rule, the paper used 20 %).
pub(crate) fn default_rayleigh_fraction() -> f64 {
    0.2
}

/// The paper's calibrated soil-soil contact (N1-N3: restitution 0.45, static friction 0.442,
/// rolling friction 0.140), without cohesion.
pub fn paper_soil_soil() -> Interaction {
    Interaction {
        restitution: 0.45,
        static_friction: 0.442,
        rolling_friction: 0.140,
        cohesion: Cohesion::None,
    }
}

/// The paper's calibrated soil-steel contact (N4-N6: restitution 0.40, static friction 0.305,
/// rolling friction 0.50), without cohesion.
pub fn paper_soil_steel() -> Interaction {
    Interaction {
        restitution: 0.40,
        static_friction: 0.305,
        rolling_friction: 0.50,
        cohesion: Cohesion::None,
    }
}

/// The grains of the drilling and shear tests' default presets: radii uniform in 2.7-3.3 mm
/// (5.4-6.6 mm diameter).
pub fn coarse_grains() -> SizeDistributionSpec {
    SizeDistributionSpec::Uniform {
        min_radius: 0.0027,
        max_radius: 0.0033,
    }
}

/// When a phase counts as "at rest": checks every `check_interval` after `min_time`; either
/// criterion ends the phase, `time_cap` (simulated seconds in the phase) gives up:
///
/// * kinetic energy: the mean kinetic energy per grain is below `kinetic_energy_threshold ×
///   m g d` (m, d: mean grain mass and diameter);
/// * stable shape: over the last `stable_window` checks the measured shape moved by at most
///   `stable_tolerance_diameters` grain diameters (the bed: its surface level; after drilling:
///   the hole's effective depth and opening diameter). Constant-torque rolling friction keeps a
///   deep bed of these soft grains jittering at a kinetic energy ratio of about 1e-3 although
///   nothing moves any more at the scale of a grain.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SettleSpec {
    /// s
    pub min_time: f64,
    /// s
    pub check_interval: f64,
    /// Dimensionless, relative to m g d (m, d: mean grain mass and diameter).
    pub kinetic_energy_threshold: f64,
    /// s
    pub time_cap: f64,
    /// Grain diameters.
    #[serde(default = "default_stable_tolerance")]
    pub stable_tolerance_diameters: f64,
    /// Consecutive checks (at least 2).
    #[serde(default = "default_stable_window")]
    pub stable_window: usize,
}

fn default_stable_tolerance() -> f64 {
    0.1
}
fn default_stable_window() -> usize {
    3
}

impl SettleSpec {
    /// The criteria of a poured bed at rest (the drilling bed's and the shear sample's
    /// default): checks every 0.05 s after 0.3 s, kinetic energy below 1e-3 m g d or the
    /// surface stable within 0.1 grain diameters over 3 checks, at most 3 s.
    pub fn poured_bed() -> SettleSpec {
        SettleSpec {
            min_time: 0.3,
            check_interval: 0.05,
            kinetic_energy_threshold: 1e-3,
            time_cap: 3.0,
            stable_tolerance_diameters: default_stable_tolerance(),
            stable_window: default_stable_window(),
        }
    }

    /// Checks the criteria; the errors name the fields under `prefix` (`bed.settle`).
    pub(crate) fn check(&self, prefix: &str) -> Result<(), SpecError> {
        non_negative(&format!("{prefix}.min_time"), self.min_time)?;
        positive(&format!("{prefix}.check_interval"), self.check_interval)?;
        positive(
            &format!("{prefix}.kinetic_energy_threshold"),
            self.kinetic_energy_threshold,
        )?;
        positive(&format!("{prefix}.time_cap"), self.time_cap)?;
        non_negative(
            &format!("{prefix}.stable_tolerance_diameters"),
            self.stable_tolerance_diameters,
        )?;
        if self.stable_window < 2 {
            return Err(invalid(
                &format!("{prefix}.stable_window"),
                "must be at least 2",
            ));
        }
        Ok(())
    }
}

/// The largest grain radius a size distribution can give, m.
pub(crate) fn max_radius(particle: &SizeDistributionSpec) -> f64 {
    match particle {
        SizeDistributionSpec::Fixed { radius } => *radius,
        SizeDistributionSpec::Uniform { max_radius, .. }
        | SizeDistributionSpec::Normal { max_radius, .. } => *max_radius,
        SizeDistributionSpec::SieveTable { rows } => {
            0.5 * rows.iter().map(|r| r.size).fold(0.0, f64::max)
        }
    }
}
