//! Plackett–Burman two-level screening designs.
//!
//! # Convention
//!
//! All five sizes are built the same way, from the cyclic generator rows printed by
//! Plackett & Burman (1946), "The design of optimum multifactorial experiments",
//! *Biometrika* 33(4), and reproduced in NIST's Engineering Statistics Handbook:
//!
//! * runs 1 … n-1 are the generator and its successive cyclic shifts **to the right**
//!   (row `i`, column `j` = `generator[(j - i) mod (n-1)]`);
//! * run n is all -1;
//! * a design for `k` factors uses the first `k` columns.
//!
//! This includes n = 8 and n = 16, for which the paper also gives cyclic generators (they are
//! equivalent to the Sylvester–Hadamard construction up to row/column permutation and sign,
//! but the cyclic form keeps one convention for every size). Shifting right rather than left
//! only changes the row order, never the set of rows.
//!
//! For the paper being reproduced here, Table 3 (12 runs, 6 factors) contains exactly the
//! rows of this construction's first six columns once its 2nd and 6th columns are swapped,
//! listed in a different run order; see `doe/tests/doe/designs.rs`.

use super::{Design, DesignError, DesignKind, DesignResult};

/// Run sizes for which a generator is tabulated.
pub const PLACKETT_BURMAN_RUN_SIZES: [usize; 5] = [8, 12, 16, 20, 24];

/// Plackett & Burman (1946) cyclic generators, `+` = +1, `-` = -1; each has `runs - 1` signs.
const GENERATORS: [(usize, &str); 5] = [
    (8, "+++-+--"),
    (12, "++-+++---+-"),
    (16, "++++-+-++--+---"),
    (20, "++--++++-+-+----++-"),
    (24, "+++++-+-++--++--+-+----"),
];

/// The `runs`-run Plackett–Burman design for `factor_names.len()` factors (see the module
/// docs for the convention). Requires `runs` ∈ {8, 12, 16, 20, 24} and `1 ≤ k ≤ runs - 1`.
///
/// Columns are mutually orthogonal and balanced (as many +1 as -1), so main effects are
/// estimated independently with `runs` observations each — the point of a screening design.
pub fn plackett_burman<S: AsRef<str>>(factor_names: &[S], runs: usize) -> DesignResult<Design> {
    let generator = GENERATORS
        .iter()
        .find(|(size, _)| *size == runs)
        .map(|(_, signs)| *signs)
        .ok_or_else(|| {
            DesignError::invalid(
                "runs",
                format!("{runs} is not supported; use one of {PLACKETT_BURMAN_RUN_SIZES:?}"),
            )
        })?;
    let k = factor_names.len();
    if k >= runs {
        return Err(DesignError::invalid(
            "factor_names",
            format!(
                "a {runs}-run Plackett–Burman design screens at most {} factors, got {k}",
                runs - 1
            ),
        ));
    }
    let signs: Vec<f64> = generator
        .chars()
        .map(|c| if c == '+' { 1.0 } else { -1.0 })
        .collect();
    let period = signs.len();
    let mut rows: Vec<Vec<f64>> = (0..period)
        .map(|shift| {
            (0..k)
                .map(|column| signs[(column + period - shift) % period])
                .collect()
        })
        .collect();
    rows.push(vec![-1.0; k]);
    Design::new(DesignKind::PlackettBurman { runs }, factor_names, rows)
}

/// The smallest tabulated Plackett–Burman size that can screen `factor_count` factors.
pub fn smallest_plackett_burman_runs(factor_count: usize) -> DesignResult<usize> {
    if factor_count == 0 {
        return Err(DesignError::invalid("factor_count", "must be at least 1"));
    }
    PLACKETT_BURMAN_RUN_SIZES
        .iter()
        .copied()
        .find(|&runs| factor_count < runs)
        .ok_or_else(|| {
            DesignError::invalid(
                "factor_count",
                format!("{factor_count} factors exceed the largest supported design (24 runs, 23 factors)"),
            )
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generators_have_runs_minus_one_signs() {
        for (runs, signs) in GENERATORS {
            assert_eq!(signs.len(), runs - 1, "generator for {runs}");
        }
    }

    #[test]
    fn first_row_is_the_generator_and_last_row_all_low() {
        let names = super::super::default_factor_names(11);
        let d = plackett_burman(&names, 12).unwrap();
        let expected: Vec<f64> = "++-+++---+-"
            .chars()
            .map(|c| if c == '+' { 1.0 } else { -1.0 })
            .collect();
        assert_eq!(d.coded_runs()[0], expected);
        assert_eq!(d.coded_runs()[11], vec![-1.0; 11]);
        // Second row is the generator shifted right by one.
        assert_eq!(d.coded_runs()[1][0], expected[10]);
        assert_eq!(d.coded_runs()[1][1], expected[0]);
    }

    #[test]
    fn unsupported_sizes_name_the_parameter() {
        let err = plackett_burman(&["a"], 10).unwrap_err();
        assert!(err.to_string().contains("`runs`"), "{err}");
        let names = super::super::default_factor_names(8);
        let err = plackett_burman(&names, 8).unwrap_err();
        assert!(err.to_string().contains("factor_names"), "{err}");
    }

    #[test]
    fn smallest_size_fits_the_factor_count() {
        assert_eq!(smallest_plackett_burman_runs(6).unwrap(), 8);
        assert_eq!(smallest_plackett_burman_runs(7).unwrap(), 8);
        assert_eq!(smallest_plackett_burman_runs(8).unwrap(), 12);
        assert_eq!(smallest_plackett_burman_runs(23).unwrap(), 24);
        assert!(smallest_plackett_burman_runs(24).is_err());
        assert!(smallest_plackett_burman_runs(0).is_err());
    }
}
