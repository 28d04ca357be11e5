//! What the soil experiments (angle of repose, drilling, shear) share: the soil's materials,
//! contacts and settling criteria as their specs give them, with the defaults and checks
//! written once; the settled soil bed as data, the store that keeps
//! beds between runs and the one way a run builds or reuses its bed ([`run_on_bed`]).

mod bed;
mod spec;

pub use bed::{run_on_bed, BedStore, NoBedStore, OnBed, SettledBed, SettledBy, BED_FORMAT};
pub(crate) use spec::{
    check_contacts, check_rayleigh_fraction, default_epsd_damping, default_rayleigh_fraction,
    max_radius, non_negative, positive,
};
pub use spec::{
    coarse_grains, paper_soil_soil, paper_soil_steel, MaterialProps, Materials, RollingSpec,
    SettleSpec,
};
