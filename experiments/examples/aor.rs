//! One angle-of-repose run without the CLI (a quicker build for profiling the engine in a real
//! experiment): `cargo run --release -p repose-experiments --example aor -- PRESET THREADS
//! [path=value ...]`. Prints the angle, the grain and step counts and the wall time.

use repose_experiments::Spec;
use std::time::Instant;

use repose_experiments::aor::{run_aor, AorSpec, Control};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let preset = args.first().map(String::as_str).unwrap_or("fast");
    let threads: usize = args.get(1).map_or(1, |t| t.parse().expect("THREADS"));
    let mut spec = AorSpec::preset(preset).expect("a preset name");
    for assignment in args.iter().skip(2) {
        let (path, value) = assignment.split_once('=').expect("path=value");
        spec.set(path, value).expect("a valid setting");
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool");
    let start = Instant::now();
    let run = pool
        .install(|| run_aor(&spec, &mut |_| Control::Continue))
        .expect("the run starts");
    let r = &run.result;
    println!(
        "{preset}, {threads} threads: angle {:?} deg, {} grains inserted, {} steps, {:.1} s wall",
        r.angle_deg,
        r.grains.inserted.count,
        r.steps,
        start.elapsed().as_secs_f64()
    );
}
