//! `repose aor`: the angle-of-repose virtual experiment (funnel or lifted cylinder) on the DEM
//! engine, measured automatically.
//!
//! Prints the result as JSON (angles in degrees, lengths in metres, masses in kg, times in s;
//! the key `angle_deg` is the mean flank angle; `rest` how far from rest the heap was at the
//! end, creep rate and kinetic energy against their limits, for every run, also one line on
//! stderr) and writes `result.json`,
//! `pile.svg` (side view with the fitted flank lines; axes in mm) and `final.csv` (every grain)
//! into `--out`. `--measure FILE` measures a particle file instead of running; `--export-stl
//! DIR` writes the rig's meshes. `--backend gpu` runs the funnel on the GPU engine.

use crate::backend::Backend;
use crate::sim::write_file;
use anyhow::{bail, Context, Result};
use clap::Args;
use repose_engine::output::write_particles_csv;
use repose_experiments::aor::{
    measure_heap, rig_meshes, run_aor_on, side_view_svg, AorCheckpoint, AorSpec, Checkpoints,
    Control, PictureOptions, SaveCheckpoint,
};
use repose_experiments::Spec;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(Debug, Args)]
pub struct AorArgs {
    /// Experiment spec (JSON, an `AorSpec`); fields not given take the preset's values.
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Start from a preset: `default` (2 mm grains, 50 g, a few minutes), `fast` (2.5 mm
    /// grains, 30 g, for tests), `paper-scale` (the paper's 0.3 kg of 2 mm grains, ~7 min on 2
    /// threads), `fine` (0.3 kg of 1 mm grains, hours: use --checkpoint), the ladder members `size-2.5mm`,
    /// `size-1.5mm`, `mass-100g`, `paper-scale-sieve` (docs/aor.md). With --spec, the fields
    /// the file does not give.
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Change one field by its dotted path, e.g. `soil_soil.rolling_friction=0.3`,
    /// `particle.radius=0.0012`, `total_mass=0.05` (repeatable, applied in order).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Directory for result.json, pile.svg and final.csv (created if missing).
    #[arg(long, required_unless_present_any = ["print_spec", "measure", "export_stl"])]
    pub out: Option<PathBuf>,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// Print the effective spec (after --preset/--spec/--set) as JSON and exit.
    #[arg(long)]
    pub print_spec: bool,
    /// Do not run: measure the heap in a particle file (CSV with a header naming the columns
    /// x, y, z and radius (or r), in metres, in the run's frame: plate top at z = 0, funnel
    /// axis at x = y = 0; e.g. a run's final.csv or a peer engine's dump) as a run measures its
    /// own heap, with the effective spec's rig and settings. Prints the measurement as JSON;
    /// with --out also writes measure.json and pile.svg there.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["print_spec", "export_stl"])]
    pub measure: Option<PathBuf>,
    /// Do not run: write the effective spec's rig as ASCII STL files (base.stl, funnel.stl;
    /// metres, the run's frame) into DIR, e.g. for a peer engine.
    #[arg(long, value_name = "DIR", conflicts_with = "print_spec")]
    pub export_stl: Option<PathBuf>,
    /// Keep the run's checkpoint in FILE (the whole state, replaced atomically every
    /// --checkpoint-every seconds): a run killed or cut short goes on from there when the same
    /// command is run again, and ends exactly as it would have without the stop. A FILE of
    /// another spec is refused (the error names the field). Deleted once the run has finished
    /// and its results are written.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["print_spec", "measure", "export_stl"])]
    pub checkpoint: Option<PathBuf>,
    /// Wall-clock seconds between two checkpoints.
    #[arg(long, value_name = "SECONDS", default_value_t = 300.0, requires = "checkpoint",
          value_parser = non_negative_seconds)]
    pub checkpoint_every: f64,
    /// The engine: `cpu` (the reference) or `gpu` (wgpu compute: Vulkan, Metal, DX12; the
    /// funnel protocol, without --checkpoint). The result's `engine_version` names it. Without
    /// a GPU adapter `gpu` is an error, never a fall-back to the CPU.
    #[arg(long, value_enum, default_value_t = Backend::Cpu)]
    pub backend: Backend,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

fn non_negative_seconds(text: &str) -> std::result::Result<f64, String> {
    match text.parse::<f64>() {
        Ok(s) if s.is_finite() && s >= 0.0 => Ok(s),
        _ => Err(format!("expected a number of seconds >= 0, got `{text}`")),
    }
}

fn effective_spec(args: &AorArgs) -> Result<AorSpec> {
    let spec: AorSpec =
        crate::local_run::spec_from_args(&args.preset, args.spec.as_deref(), &args.set)?;
    spec.validate()?;
    Ok(spec)
}

pub fn run(args: &AorArgs) -> Result<()> {
    let spec = effective_spec(args)?;
    if args.print_spec {
        println!("{}", spec.to_json());
        return Ok(());
    }
    if let Some(dir) = &args.export_stl {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        for (name, mesh) in rig_meshes(&spec)? {
            let path = dir.join(format!("{name}.stl"));
            write_file(&path, |w| w.write_all(mesh.to_stl_ascii(name).as_bytes()))?;
            eprintln!("{} ({} triangles)", path.display(), mesh.triangles().len());
        }
        return Ok(());
    }
    if let Some(file) = &args.measure {
        return measure_file(&spec, file, args.out.as_deref());
    }
    let out = args.out.as_ref().expect("clap requires --out");
    if args.backend == Backend::Gpu && args.checkpoint.is_some() {
        bail!(
            "--checkpoint with --backend gpu: a GPU run cannot be continued from a saved state \
             (run it without --checkpoint)"
        );
    }
    let gpu = crate::backend::open_gpu(args.backend)?;
    let engine = crate::backend::engine(gpu.as_ref());
    crate::local_run::create_dirs([out.as_path()])?;
    let pool = crate::local_run::thread_pool(args.threads)?;
    let resume = match &args.checkpoint {
        Some(file) => read_checkpoint(file, &spec)?,
        None => None,
    };
    let bar = crate::local_run::progress_bar(args.quiet, " {msg}");
    let run = pool.install(|| {
        let mut keep = |bytes: &[u8]| {
            if let Some(file) = &args.checkpoint {
                // A checkpoint that cannot be written (full disk) costs only the restart
                // point: the last one written stays whole, and the run goes on.
                if let Err(e) = repose_stores::write_atomically(file, bytes) {
                    bar.suspend(|| {
                        eprintln!("warning: checkpoint not kept in {}: {e}", file.display())
                    });
                }
            }
        };
        let checkpoints = Checkpoints {
            resume,
            save: args
                .checkpoint
                .is_some()
                .then_some(&mut keep as &mut SaveCheckpoint),
            every: Duration::from_secs_f64(args.checkpoint_every),
        };
        run_aor_on(
            engine,
            &spec,
            &mut |p| {
                bar.set_position((p.fraction * 1000.0) as u64);
                bar.set_message(format!(
                    "{} t={:.3} s, {} grains",
                    p.phase, p.time, p.particles
                ));
                Control::Continue
            },
            checkpoints,
        )
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
    if let Some(file) = &args.checkpoint {
        // The results are written: the checkpoint would only replay the run's tail.
        if let Err(e) = std::fs::remove_file(file) {
            if e.kind() != std::io::ErrorKind::NotFound {
                eprintln!("warning: cannot delete {}: {e}", file.display());
            }
        }
    }
    println!("{json}");
    if let Some(rest) = &run.result.rest {
        let verdict = if run.result.came_to_rest {
            "at rest"
        } else {
            "not at rest"
        };
        eprintln!("{verdict} ({:?}): {rest}", run.result.ended_by);
    }
    Ok(())
}

/// The checkpoint in `file` if there is one (it must be a run of `spec`).
fn read_checkpoint(file: &Path, spec: &AorSpec) -> Result<Option<AorCheckpoint>> {
    let bytes = match std::fs::read(file) {
        Ok(bytes) => bytes,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", file.display())),
    };
    let saved = AorCheckpoint::from_bytes(&bytes)
        .and_then(|c| c.check_spec(spec).map(|()| c))
        .with_context(|| {
            format!(
                "cannot continue from {} (delete it to start afresh)",
                file.display()
            )
        })?;
    eprintln!(
        "continuing from {}: step {}, t = {:.3} s, {} grains, {:.0} s of wall time so far",
        file.display(),
        saved.steps(),
        saved.simulated_time(),
        saved.particles(),
        saved.wall_time_s()
    );
    Ok(Some(saved))
}

/// Grain centres and radii from a CSV whose header names x, y, z and radius (or r).
fn read_particles_csv(text: &str, source: &Path) -> Result<(Vec<[f64; 3]>, Vec<f64>)> {
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header: Vec<String> = lines
        .next()
        .with_context(|| format!("{} is empty", source.display()))?
        .split(',')
        .map(|h| h.trim().to_ascii_lowercase())
        .collect();
    let column = |names: &[&str]| {
        header
            .iter()
            .position(|h| names.contains(&h.as_str()))
            .with_context(|| {
                format!(
                    "{}: the header has no column {} (found: {})",
                    source.display(),
                    names.join(" or "),
                    header.join(",")
                )
            })
    };
    let (ix, iy, iz, ir) = (
        column(&["x"])?,
        column(&["y"])?,
        column(&["z"])?,
        column(&["radius", "r"])?,
    );
    let (mut positions, mut radii) = (Vec::new(), Vec::new());
    for (n, line) in lines.enumerate() {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let value = |i: usize| -> Result<f64> {
            let v: f64 = fields
                .get(i)
                .with_context(|| format!("{} line {}: too few columns", source.display(), n + 2))?
                .parse()
                .with_context(|| {
                    format!("{} line {}: column {}", source.display(), n + 2, header[i])
                })?;
            if !v.is_finite() {
                bail!(
                    "{} line {}: {} is not finite",
                    source.display(),
                    n + 2,
                    header[i]
                );
            }
            Ok(v)
        };
        positions.push([value(ix)?, value(iy)?, value(iz)?]);
        let r = value(ir)?;
        if r <= 0.0 {
            bail!(
                "{} line {}: radius must be > 0, got {r}",
                source.display(),
                n + 2
            );
        }
        radii.push(r);
    }
    Ok((positions, radii))
}

fn measure_file(spec: &AorSpec, file: &Path, out: Option<&Path>) -> Result<()> {
    let text =
        std::fs::read_to_string(file).with_context(|| format!("cannot read {}", file.display()))?;
    let (positions, radii) = read_particles_csv(&text, file)?;
    let m = measure_heap(spec, &positions, &radii)
        .with_context(|| format!("no measurable heap in {}", file.display()))?;
    let json = serde_json::to_string_pretty(&m)?;
    if let Some(out) = out {
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
        write_file(&out.join("measure.json"), |w| writeln!(w, "{json}"))?;
        let options = PictureOptions {
            title: Some(format!(
                "{}: angle of repose {:.2}° (left {:.2}°, right {:.2}°)",
                file.display(),
                m.angle_deg,
                m.left_deg,
                m.right_deg
            )),
            ..PictureOptions::default()
        };
        // Draw the heap only (not grains still in the funnel).
        let (heap, heap_radii): (Vec<[f64; 3]>, Vec<f64>) = positions
            .iter()
            .zip(&radii)
            .filter(|(p, _)| p[2] <= m.apex[2])
            .map(|(p, r)| (*p, *r))
            .unzip();
        let svg = side_view_svg(&m, &heap, &heap_radii, &options);
        write_file(&out.join("pile.svg"), |w| w.write_all(svg.as_bytes()))?;
    }
    println!("{json}");
    Ok(())
}
