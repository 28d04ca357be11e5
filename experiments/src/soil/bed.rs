//! The settled soil bed: the grains of a bed at rest as plain data ([`SettledBed`], bit-exact
//! through serde), the store that keeps beds between runs ([`BedStore`]), and the one way a
//! run on a bed (drilling, shear) builds or reuses it ([`run_on_bed`]): the bed's share of the
//! progress and the `reused` flag are written here once.

use serde::{Deserialize, Serialize};

use super::recipe::{BedError, BedInfo};
use crate::backend::{BackendError, Engine};
use crate::progress::{Control, Progress};
use crate::spec_path::SpecError;

/// Version of the bed recipe and of its stored form; part of every key, so a change to how
/// beds are built or stored never reuses an old bed. 2: every float is stored as its bits
/// (in 1 the surface height and the build's figures were decimal, and one could come back an
/// ulp off).
pub const BED_FORMAT: u32 = 2;

/// What ended a settling phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SettledBy {
    /// Mean kinetic energy per grain below the threshold.
    KineticEnergy,
    /// The measured shape stayed within the tolerance over the window.
    Stable,
    /// Neither within the time cap (not at rest).
    TimeCap,
}

/// A settled bed: the grains and how it was made, bit-exact through serde (every float is
/// stored as its IEEE bits, so a stored bed gives the same run as a fresh one and compares
/// equal to it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SettledBed {
    /// The key of the spec that built it ([`OnBed::bed_key`]).
    pub key: String,
    #[serde(with = "bits3")]
    pub positions: Vec<[f64; 3]>,
    #[serde(with = "bits3")]
    pub velocities: Vec<[f64; 3]>,
    #[serde(with = "bits3")]
    pub angular_velocities: Vec<[f64; 3]>,
    #[serde(with = "bits1")]
    pub radii: Vec<f64>,
    /// Median surface height (probe height field, away from the walls), m above the floor.
    #[serde(with = "bits")]
    pub surface_z: f64,
    /// Whether a settle criterion was met (else the time cap ended the build).
    pub settled: bool,
    pub settled_by: SettledBy,
    #[serde(with = "bits")]
    pub kinetic_energy_ratio: f64,
    #[serde(with = "bits")]
    pub simulated_time_s: f64,
    pub steps: u64,
    #[serde(with = "bits")]
    pub wall_time_s: f64,
    /// Grains that left the bin while it was filled (lost over the walls).
    pub escaped: u64,
}

mod bits {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u64(x.to_bits())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(f64::from_bits(u64::deserialize(d)?))
    }
}

mod bits3 {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &[[f64; 3]], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(v.iter().flat_map(|p| p.iter().map(|x| x.to_bits())))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<[f64; 3]>, D::Error> {
        let flat = Vec::<u64>::deserialize(d)?;
        if flat.len() % 3 != 0 {
            return Err(serde::de::Error::custom("length is not a multiple of 3"));
        }
        Ok(flat
            .chunks_exact(3)
            .map(|c| {
                [
                    f64::from_bits(c[0]),
                    f64::from_bits(c[1]),
                    f64::from_bits(c[2]),
                ]
            })
            .collect())
    }
}

mod bits1 {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &[f64], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(v.iter().map(|x| x.to_bits()))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        Ok(Vec::<u64>::deserialize(d)?
            .into_iter()
            .map(f64::from_bits)
            .collect())
    }
}

/// Settled beds (drilling beds, and shear samples, which are drilling beds in the shear box)
/// kept between runs under their key: a worker keeps them on disk so that runs whose bed inputs
/// are equal (e.g. a batch varying only the auger, with `bed.seed` fixed) do not rebuild the bed
/// every time.
pub trait BedStore {
    /// The bed stored under `key`, if there is one.
    fn get(&mut self, key: &str) -> Option<SettledBed>;
    /// Keeps `bed` under `bed.key`; failing to keep it must not fail the run.
    fn put(&mut self, bed: &SettledBed);
}

/// No store: every run builds its own bed.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoBedStore;

impl BedStore for NoBedStore {
    fn get(&mut self, _key: &str) -> Option<SettledBed> {
        None
    }
    fn put(&mut self, _bed: &SettledBed) {}
}

/// A bed handed to a run was built for other parameters: its key and the one the spec needs.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the bed was built for other parameters (bed key {found}, the spec needs {expected})")]
pub struct BedMismatch {
    pub expected: String,
    pub found: String,
}

/// Why a run on a settled bed (drilling, shear, triaxial) could not start or was stopped
/// before it could report: one error for every such kind (a finished run that did not go as
/// planned is the kind's result with its status, not an error).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OnBedError {
    #[error(transparent)]
    Spec(#[from] SpecError),
    /// The engine rejected the world built from the spec (materials, meshes, grains).
    #[error("{part}: {reason}")]
    Build { part: &'static str, reason: String },
    /// The bed handed to the run was built for other parameters.
    #[error(transparent)]
    BedMismatch(#[from] BedMismatch),
    /// The progress callback cancelled.
    #[error("cancelled")]
    Cancelled,
    /// `wall_time_cap` ran out while the run was in `phase` (e.g. "building the bed").
    #[error("wall_time_cap ({cap_s} s) reached while {phase}")]
    WallTimeCap { phase: &'static str, cap_s: f64 },
    /// The engine backend cannot run the spec or failed (a GPU's).
    #[error(transparent)]
    Backend(#[from] BackendError),
}

impl OnBedError {
    /// The engine refused `part` of the world: `e` says why.
    pub fn build(part: &'static str, e: impl std::fmt::Display) -> OnBedError {
        OnBedError::Build {
            part,
            reason: e.to_string(),
        }
    }
}

impl From<BedError> for OnBedError {
    fn from(e: BedError) -> OnBedError {
        match e {
            BedError::Spec(e) => OnBedError::Spec(e),
            BedError::Build { part, reason } => OnBedError::Build { part, reason },
            BedError::Cancelled => OnBedError::Cancelled,
            BedError::WallTimeCap { cap_s } => OnBedError::WallTimeCap {
                phase: "building the bed",
                cap_s,
            },
            BedError::Backend(e) => OnBedError::Backend(e),
        }
    }
}

/// A spec of a kind that runs on a settled bed (the drilling test's, the shear test's), on an
/// engine: its bed is settled and used there. The bed's key names the engine
/// ([`BedRecipe::key_on`](super::BedRecipe::key_on)), so a run never takes a bed another
/// engine settled. Each kind implements [`OnBed`] for it.
#[derive(Debug, Clone, Copy)]
pub struct On<'a, S> {
    pub spec: &'a S,
    pub engine: Engine<'a>,
}

impl<'a, S> On<'a, S> {
    /// `spec` on the CPU engine.
    pub fn cpu(spec: &'a S) -> On<'a, S> {
        On {
            spec,
            engine: Engine::Cpu,
        }
    }
}

/// An experiment that runs on a settled bed: how it names, builds and runs on its bed.
/// [`run_on_bed`] does the rest.
pub trait OnBed {
    /// A finished run.
    type Run;
    /// Why a bed could not be built or a run could not report (a bed built for another key
    /// among the reasons).
    type Error: From<BedMismatch>;
    /// The share of the progress fraction that building the bed takes.
    const BED_SHARE: f64;

    /// The key of the bed this spec needs.
    fn bed_key(&self) -> String;

    /// Builds and settles the bed (its progress fraction runs from 0 to 1).
    fn build_bed(
        &self,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<SettledBed, Self::Error>;

    /// Runs on `bed`, built here or earlier (e.g. read back from a cache); a bed built for
    /// another key than [`OnBed::bed_key`] is refused ([`BedMismatch`]).
    fn run_on_bed(
        &self,
        bed: SettledBed,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<Self::Run, Self::Error> {
        let expected = self.bed_key();
        if bed.key != expected {
            return Err(BedMismatch {
                expected,
                found: bed.key,
            }
            .into());
        }
        self.run_on_matching_bed(bed, progress)
    }

    /// Runs on `bed`, known to be built for [`OnBed::bed_key`].
    fn run_on_matching_bed(
        &self,
        bed: SettledBed,
        progress: &mut dyn FnMut(Progress<'_>) -> Control,
    ) -> Result<Self::Run, Self::Error>;

    /// The run's facts about its bed and its wall time, s, for [`run_on_bed`] to complete.
    fn bed_of(run: &mut Self::Run) -> (&mut BedInfo, &mut f64);
}

/// Builds the bed `spec` needs, or takes it from `beds` when they hold one under its key (a
/// bed built here is kept there), then runs on it. Building takes the first
/// [`OnBed::BED_SHARE`] of the progress; a reused bed takes none. The run is the same, bit for
/// bit, whether the bed was built or reused, but for its bed's `reused` flag, set here, and
/// its wall time, which includes the bed's when it was built here.
pub fn run_on_bed<S: OnBed>(
    spec: &S,
    beds: &mut dyn BedStore,
    progress: &mut dyn FnMut(Progress<'_>) -> Control,
) -> Result<S::Run, S::Error> {
    let key = spec.bed_key();
    let cached = beds.get(&key).filter(|bed| bed.key == key);
    let reused = cached.is_some();
    let bed_share = if reused { 0.0 } else { S::BED_SHARE };
    let bed = match cached {
        Some(bed) => bed,
        None => {
            let bed = spec.build_bed(&mut |p| {
                progress(Progress {
                    fraction: bed_share * p.fraction,
                    ..p
                })
            })?;
            beds.put(&bed);
            bed
        }
    };
    let bed_wall_time_s = if reused { 0.0 } else { bed.wall_time_s };
    let mut run = spec.run_on_bed(bed, &mut |p| {
        progress(Progress {
            fraction: bed_share + (1.0 - bed_share) * p.fraction,
            ..p
        })
    })?;
    let (bed, wall_time_s) = S::bed_of(&mut run);
    bed.reused = reused;
    *wall_time_s += bed_wall_time_s;
    Ok(run)
}
