//! Regression tests for the defects of issue #12, each against the real server over HTTP.

use crate::common;

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{angle_for, batch_request, simulate, temp_db, TestServer};
use repose_api::ClaimResponse;
use reqwest::StatusCode;
use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use uuid::Uuid;

/// Database pages of the (checkpointed, closed) database file.
fn pages(db: &std::path::Path) -> u64 {
    std::fs::metadata(db).unwrap().len() / 4096
}

/// What a fault-injection worker saw: every completion answered 200, by run id with the
/// angle it delivered, and how many requests failed.
#[derive(Debug, Default)]
struct Outcomes {
    acknowledged: HashMap<Uuid, f64>,
    errors: usize,
    error_statuses: Vec<StatusCode>,
    /// Jobs whose completion failed: delivered again once space returns.
    undelivered: Vec<ClaimResponse>,
}

/// Claims and completes until the queue is empty or `max_errors` requests in a row failed.
async fn faulty_worker(server: &TestServer, outcomes: Arc<Mutex<Outcomes>>, max_errors: usize) {
    let worker = server.register().await;
    let mut errors_in_a_row = 0;
    while errors_in_a_row < max_errors {
        let (status, body) = server
            .post(
                "/v1/jobs/claim",
                &json!({"worker_id": worker, "wait_s": 0.0}),
            )
            .await;
        let job: ClaimResponse = match status {
            StatusCode::OK => serde_json::from_value(body).unwrap(),
            StatusCode::NO_CONTENT => return,
            other => {
                assert!(other.is_server_error(), "claim answered {other}: {body}");
                {
                    let mut seen = outcomes.lock().unwrap();
                    seen.errors += 1;
                    seen.error_statuses.push(other);
                }
                errors_in_a_row += 1;
                tokio::time::sleep(Duration::from_millis(10)).await;
                continue;
            }
        };
        let (status, body) = server.complete(&job).await;
        let mut seen = outcomes.lock().unwrap();
        if status == StatusCode::OK {
            let angle = angle_for(&job.spec, job.seed);
            assert!(
                seen.acknowledged.insert(job.run_id, angle).is_none(),
                "run {} acknowledged twice",
                job.run_id
            );
            errors_in_a_row = 0;
        } else {
            assert!(
                status.is_server_error(),
                "complete answered {status}: {body}"
            );
            seen.errors += 1;
            seen.error_statuses.push(status);
            seen.undelivered.push(job);
            errors_in_a_row += 1;
        }
    }
}

/// Defect 1 and the fault-injection test of the issue: the database fills up in the middle of
/// concurrent claims and completions. While it is full, `/healthz` says 503 and no write is
/// acknowledged; after a restart with space, every result that got a 200 is stored with the
/// value sent, no run has a result nobody was told about, and the batch finishes with exactly
/// one result per run.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn full_disk_mid_run_never_loses_an_acknowledged_result() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 40))
        .await;
    assert_eq!(batch.run_count, 160);
    server.stop().await;

    // A few pages of room: some claims and completions fit, then the "disk" is full. How many
    // pages the first claim needs depends on how the file's pages happen to be laid out, so
    // the room grows by a few pages until something fits; the attempt that counts must still
    // fill up. A failed attempt only leaves claimed jobs whose completion failed, and those
    // are delivered again below like any other.
    let outcomes = Arc::new(Mutex::new(Outcomes::default()));
    let mut room = 0;
    let server = loop {
        room += 4;
        assert!(room <= 64, "nothing fit in {room} pages of room");
        let cap = pages(&db) + room;
        let server = TestServer::start(&db, |config| config.max_db_pages = Some(cap)).await;
        let errors_before = outcomes.lock().unwrap().errors;
        let workers: Vec<_> = (0..6)
            .map(|_| faulty_worker(&server, Arc::clone(&outcomes), 25))
            .collect();
        futures_join_all(workers).await;
        let something_fit = {
            let seen = outcomes.lock().unwrap();
            assert!(
                seen.errors > errors_before,
                "the database never filled up with {room} pages of room"
            );
            !seen.acknowledged.is_empty()
        };
        if something_fit {
            break server;
        }
        server.stop().await;
    };
    let (health, body) = server.get_as("/healthz", None).await;
    assert_eq!(health, StatusCode::SERVICE_UNAVAILABLE, "{body}");
    {
        let seen = outcomes.lock().unwrap();
        assert!(
            seen.error_statuses
                .iter()
                .all(|s| *s == StatusCode::SERVICE_UNAVAILABLE),
            "a full disk is a 503, not a 500: {:?}",
            seen.error_statuses
        );
    }
    server.stop().await;

    // Space returns: restart without the cap.
    let server = TestServer::start(&db, |_| {}).await;
    let (health, _) = server.get_as("/healthz", None).await;
    assert_eq!(health, StatusCode::OK);
    let acknowledged = outcomes.lock().unwrap().acknowledged.clone();
    let runs = server.runs(batch.id).await;
    let stored: HashMap<Uuid, f64> = runs
        .iter()
        .filter_map(|run| Some((run.id, run.metrics.as_ref()?["angle_deg"])))
        .collect();
    for (run, angle) in &acknowledged {
        let kept = stored.get(run).copied();
        assert!(
            kept.is_some_and(|kept| (kept - angle).abs() < 1e-9),
            "run {run} was acknowledged with {angle} but {kept:?} is stored"
        );
    }
    assert_eq!(
        stored.len(),
        acknowledged.len(),
        "results stored that no worker was told were accepted"
    );

    // Workers deliver the results that failed again: each is accepted exactly once.
    let undelivered = std::mem::take(&mut outcomes.lock().unwrap().undelivered);
    for job in &undelivered {
        let (status, body) = server.complete(job).await;
        assert_eq!(status, StatusCode::OK, "{body}");
        let (status, _) = server.complete(job).await;
        assert_eq!(status, StatusCode::CONFLICT, "a second delivery is refused");
    }
    // The rest runs normally; every run ends with exactly one result.
    let done = common::run_fake_worker(&server, 0.5).await;
    assert_eq!(done + acknowledged.len() + undelivered.len(), 160);
    let status = server.status(batch.id).await;
    assert_eq!(status.summary.counts.completed, 160);
    server.wait_for_analysis(batch.id).await;
    server.stop().await;
}

/// Polls all `futures` concurrently on the current task until every one is done (what
/// `futures::future::join_all` does, without adding the crate for one test).
async fn futures_join_all<F: std::future::Future<Output = ()>>(futures: Vec<F>) {
    let mut pinned: Vec<_> = futures.into_iter().map(Box::pin).collect();
    std::future::poll_fn(|cx| {
        pinned.retain_mut(|f| f.as_mut().poll(cx).is_pending());
        if pinned.is_empty() {
            std::task::Poll::Ready(())
        } else {
            std::task::Poll::Pending
        }
    })
    .await;
}

/// Defect 1, directly: after a write failed because the database is full, no later write is
/// answered 200 unless it is committed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_a_full_disk_error_later_acknowledgements_are_durable() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 20))
        .await;
    server.stop().await;

    let cap = pages(&db) + 1;
    let server = TestServer::start(&db, |config| config.max_db_pages = Some(cap)).await;
    let worker = server.register().await;
    let mut acknowledged = Vec::new();
    let mut failures = 0;
    for _ in 0..80 {
        let (status, body) = server
            .post(
                "/v1/jobs/claim",
                &json!({"worker_id": worker, "wait_s": 0.0}),
            )
            .await;
        if status != StatusCode::OK {
            assert!(status.is_server_error(), "{status}: {body}");
            failures += 1;
            continue;
        }
        let job: ClaimResponse = serde_json::from_value(body).unwrap();
        let (status, _) = server.complete(&job).await;
        if status == StatusCode::OK {
            acknowledged.push(job.run_id);
        } else {
            failures += 1;
        }
    }
    assert!(failures > 0, "the cap was never reached");
    server.stop().await;

    let server = TestServer::start(&db, |_| {}).await;
    let runs = server.runs(batch.id).await;
    for run in &acknowledged {
        let stored = runs.iter().find(|r| r.id == *run).unwrap();
        assert!(
            stored.metrics.is_some(),
            "run {run} was acknowledged but its result is gone after a restart \
             ({} acknowledged, {failures} failed)",
            acknowledged.len()
        );
    }
    server.stop().await;
}

/// Defect 2: an absurd centre-point count is refused by arithmetic, before any allocation.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn huge_centre_point_counts_are_refused_naming_the_field() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let mut three = batch_request(json!({"type": "factorial"}), "linear", 1);
    three["factors"]
        .as_array_mut()
        .unwrap()
        .push(json!({"name": "r", "path": "soil_steel.static_friction", "low": 0.2, "high": 0.6}));
    for design in [
        json!({"type": "box_behnken", "centre_points": 1e12 as u64}),
        json!({"type": "central_composite", "variant": "face_centred",
               "centre_points": 1e12 as u64}),
        json!({"type": "box_behnken", "centre_points": u64::MAX}),
    ] {
        let mut request = three.clone();
        request["design"] = design.clone();
        request["model"] = json!("quadratic");
        let (status, body) = server.post("/v1/batches", &request).await;
        assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{design}: {body}");
        assert_eq!(body["field"], "design.centre_points", "{body}");
    }
    // Plackett–Burman run counts and replicates are bounded the same way.
    let mut request = three.clone();
    request["design"] = json!({"type": "plackett_burman", "runs": 1e12 as u64});
    let (status, body) = server.post("/v1/batches", &request).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "design.runs", "{body}");
    let mut request = three.clone();
    request["replicates"] = json!(u32::MAX);
    let (status, body) = server.post("/v1/batches", &request).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "replicates", "{body}");
    // The server is still there.
    let (status, _) = server.get_as("/healthz", None).await;
    assert_eq!(status, StatusCode::OK);
    server.stop().await;
}

/// Defect 3: a huge `wait_s` waits at most the server's maximum instead of panicking.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_enormous_claim_wait_is_clamped_not_a_panic() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.max_claim_wait = Duration::from_millis(200);
    })
    .await;
    let worker = server.register().await;
    for wait_s in [1e300, f64::MAX, 1e19] {
        let started = Instant::now();
        let (status, body) = server
            .post(
                "/v1/jobs/claim",
                &json!({"worker_id": worker, "wait_s": wait_s}),
            )
            .await;
        assert_eq!(status, StatusCode::NO_CONTENT, "wait_s {wait_s}: {body}");
        assert!(started.elapsed() < Duration::from_secs(5));
    }
    server.stop().await;
}

/// Defect 4: a factor range whose natural values overflow is refused at submission, naming the
/// factor, so no batch exists whose runs cannot be read back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn factor_values_that_overflow_are_refused_naming_the_factor() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let mut request = batch_request(json!({"type": "factorial"}), "linear", 1);
    request["factors"]
        .as_array_mut()
        .unwrap()
        .push(json!({"name": "cap", "path": "wall_time_cap", "low": 1.0, "high": 1.7e308}));
    request["experiment"]["spec"]["wall_time_cap"] = json!(100.0);
    let (status, body) = server.post("/v1/batches", &request).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "factors[2]", "{body}");
    // A circumscribed CCD's star points go beyond the range: they must be finite too.
    let mut request = batch_request(
        json!({"type": "central_composite", "variant": "circumscribed", "centre_points": 1}),
        "quadratic",
        1,
    );
    request["factors"][0] = json!({"name": "mu", "path": "soil_soil.static_friction",
                                   "low": 0.2, "high": 1.7e308});
    let (status, body) = server.post("/v1/batches", &request).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "factors[0]", "{body}");
    server.stop().await;
}

/// Defect 5: once a batch has finished (its analysis may already be stored and a campaign
/// moved on), a late result for one of its dead runs is refused with 409 and changes nothing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_result_after_the_batch_finished_is_refused() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.lease = Duration::from_millis(300);
        config.max_attempts = 1;
    })
    .await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "none", 1))
        .await;
    let worker = server.register().await;
    let mut jobs = Vec::new();
    while let Some(job) = server.claim(worker, 0.0).await {
        jobs.push(job);
    }
    assert_eq!(jobs.len(), 4);
    let late = jobs.pop().unwrap();
    for job in &jobs {
        let (status, body) = server.complete(job).await;
        assert_eq!(status, StatusCode::OK, "{body}");
    }
    // The last lease expires; with one attempt its job is dead and the batch is finished.
    tokio::time::sleep(Duration::from_millis(600)).await;
    assert!(server.claim(worker, 0.0).await.is_none());
    let analysis = server.wait_for_analysis(batch.id).await;
    assert_eq!(analysis.runs_used, 3);

    let (status, body) = server.complete(&late).await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    let status = server.status(batch.id).await;
    assert_eq!(status.summary.counts.completed, 3);
    assert_eq!(status.summary.counts.dead, 1);
    server.stop().await;
}

/// Defect 6: a client holding a half-sent request cannot keep the server from exiting.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_finishes_despite_half_sent_requests() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.shutdown_grace = Duration::from_millis(500);
    })
    .await;
    let address = server.url.trim_start_matches("http://").to_owned();
    // Headers never finished.
    let mut headers_only = TcpStream::connect(&address).await.unwrap();
    headers_only
        .write_all(b"POST /v1/batches HTTP/1.1\r\nHost: x\r\n")
        .await
        .unwrap();
    // Headers complete, body announced but only partly sent.
    let mut half_body = TcpStream::connect(&address).await.unwrap();
    half_body
        .write_all(
            format!(
                "POST /v1/batches HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {}\r\n\
                 Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n{{\"name\":",
                server.user_token
            )
            .as_bytes(),
        )
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    tokio::time::timeout(Duration::from_secs(10), server.stop())
        .await
        .expect("the server did not exit within 10 s of the shutdown signal");
    drop((headers_only, half_body));
}

/// Defect 6: a connection that does not finish its headers in time is closed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_header_sender_is_disconnected() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.header_read_timeout = Duration::from_millis(300);
    })
    .await;
    let address = server.url.trim_start_matches("http://").to_owned();
    let mut slow = TcpStream::connect(&address).await.unwrap();
    slow.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        .await
        .unwrap();
    let mut buffer = Vec::new();
    let read = tokio::time::timeout(Duration::from_secs(5), slow.read_to_end(&mut buffer)).await;
    assert!(
        read.is_ok(),
        "the connection was still open 5 s after its headers stalled"
    );
    server.stop().await;
}

/// Defect 7 (size limits): oversized free-text fields are refused naming the field.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_text_fields_are_refused_naming_the_field() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let long = "x".repeat(100_000);
    let (status, body) = server
        .post(
            "/v1/workers/register",
            &json!({"instance_id": Uuid::new_v4(), "host": long, "threads": 1, "version": repose_api::version::RELEASE}),
        )
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "host");
    let mut request = batch_request(json!({"type": "factorial"}), "linear", 1);
    request["name"] = json!(long);
    let (status, body) = server.post("/v1/batches", &request).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "name");

    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 1))
        .await;
    let worker = server.register().await;
    let job = server.claim(worker, 0.0).await.unwrap();
    let (status, body) = server
        .post(
            &format!("/v1/jobs/{}/fail", job.job_id),
            &json!({"lease_token": job.lease_token, "error": "e".repeat(1_000_000)}),
        )
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "error");
    let mut completion = serde_json::to_value(simulate(&job)).unwrap();
    completion["details"] = json!({"blob": "d".repeat(1_000_000)});
    let (status, body) = server
        .post(&format!("/v1/jobs/{}/complete", job.job_id), &completion)
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["field"], "details");
    let _ = batch;
    server.stop().await;
}

/// Defect 7 (write amplification): the experiment spec is stored once per batch, not once per
/// run. 2,000 runs of a batch cost far less than 2,000 copies of the spec.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_large_batch_does_not_copy_the_spec_into_every_run() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let size = |db: &std::path::Path| -> u64 {
        let wal = db.with_extension("sqlite-wal");
        std::fs::metadata(db).map(|m| m.len()).unwrap_or(0)
            + std::fs::metadata(wal).map(|m| m.len()).unwrap_or(0)
    };
    let worker = server.register().await;
    let small = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 1))
        .await;
    let job = server.claim(worker, 0.0).await.unwrap();
    let spec_bytes = serde_json::to_string(&job.spec).unwrap().len() as u64;
    let _ = small;
    server.stop().await;
    let before = size(&db);
    let server = TestServer::start(&db, |_| {}).await;
    let worker = server.register().await;
    let big = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 500))
        .await;
    assert_eq!(big.run_count, 2000);
    // Every run still gets its own complete spec.
    let job = server.claim(worker, 0.0).await.unwrap();
    assert!(job.spec["soil_soil"]["static_friction"].is_number());
    server.stop().await;
    let grown = size(&db) - before;
    assert!(
        grown < 2000 * spec_bytes * 3 / 4,
        "2,000 runs grew the database by {grown} bytes; the spec is {spec_bytes} bytes"
    );
}

/// Also found: expired leases were only reclaimed inside `claim`. With no worker polling, an
/// expired job now goes back to the queue on the server's timer.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_expired_lease_is_reclaimed_without_any_claim() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |config| {
        config.lease = Duration::from_millis(300);
        config.reclaim_interval = Duration::from_millis(100);
    })
    .await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 1))
        .await;
    let worker = server.register().await;
    let job = server.claim(worker, 0.0).await.unwrap();
    tokio::time::sleep(Duration::from_millis(1000)).await;
    let (status, jobs) = server
        .get(&format!("/v1/jobs?batch={}&state=running", batch.id))
        .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(jobs, json!([]), "job {} is still running", job.job_id);
    assert_eq!(server.status(batch.id).await.summary.counts.queued, 4);
    server.stop().await;
}

/// Also found: a worker token could register over any worker id. Worker rows now belong to the
/// token that made them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_id_belongs_to_the_token_that_registered_it() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let worker = server.register().await;
    let intruder = repose_server::create_token(&db, "intruder", repose_server::TokenRole::Worker)
        .await
        .unwrap();
    let registration = json!({"instance_id": worker, "host": "evil", "threads": 1,
                              "version": repose_api::version::RELEASE});
    let (status, body) = server
        .post_as("/v1/workers/register", &registration, Some(&intruder))
        .await;
    assert_eq!(status, StatusCode::FORBIDDEN, "{body}");
    let (status, body) = server
        .post_as(
            "/v1/jobs/claim",
            &json!({"worker_id": worker, "wait_s": 0.0}),
            Some(&intruder),
        )
        .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    let (_, workers) = server.get("/v1/workers").await;
    assert_eq!(workers[0]["host"], "test-host");
    server.stop().await;
}

/// Also found: the database file was created world-readable.
#[cfg(unix)]
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_database_file_is_private_to_its_owner() {
    use std::os::unix::fs::PermissionsExt;
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let mode = std::fs::metadata(&db).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o600, "mode {mode:o}");
    server.stop().await;
}

/// Defect 7 (starving heartbeats): while a 10,000-run batch is stored, heartbeats of running
/// jobs are never held up for a second or more (the lease protocol depends on them).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn heartbeats_are_not_blocked_by_a_large_submission() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 1))
        .await;
    let worker = server.register().await;
    let job = server.claim(worker, 0.0).await.unwrap();
    let submitting = async {
        let started = Instant::now();
        let big = server
            .submit(&batch_request(json!({"type": "factorial"}), "linear", 2500))
            .await;
        assert_eq!(big.run_count, 10_000);
        started.elapsed()
    };
    let beating = async {
        let mut worst = Duration::ZERO;
        let deadline = Instant::now() + Duration::from_secs(4);
        while Instant::now() < deadline {
            let sent = Instant::now();
            let (status, body) = server
                .post(
                    &format!("/v1/jobs/{}/heartbeat", job.job_id),
                    &json!({"lease_token": job.lease_token, "progress": 0.5}),
                )
                .await;
            assert_eq!(status, StatusCode::OK, "{body}");
            worst = worst.max(sent.elapsed());
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        worst
    };
    let (submission, worst) = tokio::join!(submitting, beating);
    assert!(
        worst < Duration::from_secs(1),
        "a heartbeat waited {worst:?} while a 10,000-run batch was stored ({submission:?})"
    );
    server.stop().await;
}

/// Defect 4 (reads): a batch stored by an older server with `null`s where natural values
/// overflowed can still be read (JSON and CSV) instead of answering 500 forever.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn runs_stored_with_nulls_by_an_older_server_can_still_be_read() {
    let (_dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 1))
        .await;
    server.stop().await;
    // What the old server wrote for an overflowing range: `null` for the infinite value.
    {
        use sqlx::Connection;
        let mut conn = sqlx::SqliteConnection::connect(&format!("sqlite://{}", db.display()))
            .await
            .unwrap();
        sqlx::query("UPDATE runs SET natural = '[null, 0.3]' WHERE run_index = 0")
            .execute(&mut conn)
            .await
            .unwrap();
        conn.close().await.unwrap();
    }
    let server = TestServer::start(&db, |_| {}).await;
    let (status, body) = server.get(&format!("/v1/batches/{}/runs", batch.id)).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, csv) = server
        .get_text(&format!("/v1/batches/{}/runs?format=csv", batch.id))
        .await;
    assert_eq!(status, StatusCode::OK, "{csv}");
    assert_eq!(csv.lines().count(), 5);
    server.stop().await;
}
