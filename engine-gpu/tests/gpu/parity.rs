//! The CPU engine's analytic checks on the GPU backend: Hertz force against overlap (anywhere
//! in a 0.3 m domain), restitution of normal impacts (sphere-sphere, sphere-plane), a sphere
//! on a triangle's face, edge and corner, sliding to rolling at 5/7 of the launch speed, CDT
//! rolling deceleration. f32 state: each test states its tolerance.

use crate::common;

use repose_engine::contact::RollingModel;
use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::material::{
    hertz_contact_time, Cohesion, DampingLaw, Interaction, InteractionEntry, Material, MaterialId,
    MaterialSet, MaterialTable,
};
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::{generators, TriMesh};
use repose_engine::neighbor::Domain;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, World, WorldConfig};
use repose_engine_gpu::{Gpu, GpuWorld};

pub(crate) const BALL: MaterialId = MaterialId(0);
pub(crate) const WALL: MaterialId = MaterialId(1);

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

pub(crate) fn table(restitution: f64, friction: f64, rolling: f64) -> MaterialTable {
    table_with(restitution, friction, rolling, Cohesion::None)
}

pub(crate) fn table_with(
    restitution: f64,
    friction: f64,
    rolling: f64,
    cohesion: Cohesion,
) -> MaterialTable {
    let coefficients = Interaction {
        restitution,
        static_friction: friction,
        rolling_friction: rolling,
        cohesion,
    };
    let entry = |a: &str, b: &str| InteractionEntry {
        a: a.into(),
        b: b.into(),
        coefficients,
    };
    MaterialSet {
        damping_law: DampingLaw::default(),
        materials: vec![ball_material(), wall_material()],
        interactions: vec![
            entry("ball", "ball"),
            entry("ball", "wall"),
            entry("wall", "wall"),
        ],
    }
    .build()
    .unwrap()
}

pub(crate) fn mass(radius: f64) -> f64 {
    2500.0 * 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3)
}

pub(crate) fn e_star_same() -> f64 {
    let m = ball_material();
    m.youngs_modulus / (2.0 * (1.0 - m.poisson * m.poisson))
}

pub(crate) fn e_star_wall() -> f64 {
    let (a, b) = (ball_material(), wall_material());
    1.0 / ((1.0 - a.poisson.powi(2)) / a.youngs_modulus
        + (1.0 - b.poisson.powi(2)) / b.youngs_modulus)
}

pub(crate) fn world(materials: MaterialTable, dt: f64, gravity: Vec3, domain: Domain) -> World {
    let mut c = WorldConfig::new(dt, domain);
    c.gravity = gravity;
    c.integrator = Integrator::SymplecticEuler;
    c.rolling_model = RollingModel::ConstantDirectionalTorque;
    World::new(materials, c).unwrap()
}

pub(crate) fn ball(
    position: Vec3,
    velocity: Vec3,
    angular_velocity: Vec3,
    radius: f64,
) -> ParticleSpec {
    ParticleSpec {
        position,
        velocity,
        angular_velocity,
        radius,
        material: BALL,
    }
}

fn add_mesh(world: &mut World, mesh: TriMesh) {
    world
        .add_geometry(Geometry {
            name: "wall".into(),
            mesh,
            motion: Motion::stationary(Pose::identity()),
            material: WALL,
        })
        .unwrap();
}

/// A square plane z = 0 of 2 × cells² triangles (the engine's generator).
pub(crate) fn plane(half_width: f64, cells: usize) -> TriMesh {
    generators::plane(2.0 * half_width, 2.0 * half_width, cells, cells).unwrap()
}

/// The force on particle `k` during the first step from rest: m Δv / Δt.
pub(crate) fn first_step_force(gpu: &Gpu, world: &World, k: usize) -> Vec3 {
    let mut w = GpuWorld::new(gpu, world).unwrap();
    w.run(1).unwrap();
    let p = w.particles().unwrap();
    p.velocity[k] * (world.particles().mass[k] / world.config().time_step)
}

pub(crate) fn hertz(e_star: f64, r_star: f64, overlap: f64) -> f64 {
    4.0 / 3.0 * e_star * r_star.sqrt() * overlap.powf(1.5)
}

#[test]
fn hertz_force_against_overlap_anywhere_in_a_03_m_domain() {
    let Some(gpu) = common::gpu() else { return };
    let r = 1.0e-3;
    let domain = Domain::closed(Vec3::zeros(), Vec3::repeat(0.3));
    // Near the far corner, where an f32 position resolves only ~3e-8 m (3 % of the smallest
    // overlap here): voxel + offset keeps the overlap exact to ~1e-10 m.
    let origin = Vec3::repeat(0.29);
    for fraction in [1e-3, 1e-2, 1e-1] {
        let overlap = fraction * r;
        let mut w = world(table(0.5, 0.5, 0.0), 1e-7, Vec3::zeros(), domain);
        w.add_particle(ball(origin, Vec3::zeros(), Vec3::zeros(), r))
            .unwrap();
        let other = origin + Vec3::new(2.0 * r - overlap, 0.0, 0.0);
        w.add_particle(ball(other, Vec3::zeros(), Vec3::zeros(), r))
            .unwrap();
        let f = first_step_force(gpu, &w, 0);
        let expected = hertz(e_star_same(), r / 2.0, overlap);
        println!(
            "overlap {fraction:e} r: GPU {:.6e} N, Hertz {expected:.6e} N",
            -f.x
        );
        assert!(
            (-f.x / expected - 1.0).abs() < 1e-3,
            "overlap {fraction:e} r: {} vs {expected}",
            -f.x
        );
        assert!(f.y.abs() < 1e-6 * expected && f.z.abs() < 1e-6 * expected);
    }
}

/// Linear (SJKR) cohesion, the CPU engine's law: the first-step force of two touching spheres,
/// and of a sphere on a triangle's face, drops by k π a² along the normal (a² the squared radius
/// of the circle where the undeformed bodies cut (JKR: `jkr::`).
#[test]
fn linear_cohesion_pulls_with_k_times_the_area_where_the_bodies_cut() {
    let Some(gpu) = common::gpu() else { return };
    let (r, k) = (1.0e-3, 2.0e5);
    let domain = Domain::closed(Vec3::repeat(-0.05), Vec3::repeat(0.05));
    let pi = std::f64::consts::PI;
    // The pull: the first-step force without cohesion minus the one with it.
    let pull = |add: &dyn Fn(&mut World)| {
        let force = |cohesion| {
            let mut w = world(
                table_with(0.5, 0.5, 0.0, cohesion),
                1e-8,
                Vec3::zeros(),
                domain,
            );
            add(&mut w);
            first_step_force(gpu, &w, 0)
        };
        force(Cohesion::None) - force(Cohesion::Linear { energy_density: k })
    };
    let at_rest = |w: &mut World, centre: Vec3| {
        w.add_particle(ball(centre, Vec3::zeros(), Vec3::zeros(), r))
            .unwrap();
    };
    for fraction in [1e-3, 1e-2, 1e-1] {
        let overlap = fraction * r;
        let dist = 2.0 * r - overlap;
        // Two spheres along x: the first is pulled towards the second, +x.
        let spheres = -pull(&|w| {
            at_rest(w, Vec3::zeros());
            at_rest(w, Vec3::new(dist, 0.0, 0.0));
        });
        let a2 = overlap * (2.0 * r - overlap).powi(2) * (4.0 * r - overlap) / (4.0 * dist * dist);
        // A sphere on a triangle's face (z = 0), from above: pulled down, -z.
        let face = pull(&|w| {
            add_mesh(w, plane(0.02, 1));
            at_rest(w, Vec3::new(0.001, 0.002, r - overlap));
        });
        for (name, along, expected) in [
            ("spheres", spheres.x, k * pi * a2),
            ("face", face.z, k * pi * overlap * (2.0 * r - overlap)),
        ] {
            println!("{name}, overlap {fraction:e} r: pull {along:.6e} N, k π a² {expected:.6e} N");
            assert!(
                (along / expected - 1.0).abs() < 1e-3,
                "{name}: {along} vs {expected}"
            );
        }
        assert!(spheres.y.abs() < 1e-6 * spheres.x && spheres.z.abs() < 1e-6 * spheres.x);
    }
}

/// A sphere over a box's top face near its edge, close enough that the side face's closest
/// point (the edge) is within its radius at 45° from the top's normal (past the merging angle):
/// the CPU engine keeps the top face's contact only (the edge is not a local minimum of the
/// distance over the triangles sharing it: the top face reaches closer), and so does the GPU.
/// Near a vertex of the top face (two triangles' diagonal) the same holds for the corner.
#[test]
fn a_sphere_over_a_boxs_edge_feels_the_top_face_only_as_on_the_cpu() {
    let Some(gpu) = common::gpu() else { return };
    let r = 2.0e-3;
    let domain = Domain::closed(Vec3::repeat(-0.05), Vec3::repeat(0.05));
    // The cuboid's top at z = 0.02, its +x side at x = 0.01. The centre is 0.45 r inside the
    // side and 0.55 r above the top: the top's overlap is 0.45 r, the edge is 0.711 r away.
    let cases = [
        ("edge", Vec3::new(0.01 - 0.45 * r, 0.003, 0.02 + 0.55 * r)),
        (
            "corner",
            Vec3::new(0.01 - 0.45 * r, 0.01 - 0.45 * r, 0.02 + 0.55 * r),
        ),
    ];
    for (name, centre) in cases {
        let mut w = world(table(0.5, 0.5, 0.0), 1e-8, Vec3::zeros(), domain);
        add_mesh(&mut w, generators::cuboid(0.02, 0.02, 0.02).unwrap());
        w.add_particle(ball(centre, Vec3::zeros(), Vec3::zeros(), r))
            .unwrap();
        let on_gpu = first_step_force(gpu, &w, 0);
        w.step();
        let p = w.particles();
        let on_cpu = p.velocity[0] * (p.mass[0] / w.config().time_step);
        let expected = hertz(e_star_wall(), r, 0.45 * r);
        println!("{name}: GPU {on_gpu:?}, CPU {on_cpu:?}, Hertz on the top {expected:.6e} N");
        assert!(
            (on_cpu.z / expected - 1.0).abs() < 1e-6,
            "{name}: CPU {on_cpu:?}"
        );
        assert!(
            (on_gpu - on_cpu).norm() < 1e-3 * expected,
            "{name}: GPU {on_gpu:?} against the CPU's {on_cpu:?}"
        );
    }
}

#[test]
fn a_sphere_on_a_triangle_face_edge_and_corner_feels_hertz_along_the_contact_normal() {
    let Some(gpu) = common::gpu() else { return };
    let r = 2.0e-3;
    let overlap = 1e-2 * r;
    let domain = Domain::closed(Vec3::repeat(-0.05), Vec3::repeat(0.05));
    // The triangle (0,0,0) (0.02,0,0) (0,0.02,0); the sphere touches, at `overlap`,
    // the face from above, the hypotenuse edge from outside (in the plane), the corner at
    // the origin from below-left.
    let edge_normal = Vec3::new(1.0, 1.0, 0.0).normalize();
    let corner_normal = Vec3::new(-1.0, -1.0, -1.0).normalize();
    let cases = [
        ("face", Vec3::new(0.005, 0.005, 0.0), Vec3::z()),
        ("edge", Vec3::new(0.01, 0.01, 0.0), edge_normal),
        ("corner", Vec3::zeros(), corner_normal),
    ];
    for (name, point, normal) in cases {
        let mut w = world(table(0.5, 0.5, 0.0), 1e-8, Vec3::zeros(), domain);
        let triangle = TriMesh::new(
            vec![
                Vec3::zeros(),
                Vec3::new(0.02, 0.0, 0.0),
                Vec3::new(0.0, 0.02, 0.0),
            ],
            vec![[0, 1, 2]],
        )
        .unwrap();
        add_mesh(&mut w, triangle);
        let centre = point + normal * (r - overlap);
        w.add_particle(ball(centre, Vec3::zeros(), Vec3::zeros(), r))
            .unwrap();
        let f = first_step_force(gpu, &w, 0);
        let expected = hertz(e_star_wall(), r, overlap);
        println!("{name}: |F| {:.6e} N, Hertz {expected:.6e} N", f.norm());
        assert!((f.norm() / expected - 1.0).abs() < 1e-3, "{name}: {f:?}");
        assert!(
            f.normalize().dot(&normal) > 1.0 - 1e-6,
            "{name}: direction {f:?}"
        );
    }
}

/// Runs `w` in blocks of `block` steps until `done(particles)`, at most `max` steps.
pub(crate) fn run_until(
    gpu_world: &mut GpuWorld,
    block: u64,
    max: u64,
    mut done: impl FnMut(&repose_engine_gpu::GpuParticles, f64) -> bool,
) {
    while gpu_world.steps() < max {
        gpu_world.run(block).unwrap();
        let p = gpu_world.particles().unwrap();
        if done(&p, gpu_world.time()) {
            return;
        }
    }
    panic!("not done after {max} steps");
}

#[test]
fn two_spheres_rebound_with_the_input_restitution() {
    let Some(gpu) = common::gpu() else { return };
    let r = 0.005;
    let speed = 0.5;
    for e in [0.2, 0.5, 0.9] {
        let tc = hertz_contact_time(mass(r) / 2.0, r / 2.0, e_star_same(), 2.0 * speed);
        let dt = tc / 400.0;
        let domain = Domain::closed(Vec3::repeat(-0.1), Vec3::repeat(0.1));
        let mut w = world(table(e, 0.5, 0.0), dt, Vec3::zeros(), domain);
        let gap = 0.2 * r;
        for (side, v) in [(-1.0, speed), (1.0, -speed)] {
            let x = Vec3::new(side * (r + gap / 2.0), 0.0, 0.0);
            w.add_particle(ball(x, Vec3::new(v, 0.0, 0.0), Vec3::zeros(), r))
                .unwrap();
        }
        let mut g = GpuWorld::new(gpu, &w).unwrap();
        let mut touched = false;
        run_until(&mut g, 20, 100_000, |p, _| {
            let touching = (p.position[1] - p.position[0]).norm() < 2.0 * r;
            touched |= touching;
            touched && !touching
        });
        let p = g.particles().unwrap();
        let measured = (p.velocity[1].x - p.velocity[0].x) / (2.0 * speed);
        println!("sphere-sphere e {e}: GPU {measured:.5}");
        assert!((measured - e).abs() < 0.02 * e, "e = {e}: {measured}");
    }
}

#[test]
fn a_sphere_dropped_on_a_plane_rebounds_with_the_input_restitution() {
    let Some(gpu) = common::gpu() else { return };
    let r = 0.005;
    let impact = 3.0;
    for e in [0.2, 0.5, 0.9] {
        let tc = hertz_contact_time(mass(r), r, e_star_wall(), impact);
        let domain = Domain::closed(Vec3::repeat(-0.06), Vec3::repeat(0.06));
        // No gravity: the rebound speed is the impact's times e exactly.
        let mut w = world(table(e, 0.5, 0.0), tc / 400.0, Vec3::zeros(), domain);
        add_mesh(&mut w, plane(0.05, 8));
        let x = Vec3::new(0.001, 0.002, r + 1.0e-4);
        w.add_particle(ball(x, Vec3::new(0.0, 0.0, -impact), Vec3::zeros(), r))
            .unwrap();
        let mut g = GpuWorld::new(gpu, &w).unwrap();
        let mut touched = false;
        run_until(&mut g, 20, 100_000, |p, _| {
            let touching = p.position[0].z < r;
            touched |= touching;
            touched && !touching
        });
        let measured = g.particles().unwrap().velocity[0].z / impact;
        println!("sphere-plane e {e}: GPU {measured:.5}");
        assert!((measured - e).abs() < 0.02 * e, "e = {e}: {measured}");
    }
}

pub(crate) fn resting_overlap(r: f64, g: f64) -> f64 {
    (mass(r) * g / (4.0 / 3.0 * e_star_wall() * r.sqrt())).powf(2.0 / 3.0)
}

/// A sphere of radius 5 mm resting on a 90-cell plane, launched with `v` and `w`.
fn sphere_on_plane(gpu: &Gpu, friction: f64, rolling: f64, v: Vec3, w: Vec3) -> GpuWorld {
    let r = 0.005;
    let materials = table(0.5, friction, rolling);
    let dt = materials.rayleigh_time_step(BALL, r, 0.2);
    let domain = Domain::closed(Vec3::new(-1.0, -1.0, -0.05), Vec3::new(1.0, 1.0, 0.05));
    let mut world = world(materials, dt, Vec3::new(0.0, 0.0, -9.81), domain);
    add_mesh(&mut world, plane(0.9, 30));
    let x = Vec3::new(-0.5, 0.003, r - resting_overlap(r, 9.81));
    world.add_particle(ball(x, v, w, r)).unwrap();
    GpuWorld::new(gpu, &world).unwrap()
}

#[test]
fn a_sliding_sphere_reaches_pure_rolling_at_five_sevenths_of_its_launch_speed() {
    let Some(gpu) = common::gpu() else { return };
    let (mu, g, v0, r) = (0.3, 9.81, 1.0, 0.005);
    let mut world = sphere_on_plane(gpu, mu, 0.0, Vec3::new(v0, 0.0, 0.0), Vec3::zeros());
    let slip = |p: &repose_engine_gpu::GpuParticles| {
        (p.velocity[0] + p.angular_velocity[0].cross(&Vec3::new(0.0, 0.0, -r))).x
    };
    let expected_time = 2.0 * v0 / (7.0 * mu * g);
    let (t, v) = when_slip_ends(&mut world, v0, slip);
    println!(
        "pure rolling at {t:.5} s (theory {expected_time:.5}), v {v:.5} (theory {:.5})",
        5.0 / 7.0 * v0
    );
    assert!((t / expected_time - 1.0).abs() < 0.02);
    assert!((v / (5.0 / 7.0 * v0) - 1.0).abs() < 0.02);
}

/// The time (interpolated between blocks of 10 steps) at which `slip`, starting at
/// `initial`, has come within a thousandth of it to zero, and the grain's x velocity then.
pub(crate) fn when_slip_ends(
    world: &mut GpuWorld,
    initial: f64,
    slip: impl Fn(&repose_engine_gpu::GpuParticles) -> f64,
) -> (f64, f64) {
    let mut previous = (0.0, initial);
    let mut crossing = None;
    run_until(world, 10, 1_000_000, |p, t| {
        let s = slip(p);
        if s.abs() < 1e-3 * initial.abs() || s * initial < 0.0 {
            let (t0, s0) = previous;
            crossing = Some((t0 + (t - t0) * s0 / (s0 - s), p.velocity[0].x));
            return true;
        }
        previous = (t, s);
        false
    });
    crossing.unwrap()
}

/// Grain 0's mean x acceleration from 0.05 s to 0.2 s, m/s².
pub(crate) fn deceleration_from_50_to_200_ms(world: &mut GpuWorld) -> f64 {
    world.run_until(0.05).unwrap();
    let (t1, v1) = (world.time(), world.particles().unwrap().velocity[0].x);
    world.run_until(0.2).unwrap();
    let (t2, v2) = (world.time(), world.particles().unwrap().velocity[0].x);
    (v2 - v1) / (t2 - t1)
}

#[test]
fn cdt_rolling_friction_decelerates_at_five_sevenths_mu_r_g() {
    let Some(gpu) = common::gpu() else { return };
    let (mu_r, v0, r) = (0.1, 0.5, 0.005);
    let mut world = sphere_on_plane(
        gpu,
        0.5,
        mu_r,
        Vec3::new(v0, 0.0, 0.0),
        Vec3::new(0.0, v0 / r, 0.0),
    );
    let measured = deceleration_from_50_to_200_ms(&mut world);
    let expected = -5.0 / 7.0 * mu_r * 9.81;
    println!("CDT deceleration {measured:.5} m/s² (theory {expected:.5})");
    assert!((measured / expected - 1.0).abs() < 0.02);
}

#[test]
fn a_colliding_cloud_conserves_momentum_to_f32_rounding() {
    use rand::{Rng, SeedableRng};
    let Some(gpu) = common::gpu() else { return };
    let r = 1.0e-3;
    let domain = Domain::closed(Vec3::repeat(-0.05), Vec3::repeat(0.05));
    let materials = table(0.5, 0.5, 0.1);
    let dt = materials.rayleigh_time_step(BALL, r, 0.2);
    let mut w = world(materials, dt, Vec3::zeros(), domain);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    // A dense 8 × 8 × 8 lattice with random velocities: thousands of collisions, no walls.
    for x in 0..8 {
        for y in 0..8 {
            for z in 0..8 {
                let centre = Vec3::new(x as f64, y as f64, z as f64) * (2.05 * r);
                let v = Vec3::from_fn(|_, _| rng.gen_range(-0.2..0.2));
                w.add_particle(ball(centre, v, Vec3::zeros(), r)).unwrap();
            }
        }
    }
    let momentum = |v: &[Vec3]| v.iter().fold(Vec3::zeros(), |s, v| s + v);
    let start = momentum(&w.particles().velocity);
    let scale: f64 = w.particles().velocity.iter().map(|v| v.norm()).sum();
    let mut g = GpuWorld::new(gpu, &w).unwrap();
    g.run(2000).unwrap();
    let p = g.particles().unwrap();
    assert!(p.removed.iter().all(|r| !r));
    assert!(p.contacts.iter().sum::<u32>() > 0 || g.counters().unwrap().rebuilds > 1);
    let drift = (momentum(&p.velocity) - start).norm() / scale;
    println!("momentum drift {drift:.2e} of the summed speeds over 2000 steps");
    // Both particles of a pair apply the same bits with opposite signs: what remains is the
    // rounding of the f32 velocity updates.
    assert!(drift < 1e-5, "momentum drift {drift:e}");
}

/// The triangles reach a grain through the grid's voxel lists: a grain resting on a plate of
/// 2 × 32 × 32 triangles (binned into many voxels, the grain touching several facets, on a
/// facet's face, on a shared edge, on a shared corner) feels the force it feels on a plate of
/// two triangles, to f32 rounding.
#[test]
fn a_grain_on_a_finely_meshed_plate_feels_what_it_feels_on_two_triangles() {
    let Some(gpu) = common::gpu() else { return };
    let r = 2.0e-3;
    let half = 0.04;
    let cell = 2.0 * half / 32.0;
    let overlap = 1e-2 * r;
    let domain = Domain::closed(Vec3::new(-0.05, -0.05, -0.01), Vec3::new(0.05, 0.05, 0.01));
    // On a fine facet's face, on a fine edge (x = a grid line), on a fine corner, and on the
    // coarse plate's diagonal; with a sideways velocity and spin so the tangential force and
    // torque enter too.
    let spots = [
        ("face", Vec3::new(0.3 * cell, 0.6 * cell, 0.0)),
        ("edge", Vec3::new(3.0 * cell, 0.45 * cell, 0.0)),
        ("corner", Vec3::new(-5.0 * cell, 7.0 * cell, 0.0)),
        ("diagonal", Vec3::new(0.011, 0.011, 0.0)),
    ];
    for (name, spot) in spots {
        let measure = |cells: usize| {
            let mut w = world(
                table(0.5, 0.5, 0.1),
                1e-6,
                Vec3::new(0.0, 0.0, -9.81),
                domain,
            );
            add_mesh(&mut w, plane(half, cells));
            let centre = spot + Vec3::new(0.0, 0.0, r - overlap);
            w.add_particle(ball(
                centre,
                Vec3::new(0.01, -0.02, 0.0),
                Vec3::new(1.0, 2.0, 0.5),
                r,
            ))
            .unwrap();
            let mut g = GpuWorld::new(gpu, &w).unwrap();
            g.run(3).unwrap();
            let p = g.particles().unwrap();
            let start = w.particles();
            (
                p.velocity[0] - start.velocity[0],
                p.angular_velocity[0] - start.angular_velocity[0],
            )
        };
        let (v_fine, w_fine) = measure(32);
        let (v_coarse, w_coarse) = measure(1);
        let dv = (v_fine - v_coarse).norm();
        let dw = (w_fine - w_coarse).norm();
        println!(
            "{name}: Δv fine {:.7e} coarse {:.7e} m/s (differ by {dv:.2e}); Δω fine {:.7e} \
             coarse {:.7e} rad/s (differ by {dw:.2e})",
            v_fine.norm(),
            v_coarse.norm(),
            w_fine.norm(),
            w_coarse.norm()
        );
        // An overlap of 1 % of the radius: ~0.6 N, a velocity change of ~0.02 m/s over the three
        // steps, with friction and rolling friction. The two plates' triangles start at other
        // corners, so the grain's offset from them rounds differently in f32: agree to 1e-4.
        // The spin is more sensitive: the lever arm's in-plane part, zero in exact arithmetic,
        // rounds to ~4e-9 m against a corner 4 cm away (the coarse plate), and the 0.6 N normal
        // force on it turns the spin by ~5e-5 rad/s in three steps (of a ~2 rad/s change).
        assert!(
            v_coarse.norm() > 1e-2,
            "{name}: the plate is not felt: {v_coarse:?}"
        );
        assert!(w_coarse.norm() > 1.0, "{name}: no torque: {w_coarse:?}");
        assert!(
            dv < 1e-4 * v_coarse.norm(),
            "{name}: {v_fine:?} vs {v_coarse:?}"
        );
        assert!(
            dw < 5e-4 * w_coarse.norm(),
            "{name}: {w_fine:?} vs {w_coarse:?}"
        );
    }
}

/// The kernels are made for the scene's laws: a world whose pairs have no cohesion leaves JKR's
/// and linear cohesion's code out of them (pipeline-overridable constants). That only removes
/// code: a cloud falling onto a plate steps to the same bits as in a world whose material table
/// also holds a sticky material (JKR against the grains, linear against itself) that no grain
/// or wall is made of, whose kernels keep that code.
#[test]
fn a_law_no_pair_uses_is_left_out_of_the_kernels_and_changes_no_bit() {
    let Some(gpu) = common::gpu() else { return };
    let r = 1.0e-3;
    let plain = table(0.5, 0.5, 0.1);
    let entry = |a: &str, b: &str, cohesion: Cohesion| InteractionEntry {
        a: a.into(),
        b: b.into(),
        coefficients: Interaction {
            restitution: 0.5,
            static_friction: 0.5,
            rolling_friction: 0.1,
            cohesion,
        },
    };
    let sticky = MaterialSet {
        damping_law: DampingLaw::default(),
        materials: vec![
            ball_material(),
            wall_material(),
            Material {
                name: "sticky".into(),
                ..ball_material()
            },
        ],
        interactions: vec![
            entry("ball", "ball", Cohesion::None),
            entry("ball", "wall", Cohesion::None),
            entry("wall", "wall", Cohesion::None),
            entry(
                "ball",
                "sticky",
                Cohesion::Jkr {
                    surface_energy: 0.5,
                },
            ),
            entry("wall", "sticky", Cohesion::None),
            entry(
                "sticky",
                "sticky",
                Cohesion::Linear {
                    energy_density: 1e4,
                },
            ),
        ],
    }
    .build()
    .unwrap();
    assert_eq!(sticky.id("ball"), Some(BALL));
    let dt = plain.rayleigh_time_step(BALL, r, 0.2);
    let domain = Domain::closed(Vec3::repeat(-0.02), Vec3::repeat(0.02));
    let state = |materials: MaterialTable| {
        let mut w = world(materials, dt, Vec3::new(0.0, 0.0, -9.81), domain);
        add_mesh(&mut w, plane(0.015, 4));
        for x in 0..4 {
            for y in 0..4 {
                for z in 0..4 {
                    let centre = Vec3::new(x as f64 - 1.5, y as f64 - 1.5, z as f64 + 0.6)
                        * (2.05 * r)
                        + Vec3::new(1e-4 * z as f64, 0.0, 0.0);
                    w.add_particle(ball(centre, Vec3::zeros(), Vec3::zeros(), r))
                        .unwrap();
                }
            }
        }
        let mut g = GpuWorld::new(gpu, &w).unwrap();
        g.run(4000).unwrap();
        let touching: u32 = g.particles().unwrap().contacts.iter().sum();
        (g.state_bytes().unwrap(), touching)
    };
    let (without, touching) = state(plain);
    let (with, _) = state(sticky);
    println!("a cloud on a plate after 4000 steps: {touching} contacts");
    assert!(touching > 0, "the grains never touched");
    assert!(
        without == with,
        "the kernels without cohesion's code stepped other bits"
    );
}
