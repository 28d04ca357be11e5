//! The direct shear test at the `fast` preset (a 50 mm box, about 1 000 grains, three normal
//! stresses). Each run takes about 40 s of wall time here (2 cores, load 2-4); the cohesionless
//! run is shared by the tests that only read it.

use repose_experiments::Spec;
use std::sync::OnceLock;

use repose_experiments::shear::{
    run_shear, run_shear_on_bed, Control, ShearError, ShearResult, ShearRun, ShearSpec, ShearStatus,
};

fn run(spec: &ShearSpec) -> ShearRun {
    run_shear(spec, &mut |_| Control::Continue).unwrap()
}

/// The fast preset: the paper's calibrated friction, no cohesion.
fn cohesionless() -> &'static ShearRun {
    static RUN: OnceLock<ShearRun> = OnceLock::new();
    RUN.get_or_init(|| run(&ShearSpec::fast()))
}

fn brief(r: &ShearResult) -> String {
    let mut r = r.clone();
    for s in &mut r.stages {
        s.series.clear();
    }
    serde_json::to_string_pretty(&r).unwrap()
}

fn fit(r: &ShearResult) -> (f64, f64) {
    (r.cohesion_kpa.unwrap(), r.friction_angle_deg.unwrap())
}

/// Tolerance: |c| < 1.25 kPa, half the paper's 2.5 kPa. A cohesionless packing's strength
/// envelope is not a straight line through the origin at these low stresses (4-12 kPa): dilation
/// and the box's edges add strength that does not scale with σ, so a straight line through
/// three points meets the τ axis above zero. At the fast preset the cohesionless intercept was
/// 0.45-0.95 kPa for interparticle friction 0.2-0.8 (docs/shear.md), with a standard error of
/// 0.25 kPa; half the paper's cohesion still tells "no cohesion" from the cohesion the
/// calibration aims at.
#[test]
fn a_cohesionless_soil_has_a_cohesion_near_zero() {
    let r = &cohesionless().result;
    println!("{}", brief(r));
    assert_eq!(r.status, ShearStatus::Ok, "{:?}", r.message);
    let (c, phi) = fit(r);
    assert!(c.abs() < 1.25, "cohesion {c} kPa without cohesion");
    assert!((15.0..40.0).contains(&phi), "friction angle {phi}°");
    let peak = r.peak_fit.unwrap();
    assert!(peak.r_squared > 0.9, "R² {}", peak.r_squared);
    assert!(peak.cohesion_std_error_kpa.is_some());
    for stage in &r.stages {
        assert!(stage.consolidated);
        // The lid held its stress while shearing, and the plane carries about that stress.
        let lid = stage.mean_lid_stress_kpa / stage.normal_stress_kpa;
        assert!((0.95..1.05).contains(&lid), "lid at {lid} of its target");
        let plane = stage.plane_normal_stress_kpa / stage.normal_stress_kpa;
        assert!(
            (0.8..1.1).contains(&plane),
            "plane at {plane} of the target"
        );
        assert!(stage.series.len() > 100);
        assert!(stage.peak_kpa > 0.2 * stage.normal_stress_kpa);
        assert_eq!(stage.escaped, 0);
    }
    let m = r.metrics();
    for key in [
        "cohesion_kpa",
        "friction_angle_deg",
        "r_squared",
        "came_to_rest",
    ] {
        assert!(m.contains_key(key), "{key} missing from {m:?}");
    }
    assert_eq!(m["came_to_rest"], 1.0);
}

/// Spheres with almost no sliding friction (μs 0.05) against the paper's 0.442: the friction
/// angle must be clearly larger with friction. (Between 0.2 and 0.8 it hardly changes at this
/// preset, 24.7° → 22.2°: with the paper's rolling friction 0.14 the grains roll rather than
/// slide once μs passes about 0.2; see docs/shear.md.)
#[test]
fn the_friction_angle_rises_with_interparticle_friction() {
    let mut slippery = ShearSpec::fast();
    slippery.soil_soil.static_friction = 0.05;
    let low = run(&slippery).result;
    println!("{}", brief(&low));
    let (_, phi_low) = fit(&low);
    let (_, phi) = fit(&cohesionless().result);
    assert!(
        phi > phi_low + 3.0,
        "φ {phi}° at μs 0.442, {phi_low}° at μs 0.05"
    );
}

/// Linear cohesion of 3e5 J/m³ against none, on the same (cohesionless) pour: the intercept
/// must rise by more than 0.3 kPa and every stage's peak must rise. Measured at the fast
/// preset: c 0.92 → 1.45 kPa, peaks 2.87/4.15/5.98 → 3.12/4.68/6.20 kPa (φ 24.7° → 21.0°). The
/// margin is small against the cohesionless fit's standard error (0.35 kPa), but the runs are
/// deterministic for a seed, and the peaks rising at every stress is the stronger evidence.
#[test]
fn cohesion_rises_with_the_cohesion_energy_density() {
    let mut cohesive = ShearSpec::fast();
    cohesive
        .set(
            "soil_soil.cohesion",
            r#"{"model":"linear","energy_density":3e5}"#,
        )
        .unwrap();
    let r = run(&cohesive).result;
    println!("{}", brief(&r));
    let (c, _) = fit(&r);
    let base = &cohesionless().result;
    let (c0, _) = fit(base);
    assert!(c > c0 + 0.3, "c {c} kPa with 3e5 J/m³, {c0} kPa without");
    for (with, without) in r.stages.iter().zip(&base.stages) {
        assert!(
            with.peak_kpa > without.peak_kpa,
            "at {} kPa: peak {} kPa with cohesion, {} without",
            with.normal_stress_kpa,
            with.peak_kpa,
            without.peak_kpa
        );
    }
}

/// Every stage starts from the same sample: run on the stored sample with only the first
/// normal stress and one more, the first stage is the same, bit for bit; the sample survives
/// JSON exactly; a sample for other parameters is refused.
#[test]
fn stages_reuse_one_sample_and_a_stored_sample_gives_the_same_stage() {
    let base = cohesionless();
    let text = serde_json::to_string(&base.bed).unwrap();
    let stored = serde_json::from_str(&text).unwrap();
    let mut spec = ShearSpec::fast();
    spec.normal_stresses_kpa = vec![4.0, 6.0];
    let again = run_shear_on_bed(&spec, stored, &mut |_| Control::Continue).unwrap();
    assert!(again.result.bed.reused);
    assert_eq!(again.result.stages[0], base.result.stages[0]);
    assert_eq!(again.result.stages.len(), 2);

    let mut other = ShearSpec::fast();
    other.soil_soil.static_friction = 0.3;
    let err = run_shear_on_bed(&other, base.bed.clone(), &mut |_| Control::Continue);
    assert!(
        matches!(err, Err(ShearError::BedMismatch { .. })),
        "{err:?}"
    );
}

#[test]
fn results_and_pictures_are_well_formed() {
    let run = cohesionless();
    let text = serde_json::to_string(&run.result).unwrap();
    // serde_json reads floats to within an ulp (no `float_roundtrip`), as the drilling tests
    // allow: the structure and the values to 1e-12 come back.
    let back: ShearResult = serde_json::from_str(&text).unwrap();
    assert_eq!(back.status, run.result.status);
    assert_eq!(back.stages.len(), run.result.stages.len());
    let (a, b) = (back.metrics(), run.result.metrics());
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (k, v) in &a {
        assert!(
            (v - b[k]).abs() <= 1e-12 * b[k].abs().max(1.0),
            "{k}: {v} vs {}",
            b[k]
        );
    }
    for svg in [run.curves_svg(), run.strength_svg()] {
        let doc = roxmltree::Document::parse(&svg).unwrap();
        let circles = doc
            .descendants()
            .filter(|n| n.has_tag_name("circle"))
            .count();
        assert!(circles >= run.result.stages.len(), "{circles} points");
    }
    let csv = run.curves_csv();
    let rows = csv.lines().count() - 1;
    let samples: usize = run.result.stages.iter().map(|s| s.series.len()).sum();
    assert_eq!(rows, samples);
}

#[test]
fn cancel_stops_the_run() {
    let mut calls = 0;
    let err = run_shear(&ShearSpec::fast(), &mut |p| {
        calls += 1;
        if p.phase == "consolidating" {
            Control::Cancel
        } else {
            Control::Continue
        }
    });
    assert!(matches!(err, Err(ShearError::Cancelled)), "{err:?}");
    assert!(calls > 1);
}
