//! The crate's integration tests as one test binary (one link, the tests of every file
//! run side by side): `cargo test -p repose-server --test server <file>::`.

mod access;
mod backend;
mod backup;
mod campaign;
mod common;
mod fuzz;
mod jobs;
mod metrics;
mod openapi;
mod page;
#[allow(unused_imports)]
#[path = "../../../campaign/tests/campaign/common/mod.rs"]
mod paper;
mod regressions;
mod versions;
