//! `repose`: the one user-facing binary. Thin by design: it parses arguments, reads files,
//! calls the libraries and prints. Every user error is one line on stderr and exit status 2.

mod analyze;
mod aor_cmd;
mod backend;
mod backup_cmd;
mod bed_cmd;
mod bench_cmd;
mod client;
mod design_cmd;
mod drill_cmd;
mod ladder_cmd;
mod levels;
mod local_run;
mod server_cmd;
mod shear_cmd;
mod sim;
mod table;
mod token_cmd;
mod triaxial_cmd;
mod up_cmd;
mod worker_cmd;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Debug, Parser)]
#[command(
    name = "repose",
    version,
    about = "Calibrate DEM contact parameters of granular soils"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Print an experimental design (coded and natural columns) as CSV or JSON.
    Design(design_cmd::DesignArgs),
    /// Fit a response-surface model to a run table and print the ANOVA (like Design-Expert).
    Analyze(analyze::AnalyzeArgs),
    /// Run a DEM scene file (TOML or JSON) and write final.csv, geometry forces, snapshots.
    Sim(sim::SimArgs),
    /// Benchmarks (engine throughput); results are recorded in BENCHMARKS.md.
    Bench(bench_cmd::BenchArgs),
    /// Angle-of-repose virtual experiment (funnel or lifted cylinder), measured automatically.
    Aor(aor_cmd::AorArgs),
    /// Drilling (pore-forming) virtual experiment: hole opening diameter, effective depth, torque.
    Drill(drill_cmd::DrillArgs),
    /// Direct shear virtual experiment: cohesion and friction angle (Mohr-Coulomb) of the soil.
    Shear(shear_cmd::ShearArgs),
    /// Drained triaxial compression virtual experiment: c and φ (Mohr circles), E and ν.
    Triaxial(triaxial_cmd::TriaxialArgs),
    /// Chart angle-of-repose runs (a grain-size or mass ladder): angle against heap height in
    /// grain diameters, as SVG.
    Ladder(ladder_cmd::LadderArgs),
    /// Run the job server (REST API, SQLite) until Ctrl-C or SIGTERM.
    Server(server_cmd::ServerArgs),
    /// Create, list and revoke the job server's access tokens (user and worker).
    Token(token_cmd::TokenArgs),
    /// Copy the job server's database consistently while the server runs (see docs/operating.md).
    Backup(backup_cmd::BackupArgs),
    /// Lease jobs from a job server and run them until Ctrl-C or SIGTERM.
    Worker(worker_cmd::WorkerArgs),
    /// Start a server and local workers on an SQLite file; optionally submit and follow batches.
    Up(up_cmd::UpArgs),
    /// Submit a batch file (JSON) to a job server.
    Submit(client::SubmitArgs),
    /// List batches, or show one batch's progress.
    Status(client::StatusArgs),
    /// Follow a batch with a progress bar and print its analysis when it finishes.
    Watch(client::WatchArgs),
    /// Start a calibration campaign (screening → steepest ascent → response surface → optimum →
    /// verification) from a JSON file.
    Campaign(client::CampaignArgs),
}

/// Log lines (tracing) go to stderr, in colour only when stderr is a terminal and `NO_COLOR`
/// is not set; `RUST_LOG` filters them (else `default_filter`).
pub(crate) fn init_logging(default_filter: &str) {
    use std::io::IsTerminal;
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| default_filter.into()),
        )
        .with_ansi(log_colours(
            std::io::stderr().is_terminal(),
            std::env::var_os("NO_COLOR").as_deref(),
        ))
        .with_writer(std::io::stderr)
        .try_init();
}

/// Whether log lines are coloured: on a terminal, unless `NO_COLOR` is set to a non-empty
/// value (no-color.org).
fn log_colours(stderr_is_terminal: bool, no_color: Option<&std::ffi::OsStr>) -> bool {
    stderr_is_terminal && no_color.is_none_or(|v| v.is_empty())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Design(args) => design_cmd::run(&args),
        Command::Analyze(args) => analyze::run(&args),
        Command::Sim(args) => sim::run(&args),
        Command::Bench(args) => bench_cmd::run(&args),
        Command::Server(args) => server_cmd::run(&args),
        Command::Token(args) => token_cmd::run(&args),
        Command::Backup(args) => backup_cmd::run(&args),
        Command::Aor(args) => aor_cmd::run(&args),
        Command::Drill(args) => drill_cmd::run(&args),
        Command::Shear(args) => shear_cmd::run(&args),
        Command::Triaxial(args) => triaxial_cmd::run(&args),
        Command::Ladder(args) => ladder_cmd::run(&args),
        Command::Worker(args) => worker_cmd::run_worker(&args),
        Command::Up(args) => up_cmd::run(&args),
        Command::Submit(args) => client::submit(&args),
        Command::Status(args) => client::status(&args),
        Command::Watch(args) => client::watch(&args),
        Command::Campaign(args) => client::campaign(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            // One line: the context chain joined, outermost first.
            let chain: Vec<String> = err.chain().map(ToString::to_string).collect();
            eprintln!("error: {}", chain.join(": "));
            ExitCode::from(2)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::log_colours;
    use std::ffi::OsStr;

    #[test]
    fn logs_are_coloured_only_on_a_terminal_without_no_color() {
        assert!(log_colours(true, None));
        assert!(
            log_colours(true, Some(OsStr::new(""))),
            "an empty NO_COLOR is unset"
        );
        assert!(!log_colours(true, Some(OsStr::new("1"))));
        assert!(!log_colours(false, None));
        assert!(!log_colours(false, Some(OsStr::new("1"))));
    }
}
