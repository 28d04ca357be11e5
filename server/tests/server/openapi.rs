//! `api/openapi.json` against the route table and against real responses.

use crate::common;

use std::collections::BTreeSet;

use common::{batch_request, run_fake_worker, temp_db, TestServer};
use repose_server::{Access, Verb, ENDPOINTS};
use reqwest::StatusCode;
use serde_json::{json, Value};
use uuid::Uuid;

fn document() -> Value {
    serde_json::from_str(repose_api::OPENAPI_JSON).expect("openapi.json is JSON")
}

#[test]
fn document_names_this_release() {
    // The worker protocol is versioned by the release (`repose_api::version`): a document
    // that names another release describes another protocol.
    assert_eq!(document()["info"]["version"], repose_api::version::RELEASE);
}

#[test]
fn document_lists_exactly_the_routes_with_their_access() {
    let doc = document();
    assert!(doc["openapi"].as_str().unwrap().starts_with("3."));
    let mut documented = BTreeSet::new();
    for (path, item) in doc["paths"].as_object().unwrap() {
        for (method, operation) in item.as_object().unwrap() {
            documented.insert((method.clone(), path.clone()));
            let endpoint = ENDPOINTS
                .iter()
                .find(|e| e.path == path && e.verb.as_str() == method)
                .unwrap_or_else(|| panic!("{method} {path} is documented but not routed"));
            let access = match endpoint.access {
                Access::Public => "public",
                Access::Read => "read",
                Access::User => "user",
                Access::Worker => "worker",
            };
            assert_eq!(operation["x-repose-access"], access, "{method} {path}");
            let security = operation["security"].as_array().unwrap();
            assert_eq!(security.is_empty(), access == "public", "{method} {path}");
            let responses = operation["responses"].as_object().unwrap();
            if access != "public" {
                assert!(responses.contains_key("401"), "{method} {path} lacks 401");
            }
            if matches!(access, "user" | "worker") {
                assert!(responses.contains_key("403"), "{method} {path} lacks 403");
            }
            if path.contains("{id}") {
                assert!(responses.contains_key("400") && responses.contains_key("404"));
            }
        }
    }
    let routed: BTreeSet<_> = ENDPOINTS
        .iter()
        .map(|e| (e.verb.as_str().to_owned(), e.path.to_owned()))
        .collect();
    assert_eq!(documented, routed);

    // Every reference resolves.
    let schemas = doc["components"]["schemas"].as_object().unwrap();
    let mut refs = Vec::new();
    collect_refs(&doc, &mut refs);
    assert!(refs.len() > 30);
    for reference in refs {
        let name = reference
            .strip_prefix("#/components/schemas/")
            .unwrap_or_else(|| panic!("unexpected $ref {reference}"));
        assert!(schemas.contains_key(name), "dangling $ref {reference}");
    }
}

fn collect_refs(value: &Value, out: &mut Vec<String>) {
    match value {
        Value::Object(map) => {
            for (key, inner) in map {
                match (key.as_str(), inner) {
                    ("$ref", Value::String(target)) => out.push(target.clone()),
                    _ => collect_refs(inner, out),
                }
            }
        }
        Value::Array(items) => items.iter().for_each(|v| collect_refs(v, out)),
        _ => {}
    }
}

/// The property names of a schema (following `allOf` and `$ref`).
fn properties(doc: &Value, schema: &str) -> BTreeSet<String> {
    let node = &doc["components"]["schemas"][schema];
    let mut names = BTreeSet::new();
    let parts: Vec<&Value> = match node["allOf"].as_array() {
        Some(parts) => parts.iter().collect(),
        None => vec![node],
    };
    for part in parts {
        if let Some(target) = part["$ref"].as_str() {
            names.extend(properties(doc, target.rsplit('/').next().unwrap()));
        } else {
            names.extend(part["properties"].as_object().unwrap().keys().cloned());
        }
    }
    assert!(!names.is_empty(), "schema {schema} has no properties");
    names
}

fn keys(value: &Value) -> BTreeSet<String> {
    value
        .as_object()
        .expect("an object")
        .keys()
        .cloned()
        .collect()
}

/// Real replies carry exactly the documented properties (catches drift when wire types change).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn real_responses_match_the_documented_schemas() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let doc = document();

    let response = server
        .client
        .get(server.url("/openapi.json"))
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), StatusCode::OK, "served without a token");
    let served: Value = response.json().await.unwrap();
    assert_eq!(served, doc);

    let (status, created) = server
        .post(
            "/v1/batches",
            &batch_request(json!({"type": "factorial"}), "linear", 1),
        )
        .await;
    assert_eq!(status, StatusCode::CREATED);
    assert_eq!(keys(&created), properties(&doc, "BatchCreated"));
    let batch = created["id"].as_str().unwrap().to_owned();

    let (_, list) = server.get("/v1/batches").await;
    assert_eq!(keys(&list[0]), properties(&doc, "BatchSummary"));
    let (_, status_body) = server.get(&format!("/v1/batches/{batch}")).await;
    assert_eq!(keys(&status_body), properties(&doc, "BatchStatus"));

    let worker = Uuid::new_v4();
    let (_, registered) = server
        .post(
            "/v1/workers/register",
            &json!({"instance_id": worker, "host": "h", "threads": 1, "version": repose_api::version::RELEASE}),
        )
        .await;
    assert_eq!(keys(&registered), properties(&doc, "WorkerRegistered"));
    let (_, claim) = server
        .post("/v1/jobs/claim", &json!({"worker_id": worker, "wait_s": 0}))
        .await;
    assert_eq!(keys(&claim), properties(&doc, "ClaimResponse"));
    let job = claim["job_id"].as_str().unwrap();
    let token = &claim["lease_token"];
    let (_, beat) = server
        .post(
            &format!("/v1/jobs/{job}/heartbeat"),
            &json!({"lease_token": token}),
        )
        .await;
    assert_eq!(keys(&beat), properties(&doc, "HeartbeatResponse"));
    let (_, workers) = server.get("/v1/workers").await;
    assert_eq!(keys(&workers[0]), properties(&doc, "WorkerView"));
    let (_, jobs) = server.get("/v1/jobs").await;
    assert_eq!(keys(&jobs[0]), properties(&doc, "JobView"));
    let (_, released) = server
        .post(
            &format!("/v1/jobs/{job}/release"),
            &json!({"lease_token": token}),
        )
        .await;
    assert_eq!(keys(&released), properties(&doc, "JobUpdateResponse"));

    assert_eq!(run_fake_worker(&server, 0.2).await, 4);
    let id: Uuid = batch.parse().unwrap();
    server.wait_for_analysis(id).await;
    let (_, analysis) = server.get(&format!("/v1/batches/{batch}/analysis")).await;
    assert_eq!(keys(&analysis), properties(&doc, "AnalysisView"));
    let (_, runs) = server.get(&format!("/v1/batches/{batch}/runs")).await;
    assert_eq!(keys(&runs[0]), properties(&doc, "RunView"));
    assert_eq!(
        keys(&runs[0]["factors"][0]),
        properties(&doc, "FactorValue")
    );

    let (status, error) = server.get("/v1/batches/nope").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert_eq!(keys(&error), BTreeSet::from(["error".to_owned()]));
    assert!(properties(&doc, "ApiError").contains("field"));
    // Methods in the table are the two the document uses.
    assert!(ENDPOINTS
        .iter()
        .all(|e| matches!(e.verb, Verb::Get | Verb::Post)));
    server.stop().await;
}
