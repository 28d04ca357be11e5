//! The triaxial test on the CPU engine, on the `ci` preset (about 500 grains of 4 mm, two
//! confining pressures): deterministic, its readings move the way the physics says they
//! must, and bad specs are refused by field. The `fast` figures are in the ignored tests.

use repose_experiments::catalog::{prepare_spec, ExperimentError, ExperimentSpec, NoBedStore};
use repose_experiments::soil::{run_on_bed, OnBed, SettledBed};
use repose_experiments::triaxial::{
    run_triaxial, Control, TriaxialOn, TriaxialResult, TriaxialSpec, TriaxialStatus,
};
use repose_experiments::Spec;
use serde_json::json;

pub fn print(label: &str, r: &TriaxialResult) {
    eprintln!(
        "{label}: {:?} c {:?} kPa φ {:?}° E {:?} MPa ν {:?} e {:.3}, {} grains, {} steps, wall {:.1} s",
        r.status,
        r.cohesion_kpa,
        r.friction_angle_deg,
        r.young_modulus_mpa,
        r.poisson_ratio,
        r.void_ratio,
        r.particles,
        r.steps,
        r.wall_time_s
    );
    for s in &r.stages {
        eprintln!(
            "  σ3 {} kPa: q {:.3} kPa at εa {:.3} (peaked {}), σ3 read {:.3}, εv {:.4}, e {:.3}, \
             E50 {:?}, ν {:?}, I {:.1e}, consolidated {} in {:.3} s",
            s.confining_kpa,
            s.peak_deviator_kpa,
            s.axial_strain_at_peak,
            s.peaked,
            s.failure_confining_kpa,
            s.volumetric_strain_at_peak,
            s.void_ratio,
            s.young_modulus_mpa,
            s.poisson_ratio,
            s.inertial_number,
            s.consolidated,
            s.consolidation_time_s
        );
    }
}

fn run(label: &str, spec: &TriaxialSpec) -> TriaxialResult {
    let r = run_triaxial(spec, &mut |_| Control::Continue)
        .unwrap()
        .result;
    print(label, &r);
    r
}

fn ci(set: &[(&str, &str)]) -> TriaxialSpec {
    let mut spec = TriaxialSpec::ci();
    for (path, value) in set {
        spec.set(path, value).unwrap();
    }
    spec
}

fn phi(r: &TriaxialResult) -> f64 {
    r.friction_angle_deg.expect("an envelope")
}

/// The same seed gives the same result to the bit, the specimen prepared here or taken from a
/// store; every stage consolidates, the loading is quasi-static (I < 1e-3), and the specimen
/// is a packing (void ratio between a dense and a loose random packing of spheres).
#[test]
fn the_same_seed_gives_the_same_result_to_the_bit() {
    let spec = TriaxialSpec::ci();
    let on = TriaxialOn::cpu(&spec);
    let bed: SettledBed = on.build_bed(&mut |_| Control::Continue).unwrap();
    assert!(
        bed.settled,
        "the ci specimen is prepared within its time cap"
    );
    let a = on
        .run_on_matching_bed(bed.clone(), &mut |_| Control::Continue)
        .unwrap()
        .result;
    let b = run_on_bed(&on, &mut NoBedStore, &mut |_| Control::Continue)
        .unwrap()
        .result;
    print("ci", &b);
    assert_eq!(a.stages, b.stages);
    assert_eq!(a.envelope, b.envelope);
    assert_eq!(b.status, TriaxialStatus::Ok, "{:?}", b.message);
    for s in &b.stages {
        assert!(s.inertial_number < 1e-3, "{}", s.inertial_number);
        assert!(s.escaped == 0);
        assert!(s.peak_deviator_kpa > 0.0);
    }
    assert!(b.void_ratio > 0.5 && b.void_ratio < 1.0, "{}", b.void_ratio);
    // Metrics a job server stores.
    let m = b.metrics();
    for key in [
        "cohesion_kpa",
        "friction_angle_deg",
        "young_modulus_mpa",
        "poisson_ratio",
        "void_ratio",
        "max_inertial_number",
    ] {
        assert!(m.contains_key(key), "{key}: {m:?}");
    }
}

/// φ rises with the soil-soil static friction and with the rolling friction; c rises with the
/// cohesion energy density. Four `ci` runs around one with little rolling friction (μr 0.02):
/// static friction 0.1 instead of 0.442, rolling friction 0.5, linear cohesion of 2e5 J/m³
/// (measured: c −0.15, 0.24, 0.52 and 3.93 kPa at 0, 5e4, 1e5 and 2e5 J/m³).
#[test]
fn friction_raises_phi_and_cohesion_raises_c() {
    let base = run("μr 0.02", &ci(&[("soil_soil.rolling_friction", "0.02")]));
    let smooth = run(
        "μs 0.1, μr 0.02",
        &ci(&[
            ("soil_soil.rolling_friction", "0.02"),
            ("soil_soil.static_friction", "0.1"),
        ]),
    );
    assert!(
        phi(&base) > phi(&smooth) + 5.0,
        "{} against {}",
        phi(&base),
        phi(&smooth)
    );
    let rolling = run("μr 0.5", &ci(&[("soil_soil.rolling_friction", "0.5")]));
    assert!(
        phi(&rolling) > phi(&base) + 2.0,
        "{} against {}",
        phi(&rolling),
        phi(&base)
    );
    let sticky = run(
        "μr 0.02, cohesion 2e5",
        &ci(&[
            ("soil_soil.rolling_friction", "0.02"),
            (
                "soil_soil.cohesion",
                r#"{"model":"linear","energy_density":2e5}"#,
            ),
        ]),
    );
    let c_base = base.cohesion_kpa.unwrap();
    let c_sticky = sticky.cohesion_kpa.unwrap();
    assert!(c_sticky > c_base + 1.0, "{c_sticky} against {c_base}");
}

/// A job's spec completes from the `ci` preset, runs through the catalog, and names its
/// pictures; bad fields are refused by path.
#[test]
fn the_catalog_runs_the_kind_and_refuses_bad_fields_by_path() {
    let spec = prepare_spec("triaxial", Some("ci"), &json!({})).unwrap();
    let parsed = ExperimentSpec::parse_job("triaxial", &spec).unwrap();
    assert!(parsed.bed_key(3).unwrap().starts_with("specimen-v"));
    for (over, path) in [
        (
            json!({"confining_pressures_kpa": [5.0]}),
            "confining_pressures_kpa",
        ),
        (
            json!({"confining_pressures_kpa": [5.0, -1.0]}),
            "confining_pressures_kpa[1]",
        ),
        (json!({"specimen": {"width": 0.004}}), "specimen.width"),
        (
            json!({"loading": {"axial_strain": 0.5}}),
            "loading.axial_strain",
        ),
        (
            json!({"preparation": {"friction": -0.1}}),
            "preparation.friction",
        ),
    ] {
        match prepare_spec("triaxial", Some("ci"), &over) {
            Err(ExperimentError::InvalidSpec { path: Some(p), .. }) => assert_eq!(p, path),
            other => panic!("{over}: {other:?}"),
        }
    }
    assert!(prepare_spec("triaxial", Some("ci"), &json!({"membrane": 1})).is_err());
    let out = parsed
        .run(
            5,
            &mut |_| Control::Continue,
            &mut NoBedStore,
            &mut repose_experiments::catalog::NoCheckpoints,
        )
        .unwrap();
    let names: Vec<&str> = out.pictures.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["mohr_circles.svg", "triaxial_curves.svg", "specimen.svg"]
    );
    assert!(out.metrics["friction_angle_deg"] > 10.0);
    assert!(serde_json::to_string(&out.details).unwrap().len() < 64 * 1024);
}
