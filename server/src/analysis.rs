//! The end-of-batch analysis: regression fit, ANOVA, optimum for the target and the
//! steepest-ascent path, plus its plain-text rendering.
//!
//! Pure computation over [`AnalysisInput`]; the caller stores the result once.

use std::fmt::Write as _;

use repose_api::{AnalysisView, ModelName};
use repose_doe::design::{direction_toward, CcdVariant, DesignKind, PathDirection, SteepestPath};
use repose_doe::report::{self, sig4};
use repose_doe::{
    fit_with_options, optimize, AnovaRow, Coefficient, EliminationStep, Fit, FitOptions, FitStats,
    Goal, Model, Objective, OptimumOptions, OptimumResult, Region,
};
use serde::Deserialize;
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
    if let Some(target) = target {
        summary["target"] = target.into();
        if target != 0.0 {
            summary["relative_error_pct"] = (100.0 * (mean - target).abs() / target.abs()).into();
        }
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
    let predicted = path
        .coded_points
        .iter()
        .map(|point| fit.try_predict(point))
        .collect::<Result<Vec<f64>, _>>()
        .map_err(|err| err.to_string())?;
    let mut value = serde_json::to_value(path).map_err(|err| err.to_string())?;
    // Beside the path itself: which way it goes and what the model predicts along it, for the
    // text rendering.
    value["direction"] = serde_json::to_value(direction).map_err(|err| err.to_string())?;
    value["predicted"] = predicted.into();
    Ok(value)
}

/// The stored fit, read back for [`render_text`]: the parts the one renderer prints.
#[derive(Debug, Deserialize)]
struct StoredFit {
    response: String,
    model: StoredModel,
    n_runs: usize,
    coefficients: Vec<Coefficient>,
    anova: Vec<AnovaRow>,
    stats: FitStats,
    #[serde(default)]
    elimination: Vec<EliminationStep>,
    confidence: f64,
}

#[derive(Debug, Deserialize)]
struct StoredModel {
    terms: Vec<String>,
}

/// The stored steepest path with the direction and predictions [`steepest_path`] adds.
#[derive(Debug, Deserialize)]
struct StoredPath {
    factor_names: Vec<String>,
    base_factor: usize,
    step_natural: Vec<f64>,
    points: Vec<Vec<f64>>,
    #[serde(default)]
    direction: Option<PathDirection>,
    #[serde(default)]
    predicted: Option<Vec<f64>>,
}

/// Plain-text report (`?format=text`, what `repose up` and `repose watch` print): the batch and
/// its response summary, then the fit, the settings for the target and the path exactly as
/// `repose analyze` prints them ([`repose_doe::report`], the one renderer).
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
    let number = |key: &str| {
        view.summary
            .as_ref()
            .and_then(|summary| summary.get(key))
            .and_then(Value::as_f64)
    };
    if view.summary.is_some() {
        let _ = write!(
            out,
            "{}: mean {}, std {}, min {}, max {} over {} runs",
            view.response,
            sig4(number("mean").unwrap_or(f64::NAN)),
            sig4(number("std").unwrap_or(f64::NAN)),
            sig4(number("min").unwrap_or(f64::NAN)),
            sig4(number("max").unwrap_or(f64::NAN)),
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
    let fit = view.fit.as_ref().map(StoredFit::deserialize);
    match &fit {
        Some(Ok(fit)) => {
            out.push('\n');
            out += &report::render_fit(&report::FitText {
                response: &fit.response,
                model: model_kind(view.model),
                n_terms: fit.model.terms.len(),
                n_runs: fit.n_runs,
                elimination: &fit.elimination,
                anova: &fit.anova,
                stats: &fit.stats,
                coefficients: &fit.coefficients,
                confidence: fit.confidence,
            });
        }
        Some(Err(err)) => {
            let _ = writeln!(out, "\nthe stored fit could not be read: {err}");
        }
        None => {}
    }
    let optimum = view
        .optimum
        .as_ref()
        .and_then(|value| OptimumResult::deserialize(value).ok());
    if let (Some(optimum), Some(target)) = (optimum, number("target")) {
        out += &report::render_optimum(&view.response, target, &optimum);
    }
    let path = view
        .steepest_path
        .as_ref()
        .and_then(|value| StoredPath::deserialize(value).ok());
    if let Some(path) = path {
        let base = path
            .factor_names
            .get(path.base_factor)
            .map_or("?", String::as_str);
        out += &report::render_path(
            &report::PathText {
                direction: path.direction,
                factors: &path.factor_names,
                base_factor: base,
                step_natural: &path.step_natural,
                points: &path.points,
                predicted: path.predicted.as_deref(),
            },
            &view.response,
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use repose_api::BatchState;
    use repose_doe::design::{DesignKind, Factor};
    use repose_doe::ModelKind;
    use uuid::Uuid;

    use super::*;

    /// A 2² factorial with centre points, y = 30 + 4 mu − 1.5 e + a little noise.
    fn input(target: Option<f64>) -> AnalysisInput {
        let points = [
            [-1.0, -1.0],
            [1.0, -1.0],
            [-1.0, 1.0],
            [1.0, 1.0],
            [0.0, 0.0],
            [0.0, 0.0],
            [0.0, 0.0],
        ];
        let noise = [0.05, -0.03, 0.02, -0.04, 0.01, -0.02, 0.03];
        AnalysisInput {
            batch_id: Uuid::nil(),
            state: BatchState::Completed,
            factors: vec![
                Factor::new("mu", 0.2, 0.6).unwrap(),
                Factor::new("e", 0.3, 0.9).unwrap(),
            ],
            design_kind: DesignKind::FullFactorial,
            response: "angle_deg".into(),
            model: ModelName::Linear,
            target,
            base_seed: 7,
            completed: points
                .iter()
                .zip(noise)
                .map(|(x, n)| {
                    let y = 30.0 + 4.0 * x[0] - 1.5 * x[1] + n;
                    (x.to_vec(), BTreeMap::from([("angle_deg".to_owned(), y)]))
                })
                .collect(),
        }
    }

    #[test]
    fn the_text_form_is_the_one_renderer_over_the_stored_analysis() {
        let input = input(Some(33.0));
        let view = analyse(&input);
        assert_eq!(view.error, None);
        // As stored and read back by the database.
        let stored: AnalysisView =
            serde_json::from_str(&serde_json::to_string(&view).unwrap()).unwrap();
        let text = render_text(&stored);

        // The same fit, live, rendered as `repose analyze` renders it.
        let (rows, response): (Vec<&[f64]>, Vec<f64>) = input
            .completed
            .iter()
            .map(|(x, m)| (x.as_slice(), m["angle_deg"]))
            .unzip();
        let model = Model::new(&["mu", "e"], ModelKind::Linear).unwrap();
        let options = FitOptions {
            response_name: "angle_deg".into(),
            ..FitOptions::default()
        };
        let fit = fit_with_options(&model, &rows, &response, &options).unwrap();
        let expected = report::render_fit(&report::FitText::of(&fit, ModelKind::Linear));
        assert!(text.contains(&expected), "{text}\n---\n{expected}");
        assert!(expected.contains("< 0.0001"), "{expected}");
        assert!(text.contains("Fit statistics\nStd. Dev."), "{text}");
        assert!(
            text.contains("\nSettings predicted to give angle_deg = 33\n"),
            "{text}"
        );
        assert!(
            text.contains("The target is met on a whole level set"),
            "a two-factor plane meets a target on a line: {text}"
        );
        assert!(
            text.contains("\nSteepest ascent path (base factor mu;"),
            "{text}"
        );
        assert!(text.contains("predicted angle_deg"), "{text}");
    }

    #[test]
    fn a_target_of_zero_is_kept_for_the_text_form() {
        let summary = summarise(&[1.0, 2.0], Some(0.0)).unwrap();
        assert_eq!(summary["target"], 0.0);
        assert!(summary.get("relative_error_pct").is_none());
    }
}
