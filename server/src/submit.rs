//! Turning a [`BatchRequest`] into validated runs: design generation, coding, seeds and specs.
//!
//! Everything that can be wrong with a submission is detected here, before anything is
//! written, and reported as a 422 naming the request field to fix.

use repose_api::{
    apply_factor_values, BatchRequest, CcdVariantName, DesignRequest, FactorSpec, ModelName,
};
use repose_doe::design::{
    box_behnken, central_composite, default_box_behnken_centre_points, full_factorial,
    plackett_burman, replicate, smallest_plackett_burman_runs, splitmix64, CcdVariant, Design,
    DesignError, Factor,
};
use repose_doe::{FitError, Model, ModelKind};
use repose_experiments::catalog::{ExperimentError, ExperimentSpec, Kind};
use serde_json::Value;

use crate::error::AppError;
pub use crate::types::{model_label, PlannedBatch, PlannedRun};

/// More runs than this in one batch is almost certainly a mistake (and a large transaction).
pub const MAX_RUNS_PER_BATCH: usize = 10_000;

/// Longest accepted name (batch, factor, response, experiment kind), in bytes.
pub const MAX_NAME_BYTES: usize = 200;

/// Most factors in one batch (a full factorial of more would exceed the run limit anyway).
pub const MAX_FACTORS: usize = 64;

/// The number of design points `request` asks for, computed without building the design, or
/// `None` when the design type decides it from the points given (explicit) or the factor
/// count is unsupported (the design builder reports that). Saturates instead of overflowing.
fn design_point_count(request: &DesignRequest, k: usize) -> Option<(u128, &'static str)> {
    let k32 = u32::try_from(k).unwrap_or(u32::MAX);
    match request {
        DesignRequest::Factorial => Some((2u128.checked_pow(k32).unwrap_or(u128::MAX), "factors")),
        DesignRequest::PlackettBurman { runs } => runs.map(|runs| (runs as u128, "design.runs")),
        DesignRequest::BoxBehnken { centre_points } => {
            let edge: u128 = match k {
                3 => 12,
                4 => 24,
                5 => 40,
                6 => 48,
                7 => 56,
                _ => return None,
            };
            Some((
                edge + centre_points.unwrap_or(0) as u128,
                "design.centre_points",
            ))
        }
        DesignRequest::CentralComposite { centre_points, .. } => {
            let core = 2u128.checked_pow(k32.min(100)).unwrap_or(u128::MAX);
            Some((
                core.saturating_add(2 * k as u128)
                    .saturating_add(*centre_points as u128),
                "design.centre_points",
            ))
        }
        DesignRequest::Explicit { points } => Some((points.len() as u128, "design.points")),
    }
}

/// Refuses a design whose size exceeds [`MAX_RUNS_PER_BATCH`] before anything is allocated.
fn check_design_size(request: &BatchRequest) -> Result<(), AppError> {
    if request.replicates as usize > MAX_RUNS_PER_BATCH {
        return Err(AppError::invalid(
            "replicates",
            format!("at most {MAX_RUNS_PER_BATCH} runs per batch"),
        ));
    }
    let Some((points, field)) = design_point_count(&request.design, request.factors.len()) else {
        return Ok(());
    };
    let total = points.saturating_mul(u128::from(request.replicates));
    if points > MAX_RUNS_PER_BATCH as u128 {
        return Err(AppError::invalid(
            field,
            format!(
                "the design has {points} points, more than the limit of {MAX_RUNS_PER_BATCH} \
                 runs per batch"
            ),
        ));
    }
    if total > MAX_RUNS_PER_BATCH as u128 {
        return Err(AppError::invalid(
            "replicates",
            format!(
                "{points} design points × {} replicates = {total} runs exceeds the limit of \
                 {MAX_RUNS_PER_BATCH}",
                request.replicates
            ),
        ));
    }
    Ok(())
}

/// Refuses text fields longer than [`MAX_NAME_BYTES`], naming the field.
pub fn check_name_length(field: &str, value: &str) -> Result<(), AppError> {
    if value.len() > MAX_NAME_BYTES {
        return Err(AppError::invalid(
            field,
            format!(
                "is {} bytes long; at most {MAX_NAME_BYTES} are allowed",
                value.len()
            ),
        ));
    }
    Ok(())
}

/// The `repose-doe` model family for a wire model name; `None` for no regression.
pub fn model_kind(model: ModelName) -> Option<ModelKind> {
    match model {
        ModelName::Linear => Some(ModelKind::Linear),
        ModelName::TwoFactorInteraction => Some(ModelKind::TwoFactorInteraction),
        ModelName::Quadratic => Some(ModelKind::Quadratic),
        ModelName::None => None,
    }
}

/// Validates `request` and expands it into runs; `fallback_seed` is used when it has no seed.
pub fn plan_batch(request: BatchRequest, fallback_seed: u64) -> Result<PlannedBatch, AppError> {
    if request.name.trim().is_empty() {
        return Err(AppError::invalid("name", "must not be empty"));
    }
    if request.experiment.kind.trim().is_empty() {
        return Err(AppError::invalid("experiment.kind", "must not be empty"));
    }
    if request.response.trim().is_empty() {
        return Err(AppError::invalid("response", "must not be empty"));
    }
    if let Some(target) = request.target {
        if !target.is_finite() {
            return Err(AppError::invalid("target", "must be a finite number"));
        }
    }
    if request.replicates == 0 {
        return Err(AppError::invalid("replicates", "must be at least 1"));
    }
    check_name_length("name", &request.name)?;
    check_name_length("experiment.kind", &request.experiment.kind)?;
    check_name_length("response", &request.response)?;
    if request.factors.len() > MAX_FACTORS {
        return Err(AppError::invalid(
            "factors",
            format!("at most {MAX_FACTORS} factors per batch"),
        ));
    }
    for (i, factor) in request.factors.iter().enumerate() {
        check_name_length(&format!("factors[{i}].name"), &factor.name)?;
        if let Some(path) = &factor.path {
            check_name_length(&format!("factors[{i}].path"), path)?;
        }
    }
    // Before the design is built: `centre_points: 1e12` must not allocate terabytes.
    check_design_size(&request)?;
    // The kind is parsed once; the template and every run's spec are checked as that kind.
    let kind = Kind::parse(&request.experiment.kind).map_err(experiment_error)?;
    let template = prepare_template(&request, kind)?;
    let factors = validate_factors(&request, &template)?;
    let names: Vec<&str> = factors.iter().map(|f| f.name.as_str()).collect();
    let model = model_kind(request.model)
        .map(|kind| Model::new(&names, kind))
        .transpose()
        .map_err(|err| AppError::invalid("factors", err.to_string()))?;

    let design = build_design(&request.design, &factors, &names)?;
    let design_points = design.run_count();
    let total_runs = design_points.saturating_mul(request.replicates as usize);
    if total_runs > MAX_RUNS_PER_BATCH {
        return Err(AppError::invalid(
            "replicates",
            format!(
                "{design_points} design points × {} replicates = {total_runs} runs exceeds the \
                 limit of {MAX_RUNS_PER_BATCH}",
                request.replicates
            ),
        ));
    }
    if let Some(model) = &model {
        check_model_is_estimable(model, &design, request.replicates as usize, request.model)?;
    }

    let base_seed = request.seed.unwrap_or(fallback_seed);
    let randomized = design.randomized(base_seed);
    let replicated = replicate(&randomized, request.replicates as usize, base_seed)
        .map_err(|err| design_error(err, &request.design))?;
    let runs = replicated
        .into_iter()
        .map(|run| -> Result<PlannedRun, AppError> {
            let natural = factors
                .iter()
                .zip(&run.coded)
                .map(|(factor, &coded)| factor.to_natural(coded))
                .collect::<Result<Vec<f64>, DesignError>>()
                .map_err(|err| design_error(err, &request.design))?;
            // A range near f64::MAX overflows to infinity at the corners or star points; such
            // a spec would be stored with nulls and could never be read back.
            if let Some(i) = natural.iter().position(|value| !value.is_finite()) {
                return Err(AppError::invalid(
                    format!("factors[{i}]"),
                    format!(
                        "the design's coded value {} of factor `{}` is {} in natural units; \
                         the range is too wide to represent",
                        run.coded[i], request.factors[i].name, natural[i]
                    ),
                ));
            }
            let spec = apply_factor_values(
                &template,
                FactorSpec::assignments(&request.factors, &natural),
            )
            .map_err(|err| AppError::invalid("factors", err.to_string()))?;
            check_run_spec(&request, kind, &spec, &natural)?;
            Ok(PlannedRun {
                run_index: run.run_index,
                design_row: randomized.standard_order()[run.design_row],
                replicate: run.replicate,
                coded: run.coded,
                natural,
                seed: run.seed,
            })
        })
        .collect::<Result<Vec<_>, AppError>>()?;

    Ok(PlannedBatch {
        factors,
        design_kind: design.kind(),
        base_seed,
        runs,
        template,
        request,
    })
}

/// The complete experiment spec of `kind` (preset + overrides), checked by the experiment
/// catalog, also for the engine it names (`experiment.backend`), as the JSON the runs are
/// written into.
fn prepare_template(request: &BatchRequest, kind: Kind) -> Result<Value, AppError> {
    let experiment = &request.experiment;
    let spec = kind
        .prepare(experiment.preset.as_deref(), &experiment.spec)
        .map_err(experiment_error)?;
    spec.check_backend(experiment.backend())
        .map_err(experiment_error)?;
    Ok(spec.to_value())
}

/// A catalog error at submission, blaming the request field to fix.
fn experiment_error(err: ExperimentError) -> AppError {
    match err {
        ExperimentError::UnknownKind { .. } => {
            AppError::invalid("experiment.kind", err.to_string())
        }
        ExperimentError::UnknownPreset { .. } => {
            AppError::invalid("experiment.preset", err.to_string())
        }
        ExperimentError::Unsupported { .. } => {
            AppError::invalid("experiment.backend", err.to_string())
        }
        ExperimentError::InvalidSpec {
            path: Some(ref path),
            ..
        } => AppError::invalid(format!("experiment.spec.{path}"), err.to_string()),
        _ => AppError::invalid("experiment.spec", err.to_string()),
    }
}

/// A run's spec must still be valid with its factor values written in (a friction range may
/// reach below zero); the error blames the factor whose path the experiment rejected.
fn check_run_spec(
    request: &BatchRequest,
    kind: Kind,
    spec: &Value,
    natural: &[f64],
) -> Result<(), AppError> {
    let Err(err) = ExperimentSpec::parse(kind, spec)
        .and_then(|parsed| parsed.check_backend(request.experiment.backend()))
    else {
        return Ok(());
    };
    let blamed = match &err {
        ExperimentError::InvalidSpec {
            path: Some(path), ..
        } => request
            .factors
            .iter()
            .position(|f| f.path.as_ref() == Some(path)),
        _ => None,
    };
    Err(match blamed {
        Some(i) => AppError::invalid(
            format!("factors[{i}]"),
            format!(
                "the design sets `{}` to {}, which the experiment rejects: {err}",
                request.factors[i].name, natural[i]
            ),
        ),
        None if matches!(err, ExperimentError::Unsupported { .. }) => AppError::invalid(
            "experiment.backend",
            format!("a run's spec, with the design's factor values: {err}"),
        ),
        None => AppError::invalid(
            "experiment.spec",
            format!("a run's spec is invalid with the design's factor values: {err}"),
        ),
    })
}

fn validate_factors(request: &BatchRequest, template: &Value) -> Result<Vec<Factor>, AppError> {
    if request.factors.is_empty() {
        return Err(AppError::invalid(
            "factors",
            "at least one factor is required",
        ));
    }
    let mut factors = Vec::with_capacity(request.factors.len());
    for (i, spec) in request.factors.iter().enumerate() {
        if spec.name.trim().is_empty() {
            return Err(AppError::invalid(
                format!("factors[{i}].name"),
                "must not be empty",
            ));
        }
        if request.factors[..i].iter().any(|f| f.name == spec.name) {
            return Err(AppError::invalid(
                format!("factors[{i}].name"),
                format!("factor name `{}` is used twice", spec.name),
            ));
        }
        if let Some(path) = &spec.path {
            if request.factors[..i]
                .iter()
                .any(|f| f.path.as_ref() == Some(path))
            {
                return Err(AppError::invalid(
                    format!("factors[{i}].path"),
                    format!("path `{path}` is already varied by another factor"),
                ));
            }
        }
        for (field, value) in [("low", spec.low), ("high", spec.high)] {
            if !value.is_finite() {
                return Err(AppError::invalid(
                    format!("factors[{i}].{field}"),
                    "must be a finite number",
                ));
            }
        }
        if spec.low >= spec.high {
            return Err(AppError::invalid(
                format!("factors[{i}].low"),
                format!(
                    "low ({}) must be less than high ({}) for factor `{}`",
                    spec.low, spec.high, spec.name
                ),
            ));
        }
        if let Some(path) = &spec.path {
            apply_factor_values(template, [(path.as_str(), spec.low)])
                .map_err(|err| AppError::invalid(format!("factors[{i}].path"), err.to_string()))?;
        }
        let factor = Factor::new(spec.name.clone(), spec.low, spec.high)
            .map_err(|err| AppError::invalid(format!("factors[{i}]"), err.to_string()))?;
        factors.push(factor);
    }
    Ok(factors)
}

fn build_design(
    request: &DesignRequest,
    factors: &[Factor],
    names: &[&str],
) -> Result<Design, AppError> {
    let design = match request {
        DesignRequest::Factorial => full_factorial(names),
        DesignRequest::PlackettBurman { runs } => match runs {
            Some(runs) => plackett_burman(names, *runs),
            None => smallest_plackett_burman_runs(names.len())
                .and_then(|runs| plackett_burman(names, runs)),
        },
        DesignRequest::BoxBehnken { centre_points } => match centre_points {
            Some(centre_points) => box_behnken(names, *centre_points),
            None => default_box_behnken_centre_points(names.len())
                .and_then(|centre_points| box_behnken(names, centre_points)),
        },
        DesignRequest::CentralComposite {
            variant,
            centre_points,
        } => central_composite(names, ccd_variant(*variant), *centre_points),
        DesignRequest::Explicit { points } => Design::custom_natural(factors, points),
    };
    design.map_err(|err| design_error(err, request))
}

fn ccd_variant(variant: CcdVariantName) -> CcdVariant {
    match variant {
        CcdVariantName::Circumscribed => CcdVariant::Circumscribed,
        CcdVariantName::FaceCentred => CcdVariant::FaceCentred,
        CcdVariantName::Inscribed => CcdVariant::Inscribed,
    }
}

/// Blames the request field a `repose-doe` design error is about.
fn design_error(err: DesignError, request: &DesignRequest) -> AppError {
    let parameter = match &err {
        DesignError::InvalidParameter { parameter, .. }
        | DesignError::NonFinite { parameter, .. }
        | DesignError::LengthMismatch { parameter, .. } => parameter.as_str(),
        DesignError::InvalidFactorRange { .. } => "factors",
    };
    let field = if parameter == "factor_names" || parameter == "factors" {
        "factors".to_owned()
    } else if let Some(rest) = parameter.strip_prefix("rows") {
        if matches!(request, DesignRequest::Explicit { .. }) {
            format!("design.points{rest}")
        } else {
            "design".to_owned()
        }
    } else if matches!(parameter, "runs" | "centre_points") {
        format!("design.{parameter}")
    } else {
        "design".to_owned()
    };
    AppError::invalid(field, err.to_string())
}

/// Rejects designs that cannot estimate the requested model, by fitting it to a synthetic
/// response: the fit's own checks (too few runs, aliased terms, constant factors) are the
/// authority, so the server cannot disagree with the analysis it will run at the end.
fn check_model_is_estimable(
    model: &Model,
    design: &Design,
    replicates: usize,
    model_name: ModelName,
) -> Result<(), AppError> {
    let rows: Vec<&[f64]> = (0..replicates)
        .flat_map(|_| design.coded_runs().iter().map(Vec::as_slice))
        .collect();
    let mut state = 0x5eed_u64;
    let synthetic: Vec<f64> = rows
        .iter()
        .map(|_| {
            state = splitmix64(state);
            (state >> 11) as f64 / (1u64 << 53) as f64
        })
        .collect();
    match repose_doe::fit(model, &rows, &synthetic) {
        Ok(_) => Ok(()),
        Err(err @ FitError::ConstantFactor { .. }) => Err(AppError::invalid(
            "design",
            format!("the design cannot be analysed: {err}"),
        )),
        Err(err) => Err(AppError::invalid(
            "model",
            format!(
                "the design cannot estimate the {} model: {err}",
                model_label(model_name)
            ),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn request(design: Value, model: &str) -> BatchRequest {
        serde_json::from_value(json!({
            "name": "t",
            "experiment": {"kind": "aor", "preset": "fast"},
            "factors": [
                {"name": "mu", "path": "soil_soil.static_friction", "low": 0.2, "high": 0.6},
                {"name": "e", "path": "soil_soil.restitution", "low": 0.3, "high": 0.9}
            ],
            "design": design,
            "replicates": 2,
            "response": "angle_deg",
            "model": model,
            "seed": 11
        }))
        .unwrap()
    }

    #[test]
    fn a_factor_without_a_path_is_a_design_column_only() {
        let mut req = request(json!({"type": "factorial"}), "linear");
        req.factors[1].path = None;
        let plan = plan_batch(req.clone(), 0).unwrap();
        assert_eq!(plan.runs.len(), 8);
        let levels: std::collections::BTreeSet<u64> =
            plan.runs.iter().map(|r| r.natural[1].to_bits()).collect();
        assert_eq!(levels.len(), 2, "the column still takes both levels");
        for run in &plan.runs {
            let spec = apply_factor_values(
                &plan.template,
                FactorSpec::assignments(&req.factors, &run.natural),
            )
            .unwrap();
            assert_eq!(spec["soil_soil"]["static_friction"], json!(run.natural[0]));
            assert_eq!(
                spec["soil_soil"]["restitution"],
                plan.template["soil_soil"]["restitution"]
            );
        }
        // Two path-less factors are not "the same path".
        req.factors[0].path = None;
        assert!(plan_batch(req, 0).is_ok());
    }

    #[test]
    fn factorial_with_replicates_has_distinct_seeds_and_applied_specs() {
        let plan = plan_batch(request(json!({"type": "factorial"}), "linear"), 0).unwrap();
        assert_eq!(plan.runs.len(), 8);
        let mut seeds: Vec<u64> = plan.runs.iter().map(|r| r.seed).collect();
        seeds.sort_unstable();
        seeds.dedup();
        assert_eq!(seeds.len(), 8);
        for run in &plan.runs {
            // The stored form: the batch's template plus the run's natural values.
            let paths = ["soil_soil.static_friction", "soil_soil.restitution"];
            let spec =
                apply_factor_values(&plan.template, paths.into_iter().zip(run.natural.clone()))
                    .unwrap();
            let friction = &spec["soil_soil"]["static_friction"];
            assert_eq!(friction.as_f64().unwrap(), run.natural[0]);
            let restitution = &spec["soil_soil"]["restitution"];
            assert_eq!(restitution.as_f64().unwrap(), run.natural[1]);
            assert_eq!(
                spec["total_mass"],
                json!(0.03),
                "the fast preset fills the rest"
            );
        }
    }

    #[test]
    fn quadratic_on_a_two_level_factorial_is_rejected_naming_the_model() {
        let err = plan_batch(request(json!({"type": "factorial"}), "quadratic"), 0).unwrap_err();
        assert!(
            matches!(&err, AppError::Invalid { field: Some(f), .. } if f == "model"),
            "{err:?}"
        );
    }

    #[test]
    fn explicit_points_with_a_short_row_name_the_row() {
        let err = plan_batch(
            request(
                json!({"type": "explicit", "points": [[0.2, 0.3], [0.4]]}),
                "linear",
            ),
            0,
        )
        .unwrap_err();
        assert!(
            matches!(&err, AppError::Invalid { field: Some(f), .. } if f == "design.points[1]"),
            "{err:?}"
        );
    }

    #[test]
    fn unknown_kind_and_a_factor_range_the_experiment_rejects_are_named() {
        let mut bad_kind = request(json!({"type": "factorial"}), "linear");
        bad_kind.experiment.kind = "cook".into();
        let err = plan_batch(bad_kind, 0).unwrap_err();
        assert!(
            matches!(&err, AppError::Invalid { field: Some(f), .. } if f == "experiment.kind"),
            "{err:?}"
        );
        let mut negative = request(json!({"type": "factorial"}), "linear");
        negative.factors[0].low = -0.2;
        let err = plan_batch(negative, 0).unwrap_err();
        assert!(
            matches!(&err, AppError::Invalid { field: Some(f), .. } if f == "factors[0]"),
            "{err:?}"
        );
    }
}
