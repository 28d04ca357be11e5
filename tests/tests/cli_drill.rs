//! `repose drill` as a user runs it: preset and --set in; result.json, section.svg, forces.svg,
//! forces.csv out; a bed cache that is written once and reused.

use crate::common;
use common::{repose, stderr, stdout};

fn drill(out: &std::path::Path, cache: &std::path::Path) -> serde_json::Value {
    let o = repose(&[
        "drill",
        "--preset",
        "fast",
        "--set",
        "drill.depth=0.03",
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
fn drill_writes_result_pictures_and_csv_and_reuses_the_bed() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("beds");
    let first_out = dir.path().join("first");
    let first = drill(&first_out, &cache);
    assert_eq!(first["status"], "ok", "{first}");
    assert_eq!(first["feed_depth_mm"], 30.0);
    assert!(first["opening_diameter_mm"].as_f64().unwrap() > 0.0);
    assert!(first["effective_depth_mm"].as_f64().unwrap() > 0.0);
    assert_eq!(first["bed"]["reused"], false);
    let key = first["bed"]["key"].as_str().unwrap().to_owned();
    assert!(cache.join(format!("{key}.json")).is_file());
    for name in ["section.svg", "forces.svg"] {
        let svg = std::fs::read_to_string(first_out.join(name)).unwrap();
        assert!(svg.starts_with("<?xml") && svg.contains("<svg"), "{name}");
    }
    let csv = std::fs::read_to_string(first_out.join("forces.csv")).unwrap();
    assert!(csv.starts_with("time_s,tip_depth_mm,torque_nm,axial_force_n"));
    assert_eq!(
        csv.lines().count(),
        first["series"].as_array().unwrap().len() + 1
    );

    // Second run: the cached bed, the same hole.
    let second = drill(&dir.path().join("second"), &cache);
    assert_eq!(second["bed"]["reused"], true);
    assert_eq!(second["bed"]["key"], first["bed"]["key"]);
    assert_eq!(first["engine_version"], second["engine_version"]);
    assert!(!first["engine_version"].as_str().unwrap().contains("gpu"));
    for k in ["opening_diameter_mm", "effective_depth_mm", "energy_j"] {
        assert_eq!(second[k], first[k], "{k}");
    }
}

#[test]
fn drill_print_spec_applies_sets_and_spec_files() {
    let dir = tempfile::tempdir().unwrap();
    let spec = dir.path().join("spec.json");
    std::fs::write(
        &spec,
        r#"{"soil_soil": {"rolling_friction": 0.3}, "drill": {"depth": 0.1}}"#,
    )
    .unwrap();
    let o = repose(&[
        "drill",
        "--spec",
        spec.to_str().unwrap(),
        "--set",
        "auger.pitch=0.05",
        "--print-spec",
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["soil_soil"]["rolling_friction"], 0.3);
    assert_eq!(v["soil_soil"]["static_friction"], 0.442);
    assert_eq!(v["drill"]["depth"], 0.1);
    assert_eq!(v["drill"]["rpm"], 400.0);
    assert_eq!(v["auger"]["pitch"], 0.05);
    assert_eq!(v["auger"]["outer_diameter"], 0.06);
}

#[test]
fn drill_bad_input_is_one_line_and_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x");
    for (args, needle) in [
        (vec!["drill", "--set", "drill.speed=0.1"], "drill.speed"),
        (vec!["drill", "--set", "drill.depth=-1"], "drill.depth"),
        (vec!["drill", "--preset", "huge"], "huge"),
    ] {
        let mut args = args.clone();
        args.extend(["--print-spec", "--out", out.to_str().unwrap()]);
        let o = repose(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        let err = stderr(&o);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains(needle), "{err}");
    }
}

#[test]
fn an_stl_drill_is_embedded_in_the_spec_and_checked() {
    use repose_engine::mesh::generators::{auger, AugerSpec};
    let dir = tempfile::tempdir().unwrap();
    let a = repose_experiments::drill::DrillSpec::fast().auger;
    let model = auger(&AugerSpec {
        shaft_diameter: a.shaft_diameter,
        flight_outer_diameter: a.outer_diameter,
        pitch: a.pitch,
        flight_length: 0.08,
        flight_thickness: a.flight_thickness,
        shaft_length: 0.12,
        tip_length: a.tip_length,
        segments_per_turn: a.segments_per_turn,
        right_handed: true,
    })
    .unwrap();
    // The same auger in millimetres, as ASCII STL.
    let ascii: String = model
        .to_stl_ascii("auger")
        .lines()
        .map(|line| match line.trim_start().strip_prefix("vertex ") {
            Some(xyz) => {
                let v: Vec<String> = xyz
                    .split_whitespace()
                    .map(|c| format!("{}", c.parse::<f64>().unwrap() * 1000.0))
                    .collect();
                format!("vertex {}\n", v.join(" "))
            }
            None => format!("{line}\n"),
        })
        .collect();
    let file = dir.path().join("auger_mm.stl");
    std::fs::write(&file, ascii).unwrap();
    let path = file.to_str().unwrap();

    let o = repose(&[
        "drill",
        "--preset",
        "fast",
        "--stl",
        path,
        "--stl-scale",
        "0.001",
        "--print-spec",
    ]);
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let spec: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(spec["auger_stl"]["scale"], 0.001);
    assert!(spec["auger_stl"]["base64"].as_str().unwrap().len() > 1000);

    // Left in millimetres, the model is a thousand times the stated diameter.
    let o = repose(&["drill", "--preset", "fast", "--stl", path, "--print-spec"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("auger.outer_diameter"),
        "{}",
        stderr(&o)
    );
}
