//! When a heap is at rest, and how far from rest any heap was: the one stop rule of the funnel
//! and tube tests ([`rest_decision`], the criteria are documented on [`SettleSpec`]) and the
//! numbers every result carries ([`RestState`]: the angle's creep rate over the last checks,
//! their angle range and the last kinetic energy, each against its limit). Pure functions of
//! the checks, so a heap that creeps (constant-torque rolling friction can hold a heap in a
//! slow slump for seconds) is reported with numbers instead of a bare time cap, and a heap that
//! came to rest says how close to the limits it stopped.

use serde::{Deserialize, Serialize};

use super::run::SettleCheck;
use super::spec::SettleSpec;

/// How far from rest a heap was at its last check (every run that made a check has one).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RestState {
    /// Least-squares slope of the measured angle against time over the last checks, °/s
    /// (negative: the heap slumps). None if fewer than two of those checks had an angle.
    pub creep_deg_per_s: Option<f64>,
    /// Checks the slope was fitted over: the last [`SettleSpec::rest_checks`] checks that
    /// measured an angle.
    pub creep_checks: usize,
    /// Time span of those checks, s.
    pub creep_span_s: f64,
    /// `settle.max_creep_deg_per_s`: the largest creep of a heap at rest.
    pub max_creep_deg_per_s: f64,
    /// Spread (max − min) of the last `settle.angle_window` of those angles, degrees, against
    /// `angle_tolerance_deg`.
    pub angle_range_deg: Option<f64>,
    pub angle_tolerance_deg: f64,
    /// The last check's mean translational kinetic energy per grain / (m g d), against the
    /// threshold (rotation is left out: a grain spinning on its spot moves nothing).
    pub kinetic_energy_ratio: f64,
    pub kinetic_energy_threshold: f64,
    /// Grains that entered or left the heap region over the creep checks.
    pub heap_grains_changed: u64,
}

impl RestState {
    /// How far the last kinetic energy is above its threshold (1: at the threshold).
    pub fn kinetic_energy_over_threshold(&self) -> f64 {
        self.kinetic_energy_ratio / self.kinetic_energy_threshold
    }
}

impl std::fmt::Display for RestState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.creep_deg_per_s {
            Some(rate) => write!(
                f,
                "angle creeping at {rate:+.2}°/s over the last {} checks ({:.2} s; limit {:.2}°/s)",
                self.creep_checks, self.creep_span_s, self.max_creep_deg_per_s
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
            ", translational kinetic energy {:.2e} m g d ({:.2}× the threshold {:.1e})",
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

/// The first criterion of the rest rule a heap failed at a check (in the order
/// [`rest_decision`] tests them).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NotYet {
    /// Fewer checks than the rule looks at.
    TooFewChecks,
    /// A check in the window measured no angle.
    NoAngle,
    /// Grains entered or left the heap region within the window.
    GrainsChanged,
    /// The kinetic energy is at or above `settle.kinetic_energy_threshold`.
    KineticEnergy,
    /// The last `angle_window` angles spread more than `settle.angle_tolerance_deg`.
    AngleRange,
    /// The angle creeps faster than `settle.max_creep_deg_per_s`.
    Creep,
}

impl std::fmt::Display for NotYet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            NotYet::TooFewChecks => "too few checks to judge",
            NotYet::NoAngle => "no angle measured at some of the last checks",
            NotYet::GrainsChanged => "grains still entering or leaving the heap",
            NotYet::KineticEnergy => "translational kinetic energy above the threshold",
            NotYet::AngleRange => "angles spread beyond the tolerance",
            NotYet::Creep => "angle creeping faster than settle.max_creep_deg_per_s",
        })
    }
}

/// The stop rule's verdict at a check.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum RestDecision {
    AtRest,
    NotYet(NotYet),
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
/// [`SettleSpec::rest_checks`] checks that measured an angle, the spread of the last
/// `angle_window` of them, the last kinetic energy and the grains that changed region. None
/// when no check ran.
pub fn rest_state(checks: &[SettleCheck], settle: &SettleSpec) -> Option<RestState> {
    let last = checks.last()?;
    let recent: Vec<&SettleCheck> = checks
        .iter()
        .rev()
        .filter(|c| c.angle_deg.is_some())
        .take(settle.rest_checks())
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
    let tail = &points[points.len().saturating_sub(settle.angle_window.max(2))..];
    let angle_range_deg = (tail.len() >= 2).then(|| {
        let lo = tail.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        let hi = tail.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        hi - lo
    });
    let heap_grains_changed = recent
        .windows(2)
        .map(|w| w[0].on_base.abs_diff(w[1].on_base))
        .sum();
    Some(RestState {
        creep_deg_per_s: slope(&points),
        creep_checks: points.len(),
        creep_span_s: span,
        max_creep_deg_per_s: settle.max_creep_deg_per_s,
        angle_range_deg,
        angle_tolerance_deg: settle.angle_tolerance_deg,
        kinetic_energy_ratio: last.kinetic_energy_ratio,
        kinetic_energy_threshold: settle.kinetic_energy_threshold,
        heap_grains_changed,
    })
}

/// The stop rule (criteria and defaults on [`SettleSpec`]): at rest when the last
/// [`SettleSpec::rest_checks`] checks all measured an angle with the same grains in the heap
/// region, the last kinetic energy is below the threshold, the last `angle_window` angles lie
/// within the tolerance and the angle's creep slope over the window is within
/// `max_creep_deg_per_s`. Otherwise the first criterion that failed.
pub fn rest_decision(checks: &[SettleCheck], settle: &SettleSpec) -> RestDecision {
    let n = settle.rest_checks();
    if checks.len() < n {
        return RestDecision::NotYet(NotYet::TooFewChecks);
    }
    let window = &checks[checks.len() - n..];
    if window.iter().any(|c| c.angle_deg.is_none()) {
        return RestDecision::NotYet(NotYet::NoAngle);
    }
    if window.iter().any(|c| c.on_base != window[0].on_base) {
        return RestDecision::NotYet(NotYet::GrainsChanged);
    }
    // Every check of the window has an angle, so the state is fitted over exactly the window.
    let state = rest_state(window, settle).expect("the window is not empty");
    let below = state
        .kinetic_energy_ratio
        .partial_cmp(&settle.kinetic_energy_threshold);
    if below != Some(std::cmp::Ordering::Less) {
        return RestDecision::NotYet(NotYet::KineticEnergy);
    }
    if !state
        .angle_range_deg
        .is_some_and(|r| r <= settle.angle_tolerance_deg)
    {
        return RestDecision::NotYet(NotYet::AngleRange);
    }
    if !state
        .creep_deg_per_s
        .is_some_and(|c| c.abs() <= settle.max_creep_deg_per_s)
    {
        return RestDecision::NotYet(NotYet::Creep);
    }
    RestDecision::AtRest
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default rule with a creep window of `window_s` (0.2 s: the last three checks).
    fn settle_over(window_s: f64) -> SettleSpec {
        SettleSpec {
            creep_window_s: window_s,
            ..SettleSpec::default()
        }
    }

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
        // Window 3 (0.2 s), threshold 1e-4, tolerance 0.3°. The angle falls 8°/s at first, then 5°/s
        // over the last three checks.
        let settle = settle_over(0.2);
        let checks = [
            check(1.0, 9e-4, Some(40.0), 1000),
            check(1.1, 6e-4, Some(39.2), 1000),
            check(1.2, 5e-4, Some(38.7), 1000),
            check(1.3, 4e-4, Some(38.2), 1001),
            check(1.4, 3e-4, Some(37.7), 1003),
        ];
        let gap = rest_state(&checks, &settle).unwrap();
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
        assert!(text.contains("3.00× the threshold"), "{text}");
    }

    #[test]
    fn checks_without_an_angle_are_skipped_and_a_flat_sequence_has_zero_rate() {
        let settle = settle_over(0.2);
        let checks = [
            check(1.0, 2e-4, Some(30.0), 500),
            check(1.1, 2e-4, None, 500),
            check(1.2, 2e-4, Some(30.0), 500),
            check(1.3, 2e-4, Some(30.0), 500),
            check(1.4, 5e-4, None, 500),
        ];
        let gap = rest_state(&checks, &settle).unwrap();
        assert_eq!(gap.creep_deg_per_s, Some(0.0));
        assert_eq!(gap.creep_checks, 3);
        assert!((gap.creep_span_s - 0.3).abs() < 1e-12);
        // The kinetic energy is the very last check's, angle or not.
        assert_eq!(gap.kinetic_energy_ratio, 5e-4);
        assert_eq!(gap.heap_grains_changed, 0);
    }

    #[test]
    fn too_few_angles_give_no_rate_and_no_checks_give_nothing() {
        let settle = settle_over(0.2);
        assert_eq!(rest_state(&[], &settle), None);
        let gap = rest_state(
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
            ..settle_over(0.2)
        };
        let checks: Vec<SettleCheck> = (0..6)
            .map(|k| check(0.5 + 0.1 * k as f64, 1e-3, Some(20.0 + 0.4 * k as f64), 10))
            .collect();
        let gap = rest_state(&checks, &settle).unwrap();
        assert!((gap.creep_deg_per_s.unwrap() - 4.0).abs() < 1e-9);
        assert_eq!(gap.creep_checks, 4);
    }

    #[test]
    fn the_rule_looks_at_the_creep_window_or_the_angle_window_whichever_is_longer() {
        let s = SettleSpec::default();
        assert_eq!(s.rest_checks(), 6, "0.5 s at 0.1 s: six checks");
        assert_eq!(settle_over(0.2).rest_checks(), 3);
        assert_eq!(settle_over(0.05).rest_checks(), 3, "angle_window 3");
        let fine = SettleSpec {
            check_interval: 0.05,
            ..s
        };
        assert_eq!(fine.rest_checks(), 11);
        let odd = SettleSpec {
            creep_window_s: 0.45,
            ..s
        };
        assert_eq!(
            odd.rest_checks(),
            6,
            "a window not a whole number of intervals rounds up"
        );
    }

    /// Six checks 0.1 s apart from t = 2.0 s with the given angles and kinetic energies, 900
    /// grains in the heap region.
    fn sequence(angles: &[f64], ke: &[f64]) -> Vec<SettleCheck> {
        angles
            .iter()
            .zip(ke)
            .enumerate()
            .map(|(k, (&a, &e))| check(2.0 + 0.1 * k as f64, e, Some(a), 900))
            .collect()
    }

    #[test]
    fn a_heap_that_stands_still_is_at_rest_and_says_how_close() {
        let settle = SettleSpec::default();
        let checks = sequence(
            &[25.31, 25.25, 25.30, 25.27, 25.24, 25.28],
            &[4e-4, 9e-5, 5e-5, 3e-5, 2e-5, 2e-5],
        );
        assert_eq!(rest_decision(&checks, &settle), RestDecision::AtRest);
        let state = rest_state(&checks, &settle).unwrap();
        assert_eq!(state.creep_checks, 6);
        assert!((state.creep_span_s - 0.5).abs() < 1e-12);
        assert!(state.creep_deg_per_s.unwrap().abs() < 0.1, "{state}");
        assert!((state.angle_range_deg.unwrap() - 0.04).abs() < 1e-9);
        assert!((state.kinetic_energy_over_threshold() - 0.2).abs() < 1e-9);
        let text = state.to_string();
        assert!(text.contains("limit 0.50°/s"), "{text}");
        assert!(text.contains("0.20× the threshold"), "{text}");
    }

    #[test]
    fn a_slow_creep_within_the_limit_is_rest_and_reports_its_rate() {
        // −0.4°/s: 0.08° between the extremes of three checks, 0.2° over the window.
        let settle = SettleSpec::default();
        let angles: Vec<f64> = (0..6).map(|k| 30.0 - 0.04 * k as f64).collect();
        let checks = sequence(&angles, &[5e-5; 6]);
        assert_eq!(rest_decision(&checks, &settle), RestDecision::AtRest);
        let rate = rest_state(&checks, &settle)
            .unwrap()
            .creep_deg_per_s
            .unwrap();
        assert!((rate + 0.4).abs() < 1e-9, "{rate}");
    }

    #[test]
    fn a_creep_inside_the_angle_tolerance_but_too_fast_is_not_rest() {
        // −1.2°/s: the last three angles lie within 0.24° (the old angle_stable rule would have
        // stopped here) and the kinetic energy is low, but the slope over 0.5 s is 1.2°/s.
        let settle = SettleSpec::default();
        let angles: Vec<f64> = (0..6).map(|k| 30.0 - 0.12 * k as f64).collect();
        let checks = sequence(&angles, &[5e-5; 6]);
        assert_eq!(
            rest_decision(&checks, &settle),
            RestDecision::NotYet(NotYet::Creep)
        );
        let state = rest_state(&checks, &settle).unwrap();
        assert!(state.angle_range_deg.unwrap() <= settle.angle_tolerance_deg);
        assert!((state.creep_deg_per_s.unwrap() + 1.2).abs() < 1e-9);
    }

    #[test]
    fn each_criterion_can_hold_a_heap_back() {
        let settle = SettleSpec::default();
        let still = [25.0, 25.05, 25.0, 25.05, 25.0, 25.05];
        let quiet = [2e-5; 6];
        // Five checks are not enough for a 0.5 s window.
        assert_eq!(
            rest_decision(&sequence(&still[..5], &quiet[..5]), &settle),
            RestDecision::NotYet(NotYet::TooFewChecks)
        );
        // A check without an angle inside the window.
        let mut checks = sequence(&still, &quiet);
        checks[1].angle_deg = None;
        assert_eq!(
            rest_decision(&checks, &settle),
            RestDecision::NotYet(NotYet::NoAngle)
        );
        // ... but one before the window does not matter.
        let mut longer = vec![check(1.9, 1e-1, None, 700)];
        longer.extend(sequence(&still, &quiet));
        assert_eq!(rest_decision(&longer, &settle), RestDecision::AtRest);
        // A grain joins the heap region.
        let mut checks = sequence(&still, &quiet);
        checks[4].on_base += 1;
        checks[5].on_base += 1;
        assert_eq!(
            rest_decision(&checks, &settle),
            RestDecision::NotYet(NotYet::GrainsChanged)
        );
        // Kinetic energy at the threshold is not below it.
        let mut checks = sequence(&still, &quiet);
        checks[5].kinetic_energy_ratio = settle.kinetic_energy_threshold;
        assert_eq!(
            rest_decision(&checks, &settle),
            RestDecision::NotYet(NotYet::KineticEnergy)
        );
        // A jump in the last three angles.
        let mut checks = sequence(&still, &quiet);
        checks[4].angle_deg = Some(25.4);
        assert_eq!(
            rest_decision(&checks, &settle),
            RestDecision::NotYet(NotYet::AngleRange)
        );
    }

    /// The old rule: kinetic energy below the threshold, or the last `angle_window` angles
    /// within the tolerance with the same grains (kept here only to show what it did).
    fn old_rule_stops(checks: &[SettleCheck], settle: &SettleSpec) -> bool {
        let last = checks.last().unwrap();
        if last.kinetic_energy_ratio < settle.kinetic_energy_threshold {
            return true;
        }
        let recent = &checks[checks.len() - settle.angle_window..];
        let angles: Vec<f64> = recent.iter().map(|c| c.angle_deg.unwrap()).collect();
        let lo = angles.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = angles.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        recent.iter().all(|c| c.on_base == recent[0].on_base)
            && hi - lo <= settle.angle_tolerance_deg
    }

    #[test]
    fn the_paper_scale_slump_cut_by_the_old_angle_rule_is_not_rest() {
        // The checks of the paper-scale run at the calibrated point (docs/aor.md, issue 13):
        // the old rule ended it `angle_stable` at 26.41° (the last three within 0.29°) while
        // the angle fell about 3°/s.
        let settle = SettleSpec::default();
        let checks: Vec<SettleCheck> = [
            (5.07, 30.17, 1.1e-1),
            (5.17, 29.44, 1.7e-3),
            (5.27, 28.57, 5.7e-4),
            (5.37, 27.91, 3.2e-4),
            (5.47, 27.61, 2.9e-4),
            (5.57, 27.19, 4.1e-4),
            (5.67, 26.70, 1.6e-3),
            (5.77, 26.61, 2.0e-4),
            (5.87, 26.41, 1.8e-4),
        ]
        .iter()
        .map(|&(t, a, e)| check(t, e, Some(a), 26_884))
        .collect();
        assert!(old_rule_stops(&checks, &settle));
        assert_eq!(
            rest_decision(&checks, &settle),
            RestDecision::NotYet(NotYet::KineticEnergy)
        );
        let state = rest_state(&checks, &settle).unwrap();
        let rate = state.creep_deg_per_s.unwrap();
        // Σ(t − t̄)(θ − θ̄) / Σ(t − t̄)² over the last six checks: −0.5495°·s / 0.175 s².
        assert!((rate + 0.5495 / 0.175).abs() < 1e-9, "{rate}");
        assert!(state.to_string().contains("-3.14°/s"), "{state}");
        // The creep alone holds it back: with the kinetic energy ignored it still creeps.
        let lax = SettleSpec {
            kinetic_energy_threshold: 1.0,
            ..settle
        };
        assert_eq!(
            rest_decision(&checks, &lax),
            RestDecision::NotYet(NotYet::Creep)
        );
        // And no prefix of it was at rest either.
        for end in 1..=checks.len() {
            assert_ne!(rest_decision(&checks[..end], &settle), RestDecision::AtRest);
        }
    }

    #[test]
    fn the_100_g_slump_cut_by_the_old_kinetic_energy_rule_is_not_rest() {
        // The angles of the `mass-100g` run (docs/aor.md): 34.28° 0.1 s after the last grain
        // landed, then down at about −3.5°/s while the kinetic energy stayed at 1-3 × 10⁻⁴ m g d;
        // the old rule stopped when it dipped below 1e-4. The energies here are illustrative
        // values in that band (the run's own are not recorded in the docs).
        let settle = SettleSpec::default();
        let angles = [34.28, 33.23, 33.19, 32.83, 32.31, 31.79, 31.44];
        let ke = [3e-4, 2.4e-4, 1.8e-4, 2.6e-4, 1.3e-4, 1.1e-4, 0.9e-4];
        let checks: Vec<SettleCheck> = angles
            .iter()
            .zip(ke)
            .enumerate()
            .map(|(k, (&a, e))| check(4.0 + 0.1 * k as f64, e, Some(a), 8_961))
            .collect();
        assert!(old_rule_stops(&checks, &settle));
        assert_eq!(
            rest_decision(&checks, &settle),
            RestDecision::NotYet(NotYet::AngleRange)
        );
        let rate = rest_state(&checks, &settle)
            .unwrap()
            .creep_deg_per_s
            .unwrap();
        assert!((-4.0..-3.0).contains(&rate), "{rate}");
        // Wider tolerance: the creep still holds it back.
        let lax = SettleSpec {
            angle_tolerance_deg: 2.0,
            ..settle
        };
        assert_eq!(
            rest_decision(&checks, &lax),
            RestDecision::NotYet(NotYet::Creep)
        );
    }
}
