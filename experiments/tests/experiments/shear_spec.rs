//! The shear test's spec: presets validate, `--set` paths and validation errors name the
//! field, the contact parameters share the angle-of-repose factor paths, the sample key follows
//! the sample's inputs only.

use repose_experiments::aor::AorSpec;
use repose_experiments::shear::{sample_key, ShearSpec, SpecError, PRESETS};
use repose_experiments::Spec;

fn invalid_path(e: SpecError) -> String {
    match e {
        SpecError::Invalid { path, .. } => path,
        other => panic!("expected Invalid, got {other:?}"),
    }
}

#[test]
fn presets_validate_and_unknown_ones_are_refused() {
    for name in PRESETS {
        let spec = ShearSpec::preset(name).unwrap();
        spec.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(ShearSpec::from_json(&spec.to_json()).unwrap(), spec);
    }
    assert_eq!(
        invalid_path(ShearSpec::preset("huge").unwrap_err()),
        "preset"
    );
}

#[test]
fn set_reaches_every_field_and_shares_the_aor_factor_paths() {
    let mut spec = ShearSpec::fast();
    for path in [
        "soil_soil.static_friction",
        "soil_soil.rolling_friction",
        "soil_steel.static_friction",
        "materials.soil.density",
    ] {
        spec.set(path, "0.5").unwrap();
        let mut aor = AorSpec::fast();
        aor.set(path, "0.5").unwrap();
    }
    assert_eq!(spec.soil_soil.static_friction, 0.5);
    spec.set("normal_stresses_kpa", "[5, 10, 20]").unwrap();
    assert_eq!(spec.normal_stresses_kpa, vec![5.0, 10.0, 20.0]);
    spec.set("box.side", "0.06").unwrap();
    assert_eq!(spec.shear_box.side, 0.06);
    spec.set(
        "soil_soil.cohesion",
        r#"{"model":"linear","energy_density":1e5}"#,
    )
    .unwrap();
    let before = spec.clone();
    let err = spec.set("box.width", "0.1").unwrap_err();
    assert!(err.to_string().contains("side"), "{err}");
    assert_eq!(spec, before, "a failed set changes nothing");
}

#[test]
fn validation_names_the_field() {
    let cases: [(&str, &str, &str); 8] = [
        ("normal_stresses_kpa", "[5]", "normal_stresses_kpa"),
        ("normal_stresses_kpa", "[5, 5]", "normal_stresses_kpa"),
        ("normal_stresses_kpa", "[5, -1]", "normal_stresses_kpa[1]"),
        ("box.side", "0.01", "box.side"),
        ("bed.height", "0.2", "bed.height"),
        ("shear.residual_fraction", "0", "shear.residual_fraction"),
        ("consolidation.tolerance", "1.5", "consolidation.tolerance"),
        ("bed.packing_fraction", "0.9", "bed.packing_fraction"),
    ];
    for (path, value, named) in cases {
        let mut spec = ShearSpec::fast();
        spec.set(path, value).unwrap();
        assert_eq!(
            invalid_path(spec.validate().unwrap_err()),
            named,
            "{path}={value}"
        );
    }
    let mut spec = ShearSpec::fast();
    spec.set("soil_soil.static_friction", "-1").unwrap();
    assert_eq!(
        invalid_path(spec.validate().unwrap_err()),
        "soil_soil.static_friction"
    );
}

#[test]
fn the_sample_key_follows_the_sample_inputs_only() {
    let base = ShearSpec::fast();
    let key = sample_key(&base);
    let mut same = base.clone();
    same.normal_stresses_kpa = vec![1.0, 2.0];
    same.shear.speed = 0.01;
    same.servo.gain = 0.2;
    assert_eq!(
        sample_key(&same),
        key,
        "stages and servo do not change the sample"
    );
    same.set(
        "soil_soil.cohesion",
        r#"{"model":"linear","energy_density":1e5}"#,
    )
    .unwrap();
    assert_eq!(
        sample_key(&same),
        key,
        "the sample is poured without cohesion, so cohesion does not change it"
    );
    let mut other = base.clone();
    other.soil_soil.static_friction = 0.3;
    assert_ne!(sample_key(&other), key);
    let mut other = base.clone();
    other.bed.height = 0.036;
    assert_ne!(sample_key(&other), key);
    let mut other = base.clone();
    other.seed = 2;
    assert_ne!(sample_key(&other), key);
    other.bed.seed = Some(1);
    assert_eq!(sample_key(&other), key, "bed.seed fixes the sample");
}

#[test]
fn set_reaches_array_elements_by_index_and_names_the_valid_range() {
    let mut spec = ShearSpec::fast();
    spec.set("normal_stresses_kpa.1", "9.5").unwrap();
    assert_eq!(spec.normal_stresses_kpa, vec![4.0, 9.5, 12.0]);
    let before = spec.clone();
    let e = spec.set("normal_stresses_kpa.3", "1").unwrap_err();
    assert!(
        matches!(&e, SpecError::UnknownPath { valid, .. } if valid.contains("0..3")),
        "{e}"
    );
    assert_eq!(spec, before);
}

#[test]
fn the_cohesion_ladder_batch_expands_to_valid_default_specs() {
    // As the server expands it: the preset with the batch's spec merged over it, then each
    // explicit point written at the factor's path.
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
    let batch: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(format!(
            "{root}/examples/batches/shear_cohesion_ladder.json"
        ))
        .unwrap(),
    )
    .unwrap();
    let experiment = &batch["experiment"];
    assert_eq!(experiment["kind"], "shear");
    assert_eq!(experiment["preset"], "default");
    let template = repose_experiments::catalog::prepare_spec(
        "shear",
        experiment["preset"].as_str(),
        &experiment["spec"],
    )
    .unwrap();
    let path = batch["factors"][0]["path"].as_str().unwrap();
    let points = batch["design"]["points"].as_array().unwrap();
    assert!(points.len() >= 3);
    let preset = ShearSpec::preset("default").unwrap();
    for point in points {
        let value = point[0].as_f64().unwrap();
        let spec = repose_api::apply_factor_values(&template, [(path, value)]).unwrap();
        repose_experiments::catalog::validate_spec("shear", &spec).unwrap();
        let mut spec = ShearSpec::from_json(&spec.to_string()).unwrap();
        // Only the cohesion varies, and the sample's seed is fixed while every run gets a seed
        // of its own: one cached sample (the preset's, seed 1) serves every run.
        spec.seed = 1000 + value as u64;
        assert_eq!(sample_key(&spec), sample_key(&preset), "{value}");
        assert_eq!(
            serde_json::to_value(spec.soil_soil.cohesion).unwrap(),
            serde_json::json!({"model": "linear", "energy_density": value})
        );
        assert_eq!(
            spec.soil_soil.static_friction,
            preset.soil_soil.static_friction
        );
    }
}
