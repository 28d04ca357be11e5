//! Angle of repose of a granular heap: measurement from final particle positions
//! ([`measure_angle_of_repose`]) and its side-view picture ([`side_view_svg`]).
//!
//! The input is plain slices (centres in metres with z up, radii in metres) so that this module
//! does not depend on the engine's particle types.

mod measure;
mod picture;

pub use measure::{
    measure_angle_of_repose, AngleOfRepose, DirectionProfile, FlankFit, MeasureError,
    MeasureSettings, ProjectionPlane, SideProjection,
};
pub use picture::{side_view_svg, PictureOptions};
