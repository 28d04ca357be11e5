//! Shared helpers for the black-box tests: build the real `repose` binary once and run it.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

/// Path to the `repose` binary, built (once per test binary) with the profile the tests use.
pub fn repose_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        escargot::CargoBuild::new()
            .package("repose")
            .bin("repose")
            .current_release()
            .current_target()
            .manifest_path(workspace_root().join("Cargo.toml"))
            .run()
            .expect("building the repose binary")
            .path()
            .to_path_buf()
    })
}

pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
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
