//! `repose analyze`: fit a response-surface model to a run table, print the ANOVA, the fit
//! statistics, the coefficients and (with `--target`) the factor settings that hit the target.

use crate::levels::{levels_for, parse_levels};
use crate::table::RunTable;
use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use repose_doe::design::Factor;
use repose_doe::{
    fit_with_options, optimize, AnovaRow, Coefficient, Fit, FitOptions, Goal, Model, ModelKind,
    Objective, OptimumOptions, OptimumResult, Region,
};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
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
    #[arg(long, value_enum, default_value = "text")]
    pub format: TextOrJson,
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
}

pub fn run(args: &AnalyzeArgs) -> Result<()> {
    let table = RunTable::read(&args.input)?;
    let factors = factor_columns(args, &table)?;
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

    let kind = match args.model {
        ModelArg::Linear => ModelKind::Linear,
        ModelArg::TwoFi => ModelKind::TwoFactorInteraction,
        ModelArg::Quadratic => ModelKind::Quadratic,
    };
    let model = Model::new(&factors, kind)?;
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
            };
            println!("{}", serde_json::to_string_pretty(&json)?);
        }
        TextOrJson::Text => print!("{}", render_text(&fit, args, optimum.as_ref())),
    }
    Ok(())
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

fn fmt_p(p: Option<f64>) -> String {
    match p {
        Some(p) if p < 1e-4 => "< 0.0001".to_owned(),
        Some(p) => format!("{p:.4}"),
        None => String::new(),
    }
}

fn fmt_opt(v: Option<f64>, f: impl Fn(f64) -> String) -> String {
    v.map(f).unwrap_or_default()
}

/// Four significant digits but at least two decimals, like the paper's tables (3586.09).
fn sig4(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (3 - v.abs().log10().floor() as i32).clamp(2, 8) as usize;
    format!("{v:.digits$}")
}

fn render_text(fit: &Fit, args: &AnalyzeArgs, optimum: Option<&OptimumResult>) -> String {
    let mut out = String::new();
    let stats = fit.stats();
    let model_name = match args.model {
        ModelArg::Linear => "linear",
        ModelArg::TwoFi => "two-factor interaction",
        ModelArg::Quadratic => "quadratic",
    };
    let _ = writeln!(
        out,
        "Response: {}   Model: {} ({} terms, {} runs)",
        fit.response(),
        model_name,
        fit.model().len(),
        fit.n_runs()
    );
    for step in fit.elimination() {
        let _ = writeln!(out, "  eliminated {} (p = {})", step.term, fmt_p(step.p));
    }
    let _ = writeln!(out, "\nANOVA (partial sums of squares, Type III)");
    let _ = writeln!(
        out,
        "{:<14} {:>14} {:>4} {:>12} {:>10} {:>10}",
        "Source", "Sum of Squares", "df", "Mean Square", "F-value", "p-value"
    );
    for row in fit.anova() {
        let verdict = match (row.source.as_str(), row.p) {
            ("Model", Some(p)) => {
                if p < 0.05 {
                    "  significant"
                } else {
                    "  not significant"
                }
            }
            ("Lack of Fit", Some(p)) => {
                if p < 0.05 {
                    "  significant"
                } else {
                    "  not significant"
                }
            }
            _ => "",
        };
        let _ = writeln!(
            out,
            "{:<14} {:>14} {:>4} {:>12} {:>10} {:>10}{}",
            row.source,
            sig4(row.sum_sq),
            row.df,
            fmt_opt(row.mean_sq, sig4),
            fmt_opt(row.f, sig4),
            fmt_p(row.p),
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
            fmt_opt(stats.cv_percent, |v| format!("{v:.2}")),
            "Predicted R²",
            fmt_opt(stats.pred_r2, |v| format!("{v:.4}")),
        ),
        (
            "PRESS",
            fmt_opt(stats.press, sig4),
            "Adeq Precision",
            fmt_opt(stats.adeq_precision, |v| format!("{v:.4}")),
        ),
    ];
    for (a, av, b, bv) in lines {
        let _ = writeln!(out, "{a:<10} {av:>10}     {b:<15} {bv:>8}");
    }
    let level = (fit.confidence() * 100.0).round();
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
    for c in fit.coefficients() {
        let _ = writeln!(
            out,
            "{:<14} {:>10} {:>10} {:>11} {:>11} {:>8}",
            c.term,
            sig4(c.estimate),
            sig4(c.std_error),
            sig4(c.ci_low),
            sig4(c.ci_high),
            fmt_opt(c.vif, |v| format!("{v:.2}"))
        );
    }
    let _ = writeln!(out, "\nFinal equation in terms of coded factors");
    let mut equation = format!("{} =", fit.response());
    for c in fit.coefficients() {
        let sign = if c.estimate < 0.0 { '-' } else { '+' };
        let magnitude = sig4(c.estimate.abs());
        if c.term == "Intercept" {
            let _ = write!(equation, " {sign}{magnitude}");
        } else {
            let _ = write!(equation, " {sign} {magnitude}·{}", c.term);
        }
    }
    let _ = writeln!(out, "{equation}");

    if let (Some(opt), Some(target)) = (optimum, args.target) {
        let _ = writeln!(
            out,
            "\nSettings predicted to give {} = {target}",
            fit.response()
        );
        if opt.level_set {
            let _ = writeln!(
                out,
                "The target is met on a whole level set, not at one point: {} of {} starts reached \
                 desirability {:.4} at {} distinct settings spread over {:.3} coded units. \
                 Listed closest to the design centre first; any of them is an equally valid answer.",
                opt.starts_at_best,
                opt.starts,
                opt.best_desirability,
                opt.distinct_at_best,
                opt.spread
            );
            let ranges: Vec<String> = opt
                .factors
                .iter()
                .enumerate()
                .map(|(i, f)| format!("{f} {:+.3}..{:+.3}", opt.coded_min[i], opt.coded_max[i]))
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
    }
    out
}
