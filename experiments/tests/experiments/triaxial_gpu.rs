//! The triaxial test on the GPU backend: six moving walls whose loads the GPU sums, servo-held
//! from the host. In CI the GPU is lavapipe, so the test is small: one `ci` specimen prepared
//! on the CPU, loaded to 5 % axial strain on both engines. Over so short a loading the two
//! runs stay together, so each stage's figures agree closely: a far tighter test of the GPU's
//! stages than a seed spread would be.

use repose_experiments::backend::Engine;
use repose_experiments::soil::OnBed;
use repose_experiments::triaxial::{Control, TriaxialOn, TriaxialResult, TriaxialSpec};
use repose_experiments::Spec;

use crate::gpu_common::gpu;
use crate::triaxial_run::print;

/// The `ci` specimen (seed 1, prepared on the CPU) loaded to 5 % on both engines: every stage
/// consolidates on the GPU in about the CPU's time, and its deviator at failure, lateral
/// stress, volumetric strain and void ratio are the CPU's within 1 % (the volumetric strain
/// within 1 % or 1e-3). The result names the adapter. About 20 s on lavapipe; measured there
/// (2026-11-28): the same figures to 1e-3 (q 5.747 / 5.750 and 12.350 / 12.346 kPa).
#[test]
fn a_ci_specimen_loaded_on_the_gpu_reads_as_on_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let mut spec = TriaxialSpec::ci();
    spec.set("loading.axial_strain", "0.05").unwrap();
    let bed = TriaxialOn::cpu(&spec)
        .build_bed(&mut |_| Control::Continue)
        .unwrap();
    let stages = |engine: Engine<'_>| -> TriaxialResult {
        let r = TriaxialOn {
            spec: &spec,
            engine,
        }
        .run_on_matching_bed(bed.clone(), &mut |_| Control::Continue)
        .unwrap()
        .result;
        print(&format!("{:?}", engine.kind()), &r);
        r
    };
    let cpu = stages(Engine::Cpu);
    let on_gpu = stages(Engine::Gpu(gpu));
    assert!(on_gpu
        .engine_version
        .as_deref()
        .is_some_and(|v| v.contains("+gpu:")));
    let close = |what: &str, g: f64, c: f64, tol: f64, floor: f64| {
        assert!(
            (g - c).abs() <= (tol * c.abs()).max(floor),
            "{what}: GPU {g} against the CPU's {c}"
        );
    };
    for (g, c) in on_gpu.stages.iter().zip(&cpu.stages) {
        assert!(g.consolidated);
        close("void ratio", g.void_ratio, c.void_ratio, 0.01, 0.0);
        close(
            "q at failure",
            g.peak_deviator_kpa,
            c.peak_deviator_kpa,
            0.01,
            0.0,
        );
        close(
            "σ3",
            g.failure_confining_kpa,
            c.failure_confining_kpa,
            0.01,
            0.0,
        );
        close(
            "εv",
            g.volumetric_strain_at_peak,
            c.volumetric_strain_at_peak,
            0.01,
            1e-3,
        );
        close(
            "consolidation time",
            g.consolidation_time_s,
            c.consolidation_time_s,
            0.0,
            2.0 * spec.servo.interval,
        );
    }
}
