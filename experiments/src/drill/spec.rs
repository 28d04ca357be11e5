//! The drilling (pore-forming) experiment as serde data ([`DrillSpec`]): what a worker receives,
//! what `repose drill --spec FILE` reads and what `--set path=value` edits.
//!
//! The contact parameters use the same field names and structure as
//! [`AorSpec`](crate::aor::AorSpec) (`soil_soil.static_friction`, `soil_steel.rolling_friction`,
//! `materials.soil.density`, `rolling_model`, `particle`, ...), so a calibration's factor paths
//! apply to both experiments unchanged.
//!
//! # Dotted paths for [`DrillSpec::set`]
//!
//! | path | meaning (SI units) | `default` preset |
//! |---|---|---|
//! | `soil_soil.*`, `soil_steel.*`, `materials.*`, `rolling_model`, `epsd_viscous_damping` | as in `AorSpec` | the paper's calibrated point |
//! | `particle` | engine size distribution (radii, m) | uniform 2.7-3.3 mm radius |
//! | `bin.size_x` / `.size_y` / `.height` | steel soil bin: footprint and wall height | 0.16 / 0.16 / 0.2 |
//! | `bed.depth` | depth of the soil bed aimed at (sizes the grain count), m | 0.14 |
//! | `bed.seed` | seed of the bed (`null`: `seed`); fix it to share one bed across replicates | null |
//! | `bed.packing_fraction` | solid fraction assumed to size the grain count (the settled beds measure about 0.52) | 0.52 |
//! | `bed.settle.*` | at-rest criteria of the bed (`min_time`, `check_interval`, `kinetic_energy_threshold`, `time_cap`, `stable_tolerance_diameters`, `stable_window`) | 0.3 / 0.05 / 1e-3 / 3 / 0.1 / 3 |
//! | `auger.outer_diameter` / `.pitch` / `.shaft_diameter` / `.flight_thickness` / `.tip_length` | auger, m | 0.06 / 0.06 / 0.02 / 0.004 / 0.015 |
//! | `auger.flight_above_surface` | flighted length above the original surface at full depth, m | 0.03 |
//! | `auger_stl.base64` / `.scale` | a drill of any shape: an STL file (base64), tip at the origin, axis +z, used instead of the generated auger; `auger.outer_diameter` must state its diameter | none / 1 |
//! | `auger.segments_per_turn` | facets per turn | 48 |
//! | `drill.rpm` / `.clockwise` | spin, r/min, and its sense seen from above | 400 / true |
//! | `drill.feed_speed` / `.depth` / `.withdraw_speed` | m/s, m (tip below the original surface), m/s | 0.02 / 0.1 / 0.02 |
//! | `drill.start_clearance` | tip height above the surface when the feed starts, m | 0.005 |
//! | `drill.lift_speed` / `.lift_height` | after withdrawal the auger is lifted clear this fast and this far, m/s, m | 0.5 / 0.06 |
//! | `settle.*` | at-rest criteria after the auger is out (same fields) | 0.1 / 0.05 / 1e-3 / 1.0 / 0.1 / 3 |
//! | `time_step_rayleigh_fraction` | Δt as a fraction of the Rayleigh time of the smallest grain | 0.2 |
//! | `wall_time_cap` | wall-clock seconds before giving up (`null`: none) | null |
//! | `seed` | seed of the bed (unless `bed.seed`) and of the auger's starting angle | 1 |
//! | `measure.*` | [`DrillMeasureSettings`] | see there |
//!
//! # Presets
//!
//! * [`DrillSpec::paper`] (`default`): the paper's 60 mm auger at 400 r/min, fed at 20 mm/s and
//!   withdrawn at 20 mm/s, but only 100 mm deep (not 600) in a 160 x 160 mm bin filled 140 mm
//!   deep, with grains of 5.4-6.6 mm diameter (10 across the auger). About 16 000 grains.
//!   The footprint is not converged for this soil model: the hole's walls slump into a crater
//!   that reaches back towards the walls (docs/drill.md shows a wider bin reading wider).
//! * [`DrillSpec::fast`] (`fast`, for tests): a 40 mm auger, 40 mm deep in a 90 x 90 mm bin
//!   65 mm deep, the same grains, spin and feed three times faster (1200 r/min, 60 mm/s: the
//!   same advance per turn). About 2 400 grains. (A time step of 30 % of the Rayleigh time
//!   would be faster, but the bed then never comes to rest: it keeps jittering at a kinetic
//!   energy ratio near 2e-3.)
//! * [`DrillSpec::full_scale`] (`full`): the paper's test unscaled (600 mm deep, 600 x 600 mm
//!   bin, 700 mm bed) at the default grain size: about 1.7 million grains, out of reach on one
//!   machine; kept so the scaled presets can be described as changes from it.

use repose_engine::contact::RollingModel;
use repose_engine::distribution::SizeDistributionSpec;
use repose_engine::material::{Interaction, MaterialSet};
use repose_engine::mesh::TriMesh;
use serde::{Deserialize, Serialize};

use crate::soil::{
    coarse_grains, default_epsd_damping, default_rayleigh_fraction, max_radius, non_negative,
    paper_soil_soil, paper_soil_steel, positive, BedRecipe, BedSpec, BinSpec, Materials,
    RollingSpec, SettleSpec, SurfaceReading,
};
pub use crate::spec_path::SpecError;
use crate::spec_path::{invalid, unknown_preset, Spec};

/// The helical auger (steel), tip down on the z axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AugerGeometry {
    /// Flight outer diameter, m (the paper: 60 mm).
    pub outer_diameter: f64,
    /// Axial advance of the flight per turn, m.
    pub pitch: f64,
    /// m
    pub shaft_diameter: f64,
    /// Axial thickness of the flight, m.
    pub flight_thickness: f64,
    /// Length of the conical tip, m (0: flat-ended).
    pub tip_length: f64,
    /// Flighted length above the original surface when the tip is at full depth, m: the flight
    /// must carry the cuttings out of the hole.
    pub flight_above_surface: f64,
    /// Facets per turn around the axis.
    pub segments_per_turn: usize,
}

/// A drill of any shape from an STL model (binary or ASCII). The model's tip is at its origin
/// and its axis is +z; the run places it above the surface and turns and feeds it like the
/// generated auger. `auger.outer_diameter` must state the drill's diameter: the hole is
/// measured against it (checked against the model within 10 %).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StlDrill {
    /// The STL file's bytes, base64: the spec stays one JSON document that a job server can
    /// send to any worker.
    pub base64: String,
    /// Multiplies the model's coordinates (0.001 for a model in millimetres).
    #[serde(default = "one")]
    pub scale: f64,
}

fn one() -> f64 {
    1.0
}

impl StlDrill {
    /// From the bytes of an STL file.
    pub fn from_bytes(bytes: &[u8], scale: f64) -> StlDrill {
        use base64::prelude::{Engine as _, BASE64_STANDARD};
        StlDrill {
            base64: BASE64_STANDARD.encode(bytes),
            scale,
        }
    }

    /// The model as a mesh, in metres; the error says what is wrong with it.
    pub fn mesh(&self) -> Result<TriMesh, String> {
        use base64::prelude::{Engine as _, BASE64_STANDARD};
        let bytes = BASE64_STANDARD
            .decode(self.base64.trim())
            .map_err(|e| format!("not base64: {e}"))?;
        TriMesh::from_stl_bytes_named(&bytes, self.scale, "auger_stl").map_err(|e| e.to_string())
    }
}

/// Kinematics of the test.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DrillMotionSpec {
    /// Revolutions per minute (> 0).
    pub rpm: f64,
    /// Clockwise seen from above (the usual sense, which lifts soil on a right-handed flight).
    pub clockwise: bool,
    /// Downward feed speed, m/s.
    pub feed_speed: f64,
    /// Depth of the tip below the original surface at the end of the feed, m.
    pub depth: f64,
    /// Upward speed while withdrawing (still turning), m/s.
    pub withdraw_speed: f64,
    /// Height of the tip above the surface when the feed starts, m.
    pub start_clearance: f64,
    /// After withdrawal (back to the start height) the auger stops turning and is lifted by
    /// `lift_height` at `lift_speed` so that nothing rests on it while the soil settles.
    pub lift_speed: f64,
    /// m
    pub lift_height: f64,
}

/// How the hole is measured (see the `measure` module).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DrillMeasureSettings {
    /// Side of the height-field cells, as a fraction of the mean grain radius.
    pub cell_fraction: f64,
    /// Radius of the probe sphere dropped on the grains to read the surface, as a fraction of
    /// the mean grain radius (it bridges the gaps between surface grains).
    pub probe_fraction: f64,
    /// A height-field cell is part of the opening if its surface lies more than this many mean
    /// grain diameters below the original surface level.
    pub open_depth_diameters: f64,
    /// Cells within this many grain diameters of a wall are left out of the original surface
    /// level (the walls disturb the packing).
    pub wall_margin_diameters: f64,
    /// Time between points of the reported torque/force series (averages over the interval), s.
    pub series_interval: f64,
}

impl Default for DrillMeasureSettings {
    /// The bed's surface is read as any bed's ([`SurfaceReading::default`]).
    fn default() -> Self {
        let surface = SurfaceReading::default();
        DrillMeasureSettings {
            cell_fraction: surface.cell_fraction,
            probe_fraction: surface.probe_fraction,
            open_depth_diameters: 1.0,
            wall_margin_diameters: surface.wall_margin_diameters,
            series_interval: 0.05,
        }
    }
}

/// A complete drilling experiment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DrillSpec {
    #[serde(default)]
    pub materials: Materials,
    /// N1-N3.
    pub soil_soil: Interaction,
    /// N4-N6 (bin and auger are steel).
    pub soil_steel: Interaction,
    pub rolling_model: RollingSpec,
    #[serde(default = "default_epsd_damping")]
    pub epsd_viscous_damping: f64,
    /// Grain sizes (engine distribution spec, radii in m).
    pub particle: SizeDistributionSpec,
    pub bin: BinSpec,
    pub bed: BedSpec,
    pub auger: AugerGeometry,
    /// A drill of any shape from STL, used instead of the generated auger (`auger.*` other
    /// than `outer_diameter` is then unused).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub auger_stl: Option<StlDrill>,
    pub drill: DrillMotionSpec,
    /// At rest after the auger is out.
    pub settle: SettleSpec,
    /// Δt = this × Rayleigh time of the smallest grain (EDEM's rule; the paper used 20 %).
    #[serde(default = "default_rayleigh_fraction")]
    pub time_step_rayleigh_fraction: f64,
    /// Wall-clock cap for the whole run (bed included), s; `None`: none.
    #[serde(default)]
    pub wall_time_cap: Option<f64>,
    /// Seed of the bed (unless `bed.seed` is set) and of the auger's starting angle.
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub measure: DrillMeasureSettings,
}

/// Names of the presets accepted by [`DrillSpec::preset`] (the first is the default).
pub const PRESETS: [&str; 3] = ["default", "fast", "full"];

impl Default for DrillSpec {
    fn default() -> Self {
        DrillSpec::paper()
    }
}

impl DrillSpec {
    /// The paper's test unscaled: 600 x 600 mm bin (750 mm walls), 700 mm bed, 60 mm auger to
    /// 600 mm at 400 r/min and 20 mm/s. Grains as in the default preset (about 1.7 million).
    pub fn full_scale() -> DrillSpec {
        DrillSpec {
            materials: Materials::default(),
            soil_soil: paper_soil_soil(),
            soil_steel: paper_soil_steel(),
            rolling_model: RollingSpec::Cdt,
            epsd_viscous_damping: default_epsd_damping(),
            particle: coarse_grains(),
            bin: BinSpec {
                size_x: 0.6,
                size_y: 0.6,
                height: 0.75,
            },
            bed: BedSpec {
                depth: 0.7,
                packing_fraction: 0.52,
                seed: None,
                settle: SettleSpec::poured_bed(),
            },
            auger: AugerGeometry {
                outer_diameter: 0.06,
                pitch: 0.06,
                shaft_diameter: 0.02,
                flight_thickness: 0.004,
                tip_length: 0.015,
                flight_above_surface: 0.03,
                segments_per_turn: 48,
            },
            auger_stl: None,
            drill: DrillMotionSpec {
                rpm: 400.0,
                clockwise: true,
                feed_speed: 0.02,
                depth: 0.6,
                withdraw_speed: 0.02,
                start_clearance: 0.005,
                lift_speed: 0.5,
                lift_height: 0.06,
            },
            settle: SettleSpec {
                min_time: 0.1,
                time_cap: 1.0,
                ..SettleSpec::poured_bed()
            },
            time_step_rayleigh_fraction: default_rayleigh_fraction(),
            wall_time_cap: None,
            seed: 1,
            measure: DrillMeasureSettings::default(),
        }
    }

    /// The default resolution: the paper's auger and kinematics and calibrated contact
    /// parameters, 100 mm deep in a 160 x 160 mm bin with a 140 mm bed of 5.4-6.6 mm grains.
    pub fn paper() -> DrillSpec {
        let mut spec = DrillSpec::full_scale();
        spec.bin = BinSpec {
            size_x: 0.16,
            size_y: 0.16,
            height: 0.2,
        };
        spec.bed.depth = 0.14;
        spec.drill.depth = 0.1;
        spec
    }

    /// A small run for tests: 40 mm auger (pitch 40 mm), 40 mm deep, 90 x 90 mm bin, 65 mm
    /// bed, 1200 r/min and 60 mm/s feed (the default's 3 mm per turn), withdrawn at 120 mm/s.
    pub fn fast() -> DrillSpec {
        let mut spec = DrillSpec::paper();
        spec.bin = BinSpec {
            size_x: 0.09,
            size_y: 0.09,
            height: 0.12,
        };
        spec.bed.depth = 0.065;
        spec.bed.settle.min_time = 0.2;
        spec.auger.outer_diameter = 0.04;
        spec.auger.pitch = 0.04;
        spec.auger.shaft_diameter = 0.014;
        spec.auger.tip_length = 0.01;
        spec.auger.flight_above_surface = 0.02;
        spec.auger.segments_per_turn = 32;
        spec.drill.depth = 0.04;
        spec.drill.rpm = 1200.0;
        spec.drill.feed_speed = 0.06;
        spec.drill.withdraw_speed = 0.12;
        spec.drill.lift_height = 0.04;
        spec.settle.time_cap = 0.5;
        spec.measure.series_interval = 0.02;
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

    /// The bed's seed.
    pub fn bed_seed(&self) -> u64 {
        self.bed.seed.unwrap_or(self.seed)
    }

    /// The recipe of the bed this spec drills (its soil, bin, bed, time step and surface
    /// reading).
    pub fn bed_recipe(&self) -> BedRecipe {
        BedRecipe {
            materials: self.materials,
            soil_soil: self.soil_soil,
            soil_steel: self.soil_steel,
            rolling_model: self.rolling_model,
            epsd_viscous_damping: self.epsd_viscous_damping,
            particle: self.particle.clone(),
            bin: self.bin,
            bed: self.bed,
            time_step_rayleigh_fraction: self.time_step_rayleigh_fraction,
            wall_time_cap: self.wall_time_cap,
            seed: self.seed,
            surface: SurfaceReading {
                cell_fraction: self.measure.cell_fraction,
                probe_fraction: self.measure.probe_fraction,
                wall_margin_diameters: self.measure.wall_margin_diameters,
            },
        }
    }

    /// Checks the fields that make the bed ([`super::bed_key`]'s inputs, the wall-time cap):
    /// all [`super::build_bed`] needs ([`BedRecipe::validate`]).
    pub fn validate_bed(&self) -> Result<(), SpecError> {
        self.bed_recipe().validate()
    }

    /// The auger, its kinematics, the settling after drilling and the hole measurement.
    fn validate_drilling(&self) -> Result<(), SpecError> {
        self.settle.check("settle")?;
        let a = &self.auger;
        positive("auger.outer_diameter", a.outer_diameter)?;
        if let Some(stl) = &self.auger_stl {
            positive("auger_stl.scale", stl.scale)?;
            let mesh = stl.mesh().map_err(|e| invalid("auger_stl", e))?;
            let reach = mesh
                .vertices()
                .iter()
                .map(|v| v.x.hypot(v.y))
                .fold(0.0, f64::max);
            if (2.0 * reach - a.outer_diameter).abs() > 0.1 * a.outer_diameter {
                return Err(invalid(
                    "auger.outer_diameter",
                    format!(
                        "the STL drill is {:.1} mm across (auger_stl, scale {}), but \
                         auger.outer_diameter says {:.1} mm; the hole is measured against it",
                        2e3 * reach,
                        stl.scale,
                        1e3 * a.outer_diameter
                    ),
                ));
            }
            let (low, _) = mesh.aabb();
            if low.z.abs() > 0.05 * a.outer_diameter {
                return Err(invalid(
                    "auger_stl",
                    format!(
                        "the model's lowest point is at z = {:.1} mm: put the drill's tip at \
                         the origin, axis +z",
                        1e3 * low.z
                    ),
                ));
            }
        }
        positive("auger.pitch", a.pitch)?;
        positive("auger.shaft_diameter", a.shaft_diameter)?;
        positive("auger.flight_thickness", a.flight_thickness)?;
        non_negative("auger.tip_length", a.tip_length)?;
        non_negative("auger.flight_above_surface", a.flight_above_surface)?;
        if a.shaft_diameter >= a.outer_diameter {
            return Err(invalid(
                "auger.shaft_diameter",
                format!(
                    "must be less than auger.outer_diameter = {}",
                    a.outer_diameter
                ),
            ));
        }
        if a.flight_thickness >= a.pitch {
            return Err(invalid(
                "auger.flight_thickness",
                format!("must be less than auger.pitch = {}", a.pitch),
            ));
        }
        if a.segments_per_turn < 12 {
            return Err(invalid("auger.segments_per_turn", "must be at least 12"));
        }
        let d = &self.drill;
        positive("drill.rpm", d.rpm)?;
        positive("drill.feed_speed", d.feed_speed)?;
        positive("drill.depth", d.depth)?;
        positive("drill.withdraw_speed", d.withdraw_speed)?;
        non_negative("drill.start_clearance", d.start_clearance)?;
        positive("drill.lift_speed", d.lift_speed)?;
        positive("drill.lift_height", d.lift_height)?;
        if a.tip_length >= d.depth {
            return Err(invalid(
                "auger.tip_length",
                format!("must be less than drill.depth = {}", d.depth),
            ));
        }
        let min_side = self.bin.size_x.min(self.bin.size_y);
        if a.outer_diameter >= min_side {
            return Err(invalid(
                "auger.outer_diameter",
                format!("must be less than the bin's smaller side ({min_side})"),
            ));
        }
        let max_radius = max_radius(&self.particle);
        if max_radius.is_finite() && max_radius > 0.0 {
            // The tip must stay a few grains above the floor.
            if d.depth + 4.0 * max_radius > self.bed.depth {
                return Err(invalid(
                    "drill.depth",
                    format!(
                        "must leave at least two grain diameters of soil under the tip: \
                         drill.depth + 4 x max radius = {:.4} m exceeds bed.depth = {} m",
                        d.depth + 4.0 * max_radius,
                        self.bed.depth
                    ),
                ));
            }
        }
        let m = &self.measure;
        positive("measure.open_depth_diameters", m.open_depth_diameters)?;
        positive("measure.series_interval", m.series_interval)?;
        Ok(())
    }
}

impl Spec for DrillSpec {
    const NAME: &'static str = "a DrillSpec";
    const PRESETS: &'static [&'static str] = &PRESETS;

    /// `default`, `fast` or `full`.
    fn preset(name: &str) -> Result<DrillSpec, SpecError> {
        match name {
            "default" | "paper" => Ok(DrillSpec::paper()),
            "fast" => Ok(DrillSpec::fast()),
            "full" => Ok(DrillSpec::full_scale()),
            other => Err(unknown_preset::<Self>(other)),
        }
    }

    /// Checks what the engine does not check itself (materials, size distribution and mesh are
    /// checked when the world is built). The error names the field.
    fn validate(&self) -> Result<(), SpecError> {
        self.validate_bed()?;
        self.validate_drilling()
    }
}
