//! Seeded run orders and replicate seeds.
//!
//! A DEM simulation is deterministic given its RNG seed, so replicating a design point with the
//! same seed reproduces the same response and makes the pure-error sum of squares exactly zero
//! — the lack-of-fit test would then divide by zero. Every replicate therefore gets its own
//! seed, derived deterministically so a campaign can be re-run bit for bit.

use super::{Design, DesignError, DesignResult};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// A permutation of `0..run_count` that depends only on `seed` (ChaCha8 + Fisher–Yates).
pub fn random_run_order(run_count: usize, seed: u64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..run_count).collect();
    shuffle_with_seed(&mut order, seed);
    order
}

/// Shuffles `items` in place, deterministically for a given `seed`.
pub fn shuffle_with_seed<T>(items: &mut [T], seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    items.shuffle(&mut rng);
}

/// Golden-ratio increment of SplitMix64 (Steele, Lea & Flood 2014); odd, so `i * GAMMA` is
/// distinct for every distinct `i` modulo 2^64.
const SPLITMIX_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// The SplitMix64 output function: a bijection on `u64` that scrambles nearby inputs into
/// unrelated-looking outputs.
pub fn splitmix64(state: u64) -> u64 {
    let mut z = state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The seed a run is given when it runs again under another seed (a job server's answer to a
/// failure of this seed's chance): the next output of a SplitMix64 generator at state `seed`,
/// unrelated-looking to `seed` and to the seeds before it.
pub fn next_seed(seed: u64) -> u64 {
    splitmix64(seed.wrapping_add(SPLITMIX_GAMMA))
}

/// The seed of the `index`-th run of a campaign: `splitmix64(base_seed + (index + 1)·γ)`, i.e.
/// the `index`-th output of a SplitMix64 generator started at `base_seed`. Because the state
/// step is odd and the output function is a bijection, indices below 2^64 never share a seed.
fn run_seed(base_seed: u64, index: usize) -> u64 {
    let step = (index as u64).wrapping_add(1);
    splitmix64(base_seed.wrapping_add(step.wrapping_mul(SPLITMIX_GAMMA)))
}

/// One simulation to perform: a design row, which replicate of it, and the RNG seed to use.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplicatedRun {
    /// Position of the run in the returned list (the campaign's run number, 0-based).
    pub run_index: usize,
    /// Row of the design this run simulates (index into [`Design::coded_runs`]).
    pub design_row: usize,
    /// Which replicate of that row this is, `0..replicates`.
    pub replicate: usize,
    /// Seed for the DEM engine; distinct across all runs of the campaign.
    pub seed: u64,
    /// The run's coded settings (a copy of the design row, for convenience).
    pub coded: Vec<f64>,
}

/// `replicates` copies of every design row, each with its own seed.
///
/// Runs are listed replicate by replicate (all rows of replicate 0, then replicate 1, …) in
/// the design's current row order; shuffle the result with [`shuffle_with_seed`] if the
/// replicates should be interleaved. Run `i` gets the `i`-th SplitMix64 output from
/// `base_seed`, so the seeds are pairwise distinct and reproducible.
pub fn replicate(
    design: &Design,
    replicates: usize,
    base_seed: u64,
) -> DesignResult<Vec<ReplicatedRun>> {
    if replicates == 0 {
        return Err(DesignError::invalid("replicates", "must be at least 1"));
    }
    let rows = design.coded_runs();
    let runs = (0..replicates)
        .flat_map(|rep| (0..rows.len()).map(move |row| (rep, row)))
        .enumerate()
        .map(|(run_index, (replicate, design_row))| ReplicatedRun {
            run_index,
            design_row,
            replicate,
            seed: run_seed(base_seed, run_index),
            coded: rows[design_row].clone(),
        })
        .collect();
    Ok(runs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitmix64_matches_the_reference_sequence() {
        // Reference: SplitMix64 seeded with 0 (Vigna's splitmix64.c) yields these first outputs.
        assert_eq!(run_seed(0, 0), 0xE220_A839_7B1D_CDAF);
        assert_eq!(run_seed(0, 1), 0x6E78_9E6A_A1B9_65F4);
    }

    #[test]
    fn zero_replicates_is_an_error() {
        let d = super::super::full_factorial(&["a"]).unwrap();
        let err = replicate(&d, 0, 1).unwrap_err();
        assert!(err.to_string().contains("replicates"), "{err}");
    }
}
