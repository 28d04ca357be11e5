//! `repose bench engine`: particle-steps per second of the DEM engine on a settled bed
//! (Hertz-Mindlin + tangential history + rolling friction, periodic in x and y), for several
//! sizes and thread counts, plus memory per particle. Results go in BENCHMARKS.md.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use repose_engine::bench::{settled_bed, time_steps, BenchResult};
use serde::Serialize;
use std::time::Instant;

#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchWhat,
}

#[derive(Debug, Subcommand)]
pub enum BenchWhat {
    /// DEM engine throughput on a settled bed of spheres.
    Engine(EngineBenchArgs),
}

#[derive(Debug, Args)]
pub struct EngineBenchArgs {
    /// Particle counts, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "10000,40000,160000")]
    pub particles: Vec<usize>,
    /// Thread counts, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub threads: Vec<usize>,
    /// Timed steps per measurement.
    #[arg(long, default_value_t = 2000)]
    pub steps: u64,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON lines instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct Row {
    particles: usize,
    threads: usize,
    steps: u64,
    seconds: f64,
    mega_particle_steps_per_s: f64,
    speedup_vs_1_thread: Option<f64>,
    contacts_per_particle: f64,
    pairs_per_particle: f64,
    rebuilds: u64,
    model_bytes_per_particle: f64,
    /// Peak resident memory of this process so far (VmHWM), KiB.
    peak_rss_kib: Option<u64>,
    settle_seconds: f64,
}

pub fn run(args: &BenchArgs) -> Result<()> {
    match &args.what {
        BenchWhat::Engine(a) => engine(a),
    }
}

fn engine(args: &EngineBenchArgs) -> Result<()> {
    if args.particles.iter().any(|&n| n < 100) {
        bail!("--particles: each count must be at least 100");
    }
    if args.threads.contains(&0) {
        bail!("--threads: each count must be at least 1");
    }
    if args.steps == 0 {
        bail!("--steps must be at least 1");
    }
    if !args.json {
        println!(
            "{:>9} {:>7} {:>8} {:>10} {:>8} {:>9} {:>7} {:>9} {:>11}",
            "particles",
            "threads",
            "seconds",
            "M p-steps/s",
            "speedup",
            "contacts",
            "pairs",
            "B/particle",
            "peak RSS MiB"
        );
    }
    for &n in &args.particles {
        let started = Instant::now();
        let bed = settled_bed(n, args.seed).context("building the settled bed")?;
        let settle_seconds = started.elapsed().as_secs_f64();
        let mut single: Option<f64> = None;
        for &threads in &args.threads {
            let r: BenchResult = time_steps(&bed, threads, args.steps);
            let rate = r.particle_steps_per_second / 1e6;
            if threads == 1 {
                single = Some(rate);
            }
            let row = Row {
                particles: r.particles,
                threads,
                steps: r.steps,
                seconds: r.seconds,
                mega_particle_steps_per_s: rate,
                speedup_vs_1_thread: single.map(|s| rate / s),
                contacts_per_particle: r.contacts_per_particle,
                pairs_per_particle: r.pairs_per_particle,
                rebuilds: r.rebuilds,
                model_bytes_per_particle: r.bytes_per_particle,
                peak_rss_kib: peak_rss_kib(),
                settle_seconds,
            };
            if args.json {
                println!("{}", serde_json::to_string(&row)?);
            } else {
                println!(
                    "{:>9} {:>7} {:>8.2} {:>10.2} {:>8} {:>9.2} {:>7.2} {:>9.0} {:>11}",
                    row.particles,
                    row.threads,
                    row.seconds,
                    row.mega_particle_steps_per_s,
                    row.speedup_vs_1_thread
                        .map_or("-".to_owned(), |s| format!("{s:.2}x")),
                    row.contacts_per_particle,
                    row.pairs_per_particle,
                    row.model_bytes_per_particle,
                    row.peak_rss_kib
                        .map_or("-".to_owned(), |k| format!("{:.1}", k as f64 / 1024.0)),
                );
            }
        }
    }
    Ok(())
}

/// Peak resident set size of this process (Linux /proc), KiB.
fn peak_rss_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}
