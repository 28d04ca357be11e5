//! Several targets in one campaign, replayed with the `table_lookup` kind (a test aid, not a
//! simulation). Two experiments (`aor` and `shear`, both lookup tables here) each give one
//! response, built so the right answer is known:
//!
//! - `aor.angle_deg = 30 + 8·A + 4·B` (target 34), `shear.cohesion_kpa = 1 + 3·B` (target 2.5);
//!   `C` moves neither. Both targets hold together only at A = 0.25, B = 0.5; C is held.
//! - a validation experiment (`drill`, also a lookup table) answers
//!   `opening_diameter_mm = 60 + 10·A` and `effective_depth_mm = 600 + 20·B`: at the answer
//!   62.5 and 610, measured here as 63.2 and 603.66.
//!
//! Every table row is written when its batch is issued, at exactly the points the campaign asks
//! for, from those formulas plus a small fixed deviation per point (so the fits have residual
//! degrees of freedom), and the lookup kind answers the runs from it.

use crate::common;

use std::collections::BTreeMap;

use common::{expand, run_lookup};
use repose_api::{apply_factor_values, BackendKind, BatchRequest, FactorSpec};
use repose_campaign::{Campaign, CampaignRequest, Next, StageKind, StageResult, Status};
use serde_json::{json, Value};

const FACTORS: [&str; 3] = ["A", "B", "C"];

fn angle(a: f64, b: f64) -> f64 {
    30.0 + 8.0 * a + 4.0 * b
}

fn cohesion(b: f64) -> f64 {
    1.0 + 3.0 * b
}

/// A fixed deviation in [-1, 1] from the point and the replicate (no randomness).
fn deviation(x: &[f64], replicate: usize) -> f64 {
    let h = x
        .iter()
        .enumerate()
        .map(|(i, v)| (v * 1000.0).round() * (i as f64 + 1.7))
        .sum::<f64>()
        + replicate as f64 * 3.1;
    (h * 12.9898).sin()
}

fn lookup(kind_metrics: &[&str]) -> Value {
    // One placeholder row (far from every design point) so the template validates.
    let mut row: BTreeMap<&str, f64> = FACTORS.iter().map(|f| (*f, -99.0)).collect();
    for m in kind_metrics {
        row.insert(m, 0.0);
    }
    json!({
        "kind": "table_lookup",
        "spec": {"values": {"A": 0.0, "B": 0.0, "C": 0.0}, "rows": [row], "tolerance": 1e-9}
    })
}

fn request(extra: Value) -> CampaignRequest {
    let mut base = json!({
        "name": "two targets",
        "experiments": {
            "aor": lookup(&["angle_deg"]),
            "shear": lookup(&["cohesion_kpa"]),
        },
        "targets": [
            {"response": "aor.angle_deg", "target": 34.0, "tolerance": {"relative_pct": 2}},
            {"response": "shear.cohesion_kpa", "target": 2.5, "tolerance": {"relative_pct": 4}}
        ],
        "factors": [
            {"name": "A", "path": "values.A", "low": 0.0, "high": 1.0},
            {"name": "B", "path": "values.B", "low": 0.0, "high": 1.0},
            {"name": "C", "path": "values.C", "low": 0.0, "high": 1.0}
        ],
        "seed": 15,
        "screening": {"design": {"type": "plackett_burman", "runs": 8}},
    });
    for (k, v) in extra.as_object().unwrap() {
        base[k] = v.clone();
    }
    serde_json::from_value(base).expect("request parses")
}

/// Writes the rows of every run of `batch` into its lookup table: the formulas at the run's
/// values plus its fixed deviation (`noise` scales it per metric).
fn add_rows(batch: &mut BatchRequest) {
    let mut rows = Vec::new();
    for (_, replicate, _, _, natural) in expand(batch) {
        let spec = apply_factor_values(
            &batch.experiment.spec,
            FactorSpec::assignments(&batch.factors, &natural),
        )
        .unwrap();
        let x: Vec<f64> = FACTORS
            .iter()
            .map(|f| spec["values"][f].as_f64().unwrap())
            .collect();
        let dev = deviation(&x, replicate);
        let mut r = serde_json::Map::new();
        for (f, v) in FACTORS.iter().zip(&x) {
            r.insert((*f).into(), json!(v));
        }
        // The target experiments' rows carry both metrics (a batch reads the ones it needs).
        let metrics: Vec<(&str, f64)> = match batch.response.as_str() {
            "angle_deg" | "cohesion_kpa" => vec![
                ("angle_deg", angle(x[0], x[1]) + 0.05 * dev),
                ("cohesion_kpa", cohesion(x[1]) + 0.01 * dev),
            ],
            _ => vec![
                ("opening_diameter_mm", 60.0 + 10.0 * x[0] + 0.05 * dev),
                ("effective_depth_mm", 600.0 + 20.0 * x[1] + 0.2 * dev),
            ],
        };
        for (m, v) in metrics {
            r.insert(m.into(), json!(v));
        }
        rows.push(Value::Object(r));
    }
    batch.experiment.spec["rows"]
        .as_array_mut()
        .unwrap()
        .extend(rows);
}

fn drive(request: CampaignRequest) -> (Campaign, Vec<StageResult>, Next) {
    let (mut campaign, mut batch) = Campaign::start(request).unwrap();
    let mut results = Vec::new();
    loop {
        let index = campaign.outstanding().unwrap();
        add_rows(&mut batch);
        let result = run_lookup(index, &batch);
        // The state survives a JSON round trip at every step (a server restart).
        campaign = serde_json::from_str(&serde_json::to_string(&campaign).unwrap()).unwrap();
        let next = campaign.advance(&result).unwrap();
        results.push(result);
        match next {
            Next::Submit(b) if results.len() < 60 => batch = b,
            other => return (campaign, results, other),
        }
    }
}

#[test]
fn two_targets_are_calibrated_together_to_the_known_answer() {
    let (campaign, results, next) = drive(request(json!({})));
    for d in &campaign.decisions {
        println!("[{:?} r{}] {}", d.stage, d.round, d.text);
    }
    let Next::Finished(summary) = next else {
        panic!("not finished: {next:?}");
    };
    assert_eq!(campaign.status, Status::Finished);

    // Every stage ran both experiments, one batch each, with the same design.
    for stage in [
        StageKind::Screening,
        StageKind::ResponseSurface,
        StageKind::Verification,
    ] {
        let batches: Vec<_> = campaign
            .batches
            .iter()
            .filter(|b| b.stage == stage)
            .collect();
        assert_eq!(batches.len() % 2, 0, "{stage:?}: one batch per experiment");
        for pair in batches.chunks(2) {
            assert_eq!(pair[0].experiment, "aor");
            assert_eq!(pair[1].experiment, "shear");
            assert_eq!(pair[0].request.design, pair[1].request.design);
            assert_eq!(pair[0].request.response, "angle_deg");
            assert_eq!(pair[1].request.response, "cohesion_kpa");
            assert!(
                pair[1].request.name.ends_with("[shear]"),
                "{}",
                pair[1].request.name
            );
        }
    }
    assert_eq!(results.len(), campaign.batches.len());

    // Screening: A and B matter (each for some response), C for none and is held.
    let s = campaign.screening.as_ref().unwrap();
    assert_eq!(s.carried, ["A", "B"]);
    assert_eq!(s.responses.len(), 2);
    assert_eq!(s.responses[0].significant, ["A", "B"]);
    assert_eq!(s.responses[1].significant, ["B"]);
    assert_eq!(s.held.len(), 1);
    assert_eq!(s.held[0].name, "C");
    assert!((s.held[0].value - 0.5).abs() < 1e-12);

    // The path follows the overall desirability and centres the surface on a point with it.
    let path = campaign.path.as_ref().unwrap();
    assert_eq!(path.goals.len(), 2);
    let centre = &path.points[path.centre.unwrap()];
    assert!(centre.desirability.unwrap() > 0.0);

    // One quadratic per response; the optimum is the known answer.
    let round = campaign.surfaces.last().unwrap();
    assert_eq!(round.fits.len(), 2);
    assert_eq!(round.fits[0].response, "aor.angle_deg");
    assert_eq!(round.fits[1].response, "shear.cohesion_kpa");
    let opt = round.optimum.as_ref().unwrap();
    assert_eq!(opt.predictions.len(), 2);
    let value = |name: &str| {
        summary
            .parameters
            .iter()
            .find(|p| p.name == name)
            .unwrap()
            .value
    };
    assert!((value("A") - 0.25).abs() < 0.02, "A = {}", value("A"));
    assert!((value("B") - 0.5).abs() < 0.02, "B = {}", value("B"));
    assert!((value("C") - 0.5).abs() < 1e-12);
    assert!(
        (opt.predictions[0] - 34.0).abs() < 0.3,
        "{:?}",
        opt.predictions
    );
    assert!(
        (opt.predictions[1] - 2.5).abs() < 0.05,
        "{:?}",
        opt.predictions
    );

    // Verification checks each response against its own tolerance.
    assert!(summary.within_tolerance);
    assert_eq!(summary.targets.len(), 2);
    assert_eq!(summary.targets[0].response, "aor.angle_deg");
    assert_eq!(summary.targets[1].response, "shear.cohesion_kpa");
    for t in &summary.targets {
        assert!(t.within_tolerance, "{t:?}");
        assert_eq!(t.responses.len(), 3);
    }
    assert!(summary.targets[0].relative_error_pct < 2.0);
    assert!(summary.targets[1].relative_error_pct < 4.0);
}

/// A campaign-level `backend` (issue 49) reaches every experiment that names none of its own,
/// the validation's included; one that names its own (`cpu` here) keeps it.
#[test]
fn a_campaign_backend_reaches_every_experiment_without_its_own_and_the_validation() {
    let mut shear = lookup(&["cohesion_kpa"]);
    shear["backend"] = json!("cpu");
    let (campaign, _, next) = drive(request(json!({
        "backend": "gpu",
        "experiments": {"aor": lookup(&["angle_deg"]), "shear": shear},
        "validation": {
            "experiment": lookup(&["opening_diameter_mm", "effective_depth_mm"]),
            "measured": {"opening_diameter_mm": 63.20, "effective_depth_mm": 603.66},
        }
    })));
    assert!(matches!(next, Next::Finished(_)), "{next:?}");
    assert_eq!(
        campaign.batches.last().unwrap().stage,
        StageKind::Drilling,
        "the validation ran"
    );
    for batch in &campaign.batches {
        let expected = match batch.experiment.as_str() {
            "shear" => BackendKind::Cpu,
            _ => BackendKind::Gpu,
        };
        assert_eq!(
            batch.request.experiment.backend,
            Some(expected),
            "{}",
            batch.request.name
        );
    }
    // Stored as asked: the request keeps telling the experiment's own `cpu` from none.
    assert_eq!(campaign.request.experiments["aor"].backend, None);
    assert_eq!(
        campaign.request.experiments["shear"].backend,
        Some(BackendKind::Cpu)
    );
}

#[test]
fn a_validation_experiment_runs_at_the_optimum_and_is_compared_with_its_measurements() {
    let (campaign, _, next) = drive(request(json!({
        "validation": {
            "experiment": lookup(&["opening_diameter_mm", "effective_depth_mm"]),
            "measured": {"opening_diameter_mm": 63.20, "effective_depth_mm": 603.66},
            "tolerance_pct": 5,
        }
    })));
    let Next::Finished(summary) = next else {
        panic!("not finished: {next:?}");
    };
    let drill = campaign.batches.last().unwrap();
    assert_eq!(drill.stage, StageKind::Drilling);
    let v = summary.drilling.as_ref().expect("validation reported");
    let metric = |name: &str| v.metrics.iter().find(|m| m.name == name).unwrap();
    // At the optimum (A ≈ 0.25, B ≈ 0.5) the table predicts ≈ 62.5 mm and ≈ 610 mm.
    let d = metric("opening_diameter_mm");
    let sim = d.simulated.unwrap();
    assert!((sim - 62.5).abs() < 0.3, "{sim}");
    let expected = (sim - 63.2).abs() / 63.2 * 100.0;
    assert!((d.relative_error_pct.unwrap() - expected).abs() < 1e-9);
    let e = metric("effective_depth_mm");
    assert!((e.simulated.unwrap() - 610.0).abs() < 0.6);
    assert!(v.passed, "{v:?}");
    let last = &campaign.decisions.last().unwrap().text;
    assert!(last.starts_with("Finished:"), "{last}");
}

#[test]
fn a_multi_target_request_is_validated_with_the_field_named() {
    let err = |extra: Value| Campaign::start(request(extra)).unwrap_err().to_string();
    assert!(
        err(json!({"targets": [{"response": "drill.depth", "target": 1.0}]}))
            .starts_with("targets[0].response"),
    );
    assert!(err(json!({"target": 34.0})).starts_with("target"));
    assert!(err(json!({"steepest": {"direction": "descent"}})).starts_with("steepest.direction"));
    assert!(err(json!({"targets": [
        {"response": "aor.angle_deg", "target": 34.0},
        {"response": "shear", "target": 2.5}
    ]}))
    .starts_with("targets[1].response"));
    assert!(
        err(json!({"targets": [{"response": "aor.angle_deg", "target": 34.0}]}))
            .starts_with("experiments.shear")
    );
    let single = json!({
        "name": "x", "factors": [{"name": "A", "path": "values.A", "low": 0.0, "high": 1.0}],
        "experiment": {"kind": "aor"}
    });
    let e = Campaign::start(serde_json::from_value(single).unwrap())
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("target"), "{e}");
}

#[test]
fn the_report_shows_every_response_the_overall_desirability_and_the_validation() {
    let (campaign, results, _) = drive(request(json!({
        "validation": {
            "experiment": lookup(&["opening_diameter_mm", "effective_depth_mm"]),
            "measured": {"opening_diameter_mm": 63.20, "effective_depth_mm": 603.66},
        }
    })));
    let html = repose_campaign::report_html(
        &campaign,
        &results,
        &repose_campaign::ReportPictures::default(),
    );
    for needle in [
        "aor.angle_deg (target 34)",
        "shear.cohesion_kpa (target 2.5)",
        "Overall desirability at the optimum",
        "Steepest path: overall desirability per step",
        "predicted shear.cohesion_kpa",
        "overall desirability",
        "Validation (not a target)",
        "opening_diameter_mm",
        "63.2",
        "603.7",
    ] {
        assert!(html.contains(needle), "report lacks {needle:?}");
    }
    // Each response has its own screening Pareto chart, ANOVA and contour plot.
    assert_eq!(
        html.matches("Pareto chart of standardized effects").count(),
        2
    );
    assert_eq!(html.matches("aor.angle_deg over A × B").count(), 1);
    assert_eq!(html.matches("shear.cohesion_kpa over A × B").count(), 1);
    let body = html
        .trim_start_matches("<!DOCTYPE html>")
        .replace("<meta charset=\"utf-8\">", "");
    roxmltree::Document::parse(&body).expect("well-formed page");

    let json = repose_campaign::report_json(&campaign, &results);
    let fits = json["stages"]["screening"]["fits"].as_array().unwrap();
    assert_eq!(fits.len(), 2);
    assert_eq!(fits[1]["response"], "shear.cohesion_kpa");
    assert!(fits[1]["fit"]["anova"].is_array());
    let full = json["stages"]["response_surfaces"][0]["fits_full"]
        .as_array()
        .unwrap();
    assert_eq!(full.len(), 2);
    assert_eq!(json["summary"]["targets"].as_array().unwrap().len(), 2);
}

#[test]
fn every_example_campaign_file_is_a_valid_request() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/campaigns");
    let mut files = 0;
    let paths = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path());
    for path in paths {
        if path.extension().and_then(|e| e.to_str()) != Some("json") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        let request: CampaignRequest =
            serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        // `begin`: a Bayesian example with several experiments issues a batch per experiment.
        Campaign::begin(request.clone()).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        files += 1;
        if path.ends_with("paper_scale_gpu.json") {
            // The paper-scale chain, every experiment on the GPU (issue 49).
            assert_eq!(request.backend, Some(BackendKind::Gpu));
            let cpu: CampaignRequest = serde_json::from_str(
                &std::fs::read_to_string(path.with_file_name("paper_scale.json")).unwrap(),
            )
            .unwrap();
            assert_eq!(cpu.backend, None);
            assert_eq!(
                CampaignRequest {
                    name: cpu.name.clone(),
                    backend: None,
                    ..request.clone()
                },
                cpu
            );
        }
        if path.ends_with("paper_three_targets.json") {
            let labels: Vec<String> = request.targets().into_iter().map(|t| t.label).collect();
            assert_eq!(
                labels,
                [
                    "aor.angle_deg",
                    "triaxial.cohesion_kpa",
                    "triaxial.friction_angle_deg"
                ]
            );
            assert_eq!(request.experiment_keys(), ["aor", "triaxial"]);
            // The heap is poured dry, as the paper's was: the cohesion acts on the triaxial
            // test (the paper's strength test; and the drilling validation) only.
            let n7 = request.factors.iter().find(|f| f.name == "N7").unwrap();
            assert!(n7.acts_on("triaxial") && !n7.acts_on("aor"));
            let v = request.drilling.as_ref().unwrap();
            assert_eq!(v.experiment.kind, "drill");
            assert_eq!(v.measured["opening_diameter_mm"], 63.20);
            // The paper's effective depth (603.66 mm) over its feed depth (600 mm): our presets drill
            // 100 mm, so the ratio is what compares.
            assert_eq!(v.measured["depth_ratio"], 1.006);
        }
    }
    assert!(files >= 4, "{files} campaign files");
    assert!(std::path::Path::new(dir)
        .join("paper_three_targets.json")
        .exists());
}

#[test]
fn two_metrics_of_one_experiment_share_its_batches() {
    let (campaign, _, next) = drive(request(json!({
        "experiments": {"soil": lookup(&["angle_deg", "cohesion_kpa"])},
        "targets": [
            {"response": "soil.angle_deg", "target": 34.0, "tolerance": {"relative_pct": 2}},
            {"response": "soil.cohesion_kpa", "target": 2.5, "tolerance": {"relative_pct": 4}}
        ],
    })));
    let Next::Finished(summary) = next else {
        panic!("not finished: {next:?}");
    };
    // One batch per stage step: both responses come from the same runs.
    assert_eq!(
        campaign
            .batches
            .iter()
            .filter(|b| b.stage == StageKind::Screening)
            .count(),
        1
    );
    assert!(campaign.batches.iter().all(|b| b.experiment == "soil"));
    assert!(!campaign.batches[0].request.name.contains('['));
    let value = |name: &str| {
        summary
            .parameters
            .iter()
            .find(|p| p.name == name)
            .unwrap()
            .value
    };
    assert!((value("A") - 0.25).abs() < 0.02, "A = {}", value("A"));
    assert!((value("B") - 0.5).abs() < 0.02, "B = {}", value("B"));
    assert!(summary.targets.iter().all(|t| t.within_tolerance));
}

#[test]
fn targets_that_cannot_hold_together_end_in_needs_attention_naming_the_response() {
    // The angle can reach at most 42 in the allowed ranges: 45 is out of reach.
    let (campaign, _, next) = drive(request(json!({
        "targets": [
            {"response": "aor.angle_deg", "target": 45.0, "tolerance": {"relative_pct": 2}},
            {"response": "shear.cohesion_kpa", "target": 2.5, "tolerance": {"relative_pct": 4}}
        ],
        "response_surface": {"max_extra_rounds": 1},
    })));
    for d in &campaign.decisions {
        println!("[{:?} r{}] {}", d.stage, d.round, d.text);
    }
    let Next::NeedsAttention(reason) = next else {
        panic!("expected a stop: {next:?}");
    };
    assert!(
        reason.contains("after 2 response-surface rounds"),
        "{reason}"
    );
    assert!(reason.contains("aor.angle_deg"), "{reason}");
    assert!(matches!(campaign.status, Status::NeedsAttention { .. }));
    let optimum = campaign
        .decisions
        .iter()
        .find(|d| d.stage == StageKind::Optimum);
    assert!(
        optimum.unwrap().text.contains("cannot all be met"),
        "{:?}",
        optimum
    );
    assert_eq!(campaign.verifications.len(), 2);
    assert!(campaign.verifications.iter().all(|v| !v.within_tolerance));
}

#[test]
fn a_validation_still_runs_when_verification_gives_up_and_the_campaign_then_stops() {
    // As above, 45 is out of reach; the drilling validation runs at the most desirable setting
    // found, and the campaign stops for attention with verification's reason after it.
    let (campaign, _, next) = drive(request(json!({
        "targets": [
            {"response": "aor.angle_deg", "target": 45.0, "tolerance": {"relative_pct": 2}},
            {"response": "shear.cohesion_kpa", "target": 2.5, "tolerance": {"relative_pct": 4}}
        ],
        "response_surface": {"max_extra_rounds": 1},
        "validation": {
            "experiment": lookup(&["opening_diameter_mm", "effective_depth_mm"]),
            "measured": {"opening_diameter_mm": 63.20, "effective_depth_mm": 603.66},
            "tolerance_pct": 5,
        }
    })));
    let Next::NeedsAttention(reason) = next else {
        panic!("expected a stop: {next:?}");
    };
    assert!(reason.contains("aor.angle_deg"), "{reason}");
    assert!(matches!(campaign.status, Status::NeedsAttention { .. }));
    assert_eq!(campaign.verifications.len(), 2);
    assert!(campaign.verifications.iter().all(|v| !v.within_tolerance));
    assert_eq!(campaign.batches.last().unwrap().stage, StageKind::Drilling);
    let v = campaign.drilling.as_ref().expect("validation reported");
    assert_eq!(v.metrics.len(), 2);
    assert!(v.metrics.iter().all(|m| m.simulated.is_some()), "{v:?}");
    assert!(campaign.unverified.is_none(), "taken when the stop is made");
    let plan = campaign
        .decisions
        .iter()
        .find(|d| d.stage == StageKind::Drilling)
        .unwrap();
    assert!(
        plan.text.contains("not a calibrated prediction"),
        "{}",
        plan.text
    );
    let result = campaign
        .decisions
        .iter()
        .filter(|d| d.stage == StageKind::Drilling)
        .nth(1)
        .unwrap();
    assert!(
        result.text.contains("does not reproduce the targets") && !result.text.contains("FAILED"),
        "{}",
        result.text
    );
    assert!(campaign.summary.is_none());
}

#[test]
fn a_factor_scoped_to_one_experiment_is_written_only_into_its_spec() {
    // A acts on the angle only and C (which moves nothing) on the shear test only: the other
    // experiment's batches keep the column in their design but never write it.
    let (campaign, _, next) = drive(request(json!({
        "factors": [
            {"name": "A", "path": "values.A", "low": 0.0, "high": 1.0, "experiments": ["aor"]},
            {"name": "B", "path": "values.B", "low": 0.0, "high": 1.0},
            {"name": "C", "path": "values.C", "low": 0.0, "high": 1.0, "experiments": ["shear"]}
        ],
        // Two factors go on, so C is held after screening whatever its noise-level t.
        "screening": {"design": {"type": "plackett_burman", "runs": 8}, "max_factors": 2},
    })));
    let Next::Finished(summary) = next else {
        panic!("not finished: {next:?}");
    };
    assert!(summary.within_tolerance);
    let value = |name: &str| {
        summary
            .parameters
            .iter()
            .find(|p| p.name == name)
            .unwrap()
            .value
    };
    assert!((value("A") - 0.25).abs() < 0.02, "A = {}", value("A"));
    assert!((value("B") - 0.5).abs() < 0.02, "B = {}", value("B"));
    let path_of = |b: &repose_campaign::IssuedBatch, name: &str| {
        b.request
            .factors
            .iter()
            .find(|f| f.name == name)
            .map(|f| f.path.clone())
    };
    let mut checked = 0;
    for b in &campaign.batches {
        match b.experiment.as_str() {
            "aor" => {
                assert_eq!(path_of(b, "A"), Some(Some("values.A".into())));
                assert!(matches!(path_of(b, "C"), None | Some(None)));
            }
            "shear" => {
                assert!(matches!(path_of(b, "A"), None | Some(None)));
                assert_eq!(path_of(b, "B"), Some(Some("values.B".into())));
            }
            other => panic!("unexpected experiment {other:?}"),
        }
        checked += 1;
        // After screening C is held: written at its hold value into the shear spec only.
        if b.stage == StageKind::Verification {
            let held = b.request.experiment.spec["values"]["C"].as_f64().unwrap();
            let expected = if b.experiment == "shear" { 0.5 } else { 0.0 };
            assert_eq!(held, expected, "{}", b.experiment);
        }
    }
    assert!(checked >= 6, "{checked} batches");
    let held = &campaign.screening.as_ref().unwrap().held;
    assert_eq!(held.len(), 1);
    assert_eq!(held[0].name, "C");
    let screening = &campaign.batches[0];
    assert_eq!(screening.request.factors.len(), 3);
    assert_eq!(
        campaign.batches[1].request.design, screening.request.design,
        "the experiments share the design rows"
    );
}

#[test]
fn a_factor_scope_names_existing_experiments() {
    let err = |scope: Value| {
        let factors = json!([
            {"name": "A", "path": "values.A", "low": 0.0, "high": 1.0, "experiments": scope},
            {"name": "B", "path": "values.B", "low": 0.0, "high": 1.0}
        ]);
        Campaign::start(request(json!({ "factors": factors })))
            .unwrap_err()
            .to_string()
    };
    let e = err(json!(["drill"]));
    assert!(e.starts_with("factors[0].experiments"), "{e}");
    assert!(e.contains("`drill`"), "{e}");
    let e = err(json!([]));
    assert!(e.starts_with("factors[0].experiments"), "{e}");
}
