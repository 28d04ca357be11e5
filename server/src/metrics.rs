//! `GET /metrics`: Prometheus text exposition format (version 0.0.4).
//!
//! Counters and the claim-latency histogram live in memory (since the process started); the
//! gauges (jobs and batches by state, workers seen within one lease period, the last time any
//! worker was seen, the database's size) are read from the database at scrape time, and the
//! writer's health (write failures) from the database handle. `deploy/prometheus/` has a
//! scrape configuration and alert rules built on these names.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::extract::{Request, State};
use axum::middleware::Next;
use axum::response::Response;

use crate::types::{Gauges, GpuWorkerGauge};

/// Upper bounds (seconds) of the claim-latency histogram buckets.
const CLAIM_BUCKETS: [f64; 12] = [
    0.000_25, 0.000_5, 0.001, 0.002, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0,
];

/// In-process counters; shared by all requests.
#[derive(Debug)]
pub struct Metrics {
    started: Instant,
    claims: AtomicU64,
    empty_claims: AtomicU64,
    completions: AtomicU64,
    failures: AtomicU64,
    releases: AtomicU64,
    claim_buckets: [AtomicU64; CLAIM_BUCKETS.len()],
    claim_count: AtomicU64,
    claim_sum_ns: AtomicU64,
    /// Responses by status class: index 0 = 1xx … 4 = 5xx.
    http: [AtomicU64; 5],
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics {
            started: Instant::now(),
            claims: AtomicU64::new(0),
            empty_claims: AtomicU64::new(0),
            completions: AtomicU64::new(0),
            failures: AtomicU64::new(0),
            releases: AtomicU64::new(0),
            claim_buckets: Default::default(),
            claim_count: AtomicU64::new(0),
            claim_sum_ns: AtomicU64::new(0),
            http: Default::default(),
        }
    }
}

impl Metrics {
    /// A job was leased; `latency` is the time the claim transaction took.
    pub fn claimed(&self, latency: Duration) {
        self.claims.fetch_add(1, Ordering::Relaxed);
        let seconds = latency.as_secs_f64();
        if let Some(bucket) = CLAIM_BUCKETS.iter().position(|&le| seconds <= le) {
            self.claim_buckets[bucket].fetch_add(1, Ordering::Relaxed);
        }
        self.claim_count.fetch_add(1, Ordering::Relaxed);
        let nanos = u64::try_from(latency.as_nanos()).unwrap_or(u64::MAX);
        self.claim_sum_ns.fetch_add(nanos, Ordering::Relaxed);
    }

    /// A claim ended without a job (204).
    pub fn claim_empty(&self) {
        self.empty_claims.fetch_add(1, Ordering::Relaxed);
    }

    /// A result was stored.
    pub fn completed(&self) {
        self.completions.fetch_add(1, Ordering::Relaxed);
    }

    /// A failure was recorded.
    pub fn failed(&self) {
        self.failures.fetch_add(1, Ordering::Relaxed);
    }

    /// `leases` leases were given back.
    pub fn released(&self, leases: u64) {
        self.releases.fetch_add(leases, Ordering::Relaxed);
    }

    fn responded(&self, status: u16) {
        let class = usize::from(status / 100).clamp(1, 5) - 1;
        self.http[class].fetch_add(1, Ordering::Relaxed);
    }

    /// The exposition text.
    pub fn render(&self, gauges: &Gauges) -> String {
        let mut out = String::with_capacity(4096);
        let load = |counter: &AtomicU64| counter.load(Ordering::Relaxed);

        family(&mut out, "repose_jobs", "gauge", "Jobs by state.");
        for (state, count) in &gauges.jobs {
            let _ = writeln!(out, "repose_jobs{{state=\"{state}\"}} {count}");
        }
        family(&mut out, "repose_batches", "gauge", "Batches by state.");
        for (state, count) in &gauges.batches {
            let _ = writeln!(out, "repose_batches{{state=\"{state}\"}} {count}");
        }
        family(
            &mut out,
            "repose_workers_active",
            "gauge",
            "Workers that registered, claimed or heartbeated within the last lease period.",
        );
        let _ = writeln!(out, "repose_workers_active {}", gauges.workers_active);
        family(
            &mut out,
            "repose_workers_registered",
            "gauge",
            "Workers ever registered.",
        );
        let _ = writeln!(
            out,
            "repose_workers_registered {}",
            gauges.workers_registered
        );
        let window = crate::db::GPU_WORKER_WINDOW.as_secs() / 60;
        family(
            &mut out,
            "repose_batches_waiting_for_gpu_worker",
            "gauge",
            &format!(
                "Active gpu batches while no worker with a GPU was seen within the last {window} min."
            ),
        );
        let _ = writeln!(
            out,
            "repose_batches_waiting_for_gpu_worker {}",
            gauges.batches_waiting_for_gpu
        );
        for (name, help, value) in [
            (
                "repose_gpu_worker_memory_bytes",
                "The GPU memory a worker with a GPU reported at registration",
                (|g: &GpuWorkerGauge| g.memory_bytes) as fn(&GpuWorkerGauge) -> Option<i64>,
            ),
            (
                "repose_gpu_worker_slots",
                "Runs a worker with a GPU shares its GPU among at once",
                |g| g.slots,
            ),
            (
                "repose_gpu_worker_running_jobs",
                "Jobs of gpu batches a worker with a GPU runs now",
                |g| Some(g.running),
            ),
        ] {
            let help = format!("{help} (workers seen within the last {window} min).");
            family(&mut out, name, "gauge", &help);
            for gpu in &gauges.gpu_workers {
                if let Some(value) = value(gpu) {
                    let _ = writeln!(
                        out,
                        "{name}{{worker=\"{}\",adapter=\"{}\"}} {value}",
                        label(&gpu.worker),
                        label(&gpu.adapter)
                    );
                }
            }
        }

        family(
            &mut out,
            "repose_worker_last_seen_timestamp_seconds",
            "gauge",
            "Unix time of the most recent registration, claim or heartbeat of any worker (0: none ever).",
        );
        let _ = writeln!(
            out,
            "repose_worker_last_seen_timestamp_seconds {}",
            gauges.worker_last_seen_ms.unwrap_or(0) as f64 / 1000.0
        );
        family(
            &mut out,
            "repose_database_bytes",
            "gauge",
            "Size of the SQLite database's pages (page_count x page_size; the WAL not included).",
        );
        let _ = writeln!(out, "repose_database_bytes {}", gauges.database_bytes);
        family(
            &mut out,
            "repose_db_writes_failing",
            "gauge",
            "1 while the last write transaction failed and none succeeded since (disk full, I/O error; /healthz is 503), else 0.",
        );
        let _ = writeln!(
            out,
            "repose_db_writes_failing {}",
            u8::from(gauges.writes_failing)
        );
        family(
            &mut out,
            "repose_db_write_failures_total",
            "counter",
            "Write transactions that failed with a database error since the server started.",
        );
        let _ = writeln!(
            out,
            "repose_db_write_failures_total {}",
            gauges.write_failures
        );

        for (name, help, counter) in [
            (
                "repose_claims_total",
                "Jobs leased to workers since the server started.",
                &self.claims,
            ),
            (
                "repose_empty_claims_total",
                "Claims answered 204 (no job within the wait) since the server started.",
                &self.empty_claims,
            ),
            (
                "repose_completions_total",
                "Results stored since the server started.",
                &self.completions,
            ),
            (
                "repose_failures_total",
                "Job failures reported since the server started.",
                &self.failures,
            ),
            (
                "repose_releases_total",
                "Leases given back by workers since the server started.",
                &self.releases,
            ),
        ] {
            family(&mut out, name, "counter", help);
            let _ = writeln!(out, "{name} {}", load(counter));
        }

        let name = "repose_claim_duration_seconds";
        family(
            &mut out,
            name,
            "histogram",
            "Time of the claim transaction of claims that leased a job (long-poll waits excluded).",
        );
        let mut cumulative = 0;
        for (le, bucket) in CLAIM_BUCKETS.iter().zip(&self.claim_buckets) {
            cumulative += load(bucket);
            let _ = writeln!(out, "{name}_bucket{{le=\"{le}\"}} {cumulative}");
        }
        let count = load(&self.claim_count);
        let _ = writeln!(out, "{name}_bucket{{le=\"+Inf\"}} {count}");
        let sum = load(&self.claim_sum_ns) as f64 / 1e9;
        let _ = writeln!(out, "{name}_sum {sum}");
        let _ = writeln!(out, "{name}_count {count}");

        family(
            &mut out,
            "repose_http_responses_total",
            "counter",
            "HTTP responses since the server started, by status class.",
        );
        for (class, counter) in ["1xx", "2xx", "3xx", "4xx", "5xx"].iter().zip(&self.http) {
            let _ = writeln!(
                out,
                "repose_http_responses_total{{class=\"{class}\"}} {}",
                load(counter)
            );
        }
        family(
            &mut out,
            "repose_uptime_seconds",
            "gauge",
            "Seconds since the server started.",
        );
        let _ = writeln!(
            out,
            "repose_uptime_seconds {}",
            self.started.elapsed().as_secs_f64()
        );
        out
    }
}

/// A label value in the text format: backslash, double quote and line feed escaped.
fn label(value: &str) -> String {
    value
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

fn family(out: &mut String, name: &str, kind: &str, help: &str) {
    let _ = writeln!(out, "# HELP {name} {help}");
    let _ = writeln!(out, "# TYPE {name} {kind}");
}

/// Counts every response by status class (installed outermost, so 401s and 404s count too).
pub async fn count_responses(
    State(metrics): State<std::sync::Arc<Metrics>>,
    request: Request,
    next: Next,
) -> Response {
    let response = next.run(request).await;
    metrics.responded(response.status().as_u16());
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_are_cumulative() {
        let metrics = Metrics::default();
        metrics.claimed(Duration::from_micros(100));
        metrics.claimed(Duration::from_micros(700));
        metrics.claimed(Duration::from_secs(3));
        let text = metrics.render(&Gauges::default());
        assert!(text.contains("repose_claim_duration_seconds_bucket{le=\"0.00025\"} 1\n"));
        assert!(text.contains("repose_claim_duration_seconds_bucket{le=\"0.001\"} 2\n"));
        assert!(text.contains("repose_claim_duration_seconds_bucket{le=\"1\"} 2\n"));
        assert!(text.contains("repose_claim_duration_seconds_bucket{le=\"+Inf\"} 3\n"));
        assert!(text.contains("repose_claim_duration_seconds_count 3\n"));
        assert!(text.contains("repose_claims_total 3\n"));
        let sum: f64 = text
            .lines()
            .find_map(|l| l.strip_prefix("repose_claim_duration_seconds_sum "))
            .unwrap()
            .parse()
            .unwrap();
        assert!((sum - 3.0008).abs() < 1e-9, "{sum}");
    }

    #[test]
    fn gpu_workers_are_listed_with_escaped_labels() {
        let gauges = Gauges {
            gpu_workers: vec![GpuWorkerGauge {
                worker: "w1".into(),
                adapter: "GPU \"x\"\\1".into(),
                memory_bytes: Some(1 << 30),
                slots: Some(4),
                running: 2,
            }],
            ..Gauges::default()
        };
        let text = Metrics::default().render(&gauges);
        let labels = r#"{worker="w1",adapter="GPU \"x\"\\1"}"#;
        for line in [
            format!("repose_gpu_worker_memory_bytes{labels} 1073741824"),
            format!("repose_gpu_worker_slots{labels} 4"),
            format!("repose_gpu_worker_running_jobs{labels} 2"),
            "repose_batches_waiting_for_gpu_worker 0".to_owned(),
        ] {
            assert!(text.contains(&format!("{line}\n")), "{line} not in\n{text}");
        }
    }
}
