//! `repose shear` as a user runs it: preset and --set in; result.json, shear_curves.svg,
//! mohr_coulomb.svg, shear_curves.csv out; a sample cache written once and reused.

use crate::common;
use common::{repose, stderr, stdout};

/// The fast preset at two normal stresses, sheared 2 mm: the smallest run that still fits a
/// line (about 10 s).
fn shear(out: &std::path::Path, cache: &std::path::Path) -> serde_json::Value {
    let o = repose(&[
        "shear",
        "--preset",
        "fast",
        "--set",
        "normal_stresses_kpa=[4,8]",
        "--set",
        "shear.displacement=0.002",
        "--out",
        out.to_str().unwrap(),
        "--bed-cache",
        cache.to_str().unwrap(),
        "--threads",
        "2",
        "--quiet",
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let printed: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("result.json")).unwrap()).unwrap();
    assert_eq!(printed, file);
    file
}

#[test]
fn shear_writes_result_pictures_and_csv_and_reuses_the_sample() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("beds");
    let first_out = dir.path().join("first");
    let first = shear(&first_out, &cache);
    assert!(first["cohesion_kpa"].is_number(), "{first}");
    assert!(first["friction_angle_deg"].as_f64().unwrap() > 0.0);
    assert_eq!(first["stages"].as_array().unwrap().len(), 2);
    assert_eq!(first["bed"]["reused"], false);
    let key = first["bed"]["key"].as_str().unwrap().to_owned();
    assert!(cache.join(format!("{key}.json")).is_file());
    for name in ["shear_curves.svg", "mohr_coulomb.svg"] {
        let svg = std::fs::read_to_string(first_out.join(name)).unwrap();
        assert!(svg.starts_with("<?xml") && svg.contains("<svg"), "{name}");
    }
    let csv = std::fs::read_to_string(first_out.join("shear_curves.csv")).unwrap();
    assert!(csv.starts_with("normal_stress_kpa,displacement_mm,shear_stress_kpa"));

    // Second run: the cached sample, the same strength.
    let second = shear(&dir.path().join("second"), &cache);
    assert_eq!(second["bed"]["reused"], true);
    assert_eq!(second["cohesion_kpa"], first["cohesion_kpa"]);
    assert_eq!(second["friction_angle_deg"], first["friction_angle_deg"]);
}

#[test]
fn shear_print_spec_applies_sets_and_bad_input_is_one_line_and_exit_2() {
    let o = repose(&[
        "shear",
        "--preset",
        "fast",
        "--set",
        "soil_soil.static_friction=0.5",
        "--print-spec",
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["soil_soil"]["static_friction"], 0.5);
    assert_eq!(v["box"]["side"], 0.05);

    for (args, needle) in [
        (vec!["shear", "--set", "box.width=0.1"], "box.width"),
        (
            vec!["shear", "--set", "normal_stresses_kpa=[5]"],
            "normal_stresses_kpa",
        ),
        (vec!["shear", "--preset", "huge"], "huge"),
    ] {
        let mut args = args.clone();
        args.push("--print-spec");
        let o = repose(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        let err = stderr(&o);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(needle), "{err}");
    }
}
