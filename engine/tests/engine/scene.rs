//! Scene documents: a valid scene builds a world; every invalid one names the field.

use repose_engine::scene::Scene;

const VALID: &str = r#"{
  "duration": 0.01,
  "domain": { "min": [-0.05, -0.05, -0.01], "max": [0.05, 0.05, 0.1], "periodic_x": false, "periodic_y": false },
  "materials": {
    "materials": [
      { "name": "soil", "density": 2664.0, "youngs_modulus": 3.67e6, "poisson": 0.36 },
      { "name": "steel", "density": 7850.0, "youngs_modulus": 2.1e11, "poisson": 0.30 }
    ],
    "interactions": [
      { "a": "soil", "b": "soil", "restitution": 0.45, "static_friction": 0.442, "rolling_friction": 0.14 },
      { "a": "soil", "b": "steel", "restitution": 0.4, "static_friction": 0.305, "rolling_friction": 0.5 },
      { "a": "steel", "b": "steel", "restitution": 0.5, "static_friction": 0.3, "rolling_friction": 0.01 }
    ]
  },
  "geometries": [
    { "name": "plate", "material": "steel",
      "mesh": { "kind": "plane", "size_x": 0.08, "size_y": 0.08, "cells_x": 2, "cells_y": 2 } }
  ],
  "factories": [
    { "material": "soil", "mass_rate": 0.01, "total_mass": 0.001,
      "region": { "kind": "box", "min": [-0.01, -0.01, 0.02], "max": [0.01, 0.01, 0.04] },
      "size": { "kind": "fixed", "radius": 0.001 } }
  ]
}"#;

/// The tests' file reader (the engine itself reads no files).
fn read_file(path: &std::path::Path) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| e.to_string())
}

fn scene_with(edit: impl FnOnce(&mut serde_json::Value)) -> serde_json::Value {
    let mut v: serde_json::Value = serde_json::from_str(VALID).unwrap();
    edit(&mut v);
    v
}

fn error_of(v: serde_json::Value) -> String {
    match serde_json::from_value::<Scene>(v) {
        Err(e) => e.to_string(),
        Ok(scene) => match scene.prepare(&read_file) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("scene should be rejected"),
        },
    }
}

#[test]
fn valid_scene_builds_and_runs() {
    let scene: Scene = serde_json::from_str(VALID).unwrap();
    let mut prepared = scene.prepare(&read_file).expect("valid scene");
    assert_eq!(prepared.geometry_names, vec!["plate"]);
    // Default time step: 20 % of the Rayleigh time of a 1 mm soil grain.
    let g = 3.67e6 / (2.0 * 1.36);
    let rayleigh = std::f64::consts::PI * 0.001 * (2664.0f64 / g).sqrt() / (0.1631 * 0.36 + 0.8766);
    assert!((prepared.time_step - 0.2 * rayleigh).abs() < 1e-15);
    prepared.world.run_until(prepared.duration);
    assert!(
        !prepared.world.particles().is_empty(),
        "the factory inserted particles"
    );
}

#[test]
fn invalid_scenes_name_the_field() {
    let cases: Vec<(serde_json::Value, &str)> = vec![
        (
            scene_with(|v| v["materials"]["materials"][0]["poisson"] = 0.7.into()),
            "poisson",
        ),
        (
            scene_with(|v| v["geometries"][0]["material"] = "wood".into()),
            "geometries[0].material",
        ),
        (
            scene_with(|v| v["factories"][0]["material"] = "sand".into()),
            "factories[0].material",
        ),
        (
            scene_with(|v| v["geometries"][0]["mesh"]["size_x"] = (-1.0).into()),
            "geometries[0].mesh",
        ),
        (scene_with(|v| v["duration"] = 0.0.into()), "duration"),
        (
            scene_with(|v| v["domain"]["max"][2] = (-1.0).into()),
            "domain.max.z",
        ),
        (
            scene_with(|v| v["time_step"] = serde_json::json!({"rayleigh_fraction": 3.0})),
            "time_step.rayleigh_fraction",
        ),
        (
            scene_with(|v| v["factories"] = serde_json::json!([])),
            "no particles",
        ),
        (scene_with(|v| v["durration"] = 1.0.into()), "durration"),
    ];
    for (scene, needle) in cases {
        let message = error_of(scene);
        assert!(
            message.contains(needle),
            "error '{message}' should name '{needle}'"
        );
    }
}
