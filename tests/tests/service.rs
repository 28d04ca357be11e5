//! The job service end to end with real processes: `repose server` on a temp SQLite file,
//! `repose worker` processes, batches submitted over HTTP; workers and the server killed with
//! SIGKILL mid-batch.

use crate::common;

use std::time::Duration;

use common::repose;
use common::service::{replay_batch, Service};
use serde_json::{json, Value};

/// A four-run angle-of-repose batch small enough for CI (≈ 1 150 grains a run, a few seconds
/// each): static and rolling soil-soil friction on a 2² factorial. The rolling friction stays
/// at or below 0.12: from about 0.2 the fast preset's funnel, with its old 17 mm outlet (6.8
/// grains wide), arched in some pours, and an arched run is `held_up`, with no angle
/// (2026-11-25: μr 0.2-0.4 left fewer than three heaps here; the outlet is 25 mm since
/// issue 37).
fn small_aor_batch() -> Value {
    json!({
        "name": "two-worker AOR",
        "experiment": {"kind": "aor", "preset": "fast", "spec": {"total_mass": 0.025}},
        "factors": [
            {"name": "mu_s", "path": "soil_soil.static_friction", "low": 0.4, "high": 0.6},
            {"name": "mu_r", "path": "soil_soil.rolling_friction", "low": 0.02, "high": 0.12}
        ],
        "design": {"type": "factorial"},
        "response": "angle_deg",
        "model": "linear",
        "seed": 5
    })
}

fn runs(service: &Service, batch: &str) -> Vec<Value> {
    service
        .get(&format!("/v1/batches/{batch}/runs"))
        .as_array()
        .unwrap()
        .clone()
}

#[test]
fn a_batch_runs_through_two_worker_processes_and_is_analysed() {
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 30.0);
    let _a = service.start_worker("worker-a", &[]);
    let _b = service.start_worker("worker-b", &[]);
    let batch = service.submit(&small_aor_batch());
    let status = service.wait_finished(&batch, Duration::from_secs(600));
    assert_eq!(status["state"], "completed", "{status}");

    let runs = runs(&service, &batch);
    assert_eq!(runs.len(), 4);
    let mut workers: Vec<&str> = runs
        .iter()
        .filter_map(|r| r["worker_id"].as_str())
        .collect();
    workers.sort_unstable();
    workers.dedup();
    assert_eq!(workers.len(), 2, "both workers ran jobs: {runs:?}");
    let angles: Vec<f64> = runs
        .iter()
        .filter_map(|r| r["metrics"]["angle_deg"].as_f64())
        .collect();
    assert!(angles.len() >= 3, "at least three heaps measured: {runs:?}");
    assert!(angles.iter().all(|a| (5.0..60.0).contains(a)), "{angles:?}");

    let analysis = service.get(&format!("/v1/batches/{batch}/analysis"));
    assert_eq!(
        analysis["runs_used"].as_u64().unwrap() as usize,
        angles.len()
    );
    assert!(analysis["fit"].is_object(), "{analysis}");
}

/// A two-run shear batch, the smallest that still fits a Mohr-Coulomb line per run: the fast
/// preset (≈ 1 000 grains) at two normal stresses, sheared 3 mm instead of 6 (tens of seconds
/// a run), at two interparticle frictions.
fn small_shear_batch() -> Value {
    json!({
        "name": "two-worker shear",
        "experiment": {"kind": "shear", "preset": "fast", "spec": {
            "normal_stresses_kpa": [4.0, 8.0],
            "shear": {"displacement": 0.003}
        }},
        "factors": [
            {"name": "mu_s", "path": "soil_soil.static_friction", "low": 0.3, "high": 0.5}
        ],
        "design": {"type": "factorial"},
        "response": "friction_angle_deg",
        "model": "none",
        "seed": 7
    })
}

/// One batch holds one experiment kind (`BatchRequest.experiment`), so "mixing" is an `aor`
/// batch and a `shear` batch queued together on one server and run by the same two worker
/// processes: both are accepted, run and analysed.
#[test]
fn an_aor_batch_and_a_shear_batch_run_side_by_side_and_are_analysed() {
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 60.0);
    let _a = service.start_worker("worker-a", &[]);
    let _b = service.start_worker("worker-b", &[]);
    let aor = service.submit(&small_aor_batch());
    let shear = service.submit(&small_shear_batch());
    for batch in [&aor, &shear] {
        let status = service.wait_finished(batch, Duration::from_secs(900));
        assert_eq!(status["state"], "completed", "{status}");
        let analysis = service.get(&format!("/v1/batches/{batch}/analysis"));
        assert!(analysis["runs_used"].as_u64().unwrap() >= 2, "{analysis}");
    }
    let shear_runs = runs(&service, &shear);
    assert_eq!(shear_runs.len(), 2);
    for run in &shear_runs {
        let m = &run["metrics"];
        let phi = m["friction_angle_deg"].as_f64().unwrap_or(f64::NAN);
        assert!((5.0..50.0).contains(&phi), "{run}");
        assert!(m["cohesion_kpa"].as_f64().is_some(), "{run}");
    }
    let angles = runs(&service, &aor)
        .iter()
        .filter_map(|r| r["metrics"]["angle_deg"].as_f64())
        .count();
    assert!(angles >= 3, "at least three heaps measured");
}

#[test]
fn a_worker_killed_mid_job_is_re_leased_and_the_run_has_exactly_one_result() {
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 2.0);
    let batch = service.submit(&replay_batch(2, 3.0));
    let mut doomed = service.start_worker("doomed", &[]);
    service.wait_for(&batch, Duration::from_secs(60), |s| {
        s["counts"]["running"].as_u64() == Some(1)
    });
    doomed.kill();

    let _survivor = service.start_worker("survivor", &[]);
    let status = service.wait_finished(&batch, Duration::from_secs(120));
    assert_eq!(status["state"], "completed", "{status}");
    assert_eq!(status["counts"]["completed"], 2, "{status}");
    let runs = runs(&service, &batch);
    let re_leased: Vec<&Value> = runs
        .iter()
        .filter(|r| r["attempts"].as_u64() == Some(2))
        .collect();
    assert_eq!(
        re_leased.len(),
        1,
        "the killed worker's job was leased again: {runs:?}"
    );
    for run in &runs {
        assert_eq!(run["status"], "completed");
        let x = run["factors"][0]["natural"].as_f64().unwrap();
        assert_eq!(run["metrics"]["y"].as_f64(), Some(10.0 + 2.0 * x), "{run}");
    }
}

#[test]
fn a_worker_killed_mid_aor_run_leaves_a_checkpoint_the_next_worker_goes_on_from() {
    // One fast angle-of-repose run, cut by the time cap while it settles. The first worker
    // keeps a checkpoint every 200 steps and is killed (SIGKILL) once it has one; the job's
    // lease expires and a second worker sharing the checkpoint directory continues the run
    // from there. Its result is the uninterrupted run's (`repose aor` on the same spec).
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 2.0);
    let checkpoints = dir.path().join("checkpoints");
    let worker_args = [
        "--checkpoint-dir",
        checkpoints.to_str().unwrap(),
        "--checkpoint-every",
        "0",
    ];
    let batch = service.submit(&json!({
        "name": "one checkpointed heap",
        "experiment": {"kind": "aor", "preset": "fast", "spec": {
            "total_mass": 0.02, "time_cap": 0.25,
            "settle": {"min_time": 0.1, "check_interval": 0.05}}},
        "factors": [{"name": "mu_r", "path": "soil_soil.rolling_friction", "low": 0.05, "high": 0.1}],
        "design": {"type": "explicit", "points": [[0.08]]},
        "response": "angle_deg",
        "model": "none",
        "seed": 3
    }));
    let mut doomed = service.start_worker("doomed", &worker_args);
    let kept = || checkpoint_files(&checkpoints);
    wait_for_a_checkpoint(&checkpoints);
    std::thread::sleep(Duration::from_millis(300));
    let status = service.get(&format!("/v1/batches/{batch}"));
    assert_eq!(status["counts"]["running"], 1, "killed mid-run: {status}");
    doomed.kill();

    let survivor = service.start_worker("survivor", &worker_args);
    let status = service.wait_finished(&batch, Duration::from_secs(300));
    assert_eq!(status["state"], "completed", "{status}");
    let runs = runs(&service, &batch);
    assert_eq!(runs[0]["attempts"], 2, "{runs:?}");
    assert!(
        survivor
            .log_text()
            .contains("found a checkpoint of this run"),
        "{}",
        survivor.log_text()
    );
    assert_eq!(kept(), 0, "the finished run's checkpoint is deleted");

    let out = dir.path().join("reference");
    let seed = runs[0]["seed"].as_u64().unwrap().to_string();
    let o = repose(&[
        "aor",
        "--preset",
        "fast",
        "--set",
        "total_mass=0.02",
        "--set",
        "time_cap=0.25",
        "--set",
        "settle.min_time=0.1",
        "--set",
        "settle.check_interval=0.05",
        "--set",
        "soil_soil.rolling_friction=0.08",
        "--set",
        &format!("seed={seed}"),
        "--threads",
        "1",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", common::stderr(&o));
    let reference: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("result.json")).unwrap()).unwrap();
    let metrics = &runs[0]["metrics"];
    for (metric, field) in [
        ("simulated_time_s", "simulated_time_s"),
        ("grains_inserted", "/grains/inserted/count"),
        ("angle_deg", "last_angle_deg"),
    ] {
        let expected = if field.starts_with('/') {
            reference.pointer(field)
        } else {
            reference.get(field)
        }
        .and_then(Value::as_f64)
        .unwrap_or_else(|| panic!("{field} in {reference}"));
        let got = metrics[metric]
            .as_f64()
            .unwrap_or_else(|| panic!("{metric} in {metrics}"));
        assert!(
            (got - expected).abs() <= 1e-12 * expected.abs(),
            "{metric}: resumed {got}, uninterrupted {expected}"
        );
    }
}

#[test]
fn a_cancelled_aor_run_leaves_no_checkpoint_behind() {
    // A worker keeps a checkpoint of a long heap every step; the batch is cancelled while it
    // runs. The worker hears it at its next heartbeat, stops, and deletes the run's checkpoint:
    // nobody will continue a cancelled run (a worker that is only stopping keeps it).
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 2.0);
    let checkpoints = dir.path().join("checkpoints");
    let batch = service.submit(&json!({
        "name": "one heap, cancelled",
        "experiment": {"kind": "aor", "preset": "fast", "spec": {"time_cap": 30.0}},
        "factors": [{"name": "mu_r", "path": "soil_soil.rolling_friction", "low": 0.05, "high": 0.1}],
        "design": {"type": "explicit", "points": [[0.08]]},
        "response": "angle_deg",
        "model": "none",
        "seed": 5
    }));
    let worker = service.start_worker(
        "worker",
        &[
            "--checkpoint-dir",
            checkpoints.to_str().unwrap(),
            "--checkpoint-every",
            "0",
        ],
    );
    let kept = || checkpoint_files(&checkpoints);
    wait_for_a_checkpoint(&checkpoints);
    service.post(&format!("/v1/batches/{batch}/cancel"), &json!({}));
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while !worker.log_text().contains("lease lost") || kept() > 0 {
        assert!(
            std::time::Instant::now() < deadline,
            "{} checkpoint(s) left a minute after the cancel\n{}",
            kept(),
            worker.log_text()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn the_server_killed_mid_batch_restarts_and_nothing_is_lost() {
    let dir = tempfile::tempdir().unwrap();
    let mut service = Service::start(dir.path(), 5.0);
    let batch = service.submit(&replay_batch(12, 0.4));
    let _a = service.start_worker("worker-a", &[]);
    let _b = service.start_worker("worker-b", &[]);
    service.wait_for(&batch, Duration::from_secs(60), |s| {
        s["counts"]["completed"].as_u64().unwrap_or(0) >= 3
    });
    service.kill_and_restart(5.0);

    let status = service.wait_finished(&batch, Duration::from_secs(180));
    assert_eq!(status["state"], "completed", "{status}");
    let runs = runs(&service, &batch);
    assert_eq!(runs.len(), 12);
    for run in &runs {
        assert_eq!(run["status"], "completed", "{run}");
        let x = run["factors"][0]["natural"].as_f64().unwrap();
        assert_eq!(run["metrics"]["y"].as_f64(), Some(10.0 + 2.0 * x), "{run}");
    }
    let analysis = service.get(&format!("/v1/batches/{batch}/analysis"));
    assert_eq!(analysis["runs_used"], 12);
}

/// A worker whose lease expired while it simulated (the server was down longer than the
/// lease) gets 409 on its heartbeats; it keeps the simulation and delivers the result as a
/// late one, which the server takes (no other result, batch still running): the run ends with
/// one result from the first attempt instead of being simulated again.
#[test]
fn a_worker_delivers_its_result_late_after_its_lease_expired() {
    let dir = tempfile::tempdir().unwrap();
    let mut service = Service::start(dir.path(), 1.0);
    let batch = service.submit(&replay_batch(2, 6.0));
    let worker = service.start_worker("late", &["--slots", "1"]);
    service.wait_for(&batch, Duration::from_secs(60), |s| {
        s["counts"]["running"].as_u64() == Some(1)
    });
    // Down for twice the lease: at restart the lease has expired and the timer reclaims it.
    service.kill_wait_restart(1.0, Duration::from_secs(2));
    let status = service.wait_finished(&batch, Duration::from_secs(120));
    assert_eq!(status["counts"]["completed"], 2, "{status}");
    let runs = runs(&service, &batch);
    assert!(
        runs.iter().all(|run| run["attempts"] == 1),
        "every result came from its first attempt (none simulated again): {runs:?}\n{}",
        worker.log_text()
    );
    let log = worker.log_text();
    assert!(
        log.contains("offered as a late result"),
        "the heartbeat 409 path was taken: {log}"
    );
}

#[test]
fn sigterm_releases_the_running_job_without_counting_an_attempt() {
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 30.0);
    let batch = service.submit(&replay_batch(2, 30.0));
    let mut worker = service.start_worker("stopping", &[]);
    service.wait_for(&batch, Duration::from_secs(60), |s| {
        s["counts"]["running"].as_u64() == Some(1)
    });
    let exit = worker.terminate(Duration::from_secs(20));
    assert!(
        exit.is_some_and(|s| s.success()),
        "worker exits cleanly on SIGTERM: {exit:?}\n{}",
        worker.log_text()
    );
    let status = service.get(&format!("/v1/batches/{batch}"));
    assert_eq!(
        status["counts"]["queued"], 2,
        "job released at once: {status}"
    );
    let runs = runs(&service, &batch);
    assert!(
        runs.iter().all(|r| r["attempts"] == 0),
        "release is not an attempt: {runs:?}"
    );
}

/// A run stuck without progress (the `table_lookup` test aid's `stall_s`: its thread sleeps,
/// deaf to cancels, as one hung in a GPU driver is): the worker's watchdog hands the job back
/// as this worker's failure and the worker exits with status 3 (restart me) at once, not after
/// the stuck thread; the service goes on with a healthy worker.
#[test]
fn a_worker_whose_run_stalls_hands_the_job_back_and_exits_for_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 30.0);
    let mut stuck = replay_batch(2, 0.0);
    stuck["experiment"]["spec"]["stall_s"] = serde_json::json!(120.0);
    let batch = service.submit(&stuck);
    let mut worker = service.start_worker("stalled", &["--stall-timeout", "1"]);
    let started = std::time::Instant::now();
    let mut exit = None;
    while started.elapsed() < Duration::from_secs(60) && exit.is_none() {
        exit = worker.child.try_wait().unwrap();
        std::thread::sleep(Duration::from_millis(100));
    }
    let log = worker.log_text();
    let exit = exit.unwrap_or_else(|| panic!("the stalled worker did not exit: {log}"));
    assert_eq!(exit.code(), Some(3), "{log}");
    assert!(started.elapsed() < Duration::from_secs(60));
    assert!(
        log.contains("no progress") && log.contains("start it again"),
        "{log}"
    );
    let runs = runs(&service, &batch);
    let tried: Vec<&Value> = runs.iter().filter(|r| r["attempts"] == 1).collect();
    assert_eq!(tried.len(), 1, "one run was leased: {runs:?}");
    assert_eq!(
        tried[0]["status"], "queued",
        "handed back to run again: {runs:?}"
    );
    let error = tried[0]["last_error"].as_str().unwrap_or_default();
    assert!(error.contains("no progress for"), "{runs:?}");

    // The service goes on: with the stuck batch cancelled, a healthy worker runs another.
    service.post(
        &format!("/v1/batches/{batch}/cancel"),
        &serde_json::json!({}),
    );
    let mut runs_fine = replay_batch(2, 0.0);
    runs_fine["name"] = serde_json::json!("fine");
    let fine = service.submit(&runs_fine);
    let _healthy = service.start_worker("healthy", &["--stall-timeout", "1"]);
    let status = service.wait_finished(&fine, Duration::from_secs(60));
    assert_eq!(status["state"], "completed", "{status}");
}

/// `repose up` whose only local worker's run stalls: the worker hands the job back and starts
/// again, so the job is tried until its attempts run out and the batch ends (its run dead,
/// naming the stall) instead of waiting for ever; `--exit-when-done` then exits.
#[test]
fn repose_up_starts_a_stalled_local_worker_again_and_the_batch_ends() {
    let dir = tempfile::tempdir().unwrap();
    let mut stuck = replay_batch(2, 0.0);
    stuck["experiment"]["spec"]["stall_s"] = serde_json::json!(120.0);
    let batch_file = dir.path().join("stuck.json");
    std::fs::write(&batch_file, stuck.to_string()).unwrap();
    let (out_path, err_path) = (dir.path().join("out.txt"), dir.path().join("err.txt"));
    let mut up = up_command(&dir.path().join("up.db"), 1)
        .args([
            "--stall-timeout",
            "1",
            "--max-attempts",
            "2",
            "--exit-when-done",
        ])
        .arg("--submit")
        .arg(&batch_file)
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .unwrap();
    // Two runs, two attempts each, a second a stall and 5 s before the retry.
    let (_, stdout, stderr) = exit_within(&mut up, 90, "repose up", &out_path, &err_path);
    assert!(
        stderr.contains("starting it again"),
        "the worker restarted: {stdout}\n{stderr}"
    );
    assert!(stderr.contains("no progress for"), "{stderr}");
}

/// Waits at most `seconds` for `child` to exit (else kills it and fails, saying `waiting_on`);
/// its exit status and what it wrote to `out` and `err`.
fn exit_within(
    child: &mut std::process::Child,
    seconds: u64,
    waiting_on: &str,
    out: &std::path::Path,
    err: &std::path::Path,
) -> (std::process::ExitStatus, String, String) {
    let read = |path: &std::path::Path| std::fs::read_to_string(path).unwrap_or_default();
    let deadline = std::time::Instant::now() + Duration::from_secs(seconds);
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return (status, read(out), read(err));
        }
        if std::time::Instant::now() > deadline {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!(
                "still waiting after {seconds} s: {waiting_on}\n{}\n{}",
                read(out),
                read(err)
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// `repose up` on `db` with `workers` local workers on any free port; the caller adds the rest.
fn up_command(db: &std::path::Path, workers: usize) -> std::process::Command {
    let mut command = std::process::Command::new(common::repose_bin());
    command
        .args(["up", "--listen", "127.0.0.1:0", "--workers"])
        .arg(workers.to_string())
        .arg("--db")
        .arg(db);
    command
}

/// `repose up` on `db`, submitting `batch` and exiting when it is done.
fn repose_up(
    db: &std::path::Path,
    batch: &std::path::Path,
    workers: usize,
) -> std::process::Output {
    up_command(db, workers)
        .arg("--exit-when-done")
        .arg("--submit")
        .arg(batch)
        .output()
        .unwrap()
}

#[test]
fn repose_up_killed_mid_batch_and_restarted_with_exit_when_done_finishes_the_batch() {
    // `repose up` is killed (SIGKILL) while its workers hold the batch's jobs on hour-long
    // leases; started again on the same database with --exit-when-done and nothing to submit,
    // it follows the unfinished batch to its end and exits cleanly. Its local workers come back
    // under the same ids, so the jobs they held return to the queue as they register: the
    // batch finishes in seconds, not after the leases run out.
    let stdout = kill_repose_up_holding_jobs_and_restart(1, 1);
    assert!(!stdout.contains("earlier start"), "{stdout}");
}

#[test]
fn repose_up_restarted_with_fewer_workers_takes_back_the_jobs_of_the_others() {
    // The same with two workers before the kill and one after: the second worker's id is not
    // started again, and its job still comes back at once.
    let stdout = kill_repose_up_holding_jobs_and_restart(2, 1);
    assert!(
        stdout.contains(
            "1 job(s) held by local workers of an earlier start that this one does not start \
             (--workers 1) are back in the queue"
        ),
        "{stdout}"
    );
}

/// Starts `repose up` with `before` workers and a batch of 3 two-second runs on hour-long
/// leases, kills it (SIGKILL) once each worker holds a job, starts it again with `after`
/// workers and --exit-when-done, and checks the batch ends in time with 3 results. Returns
/// the second start's stdout.
fn kill_repose_up_holding_jobs_and_restart(before: usize, after: usize) -> String {
    let dir = tempfile::tempdir().unwrap();
    let batch_file = dir.path().join("replay.json");
    std::fs::write(&batch_file, replay_batch(3, 2.0).to_string()).unwrap();
    let db = dir.path().join("up.db");
    let mut first = up_command(&db, before)
        .args(["--lease-s", "3600", "--submit"])
        .arg(&batch_file)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(first.stdout.take().unwrap()));
    let url = lines
        .by_ref()
        .map(Result::unwrap)
        .find_map(|l| {
            l.strip_prefix("repose up: server ")
                .and_then(|rest| rest.split(',').next())
                .map(str::to_owned)
        })
        .expect("the server's address");
    let submitted = lines
        .by_ref()
        .map(Result::unwrap)
        .find(|l| l.starts_with("submitted "))
        .expect("the batch is submitted");
    let tokens = std::fs::read_to_string(dir.path().join("up.db.tokens.env")).unwrap();
    let user = tokens
        .lines()
        .find_map(|l| l.strip_prefix("export REPOSE_TOKEN="))
        .unwrap()
        .to_owned();
    // Every worker holds a job before the kill.
    let http = reqwest::blocking::Client::new();
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    loop {
        let workers: Value = http
            .get(format!("{url}/v1/workers"))
            .bearer_auth(&user)
            .send()
            .and_then(|r| r.json())
            .unwrap();
        let busy = workers
            .as_array()
            .unwrap()
            .iter()
            .filter(|w| w["running_jobs"] == 1)
            .count();
        if busy == before {
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "the workers did not all take a job: {workers}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    first.kill().unwrap();
    first.wait().unwrap();

    // Output to files: a pipe nobody reads while we wait could fill and stall the process.
    let (out_path, err_path) = (dir.path().join("out.txt"), dir.path().join("err.txt"));
    let mut second = up_command(&db, after)
        .args(["--lease-s", "3600", "--exit-when-done"])
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .unwrap();
    // Three runs of 2 s: far less than this unless a job waits out its lease.
    let (status, stdout, stderr) = exit_within(
        &mut second,
        120,
        "a job held by the killed workers waits out its lease",
        &out_path,
        &err_path,
    );
    assert!(status.success(), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("following 1 unfinished batch(es)"),
        "{stdout}"
    );
    let id = submitted.split_whitespace().nth(4).unwrap();
    assert!(
        stdout.contains(&format!(
            "batch {id} (replay) Completed: 3 completed, 0 dead"
        )),
        "{submitted}\n{stdout}"
    );
    stdout
}

#[test]
fn repose_up_names_each_dead_run_and_why_it_failed() {
    // Four table rows and a fifth design point between two of them: the table has no row for
    // it, a permanent failure, so that run is dead at once; the others complete.
    let dir = tempfile::tempdir().unwrap();
    let mut batch = replay_batch(4, 0.0);
    batch["design"]["points"]
        .as_array_mut()
        .unwrap()
        .push(json!([1.5]));
    let batch_file = dir.path().join("replay.json");
    std::fs::write(&batch_file, batch.to_string()).unwrap();
    let out = repose_up(&dir.path().join("up.db"), &batch_file, 1);
    let stdout = common::stdout(&out);
    assert!(!out.status.success(), "a dead run is not a clean finish");
    assert!(stdout.contains("4 completed, 1 dead"), "{stdout}");
    let line = stdout
        .lines()
        .find(|l| l.trim_start().starts_with("dead run"))
        .unwrap_or_else(|| panic!("no dead-run line: {stdout}"));
    assert!(line.contains("x 1.5"), "{line}");
    assert!(line.contains("no row matching"), "{line}");
}

/// A `formula` batch of four runs at x = 0, 1, 2, 3 whose last run is in its failure region.
fn formula_batch_with_a_dead_run() -> Value {
    json!({
        "name": "formula",
        "experiment": {"kind": "formula", "spec": {
            "inputs": {"x": 0.0}, "responses": {"y": "10 + 2*x"}, "fails_when": "x > 2.5"}},
        "factors": [{"name": "x", "path": "inputs.x", "low": 0.0, "high": 3.0}],
        "design": {"type": "explicit", "points": [[0.0], [1.0], [2.0], [3.0]]},
        "response": "y",
        "model": "linear",
        "seed": 9
    })
}

#[test]
fn repose_up_logs_a_dead_run_once_and_without_colour_when_stderr_is_not_a_terminal() {
    // stderr is a pipe here: no colour escapes, even with NO_COLOR unset; and the dead run is
    // one line (the server's), not the local worker's copy of it as well.
    let dir = tempfile::tempdir().unwrap();
    let batch_file = dir.path().join("formula.json");
    std::fs::write(&batch_file, formula_batch_with_a_dead_run().to_string()).unwrap();
    let out = up_command(&dir.path().join("up.db"), 1)
        .env_remove("NO_COLOR")
        .env_remove("RUST_LOG")
        .arg("--exit-when-done")
        .arg("--submit")
        .arg(&batch_file)
        .output()
        .unwrap();
    let (stdout, stderr) = (common::stdout(&out), common::stderr(&out));
    assert!(stdout.contains("3 completed, 1 dead"), "{stdout}\n{stderr}");
    assert!(
        !out.stderr.contains(&0x1b),
        "escape codes in stderr: {stderr:?}"
    );
    // The run order is randomised: stdout's "dead run N (x 3): …" says which run it is.
    let index = stdout
        .lines()
        .find_map(|l| l.trim_start().strip_prefix("dead run "))
        .and_then(|rest| rest.split_whitespace().next())
        .unwrap_or_else(|| panic!("no dead run: {stdout}"));
    let dead: Vec<&str> = stderr.lines().filter(|l| l.contains("is dead")).collect();
    assert_eq!(dead.len(), 1, "one line for the dead run: {stderr}");
    assert!(
        dead[0].contains("WARN")
            && dead[0].contains(&format!("run {index} is dead"))
            && dead[0].contains("fails_when holds"),
        "{stderr}"
    );
    assert!(
        !stderr.contains("job failed"),
        "the worker's copy shows too: {stderr}"
    );
}

#[test]
fn repose_up_logs_a_reseeded_run_as_one_info_line_naming_it() {
    // A worker of the test's own (over HTTP) reports a seed-dependent failure (as an arch
    // is), then the result under the new seed; `repose up`'s stderr has one INFO line for the
    // reseed, naming the run, and no escape codes.
    let dir = tempfile::tempdir().unwrap();
    let batch_file = dir.path().join("replay.json");
    // The local worker holds its job long enough for the test's worker to do its part.
    std::fs::write(&batch_file, replay_batch(2, 4.0).to_string()).unwrap();
    let err_path = dir.path().join("err.txt");
    let mut up = up_command(&dir.path().join("up.db"), 1)
        .env_remove("NO_COLOR")
        .env_remove("RUST_LOG")
        .args(["--exit-when-done", "--submit"])
        .arg(&batch_file)
        .stdout(std::process::Stdio::piped())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(up.stdout.take().unwrap()));
    let url = lines
        .by_ref()
        .map(Result::unwrap)
        .find_map(|l| {
            l.strip_prefix("repose up: server ")
                .and_then(|rest| rest.split(',').next())
                .map(str::to_owned)
        })
        .expect("the server's address");
    // Drain stdout in the background so `repose up` never blocks on a full pipe.
    let drained = std::thread::spawn(move || lines.map_while(Result::ok).collect::<Vec<_>>());
    let tokens = std::fs::read_to_string(dir.path().join("up.db.tokens.env")).unwrap();
    let token = |name: &str| {
        tokens
            .lines()
            .find_map(|l| l.strip_prefix(&format!("export {name}=")))
            .unwrap()
            .to_owned()
    };
    let (user, worker) = (token("REPOSE_TOKEN"), token("REPOSE_WORKER_TOKEN"));
    let http = reqwest::blocking::Client::new();
    let post = |path: &str, body: Value| -> (u16, Value) {
        let reply = http
            .post(format!("{url}{path}"))
            .bearer_auth(&worker)
            .json(&body)
            .send()
            .unwrap();
        let status = reply.status().as_u16();
        (status, reply.json().unwrap_or(Value::Null))
    };
    // The local worker holds one job first, so the other is ours, before and after the reseed.
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while !http
        .get(format!("{url}/v1/workers"))
        .bearer_auth(&user)
        .send()
        .and_then(|r| r.json::<Value>())
        .unwrap()
        .as_array()
        .unwrap()
        .iter()
        .any(|w| w["running_jobs"] == 1)
    {
        assert!(
            std::time::Instant::now() < deadline,
            "the local worker took no job"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let me = "6f1c1c4e-8d2a-4c47-9a5e-2f6a3c1d0b01";
    let (status, body) = post(
        "/v1/workers/register",
        json!({"instance_id": me, "host": "test", "threads": 1,
               "version": repose_api::version::RELEASE}),
    );
    assert_eq!(status, 200, "{body}");
    let claim = || {
        let (status, job) = post("/v1/jobs/claim", json!({"worker_id": me, "wait_s": 5.0}));
        assert_eq!(status, 200, "{job}");
        job
    };
    let job = claim();
    let (status, body) = post(
        &format!("/v1/jobs/{}/fail", job["job_id"].as_str().unwrap()),
        json!({"lease_token": job["lease_token"], "error": "grains arched over the outlet",
               "another_seed": true}),
    );
    assert_eq!(status, 200, "{body}");
    let again = claim();
    assert_eq!(again["run_id"], job["run_id"], "{again}");
    assert_ne!(again["seed"], job["seed"], "{again}");
    let (status, body) = post(
        &format!("/v1/jobs/{}/complete", again["job_id"].as_str().unwrap()),
        json!({"lease_token": again["lease_token"], "metrics": {"y": 11.0},
               "wall_time_s": 0.1}),
    );
    assert_eq!(status, 200, "{body}");
    let runs: Value = http
        .get(format!(
            "{url}/v1/batches/{}/runs",
            job["batch_id"].as_str().unwrap()
        ))
        .bearer_auth(&user)
        .send()
        .and_then(|r| r.json())
        .unwrap();
    let index = runs
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["id"] == job["run_id"])
        .unwrap()["run_index"]
        .clone();

    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    while up.try_wait().unwrap().is_none() {
        assert!(
            std::time::Instant::now() < deadline,
            "repose up did not finish"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let stdout = drained.join().unwrap().join("\n");
    let stderr = std::fs::read(&err_path).unwrap();
    let text = String::from_utf8_lossy(&stderr);
    assert!(up.wait().unwrap().success(), "{stdout}\n{text}");
    assert!(!stderr.contains(&0x1b), "escape codes in stderr: {text:?}");
    let reseeds: Vec<&str> = text.lines().filter(|l| l.contains("arched")).collect();
    assert_eq!(reseeds.len(), 1, "one line for the reseed: {text}");
    assert!(
        reseeds[0].contains("INFO")
            && reseeds[0].contains(&format!(
                "run {index} runs again under seed {}",
                again["seed"]
            )),
        "{text}"
    );
}

#[test]
fn repose_up_runs_a_submitted_batch_to_its_analysis_and_writes_the_tokens() {
    let dir = tempfile::tempdir().unwrap();
    let batch_file = dir.path().join("replay.json");
    std::fs::write(&batch_file, replay_batch(4, 0.0).to_string()).unwrap();
    let db = dir.path().join("up.db");
    let out = repose_up(&db, &batch_file, 2);
    let stdout = common::stdout(&out);
    assert!(out.status.success(), "{stdout}\n{}", common::stderr(&out));
    assert!(
        stdout.contains("Completed: 4 completed, 0 dead"),
        "{stdout}"
    );
    assert!(
        stdout.contains("ANOVA"),
        "the analysis is printed: {stdout}"
    );
    let tokens = std::fs::read_to_string(dir.path().join("up.db.tokens.env")).unwrap();
    assert!(tokens.contains("export REPOSE_TOKEN=rp_user_"), "{tokens}");
    assert!(
        tokens.contains("export REPOSE_WORKER_TOKEN=rp_worker_"),
        "{tokens}"
    );
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(dir.path().join("up.db.tokens.env"))
            .unwrap()
            .permissions()
            .mode();
        assert_eq!(mode & 0o077, 0, "tokens file is private: {mode:o}");
    }

    // A restart on the same database is the same user (who alone may cancel the batches it
    // submitted before), until that token is revoked.
    let up_again = || {
        let out = repose_up(&db, &batch_file, 1);
        assert!(out.status.success(), "{}", common::stderr(&out));
        std::fs::read_to_string(dir.path().join("up.db.tokens.env")).unwrap()
    };
    let secrets = |text: &str| -> Vec<String> {
        text.lines()
            .filter(|l| l.contains("_TOKEN="))
            .map(str::to_owned)
            .collect()
    };
    assert_eq!(
        secrets(&up_again()),
        secrets(&tokens),
        "a restart keeps its tokens"
    );
    let user = tokens
        .lines()
        .find_map(|l| l.strip_prefix("export REPOSE_TOKEN="))
        .unwrap();
    let listed = repose(&["token", "list", "--db", db.to_str().unwrap()]);
    let name = common::stdout(&listed)
        .lines()
        .find(|l| l.starts_with("local-user-"))
        .and_then(|l| l.split_whitespace().next())
        .unwrap()
        .to_owned();
    let revoked = repose(&["token", "revoke", &name, "--db", db.to_str().unwrap()]);
    assert!(revoked.status.success(), "{}", common::stderr(&revoked));
    let fresh = up_again();
    assert_ne!(fresh, tokens);
    assert!(
        !fresh.contains(user),
        "a revoked token is not reused: {fresh}"
    );
}

#[test]
fn submit_status_and_watch_talk_to_the_server() {
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 30.0);
    let batch_file = dir.path().join("replay.json");
    std::fs::write(&batch_file, replay_batch(3, 0.0).to_string()).unwrap();
    let cli = |args: &[&str]| {
        std::process::Command::new(common::repose_bin())
            .args(args)
            .env("REPOSE_SERVER", &service.url)
            .env("REPOSE_TOKEN", &service.user_token)
            .output()
            .unwrap()
    };
    let submitted = cli(&["submit", batch_file.to_str().unwrap()]);
    assert!(submitted.status.success(), "{}", common::stderr(&submitted));
    let id = common::stdout(&submitted)
        .split_whitespace()
        .next()
        .unwrap()
        .to_owned();
    let listed = cli(&["status"]);
    assert!(
        common::stdout(&listed).contains(&id),
        "{}",
        common::stdout(&listed)
    );
    let _worker = service.start_worker("worker", &[]);
    let watched = cli(&["watch", &id, "--interval-s", "0.2"]);
    assert!(watched.status.success(), "{}", common::stderr(&watched));
    assert!(
        common::stdout(&watched).contains("Coefficients"),
        "{}",
        common::stdout(&watched)
    );

    // A bad batch file is one line naming the field, exit status 2.
    std::fs::write(&batch_file, r#"{"name": "x"}"#).unwrap();
    let refused = cli(&["submit", batch_file.to_str().unwrap()]);
    assert_eq!(refused.status.code(), Some(2));
    assert!(
        common::stderr(&refused).contains("422"),
        "{}",
        common::stderr(&refused)
    );
    // Without a token the server says 401.
    let anonymous = std::process::Command::new(common::repose_bin())
        .args(["status", "--server", &service.url])
        .env_remove("REPOSE_TOKEN")
        .output()
        .unwrap();
    assert_eq!(anonymous.status.code(), Some(2));
    assert!(
        common::stderr(&anonymous).contains("401"),
        "{}",
        common::stderr(&anonymous)
    );
}

/// The whole calibration on the real DEM engine, at a resolution CI can afford: three candidate
/// factors, ≈ 1 150-grain heaps, two worker processes. The campaign must end with a verified
/// optimum within its tolerance (±10 % at this resolution).
///
/// Out of the default run since the rest rule of issue 13c (a heap must stop creeping, not
/// only dip below the kinetic-energy threshold): its μr 0.4 corner creeps to the fast preset's
/// 2.5 s cap, and the test took 507 s of a 22-minute CI run (2026-11-24; it passed). The
/// two-target campaign below still takes a campaign through the real engine and two worker
/// processes in every CI run. Run it with
/// `cargo test -p repose --test cli -- --ignored service::a_campaign_on_the_dem_engine`.
#[test]
#[ignore = "about 8 minutes on 2 cores since the issue-13c rest rule; the two-target DEM campaign runs in CI"]
fn a_campaign_on_the_dem_engine_runs_through_two_workers_to_a_verified_optimum() {
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 60.0);
    let _a = service.start_worker("worker-a", &[]);
    let _b = service.start_worker("worker-b", &[]);
    // Seeds are fixed, and the engine is deterministic, so this campaign takes the same path
    // on every machine; a change in the engine or the campaign rules can move it.
    let campaign = json!({
        "name": "CI calibration",
        "experiment": {"kind": "aor", "preset": "fast", "spec": {"total_mass": 0.025}},
        "factors": [
            {"name": "mu_s", "path": "soil_soil.static_friction", "low": 0.4, "high": 0.6},
            {"name": "mu_r", "path": "soil_soil.rolling_friction", "low": 0.15, "high": 0.4},
            {"name": "mu_w", "path": "soil_steel.static_friction", "low": 0.3, "high": 0.6}
        ],
        "target": 30.0,
        "tolerance": {"relative_pct": 10},
        "seed": 7,
        "screening": {"design": {"type": "factorial"}},
        "steepest": {"points_per_dispatch": 4, "max_points": 8},
        "response_surface": {"design": {"type": "box_behnken", "centre_points": 3}},
        "verification": {"replicates": 2}
    });
    let created = service.post("/v1/campaigns", &campaign);
    let id = created["id"].as_str().unwrap().to_owned();
    let deadline = std::time::Instant::now() + Duration::from_secs(1500);
    let view = loop {
        let view = service.get(&format!("/v1/campaigns/{id}"));
        if view["status"] != "running" {
            break view;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "campaign still running: {view:#}"
        );
        std::thread::sleep(Duration::from_secs(1));
    };
    assert_eq!(view["status"], "finished", "{view:#}");
    let result = &view["result"];
    assert_eq!(result["within_tolerance"], true, "{view:#}");
    let error = result["verified_relative_error_pct"].as_f64().unwrap();
    assert!(error <= 10.0, "{error}");
    let report = service.get_text(&format!("/v1/campaigns/{id}/report"));
    assert!(report.contains("Provenance"), "report served");
    // The real worker sent the verification pile's picture (the batch keeps pictures) and
    // the engine version of every result.
    assert!(
        report.contains("<img alt=\"Verification pile\""),
        "verification pile in the report"
    );
    let json_report = service.get(&format!("/v1/campaigns/{id}/report?format=json"));
    for p in json_report["provenance"].as_array().unwrap() {
        if p["status"] == "completed" {
            assert!(p["engine_version"].is_string(), "{p}");
        }
    }
}

/// Two targets on the real DEM engine through the server and two worker processes: the angle
/// of repose (`aor`, fast preset, 25 g) and the shear test's cohesion (`shear`, fast preset at
/// two normal stresses, sheared 3 mm), calibrated together by the overall desirability over
/// soil-soil static friction and the linear cohesion energy density. Every stage issues one
/// batch per experiment; the campaign must end verified with each response within its own
/// tolerance.
///
/// The targets are what this resolution can reach, not the paper's: the fast funnel holds up
/// grains with cohesion (measured at μs 0.45, seed 1: 3e4 J/m³ keeps 12.6 of the 25 g in the
/// funnel, 6e4 16.1 g and 1.5e5 23.6 g, which leaves no flank to measure), so the cohesion stays
/// within 0..2e4 J/m³; there the heap angle scatters by about 5° from seed to seed (μs 0.45,
/// 1.5e4, seeds 1-4: 19.8-31.2°), hence 24° ± 20 % and three verification replicates; and the
/// fast two-stress shear test reads an intercept of about -0.1 to 0.7 kPa whatever the
/// cohesion (its noise, not the cohesion, decides), so the cohesion target is 0.5 ± 0.25 kPa.
/// The target is the box's reading (`box_cohesion_kpa`), not the soil's (`cohesion_kpa`, the
/// measurement window's): in a box 11 grains across sheared 3 mm the window is 6 grains wide,
/// and its intercept follows the friction, not the cohesion (μs 0.3 / 0.6 at 0 and 2e4 J/m³:
/// 0.72, 0.66 / 1.29, 1.41 kPa). This test shows the two-target machinery on the real engine,
/// not a calibrated cohesion.
/// The same machinery runs in the default suite on the `formula` kind
/// ([`a_two_target_campaign_runs_through_two_worker_processes_to_a_verified_optimum`]).
/// With its printout: `cargo test -p repose --test cli service::a_two_target_campaign_on_the_dem -- --ignored --nocapture`.
#[test]
#[ignore = "about 4 minutes of both cores; the same machinery runs on the formula kind in the default suite"]
fn a_two_target_campaign_on_the_dem_engine_runs_through_two_workers_to_a_verified_optimum() {
    // The factor `soil_soil.cohesion.energy_density` is written into both specs, so both name
    // the linear law (at zero, overwritten by every run's value).
    let linear = json!({"model": "linear", "energy_density": 0.0});
    let aor = json!({"kind": "aor", "preset": "fast", "spec": {
        "total_mass": 0.025,
        "soil_soil": {"cohesion": linear}
    }});
    let shear = json!({"kind": "shear", "preset": "fast", "spec": {
        "normal_stresses_kpa": [4.0, 8.0],
        "shear": {"displacement": 0.003},
        "soil_soil": {"cohesion": linear}
    }});
    let campaign = two_target_campaign(
        aor,
        shear,
        [
            "soil_soil.static_friction",
            "soil_soil.cohesion.energy_density",
        ],
    );
    two_target_campaign_through_two_workers(&campaign);
}

/// Two targets of two experiments through the server and two worker processes, by the chain:
/// closed-form responses (`formula`, with noise) standing for the heap angle and the box
/// cohesion over the same two factors and targets as the DEM campaign above. Every stage
/// issues one batch per experiment, and the campaign must end verified with each response
/// within its own tolerance.
#[test]
fn a_two_target_campaign_runs_through_two_worker_processes_to_a_verified_optimum() {
    let formula = |response: &str, expression: &str, noise: f64| {
        json!({"kind": "formula", "spec": {
            "inputs": {"mu_s": 0.0, "ced": 0.0},
            "responses": {response: expression},
            "noise_sd": {response: noise}
        }})
    };
    let campaign = two_target_campaign(
        formula("angle_deg", "12 + 25*mu_s + 1.5e-4*ced", 0.5),
        formula("box_cohesion_kpa", "0.1 + 3e-5*ced + 0.3*mu_s", 0.03),
        ["inputs.mu_s", "inputs.ced"],
    );
    two_target_campaign_through_two_workers(&campaign);
}

/// The two-target chain campaign of the two tests above: experiments `aor` and `shear`, the
/// angle 24° ± 20 % and the box cohesion 0.5 ± 0.25 kPa, over soil-soil static friction
/// (0.3-0.6) and a cohesion energy density (0-2e4 J/m³) written at `paths`.
fn two_target_campaign(aor: Value, shear: Value, paths: [&str; 2]) -> Value {
    json!({
        "name": "two-target calibration",
        "experiments": {"aor": aor, "shear": shear},
        "targets": [
            {"response": "aor.angle_deg", "target": 24.0, "tolerance": {"relative_pct": 20}},
            {"response": "shear.box_cohesion_kpa", "target": 0.5, "tolerance": {"absolute": 0.25}}
        ],
        "factors": [
            {"name": "mu_s", "path": paths[0], "low": 0.3, "high": 0.6},
            {"name": "ced", "path": paths[1], "low": 0.0, "high": 2.0e4}
        ],
        "seed": 11,
        "screening": {"design": {"type": "factorial"}},
        "steepest": {"points_per_dispatch": 2, "max_points": 4, "start": "centre"},
        "response_surface": {"design": {"type": "box_behnken", "centre_points": 1}},
        "verification": {"replicates": 3}
    })
}

/// Runs `campaign` (targets `aor.angle_deg` and `shear.box_cohesion_kpa`) on a fresh service
/// with two worker processes and checks it ends verified, one batch per experiment per stage.
fn two_target_campaign_through_two_workers(campaign: &Value) {
    let started = std::time::Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 120.0);
    let _a = service.start_worker("worker-a", &[]);
    let _b = service.start_worker("worker-b", &[]);
    let created = service.post("/v1/campaigns", campaign);
    let id = created["id"].as_str().unwrap().to_owned();
    let deadline = std::time::Instant::now() + Duration::from_secs(3600);
    let view = loop {
        let view = service.get(&format!("/v1/campaigns/{id}"));
        if view["status"] != "running" {
            break view;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "campaign still running: {view:#}"
        );
        std::thread::sleep(Duration::from_secs(2));
    };
    eprintln!(
        "two-target campaign: {:.0} s",
        started.elapsed().as_secs_f64()
    );
    eprintln!("{:#}", view["result"]);
    if view["status"] != "finished" {
        // Say which runs were lost and why, not only that the campaign stopped.
        let mut lost = String::new();
        for batch in view["batch_list"].as_array().into_iter().flatten() {
            let runs = service.get(&format!(
                "/v1/batches/{}/runs",
                batch["batch_id"].as_str().unwrap()
            ));
            for run in runs.as_array().into_iter().flatten() {
                if run["status"] != "completed" {
                    lost += &format!(
                        "{} batch {} row {}: {} {} {}\n",
                        batch["stage"],
                        batch["index"],
                        run["design_row"],
                        run["status"],
                        run["factors"],
                        run["last_error"]
                    );
                }
            }
        }
        panic!("campaign {}:\n{lost}{view:#}", view["status"]);
    }
    let result = &view["result"];
    let checks = result["targets"].as_array().unwrap();
    let responses: Vec<&str> = checks
        .iter()
        .map(|c| c["response"].as_str().unwrap())
        .collect();
    assert_eq!(responses, ["aor.angle_deg", "shear.box_cohesion_kpa"]);
    for check in checks {
        assert_eq!(check["within_tolerance"], true, "{check}");
    }
    assert_eq!(result["within_tolerance"], true, "{view:#}");
    let calibrated: Vec<&str> = result["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["calibrated"] == true)
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    assert!(!calibrated.is_empty(), "{result}");
    // One batch per experiment per stage: every stage ran an `aor` and a `shear` batch (the
    // experiment's key ends the batch's name, `… [aor]`).
    let mut kinds: Vec<(String, String)> = view["batch_list"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| {
            let batch = service.get(&format!("/v1/batches/{}", b["batch_id"].as_str().unwrap()));
            let name = batch["name"].as_str().unwrap();
            let key = name
                .rsplit_once(" [")
                .map_or("", |(_, k)| k.trim_end_matches(']'));
            (b["stage"].as_str().unwrap().to_owned(), key.to_owned())
        })
        .collect();
    kinds.sort();
    kinds.dedup();
    for stage in ["screening", "verification"] {
        for kind in ["aor", "shear"] {
            assert!(
                kinds.contains(&(stage.to_owned(), kind.to_owned())),
                "{stage} {kind}: {kinds:?}"
            );
        }
    }
    let report = service.get_text(&format!("/v1/campaigns/{id}/report"));
    assert!(
        report.contains("shear.box_cohesion_kpa"),
        "report names both responses"
    );
    assert!(report.contains("aor.angle_deg"));
}

/// `repose backup` copies the live database mid-batch; the server is then lost (SIGKILL) and a
/// server started on the copy finishes the batch with new workers. Results stored before the
/// backup are kept; runs finished after it are simulated again.
#[test]
fn repose_backup_mid_batch_restores_to_a_server_that_finishes_the_batch() {
    let dir = tempfile::tempdir().unwrap();
    let mut service = Service::start(dir.path(), 2.0);
    let batch = service.submit(&replay_batch(8, 0.5));
    let mut first = service.start_worker("before-backup", &[]);
    service.wait_for(&batch, Duration::from_secs(60), |s| {
        s["counts"]["completed"].as_u64().unwrap_or(0) >= 2
    });
    let copy = dir.path().join("backup.db");
    let out = repose(&[
        "backup",
        "--db",
        service.db.to_str().unwrap(),
        "--out",
        copy.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && stdout.contains("integrity ok"),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let at_backup: Vec<Value> = runs(&service, &batch)
        .into_iter()
        .filter(|r| r["status"] == "completed")
        .collect();
    assert!(!at_backup.is_empty());
    first.kill();
    service.kill_and_restart_on(&copy, 2.0);

    let _second = service.start_worker("after-restore", &[]);
    let status = service.wait_finished(&batch, Duration::from_secs(120));
    assert_eq!(status["state"], "completed", "{status}");
    assert_eq!(status["counts"]["completed"], 8, "{status}");
    let restored = runs(&service, &batch);
    for run in &restored {
        let x = run["factors"][0]["natural"].as_f64().unwrap();
        assert_eq!(run["metrics"]["y"].as_f64(), Some(10.0 + 2.0 * x), "{run}");
    }
    // Runs completed at the backup kept their first result (and its worker).
    for old in &at_backup {
        let now = restored.iter().find(|r| r["id"] == old["id"]).unwrap();
        assert_eq!(now["worker_id"], old["worker_id"], "{now}");
        assert_eq!(now["attempts"], old["attempts"], "{now}");
    }
    let analysis = service.get(&format!("/v1/batches/{batch}/analysis"));
    assert_eq!(analysis["runs_used"], 8);
}

#[test]
fn repose_up_refuses_bad_settings_naming_the_flag_before_starting() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("up.db");
    for (flag, value) in [
        ("--max-attempts", "0"),
        ("--workers", "0"),
        ("--lease-s", "0"),
    ] {
        let out = std::process::Command::new(common::repose_bin())
            .args(["up", "--listen", "127.0.0.1:0", "--db"])
            .arg(&db)
            .args([flag, value])
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "{flag} {value}");
        let stderr = common::stderr(&out);
        assert!(stderr.contains(flag), "{flag}: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "{flag}: {stderr}");
    }
    assert!(!db.exists(), "nothing is created for a refused command");
}

#[test]
fn a_worker_id_that_is_not_a_uuid_is_refused_naming_the_flag() {
    let out = common::repose(&["worker", "--instance-id", "worker-7"]);
    assert_eq!(out.status.code(), Some(2));
    let stderr = common::stderr(&out);
    assert!(stderr.contains("--instance-id"), "{stderr}");
    assert!(stderr.contains("worker-7"), "{stderr}");
}

/// Waits (up to 2 min) until `dir` holds a checkpoint file.
fn wait_for_a_checkpoint(dir: &std::path::Path) {
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    while checkpoint_files(dir) == 0 {
        assert!(
            std::time::Instant::now() < deadline,
            "no checkpoint after 2 min"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// How many checkpoint files `dir` holds (none if it does not exist).
fn checkpoint_files(dir: &std::path::Path) -> usize {
    std::fs::read_dir(dir).map_or(0, |d| {
        d.filter_map(Result::ok)
            .filter(|e| e.path().extension().is_some_and(|x| x == "checkpoint"))
            .count()
    })
}

/// A one-run angle-of-repose batch on the GPU: the small funnel of the GPU tests (about 560
/// grains of 4 mm poured through a 40 mm outlet onto a 15 cm plate, seconds on lavapipe).
fn small_gpu_aor_batch() -> Value {
    json!({
        "name": "GPU AOR",
        "experiment": {
            "kind": "aor",
            "backend": "gpu",
            "preset": "fast",
            "spec": {
                "particle": {"radius": 0.002},
                "total_mass": 0.05,
                "mass_rate": 0.25,
                "funnel": {"outlet_diameter": 0.04},
                "base": {"size": 0.15},
                "materials": {"soil": {"youngs_modulus": 1e6}},
                "soil_soil": {"rolling_friction": 0.3},
                "settle": {"min_time": 0.1, "check_interval": 0.05, "creep_window_s": 0.15},
                "time_cap": 1.5
            }
        },
        "factors": [
            {"name": "mu_s", "path": "soil_soil.static_friction", "low": 0.4, "high": 0.5}
        ],
        "design": {"type": "explicit", "points": [[0.442]]},
        "response": "angle_deg",
        "model": "none",
        "seed": 3
    })
}

/// `repose worker --gpu` (issue 38): without an adapter the worker stops at start naming the
/// problem (never a CPU-only worker). A `"backend": "gpu"` batch submitted while no worker has
/// a GPU says so in `repose status` (issue 49). A worker with GPU slots (`--gpu-slots 2`, on
/// lavapipe in CI) registers its adapter and slots, the batch's run goes to it and not to the
/// CPU-only worker beside it, and the result's provenance names the GPU. Where no adapter can
/// be opened at all the rest is skipped with a message (`REPOSE_REQUIRE_GPU=1` makes that a
/// failure).
#[test]
fn a_gpu_batch_runs_on_the_worker_that_opened_a_gpu_and_its_result_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let service = Service::start(dir.path(), 30.0);
    let wait_exit = |worker: &mut common::service::Proc| {
        let deadline = std::time::Instant::now() + Duration::from_secs(60);
        loop {
            if let Some(status) = worker.child.try_wait().unwrap() {
                return Some(status);
            }
            if std::time::Instant::now() > deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    let mut no_adapter = service.start_worker_with(
        "no-adapter",
        &[],
        &["--gpu"],
        &[("WGPU_ADAPTER_NAME", "no-such-adapter")],
    );
    let status = wait_exit(&mut no_adapter).expect("a --gpu worker without an adapter exits");
    assert!(!status.success());
    let log = no_adapter.log_text();
    assert!(
        log.contains("--gpu") && log.contains("no GPU adapter"),
        "{log}"
    );
    assert!(service.get("/v1/workers").as_array().unwrap().is_empty());

    let batch = service.submit(&small_gpu_aor_batch());
    let status = std::process::Command::new(common::repose_bin())
        .args(["status", "--server", &service.url])
        .env("REPOSE_TOKEN", &service.user_token)
        .output()
        .unwrap();
    assert!(status.status.success(), "{}", common::stderr(&status));
    let listed = common::stdout(&status);
    assert!(
        listed.contains("waiting for a GPU worker: none registered in the last 10 min"),
        "{listed}"
    );

    let _cpu = service.start_worker("cpu-worker", &[]);
    let mut gpu = service.start_worker("gpu-worker", &["--slots", "0", "--gpu-slots", "2"]);
    // Registered with its adapter, or stopped because there is none.
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    let gpu_worker = loop {
        let workers = service.get("/v1/workers");
        if let Some(w) = workers
            .as_array()
            .unwrap()
            .iter()
            .find(|w| w["gpu"].is_string())
        {
            break w.clone();
        }
        if gpu.child.try_wait().unwrap().is_some() {
            let log = gpu.log_text();
            assert!(common::skipped_without_gpu(&log), "{log}");
            return;
        }
        assert!(std::time::Instant::now() < deadline, "{}", gpu.log_text());
        std::thread::sleep(Duration::from_millis(100));
    };
    let adapter = gpu_worker["gpu"].as_str().unwrap();
    assert_eq!(gpu_worker["gpu_slots"], 2, "{gpu_worker}");

    let status = service.wait_finished(&batch, Duration::from_secs(300));
    assert_eq!(status["state"], "completed", "{status}");
    let runs = runs(&service, &batch);
    assert_eq!(runs.len(), 1);
    let run = &runs[0];
    assert_eq!(run["status"], "completed", "{run}\n{}", gpu.log_text());
    assert_eq!(run["worker_id"], gpu_worker["id"], "{run}");
    let engine = run["engine_version"].as_str().unwrap();
    assert!(engine.contains(&format!("+gpu:{adapter}")), "{engine}");
    let angle = run["metrics"]["angle_deg"].as_f64().unwrap();
    assert!((5.0..60.0).contains(&angle), "{run}");
}
