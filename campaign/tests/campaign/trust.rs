//! What the Bayesian strategy tells a person, on the `formula` kind (closed-form responses with
//! seeded noise, run through the experiments' catalog as a worker would): the factor
//! influences (a factor written into one experiment only has none on the other's responses, a
//! factor that moves nothing gets little, one that drives a response gets most), a target met
//! only at the edge of the factor box (named so, not "out of reach", and sampled by the
//! exploration term before any stop), and a report whose sections agree with the result.

use crate::common;

use std::collections::BTreeMap;

use common::run_batch_with;
use repose_api::BatchRequest;
use repose_campaign::{Campaign, CampaignRequest, Step};
use serde_json::{json, Value};

/// A `formula` experiment: `inputs` (all 0 until a factor writes them), one expression and
/// one noise standard deviation per response.
fn formula(inputs: &[&str], responses: &[(&str, &str, f64)]) -> Value {
    let inputs: BTreeMap<&str, f64> = inputs.iter().map(|n| (*n, 0.0)).collect();
    let exprs: BTreeMap<&str, &str> = responses.iter().map(|(m, e, _)| (*m, *e)).collect();
    let noise: BTreeMap<&str, f64> = responses.iter().map(|(m, _, sd)| (*m, *sd)).collect();
    json!({"kind": "formula",
           "spec": {"inputs": inputs, "responses": exprs, "noise_sd": noise}})
}

/// Factor `name` over `[0, 1]` at `inputs.<name>`, written into `only` when given.
fn factor(name: &str, only: Option<&[&str]>) -> Value {
    let mut f = json!({"name": name, "path": format!("inputs.{name}"), "low": 0.0, "high": 1.0});
    if let Some(keys) = only {
        f["experiments"] = json!(keys);
    }
    f
}

/// Drives a campaign to its end, every run by the `formula` kind: the campaign and its last
/// step.
fn drive(request: Value) -> (Campaign, Step) {
    let request: CampaignRequest = serde_json::from_value(request).expect("request parses");
    let (mut campaign, batches) = Campaign::begin(request).expect("begins");
    let mut outstanding: Vec<(usize, BatchRequest)> = batches.into_iter().enumerate().collect();
    let mut last = None;
    while let Some((index, batch)) = outstanding.pop() {
        let result = run_batch_with(index, &batch, |spec, seed| {
            repose_experiments::catalog::run_experiment("formula", spec, seed, &mut |_| {
                repose_experiments::aor::Control::Continue
            })
            .map(|o| o.metrics)
            .map_err(|e| e.to_string())
        });
        let step = campaign.step(&result).expect("step");
        if let Step::Submit(next) = &step {
            let first = campaign.batches.len() - next.len();
            outstanding.extend(
                next.iter()
                    .cloned()
                    .enumerate()
                    .map(|(i, b)| (first + i, b)),
            );
        }
        last = Some(step);
        assert!(campaign.batches.len() < 100, "runaway campaign");
    }
    (campaign, last.expect("a step"))
}

fn share(summary: &repose_campaign::Summary, response: &str, factor: usize) -> f64 {
    let bayes = summary.bayesian.as_ref().expect("bayesian result");
    let inf = bayes
        .influences
        .iter()
        .find(|i| i.response == response)
        .expect("the response's influences");
    inf.share[factor]
}

// ------------------------------------------------------------------------------------------
// Influences.

/// The funnel's angle moves with a (and a little with b); the box's cohesion with c alone,
/// which is written into the box only; d moves nothing.
#[test]
fn influences_follow_what_each_experiment_is_given_and_what_moves_it() {
    let request = json!({
        "name": "influences",
        "strategy": {"type": "bayesian", "max_runs": 80, "batch_size": 4},
        "experiments": {
            "aor": formula(&["a", "b", "d"], &[("angle_deg", "25 + 10*a + 2*b", 0.3)]),
            "shear": formula(&["a", "b", "c", "d"], &[("cohesion_kpa", "1 + 2*c", 0.04)]),
        },
        "targets": [
            {"response": "aor.angle_deg", "target": 31.0, "tolerance": {"relative_pct": 3}},
            {"response": "shear.cohesion_kpa", "target": 2.0, "tolerance": {"relative_pct": 5}}
        ],
        "factors": [factor("a", None), factor("b", None), factor("c", Some(&["shear"])),
                    factor("d", None)],
        "seed": 7,
    });
    let (campaign, last) = drive(request);
    let Step::Finished(summary) = last else {
        panic!("{last:?}\n{:#?}", campaign.decisions);
    };
    assert!(summary.within_tolerance);
    let bayes = summary.bayesian.as_ref().unwrap();
    for inf in &bayes.influences {
        eprintln!("{inf:?}");
    }
    let angle = &bayes.influences[0];
    assert_eq!(angle.response, "aor.angle_deg");
    // c is not written into the funnel: no length-scale, no share, by construction.
    assert_eq!(angle.length_scales[2], None);
    assert_eq!(angle.share[2], 0.0);
    // The factor that drives each response gets most of its variation.
    assert!(share(&summary, "aor.angle_deg", 0) > 0.8, "{angle:?}");
    assert!(
        share(&summary, "shear.cohesion_kpa", 2) > 0.8,
        "{:?}",
        bayes.influences[1]
    );
    // d moves nothing: little, in both; so do a and b on the cohesion.
    assert!(share(&summary, "aor.angle_deg", 3) < 0.05, "{angle:?}");
    for j in [0, 1, 3] {
        assert!(share(&summary, "shear.cohesion_kpa", j) < 0.05, "{j}");
    }
    // The shares of each response sum to 1, and no length-scale is below what its runs resolve.
    for inf in &bayes.influences {
        assert!((inf.share.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        let min = inf.min_length_scale.expect("the bound");
        assert!(inf
            .length_scales
            .iter()
            .flatten()
            .all(|l| *l >= min - 1e-12));
    }
    // The report says the funnel is not given c.
    let html = repose_campaign::report_html(&campaign, &[], &Default::default());
    assert!(
        html.contains("c (not given)"),
        "the chart names the factor left out"
    );
}

// ------------------------------------------------------------------------------------------
// A target met only at the edge of the factor box.

/// y rises with a to 16.3 at the box's corner (a = b = 1); the band starts at 16.4, half a
/// run's noise above it. Runs at the corner reach the band within their noise, a mean of three
/// rarely does: the target is met only at a's high edge.
fn edge_request(seed: u64, max_runs: usize) -> Value {
    json!({
        "name": "edge",
        "strategy": {"type": "bayesian", "max_runs": max_runs, "batch_size": 4},
        "experiment": formula(&["a", "b"], &[("y", "10 + 6*a + 0.3*b", 0.2)]),
        "response": "y",
        "target": 16.4 / 0.98,
        "tolerance": {"relative_pct": 2},
        "factors": [factor("a", None), factor("b", None)],
        "seed": seed,
    })
}

#[test]
fn a_target_met_only_at_the_edge_is_named_so_and_not_out_of_reach() {
    // (Seed 1's first runs at the edge read 0.1-0.5 below the band while the noise, estimated
    // from ten settings, came out far below its true 0.2: it stops "out of reach" after sampling
    // the edge, which is the next test's matter.)
    for seed in [2, 3] {
        let (campaign, last) = drive(edge_request(seed, 30));
        let log: Vec<&str> = campaign.decisions.iter().map(|d| d.text.as_str()).collect();
        let Step::NeedsAttention(reason) = last else {
            panic!("seed {seed}: {last:?}\n{log:#?}");
        };
        eprintln!("seed {seed}: {reason}");
        assert!(
            !reason.contains("cannot be reached"),
            "seed {seed}: {reason}"
        );
        assert!(
            reason.contains("Met only at the edge of the factor box, not out of reach: y (a at its high edge (1)"),
            "seed {seed}: {reason}"
        );
        let summary = campaign.summary.as_ref().unwrap();
        let bayes = summary.bayesian.as_ref().unwrap();
        assert!(bayes.out_of_reach.is_empty());
        let edge = &bayes.at_edge[0];
        assert_eq!(edge.response, "y");
        assert!(
            edge.edges[0].factor == "a" && edge.edges[0].high,
            "{edge:?}"
        );
        assert!(
            edge.runs >= 1 && edge.closest >= 16.4 - edge.noise_sd,
            "{edge:?}"
        );
        let html = repose_campaign::report_html(&campaign, &[], &Default::default());
        assert!(html.contains(
            "Met only at the edge of the factor box, not out of reach: y (a at its high edge"
        ));
        assert!(!html.contains("Out of reach in the factor box"));
    }
}

/// The angle is met only at a's high edge (as above); the cohesion needs a near 0.3. Aiming at
/// both together keeps the search near the middle of a; the exploration term sends a point to
/// the edge once the angle is found out of reach, before the campaign may stop on it. (Without
/// the term, seed 2 stops "out of reach" with no run beyond a = 0.9 after the first finding;
/// seed 3 samples the edge, reads 15.7 there, and then stops out of reach.)
#[test]
fn the_edge_is_sampled_before_any_out_of_reach_stop() {
    for seed in [2, 3] {
        let request = json!({
            "name": "edge and middle",
            "strategy": {"type": "bayesian", "max_runs": 36, "batch_size": 4},
            "experiments": {
                "aor": formula(&["a", "b"], &[("angle_deg", "10 + 6*a + 0.3*b", 0.2)]),
                "shear": formula(&["a", "b"], &[("cohesion_kpa", "1 + 2*a", 0.03)]),
            },
            "targets": [
                {"response": "aor.angle_deg", "target": 16.4 / 0.98,
                 "tolerance": {"relative_pct": 2}},
                {"response": "shear.cohesion_kpa", "target": 1.6, "tolerance": {"relative_pct": 5}}
            ],
            "factors": [factor("a", None), factor("b", None)],
            "seed": seed,
        });
        let (campaign, last) = drive(request);
        let log: Vec<&str> = campaign.decisions.iter().map(|d| d.text.as_str()).collect();
        let state = campaign.bayes.as_ref().unwrap();
        eprintln!("seed {seed}: {last:?}");
        let flagged = log
            .iter()
            .position(|t| t.contains("Out of reach even alone: aor.angle_deg"))
            .unwrap_or_else(|| panic!("seed {seed}: never out of reach"));
        let first_round = log[..flagged]
            .iter()
            .filter(|t| t.starts_with("Next round"))
            .count() as u32
            + 1;
        let at_edge_after = state
            .observations
            .iter()
            .filter(|o| o.round >= first_round && o.point[0] >= 0.9)
            .count();
        assert!(
            at_edge_after > 0,
            "seed {seed}: the edge was never sampled\n{log:#?}"
        );
        // By the exploring point of the next round.
        assert!(
            log[flagged + 1].contains("1 exploring where aor.angle_deg could still be met"),
            "seed {seed}: {}",
            log[flagged + 1]
        );
    }
}

// ------------------------------------------------------------------------------------------
// The report agrees with the result.

/// A band narrower than three runs' noise can promise: no setting's verified mean lands in it
/// with probability 0.5 (at best 25 %), so the region is empty, and the budget's last
/// verification passes or not by chance. Either way the region's words agree with the result.
#[test]
fn the_region_section_agrees_with_a_verified_result() {
    let mut verified = 0;
    for seed in 1..=6 {
        let request = json!({
            "name": "narrow band",
            "strategy": {"type": "bayesian", "max_runs": 30, "batch_size": 4},
            "experiment": formula(&["a", "b"], &[("y", "10 + 2*a + 0.1*b", 0.6)]),
            "response": "y",
            "target": 11.0,
            "tolerance": {"relative_pct": 1},
            "factors": [factor("a", None), factor("b", None)],
            "seed": seed,
        });
        let (campaign, _) = drive(request);
        let summary = campaign.summary.as_ref().expect("a result");
        let region = &summary.bayesian.as_ref().unwrap().region;
        assert!(region.points.is_empty(), "seed {seed}: {}", region.fraction);
        let at_result = region.at_result.expect("the result's probability");
        assert!(at_result < region.threshold, "seed {seed}: {at_result}");
        let html = repose_campaign::report_html(&campaign, &[], &Default::default());
        let section = &html[html
            .find("Region consistent with every measurement")
            .unwrap()..];
        if summary.within_tolerance {
            verified += 1;
            assert!(
                !html.contains("no setting is likely to meet them all"),
                "seed {seed}"
            );
            assert!(
                section.contains("The verification, not the region, is the evidence"),
                "seed {seed}"
            );
            assert!(
                section.contains("and its replicates verified it."),
                "seed {seed}"
            );
        } else {
            assert!(
                section.contains("None: no setting is likely to meet them all."),
                "seed {seed}"
            );
            assert!(!section.contains("verified"), "seed {seed}");
        }
    }
    eprintln!("{verified} of 6 verified");
    assert!(
        (1..6).contains(&verified),
        "both cases: {verified} of 6 verified"
    );
}
