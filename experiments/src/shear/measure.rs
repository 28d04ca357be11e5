//! Peak and residual shear strength of a shear record, and the Mohr-Coulomb fit.

use serde::{Deserialize, Serialize};

pub use crate::soil::running_mean;

/// One shear stage at one normal stress: the box's horizontal displacement and the shear force
/// the soil transmits across the shear plane, sample by sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShearRecord {
    /// Normal stress on the shear plane, Pa (the lid's force over the box's area).
    pub normal_stress_pa: f64,
    /// Area of the shear plane, m².
    pub area_m2: f64,
    /// Shear displacement, m, increasing.
    pub displacement_m: Vec<f64>,
    /// Shear force across the plane, N (same length as `displacement_m`).
    pub shear_force_n: Vec<f64>,
}

/// What one record gives.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ShearPoint {
    pub normal_stress_pa: f64,
    /// Largest shear stress, Pa.
    pub peak_pa: f64,
    /// Displacement at the peak, m.
    pub peak_displacement_m: f64,
    /// Mean shear stress over the last `residual_fraction` of the displacement, Pa.
    pub residual_pa: f64,
}

/// A (normal stress, shear stress) pair for the Mohr-Coulomb fit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StrengthPoint {
    pub normal_stress_pa: f64,
    pub shear_stress_pa: f64,
}

/// The Mohr-Coulomb line τ = c + σ tan φ fitted by least squares.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MohrCoulomb {
    /// c, kPa (the intercept; may come out negative for a cohesionless soil's scatter).
    pub cohesion_kpa: f64,
    /// φ, degrees (atan of the slope).
    pub friction_angle_deg: f64,
    /// Coefficient of determination of the fit (1 for two points).
    pub r_squared: f64,
    /// Root-mean-square residual of the shear stresses, kPa.
    pub rmse_kpa: f64,
    /// Standard error of c, kPa (absent with two points: no degrees of freedom).
    pub cohesion_std_error_kpa: Option<f64>,
    /// Standard error of the slope tan φ (absent with two points).
    pub slope_std_error: Option<f64>,
    /// Number of points.
    pub points: usize,
}

/// Why a record or a set of points cannot be measured. Messages name the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShearMeasureError {
    #[error("{field}: {reason}")]
    Invalid { field: String, reason: String },
    #[error("a Mohr-Coulomb fit needs at least two different normal stresses (got {0})")]
    TooFewStresses(usize),
}

fn invalid(field: impl Into<String>, reason: impl Into<String>) -> ShearMeasureError {
    ShearMeasureError::Invalid {
        field: field.into(),
        reason: reason.into(),
    }
}

/// The peak and residual shear stress of `record`; the residual is the mean over the last
/// `residual_fraction` (0..1] of the largest displacement.
pub fn shear_strength(
    record: &ShearRecord,
    residual_fraction: f64,
) -> Result<ShearPoint, ShearMeasureError> {
    let n = record.displacement_m.len();
    if n < 2 {
        return Err(invalid("displacement_m", "needs at least two samples"));
    }
    if record.shear_force_n.len() != n {
        return Err(invalid(
            "shear_force_n",
            format!(
                "has {} samples, displacement_m {n}",
                record.shear_force_n.len()
            ),
        ));
    }
    if !(record.area_m2 > 0.0 && record.area_m2.is_finite()) {
        return Err(invalid("area_m2", "must be > 0"));
    }
    if !(residual_fraction > 0.0 && residual_fraction <= 1.0) {
        return Err(invalid("residual_fraction", "must be in (0, 1]"));
    }
    if record.displacement_m.iter().any(|x| !x.is_finite())
        || record.displacement_m.windows(2).any(|w| w[1] < w[0])
    {
        return Err(invalid(
            "displacement_m",
            "must be finite and non-decreasing",
        ));
    }
    if record.shear_force_n.iter().any(|f| !f.is_finite()) {
        return Err(invalid("shear_force_n", "must be finite"));
    }
    let (mut peak_k, mut peak) = (0, f64::NEG_INFINITY);
    for (k, &f) in record.shear_force_n.iter().enumerate() {
        if f > peak {
            (peak_k, peak) = (k, f);
        }
    }
    let last = record.displacement_m[n - 1];
    let from = last - residual_fraction * (last - record.displacement_m[0]);
    let tail: Vec<f64> = record
        .displacement_m
        .iter()
        .zip(&record.shear_force_n)
        .filter(|(x, _)| **x >= from)
        .map(|(_, f)| *f)
        .collect();
    let residual = tail.iter().sum::<f64>() / tail.len() as f64;
    Ok(ShearPoint {
        normal_stress_pa: record.normal_stress_pa,
        peak_pa: peak / record.area_m2,
        peak_displacement_m: record.displacement_m[peak_k],
        residual_pa: residual / record.area_m2,
    })
}

/// The least-squares line τ = c + σ tan φ through `points`.
pub fn mohr_coulomb_fit(points: &[StrengthPoint]) -> Result<MohrCoulomb, ShearMeasureError> {
    for (k, p) in points.iter().enumerate() {
        if !p.normal_stress_pa.is_finite() || !p.shear_stress_pa.is_finite() {
            return Err(invalid(format!("points[{k}]"), "must be finite"));
        }
    }
    let n = points.len() as f64;
    let mean_s = points.iter().map(|p| p.normal_stress_pa).sum::<f64>() / n;
    let mean_t = points.iter().map(|p| p.shear_stress_pa).sum::<f64>() / n;
    let sxx: f64 = points
        .iter()
        .map(|p| (p.normal_stress_pa - mean_s).powi(2))
        .sum();
    let distinct = {
        let mut s: Vec<f64> = points.iter().map(|p| p.normal_stress_pa).collect();
        s.sort_by(f64::total_cmp);
        s.dedup();
        s.len()
    };
    if points.len() < 2 || distinct < 2 || sxx <= 0.0 {
        return Err(ShearMeasureError::TooFewStresses(distinct));
    }
    let sxy: f64 = points
        .iter()
        .map(|p| (p.normal_stress_pa - mean_s) * (p.shear_stress_pa - mean_t))
        .sum();
    let slope = sxy / sxx;
    let intercept = mean_t - slope * mean_s;
    let ss_res: f64 = points
        .iter()
        .map(|p| (p.shear_stress_pa - intercept - slope * p.normal_stress_pa).powi(2))
        .sum();
    let ss_tot: f64 = points
        .iter()
        .map(|p| (p.shear_stress_pa - mean_t).powi(2))
        .sum();
    let r_squared = if ss_tot > 0.0 {
        1.0 - ss_res / ss_tot
    } else {
        1.0
    };
    let dof = points.len() as f64 - 2.0;
    let (cohesion_se, slope_se) = if dof > 0.0 {
        let s2 = ss_res / dof;
        let sum_x2: f64 = points.iter().map(|p| p.normal_stress_pa.powi(2)).sum();
        (
            Some((s2 * sum_x2 / (n * sxx)).sqrt() / 1e3),
            Some((s2 / sxx).sqrt()),
        )
    } else {
        (None, None)
    };
    Ok(MohrCoulomb {
        cohesion_kpa: intercept / 1e3,
        friction_angle_deg: slope.atan().to_degrees(),
        r_squared,
        rmse_kpa: (ss_res / n).sqrt() / 1e3,
        cohesion_std_error_kpa: cohesion_se,
        slope_std_error: slope_se,
        points: points.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A shear record whose stress rises to `peak` at 2 mm, then softens to `residual` by
    /// 6 mm, with a small deterministic ripple (a DEM record is never smooth).
    fn synthetic(normal_stress_pa: f64, peak: f64, residual: f64) -> ShearRecord {
        let area = 0.06 * 0.06;
        let mut displacement_m = Vec::new();
        let mut shear_force_n = Vec::new();
        for k in 0..=400 {
            let x = 8e-3 * k as f64 / 400.0;
            let rise = 1.0 - (-x / 0.25e-3).exp();
            let soften = if x > 2e-3 {
                ((x - 2e-3) / 4e-3).min(1.0)
            } else {
                0.0
            };
            let tau = peak * rise * (1.0 - soften) + residual * soften * rise;
            // The ripple's phase differs between records, so the points scatter about the line.
            let ripple = 0.01 * peak * (k as f64 * 1.7 + normal_stress_pa / 3e3).sin();
            displacement_m.push(x);
            shear_force_n.push((tau + ripple) * area);
        }
        ShearRecord {
            normal_stress_pa,
            area_m2: area,
            displacement_m,
            shear_force_n,
        }
    }

    #[test]
    fn recovers_cohesion_and_friction_angle_from_synthetic_records() {
        // The paper's triaxial figures: c = 2.5 kPa, φ = 30.6°; residual: c = 0, φ = 27°.
        let (c, phi) = (2.5e3, 30.6f64.to_radians());
        let phi_residual = 27f64.to_radians();
        let mut peaks = Vec::new();
        let mut residuals = Vec::new();
        for sigma in [5e3, 10e3, 20e3, 40e3] {
            let record = synthetic(sigma, c + sigma * phi.tan(), sigma * phi_residual.tan());
            let point = shear_strength(&record, 0.25).unwrap();
            peaks.push(StrengthPoint {
                normal_stress_pa: sigma,
                shear_stress_pa: point.peak_pa,
            });
            residuals.push(StrengthPoint {
                normal_stress_pa: sigma,
                shear_stress_pa: point.residual_pa,
            });
        }
        let fit = mohr_coulomb_fit(&peaks).unwrap();
        println!("peak fit {fit:?}");
        // The ripple adds up to 1 % of the peak to the maximum: c within 0.5 kPa, φ within 0.5°.
        assert!((fit.cohesion_kpa - 2.5).abs() < 0.5, "{fit:?}");
        assert!((fit.friction_angle_deg - 30.6).abs() < 0.5, "{fit:?}");
        assert!(fit.r_squared > 0.99 && fit.r_squared < 1.0, "{fit:?}");
        assert_eq!(fit.points, 4);
        assert!(fit.cohesion_std_error_kpa.is_some());
        let fit = mohr_coulomb_fit(&residuals).unwrap();
        println!("residual fit {fit:?}");
        assert!(fit.cohesion_kpa.abs() < 0.3, "{fit:?}");
        assert!((fit.friction_angle_deg - 27.0).abs() < 0.5, "{fit:?}");
    }

    #[test]
    fn the_running_mean_averages_a_centred_window_cut_at_the_ends() {
        let v = [1.0, 2.0, 3.0, 4.0, 5.0, 60.0];
        assert_eq!(running_mean(&v, 1), v.to_vec());
        assert_eq!(running_mean(&v, 3), vec![1.5, 2.0, 3.0, 4.0, 23.0, 32.5]);
        assert_eq!(running_mean(&[], 5), Vec::<f64>::new());
    }

    #[test]
    fn an_exact_line_is_recovered_exactly_and_bad_input_names_the_field() {
        let points: Vec<StrengthPoint> = [1e3, 3e3]
            .iter()
            .map(|&s| StrengthPoint {
                normal_stress_pa: s,
                shear_stress_pa: 1e3 + s * 0.5,
            })
            .collect();
        let fit = mohr_coulomb_fit(&points).unwrap();
        assert!((fit.cohesion_kpa - 1.0).abs() < 1e-12);
        assert!((fit.friction_angle_deg - 0.5f64.atan().to_degrees()).abs() < 1e-12);
        assert_eq!(fit.cohesion_std_error_kpa, None);
        let same = [points[0], points[0]];
        assert_eq!(
            mohr_coulomb_fit(&same),
            Err(ShearMeasureError::TooFewStresses(1))
        );
        let mut record = synthetic(1e4, 8e3, 6e3);
        record.shear_force_n.pop();
        let err = shear_strength(&record, 0.2).unwrap_err().to_string();
        assert!(err.starts_with("shear_force_n"), "{err}");
        let record = synthetic(1e4, 8e3, 6e3);
        let err = shear_strength(&record, 0.0).unwrap_err().to_string();
        assert!(err.starts_with("residual_fraction"), "{err}");
        // Peak and residual of a record with a known shape.
        let p = shear_strength(&record, 0.2).unwrap();
        assert!((p.peak_pa / 8e3 - 1.0).abs() < 0.02, "{p:?}");
        assert!((p.residual_pa / 6e3 - 1.0).abs() < 0.01, "{p:?}");
        assert!(p.peak_displacement_m > 1e-3 && p.peak_displacement_m < 3e-3);
    }
}
