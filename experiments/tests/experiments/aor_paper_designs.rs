//! The quick rig (`fast`) measures every point of the paper's designs (issue 37): the
//! Plackett-Burman screening (Table 3's twelve rows at the Table 2 levels, and the twelve rows
//! our generator gives `examples/batches/paper_screening_pb.json` and the campaigns' screening)
//! and the Box-Behnken points of Table 6 (`examples/batches/paper_box_behnken.json`, the
//! README's first command). Every point pours, drains the funnel (no arch) and gives an angle
//! (no heap too flat to measure).
//!
//! The points come from the batch files (preset, spec, factor paths and levels) and the paper's
//! tables in `examples/paper/`, so a change to either is tested here. The default run pours each
//! distinct point once (seed 1), the points of a test in parallel; the several-seed failure rate
//! is the ignored `failure_rate_over_seeds` (run it with `--ignored --nocapture`).

use rayon::prelude::*;
use repose_doe::design::{box_behnken, plackett_burman};
use repose_experiments::aor::{run_aor, AorResult, AorSpec, Control, RunStatus};
use repose_experiments::catalog::prepare_spec;
use repose_experiments::Spec;
use serde_json::Value;

const ROOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/..");

/// One point of a design: a label and its spec (seed not yet set).
struct Point {
    label: String,
    spec: AorSpec,
}

fn read(path: &str) -> String {
    std::fs::read_to_string(format!("{ROOT}/{path}")).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// A factor of a batch: `(name, path, low, high)`.
type Factor = (String, String, f64, f64);

/// The batch's experiment (preset and spec merged as the server does), its factors and design.
fn batch(file: &str) -> (AorSpec, Vec<Factor>, Value) {
    let batch: Value = serde_json::from_str(&read(&format!("examples/batches/{file}"))).unwrap();
    let experiment = &batch["experiment"];
    assert_eq!(experiment["kind"], "aor", "{file}");
    assert_eq!(experiment["preset"], "fast", "{file}: the quick rig");
    let spec = prepare_spec("aor", experiment["preset"].as_str(), &experiment["spec"]).unwrap();
    let spec: AorSpec = serde_json::from_value(spec).unwrap();
    let factors = batch["factors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (
                f["name"].as_str().unwrap().to_owned(),
                f["path"].as_str().unwrap().to_owned(),
                f["low"].as_f64().unwrap(),
                f["high"].as_f64().unwrap(),
            )
        })
        .collect();
    (spec, factors, batch["design"].clone())
}

/// The coded rows of a paper table: one map from factor name to coded level per row.
fn paper_table(file: &str) -> Vec<Vec<(String, f64)>> {
    let text = read(&format!("examples/paper/{file}"));
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    lines
        .map(|line| {
            header
                .iter()
                .zip(line.split(','))
                .filter(|(name, _)| name.starts_with('N'))
                .map(|(name, value)| (name.to_string(), value.parse().unwrap()))
                .collect()
        })
        .collect()
}

/// Adds the point at `coded` levels (by factor name) unless an equal point is already there.
fn add_point(
    points: &mut Vec<Point>,
    label: String,
    base: &AorSpec,
    factors: &[Factor],
    coded: &[(String, f64)],
) {
    let mut spec = base.clone();
    for (name, path, low, high) in factors {
        let c = coded
            .iter()
            .find(|(n, _)| n == name)
            .unwrap_or_else(|| panic!("{label}: no level for {name}"))
            .1;
        assert!([-1.0, 0.0, 1.0].contains(&c), "{label}: {name} at {c}");
        let value = low + (high - low) * (c + 1.0) / 2.0;
        spec.set(path, &value.to_string()).unwrap();
    }
    spec.validate().unwrap();
    if points.iter().all(|p| p.spec != spec) {
        points.push(Point { label, spec });
    }
}

/// Adds `rows` (factor name → coded level) as points labelled `"{label} run {i}"`.
fn add_rows(
    points: &mut Vec<Point>,
    label: &str,
    base: &AorSpec,
    factors: &[Factor],
    rows: &[Vec<(String, f64)>],
) {
    for (i, row) in rows.iter().enumerate() {
        add_point(points, format!("{label} run {}", i + 1), base, factors, row);
    }
}

/// A generated design's coded runs as rows of (factor name, level).
fn coded_rows(names: &[&str], runs: &[Vec<f64>]) -> Vec<Vec<(String, f64)>> {
    runs.iter()
        .map(|row| {
            names
                .iter()
                .map(|n| n.to_string())
                .zip(row.clone())
                .collect()
        })
        .collect()
}

/// Table 3's rows and the PB batch's own design rows, at the Table 2 levels (18 distinct points:
/// six of the generator's rows are Table 3's).
fn plackett_burman_points() -> Vec<Point> {
    let (base, factors, design) = batch("paper_screening_pb.json");
    assert_eq!(design["type"], "plackett_burman");
    let mut points = Vec::new();
    let table = paper_table("plackett_burman_table3.csv");
    add_rows(&mut points, "Table 3", &base, &factors, &table);
    assert_eq!(points.len(), 12);
    let names: Vec<&str> = factors.iter().map(|f| f.0.as_str()).collect();
    let runs = design["runs"].as_u64().unwrap() as usize;
    let generated = plackett_burman(&names, runs).unwrap();
    let rows = coded_rows(&names, generated.coded_runs());
    add_rows(&mut points, "PB batch", &base, &factors, &rows);
    points
}

/// Table 6's points (12 edge points and the centre) at the BBD batch's levels; the batch's own
/// design is the same set of points.
fn box_behnken_points() -> Vec<Point> {
    let (base, factors, design) = batch("paper_box_behnken.json");
    assert_eq!(design["type"], "box_behnken");
    let mut points = Vec::new();
    let table = paper_table("box_behnken_table6.csv");
    add_rows(&mut points, "Table 6", &base, &factors, &table);
    assert_eq!(points.len(), 13);
    let names: Vec<&str> = factors.iter().map(|f| f.0.as_str()).collect();
    let centre = design["centre_points"].as_u64().unwrap() as usize;
    let generated = box_behnken(&names, centre).unwrap();
    assert_eq!(generated.coded_runs().len(), 17, "the README's 17 runs");
    let rows = coded_rows(&names, generated.coded_runs());
    add_rows(&mut points, "BBD batch", &base, &factors, &rows);
    assert_eq!(points.len(), 13, "the batch's design is Table 6's points");
    points
}

fn pour(point: &Point, seed: u64) -> AorResult {
    let mut spec = point.spec.clone();
    spec.seed = seed;
    let r = run_aor(&spec, &mut |_| Control::Continue)
        .expect("the spec builds")
        .result;
    eprintln!(
        "{} seed {seed}: {:?} angle {:?} height {:?} held up {} escaped {} t {:.2} s steps {} \
         wall {:.1} s {}",
        point.label,
        r.status,
        r.angle_deg.map(|a| (a * 100.0).round() / 100.0),
        r.pile_height_m,
        r.grains.held_up.count,
        r.grains.escaped.count,
        r.simulated_time_s,
        r.steps,
        r.wall_time_s,
        r.message.as_deref().unwrap_or("")
    );
    r
}

/// The one point of the paper's designs the fast rig does not measure yet (the open part of
/// issue 37): Table 3's run 7 (the PB batch's run 3), N1 0.75, N2 0.44, N3 0.01, N4 0.2,
/// N5 0.7, N6 0.1. Its bouncy grains (restitution 0.75) with almost no rolling resistance on
/// grains (0.01) or steel (0.1) spread into one layer 70-80 mm across with a ring or patch of
/// a second layer and no slope (seeds 1-3 and the batch's three seeds): no heap, so no angle.
const NO_HEAP_YET: &str = "Table 3 run 7";

/// Every point pours once (seed 1) and is measured: status ok, an angle, the funnel drained;
/// only [`NO_HEAP_YET`] may fail, and then only as a measurement (a layer, not an arch).
fn every_point_is_measured(points: &[Point]) {
    let failed: Vec<String> = points
        .par_iter()
        .filter_map(|point| {
            let r = pour(point, 1);
            if point.label == NO_HEAP_YET && r.status != RunStatus::Ok {
                assert_eq!(
                    r.status,
                    RunStatus::MeasurementFailed,
                    "{}: {r:?}",
                    point.label
                );
                assert_eq!(r.grains.held_up.count, 0, "{}: {r:?}", point.label);
                return None;
            }
            let measured = r.status == RunStatus::Ok
                && r.angle_deg
                    .is_some_and(|a| a.is_finite() && (0.0..90.0).contains(&a))
                && r.grains.held_up.count == 0;
            (!measured).then(|| format!("{}: {:?} {:?}", point.label, r.status, r.message))
        })
        .collect();
    assert!(failed.is_empty(), "not measured: {failed:#?}");
}

#[test]
fn the_fast_rig_measures_every_plackett_burman_point() {
    every_point_is_measured(&plackett_burman_points());
}

#[test]
fn the_fast_rig_measures_every_box_behnken_point() {
    every_point_is_measured(&box_behnken_points());
}

/// The failure rate of the quick rig over the paper's points × seeds 1-4 (issue 37): prints one
/// line per pour and the totals, and fails if any pour but those of [`NO_HEAP_YET`] is not
/// measured. About 4 × 31 pours:
/// minutes of two cores in the release or test profile.
#[test]
#[ignore = "minutes: the several-seed failure rate of the paper's designs at the fast rig"]
fn failure_rate_over_seeds() {
    let points: Vec<Point> = plackett_burman_points()
        .into_iter()
        .chain(box_behnken_points())
        .collect();
    let seeds = [1u64, 2, 3, 4];
    let pours: Vec<(usize, u64)> = (0..points.len())
        .flat_map(|p| seeds.iter().map(move |s| (p, *s)))
        .collect();
    let results: Vec<(usize, u64, AorResult)> = pours
        .par_iter()
        .map(|&(p, seed)| (p, seed, pour(&points[p], seed)))
        .collect();
    let failed: Vec<String> = results
        .iter()
        .filter(|(p, _, r)| {
            (r.status != RunStatus::Ok || r.angle_deg.is_none()) && points[*p].label != NO_HEAP_YET
        })
        .map(|(p, seed, r)| {
            format!(
                "{} seed {seed}: {:?} {:?}",
                points[*p].label, r.status, r.message
            )
        })
        .collect();
    let angles: Vec<f64> = results.iter().filter_map(|(_, _, r)| r.angle_deg).collect();
    let wall: f64 = results.iter().map(|(_, _, r)| r.wall_time_s).sum();
    eprintln!(
        "failure rate: {} of {} pours ({} points × {} seeds) not measured besides {NO_HEAP_YET}; angles {:.2}-{:.2}°; \
         {:.1} s of one core per pour on average",
        failed.len(),
        results.len(),
        points.len(),
        seeds.len(),
        angles.iter().copied().fold(f64::INFINITY, f64::min),
        angles.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        wall / results.len() as f64
    );
    assert!(failed.is_empty(), "not measured: {failed:#?}");
}
