//! Test harness: the real server on 127.0.0.1:0 with a temporary SQLite file, and a fake
//! worker whose "simulation" is a known function of the spec.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::time::Duration;

use repose_api::{
    AnalysisView, BatchCreated, BatchStatus, ClaimResponse, Completion, RunView, WorkerRegistration,
};
use repose_server::{create_token, serve, Config, ServeError, TokenRole};
use reqwest::StatusCode;
use serde_json::{json, Value};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use uuid::Uuid;

/// A running server and the means to stop it, with one user and one worker token.
pub struct TestServer {
    pub url: String,
    pub client: reqwest::Client,
    /// Name of the user token (owner of the batches this harness submits).
    pub user_name: String,
    /// Secret of a user (API) token.
    pub user_token: String,
    /// Secret of a worker token.
    pub worker_token: String,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<Result<(), ServeError>>>,
}

impl TestServer {
    /// Starts a server on the database at `db_path`, letting `tweak` adjust the config, after
    /// creating a fresh user and worker token in it.
    pub async fn start(db_path: &Path, tweak: impl FnOnce(&mut Config)) -> TestServer {
        let suffix = Uuid::new_v4().simple().to_string();
        let user_name = format!("user-{}", &suffix[..8]);
        let user_token = create_token(db_path, &user_name, TokenRole::User)
            .await
            .unwrap();
        let worker_token = create_token(
            db_path,
            &format!("worker-{}", &suffix[..8]),
            TokenRole::Worker,
        )
        .await
        .unwrap();
        let mut config = Config::new(db_path);
        config.retry_backoff = Duration::ZERO;
        tweak(&mut config);
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let url = format!("http://{}", listener.local_addr().unwrap());
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(serve(config, listener, async move {
            let _ = stopped.await;
        }));
        let server = TestServer {
            url,
            client: reqwest::Client::new(),
            user_name,
            user_token,
            worker_token,
            stop: Some(stop),
            task: Some(task),
        };
        // The listener is bound already; wait until migrations ran and requests are served.
        for _ in 0..200 {
            if let Ok(response) = server.client.get(server.url("/healthz")).send().await {
                if response.status().is_success() {
                    return server;
                }
            }
            tokio::time::sleep(Duration::from_millis(25)).await;
        }
        panic!("server did not become healthy");
    }

    pub fn url(&self, path: &str) -> String {
        format!("{}{}", self.url, path)
    }

    /// Graceful shutdown; returns once the database is closed.
    pub async fn stop(mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(task) = self.task.take() {
            task.await.unwrap().unwrap();
        }
    }

    /// The token a POST to `path` is sent with: the worker token for the worker protocol
    /// (`/v1/workers/…`, `/v1/jobs/…`), the user token otherwise.
    fn token_for_post(&self, path: &str) -> &str {
        if path.starts_with("/v1/jobs") || path.starts_with("/v1/workers") {
            &self.worker_token
        } else {
            &self.user_token
        }
    }

    /// POST with the token the path needs.
    pub async fn post(&self, path: &str, body: &Value) -> (StatusCode, Value) {
        self.post_as(path, body, Some(self.token_for_post(path)))
            .await
    }

    /// POST with an explicit token, or none.
    pub async fn post_as(
        &self,
        path: &str,
        body: &Value,
        token: Option<&str>,
    ) -> (StatusCode, Value) {
        let mut request = self.client.post(self.url(path)).json(body);
        if let Some(token) = token {
            request = request.bearer_auth(token);
        }
        json_reply(request.send().await.unwrap()).await
    }

    pub async fn post_raw(&self, path: &str, body: &str) -> (StatusCode, Value) {
        let response = self
            .client
            .post(self.url(path))
            .bearer_auth(self.token_for_post(path))
            .header("content-type", "application/json")
            .body(body.to_owned())
            .send()
            .await
            .unwrap();
        json_reply(response).await
    }

    /// GET with the user token.
    pub async fn get(&self, path: &str) -> (StatusCode, Value) {
        self.get_as(path, Some(&self.user_token)).await
    }

    /// GET with an explicit token, or none.
    pub async fn get_as(&self, path: &str, token: Option<&str>) -> (StatusCode, Value) {
        let mut request = self.client.get(self.url(path));
        if let Some(token) = token {
            request = request.bearer_auth(token);
        }
        json_reply(request.send().await.unwrap()).await
    }

    pub async fn get_text(&self, path: &str) -> (StatusCode, String) {
        let response = self
            .client
            .get(self.url(path))
            .bearer_auth(&self.user_token)
            .send()
            .await
            .unwrap();
        (response.status(), response.text().await.unwrap())
    }

    pub async fn submit(&self, request: &Value) -> BatchCreated {
        let (status, body) = self.post("/v1/batches", request).await;
        assert_eq!(status, StatusCode::CREATED, "{body}");
        serde_json::from_value(body).unwrap()
    }

    pub async fn status(&self, batch: Uuid) -> BatchStatus {
        let (status, body) = self.get(&format!("/v1/batches/{batch}")).await;
        assert_eq!(status, StatusCode::OK, "{body}");
        serde_json::from_value(body).unwrap()
    }

    pub async fn runs(&self, batch: Uuid) -> Vec<RunView> {
        let (status, body) = self.get(&format!("/v1/batches/{batch}/runs")).await;
        assert_eq!(status, StatusCode::OK, "{body}");
        serde_json::from_value(body).unwrap()
    }

    pub async fn register(&self) -> Uuid {
        self.register_as(Uuid::new_v4()).await
    }

    /// Registers a worker under `worker` (again, if it registered before).
    pub async fn register_as(&self, worker: Uuid) -> Uuid {
        self.register_with(worker, None).await
    }

    /// Registers a fresh worker that names the GPU adapter `adapter` (it may claim gpu jobs).
    pub async fn register_gpu(&self, adapter: &str) -> Uuid {
        self.register_with(Uuid::new_v4(), Some(adapter)).await
    }

    /// Registers a worker under `worker`, with the GPU adapter `gpu` if any.
    pub async fn register_with(&self, worker: Uuid, gpu: Option<&str>) -> Uuid {
        let registration = WorkerRegistration {
            instance_id: worker,
            host: "test-host".into(),
            threads: 1,
            version: repose_api::version::RELEASE.into(),
            gpu: gpu.map(str::to_owned),
            gpu_memory_bytes: gpu.map(|_| 8 << 30),
            gpu_slots: gpu.map(|_| 2),
        };
        let (status, body) = self
            .post(
                "/v1/workers/register",
                &serde_json::to_value(registration).unwrap(),
            )
            .await;
        assert_eq!(status, StatusCode::OK, "{body}");
        worker
    }

    /// One claim; `None` on 204.
    pub async fn claim(&self, worker: Uuid, wait_s: f64) -> Option<ClaimResponse> {
        self.claim_on(worker, wait_s, None).await
    }

    /// One claim of a slot of `backend` (none: any job the worker can run); `None` on 204.
    pub async fn claim_on(
        &self,
        worker: Uuid,
        wait_s: f64,
        backend: Option<&str>,
    ) -> Option<ClaimResponse> {
        let (status, body) = self
            .post(
                "/v1/jobs/claim",
                &json!({"worker_id": worker, "wait_s": wait_s, "backend": backend}),
            )
            .await;
        match status {
            StatusCode::OK => Some(serde_json::from_value(body).unwrap()),
            StatusCode::NO_CONTENT => None,
            other => panic!("claim answered {other}: {body}"),
        }
    }

    pub async fn complete(&self, job: &ClaimResponse) -> (StatusCode, Value) {
        self.complete_with(job, &simulate(job)).await
    }

    /// Delivers `completion` as `job`'s result.
    pub async fn complete_with(
        &self,
        job: &ClaimResponse,
        completion: &Completion,
    ) -> (StatusCode, Value) {
        self.post(
            &format!("/v1/jobs/{}/complete", job.job_id),
            &serde_json::to_value(completion).unwrap(),
        )
        .await
    }

    /// Polls until the batch's analysis is stored.
    pub async fn wait_for_analysis(&self, batch: Uuid) -> AnalysisView {
        for _ in 0..400 {
            let (status, body) = self.get(&format!("/v1/batches/{batch}/analysis")).await;
            if status == StatusCode::OK {
                return serde_json::from_value(body).unwrap();
            }
            assert_eq!(status, StatusCode::CONFLICT, "{body}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        panic!("analysis of {batch} never appeared");
    }
}

/// Status and JSON body of a reply (`Null` when the body is not JSON).
pub async fn json_reply(response: reqwest::Response) -> (StatusCode, Value) {
    let status = response.status();
    let text = response.text().await.unwrap();
    (status, serde_json::from_str(&text).unwrap_or(Value::Null))
}

/// The fake DEM run: angle = 20 + 25 μ − 8 e + seed-dependent noise of ±0.1°.
pub fn angle_for(spec: &Value, seed: u64) -> f64 {
    let mu = spec["soil_soil"]["static_friction"].as_f64().unwrap();
    let e = spec["soil_soil"]["restitution"].as_f64().unwrap();
    let noise = ((seed % 1000) as f64 / 1000.0 - 0.5) * 0.2;
    20.0 + 25.0 * mu - 8.0 * e + noise
}

pub fn simulate(job: &ClaimResponse) -> Completion {
    Completion {
        lease_token: job.lease_token,
        metrics: [("angle_deg".to_owned(), angle_for(&job.spec, job.seed))].into(),
        wall_time_s: 0.01,
        details: json!({"worker": "fake"}),
        engine_version: Some("fake-engine".into()),
        pictures: [(
            "pile.svg".to_owned(),
            format!("<svg><!-- run {} --></svg>", job.run_id),
        )]
        .into(),
    }
}

/// Claims and completes jobs until the queue stays empty for `idle_s`.
pub async fn run_fake_worker(server: &TestServer, idle_s: f64) -> usize {
    let worker = server.register().await;
    let mut done = 0;
    while let Some(job) = server.claim(worker, idle_s).await {
        let (status, body) = server.complete(&job).await;
        assert_eq!(status, StatusCode::OK, "{body}");
        done += 1;
    }
    done
}

/// A two-factor angle-of-repose batch over `design`.
pub fn batch_request(design: Value, model: &str, replicates: u32) -> Value {
    json!({
        "name": "sand AOR",
        "experiment": {
            "kind": "aor",
            "preset": "fast",
            "spec": {"total_mass": 0.02}
        },
        "factors": [
            {"name": "mu", "path": "soil_soil.static_friction", "low": 0.2, "high": 0.6},
            {"name": "e", "path": "soil_soil.restitution", "low": 0.3, "high": 0.9}
        ],
        "design": design,
        "replicates": replicates,
        "response": "angle_deg",
        "model": model,
        "target": 30.0,
        "seed": 42
    })
}

/// A fresh temporary directory holding the database file.
pub fn temp_db() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("repose.sqlite");
    (dir, path)
}
