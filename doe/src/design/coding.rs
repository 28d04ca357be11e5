//! Conversion between coded units (-1 … +1) and natural units (the DEM parameter's own scale).
//!
//! The map is the usual linear one, `natural = centre + coded * half_range`, so coded -1 is
//! the factor's low level, +1 its high level and 0 the midpoint. Coded values outside ±1
//! (central-composite star points, steepest-ascent steps) extrapolate along the same line.

use super::{require_finite, DesignError, DesignResult};
use serde::{Deserialize, Serialize};

/// A design factor: a named parameter and the natural values that coded -1 and +1 stand for.
///
/// Fields are public so the command line can build factors from a config file; every
/// conversion re-validates them, so an invalid factor is reported, never silently used.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Factor {
    /// Parameter name, e.g. `N2`.
    pub name: String,
    /// Natural value coded as -1.
    pub low: f64,
    /// Natural value coded as +1.
    pub high: f64,
}

impl Factor {
    /// A validated factor: `low` and `high` finite and `low < high`.
    pub fn new(name: impl Into<String>, low: f64, high: f64) -> DesignResult<Self> {
        let factor = Factor {
            name: name.into(),
            low,
            high,
        };
        factor.validate()?;
        Ok(factor)
    }

    /// Checks the range, so that coding neither divides by zero nor flips the sign of effects.
    pub fn validate(&self) -> DesignResult<()> {
        if self.name.trim().is_empty() {
            return Err(DesignError::invalid("factor.name", "name is empty"));
        }
        require_finite(format!("factor `{}`.low", self.name), self.low)?;
        require_finite(format!("factor `{}`.high", self.name), self.high)?;
        if self.low >= self.high {
            return Err(DesignError::InvalidFactorRange {
                factor: self.name.clone(),
                low: self.low,
                high: self.high,
            });
        }
        Ok(())
    }

    /// Natural value at coded 0.
    pub fn centre(&self) -> f64 {
        0.5 * (self.low + self.high)
    }

    /// Natural distance corresponding to one coded unit.
    pub fn half_range(&self) -> f64 {
        0.5 * (self.high - self.low)
    }

    /// Coded → natural.
    pub fn to_natural(&self, coded: f64) -> DesignResult<f64> {
        self.validate()?;
        let coded = require_finite(format!("coded value for `{}`", self.name), coded)?;
        // Weighted form rather than `centre + coded * half_range` so that coded ±1 give
        // exactly `low`/`high` (0.01, not 0.010000000000000009) for the DEM input files.
        Ok(0.5 * ((1.0 - coded) * self.low + (1.0 + coded) * self.high))
    }

    /// Natural → coded.
    pub fn to_coded(&self, natural: f64) -> DesignResult<f64> {
        self.validate()?;
        let natural = require_finite(format!("natural value for `{}`", self.name), natural)?;
        // Same reason: `low` and `high` code to exactly -1 and +1.
        Ok(((natural - self.low) - (self.high - natural)) / (self.high - self.low))
    }
}

/// Converts one coded run to natural units; `factors` gives one factor per value.
pub fn to_natural(factors: &[Factor], coded_run: &[f64]) -> DesignResult<Vec<f64>> {
    check_lengths("coded_run", factors.len(), coded_run.len())?;
    coded_run
        .iter()
        .zip(factors)
        .map(|(&coded, factor)| factor.to_natural(coded))
        .collect()
}

/// Converts one natural run to coded units; `factors` gives one factor per value.
pub fn to_coded(factors: &[Factor], natural_run: &[f64]) -> DesignResult<Vec<f64>> {
    check_lengths("natural_run", factors.len(), natural_run.len())?;
    natural_run
        .iter()
        .zip(factors)
        .map(|(&natural, factor)| factor.to_coded(natural))
        .collect()
}

/// Error unless a vector has the length its factors require.
pub(crate) fn check_lengths(parameter: &str, expected: usize, actual: usize) -> DesignResult<()> {
    if expected == actual {
        Ok(())
    } else {
        Err(DesignError::LengthMismatch {
            parameter: parameter.into(),
            expected,
            actual,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_and_centre_map_to_the_natural_range() {
        let n3 = Factor::new("N3", 0.01, 0.40).unwrap();
        assert_eq!(n3.to_natural(-1.0).unwrap(), 0.01);
        assert_eq!(n3.to_natural(1.0).unwrap(), 0.40);
        assert_eq!(n3.to_coded(0.01).unwrap(), -1.0);
        assert_eq!(n3.to_coded(0.40).unwrap(), 1.0);
        assert!((n3.to_natural(0.0).unwrap() - 0.205).abs() < 1e-15);
        assert!((n3.to_coded(0.205).unwrap()).abs() < 1e-12);
    }

    #[test]
    fn reversed_or_empty_ranges_are_rejected_with_the_factor_name() {
        let err = Factor::new("N2", 0.68, 0.44).unwrap_err();
        assert!(err.to_string().contains("N2"), "{err}");
        assert!(Factor::new("N2", 0.5, 0.5).is_err());
        assert!(Factor::new("N2", f64::NAN, 0.5).is_err());
        // A factor built by hand with bad fields is still caught at conversion time.
        let bad = Factor {
            name: "N5".into(),
            low: 1.0,
            high: 0.0,
        };
        assert!(bad.to_natural(0.0).is_err());
    }

    #[test]
    fn non_finite_values_are_rejected() {
        let f = Factor::new("N1", 0.0, 1.0).unwrap();
        assert!(f.to_natural(f64::INFINITY).is_err());
        assert!(f.to_coded(f64::NAN).is_err());
    }

    #[test]
    fn run_conversion_checks_lengths() {
        let factors = vec![Factor::new("a", 0.0, 1.0).unwrap()];
        let err = to_natural(&factors, &[0.0, 1.0]).unwrap_err();
        assert!(err.to_string().contains("coded_run"), "{err}");
    }
}
