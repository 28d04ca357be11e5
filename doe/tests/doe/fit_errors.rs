//! Error reporting, backward elimination and robustness of the fit.
//!
//! The property tests feed malformed input (NaN, mismatched lengths, too few
//! runs, constant columns) and random data, and require an `Err` (never a
//! panic) for the malformed cases.

use proptest::prelude::*;
use repose_doe::{
    fit, fit_with_options, optimize, FitError, FitOptions, Goal, Model, ModelKind, Objective,
    OptimumOptions, Region,
};

/// 2^(3-1) fraction with C = AB, plus `centre` centre points.
fn half_fraction(centre: usize) -> Vec<Vec<f64>> {
    let mut runs: Vec<Vec<f64>> = [[-1.0, -1.0], [1.0, -1.0], [-1.0, 1.0], [1.0, 1.0]]
        .iter()
        .map(|r| vec![r[0], r[1], r[0] * r[1]])
        .collect();
    runs.extend(std::iter::repeat_n(vec![0.0; 3], centre));
    runs
}

fn response(n: usize) -> Vec<f64> {
    (0..n).map(|i| 10.0 + (i as f64 * 1.7).sin()).collect()
}

#[test]
fn aliased_term_is_named() {
    let runs = half_fraction(3);
    let model =
        Model::from_term_names(&["A", "B", "C"], &["Intercept", "A", "B", "C", "A:B"]).unwrap();
    let e = fit(&model, &runs, &response(runs.len())).unwrap_err();
    assert_eq!(
        e.to_string(),
        "term A:B is aliased with C on these runs (rank-deficient model)"
    );
    match e {
        FitError::Aliased { aliases } => {
            assert_eq!(aliases.len(), 1);
            assert_eq!(aliases[0].term, "A:B");
            assert_eq!(aliases[0].combination.len(), 1);
            assert_eq!(aliases[0].combination[0].0, "C");
            assert!((aliases[0].combination[0].1 - 1.0).abs() < 1e-12);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn several_dependent_terms_are_listed() {
    let runs = half_fraction(4);
    let e = fit(
        &Model::two_fi(&["A", "B", "C"]).unwrap(),
        &runs,
        &response(8),
    )
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.starts_with("terms A:B, A:C, B:C are linearly dependent on the others"),
        "{msg}"
    );
    assert!(
        msg.contains("A:B = C") && msg.contains("A:C = B") && msg.contains("B:C = A"),
        "{msg}"
    );
}

#[test]
fn square_aliased_with_intercept_on_two_level_design() {
    // Two-level factorial without centre points: A^2 == 1 == Intercept.
    let runs: Vec<Vec<f64>> = (0..8)
        .map(|i| {
            vec![
                if i & 1 == 0 { -1.0 } else { 1.0 },
                if i & 2 == 0 { -1.0 } else { 1.0 },
                if i & 4 == 0 { -1.0 } else { 1.0 },
            ]
        })
        .collect();
    let m = Model::from_term_names(&["A", "B", "C"], &["Intercept", "A", "B", "A^2"]).unwrap();
    let e = fit(&m, &runs, &response(8)).unwrap_err();
    assert_eq!(
        e.to_string(),
        "term A^2 is aliased with Intercept on these runs (rank-deficient model)"
    );
}

#[test]
fn other_errors_name_the_problem() {
    let m = Model::linear(&["temp", "speed"]).unwrap();
    let runs = vec![
        vec![-1.0, -1.0],
        vec![1.0, -1.0],
        vec![-1.0, 1.0],
        vec![1.0, 1.0],
    ];
    let y = vec![1.0, 2.0, 3.0, 5.0];

    let e = fit(&m, &runs[..3], &y[..2]).unwrap_err();
    assert_eq!(e.to_string(), "3 runs but 2 response values");

    let mut bad = runs.clone();
    bad[2] = vec![1.0];
    let e = fit(&m, &bad, &y).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("run 3 has 1 factor values, expected 2"),
        "{e}"
    );

    let mut bad = runs.clone();
    bad[1][1] = f64::NAN;
    let e = fit(&m, &bad, &y).unwrap_err();
    assert_eq!(e.to_string(), "run 2: speed is not a finite number (NaN)");

    let opts = FitOptions {
        response_name: "angle_deg".into(),
        ..FitOptions::default()
    };
    let mut yb = y.clone();
    yb[3] = f64::INFINITY;
    let e = fit_with_options(&m, &runs, &yb, &opts).unwrap_err();
    assert_eq!(
        e.to_string(),
        "run 4: angle_deg is not a finite number (inf)"
    );

    let e = fit(&m, &runs[..3], &y[..3]).unwrap_err();
    assert!(
        matches!(
            e,
            FitError::TooFewRuns {
                runs: 3,
                terms: 3,
                needed: 4,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("Intercept, temp, speed"), "{e}");

    let e = fit_with_options(&m, &runs, &[2.0; 4], &opts).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("the response angle_deg is constant"),
        "{e}"
    );

    let flat = vec![
        vec![-1.0, 0.5],
        vec![1.0, 0.5],
        vec![-1.0, 0.5],
        vec![1.0, 0.5],
    ];
    let e = fit(&m, &flat, &y).unwrap_err();
    assert_eq!(
        e.to_string(),
        "factor speed never varies (always 0.5) but the model uses it in term(s) speed"
    );

    let e = Model::from_term_names(&["temp", "speed"], &["Intercept", "temp:sped"]).unwrap_err();
    assert!(e.to_string().contains("unknown factor \"sped\""), "{e}");
    let e = Model::linear(&["a", "a"]).unwrap_err();
    assert_eq!(e.to_string(), "factor name \"a\" is used twice");
}

#[test]
fn backward_elimination_keeps_hierarchy() {
    // y depends on A:B only; A and B alone are noise, but must stay while A:B does.
    let mut runs = Vec::new();
    for _ in 0..2 {
        for a in [-1.0, 1.0] {
            for b in [-1.0, 1.0] {
                for c in [-1.0, 1.0] {
                    runs.push(vec![a, b, c]);
                }
            }
        }
    }
    let noise = |i: usize| 0.05 * ((i as f64 * 12.9898).sin() * 43758.5453).fract();
    let y: Vec<f64> = runs
        .iter()
        .enumerate()
        .map(|(i, r)| 5.0 + 3.0 * r[0] * r[1] + noise(i))
        .collect();
    let opts = FitOptions {
        backward_alpha: Some(0.05),
        ..FitOptions::default()
    };
    let f = fit_with_options(&Model::two_fi(&["A", "B", "C"]).unwrap(), &runs, &y, &opts).unwrap();
    let terms = f.model().term_names();
    assert!(terms.contains(&"A:B".to_owned()), "{terms:?}");
    assert!(
        terms.contains(&"A".to_owned()) && terms.contains(&"B".to_owned()),
        "{terms:?}"
    );
    assert!(f.model().is_hierarchical());
    let removed: Vec<&str> = f.elimination().iter().map(|s| s.term.as_str()).collect();
    for t in ["A:C", "B:C", "C"] {
        assert!(removed.contains(&t), "{t} not removed: {removed:?}");
    }
    // C goes only after both interactions containing it.
    let pos = |t: &str| removed.iter().position(|r| *r == t).unwrap();
    assert!(pos("C") > pos("A:C") && pos("C") > pos("B:C"));
    for s in f.elimination() {
        assert!(s.p.unwrap() > 0.05);
    }
}

#[test]
fn backward_elimination_on_the_paper_screening_data() {
    let runs: Vec<Vec<f64>> = vec![
        vec![1., 1., -1., 1., 1., 1.],
        vec![-1., 1., 1., -1., 1., 1.],
        vec![1., 1., 1., 1., -1., -1.],
        vec![-1., -1., -1., 1., 1., 1.],
        vec![-1., 1., 1., -1., 1., -1.],
        vec![-1., 1., -1., 1., -1., -1.],
        vec![1., -1., -1., -1., 1., -1.],
        vec![1., 1., -1., -1., -1., 1.],
        vec![1., -1., 1., -1., -1., 1.],
        vec![-1., -1., 1., 1., -1., 1.],
        vec![1., -1., 1., 1., 1., -1.],
        vec![-1., -1., -1., -1., -1., -1.],
    ];
    let y = [
        36.83, 49.92, 41.00, 29.36, 46.20, 28.74, 24.57, 30.46, 43.27, 39.43, 43.73, 25.22,
    ];
    let factors = ["N1", "N2", "N3", "N4", "N5", "N6"];
    let opts = FitOptions {
        backward_alpha: Some(0.1),
        ..FitOptions::default()
    };
    let f = fit_with_options(&Model::linear(&factors).unwrap(), &runs, &y, &opts).unwrap();
    let removed: Vec<&str> = f.elimination().iter().map(|s| s.term.as_str()).collect();
    assert_eq!(removed, ["N4", "N1"]);
    assert_eq!(
        f.model().term_names(),
        ["Intercept", "N2", "N3", "N5", "N6"]
    );
}

#[test]
fn predict_checks_length() {
    let runs = vec![vec![-1.0], vec![0.0], vec![1.0]];
    let f = fit(&Model::linear(&["A"]).unwrap(), &runs, &[1.0, 2.0, 3.1]).unwrap();
    assert!(f.try_predict(&[0.0, 1.0]).is_err());
    assert!((f.predict(&[0.0]) - 2.0333333333333).abs() < 1e-9);
}

#[test]
fn optimum_options_are_validated() {
    let runs = vec![vec![-1.0], vec![0.0], vec![1.0]];
    let f = fit(&Model::linear(&["A"]).unwrap(), &runs, &[1.0, 2.0, 3.1]).unwrap();
    let bad_goal = Goal::Target {
        target: 5.0,
        lower: 0.0,
        upper: 4.0,
    };
    let e = optimize(&[Objective::new(&f, bad_goal)], &OptimumOptions::default()).unwrap_err();
    assert!(e.to_string().contains("target 5 must lie within"), "{e}");
    // Upper limit above anything reachable: unique optimum on the boundary.
    let good = Goal::Maximize {
        lower: 1.0,
        upper: 10.0,
    };
    let e = optimize(
        &[Objective::new(&f, good.clone()).with_importance(6)],
        &OptimumOptions::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("importance 6"), "{e}");
    let r = optimize(&[Objective::new(&f, good)], &OptimumOptions::default()).unwrap();
    assert!(
        (r.solutions[0].coded[0] - 1.0).abs() < 1e-6,
        "{:?}",
        r.solutions[0]
    );
    assert!(!r.level_set, "{}", r.note);
    assert!((r.best_desirability - (f.predict(&[1.0]) - 1.0) / 9.0).abs() < 1e-9);
}

#[test]
fn sphere_region_is_respected_for_a_rotatable_ccd() {
    let a = 2f64.sqrt();
    let runs = vec![
        vec![-1.0, -1.0],
        vec![1.0, -1.0],
        vec![-1.0, 1.0],
        vec![1.0, 1.0],
        vec![-a, 0.0],
        vec![a, 0.0],
        vec![0.0, -a],
        vec![0.0, a],
        vec![0.0, 0.0],
        vec![0.0, 0.0],
        vec![0.0, 0.0],
    ];
    // Rising plane: the maximum lies on the sphere, in direction (2, 1).
    let y: Vec<f64> = runs
        .iter()
        .enumerate()
        .map(|(i, r)| 10.0 + 2.0 * r[0] + r[1] + 0.01 * (i as f64).sin())
        .collect();
    let f = fit(&Model::linear(&["A", "B"]).unwrap(), &runs, &y).unwrap();
    let options = OptimumOptions {
        region: Region::Sphere { radius: a },
        ..OptimumOptions::default()
    };
    let goal = Goal::Maximize {
        lower: 0.0,
        upper: 100.0,
    };
    let r = optimize(&[Objective::new(&f, goal)], &options).unwrap();
    let x = &r.solutions[0].coded;
    assert!((x[0].hypot(x[1]) - a).abs() < 1e-6, "{x:?}");
    assert!((x[1] / x[0] - 0.5).abs() < 0.02, "{x:?}");
}

#[derive(Debug, Clone)]
enum Corruption {
    NanFactor(usize, usize),
    NanResponse(usize),
    ShortRow(usize),
    ResponseLength(bool),
    TooFewRuns,
    ConstantFactor(usize),
    ConstantResponse,
}

fn corruption() -> impl Strategy<Value = Corruption> {
    prop_oneof![
        (0..64usize, 0..8usize).prop_map(|(i, j)| Corruption::NanFactor(i, j)),
        (0..64usize).prop_map(Corruption::NanResponse),
        (0..64usize).prop_map(Corruption::ShortRow),
        any::<bool>().prop_map(Corruption::ResponseLength),
        Just(Corruption::TooFewRuns),
        (0..8usize).prop_map(Corruption::ConstantFactor),
        Just(Corruption::ConstantResponse),
    ]
}

fn kind() -> impl Strategy<Value = ModelKind> {
    prop_oneof![
        Just(ModelKind::Linear),
        Just(ModelKind::TwoFactorInteraction),
        Just(ModelKind::Quadratic)
    ]
}

fn names(k: usize) -> Vec<String> {
    (0..k).map(|i| format!("X{i}")).collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn malformed_input_is_an_error_not_a_panic(
        k in 1usize..5,
        kind in kind(),
        extra in 1usize..12,
        seed in proptest::collection::vec(-3.0f64..3.0, 400),
        corruption in corruption(),
    ) {
        let model = Model::new(&names(k), kind).unwrap();
        let p = model.len();
        let n = p + extra;
        let mut runs: Vec<Vec<f64>> = (0..n).map(|i| (0..k).map(|j| seed[(i * k + j) % 400]).collect()).collect();
        let mut y: Vec<f64> = (0..n).map(|i| seed[(7 * i + 3) % 400] + i as f64 * 0.01).collect();
        match corruption {
            Corruption::NanFactor(i, j) => runs[i % n][j % k] = f64::NAN,
            Corruption::NanResponse(i) => y[i % n] = f64::NAN,
            Corruption::ShortRow(i) => { runs[i % n].pop(); }
            Corruption::ResponseLength(longer) => if longer { y.push(1.0) } else { y.pop(); },
            Corruption::TooFewRuns => { runs.truncate(p); y.truncate(p); }
            Corruption::ConstantFactor(j) => { let j = j % k; runs.iter_mut().for_each(|r| r[j] = 0.25); }
            Corruption::ConstantResponse => y.iter_mut().for_each(|v| *v = 4.5),
        }
        let r = fit(&model, &runs, &y);
        prop_assert!(r.is_err(), "{corruption:?} gave Ok");
        // Errors display without panicking.
        let _ = r.unwrap_err().to_string();
    }

    #[test]
    fn random_data_never_panics(
        k in 1usize..4,
        kind in kind(),
        n in 0usize..25,
        levels in proptest::collection::vec(prop_oneof![Just(-1.0f64), Just(0.0), Just(1.0), -1e6f64..1e6, Just(1e150)], 100),
        ys in proptest::collection::vec(prop_oneof![-1e3f64..1e3, Just(0.0), Just(1e200)], 25),
        alpha in proptest::option::of(0.01f64..0.5),
    ) {
        let model = Model::new(&names(k), kind).unwrap();
        let runs: Vec<Vec<f64>> = (0..n).map(|i| (0..k).map(|j| levels[(i * k + j) % 100]).collect()).collect();
        let y: Vec<f64> = ys.iter().copied().take(n).collect();
        let opts = FitOptions { backward_alpha: alpha, ..FitOptions::default() };
        if let Ok(f) = fit_with_options(&model, &runs, &y, &opts) {
            let _ = serde_json::to_string(&f).unwrap();
            let _ = f.predict(&vec![0.0; k]);
            let goal = Goal::Target { target: 0.0, lower: -1.0, upper: 1.0 };
            let o = OptimumOptions { starts: 4, max_evals: 200, ..OptimumOptions::default() };
            let _ = optimize(&[Objective::new(&f, goal)], &o).unwrap();
        }
    }

    #[test]
    fn term_parsing_never_panics(s in "\\PC{0,20}") {
        let _ = Model::from_term_names(&["A", "B"], &["Intercept", s.as_str()]);
    }
}
