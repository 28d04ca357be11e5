//! Angle of repose of a granular heap: the virtual experiment ([`AorSpec`], [`run_aor`]: funnel
//! or lifted-cylinder test on the DEM engine; [`run_aor_on`]: on another engine backend, e.g.
//! the funnel on the GPU), the measurement from final particle positions
//! ([`measure_angle_of_repose`]) and its side-view picture ([`side_view_svg`]).
//!
//! The input is plain slices (centres in metres with z up, radii in metres) so that this module
//! does not depend on the engine's particle types.
//!
//! ```
//! use repose_experiments::aor::{measure_angle_of_repose, side_view_svg, MeasureSettings, PictureOptions};
//!
//! // A 35° cone of 1 mm spheres standing on z = 0: stacked columns on a 2 mm square grid, each
//! // column lifted by a different fraction of a grain so that the surface is not terraced.
//! let (radius, base_radius) = (1e-3, 0.03);
//! let (tan, cos) = (35f64.to_radians().tan(), 35f64.to_radians().cos());
//! let mut positions = Vec::new();
//! for i in -16i32..=16 {
//!     for j in -16i32..=16 {
//!         let lift = f64::from((i * 7 + j * 13).rem_euclid(5)) * 0.4e-3;
//!         for k in 0..16 {
//!             let p = [f64::from(i) * 2e-3, f64::from(j) * 2e-3, radius + lift + f64::from(k) * 2e-3];
//!             let surface = (base_radius - p[0].hypot(p[1])) * tan;
//!             if p[2] <= surface - radius / cos {
//!                 positions.push(p);
//!             }
//!         }
//!     }
//! }
//! let radii = vec![radius; positions.len()];
//!
//! let result = measure_angle_of_repose(&positions, &radii, &MeasureSettings::default())?;
//! assert!((result.angle_deg - 35.0).abs() < 1.5);
//! assert!((result.projection_mean_deg - 35.0).abs() < 2.0);
//! let svg: String = side_view_svg(&result, &positions, &radii, &PictureOptions::default());
//! assert!(svg.starts_with("<?xml"));
//! # Ok::<(), repose_experiments::aor::MeasureError>(())
//! ```

mod checkpoint;
mod experiment;
mod ladder;
mod measure;
mod picture;
mod rest;
mod run;
mod spec;

pub use crate::soil::{MaterialProps, Materials, RollingSpec};
pub use checkpoint::{checkpoint_key, AorCheckpoint, CheckpointError};
pub use experiment::Aor;
pub use ladder::{ladder_svg, LadderPoint};
pub use measure::{
    measure_angle_of_repose, AngleOfRepose, DirectionProfile, FlankFit, MeasureError,
    MeasureSettings, ProjectionPlane, SideProjection,
};
pub use picture::{side_view_svg, PictureOptions};
pub use rest::{rest_decision, rest_state, NotYet, RestDecision, RestState};
pub use run::{
    measure_heap, rig_meshes, run_aor, run_aor_on, run_aor_with_checkpoints, Amount, AorError,
    AorResult, AorRun, Checkpoints, Control, EndedBy, GrainBudget, Progress, RunStatus,
    SaveCheckpoint, SettleCheck,
};
pub use spec::{
    sieve_curve_with_mean_diameter, AorSpec, BaseSpec, CylinderGeometry, FunnelGeometry, Protocol,
    SettleSpec, SpecError, MASS_LADDER, PAPER_SAND_SIEVE_CURVE, PRESETS, SIZE_LADDER,
};
