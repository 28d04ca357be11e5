//! The crate's integration tests as one test binary (one link, the tests of every file
//! run side by side): `cargo test -p repose-engine --test engine <file>::`.

mod cohesion;
mod geometry;
mod physics;
mod scene;
