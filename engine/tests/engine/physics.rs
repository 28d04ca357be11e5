//! Physics validation of the DEM core against analytic results.
//!
//! Each test states the analytic value it checks and its tolerance; the measured figures are
//! printed with `--nocapture` for the record.

use repose_engine::contact::RollingModel;

use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::material::{
    hertz_contact_time, Cohesion, DampingLaw, Interaction, InteractionEntry, Material, MaterialId,
    MaterialSet, MaterialTable,
};
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::TriMesh;
use repose_engine::neighbor::Domain;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, GeometryId, World, WorldConfig};

const BALL: MaterialId = MaterialId(0);
const WALL: MaterialId = MaterialId(1);
const RADIUS: f64 = 0.005;

/// Ball and wall materials with one interaction for every pair.
fn table(
    ball: Material,
    wall: Material,
    restitution: f64,
    friction: f64,
    rolling: f64,
) -> MaterialTable {
    let coefficients = Interaction {
        restitution,
        static_friction: friction,
        rolling_friction: rolling,
        cohesion: Cohesion::None,
    };
    let entry = |a: &str, b: &str| InteractionEntry {
        a: a.into(),
        b: b.into(),
        coefficients,
    };
    MaterialSet {
        damping_law: DampingLaw::default(),
        materials: vec![ball, wall],
        interactions: vec![
            entry("ball", "ball"),
            entry("ball", "wall"),
            entry("wall", "wall"),
        ],
    }
    .build()
    .expect("valid materials")
}

fn ball_material() -> Material {
    Material {
        name: "ball".into(),
        density: 2500.0,
        youngs_modulus: 1.0e8,
        poisson: 0.3,
    }
}

fn wall_material() -> Material {
    Material {
        name: "wall".into(),
        density: 7850.0,
        youngs_modulus: 2.1e11,
        poisson: 0.3,
    }
}

fn big_box() -> Domain {
    Domain::closed(Vec3::repeat(-1.0), Vec3::repeat(1.0))
}

fn config(dt: f64, gravity: Vec3, integrator: Integrator) -> WorldConfig {
    let mut c = WorldConfig::new(dt, big_box());
    c.gravity = gravity;
    c.integrator = integrator;
    c
}

fn mass(radius: f64) -> f64 {
    2500.0 * 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3)
}

/// Equivalent modulus of two identical materials.
fn e_star_same(m: &Material) -> f64 {
    m.youngs_modulus / (2.0 * (1.0 - m.poisson * m.poisson))
}

fn e_star_pair(a: &Material, b: &Material) -> f64 {
    1.0 / ((1.0 - a.poisson.powi(2)) / a.youngs_modulus
        + (1.0 - b.poisson.powi(2)) / b.youngs_modulus)
}

/// Two spheres approach head-on at `speed` each; returns (restitution, contact duration).
fn head_on(restitution: f64, speed: f64, integrator: Integrator) -> (f64, f64, World) {
    let materials = table(ball_material(), wall_material(), restitution, 0.5, 0.0);
    let tc = hertz_contact_time(
        mass(RADIUS) / 2.0,
        RADIUS / 2.0,
        e_star_same(&ball_material()),
        2.0 * speed,
    );
    let dt = tc / 400.0;
    let mut world = World::new(materials, config(dt, Vec3::zeros(), integrator)).unwrap();
    let gap = 0.2 * RADIUS;
    for (side, v) in [(-1.0, speed), (1.0, -speed)] {
        world
            .add_particle(ParticleSpec {
                position: Vec3::new(side * (RADIUS + gap / 2.0), 0.0, 0.0),
                velocity: Vec3::new(v, 0.0, 0.0),
                angular_velocity: Vec3::zeros(),
                radius: RADIUS,
                material: BALL,
            })
            .unwrap();
    }
    let mut touching_steps = 0u64;
    let mut was_touching = false;
    let mut done = false;
    for _ in 0..100_000 {
        world.step();
        let p = world.particles();
        let dist = (p.position[1] - p.position[0]).norm();
        let touching = dist < 2.0 * RADIUS;
        if touching {
            touching_steps += 1;
        }
        if was_touching && !touching {
            done = true;
            break;
        }
        was_touching = touching;
    }
    assert!(done, "collision did not finish");
    let p = world.particles();
    let (a, b) = (p.index_of(0).unwrap(), p.index_of(1).unwrap());
    let separation_speed = p.velocity[b].x - p.velocity[a].x;
    (
        separation_speed / (2.0 * speed),
        touching_steps as f64 * dt,
        world,
    )
}

#[test]
fn two_spheres_rebound_with_the_input_restitution() {
    for e in [0.2, 0.5, 0.9] {
        for integrator in [Integrator::SymplecticEuler, Integrator::VelocityVerlet] {
            let (measured, _, _) = head_on(e, 0.5, integrator);
            println!("particle-particle e input {e}: measured {measured:.4} ({integrator:?})");
            assert!(
                (measured - e).abs() < 0.02 * e,
                "e = {e}: measured {measured} ({integrator:?})"
            );
        }
    }
}

#[test]
fn hertz_contact_duration_matches_theory() {
    let speed = 0.5;
    let (_, duration, _) = head_on(1.0, speed, Integrator::VelocityVerlet);
    let expected = hertz_contact_time(
        mass(RADIUS) / 2.0,
        RADIUS / 2.0,
        e_star_same(&ball_material()),
        2.0 * speed,
    );
    println!("contact duration {duration:.6e} s, Hertz theory {expected:.6e} s");
    assert!((duration / expected - 1.0).abs() < 0.03);
}

#[test]
fn momentum_is_conserved_in_particle_collisions() {
    let (_, _, world) = head_on(0.5, 0.5, Integrator::SymplecticEuler);
    let p = world.particles();
    let momentum = p.momentum();
    let scale = mass(RADIUS) * 0.5;
    println!("momentum after collision {momentum:?} (scale {scale:e})");
    assert!(momentum.norm() < 1e-14 * scale);
}

/// A flat square plane z = 0 of `cells` × `cells` squares, each split into two triangles.
fn plane(half_width: f64, cells: usize) -> TriMesh {
    let mut vertices = Vec::new();
    let step = 2.0 * half_width / cells as f64;
    for y in 0..=cells {
        for x in 0..=cells {
            vertices.push(Vec3::new(
                -half_width + x as f64 * step,
                -half_width + y as f64 * step,
                0.0,
            ));
        }
    }
    let row = cells as u32 + 1;
    let mut triangles = Vec::new();
    for y in 0..cells as u32 {
        for x in 0..cells as u32 {
            let a = y * row + x;
            triangles.push([a, a + 1, a + row + 1]);
            triangles.push([a, a + row + 1, a + row]);
        }
    }
    TriMesh::new(vertices, triangles).unwrap()
}

fn add_plane(world: &mut World, half_width: f64, cells: usize) -> GeometryId {
    world
        .add_geometry(Geometry {
            name: "plane".into(),
            mesh: plane(half_width, cells),
            motion: Motion::stationary(Pose::identity()),
            material: WALL,
        })
        .unwrap()
}

/// Hertz overlap of a sphere of `radius` resting under its weight on the wall material.
fn resting_overlap(radius: f64, g: f64) -> f64 {
    let e_star = e_star_pair(&ball_material(), &wall_material());
    let weight = mass(radius) * g;
    (weight / (4.0 / 3.0 * e_star * radius.sqrt())).powf(2.0 / 3.0)
}

fn rayleigh_dt(fraction: f64) -> f64 {
    let materials = table(ball_material(), wall_material(), 0.5, 0.5, 0.0);
    materials.rayleigh_time_step(BALL, RADIUS, fraction)
}

#[test]
fn sphere_dropped_on_mesh_plane_rebounds_with_the_input_restitution() {
    for e in [0.2, 0.5, 0.9] {
        let materials = table(ball_material(), wall_material(), e, 0.5, 0.0);
        // As if dropped from 0.46 m; a fast impact keeps gravity's share of the rebound small.
        let impact_speed = 3.0;
        let tc = hertz_contact_time(
            mass(RADIUS),
            RADIUS,
            e_star_pair(&ball_material(), &wall_material()),
            impact_speed,
        );
        let g = Vec3::new(0.0, 0.0, -9.81);
        let mut world = World::new(
            materials,
            config(tc / 400.0, g, Integrator::SymplecticEuler),
        )
        .unwrap();
        add_plane(&mut world, 0.05, 8);
        world
            .add_particle(ParticleSpec {
                position: Vec3::new(0.001, 0.002, RADIUS + 1.0e-4),
                velocity: Vec3::new(0.0, 0.0, -impact_speed),
                angular_velocity: Vec3::zeros(),
                radius: RADIUS,
                material: BALL,
            })
            .unwrap();
        // Gravity keeps acting during the contact (lowering the rebound by up to g Δt); at 3 m/s
        // that is below 0.5 % of the rebound speed. Both ratios are printed.
        let mut before = None;
        let mut after = None;
        let mut contact_time = 0.0;
        for _ in 0..200_000 {
            let vz = world.particles().velocity[0].z;
            let touching = world.particles().position[0].z < RADIUS;
            world.step();
            let now_touching = world.particles().position[0].z < RADIUS;
            if !touching && now_touching && before.is_none() {
                before = Some(-vz);
            }
            if now_touching {
                contact_time += world.config().time_step;
            }
            if touching && !now_touching {
                after = Some(world.particles().velocity[0].z);
                break;
            }
        }
        let measured = after.unwrap() / before.unwrap();
        let without_gravity = (after.unwrap() + 9.81 * contact_time) / before.unwrap();
        println!(
            "sphere-plane e input {e}: measured {measured:.4} (plus g Δt: {without_gravity:.4}, \
             contact {contact_time:.2e} s)"
        );
        assert!((measured - e).abs() < 0.02 * e, "e = {e}: {measured}");
    }
}

#[test]
fn edem_damping_formula_rebounds_higher_because_force_is_not_attractive() {
    // Documents why DampingLaw::ExactRestitution is the default.
    use repose_engine::material::{clamped_restitution, damping_ratio, restitution_damping_ratio};
    for (e, edem) in [(0.2, 0.3249), (0.5, 0.5503), (0.9, 0.9020)] {
        let rebound = clamped_restitution(damping_ratio(e));
        println!("EDEM beta for e = {e}: clamped rebound {rebound:.4}");
        assert!((rebound - edem).abs() < 1e-3);
        assert!((clamped_restitution(restitution_damping_ratio(e)) - e).abs() < 1e-6);
    }
}

/// Runs a sphere on a many-triangle plane; returns the world.
fn sphere_on_plane(
    friction: f64,
    rolling: f64,
    model: RollingModel,
    gravity: Vec3,
    velocity: Vec3,
    angular_velocity: Vec3,
) -> World {
    let materials = table(ball_material(), wall_material(), 0.5, friction, rolling);
    let mut c = config(rayleigh_dt(0.2), gravity, Integrator::SymplecticEuler);
    c.rolling_model = model;
    let mut world = World::new(materials, c).unwrap();
    add_plane(&mut world, 0.9, 90);
    let delta = resting_overlap(RADIUS, gravity.norm());
    world
        .add_particle(ParticleSpec {
            position: Vec3::new(-0.5, 0.003, RADIUS - delta),
            velocity,
            angular_velocity,
            radius: RADIUS,
            material: BALL,
        })
        .unwrap();
    world
}

fn slip_speed(world: &World) -> f64 {
    let p = world.particles();
    let contact_arm = Vec3::new(0.0, 0.0, -RADIUS);
    (p.velocity[0] + p.angular_velocity[0].cross(&contact_arm)).norm()
}

#[test]
fn sliding_sphere_reaches_pure_rolling_at_five_sevenths_of_launch_speed() {
    let (mu, g, v0) = (0.3, 9.81, 1.0);
    let mut world = sphere_on_plane(
        mu,
        0.0,
        RollingModel::ConstantDirectionalTorque,
        Vec3::new(0.0, 0.0, -g),
        Vec3::new(v0, 0.0, 0.0),
        Vec3::zeros(),
    );
    // While sliding, the slip speed falls linearly (7/2 μ g per second); pure rolling starts
    // when it crosses zero. Find the crossing by linear interpolation between steps.
    let mut previous = (0.0, slip_speed(&world));
    let expected_time = 2.0 * v0 / (7.0 * mu * g);
    while world.time() < 2.0 * expected_time {
        world.step();
        let slip = slip_speed(&world);
        if slip < 1e-3 * v0 {
            let (t0, s0) = previous;
            let t = t0 + (world.time() - t0) * s0 / (s0 - slip);
            let v = world.particles().velocity[0].x;
            println!(
                "pure rolling at t = {t:.5} s (theory {expected_time:.5}), v = {v:.5} \
                 (theory {:.5})",
                5.0 / 7.0 * v0
            );
            assert!((t / expected_time - 1.0).abs() < 0.02);
            assert!((v / (5.0 / 7.0 * v0) - 1.0).abs() < 0.02);
            return;
        }
        previous = (world.time(), slip);
    }
    panic!("never reached pure rolling");
}

/// Deceleration of a sphere launched in pure rolling, from a linear fit of v(t) between
/// 0.05 s and 0.3 s.
fn rolling_deceleration(model: RollingModel, mu_r: f64, v0: f64) -> f64 {
    let mut world = sphere_on_plane(
        0.5,
        mu_r,
        model,
        Vec3::new(0.0, 0.0, -9.81),
        Vec3::new(v0, 0.0, 0.0),
        Vec3::new(0.0, v0 / RADIUS, 0.0),
    );
    world.run_until(0.05);
    let (t1, v1) = (world.time(), world.particles().velocity[0].x);
    world.run_until(0.3);
    let (t2, v2) = (world.time(), world.particles().velocity[0].x);
    (v2 - v1) / (t2 - t1)
}

#[test]
fn cdt_rolling_friction_decelerates_at_five_sevenths_mu_r_g() {
    // Rolling without slip on a plane, with CDT torque τ = μr Fn R against ω (Fn = m g):
    //   m dv/dt = -F (F: friction force at the contact, opposing v)
    //   I dω/dt = F R - μr m g R, and v = ω R
    // ⇒ (m + I/R²) dv/dt = -μr m g ⇒ a = -μr g / (1 + 2/5) = -(5/7) μr g.
    let mu_r = 0.1;
    let expected = -5.0 / 7.0 * mu_r * 9.81;
    let measured = rolling_deceleration(RollingModel::ConstantDirectionalTorque, mu_r, 0.5);
    println!("CDT deceleration {measured:.5} m/s² (theory {expected:.5})");
    assert!((measured / expected - 1.0).abs() < 0.02);
}

#[test]
fn epsd_rolling_friction_decelerates_at_its_plastic_limit() {
    // Fully mobilised EPSD spring: torque μr R* Fn with R* = R for a wall, so the same
    // analysis as CDT gives a = -(5/7) μr g once rolling is plastic.
    let mu_r = 0.1;
    let expected = -5.0 / 7.0 * mu_r * 9.81;
    let measured = rolling_deceleration(RollingModel::epsd(), mu_r, 0.5);
    println!("EPSD deceleration {measured:.5} m/s² (theory {expected:.5})");
    assert!((measured / expected - 1.0).abs() < 0.02);
}

/// Creep speed (m/s, down the slope) and ω sign changes of a sphere released at rest on an
/// incline with tan θ = `slope`, μs 0.5 and μr 0.2, measured from 0.1 s to 0.5 s.
fn incline_creep(model: RollingModel, slope: f64) -> (f64, u32) {
    let theta = slope.atan();
    let g = Vec3::new(9.81 * theta.sin(), 0.0, -9.81 * theta.cos());
    let mut world = sphere_on_plane(0.5, 0.2, model, g, Vec3::zeros(), Vec3::zeros());
    world.run_until(0.1);
    let x1 = world.particles().position[0].x;
    let (_, sign_changes) = omega_windows(&mut world, 0.1, 0.4, 1)[0];
    let creep = (world.particles().position[0].x - x1) / (world.time() - 0.1);
    println!(
        "{model:?}, tan θ = {slope}: creep speed {creep:.3e} m/s, ω sign changes {sign_changes}"
    );
    (creep, sign_changes)
}

#[test]
fn both_rolling_models_hold_a_sphere_on_an_incline_below_mu_r_and_cdt_lets_it_roll_above() {
    // Incline with tan θ = 0.1 below μr = 0.2: a rolling resistance of μr R Fn can hold the
    // sphere. EPSD's spring builds up the holding torque at zero ω. CDT brakes the new spin
    // (`rolling_brake`): the contact torque never exceeds the brake, so ω stays exactly 0.
    // (Until the brake was implicit, CDT's torque followed the old ω, vanished at ω = 0, and
    // the sphere crept down at ~1e-4 m/s, a speed proportional to Δt.)
    let (cdt_creep, cdt_flips) = incline_creep(RollingModel::ConstantDirectionalTorque, 0.1);
    let (epsd_creep, _) = incline_creep(RollingModel::epsd(), 0.1);
    assert!(cdt_creep.abs() < 1e-8, "CDT holds the sphere");
    assert_eq!(cdt_flips, 0, "CDT holds it without chatter");
    assert!(epsd_creep.abs() < 1e-8, "EPSD holds the sphere");
    // tan θ = 0.3 above μr: the gravity torque beats the brake and the sphere rolls away,
    // accelerating at (5/7) g (sin θ − μr cos θ); by 0.5 s it is past 1 cm/s.
    let (cdt_roll, _) = incline_creep(RollingModel::ConstantDirectionalTorque, 0.3);
    let theta = 0.3f64.atan();
    let a = 5.0 / 7.0 * 9.81 * (theta.sin() - 0.2 * theta.cos());
    // Mean speed over [0.1, 0.5] s of a sphere starting from rest at t = 0: a · 0.3 s.
    assert!(
        (cdt_roll / (a * 0.3) - 1.0).abs() < 0.05,
        "CDT rolls down at (5/7) g (sin θ − μr cos θ): {cdt_roll} vs {}",
        a * 0.3
    );
}

/// Largest |ω| and number of ω sign changes per window of `window` seconds, from `start`.
fn omega_windows(world: &mut World, start: f64, window: f64, count: usize) -> Vec<(f64, u32)> {
    world.run_until(start);
    let mut last = world.particles().angular_velocity[0].y;
    (0..count)
        .map(|k| {
            let mut max_omega: f64 = 0.0;
            let mut sign_changes = 0;
            while world.time() < start + (k + 1) as f64 * window {
                world.step();
                let w = world.particles().angular_velocity[0].y;
                max_omega = max_omega.max(w.abs());
                if w * last < 0.0 {
                    sign_changes += 1;
                }
                last = w;
            }
            (max_omega, sign_changes)
        })
        .collect()
}

#[test]
fn rolling_sphere_comes_to_rest_cdt_dead_stop_epsd_elastic_rebound() {
    // Launched in pure rolling at v0 with μr = 0.1, both models stop after v0 / (5/7 μr g).
    // CDT stops dead: the (limited) torque takes ω to 0 and, as the torque follows ω's
    // direction, nothing remains to drive the sphere; what is left (the tangential spring
    // relaxing) dies within milliseconds to round-off.
    // EPSD's rolling spring is loaded to μr R Fn when the sphere stops; it releases, rolling
    // the sphere back a little (a damped oscillation at sqrt(kr/Ir)), and the dashpot brings
    // it to rest exponentially: a smooth rest, not a step-by-step sign flip.
    let v0 = 0.05;
    let omega0 = v0 / RADIUS;
    let stop_time = v0 / (5.0 / 7.0 * 0.1 * 9.81);
    let mut windows = Vec::new();
    for model in [
        RollingModel::ConstantDirectionalTorque,
        RollingModel::epsd(),
    ] {
        let mut world = sphere_on_plane(
            0.5,
            0.1,
            model,
            Vec3::new(0.0, 0.0, -9.81),
            Vec3::new(v0, 0.0, 0.0),
            Vec3::new(0.0, omega0, 0.0),
        );
        let w = omega_windows(&mut world, stop_time + 0.005, 0.05, 4);
        println!("{model:?}: per 0.05 s after stop (max |ω| rad/s, sign changes): {w:?}");
        windows.push(w);
    }
    let (cdt, epsd) = (&windows[0], &windows[1]);
    assert!(
        cdt.iter().all(|&(w, _)| w < 1e-4 * omega0),
        "CDT stops dead"
    );
    assert!(cdt[1].0 < 1e-12 * omega0, "CDT's residue is round-off");
    assert!(
        epsd[0].0 > 1e-3 * omega0,
        "EPSD springs back after stopping"
    );
    assert!(
        epsd[3].0 < 1e-6 * omega0,
        "EPSD's spring-back is damped out"
    );
}

#[test]
fn sphere_sliding_across_triangle_edges_feels_a_smooth_normal_force() {
    let g = 9.81;
    let mut world = sphere_on_plane(
        0.0,
        0.0,
        RollingModel::ConstantDirectionalTorque,
        Vec3::new(0.0, 0.0, -g),
        Vec3::zeros(),
        Vec3::zeros(),
    );
    // Settle, then slide frictionlessly across 0.02 m triangles (edges and diagonals).
    world.run_until(0.02);
    world.particles_mut().velocity[0] = Vec3::new(0.4, 0.3, 0.0);
    world.clear_geometry_series();
    world.run_until(0.32);
    let weight = mass(RADIUS) * g;
    let series = world.geometry_series(GeometryId(0));
    let worst = series
        .iter()
        .map(|s| (-s.force.z / weight - 1.0).abs())
        .fold(0.0, f64::max);
    let travelled = world.particles().position[0].x + 0.5;
    println!(
        "slid {travelled:.3} m over {} samples: max |Fn/mg - 1| = {worst:.2e}",
        series.len()
    );
    assert!(travelled > 0.1);
    assert!(worst < 1e-3);
}

/// A gas of spheres between a floor and a ceiling, periodic in x and y.
fn gas(particles: usize, restitution: f64, friction: f64, seed: u64) -> World {
    gas_sorted(particles, restitution, friction, seed, 4)
}

fn gas_sorted(
    particles: usize,
    restitution: f64,
    friction: f64,
    seed: u64,
    sort_every_rebuilds: u32,
) -> World {
    gas_with(
        particles,
        restitution,
        friction,
        seed,
        sort_every_rebuilds,
        None,
    )
}

/// The gas, optionally with rolling friction μr = 0.2 in the given model.
fn gas_with(
    particles: usize,
    restitution: f64,
    friction: f64,
    seed: u64,
    sort_every_rebuilds: u32,
    rolling: Option<RollingModel>,
) -> World {
    use rand::{Rng, SeedableRng};
    let rolling_friction = if rolling.is_some() { 0.2 } else { 0.0 };
    let materials = table(
        ball_material(),
        wall_material(),
        restitution,
        friction,
        rolling_friction,
    );
    let size = 0.1;
    let domain = Domain {
        min: Vec3::new(0.0, 0.0, -0.01),
        max: Vec3::new(size, size, size + 0.01),
        periodic_x: true,
        periodic_y: true,
    };
    let radius = 0.003;
    let tc = hertz_contact_time(
        mass(radius) / 2.0,
        radius / 2.0,
        e_star_same(&ball_material()),
        2.0,
    );
    let mut c = WorldConfig::new(tc / 60.0, domain);
    c.gravity = Vec3::zeros();
    c.integrator = Integrator::VelocityVerlet;
    c.seed = seed;
    c.sort_every_rebuilds = sort_every_rebuilds;
    c.rolling_model = rolling.unwrap_or_default();
    let mut world = World::new(materials, c).unwrap();
    for z in [0.0, size] {
        let mut mesh = plane(0.1, 2);
        mesh = mesh
            .transformed(&Pose::translation(size / 2.0, size / 2.0, z))
            .unwrap();
        world
            .add_geometry(Geometry {
                name: "wall".into(),
                mesh,
                motion: Motion::stationary(Pose::identity()),
                material: WALL,
            })
            .unwrap();
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let per_side = (particles as f64).cbrt().ceil() as usize;
    let spacing = size / per_side as f64;
    let mut added = 0;
    'fill: for x in 0..per_side {
        for y in 0..per_side {
            for z in 0..per_side {
                if added == particles {
                    break 'fill;
                }
                let r = radius * rng.gen_range(0.8..1.0);
                let velocity = Vec3::new(
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                );
                world
                    .add_particle(ParticleSpec {
                        position: Vec3::new(
                            (x as f64 + 0.5) * spacing,
                            (y as f64 + 0.5) * spacing,
                            (z as f64 + 0.5) * spacing,
                        ),
                        velocity,
                        angular_velocity: Vec3::zeros(),
                        radius: r,
                        material: BALL,
                    })
                    .unwrap();
                added += 1;
            }
        }
    }
    world
}

/// Kinetic + Hertz elastic energy (8/15 E* sqrt(R*) δ^2.5 per contact).
fn total_energy(world: &World, size: f64) -> f64 {
    let p = world.particles();
    let mut energy = p.kinetic_energy();
    let ball = ball_material();
    let e_pp = e_star_same(&ball);
    let e_pw = e_star_pair(&ball, &wall_material());
    let image = |d: f64| d - size * (d / size).round();
    for i in 0..p.len() {
        for j in i + 1..p.len() {
            let mut d = p.position[i] - p.position[j];
            d.x = image(d.x);
            d.y = image(d.y);
            let overlap = p.radius[i] + p.radius[j] - d.norm();
            if overlap > 0.0 {
                let r_star = p.radius[i] * p.radius[j] / (p.radius[i] + p.radius[j]);
                energy += 8.0 / 15.0 * e_pp * r_star.sqrt() * overlap.powf(2.5);
            }
        }
        for wall_z in [0.0, size] {
            let overlap = p.radius[i] - (p.position[i].z - wall_z).abs();
            if overlap > 0.0 {
                energy += 8.0 / 15.0 * e_pw * p.radius[i].sqrt() * overlap.powf(2.5);
            }
        }
    }
    energy
}

#[test]
fn energy_and_momentum_are_conserved_without_dissipation() {
    let mut world = gas(300, 1.0, 0.0, 7);
    let e0 = total_energy(&world, 0.1);
    let p0 = world.particles().momentum();
    world.run_until(0.1);
    let e1 = total_energy(&world, 0.1);
    let p1 = world.particles().momentum();
    let scale = world.particles().mass.iter().sum::<f64>();
    let drift = (e1 / e0 - 1.0).abs();
    let dp = ((p1.x - p0.x).powi(2) + (p1.y - p0.y).powi(2)).sqrt() / scale;
    println!(
        "{} steps, {} rebuilds: energy drift {drift:.2e}; horizontal momentum change {dp:.2e} \
         (kg·m/s per kg)",
        world.steps(),
        world.rebuild_count()
    );
    assert!(drift < 1e-3);
    assert!(dp < 1e-13);
}

fn bed_hash(threads: usize, seed: u64) -> (u64, usize) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut world = gas(1500, 0.5, 0.5, seed);
        world.run(400);
        (world.state_hash(), world.particles().len())
    })
}

#[test]
fn results_are_bit_identical_across_thread_counts_and_runs() {
    let (one, n) = bed_hash(1, 3);
    let (two, _) = bed_hash(2, 3);
    let (again, _) = bed_hash(2, 3);
    println!("{n} particles: hash 1 thread {one:016x}, 2 threads {two:016x}, rerun {again:016x}");
    assert_eq!(one, two);
    assert_eq!(two, again);
}

/// CPU time (user + system, all threads, including finished ones) of this process so far,
/// s, from /proc/self/stat (Linux; 10 ms resolution; 0 elsewhere). On a loaded machine
/// wall-clock throughput is meaningless; CPU time is not (except for cache interference).
fn process_cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after_name = stat.rsplit(')').next().unwrap_or("");
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    let ticks = |k: usize| {
        fields
            .get(k)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // Fields 14 and 15 of stat (utime, stime) are the 12th and 13th after the name.
    (ticks(11) + ticks(12)) / 100.0
}

/// Throughput figures (run explicitly: `cargo test --release -p repose-engine --test engine physics::
/// bench_throughput -- --ignored --nocapture`; BENCH_PARTICLES, BENCH_STEPS override).
/// Prints wall-clock throughput (what `bench::time_steps` returns) and throughput per
/// CPU-second of the timed steps (warm-up included: 20 steps).
#[test]
#[ignore]
fn bench_throughput() {
    use repose_engine::bench::{settled_bed, time_steps};
    let env = |name: &str, default: u64| {
        std::env::var(name)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let particles = env("BENCH_PARTICLES", 20_000) as usize;
    let steps = env("BENCH_STEPS", 2000);
    let bed = settled_bed(particles, 1).unwrap();
    for threads in [1, 2] {
        let cpu = process_cpu_seconds();
        let r = time_steps(&bed, threads, steps);
        let cpu = process_cpu_seconds() - cpu;
        println!("{r:?}");
        println!(
            "{} particles, {threads} threads: {:.2} M particle-steps/s wall, {:.2} M per \
             CPU-second, {:.0} B/particle, {:.2} contacts/particle, {:.2} pairs/particle",
            r.particles,
            r.particle_steps_per_second / 1e6,
            r.particles as f64 * (steps + 20) as f64 / cpu / 1e6,
            r.bytes_per_particle,
            r.contacts_per_particle,
            r.pairs_per_particle
        );
    }
}

#[test]
fn material_validation_names_the_field_and_paper_values_are_expressible() {
    let mut set = MaterialSet::paper(
        Interaction {
            restitution: 0.15,
            static_friction: 0.68,
            rolling_friction: 0.40,
            cohesion: Cohesion::None,
        },
        Interaction {
            restitution: 0.6,
            static_friction: 0.3,
            rolling_friction: 0.1,
            cohesion: Cohesion::None,
        },
    );
    let json = serde_json::to_string(&set).unwrap();
    let back: MaterialSet = serde_json::from_str(&json).unwrap();
    assert_eq!(back, set);
    let table = set.build().unwrap();
    let soil = table.id("soil").unwrap();
    assert_eq!(table.material(soil).density, 2664.0);
    set.materials[0].poisson = 0.6;
    let message = set.build().unwrap_err().to_string();
    assert!(
        message.starts_with("materials.soil.poisson must be in (0, 0.5)"),
        "{message}"
    );
    set.materials[0].poisson = 0.36;
    set.interactions[1].coefficients.restitution = 0.0;
    let message = set.build().unwrap_err().to_string();
    assert!(
        message.starts_with("interactions.soil-steel.restitution must be in (0, 1]"),
        "{message}"
    );
    set.interactions.pop();
    set.interactions[1].coefficients.restitution = 0.5;
    let message = set.build().unwrap_err().to_string();
    assert!(message.contains("no interaction given for the pair (steel, steel)"));
}

#[test]
fn time_step_rules() {
    let soil = Material::paper_soil();
    // Rayleigh time of a 1 mm soil grain: π R sqrt(ρ/G) / (0.1631 ν + 0.8766).
    let g = soil.youngs_modulus / (2.0 * 1.36);
    let expected = std::f64::consts::PI * 1e-3 * (2664.0 / g).sqrt() / (0.1631 * 0.36 + 0.8766);
    let t_r = repose_engine::material::rayleigh_time(1e-3, &soil);
    assert!((t_r / expected - 1.0).abs() < 1e-12);
    // 20 % of T_R resolves a 1 m/s impact; a 10x larger step at 20 m/s does not.
    assert!(repose_engine::material::check_time_step(0.2 * t_r, 1e-3, &soil, 1.0).is_none());
    let warning =
        repose_engine::material::check_time_step(2.0 * t_r, 1e-3, &soil, 20.0).expect("warns");
    assert!(warning.steps_per_contact < 10.0);
    assert!(warning.to_string().contains("20 m/s"));
}

#[test]
fn particles_leaving_the_domain_are_removed_and_ids_stay_stable() {
    let materials = table(ball_material(), wall_material(), 0.5, 0.5, 0.0);
    let domain = Domain::closed(Vec3::repeat(-0.1), Vec3::repeat(0.1));
    let mut world = World::new(materials, WorldConfig::new(1e-5, domain)).unwrap();
    for k in 0..5 {
        let x = -0.08 + 0.04 * k as f64;
        let velocity = if k % 2 == 1 {
            Vec3::new(0.0, 0.0, -5.0)
        } else {
            Vec3::zeros()
        };
        world
            .add_particle(ParticleSpec {
                velocity,
                ..ParticleSpec::at_rest(Vec3::new(x, 0.0, 0.0), RADIUS, BALL)
            })
            .unwrap();
    }
    world.run_until(0.03);
    assert_eq!(world.removed_count(), 2);
    let mut ids = world.particles().id.clone();
    ids.sort_unstable();
    assert_eq!(ids, vec![0, 2, 4]);
    for id in [0u64, 2, 4] {
        let k = world.particles().index_of(id).unwrap();
        let x = -0.08 + 0.04 * id as f64;
        assert!((world.particles().position[k].x - x).abs() < 1e-12);
    }
}

#[test]
fn geometry_force_and_torque_about_its_reference_point() {
    // A sphere resting on a plane placed 0.1 m to the side of the plane's reference point: the
    // plane carries the weight, and the torque about the reference point is r × F.
    let g = 9.81;
    let materials = table(ball_material(), wall_material(), 0.3, 0.5, 0.0);
    let mut world = World::new(
        materials,
        config(
            rayleigh_dt(0.2),
            Vec3::new(0.0, 0.0, -g),
            Integrator::SymplecticEuler,
        ),
    )
    .unwrap();
    let id = add_plane(&mut world, 0.2, 4);
    let x = 0.1;
    world
        .add_particle(ParticleSpec::at_rest(
            Vec3::new(x, 0.0, RADIUS - resting_overlap(RADIUS, g)),
            RADIUS,
            BALL,
        ))
        .unwrap();
    world.run_until(0.05);
    let last = *world.geometry_series(id).last().unwrap();
    let weight = mass(RADIUS) * g;
    let expected_torque = Vec3::new(x, 0.0, 0.0).cross(&Vec3::new(0.0, 0.0, -weight));
    println!("plane load {:?}, torque {:?}", last.force, last.torque);
    assert!((last.force - Vec3::new(0.0, 0.0, -weight)).norm() < 1e-6 * weight);
    assert!((last.torque - expected_torque).norm() < 1e-6 * weight * x);
}

#[test]
fn a_factory_fills_particles_without_overlap_and_they_settle_in_a_box() {
    use repose_engine::distribution::{SizeDistribution, SizeDistributionSpec};
    use repose_engine::factory::{Factory, FactorySpec, ParticleSource, Region};
    let materials = table(ball_material(), wall_material(), 0.3, 0.5, 0.1);
    let dt = materials.rayleigh_time_step(BALL, 0.002, 0.2);
    let mut world = World::new(
        materials,
        config(dt, Vec3::new(0.0, 0.0, -9.81), Integrator::SymplecticEuler),
    )
    .unwrap();
    add_plane(&mut world, 0.05, 4);
    let size = SizeDistribution::new(SizeDistributionSpec::Uniform {
        min_radius: 0.002,
        max_radius: 0.003,
    })
    .unwrap();
    let spec = FactorySpec {
        region: Region::Box {
            min: Vec3::new(-0.02, -0.02, 0.01),
            max: Vec3::new(0.02, 0.02, 0.05),
        },
        mass_rate: 0.5,
        total_mass: 0.02,
        start_time: 0.0,
        velocity: Vec3::zeros(),
        size,
        max_attempts_per_particle: 100,
    };
    let factory = Factory::new(spec, 2500.0).unwrap();
    world
        .add_source(ParticleSource::Factory(factory), BALL)
        .unwrap();
    world.run_until(0.1);
    let p = world.particles();
    let inserted: f64 = p.mass.iter().sum();
    println!("{} particles, {inserted:.4} kg inserted", p.len());
    assert!(p.len() > 20);
    assert!((inserted - 0.02).abs() < 0.002);
    // No particle fell through the plane (nor was removed).
    assert_eq!(world.removed_count(), 0);
    assert!(p.position.iter().all(|x| x.z > 0.0));
}

#[test]
fn a_world_saved_mid_pour_and_restored_continues_bit_for_bit() {
    // A pour onto a mesh plate, saved while the factory is still inserting (its random stream,
    // its books, the pair and wall histories are all live), restored from the bytes and run on
    // beside the original: the two must stay identical to the last bit, on either thread count.
    use repose_engine::distribution::{SizeDistribution, SizeDistributionSpec};
    use repose_engine::factory::{Factory, FactorySpec, ParticleSource, Region};
    let materials = table(ball_material(), wall_material(), 0.3, 0.5, 0.1);
    let dt = materials.rayleigh_time_step(BALL, 0.002, 0.2);
    let mut config = config(dt, Vec3::new(0.0, 0.0, -9.81), Integrator::SymplecticEuler);
    config.seed = 7;
    let mut world = World::new(materials, config).unwrap();
    add_plane(&mut world, 0.05, 4);
    let spec = FactorySpec {
        region: Region::Box {
            min: Vec3::new(-0.02, -0.02, 0.01),
            max: Vec3::new(0.02, 0.02, 0.05),
        },
        mass_rate: 0.2,
        total_mass: 0.02,
        start_time: 0.0,
        velocity: Vec3::new(0.0, 0.0, -0.3),
        size: SizeDistribution::new(SizeDistributionSpec::Uniform {
            min_radius: 0.002,
            max_radius: 0.003,
        })
        .unwrap(),
        max_attempts_per_particle: 100,
    };
    world
        .add_source(
            ParticleSource::Factory(Factory::new(spec, 2500.0).unwrap()),
            BALL,
        )
        .unwrap();
    world.run_until(0.05);
    let touching_walls = world
        .particles()
        .position
        .iter()
        .filter(|x| x.z < 0.0031)
        .count();
    assert!(
        world.contact_count() > 0 && touching_walls > 0,
        "the save must fall while grains touch each other and the plate"
    );
    let inserted_mass = match world.sources().next() {
        Some(ParticleSource::Factory(f)) => f.inserted_mass(),
        _ => unreachable!("one factory"),
    };
    assert!(inserted_mass < 0.015, "the save must fall mid-insertion");
    let bytes = rmp_serde::to_vec(&world).unwrap();
    let mut restored: World = rmp_serde::from_slice(&bytes).unwrap();
    assert_eq!(restored.state_hash(), world.state_hash());
    world.run_until(0.15);
    rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| restored.run_until(0.15));
    assert!(world.particles().len() > 20);
    assert_eq!(restored.steps(), world.steps());
    assert_eq!(restored.state_hash(), world.state_hash());
    assert_eq!(restored.contact_count(), world.contact_count());
}

#[test]
fn sources_taken_out_and_handed_back_pour_as_if_never_taken() {
    // What a backend that serves a world's sources itself does with them (`take_sources`,
    // `clear_of_geometries`): taking them out mid-pour and handing them back changes nothing.
    use repose_engine::distribution::{SizeDistribution, SizeDistributionSpec};
    use repose_engine::factory::{Factory, FactorySpec, ParticleSource, Region};
    let materials = table(ball_material(), wall_material(), 0.3, 0.5, 0.1);
    let dt = materials.rayleigh_time_step(BALL, 0.002, 0.2);
    let mut world = World::new(
        materials,
        config(dt, Vec3::new(0.0, 0.0, -9.81), Integrator::SymplecticEuler),
    )
    .unwrap();
    add_plane(&mut world, 0.05, 4);
    let spec = FactorySpec {
        region: Region::Box {
            min: Vec3::new(-0.02, -0.02, 0.01),
            max: Vec3::new(0.02, 0.02, 0.05),
        },
        mass_rate: 0.2,
        total_mass: 0.02,
        start_time: 0.0,
        velocity: Vec3::new(0.0, 0.0, -0.3),
        size: SizeDistribution::new(SizeDistributionSpec::Fixed { radius: 0.002 }).unwrap(),
        max_attempts_per_particle: 100,
    };
    let factory = Factory::new(spec, 2500.0).unwrap();
    assert_eq!(factory.density(), 2500.0);
    world
        .add_source(ParticleSource::Factory(factory), BALL)
        .unwrap();
    world.run_until(0.03);
    let mut handed = world.clone();
    let sources = handed.take_sources();
    assert_eq!(sources.len(), 1);
    assert!(handed.sources().next().is_none() && handed.last_spawn_reports().is_empty());
    for (source, material) in sources {
        handed.add_source(source, material).unwrap();
    }
    world.run_until(0.08);
    handed.run_until(0.08);
    assert!(world.particles().len() > 10);
    assert_eq!(handed.state_hash(), world.state_hash());
    // The plate (z = 0) is within 2 mm of a centre 1 mm above it, not of one 1 cm above it.
    assert!(!world.clear_of_geometries(Vec3::new(0.0, 0.0, 0.001), 0.002));
    assert!(world.clear_of_geometries(Vec3::new(0.0, 0.0, 0.01), 0.002));
}

#[test]
fn a_factory_places_no_grain_on_one_whose_centre_lies_just_outside_its_region() {
    // The overlap test sees only the grains near the factory's region. A layer of grains with
    // their centres half a radius below the region's floor reaches into it; grains the factory
    // places on its floor must still clear them. Without gravity nothing moves unless a new
    // grain overlaps another, so after the steps that insert, every pair must be apart.
    use repose_engine::distribution::{SizeDistribution, SizeDistributionSpec};
    use repose_engine::factory::{Factory, FactorySpec, ParticleSource, Region};
    use repose_engine::particles::ParticleSpec;
    let r = 0.002;
    let materials = table(ball_material(), wall_material(), 0.3, 0.5, 0.1);
    let dt = materials.rayleigh_time_step(BALL, r, 0.2);
    let mut world = World::new(
        materials,
        config(dt, Vec3::zeros(), Integrator::SymplecticEuler),
    )
    .unwrap();
    let (floor, half) = (0.01, 0.012);
    let spacing = 2.05 * r;
    let mut x = -half - r;
    while x <= half + r {
        let mut y = -half - r;
        while y <= half + r {
            world
                .add_particle(ParticleSpec::at_rest(
                    Vec3::new(x, y, floor - 0.5 * r),
                    r,
                    BALL,
                ))
                .unwrap();
            y += spacing;
        }
        x += spacing;
    }
    let layer = world.particles().len();
    let size = SizeDistribution::new(SizeDistributionSpec::Fixed { radius: r }).unwrap();
    let spec = FactorySpec {
        region: Region::Box {
            min: Vec3::new(-half, -half, floor),
            max: Vec3::new(half, half, floor + 2.5 * r),
        },
        mass_rate: 50.0,
        total_mass: 0.05,
        start_time: 0.0,
        velocity: Vec3::zeros(),
        size,
        max_attempts_per_particle: 200,
    };
    world
        .add_source(
            ParticleSource::Factory(Factory::new(spec, 2500.0).unwrap()),
            BALL,
        )
        .unwrap();
    for _ in 0..40 {
        world.step();
    }
    let p = world.particles();
    println!("{layer} grains in the layer, {} placed", p.len() - layer);
    assert!(p.len() > layer + 10, "the factory must place grains");
    for i in layer..p.len() {
        for k in 0..p.len() {
            if k != i {
                let gap = (p.position[i] - p.position[k]).norm() - p.radius[i] - p.radius[k];
                assert!(
                    gap >= -1e-12,
                    "new grain {i} overlaps grain {k} by {:.3e} m",
                    -gap
                );
            }
        }
    }
}

#[test]
fn contact_histories_survive_rebuilds_and_resorting() {
    // Same frictional gas twice: once with the usual occasional rebuilds, once rebuilding and
    // re-sorting the particles before every step. If a tangential spring were lost or given
    // to the wrong pair at a rebuild, the runs would part at the level of the friction forces;
    // with histories carried over they agree to round-off (sums run in a different order).
    for rolling in [
        RollingModel::ConstantDirectionalTorque,
        RollingModel::epsd(),
    ] {
        histories_survive(rolling);
    }
}

fn histories_survive(rolling: RollingModel) {
    let mut usual = gas_with(200, 0.5, 0.5, 11, 4, Some(rolling));
    let mut resorted = gas_with(200, 0.5, 0.5, 11, 1, Some(rolling));
    let mut contacts = 0;
    for _ in 0..3000 {
        resorted.invalidate_neighbours();
        resorted.step();
        usual.step();
        contacts += usual.contact_count();
    }
    assert!(
        contacts > 1000,
        "the gas must collide ({contacts} contact-steps)"
    );
    let worst = (0..200u64)
        .map(|id| {
            let a = usual.particles();
            let b = resorted.particles();
            let (ka, kb) = (a.index_of(id).unwrap(), b.index_of(id).unwrap());
            (a.angular_velocity[ka] - b.angular_velocity[kb]).norm()
        })
        .fold(0.0, f64::max);
    println!(
        "{rolling:?}: {contacts} contact-steps, rebuilds {} vs {}; max |Δω| = {worst:.2e} rad/s",
        usual.rebuild_count(),
        resorted.rebuild_count()
    );
    assert!(resorted.rebuild_count() >= 3000);
    assert!(worst < 1e-6, "{worst}");
}

proptest::proptest! {
    #[test]
    fn coulomb_cap_holds_and_normal_force_never_pulls(
        overlap in 1e-7f64..1e-4,
        nx in -1.0f64..1.0, ny in -1.0f64..1.0, nz in 0.1f64..1.0,
        vx in -2.0f64..2.0, vy in -2.0f64..2.0, vz in -2.0f64..2.0,
        sx in -1e-4f64..1e-4, sy in -1e-4f64..1e-4, sz in -1e-4f64..1e-4,
        restitution in 0.1f64..1.0,
        friction in 0.0f64..1.0,
    ) {
        use repose_engine::contact::hertz_mindlin;
        use repose_engine::material::PairConstants;
        let constants = PairConstants::new(
            &ball_material(),
            &wall_material(),
            &Interaction::new(restitution, friction, 0.0),
        );
        let normal = Vec3::new(nx, ny, nz).normalize();
        let mut spring = Vec3::new(sx, sy, sz);
        let before = (spring - normal * normal.dot(&spring)).norm();
        let stored = spring.norm();
        let contact = hertz_mindlin(
            &constants, RADIUS, mass(RADIUS), overlap, normal, Vec3::new(vx, vy, vz), 0.0,
            &mut spring,
        );
        let tangential = contact.force - normal * contact.force.dot(&normal);
        proptest::prop_assert!(contact.normal_force >= 0.0);
        proptest::prop_assert!(
            tangential.norm() <= friction * contact.normal_force * (1.0 + 1e-9) + 1e-15
        );
        // With dt = 0 the spring is only rotated into the tangent plane: its length is kept
        // unless the Coulomb cap rescaled it.
        proptest::prop_assert!(spring.dot(&normal).abs() <= 1e-12 * stored.max(1e-30));
        if tangential.norm() < friction * contact.normal_force * (1.0 - 1e-9) {
            proptest::prop_assert!((spring.norm() - stored).abs() <= 1e-9 * stored);
        }
        let _ = before;
    }
}

#[test]
fn sphere_on_a_moving_belt_ends_rolling_at_two_sevenths_of_belt_speed() {
    // In the belt's frame this is the launched-sphere problem with v0 = -v_belt: pure rolling
    // at 5/7 of that after 2 v_belt / (7 μ g); in the lab frame v = v_belt - 5/7 v_belt.
    use repose_engine::kinematics::TranslationSegment;
    let (mu, g, belt) = (0.3, 9.81, 0.5);
    let materials = table(ball_material(), wall_material(), 0.5, mu, 0.0);
    let mut world = World::new(
        materials,
        config(
            rayleigh_dt(0.2),
            Vec3::new(0.0, 0.0, -g),
            Integrator::SymplecticEuler,
        ),
    )
    .unwrap();
    let motion = Motion::new(
        Pose::identity(),
        vec![TranslationSegment {
            velocity: Vec3::new(belt, 0.0, 0.0),
            start: 0.0,
            stop: 10.0,
        }],
        vec![],
    )
    .unwrap();
    world
        .add_geometry(Geometry {
            name: "belt".into(),
            mesh: plane(0.9, 45),
            motion,
            material: WALL,
        })
        .unwrap();
    world
        .add_particle(ParticleSpec::at_rest(
            Vec3::new(0.0, 0.0, RADIUS - resting_overlap(RADIUS, g)),
            RADIUS,
            BALL,
        ))
        .unwrap();
    let rolling_time = 2.0 * belt / (7.0 * mu * g);
    world.run_until(2.0 * rolling_time);
    let v = world.particles().velocity[0].x;
    let expected = 2.0 / 7.0 * belt;
    println!("sphere on belt: v = {v:.5} m/s (theory {expected:.5})");
    assert!((v / expected - 1.0).abs() < 0.02);
}

#[test]
fn an_empty_world_steps() {
    let materials = table(ball_material(), wall_material(), 0.5, 0.5, 0.1);
    for integrator in [Integrator::SymplecticEuler, Integrator::VelocityVerlet] {
        let mut world =
            World::new(materials.clone(), config(1e-5, Vec3::zeros(), integrator)).unwrap();
        add_plane(&mut world, 0.1, 2);
        world.run(10);
        assert_eq!(world.particles().len(), 0);
        assert_eq!(world.geometry_series(GeometryId(0)).len(), 10);
    }
}

/// Servo control's engine side: a plate whose motion is replaced mid-run
/// (`World::set_geometry_motion` with `Motion::translating` from its current pose) moves on from
/// where it was, carries a grain resting on it, and its load read back
/// (`World::last_geometry_sample`) is the grain's weight once it stops again.
#[test]
fn a_plate_given_a_new_velocity_mid_run_moves_on_from_where_it_was() {
    let materials = table(ball_material(), wall_material(), 0.5, 0.5, 0.0);
    let g = 9.81;
    let c = config(
        rayleigh_dt(0.2),
        Vec3::new(0.0, 0.0, -g),
        Integrator::SymplecticEuler,
    );
    let mut world = World::new(materials, c).unwrap();
    let plate = add_plane(&mut world, 0.1, 4);
    let delta = resting_overlap(RADIUS, g);
    world
        .add_particle(ParticleSpec {
            position: Vec3::new(0.01, 0.02, RADIUS - delta),
            velocity: Vec3::zeros(),
            angular_velocity: Vec3::zeros(),
            radius: RADIUS,
            material: BALL,
        })
        .unwrap();
    world.run_until(0.05);
    let z_rest = world.particles().position[0].z;
    // Up at 0.1 m/s for 0.1 s, from the pose reached so far (the identity).
    let speed = 0.1;
    let t0 = world.time();
    let pose = world.geometry(plate).motion.pose_at(t0);
    world.set_geometry_motion(
        plate,
        Motion::translating(pose, Vec3::new(0.0, 0.0, speed), t0).unwrap(),
    );
    world.run_until(t0 + 0.1);
    let t1 = world.time();
    let lifted = world.geometry(plate).motion.pose_at(t1).translation.vector;
    assert!(
        (lifted.z - speed * (t1 - t0)).abs() < 1e-12 && lifted.x == 0.0 && lifted.y == 0.0,
        "the plate is at {lifted:?}"
    );
    let z_grain = world.particles().position[0].z;
    assert!(
        (z_grain - z_rest - speed * (t1 - t0)).abs() < 0.05 * speed * (t1 - t0),
        "the grain rose {} m, the plate {} m",
        z_grain - z_rest,
        speed * (t1 - t0)
    );
    // Stop where it is; the grain comes to rest on it and weighs on it.
    let pose = world.geometry(plate).motion.pose_at(t1);
    world.set_geometry_motion(plate, Motion::translating(pose, Vec3::zeros(), t1).unwrap());
    world.run_until(t1 + 0.2);
    let stopped = world
        .geometry(plate)
        .motion
        .pose_at(world.time())
        .translation
        .vector;
    assert_eq!(stopped, lifted, "the plate moved after it was stopped");
    let load = world.last_geometry_sample(plate).unwrap();
    let weight = mass(RADIUS) * g;
    assert!(
        (load.force.z + weight).abs() < 0.01 * weight && load.force.x.abs() < 0.01 * weight,
        "load {:?}, weight {weight}",
        load.force
    );
}
