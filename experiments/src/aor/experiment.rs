//! The angle-of-repose kind (`aor`) in the catalog: a run continued from and checkpointed to
//! the store, its result turned into metrics (or a failure), its picture.

use std::collections::BTreeMap;

use serde_json::Value;

use super::checkpoint::{checkpoint_key, AorCheckpoint};
use super::run::{run_aor_on, run_aor_with_checkpoints, AorError, AorRun, Checkpoints, RunStatus};
use super::spec::{AorSpec, PRESETS};
use crate::backend::{BackendKind, Engine};
use crate::experiment::{parse_spec, CheckpointStore, Experiment, ExperimentError, Outcome};
use crate::progress::Control;
use crate::soil::BedStore;
use crate::Spec;

/// The angle-of-repose experiment.
#[derive(Debug, Clone, Copy)]
pub struct Aor;

impl Experiment for Aor {
    const NAME: &'static str = "aor";
    type Spec = AorSpec;
    const PRESETS: &'static [&'static str] = &PRESETS;

    fn preset(name: &str) -> Option<AorSpec> {
        <AorSpec as Spec>::preset(name).ok()
    }

    fn parse(spec: &Value) -> Result<AorSpec, ExperimentError> {
        parse_spec(Self::NAME, spec, AorSpec::validate)
    }

    /// Continued from the checkpoint under [`checkpoint_key`] if `checkpoints` has one of this
    /// run, checkpointed to it while running; a run that finishes (in any state but cancelled)
    /// removes its checkpoint. The outcome is the same, bit for bit, whether the run went
    /// through in one go or was continued (`details.resumed_at_step` says which).
    fn run(
        spec: AorSpec,
        seed: u64,
        progress: &mut dyn FnMut(f64) -> Control,
        beds: &mut dyn BedStore,
        checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        Aor::run_on(spec, seed, Engine::Cpu, progress, beds, checkpoints)
    }

    /// Both engines run every angle-of-repose spec (either protocol, every contact law).
    const BACKENDS: &'static [BackendKind] = &[BackendKind::Cpu, BackendKind::Gpu];

    /// On the CPU, [`Experiment::run`] as documented there. On the GPU the run keeps no
    /// checkpoint and continues none (`checkpoints` is not used: a GPU run cannot be continued
    /// from a saved state, and a CPU checkpoint of the same spec is never taken for one); a
    /// GPU failure during the run (a lost device, a capacity overflow) is this machine's
    /// ([`ExperimentError::Local`]), so the job may run again.
    fn run_on(
        mut spec: AorSpec,
        seed: u64,
        engine: Engine<'_>,
        progress: &mut dyn FnMut(f64) -> Control,
        _beds: &mut dyn BedStore,
        checkpoints: &mut dyn CheckpointStore,
    ) -> Result<Outcome, ExperimentError> {
        spec.seed = seed;
        let run = match engine {
            Engine::Cpu => run_on_cpu(&spec, progress, checkpoints),
            Engine::Gpu(_) => run_aor_on(
                engine,
                &spec,
                &mut |p| progress(p.fraction),
                Checkpoints::default(),
            ),
        }
        .map_err(|e| run_error(engine.kind(), e))?;
        let details = serde_json::to_value(&run.result).expect("AorResult serialises");
        // A heap still creeping when the time cap ends the run (constant-torque rolling
        // friction never quite stops) is measured as it stands and flagged
        // `came_to_rest = 0`; only a run with no measurable heap has no result.
        let capped_angle = match run.result.status {
            RunStatus::NotSettled if run.result.insertion_end_s.is_some() => {
                run.result.last_angle_deg
            }
            _ => None,
        };
        match run.result.status {
            RunStatus::Ok => {}
            RunStatus::NotSettled if capped_angle.is_some() => {}
            RunStatus::Cancelled => return Err(ExperimentError::Cancelled),
            status => {
                return Err(ExperimentError::NoResult {
                    message: format!(
                        "angle-of-repose run ended {status:?}: {}",
                        run.result.message.as_deref().unwrap_or("no heap measured")
                    ),
                    details,
                    // Whether grains arch over the outlet is a matter of the pour.
                    another_seed_may_help: status == RunStatus::HeldUp,
                });
            }
        }
        let mut metrics = BTreeMap::new();
        let r = &run.result;
        let scalars = [
            ("angle_deg", r.angle_deg.or(capped_angle)),
            ("came_to_rest", Some(if r.came_to_rest { 1.0 } else { 0.0 })),
            (
                "creep_deg_per_s",
                r.rest.as_ref().and_then(|s| s.creep_deg_per_s),
            ),
            ("left_deg", r.left_deg),
            ("right_deg", r.right_deg),
            ("projection_mean_deg", r.projection_mean_deg),
            ("spread_std_deg", r.spread_std_deg),
            ("pile_height_m", r.pile_height_m),
            ("base_diameter_m", r.base_diameter_m),
            ("simulated_time_s", Some(r.simulated_time_s)),
            ("grains_inserted", Some(r.grains.inserted.count as f64)),
            ("escaped_mass_kg", Some(r.grains.escaped.mass)),
        ];
        for (name, value) in scalars {
            if let Some(v) = value.filter(|v| v.is_finite()) {
                metrics.insert(name.to_owned(), v);
            }
        }
        let pictures = run
            .pile_svg()
            .map(|svg| vec![("pile.svg".to_owned(), svg)])
            .unwrap_or_default();
        Ok(Outcome {
            metrics,
            details,
            pictures,
            hold_s: 0.0,
            engine_version: run
                .result
                .engine_version
                .unwrap_or_else(|| engine.engine_version()),
        })
    }

    /// [`checkpoint_key`] of the spec with the run's seed.
    fn checkpoint_key(spec: &AorSpec, seed: u64) -> Option<String> {
        let mut spec = spec.clone();
        spec.seed = seed;
        Some(checkpoint_key(&spec))
    }
}

/// The CPU run, continued from and checkpointed to `checkpoints` under [`checkpoint_key`].
fn run_on_cpu(
    spec: &AorSpec,
    progress: &mut dyn FnMut(f64) -> Control,
    checkpoints: &mut dyn CheckpointStore,
) -> Result<AorRun, AorError> {
    let key = checkpoint_key(spec);
    let resume = checkpoints.get(&key).and_then(|bytes| {
        let saved = AorCheckpoint::from_bytes(&bytes)
            .and_then(|saved| saved.check_spec(spec).map(|()| saved));
        saved
            .map_err(|e| checkpoints.reject(&key, &e.to_string()))
            .ok()
    });
    let every = checkpoints.every();
    let run = {
        let mut keep = |bytes: &[u8]| checkpoints.put(&key, bytes);
        run_aor_with_checkpoints(
            spec,
            &mut |p| progress(p.fraction),
            Checkpoints {
                resume,
                save: Some(&mut keep),
                every,
            },
        )?
    };
    if run.result.status != RunStatus::Cancelled {
        checkpoints.remove(&key);
    }
    Ok(run)
}

/// A run that could not start or failed on `backend`, as the catalog reports it: what the
/// backend does not simulate is [`ExperimentError::Unsupported`], a GPU failure this
/// machine's ([`ExperimentError::Local`]), anything else the spec's refusal.
fn run_error(backend: BackendKind, e: AorError) -> ExperimentError {
    let message = e.to_string();
    match e {
        AorError::Backend(b) => ExperimentError::on_backend(backend, b, message),
        e => ExperimentError::refused(&e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::BackendError;

    /// A GPU that fails during a run is the machine's failure (the job runs again); what the
    /// GPU does not simulate is the spec's, for good; the CPU's refusals stay the spec's.
    #[test]
    fn a_gpu_failure_mid_run_is_retried_and_an_unsupported_scene_is_not() {
        let lost = run_error(
            BackendKind::Gpu,
            AorError::Backend(BackendError::Gpu("GPU device error: lost".into())),
        );
        assert!(matches!(lost, ExperimentError::Local { .. }), "{lost:?}");
        assert!(!lost.is_permanent());
        assert!(lost.to_string().contains("GPU backend failed"), "{lost}");
        let unsupported = run_error(
            BackendKind::Gpu,
            AorError::Backend(BackendError::Unsupported {
                backend: "GPU",
                what: "cohesion".into(),
            }),
        );
        assert!(
            matches!(
                unsupported,
                ExperimentError::Unsupported {
                    backend: BackendKind::Gpu,
                    ..
                }
            ),
            "{unsupported:?}"
        );
        assert!(unsupported.is_permanent());
        let mut bad = AorSpec::fast();
        bad.total_mass = -1.0;
        let refused = run_error(
            BackendKind::Cpu,
            AorError::from(bad.validate().unwrap_err()),
        );
        assert!(
            matches!(refused, ExperimentError::InvalidSpec { .. }),
            "{refused:?}"
        );
    }
}
