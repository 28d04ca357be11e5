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

/// A one-target `aor` campaign whose experiment names no engine, with `extra` merged in.
fn aor_campaign(extra: Value) -> Value {
    let mut campaign = json!({
        "name": "gpu campaign",
        "experiment": {"kind": "aor", "preset": "fast", "spec": {"total_mass": 0.02}},
        "factors": [
            {"name": "mu", "path": "soil_soil.static_friction", "low": 0.2, "high": 0.6},
            {"name": "e", "path": "soil_soil.restitution", "low": 0.3, "high": 0.9}
        ],
        "target": 30.0
    });
    for (k, v) in extra.as_object().unwrap() {
        campaign[k] = v.clone();
    }
    campaign
}

/// GPU-first scheduling (issue 49): a GPU slot's claim leases the GPU jobs even behind older
/// CPU jobs, a CPU slot's the CPU jobs, and a GPU slot of a worker without a GPU is refused
/// naming `backend`. Until a worker with a GPU is seen, a `gpu` batch (and a campaign running
/// one: a campaign-level `backend` reaches an experiment that names none, not one that names
/// `cpu`) says it waits for one in its view, the list, the status page and the metrics; the
/// worker's GPU facts then show in `/v1/workers` and the metrics.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gpu_slots_claim_gpu_jobs_first_and_a_gpu_batch_without_a_gpu_worker_says_so() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let cpu_batch = server.submit(&lookup_batch(json!({}))).await;
    let gpu_batch = server.submit(&aor_batch("gpu")).await;

    let (status, campaign) = server
        .post("/v1/campaigns", &aor_campaign(json!({"backend": "gpu"})))
        .await;
    assert_eq!(status, StatusCode::CREATED, "{campaign}");
    let (_, first) = server
        .get(&format!(
            "/v1/batches/{}",
            campaign["first_batch"].as_str().unwrap()
        ))
        .await;
    assert_eq!(first["backend"], "gpu", "the campaign's backend: {first}");
    let mut own_cpu = aor_campaign(json!({"backend": "gpu"}));
    own_cpu["experiment"]["backend"] = json!("cpu");
    let (status, cpu_campaign) = server.post("/v1/campaigns", &own_cpu).await;
    assert_eq!(status, StatusCode::CREATED, "{cpu_campaign}");
    let (_, first) = server
        .get(&format!(
            "/v1/batches/{}",
            cpu_campaign["first_batch"].as_str().unwrap()
        ))
        .await;
    assert_eq!(first["backend"], "cpu", "the experiment's own: {first}");

    // No worker with a GPU yet: the GPU batch and the GPU campaign say so, the others not.
    let wait = json!({"minutes": 10});
    let (_, view) = server.get(&format!("/v1/batches/{}", gpu_batch.id)).await;
    assert_eq!(view["gpu_wait"], wait, "{view}");
    let (_, view) = server.get(&format!("/v1/batches/{}", cpu_batch.id)).await;
    assert_eq!(view["gpu_wait"], Value::Null, "{view}");
    let (_, list) = server.get("/v1/batches").await;
    let waiting: Vec<_> = list
        .as_array()
        .unwrap()
        .iter()
        .filter(|b| !b["gpu_wait"].is_null())
        .map(|b| b["id"].as_str().unwrap().to_owned())
        .collect();
    assert_eq!(
        waiting.len(),
        2,
        "the GPU batch and the GPU campaign's: {list}"
    );
    assert!(waiting.contains(&gpu_batch.id.to_string()));
    let campaign_id = campaign["id"].as_str().unwrap();
    let (_, view) = server.get(&format!("/v1/campaigns/{campaign_id}")).await;
    assert_eq!(view["gpu_wait"], wait, "{view}");
    let (_, view) = server
        .get(&format!(
            "/v1/campaigns/{}",
            cpu_campaign["id"].as_str().unwrap()
        ))
        .await;
    assert_eq!(view["gpu_wait"], Value::Null, "{view}");
    let (_, list) = server.get("/v1/campaigns").await;
    assert_eq!(
        list.as_array()
            .unwrap()
            .iter()
            .filter(|c| c["gpu_wait"] == wait)
            .count(),
        1,
        "{list}"
    );
    let words = "waiting for a GPU worker: none registered in the last 10 min";
    let (status, page) = server.get_text("/").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(
        page.matches(words).count(),
        3,
        "two batches and a campaign:\n{page}"
    );
    let (_, metrics) = server.get_text("/metrics").await;
    assert!(
        metrics.contains("repose_batches_waiting_for_gpu_worker 2\n"),
        "{metrics}"
    );

    // A CPU-only worker's GPU slot is refused; its CPU slot passes over the GPU jobs.
    let cpu_worker = server.register().await;
    let (status, body) = server
        .post(
            "/v1/jobs/claim",
            &json!({"worker_id": cpu_worker, "wait_s": 0, "backend": "gpu"}),
        )
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "backend", "{body}");

    // A GPU worker: its GPU slot leases the GPU jobs though the CPU batch is older, its CPU
    // slot the CPU jobs.
    let gpu_worker = server.register_gpu("test adapter").await;
    let on_gpu = server
        .claim_on(gpu_worker, 0.0, Some("gpu"))
        .await
        .expect("a GPU job");
    assert_eq!(on_gpu.backend, BackendKind::Gpu);
    assert_eq!(on_gpu.batch_id, gpu_batch.id, "the oldest GPU job");
    let on_cpu = server
        .claim_on(gpu_worker, 0.0, Some("cpu"))
        .await
        .expect("a CPU job");
    assert_eq!(
        (on_cpu.backend, on_cpu.batch_id),
        (BackendKind::Cpu, cpu_batch.id)
    );

    // Seen now: nothing waits any more.
    let (_, view) = server.get(&format!("/v1/batches/{}", gpu_batch.id)).await;
    assert_eq!(view["gpu_wait"], Value::Null, "{view}");
    let (_, view) = server.get(&format!("/v1/campaigns/{campaign_id}")).await;
    assert_eq!(view["gpu_wait"], Value::Null, "{view}");
    let (_, page) = server.get_text("/").await;
    assert!(!page.contains(words), "{page}");
    assert!(page.contains("1 of 2 GPU slots busy"), "{page}");

    let (_, workers) = server.get("/v1/workers").await;
    let workers: Vec<WorkerView> = serde_json::from_value(workers).unwrap();
    let view = workers.iter().find(|w| w.id == gpu_worker).unwrap();
    assert_eq!(
        (
            view.gpu_memory_bytes,
            view.gpu_slots,
            view.gpu_running_jobs,
            view.running_jobs
        ),
        (Some(8 << 30), Some(2), 1, 2)
    );
    let view = workers.iter().find(|w| w.id == cpu_worker).unwrap();
    assert_eq!((view.gpu_memory_bytes, view.gpu_slots), (None, None));
    let (_, metrics) = server.get_text("/metrics").await;
    let labels = format!("{{worker=\"{gpu_worker}\",adapter=\"test adapter\"}}");
    for line in [
        "repose_batches_waiting_for_gpu_worker 0".to_owned(),
        format!("repose_gpu_worker_memory_bytes{labels} {}", 8u64 << 30),
        format!("repose_gpu_worker_slots{labels} 2"),
        format!("repose_gpu_worker_running_jobs{labels} 1"),
    ] {
        assert!(metrics.contains(&format!("{line}\n")), "{line}:\n{metrics}");
    }

    // GPU facts need a GPU, and a GPU needs a slot.
    for (registration, field) in [
        (json!({"gpu_slots": 2}), "gpu_slots"),
        (json!({"gpu_memory_bytes": 1024}), "gpu_memory_bytes"),
        (json!({"gpu": "x", "gpu_slots": 0}), "gpu_slots"),
    ] {
        let mut body = json!({"instance_id": uuid::Uuid::new_v4(), "host": "h", "threads": 1,
                              "version": repose_api::version::RELEASE});
        for (k, v) in registration.as_object().unwrap() {
            body[k] = v.clone();
        }
        let (status, reply) = server.post("/v1/workers/register", &body).await;
        assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}: {reply}");
        assert_eq!(reply["field"], field, "{reply}");
    }
    server.stop().await;
}
