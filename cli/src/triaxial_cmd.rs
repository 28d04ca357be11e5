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

use crate::bed_cmd::BedArgs;
use crate::local_run::RunFiles;
use anyhow::Result;
use clap::Args;
use repose_experiments::triaxial::{TriaxialResult, TriaxialRun, TriaxialSpec};

#[derive(Debug, Args)]
pub struct TriaxialArgs {
    /// Start from a preset: `default` (the funnel's 2 mm grains, 12 across, three confining
    /// pressures), `fast` (8 across) or `ci` (4 mm grains, 6 across, two pressures; seconds).
    /// Paths for `--set` include `confining_pressures_kpa=[2,4,8]`, `preparation.friction=0.1`.
    #[arg(long, default_value = "default")]
    pub preset: String,
    #[command(flatten)]
    pub bed: BedArgs,
}

pub fn run(args: &TriaxialArgs) -> Result<()> {
    let spec: TriaxialSpec = args.bed.spec(&args.preset)?;
    crate::bed_cmd::run(&args.bed, spec)
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
