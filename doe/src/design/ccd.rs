//! Central composite designs: a two-level factorial, 2k star (axial) points and centre points.

use super::{two_level_rows, Design, DesignError, DesignKind, DesignResult};
use serde::{Deserialize, Serialize};

/// Where the star points sit relative to the factorial cube.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CcdVariant {
    /// Star points at ±α with α = (2^k)^(1/4), which makes the prediction variance depend only
    /// on the distance from the centre (rotatable). Star points lie *outside* the ±1 range, so
    /// the factor ranges must allow it.
    Circumscribed,
    /// Star points at ±1 on the cube faces (α = 1): use when the ±1 levels are hard limits,
    /// e.g. a friction coefficient that cannot go below its measured minimum.
    FaceCentred,
    /// The circumscribed design shrunk by 1/α so the star points sit at ±1 and the factorial
    /// points at ±1/α: rotatable and inside the ranges, at the cost of a smaller factorial.
    Inscribed,
}

/// Largest `k` accepted; the factorial part has 2^k runs and no fractional core is offered.
const MAX_CCD_FACTORS: usize = 10;

/// The rotatable axial distance (2^k)^(1/4) for a full-factorial core of `k` factors.
pub fn rotatable_alpha(factor_count: usize) -> f64 {
    // 2^(k/4): exact for the powers of two that occur (k = 4 gives 2, k = 8 gives 4).
    (factor_count as f64 / 4.0).exp2()
}

/// A central composite design for 2 ≤ k ≤ 10 factors.
///
/// Run order: the 2^k factorial (Yates order), then for each factor its -α and +α star points,
/// then `centre_points` centre runs. The stored [`DesignKind::CentralComposite`] records α.
pub fn central_composite<S: AsRef<str>>(
    factor_names: &[S],
    variant: CcdVariant,
    centre_points: usize,
) -> DesignResult<Design> {
    let k = factor_names.len();
    if !(2..=MAX_CCD_FACTORS).contains(&k) {
        return Err(DesignError::invalid(
            "factor_names",
            format!("central composite designs need 2 to {MAX_CCD_FACTORS} factors, got {k}"),
        ));
    }
    let alpha = match variant {
        CcdVariant::FaceCentred => 1.0,
        CcdVariant::Circumscribed | CcdVariant::Inscribed => rotatable_alpha(k),
    };
    let (factorial_level, star_level) = match variant {
        CcdVariant::Inscribed => (1.0 / alpha, 1.0),
        CcdVariant::Circumscribed | CcdVariant::FaceCentred => (1.0, alpha),
    };
    let mut rows: Vec<Vec<f64>> = two_level_rows(k)
        .into_iter()
        .map(|row| row.into_iter().map(|x| x * factorial_level).collect())
        .collect();
    for factor in 0..k {
        for sign in [-1.0, 1.0] {
            let mut row = vec![0.0; k];
            row[factor] = sign * star_level;
            rows.push(row);
        }
    }
    rows.extend(std::iter::repeat_n(vec![0.0; k], centre_points));
    Design::new(
        DesignKind::CentralComposite {
            variant,
            alpha,
            centre_points,
        },
        factor_names,
        rows,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotatable_alpha_matches_textbook_values() {
        assert!((rotatable_alpha(2) - 2f64.sqrt()).abs() < 1e-12);
        assert!((rotatable_alpha(3) - 1.681_792_830_507_429).abs() < 1e-12);
        assert_eq!(rotatable_alpha(4), 2.0);
    }

    #[test]
    fn run_count_is_factorial_plus_star_plus_centre() {
        let d = central_composite(&["a", "b", "c"], CcdVariant::FaceCentred, 6).unwrap();
        assert_eq!(d.run_count(), 8 + 6 + 6);
    }

    #[test]
    fn one_factor_is_rejected() {
        assert!(central_composite(&["a"], CcdVariant::Circumscribed, 1).is_err());
    }
}
