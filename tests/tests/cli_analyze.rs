//! `repose analyze` and `repose design` as a user runs them: the paper's tables in, the
//! paper's numbers out; bad input is one line and exit status 2, never a panic.

use crate::common;
use common::{paper, repose, stderr, stdout};
use std::io::Write;

fn json(args: &[&str]) -> serde_json::Value {
    let out = repose(args);
    assert!(
        out.status.success(),
        "repose {args:?} failed: {}",
        stderr(&out)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is JSON")
}

fn anova_row<'a>(doc: &'a serde_json::Value, source: &str) -> &'a serde_json::Value {
    doc["anova"]
        .as_array()
        .expect("anova is an array")
        .iter()
        .find(|r| r["source"] == source)
        .unwrap_or_else(|| panic!("no ANOVA row {source}"))
}

fn close(actual: &serde_json::Value, expected: f64, tol: f64) {
    let a = actual.as_f64().expect("a number");
    assert!((a - expected).abs() <= tol, "{a} vs {expected} (tol {tol})");
}

#[test]
fn box_behnken_table_7_through_the_command_line() {
    let bbd = paper("box_behnken_table6.csv");
    let doc = json(&[
        "analyze",
        "--input",
        bbd.to_str().unwrap(),
        "--response",
        "angle_deg",
        "--model",
        "quadratic",
        "--target",
        "34.85",
        "--format",
        "json",
    ]);
    close(&anova_row(&doc, "Model")["f"], 470.67, 0.01);
    close(&anova_row(&doc, "N3")["f"], 3586.09, 0.01);
    close(&anova_row(&doc, "Lack of Fit")["f"], 0.3455, 0.0001);
    close(&anova_row(&doc, "Lack of Fit")["p"], 0.7954, 0.0001);
    close(&doc["r2"], 0.9984, 0.00005);
    close(&doc["adj_r2"], 0.9962, 0.00005);
    close(&doc["pred_r2"], 0.9925, 0.00005);
    close(&doc["adeq_precision"], 65.3556, 0.0001);
    close(&doc["cv_percent"], 1.22, 0.005);
    close(&doc["coefficients"]["Intercept"], 39.99, 0.005);
    close(&doc["coefficients"]["N3:N5"], 1.16, 0.01);
    close(&doc["coefficients"]["N3^2"], -5.08, 0.005);
    let best = &doc["optimum"]["solutions"][0];
    close(&best["responses"][0]["value"], 34.85, 0.05);
    assert_eq!(doc["optimum"]["level_set"], true);
    for x in best["coded"].as_array().unwrap() {
        assert!(
            x.as_f64().unwrap().abs() <= 1.0 + 1e-9,
            "outside the design region"
        );
    }
}

#[test]
fn plackett_burman_table_4_through_the_command_line() {
    let pb = paper("plackett_burman_table3.csv");
    let doc = json(&[
        "analyze",
        "--input",
        pb.to_str().unwrap(),
        "--response",
        "angle_deg",
        "--model",
        "linear",
        "--format",
        "json",
    ]);
    close(&anova_row(&doc, "Model")["f"], 22.40, 0.005);
    close(&anova_row(&doc, "Model")["p"], 0.0018, 0.00005);
    close(&anova_row(&doc, "N3")["f"], 110.83, 0.005);
    assert!(doc["anova"]
        .as_array()
        .unwrap()
        .iter()
        .all(|r| r["source"] != "Lack of Fit"));
}

#[test]
fn text_output_is_the_readable_table() {
    let bbd = paper("box_behnken_table6.csv");
    let out = repose(&[
        "analyze",
        "--input",
        bbd.to_str().unwrap(),
        "--response",
        "angle_deg",
        "--model",
        "quadratic",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = stdout(&out);
    for needle in [
        "Model",
        "470.67",
        "3586.09",
        "Lack of Fit",
        "0.7954",
        "Cor Total",
        "65.3556",
    ] {
        assert!(text.contains(needle), "missing {needle} in\n{text}");
    }
}

#[test]
fn natural_levels_give_the_same_fit_as_coded_columns() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("natural.csv");
    let coded = std::fs::read_to_string(paper("box_behnken_table6.csv")).unwrap();
    let mut file = std::fs::File::create(&path).unwrap();
    writeln!(file, "N2,N3,N5,angle_deg").unwrap();
    for line in coded.lines().skip(1) {
        let v: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        writeln!(
            file,
            "{},{},{},{}",
            0.48 + 0.04 * v[1],
            0.205 + 0.195 * v[2],
            0.35 + 0.05 * v[3],
            v[4]
        )
        .unwrap();
    }
    drop(file);
    let doc = json(&[
        "analyze",
        "--input",
        path.to_str().unwrap(),
        "--response",
        "angle_deg",
        "--levels",
        "N2=0.44:0.52,N3=0.01:0.40,N5=0.30:0.40",
        "--target",
        "34.85",
        "--format",
        "json",
    ]);
    close(&anova_row(&doc, "Model")["f"], 470.67, 0.01);
    let natural = doc["optimum"]["solutions"][0]["natural"]
        .as_array()
        .unwrap();
    close(&natural[1], 0.12, 0.03); // N3 on the 34.85° level set lies near 0.12-0.14
}

fn write_temp(content: &str) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("runs.csv");
    std::fs::write(&path, content).unwrap();
    (dir, path)
}

/// Runs analyze on `csv` and asserts exit status 2 with one stderr line containing `needle`.
fn rejects(csv: &str, extra: &[&str], needle: &str) {
    let (_dir, path) = write_temp(csv);
    let mut args = vec![
        "analyze",
        "--input",
        path.to_str().unwrap(),
        "--response",
        "y",
    ];
    args.extend_from_slice(extra);
    let out = repose(&args);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "expected exit 2, stderr: {err}");
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "one line expected: {err}"
    );
    assert!(
        err.contains(needle),
        "stderr '{err}' should mention '{needle}'"
    );
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn bad_input_is_one_line_and_status_2() {
    let good_rows = "A,B,y\n-1,-1,1\n1,-1,2\n-1,1,3\n1,1,5\n0,0,2.5\n";
    rejects(good_rows, &["--factors", "A,C"], "'C'");
    rejects(
        "A,B,y\n-1,-1,1\n1,x,2\n-1,1,3\n1,1,5\n",
        &["--model", "linear"],
        "'B'",
    );
    rejects(
        "A,B,y\n-1,-1,1\n1,NaN,2\n-1,1,3\n1,1,5\n",
        &["--model", "linear"],
        "'B'",
    );
    rejects(
        "A,B,y\n-1,-1,1\n1,-1,2\n-1,1,3\n",
        &["--model", "quadratic"],
        "runs",
    );
    rejects(
        "A,B,y\n-1,-1,2\n1,-1,2\n-1,1,2\n1,1,2\n0,0,2\n",
        &["--model", "linear"],
        "constant",
    );
    rejects(
        "A,B,y\n1,-1,1\n1,-1,2\n1,1,3\n1,1,5\n1,0,2\n",
        &["--model", "linear"],
        "A",
    );
    rejects("A,B,y\n-1,-1,1\n1,-1\n", &[], "row");
    rejects(&good_rows.replace(",y", ",z"), &[], "'y'");
    rejects(good_rows, &["--levels", "A=1:0,B=0:1"], "A");
}

#[test]
fn design_box_behnken_prints_coded_and_natural_columns() {
    let out = repose(&[
        "design",
        "bbd",
        "--levels",
        "N2=0.44:0.52,N3=0.01:0.40,N5=0.30:0.40",
        "--centre-points",
        "5",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = stdout(&out);
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "run,std_order,replicate,seed,N2,N3,N5,N2_natural,N3_natural,N5_natural"
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 17);
    let seeds: std::collections::HashSet<&str> =
        rows.iter().map(|r| r.split(',').nth(3).unwrap()).collect();
    assert_eq!(seeds.len(), 17, "every run has its own seed");
}

#[test]
fn design_rejects_bad_arguments_with_status_2() {
    for args in [
        vec!["design", "pb", "--k", "6", "--runs", "10"],
        vec!["design", "bbd", "--k", "2"],
        vec!["design", "factorial"],
        vec!["design", "ccd", "--levels", "A=1:1"],
    ] {
        let out = repose(&args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stderr(&out));
        assert!(!stderr(&out).contains("panicked"));
    }
}

#[test]
fn steepest_ascent_path_reproduces_table_5() {
    let pb = paper("plackett_burman_table3.csv");
    let doc = json(&[
        "analyze",
        "--input",
        pb.to_str().unwrap(),
        "--response",
        "angle_deg",
        "--model",
        "linear",
        "--report-levels",
        "N1=0.15:0.75,N2=0.44:0.68,N3=0.01:0.40,N4=0.2:0.6,N5=0.3:0.7,N6=0.1:0.4",
        "--path-steps",
        "4",
        "--path-start",
        "corner",
        "--path-direction",
        "ascent",
        "--path-round",
        "2",
        "--format",
        "json",
    ]);
    let path = &doc["steepest_path"];
    assert_eq!(path["factors"], serde_json::json!(["N2", "N3", "N5"]));
    assert_eq!(path["base_factor"], "N3");
    for (actual, expected) in path["step_natural"]
        .as_array()
        .unwrap()
        .iter()
        .zip([0.04, 0.195, 0.05])
    {
        close(actual, expected, 1e-9);
    }
    let table5 = std::fs::read_to_string(paper("steepest_ascent_table5.csv")).unwrap();
    for (line, point) in table5
        .lines()
        .skip(1)
        .zip(path["points"].as_array().unwrap())
    {
        let cells: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
        for (k, expected) in cells[1..4].iter().enumerate() {
            close(&point[k], *expected, 1e-9);
        }
    }
}

/// The README shows what the main command prints; keep the two identical.
#[test]
fn readme_shows_what_the_main_command_prints() {
    let readme = std::fs::read_to_string(common::workspace_root().join("README.md")).unwrap();
    let section = readme
        .split("## What `repose analyze` prints for Table 6")
        .nth(1)
        .expect("README has the section");
    let block = section
        .split("```text\n")
        .nth(1)
        .and_then(|rest| rest.split("```").next())
        .expect("README has the text block");
    let bbd = paper("box_behnken_table6.csv");
    let out = repose(&[
        "analyze",
        "--input",
        bbd.to_str().unwrap(),
        "--response",
        "angle_deg",
        "--model",
        "quadratic",
        "--target",
        "34.85",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(
        stdout(&out),
        block,
        "README.md is out of date: paste the new output"
    );
}
