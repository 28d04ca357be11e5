//! The drilling test's bed: its spec's [`BedRecipe`](crate::soil::BedRecipe), built once per set
//! of bed-determining parameters and returned as plain data ([`SettledBed`]) so a caller can
//! store it and hand it back ([`bed_key`] names it).

use super::run::DrillError;
use super::spec::DrillSpec;
use crate::progress::Control;
use crate::soil::{BedProgress, SettledBed};

/// Cache key of the bed `spec` needs ([`BedRecipe::key`](crate::soil::BedRecipe::key)): the
/// auger, its kinematics and the hole measurement may change freely.
pub fn bed_key(spec: &DrillSpec) -> String {
    spec.bed_recipe().key()
}

/// Builds and settles the bed of `spec`. `progress` may cancel ([`DrillError::Cancelled`]).
pub fn build_bed(
    spec: &DrillSpec,
    progress: &mut dyn FnMut(BedProgress) -> Control,
) -> Result<SettledBed, DrillError> {
    Ok(spec.bed_recipe().build(progress)?)
}
