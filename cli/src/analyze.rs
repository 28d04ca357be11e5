//! `repose analyze`: fit a response-surface model to a run table, print the ANOVA, the fit
//! statistics, the coefficients and (with `--target`) the factor settings that hit the target.

use crate::levels::{levels_for, parse_levels};
use crate::table::RunTable;
use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use repose_doe::design::{direction_toward, Factor, PathClamp, PathDirection, SteepestPath};
use repose_doe::report;
use repose_doe::{
    fit_with_options, optimize, AnovaRow, Coefficient, Fit, FitOptions, Goal, Model, ModelKind,
    Objective, OptimumOptions, OptimumResult, Region,
};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum ModelArg {
    Linear,
    #[value(name = "2fi")]
    TwoFi,
    Quadratic,
}

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum TextOrJson {
    Text,
    Json,
}

/// Columns that describe a run rather than a factor, skipped when `--factors` is not given.
const BOOKKEEPING_COLUMNS: &[&str] = &[
    "run",
    "std_order",
    "step",
    "replicate",
    "seed",
    "relative_error_pct",
];

#[derive(Debug, Args)]
pub struct AnalyzeArgs {
    /// Run table (CSV with a header row): factor columns and a response column.
    #[arg(long)]
    pub input: PathBuf,
    /// Name of the response column.
    #[arg(long)]
    pub response: String,
    /// Model to fit.
    #[arg(long, value_enum, default_value = "quadratic")]
    pub model: ModelArg,
    /// Factor columns, comma-separated. Default: every column except the response and
    /// bookkeeping columns (run, std_order, step, replicate, seed, relative_error_pct,
    /// *_natural).
    #[arg(long, value_delimiter = ',')]
    pub factors: Option<Vec<String>>,
    /// The factor columns hold natural values with these ranges (NAME=LOW:HIGH,...);
    /// they are coded to -1..+1 before fitting, as Design-Expert does.
    #[arg(long, conflicts_with = "report_levels")]
    pub levels: Option<String>,
    /// The factor columns are coded; these ranges (NAME=LOW:HIGH,...) are used only to
    /// report the optimum in natural units.
    #[arg(long)]
    pub report_levels: Option<String>,
    /// Search the factor settings whose prediction hits this response value.
    #[arg(long)]
    pub target: Option<f64>,
    /// Search region radius for rotatable designs (coded units); default: the cube [-1, 1]^k.
    #[arg(long)]
    pub sphere_radius: Option<f64>,
    /// Backward elimination: drop terms with p above this, keeping the model hierarchical.
    #[arg(long)]
    pub eliminate: Option<f64>,
    /// Lay out a steepest ascent/descent path with this many steps (linear model; needs
    /// --levels or --report-levels). Only factors significant at --alpha move; the others stay
    /// at their centre, as in the paper.
    #[arg(long)]
    pub path_steps: Option<usize>,
    /// Where the path starts: the design centre, or the corner it moves away from.
    #[arg(long, value_enum, default_value = "centre")]
    pub path_start: PathStart,
    /// Force the direction; by default the path heads toward --target from the start point.
    #[arg(long, value_enum)]
    pub path_direction: Option<PathDirectionArg>,
    /// Round the non-base steps to this many decimals (the paper rounds to 2).
    #[arg(long)]
    pub path_round: Option<u32>,
    /// Significance level for choosing the path's factors.
    #[arg(long, default_value_t = 0.05)]
    pub alpha: f64,
    #[arg(long, value_enum, default_value = "text")]
    pub format: TextOrJson,
}

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum PathStart {
    Centre,
    Corner,
}

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum PathDirectionArg {
    Ascent,
    Descent,
}

/// A steepest ascent/descent path with the model's prediction at every point.
#[derive(Debug, Serialize)]
struct PathReport {
    direction: PathDirection,
    factors: Vec<String>,
    base_factor: String,
    step_natural: Vec<f64>,
    points: Vec<Vec<f64>>,
    predicted: Vec<f64>,
}

/// The JSON document `--format json` prints.
#[derive(Debug, Serialize)]
struct AnalysisJson<'a> {
    response: &'a str,
    factors: &'a [String],
    model: Vec<String>,
    runs: usize,
    coefficients: BTreeMap<String, f64>,
    coefficient_table: &'a [Coefficient],
    anova: &'a [AnovaRow],
    r2: f64,
    adj_r2: f64,
    pred_r2: Option<f64>,
    adeq_precision: Option<f64>,
    std_dev: f64,
    mean: f64,
    cv_percent: Option<f64>,
    press: Option<f64>,
    diagnostics: &'a [repose_doe::RunDiagnostics],
    eliminated: &'a [repose_doe::EliminationStep],
    #[serde(skip_serializing_if = "Option::is_none")]
    optimum: Option<&'a OptimumResult>,
    #[serde(skip_serializing_if = "Option::is_none")]
    steepest_path: Option<&'a PathReport>,
}

pub fn run(args: &AnalyzeArgs) -> Result<()> {
    let table = RunTable::read(&args.input)?;
    print!("{}", analyze_table(&table, args)?);
    Ok(())
}

/// The whole analysis of a table already read, as the text to print.
pub fn analyze_table(table: &RunTable, args: &AnalyzeArgs) -> Result<String> {
    let factors = factor_columns(args, table)?;
    let response = table.column(&args.response)?;

    let levels = args.levels.as_deref().map(parse_levels).transpose()?;
    let report_levels = args
        .report_levels
        .as_deref()
        .map(parse_levels)
        .transpose()?;
    let ranges: Option<Vec<Factor>> = levels
        .as_deref()
        .or(report_levels.as_deref())
        .map(|l| levels_for(&factors, l))
        .transpose()?;

    let mut runs = vec![Vec::with_capacity(factors.len()); table.rows.len()];
    for (i, name) in factors.iter().enumerate() {
        let column = table.column(name)?;
        for (r, value) in column.into_iter().enumerate() {
            let coded = match &levels {
                // --levels: the column is natural; code it with that factor's range.
                Some(_) => ranges.as_ref().expect("ranges come with levels")[i].to_coded(value)?,
                None => value,
            };
            runs[r].push(coded);
        }
    }

    let model = Model::new(&factors, model_kind(args.model))?;
    let options = FitOptions {
        response_name: args.response.clone(),
        backward_alpha: args.eliminate,
        ..FitOptions::default()
    };
    let fit = fit_with_options(&model, &runs, &response, &options)?;

    let optimum = match args.target {
        Some(target) => Some(search_target(
            &fit,
            target,
            &response,
            ranges.as_deref(),
            args,
        )?),
        None => None,
    };

    let path = match args.path_steps {
        Some(steps) => Some(steepest_path(&fit, steps, ranges.as_deref(), args)?),
        None => None,
    };

    match args.format {
        TextOrJson::Json => {
            let stats = fit.stats();
            let json = AnalysisJson {
                response: &args.response,
                factors: &factors,
                model: fit.model().term_names(),
                runs: fit.n_runs(),
                coefficients: fit.coefficient_map(),
                coefficient_table: fit.coefficients(),
                anova: fit.anova(),
                r2: stats.r2,
                adj_r2: stats.adj_r2,
                pred_r2: stats.pred_r2,
                adeq_precision: stats.adeq_precision,
                std_dev: stats.std_dev,
                mean: stats.mean,
                cv_percent: stats.cv_percent,
                press: stats.press,
                diagnostics: fit.diagnostics(),
                eliminated: fit.elimination(),
                optimum: optimum.as_ref(),
                steepest_path: path.as_ref(),
            };
            Ok(serde_json::to_string_pretty(&json)? + "\n")
        }
        TextOrJson::Text => {
            let mut text = render_text(&fit, args, optimum.as_ref());
            if let Some(path) = &path {
                text += &render_path(path, fit.response());
            }
            Ok(text)
        }
    }
}

fn factor_columns(args: &AnalyzeArgs, table: &RunTable) -> Result<Vec<String>> {
    let factors: Vec<String> = match &args.factors {
        Some(f) => f.iter().map(|s| s.trim().to_owned()).collect(),
        None => table
            .headers
            .iter()
            .filter(|h| {
                **h != args.response
                    && !BOOKKEEPING_COLUMNS.contains(&h.as_str())
                    && !h.ends_with("_natural")
            })
            .cloned()
            .collect(),
    };
    if factors.is_empty() {
        bail!("no factor columns: the table has only the response column");
    }
    for f in &factors {
        table.index_of(f)?;
        if *f == args.response {
            bail!("--factors: '{f}' is the response column");
        }
    }
    Ok(factors)
}

/// Derringer-Suich search for the target inside the design region. The desirability falls to
/// zero at the observed response range (widened to include the target), as Design-Expert does.
fn search_target(
    fit: &Fit,
    target: f64,
    observed: &[f64],
    ranges: Option<&[Factor]>,
    args: &AnalyzeArgs,
) -> Result<OptimumResult> {
    if !target.is_finite() {
        bail!("--target must be a finite number");
    }
    let (min, max) = observed
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| {
            (a.min(y), b.max(y))
        });
    let span = (max - min).max(f64::EPSILON);
    let goal = Goal::Target {
        target,
        lower: min.min(target) - 0.05 * span,
        upper: max.max(target) + 0.05 * span,
    };
    let region = match args.sphere_radius {
        Some(radius) if radius.is_finite() && radius > 0.0 => Region::Sphere { radius },
        Some(radius) => bail!("--sphere-radius must be a positive number, got {radius}"),
        None => Region::Cube,
    };
    let options = OptimumOptions {
        region,
        factor_ranges: ranges.map(<[Factor]>::to_vec),
        ..OptimumOptions::default()
    };
    Ok(optimize(&[Objective::new(fit, goal)], &options)?)
}

/// Montgomery's path from a first-order fit, over the significant factors only.
fn steepest_path(
    fit: &Fit,
    steps: usize,
    ranges: Option<&[Factor]>,
    args: &AnalyzeArgs,
) -> Result<PathReport> {
    if !matches!(args.model, ModelArg::Linear) {
        bail!("--path-steps needs a first-order model (--model linear)");
    }
    let Some(ranges) = ranges else {
        bail!("--path-steps needs the natural ranges (--levels or --report-levels)");
    };
    if !(args.alpha > 0.0 && args.alpha < 1.0) {
        bail!("--alpha must be in (0, 1), got {}", args.alpha);
    }
    let factors = fit.model().factors();
    let moving: Vec<usize> = (0..factors.len())
        .filter(|&i| {
            fit.term_anova(&factors[i])
                .and_then(|row| row.p)
                .is_some_and(|p| p < args.alpha)
        })
        .collect();
    if moving.is_empty() {
        bail!(
            "no factor is significant at alpha = {}: there is no direction to follow",
            args.alpha
        );
    }
    let coefficient = |i: usize| fit.coefficient(&factors[i]).map_or(0.0, |c| c.estimate);
    let coefficients: Vec<f64> = moving.iter().map(|&i| coefficient(i)).collect();
    let path_factors: Vec<Factor> = moving.iter().map(|&i| ranges[i].clone()).collect();

    // The coded point of the whole model for coded values of the moving factors.
    let full_point = |coded_moving: &[f64]| {
        let mut x = vec![0.0; factors.len()];
        for (slot, &i) in moving.iter().enumerate() {
            x[i] = coded_moving[slot];
        }
        x
    };
    let direction = |start_coded: &[f64]| -> Result<PathDirection> {
        Ok(match (args.path_direction, args.target) {
            (Some(PathDirectionArg::Ascent), _) => PathDirection::Ascent,
            (Some(PathDirectionArg::Descent), _) => PathDirection::Descent,
            (None, Some(target)) => {
                direction_toward(target, fit.predict(&full_point(start_coded)))?
            }
            (None, None) => bail!("--path-steps needs --target or --path-direction"),
        })
    };
    let centre = vec![0.0; moving.len()];
    let dir = direction(&centre)?;
    let mut spec = SteepestPath::spec(coefficients.clone(), path_factors.clone(), dir)
        .steps(steps)
        .clamp(PathClamp::FactorRange);
    if args.path_start == PathStart::Corner {
        // Start where the path leaves the region: each factor at the end it moves away from.
        let start = coefficients
            .iter()
            .zip(&path_factors)
            .map(|(b, f)| if b * dir.sign() >= 0.0 { f.low } else { f.high })
            .collect();
        spec = spec.start_at(start);
    }
    if let Some(decimals) = args.path_round {
        spec = spec.round_steps_to(decimals);
    }
    let path = spec.build()?;
    let predicted = path
        .coded_points
        .iter()
        .map(|c| fit.predict(&full_point(c)))
        .collect();
    Ok(PathReport {
        direction: dir,
        base_factor: path.factor_names[path.base_factor].clone(),
        factors: path.factor_names,
        step_natural: path.step_natural,
        points: path.points,
        predicted,
    })
}

/// The path as the one analysis renderer prints it.
fn render_path(path: &PathReport, response: &str) -> String {
    report::render_path(
        &report::PathText {
            direction: Some(path.direction),
            factors: &path.factors,
            base_factor: &path.base_factor,
            step_natural: &path.step_natural,
            points: &path.points,
            predicted: Some(&path.predicted),
        },
        response,
    )
}

/// The fit and the settings for the target, as the one analysis renderer
/// ([`repose_doe::report`], shared with the job server) prints them.
fn render_text(fit: &Fit, args: &AnalyzeArgs, optimum: Option<&OptimumResult>) -> String {
    let mut out = report::render_fit(&report::FitText::of(fit, model_kind(args.model)));
    if let (Some(opt), Some(target)) = (optimum, args.target) {
        out += &report::render_optimum(fit.response(), target, opt);
    }
    out
}

fn model_kind(model: ModelArg) -> ModelKind {
    match model {
        ModelArg::Linear => ModelKind::Linear,
        ModelArg::TwoFi => ModelKind::TwoFactorInteraction,
        ModelArg::Quadratic => ModelKind::Quadratic,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn args(model: ModelArg, target: Option<f64>) -> AnalyzeArgs {
        AnalyzeArgs {
            input: PathBuf::from("unused.csv"),
            response: "y".into(),
            model,
            factors: None,
            levels: None,
            report_levels: None,
            target,
            sphere_radius: None,
            eliminate: None,
            path_steps: None,
            path_start: PathStart::Centre,
            path_direction: None,
            path_round: None,
            alpha: 0.05,
            format: TextOrJson::Json,
        }
    }

    /// A cell as a lab's hand-edited spreadsheet might hold it.
    fn cell() -> impl Strategy<Value = String> {
        prop_oneof![
            40 => (-3i32..=3).prop_map(|v| v.to_string()),
            20 => (-1e3f64..1e3).prop_map(|v| v.to_string()),
            1 => Just("NaN".to_owned()),
            1 => Just("inf".to_owned()),
            1 => Just(String::new()),
            1 => Just("n/a".to_owned()),
            1 => Just("1e400".to_owned()),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// Whatever the table holds, the analysis returns Ok or an error; it never panics.
        #[test]
        fn random_tables_never_panic(
            columns in 1usize..5,
            cells in proptest::collection::vec(proptest::collection::vec(cell(), 5), 0..14),
            model in prop_oneof![Just(ModelArg::Linear), Just(ModelArg::TwoFi), Just(ModelArg::Quadratic)],
            target in proptest::option::of(-50.0f64..50.0),
        ) {
            let names = ["A", "B", "C", "D", "y"];
            let mut csv = names[5 - columns..].join(",");
            csv.push('\n');
            for row in &cells {
                csv += &row[5 - columns..].join(",");
                csv.push('\n');
            }
            if let Ok(table) = RunTable::parse(csv.as_bytes()) {
                let _ = analyze_table(&table, &args(model, target));
            }
        }

        /// Random bytes as a CSV file: parsing fails cleanly or yields a table.
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            if let Ok(table) = RunTable::parse(&bytes) {
                let _ = analyze_table(&table, &args(ModelArg::Linear, Some(1.0)));
            }
        }
    }
}
