//! `repose shear`: the direct shear virtual experiment on the DEM engine: a split steel box
//! filled with the soil, consolidated under a servo-controlled lid at each normal stress and
//! sheared at constant speed; the Mohr-Coulomb fit gives the cohesion and friction angle.
//!
//! Prints the result as JSON (stresses in kPa: `cohesion_kpa`, `friction_angle_deg`, the fit's
//! quality, each stage's peak and residual) and writes `result.json`, `shear_curves.svg` (shear
//! stress against displacement per normal stress), `mohr_coulomb.svg` (the lines and points)
//! and `shear_curves.csv` into `--out`. With `--bed-cache DIR` the settled sample is stored in
//! DIR under its key (`<key>.json`, the drilling bed store) and reused by later runs with the
//! same sample parameters. `--backend gpu` settles the sample and shears it on the GPU engine
//! (its sample key ends in `-gpu`).

use crate::backend::Backend;
use crate::local_run::{run_on_bed_and_write, RunFiles};
use anyhow::Result;
use clap::Args;
use repose_experiments::shear::{ShearOn, ShearResult, ShearRun, ShearSpec};
use repose_experiments::Spec;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct ShearArgs {
    /// Experiment spec (JSON, a `ShearSpec`); fields not given take the preset's values.
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Start from a preset: `default` (100 mm box, ~3 000 grains of 6 mm, four normal stresses)
    /// or `fast` (50 mm box, ~1 000 grains of 4.4 mm, three normal stresses, tens of seconds).
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Change one field by its dotted path, e.g. `soil_soil.static_friction=0.5`,
    /// `normal_stresses_kpa=[5,10,20]`,
    /// `soil_soil.cohesion={"model":"linear","energy_density":1e5}` (repeatable, in order).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Directory for result.json, shear_curves.svg, mohr_coulomb.svg, shear_curves.csv
    /// (created if missing).
    #[arg(long, required_unless_present = "print_spec")]
    pub out: Option<PathBuf>,
    /// Directory of settled samples (`<key>.json`): reused when present, stored when built.
    #[arg(long)]
    pub bed_cache: Option<PathBuf>,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// The engine: `cpu` (the reference) or `gpu` (the GPU engine; the sample is settled there
    /// too). Without a GPU adapter `gpu` is an error, never a fall-back to the CPU.
    #[arg(long, value_enum, default_value = "cpu")]
    pub backend: Backend,
    /// Print the effective spec (after --preset/--spec/--set) as JSON and exit.
    #[arg(long)]
    pub print_spec: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

fn effective_spec(args: &ShearArgs) -> Result<ShearSpec> {
    let spec: ShearSpec =
        crate::local_run::spec_from_args(&args.preset, args.spec.as_deref(), &args.set)?;
    spec.validate()?;
    Ok(spec)
}

pub fn run(args: &ShearArgs) -> Result<()> {
    let spec = effective_spec(args)?;
    if args.print_spec {
        println!("{}", spec.to_json());
        return Ok(());
    }
    let out = args.out.as_ref().expect("clap requires --out");
    let gpu = crate::backend::open_gpu(args.backend)?;
    run_on_bed_and_write(
        &ShearOn {
            spec: &spec,
            engine: crate::backend::engine(gpu.as_ref()),
        },
        out,
        args.bed_cache.as_deref(),
        args.threads,
        args.quiet,
    )
}

impl RunFiles for ShearRun {
    type Result = ShearResult;

    fn result_with_wall_time(&self, wall_time_s: f64) -> ShearResult {
        ShearResult {
            wall_time_s,
            ..self.result.clone()
        }
    }

    fn files(&self) -> Vec<(&'static str, String)> {
        vec![
            ("shear_curves.svg", self.curves_svg()),
            ("mohr_coulomb.svg", self.strength_svg()),
            ("shear_curves.csv", self.curves_csv()),
        ]
    }
}
