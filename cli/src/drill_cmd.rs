//! `repose drill`: the drilling (pore-forming) virtual experiment on the DEM engine: a settled
//! soil bed, a turning auger fed in and withdrawn, the hole measured.
//!
//! Prints the result as JSON (hole lengths in mm: `opening_diameter_mm`, `effective_depth_mm`;
//! torques in N·m, forces in N, energies in J) and writes `result.json`, `section.svg` (vertical
//! section through the hole axis), `forces.svg` and `forces.csv` (torque and axial force
//! against time) into `--out`. With `--bed-cache DIR` the settled bed is stored in DIR under its
//! key (`<key>.json`) and reused by later runs with the same bed parameters. `--backend gpu`
//! settles the bed and drills on the GPU engine (its bed key ends in `-gpu`).

use crate::bed_cmd::BedArgs;
use crate::local_run::RunFiles;
use anyhow::{Context, Result};
use clap::Args;
use repose_experiments::drill::{DrillResult, DrillRun, DrillSpec, StlDrill};
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct DrillArgs {
    /// Start from a preset: `default` (the paper's auger 120 mm deep, ~17 500 grains, tens of
    /// minutes), `fast` (40 mm auger, 40 mm deep, ~2 500 grains, seconds) or `full` (the
    /// paper's bin unscaled: far too large for one machine). Paths for `--set` include
    /// `drill.depth=0.08`, `bin.size_x=0.2`.
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Drill with this STL model (binary or ASCII; tip at the origin, axis +z) instead of the
    /// generated auger; set `auger.outer_diameter` to its diameter. Embedded in the spec.
    #[arg(long, value_name = "FILE")]
    pub stl: Option<PathBuf>,
    /// Multiplies the STL model's coordinates (0.001 for a model in millimetres).
    #[arg(long, default_value_t = 1.0, requires = "stl")]
    pub stl_scale: f64,
    #[command(flatten)]
    pub bed: BedArgs,
}

pub fn run(args: &DrillArgs) -> Result<()> {
    let mut spec: DrillSpec = args.bed.spec(&args.preset)?;
    if let Some(path) = &args.stl {
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        spec.auger_stl = Some(StlDrill::from_bytes(&bytes, args.stl_scale));
    }
    crate::bed_cmd::run(&args.bed, spec)
}

impl RunFiles for DrillRun {
    type Result = DrillResult;

    fn result_with_wall_time(&self, wall_time_s: f64) -> DrillResult {
        DrillResult {
            wall_time_s,
            ..self.result.clone()
        }
    }

    fn files(&self) -> Vec<(&'static str, String)> {
        vec![
            ("section.svg", self.section_svg()),
            ("forces.svg", self.forces_svg()),
            ("forces.csv", self.forces_csv()),
        ]
    }
}
