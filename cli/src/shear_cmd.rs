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

use crate::bed_cmd::BedArgs;
use crate::local_run::RunFiles;
use anyhow::Result;
use clap::Args;
use repose_experiments::shear::{ShearResult, ShearRun, ShearSpec};

#[derive(Debug, Args)]
pub struct ShearArgs {
    /// Start from a preset: `default` (100 mm box, ~3 000 grains of 6 mm, four normal stresses)
    /// or `fast` (50 mm box, ~1 000 grains of 4.4 mm, three normal stresses, tens of seconds).
    /// Paths for `--set` include `normal_stresses_kpa=[5,10,20]`.
    #[arg(long, default_value = "default")]
    pub preset: String,
    #[command(flatten)]
    pub bed: BedArgs,
}

pub fn run(args: &ShearArgs) -> Result<()> {
    let spec: ShearSpec = args.bed.spec(&args.preset)?;
    crate::bed_cmd::run(&args.bed, spec)
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
