//! The angle-of-repose virtual experiment end to end, on the `fast` preset (a ~1 380-grain heap
//! of 2.5 mm spheres poured through the paper's funnel).
//!
//! Each heap takes ~30 s of one core in the test profile (engine and experiments are built with
//! opt-level 3 there); the two monotonicity tests run two heaps each, on separate test threads.
//! The engine is deterministic, so each comparison is exactly reproducible.

use std::time::Duration;

use repose_experiments::aor::{
    run_aor, run_aor_with_checkpoints, AorCheckpoint, AorError, AorResult, AorSpec,
    CheckpointError, Checkpoints, Control, EndedBy, RunStatus,
};
use repose_experiments::Spec;

fn run(spec: &AorSpec) -> AorResult {
    let mut last = 0.0;
    let run = run_aor(spec, &mut |p| {
        assert!(
            p.fraction >= last - 1e-12 && p.fraction <= 1.0,
            "progress {p:?}"
        );
        last = p.fraction;
        Control::Continue
    })
    .expect("the fast preset builds");
    check_heap(spec, run.result)
}

/// Prints a fast run and checks that it formed a heap that came to rest.
fn check_heap(spec: &AorSpec, r: AorResult) -> AorResult {
    eprintln!(
        "soil_soil {} -> status {:?} angle {:?} (left {:?}, right {:?}) ended_by {:?} t {:.3} s \
         steps {} wall {:.1} s grains {:?}",
        serde_json::to_string(&spec.soil_soil).unwrap(),
        r.status,
        r.angle_deg,
        r.left_deg,
        r.right_deg,
        r.ended_by,
        r.simulated_time_s,
        r.steps,
        r.wall_time_s,
        r.grains
    );
    // Every fast heap forms, comes to rest and keeps (nearly) all its grains.
    assert_eq!(r.status, RunStatus::Ok, "{r:?}");
    assert!(r.came_to_rest);
    assert_eq!(r.ended_by, EndedBy::AtRest);
    // ... and says how close to the limits it stopped.
    let rest = r.rest.expect("a run that came to rest reports its creep");
    eprintln!("  at rest: {rest}");
    assert!(rest.creep_deg_per_s.unwrap().abs() <= spec.settle.max_creep_deg_per_s);
    assert!(rest.kinetic_energy_ratio < spec.settle.kinetic_energy_threshold);
    assert_eq!(rest.creep_checks, spec.settle.rest_checks());
    assert!(r.grains.inserted.mass > 0.99 * spec.total_mass - 1e-4);
    assert!(r.grains.on_pile.count as f64 > 0.8 * r.grains.inserted.count as f64);
    assert_eq!(r.grains.held_up.count, 0, "the funnel drained");
    assert!(r.pile_height_m.unwrap() > 0.005 && r.base_diameter_m.unwrap() > 0.02);
    r
}

fn angle_with(set: &[(&str, &str)]) -> f64 {
    let mut spec = AorSpec::fast();
    for (k, v) in set {
        spec.set(k, v).unwrap();
    }
    let a = run(&spec).angle_deg.expect("ok runs have an angle");
    assert!((5.0..60.0).contains(&a), "angle {a}");
    a
}

/// Ignored from the rest rule of issue 13c until 675dbdc: CDT's torque followed the old ω and
/// the μr 0.40 heap crept past any cap (4 s). With the rolling brake it comes to rest at once
/// (seed 1: 9.21° at μr 0.01, 40.97° at 0.40, both at rest by 1.2 s).
#[test]
fn angle_rises_with_soil_soil_rolling_friction() {
    let low = angle_with(&[("soil_soil.rolling_friction", "0.01")]);
    let high = angle_with(&[("soil_soil.rolling_friction", "0.40")]);
    eprintln!("rolling friction 0.01 -> {low:.2}°, 0.40 -> {high:.2}°");
    assert!(high > low + 3.0, "{low} -> {high}");
}

/// The effect of static friction over the paper's range (≈ 2-6°) is smaller than the
/// seed-to-seed spread of one 30 g heap at the fast resolution (19.4-25.2° at μs 0.44 over
/// seeds 1, 2, 4), so one seed per level can rank them either way: the claim is about the mean
/// over seeds. Since CDT rolling friction holds grains (675dbdc) the fast funnel's 17 mm outlet,
/// 6.8 grains wide, jams in some pours (μs 0.44: seed 3; μs 0.68: seeds 3 and 4; 342-573 of
/// 1 376 grains stay in the funnel) and leaves a smaller heap: the means are over the seeds
/// 1-4 whose funnel drained, at least two per level.
#[test]
fn angle_rises_with_soil_soil_static_friction() {
    let mean = |mu: &str| {
        let angles: Vec<f64> = ["1", "2", "3", "4"]
            .iter()
            .filter_map(|seed| {
                let mut spec = AorSpec::fast();
                spec.set("soil_soil.static_friction", mu).unwrap();
                spec.set("seed", seed).unwrap();
                let r = run_aor(&spec, &mut |_| Control::Continue)
                    .expect("the fast preset builds")
                    .result;
                eprintln!(
                    "static friction {mu}, seed {seed}: {:?}, held up {}",
                    r.angle_deg, r.grains.held_up.count
                );
                (r.grains.held_up.count == 0).then(|| check_heap(&spec, r).angle_deg.unwrap())
            })
            .collect();
        assert!(angles.len() >= 2, "μs {mu}: drained pours {angles:?}");
        eprintln!("static friction {mu}: {angles:.2?}");
        angles.iter().sum::<f64>() / angles.len() as f64
    };
    let (low, high) = (mean("0.44"), mean("0.68"));
    eprintln!("static friction 0.44 -> {low:.2}°, 0.68 -> {high:.2}° (means of drained pours)");
    assert!(high > low + 0.5, "{low} -> {high}");
}

#[test]
fn cancelled_run_reports_cancelled_without_angle() {
    let spec = AorSpec::fast();
    let mut calls = 0;
    let run = run_aor(&spec, &mut |_| {
        calls += 1;
        if calls > 3 {
            Control::Cancel
        } else {
            Control::Continue
        }
    })
    .unwrap();
    assert_eq!(run.result.status, RunStatus::Cancelled);
    assert_eq!(run.result.ended_by, EndedBy::Cancelled);
    assert_eq!(run.result.angle_deg, None);
    assert!(!run.result.came_to_rest);
}

#[test]
fn grains_that_cannot_form_a_heap_are_reported_not_measured() {
    // A tiny pour: a handful of grains is no heap, so no angle.
    let mut spec = AorSpec::fast();
    spec.set("total_mass", "0.0005").unwrap();
    let run = run_aor(&spec, &mut |_| Control::Continue).unwrap();
    assert_eq!(
        run.result.status,
        RunStatus::MeasurementFailed,
        "{:?}",
        run.result
    );
    assert_eq!(run.result.angle_deg, None);
    assert!(run.result.message.is_some());
    assert!(run.pile_svg().is_none());
}

#[test]
fn escaped_grains_make_an_escaped_run() {
    // A plate barely wider than the funnel (71 mm across its top): the heap spills over its
    // edge. The fast rig's gentle 0.06 kg/s stream builds a heap that keeps most of its grains
    // even there (26 of 1 376, 1.9 %, fall off), so the limit is 1 % here.
    let mut spec = AorSpec::fast();
    spec.set("base.size", "0.072").unwrap();
    spec.set("max_escaped_fraction", "0.01").unwrap();
    let run = run_aor(&spec, &mut |_| Control::Continue).unwrap();
    let r = &run.result;
    assert!(r.grains.escaped.count > 0, "{r:?}");
    assert_eq!(r.status, RunStatus::Escaped, "{r:?}");
    assert_eq!(r.angle_deg, None);
}

#[test]
fn an_arch_over_the_outlet_makes_a_held_up_run_without_an_angle() {
    // 5 g of 2.5 mm grains (about 230) fit in the funnel; an outlet of 7 mm (2.8 grains) arches
    // at once. The few grains that pass come to rest on the plate, so the run ends at rest, but
    // nearly all the mass is still in the funnel: no angle.
    let mut spec = AorSpec::fast();
    spec.set("total_mass", "0.005").unwrap();
    spec.set("funnel.outlet_diameter", "0.007").unwrap();
    let run = run_aor(&spec, &mut |_| Control::Continue).expect("the spec builds");
    let r = &run.result;
    let held = r.grains.held_up.mass / r.grains.inserted.mass;
    assert!(held > spec.max_held_up_fraction, "{held} {r:?}");
    assert_eq!(r.status, RunStatus::HeldUp, "{r:?}");
    assert_eq!(r.angle_deg, None);
    let message = r.message.as_deref().unwrap();
    assert!(message.contains("still in the funnel"), "{message}");
    // Through the catalog (what a worker runs): no result for this seed, but whether grains
    // arch is the pour's chance, so a job server may try another seed.
    let err = repose_experiments::catalog::run_experiment(
        "aor",
        &serde_json::to_value(&spec).unwrap(),
        spec.seed,
        &mut |_| Control::Continue,
    )
    .unwrap_err();
    assert!(err.is_permanent() && err.another_seed_may_help(), "{err:?}");
    assert!(err.to_string().contains("HeldUp"), "{err}");
    // The same heap with the limit lifted is judged on its own terms again.
    spec.set("max_held_up_fraction", "1").unwrap();
    let r = run_aor(&spec, &mut |_| Control::Continue).unwrap().result;
    assert_ne!(r.status, RunStatus::HeldUp, "{r:?}");
    spec.set("max_held_up_fraction", "1.5").unwrap();
    let err = spec.validate().unwrap_err().to_string();
    assert!(err.contains("max_held_up_fraction"), "{err}");
}

#[test]
fn a_heap_cut_by_the_time_cap_reports_how_far_from_rest_it_was() {
    // The fast pour: insertion ends at 0.5 s, checks every 50 ms from 0.6 s; the heap is at
    // rest by 0.85 s. Cut at 0.71 s, it ends by the time cap while slumping (24.8° → 20.9° over
    // the last three checks) with the kinetic energy ~40× the threshold.
    let mut spec = AorSpec::fast();
    spec.settle.min_time = 0.1;
    spec.settle.check_interval = 0.05;
    spec.settle.angle_window = 3;
    spec.settle.creep_window_s = 0.1;
    spec.time_cap = 0.21;
    let run = run_aor(&spec, &mut |_| Control::Continue).expect("the fast preset builds");
    let r = run.result;
    eprintln!("{:?} {:?} {:?}", r.ended_by, r.message, r.rest);
    assert_eq!(r.ended_by, EndedBy::TimeCap, "{r:?}");
    assert_eq!(r.status, RunStatus::NotSettled);
    assert!(!r.came_to_rest);
    let gap = r.rest.expect("a capped run says how far from rest it was");
    let rate = gap
        .creep_deg_per_s
        .expect("angles were measured at the last checks");
    assert!(rate < -10.0, "a slumping heap: creep {rate} °/s");
    assert_eq!(gap.creep_checks, 3);
    assert!(
        gap.kinetic_energy_ratio > gap.kinetic_energy_threshold,
        "{gap:?}"
    );
    assert_eq!(
        gap.kinetic_energy_threshold,
        spec.settle.kinetic_energy_threshold
    );
    let message = r.message.clone().unwrap();
    assert!(message.contains("°/s"), "{message}");
    // The JSON carries it, and a result written before the field existed still parses.
    let json = serde_json::to_value(&r).unwrap();
    assert!(json["rest"]["creep_deg_per_s"].is_number(), "{json}");
    let mut old = json.clone();
    old.as_object_mut().unwrap().remove("rest");
    let parsed: AorResult = serde_json::from_value(old.clone()).unwrap();
    assert_eq!(parsed.rest, None);
    // ... as does one that ended by the old rule (`ended_by: kinetic_energy`).
    old["ended_by"] = "kinetic_energy".into();
    old["came_to_rest"] = true.into();
    let parsed: AorResult = serde_json::from_value(old).unwrap();
    assert_eq!(parsed.ended_by, EndedBy::KineticEnergy);
}

#[test]
fn a_steep_heap_comes_to_rest_and_holds_its_angle() {
    // μr 0.40 at the fast resolution. Until 675dbdc CDT's torque followed the old ω, so grains
    // pushed by less than the rolling moment still turned a little every step: this heap stood
    // at ~39° 0.6 s after insertion, then slumped by degrees until the cap (24.0° at 4.2 s,
    // −2.8°/s). The rolling brake holds it: at rest, its angle flat to round-off over the last
    // checks. (At the 25 mm outlet the heap's last settling step, 0.23°, still falls inside the
    // 0.5 s creep window: −0.46°/s over it, inside the limit, where the 17 mm rig read
    // < 0.05°/s. A heap that does not come to rest reports its creep:
    // `a_heap_cut_by_the_time_cap_…` above.)
    let mut spec = AorSpec::fast();
    spec.set("soil_soil.rolling_friction", "0.40").unwrap();
    let r = run(&spec);
    let angle = r.angle_deg.unwrap();
    let rest = r.rest.unwrap();
    eprintln!("μr 0.40: {angle:.2}°, {rest}");
    assert!(angle > 35.0, "the steep heap stands: {angle}");
    assert!(rest.angle_range_deg.unwrap() < 1e-3, "{rest}");
    assert!(
        rest.creep_deg_per_s.unwrap().abs() <= spec.settle.max_creep_deg_per_s,
        "{rest}"
    );
    let last: Vec<f64> = r.checks[r.checks.len() - 3..]
        .iter()
        .map(|c| c.angle_deg.unwrap())
        .collect();
    assert!(last.iter().all(|a| (a - angle).abs() < 1e-3), "{last:?}");
}

#[test]
fn an_epsd_heap_comes_to_rest_though_lone_grains_spin_on_their_spot() {
    // EPSD rolling friction (as LIGGGHTS defines it) resists rolling but not a twist about the
    // contact normal, nor does the tangential force: a lone grain on the plate that was set
    // spinning about the vertical keeps spinning. The rest rule tests the translational kinetic
    // energy, so such a heap still comes to rest (before that, every default-preset EPSD run
    // ended `not_settled` at the cap with its angle flat).
    let mut spec = AorSpec::fast();
    spec.set("rolling_model", "epsd").unwrap();
    spec.set("damping_law", "edem_formula").unwrap();
    let run = run_aor(&spec, &mut |_| Control::Continue).expect("the fast preset builds");
    let p = run.world.particles();
    let n = p.len() as f64;
    let mean_mass = p.mass.iter().sum::<f64>() / n;
    let mean_d = 2.0 * p.radius.iter().sum::<f64>() / n;
    let scale = n * mean_mass * 9.81 * mean_d;
    let rotational = (p.kinetic_energy() - p.translational_kinetic_energy()) / scale;
    let translational = p.translational_kinetic_energy() / scale;
    let r = run.result;
    eprintln!(
        "{:?} {:?} angle {:?} at {:.2} s; final kinetic energy / (m g d): translational {translational:.2e}, rotational {rotational:.2e}",
        r.status, r.ended_by, r.angle_deg, r.simulated_time_s
    );
    assert_eq!(r.status, RunStatus::Ok, "{r:?}");
    assert_eq!(r.ended_by, EndedBy::AtRest);
    assert!(translational < spec.settle.kinetic_energy_threshold);
    let angle = r.angle_deg.unwrap();
    assert!((5.0..60.0).contains(&angle), "angle {angle}");
}

#[test]
fn a_run_resumed_from_a_checkpoint_ends_exactly_as_the_uninterrupted_run() {
    // A short fast pour with checks from 0.3 s, cut by the time cap while it settles. The run is
    // cancelled with 60 % of the mass in (grains in the funnel, in the stream and on the plate);
    // the checkpoint it leaves is resumed and must end as the uninterrupted run does, to the
    // last bit, after passing through the at-rest checks.
    let mut spec = AorSpec::fast();
    spec.settle.min_time = 0.1;
    spec.settle.check_interval = 0.05;
    spec.time_cap = 0.25;
    let whole = run_aor(&spec, &mut |_| Control::Continue).expect("the fast preset builds");

    let mut saved: Vec<Vec<u8>> = Vec::new();
    let mut keep = |bytes: &[u8]| saved.push(bytes.to_vec());
    let first = run_aor_with_checkpoints(
        &spec,
        &mut |p| {
            if p.fraction > 0.3 {
                Control::Cancel
            } else {
                Control::Continue
            }
        },
        Checkpoints {
            resume: None,
            save: Some(&mut keep),
            every: Duration::ZERO,
        },
    )
    .unwrap();
    assert_eq!(first.result.status, RunStatus::Cancelled);
    assert!(
        saved.len() > 2,
        "a checkpoint every 200 steps and one at the cancel"
    );
    let last = AorCheckpoint::from_bytes(saved.last().unwrap()).unwrap();
    assert_eq!(last.steps(), first.result.steps);
    assert!(last.particles() > 0 && last.steps() < whole.result.steps);

    // A checkpoint does not continue another experiment; the error names the field.
    let mut other = spec.clone();
    other.seed += 1;
    let err = run_aor_with_checkpoints(
        &other,
        &mut |_| Control::Continue,
        Checkpoints {
            resume: Some(last.clone()),
            ..Checkpoints::default()
        },
    )
    .unwrap_err();
    assert!(
        matches!(&err, AorError::Checkpoint(CheckpointError::OtherSpec { path, .. }) if path == "seed"),
        "{err}"
    );

    let resumed = run_aor_with_checkpoints(
        &spec,
        &mut |_| Control::Continue,
        Checkpoints {
            resume: Some(last),
            ..Checkpoints::default()
        },
    )
    .unwrap();
    let (a, b) = (&whole.result, &resumed.result);
    assert_eq!(b.resumed_at_step, Some(first.result.steps));
    assert_eq!(a.resumed_at_step, None);
    assert_eq!(resumed.world.state_hash(), whole.world.state_hash());
    assert!(
        a.checks.len() >= 3,
        "the tail runs through the checks: {a:?}"
    );
    let comparable = |r: &AorResult| {
        let mut v = serde_json::to_value(r).unwrap();
        let o = v.as_object_mut().unwrap();
        o.remove("wall_time_s");
        o.remove("resumed_at_step");
        v
    };
    assert_eq!(comparable(b), comparable(a));
    assert_eq!(
        b.last_angle_deg.map(f64::to_bits),
        a.last_angle_deg.map(f64::to_bits)
    );
    assert!(b.wall_time_s >= first.result.wall_time_s);
}

#[test]
fn a_funnel_that_jams_is_held_up_and_one_still_draining_at_the_cap_is_not_settled() {
    // 0.1 kg poured at 0.5 kg/s into the fast funnel with a 7 mm outlet (2.8 grains): the
    // outlet arches at once, the funnel fills to the brim (about 70 g) and the pour can never
    // end. A grain trickles through now and then, far below a tenth of the pour's rate over
    // the last half second before the cap: held up.
    let mut spec = AorSpec::fast();
    spec.set("total_mass", "0.1").unwrap();
    spec.set("mass_rate", "0.5").unwrap();
    spec.set("funnel.outlet_diameter", "0.007").unwrap();
    spec.time_cap = 0.55;
    let r = run_aor(&spec, &mut |_| Control::Continue).unwrap().result;
    eprintln!("jammed: {:?} {:?} {:?}", r.status, r.message, r.grains);
    assert_eq!(r.status, RunStatus::HeldUp, "{r:?}");
    assert_eq!(r.insertion_end_s, None);
    assert!(r.grains.inserted.mass < 0.09, "{r:?}");
    assert!(r.message.as_deref().unwrap().contains("jammed"), "{r:?}");
    assert_eq!(r.angle_deg, None);

    // The default grains (2 mm) flow through the paper's outlet at about 65 g/s (Beverloo's
    // law), so 50 g poured at 0.3 kg/s take about a second to drain; a cap 0.25 s after the
    // pour ends the run with most of the mass still draining: not settled (the fast preset's
    // 2.5 mm grains would arch in a funnel this full, and be held up), and the message says
    // what to raise.
    let mut spec = AorSpec::preset("default").unwrap();
    spec.set("mass_rate", "0.3").unwrap();
    spec.time_cap = 0.25;
    let r = run_aor(&spec, &mut |_| Control::Continue).unwrap().result;
    eprintln!("draining: {:?} {:?} {:?}", r.status, r.message, r.grains);
    assert_eq!(r.status, RunStatus::NotSettled, "{r:?}");
    assert!(
        r.grains.held_up.mass > 0.2 * r.grains.inserted.mass,
        "{r:?}"
    );
    let message = r.message.as_deref().unwrap();
    assert!(message.contains("raise time_cap"), "{message}");
    assert!(message.contains("g/s"), "{message}");
}

/// A checkpoint store holding one set of bytes, recording what the run did with it.
#[derive(Default)]
struct OneCheckpoint {
    bytes: Option<Vec<u8>>,
    puts: usize,
    rejected: Vec<String>,
    removed: bool,
}

impl repose_experiments::catalog::CheckpointStore for OneCheckpoint {
    fn get(&mut self, _key: &str) -> Option<Vec<u8>> {
        self.bytes.clone()
    }
    fn put(&mut self, _key: &str, bytes: &[u8]) {
        self.puts += 1;
        self.bytes = Some(bytes.to_vec());
    }
    fn remove(&mut self, _key: &str) {
        self.removed = true;
        self.bytes = None;
    }
    fn reject(&mut self, _key: &str, reason: &str) {
        self.rejected.push(reason.to_owned());
    }
    fn every(&self) -> Duration {
        Duration::ZERO
    }
}

#[test]
fn a_job_given_unreadable_checkpoint_bytes_rejects_them_and_starts_over() {
    // Bytes under the run's key that are no checkpoint (another build's format, damage) must
    // be handed back as rejected, so that a store keeps them aside instead of letting the new
    // run's first checkpoint replace them; the run starts over, checkpoints as it goes and
    // removes its checkpoint when it finishes.
    let spec = serde_json::json!({"total_mass": 0.005, "time_cap": 0.05});
    let spec = repose_experiments::catalog::prepare_spec("aor", Some("fast"), &spec).unwrap();
    let mut store = OneCheckpoint {
        bytes: Some(b"repose aor checkpoint\n\x07\x00\x00\x00".to_vec()),
        ..OneCheckpoint::default()
    };
    let outcome = repose_experiments::catalog::run_experiment_with_stores(
        "aor",
        &spec,
        4,
        &mut |_| Control::Continue,
        &mut repose_experiments::catalog::NoBedStore,
        &mut store,
    );
    assert!(
        store.rejected.len() == 1 && store.rejected[0].contains("format 7"),
        "{:?}",
        store.rejected
    );
    assert!(store.puts > 0 && store.removed, "{outcome:?}");
}
