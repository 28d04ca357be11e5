//! Grains inserted into a running GPU world: they fall and land as they would in a world built
//! with them, removed grains' slots are refilled, a full world refuses more, and a run with
//! insertions is bit-identical when repeated.

use crate::common;

use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::material::MaterialId;
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::generators;
use repose_engine::neighbor::Domain;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, World, WorldConfig};
use repose_engine_gpu::{Capacity, GpuError, GpuParticles, GpuWorld};

pub(crate) const R: f64 = 1.5e-3;
const GRAIN: MaterialId = MaterialId(0);

/// An empty world: a 5 cm plate (16 × 16 cells) at z = 0 in a 6 cm box open below it, gravity.
pub(crate) fn empty(integrator: Integrator) -> World {
    let materials = common::grain_materials(0.05);
    let dt = materials.rayleigh_time_step(GRAIN, R, 0.2);
    let domain = Domain::closed(Vec3::new(-0.03, -0.03, -0.005), Vec3::new(0.03, 0.03, 0.06));
    let mut config = WorldConfig::new(dt, domain);
    config.integrator = integrator;
    let mut world = World::new(materials, config).unwrap();
    world
        .add_geometry(Geometry {
            name: "plate".into(),
            mesh: generators::plane(0.05, 0.05, 16, 16).unwrap(),
            motion: Motion::stationary(Pose::identity()),
            material: GRAIN,
        })
        .unwrap();
    world
}

pub(crate) fn grain(x: f64, y: f64, z: f64, vz: f64) -> ParticleSpec {
    ParticleSpec {
        position: Vec3::new(x, y, z),
        velocity: Vec3::new(0.0, 0.0, vz),
        angular_velocity: Vec3::zeros(),
        radius: R,
        material: GRAIN,
    }
}

/// Grains resting near x = -15 mm (they settle before the insertions).
fn resting(count: usize) -> Vec<ParticleSpec> {
    (0..count)
        .map(|k| grain(-0.015, -0.006 + 2.2 * R * k as f64, R + 2e-4, 0.0))
        .collect()
}

/// Two leaning stacks of three grains near x = +10 mm, a few mm above the plate, thrown down,
/// each grain touching the one below it (overlap 1e-5 m) from the start, so the contacts must
/// be listed at the first step: they push apart, land on the plate and topple.
pub(crate) fn stacks() -> Vec<ParticleSpec> {
    let mut specs = Vec::new();
    for (s, y) in [-0.004, 0.004].into_iter().enumerate() {
        for level in 0..3 {
            let x = 0.01 + (0.3 + 0.1 * s as f64) * R * level as f64;
            let dz = ((2.0 * R - 1e-5).powi(2) - ((0.3 + 0.1 * s as f64) * R).powi(2)).sqrt();
            let z = R + 0.002 + level as f64 * dz;
            specs.push(grain(x, y, z, -0.3));
        }
    }
    specs
}

pub(crate) fn with(world: &World, specs: &[ParticleSpec]) -> World {
    let mut world = world.clone();
    for &spec in specs {
        world.add_particle(spec).unwrap();
    }
    world
}

/// The largest position and velocity differences between `a`'s grains in `slots` and `b`'s
/// first grains.
fn difference(a: &GpuParticles, slots: &[usize], b: &GpuParticles) -> (f64, f64) {
    slots
        .iter()
        .enumerate()
        .fold((0.0, 0.0), |(dx, dv), (k, &s)| {
            (
                f64::max(dx, (a.position[s] - b.position[k]).norm()),
                f64::max(dv, (a.velocity[s] - b.velocity[k]).norm()),
            )
        })
}

/// Runs `a` (whose grains `specs` were inserted into `slots`) and `b` (built with them) for
/// 2500 steps, checking that the inserted grains fell at least a millimetre, reached the
/// plate (the lowest of them) and stayed in the box; returns both worlds' grains at the end.
fn fall_and_land(
    a: &mut GpuWorld,
    b: &mut GpuWorld,
    slots: &[usize],
    specs: &[ParticleSpec],
) -> (GpuParticles, GpuParticles) {
    let mut lowest = vec![f64::INFINITY; slots.len()];
    for _ in 0..10 {
        a.run(250).unwrap();
        b.run(250).unwrap();
        let p = a.particles().unwrap();
        for (low, &s) in lowest.iter_mut().zip(slots) {
            assert!(!p.removed[s], "slot {s} was removed");
            *low = low.min(p.position[s].z);
        }
    }
    for ((&s, spec), low) in slots.iter().zip(specs).zip(&lowest) {
        assert!(
            *low < spec.position.z - 1e-3 && *low > 0.5 * R,
            "slot {s}: lowest z {low} (inserted at {})",
            spec.position.z
        );
    }
    let lowest = lowest.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        lowest < R * 1.01,
        "no inserted grain reached the plate: {lowest}"
    );
    (a.particles().unwrap(), b.particles().unwrap())
}

#[test]
fn grains_inserted_mid_run_fall_and_land_as_in_a_world_built_with_them() {
    let Some(gpu) = common::gpu() else { return };
    for integrator in [Integrator::SymplecticEuler, Integrator::VelocityVerlet] {
        let base = empty(integrator);
        let first = resting(5);
        let added = stacks();
        let capacity = Capacity {
            particles: first.len() + added.len(),
            max_radius: R,
        };
        let mut a = GpuWorld::with_capacity(gpu, &with(&base, &first), capacity).unwrap();
        a.run(300).unwrap();
        let slots = a.insert(&added).unwrap();
        assert_eq!(slots, (5..11).collect::<Vec<_>>());
        let mut b = GpuWorld::with_capacity(gpu, &with(&base, &added), capacity).unwrap();
        let (pa, pb) = fall_and_land(&mut a, &mut b, &slots, &added);
        let (dx, dv) = difference(&pa, &slots, &pb);
        println!("{integrator:?}: inserted vs built with them: |Δx| {dx:.2e} m, |Δv| {dv:.2e} m/s");
        // The inserted grains never come near the resting ones: the same arithmetic on the
        // same f32 values, so the same result to rounding.
        assert!(dx < 1e-7 && dv < 1e-5, "{integrator:?}: {dx} m, {dv} m/s");
        // The resting grains were not disturbed (they stay on the plate).
        for k in 0..first.len() {
            assert!((pa.position[k].z - R).abs() < 1e-5, "{:?}", pa.position[k]);
        }
    }
}

/// Four grains that fall off the plate's edge out of the box, between grains that stay: slots
/// 1, 2, 4 and 5 of 6.
pub(crate) fn leavers_among_resting() -> Vec<ParticleSpec> {
    let rest = resting(2);
    let leave = |y: f64| grain(0.028, y, 0.0, -1.0);
    vec![
        rest[0],
        leave(-0.01),
        leave(-0.005),
        rest[1],
        leave(0.005),
        leave(0.01),
    ]
}

/// Runs `world` until its four leavers are gone.
pub(crate) fn run_until_removed(world: &mut GpuWorld, removed: u64) {
    while world.counters().unwrap().removed < removed {
        assert!(world.steps() < 5000, "the grains did not leave");
        world.run(200).unwrap();
    }
}

#[test]
fn slots_of_removed_grains_are_refilled_and_a_full_world_refuses_more() {
    let Some(gpu) = common::gpu() else { return };
    let base = empty(Integrator::SymplecticEuler);
    let start = leavers_among_resting();
    let capacity = Capacity {
        particles: start.len(),
        max_radius: R,
    };
    let mut a = GpuWorld::with_capacity(gpu, &with(&base, &start), capacity).unwrap();
    run_until_removed(&mut a, 4);
    let added: Vec<ParticleSpec> = stacks().into_iter().take(4).collect();
    let mut too_many = added.clone();
    too_many.push(stacks()[4]);
    match a.insert(&too_many) {
        Err(GpuError::Capacity(message)) => {
            println!("{message}");
            assert!(message.contains("of the 6 particle slots"), "{message}");
        }
        other => panic!("five grains into four free slots: {other:?}"),
    }
    // Nothing was inserted by the refused call.
    assert!(a.particles().unwrap().removed[1]);
    // The two-buffer read-back agrees with the full one.
    let (positions, removed) = a.positions().unwrap();
    let p = a.particles().unwrap();
    assert_eq!((positions, removed), (p.position, p.removed));
    let slots = a.insert(&added).unwrap();
    assert_eq!(slots, vec![1, 2, 4, 5]);
    assert!(matches!(a.insert(&added[..1]), Err(GpuError::Capacity(_))));
    let mut b = GpuWorld::with_capacity(gpu, &with(&base, &added), capacity).unwrap();
    let (pa, pb) = fall_and_land(&mut a, &mut b, &slots, &added);
    let (dx, dv) = difference(&pa, &slots, &pb);
    println!("refilled slots vs a world built with the grains: |Δx| {dx:.2e} m, |Δv| {dv:.2e} m/s");
    assert!(dx < 1e-7 && dv < 1e-5, "{dx} m, {dv} m/s");
    assert_eq!(a.counters().unwrap().removed, 4);
}

#[test]
fn invalid_grains_are_refused_by_name() {
    let Some(gpu) = common::gpu() else { return };
    let base = empty(Integrator::SymplecticEuler);
    let capacity = Capacity {
        particles: 4,
        max_radius: R,
    };
    // An empty world with room for grains.
    let mut w = GpuWorld::with_capacity(gpu, &base, capacity).unwrap();
    let mut big = grain(0.0, 0.0, 0.01, 0.0);
    big.radius = 1.5 * R;
    let mut unknown = grain(0.0, 0.0, 0.01, 0.0);
    unknown.material = MaterialId(3);
    let outside = grain(0.0, 0.0, 0.07, 0.0);
    for (spec, says) in [
        (big, "radius"),
        (unknown, "material 3"),
        (outside, "outside the domain"),
    ] {
        match w.insert(&[grain(0.0, 0.0, 0.02, 0.0), spec]) {
            Err(GpuError::Particle(message)) => assert!(message.contains(says), "{message}"),
            other => panic!("{spec:?}: {other:?}"),
        }
    }
    assert_eq!(w.len(), 0);
    w.run(10).unwrap();
    assert_eq!(w.insert(&[grain(0.0, 0.0, 0.02, 0.0)]).unwrap(), vec![0]);
    w.run(10).unwrap();
    let p = w.particles().unwrap();
    assert_eq!(p.position.len(), 1);
    assert!(
        p.velocity[0].z < 0.0,
        "the grain does not fall: {:?}",
        p.velocity[0]
    );
}

#[test]
fn a_run_with_insertions_is_bit_identical_when_repeated() {
    let Some(gpu) = common::gpu() else { return };
    for integrator in [Integrator::SymplecticEuler, Integrator::VelocityVerlet] {
        let base = empty(integrator);
        let start = leavers_among_resting();
        let world = with(&base, &start);
        let capacity = Capacity {
            particles: 9,
            max_radius: R,
        };
        let run = || {
            let mut w = GpuWorld::with_capacity(gpu, &world, capacity).unwrap();
            run_until_removed(&mut w, 4);
            // Four refilled slots, two fresh ones, mid-chunk of the neighbour lists' life.
            let slots = w.insert(&stacks()).unwrap();
            assert_eq!(slots, vec![1, 2, 4, 5, 6, 7]);
            w.run(700).unwrap();
            let last = w.insert(&[grain(-0.005, 0.0, 0.01, 0.0)]).unwrap();
            assert_eq!(last, vec![8]);
            w.run(700).unwrap();
            w.state_bytes().unwrap()
        };
        let (a, b) = (run(), run());
        assert!(
            a == b,
            "{integrator:?}: two runs with the same insertions differ"
        );
    }
}

/// A grain sliding on a plate that runs out of the box leaves with a tangential spring in its
/// triangle contact history; a grain inserted into its slot right after, resting on the
/// plate, starts without that history: it stays as still as in a world built with it.
#[test]
fn a_refilled_slot_starts_without_the_removed_grains_history() {
    let Some(gpu) = common::gpu() else { return };
    let mut base = empty(Integrator::SymplecticEuler);
    // A second plate reaching past the box's +x face (the first stops 5 mm short of it).
    base.add_geometry(Geometry {
        name: "runway".into(),
        mesh: generators::plane(0.04, 0.02, 8, 4).unwrap(),
        motion: Motion::stationary(Pose::translation(0.03, 0.0, 0.0)),
        material: GRAIN,
    })
    .unwrap();
    let resting_z = R - 2e-7;
    let mut slider = grain(0.027, 0.0, resting_z, 0.0);
    slider.velocity = Vec3::new(0.5, 0.0, 0.0);
    let capacity = Capacity {
        particles: 1,
        max_radius: R,
    };
    let mut a = GpuWorld::with_capacity(gpu, &with(&base, &[slider]), capacity).unwrap();
    while a.counters().unwrap().removed < 1 {
        assert!(a.steps() < 3000, "the slider did not leave");
        a.run(10).unwrap();
    }
    let still = grain(0.005, 0.0, resting_z, 0.0);
    assert_eq!(a.insert(&[still]).unwrap(), vec![0]);
    let mut b = GpuWorld::with_capacity(gpu, &with(&base, &[still]), capacity).unwrap();
    a.run(50).unwrap();
    b.run(50).unwrap();
    let (pa, pb) = (a.particles().unwrap(), b.particles().unwrap());
    println!(
        "refilled slot: v {:?}, built with it: v {:?}",
        pa.velocity[0], pb.velocity[0]
    );
    assert!(
        pa.velocity[0] == pb.velocity[0] && pa.position[0] == pb.position[0],
        "the refilled grain moves differently: {:?} vs {:?}",
        pa.velocity[0],
        pb.velocity[0]
    );
}
