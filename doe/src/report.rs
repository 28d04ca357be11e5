//! The one text rendering of an analysis, in Design-Expert's layout: the ANOVA (p below 0.0001
//! as "< 0.0001", the model and lack-of-fit verdicts), the fit statistics block, the coded
//! coefficients with their confidence intervals, the final equation, the settings predicted to
//! hit a target (the whole level set explained when the target is met on one), and a steepest
//! path. `repose analyze` renders a live [`Fit`]; the job server renders the same parts from the
//! analysis it stored as JSON (which is why the parts are plain data with `Deserialize`), so
//! `repose analyze`, `repose up` / `watch` and `?format=text` print one table one way.
//!
//! Pure: returns text, prints nothing.

use std::fmt::Write as _;

use crate::design::PathDirection;
use crate::{AnovaRow, Coefficient, EliminationStep, Fit, FitStats, ModelKind, OptimumResult};

/// The fit half of an analysis: what [`render_fit`] prints.
#[derive(Debug, Clone, Copy)]
pub struct FitText<'a> {
    /// Response name.
    pub response: &'a str,
    /// Model family, when known (a stored analysis may predate the field).
    pub model: Option<ModelKind>,
    /// Number of model terms (after any elimination).
    pub n_terms: usize,
    /// Runs fitted.
    pub n_runs: usize,
    /// Terms removed by backward elimination, in order.
    pub elimination: &'a [EliminationStep],
    /// ANOVA rows.
    pub anova: &'a [AnovaRow],
    /// Fit statistics.
    pub stats: &'a FitStats,
    /// Coefficient table (coded units).
    pub coefficients: &'a [Coefficient],
    /// Confidence level of the intervals, e.g. 0.95.
    pub confidence: f64,
}

impl<'a> FitText<'a> {
    /// The parts of a live fit of a `model` model.
    pub fn of(fit: &'a Fit, model: ModelKind) -> Self {
        FitText {
            response: fit.response(),
            model: Some(model),
            n_terms: fit.model().len(),
            n_runs: fit.n_runs(),
            elimination: fit.elimination(),
            anova: fit.anova(),
            stats: fit.stats(),
            coefficients: fit.coefficients(),
            confidence: fit.confidence(),
        }
    }
}

/// A steepest ascent or descent path: what [`render_path`] prints.
#[derive(Debug, Clone, Copy)]
pub struct PathText<'a> {
    /// Up or down the response; `None` when not recorded (older stored analyses).
    pub direction: Option<PathDirection>,
    /// Factors that move, in the order of every vector below.
    pub factors: &'a [String],
    /// The factor whose step is one coded unit.
    pub base_factor: &'a str,
    /// Increment per step, natural units.
    pub step_natural: &'a [f64],
    /// Points in natural units, the start first.
    pub points: &'a [Vec<f64>],
    /// The model's prediction at each point, when known.
    pub predicted: Option<&'a [f64]>,
}

/// The words for a model family.
pub fn model_words(model: ModelKind) -> &'static str {
    match model {
        ModelKind::Linear => "linear",
        ModelKind::TwoFactorInteraction => "two-factor interaction",
        ModelKind::Quadratic => "quadratic",
    }
}

/// A p-value as Design-Expert prints it: four decimals, "< 0.0001" below that.
pub fn format_p(p: Option<f64>) -> String {
    match p {
        Some(p) if p < 1e-4 => "< 0.0001".to_owned(),
        Some(p) => format!("{p:.4}"),
        None => String::new(),
    }
}

fn format_opt(v: Option<f64>, f: impl Fn(f64) -> String) -> String {
    v.map(f).unwrap_or_default()
}

/// Four significant digits but at least two decimals, like the paper's tables (3586.09).
pub fn sig4(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).clamp(2, 8) as usize;
    format!("{v:.digits$}")
}

/// The fit: title line, eliminated terms, ANOVA, fit statistics, coefficients, equation.
pub fn render_fit(fit: &FitText<'_>) -> String {
    let mut out = String::new();
    let stats = fit.stats;
    let model = fit.model.map_or("model", model_words);
    let _ = writeln!(
        out,
        "Response: {}   Model: {} ({} terms, {} runs)",
        fit.response, model, fit.n_terms, fit.n_runs
    );
    for step in fit.elimination {
        let _ = writeln!(out, "  eliminated {} (p = {})", step.term, format_p(step.p));
    }
    let _ = writeln!(out, "\nANOVA (partial sums of squares, Type III)");
    let _ = writeln!(
        out,
        "{:<14} {:>14} {:>4} {:>12} {:>10} {:>10}",
        "Source", "Sum of Squares", "df", "Mean Square", "F-value", "p-value"
    );
    for row in fit.anova {
        let verdict = match (row.source.as_str(), row.p) {
            ("Model" | "Lack of Fit", Some(p)) if p < 0.05 => "  significant",
            ("Model" | "Lack of Fit", Some(_)) => "  not significant",
            _ => "",
        };
        let _ = writeln!(
            out,
            "{:<14} {:>14} {:>4} {:>12} {:>10} {:>10}{}",
            row.source,
            sig4(row.sum_sq),
            row.df,
            format_opt(row.mean_sq, sig4),
            format_opt(row.f, sig4),
            format_p(row.p),
            verdict
        );
    }
    let _ = writeln!(out, "\nFit statistics");
    let lines = [
        (
            "Std. Dev.",
            sig4(stats.std_dev),
            "R²",
            format!("{:.4}", stats.r2),
        ),
        (
            "Mean",
            sig4(stats.mean),
            "Adjusted R²",
            format!("{:.4}", stats.adj_r2),
        ),
        (
            "C.V. %",
            format_opt(stats.cv_percent, |v| format!("{v:.2}")),
            "Predicted R²",
            format_opt(stats.pred_r2, |v| format!("{v:.4}")),
        ),
        (
            "PRESS",
            format_opt(stats.press, sig4),
            "Adeq Precision",
            format_opt(stats.adeq_precision, |v| format!("{v:.4}")),
        ),
    ];
    for (a, av, b, bv) in lines {
        let _ = writeln!(out, "{a:<10} {av:>10}     {b:<15} {bv:>8}");
    }
    let level = (fit.confidence * 100.0).round();
    let _ = writeln!(out, "\nCoefficients in terms of coded factors");
    let _ = writeln!(
        out,
        "{:<14} {:>10} {:>10} {:>11} {:>11} {:>8}",
        "Term",
        "Estimate",
        "Std. Error",
        format!("{level}% CI Low"),
        format!("{level}% CI High"),
        "VIF"
    );
    for c in fit.coefficients {
        let _ = writeln!(
            out,
            "{:<14} {:>10} {:>10} {:>11} {:>11} {:>8}",
            c.term,
            sig4(c.estimate),
            sig4(c.std_error),
            sig4(c.ci_low),
            sig4(c.ci_high),
            format_opt(c.vif, |v| format!("{v:.2}"))
        );
    }
    let _ = writeln!(out, "\nFinal equation in terms of coded factors");
    let mut equation = format!("{} =", fit.response);
    for c in fit.coefficients {
        let sign = if c.estimate < 0.0 { '-' } else { '+' };
        let magnitude = sig4(c.estimate.abs());
        if c.term == "Intercept" {
            let _ = write!(equation, " {sign}{magnitude}");
        } else {
            let _ = write!(equation, " {sign} {magnitude}·{}", c.term);
        }
    }
    let _ = writeln!(out, "{equation}");
    out
}

/// The settings predicted to give `response` = `target`: every solution found, and when the
/// target is met on a whole level set, what that means and how far the set reaches.
pub fn render_optimum(response: &str, target: f64, opt: &OptimumResult) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "\nSettings predicted to give {response} = {target}");
    if opt.level_set {
        let _ = writeln!(
            out,
            "The target is met on a whole level set, not at one point: {} of {} starts reached \
             desirability {:.4} at {} distinct settings spread over {:.3} coded units. \
             Listed closest to the design centre first; any of them is an equally valid answer.",
            opt.starts_at_best, opt.starts, opt.best_desirability, opt.distinct_at_best, opt.spread
        );
        let ranges: Vec<String> = opt
            .factors
            .iter()
            .zip(opt.coded_min.iter().zip(&opt.coded_max))
            .map(|(f, (low, high))| format!("{f} {low:+.3}..{high:+.3}"))
            .collect();
        let _ = writeln!(
            out,
            "Coded extent of the solutions found: {}",
            ranges.join(", ")
        );
    }
    let mut header = format!("{:>3}", "#");
    for f in &opt.factors {
        let _ = write!(header, " {:>9}", format!("{f} coded"));
    }
    let natural = opt.solutions.first().is_some_and(|s| s.natural.is_some());
    if natural {
        for f in &opt.factors {
            let _ = write!(header, " {f:>9}");
        }
    }
    let _ = writeln!(out, "{header} {:>10} {:>12}", "predicted", "desirability");
    for (i, s) in opt.solutions.iter().enumerate() {
        let mut line = format!("{:>3}", i + 1);
        for v in &s.coded {
            let _ = write!(line, " {v:>9.4}");
        }
        if let Some(nat) = &s.natural {
            for v in nat {
                let _ = write!(line, " {v:>9.4}");
            }
        }
        let predicted = s.responses.first().map(|r| r.value).unwrap_or(f64::NAN);
        let _ = writeln!(out, "{line} {predicted:>10.3} {:>12.4}", s.desirability);
    }
    out
}

/// A steepest path: its direction and base factor, the step, and one line per point.
pub fn render_path(path: &PathText<'_>, response: &str) -> String {
    let mut out = String::new();
    let name = match path.direction {
        Some(PathDirection::Ascent) => "Steepest ascent path",
        Some(PathDirection::Descent) => "Steepest descent path",
        None => "Steepest path",
    };
    let _ = writeln!(
        out,
        "\n{name} (base factor {}; the other factors stay at their centre)",
        path.base_factor
    );
    let steps: Vec<String> = path
        .factors
        .iter()
        .zip(path.step_natural)
        .map(|(f, s)| format!("{f} {s:+.4}"))
        .collect();
    let _ = writeln!(out, "Step: {}", steps.join(", "));
    let mut header = format!("{:>4}", "step");
    for f in path.factors {
        let _ = write!(header, " {f:>9}");
    }
    if path.predicted.is_some() {
        let _ = write!(header, " {:>12}", format!("predicted {response}"));
    }
    let _ = writeln!(out, "{header}");
    for (i, point) in path.points.iter().enumerate() {
        let mut line = format!("{:>4}", i + 1);
        for v in point {
            let _ = write!(line, " {v:>9.4}");
        }
        if let Some(y) = path.predicted.and_then(|p| p.get(i)) {
            let _ = write!(line, " {y:>12.3}");
        }
        let _ = writeln!(out, "{line}");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn p_values_and_numbers_read_as_in_design_expert() {
        assert_eq!(format_p(Some(1.2658e-9)), "< 0.0001");
        assert_eq!(format_p(Some(0.00421)), "0.0042");
        assert_eq!(format_p(None), "");
        assert_eq!(sig4(3586.0912), "3586.09");
        assert_eq!(sig4(0.065023), "0.06502");
        assert_eq!(sig4(734.4), "734.40");
    }

    #[test]
    fn a_path_without_predictions_has_no_prediction_column() {
        let factors = vec!["mu".to_owned(), "e".to_owned()];
        let points = vec![vec![0.4, 0.6], vec![0.5, 0.55]];
        let path = PathText {
            direction: None,
            factors: &factors,
            base_factor: "mu",
            step_natural: &[0.1, -0.05],
            points: &points,
            predicted: None,
        };
        let text = render_path(&path, "angle_deg");
        assert!(text.contains("Steepest path (base factor mu;"), "{text}");
        assert!(text.contains("Step: mu +0.1000, e -0.0500"), "{text}");
        assert!(!text.contains("predicted"), "{text}");
        let predicted = [30.0, 31.5];
        let text = render_path(
            &PathText {
                direction: Some(PathDirection::Ascent),
                predicted: Some(&predicted),
                ..path
            },
            "angle_deg",
        );
        assert!(text.contains("Steepest ascent path"), "{text}");
        assert!(text.contains("predicted angle_deg"), "{text}");
        assert!(text.contains("      31.500"), "{text}");
    }
}
