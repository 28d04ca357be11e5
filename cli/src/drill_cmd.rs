//! `repose drill`: the drilling (pore-forming) virtual experiment on the DEM engine: a settled
//! soil bed, a turning auger fed in and withdrawn, the hole measured.
//!
//! Prints the result as JSON (hole lengths in mm: `opening_diameter_mm`, `effective_depth_mm`;
//! torques in N·m, forces in N, energies in J) and writes `result.json`, `section.svg` (vertical
//! section through the hole axis), `forces.svg` and `forces.csv` (torque and axial force
//! against time) into `--out`. With `--bed-cache DIR` the settled bed is stored in DIR under its
//! key (`<key>.json`) and reused by later runs with the same bed parameters. `--backend gpu`
//! settles the bed and drills on the GPU engine (its bed key ends in `-gpu`).

use crate::backend::Backend;
use crate::local_run::{run_on_bed_and_write, RunFiles};
use anyhow::{Context, Result};
use clap::Args;
use repose_experiments::drill::{DrillOn, DrillResult, DrillRun, DrillSpec, StlDrill};
use repose_experiments::Spec;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct DrillArgs {
    /// Experiment spec (JSON, a `DrillSpec`); fields not given take the preset's values.
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Start from a preset: `default` (the paper's auger 120 mm deep, ~17 500 grains, tens of
    /// minutes), `fast` (40 mm auger, 40 mm deep, ~2 500 grains, seconds) or `full` (the
    /// paper's bin unscaled: far too large for one machine).
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Change one field by its dotted path, e.g. `soil_soil.rolling_friction=0.3`,
    /// `drill.depth=0.08`, `bin.size_x=0.2` (repeatable, applied in order).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Directory for result.json, section.svg, forces.svg, forces.csv (created if missing).
    #[arg(long, required_unless_present = "print_spec")]
    pub out: Option<PathBuf>,
    /// Drill with this STL model (binary or ASCII; tip at the origin, axis +z) instead of the
    /// generated auger; set `auger.outer_diameter` to its diameter. Embedded in the spec.
    #[arg(long, value_name = "FILE")]
    pub stl: Option<PathBuf>,
    /// Multiplies the STL model's coordinates (0.001 for a model in millimetres).
    #[arg(long, default_value_t = 1.0, requires = "stl")]
    pub stl_scale: f64,
    /// Directory of settled beds (`<bed key>.json`): reused when present, stored when built.
    #[arg(long)]
    pub bed_cache: Option<PathBuf>,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// The engine: `cpu` (the reference) or `gpu` (wgpu compute: Vulkan, Metal, DX12; the bed
    /// is settled there too). Without a GPU
    /// adapter `gpu` is an error, never a fall-back to the CPU.
    #[arg(long, value_enum, default_value = "cpu")]
    pub backend: Backend,
    /// Print the effective spec (after --preset/--spec/--set) as JSON and exit.
    #[arg(long)]
    pub print_spec: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

fn effective_spec(args: &DrillArgs) -> Result<DrillSpec> {
    let mut spec: DrillSpec =
        crate::local_run::spec_from_args(&args.preset, args.spec.as_deref(), &args.set)?;
    if let Some(path) = &args.stl {
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        spec.auger_stl = Some(StlDrill::from_bytes(&bytes, args.stl_scale));
    }
    spec.validate()?;
    Ok(spec)
}

pub fn run(args: &DrillArgs) -> Result<()> {
    let spec = effective_spec(args)?;
    if args.print_spec {
        println!("{}", spec.to_json());
        return Ok(());
    }
    let out = args.out.as_ref().expect("clap requires --out");
    let gpu = crate::backend::open_gpu(args.backend)?;
    run_on_bed_and_write(
        &DrillOn {
            spec: &spec,
            engine: crate::backend::engine(gpu.as_ref()),
        },
        out,
        args.bed_cache.as_deref(),
        args.threads,
        args.quiet,
    )
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
