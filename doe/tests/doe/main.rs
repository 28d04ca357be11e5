//! The crate's integration tests as one test binary (one link, the tests of every file
//! run side by side): `cargo test -p repose-doe --test doe <file>::`.

mod crosscheck;
mod designs;
mod fit_errors;
mod optimum;
mod paper;
