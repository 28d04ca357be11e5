//! Access control, request limits and path validation over real HTTP.

use crate::common;

use common::{batch_request, json_reply, temp_db, TestServer};
use repose_server::{create_token, revoke_token, TokenRole, ENDPOINTS};
use reqwest::{header, StatusCode};
use serde_json::{json, Value};
use uuid::Uuid;

fn factorial() -> Value {
    batch_request(json!({"type": "factorial"}), "linear", 1)
}

/// A 401 carries a JSON error and a Bearer challenge.
async fn expect_401(response: reqwest::Response, needle: &str) {
    assert_eq!(response.status(), StatusCode::UNAUTHORIZED);
    let challenge = response
        .headers()
        .get(header::WWW_AUTHENTICATE)
        .expect("WWW-Authenticate on 401")
        .to_str()
        .unwrap()
        .to_owned();
    assert!(challenge.starts_with("Bearer"), "{challenge}");
    let (_, body) = json_reply(response).await;
    let message = body["error"].as_str().expect("JSON error body");
    assert!(message.contains(needle), "{message:?} lacks {needle:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn requests_without_a_valid_token_get_401() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let client = &server.client;

    // Health needs nothing.
    let response = client.get(server.url("/healthz")).send().await.unwrap();
    assert_eq!(response.status(), StatusCode::OK);

    // No header, on a read, a user write and a worker write.
    for (method, path) in [
        ("GET", "/v1/batches"),
        ("GET", "/v1/workers"),
        ("GET", "/v1/jobs"),
        ("POST", "/v1/batches"),
        ("POST", "/v1/jobs/claim"),
        ("POST", "/v1/workers/register"),
    ] {
        let request = match method {
            "GET" => client.get(server.url(path)),
            _ => client.post(server.url(path)).json(&json!({})),
        };
        expect_401(request.send().await.unwrap(), "needs a token").await;
    }
    // Wrong scheme, garbage, and a well-formed token that was never issued.
    let response = client
        .get(server.url("/v1/batches"))
        .header(header::AUTHORIZATION, "Basic dXNlcjpwYXNz")
        .send()
        .await
        .unwrap();
    expect_401(response, "Bearer").await;
    for (token, needle) in [
        ("letmein", "invalid token"),
        ("rp_user_0123456789abcdef0123456789abcdef", "unknown token"),
    ] {
        let response = client
            .get(server.url("/v1/batches"))
            .bearer_auth(token)
            .send()
            .await
            .unwrap();
        expect_401(response, needle).await;
    }
    // Nothing was stored by the rejected submission.
    let (status, body) = server.get("/v1/batches").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body, json!([]));
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn revoked_tokens_get_401_at_once() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let (status, _) = server.get("/v1/batches").await;
    assert_eq!(status, StatusCode::OK);
    let worker = server.register().await;

    // Revoked through the library while the server runs (what `repose token revoke` does).
    revoke_token(&db, &server.user_name).await.unwrap();
    let response = server
        .client
        .get(server.url("/v1/batches"))
        .bearer_auth(&server.user_token)
        .send()
        .await
        .unwrap();
    expect_401(response, "revoked").await;
    let (status, _) = server.post("/v1/batches", &factorial()).await;
    assert_eq!(status, StatusCode::UNAUTHORIZED);

    // The worker token is unaffected; revoking it stops the worker too.
    assert!(server.claim(worker, 0.0).await.is_none());
    let worker_name = repose_server::list_tokens(&db)
        .await
        .unwrap()
        .into_iter()
        .find(|t| t.role == TokenRole::Worker)
        .unwrap()
        .name;
    revoke_token(&db, &worker_name).await.unwrap();
    let (status, body) = server
        .post("/v1/jobs/claim", &json!({"worker_id": worker, "wait_s": 0}))
        .await;
    assert_eq!(status, StatusCode::UNAUTHORIZED, "{body}");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_of_the_wrong_role_get_403() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let user = Some(server.user_token.as_str());
    let worker = Some(server.worker_token.as_str());
    let registration = json!({"instance_id": Uuid::new_v4(), "host": "h", "threads": 1,
                              "version": repose_api::version::RELEASE});

    // A user token on the worker protocol.
    let (status, body) = server
        .post_as("/v1/workers/register", &registration, user)
        .await;
    assert_eq!(status, StatusCode::FORBIDDEN, "{body}");
    assert!(body["error"].as_str().unwrap().contains("worker token"));
    let claim = json!({"worker_id": Uuid::new_v4(), "wait_s": 0});
    let (status, _) = server.post_as("/v1/jobs/claim", &claim, user).await;
    assert_eq!(status, StatusCode::FORBIDDEN);

    // A worker token submitting or cancelling.
    let (status, body) = server.post_as("/v1/batches", &factorial(), worker).await;
    assert_eq!(status, StatusCode::FORBIDDEN, "{body}");
    assert!(body["error"].as_str().unwrap().contains("user token"));
    let batch = server.submit(&factorial()).await;
    let (status, _) = server
        .post_as(
            &format!("/v1/batches/{}/cancel", batch.id),
            &json!({}),
            worker,
        )
        .await;
    assert_eq!(status, StatusCode::FORBIDDEN);

    // Worker tokens may read.
    let (status, body) = server
        .get_as(&format!("/v1/batches/{}", batch.id), worker)
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["state"], "active");
    assert_eq!(body["owner"], server.user_name.as_str());
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_the_owner_may_cancel_a_batch() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let bob = create_token(&db, "bob", TokenRole::User).await.unwrap();
    let batch = server.submit(&factorial()).await;

    let cancel = format!("/v1/batches/{}/cancel", batch.id);
    let (status, body) = server.post_as(&cancel, &json!({}), Some(&bob)).await;
    assert_eq!(status, StatusCode::FORBIDDEN, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains(&server.user_name),
        "{body}"
    );
    assert_eq!(
        server.status(batch.id).await.summary.owner.as_deref(),
        Some(server.user_name.as_str())
    );
    assert_eq!(
        server.status(batch.id).await.summary.state,
        repose_api::BatchState::Active,
        "nothing changed"
    );
    // Bob may read it, and the owner may cancel it.
    let (status, _) = server
        .get_as(&format!("/v1/batches/{}", batch.id), Some(&bob))
        .await;
    assert_eq!(status, StatusCode::OK);
    let (status, body) = server.post(&cancel, &json!({})).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["state"], "cancelled");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn open_read_lets_anonymous_gets_through_but_not_posts() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| config.open_read = true).await;
    let batch = server.submit(&factorial()).await;
    for path in [
        "/v1/batches".to_owned(),
        format!("/v1/batches/{}", batch.id),
        format!("/v1/batches/{}/runs", batch.id),
        "/v1/workers".to_owned(),
        "/v1/jobs".to_owned(),
        "/metrics".to_owned(),
    ] {
        let (status, body) = server.get_as(&path, None).await;
        assert_eq!(status, StatusCode::OK, "{path}: {body}");
    }
    // A bad token is still refused even where anonymous reads are allowed.
    let (status, _) = server.get_as("/v1/batches", Some("nonsense")).await;
    assert_eq!(status, StatusCode::UNAUTHORIZED);
    for path in [
        "/v1/batches".to_owned(),
        format!("/v1/batches/{}/cancel", batch.id),
        "/v1/jobs/claim".to_owned(),
        "/v1/workers/register".to_owned(),
    ] {
        let (status, body) = server.post_as(&path, &factorial(), None).await;
        assert_eq!(status, StatusCode::UNAUTHORIZED, "{path}: {body}");
    }
    assert_eq!(
        server.status(batch.id).await.summary.state,
        repose_api::BatchState::Active
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_bodies_get_413_with_a_json_error() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| config.body_limit_bytes = 2048).await;
    let mut request = factorial();
    request["name"] = json!("x".repeat(4096));
    let (status, body) = server.post("/v1/batches", &request).await;
    assert_eq!(status, StatusCode::PAYLOAD_TOO_LARGE, "{body}");
    assert!(!body["error"].as_str().expect("JSON error").is_empty());
    // Under the limit the same request is fine.
    server.submit(&factorial()).await;
    server.stop().await;
}

/// Every endpoint with an id in its path answers 400 naming the id when it is not a UUID and
/// 404 naming it when nothing has that id; unknown paths and methods answer JSON too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_path_id_is_validated() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    // A body every job update accepts, so only the id can be wrong.
    let update = json!({"lease_token": Uuid::new_v4(), "metrics": {"angle_deg": 1.0},
                        "wall_time_s": 1.0, "error": "x", "progress": 0.5});
    let with_id: Vec<_> = ENDPOINTS
        .iter()
        .filter(|e| e.path.contains("{id}"))
        .collect();
    assert!(with_id.len() >= 8);
    for endpoint in with_id {
        // `/v1/batches/{id}/…` names a batch, `/v1/jobs/{id}/…` a job, and so on.
        let collection = endpoint.path.split('/').nth(2).unwrap();
        let what = collection
            .strip_suffix("es")
            .filter(|stem| stem.ends_with("ch"))
            .or_else(|| collection.strip_suffix('s'))
            .unwrap();
        let unknown = Uuid::new_v4();
        for (id, expected, needle) in [
            (
                "not-a-uuid".to_owned(),
                StatusCode::BAD_REQUEST,
                format!("invalid {what} id `not-a-uuid`"),
            ),
            (
                unknown.to_string(),
                StatusCode::NOT_FOUND,
                format!("{what} {unknown} not found"),
            ),
        ] {
            let path = endpoint.path.replace("{id}", &id);
            let (status, body) = match endpoint.verb {
                repose_server::Verb::Get => server.get(&path).await,
                repose_server::Verb::Post => server.post(&path, &update).await,
            };
            assert_eq!(status, expected, "{path}: {body}");
            let message = body["error"].as_str().unwrap_or_default();
            assert!(message.contains(&needle), "{path}: {body}");
        }
    }
    let (status, body) = server.get("/v1/nothing-here").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert!(body["error"].is_string());
    let (status, body) = server.get("/v1/jobs/claim").await;
    assert_eq!(status, StatusCode::METHOD_NOT_ALLOWED);
    assert!(body["error"].is_string());
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn workers_and_jobs_are_listed() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let batch = server.submit(&factorial()).await;
    let worker = server.register().await;
    let job = server.claim(worker, 0.0).await.unwrap();

    let (status, workers) = server.get("/v1/workers").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(workers[0]["id"], json!(worker));
    assert_eq!(workers[0]["running_jobs"], 1);
    assert!(workers[0]["last_seen_at_ms"].as_i64().unwrap() > 0);

    let (status, running) = server.get("/v1/jobs?state=running").await;
    assert_eq!(status, StatusCode::OK, "{running}");
    assert_eq!(running.as_array().unwrap().len(), 1);
    assert_eq!(running[0]["id"], json!(job.job_id));
    assert_eq!(running[0]["worker_id"], json!(worker));
    let (status, all) = server
        .get(&format!("/v1/jobs?batch={}&limit=3", batch.id))
        .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(all.as_array().unwrap().len(), 3);
    let (status, queued) = server.get("/v1/jobs?state=queued").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(queued.as_array().unwrap().len(), 3);
    let (status, none) = server
        .get(&format!("/v1/jobs?batch={}", Uuid::new_v4()))
        .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(none, json!([]));
    for bad in ["state=sleeping", "batch=nope", "limit=0", "limit=many"] {
        let (status, body) = server.get(&format!("/v1/jobs?{bad}")).await;
        assert_eq!(status, StatusCode::BAD_REQUEST, "{bad}: {body}");
        assert!(body["error"].is_string());
    }
    server.stop().await;
}

/// `--private-reads`: a user reads only its own batches (another user's is 403 and missing from
/// the list), anonymous reads are refused, and a worker token reads only its workers' jobs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn private_reads_keep_users_to_their_own_batches_and_workers_to_their_jobs() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| config.private_reads = true).await;
    let other = create_token(&db, "someone-else", TokenRole::User)
        .await
        .unwrap();
    let mine = server.submit(&factorial()).await;
    let theirs: Value = {
        let (status, body) = server
            .post_as("/v1/batches", &factorial(), Some(&other))
            .await;
        assert_eq!(status, StatusCode::CREATED, "{body}");
        body
    };
    let theirs = theirs["id"].as_str().unwrap().to_owned();

    for path in ["", "/runs", "/analysis"] {
        let (status, body) = server.get(&format!("/v1/batches/{theirs}{path}")).await;
        assert_eq!(status, StatusCode::FORBIDDEN, "{path}: {body}");
        let (status, _) = server
            .get_as(&format!("/v1/batches/{theirs}{path}"), Some(&other))
            .await;
        assert_ne!(status, StatusCode::FORBIDDEN, "the owner reads {path}");
    }
    let (status, list) = server.get("/v1/batches").await;
    assert_eq!(status, StatusCode::OK);
    let ids: Vec<&str> = list
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, [mine.id.to_string()]);
    let (status, _) = server.get_as("/v1/batches", None).await;
    assert_eq!(status, StatusCode::UNAUTHORIZED);

    // Workers: only GET /v1/jobs, and only the jobs of the workers their token registered.
    let worker = server.register().await;
    let job = server.claim(worker, 0.0).await.unwrap();
    let (status, _) = server
        .get_as(
            &format!("/v1/batches/{}", mine.id),
            Some(&server.worker_token),
        )
        .await;
    assert_eq!(status, StatusCode::FORBIDDEN);
    let (status, jobs) = server.get_as("/v1/jobs", Some(&server.worker_token)).await;
    assert_eq!(status, StatusCode::OK, "{jobs}");
    let listed: Vec<&str> = jobs
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["id"].as_str().unwrap())
        .collect();
    assert_eq!(listed, [job.job_id.to_string()]);
    // The other user sees only its own batch's jobs.
    let (_, jobs) = server.get_as("/v1/jobs", Some(&other)).await;
    assert!(jobs
        .as_array()
        .unwrap()
        .iter()
        .all(|j| j["batch_id"] == theirs.as_str()));
    server.stop().await;
}
