//! Polynomial model specification in the factors of a design.
//!
//! A term is a monomial `∏ x_i^{e_i}` in the (coded) factors. Names follow the
//! factor (CSV column) names so that a coefficient table can be read next to
//! the data: `Intercept`, `A`, `A:B`, `A^2`, and in general `A^2:B`.
//! Terms are always kept in the order Design-Expert prints them (intercept,
//! main effects in factor order, interactions in `i < j` order, pure squares,
//! then anything else by degree), so that the output of an explicit term list
//! and of a named model kind look the same.

use std::cmp::Ordering;
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::FitError;

/// A monomial term of a polynomial model.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize)]
pub struct Term {
    /// Canonical name, e.g. `A:B` or `A^2`.
    name: String,
    /// Exponent of each factor (length = number of factors).
    exponents: Vec<u32>,
}

impl Term {
    fn new(exponents: Vec<u32>, factors: &[String]) -> Self {
        let name = term_name(&exponents, factors);
        Self { name, exponents }
    }

    /// Canonical name of the term.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Exponent of each factor.
    pub fn exponents(&self) -> &[u32] {
        &self.exponents
    }

    /// Total degree (0 for the intercept).
    pub fn degree(&self) -> u32 {
        self.exponents.iter().sum()
    }

    /// True for the constant term.
    pub fn is_intercept(&self) -> bool {
        self.degree() == 0
    }

    /// True if `other` is a proper lower-order part of `self` (e.g. `A` and
    /// `B` are parts of `A:B`, `A` is a part of `A^2`, the intercept is a
    /// part of everything). This is what model hierarchy is about.
    pub fn contains(&self, other: &Term) -> bool {
        self.exponents.len() == other.exponents.len()
            && self != other
            && self
                .exponents
                .iter()
                .zip(&other.exponents)
                .all(|(s, o)| o <= s)
    }

    /// Value of the monomial at point `x` (coded units).
    pub fn eval(&self, x: &[f64]) -> f64 {
        self.exponents
            .iter()
            .zip(x)
            .filter(|(e, _)| **e > 0)
            .map(|(e, v)| v.powi(*e as i32))
            .product()
    }

    fn order_key(&self) -> (u8, u32, Vec<i64>) {
        let d = self.degree();
        let used: Vec<usize> = (0..self.exponents.len())
            .filter(|&i| self.exponents[i] > 0)
            .collect();
        let class = if d == 0 {
            0
        } else if d == 1 {
            1
        } else if self.exponents.iter().all(|&e| e <= 1) {
            2
        } else if used.len() == 1 && d == 2 {
            3
        } else {
            4
        };
        let key = match class {
            4 => self.exponents.iter().map(|&e| -i64::from(e)).collect(),
            _ => used.iter().map(|&i| i as i64).collect(),
        };
        (class, d, key)
    }
}

impl fmt::Display for Term {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name)
    }
}

fn term_name(exponents: &[u32], factors: &[String]) -> String {
    let parts: Vec<String> = exponents
        .iter()
        .zip(factors)
        .filter(|(e, _)| **e > 0)
        .map(|(e, f)| {
            if *e == 1 {
                f.clone()
            } else {
                format!("{f}^{e}")
            }
        })
        .collect();
    if parts.is_empty() {
        "Intercept".to_owned()
    } else {
        parts.join(":")
    }
}

fn canonical_order(a: &Term, b: &Term) -> Ordering {
    a.order_key().cmp(&b.order_key())
}

/// The standard model families of response-surface methodology.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelKind {
    /// Intercept and main effects.
    Linear,
    /// Linear plus all two-factor interactions (`2fi`).
    #[serde(rename = "2fi")]
    TwoFactorInteraction,
    /// Two-factor interaction model plus pure squares.
    Quadratic,
}

impl FromStr for ModelKind {
    type Err = FitError;

    /// Accepts `linear`, `2fi` (or `two_factor_interaction`, `interaction`)
    /// and `quadratic`, case-insensitively.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "linear" => Ok(Self::Linear),
            "2fi" | "two_factor_interaction" | "interaction" | "twofi" => {
                Ok(Self::TwoFactorInteraction)
            }
            "quadratic" => Ok(Self::Quadratic),
            other => Err(FitError::InvalidOption {
                option: "model",
                reason: format!("unknown model kind {other:?} (expected linear, 2fi or quadratic)"),
            }),
        }
    }
}

/// A polynomial model: the factor names and the terms, in canonical order.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Model {
    factors: Vec<String>,
    #[serde(serialize_with = "serialize_term_names")]
    terms: Vec<Term>,
}

fn serialize_term_names<S: serde::Serializer>(terms: &[Term], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(terms.iter().map(Term::name))
}

fn check_factors<S: AsRef<str>>(factors: &[S]) -> Result<Vec<String>, FitError> {
    if factors.is_empty() {
        return Err(FitError::NoFactors);
    }
    let mut out: Vec<String> = Vec::with_capacity(factors.len());
    for f in factors {
        let f = f.as_ref();
        if f.is_empty()
            || f.eq_ignore_ascii_case("intercept")
            || f == "1"
            || f.chars()
                .any(|c| c == ':' || c == '*' || c == '^' || c.is_whitespace())
        {
            return Err(FitError::InvalidFactorName { name: f.to_owned() });
        }
        if out.iter().any(|o| o == f) {
            return Err(FitError::DuplicateFactor { name: f.to_owned() });
        }
        out.push(f.to_owned());
    }
    Ok(out)
}

impl Model {
    /// Model of the given family in `factors`.
    pub fn new<S: AsRef<str>>(factors: &[S], kind: ModelKind) -> Result<Self, FitError> {
        let factors = check_factors(factors)?;
        let k = factors.len();
        let unit = |idx: &[usize]| {
            let mut e = vec![0u32; k];
            for &i in idx {
                e[i] += 1;
            }
            e
        };
        let mut exps = vec![vec![0u32; k]];
        exps.extend((0..k).map(|i| unit(&[i])));
        if matches!(kind, ModelKind::TwoFactorInteraction | ModelKind::Quadratic) {
            for i in 0..k {
                for j in i + 1..k {
                    exps.push(unit(&[i, j]));
                }
            }
        }
        if kind == ModelKind::Quadratic {
            exps.extend((0..k).map(|i| unit(&[i, i])));
        }
        let terms = exps.into_iter().map(|e| Term::new(e, &factors)).collect();
        Ok(Self { factors, terms })
    }

    /// Linear model (intercept + main effects).
    pub fn linear<S: AsRef<str>>(factors: &[S]) -> Result<Self, FitError> {
        Self::new(factors, ModelKind::Linear)
    }

    /// Two-factor-interaction model.
    pub fn two_fi<S: AsRef<str>>(factors: &[S]) -> Result<Self, FitError> {
        Self::new(factors, ModelKind::TwoFactorInteraction)
    }

    /// Full quadratic model.
    pub fn quadratic<S: AsRef<str>>(factors: &[S]) -> Result<Self, FitError> {
        Self::new(factors, ModelKind::Quadratic)
    }

    /// Model with an explicit list of term names such as
    /// `["Intercept", "A", "B", "A:B", "A^2"]`.
    ///
    /// Accepted syntax per term: `Intercept` (or `1`), factor names joined by
    /// `:` or `*`, each optionally raised with `^n` (`A^2`, `A*A` and `A:A`
    /// are the same term). The terms are re-ordered canonically; the
    /// intercept is required.
    pub fn from_term_names<S: AsRef<str>, T: AsRef<str>>(
        factors: &[S],
        terms: &[T],
    ) -> Result<Self, FitError> {
        let factors = check_factors(factors)?;
        let mut parsed: Vec<Term> = Vec::with_capacity(terms.len());
        for t in terms {
            let term = parse_term(t.as_ref(), &factors)?;
            if parsed.contains(&term) {
                return Err(FitError::DuplicateTerm { term: term.name });
            }
            parsed.push(term);
        }
        if !parsed.iter().any(Term::is_intercept) {
            return Err(FitError::MissingIntercept);
        }
        parsed.sort_by(canonical_order);
        Ok(Self {
            factors,
            terms: parsed,
        })
    }

    /// Parse a single term name against this model's factors.
    pub fn parse_term(&self, name: &str) -> Result<Term, FitError> {
        parse_term(name, &self.factors)
    }

    /// Factor names.
    pub fn factors(&self) -> &[String] {
        &self.factors
    }

    /// Terms in canonical order.
    pub fn terms(&self) -> &[Term] {
        &self.terms
    }

    /// Term names in canonical order.
    pub fn term_names(&self) -> Vec<String> {
        self.terms.iter().map(|t| t.name.clone()).collect()
    }

    /// Number of terms (= number of coefficients).
    pub fn len(&self) -> usize {
        self.terms.len()
    }

    /// Always false for a valid model (the intercept is required); provided
    /// for API symmetry with `len`.
    pub fn is_empty(&self) -> bool {
        self.terms.is_empty()
    }

    /// Position of a term by (canonical or parseable) name.
    pub fn term_index(&self, name: &str) -> Option<usize> {
        let t = parse_term(name, &self.factors).ok()?;
        self.terms.iter().position(|x| *x == t)
    }

    /// Row of the model matrix at point `x` (coded units).
    pub fn row(&self, x: &[f64]) -> Vec<f64> {
        self.terms.iter().map(|t| t.eval(x)).collect()
    }

    /// The same model without term `index`.
    pub fn without_term(&self, index: usize) -> Self {
        let mut terms = self.terms.clone();
        terms.remove(index);
        Self {
            factors: self.factors.clone(),
            terms,
        }
    }

    /// True if removing term `index` keeps the model hierarchical, i.e. no
    /// other term of the model contains it. The intercept is never removable.
    pub fn is_removable(&self, index: usize) -> bool {
        let t = &self.terms[index];
        !t.is_intercept() && !self.terms.iter().any(|u| u.contains(t))
    }

    /// True if every lower-order part of every term is also in the model.
    pub fn is_hierarchical(&self) -> bool {
        self.terms.iter().all(|t| {
            // Every part obtained by lowering one exponent by one must be present;
            // by induction that covers all parts.
            (0..t.exponents.len()).all(|i| {
                if t.exponents[i] == 0 {
                    return true;
                }
                let mut e = t.exponents.clone();
                e[i] -= 1;
                self.terms.iter().any(|u| u.exponents == e)
            })
        })
    }
}

fn parse_term(raw: &str, factors: &[String]) -> Result<Term, FitError> {
    let s = raw.trim();
    let invalid = |reason: &str| FitError::InvalidTerm {
        term: raw.to_owned(),
        reason: reason.to_owned(),
    };
    if s.is_empty() {
        return Err(invalid("empty term name"));
    }
    let mut exps = vec![0u32; factors.len()];
    if s.eq_ignore_ascii_case("intercept") || s == "1" {
        return Ok(Term::new(exps, factors));
    }
    for part in s.split([':', '*']) {
        let part = part.trim();
        if part.is_empty() {
            return Err(invalid("empty factor between separators"));
        }
        let (name, power) = match part.split_once('^') {
            Some((n, p)) => {
                let p: u32 = p.trim().parse().map_err(|_| {
                    invalid(&format!(
                        "exponent {:?} is not a positive integer",
                        p.trim()
                    ))
                })?;
                if p == 0 || p > 16 {
                    return Err(invalid("exponent must be between 1 and 16"));
                }
                (n.trim(), p)
            }
            None => (part, 1),
        };
        let idx =
            factors
                .iter()
                .position(|f| f == name)
                .ok_or_else(|| FitError::UnknownFactor {
                    term: raw.to_owned(),
                    factor: name.to_owned(),
                    known: factors.join(", "),
                })?;
        exps[idx] += power;
    }
    Ok(Term::new(exps, factors))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadratic_order_matches_design_expert() {
        let m = Model::quadratic(&["A", "B", "C"]).unwrap();
        assert_eq!(
            m.term_names(),
            [
                "Intercept",
                "A",
                "B",
                "C",
                "A:B",
                "A:C",
                "B:C",
                "A^2",
                "B^2",
                "C^2"
            ]
        );
        assert!(m.is_hierarchical());
    }

    #[test]
    fn explicit_terms_are_parsed_and_sorted() {
        let m =
            Model::from_term_names(&["A", "B"], &["B^2", "A*B", "A", "intercept", "B"]).unwrap();
        assert_eq!(m.term_names(), ["Intercept", "A", "B", "A:B", "B^2"]);
        let e = Model::from_term_names(&["A", "B"], &["Intercept", "A:Q"]).unwrap_err();
        assert!(e.to_string().contains("\"Q\""), "{e}");
        let e = Model::from_term_names(&["A", "B"], &["Intercept", "A", "A^1"]).unwrap_err();
        assert!(matches!(e, FitError::DuplicateTerm { .. }));
        assert_eq!(
            Model::from_term_names(&["A"], &["A"]).unwrap_err(),
            FitError::MissingIntercept
        );
        let m = Model::from_term_names(&["A", "B"], &["1", "A:A:B", "A"]).unwrap();
        assert_eq!(m.term_names(), ["Intercept", "A", "A^2:B"]);
        assert!(!m.is_hierarchical());
    }

    #[test]
    fn hierarchy() {
        let m = Model::two_fi(&["A", "B"]).unwrap();
        assert!(!m.is_removable(0));
        assert!(!m.is_removable(1));
        assert!(m.is_removable(3));
    }
}
