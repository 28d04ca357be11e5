//! What the shear-box test needs of the GPU: a still geometry held as a moving mesh (its loads
//! recorded).

use crate::common;
use crate::parity::{ball, mass, plane, resting_overlap, table, BALL, WALL};

use repose_engine::contact::RollingModel;
use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::math::{Pose, Vec3};
use repose_engine::neighbor::Domain;
use repose_engine::world::{Geometry, World, WorldConfig};
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
/// as a moving one does; a still geometry not listed has no loads. A movable
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
}
