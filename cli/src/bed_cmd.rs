//! What the commands of the kinds that run on a settled bed (`repose drill`, `shear`,
//! `triaxial`) share: their common flags ([`BedArgs`], flattened into each command's own) and
//! their one flow ([`run`]): the spec from `--preset`/`--spec`/`--set`, checked, printed with
//! `--print-spec`, else run on the engine `--backend` names and written to `--out`.

use crate::backend::Backend;
use crate::local_run::{run_on_bed_and_write, RunFiles};
use anyhow::Result;
use clap::Args;
use repose_experiments::soil::{On, OnBed, OnBedError};
use repose_experiments::Spec;
use std::path::PathBuf;

/// The flags every command of a kind on a settled bed takes.
#[derive(Debug, Args)]
pub struct BedArgs {
    /// Experiment spec (JSON); fields not given take the preset's values.
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Change one field by its dotted path, e.g. `soil_soil.static_friction=0.5` or
    /// `soil_soil.cohesion={"model":"linear","energy_density":1e5}` (repeatable, in order).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Directory for result.json and the pictures (created if missing).
    #[arg(long, required_unless_present = "print_spec")]
    pub out: Option<PathBuf>,
    /// Directory of settled beds (`<key>.json`): reused when present, stored when built.
    #[arg(long)]
    pub bed_cache: Option<PathBuf>,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// The engine: `cpu` (the reference) or `gpu` (wgpu compute: Vulkan, Metal, DX12; the bed
    /// is settled there too). Without a GPU adapter `gpu` is an error, never a fall-back to
    /// the CPU.
    #[arg(long, value_enum, default_value = "cpu")]
    pub backend: Backend,
    /// Print the effective spec (after --preset/--spec/--set) as JSON and exit.
    #[arg(long)]
    pub print_spec: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

impl BedArgs {
    /// The spec `preset`, `--spec` and `--set` give, not yet checked.
    pub fn spec<S: Spec>(&self, preset: &str) -> Result<S> {
        crate::local_run::spec_from_args(preset, self.spec.as_deref(), &self.set)
    }
}

/// Checks `spec`, prints it (`--print-spec`) or runs it on the engine `--backend` names,
/// writing the result and the kind's files to `--out`.
pub fn run<S, R>(args: &BedArgs, spec: S) -> Result<()>
where
    S: Spec + Sync,
    for<'a> On<'a, S>: OnBed<Run = R, Error = OnBedError>,
    R: Send + RunFiles,
{
    spec.validate()?;
    if args.print_spec {
        println!("{}", spec.to_json());
        return Ok(());
    }
    let out = args.out.as_ref().expect("clap requires --out");
    let gpu = crate::backend::open_gpu(args.backend)?;
    run_on_bed_and_write(
        &On {
            spec: &spec,
            engine: crate::backend::engine(gpu.as_ref()),
        },
        out,
        args.bed_cache.as_deref(),
        args.threads,
        args.quiet,
    )
}
