//! What the soil experiments (angle of repose, drilling, shear) share: the soil's materials,
//! contacts and settling criteria as their specs give them, with the defaults and checks
//! written once; the recipe of a settled bed ([`BedRecipe`]: the drilling bed, and the shear
//! sample in its box) and the reading of a soil surface ([`height_field`]); the settled bed
//! as data, the store that keeps beds between runs and the one way a run builds or reuses its
//! bed ([`run_on_bed`]).

mod bed;
mod recipe;
mod series;
mod spec;
mod surface;

pub use bed::{
    run_on_bed, BedMismatch, BedStore, NoBedStore, On, OnBed, OnBedError, SettledBed, SettledBy,
    BED_FORMAT,
};
pub(crate) use recipe::{
    advance_to_check, bin_world, is_stable, kinetic_energy_ratio, setup, Setup, SplitMix,
};
pub use recipe::{BedError, BedInfo, BedProgress, BedRecipe, BedSpec, BinSpec, SurfaceReading};
pub use series::running_mean;
pub(crate) use spec::{
    check_contacts, check_rayleigh_fraction, check_stress_list, default_epsd_damping,
    default_rayleigh_fraction, max_radius, non_negative, positive,
};
pub use spec::{
    coarse_grains, paper_soil_soil, paper_soil_steel, MaterialProps, Materials, RollingSpec,
    SettleSpec,
};
pub use surface::{height_field, surface_level, HeightField, MeasureError};
