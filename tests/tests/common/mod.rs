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

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}
