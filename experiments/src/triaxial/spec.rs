//! The triaxial compression test as serde data ([`TriaxialSpec`]): what a worker receives,
//! what `repose triaxial --spec FILE` reads and what `--set path=value` edits.
//!
//! The contact parameters use the same field names as the other soil tests
//! (`soil_soil.*`, `soil_steel.*`, `materials.*`, `rolling_model`, `particle`), so a
//! calibration's factor paths apply to all of them. The walls are frictionless and without
//! cohesion whatever `soil_steel` says (a membrane and lubricated platens; docs/triaxial.md):
//! `soil_steel` is kept for its restitution and so that a campaign's paths stay valid.
//!
//! # Dotted paths for [`TriaxialSpec::set`](crate::Spec::set)
//!
//! | path | meaning (SI units unless named) | `default` | `fast` | `ci` |
//! |---|---|---|---|---|
//! | `soil_soil.*`, `soil_steel.*`, `materials.*`, `rolling_model`, `epsd_viscous_damping` | as in `AorSpec` | the paper's calibrated point, no cohesion | same | same |
//! | `particle` | engine size distribution (radii, m) | fixed 1 mm radius (the funnel's 2 mm grains) | same | fixed 2 mm radius |
//! | `specimen.width` | side of the square cross-section aimed at, m | 0.024 (12 grains) | 0.016 (8) | 0.024 (6) |
//! | `specimen.height` | height aimed at, m (twice the width, as a lab's specimen) | 0.048 | 0.032 | 0.048 |
//! | `specimen.packing_fraction` | solid fraction assumed to size the grain count | 0.6 | 0.6 | 0.6 |
//! | `preparation.friction` | soil-soil static friction while the specimen is compacted (`null`: the soil's own) | null | null | null |
//! | `preparation.pressure_kpa` | isotropic pressure the specimen is compacted to, kPa | 1.0 | 1.0 | 1.0 |
//! | `preparation.seed` | seed of the specimen (`null`: `seed`) | null | null | null |
//! | `confining_pressures_kpa` | σ3 of each specimen, kPa, one stage each | [2.5, 5, 7.5] | [2.5, 5, 7.5] | [2.5, 7.5] |
//! | `servo.interval` | control and record interval of the walls, s | 5e-4 | 5e-4 | 5e-4 |
//! | `servo.gain` | a wall's strain rate per unit relative stress error, 1/s | 20 | 20 | 20 |
//! | `servo.max_strain_rate` | a servo wall's largest strain rate, 1/s | 1 | 1 | 2 |
//! | `servo.filter_time` | time constant of the low-pass filter on the walls' forces, s | 0.002 | 0.002 | 0.002 |
//! | `consolidation.tolerance` | consolidated when every wall's stress is within this fraction of its target… | 0.03 | 0.03 | 0.05 |
//! | `consolidation.hold_time` | …for this long, s | 0.02 | 0.02 | 0.01 |
//! | `consolidation.time_cap` | gives up consolidating after this long (the stage is loaded anyway, flagged), s | 1.0 | 1.0 | 0.5 |
//! | `loading.strain_rate` | axial strain rate of the platens, 1/s | 0.25 | 0.25 | 0.2 |
//! | `loading.axial_strain` | axial strain at the end of loading | 0.15 | 0.15 | 0.15 |
//! | `time_step_rayleigh_fraction` | Δt as a fraction of the Rayleigh time of the smallest grain | 0.15 | 0.15 | 0.15 |
//! | `wall_time_cap` | wall-clock seconds before giving up (`null`: none) | null | null | null |
//! | `seed` | seed of the specimen (unless `preparation.seed`) | 1 | 1 | 1 |
//!
//! Gravity is off throughout (ρgH of the 48 mm specimen is about 0.6 kPa, a quarter of the
//! lowest confining pressure).

use repose_engine::contact::RollingModel;
use repose_engine::distribution::SizeDistributionSpec;
use repose_engine::material::{Cohesion, Interaction, MaterialSet};
use serde::{Deserialize, Serialize};

use crate::soil::{
    check_contacts, check_rayleigh_fraction, check_stress_list, default_epsd_damping, max_radius,
    non_negative, paper_soil_soil, paper_soil_steel, positive, Materials, RollingSpec,
};
pub use crate::spec_path::SpecError;
use crate::spec_path::{invalid, unknown_preset, Spec};

/// The specimen: a square prism between six walls, `width` × `width` × `height` aimed at.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpecimenSpec {
    /// m
    pub width: f64,
    /// m
    pub height: f64,
    /// Solid volume fraction assumed to size the grain count.
    pub packing_fraction: f64,
}

/// How the specimen is made: a loose random cloud compacted isotropically by the six walls to
/// `pressure_kpa`, with the soil-soil friction `friction` (YADE's REFD method lowers it to
/// reach a denser packing) and no cohesion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PreparationSpec {
    /// Soil-soil static friction while compacting; `None`: the soil's own.
    #[serde(default)]
    pub friction: Option<f64>,
    /// kPa
    pub pressure_kpa: f64,
    /// Seed of the specimen; `None` uses the spec's `seed`.
    #[serde(default)]
    pub seed: Option<u64>,
}

/// How the walls are driven: every `interval` each servo wall's mean force over the interval
/// goes through a first-order low-pass filter (`filter_time`), and the wall moves along its
/// normal at `gain` × the relative stress error × the specimen's size across it, at most
/// `max_strain_rate` × that size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriaxialServoSpec {
    /// s
    pub interval: f64,
    /// 1/s per unit relative stress error.
    pub gain: f64,
    /// 1/s
    pub max_strain_rate: f64,
    /// s
    pub filter_time: f64,
}

/// When the specimen counts as consolidated (and as prepared).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriaxialConsolidationSpec {
    /// Relative error of every wall's stress.
    pub tolerance: f64,
    /// s the stresses must stay within the tolerance.
    pub hold_time: f64,
    /// s; the stage is then loaded anyway and flagged not consolidated.
    pub time_cap: f64,
}

/// The drained axial loading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadingSpec {
    /// 1/s, of the specimen's height at the start of loading (both platens move).
    pub strain_rate: f64,
    /// Axial strain at the end.
    pub axial_strain: f64,
}

/// A complete triaxial compression test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriaxialSpec {
    #[serde(default)]
    pub materials: Materials,
    pub soil_soil: Interaction,
    /// The walls' contact: its restitution only (they are frictionless, without cohesion).
    pub soil_steel: Interaction,
    pub rolling_model: RollingSpec,
    #[serde(default = "default_epsd_damping")]
    pub epsd_viscous_damping: f64,
    /// Grain sizes (engine distribution spec, radii in m).
    pub particle: SizeDistributionSpec,
    pub specimen: SpecimenSpec,
    pub preparation: PreparationSpec,
    /// σ3 of each stage, kPa (each a copy of the one prepared specimen).
    pub confining_pressures_kpa: Vec<f64>,
    pub servo: TriaxialServoSpec,
    pub consolidation: TriaxialConsolidationSpec,
    pub loading: LoadingSpec,
    pub time_step_rayleigh_fraction: f64,
    /// Wall-clock cap for the whole run (specimen included), s; `None`: none.
    #[serde(default)]
    pub wall_time_cap: Option<f64>,
    #[serde(default)]
    pub seed: u64,
}

/// Names of the presets accepted by [`TriaxialSpec::preset`](Spec::preset) (the first is the
/// default).
pub const PRESETS: [&str; 3] = ["default", "fast", "ci"];

impl Default for TriaxialSpec {
    fn default() -> Self {
        TriaxialSpec::paper()
    }
}

impl TriaxialSpec {
    /// The default preset (see the module docs): the funnel's 2 mm grains, 12 across.
    pub fn paper() -> TriaxialSpec {
        TriaxialSpec {
            materials: Materials::default(),
            soil_soil: paper_soil_soil(),
            soil_steel: paper_soil_steel(),
            rolling_model: RollingSpec::Cdt,
            epsd_viscous_damping: default_epsd_damping(),
            particle: SizeDistributionSpec::Fixed { radius: 0.001 },
            specimen: SpecimenSpec {
                width: 0.024,
                height: 0.048,
                packing_fraction: 0.6,
            },
            preparation: PreparationSpec {
                friction: None,
                pressure_kpa: 1.0,
                seed: None,
            },
            confining_pressures_kpa: vec![2.5, 5.0, 7.5],
            servo: TriaxialServoSpec {
                interval: 5e-4,
                gain: 20.0,
                max_strain_rate: 1.0,
                filter_time: 0.002,
            },
            consolidation: TriaxialConsolidationSpec {
                tolerance: 0.03,
                hold_time: 0.02,
                time_cap: 1.0,
            },
            loading: LoadingSpec {
                strain_rate: 0.25,
                axial_strain: 0.15,
            },
            time_step_rayleigh_fraction: 0.15,
            wall_time_cap: None,
            seed: 1,
        }
    }

    /// The smaller preset: the same grains, 8 across.
    pub fn fast() -> TriaxialSpec {
        let mut spec = TriaxialSpec::paper();
        spec.specimen.width = 0.016;
        spec.specimen.height = 0.032;
        spec
    }

    /// The preset for the test suite (seconds): 4 mm grains, 6 across, two pressures.
    pub fn ci() -> TriaxialSpec {
        let mut spec = TriaxialSpec::paper();
        spec.particle = SizeDistributionSpec::Fixed { radius: 0.002 };
        spec.confining_pressures_kpa = vec![2.5, 7.5];
        spec.servo.max_strain_rate = 2.0;
        spec.consolidation = TriaxialConsolidationSpec {
            tolerance: 0.05,
            hold_time: 0.01,
            time_cap: 0.5,
        };
        spec.loading.strain_rate = 0.2;
        spec
    }

    /// The engine material set (soil = material 0, steel = material 1: the walls).
    pub fn material_set(&self) -> MaterialSet {
        self.materials.material_set(self.soil_soil, self.walls())
    }

    /// The walls' contact with the soil: frictionless, without rolling friction or cohesion,
    /// `soil_steel`'s restitution.
    pub fn walls(&self) -> Interaction {
        Interaction {
            restitution: self.soil_steel.restitution,
            static_friction: 0.0,
            rolling_friction: 0.0,
            cohesion: Cohesion::None,
        }
    }

    /// The engine rolling model.
    pub fn engine_rolling_model(&self) -> RollingModel {
        self.rolling_model.engine_model(self.epsd_viscous_damping)
    }

    /// The specimen's seed.
    pub fn specimen_seed(&self) -> u64 {
        self.preparation.seed.unwrap_or(self.seed)
    }
}

impl Spec for TriaxialSpec {
    const NAME: &'static str = "a TriaxialSpec";
    const PRESETS: &'static [&'static str] = &PRESETS;

    /// `default`, `fast` or `ci`.
    fn preset(name: &str) -> Result<TriaxialSpec, SpecError> {
        match name {
            "default" | "paper" => Ok(TriaxialSpec::paper()),
            "fast" => Ok(TriaxialSpec::fast()),
            "ci" => Ok(TriaxialSpec::ci()),
            other => Err(unknown_preset::<Self>(other)),
        }
    }

    /// Checks what the engine does not check itself. The error names the field.
    fn validate(&self) -> Result<(), SpecError> {
        check_contacts(&self.materials, &self.soil_soil, &self.soil_steel)?;
        non_negative("epsd_viscous_damping", self.epsd_viscous_damping)?;
        let r = max_radius(&self.particle);
        if !(r.is_finite() && r > 0.0) {
            return Err(invalid(
                "particle",
                "needs a finite, positive largest radius",
            ));
        }
        let s = &self.specimen;
        positive("specimen.width", s.width)?;
        positive("specimen.height", s.height)?;
        if s.width < 8.0 * r {
            return Err(invalid(
                "specimen.width",
                format!(
                    "must be at least 4 of the largest grains across ({:.4} m), got {}",
                    8.0 * r,
                    s.width
                ),
            ));
        }
        if s.height < s.width {
            return Err(invalid(
                "specimen.height",
                format!(
                    "must be at least specimen.width ({}), got {}",
                    s.width, s.height
                ),
            ));
        }
        let grains = s.width * s.width * s.height / (8.0 * r * r * r);
        if grains > 2.0e6 {
            return Err(invalid(
                "specimen.width",
                format!("makes a specimen of about {grains:.0} grains; at most 2 000 000"),
            ));
        }
        if !(s.packing_fraction > 0.3 && s.packing_fraction < 0.74) {
            return Err(invalid(
                "specimen.packing_fraction",
                format!("must be between 0.3 and 0.74, got {}", s.packing_fraction),
            ));
        }
        if let Some(f) = self.preparation.friction {
            non_negative("preparation.friction", f)?;
        }
        positive("preparation.pressure_kpa", self.preparation.pressure_kpa)?;
        check_stress_list(
            "confining_pressures_kpa",
            &self.confining_pressures_kpa,
            "confining pressures",
        )?;
        for (k, &p) in self.confining_pressures_kpa.iter().enumerate() {
            if p > 1000.0 {
                return Err(invalid(
                    &format!("confining_pressures_kpa[{k}]"),
                    format!("must be at most 1000 kPa, got {p}"),
                ));
            }
        }
        let v = &self.servo;
        positive("servo.interval", v.interval)?;
        positive("servo.gain", v.gain)?;
        positive("servo.max_strain_rate", v.max_strain_rate)?;
        positive("servo.filter_time", v.filter_time)?;
        let c = &self.consolidation;
        if !(c.tolerance > 0.0 && c.tolerance < 1.0) {
            return Err(invalid(
                "consolidation.tolerance",
                format!("must be in (0, 1), got {}", c.tolerance),
            ));
        }
        positive("consolidation.hold_time", c.hold_time)?;
        positive("consolidation.time_cap", c.time_cap)?;
        positive("loading.strain_rate", self.loading.strain_rate)?;
        let e = self.loading.axial_strain;
        if !(e > 0.0 && e <= 0.3) {
            return Err(invalid(
                "loading.axial_strain",
                format!("must be in (0, 0.3], got {e}"),
            ));
        }
        check_rayleigh_fraction(self.time_step_rayleigh_fraction)?;
        if let Some(cap) = self.wall_time_cap {
            positive("wall_time_cap", cap)?;
        }
        Ok(())
    }
}
