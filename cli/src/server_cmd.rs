//! `repose server`: the lab's job server (REST API over SQLite) until Ctrl-C or SIGTERM.

use anyhow::{bail, Context, Result};
use clap::Args;
use repose_server::{serve, Config};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Debug, Args)]
pub struct ServerArgs {
    /// Address to listen on.
    #[arg(long, env = "REPOSE_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// SQLite database file (created and migrated if missing).
    #[arg(long, env = "REPOSE_DB", default_value = "repose.db")]
    pub db: PathBuf,
    /// Lease length, seconds: a job whose worker stops heartbeating is re-queued after this.
    #[arg(long, env = "REPOSE_LEASE_S", default_value_t = 60.0)]
    pub lease_s: f64,
    /// Attempts before a failing job is marked dead.
    #[arg(long, env = "REPOSE_MAX_ATTEMPTS", default_value_t = 3)]
    pub max_attempts: u32,
    /// Let requests without a token use the read-only GET endpoints (batches, runs, analyses,
    /// workers, jobs, metrics). Submitting, cancelling and the worker protocol always need a
    /// token (`repose token create`).
    #[arg(long, env = "REPOSE_OPEN_READ", conflicts_with = "private_reads")]
    pub open_read: bool,
    /// Users read only their own batches and campaigns (and their batches' jobs); worker
    /// tokens read only their own workers' jobs. Default: any valid token reads everything.
    #[arg(long, env = "REPOSE_PRIVATE_READS")]
    pub private_reads: bool,
    /// `normal`: an acknowledged result survives a crash of the server process (SQLite
    /// `synchronous=NORMAL` in WAL mode) but the last ones may be lost on power loss; `full`:
    /// it survives power loss too (an fsync per write, slower).
    #[arg(long, env = "REPOSE_DURABILITY", default_value = "normal", value_parser = ["normal", "full"])]
    pub durability: String,
}

/// Longest accepted lease: a day.
pub(crate) const MAX_LEASE_S: f64 = 86_400.0;

/// The validated server configuration (checked once, before anything starts).
fn config(args: &ServerArgs) -> Result<Config> {
    if !(args.lease_s.is_finite() && (1.0..=MAX_LEASE_S).contains(&args.lease_s)) {
        bail!(
            "--lease-s must be between 1 and {MAX_LEASE_S} seconds, got {}",
            args.lease_s
        );
    }
    if args.max_attempts == 0 {
        bail!("--max-attempts must be at least 1");
    }
    let mut config = Config::new(args.db.clone());
    config.listen = args.listen;
    config.lease = Duration::from_secs_f64(args.lease_s);
    config.max_attempts = args.max_attempts;
    config.open_read = args.open_read;
    config.private_reads = args.private_reads;
    config.durability_full = args.durability == "full";
    Ok(config)
}

pub fn run(args: &ServerArgs) -> Result<()> {
    let config = config(args)?;
    crate::init_logging("info");
    let runtime = tokio::runtime::Runtime::new().context("cannot start the async runtime")?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(config.listen)
            .await
            .with_context(|| format!("cannot listen on {}", config.listen))?;
        let address = listener.local_addr()?;
        // The first stdout line says where the server is, so scripts can find an ephemeral port.
        println!("listening on http://{address}");
        serve(config, listener, shutdown_signal())
            .await
            .context("server failed")
    })
}

/// Resolves on Ctrl-C or SIGTERM.
pub(crate) async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {},
        () = terminate => {},
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        server: ServerArgs,
    }

    #[test]
    fn an_absurd_lease_is_an_error_not_a_panic() {
        for lease in ["1e300", "inf", "0.5", "86401"] {
            let cli = Cli::try_parse_from(["repose", "--lease-s", lease]).unwrap();
            let err = config(&cli.server).unwrap_err();
            assert!(err.to_string().contains("--lease-s"), "{err}");
        }
        let cli =
            Cli::try_parse_from(["repose", "--lease-s", "30", "--durability", "full"]).unwrap();
        let config = config(&cli.server).unwrap();
        assert_eq!(config.lease, Duration::from_secs(30));
        assert!(config.durability_full);
    }
}
