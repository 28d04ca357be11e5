//! Replay of the paper (Zhang et al.): the campaign is driven with responses looked up from the
//! paper's Tables 3, 5 and 6 through the `table_lookup` replay kind (a test aid, not a
//! simulation), and its decisions must be the paper's.
//!
//! Verification: the paper has no table of runs at the optimum the campaign picks (any point
//! of the 34.85° level set is valid), so the verification rows are synthesised at the point
//! the campaign asks for from the paper's own Eq. 16 (its fitted quadratic) plus fixed
//! deviations of the size of Table 6's pure error (−0.5, +0.1, +0.4; mean 0). They are added to
//! the lookup table when the verification batch is issued and are labelled in the spec
//! (`"source": "synthetic: Eq. 16 + fixed deviations"`).

use crate::common;

use common::*;
use repose_campaign::{
    report_html, report_json, Campaign, CampaignRequest, CarryRule, Next, ReportPictures,
    StageKind, StageResult,
};
use serde_json::json;

fn paper_request() -> CampaignRequest {
    serde_json::from_value(paper_campaign_json("paper replay")).expect("request parses")
}

/// Adds the synthetic verification rows (Eq. 16 at the requested point) to the batch's table.
fn add_verification_rows(batch: &mut repose_api::BatchRequest) {
    let repose_api::DesignRequest::Explicit { points } = &batch.design else {
        panic!("verification is an explicit design");
    };
    assert_eq!(points.len(), 1, "verification is one point");
    let p = &points[0];
    let y = eq16(p);
    let rows = batch.experiment.spec["rows"].as_array_mut().unwrap();
    for dev in [-0.5, 0.1, 0.4] {
        let mut row = serde_json::Map::new();
        for (f, v) in batch.factors.iter().zip(p) {
            row.insert(f.name.clone(), json!(v));
        }
        for (n, v) in HELD {
            row.insert(n.into(), json!(v));
        }
        row.insert("angle_deg".into(), json!(y + dev));
        rows.push(serde_json::Value::Object(row));
    }
}

pub fn run_paper_campaign() -> (Campaign, Vec<StageResult>) {
    let (mut campaign, first) = Campaign::start(paper_request()).unwrap();
    let mut results = Vec::new();
    let mut batch = first;
    loop {
        let index = campaign.outstanding().unwrap();
        if campaign.batches[index].stage == StageKind::Verification {
            add_verification_rows(&mut batch);
        }
        let result = run_lookup(index, &batch);
        // The state survives a round trip through JSON at every step (server restart).
        campaign = serde_json::from_str(&serde_json::to_string(&campaign).unwrap()).unwrap();
        let next = campaign.advance(&result).unwrap();
        results.push(result);
        match next {
            Next::Submit(b) => batch = b,
            Next::Finished(_) => break,
            Next::NeedsAttention(reason) => panic!("needs attention: {reason}"),
        }
    }
    (campaign, results)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn paper_replay_reproduces_the_papers_decisions() {
    let (campaign, results) = run_paper_campaign();
    for d in &campaign.decisions {
        println!("[{:?} r{}] {}", d.stage, d.round, d.text);
    }

    // Stage 1: N2, N3, N5 significant; N1, N4, N6 held at 0.45, 0.40, 0.50.
    let s = campaign.screening.as_ref().unwrap();
    assert_eq!(s.carried, ["N2", "N3", "N5"]);
    assert_eq!(s.rule, CarryRule::Significant);
    let mut sig = s.significant.clone();
    sig.sort();
    assert_eq!(sig, ["N2", "N3", "N5"]);
    let held: Vec<(String, f64)> = s.held.iter().map(|h| (h.name.clone(), h.value)).collect();
    assert_eq!(held.len(), 3);
    for ((n, v), (en, ev)) in held.iter().zip(HELD) {
        assert_eq!(n, en);
        assert!(close(*v, ev, 1e-12), "{n} held at {v}");
    }
    // Table 4's coefficients (paper: 2.30, 7.36, 1.87 for N2, N3, N5).
    for (name, expected) in [("N2", 2.30), ("N3", 7.36), ("N5", 1.87)] {
        let i = s.factors.iter().position(|f| f == name).unwrap();
        assert!(
            close(s.estimates[i], expected, 0.01),
            "{name}: {}",
            s.estimates[i]
        );
    }

    // Stage 2: steps 0.04 / 0.195 / 0.05; the path is Table 5; step 2 is the centre.
    let path = campaign.path.as_ref().unwrap();
    assert_eq!(path.base_factor, "N3");
    assert_eq!(path.direction, repose_doe::design::PathDirection::Ascent);
    for (step, expected) in path.step_natural.iter().zip([0.04, 0.195, 0.05]) {
        assert!(close(*step, expected, 1e-9), "step {step} vs {expected}");
    }
    let table5 = paper_csv("steepest_ascent_table5.csv");
    assert_eq!(
        path.dispatched, 5,
        "one dispatch of five points crosses the target"
    );
    for (point, row) in path.points.iter().zip(&table5) {
        for (v, n) in point.natural.iter().zip(["N2", "N3", "N5"]) {
            assert!(
                close(*v, row[n], 1e-9),
                "step {}: {n} {v} vs {}",
                point.step,
                row[n]
            );
        }
        assert!(close(point.response.unwrap(), row["angle_deg"], 1e-9));
    }
    assert_eq!(path.centre, Some(1), "step 2 is the centre");
    assert!(path.crossed);

    // Stage 3: Table 6's levels.
    let round = &campaign.surfaces[0];
    for (f, (n, lo, hi)) in round.factors.iter().zip(BBD_LEVELS) {
        assert_eq!(f.name, n);
        assert!(close(f.low, lo, 1e-9) && close(f.high, hi, 1e-9), "{f:?}");
    }
    let fit = round.fit.as_ref().unwrap();
    // Table 7 has R² 0.9984, adjusted 0.9962. The five centre runs draw their values from the
    // five Table 6 centre rows by seed (with replacement, as replicates would), so the figures
    // match Table 7 closely rather than exactly.
    assert!(close(fit.r2, 0.9984, 1e-3), "R² {}", fit.r2);
    assert!(
        close(fit.adj_r2, 0.9962, 2e-3),
        "adjusted R² {}",
        fit.adj_r2
    );
    assert!(fit.lack_of_fit_p.unwrap() > 0.05);
    let mut sig_terms = fit.significant_terms.clone();
    sig_terms.sort();
    assert_eq!(
        sig_terms,
        ["N2", "N2:N3", "N2^2", "N3", "N3:N5", "N3^2", "N5"]
    ); // Table 7

    // Stage 4: on the 34.85° level set, which passes by the paper's (0.442, 0.140, 0.305).
    let opt = round.optimum.as_ref().unwrap();
    assert!(opt.level_set);
    assert!(
        close(opt.predicted, 34.85, 0.01),
        "predicted {}",
        opt.predicted
    );
    assert!(opt.starts_at_best > 10 && opt.spread > 1.0, "{opt:?}");
    let paper = [0.442, 0.140, 0.305];
    for (i, v) in paper.iter().enumerate() {
        assert!(
            opt.natural_min[i] - 1e-3 <= *v && *v <= opt.natural_max[i] + 1e-3,
            "paper value {v} of factor {i} outside the reported extent {}..{}",
            opt.natural_min[i],
            opt.natural_max[i]
        );
    }
    // The campaign's model at the paper's point: Eq. 16 gives 34.87.
    let model = repose_campaign_fit(&campaign, &results);
    let coded: Vec<f64> = paper
        .iter()
        .zip(&round.factors)
        .map(|(v, f)| (v - f.centre()) / f.half_range())
        .collect();
    let at_paper = model.predict(&coded);
    assert!(
        close(at_paper, 34.87, 0.02),
        "prediction at the paper's point {at_paper}"
    );
    // First-order distance from the paper's point to the level set, coded units.
    let h = 1e-6;
    let grad: Vec<f64> = (0..3)
        .map(|j| {
            let mut x = coded.clone();
            x[j] += h;
            (model.predict(&x) - at_paper) / h
        })
        .collect();
    let distance = (at_paper - 34.85).abs() / grad.iter().map(|g| g * g).sum::<f64>().sqrt();
    assert!(distance < 0.01, "distance to the level set {distance}");
    println!("prediction at the paper's point {at_paper:.3}, distance to the level set {distance:.5} coded");

    // Stage 5: verification within 5 %.
    let v = campaign.verifications.last().unwrap();
    assert_eq!(v.responses.len(), 3);
    assert!(v.within_tolerance && v.relative_error_pct < 1.0, "{v:?}");
    let summary = campaign.summary.as_ref().unwrap();
    assert_eq!(summary.surface_rounds, 1);
    assert_eq!(summary.batches, 4);
    let names: Vec<&str> = campaign
        .batches
        .iter()
        .map(|b| b.request.name.as_str())
        .collect();
    assert_eq!(
        names,
        [
            "paper replay: screening",
            "paper replay: steepest path",
            "paper replay: response surface",
            "paper replay: verification"
        ]
    );
    // Fresh seeds: no two runs of the campaign share a seed.
    let mut seeds: Vec<u64> = results
        .iter()
        .flat_map(|r| r.runs.iter().map(|x| x.seed))
        .collect();
    let n = seeds.len();
    seeds.sort_unstable();
    seeds.dedup();
    assert_eq!(seeds.len(), n);

    // Report.
    let json = report_json(&campaign, &results);
    assert_eq!(
        json["stages"]["screening"]["carried"],
        json!(["N2", "N3", "N5"])
    );
}

#[test]
fn the_report_renders_with_anova_optimum_and_well_formed_svg() {
    let (campaign, results) = run_paper_campaign();
    let pile = r##"<svg xmlns="http://www.w3.org/2000/svg" width="120" height="60"><polygon points="0,60 60,18 120,60" fill="#c8a96e"/><text x="4" y="12" font-size="10">test pile</text></svg>"##;
    let html = report_html(
        &campaign,
        &results,
        &ReportPictures {
            verification_pile: Some(pile.to_owned()),
            drilled_hole: None,
        },
    );
    std::fs::write(
        std::env::temp_dir().join("repose-campaign-replay.html"),
        &html,
    )
    .unwrap();
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    assert!(!html.contains("<script"), "no scripts");
    assert!(!html.contains("src=\"http"), "no external assets");
    for needle in [
        "Lack of Fit",
        "Pure Error",
        "Pareto chart of standardized effects",
        "Steepest path: response per step",
        "Normal probability plot",
        "Residuals vs predicted",
        "Predicted vs actual",
        "Provenance of every run",
        "data:image/svg+xml;base64,",
        "within tolerance",
    ] {
        assert!(html.contains(needle), "report lacks {needle:?}");
    }
    // The chosen optimum appears in the report.
    let opt = campaign.surfaces[0].optimum.as_ref().unwrap();
    assert!(html.contains("<b>chosen</b>"));
    for v in &opt.natural {
        assert!(html.contains(&fmt4(*v)), "optimum value {v} missing");
    }
    // Every inline SVG parses as XML; 3 contour plots (one per pair of N2, N3, N5).
    let mut svgs = 0;
    let mut contours = 0;
    let mut rest = html.as_str();
    while let Some(start) = rest.find("<svg") {
        let end = rest[start..].find("</svg>").unwrap() + start + 6;
        let doc = &rest[start..end];
        roxmltree::Document::parse(doc).unwrap_or_else(|e| panic!("bad SVG: {e}\n{doc:.300}"));
        svgs += 1;
        if doc.contains(" over N") {
            contours += 1;
        }
        rest = &rest[end..];
    }
    assert_eq!(contours, 3);
    assert!(svgs >= 3 + 3 + 2, "{svgs} SVGs");
    // The page as a whole parses as XML once the doctype is dropped (tags closed, attributes
    // quoted): a lenient well-formedness check.
    let body = html
        .trim_start_matches("<!DOCTYPE html>")
        .replace("<meta charset=\"utf-8\">", "");
    roxmltree::Document::parse(&body).expect("well-formed page");

    let json = report_json(&campaign, &results);
    assert_eq!(
        json["stages"]["screening"]["carried"],
        json!(["N2", "N3", "N5"])
    );
    assert!(json["stages"]["screening"]["fit"]["anova"].is_array());
    assert!(json["stages"]["response_surfaces"][0]["fit_full"]["anova"].is_array());
    let provenance = json["provenance"].as_array().unwrap();
    assert_eq!(
        provenance.len(),
        results.iter().map(|r| r.runs.len()).sum::<usize>()
    );
    assert!(provenance
        .iter()
        .all(|p| p["spec_sha256"].as_str().unwrap().len() == 16));
}

/// The report's number format (4 significant digits, trailing zeros trimmed).
fn fmt4(v: f64) -> String {
    let digits = (3 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.digits$}");
    s.trim_end_matches('0').trim_end_matches('.').to_owned()
}

/// The campaign's response-surface fit, recomputed from the runs the way the report does.
fn repose_campaign_fit(campaign: &Campaign, results: &[StageResult]) -> repose_doe::Fit {
    let round = &campaign.surfaces[0];
    let batch = campaign
        .batches
        .iter()
        .find(|b| b.stage == StageKind::ResponseSurface)
        .unwrap()
        .index;
    let runs = &results.iter().find(|r| r.batch == batch).unwrap().runs;
    let names: Vec<&str> = round.factors.iter().map(|f| f.name.as_str()).collect();
    let x: Vec<Vec<f64>> = runs
        .iter()
        .map(|r| r.factors.iter().map(|f| f.coded).collect())
        .collect();
    let y: Vec<f64> = runs
        .iter()
        .map(|r| r.metrics.as_ref().unwrap()["angle_deg"])
        .collect();
    let model = repose_doe::Model::new(&names, repose_doe::ModelKind::Quadratic).unwrap();
    repose_doe::fit(&model, &x, &y).unwrap()
}
