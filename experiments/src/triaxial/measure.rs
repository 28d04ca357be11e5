//! How a triaxial test's records are read, as the lab reads them: failure at the peak deviator
//! stress, or at the end of a record without a peak (ASTM D7181: the peak, or q at 15 % axial
//! strain, whichever comes first); the Mohr-Coulomb envelope fitted to the failure circles by
//! least squares of σ1 = N·σ3 + 2c·√N, N = (1 + sin φ)/(1 − sin φ); Young's modulus as the
//! secant modulus to half the failure deviator (E50: the slope of the paper's "linear section",
//! its Eq. 1) and Poisson's ratio from its Eq. 2, ν = ½(1 − Δεv/Δεa), over the same range.

use serde::{Deserialize, Serialize};

use crate::soil::running_mean;

/// One recorded point of a stage's loading (means over one servo interval). Strains are
/// positive in compression, from the start of loading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TriaxialSample {
    /// Axial strain.
    pub axial_strain: f64,
    /// Deviator stress q = σ1 − σ3, kPa.
    pub deviator_kpa: f64,
    /// Volumetric strain (positive: contraction).
    pub volumetric_strain: f64,
    /// The lateral walls' mean stress, kPa (its target is the stage's σ3).
    pub lateral_kpa: f64,
}

/// Failure of one stage.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Failure {
    /// Index of the failure sample in the record.
    pub index: usize,
    /// q at failure, of the record smoothed over a twentieth of its samples, kPa.
    pub deviator_kpa: f64,
    /// The lateral walls' stress at failure (smoothed as q), kPa: the circle's σ3.
    pub confining_kpa: f64,
    pub axial_strain: f64,
    /// Whether q peaked before the end of the record (else failure is the end's q).
    pub peaked: bool,
}

/// The record is smoothed over 1/this of its samples before its peak is read.
pub const SMOOTHING_DIVISOR: usize = 20;

/// A peak counts only if q at the end of the record has fallen this fraction below it (a
/// record still rising, or flat within its noise, fails at its end).
pub const PEAK_DROP: f64 = 0.02;

/// The failure point of `series` (empty: none).
pub fn failure(series: &[TriaxialSample]) -> Option<Failure> {
    let n = series.len();
    if n == 0 {
        return None;
    }
    let width = (n / SMOOTHING_DIVISOR).max(1);
    let q = running_mean(
        &series.iter().map(|s| s.deviator_kpa).collect::<Vec<_>>(),
        width,
    );
    let lateral = running_mean(
        &series.iter().map(|s| s.lateral_kpa).collect::<Vec<_>>(),
        width,
    );
    let (mut index, peak) =
        q.iter().copied().enumerate().fold(
            (0, f64::MIN),
            |best, (k, v)| if v > best.1 { (k, v) } else { best },
        );
    let end = q[n - 1];
    let peaked = index < n - 1 && end < peak - PEAK_DROP * peak.abs();
    if !peaked {
        index = n - 1;
    }
    Some(Failure {
        index,
        deviator_kpa: q[index],
        confining_kpa: lateral[index],
        axial_strain: series[index].axial_strain,
        peaked,
    })
}

/// The Mohr-Coulomb envelope of the failure circles.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// c, kPa (may come out negative for a cohesionless soil's scatter).
    pub cohesion_kpa: f64,
    /// φ, degrees.
    pub friction_angle_deg: f64,
    /// N = (1 + sin φ)/(1 − sin φ), the slope of σ1 against σ3.
    pub slope: f64,
    /// 2c√N, the intercept of σ1 against σ3, kPa.
    pub intercept_kpa: f64,
    /// Coefficient of determination of the σ1-σ3 line (1 for two circles).
    pub r_squared: f64,
    pub circles: usize,
}

/// Why no envelope could be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EnvelopeError {
    #[error("needs at least two circles at different confining pressures, got {0}")]
    TooFew(usize),
    #[error("circle {0} is not finite")]
    NotFinite(usize),
    /// σ1 does not rise with σ3 (N ≤ 1): no positive friction angle.
    #[error("σ1 at failure does not rise with σ3 (slope {0:.3}): no friction angle")]
    NoFriction(f64),
}

/// The envelope of the circles `(σ3, σ1)` at failure, kPa: the least-squares line σ1 = N·σ3 +
/// b, then sin φ = (N − 1)/(N + 1) and c = b/(2√N).
pub fn envelope(circles: &[(f64, f64)]) -> Result<Envelope, EnvelopeError> {
    for (k, &(s3, s1)) in circles.iter().enumerate() {
        if !(s3.is_finite() && s1.is_finite()) {
            return Err(EnvelopeError::NotFinite(k));
        }
    }
    let n = circles.len() as f64;
    let mean3 = circles.iter().map(|c| c.0).sum::<f64>() / n;
    let mean1 = circles.iter().map(|c| c.1).sum::<f64>() / n;
    let sxx: f64 = circles.iter().map(|c| (c.0 - mean3).powi(2)).sum();
    if circles.len() < 2 || sxx <= 1e-12 * mean3.abs().max(1.0) {
        return Err(EnvelopeError::TooFew(circles.len()));
    }
    let sxy: f64 = circles.iter().map(|c| (c.0 - mean3) * (c.1 - mean1)).sum();
    let slope = sxy / sxx;
    if slope.is_nan() || slope <= 1.0 {
        return Err(EnvelopeError::NoFriction(slope));
    }
    let intercept = mean1 - slope * mean3;
    let syy: f64 = circles.iter().map(|c| (c.1 - mean1).powi(2)).sum();
    let sse: f64 = circles
        .iter()
        .map(|c| (c.1 - intercept - slope * c.0).powi(2))
        .sum();
    let r_squared = if syy > 0.0 { 1.0 - sse / syy } else { 1.0 };
    Ok(Envelope {
        cohesion_kpa: intercept / (2.0 * slope.sqrt()),
        friction_angle_deg: ((slope - 1.0) / (slope + 1.0)).asin().to_degrees(),
        slope,
        intercept_kpa: intercept,
        r_squared,
        circles: circles.len(),
    })
}

/// The stiffness read off one stage's record.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stiffness {
    /// E50: q at half the failure deviator over the axial strain there, MPa.
    pub young_modulus_mpa: f64,
    /// ν = ½(1 − Δεv/Δεa) from the start of loading to the same point.
    pub poisson_ratio: f64,
    /// The axial strain at half the failure deviator.
    pub axial_strain: f64,
}

/// E50 and ν of `series` failing at `failure` (none if q never reaches half its failure value
/// at a positive strain before failure).
pub fn stiffness(series: &[TriaxialSample], failure: &Failure) -> Option<Stiffness> {
    let half = 0.5 * failure.deviator_kpa;
    if half.is_nan() || half <= 0.0 {
        return None;
    }
    let end = failure.index.min(series.len().checked_sub(1)?);
    let k = (1..=end).find(|&k| series[k].deviator_kpa >= half)?;
    let (a, b) = (series[k - 1], series[k]);
    let dq = b.deviator_kpa - a.deviator_kpa;
    let t = if dq > 0.0 {
        ((half - a.deviator_kpa) / dq).clamp(0.0, 1.0)
    } else {
        1.0
    };
    let ea = a.axial_strain + t * (b.axial_strain - a.axial_strain);
    let ev = a.volumetric_strain + t * (b.volumetric_strain - a.volumetric_strain);
    if ea.is_nan() || ea <= 0.0 {
        return None;
    }
    Some(Stiffness {
        young_modulus_mpa: 1e-3 * half / ea,
        poisson_ratio: 0.5 * (1.0 - ev / ea),
        axial_strain: ea,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Circles of a known envelope give it back, to rounding.
    #[test]
    fn circles_of_a_known_envelope_give_it_back() {
        let (c, phi) = (2.5_f64, 30.6_f64.to_radians());
        let n = (1.0 + phi.sin()) / (1.0 - phi.sin());
        let circles: Vec<(f64, f64)> = [2.5, 5.0, 7.5]
            .iter()
            .map(|&s3| (s3, n * s3 + 2.0 * c * n.sqrt()))
            .collect();
        let e = envelope(&circles).unwrap();
        assert!((e.cohesion_kpa - 2.5).abs() < 1e-9, "{e:?}");
        assert!((e.friction_angle_deg - 30.6).abs() < 1e-9, "{e:?}");
        assert!((e.r_squared - 1.0).abs() < 1e-12);
        // The common tangent of the circles is the same line: τ = c + σ tan φ touches each
        // circle (its distance from the centre equals the radius).
        for &(s3, s1) in &circles {
            let (centre, radius) = (0.5 * (s1 + s3), 0.5 * (s1 - s3));
            let distance = (c + centre * phi.tan()) * phi.cos();
            assert!((distance - radius).abs() < 1e-9);
        }
        assert!(matches!(
            envelope(&circles[..1]),
            Err(EnvelopeError::TooFew(1))
        ));
        assert!(matches!(
            envelope(&[(5.0, 4.0), (10.0, 6.0)]),
            Err(EnvelopeError::NoFriction(_))
        ));
        assert!(matches!(
            envelope(&[(5.0, f64::NAN), (10.0, 6.0)]),
            Err(EnvelopeError::NotFinite(0))
        ));
    }

    fn record(q: impl Fn(f64) -> f64, ev: impl Fn(f64) -> f64) -> Vec<TriaxialSample> {
        (0..=300)
            .map(|k| {
                let ea = 0.15 * k as f64 / 300.0;
                TriaxialSample {
                    axial_strain: ea,
                    deviator_kpa: q(ea),
                    volumetric_strain: ev(ea),
                    lateral_kpa: 5.0,
                }
            })
            .collect()
    }

    #[test]
    fn failure_is_the_peak_or_the_end_of_a_record_without_one() {
        // Peaks at 5 % and softens.
        let peaked = record(
            |e| 10.0 * (e / 0.05) * (1.0 - e / 0.1) + 10.0 * 0.0,
            |_| 0.0,
        );
        let f = failure(&peaked).unwrap();
        assert!(f.peaked);
        assert!((f.axial_strain - 0.05).abs() < 0.002, "{f:?}");
        assert!((f.deviator_kpa - 5.0).abs() < 0.05, "{f:?}");
        // Still hardening: failure at the end.
        let hardening = record(|e| 20.0 * (1.0 - (-e / 0.05).exp()), |_| 0.0);
        let f = failure(&hardening).unwrap();
        assert!(!f.peaked);
        assert_eq!(f.index, 300);
        assert_eq!(f.confining_kpa, 5.0);
        assert!(failure(&[]).is_none());
    }

    #[test]
    fn e50_and_poisson_ratio_of_a_linear_elastic_record() {
        // q = E εa with E = 4 MPa up to a plateau; εv = (1 - 2ν) εa with ν = 0.3.
        let e = 4000.0;
        let series = record(|ea| (e * ea).min(100.0), |ea| 0.4 * ea);
        let f = failure(&series).unwrap();
        let s = stiffness(&series, &f).unwrap();
        assert!((s.young_modulus_mpa - 4.0).abs() < 0.05, "{s:?}");
        assert!((s.poisson_ratio - 0.3).abs() < 1e-9, "{s:?}");
    }
}
