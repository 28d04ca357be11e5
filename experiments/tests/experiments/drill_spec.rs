//! DrillSpec: presets, dotted-path edits shared with AorSpec, validation naming the field, bed
//! keys.

use crate::common;
use repose_experiments::aor::AorSpec;
use repose_experiments::Spec;

use common::fast_auger_stl;
use repose_engine::math::Pose;
use repose_experiments::drill::{bed_key, DrillSpec, SpecError, StlDrill, PRESETS};

#[test]
fn presets_validate_and_round_trip_through_json() {
    for name in PRESETS {
        let spec = DrillSpec::preset(name).unwrap();
        spec.validate().unwrap();
        assert_eq!(
            DrillSpec::from_json(&spec.to_json()).unwrap(),
            spec,
            "{name}"
        );
    }
    let paper = DrillSpec::paper();
    assert_eq!(paper.auger.outer_diameter, 0.06);
    assert_eq!(paper.drill.rpm, 400.0);
    assert!(paper.drill.clockwise);
    assert_eq!(paper.drill.feed_speed, 0.02);
    assert_eq!(paper.drill.withdraw_speed, 0.02);
    assert_eq!(DrillSpec::full_scale().drill.depth, 0.6);
    assert!(matches!(
        DrillSpec::preset("huge"),
        Err(SpecError::Invalid { path, .. }) if path == "preset"
    ));
}

#[test]
fn calibration_factor_paths_are_the_same_as_the_angle_of_repose_test() {
    let mut aor = AorSpec::paper();
    let mut drill = DrillSpec::paper();
    assert_eq!(aor.soil_soil, drill.soil_soil);
    assert_eq!(aor.soil_steel, drill.soil_steel);
    assert_eq!(aor.materials, drill.materials);
    for (path, value) in [
        ("soil_soil.restitution", "0.5"),
        ("soil_soil.static_friction", "0.48"),
        ("soil_soil.rolling_friction", "0.2"),
        ("soil_steel.restitution", "0.3"),
        ("soil_steel.static_friction", "0.35"),
        ("soil_steel.rolling_friction", "0.4"),
        ("materials.soil.density", "2600"),
        ("materials.steel.youngs_modulus", "2e11"),
        ("rolling_model", "epsd"),
        ("particle.radius", "0.003"),
    ] {
        if path != "particle.radius" {
            aor.set(path, value).unwrap();
        }
        let result = drill.set(path, value);
        if path == "particle.radius" {
            // The drilling preset's grains are a uniform distribution: no `radius` key.
            assert!(
                matches!(result, Err(SpecError::UnknownPath { .. })),
                "{result:?}"
            );
        } else {
            result.unwrap();
        }
    }
    assert_eq!(aor.soil_soil, drill.soil_soil);
    assert_eq!(aor.soil_steel, drill.soil_steel);
    assert_eq!(aor.materials, drill.materials);
    assert_eq!(aor.rolling_model, drill.rolling_model);
    drill
        .set("particle", r#"{"kind":"fixed","radius":0.003}"#)
        .unwrap();
    drill.set("particle.radius", "0.0032").unwrap();
    drill.validate().unwrap();
}

fn invalid_path(spec: &DrillSpec) -> String {
    match spec.validate() {
        Err(SpecError::Invalid { path, reason }) => {
            let message = spec.validate().unwrap_err().to_string();
            assert!(message.contains(&path), "{message}");
            assert!(!reason.is_empty());
            path
        }
        other => panic!("expected an invalid field, got {other:?}"),
    }
}

#[test]
fn validation_errors_name_the_field() {
    let cases: [(&str, &str, &str); 12] = [
        ("drill.depth", "-0.1", "drill.depth"),
        ("drill.rpm", "0", "drill.rpm"),
        ("drill.feed_speed", "0", "drill.feed_speed"),
        ("drill.withdraw_speed", "-1", "drill.withdraw_speed"),
        ("auger.shaft_diameter", "0.07", "auger.shaft_diameter"),
        ("auger.flight_thickness", "0.07", "auger.flight_thickness"),
        ("auger.outer_diameter", "0.5", "auger.outer_diameter"),
        ("bin.size_x", "0", "bin.size_x"),
        ("bed.depth", "0.5", "bed.depth"),
        ("bed.packing_fraction", "0.9", "bed.packing_fraction"),
        ("settle.time_cap", "0", "settle.time_cap"),
        (
            "time_step_rayleigh_fraction",
            "1.5",
            "time_step_rayleigh_fraction",
        ),
    ];
    for (path, value, named) in cases {
        let mut spec = DrillSpec::paper();
        spec.set(path, value).unwrap();
        assert_eq!(invalid_path(&spec), named, "{path}={value}");
    }
    // Too deep for the bed: named as the drill depth.
    let mut spec = DrillSpec::paper();
    spec.set("drill.depth", "0.149").unwrap();
    assert_eq!(invalid_path(&spec), "drill.depth");
    let mut spec = DrillSpec::fast();
    spec.set("bed.settle.kinetic_energy_threshold", "0")
        .unwrap();
    assert_eq!(invalid_path(&spec), "bed.settle.kinetic_energy_threshold");
}

#[test]
fn bad_paths_and_values_are_reported_and_leave_the_spec_unchanged() {
    let mut spec = DrillSpec::fast();
    let before = spec.clone();
    match spec.set("drill.speed", "0.1") {
        Err(SpecError::UnknownPath { path, key, valid }) => {
            assert_eq!(path, "drill.speed");
            assert_eq!(key, "speed");
            assert!(valid.contains("feed_speed"), "{valid}");
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        spec.set("drill.rpm", "fast"),
        Err(SpecError::BadValue { .. })
    ));
    assert!(matches!(
        spec.apply_assignments(["drill.rpm"]),
        Err(SpecError::NotAnAssignment(_))
    ));
    assert_eq!(spec, before);
    spec.apply_assignments(["drill.rpm=300", "bed.seed=7"])
        .unwrap();
    assert_eq!(spec.drill.rpm, 300.0);
    assert_eq!(spec.bed_seed(), 7);
    let err = DrillSpec::from_json(r#"{"auger": {"diameter": 0.06}}"#).unwrap_err();
    assert!(matches!(err, SpecError::Parse(ref m) if m.contains("DrillSpec")));
}

#[test]
fn the_bed_key_follows_the_bed_inputs_only() {
    let base = DrillSpec::fast();
    let key = bed_key(&base);
    assert!(key.starts_with("bed-v2-"), "{key}");
    for (path, value) in [
        ("drill.depth", "0.03"),
        ("drill.rpm", "600"),
        ("auger.pitch", "0.03"),
        ("settle.time_cap", "2"),
        ("measure.series_interval", "0.1"),
        ("wall_time_cap", "100"),
    ] {
        let mut spec = base.clone();
        spec.set(path, value).unwrap();
        assert_eq!(bed_key(&spec), key, "{path} must not change the bed");
    }
    for (path, value) in [
        ("soil_soil.static_friction", "0.5"),
        ("soil_steel.rolling_friction", "0.3"),
        ("materials.soil.youngs_modulus", "4e6"),
        ("bin.size_x", "0.1"),
        ("bed.depth", "0.07"),
        ("seed", "2"),
        ("time_step_rayleigh_fraction", "0.25"),
    ] {
        let mut spec = base.clone();
        spec.set(path, value).unwrap();
        assert_ne!(bed_key(&spec), key, "{path} must change the bed");
    }
    // A fixed bed seed shares one bed across run seeds.
    let mut a = base.clone();
    a.apply_assignments(["bed.seed=5", "seed=1"]).unwrap();
    let mut b = base.clone();
    b.apply_assignments(["bed.seed=5", "seed=2"]).unwrap();
    assert_eq!(bed_key(&a), bed_key(&b));
}

#[test]
fn an_stl_drill_is_checked_against_the_stated_diameter_and_its_tip() {
    let stl = fast_auger_stl();
    let mut spec = DrillSpec::fast();
    spec.auger_stl = Some(StlDrill::from_bytes(&stl, 1.0));
    spec.validate().unwrap();
    // Round trip through JSON (the spec a job server stores and sends).
    let back = DrillSpec::from_json(&spec.to_json()).unwrap();
    assert_eq!(back, spec);

    // A model in the wrong units is not the stated diameter.
    spec.auger_stl = Some(StlDrill::from_bytes(&stl, 2.0));
    assert_eq!(invalid_path(&spec), "auger.outer_diameter");
    // Not base64, or not an STL.
    spec.auger_stl = Some(StlDrill {
        base64: "%%%".into(),
        scale: 1.0,
    });
    assert_eq!(invalid_path(&spec), "auger_stl");
    spec.auger_stl = Some(StlDrill::from_bytes(b"solid nothing here", 1.0));
    assert_eq!(invalid_path(&spec), "auger_stl");
    // The tip must be at the origin.
    let lifted = repose_engine::mesh::TriMesh::from_stl_bytes(&stl, 1.0)
        .unwrap()
        .transformed(&Pose::translation(0.0, 0.0, 0.01))
        .unwrap()
        .to_stl_binary();
    spec.auger_stl = Some(StlDrill::from_bytes(&lifted, 1.0));
    assert_eq!(invalid_path(&spec), "auger_stl");
}

/// A stored bed comes back equal to the bed, every float to the last bit. (The first stored
/// form wrote the surface height and the build's figures as decimals, and serde_json's default
/// float parser reads some, such as 1.7301083670000001, one ulp off.)
#[test]
fn a_stored_bed_comes_back_to_the_last_bit() {
    use repose_experiments::drill::{SettledBed, SettledBy};
    let awkward = 1.7301083670000001_f64;
    let bed = SettledBed {
        key: "bed-v2-0123456789abcdef".into(),
        positions: vec![[awkward, -0.0, 1e-300]],
        velocities: vec![[f64::MIN_POSITIVE, 0.1 + 0.2, -awkward]],
        angular_velocities: vec![[3.0, 1.0 / 3.0, 7e22]],
        radii: vec![0.000_5 * awkward],
        surface_z: 0.05 * awkward,
        settled: true,
        settled_by: SettledBy::TimeCap,
        kinetic_energy_ratio: awkward * 1e-4,
        simulated_time_s: awkward,
        steps: 123_456,
        wall_time_s: awkward,
        escaped: 7,
    };
    let back: SettledBed = serde_json::from_str(&serde_json::to_string(&bed).unwrap()).unwrap();
    let bits = |b: &SettledBed| {
        [
            b.surface_z,
            b.kinetic_energy_ratio,
            b.simulated_time_s,
            b.wall_time_s,
        ]
        .map(f64::to_bits)
    };
    assert_eq!(bits(&back), bits(&bed));
    assert_eq!(back, bed);
    // Through a generic JSON value too (what the worker's bed store and the API pass along).
    let value = serde_json::to_value(&bed).unwrap();
    let back: SettledBed = serde_json::from_value(value).unwrap();
    assert_eq!(back, bed);
}
