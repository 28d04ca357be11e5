use std::collections::BTreeMap;

use proptest::prelude::*;
use serde_json::{json, Value};

use super::expr::{Expression, Grammar, FUNCTIONS};
use super::*;
use crate::catalog::{prepare_spec, run_experiment, ExperimentError, ExperimentSpec, Kind};
use crate::progress::Control;

fn inputs(pairs: &[(&str, f64)]) -> BTreeMap<String, f64> {
    pairs.iter().map(|(k, v)| ((*k).to_owned(), *v)).collect()
}

fn value_of(source: &str, at: &[(&str, f64)]) -> f64 {
    let at = inputs(at);
    Expression::compile(source, "responses.y", Grammar::Response, &at)
        .unwrap_or_else(|e| panic!("{source}: {e}"))
        .eval(&at)
        .unwrap()
}

fn holds(source: &str, at: &[(&str, f64)]) -> bool {
    let at = inputs(at);
    let value = Expression::compile(source, "fails_when", Grammar::Condition, &at)
        .unwrap_or_else(|e| panic!("{source}: {e}"))
        .eval(&at)
        .unwrap();
    assert!(value == 0.0 || value == 1.0, "{source} gave {value}");
    value == 1.0
}

/// The issue's example spec.
fn example() -> Value {
    json!({
        "inputs": {"mu_s": 0.5, "mu_r": 0.1},
        "responses": {"angle_deg": "22 + 30*tanh(4*mu_r) + 8*(mu_s - 0.44)"},
        "noise_sd": {"angle_deg": 0.8},
        "fails_when": "mu_r > 0.3 && mu_s > 0.6"
    })
}

fn spec(doc: &Value) -> FormulaSpec {
    FormulaSpec::from_json(doc).unwrap_or_else(|e| panic!("{e}"))
}

/// The path and message of the error `doc` gives.
fn error_of(doc: &Value) -> (String, String) {
    match FormulaSpec::from_json(doc) {
        Err(FormulaError::Invalid { path, reason }) => (path, reason),
        Ok(_) => panic!("accepted: {doc}"),
    }
}

#[test]
fn arithmetic_follows_the_usual_precedence() {
    let x = [("x", 3.0)];
    assert_eq!(value_of("1 + 2*3", &x), 7.0);
    assert_eq!(value_of("(1 + 2)*3", &x), 9.0);
    assert_eq!(value_of("10 - 3 - 2", &x), 5.0);
    assert_eq!(value_of("10 - 3 + 2", &x), 9.0);
    assert_eq!(value_of("8/4/2", &x), 1.0);
    assert_eq!(value_of("8/4*2", &x), 4.0);
    assert_eq!(value_of("2^3", &x), 8.0);
    assert_eq!(
        value_of("-x^2", &x),
        -9.0,
        "the power binds tighter than the sign"
    );
    assert_eq!(value_of("2^3^2", &x), 64.0, "`^` groups from the left");
    assert_eq!(value_of("2^-1", &x), 0.5);
    assert_eq!(value_of("x - -1", &x), 4.0);
    assert_eq!(value_of("1e-3*x", &x), 0.003);
    assert_eq!(value_of(".5 + 5.", &x), 5.5);
    assert_eq!(value_of("2*x^2", &x), 18.0);
    assert_eq!(
        value_of("1/2", &x),
        0.5,
        "numbers are floats, never integers"
    );
    assert_eq!(value_of("x/2", &x), 1.5);
    assert_eq!(value_of("-x + 1", &x), -2.0);
    assert_eq!(value_of("2*-x", &x), -6.0);
    assert_eq!(value_of("1.5e2 + x", &x), 153.0);
    assert_eq!(value_of("  x  ", &x), 3.0);
}

#[test]
fn every_function_is_known_by_its_name() {
    let at = [("a", 0.7), ("b", -2.5)];
    let cases: [(&str, f64); 7] = [
        ("exp(a)", 0.7f64.exp()),
        ("ln(a)", 0.7f64.ln()),
        ("sqrt(a)", 0.7f64.sqrt()),
        ("tanh(a)", 0.7f64.tanh()),
        ("abs(b)", 2.5),
        ("min(a, b)", -2.5),
        ("max(a, b)", 0.7),
    ];
    for (source, want) in cases {
        let got = value_of(source, &at);
        assert!((got - want).abs() < 1e-12, "{source}: {got} != {want}");
    }
    let named: Vec<&str> = cases
        .iter()
        .map(|(s, _)| s.split('(').next().unwrap())
        .collect();
    assert_eq!(named, FUNCTIONS, "every documented function is tested");
    // Nested, and the issue's example response.
    let got = value_of("max(0, min(ln(exp(a)), sqrt(abs(b))))", &at);
    assert!((got - 0.7).abs() < 1e-12, "{got}");
    let angle = value_of(
        "22 + 30*tanh(4*mu_r) + 8*(mu_s - 0.44)",
        &[("mu_s", 0.5), ("mu_r", 0.1)],
    );
    let want = 22.0 + 30.0 * (0.4f64).tanh() + 8.0 * (0.5 - 0.44);
    assert!((angle - want).abs() < 1e-12, "{angle} != {want}");
}

#[test]
fn only_the_documented_names_are_functions_and_there_are_no_constants() {
    let at = inputs(&[("x", 1.0)]);
    let reason = |source: &str, grammar: Grammar| -> String {
        match Expression::compile(source, "responses.y", grammar, &at) {
            Err(FormulaError::Invalid { path, reason }) => {
                assert_eq!(path, "responses.y");
                reason
            }
            Ok(_) => panic!("{source} accepted"),
        }
    };
    for source in ["sin(x)", "math::ln(x)", "floor(x)", "x y"] {
        let r = reason(source, Grammar::Response);
        assert!(r.contains("unknown function"), "{source}: {r}");
    }
    for source in ["e*x", "PI", "pi + x"] {
        let r = reason(source, Grammar::Response);
        assert!(r.contains("unknown variable"), "{source}: {r}");
    }
    // ... so an input may be called `e` (it is not Euler's number).
    assert_eq!(value_of("2*e", &[("e", 4.0)]), 8.0);
    assert_eq!(
        value_of("exponent + maxload", &[("exponent", 1.0), ("maxload", 2.0)]),
        3.0
    );
    // Arity and argument types are checked when parsed, not when run.
    for (source, words) in [
        ("min(x)", "'min' takes a pair of numbers, not a number"),
        ("min(x, x, x)", "not allowed"),
        ("ln(x, x)", "'ln' takes a number, not a pair of numbers"),
        ("(x, x)", "is a pair of numbers; it must be a number"),
        ("x % 2", "'%' is not allowed in a response"),
        ("x = 2", "'=' is not allowed"),
        ("x; x", "';' is not allowed"),
        ("\"x\"", "not allowed"),
        ("true", "not allowed"),
        ("x > 0", "'>' is not allowed in a response"),
        ("()", "empty"),
    ] {
        let r = reason(source, Grammar::Response);
        assert!(r.contains(words), "{source}: {r}");
    }
    for (source, words) in [
        ("x + 1", "is a number; it must be a condition"),
        ("(x > 1) + 1", "'+' takes a number, not a condition"),
        ("x && x > 1", "'&&' takes a condition, not a number"),
    ] {
        let r = reason(source, Grammar::Condition);
        assert!(r.contains(words), "{source}: {r}");
    }
}

#[test]
fn deep_nesting_is_parsed_without_overflowing() {
    let at = [("x", 2.0)];
    let deep = format!("{}x{}", "(".repeat(900), ")".repeat(900));
    assert_eq!(value_of(&deep, &at), 2.0);
    let signs = format!("{}x", "-".repeat(1000));
    assert_eq!(value_of(&signs, &at), 2.0);
}

#[test]
fn conditions_compare_and_combine() {
    let at = |r: f64, s: f64| [("mu_r", r), ("mu_s", s)];
    let c = "mu_r > 0.3 && mu_s > 0.6";
    assert!(holds(c, &at(0.35, 0.7)));
    assert!(!holds(c, &at(0.35, 0.5)));
    assert!(!holds(c, &at(0.2, 0.7)));
    assert!(!holds(c, &at(0.3, 0.7)), "strict");
    let c = "mu_r >= 0.3 || mu_s <= 0.2";
    assert!(holds(c, &at(0.3, 0.5)));
    assert!(holds(c, &at(0.1, 0.2)));
    assert!(!holds(c, &at(0.1, 0.5)));
    assert!(holds("mu_r == 0.5", &at(0.5, 0.0)));
    assert!(holds("!(mu_r > 0.5)", &at(0.5, 0.0)));
    assert!(!holds("mu_r != 0.5", &at(0.5, 0.0)));
    assert!(holds("mu_r < mu_s", &at(0.1, 0.2)));
    // Arithmetic binds tighter than comparisons, comparisons than &&, && than ||.
    assert!(holds("mu_r + 1 > 2*mu_s && mu_s < 1", &at(0.5, 0.7)));
    assert!(holds("mu_r > 1 && mu_s > 1 || mu_s < 1", &at(0.5, 0.5)));
    assert!(!holds("mu_r > 1 && (mu_s > 1 || mu_s < 1)", &at(0.5, 0.5)));
    // Comparisons belong to conditions, not responses.
    let at = inputs(&[("x", 1.0)]);
    assert!(Expression::compile("x > 0", "responses.y", Grammar::Response, &at).is_err());
}

#[test]
fn the_example_spec_runs_and_its_metrics_are_the_responses() {
    let out = run_experiment("formula", &example(), 7, &mut |_| Control::Continue).unwrap();
    assert_eq!(out.metrics.keys().collect::<Vec<_>>(), ["angle_deg"]);
    let noise_free = 22.0 + 30.0 * (0.4f64).tanh() + 8.0 * (0.5 - 0.44);
    assert_eq!(out.details["noise_free"]["angle_deg"], json!(noise_free));
    let noise = out.details["noise"]["angle_deg"].as_f64().unwrap();
    assert_eq!(noise, super::noise(7, "angle_deg", 0.8));
    assert_ne!(noise, 0.0);
    assert_eq!(out.metrics["angle_deg"], noise_free + noise);
    assert_eq!(out.hold_s, 0.0);
    // Without noise_sd, no noise.
    let mut quiet = example();
    quiet.as_object_mut().unwrap().remove("noise_sd");
    let out = run_experiment("formula", &quiet, 7, &mut |_| Control::Continue).unwrap();
    assert_eq!(out.metrics["angle_deg"], noise_free);
    // Cancelled before it starts.
    assert_eq!(
        run_experiment("formula", &quiet, 7, &mut |_| Control::Cancel),
        Err(ExperimentError::Cancelled)
    );
}

#[test]
fn seeded_noise_is_gaussian_with_the_given_sd_and_independent_between_metrics() {
    // Known answer: over n seeds the draws of N(0, 0.8) have mean 0 (standard error
    // 0.8/√n), standard deviation 0.8 (standard error ≈ 0.8/√(2n)), 68.27 % within one sd,
    // and two metrics' draws are uncorrelated (standard error 1/√n). Bounds are 5 standard
    // errors.
    let n = 20_000u64;
    let sd = 0.8;
    let a: Vec<f64> = (0..n).map(|seed| noise(seed, "angle_deg", sd)).collect();
    let b: Vec<f64> = (0..n).map(|seed| noise(seed, "cohesion_kpa", sd)).collect();
    let nf = n as f64;
    let mean = |x: &[f64]| x.iter().sum::<f64>() / nf;
    let (ma, mb) = (mean(&a), mean(&b));
    let sd_of =
        |x: &[f64], m: f64| (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (nf - 1.0)).sqrt();
    let (sa, sb) = (sd_of(&a, ma), sd_of(&b, mb));
    assert!(ma.abs() < 5.0 * sd / nf.sqrt(), "mean {ma}");
    assert!(mb.abs() < 5.0 * sd / nf.sqrt(), "mean {mb}");
    assert!((sa - sd).abs() < 5.0 * sd / (2.0 * nf).sqrt(), "sd {sa}");
    assert!((sb - sd).abs() < 5.0 * sd / (2.0 * nf).sqrt(), "sd {sb}");
    let within = a.iter().filter(|v| v.abs() <= sd).count() as f64 / nf;
    let p = 0.682_689_5;
    assert!(
        (within - p).abs() < 5.0 * (p * (1.0 - p) / nf).sqrt(),
        "{within}"
    );
    let r = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - ma) * (y - mb))
        .sum::<f64>()
        / ((nf - 1.0) * sa * sb);
    assert!(r.abs() < 5.0 / nf.sqrt(), "correlation {r}");
    // Without noise, none.
    assert_eq!(noise(3, "angle_deg", 0.0), 0.0);
}

#[test]
fn a_seed_always_draws_the_same_and_other_seeds_draw_otherwise() {
    let doc = json!({
        "inputs": {"x": 1.0},
        "responses": {"y": "2*x", "z": "x"},
        "noise_sd": {"y": 1.0, "z": 1.0}
    });
    let s = spec(&doc);
    let first = s.evaluate(42).unwrap();
    assert_eq!(first, s.evaluate(42).unwrap(), "deterministic for a seed");
    assert_ne!(first.metrics["y"], s.evaluate(43).unwrap().metrics["y"]);
    assert_ne!(
        first.noise["y"], first.noise["z"],
        "each metric its own draw"
    );
    // A metric's noise does not depend on which other responses the spec has.
    let alone = spec(&json!({"inputs": {"x": 1.0}, "responses": {"y": "2*x"},
                             "noise_sd": {"y": 1.0}}));
    assert_eq!(alone.evaluate(42).unwrap().metrics["y"], first.metrics["y"]);
    assert_eq!(first.noise_free["y"], 2.0);
}

#[test]
fn inside_the_failure_region_a_run_is_dead_under_every_seed() {
    let mut doc = example();
    doc["inputs"]["mu_r"] = json!(0.35);
    doc["inputs"]["mu_s"] = json!(0.7);
    let s = spec(&doc);
    for seed in 0..5 {
        match s.evaluate(seed) {
            Err(FormulaFailure::FailsWhen { condition, inputs }) => {
                assert_eq!(condition, "mu_r > 0.3 && mu_s > 0.6");
                assert_eq!(inputs["mu_r"], 0.35);
            }
            other => panic!("{other:?}"),
        }
    }
    let err = run_experiment("formula", &doc, 1, &mut |_| Control::Continue).unwrap_err();
    assert!(
        err.is_permanent() && !err.another_seed_may_help(),
        "{err:?}"
    );
    let message = err.to_string();
    assert!(
        message.contains("fails_when holds: `mu_r > 0.3 && mu_s > 0.6`")
            && message.contains("mu_r = 0.35"),
        "{message}"
    );
    let ExperimentError::NoResult { details, .. } = err else {
        unreachable!()
    };
    assert_eq!(details["failure"], "fails_when");
    // Outside it, the run measures.
    doc["inputs"]["mu_s"] = json!(0.6);
    assert!(run_experiment("formula", &doc, 1, &mut |_| Control::Continue).is_ok());
}

#[test]
fn a_response_without_a_finite_value_fails_the_run_naming_it() {
    let doc = json!({"inputs": {"x": 0.5}, "responses": {"ok": "x", "bad": "ln(x - 1)"}});
    let err = run_experiment("formula", &doc, 1, &mut |_| Control::Continue).unwrap_err();
    assert!(
        err.is_permanent() && !err.another_seed_may_help(),
        "{err:?}"
    );
    let message = err.to_string();
    assert!(
        message.contains("responses.bad is NaN") && message.contains("ln(x - 1)"),
        "{message}"
    );
    let doc = json!({"inputs": {"x": 0.0}, "responses": {"y": "1/x"}});
    let err = run_experiment("formula", &doc, 1, &mut |_| Control::Continue).unwrap_err();
    assert!(err.to_string().contains("responses.y is inf"), "{err}");
    // A condition with a NaN in it is false (NaN compares false), not a failure.
    let doc = json!({"inputs": {"x": -1.0}, "responses": {"y": "x"},
                     "fails_when": "sqrt(x) > 0"});
    assert!(run_experiment("formula", &doc, 1, &mut |_| Control::Continue).is_ok());
}

#[test]
fn each_bad_field_is_named() {
    let with = |pointer: &str, value: Value| {
        let mut doc = example();
        *doc.pointer_mut(pointer).unwrap() = value;
        doc
    };
    let cases: Vec<(Value, &str, &str)> = vec![
        (
            with("/responses/angle_deg", json!("22 + mu_x")),
            "responses.angle_deg",
            "unknown variable 'mu_x' (inputs: mu_r, mu_s",
        ),
        (
            with("/responses/angle_deg", json!("22 +* (mu_s")),
            "responses.angle_deg",
            "cannot parse",
        ),
        (
            with("/responses/angle_deg", json!("mu_s > 1")),
            "responses.angle_deg",
            "not allowed in a response",
        ),
        (
            with("/responses/angle_deg", json!("  ")),
            "responses.angle_deg",
            "empty",
        ),
        (
            with("/responses/angle_deg", json!("x".repeat(5000))),
            "responses.angle_deg",
            "longer than",
        ),
        (
            with("/responses/angle_deg", json!(3)),
            "responses.angle_deg",
            "invalid type",
        ),
        (
            with("/fails_when", json!("mu_q > 1")),
            "fails_when",
            "unknown variable 'mu_q'",
        ),
        (
            with("/fails_when", json!("mu_r >")),
            "fails_when",
            "'>' needs 2 operands",
        ),
        (
            with("/fails_when", json!("mu_r")),
            "fails_when",
            "it must be a condition",
        ),
        (
            with("/noise_sd", json!({"cohesion": 1.0})),
            "noise_sd.cohesion",
            "not a response",
        ),
        (
            with("/noise_sd/angle_deg", json!(-1.0)),
            "noise_sd.angle_deg",
            "non-negative",
        ),
        (
            with("/inputs/mu_s", Value::Null),
            "inputs.mu_s",
            "invalid type: null",
        ),
        (
            with("/inputs", json!({"exp": 1.0})),
            "inputs.exp",
            "function",
        ),
        (
            with("/inputs", json!({"mu-s": 1.0})),
            "inputs.mu-s",
            "identifier",
        ),
        (with("/responses", json!({})), "responses", "at least one"),
        (
            with("/responses", json!({"2nd": "mu_s"})),
            "responses.2nd",
            "identifier",
        ),
    ];
    for (doc, path, words) in cases {
        let (got_path, reason) = error_of(&doc);
        assert_eq!(got_path, path, "{doc}: {reason}");
        assert!(reason.contains(words), "{path}: {reason}");
    }
    // A field it does not know, and no inputs at all.
    let mut doc = example();
    doc["noise"] = json!(1.0);
    let (_, reason) = error_of(&doc);
    assert!(reason.contains("unknown field `noise`"), "{reason}");
    let (path, reason) = error_of(&json!({"responses": {"y": "1"}}));
    assert!(
        path.is_empty() && reason.contains("missing field `inputs`"),
        "{path}: {reason}"
    );
    // Through the catalog, the path travels with the error (the server's 422 names it).
    match prepare_spec(
        "formula",
        None,
        &with("/responses/angle_deg", json!("mu_x")),
    ) {
        Err(ExperimentError::InvalidSpec { path, message }) => {
            assert_eq!(path.as_deref(), Some("responses.angle_deg"));
            assert!(
                message.starts_with("responses.angle_deg: unknown variable 'mu_x'"),
                "{message}"
            );
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn the_kind_has_no_presets_and_its_spec_round_trips() {
    assert_eq!(Kind::parse("formula").unwrap(), Kind::Formula);
    assert!(Kind::Formula.presets().is_empty());
    assert!(matches!(
        prepare_spec("formula", Some("fast"), &example()),
        Err(ExperimentError::UnknownPreset { .. })
    ));
    let prepared = prepare_spec("formula", None, &example()).unwrap();
    assert_eq!(prepared, example());
    let parsed = ExperimentSpec::parse(Kind::Formula, &prepared).unwrap();
    assert_eq!(parsed.kind(), Kind::Formula);
    assert_eq!(parsed.to_value(), example());
    // Optional fields stay absent.
    let bare = json!({"inputs": {"x": 1.0}, "responses": {"y": "x"}});
    assert_eq!(prepare_spec("formula", None, &bare).unwrap(), bare);
}

/// Token soup close to the grammar, to reach deeper into the parser than random text does.
fn token_soup() -> impl Strategy<Value = String> {
    let tokens = prop::sample::select(vec![
        "x", "y", "(", ")", "+", "-", "*", "/", "^", ",", "exp", "ln", "sqrt", "tanh", "abs",
        "min", "max", "0", "1", "2.5", "1e3", "1e400", ".", " ", ">", ">=", "<", "==", "!=", "&&",
        "||", "!", "e", "=", ";", "%", "\"", "true",
    ]);
    prop::collection::vec(tokens, 0..40).prop_map(|t| t.concat())
}

proptest! {
    #[test]
    fn any_text_as_an_expression_is_an_error_or_a_number_never_a_panic(
        text in prop_oneof![any::<String>(), token_soup()],
        x in -10.0f64..10.0,
    ) {
        let at = inputs(&[("x", x), ("y", 2.0)]);
        for grammar in [Grammar::Response, Grammar::Condition] {
            if let Ok(expression) = Expression::compile(&text, "responses.y", grammar, &at) {
                let value = expression.eval(&at);
                prop_assert!(value.is_ok(), "{text}: {value:?}");
            }
        }
        let doc = json!({"inputs": {"x": x, "y": 2.0}, "responses": {"r": text},
                         "fails_when": text});
        if let Ok(spec) = FormulaSpec::from_json(&doc) {
            let _ = spec.evaluate(1);
        }
    }
}
