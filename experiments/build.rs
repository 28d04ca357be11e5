//! Fingerprints the code that decides a run's trajectory for the checkpoints: this crate's and
//! the engine's sources (when built inside the workspace), the locked versions of every
//! package the two depend on (from the workspace's `Cargo.lock`: a new nalgebra or rand_chacha
//! may compute or draw differently) and the compiler's version. A checkpoint is continued only
//! by a build of the same code (`aor::checkpoint`). No I/O happens at run time.

use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};

/// `name version` of every package `roots` depend on, directly or not, themselves included,
/// from a `Cargo.lock`'s text (sorted; empty if it cannot be read).
fn locked_closure(lock: &str, roots: &[&str]) -> BTreeSet<String> {
    #[derive(serde::Deserialize)]
    struct Lock {
        #[serde(default)]
        package: Vec<Package>,
    }
    #[derive(serde::Deserialize)]
    struct Package {
        name: String,
        version: String,
        #[serde(default)]
        dependencies: Vec<String>,
    }
    let Ok(lock) = toml::from_str::<Lock>(lock) else {
        return BTreeSet::new();
    };
    // A dependency is written `name` when one version is locked, else `name version [(source)]`.
    let mut by_name: HashMap<&str, Vec<&Package>> = HashMap::new();
    for package in &lock.package {
        by_name.entry(&package.name).or_default().push(package);
    }
    let resolve = |dependency: &str| -> Vec<&Package> {
        let mut words = dependency.split(' ');
        let name = words.next().unwrap_or_default();
        let candidates = by_name.get(name).cloned().unwrap_or_default();
        match words.next() {
            Some(version) => candidates
                .into_iter()
                .filter(|p| p.version == version)
                .collect(),
            None => candidates,
        }
    };
    let mut seen = BTreeSet::new();
    let mut stack: Vec<&Package> = roots.iter().flat_map(|r| resolve(r)).collect();
    while let Some(package) = stack.pop() {
        if seen.insert(format!("{} {}", package.name, package.version)) {
            for dependency in &package.dependencies {
                stack.extend(resolve(dependency));
            }
        }
    }
    seen
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let dirs = [root.join("src"), root.join("../engine/src")];
    let mut files = Vec::new();
    for dir in &dirs {
        println!("cargo:rerun-if-changed={}", dir.display());
        rust_files(dir, &mut files);
    }
    // Paths relative to the crate, so the fingerprint does not depend on where the tree lies.
    let mut named: Vec<(String, PathBuf)> = files
        .into_iter()
        .map(|p| {
            let name = p
                .strip_prefix(&root)
                .unwrap_or(&p)
                .to_string_lossy()
                .replace('\\', "/");
            (name, p)
        })
        .collect();
    named.sort();
    // FNV-1a over each file's relative path and contents.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    for (name, path) in &named {
        eat(name.as_bytes());
        eat(&std::fs::read(path).unwrap_or_default());
    }
    let lock_path = root.join("../Cargo.lock");
    println!("cargo:rerun-if-changed={}", lock_path.display());
    let lock = std::fs::read_to_string(&lock_path).unwrap_or_default();
    for package in locked_closure(&lock, &["repose-engine", "repose-experiments"]) {
        eat(package.as_bytes());
        eat(b"\n");
    }
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    if let Ok(out) = std::process::Command::new(rustc).arg("-V").output() {
        eat(&out.stdout);
    }
    println!("cargo:rustc-env=REPOSE_TRAJECTORY_CODE={h:016x}");
}
