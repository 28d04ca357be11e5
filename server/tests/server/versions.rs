//! Worker versions: a worker of another `MAJOR.MINOR` than the server is refused with a 422
//! naming both versions, at registration and, after a server upgrade, at its next claim.

use crate::common;

use common::{temp_db, TestServer};
use repose_api::version::RELEASE;
use repose_api::ReleaseVersion;
use reqwest::StatusCode;
use serde_json::{json, Value};
use uuid::Uuid;

fn registration(version: &str) -> Value {
    json!({"instance_id": Uuid::new_v4(), "host": "node-1", "threads": 4, "version": version})
}

fn with_minor(minor: u64, patch: u64) -> ReleaseVersion {
    ReleaseVersion {
        minor,
        patch,
        ..ReleaseVersion::current()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn registration_accepts_the_servers_major_minor_and_refuses_others_naming_both() {
    let (_dir, db) = temp_db();
    // The server pretends to be release X.5.3, so older and newer workers both exist.
    let server_release = with_minor(5, 3);
    let server = TestServer::start(&db, |c| c.release = server_release).await;
    let (status, health) = server.get_as("/healthz", None).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(health["version"], server_release.to_string());

    for accepted in [with_minor(5, 0), with_minor(5, 9)] {
        let (status, body) = server
            .post("/v1/workers/register", &registration(&accepted.to_string()))
            .await;
        assert_eq!(status, StatusCode::OK, "{accepted}: {body}");
    }
    let mut newer_major = server_release;
    newer_major.major += 1;
    for refused in [with_minor(4, 9), with_minor(6, 0), newer_major] {
        let version = refused.to_string();
        let (status, body) = server
            .post("/v1/workers/register", &registration(&version))
            .await;
        assert_eq!(
            status,
            StatusCode::UNPROCESSABLE_ENTITY,
            "{version}: {body}"
        );
        assert_eq!(body["field"], "version", "{body}");
        let message = body["error"].as_str().unwrap();
        assert!(
            message.contains(&format!("worker version {version}"))
                && message.contains(&format!("server version {server_release}")),
            "{message}"
        );
    }
    let (status, body) = server
        .post("/v1/workers/register", &registration("banana"))
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "version");
    assert!(
        body["error"].as_str().unwrap().contains("`banana`"),
        "{body}"
    );
    // Refused workers are not registered.
    let (_, workers) = server.get("/v1/workers").await;
    assert_eq!(workers.as_array().unwrap().len(), 2, "{workers}");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_registered_before_a_server_upgrade_is_refused_at_its_next_claim() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let worker = server.register().await;
    assert!(server.claim(worker, 0.0).await.is_none());
    let worker_token = server.worker_token.clone();
    server.stop().await;

    let upgraded = with_minor(ReleaseVersion::current().minor + 1, 0);
    let server = TestServer::start(&db, |c| c.release = upgraded).await;
    let (status, body) = server
        .post_as(
            "/v1/jobs/claim",
            &json!({"worker_id": worker, "wait_s": 0.0}),
            Some(&worker_token),
        )
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "version");
    let message = body["error"].as_str().unwrap();
    assert!(
        message.contains(&format!("worker version {RELEASE}"))
            && message.contains(&format!("server version {upgraded}"))
            && message.contains("upgrade the worker"),
        "{message}"
    );
    // A worker of the new release registers and claims as usual.
    let (status, body) = server
        .post("/v1/workers/register", &registration(&upgraded.to_string()))
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, _) = server
        .post(
            "/v1/jobs/claim",
            &json!({"worker_id": body["worker_id"], "wait_s": 0.0}),
        )
        .await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    server.stop().await;
}
