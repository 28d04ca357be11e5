//! Test aids: a stand-in for the job server that expands a batch like `server/src/submit.rs`
//! does and "runs" it with the `table_lookup` replay kind (or a closure), and the paper's tables
//! as replay rows. Replay/test aids only — no simulation happens here.
#![allow(dead_code)]

use std::collections::BTreeMap;

use repose_api::{
    apply_factor_values, BatchRequest, CcdVariantName, DesignRequest, FactorSpec, FactorValue,
    RunState, RunView,
};
use repose_campaign::StageResult;
use repose_doe::design::{
    box_behnken, central_composite, full_factorial, plackett_burman, replicate,
    smallest_plackett_burman_runs, CcdVariant, Design, Factor,
};
use repose_experiments::aor::Control;
use repose_experiments::catalog::run_experiment;
use serde_json::{json, Value};
use uuid::Uuid;

pub type Row = BTreeMap<String, f64>;

/// Table 2 levels of the paper.
pub const PB_LEVELS: [(&str, f64, f64); 6] = [
    ("N1", 0.15, 0.75),
    ("N2", 0.44, 0.68),
    ("N3", 0.01, 0.40),
    ("N4", 0.2, 0.6),
    ("N5", 0.3, 0.7),
    ("N6", 0.1, 0.4),
];
/// Table 6 levels.
pub const BBD_LEVELS: [(&str, f64, f64); 3] =
    [("N2", 0.44, 0.52), ("N3", 0.01, 0.40), ("N5", 0.30, 0.40)];
/// Values the paper holds the non-significant factors at.
pub const HELD: [(&str, f64); 3] = [("N1", 0.45), ("N4", 0.40), ("N6", 0.50)];

pub fn paper_csv(name: &str) -> Vec<Row> {
    let path = format!("{}/../examples/paper/{name}", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_owned)
        .collect();
    lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(',').map(|c| c.trim().parse::<f64>().unwrap()))
                .collect()
        })
        .collect()
}

fn decode(row: &Row, levels: &[(&str, f64, f64)]) -> Row {
    let mut out = row.clone();
    for (name, low, high) in levels {
        let c = row[*name];
        out.insert(
            (*name).to_owned(),
            0.5 * (low + high) + c * 0.5 * (high - low),
        );
    }
    out.remove("run");
    out.remove("step");
    out.remove("relative_error_pct");
    out
}

fn with_held(mut row: Row) -> Row {
    for (n, v) in HELD {
        row.insert(n.to_owned(), v);
    }
    row
}

/// Table 3 in natural units (all six factors).
pub fn table3_rows() -> Vec<Row> {
    paper_csv("plackett_burman_table3.csv")
        .iter()
        .map(|r| decode(r, &PB_LEVELS))
        .collect()
}

/// Table 5 (natural already) with the held factors.
pub fn table5_rows() -> Vec<Row> {
    paper_csv("steepest_ascent_table5.csv")
        .iter()
        .map(|r| with_held(decode(r, &[])))
        .collect()
}

/// Table 6 in natural units with the held factors.
pub fn table6_rows() -> Vec<Row> {
    paper_csv("box_behnken_table6.csv")
        .iter()
        .map(|r| with_held(decode(r, &BBD_LEVELS)))
        .collect()
}

/// A `table_lookup` template over `rows`, with every factor present in `values`.
pub fn lookup_template(rows: &[Row]) -> repose_api::ExperimentTemplate {
    let values: BTreeMap<String, f64> = PB_LEVELS
        .iter()
        .map(|(n, _, _)| ((*n).to_owned(), 0.0))
        .collect();
    repose_api::ExperimentTemplate {
        kind: "table_lookup".into(),
        backend: None,
        preset: None,
        spec: json!({"values": values, "rows": rows, "tolerance": 1e-6}),
    }
}

/// Expands a batch into (design row, replicate, seed, natural values) as the server does.
/// (design row, replicate, seed, coded values, natural values) of one run.
pub type ExpandedRun = (usize, usize, u64, Vec<f64>, Vec<f64>);

pub fn expand(batch: &BatchRequest) -> Vec<ExpandedRun> {
    let factors: Vec<Factor> = batch
        .factors
        .iter()
        .map(|f| Factor::new(f.name.clone(), f.low, f.high).unwrap())
        .collect();
    let names: Vec<&str> = batch.factors.iter().map(|f| f.name.as_str()).collect();
    let design: Design = match &batch.design {
        DesignRequest::Factorial => full_factorial(&names),
        DesignRequest::PlackettBurman { runs } => plackett_burman(
            &names,
            runs.unwrap_or_else(|| smallest_plackett_burman_runs(names.len()).unwrap()),
        ),
        DesignRequest::BoxBehnken { centre_points } => {
            box_behnken(&names, centre_points.unwrap_or(3))
        }
        DesignRequest::CentralComposite {
            variant,
            centre_points,
        } => central_composite(
            &names,
            match variant {
                CcdVariantName::Circumscribed => CcdVariant::Circumscribed,
                CcdVariantName::FaceCentred => CcdVariant::FaceCentred,
                CcdVariantName::Inscribed => CcdVariant::Inscribed,
            },
            *centre_points,
        ),
        DesignRequest::Explicit { points } => Design::custom_natural(&factors, points),
    }
    .expect("design");
    let natural = design.natural_runs(&factors).unwrap();
    replicate(&design, batch.replicates as usize, batch.seed.unwrap_or(7))
        .unwrap()
        .into_iter()
        .map(|r| {
            (
                r.design_row,
                r.replicate,
                r.seed,
                r.coded.clone(),
                natural[r.design_row].clone(),
            )
        })
        .collect()
}

/// Runs a batch: each run's spec gets its factor values, then `simulate(spec, seed)` gives the
/// metrics (or an error string, which makes the run dead).
pub fn run_batch_with(
    index: usize,
    batch: &BatchRequest,
    mut simulate: impl FnMut(&Value, u64) -> Result<BTreeMap<String, f64>, String>,
) -> StageResult {
    run_batch_at(index, batch, |natural, seed| {
        let spec = apply_factor_values(
            &batch.experiment.spec,
            FactorSpec::assignments(&batch.factors, natural),
        )
        .expect("factor paths exist");
        simulate(&spec, seed)
    })
}

/// Runs a batch: `simulate(factor values, seed)` gives each run's metrics (or an error string,
/// which makes the run dead).
pub fn run_batch_at(
    index: usize,
    batch: &BatchRequest,
    mut simulate: impl FnMut(&[f64], u64) -> Result<BTreeMap<String, f64>, String>,
) -> StageResult {
    let runs = expand(batch)
        .into_iter()
        .enumerate()
        .map(|(i, (row, rep, seed, coded, natural))| {
            let result = simulate(&natural, seed);
            let ok = result.is_ok();
            RunView {
                id: Uuid::from_u128((index as u128) << 64 | i as u128),
                run_index: i as u32,
                design_row: row as u32,
                replicate: rep as u32,
                factors: batch
                    .factors
                    .iter()
                    .zip(coded.iter().zip(&natural))
                    .map(|(f, (c, n))| FactorValue {
                        name: f.name.clone(),
                        coded: *c,
                        natural: *n,
                    })
                    .collect(),
                seed,
                status: if ok {
                    RunState::Completed
                } else {
                    RunState::Dead
                },
                attempts: 1,
                metrics: result.as_ref().ok().cloned(),
                spec_sha256: None,
                engine_version: None,
                wall_time_s: ok.then_some(0.01 + (i % 7) as f64 * 0.001),
                worker_id: Some(Uuid::from_u128(0xABCD_0000 + (i % 2) as u128)),
                last_error: result.err(),
            }
        })
        .collect();
    StageResult {
        batch: index,
        runs,
        analysis: None,
    }
}

/// Runs a batch with the `table_lookup` replay kind.
pub fn run_lookup(index: usize, batch: &BatchRequest) -> StageResult {
    assert_eq!(batch.experiment.kind, "table_lookup");
    run_batch_with(index, batch, |spec, seed| {
        run_experiment("table_lookup", spec, seed, &mut |_| Control::Continue)
            .map(|o| o.metrics)
            .map_err(|e| e.to_string())
    })
}

/// The paper's Eq. 16 (coded units of Table 6), i.e. the quadratic model of Table 7.
pub fn eq16(natural: &[f64]) -> f64 {
    let c: Vec<f64> = natural
        .iter()
        .zip(&BBD_LEVELS)
        .map(|(v, (_, lo, hi))| (v - 0.5 * (lo + hi)) / (0.5 * (hi - lo)))
        .collect();
    let (a, b, d) = (c[0], c[1], c[2]);
    39.99 + 0.6675 * a + 9.581 * b + 0.6537 * d + 0.7075 * a * b + 0.1275 * a * d + 1.155 * b * d
        - 1.265 * a * a
        - 5.083 * b * b
        + 0.4070 * d * d
}

/// The paper's campaign as a request document: Table 3 itself as the (explicit) screening
/// design, in natural units and the paper's factor order; Table 2 ranges; each stage looks its
/// responses up in its own table. The paper holds N6 at 0.50 (outside Table 2's 0.1..0.4),
/// N1 and N4 at mid-range.
pub fn paper_campaign_json(name: &str) -> Value {
    let table3 = table3_rows();
    let points: Vec<Vec<f64>> = table3
        .iter()
        .map(|r| PB_LEVELS.iter().map(|(n, _, _)| r[*n]).collect())
        .collect();
    let factors: Vec<Value> = PB_LEVELS
        .iter()
        .map(|(n, lo, hi)| {
            let mut f = json!({"name": n, "path": format!("values.{n}"), "low": lo, "high": hi});
            if *n == "N6" {
                f["fixed_at"] = json!(0.50);
            }
            f
        })
        .collect();
    json!({
        "name": name,
        "experiment": lookup_template(&table3),
        "stage_experiments": {
            "screening": lookup_template(&table3),
            "steepest": lookup_template(&table5_rows()),
            "response_surface": lookup_template(&table6_rows()),
            "verification": lookup_template(&table6_rows()),
        },
        "factors": factors,
        "target": 34.85,
        "seed": 2026,
        "screening": {"design": {"type": "explicit", "points": points}},
    })
}
