//! `repose backup`: a consistent copy of a database while the server keeps running.
//!
//! SQLite's `VACUUM INTO` reads the source inside one read transaction, so the copy is the
//! database as of one instant (WAL readers never block the server's writer, and the writer
//! never blocks them). The copy is written to a temporary file beside the destination (0600),
//! checked with `PRAGMA integrity_check`, synced, and only then renamed over the destination:
//! a crash or a failure leaves either the previous file or none, never a partial one.

use std::path::{Path, PathBuf};

use sqlx::sqlite::SqliteConnectOptions;
use sqlx::{ConnectOptions, Connection, Row, SqliteConnection};

use super::BUSY_TIMEOUT;

/// What [`backup`] wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BackupReport {
    /// The destination file.
    pub path: PathBuf,
    /// Its size in bytes.
    pub bytes: u64,
    /// Schema migrations recorded in the copy (its schema version).
    pub migrations: i64,
}

/// Why a backup was not written.
#[derive(Debug, thiserror::Error)]
pub enum BackupError {
    /// There is no file at the source path.
    #[error("no database file at {0}")]
    Missing(PathBuf),
    /// The source cannot be opened as an SQLite database.
    #[error("opening {path}: {error}")]
    Open {
        /// The source file.
        path: PathBuf,
        /// SQLite's error.
        error: sqlx::Error,
    },
    /// The source is an SQLite file but not a repose database (no migrations table).
    #[error("{0} is not a repose database (it has no schema migrations)")]
    NotRepose(PathBuf),
    /// The destination is the source itself.
    #[error("the backup destination {0} is the database itself")]
    SameFile(PathBuf),
    /// Writing the copy failed.
    #[error("copying the database: {0}")]
    Copy(sqlx::Error),
    /// The copy does not pass SQLite's integrity check.
    #[error("the copy failed its integrity check: {0}")]
    Integrity(String),
    /// A file operation (temporary file, sync, rename) failed.
    #[error("{what}: {error}")]
    Io {
        /// What was being done.
        what: String,
        /// The error.
        error: std::io::Error,
    },
}

fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> BackupError {
    let what = what.into();
    move |error| BackupError::Io { what, error }
}

/// Copies the database at `source` to `out` (replacing `out` atomically if it exists) while a
/// server may be using `source`. The source is opened read-only and never migrated or changed.
pub async fn backup(source: &Path, out: &Path) -> Result<BackupReport, BackupError> {
    if !source.is_file() {
        return Err(BackupError::Missing(source.to_owned()));
    }
    if let (Ok(a), Ok(b)) = (source.canonicalize(), out.canonicalize()) {
        if a == b {
            return Err(BackupError::SameFile(out.to_owned()));
        }
    }
    let mut conn = SqliteConnectOptions::new()
        .filename(source)
        .create_if_missing(false)
        .read_only(true)
        .busy_timeout(BUSY_TIMEOUT)
        .connect()
        .await
        .map_err(|error| BackupError::Open {
            path: source.to_owned(),
            error,
        })?;
    let result = copy_into(&mut conn, source, out).await;
    let _ = conn.close().await;
    result
}

async fn copy_into(
    conn: &mut SqliteConnection,
    source: &Path,
    out: &Path,
) -> Result<BackupReport, BackupError> {
    let has_migrations: i64 = sqlx::query(
        "SELECT count(*) FROM sqlite_schema WHERE type = 'table' AND name = '_sqlx_migrations'",
    )
    .fetch_one(&mut *conn)
    .await
    .and_then(|row| row.try_get(0))
    .map_err(|error| BackupError::Open {
        path: source.to_owned(),
        error,
    })?;
    if has_migrations == 0 {
        return Err(BackupError::NotRepose(source.to_owned()));
    }

    let dir = match out.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent.to_owned(),
        _ => PathBuf::from("."),
    };
    let file_name = out
        .file_name()
        .map(|name| name.to_string_lossy().into_owned())
        .unwrap_or_else(|| "backup".to_owned());
    let temp = dir.join(format!(
        ".{file_name}.partial-{}",
        uuid::Uuid::new_v4().simple()
    ));
    // `VACUUM INTO` accepts an existing empty file; creating it first gives it 0600.
    super::create_private(&temp).map_err(io(format!("creating {}", temp.display())))?;
    let written = write_and_check(conn, &temp).await;
    let report = match written {
        Ok(migrations) => finish_file(&temp, out, &dir).map(|bytes| BackupReport {
            path: out.to_owned(),
            bytes,
            migrations,
        }),
        Err(err) => Err(err),
    };
    if report.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    report
}

/// `VACUUM INTO temp`, then the integrity check and schema version of the copy.
async fn write_and_check(conn: &mut SqliteConnection, temp: &Path) -> Result<i64, BackupError> {
    let target = temp.to_str().ok_or_else(|| BackupError::Io {
        what: format!("the path {} is not UTF-8", temp.display()),
        error: std::io::Error::from(std::io::ErrorKind::InvalidInput),
    })?;
    sqlx::query("VACUUM INTO ?")
        .bind(target)
        .execute(&mut *conn)
        .await
        .map_err(BackupError::Copy)?;

    let mut copy = SqliteConnectOptions::new()
        .filename(temp)
        .create_if_missing(false)
        .read_only(true)
        .connect()
        .await
        .map_err(BackupError::Copy)?;
    let checked = async {
        let verdict: String = sqlx::query("PRAGMA integrity_check")
            .fetch_one(&mut copy)
            .await
            .and_then(|row| row.try_get(0))
            .map_err(BackupError::Copy)?;
        if verdict != "ok" {
            return Err(BackupError::Integrity(verdict));
        }
        sqlx::query("SELECT count(*) FROM _sqlx_migrations WHERE success")
            .fetch_one(&mut copy)
            .await
            .and_then(|row| row.try_get::<i64, _>(0))
            .map_err(BackupError::Copy)
    }
    .await;
    let _ = copy.close().await;
    checked
}

/// Syncs the copy, renames it to `out` and syncs the directory; returns the size.
fn finish_file(temp: &Path, out: &Path, dir: &Path) -> Result<u64, BackupError> {
    let file = std::fs::File::open(temp).map_err(io(format!("opening {}", temp.display())))?;
    file.sync_all()
        .map_err(io(format!("syncing {}", temp.display())))?;
    let bytes = file
        .metadata()
        .map_err(io(format!("reading {}", temp.display())))?
        .len();
    drop(file);
    std::fs::rename(temp, out).map_err(io(format!(
        "renaming {} to {}",
        temp.display(),
        out.display()
    )))?;
    // The rename is durable once the directory is synced (not possible on every platform).
    if let Ok(dir) = std::fs::File::open(dir) {
        let _ = dir.sync_all();
    }
    Ok(bytes)
}
