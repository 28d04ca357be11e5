//! EPSD rolling (elastic-plastic spring-dashpot) on the GPU: the CPU engine's analytic checks
//! (the plastic limit's deceleration, a sphere held on an incline, the spring-back after a
//! rolling sphere stops) and a small pile against the CPU engine.

use crate::common;
use crate::parity::{
    ball, deceleration_from_50_to_200_ms, plane, resting_overlap, table, BALL, WALL,
};

use repose_engine::contact::RollingModel;
use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::math::{Pose, Vec3};
use repose_engine::neighbor::Domain;
use repose_engine::world::{Geometry, World, WorldConfig};
use repose_engine_gpu::{Gpu, GpuWorld};

const R: f64 = 0.005;

/// A 5 mm sphere resting on a 1.8 m plate under `gravity`, launched with `v` and spin `w`,
/// μs 0.5, μr `mu_r`, EPSD rolling (viscous damping 0.3): the CPU engine's world.
fn sphere_on_plane(mu_r: f64, gravity: Vec3, v: Vec3, w: Vec3) -> World {
    let materials = table(0.5, 0.5, mu_r);
    let dt = materials.rayleigh_time_step(BALL, R, 0.2);
    let domain = Domain::closed(Vec3::new(-1.0, -1.0, -0.05), Vec3::new(1.0, 1.0, 0.05));
    let mut c = WorldConfig::new(dt, domain);
    c.gravity = gravity;
    c.integrator = Integrator::SymplecticEuler;
    c.rolling_model = RollingModel::epsd();
    let mut world = World::new(materials, c).unwrap();
    world
        .add_geometry(Geometry {
            name: "plate".into(),
            mesh: plane(0.9, 30),
            motion: Motion::stationary(Pose::identity()),
            material: WALL,
        })
        .unwrap();
    let x = Vec3::new(-0.5, 0.003, R - resting_overlap(R, gravity.norm()));
    world.add_particle(ball(x, v, w, R)).unwrap();
    world
}

fn on_gpu(gpu: &Gpu, world: &World) -> GpuWorld {
    GpuWorld::new(gpu, world).unwrap()
}

/// Rolling without slip at v0 with the rolling spring fully mobilised (torque μr R Fn): the
/// same analysis as CDT's, a = -(5/7) μr g (the CPU engine's
/// `epsd_rolling_friction_decelerates_at_its_plastic_limit`).
#[test]
fn epsd_rolling_decelerates_at_five_sevenths_mu_r_g_once_plastic() {
    let Some(gpu) = common::gpu() else { return };
    let (mu_r, v0) = (0.1, 0.5);
    let scene = sphere_on_plane(
        mu_r,
        Vec3::new(0.0, 0.0, -9.81),
        Vec3::new(v0, 0.0, 0.0),
        Vec3::new(0.0, v0 / R, 0.0),
    );
    let measured = deceleration_from_50_to_200_ms(&mut on_gpu(gpu, &scene));
    let expected = -5.0 / 7.0 * mu_r * 9.81;
    println!("EPSD deceleration {measured:.5} m/s² (theory {expected:.5})");
    assert!((measured / expected - 1.0).abs() < 0.02);
}

/// A sphere released at rest on an incline with tan θ = 0.1, below μr = 0.2: the rolling
/// spring builds the holding torque at zero spin and the sphere stays (CDT would hold it too,
/// by its brake); at tan θ = 0.3 it rolls away.
#[test]
fn epsd_holds_a_sphere_on_an_incline_below_mu_r() {
    let Some(gpu) = common::gpu() else { return };
    let creep = |slope: f64| {
        let theta = f64::atan(slope);
        let g = Vec3::new(9.81 * theta.sin(), 0.0, -9.81 * theta.cos());
        let mut world = on_gpu(gpu, &sphere_on_plane(0.2, g, Vec3::zeros(), Vec3::zeros()));
        world.run_until(0.1).unwrap();
        let x1 = world.particles().unwrap().position[0].x;
        let t1 = world.time();
        world.run_until(0.2).unwrap();
        let x2 = world.particles().unwrap().position[0].x;
        (x2 - x1) / (world.time() - t1)
    };
    let (held, rolling) = (creep(0.1), creep(0.3));
    println!(
        "EPSD on an incline: tan θ 0.1 creeps {held:.2e} m/s, tan θ 0.3 rolls {rolling:.3} m/s"
    );
    // f32: the CPU engine holds it to 1e-8 m/s.
    assert!(held.abs() < 1e-6, "{held}");
    assert!(rolling > 0.01, "{rolling}");
}

/// A sphere rolling at 5 cm/s with μr 0.1 stops after v0 / (5/7 μr g); EPSD's spring, loaded
/// to μr R Fn, then rolls it back a little and its dashpot damps that out (the CPU engine's
/// `rolling_sphere_comes_to_rest_cdt_dead_stop_epsd_elastic_rebound`).
#[test]
fn epsd_springs_a_stopped_sphere_back_and_damps_it_out() {
    let Some(gpu) = common::gpu() else { return };
    let v0 = 0.05;
    let omega0 = v0 / R;
    let stop_time = v0 / (5.0 / 7.0 * 0.1 * 9.81);
    let scene = sphere_on_plane(
        0.1,
        Vec3::new(0.0, 0.0, -9.81),
        Vec3::new(v0, 0.0, 0.0),
        Vec3::new(0.0, omega0, 0.0),
    );
    let mut world = on_gpu(gpu, &scene);
    world.run_until(stop_time + 0.005).unwrap();
    // Largest |ω| in each of four 0.05 s windows, sampled every 40 steps.
    let mut windows = Vec::new();
    for k in 1..=4 {
        let end = stop_time + 0.005 + 0.05 * k as f64;
        let mut largest: f64 = 0.0;
        while world.time() < end {
            world.run(40).unwrap();
            largest = largest.max(world.particles().unwrap().angular_velocity[0].y.abs());
        }
        windows.push(largest);
    }
    println!("EPSD after the stop, max |ω| per 0.05 s: {windows:.3?} (ω0 {omega0})");
    assert!(windows[0] > 1e-3 * omega0, "the spring rolls it back");
    assert!(windows[3] < 1e-4 * omega0, "the dashpot damps that out");
}

/// Three 5 mm spheres: two resting side by side on a plate, a third in the groove between them
/// with a spin, under gravity; EPSD holds the pile. After 0.1 s every grain is where the CPU
/// engine's is (within 2 % of the top sphere's travel, and 1e-6 m), its spin within 2 %: the
/// sphere-sphere rolling springs, with the pair's reduced rolling inertia, are the CPU's.
#[test]
fn a_small_pile_with_epsd_rolling_moves_as_on_the_cpu_engine() {
    let Some(gpu) = common::gpu() else { return };
    let mut scene = sphere_on_plane(
        0.3,
        Vec3::new(0.0, 0.0, -9.81),
        Vec3::zeros(),
        Vec3::zeros(),
    );
    let base = scene.particles().position[0];
    let side = base + Vec3::new(2.0 * R + 1e-4, 0.0, 0.0);
    scene
        .add_particle(ball(side, Vec3::zeros(), Vec3::zeros(), R))
        .unwrap();
    let top = base + Vec3::new(R + 5e-5, 0.0, (3.0f64).sqrt() * R);
    scene
        .add_particle(ball(top, Vec3::zeros(), Vec3::new(0.0, 20.0, 5.0), R))
        .unwrap();
    let mut cpu = scene.clone();
    let mut gpu_world = on_gpu(gpu, &scene);
    let steps = (0.1 / scene.config().time_step).round() as u64;
    for _ in 0..steps {
        cpu.step();
    }
    gpu_world.run(steps).unwrap();
    let g = gpu_world.particles().unwrap();
    let c = cpu.particles();
    let travel = (c.position[2] - top).norm();
    println!(
        "pile after 0.1 s: top moved {travel:.3e} m; CPU x {:?} ω {:?}; GPU x {:?} ω {:?}",
        c.position[2], c.angular_velocity[2], g.position[2], g.angular_velocity[2]
    );
    for k in 0..3 {
        let dx = (g.position[k] - c.position[k]).norm();
        assert!(dx < 0.02 * travel + 1e-6, "grain {k}: {dx:e} m apart");
        let dw = (g.angular_velocity[k] - c.angular_velocity[k]).norm();
        assert!(
            dw < 0.02 * c.angular_velocity[k].norm() + 1e-3,
            "grain {k}: spins {:?} and {:?}",
            g.angular_velocity[k],
            c.angular_velocity[k]
        );
    }
}
