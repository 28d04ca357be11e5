//! Property test: generated malformed and extreme requests against the real router over HTTP.
//! Whatever arrives, the answer is never a 5xx, the server never drops a connection without a
//! reply (a panic), and it keeps answering.

use crate::common;

use std::sync::OnceLock;

use common::{batch_request, temp_db, TestServer};
use proptest::prelude::*;
use repose_server::{Verb, ENDPOINTS};
use serde_json::{json, Value};

/// One server (and runtime) for every generated case.
struct Shared {
    runtime: tokio::runtime::Runtime,
    server: TestServer,
    /// Ids that exist, so generated paths also reach real batches and jobs.
    batch: String,
    /// A registered worker id.
    worker: uuid::Uuid,
    /// No connection reuse: a connection the server closes after an error reply must not be
    /// picked up for the next case (a client-side race, not the server's fault).
    client: reqwest::Client,
    _dir: tempfile::TempDir,
}

fn shared() -> &'static Shared {
    static SHARED: OnceLock<Shared> = OnceLock::new();
    SHARED.get_or_init(|| {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        let (dir, db) = temp_db();
        let (server, batch, worker) = runtime.block_on(async {
            let server = TestServer::start(&db, |config| {
                config.max_claim_wait = std::time::Duration::from_millis(50);
            })
            .await;
            let batch = server
                .submit(&batch_request(json!({"type": "factorial"}), "linear", 2))
                .await;
            let worker = server.register().await;
            (server, batch.id.to_string(), worker)
        });
        Shared {
            runtime,
            server,
            batch,
            worker,
            client: reqwest::Client::builder()
                .pool_max_idle_per_host(0)
                .build()
                .unwrap(),
            _dir: dir,
        }
    })
}

/// Numbers at the edges of what JSON and f64 can say.
fn extreme_number() -> impl Strategy<Value = Value> {
    prop_oneof![
        Just(json!(0)),
        Just(json!(-1)),
        Just(json!(1e300)),
        Just(json!(-1e300)),
        Just(json!(f64::MAX)),
        Just(json!(f64::MIN_POSITIVE)),
        Just(json!(u64::MAX)),
        Just(json!(i64::MIN)),
        Just(json!(1e12 as u64)),
        any::<f64>()
            .prop_filter("finite", |x| x.is_finite())
            .prop_map(|x| json!(x)),
        any::<i64>().prop_map(|x| json!(x)),
    ]
}

/// Arbitrary JSON, nested a few levels, with extreme numbers and odd strings.
fn any_json() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        extreme_number(),
        ".{0,40}".prop_map(Value::String),
        (1usize..20_000).prop_map(|n| Value::String("x".repeat(n))),
        Just(json!(uuid::Uuid::nil().to_string())),
    ];
    leaf.prop_recursive(4, 64, 8, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..8).prop_map(Value::Array),
            prop::collection::btree_map(
                prop_oneof![
                    Just("name".to_owned()),
                    Just("worker_id".to_owned()),
                    Just("wait_s".to_owned()),
                    Just("lease_token".to_owned()),
                    Just("design".to_owned()),
                    Just("factors".to_owned()),
                    Just("centre_points".to_owned()),
                    Just("replicates".to_owned()),
                    "[a-z_]{1,12}",
                ],
                inner,
                0..6
            )
            .prop_map(|map| Value::Object(map.into_iter().collect())),
        ]
    })
}

/// A valid batch request with one field replaced by something generated.
fn mutated_batch() -> impl Strategy<Value = Value> {
    let fields = prop_oneof![
        Just(vec!["name"]),
        Just(vec!["replicates"]),
        Just(vec!["design"]),
        Just(vec!["design", "centre_points"]),
        Just(vec!["design", "runs"]),
        Just(vec!["factors"]),
        Just(vec!["factors", "0", "low"]),
        Just(vec!["factors", "0", "high"]),
        Just(vec!["factors", "1", "path"]),
        Just(vec!["experiment", "spec"]),
        Just(vec!["experiment", "kind"]),
        Just(vec!["target"]),
        Just(vec!["model"]),
        Just(vec!["seed"]),
    ];
    let designs = prop_oneof![
        Just(json!({"type": "factorial"})),
        Just(json!({"type": "box_behnken"})),
        Just(
            json!({"type": "central_composite", "variant": "circumscribed",
                    "centre_points": 2})
        ),
        Just(json!({"type": "plackett_burman"})),
    ];
    (fields, designs, any_json()).prop_map(|(path, design, value)| {
        let mut request = batch_request(design, "linear", 1);
        let mut slot = &mut request;
        for key in &path[..path.len() - 1] {
            slot = match key.parse::<usize>() {
                Ok(i) => &mut slot[i],
                Err(_) => &mut slot[*key],
            };
        }
        let last = path[path.len() - 1];
        match last.parse::<usize>() {
            Ok(i) => slot[i] = value,
            Err(_) => slot[last] = value,
        }
        request
    })
}

#[derive(Debug, Clone)]
struct Generated {
    verb: Verb,
    path: String,
    body: Option<String>,
    token: u8,
}

/// The worker protocol with generated numbers where durations and progress go (`wait_s`,
/// `progress`), sent with the worker token: the fields that once reached `from_secs_f64`.
fn worker_request() -> impl Strategy<Value = Generated> {
    (extreme_number(), 0usize..2).prop_map(|(number, which)| {
        let worker = shared().worker;
        match which {
            0 => Generated {
                verb: Verb::Post,
                path: "/v1/jobs/claim".to_owned(),
                body: Some(json!({"worker_id": worker, "wait_s": number}).to_string()),
                token: 1,
            },
            _ => Generated {
                verb: Verb::Post,
                path: format!("/v1/jobs/{}/heartbeat", uuid::Uuid::new_v4()),
                body: Some(
                    json!({"lease_token": uuid::Uuid::new_v4(), "progress": number}).to_string(),
                ),
                token: 1,
            },
        }
    })
}

fn request() -> impl Strategy<Value = Generated> {
    prop_oneof![3 => any_request(), 1 => worker_request()]
}

fn any_request() -> impl Strategy<Value = Generated> {
    let endpoint = 0..ENDPOINTS.len();
    let id = prop_oneof![
        Just(None),
        Just(Some(uuid::Uuid::new_v4().to_string())),
        "[^/?#]{0,60}".prop_map(Some),
        Just(Some("%00%ff".to_owned())),
    ];
    let body = prop_oneof![
        any_json().prop_map(|v| Some(v.to_string())),
        mutated_batch().prop_map(|v| Some(v.to_string())),
        ".{0,200}".prop_map(Some),
        Just(Some("{\"wait_s\": 1e999}".to_owned())),
        extreme_number().prop_map(|wait| Some(
            json!({"worker_id": uuid::Uuid::nil(), "wait_s": wait}).to_string()
        )),
        Just(None),
    ];
    let query = prop_oneof![
        Just(String::new()),
        Just("?format=csv".to_owned()),
        Just("?format=text".to_owned()),
        Just("?limit=99999999999999999999".to_owned()),
        Just("?state=running&batch=x".to_owned()),
        "[?][a-z]{1,8}=[^#]{0,20}",
    ];
    (endpoint, any::<bool>(), id, body, query, 0u8..3).prop_map(
        |(index, flip_verb, id, body, query, token)| {
            let endpoint = &ENDPOINTS[index];
            let verb = match (endpoint.verb, flip_verb) {
                (v, false) => v,
                (Verb::Get, true) => Verb::Post,
                (Verb::Post, true) => Verb::Get,
            };
            let shared_batch = &shared().batch;
            let segment = id.unwrap_or_else(|| shared_batch.clone());
            let encoded: String = segment
                .bytes()
                .map(|b| match b {
                    b'a'..=b'z' | b'A'..=b'Z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'%' => {
                        (b as char).to_string()
                    }
                    _ => format!("%{b:02X}"),
                })
                .collect();
            Generated {
                verb,
                path: format!("{}{query}", endpoint.path.replace("{id}", &encoded)),
                body,
                token,
            }
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn no_generated_request_gets_a_5xx(generated in request()) {
        let shared = shared();
        let server = &shared.server;
        let status = shared.runtime.block_on(async {
            let url = server.url(&generated.path);
            let mut request = match generated.verb {
                Verb::Get => shared.client.get(url),
                Verb::Post => shared.client.post(url),
            };
            request = match generated.token {
                0 => request.bearer_auth(&server.user_token),
                1 => request.bearer_auth(&server.worker_token),
                _ => request,
            };
            if let Some(body) = &generated.body {
                request = request
                    .header("content-type", "application/json")
                    .body(body.clone());
            }
            request.send().await.map(|r| r.status())
        });
        let status = status.map_err(|err| {
            TestCaseError::fail(format!("no reply (a panic?) to {generated:?}: {err}"))
        })?;
        prop_assert!(
            !status.is_server_error(),
            "{status} for {generated:?}"
        );
        let health = shared
            .runtime
            .block_on(shared.client.get(server.url("/healthz")).send())
            .map(|r| r.status());
        prop_assert!(
            matches!(health, Ok(reqwest::StatusCode::OK)),
            "the server stopped answering after {generated:?}: {health:?}"
        );
    }
}
