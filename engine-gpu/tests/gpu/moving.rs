//! Moving geometries on the GPU: a belt (a translating plate), a turntable (a turning plate),
//! a turning paddle against the CPU engine, and the body frame's precision.

use crate::common;
use crate::parity::{
    ball, e_star_wall, hertz, mass, plane, resting_overlap, table, when_slip_ends, world, BALL,
    WALL,
};

use repose_engine::integrate::Integrator;
use repose_engine::kinematics::{Motion, RotationSegment, TranslationSegment};
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::{generators, TriMesh};
use repose_engine::neighbor::Domain;
use repose_engine::world::{Geometry, World, WorldConfig};
use repose_engine_gpu::GpuWorld;

fn add_moving(world: &mut World, mesh: TriMesh, motion: Motion) {
    world
        .add_geometry(Geometry {
            name: "mover".into(),
            mesh,
            motion,
            material: WALL,
        })
        .unwrap();
}

/// Translates at `velocity` from t = 0 on.
fn translating(velocity: Vec3) -> Motion {
    Motion::new(
        Pose::identity(),
        vec![TranslationSegment {
            velocity,
            start: 0.0,
            stop: 100.0,
        }],
        Vec::new(),
    )
    .unwrap()
}

/// Turns at `rpm` about the vertical line through `axis_point` (body frame), placed at
/// `placement`, from t = 0 on.
fn turning(placement: Pose, axis_point: Vec3, rpm: f64) -> Motion {
    Motion::new(
        placement,
        Vec::new(),
        vec![RotationSegment {
            axis: Vec3::z(),
            axis_point,
            rpm,
            start: 0.0,
            stop: 100.0,
        }],
    )
    .unwrap()
}

const R: f64 = 0.005;

/// A 5 mm sphere at rest on a 1.8 m plate that moves as `motion`, at `x` (z: its resting
/// height).
fn sphere_on_moving_plate(friction: f64, motion: Motion, x: Vec3) -> World {
    let materials = table(0.5, friction, 0.0);
    let dt = materials.rayleigh_time_step(BALL, R, 0.2);
    let domain = Domain::closed(Vec3::new(-1.0, -1.0, -0.05), Vec3::new(1.0, 1.0, 0.05));
    let mut w = world(materials, dt, Vec3::new(0.0, 0.0, -9.81), domain);
    add_moving(&mut w, plane(0.9, 30), motion);
    let x = Vec3::new(x.x, x.y, R - resting_overlap(R, 9.81));
    w.add_particle(ball(x, Vec3::zeros(), Vec3::zeros(), R))
        .unwrap();
    w
}

/// A sphere set down on a belt moving at u slides until its contact point moves with the belt:
/// after 2u / (7 μ g), at 2u/7 (in the belt's frame, a sphere launched at −u rolls at 5/7 of
/// that). The belt's velocity enters the contact's relative velocity.
#[test]
fn a_sphere_set_down_on_a_moving_belt_rolls_at_two_sevenths_of_its_speed() {
    let Some(gpu) = common::gpu() else { return };
    let (mu, g, u) = (0.3, 9.81, 1.0);
    let w = sphere_on_moving_plate(
        mu,
        translating(Vec3::new(u, 0.0, 0.0)),
        Vec3::new(0.3, 0.0, 0.0),
    );
    let mut world = GpuWorld::new(gpu, &w).unwrap();
    // The contact point's velocity less the belt's.
    let slip = |p: &repose_engine_gpu::GpuParticles| {
        (p.velocity[0] + p.angular_velocity[0].cross(&Vec3::new(0.0, 0.0, -R))).x - u
    };
    let expected_time = 2.0 * u / (7.0 * mu * g);
    let (t, v) = when_slip_ends(&mut world, -u, slip);
    println!(
        "belt: rolling at {t:.5} s (theory {expected_time:.5}), v {v:.5} (theory {:.5})",
        2.0 / 7.0 * u
    );
    assert!((t / expected_time - 1.0).abs() < 0.02, "{t}");
    assert!((v / (2.0 / 7.0 * u) - 1.0).abs() < 0.02, "{v}");
}

/// A sphere at rest 0.2 m from the axis of a turntable (60 rpm) slides on it at first: kinetic
/// friction accelerates it at μ g along the table's surface velocity there, ω × r (+y), with
/// nothing along the radius yet. The table's turn enters the body frame and the wall's velocity
/// at the contact point. The table takes the reaction, (0, −μ m g, −m g), and its torque about
/// the axis through the contact 0.2 m out, (0, 0.2 m g, −0.2 μ m g), every step.
#[test]
fn a_turntable_drags_a_resting_sphere_along_its_surface_velocity() {
    let Some(gpu) = common::gpu() else { return };
    let (mu, g, radius) = (0.3, 9.81, 0.2);
    let w = sphere_on_moving_plate(
        mu,
        turning(Pose::identity(), Vec3::zeros(), 60.0),
        Vec3::new(radius, 0.0, 0.0),
    );
    let dt = w.config().time_step;
    let mut world = GpuWorld::new(gpu, &w).unwrap();
    // 2 ms: the table's surface under the sphere moves at 1.26 m/s, the sphere reaches
    // 6 mm/s: still sliding.
    let steps = (2e-3 / dt).round() as u64;
    world.run(steps).unwrap();
    let p = world.particles().unwrap();
    let t = world.time();
    let v = p.velocity[0];
    println!(
        "turntable: after {t:.5} s v = {v:?}, theory (0, {:.6}, 0)",
        mu * g * t
    );
    // The tangential spring needs a few steps to reach the Coulomb cap: 3 %.
    assert!((v.y / (mu * g * t) - 1.0).abs() < 0.03, "{v:?}");
    assert!(v.x.abs() < 0.01 * v.y, "{v:?}");
    assert!(v.z.abs() < 0.01 * v.y, "{v:?}");
    let series = world.geometry_series(0).unwrap();
    assert_eq!(series.len() as u64, steps, "one record a step");
    let last = series.last().unwrap();
    assert!(
        (last.time - (t - dt)).abs() < 1e-12,
        "{} vs {}",
        last.time,
        t - dt
    );
    let weight = mass(R) * g;
    let (force, torque) = (last.force, last.torque);
    println!("turntable: load {force:?} N, torque {torque:?} N m; m g = {weight:.6e} N");
    let close = |a: f64, b: f64| (a - b).abs() < 0.03 * b.abs();
    assert!(
        close(force.y, -mu * weight) && close(force.z, -weight),
        "{force:?}"
    );
    assert!(force.x.abs() < 0.01 * weight, "{force:?}");
    assert!(close(torque.y, radius * weight), "{torque:?}");
    assert!(close(torque.z, -radius * mu * weight), "{torque:?}");
    assert!(world.geometry_series(1).is_err(), "there is no geometry 1");
    world.clear_geometry_series();
    world.run(10).unwrap();
    assert_eq!(world.geometry_series(0).unwrap().len(), 10);
}

/// A scene for the paddle test on either engine.
fn paddle_scene(integrator: Integrator) -> World {
    let materials = table(0.5, 0.3, 0.0);
    let dt = materials.rayleigh_time_step(BALL, R, 0.2);
    let domain = Domain::closed(Vec3::new(-0.2, -0.2, -0.02), Vec3::new(0.2, 0.2, 0.08));
    let mut c = WorldConfig::new(dt, domain);
    c.gravity = Vec3::new(0.0, 0.0, -9.81);
    c.integrator = integrator;
    let mut w = World::new(materials, c).unwrap();
    // A static floor, and a 60 × 10 × 30 mm paddle turning at 60 rpm about the vertical line
    // through its centre, its lower face 1 mm above the floor.
    w.add_geometry(Geometry {
        name: "floor".into(),
        mesh: plane(0.19, 8),
        motion: Motion::stationary(Pose::identity()),
        material: WALL,
    })
    .unwrap();
    add_moving(
        &mut w,
        generators::cuboid(0.06, 0.01, 0.03).unwrap(),
        turning(Pose::translation(0.0, 0.0, 0.001), Vec3::zeros(), 60.0),
    );
    // 20 mm from the axis, 40° ahead of the paddle's +x arm: struck after about 30 ms.
    let angle = 40f64.to_radians();
    let x = Vec3::new(
        0.02 * angle.cos(),
        0.02 * angle.sin(),
        R - resting_overlap(R, 9.81),
    );
    w.add_particle(ball(x, Vec3::zeros(), Vec3::zeros(), R))
        .unwrap();
    w
}

/// One grain on a floor, struck by a turning paddle (its face, then sliding out along it and
/// off its end): after 0.2 s the GPU's grain is where the CPU engine's is, under both
/// integrators, and the paddle took the same loads. One grain's path is not chaotic, so the two
/// engines, f32 against f64, agree to a thousandth of the path. The same run again on the GPU
/// gives the same bits, loads included (summed in a fixed order, no float atomics).
#[test]
fn a_grain_struck_by_a_turning_paddle_moves_as_on_the_cpu_engine() {
    let Some(gpu) = common::gpu() else { return };
    for integrator in [Integrator::SymplecticEuler, Integrator::VelocityVerlet] {
        let scene = paddle_scene(integrator);
        let start = scene.particles().position[0];
        let mut cpu = scene.clone();
        let mut gpu_world = GpuWorld::new(gpu, &scene).unwrap();
        let dt = scene.config().time_step;
        let steps = (0.2 / dt).round() as u64;
        for _ in 0..steps {
            cpu.step();
        }
        gpu_world.run(steps).unwrap();
        // The paddle's loads, every step, against the CPU engine's: the impulse of its force
        // and of its torque about its axis over the run.
        let impulse = |series: &[repose_engine::world::GeometrySample]| {
            series
                .iter()
                .fold((Vec3::zeros(), Vec3::zeros()), |(f, q), s| {
                    (f + s.force * dt, q + s.torque * dt)
                })
        };
        let on_cpu = cpu.geometry_series(repose_engine::world::GeometryId(1));
        let on_gpu = gpu_world.geometry_series(1).unwrap();
        assert_eq!(on_gpu.len(), on_cpu.len());
        assert!(on_gpu.iter().zip(on_cpu).all(|(a, b)| a.time == b.time));
        let ((f_cpu, q_cpu), (f_gpu, q_gpu)) = (impulse(on_cpu), impulse(on_gpu));
        println!(
            "paddle, {integrator:?}: force impulse CPU {f_cpu:?} GPU {f_gpu:?}; torque impulse \
             CPU {q_cpu:?} GPU {q_gpu:?}"
        );
        assert!(f_cpu.norm() > 0.0 && q_cpu.z.abs() > 0.0);
        assert!(
            (f_gpu - f_cpu).norm() < 1e-3 * f_cpu.norm(),
            "{f_gpu:?} vs {f_cpu:?}"
        );
        assert!(
            (q_gpu - q_cpu).norm() < 1e-3 * q_cpu.norm(),
            "{q_gpu:?} vs {q_cpu:?}"
        );
        let p = gpu_world.particles().unwrap();
        let (x_cpu, v_cpu) = (cpu.particles().position[0], cpu.particles().velocity[0]);
        let (x_gpu, v_gpu) = (p.position[0], p.velocity[0]);
        let path = (x_cpu - start).norm();
        println!(
            "paddle, {integrator:?}: moved {path:.5} m; CPU x {x_cpu:?} v {v_cpu:?}; \
             GPU x {x_gpu:?} v {v_gpu:?}"
        );
        assert!(path > 0.01, "the paddle did not strike the grain: {path} m");
        assert!(
            (x_gpu - x_cpu).norm() < 1e-3 * path,
            "{integrator:?}: positions {:e} m apart",
            (x_gpu - x_cpu).norm()
        );
        assert!(
            (v_gpu - v_cpu).norm() < 1e-3 * v_cpu.norm().max(0.01),
            "{integrator:?}: velocities {v_gpu:?} and {v_cpu:?}"
        );
        if integrator == Integrator::SymplecticEuler {
            let bits = |w: &mut GpuWorld| -> Vec<u64> {
                let p = w.particles().unwrap();
                let mut bits: Vec<u64> = [p.position[0], p.velocity[0], p.angular_velocity[0]]
                    .iter()
                    .flat_map(|v| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
                    .collect();
                for s in w.geometry_series(1).unwrap() {
                    bits.extend(s.force.iter().chain(s.torque.iter()).map(|c| c.to_bits()));
                }
                bits
            };
            let mut again = GpuWorld::new(gpu, &scene).unwrap();
            again.run(steps).unwrap();
            let (a, b) = (bits(&mut gpu_world), bits(&mut again));
            assert_eq!(a.len() as u64, 9 + steps * 6);
            assert!(a == b, "two runs on one adapter differ");
        }
    }
}

/// Hertz's force against overlap on a moving plate whose triangles lie 0.1 m from its body
/// origin on each axis (the body frame is f32 arithmetic on vectors of that size): 1e-1 r to
/// 1e-3, 1e-3 r to 2 % (a static plate's: 1e-3 at 0.29 m, `parity::hertz_force_against_overlap`).
#[test]
fn a_moving_plate_far_from_its_origin_resolves_a_thousandth_of_a_radius() {
    let Some(gpu) = common::gpu() else { return };
    let r = 1.0e-3;
    let far = Vec3::repeat(0.1);
    // The plate lies at z = 0.1 in its body frame, centred at (0.1, 0.1); placed 0.1 m lower
    // and turning slowly about a vertical line through the body origin.
    let mesh = plane(0.01, 2)
        .transformed(&Pose::translation(far.x, far.y, far.z))
        .unwrap();
    for (overlap, tolerance) in [(1e-1 * r, 1e-3), (1e-2 * r, 2e-3), (1e-3 * r, 2e-2)] {
        let domain = Domain::closed(Vec3::new(-0.05, -0.05, -0.15), Vec3::new(0.25, 0.25, 0.05));
        let mut w = world(table(0.5, 0.5, 0.0), 1e-9, Vec3::zeros(), domain);
        add_moving(
            &mut w,
            mesh.clone(),
            turning(Pose::translation(0.0, 0.0, -0.1), Vec3::zeros(), 1e-6),
        );
        let x = Vec3::new(far.x + 1e-3, far.y - 2e-3, r - overlap);
        w.add_particle(ball(x, Vec3::zeros(), Vec3::zeros(), r))
            .unwrap();
        let mut g = GpuWorld::new(gpu, &w).unwrap();
        g.run(1).unwrap();
        let force = g.particles().unwrap().velocity[0] * (mass(r) / 1e-9);
        let expected = hertz(e_star_wall(), r, overlap);
        let error = (force.z / expected - 1.0).abs();
        println!("moving plate, overlap {overlap:e} m: {:.7e} N (Hertz {expected:.7e} N), error {error:.1e}", force.z);
        assert!(
            error < tolerance,
            "overlap {overlap:e}: {force:?} vs {expected}"
        );
        assert!(force.x.abs() + force.y.abs() < 1e-3 * force.z, "{force:?}");
    }
}
