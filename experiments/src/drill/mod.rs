//! The drilling (pore-forming) test of Zhang et al.: a helical steel auger turning at 400 r/min
//! is fed into a settled soil bed at 20 mm/s, withdrawn, and the hole it leaves is measured
//! (opening diameter at the original surface level, effective depth along the axis, backfill),
//! with the torque and axial force on the auger over time.
//!
//! * [`DrillSpec`]: the experiment as serde data, presets, dotted-path `set`, `validate`.
//! * [`build_bed`] / [`bed_key`] / [`SettledBed`]: the settled bed as data, and the key under
//!   which a caller may cache it; [`run_drill_on_bed`] drills a cached bed, [`run_drill`] builds
//!   the bed and drills it (the same outcome bit for bit).
//! * [`DrillResult`] (serde; [`DrillResult::metrics`] for a job server) and the pictures
//!   [`DrillRun::section_svg`] / [`DrillRun::forces_svg`].
//!
//! No file I/O here: the bed and the pictures are returned as data and text.

mod bed;
mod experiment;
mod measure;
mod picture;
mod run;
mod spec;

pub use crate::progress::Control;
pub use crate::soil::{
    height_field, surface_level, BedInfo, BedProgress, BedSpec, BinSpec, HeightField, MeasureError,
    SettleSpec, SettledBed, SettledBy, BED_FORMAT,
};
pub use bed::{bed_key, build_bed};
pub use experiment::Drill;
pub use measure::{measure_hole, solid_volume_in_cylinder, HoleMeasurement};
pub use picture::{forces_svg, section_svg};
pub use run::{
    run_drill, run_drill_on_bed, DrillError, DrillOn, DrillResult, DrillRun, DrillStatus,
    LoadSample, Progress,
};
pub use spec::{
    AugerGeometry, DrillMeasureSettings, DrillMotionSpec, DrillSpec, SpecError, StlDrill, PRESETS,
};
