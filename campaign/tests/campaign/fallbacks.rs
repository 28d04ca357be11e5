//! The documented fallbacks, on synthetic responses (a closure stands in for the simulation).

use crate::common;

use std::collections::BTreeMap;

use common::run_batch_with;
use repose_api::BatchRequest;
use repose_campaign::{Campaign, CampaignRequest, CarryRule, Next, StageKind, StageResult, Status};
use serde_json::{json, Value};

fn request(extra: Value) -> CampaignRequest {
    let mut base = json!({
        "name": "synthetic",
        "experiment": {"kind": "synthetic", "spec": {"values": {"A": 0.0, "B": 0.0, "C": 0.0, "D": 0.0}}},
        "factors": [
            {"name": "A", "path": "values.A", "low": 0.0, "high": 1.0},
            {"name": "B", "path": "values.B", "low": 0.0, "high": 1.0},
            {"name": "C", "path": "values.C", "low": 0.0, "high": 1.0},
            {"name": "D", "path": "values.D", "low": 0.0, "high": 1.0, "fixed_at": 0.2}
        ],
        "target": 34.0,
        "seed": 11,
    });
    for (k, v) in extra.as_object().unwrap() {
        base[k] = v.clone();
    }
    serde_json::from_value(base).unwrap()
}

/// Deterministic noise in [-amp/2, amp/2] from the run seed.
fn noise(seed: u64, amp: f64) -> f64 {
    ((seed % 1000) as f64 / 999.0 - 0.5) * amp
}

fn values(spec: &Value) -> [f64; 4] {
    let v = &spec["values"];
    ["A", "B", "C", "D"].map(|n| v[n].as_f64().unwrap())
}

type Truth = dyn Fn(&BatchRequest, [f64; 4], u64) -> f64;

/// Drives a campaign until it stops or `limit` batches ran.
fn drive(
    request: CampaignRequest,
    truth: &Truth,
    limit: usize,
) -> (Campaign, Vec<StageResult>, Next) {
    let (mut campaign, mut batch) = Campaign::start(request).unwrap();
    let mut results = Vec::new();
    loop {
        let index = campaign.outstanding().unwrap();
        let b = batch.clone();
        let result = run_batch_with(index, &batch, |spec, seed| {
            Ok(BTreeMap::from([(
                "angle_deg".to_owned(),
                truth(&b, values(spec), seed),
            )]))
        });
        let next = campaign.advance(&result).unwrap();
        results.push(result);
        match &next {
            Next::Submit(nb) if results.len() < limit => batch = nb.clone(),
            _ => return (campaign, results, next),
        }
    }
}

fn smooth(x: [f64; 4]) -> f64 {
    let [a, b, c, d] = x;
    25.0 + 10.0 * a + 4.0 * b + 0.3 * c - 0.2 * d - 3.0 * a * a + 1.0 * a * b
}

#[test]
fn none_significant_carries_the_largest_t_and_says_so() {
    let truth = |_: &BatchRequest, _x: [f64; 4], seed: u64| 30.0 + noise(seed, 2.0);
    let (campaign, _, next) = drive(request(json!({"seed": 3})), &truth, 1);
    let s = campaign.screening.as_ref().unwrap();
    assert!(s.significant.is_empty(), "{:?}", s.p_values);
    assert_eq!(s.rule, CarryRule::NoneSignificant);
    assert_eq!(s.carried.len(), 2);
    // The carried ones are those with the largest |t|.
    let mut t: Vec<(f64, &String)> = s
        .t_values
        .iter()
        .zip(&s.factors)
        .map(|(t, n)| (t.unwrap().abs(), n))
        .collect();
    t.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut top: Vec<String> = t[..2].iter().map(|(_, n)| (*n).clone()).collect();
    top.sort();
    assert_eq!(s.carried, top);
    let text = &campaign.decisions[1].text;
    assert!(text.contains("No factor is significant"), "{text}");
    let Next::Submit(b) = next else {
        panic!("the campaign goes on")
    };
    assert_eq!(b.name, "synthetic: steepest path");
    // Held factors are written into the spec: D at its user value, the others at mid-range.
    assert_eq!(s.held.len(), 2);
    for h in &s.held {
        let expected = if h.name == "D" { 0.2 } else { 0.5 };
        assert_eq!(h.value, expected);
        assert_eq!(b.experiment.spec["values"][&h.name], json!(expected));
    }
}

#[test]
fn too_many_significant_keeps_the_top_k_by_t() {
    let truth = |_: &BatchRequest, x: [f64; 4], seed: u64| {
        30.0 + 8.0 * x[0] + 6.0 * x[1] + 4.0 * x[2] + 2.0 * x[3] + noise(seed, 0.05)
    };
    let (campaign, _, _) = drive(request(json!({})), &truth, 1);
    let s = campaign.screening.as_ref().unwrap();
    assert_eq!(s.significant, ["A", "B", "C", "D"]);
    assert_eq!(s.carried, ["A", "B", "C"]);
    assert_eq!(
        s.rule,
        CarryRule::TopOfSignificant {
            dropped: vec!["D".into()]
        }
    );
    assert!(campaign.decisions[1].text.contains("more than the 3"));
}

#[test]
fn a_path_that_never_crosses_the_target_falls_back_to_the_closest_point() {
    // Target far above anything reachable in the allowed ranges.
    let truth = |_: &BatchRequest, x: [f64; 4], seed: u64| smooth(x) + noise(seed, 0.05);
    let req =
        request(json!({"target": 80.0, "steepest": {"points_per_dispatch": 2, "max_points": 10}}));
    let (campaign, _, next) = drive(req, &truth, 20);
    let path = campaign.path.as_ref().unwrap();
    assert!(!path.crossed);
    let steepest_batches = campaign
        .batches
        .iter()
        .filter(|b| b.stage == StageKind::Steepest)
        .count();
    assert!(steepest_batches >= 2, "several dispatches before giving up");
    assert_eq!(path.dispatched, path.points.len(), "every point was tried");
    let centre = path.centre.unwrap();
    let best = path
        .points
        .iter()
        .enumerate()
        .min_by(|a, b| {
            (a.1.response.unwrap() - 80.0)
                .abs()
                .total_cmp(&(b.1.response.unwrap() - 80.0).abs())
        })
        .unwrap()
        .0;
    assert_eq!(centre, best);
    assert!(campaign
        .decisions
        .iter()
        .any(|d| d.text.contains("never crossed the target")));
    assert!(campaign.decisions.iter().any(|d| d
        .text
        .contains("starts from the corner below the target 80 and walks toward it (the target lies beyond both corners' predictions")));
    assert_eq!(campaign.surfaces[0].centre, path.points[centre].natural);
    // The unreachable target ends in a stop with a reason, not silently.
    let Next::NeedsAttention(reason) = next else {
        panic!("expected a stop, got {next:?}")
    };
    assert!(
        reason.contains("verification is still outside the tolerance"),
        "{reason}"
    );
}

#[test]
fn failed_verification_starts_another_round_then_stops() {
    // Simulations at the optimum come out 4 higher than the surface predicts (e.g. a model
    // that misses local structure); the target is reachable.
    let truth = |b: &BatchRequest, x: [f64; 4], seed: u64| {
        smooth(x)
            + noise(seed, 0.05)
            + if b.name.contains("verification") {
                4.0
            } else {
                0.0
            }
    };
    let (campaign, results, next) = drive(request(json!({})), &truth, 20);
    for d in &campaign.decisions {
        println!("[{:?} r{}] {}", d.stage, d.round, d.text);
    }
    assert_eq!(
        campaign.verifications.len(),
        3,
        "1 + max_extra_rounds (2) verifications"
    );
    assert!(campaign.verifications.iter().all(|v| !v.within_tolerance));
    assert_eq!(campaign.surfaces.len(), 3);
    // The target is reachable, so each further round is centred at the previous optimum with
    // half the half-ranges.
    for w in campaign.surfaces.windows(2) {
        let prev = w[0].optimum.as_ref().unwrap();
        assert_eq!(w[1].centre, prev.natural);
        for (a, b) in w[0].factors.iter().zip(&w[1].factors) {
            assert!(b.high - b.low <= 0.5 * (a.high - a.low) + 1e-12);
        }
    }
    assert!(campaign
        .batches
        .iter()
        .any(|b| b.request.name == "synthetic: response surface (round 2)"));
    let Next::NeedsAttention(reason) = next else {
        panic!("{next:?}")
    };
    assert!(
        reason.contains("after 3 response-surface rounds"),
        "{reason}"
    );
    assert!(matches!(campaign.status, Status::NeedsAttention { .. }));
    // A stopped campaign refuses further input.
    assert!(campaign.clone().advance(results.last().unwrap()).is_err());
}

#[test]
fn a_small_bias_verifies_and_finishes() {
    let truth = |_: &BatchRequest, x: [f64; 4], seed: u64| smooth(x) + noise(seed, 0.2);
    let (campaign, _, next) = drive(request(json!({})), &truth, 20);
    let Next::Finished(summary) = next else {
        panic!("{next:?}")
    };
    assert!(summary.within_tolerance);
    assert_eq!(summary.parameters.len(), 4);
    assert!(matches!(campaign.status, Status::Finished));
}

#[test]
fn requests_are_validated_with_the_field_named() {
    let mut bad = request(json!({}));
    bad.factors[1].low = 2.0;
    let err = Campaign::start(bad).unwrap_err().to_string();
    assert!(err.starts_with("factors[1].low"), "{err}");
    let err = serde_json::from_value::<CampaignRequest>(json!({
        "name": "x", "experiment": {"kind": "aor"}, "factors": [], "target": 1.0, "bogus": 1
    }))
    .unwrap_err()
    .to_string();
    assert!(err.contains("bogus"), "{err}");
    let mut wrong = request(json!({}));
    wrong.screening.design = repose_api::DesignRequest::BoxBehnken {
        centre_points: None,
    };
    assert!(Campaign::start(wrong).is_err());
}

#[test]
fn advance_rejects_a_batch_that_is_not_outstanding() {
    let (mut campaign, _) = Campaign::start(request(json!({}))).unwrap();
    let err = campaign
        .advance(&StageResult {
            batch: 3,
            runs: vec![],
            analysis: None,
        })
        .unwrap_err();
    assert!(err.to_string().contains("expected 0"));
}

#[test]
fn points_beyond_the_crossing_do_not_compete_for_the_centre() {
    // Along the path the response jumps over the target (20 → 40) and then falls back to 36.5,
    // which is closer to 34 than 40 but lies beyond the crossing.
    let truth = |b: &BatchRequest, x: [f64; 4], seed: u64| {
        if b.name.ends_with("steepest path") {
            let a = x[0];
            if a > 0.75 {
                20.0
            } else if a > 0.25 {
                40.0
            } else {
                36.5
            }
        } else {
            smooth(x) + noise(seed, 0.05)
        }
    };
    let req = request(json!({"steepest": {"points_per_dispatch": 10, "max_points": 10}}));
    let (campaign, _, _) = drive(req, &truth, 2);
    let path = campaign.path.as_ref().unwrap();
    let responses: Vec<f64> = path.points[..path.dispatched]
        .iter()
        .map(|p| p.response.unwrap())
        .collect();
    let closest = (0..responses.len())
        .min_by(|&a, &b| {
            (responses[a] - 34.0)
                .abs()
                .total_cmp(&(responses[b] - 34.0).abs())
        })
        .unwrap();
    assert_eq!(
        responses[..3],
        [20.0, 40.0, 36.5],
        "the set-up: the path starts at A = 1"
    );
    assert_eq!(responses[closest], 36.5, "a closer point past the crossing");
    let centre = path.centre.unwrap();
    assert_eq!(responses[centre], 40.0, "{responses:?}");
    assert!(campaign
        .decisions
        .iter()
        .any(|d| d.text.contains("later steps do not count")));
}

#[test]
fn an_unreachable_target_moves_the_next_region_instead_of_shrinking_it() {
    // Every response-surface and verification run comes out 15 higher than the screening and
    // path saw, so the target 34 is never reachable inside a response-surface region.
    let truth = |b: &BatchRequest, x: [f64; 4], seed: u64| {
        smooth(x)
            + noise(seed, 0.05)
            + if b.name.contains("response surface") || b.name.contains("verification") {
                15.0
            } else {
                0.0
            }
    };
    let (campaign, _, next) = drive(request(json!({})), &truth, 20);
    assert!(matches!(next, Next::NeedsAttention(_)), "{next:?}");
    assert_eq!(campaign.surfaces.len(), 3);
    for w in campaign.surfaces.windows(2) {
        let prev = w[0].optimum.as_ref().unwrap();
        assert!(prev.desirability < 0.999, "unreachable: {prev:?}");
        assert_eq!(w[1].centre, prev.natural);
        assert_eq!(w[1].half_ranges, w[0].half_ranges, "same size, moved");
    }
    // The regions do move: round 2 is not round 1.
    assert_ne!(campaign.surfaces[1].centre, campaign.surfaces[0].centre);
    assert!(campaign
        .decisions
        .iter()
        .any(|d| d.text.contains("moves toward it instead of shrinking")));
}

#[test]
fn markup_in_names_and_reasons_is_escaped_exactly_once_in_the_report() {
    const NASTY: &str = "<script>alert(\"x\")</script> & co";
    const ESCAPED: &str = "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; co";
    const FACTOR: &str = "A<&>";
    const FACTOR_ESCAPED: &str = "A&lt;&amp;&gt;";
    let mut r = request(json!({
        "name": NASTY,
        "experiment": {
            "kind": "synthetic",
            "preset": NASTY,
            "spec": {"values": {"A": 0.0, "B": 0.0, "C": 0.0, "D": 0.0}}
        },
    }));
    r.factors[0].name = FACTOR.to_owned();
    let (mut campaign, batch) = Campaign::start(r).unwrap();
    // The screening batch, its first run dead with markup in its error.
    let mut first = true;
    let result = run_batch_with(0, &batch, |spec, seed| {
        if std::mem::take(&mut first) {
            return Err(NASTY.to_owned());
        }
        let value = smooth(values(spec)) + noise(seed, 0.2);
        Ok(BTreeMap::from([("angle_deg".to_owned(), value)]))
    });
    campaign.advance(&result).unwrap();
    campaign.status = Status::NeedsAttention {
        reason: NASTY.to_owned(),
    };
    let html = repose_campaign::report_html(&campaign, &[result], &Default::default());

    // Escaped once where each appears: the title and heading, the status, the experiment's
    // preset, the batch names and the dead run's reason in the provenance table, the factor in
    // the tables and in the Pareto chart's SVG.
    for needle in [
        format!("<title>Calibration campaign: {ESCAPED}</title>"),
        format!("<h1>Calibration campaign: {ESCAPED}</h1>"),
        format!("<span class=\"bad\">needs attention</span>: {ESCAPED}. "),
        format!("<b>synthetic</b> (preset {ESCAPED})"),
        format!("<td class=\"l\">{ESCAPED}: screening</td>"),
        format!("<td>{ESCAPED}</td></tr>"),
        format!("<th>{FACTOR_ESCAPED}</th>"),
        format!("font-weight=\"bold\">{FACTOR_ESCAPED}</text>"),
    ] {
        assert!(html.contains(&needle), "report lacks {needle:?}");
    }
    assert!(!html.contains("<script"), "markup got through");
    assert!(!html.contains(FACTOR), "markup got through");
    for twice in ["&amp;lt;", "&amp;gt;", "&amp;amp;", "&amp;quot;"] {
        assert!(!html.contains(twice), "escaped twice: {twice}");
    }
    let body = html
        .trim_start_matches("<!DOCTYPE html>")
        .replace("<meta charset=\"utf-8\">", "");
    roxmltree::Document::parse(&body).expect("well-formed page");
}
