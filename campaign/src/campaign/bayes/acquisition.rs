//! What a proposal aims at: the probability that the verified mean of every target lands within
//! its tolerance, times the probability that the point is feasible, under the surrogates; in
//! logarithms so that points far from every target still rank by how far they are. The
//! exploration term is the same probability at an optimistic mean ([`ln_p_within_optimistic`]):
//! an upper confidence bound, high where the surrogate does not know yet (an edge of the box it
//! has not seen) as well as where it expects the target.

use statrs::function::erf::erfc;

use super::surrogate::Prediction;

const LN_SQRT_2PI: f64 = 0.918_938_533_204_672_8;

/// `Φ(z)`, the standard normal distribution function.
pub(crate) fn norm_cdf(z: f64) -> f64 {
    0.5 * erfc(-z / std::f64::consts::SQRT_2)
}

/// `ln Φ(z)`, with the asymptotic tail where `Φ` underflows.
fn ln_norm_cdf(z: f64) -> f64 {
    if z > -30.0 {
        norm_cdf(z).ln()
    } else {
        -0.5 * z * z - (-z).ln() - LN_SQRT_2PI
    }
}

/// `ln (Φ(b) - Φ(a))` for `a < b`, accurate far in either tail.
pub(crate) fn ln_norm_interval(a: f64, b: f64) -> f64 {
    if a > 0.0 {
        // Upper tail: reflect so that the interval lies on the side that does not round to 1.
        return ln_norm_interval(-b, -a);
    }
    let mass = norm_cdf(b) - norm_cdf(a);
    if mass > 1e-280 {
        return mass.ln();
    }
    let (la, lb) = (ln_norm_cdf(a), ln_norm_cdf(b));
    lb + (-(la - lb).exp()).ln_1p()
}

/// One target as the acquisition sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Band {
    /// Measured value.
    pub target: f64,
    /// Half-width of the tolerance band.
    pub half_width: f64,
}

/// `ln P(|mean of r runs − target| ≤ half-width)` under one prediction: the latent mean's
/// uncertainty plus the noise of `replicates` runs.
pub(crate) fn ln_p_within(p: &Prediction, band: Band, replicates: u32) -> f64 {
    let sd = (p.sd * p.sd + p.noise_sd * p.noise_sd / f64::from(replicates.max(1)))
        .sqrt()
        .max(1e-12 * band.half_width.max(1e-300));
    let a = (band.target - band.half_width - p.mean) / sd;
    let b = (band.target + band.half_width - p.mean) / sd;
    ln_norm_interval(a, b)
}

/// How many posterior standard deviations the optimistic mean may move toward the target.
pub(crate) const OPTIMISM: f64 = 2.0;

/// [`ln_p_within`] at the most favourable latent mean within [`OPTIMISM`] posterior standard
/// deviations of the prediction: an upper confidence bound on the probability.
pub(crate) fn ln_p_within_optimistic(p: &Prediction, band: Band, replicates: u32) -> f64 {
    let reach = OPTIMISM * p.sd;
    let shift = (band.target - p.mean).clamp(-reach, reach);
    let optimistic = Prediction {
        mean: p.mean + shift,
        ..*p
    };
    ln_p_within(&optimistic, band, replicates)
}

/// The probability that a point is feasible from the feasibility surrogate (fitted on +1 for
/// points whose runs all gave their metrics, −1 for failed ones): `Φ(μ / s)`.
pub(crate) fn ln_p_feasible(p: &Prediction) -> f64 {
    ln_norm_cdf(p.mean / (p.sd * p.sd + 1e-4).sqrt())
}

/// Joint misfit `Σ ((y − t) / half-width)²` of response values against their bands.
pub(crate) fn misfit(values: &[f64], bands: &[Band]) -> f64 {
    values
        .iter()
        .zip(bands)
        .map(|(v, b)| ((v - b.target) / b.half_width).powi(2))
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_distribution_known_values() {
        // statrs's erfc is accurate to about 1e-11 here.
        assert!((norm_cdf(0.0) - 0.5).abs() < 1e-15);
        let v = norm_cdf(1.96);
        assert!((v - 0.975_002_104_851_780).abs() < 1e-9, "{v}");
        let w = norm_cdf(-1.0);
        assert!((w - 0.158_655_253_931_457).abs() < 1e-9, "{w}");
        // Φ(1) − Φ(−1) = 0.682689492137086
        assert!((ln_norm_interval(-1.0, 1.0).exp() - 0.682_689_492_137_086).abs() < 1e-9);
        // Reflected upper interval: Φ(3) − Φ(2) = 0.021400233916549
        assert!((ln_norm_interval(2.0, 3.0).exp() - 0.021_400_233_916_549).abs() < 1e-9);
    }

    #[test]
    fn far_tails_stay_finite_and_ordered() {
        let near = ln_norm_interval(-41.0, -40.0);
        let far = ln_norm_interval(-61.0, -60.0);
        assert!(near.is_finite() && far.is_finite());
        assert!(near > far);
        // Mills ratio: ln Φ(-40) ≈ -800 - ln 40 - ln √(2π)
        assert!(
            (near - (-800.0 - 40f64.ln() - LN_SQRT_2PI)).abs() < 0.01,
            "{near}"
        );
        assert_eq!(ln_norm_interval(40.0, 41.0), ln_norm_interval(-41.0, -40.0));
    }

    #[test]
    fn probability_within_a_band_uses_the_replicates_noise() {
        let p = Prediction {
            mean: 10.0,
            sd: 0.0,
            noise_sd: 1.0,
        };
        let band = Band {
            target: 10.0,
            half_width: 1.0,
        };
        // One run: P(|N(0,1)| ≤ 1) = 0.6827; four runs: P(|N(0,½)| ≤ 1) = P(|Z| ≤ 2) = 0.9545.
        assert!((ln_p_within(&p, band, 1).exp() - 0.682_689_492).abs() < 1e-8);
        assert!((ln_p_within(&p, band, 4).exp() - 0.954_499_736).abs() < 1e-8);
    }

    #[test]
    fn the_optimistic_probability_moves_the_mean_by_at_most_two_sd() {
        let band = Band {
            target: 10.0,
            half_width: 1.0,
        };
        let far = Prediction {
            mean: 14.0,
            sd: 1.0,
            noise_sd: 0.5,
        };
        // Moved to 12: as likely as a prediction of 12 with the same uncertainty.
        let moved = Prediction { mean: 12.0, ..far };
        assert_eq!(
            ln_p_within_optimistic(&far, band, 1),
            ln_p_within(&moved, band, 1)
        );
        assert!(ln_p_within_optimistic(&far, band, 1) > ln_p_within(&far, band, 1));
        // Within reach of the target: as if predicted on it; certain: unchanged.
        let near = Prediction { mean: 11.5, ..far };
        let on = Prediction { mean: 10.0, ..far };
        assert_eq!(
            ln_p_within_optimistic(&near, band, 1),
            ln_p_within(&on, band, 1)
        );
        let certain = Prediction { sd: 0.0, ..far };
        assert_eq!(
            ln_p_within_optimistic(&certain, band, 1),
            ln_p_within(&certain, band, 1)
        );
    }
}
