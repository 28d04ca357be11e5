//! `repose aor`: the angle-of-repose virtual experiment (funnel or lifted cylinder) on the DEM
//! engine, measured automatically.
//!
//! Prints the result as JSON (angles in degrees, lengths in metres, masses in kg, times in s;
//! the key `angle_deg` is the mean flank angle) and writes `result.json`, `pile.svg` (side view
//! with the fitted flank lines; axes in mm) and `final.csv` (every grain) into `--out`.

use crate::sim::write_file;
use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use repose_engine::output::write_particles_csv;
use repose_experiments::aor::{run_aor, AorSpec, Control};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub struct AorArgs {
    /// Experiment spec (JSON, an `AorSpec`); fields not given take the preset's values.
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Start from a preset: `default` (1 mm grains, 50 g, a few minutes) or `fast` (1.25 mm
    /// grains, 12 g, seconds). Ignored with --spec.
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Change one field by its dotted path, e.g. `soil_soil.rolling_friction=0.3`,
    /// `particle.radius=0.0012`, `total_mass=0.05` (repeatable, applied in order).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Directory for result.json, pile.svg and final.csv (created if missing).
    #[arg(long, required_unless_present = "print_spec")]
    pub out: Option<PathBuf>,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// Print the effective spec (after --preset/--spec/--set) as JSON and exit.
    #[arg(long)]
    pub print_spec: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

fn effective_spec(args: &AorArgs) -> Result<AorSpec> {
    let mut spec = match &args.spec {
        Some(path) => crate::sim::spec_over_preset(path, &AorSpec::preset(&args.preset)?)?,
        None => AorSpec::preset(&args.preset)?,
    };
    spec.apply_assignments(args.set.iter().map(String::as_str))?;
    spec.validate()?;
    Ok(spec)
}

pub fn run(args: &AorArgs) -> Result<()> {
    let spec = effective_spec(args)?;
    if args.print_spec {
        println!("{}", spec.to_json());
        return Ok(());
    }
    let out = args.out.as_ref().expect("clap requires --out");
    let threads = match args.threads {
        Some(0) => bail!("--threads must be at least 1"),
        Some(t) => t,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("cannot start the thread pool")?;

    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(1000)
    };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:40} {percent:>3}% {msg}")
            .expect("valid template"),
    );
    let run = pool.install(|| {
        run_aor(&spec, &mut |p| {
            bar.set_position((p.fraction * 1000.0) as u64);
            bar.set_message(format!(
                "{} t={:.3} s, {} grains",
                p.phase, p.time, p.particles
            ));
            Control::Continue
        })
    })?;
    bar.finish_and_clear();

    let json = serde_json::to_string_pretty(&run.result)?;
    write_file(&out.join("result.json"), |w| writeln!(w, "{json}"))?;
    if let Some(svg) = run.pile_svg() {
        write_file(&out.join("pile.svg"), |w| w.write_all(svg.as_bytes()))?;
    }
    write_file(&out.join("final.csv"), |w| {
        write_particles_csv(w, run.world.particles())
    })?;
    println!("{json}");
    Ok(())
}
