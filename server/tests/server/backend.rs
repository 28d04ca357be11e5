//! `"backend": "gpu"` beside `kind` (issue 38): what the server refuses at submission, naming
//! `experiment.backend`, and which workers may claim a GPU batch's jobs.

use crate::common;
use crate::paper;

use common::{batch_request, temp_db, TestServer};
use repose_api::{BackendKind, WorkerView};
use reqwest::StatusCode;
use serde_json::{json, Value};

/// A small `aor` batch on `backend` (two runs).
fn aor_batch(backend: &str) -> Value {
    let mut request = batch_request(json!({"type": "factorial"}), "none", 1);
    request["experiment"]["backend"] = json!(backend);
    request["factors"].as_array_mut().unwrap().truncate(1);
    request
}

/// A one-factor `table_lookup` batch (two runs) with the given experiment fields merged in.
fn lookup_batch(experiment: Value) -> Value {
    let mut template = json!({
        "kind": "table_lookup",
        "spec": {"values": {"a": 0.0}, "rows": [{"a": 0.0, "y": 1.0}, {"a": 1.0, "y": 2.0}]}
    });
    for (k, v) in experiment.as_object().unwrap() {
        template[k] = v.clone();
    }
    json!({
        "name": "lookup",
        "experiment": template,
        "factors": [{"name": "a", "path": "values.a", "low": 0.0, "high": 1.0}],
        "design": {"type": "factorial"},
        "response": "y",
        "model": "none"
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_backend_the_experiment_cannot_run_on_is_a_422_naming_experiment_backend() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let refused = |body: &Value, what: &str| {
        assert_eq!(body["field"], "experiment.backend", "{what}: {body}");
    };
    // Only `aor`, `drill` and `shear` run on the GPU.
    let (status, body) = server
        .post("/v1/batches", &lookup_batch(json!({"backend": "gpu"})))
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    refused(&body, "table_lookup on the GPU");
    assert!(
        body["error"].as_str().unwrap().contains("CPU backend only"),
        "{body}"
    );
    for (kind, response) in [
        ("drill", "opening_diameter_mm"),
        ("shear", "friction_angle_deg"),
    ] {
        let mut request = aor_batch("gpu");
        request["experiment"] = json!({"kind": kind, "preset": "fast", "backend": "gpu"});
        request["response"] = json!(response);
        let (status, body) = server.post("/v1/batches", &request).await;
        assert_eq!(status, StatusCode::CREATED, "{kind} on the GPU: {body}");
    }
    // No such backend: the JSON itself is refused, at the same field.
    let (status, body) = server
        .post("/v1/batches", &lookup_batch(json!({"backend": "tpu"})))
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    refused(&body, "an unknown backend");
    assert!(body["error"].as_str().unwrap().contains("tpu"), "{body}");
    // Every `aor` and `drill` spec runs on the GPU: the lifted cylinder (a moving tube), EPSD
    // rolling, JKR cohesion.
    for (kind, spec) in [
        ("aor", json!({"protocol": "lifted_cylinder"})),
        ("aor", json!({"rolling_model": "epsd"})),
        (
            "aor",
            json!({"soil_soil": {"cohesion": {"model": "jkr", "surface_energy": 0.1}}}),
        ),
        (
            "drill",
            json!({"soil_steel": {"cohesion": {"model": "jkr", "surface_energy": 0.1}}}),
        ),
    ] {
        let mut request = aor_batch("gpu");
        request["experiment"] = json!({"kind": kind, "preset": "fast", "backend": "gpu"});
        request["experiment"]["spec"] = spec.clone();
        if kind == "drill" {
            request["response"] = json!("opening_diameter_mm");
        }
        let (status, body) = server.post("/v1/batches", &request).await;
        assert_eq!(
            status,
            StatusCode::CREATED,
            "{kind} {spec} on the GPU: {body}"
        );
    }
    // A campaign's experiment is checked the same way.
    let mut campaign = paper::paper_campaign_json("gpu lookup campaign");
    campaign["experiment"]["backend"] = json!("gpu");
    campaign["stage_experiments"]["screening"]["backend"] = json!("gpu");
    let (status, body) = server.post("/v1/campaigns", &campaign).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    refused(&body, "a campaign's table_lookup on the GPU");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_a_worker_that_registered_a_gpu_claims_a_gpu_batchs_jobs() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    // The GPU batch is the oldest in the queue; a CPU batch after it.
    let gpu_batch = server.submit(&aor_batch("gpu")).await;
    let cpu_batch = server.submit(&lookup_batch(json!({}))).await;
    assert_eq!((gpu_batch.run_count, cpu_batch.run_count), (2, 2));

    // A CPU-only worker passes over the GPU jobs: it leases the CPU batch's, then nothing.
    let cpu_worker = server.register().await;
    for _ in 0..2 {
        let job = server.claim(cpu_worker, 0.0).await.expect("a CPU job");
        assert_eq!(job.batch_id, cpu_batch.id);
        assert_eq!(job.backend, BackendKind::Cpu);
    }
    assert!(
        server.claim(cpu_worker, 0.0).await.is_none(),
        "a CPU-only worker claimed a GPU job"
    );

    // A worker that names an adapter claims them, told to run them on the GPU.
    let gpu_worker = server.register_gpu("test adapter").await;
    for _ in 0..2 {
        let job = server.claim(gpu_worker, 0.0).await.expect("a GPU job");
        assert_eq!(job.batch_id, gpu_batch.id);
        assert_eq!(job.backend, BackendKind::Gpu);
        assert_eq!(job.kind, "aor");
    }
    assert!(server.claim(gpu_worker, 0.0).await.is_none());

    let (status, workers) = server.get("/v1/workers").await;
    assert_eq!(status, StatusCode::OK);
    let workers: Vec<WorkerView> = serde_json::from_value(workers).unwrap();
    let adapter = |id| {
        workers
            .iter()
            .find(|w| w.id == id)
            .map(|w| w.gpu.clone())
            .unwrap()
    };
    assert_eq!(adapter(cpu_worker), None);
    assert_eq!(adapter(gpu_worker).as_deref(), Some("test adapter"));

    // Registering again without an adapter (restarted without --gpu) takes the capability
    // back: its leases went back to the queue and it claims no GPU job now.
    server.register_with(gpu_worker, None).await;
    assert!(server.claim(gpu_worker, 0.0).await.is_none());
    server.stop().await;
}
