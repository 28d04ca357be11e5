//! `repose sim SCENE --out DIR`: run one scene file with a progress bar and write the results.

use anyhow::{Context, Result};
use clap::Args;
use repose_engine::output::{
    write_geometry_csv, write_mesh_vtk, write_particles_csv, write_particles_vtk,
};
use repose_engine::scene::Scene;
use repose_engine::world::{GeometryId, World};
use serde::Serialize;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Args)]
pub struct SimArgs {
    /// Scene file, TOML (.toml) or JSON (.json).
    pub scene: PathBuf,
    /// Directory for final.csv, geometry_forces.csv and snapshots (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Worker threads (default: all cores). Results are identical for any count.
    #[arg(long, env = "REPOSE_THREADS")]
    pub threads: Option<usize>,
    /// Override the scene's duration, s.
    #[arg(long)]
    pub duration: Option<f64>,
}

/// What `repose sim` prints when it finishes.
#[derive(Debug, Serialize)]
struct SimSummary {
    particles: usize,
    removed: u64,
    steps: u64,
    simulated_time_s: f64,
    time_step_s: f64,
    wall_time_s: f64,
    particle_steps_per_s: f64,
    threads: usize,
    snapshots: usize,
    out: PathBuf,
}

pub fn read_scene(path: &Path) -> Result<Scene> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read scene {}", path.display()))?;
    let is_json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    let scene = if is_json {
        serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{e}"))
    } else {
        // toml's message spans several lines (it quotes the line); keep it on one.
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}", one_line(&e.to_string())))
    };
    scene.with_context(|| format!("invalid scene {}", path.display()))
}

fn one_line(s: &str) -> String {
    s.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('|') && !l.chars().all(|c| c == '^'))
        .collect::<Vec<_>>()
        .join(" ")
}

pub fn run(args: &SimArgs) -> Result<()> {
    let mut scene = read_scene(&args.scene)?;
    if let Some(d) = args.duration {
        scene.duration = d;
    }
    let prepared = scene
        .prepare(&|path| std::fs::read(path).map_err(|e| e.to_string()))
        .with_context(|| format!("invalid scene {}", args.scene.display()))?;
    if let Some(w) = &prepared.time_step_warning {
        eprintln!(
            "warning: time step {:.3e} s resolves a {:.2} m/s impact of the smallest particles \
             in only {:.1} steps (contact time {:.3e} s); results may be inaccurate",
            w.time_step, w.impact_speed, w.steps_per_contact, w.contact_time
        );
    }
    crate::local_run::create_dirs([args.out.as_path()])?;
    let pool = crate::local_run::thread_pool(args.threads)?;

    let mut world = prepared.world;
    let names = prepared.geometry_names;
    let duration = prepared.duration;
    let snapshot_every = scene.output.snapshot_interval;
    let started = Instant::now();
    let bar = crate::local_run::progress_bar(false, " t={msg} (eta {eta})");
    let mut snapshots = 0usize;
    let mut next_snapshot = snapshot_every.map(|_| 0.0);
    pool.install(|| -> Result<()> {
        while world.time() < duration {
            if let (Some(at), Some(every)) = (next_snapshot, snapshot_every) {
                if world.time() >= at {
                    write_snapshot(&args.out, &world, &names, snapshots)?;
                    snapshots += 1;
                    next_snapshot = Some(at + every);
                }
            }
            let chunk_end = (world.time() + duration / 1000.0).min(duration);
            let until = next_snapshot.map_or(chunk_end, |s| s.min(chunk_end));
            world.run_until(until.max(world.time() + world.config().time_step * 0.5));
            bar.set_position((world.time() / duration * 1000.0) as u64);
            bar.set_message(format!(
                "{:.4} s, {} particles",
                world.time(),
                world.particles().len()
            ));
        }
        Ok(())
    })?;
    bar.finish_and_clear();
    if snapshot_every.is_some() {
        write_snapshot(&args.out, &world, &names, snapshots)?;
        snapshots += 1;
    }
    let wall = started.elapsed().as_secs_f64();

    write_file(&args.out.join("final.csv"), |w| {
        write_particles_csv(w, world.particles())
    })?;
    write_file(&args.out.join("geometry_forces.csv"), |w| {
        write_geometry_csv(
            w,
            names
                .iter()
                .enumerate()
                .map(|(i, n)| (n.as_str(), world.geometry_series(GeometryId(i as u32)))),
        )
    })?;

    let summary = SimSummary {
        particles: world.particles().len(),
        removed: world.removed_count(),
        steps: world.steps(),
        simulated_time_s: world.time(),
        time_step_s: prepared.time_step,
        wall_time_s: wall,
        particle_steps_per_s: 0.0,
        threads: pool.current_num_threads(),
        snapshots,
        out: args.out.clone(),
    };
    let summary = SimSummary {
        particle_steps_per_s: summary.particles as f64 * summary.steps as f64 / wall.max(1e-9),
        ..summary
    };
    println!("{}", serde_json::to_string_pretty(&summary)?);
    Ok(())
}

/// Creates `path` and writes it through a buffer; errors name the file.
pub fn write_file(
    path: &Path,
    body: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<()> {
    let file = File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut w = BufWriter::new(file);
    body(&mut w)
        .and_then(|()| w.flush())
        .with_context(|| format!("cannot write {}", path.display()))
}

fn write_snapshot(dir: &Path, world: &World, names: &[String], index: usize) -> Result<()> {
    write_file(&dir.join(format!("particles_{index:05}.vtk")), |w| {
        write_particles_vtk(w, world.particles(), world.time())
    })?;
    for (g, name) in names.iter().enumerate() {
        let geometry = world.geometry(GeometryId(g as u32));
        let pose = geometry.motion.pose_at(world.time());
        write_file(&dir.join(format!("{name}_{index:05}.vtk")), |w| {
            write_mesh_vtk(
                w,
                &geometry.mesh,
                |v| pose.transform_point(&v.into()).coords,
                name,
            )
        })?;
    }
    Ok(())
}

/// The spec in the JSON file at `path`, merged over `preset`: fields the file leaves out take
/// the preset's values.
pub fn spec_over_preset<T: Serialize + serde::de::DeserializeOwned>(
    path: &Path,
    preset: &T,
) -> Result<T> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read spec {}", path.display()))?;
    let given: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("invalid spec {}", path.display()))?;
    let base = serde_json::to_value(preset)?;
    serde_json::from_value(repose_experiments::catalog::merge_json(base, given))
        .with_context(|| format!("invalid spec {}", path.display()))
}
