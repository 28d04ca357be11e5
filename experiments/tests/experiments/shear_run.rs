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
/// envelope is not a straight line through the origin at these low stresses (4-12 kPa): it is
/// curved (τ/σ falls as σ rises), so a straight line through three points meets the τ axis
/// above zero, in the measurement window far from the walls as in the box's forces (docs/shear.md,
/// "Where the strength is read"). At the fast preset the window's cohesionless intercept is
/// 0.73 ± 0.24 kPa (the box's 1.12 ± 0.56); half the paper's cohesion still tells "no cohesion"
/// from the cohesion the calibration aims at.
#[test]
fn a_cohesionless_soil_has_a_cohesion_near_zero() {
    let r = &cohesionless().result;
    println!("{}", brief(r));
    assert_eq!(r.status, ShearStatus::Ok, "{:?}", r.message);
    let (c, phi) = fit(r);
    assert!(c.abs() < 1.25, "cohesion {c} kPa without cohesion");
    assert!((15.0..40.0).contains(&phi), "friction angle {phi}°");
    let window = r.window_fit.unwrap();
    assert!(window.r_squared > 0.9, "R² {}", window.r_squared);
    assert!(window.cohesion_std_error_kpa.is_some());
    assert!(r.peak_fit.is_some() && r.residual_fit.is_some());
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
        // The walls' friction holds part of the lid's load near them: the middle of the
        // plane carries more than the mean (measured 1.17-1.31 times the lid's target).
        let middle = stage.window_normal_stress_kpa / stage.normal_stress_kpa;
        assert!(
            (1.0..1.5).contains(&middle),
            "window at {middle} of the target"
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
        "box_cohesion_kpa",
        "came_to_rest",
    ] {
        assert!(m.contains_key(key), "{key} missing from {m:?}");
    }
    assert_eq!(m["came_to_rest"], 1.0);
}

/// Spheres with almost no sliding friction (μs 0.05) against the paper's 0.442: the friction
/// angle must be clearly larger with friction. Measured at this preset (window's line): 17.4°
/// at μs 0.05, 35.8° at 0.442.
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

/// Linear cohesion of 1e5 J/m³ against none, on the same (cohesionless) pour: the intercept
/// must rise by more than 1 kPa and every stage's peak, in the window and in the box, must
/// rise. Measured at the fast preset (window's line): c 0.73 → 3.87 kPa (standard errors 0.24
/// and 0.23), φ 35.8° → 30.3°, window peaks 4.44/7.77/10.74 → 6.81/9.71/12.31 kPa. (Past about
/// 2.5e5 J/m³ the test stops measuring a strength, docs/shear.md: at 3e5 the window's peaks
/// fall below the cohesionless ones while its intercept still rises, 2.35 kPa at φ 19.2°.)
#[test]
fn cohesion_rises_with_the_cohesion_energy_density() {
    let mut cohesive = ShearSpec::fast();
    cohesive
        .set(
            "soil_soil.cohesion",
            r#"{"model":"linear","energy_density":1e5}"#,
        )
        .unwrap();
    let r = run(&cohesive).result;
    println!("{}", brief(&r));
    let (c, _) = fit(&r);
    let base = &cohesionless().result;
    let (c0, _) = fit(base);
    assert!(c > c0 + 1.0, "c {c} kPa with 1e5 J/m³, {c0} kPa without");
    for (with, without) in r.stages.iter().zip(&base.stages) {
        assert!(
            with.peak_kpa > without.peak_kpa && with.window_peak_kpa > without.window_peak_kpa,
            "at {} kPa: peaks (box, window) {} / {} kPa with cohesion, {} / {} without",
            with.normal_stress_kpa,
            with.peak_kpa,
            with.window_peak_kpa,
            without.peak_kpa,
            without.window_peak_kpa
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
    assert!(matches!(err, Err(ShearError::BedMismatch(_))), "{err:?}");
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
