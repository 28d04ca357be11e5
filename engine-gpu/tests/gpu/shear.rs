//! What the shear-box test needs of the GPU: a still geometry held as a moving mesh (its loads
//! recorded), a motion replaced during the run (`GpuWorld::set_motion`, against the CPU
//! engine's `World::set_geometry_motion`), and a slab's contact stress sums
//! (`GpuWorld::run_sampling_slab`, against the CPU's shear window on the CPU engine's
//! contacts, and a column's known answer).

use crate::common;
use crate::parity::{
    ball, e_star_same, e_star_wall, mass, plane, resting_overlap, table, BALL, WALL,
};

use repose_engine::contact::RollingModel;
use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::math::{Pose, Vec3};
use repose_engine::neighbor::Domain;
use repose_engine::world::{Geometry, GeometryId, World, WorldConfig};
use repose_engine_gpu::{Capacity, GpuError, GpuWorld, Slab, MAX_MOVERS};

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
    match GpuWorld::with_movers(gpu, &w, capacity, &[0, 2]) {
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
        GpuWorld::with_movers(gpu, &crowded, Capacity::of(&crowded), &all),
        Err(GpuError::Capacity(_))
    ));

    let mut world = GpuWorld::with_movers(gpu, &w, capacity, &[0, 0]).unwrap();
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
    let mut world = GpuWorld::with_movers(gpu, &cpu, Capacity::of(&cpu), &[0]).unwrap();
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

/// The shear window's sum (`Window::add` in `experiments/src/shear/window.rs`) over the CPU
/// engine's contacts now, in f64: Σ force on the upper grain × branch length inside the slab.
fn window_sum(world: &World, slab: &Slab) -> [f64; 3] {
    let x = &world.particles().position;
    let mut sum = [0.0; 3];
    world.for_each_contact(|c| {
        let xi = x[c.i];
        let mid = [xi.x + 0.5 * c.branch.x, xi.y + 0.5 * c.branch.y];
        if mid[0] < slab.x[0] || mid[0] >= slab.x[1] || mid[1] < slab.y[0] || mid[1] >= slab.y[1] {
            return;
        }
        let zj = xi.z + c.branch.z;
        let inside = (xi.z.max(zj).min(slab.z[1]) - xi.z.min(zj).max(slab.z[0])).max(0.0);
        if inside == 0.0 {
            return;
        }
        let on_upper = if c.branch.z >= 0.0 {
            c.force_on_j
        } else {
            -c.force_on_j
        };
        for (s, f) in sum.iter_mut().zip(on_upper.iter()) {
            *s += f * inside;
        }
    });
    sum
}

/// A small pile on the plate (velocity Verlet, restitution 0.1), stepped alike on both
/// engines: a pyramid of four spheres and one set into their pocket, and a column of three,
/// all touching at zero overlap, settling for 150 steps, then sampled every 15 steps, ten
/// times. The slab runs through the pyramid's four upper contacts and the column's lowest one;
/// the window holds two of the four (the top's, on +x) and the column. Each GPU sum is the CPU
/// window's over the CPU engine's contacts to 2e-3 of its norm (measured on lavapipe: at worst
/// 7.3e-4; f32 positions resolve ~1e-9 m of 1e-6 m overlaps in a pile still ringing) and its
/// shear component to 1e-2 of itself (at worst 1.3e-3). The plate's loads are recorded while
/// sampling, and the same run again gives the same bits.
#[test]
fn a_slab_sum_over_a_small_pile_is_the_cpu_windows() {
    let Some(gpu) = common::gpu() else { return };
    let mut cpu = box_world(0.1, 0.5, Integrator::VelocityVerlet);
    let z = resting_height();
    // The pyramid, its base's centres 2R apart around (-0.01, 0).
    let centre = Vec3::new(-0.01, 0.0, z);
    for (dx, dy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        add_ball(&mut cpu, centre + Vec3::new(dx * R, dy * R, 0.0));
    }
    add_ball(&mut cpu, centre + Vec3::new(0.0, 0.0, 2f64.sqrt() * R));
    // The column at (0.012, 0.003).
    for k in 0..3 {
        add_ball(&mut cpu, Vec3::new(0.012, 0.003, z + 2.0 * R * k as f64));
    }
    let slab = Slab {
        x: [centre.x, 0.03],
        y: [-0.03, 0.03],
        z: [1.5 * R, 2.8 * R],
    };
    let (settle, every, count) = (150, 15, 10);
    let sample = |world: &World| {
        let mut gpu_world = GpuWorld::with_movers(gpu, world, Capacity::of(world), &[0]).unwrap();
        gpu_world.run(settle).unwrap();
        let sums: Vec<[f64; 3]> = (0..count)
            .map(|_| gpu_world.run_sampling_slab(every, &slab).unwrap())
            .collect();
        let loads = gpu_world.geometry_series(0).unwrap().len() as u64;
        (sums, loads)
    };
    let (sums, loads) = sample(&cpu);
    let again = sample(&cpu).0;
    assert!(
        sums.iter()
            .zip(&again)
            .all(|(a, b)| a.map(f64::to_bits) == b.map(f64::to_bits)),
        "two runs on one adapter differ"
    );
    assert_eq!(
        loads,
        settle + every * count,
        "the plate's loads, every step"
    );
    for _ in 0..settle {
        cpu.step();
    }
    let (mut worst, mut worst_shear) = (0.0f64, 0.0f64);
    for sum in &sums {
        for _ in 0..every {
            cpu.step();
        }
        let expected = window_sum(&cpu, &slab);
        let norm = expected.iter().map(|c| c * c).sum::<f64>().sqrt();
        let error = (0..3)
            .map(|a| (sum[a] - expected[a]).powi(2))
            .sum::<f64>()
            .sqrt()
            / norm;
        let shear = (sum[0] / expected[0] - 1.0).abs();
        (worst, worst_shear) = (worst.max(error), worst_shear.max(shear));
        // The top is pushed up and back (-x) by the two base spheres on +x.
        assert!(
            expected[2] > 0.0 && expected[0] < -0.02 * expected[2],
            "{expected:?}"
        );
        assert!(
            error < 2e-3 && shear < 1e-2,
            "at {:.5} s: GPU {sum:?} N m, CPU {expected:?} N m",
            cpu.time()
        );
    }
    println!(
        "pile: {count} samples, GPU against CPU: at worst {worst:.2e} of the norm, the shear \
         component {worst_shear:.2e} of itself; the last GPU {:?} N m",
        sums.last().unwrap()
    );
}

/// A column of four spheres resting on the plate, at their Hertz overlaps: a slab 2 mm thick
/// around the second contact from the bottom, inside the branch of that contact only, sums the
/// weight of the two spheres above it times the slab's thickness, with no shear; a window
/// beside the column sums nothing. Bad slabs and no steps are refused.
#[test]
fn a_slab_across_a_resting_column_sums_the_weight_above_times_its_thickness() {
    let Some(gpu) = common::gpu() else { return };
    let mut w = box_world(0.5, 0.5, Integrator::SymplecticEuler);
    let n = 4;
    let weight = mass(R) * G;
    let hertz_overlap = |force: f64, e_star: f64, r_star: f64| {
        (force / (4.0 / 3.0 * e_star * r_star.sqrt())).powf(2.0 / 3.0)
    };
    let mut z = R - hertz_overlap(n as f64 * weight, e_star_wall(), R);
    let mut contact = 0.0;
    for k in 0..n {
        add_ball(&mut w, Vec3::new(0.002, -0.001, z));
        let above = (n - 1 - k) as f64 * weight;
        let next = z + 2.0 * R - hertz_overlap(above, e_star_same(), R / 2.0);
        if k == 1 {
            contact = 0.5 * (z + next);
        }
        z = next;
    }
    let mut world = GpuWorld::new(gpu, &w).unwrap();
    let half = 1e-3;
    let slab = Slab {
        x: [-0.03, 0.03],
        y: [-0.03, 0.03],
        z: [contact - half, contact + half],
    };
    let sum = world.run_sampling_slab(20, &slab).unwrap();
    let expected = 2.0 * weight * 2.0 * half;
    println!(
        "column: {sum:?} N m, 2 m g x thickness {expected:.6e} N m, error {:.2e}",
        sum[2] / expected - 1.0
    );
    assert!((sum[2] / expected - 1.0).abs() < 1e-3, "{sum:?}");
    assert!(sum[0].abs() + sum[1].abs() < 1e-6 * expected, "{sum:?}");
    let beside = Slab {
        x: [0.0021, 0.03],
        ..slab
    };
    let below = Slab {
        z: [0.0, 0.5 * R],
        ..slab
    };
    for other in [beside, below] {
        assert_eq!(world.run_sampling_slab(1, &other).unwrap(), [0.0; 3]);
    }
    for bad in [
        Slab {
            z: [f64::NAN, 0.01],
            ..slab
        },
        Slab {
            x: [0.01, -0.01],
            ..slab
        },
    ] {
        assert!(matches!(
            world.run_sampling_slab(1, &bad),
            Err(GpuError::Invalid(_))
        ));
    }
    assert!(matches!(
        world.run_sampling_slab(0, &slab),
        Err(GpuError::Invalid(_))
    ));
}
