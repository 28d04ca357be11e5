//! What the shear-box test needs of the GPU: a still geometry held as a moving mesh (its loads
//! recorded), and a motion replaced during the run (`GpuWorld::set_motion`, against the CPU
//! engine's `World::set_geometry_motion`).

use crate::common;
use crate::parity::{ball, mass, plane, resting_overlap, table, BALL, WALL};

use repose_engine::contact::RollingModel;
use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::math::{Pose, Vec3};
use repose_engine::neighbor::Domain;
use repose_engine::world::{Geometry, GeometryId, World, WorldConfig};
use repose_engine_gpu::{Capacity, GpuError, GpuWorld, MAX_MOVERS};

const R: f64 = 0.005;
const G: f64 = 9.81;

/// A world of 5 mm grains in a 60 mm box over a still 50 mm plate at z = 0 (geometry 0), with
/// `integrator`.
fn box_world(restitution: f64, friction: f64, integrator: Integrator) -> World {
    let materials = table(restitution, friction, 0.0);
    let dt = materials.rayleigh_time_step(BALL, R, 0.2);
    let domain = Domain::closed(Vec3::new(-0.03, -0.03, -0.01), Vec3::new(0.03, 0.03, 0.05));
    let mut c = WorldConfig::new(dt, domain);
    c.gravity = Vec3::new(0.0, 0.0, -G);
    c.integrator = integrator;
    c.rolling_model = RollingModel::ConstantDirectionalTorque;
    let mut w = World::new(materials, c).unwrap();
    add_still(&mut w, "plate", plane(0.025, 4), Pose::identity());
    w
}

fn add_still(world: &mut World, name: &str, mesh: repose_engine::mesh::TriMesh, at: Pose) {
    world
        .add_geometry(Geometry {
            name: name.into(),
            mesh,
            motion: Motion::stationary(at),
            material: WALL,
        })
        .unwrap();
}

fn add_ball(world: &mut World, x: Vec3) {
    world
        .add_particle(ball(x, Vec3::zeros(), Vec3::zeros(), R))
        .unwrap();
}

/// The height above the plate of a resting sphere's centre.
fn resting_height() -> f64 {
    R - resting_overlap(R, G)
}

/// A still plate listed as movable takes the weight of the sphere resting on it, every step,
/// as a moving one does; a still geometry not listed has no loads and no new motion. A movable
/// index that is not a geometry, and more than `MAX_MOVERS` moving meshes, are refused.
#[test]
fn a_still_plate_listed_as_movable_records_the_weight_on_it() {
    let Some(gpu) = common::gpu() else { return };
    let mut w = box_world(0.5, 0.5, Integrator::SymplecticEuler);
    // A second, still plate above the box's floor (geometry 1), not listed.
    add_still(
        &mut w,
        "shelf",
        plane(0.005, 1),
        Pose::translation(0.02, 0.02, 0.04),
    );
    add_ball(&mut w, Vec3::new(0.001, -0.002, resting_height()));
    let capacity = Capacity::of(&w);
    match GpuWorld::with_movers(&gpu, &w, capacity, &[0, 2]) {
        Err(GpuError::Invalid(message)) => assert!(message.contains("geometry 2"), "{message}"),
        other => panic!("an index past the geometries: {other:?}"),
    }
    let mut crowded = w.clone();
    for k in 0..MAX_MOVERS {
        add_still(
            &mut crowded,
            "extra",
            plane(0.001, 1),
            Pose::translation(-0.02, 0.0, 0.001 * k as f64),
        );
    }
    let all: Vec<usize> = (0..crowded.geometries().len()).collect();
    assert!(matches!(
        GpuWorld::with_movers(&gpu, &crowded, Capacity::of(&crowded), &all),
        Err(GpuError::Capacity(_))
    ));

    let mut world = GpuWorld::with_movers(&gpu, &w, capacity, &[0, 0]).unwrap();
    let steps = 100;
    world.run(steps).unwrap();
    let weight = mass(R) * G;
    let series = world.geometry_series(0).unwrap();
    assert_eq!(series.len() as u64, steps, "one record a step");
    let load = series.last().unwrap().force;
    println!("a still plate listed as movable: load {load:?} N, m g = {weight:.6e} N");
    assert!((load.z / -weight - 1.0).abs() < 1e-3, "{load:?}");
    assert!(load.x.abs() + load.y.abs() < 1e-3 * weight, "{load:?}");
    assert!(matches!(
        world.geometry_series(1),
        Err(GpuError::Unsupported(_))
    ));
    let motion = Motion::translating(Pose::identity(), Vec3::x(), world.time()).unwrap();
    match world.set_motion(1, motion.clone()) {
        Err(GpuError::Unsupported(message)) => assert!(message.contains("geometry 1")),
        other => panic!("a still geometry not listed: {other:?}"),
    }
    assert!(matches!(
        world.set_motion(2, motion),
        Err(GpuError::Invalid(_))
    ));
}

/// A sphere resting on a still plate that is set translating at 0.5 m/s (velocity Verlet) is
/// dragged by friction as on the CPU engine with `World::set_geometry_motion` at the same time:
/// its velocity, spin and position agree to f32's precision. Both engines evaluate the forces
/// again with the plate's new velocity before the next step: without that evaluation the
/// sphere would gain one half step's kinetic friction less of 40 (2.5 %) here.
#[test]
fn a_plate_set_moving_during_the_run_drags_a_sphere_as_on_the_cpu_engine() {
    let Some(gpu) = common::gpu() else { return };
    let mut cpu = box_world(0.5, 0.3, Integrator::VelocityVerlet);
    add_ball(&mut cpu, Vec3::new(0.0, 0.0, resting_height()));
    let mut world = GpuWorld::with_movers(&gpu, &cpu, Capacity::of(&cpu), &[0]).unwrap();
    let (still, dragged) = (20, 20);
    for _ in 0..still {
        cpu.step();
    }
    world.run(still).unwrap();
    let t = cpu.time();
    assert_eq!(world.time(), t);
    let u = 0.5;
    let pose = cpu.geometry(GeometryId(0)).motion.pose_at(t);
    let motion = Motion::translating(pose, Vec3::new(u, 0.0, 0.0), t).unwrap();
    cpu.set_geometry_motion(GeometryId(0), motion.clone());
    world.set_motion(0, motion).unwrap();
    for _ in 0..dragged {
        cpu.step();
    }
    world.run(dragged).unwrap();
    let p = world.particles().unwrap();
    let c = cpu.particles();
    let (v, w, x) = (p.velocity[0], p.angular_velocity[0], p.position[0]);
    let (v_cpu, w_cpu, x_cpu) = (c.velocity[0], c.angular_velocity[0], c.position[0]);
    let sliding = 0.3 * G * (cpu.time() - t);
    println!(
        "set moving: GPU v {v:?} w {w:?}; CPU v {v_cpu:?} w {w_cpu:?}; mu g t {sliding:.4e} m/s"
    );
    // Dragged along +x (slipping all along: 2 u / (7 mu g) is 50 ms).
    assert!(v_cpu.x > 0.5 * sliding, "{v_cpu:?}");
    assert!((v.x / v_cpu.x - 1.0).abs() < 1e-3, "{v:?} vs {v_cpu:?}");
    assert!(
        (w - w_cpu).norm() < 1e-3 * w_cpu.norm(),
        "{w:?} vs {w_cpu:?}"
    );
    // Vertically the GPU's sphere rings by a few µm/s: its resting height is rounded to the
    // f32 offset's resolution, 5e-10 m of a 1.4e-6 m overlap.
    assert!(v.y.abs() < 1e-9 && v.z.abs() < 1e-5, "{v:?}");
    let moved = x_cpu.x;
    println!("set moving: GPU moved {:.6e} m, CPU {moved:.6e} m", x.x);
    assert!((x.x / moved - 1.0).abs() < 1e-3, "{x:?} vs {x_cpu:?}");
    let load = world.geometry_series(0).unwrap().last().unwrap().force;
    let load_cpu = cpu.geometry_series(GeometryId(0)).last().unwrap().force;
    assert!(
        (load - load_cpu).norm() < 1e-3 * load_cpu.norm(),
        "{load:?} vs {load_cpu:?}"
    );
}
