//! Per-run residual diagnostics (Design-Expert's "Diagnostics Case
//! Statistics"): what a user looks at to find outliers and influential runs
//! before trusting a model.

use nalgebra::DVector;
use serde::Serialize;

use crate::anova::LEVERAGE_ONE;
use crate::fit::Ols;

/// Diagnostics of one run. Studentised residuals and Cook's distance are
/// `None` where they are undefined (leverage 1, or no degrees of freedom left
/// for the deleted-run variance).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunDiagnostics {
    /// 1-based run number (position in the input).
    pub run: usize,
    /// Observed response.
    pub actual: f64,
    /// Fitted value.
    pub predicted: f64,
    /// `actual - predicted`.
    pub residual: f64,
    /// Diagonal of the hat matrix.
    pub leverage: f64,
    /// `e / (s·sqrt(1-h))`.
    pub internally_studentized: Option<f64>,
    /// `e / (s_(i)·sqrt(1-h))` with the run-deleted standard deviation.
    pub externally_studentized: Option<f64>,
    /// `r² h / (p (1-h))` with `r` internally studentised.
    pub cooks_distance: Option<f64>,
}

pub(crate) fn run_diagnostics(
    y: &DVector<f64>,
    full: &Ols,
    p: usize,
    df_res: usize,
) -> Vec<RunDiagnostics> {
    let mse = full.sse / df_res as f64;
    let s = mse.sqrt();
    (0..y.len())
        .map(|i| {
            let e = full.resid[i];
            let h = full.leverage[i];
            let ok = h < LEVERAGE_ONE && s > 0.0;
            let one_h = 1.0 - h;
            let r = ok.then(|| e / (s * one_h.sqrt()));
            let ext = if ok && df_res > 1 {
                let s2_del = (full.sse - e * e / one_h) / (df_res - 1) as f64;
                (s2_del > 0.0).then(|| e / (s2_del * one_h).sqrt())
            } else {
                None
            };
            RunDiagnostics {
                run: i + 1,
                actual: y[i],
                predicted: full.fitted[i],
                residual: e,
                leverage: h,
                internally_studentized: r,
                externally_studentized: ext,
                cooks_distance: r.map(|r| r * r * h / (p as f64 * one_h)),
            }
        })
        .collect()
}
