//! The direct shear test on the GPU backend (issue 38): the box's three parts moving meshes
//! (the lower half one that stays put) whose loads the GPU sums, the lid servo-held, the
//! window's stresses summed on the GPU, the sample settled on the GPU (its key ends in `-gpu`).
//! In CI the GPU is lavapipe, so the CI test is small: one sample, settled on the CPU, sheared
//! on both engines. Over a shear of a few millimetres the two runs stay together, so each
//! stage's figures agree closely, which tests the GPU's stages far more tightly than a seed
//! spread would. A GPU-settled sample is another draw of the sample; the ignored test compares
//! those draws with the CPU's.

use repose_experiments::backend::{BackendKind, Engine};
use repose_experiments::catalog::NoBedStore;
use repose_experiments::shear::{
    build_sample, Control, ShearOn, ShearResult, ShearSpec, ShearStage, ShearStatus,
};
use repose_experiments::soil::{run_on_bed, OnBed, SettledBed};
use repose_experiments::Spec;

use crate::gpu_common::gpu;

/// The `fast` preset at two normal stresses (4 and 12 kPa), sheared 3 mm, at twice the time
/// step (0.16 of the Rayleigh time): about 1 000 grains and 12 000 steps over both stages.
fn small() -> ShearSpec {
    let mut spec = ShearSpec::fast();
    for (path, value) in [
        ("normal_stresses_kpa", "[4, 12]"),
        ("shear.displacement", "0.003"),
        ("time_step_rayleigh_fraction", "0.16"),
    ] {
        spec.set(path, value).unwrap();
    }
    spec
}

fn print(engine: BackendKind, seed: u64, r: &ShearResult) {
    eprintln!(
        "{engine:?} seed {seed}: {:?} c {:?} kPa φ {:?}°, {} steps, sample {} ({} grains), wall \
         {:.1} s",
        r.status,
        r.cohesion_kpa,
        r.friction_angle_deg,
        r.steps,
        r.bed.key,
        r.bed.particles,
        r.wall_time_s,
    );
    for s in &r.stages {
        eprintln!(
            "  {} kPa: window peak {:.4} kPa (σ {:.4}), box peak {:.4} kPa (σ {:.4}), lid {:.4} \
             kPa, dilation {:.4} mm, consolidated {} in {:.4} s",
            s.normal_stress_kpa,
            s.window_peak_kpa,
            s.window_normal_stress_kpa,
            s.peak_kpa,
            s.plane_normal_stress_kpa,
            s.mean_lid_stress_kpa,
            s.dilation_mm,
            s.consolidated,
            s.consolidation_time_s
        );
    }
}

/// The stages of `spec` on `bed` (whichever engine settled it), on `engine`.
fn stages_on(engine: Engine<'_>, spec: &ShearSpec, bed: &SettledBed) -> ShearResult {
    let on = ShearOn { spec, engine };
    let r = on
        .run_on_matching_bed(bed.clone(), &mut |_| Control::Continue)
        .unwrap()
        .result;
    print(engine.kind(), spec.seed, &r);
    r
}

/// One sample (the small test's, seed 1, settled on the CPU engine) sheared on both engines:
/// every stage consolidates on the GPU, and its window and box peaks, normal stresses, lid
/// stress and dilation are the CPU's within 2 % (the dilation within 2 % or 5 µm), its
/// consolidation time within two servo intervals. The result names the adapter; a GPU run's
/// own sample is kept under the key with `-gpu` after it. Measured on lavapipe (2026-11-27):
/// the same figures to 1e-3 or better (on the `fast` preset's three seeds too, e.g. window
/// peaks 4.441 / 10.738 kPa on both). About 40 s on lavapipe.
#[test]
fn one_sample_sheared_on_both_engines_gives_the_same_stages() {
    let Some(gpu) = gpu() else { return };
    let mut spec = small();
    spec.seed = 1;
    let bed = build_sample(&spec, &mut |_| Control::Continue).unwrap();
    let cpu = stages_on(Engine::Cpu, &spec, &bed);
    let on_gpu = stages_on(Engine::Gpu(gpu), &spec, &bed);
    assert_eq!(on_gpu.status, ShearStatus::Ok, "{:?}", on_gpu.message);
    let version = on_gpu.engine_version.as_deref().unwrap();
    assert!(
        version.contains(&format!("+gpu:{}", gpu.name())),
        "{version}"
    );
    assert_eq!(cpu.engine_version.as_deref(), Some(repose_engine::VERSION));
    let gpu_key = ShearOn {
        spec: &spec,
        engine: Engine::Gpu(gpu),
    }
    .bed_key();
    assert_eq!(gpu_key, format!("{}-gpu", ShearOn::cpu(&spec).bed_key()));
    let interval = spec.servo.interval;
    for (c, g) in cpu.stages.iter().zip(&on_gpu.stages) {
        let sigma = c.normal_stress_kpa;
        assert!(g.consolidated, "{sigma} kPa");
        assert!(
            (g.consolidation_time_s - c.consolidation_time_s).abs() <= 2.0 * interval + 1e-9,
            "{sigma} kPa: consolidated in {} s on the GPU, {} s on the CPU",
            g.consolidation_time_s,
            c.consolidation_time_s
        );
        assert_eq!(g.escaped, 0);
        for (name, of) in [
            (
                "window peak",
                (|s: &ShearStage| s.window_peak_kpa) as fn(&ShearStage) -> f64,
            ),
            ("window normal stress", |s| s.window_normal_stress_kpa),
            ("box peak", |s| s.peak_kpa),
            ("plane normal stress", |s| s.plane_normal_stress_kpa),
            ("lid stress", |s| s.mean_lid_stress_kpa),
        ] {
            let (want, got) = (of(c), of(g));
            assert!(
                (got - want).abs() <= 0.02 * want.abs(),
                "{name} at {sigma} kPa: GPU {got}, CPU {want}"
            );
        }
        assert!(
            (g.dilation_mm - c.dilation_mm).abs() <= (0.02 * c.dilation_mm.abs()).max(0.005),
            "dilation at {sigma} kPa: GPU {} mm, CPU {} mm",
            g.dilation_mm,
            c.dilation_mm
        );
    }
}

fn mean_and_std(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// The `fast` preset's strength from samples settled on the GPU (seeds 1-9) against the CPU's
/// runs (seeds 1-12): the cohesion and the friction angle agree within three standard errors of
/// their difference. The GPU's samples are sheared on the CPU engine: the test above shows the
/// two engines shear one sample alike, and the GPU's stages take 2-3 minutes each on lavapipe.
/// About nine minutes on lavapipe:
/// `cargo test -p repose-experiments --test experiments shear_gpu::samples -- --ignored
/// --nocapture`.
///
/// Measured 2026-11-27: GPU-settled samples c 1.51 ± 0.38 kPa, φ 30.60 ± 2.59°; the CPU's
/// c 1.31 ± 0.43 kPa, φ 30.94 ± 3.55° (differences 1.1 and 0.25 standard errors). Seeds 1-3
/// sheared on the GPU as well (`repose shear --preset fast --backend gpu --set seed=N`, 140-190 s
/// a run on lavapipe) read c 2.13, 1.93, 1.62 kPa and φ 31.4, 27.8, 30.2°.
#[test]
#[ignore = "nine samples settled on the GPU and 21 fast shear tests: nine minutes on lavapipe"]
fn samples_settled_on_the_gpu_give_the_cpus_strength_over_nine_seeds() {
    let Some(gpu) = gpu() else { return };
    let fit = |r: &ShearResult| (r.cohesion_kpa.unwrap(), r.friction_angle_deg.unwrap());
    let mut on_gpu = Vec::new();
    for seed in 1..=9 {
        let mut spec = ShearSpec::fast();
        spec.seed = seed;
        let on = ShearOn {
            spec: &spec,
            engine: Engine::Gpu(gpu),
        };
        let bed = on.build_bed(&mut |_| Control::Continue).unwrap();
        assert!(bed.settled);
        on_gpu.push(fit(&stages_on(Engine::Cpu, &spec, &bed)));
    }
    let cpu: Vec<(f64, f64)> = (1..=12)
        .map(|seed| {
            let mut spec = ShearSpec::fast();
            spec.seed = seed;
            let run = run_on_bed(&ShearOn::cpu(&spec), &mut NoBedStore, &mut |_| {
                Control::Continue
            })
            .unwrap();
            print(BackendKind::Cpu, seed, &run.result);
            fit(&run.result)
        })
        .collect();
    for (name, of) in [
        (
            "cohesion (kPa)",
            (|f: &(f64, f64)| f.0) as fn(&(f64, f64)) -> f64,
        ),
        ("friction angle (°)", |f| f.1),
    ] {
        let g: Vec<f64> = on_gpu.iter().map(of).collect();
        let c: Vec<f64> = cpu.iter().map(of).collect();
        let ((gm, gs), (cm, cs)) = (mean_and_std(&g), mean_and_std(&c));
        let se = (gs * gs / g.len() as f64 + cs * cs / c.len() as f64).sqrt();
        eprintln!("{name}: GPU samples {gm:.3} ± {gs:.3}, CPU {cm:.3} ± {cs:.3}, SE {se:.3}");
        assert!(
            (gm - cm).abs() < 3.0 * se,
            "{name}: GPU samples {gm} against the CPU's {cm}, more than 3 SE ({se}) apart"
        );
    }
}
