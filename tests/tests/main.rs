//! Black-box tests of the `repose` binary and the service it runs, as one test binary (one link,
//! the files' tests run side by side): `cargo test -p repose --test cli <file>::`.

mod common;

mod cli_analyze;
mod cli_aor;
mod cli_drill;
mod cli_shear;
mod cli_sim;
mod netns;
mod service;
