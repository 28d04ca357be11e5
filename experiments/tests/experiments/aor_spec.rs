//! The experiment spec: presets, JSON round trip, dotted-path edits and their errors.

use repose_experiments::aor::{AorSpec, Protocol, RollingSpec, SpecError};
use repose_experiments::Spec;

#[test]
fn paper_defaults_are_table_1_and_the_calibrated_point() {
    let s = AorSpec::default();
    assert_eq!(s.protocol, Protocol::Funnel);
    assert_eq!(s.materials.soil.density, 2664.0);
    assert_eq!(s.materials.soil.youngs_modulus, 3.67e6);
    assert_eq!(s.materials.soil.poisson, 0.36);
    assert_eq!(s.materials.steel.density, 7850.0);
    assert_eq!(s.materials.steel.youngs_modulus, 2.1e11);
    assert_eq!(s.materials.steel.poisson, 0.30);
    assert_eq!(
        [
            s.soil_soil.restitution,
            s.soil_soil.static_friction,
            s.soil_soil.rolling_friction
        ],
        [0.45, 0.442, 0.140]
    );
    assert_eq!(
        [
            s.soil_steel.restitution,
            s.soil_steel.static_friction,
            s.soil_steel.rolling_friction
        ],
        [0.40, 0.305, 0.50]
    );
    assert_eq!(s.rolling_model, RollingSpec::Cdt);
    assert_eq!(s.mass_rate, 0.15);
    assert_eq!(s.funnel.wall_inclination_deg, 60.0);
    assert_eq!(s.funnel.outlet_diameter, 0.017);
    assert_eq!(s.funnel.outlet_height, 0.105);
    assert!((s.funnel.top_diameter() - 0.0632).abs() < 1e-3);
    assert_eq!(s.base.material, "steel");
    s.validate().unwrap();
    AorSpec::fast().validate().unwrap();
    assert!(AorSpec::preset("nope").is_err());
}

#[test]
fn json_round_trip_is_exact() {
    for spec in [AorSpec::paper(), AorSpec::fast()] {
        let text = spec.to_json();
        let back = AorSpec::from_json(&text).unwrap();
        assert_eq!(back, spec);
        // Stable: serialising the parsed spec gives the same document.
        assert_eq!(back.to_json(), text);
    }
    let mut s = AorSpec::fast();
    s.set("protocol", "lifted_cylinder").unwrap();
    s.set("rolling_model", "epsd").unwrap();
    s.set("wall_time_cap", "60").unwrap();
    assert_eq!(AorSpec::from_json(&s.to_json()).unwrap(), s);
}

#[test]
fn set_reaches_every_level() {
    let mut s = AorSpec::default();
    s.set("soil_soil.rolling_friction", "0.3").unwrap();
    assert_eq!(s.soil_soil.rolling_friction, 0.3);
    s.set("particle.radius", "0.0012").unwrap();
    assert_eq!(s.to_json().matches("0.0012").count(), 1);
    s.set("total_mass", "0.05").unwrap();
    s.set("funnel.outlet_height", "0.09").unwrap();
    assert_eq!(s.funnel.outlet_height, 0.09);
    s.set("materials.steel.poisson", "0.29").unwrap();
    assert_eq!(s.materials.steel.poisson, 0.29);
    s.set("measure.directions", "12").unwrap();
    assert_eq!(s.measure.directions, 12);
    s.set("base.material", "soil").unwrap();
    assert_eq!(s.base.material, "soil");
    s.set(
        "particle",
        r#"{"kind":"uniform","min_radius":0.0009,"max_radius":0.0011}"#,
    )
    .unwrap();
    s.validate().unwrap();
    s.apply_assignments(["seed=7", " settle.angle_window = 4 "])
        .unwrap();
    assert_eq!((s.seed, s.settle.angle_window), (7, 4));
}

#[test]
fn set_errors_name_the_path_and_the_valid_keys() {
    let mut s = AorSpec::default();
    let before = s.clone();
    let e = s.set("soil_soil.rolling", "0.3").unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, SpecError::UnknownPath { .. }), "{msg}");
    assert!(msg.contains("soil_soil.rolling"), "{msg}");
    for key in ["restitution", "static_friction", "rolling_friction"] {
        assert!(msg.contains(key), "{msg}");
    }
    let msg = s.set("nonsense", "1").unwrap_err().to_string();
    assert!(
        msg.contains("soil_steel") && msg.contains("total_mass"),
        "{msg}"
    );
    // Below a leaf.
    let msg = s.set("total_mass.x", "1").unwrap_err().to_string();
    assert!(msg.contains("total_mass.x"), "{msg}");
    // Wrong type.
    let e = s.set("soil_soil.static_friction", "high").unwrap_err();
    assert!(matches!(e, SpecError::BadValue { .. }), "{e}");
    let e = s.set("protocol", "cone").unwrap_err();
    assert!(e.to_string().contains("protocol"), "{e}");
    assert!(matches!(
        s.apply_assignments(["total_mass"]),
        Err(SpecError::NotAnAssignment(_))
    ));
    assert_eq!(s, before, "failed edits leave the spec unchanged");
}

#[test]
fn validate_rejects_impossible_values_by_path() {
    let mut s = AorSpec::default();
    s.set("total_mass", "-1").unwrap();
    assert!(s
        .validate()
        .unwrap_err()
        .to_string()
        .starts_with("total_mass"));
    let mut s = AorSpec::default();
    s.set("base.material", "wood").unwrap();
    assert!(s
        .validate()
        .unwrap_err()
        .to_string()
        .contains("base.material"));
    let mut s = AorSpec::default();
    s.set("funnel.wall_inclination_deg", "90").unwrap();
    assert!(s.validate().is_err());
    let mut s = AorSpec::default();
    s.set("settle.angle_window", "1").unwrap();
    assert!(s.validate().is_err());
}

#[test]
fn the_rest_rule_fields_are_validated_by_path_and_default_when_missing() {
    let s = AorSpec::default();
    assert_eq!(
        (s.settle.creep_window_s, s.settle.max_creep_deg_per_s),
        (0.5, 0.5)
    );
    for (path, bad) in [
        ("settle.creep_window_s", "0"),
        ("settle.creep_window_s", "-0.5"),
        ("settle.creep_window_s", "1e9"),
        ("settle.max_creep_deg_per_s", "0"),
        ("settle.max_creep_deg_per_s", "-1"),
    ] {
        let mut s = AorSpec::default();
        s.set(path, bad).unwrap();
        let e = s.validate().unwrap_err();
        assert!(matches!(e, SpecError::Invalid { .. }), "{e}");
        assert!(e.to_string().starts_with(path), "{path}={bad}: {e}");
    }
    let mut s = AorSpec::default();
    s.apply_assignments([
        "settle.creep_window_s=1.0",
        "settle.max_creep_deg_per_s=0.2",
    ])
    .unwrap();
    s.validate().unwrap();
    assert_eq!(s.settle.rest_checks(), 11);
    // A spec written before the fields existed parses with the defaults.
    let mut json: serde_json::Value = serde_json::from_str(&AorSpec::default().to_json()).unwrap();
    let settle = json["settle"].as_object_mut().unwrap();
    settle.remove("creep_window_s");
    settle.remove("max_creep_deg_per_s");
    let old: AorSpec = serde_json::from_value(json).unwrap();
    assert_eq!(old, AorSpec::default());
}
