//! What the soil experiments share: the settled soil bed as data, the store that keeps beds
//! between runs and the one way a run builds or reuses its bed ([`bed`]).

mod bed;

pub use bed::{run_on_bed, BedStore, NoBedStore, OnBed, SettledBed, SettledBy, BED_FORMAT};
