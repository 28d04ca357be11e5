//! The angle-of-repose funnel on the GPU backend (issue 38): the rig, run loop, rest rule and
//! measurement of the CPU run, the factory served from the host into a `GpuWorld`. In CI the
//! GPU is Mesa's lavapipe (a Vulkan driver on the CPU), so the heaps here are small.
//!
//! The two engines do not follow one trajectory (the GPU computes in f32 and sums in another
//! order, and a pour is chaotic): a GPU run is another sample of the same experiment, like a
//! run with another seed. So its angle is compared with the spread of the CPU's angles over
//! seeds, not to the bit.

use repose_experiments::aor::{
    run_aor_on, AorError, AorResult, AorRun, AorSpec, Checkpoints, Control, RunStatus,
};
use repose_experiments::backend::{BackendError, Engine};
use repose_experiments::Spec;

use crate::gpu_common::gpu;

/// A small funnel for CI: about 560 grains of 4 mm poured in 0.2 s through the `fast` funnel
/// (a 40 mm outlet, 10 grains wide, 40 mm above a 15 cm plate), checked every 50 ms; at rest
/// after about 0.7 s, 6 000 steps. Rolling friction 0.3 makes a few hundred grains stand as a
/// heap (at the `fast` preset's 0.14 they spread into a mound two or three grains high); a
/// softer soil (E 1 MPa) doubles the time step. Seconds on lavapipe. (With half the grains,
/// 3 of 24 seeds left a flank too short to measure.)
fn small() -> AorSpec {
    let mut spec = AorSpec::fast();
    for (path, value) in [
        ("particle.radius", "0.002"),
        ("total_mass", "0.05"),
        ("mass_rate", "0.25"),
        ("funnel.outlet_diameter", "0.04"),
        ("base.size", "0.15"),
        ("materials.soil.youngs_modulus", "1e6"),
        ("soil_soil.rolling_friction", "0.3"),
        ("settle.min_time", "0.1"),
        ("settle.check_interval", "0.05"),
        ("settle.creep_window_s", "0.15"),
        ("time_cap", "1.5"),
    ] {
        spec.set(path, value).unwrap();
    }
    spec
}

/// The small spec's grains in the lifted-cylinder rig: 80 g (about 900 grains) fill the 40 mm
/// tube standing on the plate, settle 0.1 s, and the tube is lifted 40 mm at 0.2 m/s; at rest
/// after about 1.2 s, 11 000 steps. (With the small funnel's 50 g the heap is too low for a
/// flank fit.)
fn small_lifted() -> AorSpec {
    let mut spec = small();
    for (path, value) in [
        ("protocol", "lifted_cylinder"),
        ("total_mass", "0.08"),
        ("cylinder.fill_settle_time", "0.1"),
        ("cylinder.lift_speed", "0.2"),
    ] {
        spec.set(path, value).unwrap();
    }
    spec
}

/// The small funnel's seed-to-seed standard deviation of the angle on the CPU, rounded up:
/// seeds 1-24 read 24.07 ± 1.85° (20.1-26.6°). The GPU on lavapipe read 24.04 ± 2.36° over
/// the same seeds (one of them, seed 5, left a flank too short to measure): no bias between
/// the engines to the means' 0.6° (measured 2026-11-27).
const SEED_STD_DEG: f64 = 1.9;

fn run(engine: Engine<'_>, spec: &AorSpec) -> AorRun {
    let run = run_aor_on(
        engine,
        spec,
        &mut |_| Control::Continue,
        Checkpoints::default(),
    )
    .expect("the small funnel runs");
    let r = &run.result;
    eprintln!(
        "{:?} seed {}: {:?} angle {:?} ended_by {:?} t {:.3} s steps {} wall {:.1} s grains {:?} \
         ({:?})",
        engine.kind(),
        spec.seed,
        r.status,
        r.angle_deg,
        r.ended_by,
        r.simulated_time_s,
        r.steps,
        r.wall_time_s,
        r.grains,
        r.engine_version
    );
    run
}

/// A heap that came to rest with (nearly) every grain on it; its angle.
fn heap_angle(spec: &AorSpec, r: &AorResult) -> f64 {
    assert_eq!(r.status, RunStatus::Ok, "{r:?}");
    assert!(r.came_to_rest, "{r:?}");
    assert!(
        r.grains.inserted.mass > 0.99 * spec.total_mass - 1e-4,
        "{r:?}"
    );
    assert_eq!(r.grains.held_up.count, 0, "the funnel drained: {r:?}");
    assert!(
        r.grains.on_pile.count as f64 > 0.8 * r.grains.inserted.count as f64,
        "{r:?}"
    );
    r.angle_deg.unwrap()
}

#[test]
fn a_small_funnel_on_the_gpu_forms_a_heap_inside_the_cpu_seed_spread() {
    let Some(gpu) = gpu() else { return };
    let seeds = [1, 2, 3];
    let angles = |engine: Engine<'_>| -> Vec<f64> {
        seeds
            .iter()
            .map(|&seed| {
                let mut spec = small();
                spec.seed = seed;
                let run = run(engine, &spec);
                let r = &run.result;
                let version = r.engine_version.as_deref().unwrap();
                match engine {
                    Engine::Cpu => assert_eq!(version, repose_engine::VERSION),
                    Engine::Gpu(gpu) => {
                        assert!(
                            version.contains(&format!("+gpu:{}", gpu.name())),
                            "{version}"
                        )
                    }
                }
                // The final world holds the grains the run ended with.
                assert_eq!(
                    run.world.particles().len() as u64,
                    r.grains.on_base.count + r.grains.held_up.count
                );
                heap_angle(&spec, r)
            })
            .collect()
    };
    let cpu = angles(Engine::Cpu);
    let on_gpu = angles(Engine::Gpu(gpu));
    let mean = |a: &[f64]| a.iter().sum::<f64>() / a.len() as f64;
    let (cpu_mean, gpu_mean) = (mean(&cpu), mean(&on_gpu));
    eprintln!("CPU {cpu:.2?} (mean {cpu_mean:.2}°), GPU {on_gpu:.2?} (mean {gpu_mean:.2}°)");
    // A GPU heap is one more draw from the seeds' spread (σ = SEED_STD_DEG): each lies within
    // 3.5 σ of the CPU's mean of three (3 σ of the draw, and the mean's own σ/√3 on top:
    // ±6.7°), and the two means of three, each with σ/√3, differ by less than 3 σ √(2/3)
    // (4.7°). A GPU without rolling friction (9° at μr 0.01 in the `fast` rig) or with a
    // wrong factory rate fails either. On lavapipe the GPU runs are deterministic, so the
    // test is too; another adapter draws other heaps, inside the same bounds.
    for a in &on_gpu {
        assert!(
            (a - cpu_mean).abs() < 3.5 * SEED_STD_DEG,
            "GPU angle {a:.2}° is more than 3.5 σ from the CPU's mean {cpu_mean:.2}°"
        );
    }
    let tolerance = 3.0 * SEED_STD_DEG * (2.0f64 / 3.0).sqrt();
    assert!(
        (cpu_mean - gpu_mean).abs() < tolerance,
        "means {cpu_mean:.2}° (CPU) and {gpu_mean:.2}° (GPU) differ by {tolerance:.1}° or more"
    );
}

/// The small lifted cylinder's seed-to-seed standard deviation of the angle on the CPU,
/// rounded up: seeds 1-24 read 36.04 ± 1.90° (31.9-39.6°) (measured 2026-11-27).
const LIFTED_SEED_STD_DEG: f64 = 2.0;

/// The small lifted cylinder's angles on `engine` for `seeds`, each heap at rest with every
/// grain on it once the tube is up (nothing held in the tube).
fn lifted_angles(engine: Engine<'_>, seeds: std::ops::RangeInclusive<u64>) -> Vec<f64> {
    seeds
        .map(|seed| {
            let mut spec = small_lifted();
            spec.seed = seed;
            let r = run(engine, &spec).result;
            assert_eq!(r.status, RunStatus::Ok, "{r:?}");
            assert!(r.came_to_rest, "{r:?}");
            assert!(
                r.grains.on_pile.count as f64 > 0.95 * r.grains.inserted.count as f64,
                "{r:?}"
            );
            r.angle_deg.unwrap()
        })
        .collect()
}

/// The lifted cylinder on the GPU (its tube a moving geometry, lifted 40 mm): the heap it
/// leaves is one more draw from the CPU's seed spread, within 3.5 σ of the CPU's mean of three
/// (±7°). A tube that did not move holds the grains (no heap); one whose wall velocity were
/// lost would drag nothing and leave another heap. 20 s on lavapipe.
#[test]
fn a_small_lifted_cylinder_on_the_gpu_slumps_inside_the_cpu_seed_spread() {
    let Some(gpu) = gpu() else { return };
    let cpu = lifted_angles(Engine::Cpu, 1..=3);
    let cpu_mean = cpu.iter().sum::<f64>() / 3.0;
    let on_gpu = lifted_angles(Engine::Gpu(gpu), 1..=1)[0];
    eprintln!("lifted cylinder: CPU {cpu:.2?} (mean {cpu_mean:.2}°), GPU {on_gpu:.2}°");
    assert!(
        (on_gpu - cpu_mean).abs() < 3.5 * LIFTED_SEED_STD_DEG,
        "GPU angle {on_gpu:.2}° is more than 3.5 σ from the CPU's mean {cpu_mean:.2}°"
    );
}

/// The small lifted cylinder over seeds 1-12 on each backend: the means differ by less than
/// 3 σ √(2/12) (2.4°). Five minutes on lavapipe:
/// `cargo test -p repose-experiments --test experiments aor_gpu::the_small_lifted -- --ignored
/// --nocapture`.
#[test]
#[ignore = "twelve GPU heaps: five minutes on lavapipe"]
fn the_small_lifted_cylinder_agrees_on_both_backends_over_twelve_seeds() {
    let Some(gpu) = gpu() else { return };
    let cpu = lifted_angles(Engine::Cpu, 1..=12);
    let on_gpu = lifted_angles(Engine::Gpu(gpu), 1..=12);
    let stats = |a: &[f64]| {
        let mean = a.iter().sum::<f64>() / a.len() as f64;
        let var = a.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (a.len() - 1) as f64;
        (mean, var.sqrt())
    };
    let ((cpu_mean, cpu_std), (gpu_mean, gpu_std)) = (stats(&cpu), stats(&on_gpu));
    println!("small lifted cylinder, seeds 1-12, angle of repose (°):");
    println!("  CPU {cpu:.2?}: mean {cpu_mean:.2} ± {cpu_std:.2}");
    println!(
        "  GPU ({}) {on_gpu:.2?}: mean {gpu_mean:.2} ± {gpu_std:.2}",
        gpu.describe()
    );
    let tolerance = 3.0 * LIFTED_SEED_STD_DEG * (2.0f64 / 12.0).sqrt();
    assert!(
        (cpu_mean - gpu_mean).abs() < tolerance,
        "means {cpu_mean:.2}° (CPU) and {gpu_mean:.2}° (GPU) differ by {tolerance:.1}° or more"
    );
}

#[test]
fn a_gpu_funnel_run_twice_is_bit_identical() {
    let Some(gpu) = gpu() else { return };
    let spec = small();
    let (a, b) = (run(Engine::Gpu(gpu), &spec), run(Engine::Gpu(gpu), &spec));
    let comparable = |r: &AorResult| {
        let mut v = serde_json::to_value(r).unwrap();
        v.as_object_mut().unwrap().remove("wall_time_s");
        v
    };
    assert_eq!(comparable(&a.result), comparable(&b.result));
    let bits = |run: &AorRun| -> Vec<u64> {
        let p = run.world.particles();
        p.position
            .iter()
            .chain(&p.velocity)
            .flat_map(|v| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
            .collect()
    };
    assert!(!bits(&a).is_empty());
    assert!(bits(&a) == bits(&b), "the final grains differ");
    heap_angle(&spec, &a.result);
}

/// The GPU runs every `aor` spec (either protocol, every contact law) but refuses checkpoints
/// by name: a GPU run cannot be continued from a saved state.
#[test]
fn the_gpu_backend_refuses_checkpoints_by_name() {
    let Some(gpu) = gpu() else { return };
    let mut keep = |_: &[u8]| {};
    let message = run_aor_on(
        Engine::Gpu(gpu),
        &small(),
        &mut |_| Control::Continue,
        Checkpoints {
            save: Some(&mut keep),
            ..Checkpoints::default()
        },
    )
    .unwrap_err();
    assert!(
        matches!(
            &message,
            AorError::Backend(BackendError::Unsupported { backend: "GPU", .. })
        ),
        "{message:?}"
    );
    assert!(message.to_string().contains("checkpoints"), "{message}");
}

/// Issue 38's acceptance check: the `fast` funnel (about 1 380 grains of 2.5 mm), seeds 1-5 on
/// each backend; the mean angles agree within 1° and each backend's mean lies inside the
/// other's range over the seeds. Half an hour on lavapipe on two loaded cores (the GPU heaps
/// 140-320 s each): `cargo test -p repose-experiments --test experiments aor_gpu:: --
/// --ignored --nocapture`.
///
/// Measured 2026-11-27 on lavapipe, before the GPU had the local-minimum test (225545c): CPU
/// 21.21, 22.69, 20.04, 22.65, 23.37° (mean 21.99°), GPU 22.26, 21.51, 19.56, 20.05, 20.28°
/// (mean 20.73°): each mean inside the other's range, but
/// 1.26° apart, so this test fails. Five heaps a side (σ 1.3° a heap, so σ 0.8° for the
/// difference of the means) cannot tell a 1° bias from chance; the small funnel over 24 seeds
/// (`SEED_STD_DEG`) found none (0.03°).
#[test]
#[ignore = "ten fast heaps, five of them on the GPU: half an hour on lavapipe"]
fn the_fast_funnel_agrees_on_both_backends_over_five_seeds() {
    let Some(gpu) = gpu() else { return };
    let angles = |engine: Engine<'_>| -> (Vec<f64>, f64) {
        let mut wall = 0.0;
        let angles = (1..=5)
            .map(|seed| {
                let mut spec = AorSpec::fast();
                spec.seed = seed;
                let r = run(engine, &spec).result;
                wall += r.wall_time_s;
                heap_angle(&spec, &r)
            })
            .collect();
        (angles, wall)
    };
    let (cpu, cpu_wall) = angles(Engine::Cpu);
    let (on_gpu, gpu_wall) = angles(Engine::Gpu(gpu));
    let mean = |a: &[f64]| a.iter().sum::<f64>() / a.len() as f64;
    let range = |a: &[f64]| {
        (
            a.iter().copied().fold(f64::INFINITY, f64::min),
            a.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let (cpu_mean, gpu_mean) = (mean(&cpu), mean(&on_gpu));
    let (cpu_range, gpu_range) = (range(&cpu), range(&on_gpu));
    println!("fast funnel, seeds 1-5, angle of repose (°):");
    println!("  CPU {cpu:.2?}: mean {cpu_mean:.2}, range {cpu_range:.2?}, {cpu_wall:.0} s");
    println!(
        "  GPU ({}) {on_gpu:.2?}: mean {gpu_mean:.2}, range {gpu_range:.2?}, {gpu_wall:.0} s",
        gpu.describe()
    );
    assert!(
        (cpu_mean - gpu_mean).abs() < 1.0,
        "means {cpu_mean:.2}° and {gpu_mean:.2}° differ by 1° or more"
    );
    assert!(
        (cpu_range.0..=cpu_range.1).contains(&gpu_mean),
        "the GPU's mean is outside the CPU's seed range"
    );
    assert!(
        (gpu_range.0..=gpu_range.1).contains(&cpu_mean),
        "the CPU's mean is outside the GPU's seed range"
    );
}
