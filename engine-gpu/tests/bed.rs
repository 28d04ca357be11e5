//! The benchmark's bed on the GPU: it settles like the CPU engine's, and the same run twice is
//! bit-identical on one adapter.

mod common;

use repose_engine::bench::{bed_lattice, settled_bed};
use repose_engine_gpu::GpuWorld;

fn mean_height(z: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = z.fold((0.0, 0usize), |(s, n), z| (s + z, n + 1));
    sum / n as f64
}

#[test]
fn a_bed_settles_on_the_gpu_as_on_the_cpu() {
    let Some(gpu) = common::gpu() else { return };
    let n = 600;
    let cpu = settled_bed(n, 3).unwrap();
    let (gpu_bed, settle_steps) = repose_engine_gpu::bench::settled_bed(&gpu, n, 3).unwrap();
    let cpu_h = mean_height(cpu.particles().position.iter().map(|x| x.z));
    let gpu_h = mean_height(gpu_bed.particles().position.iter().map(|x| x.z));
    let cpu_top = cpu
        .particles()
        .position
        .iter()
        .map(|x| x.z)
        .fold(0.0, f64::max);
    let gpu_top = gpu_bed
        .particles()
        .position
        .iter()
        .map(|x| x.z)
        .fold(0.0, f64::max);
    eprintln!(
        "mean height cpu {cpu_h:.6} m, gpu {gpu_h:.6} m; top {cpu_top:.6} / {gpu_top:.6}; \
         GPU settling steps {settle_steps}"
    );
    // Random packings of the same lattice differ grain by grain; the bed's mean height agrees
    // within 2 % (a tenth of a grain on a bed a few grains deep).
    assert!(
        (gpu_h - cpu_h).abs() < 0.02 * cpu_h,
        "mean height: GPU {gpu_h} vs CPU {cpu_h}"
    );
    assert!(gpu_bed
        .particles()
        .position
        .iter()
        .all(|x| x.z > 0.0 && x.z.is_finite()));
}

#[test]
fn the_same_run_twice_is_bit_identical() {
    let Some(gpu) = common::gpu() else { return };
    let (world, _) = bed_lattice(500, 5).unwrap();
    let run = || {
        let mut w = GpuWorld::new(&gpu, &world).unwrap();
        w.run(600);
        w.state_bytes().unwrap()
    };
    let (a, b) = (run(), run());
    assert_eq!(a.len(), b.len());
    assert!(a == b, "two runs of the same world differ");
}
