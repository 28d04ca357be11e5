//! `repose bench engine`: particle-steps per second of the DEM engine on a settled bed
//! (Hertz-Mindlin + tangential history + rolling friction, periodic in x and y), for several
//! sizes and thread counts, plus memory per particle. `repose bench server`: the job server
//! alone (no simulation) under many concurrent fake workers. Results go in BENCHMARKS.md.

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
    /// Job server throughput: one large batch, many concurrent fake workers claiming and
    /// completing jobs over HTTP (server in this process on 127.0.0.1, no simulation).
    Server(ServerBenchArgs),
}

#[derive(Debug, Args)]
pub struct EngineBenchArgs {
    /// Particle counts, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "10000,40000,160000")]
    pub particles: Vec<usize>,
    /// Thread counts of the CPU engine, comma-separated. With `--backend gpu`, the CPU engine
    /// is timed on the GPU-settled bed at these counts only if `--cpu-steps` is given.
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub threads: Vec<usize>,
    /// Timed steps per measurement.
    #[arg(long, default_value_t = 2000)]
    pub steps: u64,
    /// The engine: `cpu` (the reference) or `gpu` (wgpu: Vulkan, Metal, DX12). With `gpu` the
    /// bed is settled on the GPU too.
    #[arg(long, value_enum, default_value_t = crate::backend::Backend::Cpu)]
    pub backend: crate::backend::Backend,
    /// Which engine settles the bed before the timed steps (default: the one timed).
    #[arg(long, value_enum)]
    pub settle: Option<crate::backend::Backend>,
    /// With `--backend gpu`: also time the CPU engine on the same bed, this many steps (the
    /// CPU is slower: fewer steps give the same confidence).
    #[arg(long)]
    pub cpu_steps: Option<u64>,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Print JSON lines instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct Row {
    particles: usize,
    /// `cpu` or `gpu`.
    backend: &'static str,
    /// CPU threads (0 for the GPU).
    threads: usize,
    steps: u64,
    seconds: f64,
    mega_particle_steps_per_s: f64,
    /// Against the CPU engine on one thread on the same bed, when measured.
    speedup_vs_1_thread: Option<f64>,
    contacts_per_particle: f64,
    pairs_per_particle: f64,
    rebuilds: u64,
    model_bytes_per_particle: f64,
    /// Peak resident memory of this process so far (VmHWM), KiB.
    peak_rss_kib: Option<u64>,
    settle_seconds: f64,
    /// GPU rows: the fastest grain after the timed steps, m/s (a settled bed stays at rest).
    fastest_speed: Option<f64>,
}

impl Row {
    /// A measurement as a row; `single` is the CPU engine's one-thread rate on the same bed,
    /// M particle-steps/s, when measured.
    fn new(
        r: &BenchResult,
        backend: &'static str,
        single: Option<f64>,
        settle_seconds: f64,
        fastest_speed: Option<f64>,
    ) -> Row {
        let rate = r.particle_steps_per_second / 1e6;
        Row {
            particles: r.particles,
            backend,
            threads: r.threads,
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
            fastest_speed,
        }
    }
}

pub fn run(args: &BenchArgs) -> Result<()> {
    match &args.what {
        BenchWhat::Engine(a) => engine(a),
        BenchWhat::Server(a) => server(a),
    }
}

fn engine(args: &EngineBenchArgs) -> Result<()> {
    if args.particles.iter().any(|&n| n < 100) {
        bail!("--particles: each count must be at least 100");
    }
    if args.threads.contains(&0) {
        bail!("--threads: each count must be at least 1");
    }
    if args.settle == Some(crate::backend::Backend::Gpu)
        && args.backend != crate::backend::Backend::Gpu
    {
        bail!("--settle gpu needs --backend gpu");
    }
    if args.steps == 0 || args.cpu_steps == Some(0) {
        bail!("--steps and --cpu-steps must be at least 1");
    }
    let gpu = match args.backend {
        crate::backend::Backend::Gpu => {
            let gpu = repose_engine_gpu::Gpu::open().context("--backend gpu")?;
            crate::backend::announce_and_log(&gpu);
            Some(gpu)
        }
        crate::backend::Backend::Cpu => None,
    };
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
        let settle_on_gpu = args.settle.unwrap_or(args.backend) == crate::backend::Backend::Gpu;
        let bed = match gpu.as_ref().filter(|_| settle_on_gpu) {
            Some(gpu) => {
                repose_engine_gpu::bench::settled_bed(gpu, n, args.seed)
                    .context("settling the bed on the GPU")?
                    .0
            }
            None => settled_bed(n, args.seed).context("building the settled bed")?,
        };
        let settle_seconds = started.elapsed().as_secs_f64();
        let mut single: Option<f64> = None;
        let cpu_steps = match gpu {
            Some(_) => args.cpu_steps,
            None => Some(args.steps),
        };
        if let Some(steps) = cpu_steps {
            for &threads in &args.threads {
                let r: BenchResult = time_steps(&bed, threads, steps);
                let rate = r.particle_steps_per_second / 1e6;
                if threads == 1 {
                    single = Some(rate);
                }
                print_row(
                    args.json,
                    &Row::new(&r, "cpu", single, settle_seconds, None),
                )?;
            }
        }
        if let Some(gpu) = &gpu {
            let r = repose_engine_gpu::bench::time_steps(gpu, &bed, args.steps)
                .context("timing the GPU engine")?;
            print_row(
                args.json,
                &Row::new(
                    &r.bench,
                    "gpu",
                    single,
                    settle_seconds,
                    Some(r.fastest_speed),
                ),
            )?;
        }
    }
    Ok(())
}

fn print_row(json: bool, row: &Row) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(row)?);
    } else {
        println!(
            "{:>9} {:>7} {:>8.2} {:>10.2} {:>8} {:>9.2} {:>7.2} {:>9.0} {:>11}",
            row.particles,
            if row.backend == "gpu" {
                "gpu".to_owned()
            } else {
                row.threads.to_string()
            },
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
        if let Some(v) = row.fastest_speed {
            println!("{:>9} fastest grain after the timed steps: {v:.4} m/s", "");
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

#[derive(Debug, Args)]
pub struct ServerBenchArgs {
    /// Runs in the batch (a multiple of 4, at most 10 000: a 2² factorial with replicates).
    #[arg(long, default_value_t = 10_000)]
    pub runs: usize,
    /// Concurrent fake workers (tokio tasks, each claim → complete in a loop).
    #[arg(long, default_value_t = 32)]
    pub workers: usize,
    /// SQLite file to use (default: a fresh file in a temporary directory).
    #[arg(long)]
    pub db: Option<std::path::PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Serialize)]
struct ServerBenchReport {
    runs: usize,
    workers: usize,
    submit_s: f64,
    drain_s: f64,
    cycles_per_s: f64,
    claim_p50_ms: f64,
    claim_p99_ms: f64,
    claim_max_ms: f64,
    complete_p50_ms: f64,
    complete_p99_ms: f64,
    complete_max_ms: f64,
    /// Server-side claim transaction time from `/metrics` (mean), ms.
    server_claim_mean_ms: f64,
    empty_claims: u64,
}

/// One fake worker's latencies, seconds.
#[derive(Debug, Default)]
struct WorkerTimes {
    claims: Vec<f64>,
    completes: Vec<f64>,
    empty: u64,
}

fn server(args: &ServerBenchArgs) -> Result<()> {
    if args.runs == 0 || args.runs % 4 != 0 || args.runs > 10_000 {
        bail!("--runs must be a positive multiple of 4, at most 10000");
    }
    if args.workers == 0 {
        bail!("--workers must be at least 1");
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let report = runtime.block_on(server_bench(args))?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "runs {}  workers {}  submit {:.2} s  drain {:.2} s  {:.0} claim+complete cycles/s",
            report.runs, report.workers, report.submit_s, report.drain_s, report.cycles_per_s
        );
        println!(
            "claim    p50 {:.2} ms  p99 {:.2} ms  max {:.2} ms  (server-side transaction mean {:.3} ms; {} empty claims)",
            report.claim_p50_ms,
            report.claim_p99_ms,
            report.claim_max_ms,
            report.server_claim_mean_ms,
            report.empty_claims
        );
        println!(
            "complete p50 {:.2} ms  p99 {:.2} ms  max {:.2} ms",
            report.complete_p50_ms, report.complete_p99_ms, report.complete_max_ms
        );
    }
    Ok(())
}

async fn server_bench(args: &ServerBenchArgs) -> Result<ServerBenchReport> {
    use repose_server::{create_token, serve, Config, TokenRole};
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;

    let temp = tempfile::tempdir().context("creating a temporary directory")?;
    let db = args
        .db
        .clone()
        .unwrap_or_else(|| temp.path().join("bench.sqlite"));
    let tag = uuid::Uuid::new_v4().simple().to_string();
    let user = create_token(&db, &format!("bench-user-{}", &tag[..8]), TokenRole::User)
        .await
        .context("creating the user token")?;
    let worker_token = create_token(
        &db,
        &format!("bench-worker-{}", &tag[..8]),
        TokenRole::Worker,
    )
    .await
    .context("creating the worker token")?;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let base = format!("http://{}", listener.local_addr()?);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(serve(Config::new(&db), listener, async move {
        let _ = stopped.await;
    }));
    let client = reqwest::Client::builder()
        .pool_max_idle_per_host(args.workers + 4)
        .build()?;
    wait_healthy(&client, &base).await?;

    // A 2² factorial on the table_lookup replay kind: every run is a table look-up, so the
    // workers spend no time simulating.
    let rows: Vec<serde_json::Value> = [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
        .iter()
        .map(|&(a, b)| serde_json::json!({"A": a, "B": b, "y": 30.0 + 2.0 * a - b}))
        .collect();
    let request = serde_json::json!({
        "name": "server bench",
        "experiment": {"kind": "table_lookup", "spec": {"values": {"A": 0.0, "B": 0.0}, "rows": rows}},
        "factors": [
            {"name": "A", "path": "values.A", "low": -1.0, "high": 1.0},
            {"name": "B", "path": "values.B", "low": -1.0, "high": 1.0}
        ],
        "design": {"type": "factorial"},
        "replicates": args.runs / 4,
        "response": "y",
        "model": "linear",
        "seed": 1
    });
    let submitted = Instant::now();
    let response = client
        .post(format!("{base}/v1/batches"))
        .bearer_auth(&user)
        .json(&request)
        .send()
        .await?;
    if response.status() != reqwest::StatusCode::CREATED {
        bail!(
            "submission answered {}: {}",
            response.status(),
            response.text().await?
        );
    }
    let submit_s = submitted.elapsed().as_secs_f64();

    let done = Arc::new(AtomicUsize::new(0));
    let started = Instant::now();
    let mut tasks = Vec::new();
    for _ in 0..args.workers {
        let (client, base, token, done) = (
            client.clone(),
            base.clone(),
            worker_token.clone(),
            done.clone(),
        );
        let runs = args.runs;
        tasks.push(tokio::spawn(async move {
            fake_worker(client, base, token, done, runs).await
        }));
    }
    let mut times = WorkerTimes::default();
    for task in tasks {
        let mut one = task.await.context("worker task")??;
        times.claims.append(&mut one.claims);
        times.completes.append(&mut one.completes);
        times.empty += one.empty;
    }
    let drain_s = started.elapsed().as_secs_f64();
    let completed = done.load(Ordering::Relaxed);
    if completed != args.runs {
        bail!("{completed} of {} runs completed", args.runs);
    }

    let metrics = client
        .get(format!("{base}/metrics"))
        .bearer_auth(&user)
        .send()
        .await?
        .text()
        .await?;
    let sample = |name: &str| -> f64 {
        metrics
            .lines()
            .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
            .unwrap_or(f64::NAN)
    };
    let server_claim_mean_ms = 1e3 * sample("repose_claim_duration_seconds_sum")
        / sample("repose_claim_duration_seconds_count");

    let _ = stop.send(());
    server
        .await
        .context("server task")?
        .context("server failed")?;
    let ms = |values: &mut Vec<f64>, q: f64| percentile(values, q) * 1e3;
    Ok(ServerBenchReport {
        runs: args.runs,
        workers: args.workers,
        submit_s,
        drain_s,
        cycles_per_s: args.runs as f64 / drain_s,
        claim_p50_ms: ms(&mut times.claims, 0.50),
        claim_p99_ms: ms(&mut times.claims, 0.99),
        claim_max_ms: ms(&mut times.claims, 1.0),
        complete_p50_ms: ms(&mut times.completes, 0.50),
        complete_p99_ms: ms(&mut times.completes, 0.99),
        complete_max_ms: ms(&mut times.completes, 1.0),
        server_claim_mean_ms,
        empty_claims: times.empty,
    })
}

async fn wait_healthy(client: &reqwest::Client, base: &str) -> Result<()> {
    for _ in 0..400 {
        if let Ok(response) = client.get(format!("{base}/healthz")).send().await {
            if response.status().is_success() {
                return Ok(());
            }
        }
        tokio::time::sleep(std::time::Duration::from_millis(25)).await;
    }
    bail!("the server did not become healthy")
}

/// Registers, then claims and completes until every run of the batch is done.
async fn fake_worker(
    client: reqwest::Client,
    base: String,
    token: String,
    done: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    runs: usize,
) -> Result<WorkerTimes> {
    use std::sync::atomic::Ordering;
    let id = uuid::Uuid::new_v4();
    let registration = repose_api::WorkerRegistration {
        instance_id: id,
        host: "bench".into(),
        threads: 1,
        version: repose_api::version::RELEASE.into(),
        gpu: None,
        gpu_memory_bytes: None,
        gpu_slots: None,
    };
    let response = client
        .post(format!("{base}/v1/workers/register"))
        .bearer_auth(&token)
        .json(&registration)
        .send()
        .await?;
    if !response.status().is_success() {
        bail!("registration answered {}", response.status());
    }
    let mut times = WorkerTimes::default();
    let claim = repose_api::ClaimRequest {
        worker_id: id,
        wait_s: 0.2,
        backend: None,
    };
    while done.load(Ordering::Relaxed) < runs {
        let started = Instant::now();
        let response = client
            .post(format!("{base}/v1/jobs/claim"))
            .bearer_auth(&token)
            .json(&claim)
            .send()
            .await?;
        match response.status() {
            reqwest::StatusCode::OK => {}
            reqwest::StatusCode::NO_CONTENT => {
                times.empty += 1;
                continue;
            }
            other => bail!("claim answered {other}: {}", response.text().await?),
        }
        let job: repose_api::ClaimResponse = response.json().await?;
        times.claims.push(started.elapsed().as_secs_f64());
        let a = job.spec["values"]["A"].as_f64().unwrap_or(0.0);
        let b = job.spec["values"]["B"].as_f64().unwrap_or(0.0);
        let completion = repose_api::Completion {
            lease_token: job.lease_token,
            metrics: [("y".to_owned(), 30.0 + 2.0 * a - b)].into(),
            wall_time_s: 0.0,
            details: serde_json::Value::Null,
            engine_version: None,
            pictures: Default::default(),
        };
        let started = Instant::now();
        let response = client
            .post(format!("{base}/v1/jobs/{}/complete", job.job_id))
            .bearer_auth(&token)
            .json(&completion)
            .send()
            .await?;
        if response.status() != reqwest::StatusCode::OK {
            bail!(
                "complete answered {}: {}",
                response.status(),
                response.text().await?
            );
        }
        times.completes.push(started.elapsed().as_secs_f64());
        done.fetch_add(1, Ordering::Relaxed);
    }
    Ok(times)
}

/// The `q` quantile (nearest rank) of `values`, sorting them; NaN when empty.
fn percentile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let rank = ((q * values.len() as f64).ceil() as usize).clamp(1, values.len());
    values[rank - 1]
}

#[cfg(test)]
mod tests {
    use super::percentile;

    #[test]
    fn nearest_rank_percentiles() {
        let mut values: Vec<f64> = (1..=100).rev().map(f64::from).collect();
        assert_eq!(percentile(&mut values, 0.5), 50.0);
        assert_eq!(percentile(&mut values, 0.99), 99.0);
        assert_eq!(percentile(&mut values, 1.0), 100.0);
        assert!(percentile(&mut [], 0.5).is_nan());
    }
}
