//! The drilling experiment at the `fast` preset: a hole forms, it is at least as wide as the
//! auger, deeper feeds give deeper holes, the torque rises as the auger enters the soil, the bed
//! can be stored and reused exactly, results survive JSON.

use crate::common;

use repose_experiments::Spec;
use std::sync::OnceLock;

use repose_experiments::catalog::{prepare_spec, run_experiment_with_beds, BedStore};
use repose_experiments::drill::{
    bed_key, build_bed, run_drill, run_drill_on_bed, Control, DrillError, DrillResult, DrillRun,
    DrillSpec, DrillStatus, SettledBed, StlDrill,
};

fn fast() -> DrillSpec {
    DrillSpec::fast()
}

/// The fast preset's bed, built once for this test binary.
fn bed() -> &'static SettledBed {
    static BED: OnceLock<SettledBed> = OnceLock::new();
    BED.get_or_init(|| build_bed(&fast(), &mut |_| Control::Continue).unwrap())
}

/// The fast preset drilled to 40 mm (bed built by `run_drill` itself).
fn deep() -> &'static DrillRun {
    static RUN: OnceLock<DrillRun> = OnceLock::new();
    RUN.get_or_init(|| run_drill(&fast(), &mut |_| Control::Continue).unwrap())
}

fn brief(r: &DrillResult) -> String {
    let mut r = r.clone();
    r.series.clear();
    serde_json::to_string_pretty(&r).unwrap()
}

#[test]
fn the_bed_settles_and_is_the_same_fresh_or_stored() {
    let bed = bed();
    assert!(
        bed.settled,
        "kinetic energy ratio {}",
        bed.kinetic_energy_ratio
    );
    assert!(bed.positions.len() > 1000);
    let spec = fast();
    // The surface lies near the bed depth aimed at.
    assert!(
        (bed.surface_z - spec.bed.depth).abs() < 0.15 * spec.bed.depth,
        "surface {} for a {} m bed",
        bed.surface_z,
        spec.bed.depth
    );
    // run_drill built the same bed (same seed), bit for bit (only the wall time differs).
    let mut fresh = deep().bed.clone();
    fresh.wall_time_s = bed.wall_time_s;
    // Should the two builds ever differ, say how. (The failure seen on 2026-11-25 was the JSON
    // step below: the wall time came back an ulp off, before beds stored every float as bits.)
    assert_eq!(
        (fresh.steps, fresh.escaped, fresh.positions.len()),
        (bed.steps, bed.escaped, bed.positions.len()),
        "steps, escaped, grains"
    );
    if let Some(i) = (0..bed.positions.len()).find(|&i| {
        fresh.positions[i] != bed.positions[i] || fresh.velocities[i] != bed.velocities[i]
    }) {
        panic!(
            "grain {i} of {} differs: position {:?} vs {:?}, velocity {:?} vs {:?}",
            bed.positions.len(),
            fresh.positions[i],
            bed.positions[i],
            fresh.velocities[i],
            bed.velocities[i]
        );
    }
    assert_eq!(&fresh, bed);
    // Through JSON, exactly.
    let text = serde_json::to_string(bed).unwrap();
    let back: SettledBed = serde_json::from_str(&text).unwrap();
    assert_eq!(&back, bed);
}

#[test]
fn a_hole_forms_at_least_as_wide_as_the_auger() {
    let run = deep();
    let r = &run.result;
    assert_eq!(r.status, DrillStatus::Ok, "{}", brief(r));
    let depth = r.effective_depth_mm.unwrap();
    let opening = r.opening_diameter_mm.unwrap();
    assert!(depth > 0.3 * r.feed_depth_mm, "{}", brief(r));
    assert!(depth < r.feed_depth_mm + 10.0, "{}", brief(r));
    assert!(opening >= r.auger_diameter_mm, "{}", brief(r));
    assert!(r.opening_diameter_x_mm.unwrap() > 0.5 * r.auger_diameter_mm);
    assert!(r.opening_diameter_y_mm.unwrap() > 0.5 * r.auger_diameter_mm);
    let backfill = r.backfill_ratio.unwrap();
    assert!(backfill > 0.0 && backfill < 0.9, "{}", brief(r));
    assert!(r.energy_j > 0.0);
    let metrics = r.metrics();
    for key in [
        "opening_diameter_mm",
        "effective_depth_mm",
        "backfill_ratio",
        "peak_torque_nm",
        "energy_j",
    ] {
        assert!(metrics.contains_key(key), "{key} missing from {metrics:?}");
    }
    assert_eq!(metrics["opening_diameter_mm"], opening);
    // The mouth against the settled surface: no wider than against the original one unless
    // the surface rose, and a hole as wide as the auger at least (mm).
    let settled = r.settled_opening_diameter_mm.unwrap();
    let subsidence = r.surface_subsidence_mm.unwrap();
    assert_eq!(metrics["settled_opening_diameter_mm"], settled);
    assert!(subsidence.abs() < 0.5 * r.feed_depth_mm, "{}", brief(r));
    assert!(
        subsidence < 0.0 || settled <= opening + 1e-9,
        "{}",
        brief(r)
    );
    assert!(settled >= 0.8 * r.auger_diameter_mm, "{}", brief(r));
    // Pictures and CSV.
    let section = run.section_svg();
    assert!(section.starts_with("<?xml") && section.contains("<circle"));
    let forces = run.forces_svg();
    assert!(forces.contains("<polyline"));
    assert_eq!(run.forces_csv().lines().count(), r.series.len() + 1);
}

#[test]
fn torque_rises_when_the_auger_enters_the_soil() {
    let r = &deep().result;
    let mean = |pick: &dyn Fn(f64) -> bool| {
        let v: Vec<f64> = r
            .series
            .iter()
            .filter(|p| pick(p.tip_depth_mm) && p.time_s < 0.7)
            .map(|p| p.torque_nm)
            .collect();
        assert!(!v.is_empty());
        v.iter().sum::<f64>() / v.len() as f64
    };
    let in_air = mean(&|d| d < -1.0);
    let in_soil = mean(&|d| d > 15.0);
    assert!(in_soil > 1e-3, "torque in the soil {in_soil} N·m");
    assert!(
        in_soil > 10.0 * in_air.abs(),
        "{in_air} in air, {in_soil} in soil"
    );
    assert!(r.peak_torque_nm >= in_soil);
    assert!(r.mean_feed_axial_force_n > 0.0, "the soil resists the feed");
}

#[test]
fn the_effective_depth_grows_with_the_feed_depth() {
    let mut shallow = fast();
    shallow.set("drill.depth", "0.02").unwrap();
    let run = run_drill_on_bed(&shallow, bed().clone(), &mut |_| Control::Continue).unwrap();
    let r = &run.result;
    assert_eq!(r.status, DrillStatus::Ok, "{}", brief(r));
    assert!(r.bed.reused);
    let deep = &deep().result;
    let (d20, d40) = (
        r.effective_depth_mm.unwrap(),
        deep.effective_depth_mm.unwrap(),
    );
    assert!(
        d40 > d20 + 5.0,
        "20 mm feed: {d20} mm, 40 mm feed: {d40} mm"
    );
    assert!(d20 > 0.0);
}

#[test]
fn results_round_trip_through_json() {
    let r = &deep().result;
    let text = serde_json::to_string(r).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(v["opening_diameter_mm"].is_number());
    assert!(v["effective_depth_mm"].is_number());
    assert_eq!(v["status"], "ok");
    let back: DrillResult = serde_json::from_str(&text).unwrap();
    assert_eq!(back.status, r.status);
    assert_eq!(back.series.len(), r.series.len());
    let (a, b) = (back.metrics(), r.metrics());
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (k, x) in &a {
        assert!((x - b[k]).abs() <= 1e-12 * b[k].abs().max(1.0), "{k}");
    }
    // (serde_json's default float parsing may be one ulp off, so no exact comparison here; the
    // bed, which must be exact, stores bits.)
}

#[test]
fn a_bed_for_other_parameters_is_refused_and_cancel_stops() {
    let mut other = fast();
    other.set("soil_soil.static_friction", "0.6").unwrap();
    let err = run_drill_on_bed(&other, bed().clone(), &mut |_| Control::Continue).unwrap_err();
    assert!(matches!(err, DrillError::BedMismatch(_)), "{err}");
    // Cancel during the bed build is an error; during drilling, a cancelled result.
    assert_eq!(
        build_bed(&fast(), &mut |_| Control::Cancel).unwrap_err(),
        DrillError::Cancelled
    );
    let mut calls = 0;
    let run = run_drill_on_bed(&fast(), bed().clone(), &mut |p| {
        calls += 1;
        assert!((0.0..=1.0).contains(&p.fraction));
        if p.time > 0.05 {
            Control::Cancel
        } else {
            Control::Continue
        }
    })
    .unwrap();
    assert_eq!(run.result.status, DrillStatus::Cancelled);
    assert!(run.result.metrics().is_empty());
    assert!(run.result.simulated_time_s < 0.2);
    assert!(calls > 1);
}

/// An in-memory [`BedStore`] that counts what it was asked.
#[derive(Default)]
struct MemoryBeds {
    beds: std::collections::HashMap<String, SettledBed>,
    hits: usize,
    puts: usize,
}

impl BedStore for MemoryBeds {
    fn get(&mut self, key: &str) -> Option<SettledBed> {
        let bed = self.beds.get(key).cloned();
        self.hits += usize::from(bed.is_some());
        bed
    }
    fn put(&mut self, bed: &SettledBed) {
        self.puts += 1;
        self.beds.insert(bed.key.clone(), bed.clone());
    }
}

#[test]
fn a_job_reuses_a_stored_bed_with_the_same_outcome_and_keeps_a_new_one() {
    let spec = prepare_spec("drill", Some("fast"), &serde_json::json!({})).unwrap();
    let seed = fast().seed;
    // A store holding the fast bed: the job drills it instead of building one, and the
    // metrics are those of a run that built its own bed, bit for bit.
    let mut store = MemoryBeds::default();
    store.put(bed());
    let outcome =
        run_experiment_with_beds("drill", &spec, seed, &mut |_| Control::Continue, &mut store)
            .unwrap();
    assert_eq!(store.hits, 1);
    assert_eq!(outcome.details["bed"]["reused"], true);
    assert_eq!(outcome.metrics, deep().result.metrics());

    // An empty store: the job builds the bed (the same one) and keeps it under its key.
    let mut empty = MemoryBeds::default();
    let mut shallow = spec.clone();
    shallow["drill"]["depth"] = serde_json::json!(0.02);
    let outcome = run_experiment_with_beds(
        "drill",
        &shallow,
        seed,
        &mut |_| Control::Continue,
        &mut empty,
    )
    .unwrap();
    assert_eq!((empty.hits, empty.puts), (0, 1));
    assert_eq!(outcome.details["bed"]["reused"], false);
    let mut kept = empty
        .beds
        .remove(&bed().key)
        .expect("kept under the fast bed's key");
    kept.wall_time_s = bed().wall_time_s;
    assert_eq!(&kept, bed());
}

#[test]
fn runs_of_a_batch_share_a_bed_only_when_its_seed_is_fixed() {
    let (mut a, mut b) = (fast(), fast());
    a.seed = 1;
    b.seed = 2;
    assert_ne!(
        bed_key(&a),
        bed_key(&b),
        "the bed follows the run's seed by default"
    );
    a.set("bed.seed", "7").unwrap();
    b.set("bed.seed", "7").unwrap();
    assert_eq!(bed_key(&a), bed_key(&b));
}

#[test]
fn an_stl_drill_makes_the_same_kind_of_hole_as_the_generated_auger() {
    // The generated fast auger, exported as STL (float32 corners) and drilled like any model.
    let mut spec = fast();
    spec.auger_stl = Some(StlDrill::from_bytes(&common::fast_auger_stl(), 1.0));
    spec.validate().unwrap();
    let run = run_drill_on_bed(&spec, bed().clone(), &mut |_| Control::Continue).unwrap();
    let r = &run.result;
    assert_eq!(r.status, DrillStatus::Ok, "{}", brief(r));
    let generated = &deep().result;
    let (stl_open, gen_open) = (
        r.opening_diameter_mm.unwrap(),
        generated.opening_diameter_mm.unwrap(),
    );
    assert!(stl_open >= r.auger_diameter_mm, "{}", brief(r));
    assert!(
        (stl_open - gen_open).abs() < 0.2 * gen_open,
        "STL {stl_open} mm vs generated {gen_open} mm"
    );
    assert!(r.effective_depth_mm.unwrap() > 0.0);
}
