//! Shared helpers for the black-box tests: run the real `repose` binary.

#![allow(dead_code)]

pub mod service;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Path to the `repose` binary cargo built for these tests.
pub fn repose_bin() -> &'static Path {
    Path::new(env!("CARGO_BIN_EXE_repose"))
}

pub fn workspace_root() -> PathBuf {
    // The tests are targets of the `cli` package.
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("cli/ has a parent")
        .to_path_buf()
}

pub fn paper(file: &str) -> PathBuf {
    workspace_root().join("examples/paper").join(file)
}

/// Runs `repose` with the arguments and returns its output.
pub fn repose(args: &[&str]) -> Output {
    Command::new(repose_bin())
        .args(args)
        .output()
        .expect("spawning repose")
}

pub fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Whether a GPU command's `text` (its stderr or log) says no GPU adapter could be opened at
/// all: then the test says it skipped and should return, or, under `REPOSE_REQUIRE_GPU=1`
/// (`.ci/run` sets it where lavapipe is installed), fails.
pub fn skipped_without_gpu(text: &str) -> bool {
    if !text.contains("no GPU adapter") {
        return false;
    }
    assert!(
        !std::env::var("REPOSE_REQUIRE_GPU").is_ok_and(|v| v == "1"),
        "REPOSE_REQUIRE_GPU=1 but {text}"
    );
    eprintln!("SKIPPED: {text}");
    true
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}
