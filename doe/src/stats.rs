//! Distribution helpers (statrs) with the edge cases handled once.
//!
//! p-values are computed from the upper tail directly (regularised incomplete
//! beta of the complementary argument), not as `1 - cdf`, so that very small
//! p-values such as the paper's "< 0.0001" rows keep full relative accuracy.

use statrs::distribution::{ContinuousCDF, StudentsT};
use statrs::function::beta::beta_reg;

/// Upper-tail probability `P(F > f)` of the F distribution with `(d1, d2)`
/// degrees of freedom; `None` when undefined (non-finite `f`, zero df).
pub(crate) fn f_sf(f: f64, d1: f64, d2: f64) -> Option<f64> {
    if !(d1 > 0.0 && d2 > 0.0) || f.is_nan() {
        return None;
    }
    if f <= 0.0 {
        return Some(1.0);
    }
    if f.is_infinite() {
        return Some(0.0);
    }
    // P(F > f) = I_{d2/(d2 + d1 f)}(d2/2, d1/2), written without cancellation.
    let x = d2 / (d2 + d1 * f);
    Some(beta_reg(d2 / 2.0, d1 / 2.0, x))
}

/// Two-sided p-value of a t statistic.
pub(crate) fn t_two_sided_p(t: f64, df: f64) -> f64 {
    if t.is_nan() {
        return f64::NAN;
    }
    // P(|T| > t) = I_{df/(df + t²)}(df/2, 1/2).
    let x = df / (df + t * t);
    beta_reg(df / 2.0, 0.5, x)
}

/// Quantile `q` of Student's t with `df` degrees of freedom.
pub(crate) fn t_quantile(q: f64, df: f64) -> f64 {
    match StudentsT::new(0.0, 1.0, df) {
        Ok(t) => t.inverse_cdf(q),
        Err(_) => f64::NAN,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use statrs::distribution::FisherSnedecor;

    #[test]
    fn f_sf_matches_statrs() {
        let d = FisherSnedecor::new(3.0, 7.0).unwrap();
        for f in [0.1, 0.3455, 1.0, 5.0, 40.0] {
            let a = f_sf(f, 3.0, 7.0).unwrap();
            let b = d.sf(f);
            assert!((a - b).abs() < 1e-12 * b.max(1e-300) + 1e-15, "{a} {b}");
        }
    }

    #[test]
    fn t_quantile_known_value() {
        // t_{0.975, 5} = 2.570581836...
        assert!((t_quantile(0.975, 5.0) - 2.570_581_836_614_739).abs() < 1e-9);
        assert!((t_two_sided_p(2.570_581_836_614_739, 5.0) - 0.05).abs() < 1e-10);
    }
}
