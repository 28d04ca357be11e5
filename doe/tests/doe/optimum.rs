//! Desirability optimisation on small synthetic surfaces (the paper case is
//! in `paper.rs`).

use repose_doe::design::Factor;
use repose_doe::{fit, optimize, Fit, Goal, Model, Objective, OptimumOptions};

/// 3^2 grid with a centre replicate, response `f(a, b)` plus a tiny fixed wobble.
fn surface(f: impl Fn(f64, f64) -> f64, model: &Model) -> Fit {
    let mut runs = Vec::new();
    for a in [-1.0, 0.0, 1.0] {
        for b in [-1.0, 0.0, 1.0] {
            runs.push(vec![a, b]);
        }
    }
    runs.push(vec![0.0, 0.0]);
    let y: Vec<f64> = runs
        .iter()
        .enumerate()
        .map(|(i, r)| f(r[0], r[1]) + 1e-3 * (i as f64 * 2.3).sin())
        .collect();
    fit(model, &runs, &y).unwrap()
}

#[test]
fn importance_weighted_geometric_mean() {
    let q = Model::quadratic(&["A", "B"]).unwrap();
    let yield_ = surface(|a, b| 60.0 + 8.0 * a + 3.0 * b - 4.0 * a * a, &q);
    let cost = surface(|a, b| 10.0 + 2.0 * a + 2.0 * b + b * b, &q);
    let o1 = Objective::new(
        &yield_,
        Goal::Maximize {
            lower: 50.0,
            upper: 70.0,
        },
    )
    .with_importance(5);
    let mut o2 = Objective::new(
        &cost,
        Goal::Minimize {
            lower: 8.0,
            upper: 16.0,
        },
    )
    .with_importance(1);
    o2.name = "cost".into();
    let ranges = vec![
        Factor::new("A", 100.0, 200.0).unwrap(),
        Factor::new("B", 0.5, 1.5).unwrap(),
    ];
    let options = OptimumOptions {
        factor_ranges: Some(ranges),
        ..OptimumOptions::default()
    };
    let r = optimize(&[o1.clone(), o2.clone()], &options).unwrap();
    let s = &r.solutions[0];
    let (d1, d2) = (s.responses[0].desirability, s.responses[1].desirability);
    assert!((s.desirability - (d1.powi(5) * d2).powf(1.0 / 6.0)).abs() < 1e-12);
    assert_eq!(s.responses[1].name, "cost");
    // Natural units follow the factor ranges.
    let nat = s.natural.as_ref().unwrap();
    assert!((nat[0] - (150.0 + 50.0 * s.coded[0])).abs() < 1e-9);
    // No grid point of the cube does better (the search is a real optimum).
    let d_at = |a: f64, b: f64| {
        let x = [a, b];
        let d1 = o1.desirability(yield_.predict(&x));
        let d2 = o2.desirability(cost.predict(&x));
        (d1.powi(5) * d2).powf(1.0 / 6.0)
    };
    for i in 0..=40 {
        for j in 0..=40 {
            let (a, b) = (-1.0 + i as f64 / 20.0, -1.0 + j as f64 / 20.0);
            assert!(
                d_at(a, b) <= s.desirability + 1e-6,
                "({a}, {b}) beats the optimum"
            );
        }
    }
    assert!(!r.level_set, "{}", r.note);
    // Raising the importance of cost moves the optimum towards lower cost.
    let r2 = optimize(&[o1.with_importance(1), o2.with_importance(5)], &options).unwrap();
    assert!(r2.solutions[0].responses[1].value < s.responses[1].value);
}

#[test]
fn in_range_goal_is_a_constraint_only() {
    let lin = Model::linear(&["A", "B"]).unwrap();
    let y1 = surface(|a, b| 10.0 + a + b, &lin);
    let y2 = surface(|a, _| 5.0 + 2.0 * a, &lin);
    let o1 = Objective::new(
        &y1,
        Goal::Maximize {
            lower: 8.0,
            upper: 12.0,
        },
    );
    let o2 = Objective::new(
        &y2,
        Goal::InRange {
            lower: 3.0,
            upper: 5.0,
        },
    );
    let r = optimize(&[o1, o2], &OptimumOptions::default()).unwrap();
    let s = &r.solutions[0];
    assert!(s.responses[1].value <= 5.0 + 1e-9, "{s:?}");
    // D is the desirability of the first response alone.
    assert!((s.desirability - s.responses[0].desirability).abs() < 1e-12);
    assert!(
        s.coded[0].abs() < 1e-3 && (s.coded[1] - 1.0).abs() < 1e-6,
        "{s:?}"
    );
}

#[test]
fn plateau_of_full_desirability_is_reported_as_level_set() {
    let lin = Model::linear(&["A", "B"]).unwrap();
    let y = surface(|a, b| 10.0 + a + b, &lin);
    let r = optimize(
        &[Objective::new(
            &y,
            Goal::Maximize {
                lower: 8.0,
                upper: 10.5,
            },
        )],
        &OptimumOptions::default(),
    )
    .unwrap();
    assert!(r.level_set, "{}", r.note);
    assert_eq!(r.best_desirability, 1.0);
    // Nearest-to-centre point with ŷ >= 10.5 is on the line a + b = 0.5, at (0.25, 0.25).
    let x = &r.solutions[0].coded;
    assert!(
        (x[0] - 0.25).abs() < 0.01 && (x[1] - 0.25).abs() < 0.01,
        "{x:?}"
    );
}

#[test]
fn unreachable_goal_reports_zero_desirability() {
    let lin = Model::linear(&["A", "B"]).unwrap();
    let y = surface(|a, b| 10.0 + a + b, &lin);
    let r = optimize(
        &[Objective::new(
            &y,
            Goal::Target {
                target: 50.0,
                lower: 40.0,
                upper: 60.0,
            },
        )],
        &OptimumOptions::default(),
    )
    .unwrap();
    assert_eq!(r.best_desirability, 0.0);
    assert!(!r.level_set);
    assert!(r.note.starts_with("no point of the region"), "{}", r.note);
    assert!(r.coded_min.is_empty() && r.natural_min.is_none());
    assert_eq!(r.starts_at_best, 0);
    // The closest approach is the corner (1, 1).
    let x = &r.solutions[0].coded;
    assert!(
        (x[0] - 1.0).abs() < 1e-6 && (x[1] - 1.0).abs() < 1e-6,
        "{x:?}"
    );
}

#[test]
fn options_deserialise_with_defaults() {
    let o: OptimumOptions =
        serde_json::from_str(r#"{"region": {"shape": "sphere", "radius": 1.414}, "seed": 3}"#)
            .unwrap();
    assert_eq!(o.seed, 3);
    assert_eq!(o.starts, OptimumOptions::default().starts);
    let g: Goal = serde_json::from_str(
        r#"{"goal": "target", "target": 34.85, "lower": 24.24, "upper": 46.58}"#,
    )
    .unwrap();
    assert!(matches!(g, Goal::Target { .. }));
}
