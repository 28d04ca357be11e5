//! Several worlds on one device, as a worker's GPU slots share their adapter: each gives the
//! bits it gives alone, every world is admitted against the device's memory (one that can
//! never fit is refused at once, one that fits beside fewer others waits for them), and a lost
//! device refuses new worlds.

use std::time::{Duration, Instant};

use crate::common;
use crate::insertion::{empty, grain, leavers_among_resting, run_until_removed, stacks, with, R};

use repose_engine::integrate::Integrator;
use repose_engine::world::World;
use repose_engine_gpu::{Capacity, Gpu, GpuError, GpuWorld};

/// The insertion test's run: grains leave, others are inserted into their slots mid-run.
fn run(gpu: &Gpu, world: &World) -> Vec<u8> {
    let capacity = Capacity {
        particles: 9,
        max_radius: R,
    };
    let mut w = GpuWorld::with_capacity(gpu, world, capacity).unwrap();
    run_until_removed(&mut w, 4);
    w.insert(&stacks()).unwrap();
    w.run(700).unwrap();
    w.insert(&[grain(-0.005, 0.0, 0.01, 0.0)]).unwrap();
    w.run(700).unwrap();
    w.state_bytes().unwrap()
}

#[test]
fn worlds_run_at_once_on_one_device_give_the_bits_of_a_lone_run() {
    let Some(gpu) = common::gpu() else { return };
    let world = with(
        &empty(Integrator::SymplecticEuler),
        &leavers_among_resting(),
    );
    let alone = run(gpu, &world);
    let together: Vec<Vec<u8>> = std::thread::scope(|s| {
        let runs: Vec<_> = (0..3).map(|_| s.spawn(|| run(gpu, &world))).collect();
        runs.into_iter().map(|r| r.join().unwrap()).collect()
    });
    for (k, bits) in together.iter().enumerate() {
        assert!(
            *bits == alone,
            "run {k} of 3 on one device differs from the lone run"
        );
    }
}

/// A GPU of this test's own: the budget it sets must not reach the other tests' worlds.
fn own_gpu() -> Option<Gpu> {
    common::gpu()?;
    Some(Gpu::open().unwrap())
}

#[test]
fn a_world_over_the_memory_budget_is_refused_at_admission_and_one_that_fits_later_waits() {
    let Some(gpu) = own_gpu() else { return };
    println!(
        "{}: memory {:?}, budget {:?}",
        gpu.describe(),
        gpu.memory(),
        gpu.memory_budget()
    );
    if cfg!(target_os = "linux") {
        let memory = gpu.memory().expect("a Vulkan adapter's heaps");
        assert_eq!(gpu.memory_budget(), Some(memory / 100 * 90));
    }
    let world = with(
        &empty(Integrator::SymplecticEuler),
        &leavers_among_resting(),
    );
    let capacity = Capacity {
        particles: 9,
        max_radius: R,
    };
    let first = GpuWorld::with_capacity(&gpu, &world, capacity).unwrap();
    let (worlds, held) = gpu.in_flight();
    assert_eq!(worlds, 1);
    assert_eq!(
        held,
        first.memory_bytes() + 64 * 9,
        "buffers and read-back staging"
    );

    // Too large for the whole budget: refused at once, naming what it needs and what the
    // device allows.
    gpu.set_memory_budget(held - 1);
    let started = Instant::now();
    match GpuWorld::with_capacity(&gpu, &world, capacity) {
        Err(GpuError::Capacity(message)) => {
            println!("{message}");
            assert!(
                message.contains("needs") && message.contains("of device memory"),
                "{message}"
            );
            assert!(message.contains(gpu.name()), "{message}");
        }
        other => panic!("a world over the budget: {other:?}"),
    }
    assert!(
        started.elapsed() < Duration::from_secs(1),
        "refused at once"
    );

    // Fits alone, not beside the first: waits for it, then is refused when the wait runs out.
    gpu.set_memory_budget(held + held / 2);
    gpu.set_admission_wait(Duration::from_millis(300));
    let started = Instant::now();
    match GpuWorld::with_capacity(&gpu, &world, capacity) {
        Err(GpuError::Capacity(message)) => {
            println!("{message}");
            assert!(message.contains("1 other run(s)"), "{message}");
        }
        other => panic!("a world beside a full budget: {other:?}"),
    }
    assert!(started.elapsed() >= Duration::from_millis(300));
    // … and is admitted as soon as the first world ends within the wait.
    gpu.set_admission_wait(Duration::from_secs(60));
    let second = std::thread::scope(|s| {
        let second = s.spawn(|| GpuWorld::with_capacity(&gpu, &world, capacity));
        std::thread::sleep(Duration::from_millis(200));
        assert_eq!(gpu.in_flight().0, 1, "the second world waits");
        drop(first);
        second.join().unwrap()
    })
    .unwrap();
    assert_eq!(gpu.in_flight(), (1, held));
    drop(second);
    assert_eq!(gpu.in_flight(), (0, 0));
}

#[test]
fn a_lost_device_says_why_and_refuses_new_worlds() {
    let Some(gpu) = own_gpu() else { return };
    assert_eq!(gpu.lost(), None);
    gpu.destroy();
    let reason = gpu.lost().expect("a destroyed device is lost");
    println!("{reason}");
    let world = with(
        &empty(Integrator::SymplecticEuler),
        &leavers_among_resting(),
    );
    match GpuWorld::new(&gpu, &world) {
        Err(GpuError::Lost(message)) => assert!(message.contains("lost"), "{message}"),
        other => panic!("a world on a lost device: {other:?}"),
    }
}
