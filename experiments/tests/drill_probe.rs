//! Manual probe: `cargo test -p repose-experiments --test drill_probe -- --ignored --nocapture`
//! with `DRILL_PRESET` and `DRILL_SET` (`;`-separated `key=value`) to time a preset.

use repose_experiments::drill::{run_drill, Control, DrillSpec};

#[test]
#[ignore = "manual timing probe"]
fn probe() {
    let preset = std::env::var("DRILL_PRESET").unwrap_or_else(|_| "fast".into());
    let mut spec = DrillSpec::preset(&preset).unwrap();
    if let Ok(sets) = std::env::var("DRILL_SET") {
        spec.apply_assignments(sets.split(';').filter(|s| !s.is_empty()))
            .unwrap();
    }
    let mut last = 0.0;
    let run = run_drill(&spec, &mut |p| {
        if p.fraction >= last + 0.05 {
            last = p.fraction;
            eprintln!(
                "{:.2} {} t={:.3} n={}",
                p.fraction, p.phase, p.time, p.particles
            );
        }
        Control::Continue
    })
    .unwrap();
    let mut r = run.result.clone();
    r.series.clear();
    println!("{}", serde_json::to_string_pretty(&r).unwrap());
}
