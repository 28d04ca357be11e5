//! Error types of the regression and optimisation half of the crate.
//!
//! Every message names the offending column, term or run, because the person
//! reading it is usually looking at a CSV file and needs to know *where* to
//! look, not only *that* something is wrong.

use std::fmt::Write as _;

use serde::Serialize;
use thiserror::Error;

/// One term that is a linear combination of other (earlier) terms of the model
/// on the given runs, so its coefficient cannot be estimated.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Alias {
    /// The term that could not be estimated.
    pub term: String,
    /// `term == Σ coefficient · other_term` on the design points; empty when
    /// the term's column is identically zero.
    pub combination: Vec<(String, f64)>,
}

impl Alias {
    /// Human-readable right-hand side, e.g. `-N3^2 + Intercept` or `0.5·A`.
    pub fn combination_text(&self) -> String {
        if self.combination.is_empty() {
            return "0 (the column is identically zero on these runs)".to_owned();
        }
        let mut out = String::new();
        for (i, (name, c)) in self.combination.iter().enumerate() {
            let sign = if *c < 0.0 { "-" } else { "+" };
            if i == 0 {
                if *c < 0.0 {
                    out.push('-');
                }
            } else {
                let _ = write!(out, " {sign} ");
            }
            let a = c.abs();
            if (a - 1.0).abs() < 1e-9 {
                out.push_str(name);
            } else {
                let _ = write!(out, "{}·{name}", format_coef(a));
            }
        }
        out
    }
}

fn format_coef(a: f64) -> String {
    let s = format!("{a:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_owned()
}

fn format_aliases(aliases: &[Alias]) -> String {
    match aliases {
        [one] => format!(
            "term {} is aliased with {} on these runs (rank-deficient model)",
            one.term,
            one.combination_text()
        ),
        many => {
            let names: Vec<&str> = many.iter().map(|a| a.term.as_str()).collect();
            let detail: Vec<String> = many
                .iter()
                .map(|a| format!("{} = {}", a.term, a.combination_text()))
                .collect();
            format!(
                "terms {} are linearly dependent on the others ({}) (rank-deficient model)",
                names.join(", "),
                detail.join("; ")
            )
        }
    }
}

/// Why a model specification or a fit was rejected.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum FitError {
    /// The model has no factors.
    #[error("the model has no factors")]
    NoFactors,
    /// A factor name is empty or contains a character reserved for term names.
    #[error("invalid factor name {name:?}: names must be non-empty, must not be `Intercept` or `1` (they name the constant term) and must not contain ':', '*', '^' or whitespace")]
    InvalidFactorName {
        /// The offending name.
        name: String,
    },
    /// Two factors share a name.
    #[error("factor name {name:?} is used twice")]
    DuplicateFactor {
        /// The repeated name.
        name: String,
    },
    /// A term name could not be parsed.
    #[error("cannot parse term {term:?}: {reason}")]
    InvalidTerm {
        /// The term as written.
        term: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A term refers to a factor that is not in the model's factor list.
    #[error("term {term:?} refers to unknown factor {factor:?} (factors: {known})")]
    UnknownFactor {
        /// The term as written.
        term: String,
        /// The unknown factor.
        factor: String,
        /// Comma-separated list of the known factors.
        known: String,
    },
    /// A term appears twice in an explicit term list.
    #[error("term {term} appears more than once in the model")]
    DuplicateTerm {
        /// Canonical name of the repeated term.
        term: String,
    },
    /// The explicit term list does not contain `Intercept`.
    #[error("the model must contain the Intercept term (ANOVA is about the corrected total)")]
    MissingIntercept,
    /// Number of responses differs from the number of runs.
    #[error("{runs} runs but {responses} response values")]
    ResponseLength {
        /// Number of factor rows.
        runs: usize,
        /// Number of response values.
        responses: usize,
    },
    /// A run has the wrong number of factor values.
    #[error("run {run} has {found} factor values, expected {expected} ({factors})")]
    RowLength {
        /// 1-based run number.
        run: usize,
        /// Number of model factors.
        expected: usize,
        /// Number of values given.
        found: usize,
        /// Comma-separated factor names.
        factors: String,
    },
    /// NaN or infinity in the data.
    #[error("run {run}: {column} is not a finite number ({value})")]
    NonFinite {
        /// 1-based run number.
        run: usize,
        /// Factor or response name.
        column: String,
        /// The value found.
        value: f64,
    },
    /// Not enough runs to estimate all coefficients and the error variance.
    #[error("{runs} runs are too few for a model with {terms} terms ({term_list}): at least {needed} runs are needed so that one residual degree of freedom remains")]
    TooFewRuns {
        /// Number of runs.
        runs: usize,
        /// Number of terms.
        terms: usize,
        /// Number of runs needed.
        needed: usize,
        /// Comma-separated term names.
        term_list: String,
    },
    /// Every response value is the same.
    #[error(
        "the response {response} is constant ({value}) over all runs: there is nothing to model"
    )]
    ConstantResponse {
        /// Response name.
        response: String,
        /// The constant value.
        value: f64,
    },
    /// A factor used in the model never changes.
    #[error(
        "factor {factor} never varies (always {value}) but the model uses it in term(s) {terms}"
    )]
    ConstantFactor {
        /// Factor name.
        factor: String,
        /// Its only value.
        value: f64,
        /// Comma-separated terms that use it.
        terms: String,
    },
    /// The model matrix is rank deficient.
    #[error("{}", format_aliases(.aliases))]
    Aliased {
        /// The terms that could not be estimated, in model order.
        aliases: Vec<Alias>,
    },
    /// A prediction point has the wrong length.
    #[error(
        "prediction point has {found} coordinates, the model has {expected} factors ({factors})"
    )]
    PointLength {
        /// Number of factors.
        expected: usize,
        /// Number of coordinates given.
        found: usize,
        /// Comma-separated factor names.
        factors: String,
    },
    /// An option is out of range.
    #[error("invalid option {option}: {reason}")]
    InvalidOption {
        /// Option name.
        option: &'static str,
        /// Why it is invalid.
        reason: String,
    },
    /// A numerical step produced a non-finite number (e.g. overflow with huge inputs).
    #[error("numerical failure: {0}")]
    Numerical(String),
}

/// Why an optimum search was rejected.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum OptimumError {
    /// No responses were given.
    #[error("no responses to optimise")]
    NoResponses,
    /// Responses were fitted on different numbers of factors.
    #[error("response {response} has {found} factors but the first response has {expected}")]
    FactorCountMismatch {
        /// Response name.
        response: String,
        /// Factor count of the first response.
        expected: usize,
        /// Factor count of this response.
        found: usize,
    },
    /// Goal limits are inconsistent.
    #[error("response {response}: {reason}")]
    InvalidGoal {
        /// Response name.
        response: String,
        /// What is wrong.
        reason: String,
    },
    /// Importance outside 1..=5.
    #[error("response {response}: importance {importance} is outside 1..=5")]
    InvalidImportance {
        /// Response name.
        response: String,
        /// The given importance.
        importance: u8,
    },
    /// The factor ranges do not match the factors.
    #[error("{found} factor ranges given for {expected} factors")]
    FactorRangesLength {
        /// Number of factors.
        expected: usize,
        /// Number of ranges.
        found: usize,
    },
    /// A factor range is degenerate.
    #[error("factor {factor:?}: needs a non-empty name and finite low ({low}) < high ({high})")]
    InvalidFactorRange {
        /// Factor name.
        factor: String,
        /// Natural value at coded -1.
        low: f64,
        /// Natural value at coded +1.
        high: f64,
    },
    /// An option is out of range.
    #[error("invalid option {option}: {reason}")]
    InvalidOption {
        /// Option name.
        option: &'static str,
        /// Why it is invalid.
        reason: String,
    },
}
