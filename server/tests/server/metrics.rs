//! `GET /metrics`: well-formed Prometheus text whose values follow what the server did.

use crate::common;

use std::collections::{BTreeMap, HashSet};

use common::{batch_request, temp_db, TestServer};
use reqwest::StatusCode;
use serde_json::json;

/// One sample line: metric name, labels, value.
type Sample = (String, BTreeMap<String, String>, f64);

/// Parses the text exposition format line by line, checking that every sample belongs to a
/// family announced by `# HELP` and `# TYPE` lines before it and that no series repeats.
fn parse_exposition(text: &str) -> Vec<Sample> {
    let mut helped = HashSet::new();
    let mut typed: BTreeMap<String, String> = BTreeMap::new();
    let mut seen = HashSet::new();
    let mut samples = Vec::new();
    let valid_name = |name: &str| {
        !name.is_empty()
            && !name.starts_with(|c: char| c.is_ascii_digit())
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':')
    };
    for line in text.lines() {
        assert!(!line.is_empty(), "blank line in exposition");
        if let Some(rest) = line.strip_prefix("# HELP ") {
            let (name, help) = rest.split_once(' ').expect("HELP has a text");
            assert!(valid_name(name) && !help.is_empty(), "{line}");
            assert!(helped.insert(name.to_owned()), "second HELP for {name}");
            continue;
        }
        if let Some(rest) = line.strip_prefix("# TYPE ") {
            let (name, kind) = rest.split_once(' ').expect("TYPE has a kind");
            assert!(helped.contains(name), "TYPE before HELP: {line}");
            assert!(
                ["counter", "gauge", "histogram", "summary", "untyped"].contains(&kind),
                "{line}"
            );
            assert!(
                typed.insert(name.to_owned(), kind.to_owned()).is_none(),
                "{line}"
            );
            continue;
        }
        assert!(!line.starts_with('#'), "unknown comment {line}");
        let (series, value) = line.rsplit_once(' ').expect("sample has a value");
        let value: f64 = match value {
            "+Inf" => f64::INFINITY,
            "-Inf" => f64::NEG_INFINITY,
            other => other
                .parse()
                .unwrap_or_else(|_| panic!("bad value in {line}")),
        };
        let (name, labels) = match series.split_once('{') {
            None => (series, BTreeMap::new()),
            Some((name, rest)) => {
                let inner = rest.strip_suffix('}').expect("labels end with }");
                let labels = inner
                    .split(',')
                    .map(|pair| {
                        let (key, quoted) = pair.split_once('=').expect("label is k=\"v\"");
                        assert!(valid_name(key), "{line}");
                        let value = quoted
                            .strip_prefix('"')
                            .and_then(|v| v.strip_suffix('"'))
                            .expect("label value quoted");
                        (key.to_owned(), value.to_owned())
                    })
                    .collect();
                (name, labels)
            }
        };
        assert!(valid_name(name), "{line}");
        let family = match typed.get(name) {
            Some(_) => name,
            None => ["_bucket", "_sum", "_count"]
                .iter()
                .find_map(|suffix| name.strip_suffix(suffix))
                .filter(|base| typed.get(*base).map(String::as_str) == Some("histogram"))
                .unwrap_or_else(|| panic!("sample of undeclared family: {line}")),
        };
        assert!(typed.contains_key(family));
        assert!(seen.insert(series.to_owned()), "repeated series {series}");
        samples.push((name.to_owned(), labels, value));
    }
    samples
}

fn value(samples: &[Sample], name: &str, label: Option<(&str, &str)>) -> f64 {
    samples
        .iter()
        .find(|(n, labels, _)| {
            n == name && label.is_none_or(|(k, v)| labels.get(k).map(String::as_str) == Some(v))
        })
        .unwrap_or_else(|| panic!("no sample {name} {label:?}"))
        .2
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_parse_and_count_what_happened() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 1))
        .await;
    let worker = server.register().await;
    for _ in 0..3 {
        let job = server.claim(worker, 0.0).await.unwrap();
        let (status, _) = server.complete(&job).await;
        assert_eq!(status, StatusCode::OK);
    }
    let last = server.claim(worker, 0.0).await.unwrap();
    let (status, _) = server
        .post(
            &format!("/v1/jobs/{}/fail", last.job_id),
            &json!({"lease_token": last.lease_token, "error": "boom"}),
        )
        .await;
    assert_eq!(status, StatusCode::OK);
    let (status, _) = server.get("/v1/no-such-thing").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let (status, _) = server.get_as("/metrics", None).await;
    assert_eq!(status, StatusCode::UNAUTHORIZED, "metrics need a token");

    let response = server
        .client
        .get(server.url("/metrics"))
        .bearer_auth(&server.user_token)
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), StatusCode::OK);
    let content_type = response.headers()["content-type"]
        .to_str()
        .unwrap()
        .to_owned();
    assert!(
        content_type.starts_with("text/plain; version=0.0.4"),
        "{content_type}"
    );
    let text = response.text().await.unwrap();
    let samples = parse_exposition(&text);

    assert_eq!(
        value(&samples, "repose_jobs", Some(("state", "completed"))),
        3.0
    );
    assert_eq!(
        value(&samples, "repose_jobs", Some(("state", "queued"))),
        1.0
    );
    assert_eq!(
        value(&samples, "repose_jobs", Some(("state", "leased"))),
        0.0
    );
    assert_eq!(
        value(&samples, "repose_batches", Some(("state", "active"))),
        1.0
    );
    assert_eq!(
        value(&samples, "repose_batches", Some(("state", "completed"))),
        0.0
    );
    assert_eq!(value(&samples, "repose_workers_active", None), 1.0);
    let last_seen = value(&samples, "repose_worker_last_seen_timestamp_seconds", None);
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    assert!(
        last_seen <= now && now - last_seen < 60.0,
        "last seen {last_seen}, now {now}"
    );
    let bytes = value(&samples, "repose_database_bytes", None);
    assert!(bytes >= 4096.0 && bytes % 512.0 == 0.0, "{bytes}");
    assert_eq!(value(&samples, "repose_db_writes_failing", None), 0.0);
    assert_eq!(value(&samples, "repose_db_write_failures_total", None), 0.0);
    assert_eq!(value(&samples, "repose_claims_total", None), 4.0);
    assert_eq!(value(&samples, "repose_completions_total", None), 3.0);
    assert_eq!(value(&samples, "repose_failures_total", None), 1.0);
    assert_eq!(
        value(&samples, "repose_claim_duration_seconds_count", None),
        4.0
    );
    assert!(value(&samples, "repose_claim_duration_seconds_sum", None) > 0.0);
    let buckets: Vec<(f64, f64)> = samples
        .iter()
        .filter(|(n, _, _)| n == "repose_claim_duration_seconds_bucket")
        .map(|(_, labels, v)| {
            let le = &labels["le"];
            let bound = if le == "+Inf" {
                f64::INFINITY
            } else {
                le.parse().unwrap()
            };
            (bound, *v)
        })
        .collect();
    assert!(buckets
        .windows(2)
        .all(|w| w[0].0 < w[1].0 && w[0].1 <= w[1].1));
    assert_eq!(buckets.last().unwrap(), &(f64::INFINITY, 4.0));
    // Registration, submission, claims, completions, the failure report: all 2xx.
    assert!(
        value(
            &samples,
            "repose_http_responses_total",
            Some(("class", "2xx"))
        ) >= 10.0
    );
    assert_eq!(
        value(
            &samples,
            "repose_http_responses_total",
            Some(("class", "4xx"))
        ),
        2.0
    );
    assert_eq!(
        value(
            &samples,
            "repose_http_responses_total",
            Some(("class", "5xx"))
        ),
        0.0
    );
    server.stop().await;
}

async fn scrape(server: &TestServer) -> Vec<Sample> {
    let response = server
        .client
        .get(server.url("/metrics"))
        .bearer_auth(&server.user_token)
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), StatusCode::OK);
    parse_exposition(&response.text().await.unwrap())
}

/// The alert rules of `deploy/prometheus/` rely on these: write failures while the disk is
/// full, and a last-seen time of 0 before any worker registered.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_show_failing_writes_and_when_a_worker_was_last_seen() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let samples = scrape(&server).await;
    assert_eq!(
        value(&samples, "repose_worker_last_seen_timestamp_seconds", None),
        0.0
    );
    server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 30))
        .await;
    server.stop().await;

    // One page of room: registration fits, then the "disk" is full.
    let pages = std::fs::metadata(&db).unwrap().len() / 4096;
    let server = TestServer::start(&db, |c| c.max_db_pages = Some(pages + 1)).await;
    let worker = server.register().await;
    let mut refused = 0;
    for _ in 0..60 {
        let (status, _) = server
            .post(
                "/v1/jobs/claim",
                &json!({"worker_id": worker, "wait_s": 0.0}),
            )
            .await;
        match status {
            StatusCode::OK => {}
            StatusCode::SERVICE_UNAVAILABLE => refused += 1,
            other => panic!("claim answered {other}"),
        }
        if refused >= 2 {
            break;
        }
    }
    assert!(refused >= 2, "the database never filled up");
    let samples = scrape(&server).await;
    assert_eq!(value(&samples, "repose_db_writes_failing", None), 1.0);
    assert!(value(&samples, "repose_db_write_failures_total", None) >= 2.0);
    assert!(value(&samples, "repose_worker_last_seen_timestamp_seconds", None) > 0.0);
    assert!(
        value(
            &samples,
            "repose_http_responses_total",
            Some(("class", "5xx"))
        ) >= 2.0
    );
    server.stop().await;
}

/// Every `repose_*` series that `deploy/prometheus/repose-alerts.yml` uses (name and `k="v"`
/// label matchers) is exported by a live server, so an alert cannot watch a metric that does
/// not exist.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_alert_rules_use_only_exported_metrics() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/prometheus/repose-alerts.yml");
    let rules = std::fs::read_to_string(&path).unwrap();
    let mut used: Vec<(String, Vec<(String, String)>)> = Vec::new();
    let mut rest = rules.as_str();
    while let Some(at) = rest.find("repose_") {
        let tail = &rest[at..];
        let end = tail
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(tail.len());
        let name = tail[..end].to_owned();
        let mut matchers = Vec::new();
        if let Some(inner) = tail[end..].strip_prefix('{') {
            let inner = &inner[..inner.find('}').expect("matchers end with }")];
            for matcher in inner.split(',') {
                if let Some((key, value)) = matcher.split_once('=') {
                    if let Some(value) = value.trim().strip_prefix('"') {
                        if !key.ends_with('!') && !value.starts_with('~') {
                            let value = value.trim_end_matches('"');
                            matchers.push((key.trim().to_owned(), value.to_owned()));
                        }
                    }
                }
            }
        }
        used.push((name, matchers));
        rest = &tail[end..];
    }
    assert!(used.len() >= 6, "{used:?}");

    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    server.register().await;
    let samples = scrape(&server).await;
    for (name, matchers) in &used {
        let found = samples.iter().any(|(n, labels, _)| {
            n == name
                && matchers
                    .iter()
                    .all(|(k, v)| labels.get(k).map(String::as_str) == Some(v.as_str()))
        });
        // The job and instance labels are Prometheus's own, added at scrape time.
        let prometheus_labels = matchers.iter().all(|(k, _)| k == "job" || k == "instance");
        assert!(
            found || (prometheus_labels && samples.iter().any(|(n, _, _)| n == name)),
            "{} uses {name}{matchers:?}, which /metrics does not export",
            path.display()
        );
    }
    server.stop().await;
}
