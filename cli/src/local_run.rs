//! What every local simulation command (`repose aor`, `drill`, `shear`, `sim`) sets up the same
//! way: its spec from `--preset`/`--spec`/`--set`, its output folders, a thread pool of
//! `--threads` threads and a progress bar.

use std::io::Write;
use std::path::Path;

use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use repose_experiments::progress::Control;
use repose_experiments::soil::{BedStore, NoBedStore, OnBed, SettledBed};
use repose_experiments::Spec;
use repose_stores::FileBedStore;

/// The spec `--preset`, `--spec FILE` (merged over the preset) and `--set` assignments give,
/// in that order; not yet validated (a command may add to it first).
pub fn spec_from_args<S: Spec>(preset: &str, file: Option<&Path>, set: &[String]) -> Result<S> {
    let base = S::preset(preset)?;
    let mut spec = match file {
        Some(path) => crate::sim::spec_over_preset(path, &base)?,
        None => base,
    };
    spec.apply_assignments(set.iter().map(String::as_str))?;
    Ok(spec)
}

/// Creates each folder (and its parents) if it does not exist.
pub fn create_dirs<'a>(dirs: impl IntoIterator<Item = &'a Path>) -> Result<()> {
    for dir in dirs {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    Ok(())
}

/// A pool of `--threads` threads (all cores without the flag; 0 is refused).
pub fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    let threads = match threads {
        Some(0) => bail!("--threads must be at least 1"),
        Some(t) => t,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .context("cannot start the thread pool")
}

/// A progress bar of 1000 steps (hidden with `quiet`): spinner, elapsed time, bar and percent,
/// then `message_template` (e.g. `" {msg}"`, or `" t={msg} (eta {eta})"`).
pub fn progress_bar(quiet: bool, message_template: &str) -> ProgressBar {
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(1000)
    };
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{spinner}} [{{elapsed_precise}}] {{bar:40}} {{percent:>3}}%{message_template}"
        ))
        .expect("valid template"),
    );
    bar
}

/// A local run on a settled bed (`repose drill`, `repose shear`): `out` and `bed_cache` made,
/// then [`run_on_bed`](repose_experiments::soil::run_on_bed) on a pool of `threads` threads
/// with a progress bar (hidden with `quiet`), the bed taken from or kept in `--bed-cache`.
pub fn run_on_bed<S>(
    spec: &S,
    out: &Path,
    bed_cache: Option<&Path>,
    threads: Option<usize>,
    quiet: bool,
) -> Result<S::Run>
where
    S: OnBed + Sync,
    S::Run: Send,
    S::Error: std::error::Error + Send + Sync + 'static,
{
    create_dirs(std::iter::once(out).chain(bed_cache))?;
    let pool = thread_pool(threads)?;
    let bar = progress_bar(quiet, " {msg}");
    let mut beds = cache_of_beds(bed_cache, &bar);
    let run = pool.install(|| {
        repose_experiments::soil::run_on_bed(spec, beds.as_mut(), &mut |p| {
            bar.set_position((p.fraction * 1000.0) as u64);
            bar.set_message(format!(
                "{} t={:.3} s, {} grains",
                p.phase, p.time, p.particles
            ));
            Control::Continue
        })
    })?;
    bar.finish_and_clear();
    Ok(run)
}

/// What `repose drill` and `repose shear` keep of a finished run: its result and its files.
pub trait RunFiles {
    type Result: serde::Serialize;
    /// The run's result, its wall time replaced by `wall_time_s`.
    fn result_with_wall_time(&self, wall_time_s: f64) -> Self::Result;
    /// The pictures and tables beside `result.json`: file name and contents, in order.
    fn files(&self) -> Vec<(&'static str, String)>;
}

/// [`run_on_bed`], then `result.json` (its wall time this command's, the bed's included when
/// it was built here) and the run's [`RunFiles::files`] written into `out`; prints the JSON.
pub fn run_on_bed_and_write<S>(
    spec: &S,
    out: &Path,
    bed_cache: Option<&Path>,
    threads: Option<usize>,
    quiet: bool,
) -> Result<()>
where
    S: OnBed + Sync,
    S::Run: Send + RunFiles,
    S::Error: std::error::Error + Send + Sync + 'static,
{
    let started = std::time::Instant::now();
    let run = run_on_bed(spec, out, bed_cache, threads, quiet)?;
    let result = run.result_with_wall_time(started.elapsed().as_secs_f64());
    let json = serde_json::to_string_pretty(&result)?;
    crate::sim::write_file(&out.join("result.json"), |w| writeln!(w, "{json}"))?;
    for (name, contents) in run.files() {
        crate::sim::write_file(&out.join(name), |w| w.write_all(contents.as_bytes()))?;
    }
    println!("{json}");
    Ok(())
}

/// The settled beds of `--bed-cache DIR` (none without the flag): a bed found there is reused,
/// a bed built is kept there. A bed that cannot be kept costs only its reuse: a warning (above
/// `bar`), and the run goes on.
fn cache_of_beds<'a>(dir: Option<&Path>, bar: &'a ProgressBar) -> Box<dyn BedStore + Send + 'a> {
    match dir {
        Some(dir) => Box::new(BedCache {
            store: FileBedStore::new(dir),
            bar,
        }),
        None => Box::new(NoBedStore),
    }
}

/// [`cache_of_beds`]'s store: the file store, its write failures shown as warnings.
struct BedCache<'a> {
    store: FileBedStore,
    bar: &'a ProgressBar,
}

impl BedStore for BedCache<'_> {
    fn get(&mut self, key: &str) -> Option<SettledBed> {
        self.store.get(key)
    }

    fn put(&mut self, bed: &SettledBed) {
        if let Err(e) = self.store.write(bed) {
            let dir = self.store.dir().display();
            self.bar
                .suspend(|| eprintln!("warning: bed not kept in {dir}: {e}"));
        }
    }
}
