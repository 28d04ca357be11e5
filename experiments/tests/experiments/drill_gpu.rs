//! The drilling test on the GPU backend (issue 38): the bed settled on the GPU (its key ends in
//! `-gpu`), the auger a moving mesh whose loads the GPU sums. In CI the GPU is lavapipe, so the
//! bed here is small. A GPU run is another draw of the experiment (f32, another summation
//! order, its own bed), so it is compared with the CPU's seed spread.

use repose_experiments::backend::Engine;
use repose_experiments::catalog::NoBedStore;
use repose_experiments::drill::{Control, DrillOn, DrillResult, DrillSpec, DrillStatus};
use repose_experiments::soil::{run_on_bed, OnBed};
use repose_experiments::Spec;

use crate::common::assert_each_names_its_engine;
use crate::gpu_common::gpu;

/// The `fast` drill in a 70 mm bin on a 45 mm bed (about 1 000 grains) of a softer soil (E
/// 1 MPa: a step twice as long), fed 25 mm at twice the preset's speeds: about 4 500 drilling
/// steps.
fn small() -> DrillSpec {
    let mut spec = DrillSpec::fast();
    for (path, value) in [
        ("bin.size_x", "0.07"),
        ("bin.size_y", "0.07"),
        ("bed.depth", "0.045"),
        ("drill.depth", "0.025"),
        ("drill.feed_speed", "0.12"),
        ("drill.withdraw_speed", "0.24"),
        ("materials.soil.youngs_modulus", "1e6"),
    ] {
        spec.set(path, value).unwrap();
    }
    spec
}

/// The small drill's seed-to-seed standard deviations on the CPU, rounded up: seeds 1-12 read
/// an opening of 36.29 ± 2.72 mm, a mean feed torque of 0.0113 ± 0.0011 N·m and an energy of
/// 0.440 ± 0.038 J (measured 2026-11-27).
const OPENING_STD_MM: f64 = 2.8;
const TORQUE_STD_NM: f64 = 0.0012;
const ENERGY_STD_J: f64 = 0.04;

fn drill(engine: Engine<'_>, spec: &DrillSpec, seed: u64) -> DrillResult {
    let mut spec = spec.clone();
    spec.seed = seed;
    let on = DrillOn {
        spec: &spec,
        engine,
    };
    let run = run_on_bed(&on, &mut NoBedStore, &mut |_| Control::Continue).unwrap();
    let r = run.result;
    eprintln!(
        "{:?} seed {seed}: {:?} opening {:?} mm depth {:?} mm feed torque {:.5} N m energy \
         {:.4} J, {} steps, bed {} ({} grains), wall {:.1} s ({:?})",
        engine.kind(),
        r.status,
        r.opening_diameter_mm,
        r.effective_depth_mm,
        r.mean_feed_torque_nm,
        r.energy_j,
        r.steps,
        r.bed.key,
        r.bed.particles,
        r.wall_time_s,
        r.engine_version
    );
    assert_eq!(r.status, DrillStatus::Ok, "{:?}", r.message);
    assert!(r.bed.settled);
    r
}

/// The small drill on the GPU (seed 1) against the CPU's seeds 1-3: each figure within 3.5 σ
/// of the CPU's mean of three. The bed was settled on the GPU and says so; the result names
/// the adapter. A minute on lavapipe.
#[test]
fn a_small_drill_on_the_gpu_opens_a_hole_inside_the_cpu_seed_spread() {
    let Some(gpu) = gpu() else { return };
    let spec = small();
    let cpu: Vec<DrillResult> = (1..=3)
        .map(|seed| drill(Engine::Cpu, &spec, seed))
        .collect();
    let on_gpu = drill(Engine::Gpu(gpu), &spec, 1);
    assert_each_names_its_engine(
        gpu,
        (&on_gpu.bed.key, on_gpu.engine_version.as_deref()),
        (&cpu[0].bed.key, cpu[0].engine_version.as_deref()),
    );
    let mean = |f: &dyn Fn(&DrillResult) -> f64| cpu.iter().map(f).sum::<f64>() / 3.0;
    for (name, std, of) in [
        (
            "opening (mm)",
            OPENING_STD_MM,
            &(|r: &DrillResult| r.opening_diameter_mm.unwrap()) as &dyn Fn(&DrillResult) -> f64,
        ),
        (
            "mean feed torque (N m)",
            TORQUE_STD_NM,
            &|r: &DrillResult| r.mean_feed_torque_nm,
        ),
        ("energy (J)", ENERGY_STD_J, &|r: &DrillResult| r.energy_j),
    ] {
        let (cpu_mean, value) = (mean(of), of(&on_gpu));
        assert!(
            (value - cpu_mean).abs() < 3.5 * std,
            "{name}: GPU {value} is more than 3.5 σ ({std}) from the CPU's mean {cpu_mean}"
        );
    }
}

/// The `fast` drill (about 2 400 grains, 40 mm deep), seeds 1-3 on each backend: the mean feed
/// torque and the energy agree within 3 σ √(2/3) of the CPU's seed spread (σ 0.0011 N·m and
/// 0.09 J over seeds 1-6). Eight minutes on lavapipe:
/// `cargo test -p repose-experiments --test experiments drill_gpu::the_fast -- --ignored
/// --nocapture`.
///
/// Measured 2026-11-27 (`repose drill --preset fast [--backend gpu] --set seed=N`, lavapipe,
/// 225545c): CPU openings 62.70, 61.78, 63.34 mm, feed torques 0.0175, 0.0159, 0.0171 N·m,
/// energies 1.893, 1.743, 1.816 J; GPU 64.44, 62.15, 61.74 mm, 0.0165, 0.0153, 0.0165 N·m,
/// 1.742, 1.692, 1.864 J (about 100 s a run).
#[test]
#[ignore = "six fast drills, three of them on the GPU: eight minutes on lavapipe"]
fn the_fast_drill_agrees_on_both_backends_over_three_seeds() {
    let Some(gpu) = gpu() else { return };
    let spec = DrillSpec::fast();
    let runs = |engine: Engine<'_>| -> Vec<DrillResult> {
        (1..=3).map(|seed| drill(engine, &spec, seed)).collect()
    };
    let (cpu, on_gpu) = (runs(Engine::Cpu), runs(Engine::Gpu(gpu)));
    let mean = |rs: &[DrillResult], f: fn(&DrillResult) -> f64| {
        rs.iter().map(f).sum::<f64>() / rs.len() as f64
    };
    let tolerance = 3.0 * (2.0f64 / 3.0).sqrt();
    for (name, std, of) in [
        (
            "mean feed torque (N m)",
            0.0011,
            (|r: &DrillResult| r.mean_feed_torque_nm) as fn(&DrillResult) -> f64,
        ),
        ("energy (J)", 0.09, |r: &DrillResult| r.energy_j),
        ("opening (mm)", 1.7, |r: &DrillResult| {
            r.opening_diameter_mm.unwrap()
        }),
    ] {
        let (c, g) = (mean(&cpu, of), mean(&on_gpu, of));
        println!("fast drill, seeds 1-3, {name}: CPU {c:.5}, GPU {g:.5}");
        assert!(
            (c - g).abs() < tolerance * std,
            "{name}: means {c} (CPU) and {g} (GPU) differ by {} σ or more",
            tolerance
        );
    }
}

/// One CPU-settled bed drilled on both engines, the small drill at seeds 1-12: the bed handed to
/// [`OnBed::run_on_matching_bed`] with each engine, so the drilling alone differs. The runs part
/// (the auger churns the bed), so only means compare: each figure's mean paired difference
/// (GPU − CPU) lies within three standard errors of zero. 3 min 20 s on lavapipe:
/// `cargo test -p repose-experiments --test experiments drill_gpu::one_bed -- --ignored
/// --nocapture`.
///
/// Measured 2026-11-27 (225545c; the CPU's means 11.57 mm deep, backfill 0.708, feed torque
/// 0.0113 N·m, energy 0.440 J): depth +0.59 ± 0.76 mm, backfill −0.005 ± 0.007, torque
/// −0.0005 ± 0.0002 N·m (2.5 standard errors), energy −0.016 ± 0.007 J (2.3): the GPU's drilling
/// energy and torque run about 4 % low; the cause is not known (docs/gpu.md).
#[test]
#[ignore = "twelve beds drilled on both engines: three and a half minutes on lavapipe"]
fn one_bed_drilled_on_both_engines_over_twelve_seeds() {
    let Some(gpu) = gpu() else { return };
    let figures = |r: &DrillResult| {
        [
            r.effective_depth_mm.unwrap(),
            r.backfill_ratio.unwrap(),
            r.mean_feed_torque_nm,
            r.energy_j,
        ]
    };
    let mut differences = Vec::new();
    for seed in 1..=12 {
        let mut spec = small();
        spec.seed = seed;
        let bed = DrillOn::cpu(&spec)
            .build_bed(&mut |_| Control::Continue)
            .unwrap();
        let on = |engine| {
            let on = DrillOn {
                spec: &spec,
                engine,
            };
            let r = on
                .run_on_matching_bed(bed.clone(), &mut |_| Control::Continue)
                .unwrap()
                .result;
            assert_eq!(r.status, DrillStatus::Ok, "{:?}", r.message);
            figures(&r)
        };
        let (cpu, on_gpu) = (on(Engine::Cpu), on(Engine::Gpu(gpu)));
        eprintln!("seed {seed}: CPU {cpu:?}, GPU {on_gpu:?}");
        differences.push(std::array::from_fn::<f64, 4, _>(|k| on_gpu[k] - cpu[k]));
    }
    let n = differences.len() as f64;
    for (k, name) in ["depth (mm)", "backfill", "feed torque (N m)", "energy (J)"]
        .iter()
        .enumerate()
    {
        let mean = differences.iter().map(|d| d[k]).sum::<f64>() / n;
        let var = differences
            .iter()
            .map(|d| (d[k] - mean).powi(2))
            .sum::<f64>()
            / (n - 1.0);
        let se = (var / n).sqrt();
        eprintln!("{name}: GPU − CPU {mean:.5} ± {se:.5}");
        assert!(
            mean.abs() < 3.0 * se,
            "{name}: the GPU's mean difference {mean} is more than 3 standard errors ({se})"
        );
    }
}
