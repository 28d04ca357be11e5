//! The end-of-batch analysis: regression fit, ANOVA, optimum for the target and the
//! steepest-ascent path, plus its plain-text rendering.
//!
//! Pure computation over [`AnalysisInput`]; the caller stores the result once.

use std::fmt::Write as _;

use repose_api::{AnalysisView, ModelName};
use repose_doe::design::{direction_toward, CcdVariant, DesignKind, PathDirection, SteepestPath};
use repose_doe::{
    fit_with_options, optimize, Fit, FitOptions, Goal, Model, Objective, OptimumOptions, Region,
};
use serde_json::Value;

use crate::db::{now_ms, AnalysisInput};
use crate::submit::{model_kind, model_label};

/// Fits the batch's model to its completed runs. Never fails: a fit that cannot be computed
/// (too few completed runs, constant response, …) is reported in `error`, because the analysis
/// is stored once and must say why it is empty.
pub fn analyse(input: &AnalysisInput) -> AnalysisView {
    let names: Vec<String> = input.factors.iter().map(|f| f.name.clone()).collect();
    let mut view = AnalysisView {
        batch_id: input.batch_id,
        computed_at_ms: now_ms(),
        response: input.response.clone(),
        model: input.model,
        factors: names.clone(),
        runs_used: 0,
        fit: None,
        optimum: None,
        steepest_path: None,
        summary: None,
        error: None,
    };
    let (rows, response): (Vec<&[f64]>, Vec<f64>) = input
        .completed
        .iter()
        .filter_map(|(coded, metrics)| {
            let value = *metrics.get(&input.response)?;
            value.is_finite().then_some((coded.as_slice(), value))
        })
        .unzip();
    view.runs_used = rows.len();
    view.summary = summarise(&response, input.target);
    let Some(kind) = model_kind(input.model) else {
        if response.is_empty() {
            view.error = Some("no completed run reported the response".into());
        }
        return view;
    };
    let fitted = Model::new(&names, kind).and_then(|model| {
        let options = FitOptions {
            response_name: input.response.clone(),
            ..FitOptions::default()
        };
        fit_with_options(&model, &rows, &response, &options)
    });
    let fit = match fitted {
        Ok(fit) => fit,
        Err(err) => {
            view.error = Some(format!("fit failed: {err}"));
            return view;
        }
    };
    let mut problems = Vec::new();
    match serde_json::to_value(&fit) {
        Ok(value) => view.fit = Some(value),
        Err(err) => problems.push(format!("fit could not be serialised: {err}")),
    }
    if let Some(target) = input.target {
        match optimum_for_target(input, &fit, &response, target) {
            Ok(value) => view.optimum = Some(value),
            Err(err) => problems.push(format!("optimum: {err}")),
        }
    }
    if input.model == ModelName::Linear {
        match steepest_path(input, &fit) {
            Ok(value) => view.steepest_path = Some(value),
            Err(err) => problems.push(format!("steepest path: {err}")),
        }
    }
    if !problems.is_empty() {
        view.error = Some(problems.join("; "));
    }
    view
}

/// Mean, spread and (with a target) relative error of the observed responses.
fn summarise(observed: &[f64], target: Option<f64>) -> Option<Value> {
    if observed.is_empty() {
        return None;
    }
    let n = observed.len() as f64;
    let mean = observed.iter().sum::<f64>() / n;
    let std = if observed.len() > 1 {
        (observed.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    let min = observed.iter().copied().fold(f64::INFINITY, f64::min);
    let max = observed.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut summary = serde_json::json!({
        "n": observed.len(), "mean": mean, "std": std, "min": min, "max": max,
    });
    if let Some(target) = target.filter(|t| *t != 0.0) {
        summary["target"] = target.into();
        summary["relative_error_pct"] = (100.0 * (mean - target).abs() / target.abs()).into();
    }
    Some(summary)
}

/// Desirability search for `target`; the acceptable band spans the observed responses and the
/// target with half their spread to spare, so the desirability is informative everywhere.
fn optimum_for_target(
    input: &AnalysisInput,
    fit: &Fit,
    observed: &[f64],
    target: f64,
) -> Result<Value, String> {
    let low = observed.iter().copied().fold(target, f64::min);
    let high = observed.iter().copied().fold(target, f64::max);
    let margin = ((high - low) * 0.5).max(1e-9 * target.abs().max(1.0));
    let goal = Goal::Target {
        target,
        lower: low - margin,
        upper: high + margin,
    };
    let region = match input.design_kind {
        // Rotatable designs explore a ball; the others (and user points) the cube.
        DesignKind::CentralComposite {
            variant: CcdVariant::Circumscribed,
            alpha,
            ..
        } => Region::Sphere { radius: alpha },
        DesignKind::CentralComposite {
            variant: CcdVariant::Inscribed,
            ..
        } => Region::Sphere { radius: 1.0 },
        _ => Region::Cube,
    };
    let options = OptimumOptions {
        region,
        seed: input.base_seed,
        factor_ranges: Some(input.factors.clone()),
        ..OptimumOptions::default()
    };
    let result = optimize(&[Objective::new(fit, goal)], &options).map_err(|err| err.to_string())?;
    serde_json::to_value(result).map_err(|err| err.to_string())
}

/// Path of steepest ascent from the design centre (descent when the target lies below the
/// centre prediction).
fn steepest_path(input: &AnalysisInput, fit: &Fit) -> Result<Value, String> {
    let coefficients = input
        .factors
        .iter()
        .map(|factor| {
            fit.coefficient(&factor.name)
                .map(|c| c.estimate)
                .ok_or_else(|| format!("no coefficient for {}", factor.name))
        })
        .collect::<Result<Vec<f64>, String>>()?;
    let direction = match input.target {
        Some(target) => {
            let centre = fit
                .try_predict(&vec![0.0; input.factors.len()])
                .map_err(|err| err.to_string())?;
            direction_toward(target, centre).map_err(|err| err.to_string())?
        }
        None => PathDirection::Ascent,
    };
    let path = SteepestPath::spec(coefficients, input.factors.clone(), direction)
        .build()
        .map_err(|err| err.to_string())?;
    serde_json::to_value(path).map_err(|err| err.to_string())
}

/// Plain-text report: coefficients, ANOVA, fit statistics, optimum and path.
pub fn render_text(view: &AnalysisView) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Analysis of batch {}\nresponse: {}   model: {}   factors: {}   runs used: {}",
        view.batch_id,
        view.response,
        model_label(view.model),
        view.factors.join(", "),
        view.runs_used
    );
    if let Some(error) = &view.error {
        let _ = writeln!(out, "note: {error}");
    }
    if let Some(summary) = &view.summary {
        let number = |key: &str| summary.get(key).and_then(Value::as_f64);
        let _ = write!(
            out,
            "\n{}: mean {:.4}, std {:.4}, min {:.4}, max {:.4} over {} runs",
            view.response,
            number("mean").unwrap_or(f64::NAN),
            number("std").unwrap_or(f64::NAN),
            number("min").unwrap_or(f64::NAN),
            number("max").unwrap_or(f64::NAN),
            view.runs_used
        );
        if let (Some(target), Some(error)) = (number("target"), number("relative_error_pct")) {
            let _ = write!(
                out,
                "; target {target}, relative error of the mean {error:.2} %"
            );
        }
        let _ = writeln!(out);
    }
    if let Some(fit) = &view.fit {
        let _ = writeln!(out, "\nCoefficients (coded units)");
        let _ = writeln!(
            out,
            "{:<16} {:>12} {:>12} {:>10}",
            "term", "estimate", "std error", "p"
        );
        for c in array(fit, "coefficients") {
            let _ = writeln!(
                out,
                "{:<16} {:>12} {:>12} {:>10}",
                text(c, "term"),
                number(c, "estimate"),
                number(c, "std_error"),
                number(c, "p_value")
            );
        }
        let _ = writeln!(out, "\nANOVA");
        let _ = writeln!(
            out,
            "{:<16} {:>12} {:>4} {:>12} {:>10} {:>10}",
            "source", "sum sq", "df", "mean sq", "F", "p"
        );
        for row in array(fit, "anova") {
            let _ = writeln!(
                out,
                "{:<16} {:>12} {:>4} {:>12} {:>10} {:>10}",
                text(row, "source"),
                number(row, "sum_sq"),
                row.get("df").map(Value::to_string).unwrap_or_default(),
                number(row, "mean_sq"),
                number(row, "f"),
                number(row, "p")
            );
        }
        if let Some(stats) = fit.get("stats") {
            let _ = writeln!(
                out,
                "\nR² {}   adjusted R² {}   predicted R² {}   std dev {}",
                number(stats, "r2"),
                number(stats, "adj_r2"),
                number(stats, "pred_r2"),
                number(stats, "std_dev")
            );
        }
    }
    if let Some(optimum) = &view.optimum {
        let best_desirability = number(optimum, "best_desirability");
        let _ = writeln!(out, "\nOptimum (best desirability {best_desirability})");
        if let Some(best) = array(optimum, "solutions").first() {
            let natural = best.get("natural").and_then(Value::as_array);
            for (i, name) in view.factors.iter().enumerate() {
                let value = natural
                    .and_then(|n| n.get(i))
                    .map(|v| format_number(v.as_f64()))
                    .unwrap_or_default();
                let _ = writeln!(out, "  {name:<14} {value:>12}");
            }
            for response in array(best, "responses") {
                let _ = writeln!(
                    out,
                    "  predicted {} = {}",
                    text(response, "name"),
                    number(response, "value")
                );
            }
        }
    }
    if let Some(path) = &view.steepest_path {
        let _ = writeln!(out, "\nSteepest path (natural units)");
        let _ = writeln!(out, "step  {}", view.factors.join("  "));
        for (step, point) in array(path, "points").iter().enumerate() {
            let values: Vec<String> = point
                .as_array()
                .map(|p| p.iter().map(|v| format_number(v.as_f64())).collect())
                .unwrap_or_default();
            let _ = writeln!(out, "{step:<5} {}", values.join("  "));
        }
    }
    out
}

fn array<'v>(value: &'v Value, key: &str) -> &'v [Value] {
    value
        .get(key)
        .and_then(Value::as_array)
        .map(Vec::as_slice)
        .unwrap_or(&[])
}

fn text(value: &Value, key: &str) -> String {
    value
        .get(key)
        .and_then(Value::as_str)
        .unwrap_or("")
        .to_owned()
}

fn number(value: &Value, key: &str) -> String {
    format_number(value.get(key).and_then(Value::as_f64))
}

fn format_number(value: Option<f64>) -> String {
    match value {
        Some(v) if v != 0.0 && (v.abs() >= 1e5 || v.abs() < 1e-3) => format!("{v:.4e}"),
        Some(v) => format!("{v:.4}"),
        None => "-".to_owned(),
    }
}
