//! How far from rest a heap was when a run ended without coming to rest: the angle's creep rate
//! over the last at-rest checks and the last kinetic energy against the threshold. A pure
//! function of the checks, so a heap that creeps (constant-torque rolling friction can hold a
//! heap in a slow slump for seconds) is reported with numbers instead of a bare time cap.

use serde::{Deserialize, Serialize};

use super::run::SettleCheck;
use super::spec::SettleSpec;

/// The state of a heap that did not come to rest, from its last checks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NotAtRest {
    /// Least-squares slope of the measured angle against time over the last checks, °/s
    /// (negative: the heap slumps). None if fewer than two of those checks had an angle.
    pub creep_deg_per_s: Option<f64>,
    /// Checks the slope was fitted over (the last `settle.angle_window` checks that measured
    /// an angle).
    pub creep_checks: usize,
    /// Time span of those checks, s.
    pub creep_span_s: f64,
    /// Spread (max − min) of their angles, degrees, against `angle_tolerance_deg`.
    pub angle_range_deg: Option<f64>,
    pub angle_tolerance_deg: f64,
    /// The last check's mean kinetic energy per grain / (m g d), against the threshold.
    pub kinetic_energy_ratio: f64,
    pub kinetic_energy_threshold: f64,
    /// Grains that entered or left the heap region over those checks.
    pub heap_grains_changed: u64,
}

impl NotAtRest {
    /// How far the last kinetic energy is above its threshold (1: at the threshold).
    pub fn kinetic_energy_over_threshold(&self) -> f64 {
        self.kinetic_energy_ratio / self.kinetic_energy_threshold
    }
}

impl std::fmt::Display for NotAtRest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.creep_deg_per_s {
            Some(rate) => write!(
                f,
                "angle creeping at {rate:+.2}°/s over the last {} checks ({:.2} s)",
                self.creep_checks, self.creep_span_s
            )?,
            None => write!(f, "no angle to follow over the last checks")?,
        }
        if let Some(range) = self.angle_range_deg {
            write!(
                f,
                ", range {range:.2}° (tolerance {:.2}°)",
                self.angle_tolerance_deg
            )?;
        }
        write!(
            f,
            ", kinetic energy {:.2e} m g d ({:.1}× the threshold {:.1e})",
            self.kinetic_energy_ratio,
            self.kinetic_energy_over_threshold(),
            self.kinetic_energy_threshold
        )?;
        if self.heap_grains_changed > 0 {
            write!(
                f,
                ", {} grains entered or left the heap",
                self.heap_grains_changed
            )?;
        }
        Ok(())
    }
}

/// Least-squares slope of y against t; None for fewer than two points or no spread in t.
fn slope(points: &[(f64, f64)]) -> Option<f64> {
    if points.len() < 2 {
        return None;
    }
    let n = points.len() as f64;
    let t_mean = points.iter().map(|p| p.0).sum::<f64>() / n;
    let y_mean = points.iter().map(|p| p.1).sum::<f64>() / n;
    let (mut sty, mut stt) = (0.0, 0.0);
    for &(t, y) in points {
        sty += (t - t_mean) * (y - y_mean);
        stt += (t - t_mean) * (t - t_mean);
    }
    (stt > 0.0).then(|| sty / stt)
}

/// How far from rest the heap was at its last check: the angle's slope over the last
/// `settle.angle_window` checks that measured an angle, their spread, the last kinetic energy
/// and the grains that changed region. None when no check ran.
pub fn not_at_rest(checks: &[SettleCheck], settle: &SettleSpec) -> Option<NotAtRest> {
    let last = checks.last()?;
    let window = settle.angle_window.max(2);
    let recent: Vec<&SettleCheck> = checks
        .iter()
        .rev()
        .filter(|c| c.angle_deg.is_some())
        .take(window)
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    let points: Vec<(f64, f64)> = recent
        .iter()
        .filter_map(|c| c.angle_deg.map(|a| (c.time, a)))
        .collect();
    let span = match (recent.first(), recent.last()) {
        (Some(a), Some(b)) => b.time - a.time,
        _ => 0.0,
    };
    let angle_range_deg = (points.len() >= 2).then(|| {
        let lo = points.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        let hi = points.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        hi - lo
    });
    let heap_grains_changed = recent
        .windows(2)
        .map(|w| w[0].on_base.abs_diff(w[1].on_base))
        .sum();
    Some(NotAtRest {
        creep_deg_per_s: slope(&points),
        creep_checks: points.len(),
        creep_span_s: span,
        angle_range_deg,
        angle_tolerance_deg: settle.angle_tolerance_deg,
        kinetic_energy_ratio: last.kinetic_energy_ratio,
        kinetic_energy_threshold: settle.kinetic_energy_threshold,
        heap_grains_changed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(time: f64, ke: f64, angle: Option<f64>, on_base: u64) -> SettleCheck {
        SettleCheck {
            time,
            kinetic_energy_ratio: ke,
            angle_deg: angle,
            on_base,
        }
    }

    #[test]
    fn a_slumping_heap_reports_its_rate_over_the_last_window() {
        // Window 3, threshold 1e-4, tolerance 0.3°. The angle falls 8°/s at first, then 5°/s
        // over the last three checks.
        let settle = SettleSpec::default();
        let checks = [
            check(1.0, 9e-4, Some(40.0), 1000),
            check(1.1, 6e-4, Some(39.2), 1000),
            check(1.2, 5e-4, Some(38.7), 1000),
            check(1.3, 4e-4, Some(38.2), 1001),
            check(1.4, 3e-4, Some(37.7), 1003),
        ];
        let gap = not_at_rest(&checks, &settle).unwrap();
        let rate = gap.creep_deg_per_s.unwrap();
        assert!((rate + 5.0).abs() < 1e-9, "{rate}");
        assert_eq!(gap.creep_checks, 3);
        assert!((gap.creep_span_s - 0.2).abs() < 1e-12);
        assert!((gap.angle_range_deg.unwrap() - 1.0).abs() < 1e-9);
        assert_eq!(gap.kinetic_energy_ratio, 3e-4);
        assert!((gap.kinetic_energy_over_threshold() - 3.0).abs() < 1e-9);
        assert_eq!(gap.heap_grains_changed, 3);
        let text = gap.to_string();
        assert!(text.contains("-5.00°/s"), "{text}");
        assert!(text.contains("3.0× the threshold"), "{text}");
    }

    #[test]
    fn checks_without_an_angle_are_skipped_and_a_flat_sequence_has_zero_rate() {
        let settle = SettleSpec::default();
        let checks = [
            check(1.0, 2e-4, Some(30.0), 500),
            check(1.1, 2e-4, None, 500),
            check(1.2, 2e-4, Some(30.0), 500),
            check(1.3, 2e-4, Some(30.0), 500),
            check(1.4, 5e-4, None, 500),
        ];
        let gap = not_at_rest(&checks, &settle).unwrap();
        assert_eq!(gap.creep_deg_per_s, Some(0.0));
        assert_eq!(gap.creep_checks, 3);
        assert!((gap.creep_span_s - 0.3).abs() < 1e-12);
        // The kinetic energy is the very last check's, angle or not.
        assert_eq!(gap.kinetic_energy_ratio, 5e-4);
        assert_eq!(gap.heap_grains_changed, 0);
    }

    #[test]
    fn too_few_angles_give_no_rate_and_no_checks_give_nothing() {
        let settle = SettleSpec::default();
        assert_eq!(not_at_rest(&[], &settle), None);
        let gap = not_at_rest(
            &[check(1.0, 1e-3, None, 0), check(1.1, 1e-3, Some(20.0), 4)],
            &settle,
        )
        .unwrap();
        assert_eq!(gap.creep_deg_per_s, None);
        assert_eq!(gap.angle_range_deg, None);
        assert_eq!(gap.creep_checks, 1);
        assert!(gap.to_string().starts_with("no angle"), "{gap}");
    }

    #[test]
    fn a_rising_angle_is_a_positive_rate() {
        let settle = SettleSpec {
            angle_window: 4,
            ..SettleSpec::default()
        };
        let checks: Vec<SettleCheck> = (0..6)
            .map(|k| check(0.5 + 0.1 * k as f64, 1e-3, Some(20.0 + 0.4 * k as f64), 10))
            .collect();
        let gap = not_at_rest(&checks, &settle).unwrap();
        assert!((gap.creep_deg_per_s.unwrap() - 4.0).abs() < 1e-9);
        assert_eq!(gap.creep_checks, 4);
    }
}
