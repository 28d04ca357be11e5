//! `repose triaxial`: the drained triaxial compression test on the DEM engine: a specimen
//! between six servo-controlled walls, consolidated to each confining pressure and loaded
//! axially; the Mohr-Coulomb envelope of the failure circles gives the cohesion and friction
//! angle, the stress-strain curve E50 and Poisson's ratio.
//!
//! Prints the result as JSON and writes `result.json`, `mohr_circles.svg` (the failure circles
//! with the fitted envelope and the paper's), `triaxial_curves.svg` (q and εv against εa),
//! `specimen.svg` (the last specimen at the end of loading) and `triaxial_curves.csv` into
//! `--out`. With `--bed-cache DIR` the prepared specimen is stored in DIR under its key and
//! reused by later runs with the same specimen parameters. `--backend gpu` prepares and loads
//! the specimen on the GPU engine (its key ends in `-gpu`).

use crate::backend::Backend;
use crate::local_run::{run_on_bed_and_write, RunFiles};
use anyhow::Result;
use clap::Args;
use repose_experiments::triaxial::{TriaxialOn, TriaxialResult, TriaxialRun, TriaxialSpec};
use repose_experiments::Spec;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct TriaxialArgs {
    /// Experiment spec (JSON, a `TriaxialSpec`); fields not given take the preset's values.
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Start from a preset: `default` (the funnel's 2 mm grains, 12 across, three confining
    /// pressures), `fast` (8 across) or `ci` (4 mm grains, 6 across, two pressures; seconds).
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Change one field by its dotted path, e.g. `soil_soil.static_friction=0.5`,
    /// `confining_pressures_kpa=[2,4,8]`, `preparation.friction=0.1` (repeatable, in order).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Directory for result.json, mohr_circles.svg, triaxial_curves.svg, specimen.svg,
    /// triaxial_curves.csv (created if missing).
    #[arg(long, required_unless_present = "print_spec")]
    pub out: Option<PathBuf>,
    /// Directory of prepared specimens (`<key>.json`): reused when present, stored when built.
    #[arg(long)]
    pub bed_cache: Option<PathBuf>,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// The engine: `cpu` (the reference) or `gpu` (the specimen is prepared there too).
    /// Without a GPU adapter `gpu` is an error, never a fall-back to the CPU.
    #[arg(long, value_enum, default_value = "cpu")]
    pub backend: Backend,
    /// Print the effective spec (after --preset/--spec/--set) as JSON and exit.
    #[arg(long)]
    pub print_spec: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: &TriaxialArgs) -> Result<()> {
    let spec: TriaxialSpec =
        crate::local_run::spec_from_args(&args.preset, args.spec.as_deref(), &args.set)?;
    spec.validate()?;
    if args.print_spec {
        println!("{}", spec.to_json());
        return Ok(());
    }
    let out = args.out.as_ref().expect("clap requires --out");
    let gpu = crate::backend::open_gpu(args.backend)?;
    run_on_bed_and_write(
        &TriaxialOn {
            spec: &spec,
            engine: crate::backend::engine(gpu.as_ref()),
        },
        out,
        args.bed_cache.as_deref(),
        args.threads,
        args.quiet,
    )
}

impl RunFiles for TriaxialRun {
    type Result = TriaxialResult;

    fn result_with_wall_time(&self, wall_time_s: f64) -> TriaxialResult {
        TriaxialResult {
            wall_time_s,
            ..self.result.clone()
        }
    }

    fn files(&self) -> Vec<(&'static str, String)> {
        vec![
            ("mohr_circles.svg", self.mohr_svg()),
            ("triaxial_curves.svg", self.curves_svg()),
            ("specimen.svg", self.specimen_svg()),
            ("triaxial_curves.csv", self.curves_csv()),
        ]
    }
}
