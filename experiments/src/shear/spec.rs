//! The direct shear test as serde data ([`ShearSpec`]): what a worker receives, what
//! `repose shear --spec FILE` reads and what `--set path=value` edits.
//!
//! The contact parameters use the same field names and structure as
//! [`AorSpec`](crate::aor::AorSpec) and [`DrillSpec`](crate::drill::DrillSpec)
//! (`soil_soil.static_friction`, `soil_soil.cohesion`, `soil_steel.*`, `materials.*`,
//! `rolling_model`, `particle`), so a calibration's factor paths apply to all three.
//!
//! # Dotted paths for [`ShearSpec::set`]
//!
//! | path | meaning (SI units unless named) | `default` | `fast` |
//! |---|---|---|---|
//! | `soil_soil.*`, `soil_steel.*`, `materials.*`, `rolling_model`, `epsd_viscous_damping` | as in `AorSpec` | the paper's calibrated point, no cohesion | same |
//! | `particle` | engine size distribution (radii, m) | uniform 2.7-3.3 mm radius | uniform 2.0-2.4 mm |
//! | `box.side` | inside width of the square steel box (both halves), m | 0.1 | 0.05 |
//! | `box.half_height` | height of the lower half: the shear plane is at z = `half_height`, m | 0.025 | 0.012 |
//! | `box.upper_height` | height of the upper half's walls, m | 0.05 | 0.03 |
//! | `bed.height` | height of the poured sample aimed at (sizes the grain count), m | 0.065 | 0.035 |
//! | `bed.packing_fraction` | solid fraction assumed to size the grain count | 0.52 | 0.52 |
//! | `bed.seed` | seed of the sample (`null`: `seed`); fix it to share one sample across runs | null | null |
//! | `bed.settle.*` | at-rest criteria of the poured sample (as the drilling bed's) | 0.3 / 0.05 / 1e-3 / 3 / 0.1 / 3 | min 0.15, cap 1.5 |
//! | `normal_stresses_kpa` | the normal stresses applied by the lid, kPa, one shear stage each | [5, 10, 15, 20] | [4, 8, 12] |
//! | `servo.interval` | control interval of the lid and record interval, s | 0.001 | 0.001 |
//! | `servo.gain` | the lid's speed per unit relative error of its filtered force, m/s | 0.1 | 0.1 |
//! | `servo.max_speed` | the lid's largest speed, m/s | 0.1 | 0.1 |
//! | `servo.filter_time` | time constant of the low-pass filter on the lid's force, s | 0.005 | 0.005 |
//! | `consolidation.tolerance` | consolidated when the lid's force is within this fraction of its target… | 0.05 | 0.05 |
//! | `consolidation.hold_time` | …for this long, s | 0.05 | 0.03 |
//! | `consolidation.time_cap` | gives up consolidating after this long (the stage is sheared anyway, flagged), s | 1.0 | 0.5 |
//! | `shear.speed` | speed of the upper half (and the lid) along +x, m/s | 0.005 | 0.02 |
//! | `shear.displacement` | shear displacement at the end of a stage, m | 0.01 | 0.006 |
//! | `shear.residual_fraction` | the residual strength is the mean over this last fraction of the displacement | 0.2 | 0.2 |
//! | `window.margin_grains` | the measurement window keeps this many of the largest grains' diameters from every wall of the part of the plane both halves share | 2 | 2 |
//! | `window.thickness_grains` | the window's slab around the shear plane, in the largest grains' diameters | 2 | 2 |
//! | `time_step_rayleigh_fraction` | Δt as a fraction of the Rayleigh time of the smallest grain (0.2, the other tests' value, is unstable under these loads: see below) | 0.08 | 0.08 |
//! | `wall_time_cap` | wall-clock seconds before giving up (`null`: none) | null | null |
//! | `seed` | seed of the sample (unless `bed.seed`) | 1 | 1 |
//!
//! # Presets
//!
//! * [`ShearSpec::paper`] (`default`): a 100 × 100 mm box (a 25 mm lower half, a 50 mm upper
//!   one), a 65 mm poured sample of the drilling test's grains (5.4-6.6 mm diameter, 17 across
//!   the box; about 3 000 grains), sheared 10 mm at 5 mm/s under 5, 10, 15 and 20 kPa.
//! * [`ShearSpec::fast`] (`fast`, for tests): a 50 × 50 mm box (a 12 mm lower half, a 30 mm
//!   upper one), a 35 mm poured sample of 4.0-4.8 mm grains (11 across; about 1 000 grains),
//!   sheared 6 mm at 20 mm/s under 4, 8 and 12 kPa.
//!
//! The time step is smaller than the other experiments' 0.2 Rayleigh times: under a lid at
//! 12 kPa the soft grains (E = 3.67 MPa) overlap by several per cent of their radius and the
//! Hertz contacts stiffen with the overlap. At 0.2 the fast sample kept a kinetic energy ratio
//! near 1 (it boiled, and sheared at τ/σ ≈ 0.2 whatever the friction); at 0.12 and 0.08 the
//! cohesionless sample stayed below 1e-3 and sheared smoothly; with linear cohesion of 3e5
//! J/m³ (larger overlaps still) 0.12 was not enough and 0.06 was (kinetic energy ratio 8e-5).
//! Both presets use 0.08.
//!
//! The sample is poured and settled **without cohesion**; the cohesion law acts from the
//! consolidation on. A cohesive pour stands open (at 3e5 J/m³ the fast sample stood 46 mm high
//! instead of 37 mm), the lid then spends the stage collapsing it, and the strength measured
//! is that of a different fabric for every cohesion. One cohesionless pour gives every cohesion
//! the same starting fabric, as a lab compacts a moist sample to a set density; it also lets a
//! batch varying only the cohesion share one cached sample.
//!
//! Neither is the paper's sand (0.1-0.5 mm grains, which a box of this size would hold by the
//! billion): the grains are the drilling test's, so that the cohesion calibrated here applies to
//! the drilling test's soil.

use repose_engine::contact::RollingModel;
use repose_engine::distribution::SizeDistributionSpec;
use repose_engine::material::{Cohesion, Interaction, MaterialSet};
use serde::{Deserialize, Serialize};

use crate::soil::{
    check_contacts, check_stress_list, coarse_grains, default_epsd_damping,
    default_rayleigh_fraction, max_radius, non_negative, paper_soil_soil, paper_soil_steel,
    positive, BedRecipe, BedSpec, BinSpec, Materials, RollingSpec, SettleSpec, SurfaceReading,
};
pub use crate::spec_path::SpecError;
use crate::spec_path::{invalid, unknown_preset, Spec};

/// The split box: two square steel halves of the same inside width, the lower one closed by a
/// floor at z = 0, the upper one open at both ends and resting on it (no gap). The shear plane
/// is at z = `half_height`, the lower half's height.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Inside width (x and y), m.
    pub side: f64,
    /// Height of the lower half (the shear plane's height above the floor), m.
    pub half_height: f64,
    /// Height of the upper half's walls, m. The sample is poured loose above the plane and the
    /// lid compresses it by a fifth to a quarter (soft grains, 0.52 poured packing), so the
    /// upper half is taller than the lower one: the poured sample must stand high enough that
    /// several grain layers remain above the plane once consolidated.
    pub upper_height: f64,
}

/// The sample: grains poured into the closed box and settled (the drilling test's bed recipe).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SampleSpec {
    /// Height of the settled sample aimed at, m (sizes the grain count).
    pub height: f64,
    /// Solid volume fraction assumed to size the grain count.
    pub packing_fraction: f64,
    /// Seed of the sample; `None` uses the spec's `seed`.
    #[serde(default)]
    pub seed: Option<u64>,
    pub settle: SettleSpec,
}

/// How the lid is driven: every `interval` its mean force over the interval goes through a
/// first-order low-pass filter (`filter_time`), and the lid's vertical speed is set to `gain` ×
/// the filtered force's relative error, at most `max_speed`, downward when the force is too
/// small.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServoSpec {
    /// s
    pub interval: f64,
    /// m/s per unit relative force error.
    pub gain: f64,
    /// m/s
    pub max_speed: f64,
    /// Time constant of the force filter, s (at most `interval`: no filtering).
    pub filter_time: f64,
}

/// When a stage counts as consolidated.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConsolidationSpec {
    /// Relative error of the lid's force.
    pub tolerance: f64,
    /// s the force must stay within the tolerance.
    pub hold_time: f64,
    /// s; the stage is then sheared anyway and flagged not consolidated.
    pub time_cap: f64,
}

/// The shearing.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShearMotionSpec {
    /// m/s, along +x.
    pub speed: f64,
    /// m
    pub displacement: f64,
    /// In (0, 1].
    pub residual_fraction: f64,
}

/// Where the soil's own stresses are measured (`run::Window`): a slab around the shear plane,
/// inset from the box's walls, in diameters of the largest grain.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindowSpec {
    /// Distance kept from every wall of the part of the plane the two halves still share.
    pub margin_grains: f64,
    /// Thickness of the slab, centred on the plane.
    pub thickness_grains: f64,
}

impl Default for WindowSpec {
    fn default() -> Self {
        WindowSpec {
            margin_grains: 2.0,
            thickness_grains: 2.0,
        }
    }
}

/// A complete direct shear experiment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShearSpec {
    #[serde(default)]
    pub materials: Materials,
    pub soil_soil: Interaction,
    /// The box and the lid are steel.
    pub soil_steel: Interaction,
    pub rolling_model: RollingSpec,
    #[serde(default = "default_epsd_damping")]
    pub epsd_viscous_damping: f64,
    /// Grain sizes (engine distribution spec, radii in m).
    pub particle: SizeDistributionSpec,
    #[serde(rename = "box")]
    pub shear_box: BoxSpec,
    pub bed: SampleSpec,
    /// One stage per normal stress, kPa (each from the same settled sample).
    pub normal_stresses_kpa: Vec<f64>,
    pub servo: ServoSpec,
    pub consolidation: ConsolidationSpec,
    pub shear: ShearMotionSpec,
    /// The measurement window inside the sample.
    #[serde(default)]
    pub window: WindowSpec,
    #[serde(default = "default_rayleigh_fraction")]
    pub time_step_rayleigh_fraction: f64,
    /// Wall-clock cap for the whole run (sample included), s; `None`: none.
    #[serde(default)]
    pub wall_time_cap: Option<f64>,
    #[serde(default)]
    pub seed: u64,
}

/// Names of the presets accepted by [`ShearSpec::preset`] (the first is the default).
pub const PRESETS: [&str; 2] = ["default", "fast"];

impl Default for ShearSpec {
    fn default() -> Self {
        ShearSpec::paper()
    }
}

impl ShearSpec {
    /// The default preset (see the module docs).
    pub fn paper() -> ShearSpec {
        ShearSpec {
            materials: Materials::default(),
            soil_soil: paper_soil_soil(),
            soil_steel: paper_soil_steel(),
            rolling_model: RollingSpec::Cdt,
            epsd_viscous_damping: default_epsd_damping(),
            particle: coarse_grains(),
            shear_box: BoxSpec {
                side: 0.1,
                half_height: 0.025,
                upper_height: 0.05,
            },
            bed: SampleSpec {
                height: 0.065,
                packing_fraction: 0.52,
                seed: None,
                settle: SettleSpec::poured_bed(),
            },
            normal_stresses_kpa: vec![5.0, 10.0, 15.0, 20.0],
            servo: ServoSpec {
                interval: 0.001,
                gain: 0.1,
                max_speed: 0.1,
                filter_time: 0.005,
            },
            consolidation: ConsolidationSpec {
                tolerance: 0.05,
                hold_time: 0.05,
                time_cap: 1.0,
            },
            shear: ShearMotionSpec {
                speed: 0.005,
                displacement: 0.01,
                residual_fraction: 0.2,
            },
            window: WindowSpec::default(),
            time_step_rayleigh_fraction: 0.08,
            wall_time_cap: None,
            seed: 1,
        }
    }

    /// The small preset for tests (see the module docs).
    pub fn fast() -> ShearSpec {
        let mut spec = ShearSpec::paper();
        spec.particle = SizeDistributionSpec::Uniform {
            min_radius: 0.002,
            max_radius: 0.0024,
        };
        spec.shear_box = BoxSpec {
            side: 0.05,
            half_height: 0.012,
            upper_height: 0.03,
        };
        spec.bed.height = 0.035;
        spec.bed.settle.min_time = 0.15;
        spec.bed.settle.time_cap = 1.5;
        spec.normal_stresses_kpa = vec![4.0, 8.0, 12.0];
        spec.consolidation.hold_time = 0.03;
        spec.consolidation.time_cap = 0.5;
        spec.shear.speed = 0.02;
        spec.shear.displacement = 0.006;
        spec.time_step_rayleigh_fraction = 0.08;
        spec
    }

    /// The engine material set (soil = material 0, steel = material 1).
    pub fn material_set(&self) -> MaterialSet {
        self.materials.material_set(self.soil_soil, self.soil_steel)
    }

    /// The engine rolling model.
    pub fn engine_rolling_model(&self) -> RollingModel {
        self.rolling_model.engine_model(self.epsd_viscous_damping)
    }

    /// The sample's bed recipe (the drilling bed's, [`BedRecipe`]): the box as the bin (walls
    /// as high as both halves together), the sample height as the bed depth, the contacts
    /// without cohesion, the surface read as any bed's. A cached bed with the same key is the
    /// same sample.
    pub fn bed_recipe(&self) -> BedRecipe {
        // Poured without cohesion (see the module docs).
        let without_cohesion = |pair: Interaction| Interaction {
            cohesion: Cohesion::None,
            ..pair
        };
        BedRecipe {
            materials: self.materials,
            soil_soil: without_cohesion(self.soil_soil),
            soil_steel: without_cohesion(self.soil_steel),
            rolling_model: self.rolling_model,
            epsd_viscous_damping: self.epsd_viscous_damping,
            particle: self.particle.clone(),
            bin: BinSpec {
                size_x: self.shear_box.side,
                size_y: self.shear_box.side,
                height: self.shear_box.half_height + self.shear_box.upper_height,
            },
            bed: BedSpec {
                depth: self.bed.height,
                packing_fraction: self.bed.packing_fraction,
                seed: self.bed.seed,
                settle: self.bed.settle,
            },
            time_step_rayleigh_fraction: self.time_step_rayleigh_fraction,
            wall_time_cap: self.wall_time_cap,
            seed: self.seed,
            surface: SurfaceReading::default(),
        }
    }
}

/// A drilling-bed path as this spec names it (`bin.*` is `box.*`, `bed.depth` is `bed.height`).
fn rename_bed_path(path: &str) -> String {
    match path {
        "bed.depth" => "bed.height".to_owned(),
        "bin.size_x" | "bin.size_y" => "box.side".to_owned(),
        "bin.height" => "box.upper_height".to_owned(),
        other => other.to_owned(),
    }
}

impl Spec for ShearSpec {
    const NAME: &'static str = "a ShearSpec";
    const PRESETS: &'static [&'static str] = &PRESETS;

    /// `default` or `fast`.
    fn preset(name: &str) -> Result<ShearSpec, SpecError> {
        match name {
            "default" | "paper" => Ok(ShearSpec::paper()),
            "fast" => Ok(ShearSpec::fast()),
            other => Err(unknown_preset::<Self>(other)),
        }
    }

    /// Checks what the engine does not check itself. The error names the field.
    fn validate(&self) -> Result<(), SpecError> {
        check_contacts(&self.materials, &self.soil_soil, &self.soil_steel)?;
        positive("box.side", self.shear_box.side)?;
        positive("box.half_height", self.shear_box.half_height)?;
        positive("box.upper_height", self.shear_box.upper_height)?;
        positive("bed.height", self.bed.height)?;
        let r = max_radius(&self.particle);
        if !(r.is_finite() && r > 0.0) {
            return Err(invalid(
                "particle",
                "needs a finite, positive largest radius",
            ));
        }
        let h = self.shear_box.half_height;
        if self.shear_box.side < 10.0 * r {
            return Err(invalid(
                "box.side",
                format!(
                    "must be at least 5 of the largest grains across ({:.4} m), got {}",
                    10.0 * r,
                    self.shear_box.side
                ),
            ));
        }
        if h < 4.0 * r {
            return Err(invalid(
                "box.half_height",
                format!(
                    "must be at least 2 of the largest grains ({:.4} m), got {h}",
                    4.0 * r
                ),
            ));
        }
        let top = h + self.shear_box.upper_height;
        if self.bed.height < h + 4.0 * r || self.bed.height > top - 2.0 * r {
            return Err(invalid(
                "bed.height",
                format!(
                    "must reach at least 2 grains above the shear plane and leave a grain \
                     of room under the upper half's top: between {:.4} and {:.4} m, got {}",
                    h + 4.0 * r,
                    top - 2.0 * r,
                    self.bed.height
                ),
            ));
        }
        check_stress_list(
            "normal_stresses_kpa",
            &self.normal_stresses_kpa,
            "normal stresses",
        )?;
        positive("servo.interval", self.servo.interval)?;
        positive("servo.gain", self.servo.gain)?;
        positive("servo.max_speed", self.servo.max_speed)?;
        positive("servo.filter_time", self.servo.filter_time)?;
        let c = &self.consolidation;
        if !(c.tolerance > 0.0 && c.tolerance < 1.0) {
            return Err(invalid(
                "consolidation.tolerance",
                format!("must be in (0, 1), got {}", c.tolerance),
            ));
        }
        positive("consolidation.hold_time", c.hold_time)?;
        positive("consolidation.time_cap", c.time_cap)?;
        positive("shear.speed", self.shear.speed)?;
        positive("shear.displacement", self.shear.displacement)?;
        if self.shear.displacement > 0.5 * self.shear_box.side {
            return Err(invalid(
                "shear.displacement",
                format!(
                    "must be at most half of box.side ({}), got {}",
                    0.5 * self.shear_box.side,
                    self.shear.displacement
                ),
            ));
        }
        let f = self.shear.residual_fraction;
        if !(f > 0.0 && f <= 1.0) {
            return Err(invalid(
                "shear.residual_fraction",
                format!("must be in (0, 1], got {f}"),
            ));
        }
        let w = &self.window;
        non_negative("window.margin_grains", w.margin_grains)?;
        positive("window.thickness_grains", w.thickness_grains)?;
        let d = 2.0 * r;
        let width = self.shear_box.side - self.shear.displacement - 2.0 * w.margin_grains * d;
        if width < 2.0 * d {
            return Err(invalid(
                "window.margin_grains",
                format!(
                    "leaves a window {width:.4} m wide at the end of the displacement; it needs \
                     at least two of the largest grains ({:.4} m)",
                    2.0 * d
                ),
            ));
        }
        if 0.5 * w.thickness_grains * d > h {
            return Err(invalid(
                "window.thickness_grains",
                format!(
                    "makes a slab reaching below the floor: at most {:.2} with box.half_height {h}",
                    2.0 * h / d
                ),
            ));
        }
        // The remaining sample fields (packing, settle criteria, time step, wall-time cap)
        // are the drilling bed's; its checks name the same paths under `bed.`.
        self.bed_recipe().validate().map_err(|e| match e {
            SpecError::Invalid { path, reason } => invalid(&rename_bed_path(&path), reason),
            other => other,
        })
    }
}
