//! Path of steepest ascent / descent from a first-order model (Montgomery, *Design and Analysis
//! of Experiments*, §11.2).
//!
//! A fitted first-order model `ŷ = b0 + Σ b_i x_i` in coded units increases fastest along the
//! direction of its coefficient vector. Montgomery's recipe turns that into concrete runs:
//!
//! 1. choose the *base* factor — the one with the largest |b_i| — and a step of Δ coded units
//!    for it (usually Δ = 1, i.e. half its range);
//! 2. every other factor moves `Δ · b_i / |b_base|` coded units per step, which keeps the path
//!    parallel to the gradient;
//! 3. convert to natural units (multiply by the half-range) and walk from a start point.
//!
//! The coefficients are plain `f64` (one per factor, coded units) so this module does not depend
//! on the regression types in the rest of the crate.

use super::coding::check_lengths;
use super::{require_finite, DesignError, DesignResult, Factor};
use serde::{Deserialize, Serialize};

/// Whether the response should go up or down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PathDirection {
    /// Move along the gradient: the response rises.
    Ascent,
    /// Move against the gradient: the response falls.
    Descent,
}

impl PathDirection {
    /// +1 for ascent, -1 for descent.
    pub fn sign(self) -> f64 {
        match self {
            PathDirection::Ascent => 1.0,
            PathDirection::Descent => -1.0,
        }
    }
}

/// The direction that brings the response from `current_prediction` toward `target` — e.g. a
/// measured angle of repose of 35.6° when the model predicts 30° at the design centre gives
/// [`PathDirection::Ascent`]. Equal values have no direction and are reported as an error.
pub fn direction_toward(target: f64, current_prediction: f64) -> DesignResult<PathDirection> {
    let target = require_finite("target", target)?;
    let current = require_finite("current_prediction", current_prediction)?;
    if target > current {
        Ok(PathDirection::Ascent)
    } else if target < current {
        Ok(PathDirection::Descent)
    } else {
        Err(DesignError::invalid(
            "target",
            format!("equals current_prediction ({current}); there is no direction to move in"),
        ))
    }
}

/// Limits the path may not cross, per factor, in natural units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PathClamp {
    /// Let the path leave every range (pure extrapolation).
    #[default]
    Unbounded,
    /// Keep every factor within its `[low, high]` design range, as the paper does.
    FactorRange,
    /// Keep factor `i` within `bounds[i] = (min, max)`, e.g. physical limits wider than the
    /// screening range.
    Bounds(Vec<(f64, f64)>),
}

/// Everything needed to lay out a steepest-ascent/descent path. Build with [`SteepestPath::spec`]
/// and the chained setters, then call [`SteepestPathSpec::build`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SteepestPathSpec {
    /// First-order coefficients in coded units, one per factor (intercept excluded).
    pub coefficients: Vec<f64>,
    /// The factors the coefficients refer to, in the same order.
    pub factors: Vec<Factor>,
    /// Whether the response must rise or fall.
    pub direction: PathDirection,
    /// Start point in natural units; `None` starts at the design centre.
    pub start: Option<Vec<f64>>,
    /// Number of moves after the start point; the path has `steps + 1` points.
    pub steps: usize,
    /// Step of the base factor in coded units (Montgomery's Δ; 1 = half the base factor's range).
    pub base_step_coded: f64,
    /// Round every non-base factor's natural step to this many decimals. The base factor's
    /// step is the experimenter's chosen unit and is never rounded (the paper keeps N3's
    /// 0.195 while rounding N2's 0.0375 to 0.04 and N5's 0.0508 to 0.05).
    pub round_steps_to_decimals: Option<u32>,
    /// Bounds applied to every point, factor by factor, after stepping.
    pub clamp: PathClamp,
}

impl SteepestPathSpec {
    /// Starts at `start` (natural units) instead of the design centre.
    pub fn start_at(mut self, start: Vec<f64>) -> Self {
        self.start = Some(start);
        self
    }

    /// Sets the number of moves after the start point.
    pub fn steps(mut self, steps: usize) -> Self {
        self.steps = steps;
        self
    }

    /// Sets the base factor's step in coded units.
    pub fn base_step_coded(mut self, delta: f64) -> Self {
        self.base_step_coded = delta;
        self
    }

    /// Rounds the non-base steps to `decimals` decimals.
    pub fn round_steps_to(mut self, decimals: u32) -> Self {
        self.round_steps_to_decimals = Some(decimals);
        self
    }

    /// Sets the clamping policy.
    pub fn clamp(mut self, clamp: PathClamp) -> Self {
        self.clamp = clamp;
        self
    }

    /// Validates the inputs and computes the path.
    pub fn build(&self) -> DesignResult<SteepestPath> {
        let k = self.factors.len();
        if k == 0 {
            return Err(DesignError::invalid(
                "factors",
                "at least one factor is required",
            ));
        }
        for factor in &self.factors {
            factor.validate()?;
        }
        check_lengths("coefficients", k, self.coefficients.len())?;
        for (i, &b) in self.coefficients.iter().enumerate() {
            require_finite(format!("coefficients[{i}]"), b)?;
        }
        let base_factor = self
            .coefficients
            .iter()
            .enumerate()
            .fold(0, |best, (i, b)| {
                if b.abs() > self.coefficients[best].abs() {
                    i
                } else {
                    best
                }
            });
        let base_magnitude = self.coefficients[base_factor].abs();
        if base_magnitude == 0.0 {
            return Err(DesignError::invalid(
                "coefficients",
                "all coefficients are zero, so the model has no gradient to follow",
            ));
        }
        let delta = require_finite("base_step_coded", self.base_step_coded)?;
        if delta <= 0.0 {
            return Err(DesignError::invalid(
                "base_step_coded",
                format!("must be positive, got {delta}; choose the direction with `direction`"),
            ));
        }
        if let Some(decimals) = self.round_steps_to_decimals {
            if decimals > MAX_DECIMALS {
                return Err(DesignError::invalid(
                    "round_steps_to_decimals",
                    format!(
                        "at most {MAX_DECIMALS} decimals are meaningful in f64, got {decimals}"
                    ),
                ));
            }
        }

        let sign = self.direction.sign();
        let step_coded: Vec<f64> = self
            .coefficients
            .iter()
            .map(|&b| sign * delta * b / base_magnitude)
            .collect();
        let step_natural: Vec<f64> = step_coded
            .iter()
            .zip(&self.factors)
            .enumerate()
            .map(|(i, (&dx, factor))| {
                let natural = dx * factor.half_range();
                match self.round_steps_to_decimals {
                    Some(decimals) if i != base_factor => round_to_decimals(natural, decimals),
                    _ => natural,
                }
            })
            .collect();

        let start = match &self.start {
            Some(start) => {
                check_lengths("start", k, start.len())?;
                for (i, &x) in start.iter().enumerate() {
                    require_finite(format!("start[{i}]"), x)?;
                }
                start.clone()
            }
            None => self.factors.iter().map(Factor::centre).collect(),
        };
        let bounds = self.resolved_bounds()?;
        if let Some(bounds) = &bounds {
            for (i, (&x, &(min, max))) in start.iter().zip(bounds).enumerate() {
                if x < min || x > max {
                    return Err(DesignError::invalid(
                        format!("start[{i}]"),
                        format!(
                            "{x} lies outside the clamp bounds [{min}, {max}] for `{}`",
                            self.factors[i].name
                        ),
                    ));
                }
            }
        }

        let points: Vec<Vec<f64>> = (0..=self.steps)
            .map(|n| {
                (0..k)
                    .map(|i| {
                        let x = start[i] + n as f64 * step_natural[i];
                        match &bounds {
                            Some(bounds) => x.clamp(bounds[i].0, bounds[i].1),
                            None => x,
                        }
                    })
                    .collect()
            })
            .collect();
        let coded_points = points
            .iter()
            .map(|p| super::to_coded(&self.factors, p))
            .collect::<DesignResult<Vec<_>>>()?;

        Ok(SteepestPath {
            factor_names: self.factors.iter().map(|f| f.name.clone()).collect(),
            base_factor,
            step_coded,
            step_natural,
            points,
            coded_points,
        })
    }

    fn resolved_bounds(&self) -> DesignResult<Option<Vec<(f64, f64)>>> {
        match &self.clamp {
            PathClamp::Unbounded => Ok(None),
            PathClamp::FactorRange => {
                Ok(Some(self.factors.iter().map(|f| (f.low, f.high)).collect()))
            }
            PathClamp::Bounds(bounds) => {
                check_lengths("clamp bounds", self.factors.len(), bounds.len())?;
                for (i, &(min, max)) in bounds.iter().enumerate() {
                    require_finite(format!("bounds[{i}].min"), min)?;
                    require_finite(format!("bounds[{i}].max"), max)?;
                    if min > max {
                        return Err(DesignError::invalid(
                            format!("bounds[{i}]"),
                            format!("min ({min}) exceeds max ({max})"),
                        ));
                    }
                }
                Ok(Some(bounds.clone()))
            }
        }
    }
}

/// A computed path: the per-step increments and the points to simulate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SteepestPath {
    /// Factor names, in the order of every vector below.
    pub factor_names: Vec<String>,
    /// Index of the factor with the largest |coefficient|.
    pub base_factor: usize,
    /// Increment per step in coded units (before rounding in natural units).
    pub step_coded: Vec<f64>,
    /// Increment per step in natural units (after any rounding).
    pub step_natural: Vec<f64>,
    /// `steps + 1` points in natural units, the start first, each clamped if requested.
    pub points: Vec<Vec<f64>>,
    /// The same points in coded units, for predicting the response along the path.
    pub coded_points: Vec<Vec<f64>>,
}

impl SteepestPath {
    /// A specification with defaults: start at the centre, 5 steps, Δ = 1 coded unit for the
    /// base factor, no rounding, no clamping.
    pub fn spec(
        coefficients: Vec<f64>,
        factors: Vec<Factor>,
        direction: PathDirection,
    ) -> SteepestPathSpec {
        SteepestPathSpec {
            coefficients,
            factors,
            direction,
            start: None,
            steps: 5,
            base_step_coded: 1.0,
            round_steps_to_decimals: None,
            clamp: PathClamp::Unbounded,
        }
    }
}

/// More decimals than f64 can resolve for values of order one would only add noise.
const MAX_DECIMALS: u32 = 15;

/// Rounds half away from zero to `decimals` decimals, treating values within 1e-9 (in units of
/// the last kept decimal) of a half as the half.
///
/// The tolerance exists because inputs such as 0.0375 are not representable in binary and
/// arrive as 0.037499999…; a hand calculation (and the paper) rounds them up to 0.04.
pub fn round_to_decimals(value: f64, decimals: u32) -> f64 {
    let scale = 10f64.powi(decimals.min(MAX_DECIMALS) as i32);
    let scaled = value * scale;
    let snapped = (scaled * 1e9).round() / 1e9;
    snapped.round() / scale
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_factors() -> Vec<Factor> {
        vec![
            Factor::new("a", 0.0, 2.0).unwrap(),
            Factor::new("b", 10.0, 20.0).unwrap(),
        ]
    }

    #[test]
    fn direction_follows_the_sign_of_the_gap() {
        assert_eq!(direction_toward(35.6, 30.0).unwrap(), PathDirection::Ascent);
        assert_eq!(
            direction_toward(20.0, 30.0).unwrap(),
            PathDirection::Descent
        );
        let err = direction_toward(30.0, 30.0).unwrap_err();
        assert!(err.to_string().contains("target"), "{err}");
        assert!(direction_toward(f64::NAN, 1.0).is_err());
    }

    #[test]
    fn descent_moves_against_the_gradient_from_the_centre() {
        let path = SteepestPath::spec(vec![1.0, -2.0], two_factors(), PathDirection::Descent)
            .steps(2)
            .build()
            .unwrap();
        assert_eq!(path.base_factor, 1);
        // base factor b: Δ = 1 coded unit = 5 natural, moved against b's negative coefficient.
        assert_eq!(path.step_natural, vec![-0.5, 5.0]);
        assert_eq!(path.points[0], vec![1.0, 15.0]);
        assert_eq!(path.points[2], vec![0.0, 25.0]);
        assert_eq!(path.coded_points[2], vec![-1.0, 2.0]);
    }

    #[test]
    fn bad_inputs_name_the_parameter() {
        let spec = |coefficients: Vec<f64>| {
            SteepestPath::spec(coefficients, two_factors(), PathDirection::Ascent)
        };
        let msg = |r: DesignResult<SteepestPath>| r.unwrap_err().to_string();
        assert!(msg(spec(vec![1.0]).build()).contains("coefficients"));
        assert!(msg(spec(vec![0.0, 0.0]).build()).contains("coefficients"));
        assert!(msg(spec(vec![1.0, f64::NAN]).build()).contains("coefficients[1]"));
        assert!(msg(spec(vec![1.0, 1.0]).start_at(vec![1.0]).build()).contains("start"));
        assert!(msg(spec(vec![1.0, 1.0]).base_step_coded(0.0).build()).contains("base_step_coded"));
        assert!(msg(spec(vec![1.0, 1.0])
            .start_at(vec![3.0, 15.0])
            .clamp(PathClamp::FactorRange)
            .build())
        .contains("start[0]"));
        assert!(msg(spec(vec![1.0, 1.0])
            .clamp(PathClamp::Bounds(vec![(0.0, 1.0), (5.0, 4.0)]))
            .build())
        .contains("bounds[1]"));
    }

    #[test]
    fn rounding_treats_binary_noise_at_a_half_as_the_half() {
        assert_eq!(round_to_decimals(0.0375, 2), 0.04);
        assert_eq!(round_to_decimals(2.30 / 7.36 * 0.12, 2), 0.04);
        assert_eq!(round_to_decimals(0.0508, 2), 0.05);
        assert_eq!(round_to_decimals(-0.0375, 2), -0.04);
        assert_eq!(round_to_decimals(0.0349, 2), 0.03);
    }
}
