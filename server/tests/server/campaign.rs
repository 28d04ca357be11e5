//! A campaign through the real server: the paper replayed with the `table_lookup` kind (a test
//! aid; responses come from the paper's Tables 3, 5 and 6, verification runs from its Eq. 16),
//! run by an in-test worker over HTTP, with a server restart in the middle.

use crate::common;

use crate::paper;

use common::{temp_db, TestServer};
use paper::{eq16, paper_campaign_json};
use repose_api::{ClaimResponse, Completion};
use repose_experiments::aor::Control;
use repose_experiments::catalog::{run_experiment, ExperimentError};
use reqwest::StatusCode;
use serde_json::{json, Value};
use uuid::Uuid;

fn paper_campaign() -> Value {
    paper_campaign_json("paper replay via the server")
}

/// The test worker's answer: the replay table, or for a point the paper never ran (the
/// verification point) the paper's fitted Eq. 16 with a seed-dependent deviation of ±0.5°.
fn answer(job: &ClaimResponse) -> Completion {
    let metrics = match run_experiment(&job.kind, &job.spec, job.seed, &mut |_| Control::Continue) {
        Ok(outcome) => outcome.metrics,
        Err(ExperimentError::NoResult { .. }) => {
            let values = &job.spec["values"];
            let point: Vec<f64> = ["N2", "N3", "N5"]
                .iter()
                .map(|n| values[*n].as_f64().unwrap())
                .collect();
            let deviation = [-0.5, 0.1, 0.4][(job.seed % 3) as usize];
            [("angle_deg".to_owned(), eq16(&point) + deviation)].into()
        }
        Err(other) => panic!("replay failed: {other}"),
    };
    Completion {
        lease_token: job.lease_token,
        metrics,
        wall_time_s: 0.0,
        details: json!({"worker": "test replay"}),
        engine_version: Some("replay-engine-0".into()),
        // Sent only when asked, as the real worker does; the server keeps them only for
        // batches that keep pictures anyway.
        pictures: if job.keep_pictures {
            [(
                "pile.svg".to_owned(),
                format!(
                    "<svg id=\"verification-pile\"><!-- seed {} --></svg>",
                    job.seed
                ),
            )]
            .into()
        } else {
            Default::default()
        },
    }
}

/// Claims and answers jobs until none arrives within `idle_s` or `max_jobs` are done; returns
/// how many it did.
async fn work(server: &TestServer, idle_s: f64, max_jobs: usize) -> usize {
    let worker = server.register().await;
    let mut done = 0;
    while done < max_jobs {
        let Some(job) = server.claim(worker, idle_s).await else {
            break;
        };
        let completion = answer(&job);
        let (status, body) = server.complete_with(&job, &completion).await;
        assert_eq!(status, StatusCode::OK, "{body}");
        done += 1;
    }
    done
}

async fn campaign(server: &TestServer, id: Uuid) -> Value {
    let (status, body) = server.get(&format!("/v1/campaigns/{id}")).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_paper_replayed_as_a_campaign_through_the_server_survives_a_restart() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let (status, created) = server.post("/v1/campaigns", &paper_campaign()).await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    let id: Uuid = serde_json::from_value(created["id"].clone()).unwrap();

    // Screening only, then a restart: the campaign must continue from the database.
    assert_eq!(
        work(&server, 5.0, 12).await,
        12,
        "the screening batch has 12 runs"
    );
    server.stop().await;
    let server = TestServer::start(&db, |_| {}).await;

    for _ in 0..20 {
        work(&server, 1.0, usize::MAX).await;
        let view = campaign(&server, id).await;
        if view["status"] != "running" {
            break;
        }
    }
    let view = campaign(&server, id).await;
    assert_eq!(view["status"], "finished", "{view:#}");
    let decisions: Vec<&str> = view["decisions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["text"].as_str().unwrap())
        .collect();
    let all = decisions.join("\n");
    for factor in ["N2", "N3", "N5"] {
        assert!(all.contains(factor), "{all}");
    }
    let stages: Vec<&str> = view["batch_list"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["stage"].as_str().unwrap())
        .collect();
    assert_eq!(
        stages.first().copied(),
        Some("screening"),
        "batches: {stages:?}"
    );
    assert!(stages.contains(&"steepest"), "{stages:?}");
    assert!(stages.contains(&"verification"), "{stages:?}");
    let result = &view["result"];
    assert_eq!(result["within_tolerance"], true, "{result:#}");

    // The report: self-contained HTML with the ANOVA, and its JSON form.
    let (status, html) = server.get_text(&format!("/v1/campaigns/{id}/report")).await;
    assert_eq!(status, StatusCode::OK);
    assert!(
        html.contains("<html") && html.contains("Lack of Fit") && html.contains("Provenance"),
        "{}",
        &html[..html.len().min(400)]
    );
    let (status, json_report) = server
        .get(&format!("/v1/campaigns/{id}/report?format=json"))
        .await;
    assert_eq!(status, StatusCode::OK, "{json_report}");
    assert!(json_report.is_object());

    // The verification batch kept its pictures, and the report shows one.
    assert!(
        html.contains("<img alt=\"Verification pile\"") && !html.contains("No picture supplied"),
        "verification pile in the report"
    );
    // Provenance: every run names the engine that computed it, and the spec hash is the
    // server's hash of the run's own spec (distinct runs of the screening have distinct ones).
    let provenance = json_report["provenance"].as_array().expect("provenance");
    assert!(!provenance.is_empty());
    for p in provenance {
        if p["status"] == "completed" {
            assert_eq!(p["engine_version"], "replay-engine-0", "{p}");
        }
    }
    let screening: std::collections::BTreeSet<&str> = provenance
        .iter()
        .filter(|p| p["batch"] == 0)
        .map(|p| p["spec_sha256"].as_str().unwrap())
        .collect();
    assert_eq!(screening.len(), 12, "one hash per PB run: {screening:?}");

    let (status, list) = server.get("/v1/campaigns").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(list.as_array().unwrap().len(), 1);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_campaign_is_a_422_naming_the_field_and_unknown_ids_are_404() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let mut bad = paper_campaign();
    bad["factors"][1]["low"] = json!(0.9);
    let (status, body) = server.post("/v1/campaigns", &bad).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert!(
        body["field"]
            .as_str()
            .unwrap_or_default()
            .starts_with("factors[1]"),
        "{body}"
    );
    let (status, _) = server
        .get(&format!("/v1/campaigns/{}", Uuid::new_v4()))
        .await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let (status, _) = server.get("/v1/campaigns/not-a-uuid").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    server.stop().await;
}

/// A two-target campaign (issue 15) on two `table_lookup` experiments whose tables hold only a
/// placeholder row: the test worker answers every run from the formulas
/// `angle_deg = 30 + 8·A + 4·B` and `cohesion_kpa = 1 + 3·B` (plus a fixed deviation per point
/// and seed), so both targets (34 and 2.5) hold together only at A = 0.25, B = 0.5.
fn two_target_answer(job: &ClaimResponse) -> Completion {
    let v = &job.spec["values"];
    let (a, b, c) = (
        v["A"].as_f64().unwrap(),
        v["B"].as_f64().unwrap(),
        v["C"].as_f64().unwrap(),
    );
    let dev = (((a * 1000.0).round() * 1.7
        + (b * 1000.0).round() * 2.7
        + (c * 1000.0).round() * 3.7
        + (job.seed % 3) as f64 * 3.1)
        * 12.9898)
        .sin();
    Completion {
        lease_token: job.lease_token,
        metrics: [
            (
                "angle_deg".to_owned(),
                30.0 + 8.0 * a + 4.0 * b + 0.05 * dev,
            ),
            ("cohesion_kpa".to_owned(), 1.0 + 3.0 * b + 0.01 * dev),
        ]
        .into(),
        wall_time_s: 0.0,
        details: json!({"worker": "test formulas"}),
        engine_version: Some("replay-engine-0".into()),
        pictures: Default::default(),
    }
}

async fn work_with(
    server: &TestServer,
    idle_s: f64,
    max_jobs: usize,
    answer: fn(&ClaimResponse) -> Completion,
) -> usize {
    let worker = server.register().await;
    let mut done = 0;
    while done < max_jobs {
        let Some(job) = server.claim(worker, idle_s).await else {
            break;
        };
        let (status, body) = server
            .post(
                &format!("/v1/jobs/{}/complete", job.job_id),
                &serde_json::to_value(answer(&job)).unwrap(),
            )
            .await;
        assert_eq!(status, StatusCode::OK, "{body}");
        done += 1;
    }
    done
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_two_target_campaign_runs_one_batch_per_experiment_and_survives_a_restart_between_them() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let lookup = |metric: &str| {
        json!({"kind": "table_lookup", "spec": {
            "values": {"A": 0.0, "B": 0.0, "C": 0.0},
            "rows": [{"A": -99.0, "B": -99.0, "C": -99.0, metric: 0.0}]
        }})
    };
    let request = json!({
        "name": "two targets via the server",
        "experiments": {"aor": lookup("angle_deg"), "shear": lookup("cohesion_kpa")},
        "targets": [
            {"response": "aor.angle_deg", "target": 34.0, "tolerance": {"relative_pct": 2}},
            {"response": "shear.cohesion_kpa", "target": 2.5, "tolerance": {"relative_pct": 4}}
        ],
        "factors": [
            {"name": "A", "path": "values.A", "low": 0.0, "high": 1.0},
            {"name": "B", "path": "values.B", "low": 0.0, "high": 1.0},
            {"name": "C", "path": "values.C", "low": 0.0, "high": 1.0}
        ],
        "seed": 15,
        "screening": {"design": {"type": "plackett_burman", "runs": 8}},
    });
    let (status, created) = server.post("/v1/campaigns", &request).await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    let id: Uuid = serde_json::from_value(created["id"].clone()).unwrap();

    // The first experiment's screening batch only, then a restart: the finished batch waits in
    // the stored campaign while the second experiment's batch runs.
    assert_eq!(work_with(&server, 5.0, 8, two_target_answer).await, 8);
    server.stop().await;
    let server = TestServer::start(&db, |_| {}).await;
    for _ in 0..30 {
        work_with(&server, 1.0, usize::MAX, two_target_answer).await;
        if campaign(&server, id).await["status"] != "running" {
            break;
        }
    }
    let view = campaign(&server, id).await;
    assert_eq!(view["status"], "finished", "{view:#}");
    let batches = view["batch_list"].as_array().unwrap();
    assert_eq!(batches[0]["stage"], "screening");
    assert_eq!(batches[1]["stage"], "screening");
    let result = &view["result"];
    assert_eq!(result["within_tolerance"], true, "{result:#}");
    let value = |name: &str| {
        result["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == name)
            .unwrap()["value"]
            .as_f64()
            .unwrap()
    };
    assert!((value("A") - 0.25).abs() < 0.02, "{result:#}");
    assert!((value("B") - 0.5).abs() < 0.02, "{result:#}");
    assert_eq!(result["targets"].as_array().unwrap().len(), 2, "{result:#}");
    let (status, html) = server.get_text(&format!("/v1/campaigns/{id}/report")).await;
    assert_eq!(status, StatusCode::OK);
    assert!(html.contains("shear.cohesion_kpa (target 2.5)"));

    // An experiment of a kind the catalog does not have is refused at creation, naming it.
    let mut unknown = request.clone();
    unknown["experiments"]["shear"]["kind"] = json!("no_such_kind");
    let (status, body) = server.post("/v1/campaigns", &unknown).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert!(body.to_string().contains("`shear`"), "{body}");
    server.stop().await;
}

/// The Bayesian strategy's test worker: runs each job with the real `formula` kind and sends
/// its metrics, or its failure (permanent, as the real worker does for a `fails_when` region).
async fn formula_work(server: &TestServer, idle_s: f64, max_jobs: usize) -> usize {
    let worker = server.register().await;
    let mut done = 0;
    while done < max_jobs {
        let Some(job) = server.claim(worker, idle_s).await else {
            break;
        };
        let (path, body) =
            match run_experiment(&job.kind, &job.spec, job.seed, &mut |_| Control::Continue) {
                Ok(outcome) => (
                    "complete",
                    serde_json::to_value(Completion {
                        lease_token: job.lease_token,
                        metrics: outcome.metrics,
                        wall_time_s: 0.0,
                        details: json!({"worker": "test formula worker"}),
                        engine_version: Some("formula-0".into()),
                        pictures: Default::default(),
                    })
                    .unwrap(),
                ),
                Err(err) => {
                    assert!(err.is_permanent(), "{err}");
                    (
                        "fail",
                        json!({"lease_token": job.lease_token, "error": err.to_string(),
                               "permanent": true}),
                    )
                }
            };
        let (status, reply) = server
            .post(&format!("/v1/jobs/{}/{path}", job.job_id), &body)
            .await;
        assert_eq!(status, StatusCode::OK, "{reply}");
        done += 1;
    }
    done
}

/// Two `formula` experiments, coupled targets (angle 31 ± 3 %, cohesion 2.2 ± 5 %, met together
/// along a curve with A ≤ 0.6), heaps that fail for A > 0.6, seeded noise.
fn bayes_request() -> Value {
    let formula = |metric: &str, expression: &str, sd: f64| {
        let mut spec = json!({
            "inputs": {"A": 0.0, "B": 0.0, "C": 0.0},
            "responses": {metric: expression},
            "noise_sd": {metric: sd},
        });
        if metric == "angle_deg" {
            spec["fails_when"] = json!("A > 0.6");
        }
        json!({"kind": "formula", "spec": spec})
    };
    json!({
        "name": "bayesian via the server",
        "strategy": {"type": "bayesian", "max_runs": 80, "batch_size": 4},
        "experiments": {
            "aor": formula("angle_deg", "25 + 12*A + 6*B + 2*A*C", 0.3),
            "shear": formula("cohesion_kpa", "1 + 2*C + 0.8*B^2", 0.03),
        },
        "targets": [
            {"response": "aor.angle_deg", "target": 31.0, "tolerance": {"relative_pct": 3}},
            {"response": "shear.cohesion_kpa", "target": 2.2, "tolerance": {"relative_pct": 5}}
        ],
        "factors": [
            {"name": "A", "path": "inputs.A", "low": 0.0, "high": 1.0},
            {"name": "B", "path": "inputs.B", "low": 0.0, "high": 1.0},
            {"name": "C", "path": "inputs.C", "low": 0.0, "high": 1.0}
        ],
        "seed": 21,
    })
}

/// Runs a Bayesian campaign to its end; with `restart_after`, the server is stopped after that
/// many jobs (mid-round) and a new one on the same database carries on.
async fn bayes_campaign(restart_after: Option<usize>) -> Value {
    let (_dir, db) = temp_db();
    let mut server = TestServer::start(&db, |_| {}).await;
    let (status, created) = server.post("/v1/campaigns", &bayes_request()).await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    let id: Uuid = serde_json::from_value(created["id"].clone()).unwrap();
    // Both experiments' start batches are queued at once.
    let view = campaign(&server, id).await;
    let batches = view["batch_list"].as_array().unwrap();
    assert_eq!(batches.len(), 2, "{view:#}");
    assert!(batches.iter().all(|b| b["stage"] == "design"), "{view:#}");
    if let Some(jobs) = restart_after {
        assert_eq!(formula_work(&server, 5.0, jobs).await, jobs);
        server.stop().await;
        server = TestServer::start(&db, |_| {}).await;
    }
    for _ in 0..40 {
        formula_work(&server, 1.0, usize::MAX).await;
        if campaign(&server, id).await["status"] != "running" {
            break;
        }
    }
    let view = campaign(&server, id).await;
    let (status, html) = server.get_text(&format!("/v1/campaigns/{id}/report")).await;
    assert_eq!(status, StatusCode::OK);
    assert!(html.contains("<html"));
    server.stop().await;
    view
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bayesian_campaign_killed_mid_round_ends_as_an_uninterrupted_one() {
    let whole = bayes_campaign(None).await;
    assert_eq!(whole["status"], "finished", "{whole:#}");
    let result = &whole["result"];
    assert_eq!(result["within_tolerance"], true, "{result:#}");
    assert!(result["simulations"].as_u64().unwrap() <= 80, "{result:#}");
    assert!(
        result["bayesian"]["region"]["points"].is_array(),
        "{result:#}"
    );
    // Every round ran both experiments' batches.
    let stages: Vec<&str> = whole["batch_list"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["stage"].as_str().unwrap())
        .collect();
    assert!(stages.contains(&"verification"), "{stages:?}");
    assert_eq!(stages.len() % 2, 0, "{stages:?}");

    // Killed with 11 of the start design's 16 runs done: one batch finished, one not.
    let resumed = bayes_campaign(Some(11)).await;
    assert_eq!(resumed["status"], "finished", "{resumed:#}");
    assert_eq!(resumed["result"], whole["result"]);
    assert_eq!(resumed["decisions"], whole["decisions"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bayesian_settings_and_chain_settings_under_it_are_422_naming_the_field() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    for (change, field) in [
        (json!({"screening": {"replicates": 2}}), "screening"),
        (
            json!({"strategy": {"type": "bayesian", "batch_size": 0}}),
            "strategy.batch_size",
        ),
        (
            json!({"strategy": {"type": "bayesian", "max_runs": 5}}),
            "strategy.max_runs",
        ),
    ] {
        let mut request = bayes_request();
        for (k, v) in change.as_object().unwrap() {
            request[k] = v.clone();
        }
        let (status, body) = server.post("/v1/campaigns", &request).await;
        assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
        assert_eq!(body["field"], field, "{body}");
    }
    server.stop().await;
}
