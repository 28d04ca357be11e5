//! Analysis of variance and summary statistics, as Design-Expert prints them.
//!
//! Term rows use partial (Type III) sums of squares,
//! `SS_term = SSE(model without the term) - SSE(full model)`, which is what
//! Design-Expert reports for response-surface models and what makes each
//! row's F test the test of that coefficient. When some design points are
//! replicated, the residual is split into lack of fit and pure error, with
//! design points identified by identical factor settings over *all* factor
//! columns given to the fit.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::error::FitError;
use crate::fit::Ols;
use crate::model::Model;
use crate::stats::f_sf;

/// Kind of an ANOVA row.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AnovaSource {
    /// The whole model (corrected for the mean).
    Model,
    /// One model term.
    Term,
    /// Residual error.
    Residual,
    /// Lack of fit (part of the residual).
    LackOfFit,
    /// Pure error from replicated design points (part of the residual).
    PureError,
    /// Corrected total sum of squares.
    CorTotal,
}

/// One ANOVA row. `mean_sq` is absent for rows without degrees of freedom and
/// for the total; `f` and `p` only for rows that are tested.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnovaRow {
    /// `Model`, a term name, `Residual`, `Lack of Fit`, `Pure Error` or `Cor Total`.
    pub source: String,
    /// Machine-readable kind of the row.
    pub kind: AnovaSource,
    /// Sum of squares.
    pub sum_sq: f64,
    /// Degrees of freedom.
    pub df: usize,
    /// Mean square `sum_sq / df`.
    pub mean_sq: Option<f64>,
    /// F value (against the residual mean square; lack of fit against pure error).
    pub f: Option<f64>,
    /// Upper-tail p-value of `f`.
    pub p: Option<f64>,
}

/// Fit statistics of the Design-Expert "Fit Statistics" table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitStats {
    /// `1 - SSE/SST`.
    pub r2: f64,
    /// `1 - (SSE/(n-p)) / (SST/(n-1))`.
    pub adj_r2: f64,
    /// `1 - PRESS/SST`; None if a run has leverage 1 (PRESS undefined).
    pub pred_r2: Option<f64>,
    /// `(max ŷ - min ŷ) / sqrt(p·MSE/n)` over the design points: the signal
    /// range against the average prediction standard error. Design-Expert
    /// calls a value above 4 adequate. None if MSE is zero.
    pub adeq_precision: Option<f64>,
    /// `sqrt(MSE)`.
    pub std_dev: f64,
    /// Mean of the response.
    pub mean: f64,
    /// `100 · std_dev / mean`; None if the mean is zero.
    pub cv_percent: Option<f64>,
    /// Prediction error sum of squares `Σ (e_i / (1 - h_ii))²`.
    pub press: Option<f64>,
    /// Number of runs.
    pub n_runs: usize,
    /// Number of model terms (coefficients).
    pub n_terms: usize,
    /// Number of distinct design points.
    pub n_design_points: usize,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// Leverage above which a run is treated as exactly fitted (PRESS undefined).
pub(crate) const LEVERAGE_ONE: f64 = 1.0 - 1e-10;

fn tested(
    source: String,
    kind: AnovaSource,
    ss: f64,
    df: usize,
    mse: f64,
    df_den: usize,
) -> AnovaRow {
    let ms = if df > 0 { Some(ss / df as f64) } else { None };
    let f = ms.and_then(|ms| finite(ms / mse));
    let p = f.and_then(|f| f_sf(f, df as f64, df_den as f64));
    AnovaRow {
        source,
        kind,
        sum_sq: ss,
        df,
        mean_sq: ms,
        f,
        p,
    }
}

/// Build the ANOVA table and fit statistics.
pub(crate) fn build_anova(
    model: &Model,
    rows: &[Vec<f64>],
    response: &[f64],
    full: &Ols,
    partial: &[Option<f64>],
    sst: f64,
    mean: f64,
) -> Result<(Vec<AnovaRow>, FitStats), FitError> {
    let n = rows.len();
    let p = model.len();
    let df_res = n - p;
    let sse = full.sse;
    let mse = sse / df_res as f64;
    let mut table = Vec::with_capacity(p + 5);
    table.push(tested(
        "Model".to_owned(),
        AnovaSource::Model,
        (sst - sse).max(0.0),
        p - 1,
        mse,
        df_res,
    ));
    for (t, ss) in model.terms().iter().zip(partial) {
        if let Some(ss) = ss {
            table.push(tested(
                t.name().to_owned(),
                AnovaSource::Term,
                *ss,
                1,
                mse,
                df_res,
            ));
        }
    }
    table.push(AnovaRow {
        source: "Residual".to_owned(),
        kind: AnovaSource::Residual,
        sum_sq: sse,
        df: df_res,
        mean_sq: Some(mse),
        f: None,
        p: None,
    });

    // Replicated design points → pure error.
    let mut groups: BTreeMap<Vec<u64>, Vec<usize>> = BTreeMap::new();
    for (i, r) in rows.iter().enumerate() {
        // `+ 0.0` maps -0.0 to 0.0 so both land in the same group.
        let key = r.iter().map(|v| (v + 0.0).to_bits()).collect();
        groups.entry(key).or_default().push(i);
    }
    let n_points = groups.len();
    let df_pe = n - n_points;
    if df_pe > 0 {
        let ss_pe: f64 = groups
            .values()
            .map(|idx| {
                let m = idx.iter().map(|&i| response[i]).sum::<f64>() / idx.len() as f64;
                idx.iter().map(|&i| (response[i] - m).powi(2)).sum::<f64>()
            })
            .sum();
        // n_points >= p for a full-rank model, so this cannot underflow.
        let df_lof = df_res.saturating_sub(df_pe);
        let ss_lof = (sse - ss_pe).max(0.0);
        let ms_pe = ss_pe / df_pe as f64;
        let mut lof = tested(
            "Lack of Fit".to_owned(),
            AnovaSource::LackOfFit,
            ss_lof,
            df_lof,
            ms_pe,
            df_pe,
        );
        if ms_pe == 0.0 {
            lof.f = None;
            lof.p = None;
        }
        table.push(lof);
        table.push(AnovaRow {
            source: "Pure Error".to_owned(),
            kind: AnovaSource::PureError,
            sum_sq: ss_pe,
            df: df_pe,
            mean_sq: Some(ms_pe),
            f: None,
            p: None,
        });
    }
    table.push(AnovaRow {
        source: "Cor Total".to_owned(),
        kind: AnovaSource::CorTotal,
        sum_sq: sst,
        df: n - 1,
        mean_sq: None,
        f: None,
        p: None,
    });

    let press = if full.leverage.iter().any(|&h| h >= LEVERAGE_ONE) {
        None
    } else {
        Some(
            full.resid
                .iter()
                .zip(&full.leverage)
                .map(|(e, h)| (e / (1.0 - h)).powi(2))
                .sum::<f64>(),
        )
    };
    let (lo, hi) = full
        .fitted
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    let std_dev = mse.sqrt();
    let stats = FitStats {
        r2: 1.0 - sse / sst,
        adj_r2: 1.0 - mse / (sst / (n - 1) as f64),
        pred_r2: press.map(|pr| 1.0 - pr / sst),
        adeq_precision: finite((hi - lo) / (p as f64 * mse / n as f64).sqrt()),
        std_dev,
        mean,
        cv_percent: finite(100.0 * std_dev / mean),
        press,
        n_runs: n,
        n_terms: p,
        n_design_points: n_points,
    };
    if !stats.r2.is_finite() {
        return Err(FitError::Numerical("R² is not finite".to_owned()));
    }
    Ok((table, stats))
}
