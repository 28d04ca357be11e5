//! End-to-end tests of the job server over real HTTP.

use crate::common;

use std::time::Duration;

use common::{batch_request, run_fake_worker, temp_db, TestServer};
use repose_api::{BatchState, RunState};
use reqwest::StatusCode;
use serde_json::{json, Value};
use uuid::Uuid;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn batch_runs_through_two_concurrent_workers_and_is_analysed() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 3))
        .await;
    assert_eq!(batch.run_count, 12);

    let (first, second) =
        tokio::join!(run_fake_worker(&server, 1.0), run_fake_worker(&server, 1.0));
    assert_eq!(first + second, 12);

    let analysis = server.wait_for_analysis(batch.id).await;
    assert_eq!(analysis.error, None);
    assert_eq!(analysis.runs_used, 12);
    let fit = analysis.fit.expect("fit stored");
    let mu_effect = fit["coefficients"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["term"] == "mu")
        .unwrap()["estimate"]
        .as_f64()
        .unwrap();
    // 25 per unit of μ over a half range of 0.2 is 5 per coded unit.
    assert!((mu_effect - 5.0).abs() < 0.1, "mu effect {mu_effect}");
    let optimum = analysis.optimum.expect("optimum for the target");
    let predicted = optimum["solutions"][0]["responses"][0]["value"]
        .as_f64()
        .unwrap();
    assert!((predicted - 30.0).abs() < 0.05, "predicted {predicted}");
    assert!(analysis.steepest_path.is_some());

    let status = server.status(batch.id).await;
    assert_eq!(status.summary.state, BatchState::Completed);
    assert_eq!(status.summary.counts.completed, 12);
    assert_eq!(status.summary.percent_done, 100.0);
    assert!(status.analysis_ready);
    assert!(status.mean_wall_time_s.is_some());

    let runs = server.runs(batch.id).await;
    let mut seeds: Vec<u64> = runs.iter().map(|r| r.seed).collect();
    seeds.sort_unstable();
    seeds.dedup();
    assert_eq!(seeds.len(), 12, "every run and replicate has its own seed");
    assert!(runs.iter().all(|r| r.status == RunState::Completed));

    let (status, csv) = server
        .get_text(&format!("/v1/batches/{}/runs?format=csv", batch.id))
        .await;
    assert_eq!(status, StatusCode::OK);
    let mut lines = csv.lines();
    let header = lines.next().unwrap();
    assert!(
        header.starts_with(
            "run_index,replicate,mu,e,seed,status,attempts,angle_deg,worker_id,wall_time_s"
        ),
        "{header}"
    );
    assert_eq!(lines.count(), 12);

    let (status, text) = server
        .get_text(&format!("/v1/batches/{}/analysis?format=text", batch.id))
        .await;
    assert_eq!(status, StatusCode::OK);
    assert!(text.contains("ANOVA") && text.contains("mu"), "{text}");

    let (status, list) = server.get("/v1/batches").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(list.as_array().unwrap().len(), 1);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stale_and_duplicate_updates_get_409_and_change_nothing() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 2))
        .await;
    let worker = server.register().await;

    let job = server.claim(worker, 0.0).await.unwrap();
    let (status, body) = server.complete(&job).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let before = server.runs(batch.id).await;

    // The same completion again, and a forged one with different metrics.
    let (status, _) = server.complete(&job).await;
    assert_eq!(status, StatusCode::CONFLICT);
    let forged = json!({"lease_token": job.lease_token, "metrics": {"angle_deg": 99.0},
                        "wall_time_s": 1.0});
    let (status, body) = server
        .post(&format!("/v1/jobs/{}/complete", job.job_id), &forged)
        .await;
    assert_eq!(status, StatusCode::CONFLICT);
    assert!(
        body["error"].as_str().unwrap().contains("already"),
        "{body}"
    );
    let unknown_token = json!({"lease_token": Uuid::new_v4(), "metrics": {"angle_deg": 1.0},
                               "wall_time_s": 1.0});
    let (status, _) = server
        .post(&format!("/v1/jobs/{}/complete", job.job_id), &unknown_token)
        .await;
    assert_eq!(status, StatusCode::CONFLICT);
    for action in ["heartbeat", "fail", "release"] {
        let (status, _) = server
            .post(
                &format!("/v1/jobs/{}/{action}", job.job_id),
                &json!({"lease_token": job.lease_token, "error": "x", "progress": 0.5}),
            )
            .await;
        assert_eq!(
            status,
            StatusCode::CONFLICT,
            "{action} on a completed lease"
        );
    }

    // A released lease is stale too: its completion must not store anything.
    let second = server.claim(worker, 0.0).await.unwrap();
    let (status, body) = server
        .post(
            &format!("/v1/jobs/{}/release", second.job_id),
            &json!({"lease_token": second.lease_token}),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["status"], "queued");
    let (status, _) = server.complete(&second).await;
    assert_eq!(status, StatusCode::CONFLICT);

    let after = server.runs(batch.id).await;
    assert_eq!(before, after, "rejected updates changed nothing");
    assert_eq!(
        after
            .iter()
            .filter(|r| r.status == RunState::Completed)
            .count(),
        1
    );
    let released = after.iter().find(|r| r.id == second.run_id).unwrap();
    assert_eq!(released.status, RunState::Queued);
    assert_eq!(
        released.attempts, 0,
        "a release does not count as an attempt"
    );

    // Ids in paths: malformed → 400, unknown → 404.
    let (status, _) = server.post("/v1/jobs/not-a-uuid/complete", &forged).await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    let (status, _) = server
        .post(&format!("/v1/jobs/{}/complete", Uuid::new_v4()), &forged)
        .await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let (status, _) = server.get("/v1/batches/nope").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    let (status, _) = server.get(&format!("/v1/batches/{}", Uuid::new_v4())).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let (status, _) = server
        .get(&format!("/v1/batches/{}/analysis", Uuid::new_v4()))
        .await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn expired_lease_is_re_leased_and_ends_with_exactly_one_result() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.lease = Duration::from_millis(800);
    })
    .await;
    // Four explicit points: the smallest batch a two-factor linear model accepts.
    let batch = server
        .submit(&batch_request(
            json!({"type": "explicit", "points": [[0.2, 0.3], [0.6, 0.3], [0.4, 0.9], [0.3, 0.6]]}),
            "linear",
            1,
        ))
        .await;
    let slow = server.register().await;
    let fast = server.register().await;
    let mut slow_jobs = Vec::new();
    for _ in 0..4 {
        slow_jobs.push(server.claim(slow, 0.0).await.unwrap());
    }
    assert!(
        server.claim(fast, 0.0).await.is_none(),
        "all four are leased"
    );
    tokio::time::sleep(Duration::from_millis(1200)).await;

    // The leases expired: the fast worker gets every job again, as a second attempt.
    let mut fast_jobs = Vec::new();
    for _ in 0..4 {
        let job = server.claim(fast, 0.0).await.unwrap();
        assert_eq!(job.attempt, 2);
        fast_jobs.push(job);
    }
    let slow_of = |run: Uuid| slow_jobs.iter().find(|j| j.run_id == run).unwrap();

    // Job 1: the re-lease finishes first, so the late result is a conflict.
    let (status, _) = server.complete(&fast_jobs[0]).await;
    assert_eq!(status, StatusCode::OK);
    let (status, _) = server.complete(slow_of(fast_jobs[0].run_id)).await;
    assert_eq!(status, StatusCode::CONFLICT);

    // Job 2: the expired lease delivers first and is accepted (no result yet); the current
    // holder is told to stop and its completion is a conflict.
    let (status, body) = server.complete(slow_of(fast_jobs[1].run_id)).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = server
        .post(
            &format!("/v1/jobs/{}/heartbeat", fast_jobs[1].job_id),
            &json!({"lease_token": fast_jobs[1].lease_token, "progress": 0.9}),
        )
        .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body["cancel"], true);
    let (status, _) = server.complete(&fast_jobs[1]).await;
    assert_eq!(status, StatusCode::CONFLICT);

    // Jobs 3 and 4: normal completions.
    for job in &fast_jobs[2..] {
        let (status, _) = server.complete(job).await;
        assert_eq!(status, StatusCode::OK);
    }

    let runs = server.runs(batch.id).await;
    assert!(runs.iter().all(|r| r.status == RunState::Completed));
    let late = runs.iter().find(|r| r.id == fast_jobs[1].run_id).unwrap();
    assert_eq!(late.worker_id, Some(slow));
    let on_time = runs.iter().find(|r| r.id == fast_jobs[0].run_id).unwrap();
    assert_eq!(on_time.worker_id, Some(fast));
    let analysis = server.wait_for_analysis(batch.id).await;
    assert_eq!(analysis.runs_used, 4);
    server.stop().await;
}

/// A worker registers when it starts: jobs still leased to its id are ones it no longer runs
/// (it crashed or was killed), so they go back to the queue at once, their attempt not
/// counted, and the old leases are dead. Another worker's lease is untouched.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_registering_again_puts_the_jobs_it_held_back_in_the_queue_at_once() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.lease = Duration::from_secs(3600);
    })
    .await;
    let batch = server
        .submit(&batch_request(
            json!({"type": "explicit", "points": [[0.2, 0.3], [0.6, 0.3], [0.4, 0.9], [0.3, 0.6]]}),
            "linear",
            1,
        ))
        .await;
    let restarted = server.register_as(Uuid::new_v4()).await;
    let other = server.register().await;
    let held = [
        server.claim(restarted, 0.0).await.unwrap(),
        server.claim(restarted, 0.0).await.unwrap(),
    ];
    let others = server.claim(other, 0.0).await.unwrap();

    // The same id registers again, as after a restart.
    server.register_as(restarted).await;
    let workers = server.get("/v1/workers").await.1;
    let running = |id: Uuid| {
        workers
            .as_array()
            .unwrap()
            .iter()
            .find(|w| w["id"] == id.to_string())
            .unwrap()["running_jobs"]
            .clone()
    };
    assert_eq!(running(restarted), 0, "{workers}");
    assert_eq!(running(other), 1, "{workers}");
    for job in &held {
        let (status, body) = server
            .post(
                &format!("/v1/jobs/{}/heartbeat", job.job_id),
                &json!({"lease_token": job.lease_token, "progress": 0.5}),
            )
            .await;
        assert_eq!(status, StatusCode::CONFLICT, "an old lease is dead: {body}");
    }
    // The two released jobs and the one never claimed, each as a first attempt; the other
    // worker's job stays with it.
    let mut again = Vec::new();
    while let Some(job) = server.claim(restarted, 0.0).await {
        assert_eq!(job.attempt, 1, "a release is not an attempt");
        again.push(job);
    }
    assert_eq!(again.len(), 3);
    for job in &held {
        assert!(again.iter().any(|j| j.run_id == job.run_id));
    }
    assert!(again.iter().all(|j| j.run_id != others.run_id));
    for job in again.iter().chain([&others]) {
        let (status, body) = server.complete(job).await;
        assert_eq!(status, StatusCode::OK, "{body}");
    }
    assert_eq!(server.status(batch.id).await.summary.counts.completed, 4);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn restart_mid_batch_loses_nothing() {
    let (_dir, db) = temp_db();
    let first = TestServer::start(&db, |_| {}).await;
    let batch = first
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 2))
        .await;
    let worker = first.register().await;
    for _ in 0..3 {
        let job = first.claim(worker, 0.0).await.unwrap();
        let (status, _) = first.complete(&job).await;
        assert_eq!(status, StatusCode::OK);
    }
    let in_flight = first.claim(worker, 0.0).await.unwrap();
    let before = first.runs(batch.id).await;
    first.stop().await;

    let second = TestServer::start(&db, |_| {}).await;
    let after = second.runs(batch.id).await;
    assert_eq!(before, after, "runs survive the restart unchanged");
    let status = second.status(batch.id).await;
    assert_eq!(status.summary.counts.completed, 3);
    assert_eq!(status.summary.counts.running, 1);
    assert_eq!(status.summary.counts.queued, 4);

    // The lease granted by the old process is honoured by the new one.
    let (status, body) = second.complete(&in_flight).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(run_fake_worker(&second, 0.5).await, 4);
    let analysis = second.wait_for_analysis(batch.id).await;
    assert_eq!(analysis.runs_used, 8);
    second.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_submissions_get_4xx_naming_the_field() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let valid = batch_request(json!({"type": "factorial"}), "linear", 1);

    let expect_field = |mut request: serde_json::Value,
                        edit: &dyn Fn(&mut serde_json::Value),
                        field: &'static str| {
        edit(&mut request);
        let server = &server;
        async move {
            let (status, body) = server.post("/v1/batches", &request).await;
            assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{field}: {body}");
            let named = body["field"].as_str().unwrap_or_default();
            assert!(named.starts_with(field), "expected {field}, got {body}");
            assert!(!body["error"].as_str().unwrap().is_empty());
        }
    };

    expect_field(
        valid.clone(),
        &|r| r["factors"][0]["low"] = json!("low"),
        "factors[0].low",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["replicates"] = json!(-1),
        "replicates",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["design"] = json!({"type": "latin_square"}),
        "design",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["factors"][1]["path"] = json!("material.restitution"),
        "factors[1].path",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["factors"][0]["path"] = json!("material"),
        "factors[0].path",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["factors"][0]["low"] = json!(0.9),
        "factors[0].low",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["experiment"]["kind"] = json!("cook"),
        "experiment.kind",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["experiment"]["spec"]["total_mass"] = json!(-1.0),
        "experiment.spec.total_mass",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["factors"][0]["low"] = json!(-0.5),
        "factors[0]",
    )
    .await;
    expect_field(valid.clone(), &|r| r["model"] = json!("quadratic"), "model").await;
    expect_field(valid.clone(), &|r| r["model"] = json!("cubic"), "model").await;
    expect_field(valid.clone(), &|r| r["factors"] = json!([]), "factors").await;
    expect_field(
        valid.clone(),
        &|r| r["design"] = json!({"type": "plackett_burman", "runs": 7}),
        "design.runs",
    )
    .await;
    expect_field(
        valid.clone(),
        &|r| r["design"] = json!({"type": "explicit", "points": [[0.2, 0.3], [0.4]]}),
        "design.points[1]",
    )
    .await;

    let (status, body) = server.post_raw("/v1/batches", "{\"name\": ").await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    let (status, body) = server.get("/v1/batches").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body, json!([]), "nothing was stored");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failures_retry_then_die_and_the_batch_still_finishes() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| config.max_attempts = 2).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 2))
        .await;
    let worker = server.register().await;
    let doomed = server.claim(worker, 0.0).await.unwrap();
    let (status, body) = server
        .post(
            &format!("/v1/jobs/{}/fail", doomed.job_id),
            &json!({"lease_token": doomed.lease_token, "error": "particles escaped"}),
        )
        .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body["status"], "queued");
    let mut dead = false;
    while let Some(job) = server.claim(worker, 0.5).await {
        if job.run_id == doomed.run_id {
            assert_eq!(job.attempt, 2);
            let (status, body) = server
                .post(
                    &format!("/v1/jobs/{}/fail", job.job_id),
                    &json!({"lease_token": job.lease_token, "error": "again"}),
                )
                .await;
            assert_eq!(status, StatusCode::OK);
            assert_eq!(body["status"], "dead");
            dead = true;
        } else {
            let (status, _) = server.complete(&job).await;
            assert_eq!(status, StatusCode::OK);
        }
    }
    assert!(dead);
    let status = server.status(batch.id).await;
    assert_eq!(status.summary.counts.dead, 1);
    assert_eq!(status.summary.counts.completed, 7);
    assert_eq!(status.summary.state, BatchState::Completed);
    let runs = server.runs(batch.id).await;
    let doomed_run = runs.iter().find(|r| r.id == doomed.run_id).unwrap();
    assert_eq!(doomed_run.last_error.as_deref(), Some("again"));
    let analysis = server.wait_for_analysis(batch.id).await;
    assert_eq!(analysis.runs_used, 7);
    server.stop().await;
}

/// A failure of the seed's chance (`another_seed`, e.g. grains arched over the funnel's
/// outlet): the run is queued again at once, without the retry back-off, under the next seed,
/// which its result then carries; it dies when the attempts run out like any other failure.
/// A failure cannot be both permanent and worth another seed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failure_another_seed_may_cure_runs_again_at_once_under_a_new_seed() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.max_attempts = 3;
        config.retry_backoff = Duration::from_secs(3600);
    })
    .await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 1))
        .await;
    let worker = server.register().await;
    let fail = |job: &repose_api::ClaimResponse, extra: Value| {
        let mut body = json!({"lease_token": job.lease_token, "error": "held up: an arch"});
        body.as_object_mut()
            .unwrap()
            .extend(extra.as_object().unwrap().clone());
        (format!("/v1/jobs/{}/fail", job.job_id), body)
    };

    let first = server.claim(worker, 0.0).await.unwrap();
    let (path, body) = fail(&first, json!({"permanent": true, "another_seed": true}));
    let (status, reply) = server.post(&path, &body).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{reply}");
    assert_eq!(reply["field"], "another_seed", "{reply}");

    let (path, body) = fail(&first, json!({"another_seed": true}));
    let (status, reply) = server.post(&path, &body).await;
    assert_eq!(status, StatusCode::OK, "{reply}");
    assert_eq!(reply["status"], "queued");
    // At once (the back-off is an hour), the same run under the next seed. (Claims take the
    // longest-waiting job first; the others met on the way are held, finished at the end.)
    async fn claim_run(
        server: &TestServer,
        worker: Uuid,
        run_id: Uuid,
        held: &mut Vec<repose_api::ClaimResponse>,
    ) -> repose_api::ClaimResponse {
        loop {
            let job = server.claim(worker, 0.0).await.expect("the run is queued");
            if job.run_id == run_id {
                return job;
            }
            held.push(job);
        }
    }
    let mut held = Vec::new();
    let again = claim_run(&server, worker, first.run_id, &mut held).await;
    assert_eq!(again.attempt, 2);
    assert_eq!(again.seed, repose_doe::design::next_seed(first.seed));
    assert_ne!(again.seed, first.seed);
    let (status, reply) = server.complete(&again).await;
    assert_eq!(status, StatusCode::OK, "{reply}");
    let runs = server.runs(batch.id).await;
    let run = runs.iter().find(|r| r.id == first.run_id).unwrap();
    assert_eq!(run.seed, again.seed, "the result's seed is the run's");
    assert_eq!(
        run.metrics.as_ref().unwrap()["angle_deg"],
        common::angle_for(&again.spec, again.seed)
    );

    // A run that fails under every seed dies after max_attempts (3) like any other.
    let doomed = match server.claim(worker, 0.0).await {
        Some(job) => job,
        None => held.pop().expect("a run left"),
    };
    let mut seeds = vec![doomed.seed];
    let mut job = doomed.clone();
    loop {
        let (path, body) = fail(&job, json!({"another_seed": true}));
        let (status, reply) = server.post(&path, &body).await;
        assert_eq!(status, StatusCode::OK, "{reply}");
        if reply["status"] == "dead" {
            break;
        }
        job = claim_run(&server, worker, doomed.run_id, &mut held).await;
        seeds.push(job.seed);
    }
    assert_eq!(job.attempt, 3);
    seeds.dedup();
    assert_eq!(seeds.len(), 3, "three attempts, three seeds: {seeds:?}");
    while let Some(job) = server.claim(worker, 0.0).await {
        held.push(job);
    }
    for job in &held {
        let (status, _) = server.complete(job).await;
        assert_eq!(status, StatusCode::OK);
    }
    let status = server.status(batch.id).await;
    assert_eq!(status.summary.counts.dead, 1);
    assert_eq!(status.summary.counts.completed, 3);
    server.stop().await;
}

/// A late result of an expired lease is kept only while it is of the run's seed: once a later
/// attempt failed and the run took a new seed, the old lease's result is refused (409) and its
/// heartbeat tells it to stop.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_result_of_the_seed_before_a_new_one_is_refused() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.lease = Duration::from_millis(400);
    })
    .await;
    server
        .submit(&batch_request(
            json!({"type": "explicit", "points": [[0.2, 0.3], [0.6, 0.3], [0.4, 0.9], [0.3, 0.6]]}),
            "linear",
            1,
        ))
        .await;
    let slow = server.register().await;
    let fast = server.register().await;
    let mut old = Vec::new();
    for _ in 0..4 {
        old.push(server.claim(slow, 0.0).await.unwrap());
    }
    tokio::time::sleep(Duration::from_millis(700)).await;
    let second = server.claim(fast, 0.0).await.unwrap();
    assert_eq!(second.attempt, 2);
    let first = old.iter().find(|j| j.run_id == second.run_id).unwrap();
    assert_eq!(second.seed, first.seed);
    let (status, reply) = server
        .post(
            &format!("/v1/jobs/{}/fail", second.job_id),
            &json!({"lease_token": second.lease_token, "error": "an arch", "another_seed": true}),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{reply}");
    let (status, reply) = server.complete(first).await;
    assert_eq!(
        status,
        StatusCode::CONFLICT,
        "a result of the old seed: {reply}"
    );
    let (status, reply) = server
        .post(
            &format!("/v1/jobs/{}/heartbeat", first.job_id),
            &json!({"lease_token": first.lease_token, "progress": 0.9}),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{reply}");
    assert_eq!(reply["cancel"], true);
    server.stop().await;
}

/// A result is stored as sent, to the last bit: 1.7301083670000001 is a number serde_json's
/// default (fast) float parser reads one unit in the last place off; the workspace turns on its
/// exact parser (`float_roundtrip`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_result_is_stored_to_the_last_bit() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 1))
        .await;
    let worker = server.register().await;
    let job = server.claim(worker, 0.0).await.unwrap();
    let awkward = 1.7301083670000001_f64;
    let mut completion = common::simulate(&job);
    completion.metrics.insert("angle_deg".into(), awkward);
    completion.wall_time_s = awkward;
    let (status, body) = server.complete_with(&job, &completion).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let runs = server.runs(batch.id).await;
    let run = runs.iter().find(|r| r.id == job.run_id).unwrap();
    assert_eq!(
        run.metrics.as_ref().unwrap()["angle_deg"].to_bits(),
        awkward.to_bits()
    );
    assert_eq!(run.wall_time_s.unwrap().to_bits(), awkward.to_bits());
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn long_poll_wakes_on_submission_and_cancel_stops_workers() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let worker = server.register().await;
    assert!(server.claim(worker, 0.0).await.is_none());

    let started = tokio::time::Instant::now();
    let (claimed, batch) = tokio::join!(server.claim(worker, 10.0), async {
        tokio::time::sleep(Duration::from_millis(200)).await;
        server
            .submit(&batch_request(json!({"type": "factorial"}), "linear", 2))
            .await
    });
    let job = claimed.expect("the waiting claim receives the new job");
    assert!(started.elapsed() < Duration::from_secs(5));

    let (status, body) = server
        .post(&format!("/v1/batches/{}/cancel", batch.id), &json!({}))
        .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["state"], "cancelled");
    let (status, body) = server
        .post(
            &format!("/v1/jobs/{}/heartbeat", job.job_id),
            &json!({"lease_token": job.lease_token, "progress": 0.2}),
        )
        .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body["cancel"], true);
    let (status, _) = server.complete(&job).await;
    assert_eq!(status, StatusCode::CONFLICT);
    assert!(server.claim(worker, 0.0).await.is_none());
    let (status, _) = server
        .get(&format!("/v1/batches/{}/analysis", batch.id))
        .await;
    assert_eq!(status, StatusCode::CONFLICT);

    let unregistered = json!({"worker_id": Uuid::new_v4(), "wait_s": 0});
    let (status, body) = server.post("/v1/jobs/claim", &unregistered).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY);
    assert_eq!(body["field"], "worker_id");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_example_batch_and_campaign_files_are_accepted() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    let mut seen = 0;
    for (folder, endpoint) in [("batches", "/v1/batches"), ("campaigns", "/v1/campaigns")] {
        let mut files: Vec<_> = std::fs::read_dir(root.join(folder))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|x| x == "json"))
            .collect();
        files.sort();
        for file in files {
            let body: Value = serde_json::from_str(&std::fs::read_to_string(&file).unwrap())
                .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
            let (status, reply) = server.post(endpoint, &body).await;
            assert_eq!(status, StatusCode::CREATED, "{}: {reply}", file.display());
            seen += 1;
        }
    }
    assert!(seen >= 5, "example files found: {seen}");
    server.stop().await;
}
