//! Two-level full factorial designs.

use super::{two_level_rows, Design, DesignError, DesignKind, DesignResult};

/// Largest `k` accepted by [`full_factorial`]: 2^16 = 65 536 DEM runs is already far beyond any
/// sensible calibration budget, and the cap keeps a typo from allocating gigabytes.
pub const MAX_FULL_FACTORIAL_FACTORS: usize = 16;

/// The 2^k full factorial in Yates standard order, coded -1/+1.
///
/// Run `r` sets factor `j` (0-based) to +1 when bit `j` of `r` is set, so the first factor
/// alternates fastest and run 0 is all-low — the order of Montgomery's and NIST's tables.
pub fn full_factorial<S: AsRef<str>>(factor_names: &[S]) -> DesignResult<Design> {
    let k = factor_names.len();
    if k > MAX_FULL_FACTORIAL_FACTORS {
        return Err(DesignError::invalid(
            "factor_names",
            format!(
                "{k} factors would need 2^{k} runs; at most {MAX_FULL_FACTORIAL_FACTORS} factors are supported"
            ),
        ));
    }
    Design::new(DesignKind::FullFactorial, factor_names, two_level_rows(k))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_factors_give_eight_distinct_runs_starting_all_low() {
        let d = full_factorial(&["a", "b", "c"]).unwrap();
        assert_eq!(d.run_count(), 8);
        assert_eq!(d.coded_runs()[0], vec![-1.0, -1.0, -1.0]);
        assert_eq!(d.coded_runs()[7], vec![1.0, 1.0, 1.0]);
        assert_eq!(d.coded_runs()[1], vec![1.0, -1.0, -1.0]);
    }

    #[test]
    fn too_many_factors_is_an_error_not_an_allocation() {
        let names = super::super::default_factor_names(MAX_FULL_FACTORIAL_FACTORS + 1);
        assert!(full_factorial(&names).is_err());
    }
}
