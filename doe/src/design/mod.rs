//! Experimental designs: which factor settings to simulate, in which order, with which seeds.
//!
//! Every design is produced in *coded* units (low = -1, high = +1, centre = 0) because the
//! classical constructions (factorial, Plackett–Burman, Box–Behnken, central composite) and
//! their optimality properties are defined there; [`Factor`] maps coded values to the natural
//! units a DEM simulation needs. Generated designs are listed in *standard order*; call
//! [`Design::randomized`] for a seeded run order and [`replicate`] for per-run RNG seeds.
//!
//! Nothing here performs I/O, panics on bad input, or depends on the regression half of the
//! crate: inputs that come from a fit (the steepest-ascent coefficients) are plain `f64`s.
//!
//! ```
//! use repose_doe::design::{box_behnken, replicate, Factor, PathClamp, PathDirection, SteepestPath};
//!
//! // The paper's Box–Behnken design: 3 factors, 12 edge runs + 5 centre points.
//! let factors = vec![
//!     Factor::new("N2", 0.44, 0.68)?,
//!     Factor::new("N3", 0.01, 0.40)?,
//!     Factor::new("N5", 0.30, 0.70)?,
//! ];
//! let design = box_behnken(&["N2", "N3", "N5"], 5)?.randomized(2026);
//! let natural = design.natural_runs(&factors)?;
//! assert_eq!(natural.len(), 17);
//! let runs = replicate(&design, 2, 7)?; // 34 runs, each with its own DEM seed
//! assert_eq!(runs.len(), 34);
//!
//! // The paper's steepest-ascent path (Eqs. 13-15, Table 5).
//! let path = SteepestPath::spec(vec![2.30, 7.36, 1.87], factors, PathDirection::Ascent)
//!     .start_at(vec![0.44, 0.01, 0.30])
//!     .steps(4)
//!     .round_steps_to(2)
//!     .clamp(PathClamp::FactorRange)
//!     .build()?;
//! assert!((path.points[4][1] - 0.40).abs() < 1e-12); // N3 held at its upper bound
//! # Ok::<(), repose_doe::design::DesignError>(())
//! ```

mod box_behnken;
mod ccd;
mod coding;
mod factorial;
mod plackett_burman;
mod randomize;
mod steepest;

pub use box_behnken::{box_behnken, default_box_behnken_centre_points};
pub use ccd::{central_composite, rotatable_alpha, CcdVariant};
pub use coding::{to_coded, to_natural, Factor};
pub use factorial::{full_factorial, MAX_FULL_FACTORIAL_FACTORS};
pub use plackett_burman::{
    plackett_burman, smallest_plackett_burman_runs, PLACKETT_BURMAN_RUN_SIZES,
};
pub use randomize::{
    next_seed, random_run_order, replicate, shuffle_with_seed, splitmix64, ReplicatedRun,
};
pub use steepest::{
    direction_toward, round_to_decimals, PathClamp, PathDirection, SteepestPath, SteepestPathSpec,
};

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

/// Everything that can go wrong when building or using a design.
///
/// Every variant names the offending parameter (as the caller would spell it, e.g.
/// `runs`, `rows[3][1]`, `factors[0].low`) so a command-line user can fix the input
/// without reading the source.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DesignError {
    /// A parameter has a value outside what the construction supports.
    #[error("invalid `{parameter}`: {reason}")]
    InvalidParameter {
        /// Name of the parameter, e.g. `runs` or `factor_names[2]`.
        parameter: String,
        /// Why it was rejected.
        reason: String,
    },
    /// A numeric input was NaN or infinite.
    #[error("`{parameter}` must be finite, got {value}")]
    NonFinite {
        /// Name of the parameter, e.g. `rows[3][1]`.
        parameter: String,
        /// The rejected value.
        value: f64,
    },
    /// Two inputs that must line up (one value per factor, one row length) do not.
    #[error("`{parameter}` must have {expected} entries, got {actual}")]
    LengthMismatch {
        /// Name of the parameter whose length is wrong.
        parameter: String,
        /// The required length.
        expected: usize,
        /// The length that was supplied.
        actual: usize,
    },
    /// A factor's natural range is empty or reversed, so coding would divide by zero or flip signs.
    #[error("factor `{factor}`: low ({low}) must be strictly less than high ({high})")]
    InvalidFactorRange {
        /// The factor's name.
        factor: String,
        /// The supplied low level.
        low: f64,
        /// The supplied high level.
        high: f64,
    },
}

impl DesignError {
    pub(crate) fn invalid(parameter: impl Into<String>, reason: impl Into<String>) -> Self {
        Self::InvalidParameter {
            parameter: parameter.into(),
            reason: reason.into(),
        }
    }
}

/// Shorthand used throughout the design module.
pub type DesignResult<T> = Result<T, DesignError>;

/// Which construction produced a design; kept so reports and fits can say what was run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum DesignKind {
    /// Two-level full factorial, 2^k runs.
    FullFactorial,
    /// Plackett–Burman screening design with the given number of runs.
    PlackettBurman {
        /// Number of runs (8, 12, 16, 20 or 24).
        runs: usize,
    },
    /// Box–Behnken response-surface design.
    BoxBehnken {
        /// Number of centre-point runs appended after the edge runs.
        centre_points: usize,
    },
    /// Central composite design.
    CentralComposite {
        /// Circumscribed, face-centred or inscribed.
        variant: CcdVariant,
        /// Distance of the star points from the centre in the *un-scaled* design
        /// (for inscribed designs the stored factorial points are divided by it).
        alpha: f64,
        /// Number of centre-point runs appended at the end.
        centre_points: usize,
    },
    /// A run matrix supplied by the user.
    Custom,
}

/// A run matrix in coded units together with the names of its factors.
///
/// Rows are runs, columns are factors. `standard_order[i]` is the position run `i` had when the
/// design was generated, so a randomised design can still be related to its textbook layout.
/// Deserialisation re-validates everything, so a hand-edited JSON file cannot smuggle in a
/// ragged or non-finite matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "DesignRepr")]
pub struct Design {
    kind: DesignKind,
    factor_names: Vec<String>,
    coded_runs: Vec<Vec<f64>>,
    standard_order: Vec<usize>,
}

/// Unvalidated mirror of [`Design`] used only as the deserialisation source.
#[derive(Deserialize)]
struct DesignRepr {
    kind: DesignKind,
    factor_names: Vec<String>,
    coded_runs: Vec<Vec<f64>>,
    standard_order: Vec<usize>,
}

impl TryFrom<DesignRepr> for Design {
    type Error = DesignError;

    fn try_from(repr: DesignRepr) -> DesignResult<Self> {
        let design = Design::new(repr.kind, &repr.factor_names, repr.coded_runs)?;
        validate_permutation("standard_order", &repr.standard_order, design.run_count())?;
        Ok(Design {
            standard_order: repr.standard_order,
            ..design
        })
    }
}

impl Design {
    /// Builds a validated design in standard order. Used by every generator.
    pub(crate) fn new<S: AsRef<str>>(
        kind: DesignKind,
        factor_names: &[S],
        coded_runs: Vec<Vec<f64>>,
    ) -> DesignResult<Self> {
        let factor_names = validate_factor_names(factor_names)?;
        validate_run_matrix(&coded_runs, factor_names.len())?;
        let standard_order = (0..coded_runs.len()).collect();
        Ok(Design {
            kind,
            factor_names,
            coded_runs,
            standard_order,
        })
    }

    /// A user-supplied run matrix in coded units.
    ///
    /// Rejected unless there is at least one factor and one run, every row has one value per
    /// factor, every value is finite and the factor names are non-empty and distinct.
    pub fn custom<S: AsRef<str>>(
        factor_names: &[S],
        coded_runs: Vec<Vec<f64>>,
    ) -> DesignResult<Self> {
        Self::new(DesignKind::Custom, factor_names, coded_runs)
    }

    /// A user-supplied run matrix in natural units, coded through `factors`.
    pub fn custom_natural(factors: &[Factor], natural_runs: &[Vec<f64>]) -> DesignResult<Self> {
        if factors.is_empty() {
            return Err(DesignError::invalid(
                "factors",
                "at least one factor is required",
            ));
        }
        validate_run_matrix(natural_runs, factors.len())?;
        let coded = natural_runs
            .iter()
            .map(|row| {
                row.iter()
                    .zip(factors)
                    .map(|(&value, factor)| factor.to_coded(value))
                    .collect::<DesignResult<Vec<f64>>>()
            })
            .collect::<DesignResult<Vec<_>>>()?;
        let names: Vec<&str> = factors.iter().map(|f| f.name.as_str()).collect();
        Self::custom(&names, coded)
    }

    /// How the design was constructed.
    pub fn kind(&self) -> DesignKind {
        self.kind
    }

    /// Factor names, one per column.
    pub fn factor_names(&self) -> &[String] {
        &self.factor_names
    }

    /// Number of factors (columns).
    pub fn factor_count(&self) -> usize {
        self.factor_names.len()
    }

    /// Number of runs (rows).
    pub fn run_count(&self) -> usize {
        self.coded_runs.len()
    }

    /// All runs in coded units, in the design's current run order.
    pub fn coded_runs(&self) -> &[Vec<f64>] {
        &self.coded_runs
    }

    /// For each run, its index in the standard (generated) order.
    pub fn standard_order(&self) -> &[usize] {
        &self.standard_order
    }

    /// The coded runs as an `n × k` matrix, ready to build a model matrix from.
    pub fn to_matrix(&self) -> DMatrix<f64> {
        DMatrix::from_fn(self.run_count(), self.factor_count(), |r, c| {
            self.coded_runs[r][c]
        })
    }

    /// Renames the factors, e.g. to turn generated `x1..xk` into DEM parameter names.
    pub fn with_factor_names<S: AsRef<str>>(self, factor_names: &[S]) -> DesignResult<Self> {
        if factor_names.len() != self.factor_count() {
            return Err(DesignError::LengthMismatch {
                parameter: "factor_names".into(),
                expected: self.factor_count(),
                actual: factor_names.len(),
            });
        }
        Ok(Design {
            factor_names: validate_factor_names(factor_names)?,
            ..self
        })
    }

    /// The runs in natural units.
    ///
    /// `factors` must list the design's factors in column order with matching names; the
    /// name check exists because silently swapping two ranges would simulate the wrong soil.
    pub fn natural_runs(&self, factors: &[Factor]) -> DesignResult<Vec<Vec<f64>>> {
        self.check_factors_match(factors)?;
        self.coded_runs
            .iter()
            .map(|row| {
                row.iter()
                    .zip(factors)
                    .map(|(&coded, factor)| factor.to_natural(coded))
                    .collect()
            })
            .collect()
    }

    /// A copy with the runs in a random order that depends only on `seed`.
    ///
    /// Randomising the order guards physical experiments against drift; for deterministic DEM
    /// runs it mostly matters when runs share a machine whose state could leak between runs,
    /// but it is cheap and keeps the workflow identical to the paper's.
    pub fn randomized(&self, seed: u64) -> Design {
        let order = random_run_order(self.run_count(), seed);
        Design {
            kind: self.kind,
            factor_names: self.factor_names.clone(),
            coded_runs: order.iter().map(|&i| self.coded_runs[i].clone()).collect(),
            standard_order: order.iter().map(|&i| self.standard_order[i]).collect(),
        }
    }

    fn check_factors_match(&self, factors: &[Factor]) -> DesignResult<()> {
        if factors.len() != self.factor_count() {
            return Err(DesignError::LengthMismatch {
                parameter: "factors".into(),
                expected: self.factor_count(),
                actual: factors.len(),
            });
        }
        for (i, (factor, name)) in factors.iter().zip(&self.factor_names).enumerate() {
            if &factor.name != name {
                return Err(DesignError::invalid(
                    format!("factors[{i}].name"),
                    format!(
                        "expected `{name}` (the design's column {i}), got `{}`",
                        factor.name
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// `x1, x2, …, xk`: names for designs generated before the real parameters are known.
pub fn default_factor_names(factor_count: usize) -> Vec<String> {
    (1..=factor_count).map(|i| format!("x{i}")).collect()
}

pub(crate) fn validate_factor_names<S: AsRef<str>>(names: &[S]) -> DesignResult<Vec<String>> {
    if names.is_empty() {
        return Err(DesignError::invalid(
            "factor_names",
            "at least one factor is required",
        ));
    }
    let mut owned: Vec<String> = Vec::with_capacity(names.len());
    for (i, name) in names.iter().enumerate() {
        let name = name.as_ref();
        if name.trim().is_empty() {
            return Err(DesignError::invalid(
                format!("factor_names[{i}]"),
                "name is empty",
            ));
        }
        if owned.iter().any(|existing| existing == name) {
            return Err(DesignError::invalid(
                format!("factor_names[{i}]"),
                format!("duplicate factor name `{name}`"),
            ));
        }
        owned.push(name.to_owned());
    }
    Ok(owned)
}

pub(crate) fn validate_run_matrix(rows: &[Vec<f64>], factor_count: usize) -> DesignResult<()> {
    if rows.is_empty() {
        return Err(DesignError::invalid("rows", "at least one run is required"));
    }
    for (r, row) in rows.iter().enumerate() {
        if row.len() != factor_count {
            return Err(DesignError::LengthMismatch {
                parameter: format!("rows[{r}]"),
                expected: factor_count,
                actual: row.len(),
            });
        }
        for (c, &value) in row.iter().enumerate() {
            if !value.is_finite() {
                return Err(DesignError::NonFinite {
                    parameter: format!("rows[{r}][{c}]"),
                    value,
                });
            }
        }
    }
    Ok(())
}

fn validate_permutation(parameter: &str, order: &[usize], len: usize) -> DesignResult<()> {
    if order.len() != len {
        return Err(DesignError::LengthMismatch {
            parameter: parameter.into(),
            expected: len,
            actual: order.len(),
        });
    }
    let mut seen = vec![false; len];
    for (i, &index) in order.iter().enumerate() {
        if index >= len || std::mem::replace(&mut seen[index], true) {
            return Err(DesignError::invalid(
                format!("{parameter}[{i}]"),
                format!("{index} repeats or is out of range; must be a permutation of 0..{len}"),
            ));
        }
    }
    Ok(())
}

pub(crate) fn require_finite(parameter: impl Into<String>, value: f64) -> DesignResult<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(DesignError::NonFinite {
            parameter: parameter.into(),
            value,
        })
    }
}

/// Two-level full factorial rows in Yates standard order (first factor alternates fastest).
/// Shared by the factorial, Box–Behnken and central composite constructions.
pub(crate) fn two_level_rows(factor_count: usize) -> Vec<Vec<f64>> {
    (0..1usize << factor_count)
        .map(|run| {
            (0..factor_count)
                .map(|factor| if (run >> factor) & 1 == 1 { 1.0 } else { -1.0 })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn custom_rejects_ragged_rows_naming_the_row() {
        let err = Design::custom(&["a", "b"], vec![vec![0.0, 1.0], vec![1.0]]).unwrap_err();
        assert!(err.to_string().contains("rows[1]"), "{err}");
    }

    #[test]
    fn custom_rejects_non_finite_values_naming_the_cell() {
        let err = Design::custom(&["a"], vec![vec![f64::NAN]]).unwrap_err();
        assert!(err.to_string().contains("rows[0][0]"), "{err}");
    }

    #[test]
    fn custom_rejects_empty_and_duplicate_names() {
        assert!(Design::custom::<&str>(&[], vec![vec![]]).is_err());
        assert!(Design::custom(&["a"], vec![]).is_err());
        let err = Design::custom(&["a", "a"], vec![vec![0.0, 0.0]]).unwrap_err();
        assert!(err.to_string().contains("factor_names[1]"), "{err}");
    }

    #[test]
    fn deserialisation_source_rejects_a_standard_order_that_is_not_a_permutation() {
        let err = Design::try_from(DesignRepr {
            kind: DesignKind::Custom,
            factor_names: vec!["a".into()],
            coded_runs: vec![vec![0.0], vec![1.0]],
            standard_order: vec![0, 0],
        })
        .unwrap_err();
        assert!(err.to_string().contains("standard_order[1]"), "{err}");
    }

    #[test]
    fn two_level_rows_are_in_yates_order() {
        assert_eq!(
            two_level_rows(2),
            vec![
                vec![-1.0, -1.0],
                vec![1.0, -1.0],
                vec![-1.0, 1.0],
                vec![1.0, 1.0]
            ]
        );
    }
}
