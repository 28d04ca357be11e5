//! The worker library against the real server (in-process, 127.0.0.1, ephemeral port, temp
//! SQLite): the version refusal, the idle exit, and a `formula` batch from submission to its
//! analysis.

use std::path::Path;
use std::time::Duration;

use repose_api::ReleaseVersion;
use repose_server::{create_token, serve, Config, ServeError, TokenRole};
use repose_worker::{run, WorkerConfig, WorkerError};
use serde_json::json;
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

struct Server {
    url: String,
    stop: oneshot::Sender<()>,
    task: JoinHandle<Result<(), ServeError>>,
}

impl Server {
    async fn start(db: &Path, address: &str, release: ReleaseVersion) -> Server {
        let mut config = Config::new(db);
        config.release = release;
        config.lease = Duration::from_secs(5);
        let listener = TcpListener::bind(address).await.unwrap();
        let url = format!("http://{}", listener.local_addr().unwrap());
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(serve(config, listener, async move {
            let _ = stopped.await;
        }));
        Server { url, stop, task }
    }

    async fn stop(self) {
        let _ = self.stop.send(());
        self.task.await.unwrap().unwrap();
    }
}

fn worker_config(url: &str, token: &str) -> WorkerConfig {
    let mut config = WorkerConfig::new(url);
    config.token = Some(token.to_owned());
    config.threads = 1;
    config.claim_wait = Duration::from_millis(500);
    config.max_backoff = Duration::from_millis(500);
    config
}

/// A replay batch (`table_lookup`) of `points` runs, each holding its worker `hold_s`.
async fn submit_replay(url: &str, user: &str, points: usize, hold_s: f64) {
    let rows: Vec<_> = (0..points)
        .map(|i| json!({"x": i as f64, "y": 1.0 + i as f64}))
        .collect();
    let design: Vec<_> = (0..points).map(|i| json!([i as f64])).collect();
    let batch = json!({
        "name": "replay",
        "experiment": {"kind": "table_lookup",
                       "spec": {"values": {"x": 0.0}, "rows": rows, "hold_s": hold_s}},
        "factors": [{"name": "x", "path": "values.x", "low": 0.0, "high": (points - 1) as f64}],
        "design": {"type": "explicit", "points": design},
        "response": "y",
        "model": "none",
        "seed": 3
    });
    let response = reqwest::Client::new()
        .post(format!("{url}/v1/batches"))
        .bearer_auth(user)
        .json(&batch)
        .send()
        .await
        .unwrap();
    assert!(response.status().is_success(), "{}", response.status());
}

fn bumped_minor() -> ReleaseVersion {
    let current = ReleaseVersion::current();
    ReleaseVersion {
        minor: current.minor + 1,
        patch: 0,
        ..current
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_older_worker_is_refused_at_registration_and_exits_naming_both_versions() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("repose.sqlite");
    let token = create_token(&db, "workers", TokenRole::Worker)
        .await
        .unwrap();
    let server = Server::start(&db, "127.0.0.1:0", bumped_minor()).await;
    let config = worker_config(&server.url, &token);
    let outcome =
        tokio::time::timeout(Duration::from_secs(20), run(config, std::future::pending()))
            .await
            .expect("the worker gives up instead of retrying");
    let Err(WorkerError::IncompatibleVersion(message)) = outcome else {
        panic!("expected a version refusal, got {outcome:?}");
    };
    assert!(
        message.contains(repose_api::version::RELEASE)
            && message.contains(&bumped_minor().to_string()),
        "{message}"
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_running_across_a_server_upgrade_is_refused_at_its_next_claim_and_stops() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("repose.sqlite");
    let token = create_token(&db, "workers", TokenRole::Worker)
        .await
        .unwrap();
    let old = Server::start(&db, "127.0.0.1:0", ReleaseVersion::current()).await;
    let url = old.url.clone();
    let worker = tokio::spawn(run(worker_config(&url, &token), std::future::pending()));
    // Registered and long-polling on the old server.
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(!worker.is_finished());
    old.stop().await;

    // The "upgraded" server on the same address and database.
    let address = url.trim_start_matches("http://").to_owned();
    let new = Server::start(&db, &address, bumped_minor()).await;
    let outcome = tokio::time::timeout(Duration::from_secs(30), worker)
        .await
        .expect("the worker stops instead of retrying forever")
        .unwrap();
    let Err(WorkerError::IncompatibleVersion(message)) = outcome else {
        panic!("expected a version refusal, got {outcome:?}");
    };
    assert!(
        message.contains(repose_api::version::RELEASE)
            && message.contains(&bumped_minor().to_string())
            && message.contains("upgrade the worker"),
        "{message}"
    );
    new.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn exit_when_idle_stops_the_worker_once_the_queue_stays_empty() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("repose.sqlite");
    let token = create_token(&db, "workers", TokenRole::Worker)
        .await
        .unwrap();
    let user = create_token(&db, "someone", TokenRole::User).await.unwrap();
    let server = Server::start(&db, "127.0.0.1:0", ReleaseVersion::current()).await;
    // Each job holds its slot longer than the idle limit: busy slots are not idle.
    submit_replay(&server.url, &user, 3, 1.5).await;
    let mut config = worker_config(&server.url, &token);
    config.slots = 2;
    config.exit_when_idle = Some(Duration::from_secs(1));
    let started = std::time::Instant::now();
    let summary =
        tokio::time::timeout(Duration::from_secs(60), run(config, std::future::pending()))
            .await
            .expect("the idle worker exits by itself")
            .unwrap();
    let took = started.elapsed();
    assert_eq!(summary.completed, 3, "{summary:?}");
    assert_eq!(summary.released, 0, "{summary:?}");
    assert!(summary.exited_idle);
    // Two rounds of 1.5 s jobs, then one idle second (plus a claim's wait at most).
    assert!(took >= Duration::from_secs(4), "{took:?}");
    assert!(took < Duration::from_secs(15), "{took:?}");

    // Without the option, the worker keeps waiting.
    let config = worker_config(&server.url, &token);
    let waiting =
        tokio::time::timeout(Duration::from_secs(3), run(config, std::future::pending())).await;
    assert!(
        waiting.is_err(),
        "a worker without the idle exit keeps waiting"
    );
    server.stop().await;
}

/// POSTs `batch` as `user`; the reply's status and JSON body.
async fn post_batch(url: &str, user: &str, batch: &serde_json::Value) -> (u16, serde_json::Value) {
    let response = reqwest::Client::new()
        .post(format!("{url}/v1/batches"))
        .bearer_auth(user)
        .json(batch)
        .send()
        .await
        .unwrap();
    let status = response.status().as_u16();
    (status, response.json().await.unwrap_or_default())
}

/// GETs `path` as `user`; the reply's status and JSON body.
async fn get(url: &str, user: &str, path: &str) -> (u16, serde_json::Value) {
    let response = reqwest::Client::new()
        .get(format!("{url}{path}"))
        .bearer_auth(user)
        .send()
        .await
        .unwrap();
    let status = response.status().as_u16();
    (status, response.json().await.unwrap_or_default())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_formula_batch_runs_to_its_analysis_and_a_bad_expression_is_a_422_naming_its_field() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("repose.sqlite");
    let token = create_token(&db, "workers", TokenRole::Worker)
        .await
        .unwrap();
    let user = create_token(&db, "someone", TokenRole::User).await.unwrap();
    let server = Server::start(&db, "127.0.0.1:0", ReleaseVersion::current()).await;

    // y = 3 + 2a - b with a little noise; the corner a = 1, b = 2 is a failure region.
    let batch = |response: &str| {
        json!({
            "name": "known answer",
            "experiment": {"kind": "formula", "spec": {
                "inputs": {"a": 0.0, "b": 0.0},
                "responses": {"y": response},
                "noise_sd": {"y": 0.01},
                "fails_when": "a > 0.9 && b > 1.9"}},
            "factors": [{"name": "a", "path": "inputs.a", "low": 0.0, "high": 1.0},
                        {"name": "b", "path": "inputs.b", "low": 0.0, "high": 2.0}],
            "design": {"type": "explicit",
                       "points": [[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [1.0, 2.0],
                                  [0.5, 1.0], [0.5, 1.0]]},
            "response": "y",
            "model": "linear",
            "seed": 5
        })
    };
    let (status, body) = post_batch(&server.url, &user, &batch("3 + 2*a - c")).await;
    assert_eq!(status, 422, "{body}");
    assert_eq!(body["field"], "experiment.spec.responses.y", "{body}");
    assert!(body.to_string().contains("unknown variable 'c'"), "{body}");
    let (status, body) = post_batch(&server.url, &user, &batch("3 + 2*a - b")).await;
    assert_eq!(status, 201, "{body}");
    let id = body["id"].as_str().unwrap().to_owned();

    let mut config = worker_config(&server.url, &token);
    config.exit_when_idle = Some(Duration::from_secs(1));
    let summary =
        tokio::time::timeout(Duration::from_secs(60), run(config, std::future::pending()))
            .await
            .expect("the idle worker exits by itself")
            .unwrap();
    assert_eq!(summary.completed, 5, "{summary:?}");
    assert_eq!(summary.failed, 1, "{summary:?}");

    let (status, runs) = get(&server.url, &user, &format!("/v1/batches/{id}/runs")).await;
    assert_eq!(status, 200, "{runs}");
    for run in runs.as_array().unwrap() {
        let (a, b) = (
            run["factors"][0]["natural"].as_f64().unwrap(),
            run["factors"][1]["natural"].as_f64().unwrap(),
        );
        if a == 1.0 && b == 2.0 {
            // Dead at once: a closed form fails under every seed, so no reseed.
            assert_eq!(run["status"], "dead", "{run}");
            assert_eq!(run["attempts"], 1, "{run}");
            assert!(
                run["last_error"]
                    .as_str()
                    .unwrap()
                    .contains("fails_when holds"),
                "{run}"
            );
        } else {
            assert_eq!(run["status"], "completed", "{run}");
            let y = run["metrics"]["y"].as_f64().unwrap();
            assert!((y - (3.0 + 2.0 * a - b)).abs() < 0.06, "{run}");
        }
    }

    let mut analysis = serde_json::Value::Null;
    for _ in 0..200 {
        let (status, body) = get(&server.url, &user, &format!("/v1/batches/{id}/analysis")).await;
        if status == 200 {
            analysis = body;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(analysis["runs_used"], 5, "{analysis}");
    // In coded units: a's half range 0.5 gives 1.0, b's half range 1 gives -1.0.
    let coefficient = |term: &str| {
        analysis["fit"]["coefficients"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["term"] == term)
            .unwrap_or_else(|| panic!("no {term}: {analysis}"))["estimate"]
            .as_f64()
            .unwrap()
    };
    assert!((coefficient("a") - 1.0).abs() < 0.05, "{analysis}");
    assert!((coefficient("b") + 1.0).abs() < 0.05, "{analysis}");
    server.stop().await;
}

/// The GPU tests' adapter (lavapipe in CI), opened for this test alone, or none with a message
/// where none can be opened (`REPOSE_REQUIRE_GPU=1`, which `.ci/run` sets where lavapipe is
/// installed, makes that a failure).
fn test_gpu() -> Option<std::sync::Arc<repose_experiments::backend::Gpu>> {
    match repose_experiments::backend::Gpu::open() {
        Ok(gpu) => Some(std::sync::Arc::new(gpu)),
        Err(e) if std::env::var("REPOSE_REQUIRE_GPU").is_ok_and(|v| v == "1") => {
            panic!("REPOSE_REQUIRE_GPU=1 but {e}")
        }
        Err(e) => {
            eprintln!("SKIPPED: {e}");
            None
        }
    }
}

/// A `gpu` batch of `runs` small funnels (the GPU tests' funnel at half its mass: about 280
/// grains of 4 mm, a few seconds each on lavapipe).
fn small_gpu_funnels(runs: usize) -> serde_json::Value {
    let points: Vec<_> = (0..runs).map(|k| json!([0.4 + 0.02 * k as f64])).collect();
    json!({
        "name": "small GPU funnels",
        "experiment": {"kind": "aor", "backend": "gpu", "preset": "fast", "spec": {
            "particle": {"radius": 0.002},
            "total_mass": 0.025,
            "mass_rate": 0.25,
            "funnel": {"outlet_diameter": 0.04},
            "base": {"size": 0.15},
            "materials": {"soil": {"youngs_modulus": 1e6}},
            "soil_soil": {"rolling_friction": 0.3},
            "settle": {"min_time": 0.1, "check_interval": 0.05, "creep_window_s": 0.15},
            "time_cap": 1.5
        }},
        "factors": [{"name": "mu_s", "path": "soil_soil.static_friction", "low": 0.4, "high": 0.5}],
        "design": {"type": "explicit", "points": points},
        "response": "angle_deg",
        "model": "none",
        "seed": 3
    })
}

/// A worker with one CPU slot and two GPU slots (issue 49): the GPU slots run a `gpu` batch's
/// two jobs at once on the one adapter while the CPU slot takes the CPU jobs, one at a time;
/// `/v1/workers` shows its GPU. Then its GPU is lost in the middle of two runs: both jobs are
/// reported failed, naming the lost device (they go back to the queue for another worker),
/// and the worker stops with `GpuFailed` for its service manager to start it again.
#[test]
fn gpu_slots_run_gpu_jobs_at_once_beside_a_cpu_slot_and_a_lost_gpu_fails_them() {
    let Some(gpu) = test_gpu() else { return };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async move {
        let dir = tempfile::tempdir().unwrap();
        let db = dir.path().join("repose.sqlite");
        let token = create_token(&db, "workers", TokenRole::Worker)
            .await
            .unwrap();
        let user = create_token(&db, "someone", TokenRole::User).await.unwrap();
        let server = Server::start(&db, "127.0.0.1:0", ReleaseVersion::current()).await;
        let url = server.url.clone();
        submit_replay(&url, &user, 2, 1.0).await;
        let (status, body) = post_batch(&url, &user, &small_gpu_funnels(2)).await;
        assert_eq!(status, 201, "{body}");
        let gpu_batch = body["id"].as_str().unwrap().to_owned();

        let mut config = worker_config(&url, &token);
        config.slots = 1;
        config.gpu_slots = 2;
        config.gpu = Some(gpu.clone());
        let (stop, stopped) = oneshot::channel::<()>();
        let worker = tokio::spawn(run(config, async move {
            let _ = stopped.await;
        }));

        // Until every run is in: the most GPU runs at once, and the most CPU jobs leased at once.
        let (mut gpu_peak, mut cpu_peak, mut view) = (0, 0, serde_json::Value::Null);
        let deadline = std::time::Instant::now() + Duration::from_secs(120);
        loop {
            gpu_peak = gpu_peak.max(gpu.in_flight().0);
            let (_, workers) = get(&url, &user, "/v1/workers").await;
            if let Some(w) = workers.get(0) {
                let (all, on_gpu) = (w["running_jobs"].as_u64(), w["gpu_running_jobs"].as_u64());
                cpu_peak = cpu_peak.max(all.unwrap_or(0) - on_gpu.unwrap_or(0));
                view = w.clone();
            }
            let (_, batches) = get(&url, &user, "/v1/batches").await;
            let batches = batches.as_array().unwrap();
            if batches.iter().all(|b| b["state"] != "active") {
                break;
            }
            assert!(std::time::Instant::now() < deadline, "{batches:?}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        assert_eq!(gpu_peak, 2, "the two GPU slots run at once");
        assert_eq!(cpu_peak, 1, "the CPU slot runs one CPU job at a time");
        assert_eq!(view["gpu"].as_str(), Some(gpu.name()), "{view}");
        assert_eq!(view["gpu_slots"], 2, "{view}");
        assert_eq!(view["gpu_memory_bytes"].as_u64(), gpu.memory(), "{view}");
        let (_, runs) = get(&url, &user, &format!("/v1/batches/{gpu_batch}/runs")).await;
        for run in runs.as_array().unwrap() {
            assert_eq!(run["status"], "completed", "{run}");
            assert_eq!(run["worker_id"], view["id"], "{run}");
            let engine = run["engine_version"].as_str().unwrap();
            assert!(engine.contains(&format!("+gpu:{}", gpu.name())), "{run}");
        }
        assert_eq!(gpu.in_flight(), (0, 0));

        // The GPU is lost while both GPU slots run.
        let (status, body) = post_batch(&url, &user, &small_gpu_funnels(2)).await;
        assert_eq!(status, 201, "{body}");
        let lost_batch = body["id"].as_str().unwrap().to_owned();
        let deadline = std::time::Instant::now() + Duration::from_secs(60);
        while gpu.in_flight().0 < 2 {
            assert!(
                std::time::Instant::now() < deadline,
                "the runs never started"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        gpu.destroy();
        let stopped = tokio::time::timeout(Duration::from_secs(60), worker)
            .await
            .expect("a worker whose GPU was lost stops")
            .unwrap();
        match stopped {
            Err(WorkerError::GpuFailed { reason }) => {
                assert!(reason.contains("Destroyed"), "{reason}")
            }
            other => panic!("the worker of a lost GPU: {other:?}"),
        }
        let (_, runs) = get(&url, &user, &format!("/v1/batches/{lost_batch}/runs")).await;
        for run in runs.as_array().unwrap() {
            // Back in the queue (after the retry back-off) for another worker.
            assert_eq!(run["status"], "queued", "{run}");
            assert_eq!(run["attempts"], 1, "{run}");
            let error = run["last_error"].as_str().unwrap_or_default();
            assert!(
                error.contains("device was lost") && error.contains("goes to another"),
                "{run}"
            );
        }
        drop(stop);
        server.stop().await;
    });
    // A lost device's runs may leave their threads behind: the test does not wait for them.
    runtime.shutdown_background();
}
