//! The worker's side of the job protocol: typed calls over HTTP, nothing else.

use std::time::Duration;

use repose_api::{
    ApiError, BackendKind, ClaimRequest, ClaimResponse, Completion, Failure, Heartbeat,
    HeartbeatResponse, JobUpdateResponse, Release, WorkerRegistered, WorkerRegistration,
};
use reqwest::StatusCode;
use serde::de::DeserializeOwned;
use serde::Serialize;
use uuid::Uuid;

/// Why a call did not succeed.
#[derive(Debug, thiserror::Error)]
pub enum CallError {
    /// No answer (connection refused, reset, timeout): worth retrying.
    #[error("server unreachable: {0}")]
    Unreachable(#[source] reqwest::Error),
    /// The server answered with an error status.
    #[error("server answered {status}: {message}")]
    Status {
        /// The status code.
        status: StatusCode,
        /// The server's explanation (with the field it blames, if any).
        message: String,
        /// The request field the server blamed, if any.
        field: Option<String>,
    },
    /// The server answered 2xx with a body that is not the expected type.
    #[error("unexpected reply: {0}")]
    Decode(String),
}

impl CallError {
    /// Transient: the same call may succeed later (no answer, or the server is overloaded or
    /// restarting).
    pub fn is_transient(&self) -> bool {
        match self {
            CallError::Unreachable(_) => true,
            CallError::Status { status, .. } => {
                status.is_server_error() || *status == StatusCode::TOO_MANY_REQUESTS
            }
            CallError::Decode(_) => false,
        }
    }

    /// The server does not accept this worker's release (422 blaming `version`): retrying
    /// cannot help; the worker has to be upgraded (or the server).
    pub fn is_version_refusal(&self) -> bool {
        matches!(self, CallError::Status { status, field: Some(field), .. }
            if *status == StatusCode::UNPROCESSABLE_ENTITY && field == "version")
    }

    /// The server refused the update because the lease is no longer ours (409) or the job is
    /// gone (404).
    pub fn is_lost_lease(&self) -> bool {
        matches!(self, CallError::Status { status, .. }
            if *status == StatusCode::CONFLICT || *status == StatusCode::NOT_FOUND)
    }
}

/// HTTP client for one server.
#[derive(Debug, Clone)]
pub struct Client {
    http: reqwest::Client,
    base: String,
    token: Option<String>,
}

impl Client {
    /// `server` like `http://10.0.0.5:8080`; `token` is sent as `Authorization: Bearer`.
    pub fn new(server: &str, token: Option<String>) -> Result<Client, reqwest::Error> {
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(5))
            // The server closes connections idle for its header-read timeout (30 s); dropping
            // ours sooner avoids sending a request on a connection it is closing.
            .pool_idle_timeout(Duration::from_secs(20))
            .build()?;
        Ok(Client {
            http,
            base: server.trim_end_matches('/').to_owned(),
            token,
        })
    }

    /// Registers (or re-registers) this worker.
    pub async fn register(
        &self,
        registration: &WorkerRegistration,
    ) -> Result<WorkerRegistered, CallError> {
        self.post(
            "/v1/workers/register",
            registration,
            Duration::from_secs(10),
        )
        .await?
        .ok_or_else(|| CallError::Decode("empty registration reply".into()))
    }

    /// Asks for a job, waiting up to `wait`; `None` when none appeared.
    pub async fn claim(
        &self,
        worker_id: Uuid,
        wait: Duration,
        backend: Option<BackendKind>,
    ) -> Result<Option<ClaimResponse>, CallError> {
        let request = ClaimRequest {
            worker_id,
            wait_s: wait.as_secs_f64(),
            backend,
        };
        self.post("/v1/jobs/claim", &request, wait + Duration::from_secs(10))
            .await
    }

    /// Renews the lease and reports progress.
    pub async fn heartbeat(
        &self,
        job_id: Uuid,
        beat: &Heartbeat,
    ) -> Result<HeartbeatResponse, CallError> {
        self.post(
            &format!("/v1/jobs/{job_id}/heartbeat"),
            beat,
            Duration::from_secs(10),
        )
        .await?
        .ok_or_else(|| CallError::Decode("empty heartbeat reply".into()))
    }

    /// Stores a result.
    pub async fn complete(
        &self,
        job_id: Uuid,
        completion: &Completion,
    ) -> Result<JobUpdateResponse, CallError> {
        self.update(job_id, "complete", completion).await
    }

    /// Reports a failed attempt.
    pub async fn fail(
        &self,
        job_id: Uuid,
        failure: &Failure,
    ) -> Result<JobUpdateResponse, CallError> {
        self.update(job_id, "fail", failure).await
    }

    /// Gives the job back without counting the attempt.
    pub async fn release(
        &self,
        job_id: Uuid,
        release: &Release,
    ) -> Result<JobUpdateResponse, CallError> {
        self.update(job_id, "release", release).await
    }

    async fn update<B: Serialize>(
        &self,
        job_id: Uuid,
        action: &str,
        body: &B,
    ) -> Result<JobUpdateResponse, CallError> {
        self.post(
            &format!("/v1/jobs/{job_id}/{action}"),
            body,
            Duration::from_secs(30),
        )
        .await?
        .ok_or_else(|| CallError::Decode(format!("empty {action} reply")))
    }

    /// POSTs JSON; `Ok(None)` for 204 No Content.
    async fn post<B: Serialize, T: DeserializeOwned>(
        &self,
        path: &str,
        body: &B,
        timeout: Duration,
    ) -> Result<Option<T>, CallError> {
        let mut request = self
            .http
            .post(format!("{}{path}", self.base))
            .timeout(timeout)
            .json(body);
        if let Some(token) = &self.token {
            request = request.bearer_auth(token);
        }
        let response = request.send().await.map_err(CallError::Unreachable)?;
        let status = response.status();
        if status == StatusCode::NO_CONTENT {
            return Ok(None);
        }
        let bytes = response.bytes().await.map_err(CallError::Unreachable)?;
        if !status.is_success() {
            let (message, field) = match serde_json::from_slice::<ApiError>(&bytes) {
                Ok(ApiError {
                    error,
                    field: Some(field),
                }) => (format!("{error} (field {field})"), Some(field)),
                Ok(ApiError { error, field: None }) => (error, None),
                Err(_) => (
                    String::from_utf8_lossy(&bytes).chars().take(200).collect(),
                    None,
                ),
            };
            return Err(CallError::Status {
                status,
                message,
                field,
            });
        }
        serde_json::from_slice(&bytes)
            .map(Some)
            .map_err(|e| CallError::Decode(e.to_string()))
    }
}
