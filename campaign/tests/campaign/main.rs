//! The crate's integration tests as one test binary (one link, the tests of every file
//! run side by side): `cargo test -p repose-campaign --test campaign <file>::`.

mod bayes;
mod common;
mod fallbacks;
mod replay;
mod strategies;
mod targets;
mod trust;
