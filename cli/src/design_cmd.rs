//! `repose design <kind>`: generate a design and print it with coded (and natural) columns.

use crate::levels::{levels_for, parse_levels};
use crate::table::RunTable;
use anyhow::{anyhow, bail, Context, Result};
use clap::{Args, ValueEnum};
use repose_doe::design::{
    box_behnken, central_composite, default_box_behnken_centre_points, full_factorial,
    plackett_burman, replicate, smallest_plackett_burman_runs, CcdVariant, Design, Factor,
};
use serde::Serialize;
use std::path::PathBuf;

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum DesignKindArg {
    /// Two-level full factorial (2^k runs).
    Factorial,
    /// Plackett-Burman screening design (8, 12, 16, 20 or 24 runs).
    Pb,
    /// Box-Behnken response-surface design (3 to 7 factors).
    Bbd,
    /// Central composite design (see --ccd).
    Ccd,
    /// A run matrix you supply in coded units (--input CSV whose columns are the factors).
    Custom,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum CcdArg {
    /// Rotatable, star points at ±(2^k)^(1/4) outside the cube.
    Circumscribed,
    /// Star points on the cube faces (alpha = 1).
    FaceCentred,
    /// Rotatable, shrunk so the star points sit at ±1.
    Inscribed,
}

#[derive(Debug, Clone, Copy, ValueEnum, PartialEq, Eq)]
pub enum OutputFormat {
    Csv,
    Json,
}

#[derive(Debug, Args)]
pub struct DesignArgs {
    /// Which design to build.
    pub kind: DesignKindArg,
    /// Factor names, comma-separated (e.g. N2,N3,N5). Defaults to the names in --levels, or
    /// A, B, C, ... with --k.
    #[arg(long, value_delimiter = ',')]
    pub factors: Option<Vec<String>>,
    /// Number of factors when names are not given.
    #[arg(long)]
    pub k: Option<usize>,
    /// Natural ranges, NAME=LOW:HIGH,... : adds natural-unit columns.
    #[arg(long)]
    pub levels: Option<String>,
    /// Plackett-Burman run count (default: the smallest that fits the factors).
    #[arg(long)]
    pub runs: Option<usize>,
    /// Centre points (Box-Behnken default: the classical count for k; CCD default: 5).
    #[arg(long)]
    pub centre_points: Option<usize>,
    /// Central composite variant.
    #[arg(long, value_enum, default_value = "circumscribed")]
    pub ccd: CcdArg,
    /// Coded run matrix for `custom`.
    #[arg(long)]
    pub input: Option<PathBuf>,
    /// Randomise the run order with this seed.
    #[arg(long)]
    pub randomize: Option<u64>,
    /// Replicates of every run, each with its own seed.
    #[arg(long, default_value_t = 1)]
    pub replicates: usize,
    /// Base seed from which every run's simulation seed is derived.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(long, value_enum, default_value = "csv")]
    pub format: OutputFormat,
}

/// One printed run: what a lab feeds into its simulations.
#[derive(Debug, Serialize)]
struct PrintedRun {
    run: usize,
    std_order: usize,
    replicate: usize,
    seed: u64,
    coded: Vec<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    natural: Option<Vec<f64>>,
}

#[derive(Debug, Serialize)]
struct PrintedDesign<'a> {
    design: &'a Design,
    factors: &'a [String],
    #[serde(skip_serializing_if = "Option::is_none")]
    levels: Option<&'a [Factor]>,
    runs: Vec<PrintedRun>,
}

pub fn run(args: &DesignArgs) -> Result<()> {
    let levels = args.levels.as_deref().map(parse_levels).transpose()?;
    let names = factor_names(args, levels.as_deref())?;
    let factors = levels
        .as_deref()
        .map(|l| levels_for(&names, l))
        .transpose()?;

    let mut design = build(args, &names)?;
    if let Some(seed) = args.randomize {
        design = design.randomized(seed);
    }
    let runs = replicate(&design, args.replicates, args.seed)?;
    let printed = runs
        .iter()
        .map(|r| -> Result<PrintedRun> {
            Ok(PrintedRun {
                run: r.run_index + 1,
                std_order: design.standard_order()[r.design_row] + 1,
                replicate: r.replicate + 1,
                seed: r.seed,
                natural: factors
                    .as_deref()
                    .map(|f| repose_doe::design::to_natural(f, &r.coded))
                    .transpose()?,
                coded: r.coded.clone(),
            })
        })
        .collect::<Result<Vec<_>>>()?;

    match args.format {
        OutputFormat::Json => {
            let out = PrintedDesign {
                design: &design,
                factors: &names,
                levels: factors.as_deref(),
                runs: printed,
            };
            println!("{}", serde_json::to_string_pretty(&out)?);
        }
        OutputFormat::Csv => print_csv(&names, factors.is_some(), &printed)?,
    }
    Ok(())
}

fn factor_names(args: &DesignArgs, levels: Option<&[Factor]>) -> Result<Vec<String>> {
    if let Some(names) = &args.factors {
        if let Some(k) = args.k {
            if k != names.len() {
                bail!(
                    "--k {k} disagrees with --factors, which names {}",
                    names.len()
                );
            }
        }
        return Ok(names.iter().map(|s| s.trim().to_owned()).collect());
    }
    if let Some(levels) = levels {
        return Ok(levels.iter().map(|f| f.name.clone()).collect());
    }
    if let DesignKindArg::Custom = args.kind {
        let input = args
            .input
            .as_ref()
            .ok_or_else(|| anyhow!("custom designs need --input FILE.csv"))?;
        return Ok(RunTable::read(input)?.headers);
    }
    let k = args
        .k
        .ok_or_else(|| anyhow!("give the factors: --factors A,B,C, --levels or --k N"))?;
    Ok(repose_doe::design::default_factor_names(k))
}

fn build(args: &DesignArgs, names: &[String]) -> Result<Design> {
    let design = match args.kind {
        DesignKindArg::Factorial => full_factorial(names)?,
        DesignKindArg::Pb => {
            let runs = match args.runs {
                Some(r) => r,
                None => smallest_plackett_burman_runs(names.len())?,
            };
            plackett_burman(names, runs)?
        }
        DesignKindArg::Bbd => {
            let centre = match args.centre_points {
                Some(c) => c,
                None => default_box_behnken_centre_points(names.len())?,
            };
            box_behnken(names, centre)?
        }
        DesignKindArg::Ccd => {
            let variant = match args.ccd {
                CcdArg::Circumscribed => CcdVariant::Circumscribed,
                CcdArg::FaceCentred => CcdVariant::FaceCentred,
                CcdArg::Inscribed => CcdVariant::Inscribed,
            };
            central_composite(names, variant, args.centre_points.unwrap_or(5))?
        }
        DesignKindArg::Custom => {
            let input = args
                .input
                .as_ref()
                .ok_or_else(|| anyhow!("custom designs need --input FILE.csv"))?;
            let table = RunTable::read(input)?;
            let columns = names
                .iter()
                .map(|n| table.column(n))
                .collect::<Result<Vec<_>>>()
                .with_context(|| format!("in {}", input.display()))?;
            let rows = (0..table.rows.len())
                .map(|r| columns.iter().map(|c| c[r]).collect())
                .collect();
            Design::custom(names, rows)?
        }
    };
    Ok(design)
}

fn print_csv(names: &[String], natural: bool, runs: &[PrintedRun]) -> Result<()> {
    let mut out = csv::Writer::from_writer(std::io::stdout().lock());
    let mut header = vec!["run".to_owned(), "std_order".into(), "replicate".into()];
    header.push("seed".into());
    header.extend(names.iter().cloned());
    if natural {
        header.extend(names.iter().map(|n| format!("{n}_natural")));
    }
    out.write_record(&header)?;
    for r in runs {
        let mut row = vec![
            r.run.to_string(),
            r.std_order.to_string(),
            r.replicate.to_string(),
            r.seed.to_string(),
        ];
        row.extend(r.coded.iter().map(|v| fmt_num(*v)));
        if let Some(nat) = &r.natural {
            row.extend(nat.iter().map(|v| fmt_num(*v)));
        }
        out.write_record(&row)?;
    }
    out.flush()?;
    Ok(())
}

/// Shortest text that reads back as the same float, with `-0` shown as `0`.
fn fmt_num(v: f64) -> String {
    if v == 0.0 {
        "0".to_owned()
    } else {
        format!("{v}")
    }
}
