//! `repose_server::backup`: a copy taken mid-batch while the server runs restores to a server
//! that finishes the batch.

use crate::common;

use std::collections::HashMap;
use std::time::Duration;

use common::{batch_request, run_fake_worker, temp_db, TestServer};
use repose_api::{BatchState, RunState};
use repose_server::{backup, BackupError};
use reqwest::StatusCode;
use serde_json::json;

fn migrations_in_tree() -> i64 {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../migrations");
    std::fs::read_dir(dir)
        .unwrap()
        .filter(|entry| {
            entry
                .as_ref()
                .is_ok_and(|e| e.path().extension().is_some_and(|x| x == "sql"))
        })
        .count() as i64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_backup_taken_mid_batch_restores_to_a_server_that_finishes_the_batch() {
    let (dir, db) = temp_db();
    let lease = Duration::from_secs(2);
    let server = TestServer::start(&db, |c| c.lease = lease).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 3))
        .await;
    assert_eq!(batch.run_count, 12);
    let worker = server.register().await;
    for _ in 0..5 {
        let job = server.claim(worker, 0.0).await.unwrap();
        let (status, body) = server.complete(&job).await;
        assert_eq!(status, StatusCode::OK, "{body}");
    }
    // One run is being simulated when the backup is taken.
    let in_flight = server.claim(worker, 0.0).await.unwrap();
    let before = server.runs(batch.id).await;

    let out_dir = dir.path().join("backups");
    std::fs::create_dir(&out_dir).unwrap();
    let out = out_dir.join("repose-copy.sqlite");
    let report = backup(&db, &out)
        .await
        .expect("backup of the live database");
    assert_eq!(report.path, out);
    assert_eq!(report.bytes, std::fs::metadata(&out).unwrap().len());
    assert_eq!(report.migrations, migrations_in_tree());
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&out).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600, "the copy is private like the database");
    }
    let left: Vec<_> = std::fs::read_dir(&out_dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("repose-copy.sqlite")]);

    // The live server keeps working; what it stores now is not in the copy.
    let (status, body) = server.complete(&in_flight).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    for _ in 0..2 {
        let job = server.claim(worker, 0.0).await.unwrap();
        assert_eq!(server.complete(&job).await.0, StatusCode::OK);
    }
    assert_eq!(server.status(batch.id).await.summary.counts.completed, 8);
    server.stop().await;

    // Restore: a new server on the copy sees the batch as it was at the backup.
    let restored = TestServer::start(&out, |c| c.lease = lease).await;
    let status = restored.status(batch.id).await;
    assert_eq!(status.summary.state, BatchState::Active);
    assert_eq!(status.summary.counts.completed, 5, "{status:?}");
    assert_eq!(
        status.summary.counts.running + status.summary.counts.queued,
        7,
        "{status:?}"
    );
    // The in-flight run's lease expires (it was granted before the backup), and it is leased
    // again with the six queued ones.
    let done = run_fake_worker(&restored, 5.0).await;
    assert_eq!(done, 7);
    let analysis = restored.wait_for_analysis(batch.id).await;
    assert_eq!(analysis.error, None);
    assert_eq!(analysis.runs_used, 12);
    let status = restored.status(batch.id).await;
    assert_eq!(status.summary.state, BatchState::Completed);
    assert_eq!(status.summary.counts.completed, 12);

    let earlier: HashMap<_, _> = before.iter().map(|run| (run.id, run)).collect();
    for run in restored.runs(batch.id).await {
        assert_eq!(run.status, RunState::Completed, "{run:?}");
        let old = earlier[&run.id];
        if old.status == RunState::Completed {
            assert_eq!(
                run.metrics, old.metrics,
                "results before the backup are kept"
            );
            assert_eq!(run.attempts, 1);
        } else if run.id == in_flight.run_id {
            assert_eq!(run.attempts, 2, "the in-flight run was leased again");
        } else {
            assert_eq!(run.attempts, 1);
        }
    }
    restored.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_backup_under_concurrent_writes_is_consistent_and_replaces_the_old_copy() {
    let (dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let batch = server
        .submit(&batch_request(json!({"type": "factorial"}), "linear", 10))
        .await;
    let out = dir.path().join("copy.sqlite");
    std::fs::write(&out, b"an older backup").unwrap();
    // A worker completes runs while backups are taken.
    let working = run_fake_worker(&server, 0.5);
    let backing_up = async {
        let mut reports = Vec::new();
        for _ in 0..5 {
            reports.push(backup(&db, &out).await.expect("backup"));
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        reports
    };
    let (done, reports) = tokio::join!(working, backing_up);
    assert_eq!(done, 40);
    assert!(reports.iter().all(|r| r.bytes > 0));
    server.stop().await;

    // The last copy opens as a server and holds a consistent state of the batch.
    let restored = TestServer::start(&out, |_| {}).await;
    let status = restored.status(batch.id).await;
    let counts = status.summary.counts;
    assert_eq!(counts.completed + counts.running + counts.queued, 40);
    let runs = restored.runs(batch.id).await;
    let with_result = runs.iter().filter(|r| r.metrics.is_some()).count() as u64;
    assert_eq!(
        with_result, counts.completed,
        "every completed run has its result"
    );
    restored.stop().await;
}

#[tokio::test]
async fn a_backup_refuses_its_own_database_and_files_that_are_not_repose_databases() {
    let (dir, db) = temp_db();
    let server = TestServer::start(&db, |_| {}).await;
    let err = backup(&db, &db).await.unwrap_err();
    assert!(matches!(err, BackupError::SameFile(_)), "{err}");
    server.stop().await;

    let missing = dir.path().join("missing.sqlite");
    let err = backup(&missing, &dir.path().join("x.sqlite"))
        .await
        .unwrap_err();
    assert!(matches!(err, BackupError::Missing(_)), "{err}");
    assert!(!missing.exists(), "a backup never creates its source");

    let garbage = dir.path().join("garbage.sqlite");
    std::fs::write(&garbage, vec![0x5a_u8; 8192]).unwrap();
    let err = backup(&garbage, &dir.path().join("z.sqlite"))
        .await
        .unwrap_err();
    assert!(matches!(err, BackupError::Open { .. }), "{err}");

    let other = dir.path().join("other.sqlite");
    std::fs::write(&other, b"").unwrap();
    let err = backup(&other, &dir.path().join("y.sqlite"))
        .await
        .unwrap_err();
    assert!(err.to_string().contains("not a repose database"), "{err}");
    assert!(!dir.path().join("y.sqlite").exists());
}
