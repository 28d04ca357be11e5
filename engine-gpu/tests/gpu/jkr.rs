//! JKR cohesion on the GPU: the force at a positive overlap against the CPU engine's law (two
//! spheres, a sphere on a face), and the necking past zero overlap of two grains pulled apart,
//! against the CPU engine.

use crate::common;
use crate::parity::{
    ball, e_star_same, e_star_wall, first_step_force, hertz, plane, table_with, world, BALL, WALL,
};

use repose_engine::contact::JKR_SEPARATION;
use repose_engine::kinematics::Motion;
use repose_engine::material::Cohesion;
use repose_engine::math::{Pose, Vec3};
use repose_engine::neighbor::Domain;
use repose_engine::world::{Geometry, World};
use repose_engine_gpu::GpuWorld;
use std::f64::consts::PI;

const R: f64 = 0.005;
const GAMMA: f64 = 0.5;

fn jkr() -> Cohesion {
    Cohesion::Jkr {
        surface_energy: GAMMA,
    }
}

/// JKR's length unit a0² / R* for the pair's E* and R*.
fn unit(e_star: f64, r_star: f64) -> f64 {
    let a0 = (2.0 * PI * GAMMA * r_star * r_star / e_star).cbrt();
    a0 * a0 / r_star
}

/// Two spheres and a sphere on a face at overlaps from a twentieth of JKR's length unit to 50
/// of them: the first step's force is Hertz's less the CPU engine's JKR attraction, to 1e-3 of
/// the two terms' magnitudes (the net nearly vanishes where they balance, and in f32 D^1.5 and
/// s^6 nearly cancel at large D).
#[test]
fn jkr_pulls_as_the_cpu_law_at_positive_overlaps() {
    let Some(gpu) = common::gpu() else { return };
    let materials = table_with(0.5, 0.5, 0.0, jkr());
    let domain = Domain::closed(Vec3::repeat(-0.05), Vec3::repeat(0.05));
    for scale in [0.05, 0.5, 5.0, 50.0] {
        // Two spheres along x.
        let r_star = R / 2.0;
        let overlap = scale * unit(e_star_same(), r_star);
        let mut w = world(materials.clone(), 1e-9, Vec3::zeros(), domain);
        let half = R - overlap / 2.0;
        w.add_particle(ball(
            Vec3::new(-half, 0.0, 0.0),
            Vec3::zeros(),
            Vec3::zeros(),
            R,
        ))
        .unwrap();
        w.add_particle(ball(
            Vec3::new(half, 0.0, 0.0),
            Vec3::zeros(),
            Vec3::zeros(),
            R,
        ))
        .unwrap();
        let law = w.materials().pair(BALL, BALL).cohesion;
        let (repel, pull) = (
            hertz(e_star_same(), r_star, overlap),
            law.attraction(r_star, overlap, || 0.0),
        );
        let expected = repel - pull;
        let force = first_step_force(gpu, &w, 1).x;
        println!("JKR spheres, overlap {scale} a0²/R*: {force:.7e} N (CPU law {expected:.7e} N)");
        assert!(
            (force - expected).abs() < 1e-3 * (repel + pull),
            "{force} vs {expected}"
        );

        // A sphere on a face (R* = R).
        let overlap = scale * unit(e_star_wall(), R);
        let mut w = world(materials.clone(), 1e-9, Vec3::zeros(), domain);
        w.add_geometry(Geometry {
            name: "plate".into(),
            mesh: plane(0.04, 2),
            motion: Motion::stationary(Pose::identity()),
            material: WALL,
        })
        .unwrap();
        w.add_particle(ball(
            Vec3::new(0.001, 0.002, R - overlap),
            Vec3::zeros(),
            Vec3::zeros(),
            R,
        ))
        .unwrap();
        let law = w.materials().pair(BALL, WALL).cohesion;
        let (repel, pull) = (
            hertz(e_star_wall(), R, overlap),
            law.attraction(R, overlap, || 0.0),
        );
        let expected = repel - pull;
        let force = first_step_force(gpu, &w, 0).z;
        println!("JKR on a face, overlap {scale} a0²/R*: {force:.7e} N (CPU law {expected:.7e} N)");
        assert!(
            (force - expected).abs() < 1e-3 * (repel + pull),
            "{force} vs {expected}"
        );
    }
}

/// Two JKR grains leaving each other at 0.1 m/s (the CPU engine's
/// `jkr_grains_pulled_apart_keep_attracting_past_zero_overlap`): past zero overlap the contact
/// necks, pulling until the gap reaches 0.4725 a0²/R*, and the GPU's relative speed after the
/// separation is the CPU engine's to 1e-4.
#[test]
fn jkr_grains_pulled_apart_neck_until_they_separate_as_on_the_cpu() {
    let Some(gpu) = common::gpu() else { return };
    let materials = table_with(0.5, 0.5, 0.0, jkr());
    let dt = materials.rayleigh_time_step(BALL, R, 0.002);
    let mut scene = world(
        materials,
        dt,
        Vec3::zeros(),
        Domain::closed(Vec3::repeat(-0.1), Vec3::repeat(0.1)),
    );
    let half = R - 1e-6 / 2.0;
    for (side, v) in [(-1.0, -0.05), (1.0, 0.05)] {
        scene
            .add_particle(ball(
                Vec3::new(side * half, 0.0, 0.0),
                Vec3::new(v, 0.0, 0.0),
                Vec3::zeros(),
                R,
            ))
            .unwrap();
    }
    let separation = -JKR_SEPARATION * unit(e_star_same(), R / 2.0);
    let mut cpu: World = scene.clone();
    let mut gpu_world = GpuWorld::new(gpu, &scene).unwrap();
    let (mut at_zero, mut deepest_pull) = (None, 0.0);
    let (mut previous_gap, mut previous_speed) = (-1e-6, 0.1);
    let mut steps = 0;
    while previous_gap < 3.0 * separation {
        gpu_world.run(1).unwrap();
        cpu.step();
        steps += 1;
        assert!(steps < 20_000, "the grains did not separate");
        let p = gpu_world.particles().unwrap();
        let gap = (p.position[1] - p.position[0]).norm() - 2.0 * R;
        let speed = p.velocity[1].x - p.velocity[0].x;
        if gap > 0.0 && at_zero.is_none() {
            at_zero = Some(speed);
        }
        if previous_gap > 0.0 && speed < previous_speed {
            deepest_pull = f64::max(deepest_pull, previous_gap);
        }
        (previous_gap, previous_speed) = (gap, speed);
    }
    let at_zero = at_zero.unwrap();
    let c = cpu.particles();
    let cpu_speed = c.velocity[1].x - c.velocity[0].x;
    println!(
        "JKR necking: relative speed at zero overlap {at_zero:.6e} m/s, after separation \
         {previous_speed:.6e} m/s (CPU {cpu_speed:.6e}); pulling at a gap of {deepest_pull:.3e} m \
         (separation at {separation:.3e} m)"
    );
    assert!(
        previous_speed < at_zero * (1.0 - 1e-5),
        "no pull past zero overlap"
    );
    assert!(deepest_pull > 0.5 * separation, "{deepest_pull}");
    assert!(deepest_pull < separation, "{deepest_pull}");
    assert!(
        (previous_speed / cpu_speed - 1.0).abs() < 1e-4,
        "{previous_speed} vs {cpu_speed}"
    );
}
