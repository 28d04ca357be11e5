//! Ordinary least squares fit of a polynomial [`Model`], with the
//! Design-Expert style summaries (ANOVA, fit statistics, coefficient table,
//! residual diagnostics).
//!
//! The library does no I/O: callers pass the runs (factor settings in coded
//! units, one row per run) and the response values, and get back a [`Fit`]
//! that serialises to JSON. That keeps the statistics testable against
//! published tables and lets the command-line tool and the server decide how
//! to read and print data.
//!
//! Numerics: the model matrix is factorised by Householder QR (nalgebra);
//! leverages are the squared row norms of the thin `Q`, the unscaled
//! covariance is `R⁻¹R⁻ᵀ`. Rank deficiency is detected *before* solving by a
//! Gram–Schmidt pass over the unit-scaled columns in model order, which also
//! tells which terms are aliased with which, so the error can name them.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::anova::{build_anova, AnovaRow, AnovaSource, FitStats};
use crate::design::Design;
use crate::diagnostics::{run_diagnostics, RunDiagnostics};
use crate::error::{Alias, FitError};
use crate::model::{Model, ModelKind};
use crate::stats::{t_quantile, t_two_sided_p};

/// Relative residual norm below which a column counts as a linear
/// combination of the previous ones (i.e. VIF above ~1e16).
const ALIAS_TOL: f64 = 1e-8;

/// Options of [`fit_with_options`]. Deserialisable (missing fields take the
/// defaults) so a command line or config file can carry them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FitOptions {
    /// Name of the response, used in error messages and carried in the result.
    pub response_name: String,
    /// Confidence level of the coefficient intervals (default 0.95).
    pub confidence: f64,
    /// If set, backward elimination: repeatedly remove the least significant
    /// removable term while its p-value exceeds this `alpha_out`. Only terms
    /// not contained in another remaining term are candidates, so the model
    /// stays hierarchical.
    pub backward_alpha: Option<f64>,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            response_name: "response".to_owned(),
            confidence: 0.95,
            backward_alpha: None,
        }
    }
}

/// One row of the coefficient table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Coefficient {
    /// Term name (`Intercept`, `A`, `A:B`, `A^2`, ...).
    pub term: String,
    /// Least-squares estimate (coded units).
    pub estimate: f64,
    /// Standard error `sqrt(MSE · (XᵀX)⁻¹_jj)`.
    pub std_error: f64,
    /// Lower end of the confidence interval.
    pub ci_low: f64,
    /// Upper end of the confidence interval.
    pub ci_high: f64,
    /// Variance inflation factor; `None` for the intercept.
    pub vif: Option<f64>,
    /// `estimate / std_error` (None if the standard error is zero).
    pub t_value: Option<f64>,
    /// Two-sided p-value of the t test (equals the ANOVA p of a 1-df term).
    pub p_value: Option<f64>,
}

/// One step of backward elimination.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EliminationStep {
    /// Term removed.
    pub term: String,
    /// Its partial F value in the model it was removed from.
    pub f: Option<f64>,
    /// Its p-value in the model it was removed from.
    pub p: Option<f64>,
}

/// A fitted model with all Design-Expert style summaries.
#[derive(Debug, Clone, Serialize)]
pub struct Fit {
    response: String,
    model: Model,
    n_runs: usize,
    residual_df: usize,
    coefficients: Vec<Coefficient>,
    anova: Vec<AnovaRow>,
    stats: FitStats,
    diagnostics: Vec<RunDiagnostics>,
    elimination: Vec<EliminationStep>,
    confidence: f64,
}

impl Fit {
    /// Response name.
    pub fn response(&self) -> &str {
        &self.response
    }

    /// The fitted model (after backward elimination, if any).
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Number of runs.
    pub fn n_runs(&self) -> usize {
        self.n_runs
    }

    /// Residual degrees of freedom `n - p`.
    pub fn residual_df(&self) -> usize {
        self.residual_df
    }

    /// Coefficient table in model order.
    pub fn coefficients(&self) -> &[Coefficient] {
        &self.coefficients
    }

    /// Coefficient estimates keyed by term name.
    pub fn coefficient_map(&self) -> BTreeMap<String, f64> {
        self.coefficients
            .iter()
            .map(|c| (c.term.clone(), c.estimate))
            .collect()
    }

    /// Coefficient row of a term, by canonical or parseable name.
    pub fn coefficient(&self, term: &str) -> Option<&Coefficient> {
        self.model.term_index(term).map(|i| &self.coefficients[i])
    }

    /// ANOVA rows: Model, one per non-intercept term, Residual, optionally
    /// Lack of Fit and Pure Error, Cor Total.
    pub fn anova(&self) -> &[AnovaRow] {
        &self.anova
    }

    /// ANOVA row by source: `Model`, a term name, `Residual`, `Lack of Fit`,
    /// `Pure Error` or `Cor Total`. If a factor is itself called e.g.
    /// `Model`, the summary row wins; use [`Fit::term_anova`] for terms.
    pub fn anova_row(&self, source: &str) -> Option<&AnovaRow> {
        self.anova
            .iter()
            .find(|r| r.kind != AnovaSource::Term && r.source == source)
            .or_else(|| self.term_anova(source))
    }

    /// ANOVA row of a model term, by canonical or parseable name (`A:B`, `B*A`).
    pub fn term_anova(&self, term: &str) -> Option<&AnovaRow> {
        let term = self.model.parse_term(term).ok()?;
        self.anova
            .iter()
            .find(|r| r.kind == AnovaSource::Term && r.source == term.name())
    }

    /// Fit statistics (R², adjusted and predicted R², adequate precision, ...).
    pub fn stats(&self) -> &FitStats {
        &self.stats
    }

    /// Per-run residual diagnostics, in run order.
    pub fn diagnostics(&self) -> &[RunDiagnostics] {
        &self.diagnostics
    }

    /// Terms removed by backward elimination, in removal order.
    pub fn elimination(&self) -> &[EliminationStep] {
        &self.elimination
    }

    /// Confidence level of the coefficient intervals.
    pub fn confidence(&self) -> f64 {
        self.confidence
    }

    /// Predicted response at `x` (coded units, one value per factor).
    ///
    /// # Panics
    /// If `x.len()` differs from the number of factors; use
    /// [`Fit::try_predict`] for unchecked input.
    pub fn predict(&self, x: &[f64]) -> f64 {
        match self.try_predict(x) {
            Ok(v) => v,
            Err(e) => panic!("{e}"),
        }
    }

    /// Predicted response at `x`, checking its length.
    pub fn try_predict(&self, x: &[f64]) -> Result<f64, FitError> {
        let k = self.model.factors().len();
        if x.len() != k {
            return Err(FitError::PointLength {
                expected: k,
                found: x.len(),
                factors: self.model.factors().join(", "),
            });
        }
        Ok(self
            .model
            .terms()
            .iter()
            .zip(&self.coefficients)
            .map(|(t, c)| c.estimate * t.eval(x))
            .sum())
    }
}

/// Fit `model` by OLS with default options.
///
/// `runs[i]` holds the coded factor settings of run `i` (one value per factor
/// of the model, in the model's factor order) and `response[i]` its response.
///
/// ```
/// use repose_doe::{fit, Model};
/// let runs = vec![
///     vec![-1.0, -1.0],
///     vec![1.0, -1.0],
///     vec![-1.0, 1.0],
///     vec![1.0, 1.0],
///     vec![0.0, 0.0],
/// ];
/// let y = [10.0, 14.0, 11.0, 16.0, 12.6];
/// let f = fit(&Model::linear(&["A", "B"])?, &runs, &y)?;
/// assert!((f.coefficient_map()["A"] - 2.25).abs() < 1e-12);
/// let model_row = f.anova_row("Model").unwrap();
/// assert!(model_row.p.unwrap() < 0.05);
/// # Ok::<(), repose_doe::FitError>(())
/// ```
pub fn fit<R: AsRef<[f64]>>(model: &Model, runs: &[R], response: &[f64]) -> Result<Fit, FitError> {
    fit_with_options(model, runs, response, &FitOptions::default())
}

/// Fit `model` by OLS, optionally with hierarchical backward elimination.
pub fn fit_with_options<R: AsRef<[f64]>>(
    model: &Model,
    runs: &[R],
    response: &[f64],
    options: &FitOptions,
) -> Result<Fit, FitError> {
    if !(options.confidence > 0.0 && options.confidence < 1.0) {
        return Err(FitError::InvalidOption {
            option: "confidence",
            reason: format!("{} is not strictly between 0 and 1", options.confidence),
        });
    }
    if let Some(a) = options.backward_alpha {
        if !(a > 0.0 && a < 1.0) {
            return Err(FitError::InvalidOption {
                option: "backward_alpha",
                reason: format!("{a} is not strictly between 0 and 1"),
            });
        }
    }
    let rows = validate_data(model, runs, response, &options.response_name)?;
    let mut current = model.clone();
    let mut steps = Vec::new();
    loop {
        let mut f = fit_core(&current, &rows, response, options)?;
        let Some(alpha) = options.backward_alpha else {
            return Ok(f);
        };
        let worst = (0..current.len())
            .filter(|&i| current.is_removable(i))
            .filter_map(|i| {
                let row = f.term_anova(current.terms()[i].name())?;
                Some((i, row.f, row.p?))
            })
            .max_by(|a, b| a.2.total_cmp(&b.2));
        match worst {
            Some((i, fv, p)) if p > alpha => {
                steps.push(EliminationStep {
                    term: current.terms()[i].name().to_owned(),
                    f: fv,
                    p: Some(p),
                });
                current = current.without_term(i);
            }
            _ => {
                f.elimination = steps;
                return Ok(f);
            }
        }
    }
}

/// Fit a model of family `kind` in all factors of `design` (coded runs, in
/// the design's row order) to `response`.
///
/// Convenience for callers that already hold a [`Design`]: the factor names
/// and run layout come from the design, so they cannot disagree with the model.
pub fn fit_design(
    design: &Design,
    kind: ModelKind,
    response: &[f64],
    options: &FitOptions,
) -> Result<Fit, FitError> {
    let model = Model::new(design.factor_names(), kind)?;
    fit_with_options(&model, design.coded_runs(), response, options)
}

/// Checks lengths and finiteness; returns the rows as owned vectors.
fn validate_data<R: AsRef<[f64]>>(
    model: &Model,
    runs: &[R],
    response: &[f64],
    response_name: &str,
) -> Result<Vec<Vec<f64>>, FitError> {
    let k = model.factors().len();
    if runs.len() != response.len() {
        return Err(FitError::ResponseLength {
            runs: runs.len(),
            responses: response.len(),
        });
    }
    let mut rows = Vec::with_capacity(runs.len());
    for (i, r) in runs.iter().enumerate() {
        let r = r.as_ref();
        if r.len() != k {
            return Err(FitError::RowLength {
                run: i + 1,
                expected: k,
                found: r.len(),
                factors: model.factors().join(", "),
            });
        }
        if let Some((j, v)) = r.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(FitError::NonFinite {
                run: i + 1,
                column: model.factors()[j].clone(),
                value: *v,
            });
        }
        if !response[i].is_finite() {
            return Err(FitError::NonFinite {
                run: i + 1,
                column: response_name.to_owned(),
                value: response[i],
            });
        }
        rows.push(r.to_vec());
    }
    Ok(rows)
}

/// Result of one least-squares solve.
pub(crate) struct Ols {
    pub beta: DVector<f64>,
    pub fitted: DVector<f64>,
    pub resid: DVector<f64>,
    pub sse: f64,
    pub leverage: Vec<f64>,
    /// `(XᵀX)⁻¹`.
    pub xtx_inv: DMatrix<f64>,
}

/// Householder-QR least squares for a full-column-rank, tall `x`.
pub(crate) fn ols(x: &DMatrix<f64>, y: &DVector<f64>) -> Result<Ols, FitError> {
    let p = x.ncols();
    let qr = x.clone().qr();
    let q = qr.q();
    let r = qr.r();
    let rinv = r
        .solve_upper_triangular(&DMatrix::identity(p, p))
        .ok_or_else(|| FitError::Numerical("singular R factor".to_owned()))?;
    let beta = &rinv * (q.transpose() * y);
    let fitted = x * &beta;
    let resid = y - &fitted;
    let sse = resid.norm_squared();
    let leverage = (0..x.nrows()).map(|i| q.row(i).norm_squared()).collect();
    let xtx_inv = &rinv * rinv.transpose();
    if !sse.is_finite() || beta.iter().any(|b| !b.is_finite()) {
        return Err(FitError::Numerical(
            "least-squares solution is not finite (data too large or ill-conditioned)".to_owned(),
        ));
    }
    Ok(Ols {
        beta,
        fitted,
        resid,
        sse,
        leverage,
        xtx_inv,
    })
}

/// Model matrix of `model` on `rows`.
pub(crate) fn model_matrix(model: &Model, rows: &[Vec<f64>]) -> DMatrix<f64> {
    let n = rows.len();
    let p = model.len();
    DMatrix::from_fn(n, p, |i, j| model.terms()[j].eval(&rows[i]))
}

/// Terms whose columns are linear combinations of earlier columns.
pub(crate) fn find_aliases(x: &DMatrix<f64>, names: &[String]) -> Vec<Alias> {
    let mut basis: Vec<DVector<f64>> = Vec::new();
    let mut accepted: Vec<usize> = Vec::new();
    let mut aliases = Vec::new();
    for j in 0..x.ncols() {
        let col = x.column(j).into_owned();
        let norm = col.norm();
        if norm == 0.0 || !norm.is_finite() {
            aliases.push(Alias {
                term: names[j].clone(),
                combination: Vec::new(),
            });
            continue;
        }
        let mut v = &col / norm;
        for _ in 0..2 {
            for b in &basis {
                let d = b.dot(&v);
                v -= b * d;
            }
        }
        let rn = v.norm();
        if rn < ALIAS_TOL {
            let xa = x.select_columns(&accepted);
            let combination = match xa.clone().svd(true, true).solve(&col, 1e-12) {
                Ok(c) => {
                    let cmax = c.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
                    accepted
                        .iter()
                        .zip(c.iter())
                        .filter(|(_, c)| c.abs() > 1e-9 * cmax.max(1e-300))
                        .map(|(&a, &c)| (names[a].clone(), c))
                        .collect()
                }
                Err(_) => Vec::new(),
            };
            aliases.push(Alias {
                term: names[j].clone(),
                combination,
            });
        } else {
            basis.push(v / rn);
            accepted.push(j);
        }
    }
    aliases
}

fn fit_core(
    model: &Model,
    rows: &[Vec<f64>],
    response: &[f64],
    options: &FitOptions,
) -> Result<Fit, FitError> {
    let n = rows.len();
    let p = model.len();
    if n < p + 1 {
        return Err(FitError::TooFewRuns {
            runs: n,
            terms: p,
            needed: p + 1,
            term_list: model.term_names().join(", "),
        });
    }
    // A factor used by the model that never varies.
    for (j, name) in model.factors().iter().enumerate() {
        let using: Vec<&str> = model
            .terms()
            .iter()
            .filter(|t| t.exponents()[j] > 0)
            .map(|t| t.name())
            .collect();
        if using.is_empty() {
            continue;
        }
        let v0 = rows[0][j];
        if rows.iter().all(|r| r[j] == v0) {
            return Err(FitError::ConstantFactor {
                factor: name.clone(),
                value: v0,
                terms: using.join(", "),
            });
        }
    }
    let mean = response.iter().sum::<f64>() / n as f64;
    let sst: f64 = response.iter().map(|v| (v - mean).powi(2)).sum();
    let scale: f64 = response.iter().map(|v| v * v).sum();
    if sst.is_nan() || sst <= 1e-28 * scale {
        return Err(FitError::ConstantResponse {
            response: options.response_name.clone(),
            value: response[0],
        });
    }
    let x = model_matrix(model, rows);
    let names = model.term_names();
    let aliases = find_aliases(&x, &names);
    if !aliases.is_empty() {
        return Err(FitError::Aliased { aliases });
    }
    let y = DVector::from_column_slice(response);
    let full = ols(&x, &y)?;
    let df_res = n - p;
    let mse = full.sse / df_res as f64;

    // Partial (Type III) sums of squares: refit without each term.
    let mut partial = vec![None; p];
    for (j, slot) in partial.iter_mut().enumerate() {
        if model.terms()[j].is_intercept() {
            continue;
        }
        let cols: Vec<usize> = (0..p).filter(|&c| c != j).collect();
        let reduced = ols(&x.select_columns(&cols), &y)?;
        *slot = Some((reduced.sse - full.sse).max(0.0));
    }

    let (anova, stats) = build_anova(model, rows, response, &full, &partial, sst, mean)?;

    // Coefficient table.
    let tq = t_quantile(1.0 - 0.5 * (1.0 - options.confidence), df_res as f64);
    let vifs = variance_inflation(&x, model);
    let coefficients = (0..p)
        .map(|j| {
            let est = full.beta[j];
            let se = (mse * full.xtx_inv[(j, j)]).max(0.0).sqrt();
            let t = if se > 0.0 { Some(est / se) } else { None };
            Coefficient {
                term: names[j].clone(),
                estimate: est,
                std_error: se,
                ci_low: est - tq * se,
                ci_high: est + tq * se,
                vif: vifs[j],
                t_value: t,
                p_value: t.map(|t| t_two_sided_p(t, df_res as f64)),
            }
        })
        .collect();

    let diagnostics = run_diagnostics(&y, &full, p, df_res);
    Ok(Fit {
        response: options.response_name.clone(),
        model: model.clone(),
        n_runs: n,
        residual_df: df_res,
        coefficients,
        anova,
        stats,
        diagnostics,
        elimination: Vec::new(),
        confidence: options.confidence,
    })
}

/// VIF of each non-intercept column: diagonal of the inverse correlation
/// matrix of those columns (Design-Expert's definition, equal to
/// `1 / (1 - R²_j)`).
fn variance_inflation(x: &DMatrix<f64>, model: &Model) -> Vec<Option<f64>> {
    let p = x.ncols();
    let n = x.nrows();
    let idx: Vec<usize> = (0..p)
        .filter(|&j| !model.terms()[j].is_intercept())
        .collect();
    let mut out = vec![None; p];
    if idx.is_empty() {
        return out;
    }
    let mut z = DMatrix::zeros(n, idx.len());
    for (c, &j) in idx.iter().enumerate() {
        let col = x.column(j);
        let m = col.mean();
        let centred = col.map(|v| v - m);
        let norm = centred.norm();
        if norm == 0.0 {
            return out;
        }
        z.set_column(c, &(centred / norm));
    }
    let corr = z.transpose() * &z;
    if let Some(ch) = corr.cholesky() {
        let inv = ch.inverse();
        for (c, &j) in idx.iter().enumerate() {
            out[j] = Some(inv[(c, c)]);
        }
    }
    out
}
