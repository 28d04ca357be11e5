//! Box–Behnken three-level response-surface designs (Box & Behnken 1960, *Technometrics* 2(4)).
//!
//! Each design is a union of blocks; a block names a few factors which run through a two-level
//! full factorial while all other factors sit at 0. The blocks follow the original paper:
//!
//! * k = 3, 4, 5: every pair of factors (a 2² factorial per pair) — 12, 24, 40 edge runs;
//! * k = 6: six blocks of **three** factors forming Box & Behnken's partially balanced
//!   incomplete block arrangement (each a 2³ factorial) — 48 edge runs;
//! * k = 7: the seven three-factor blocks of the balanced incomplete block design (the Fano
//!   plane: every pair of factors shares exactly one block) — 56 edge runs.
//!
//! Using all pairs for k = 6 or 7 would give a valid but different and larger design (60 or
//! 84 edge runs), which is not what published tables or other software mean by "Box–Behnken".
//! Centre points are appended after the edge runs.

use super::{two_level_rows, Design, DesignError, DesignKind, DesignResult};

/// 1-based factor blocks for k = 6 (Box & Behnken 1960, design for six factors).
const SIX_FACTOR_BLOCKS: [[usize; 3]; 6] = [
    [1, 2, 4],
    [2, 3, 5],
    [3, 4, 6],
    [1, 4, 5],
    [2, 5, 6],
    [1, 3, 6],
];

/// 1-based factor blocks for k = 7 (Box & Behnken 1960, design for seven factors).
const SEVEN_FACTOR_BLOCKS: [[usize; 3]; 7] = [
    [4, 5, 6],
    [1, 6, 7],
    [2, 5, 7],
    [1, 2, 4],
    [3, 4, 7],
    [1, 3, 5],
    [2, 3, 6],
];

/// Centre points that common statistical software adds by default (3 for k = 3 and 4,
/// 6 for k = 5 to 7). The paper reproduced here used 5 for k = 3, hence the explicit argument
/// to [`box_behnken`].
pub fn default_box_behnken_centre_points(factor_count: usize) -> DesignResult<usize> {
    match factor_count {
        3 | 4 => Ok(3),
        5..=7 => Ok(6),
        _ => Err(unsupported_factor_count(factor_count)),
    }
}

/// The Box–Behnken design for 3 ≤ k ≤ 7 factors with `centre_points` runs at the centre.
///
/// Edge runs come block by block (blocks in the order of the module docs, pairs in
/// lexicographic order), each block's factorial in Yates standard order.
pub fn box_behnken<S: AsRef<str>>(
    factor_names: &[S],
    centre_points: usize,
) -> DesignResult<Design> {
    let k = factor_names.len();
    let blocks: Vec<Vec<usize>> = match k {
        3..=5 => (0..k)
            .flat_map(|i| (i + 1..k).map(move |j| vec![i, j]))
            .collect(),
        6 => zero_based(&SIX_FACTOR_BLOCKS),
        7 => zero_based(&SEVEN_FACTOR_BLOCKS),
        _ => return Err(unsupported_factor_count(k)),
    };
    let mut rows = Vec::new();
    for block in &blocks {
        for corner in two_level_rows(block.len()) {
            let mut row = vec![0.0; k];
            for (&factor, level) in block.iter().zip(corner) {
                row[factor] = level;
            }
            rows.push(row);
        }
    }
    rows.extend(std::iter::repeat_n(vec![0.0; k], centre_points));
    Design::new(DesignKind::BoxBehnken { centre_points }, factor_names, rows)
}

fn zero_based<const B: usize>(blocks: &[[usize; B]]) -> Vec<Vec<usize>> {
    blocks
        .iter()
        .map(|block| block.iter().map(|&f| f - 1).collect())
        .collect()
}

fn unsupported_factor_count(k: usize) -> DesignError {
    DesignError::invalid(
        "factor_names",
        format!("Box–Behnken designs are tabulated for 3 to 7 factors, got {k}"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_counts_match_the_published_designs() {
        for (k, edge_runs) in [(3, 12), (4, 24), (5, 40), (6, 48), (7, 56)] {
            let names = super::super::default_factor_names(k);
            let d = box_behnken(&names, 2).unwrap();
            assert_eq!(d.run_count(), edge_runs + 2, "k = {k}");
        }
    }

    #[test]
    fn seven_factor_blocks_form_a_balanced_incomplete_block_design() {
        // 7 blocks × 3 pairs = 21 = C(7, 2): every pair exactly once iff no pair repeats.
        let mut pairs = std::collections::BTreeSet::new();
        for block in SEVEN_FACTOR_BLOCKS {
            for (i, &a) in block.iter().enumerate() {
                for &b in &block[i + 1..] {
                    assert!(
                        pairs.insert((a.min(b), a.max(b))),
                        "pair ({a}, {b}) repeats"
                    );
                }
            }
        }
        assert_eq!(pairs.len(), 21);
    }

    #[test]
    fn six_factor_blocks_use_each_factor_three_times() {
        for factor in 1..=6 {
            let uses = SIX_FACTOR_BLOCKS
                .iter()
                .filter(|b| b.contains(&factor))
                .count();
            assert_eq!(uses, 3, "factor {factor}");
        }
    }

    #[test]
    fn out_of_range_factor_counts_are_rejected() {
        assert!(box_behnken(&["a", "b"], 3).is_err());
        let names = super::super::default_factor_names(8);
        assert!(box_behnken(&names, 3).is_err());
        assert!(default_box_behnken_centre_points(2).is_err());
    }
}
