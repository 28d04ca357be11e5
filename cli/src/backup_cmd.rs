//! `repose backup`: a consistent copy of the job server's database, taken while it runs.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

#[derive(Debug, Args)]
pub struct BackupArgs {
    /// The server's SQLite database file (opened read-only; the server may keep running).
    #[arg(long, env = "REPOSE_DB", default_value = "repose.db")]
    pub db: PathBuf,
    /// Where to write the copy. Written to a temporary file beside it, checked, then renamed
    /// over it (an existing file is replaced only by a complete copy); permissions 0600.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
}

pub fn run(args: &BackupArgs) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let report = runtime
        .block_on(repose_server::backup(&args.db, &args.out))
        .with_context(|| format!("backing up {}", args.db.display()))?;
    println!(
        "backed up {} to {} ({} bytes, schema version {}, integrity ok)",
        args.db.display(),
        report.path.display(),
        report.bytes,
        report.migrations
    );
    Ok(())
}
