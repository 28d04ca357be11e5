//! The crate's integration tests as one test binary (one link, the tests of every file
//! run side by side): `cargo test -p repose-engine-gpu --test gpu <file>::`.

mod bed;
mod common;
mod epsd;
mod insertion;
mod jkr;
mod moving;
mod parity;
mod sharing;
mod shear;
