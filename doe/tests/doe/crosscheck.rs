//! Cross-checks the fit against an independent implementation (statsmodels)
//! on designs that are not in the paper.
//!
//! The fixtures in `tests/fixtures/*.json` were produced by hand with
//! `tests/fixtures/generate.py` (statsmodels 0.15.0); CI only reads them.
//! Every number is compared with a relative tolerance of 1e-8 (plus an
//! absolute 1e-11 floor for values that are zero up to rounding).

use repose_doe::{fit, AnovaSource, Fit, Model, ModelKind};
use serde_json::Value;

const REL: f64 = 1e-8;
const ABS: f64 = 1e-11;

fn load(name: &str) -> Value {
    let path = format!("{}/tests/fixtures/{name}.json", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    serde_json::from_str(&text).unwrap()
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn close(label: &str, ours: f64, theirs: f64) {
    let tol = REL * ours.abs().max(theirs.abs()) + ABS;
    assert!(
        (ours - theirs).abs() <= tol,
        "{label}: ours {ours:e} vs statsmodels {theirs:e} (diff {:e})",
        (ours - theirs).abs()
    );
}

fn close_vec(label: &str, ours: impl Iterator<Item = f64>, theirs: &Value) {
    let theirs = theirs.as_array().unwrap();
    let ours: Vec<f64> = ours.collect();
    assert_eq!(ours.len(), theirs.len(), "{label}: lengths");
    for (i, (o, t)) in ours.iter().zip(theirs).enumerate() {
        close(&format!("{label}[run {}]", i + 1), *o, num(t));
    }
}

fn fit_fixture(fx: &Value) -> Fit {
    let factors: Vec<String> = fx["factors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_owned())
        .collect();
    let kind: ModelKind = fx["model"].as_str().unwrap().parse().unwrap();
    let model = Model::new(&factors, kind).unwrap();
    let runs: Vec<Vec<f64>> = fx["runs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r.as_array().unwrap().iter().map(num).collect())
        .collect();
    let y: Vec<f64> = fx["response"].as_array().unwrap().iter().map(num).collect();
    let f = fit(&model, &runs, &y).unwrap();
    let terms: Vec<&str> = fx["terms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(f.model().term_names(), terms, "term order");
    f
}

fn check(name: &str) {
    let fx = load(name);
    let f = fit_fixture(&fx);

    for (c, t) in f
        .coefficients()
        .iter()
        .zip(fx["coefficients"].as_array().unwrap())
    {
        let l = |what: &str| format!("{name} {} {what}", c.term);
        close(&l("estimate"), c.estimate, num(&t["estimate"]));
        close(&l("std_error"), c.std_error, num(&t["std_error"]));
        close(&l("ci_low"), c.ci_low, num(&t["ci_low"]));
        close(&l("ci_high"), c.ci_high, num(&t["ci_high"]));
        close(&l("t"), c.t_value.unwrap(), num(&t["t_value"]));
        close(&l("p"), c.p_value.unwrap(), num(&t["p_value"]));
        match (c.vif, t["vif"].as_f64()) {
            (None, None) => {}
            (Some(o), Some(s)) => close(&l("vif"), o, s),
            other => panic!("{}: VIF presence differs {other:?}", l("vif")),
        }
    }

    let m = f.anova_row("Model").unwrap();
    let mt = &fx["model_row"];
    close(&format!("{name} Model SS"), m.sum_sq, num(&mt["sum_sq"]));
    assert_eq!(m.df as u64, mt["df"].as_u64().unwrap());
    close(&format!("{name} Model F"), m.f.unwrap(), num(&mt["f"]));
    close(&format!("{name} Model p"), m.p.unwrap(), num(&mt["p"]));

    let terms: Vec<_> = f
        .anova()
        .iter()
        .filter(|r| r.kind == AnovaSource::Term)
        .collect();
    let their_terms = fx["terms_anova"].as_array().unwrap();
    assert_eq!(terms.len(), their_terms.len());
    for (r, t) in terms.iter().zip(their_terms) {
        assert_eq!(r.source, t["source"].as_str().unwrap());
        let l = |what: &str| format!("{name} {} {what}", r.source);
        close(&l("SS"), r.sum_sq, num(&t["sum_sq"]));
        close(&l("F"), r.f.unwrap(), num(&t["f"]));
        close(&l("p"), r.p.unwrap(), num(&t["p"]));
        assert_eq!(r.df, 1);
    }

    let res = f.anova_row("Residual").unwrap();
    close(
        &format!("{name} Residual SS"),
        res.sum_sq,
        num(&fx["residual"]["sum_sq"]),
    );
    close(
        &format!("{name} Residual MS"),
        res.mean_sq.unwrap(),
        num(&fx["residual"]["mean_sq"]),
    );
    assert_eq!(res.df as u64, fx["residual"]["df"].as_u64().unwrap());
    let tot = f.anova_row("Cor Total").unwrap();
    close(
        &format!("{name} Cor Total"),
        tot.sum_sq,
        num(&fx["cor_total"]["sum_sq"]),
    );
    assert_eq!(tot.df as u64, fx["cor_total"]["df"].as_u64().unwrap());

    let lof = &fx["lack_of_fit"];
    if lof.is_null() {
        assert!(f.anova_row("Lack of Fit").is_none());
        assert!(f.anova_row("Pure Error").is_none());
    } else {
        let l = f.anova_row("Lack of Fit").unwrap();
        let pe = f.anova_row("Pure Error").unwrap();
        close(
            &format!("{name} LoF SS"),
            l.sum_sq,
            num(&lof["lack_of_fit_ss"]),
        );
        assert_eq!(l.df as u64, lof["lack_of_fit_df"].as_u64().unwrap());
        close(
            &format!("{name} LoF F"),
            l.f.unwrap(),
            num(&lof["lack_of_fit_f"]),
        );
        close(
            &format!("{name} LoF p"),
            l.p.unwrap(),
            num(&lof["lack_of_fit_p"]),
        );
        close(
            &format!("{name} PE SS"),
            pe.sum_sq,
            num(&lof["pure_error_ss"]),
        );
        assert_eq!(pe.df as u64, lof["pure_error_df"].as_u64().unwrap());
    }

    let s = f.stats();
    let st = &fx["stats"];
    close(&format!("{name} r2"), s.r2, num(&st["r2"]));
    close(&format!("{name} adj_r2"), s.adj_r2, num(&st["adj_r2"]));
    close(
        &format!("{name} press"),
        s.press.unwrap(),
        num(&st["press"]),
    );
    close(
        &format!("{name} pred_r2"),
        s.pred_r2.unwrap(),
        num(&st["pred_r2"]),
    );
    close(&format!("{name} std_dev"), s.std_dev, num(&st["std_dev"]));
    close(&format!("{name} mean"), s.mean, num(&st["mean"]));
    close(
        &format!("{name} cv"),
        s.cv_percent.unwrap(),
        num(&st["cv_percent"]),
    );
    close(
        &format!("{name} adeq"),
        s.adeq_precision.unwrap(),
        num(&st["adeq_precision"]),
    );

    let d = f.diagnostics();
    let dt = &fx["diagnostics"];
    close_vec(
        &format!("{name} predicted"),
        d.iter().map(|r| r.predicted),
        &dt["predicted"],
    );
    close_vec(
        &format!("{name} leverage"),
        d.iter().map(|r| r.leverage),
        &dt["leverage"],
    );
    close_vec(
        &format!("{name} internally studentized"),
        d.iter().map(|r| r.internally_studentized.unwrap()),
        &dt["internally_studentized"],
    );
    close_vec(
        &format!("{name} externally studentized"),
        d.iter().map(|r| r.externally_studentized.unwrap()),
        &dt["externally_studentized"],
    );
    close_vec(
        &format!("{name} Cook's distance"),
        d.iter().map(|r| r.cooks_distance.unwrap()),
        &dt["cooks_distance"],
    );
}

#[test]
fn factorial_2x3_with_centre_points_2fi() {
    check("factorial_2x3_centre_2fi");
}

#[test]
fn rotatable_ccd_two_factors_quadratic() {
    check("ccd_rotatable_2f_quadratic");
}

#[test]
fn irregular_unbalanced_linear() {
    check("irregular_3f_linear");
}
