//! Cohesion laws (linear / simplified JKR and JKR) against their closed forms, and in the
//! engine: a grain hanging under a plate, two grains settling at the predicted overlap, and
//! determinism with cohesion on. Every figure is printed with `--nocapture`.

use std::f64::consts::PI;

use repose_engine::contact::{
    sphere_sphere_contact_radius2, sphere_wall_contact_radius2, CohesionLaw, JKR_SEPARATION,
};
use repose_engine::integrate::Integrator;
use repose_engine::kinematics::Motion;
use repose_engine::material::{
    Cohesion, DampingLaw, Interaction, InteractionEntry, Material, MaterialId, MaterialSet,
    MaterialTable,
};
use repose_engine::math::{Pose, Vec3};
use repose_engine::mesh::TriMesh;
use repose_engine::neighbor::Domain;
use repose_engine::particles::ParticleSpec;
use repose_engine::world::{Geometry, World, WorldConfig};

const GRAIN: MaterialId = MaterialId(0);
const PLATE: MaterialId = MaterialId(1);
const RADIUS: f64 = 0.005;

fn grain_material() -> Material {
    Material {
        name: "grain".into(),
        density: 2500.0,
        youngs_modulus: 1.0e8,
        poisson: 0.3,
    }
}

fn plate_material() -> Material {
    Material {
        name: "plate".into(),
        density: 7850.0,
        youngs_modulus: 2.1e11,
        poisson: 0.3,
    }
}

fn e_star(a: &Material, b: &Material) -> f64 {
    1.0 / ((1.0 - a.poisson.powi(2)) / a.youngs_modulus
        + (1.0 - b.poisson.powi(2)) / b.youngs_modulus)
}

fn grain_mass() -> f64 {
    2500.0 * 4.0 / 3.0 * PI * RADIUS.powi(3)
}

fn table(cohesion: Cohesion) -> MaterialTable {
    let coefficients = Interaction {
        restitution: 0.3,
        static_friction: 0.5,
        rolling_friction: 0.0,
        cohesion,
    };
    let entry = |a: &str, b: &str| InteractionEntry {
        a: a.into(),
        b: b.into(),
        coefficients,
    };
    MaterialSet {
        damping_law: DampingLaw::default(),
        materials: vec![grain_material(), plate_material()],
        interactions: vec![
            entry("grain", "grain"),
            entry("grain", "plate"),
            entry("plate", "plate"),
        ],
    }
    .build()
    .expect("valid materials")
}

/// Hertz's elastic normal force 4/3 E* sqrt(R*) δ^1.5.
fn hertz(e_star: f64, r_star: f64, overlap: f64) -> f64 {
    4.0 / 3.0 * e_star * r_star.sqrt() * overlap.powf(1.5)
}

/// The root of `f` in [lo, hi] (f(lo), f(hi) of opposite signs), by bisection.
fn bisect(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    let f_lo = f(lo);
    assert!(f_lo * f(hi) < 0.0, "no sign change in [{lo}, {hi}]");
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if (f(mid) > 0.0) == (f_lo > 0.0) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[test]
fn jkr_pull_off_force_is_one_and_a_half_pi_gamma_r_star() {
    let gamma = 0.2;
    let e = e_star(&grain_material(), &grain_material());
    for r_star in [0.5e-3, RADIUS / 2.0, 0.02] {
        let law = CohesionLaw::new(
            &Cohesion::Jkr {
                surface_energy: gamma,
            },
            e,
        );
        let a0 = (2.0 * PI * gamma * r_star * r_star / e).cbrt();
        let unit = a0 * a0 / r_star;
        // The net elastic normal force (repulsive > 0) over the whole contact, necking included.
        let net = |overlap: f64| {
            if overlap > 0.0 {
                hertz(e, r_star, overlap) - law.attraction(r_star, overlap, || unreachable!())
            } else {
                law.necking_force(r_star, overlap)
                    .expect("still in contact")
            }
        };
        let samples = 20_000;
        let (lo, hi) = (0.9999 * JKR_SEPARATION * unit, 2.0 * unit);
        let minimum = (0..=samples)
            .map(|k| net(lo + (hi - lo) * k as f64 / samples as f64))
            .fold(f64::INFINITY, f64::min);
        let pull_off = 1.5 * PI * gamma * r_star;
        println!(
            "R* {r_star:.1e} m: smallest force {:.6e} N, 1.5 π γ R* = {pull_off:.6e} N",
            -minimum
        );
        assert!(
            (-minimum / pull_off - 1.0).abs() < 0.02,
            "{minimum} vs {pull_off}"
        );
        // At zero overlap JKR pulls with 8/9 of the pull-off force (4/3 π γ R*)...
        let at_zero = law.necking_force(r_star, 0.0).unwrap();
        assert!((at_zero / (-4.0 / 3.0 * PI * gamma * r_star) - 1.0).abs() < 1e-9);
        // ... and continuously so from the positive side.
        assert!((net(1e-9 * unit) / at_zero - 1.0).abs() < 1e-3);
        // The contact separates at δ = −0.4725 a0²/R*.
        assert!(law
            .necking_force(r_star, 0.999 * JKR_SEPARATION * unit)
            .is_some());
        assert!(law
            .necking_force(r_star, 1.001 * JKR_SEPARATION * unit)
            .is_none());
    }
    // The separation constant: x^1.5 = 1/4, D = x² − √x.
    let x: f64 = 0.25f64.powf(2.0 / 3.0);
    assert!((JKR_SEPARATION - (x * x - x.sqrt())).abs() < 1e-15);
}

#[test]
fn linear_cohesion_is_the_energy_density_times_the_intersection_area() {
    let k = 3.0e5;
    let law = CohesionLaw::new(&Cohesion::Linear { energy_density: k }, 1.0e8);
    for (ri, rj, overlap) in [
        (1e-3, 1e-3, 1e-5),
        (1e-3, 2.5e-3, 4e-5),
        (2e-3, 0.7e-3, 1e-4),
    ] {
        let dist = ri + rj - overlap;
        // The circle where the spheres intersect: its plane is x from i's centre, with
        // x = (d² + ri² − rj²) / (2 d), and its radius² is ri² − x².
        let x = (dist * dist + ri * ri - rj * rj) / (2.0 * dist);
        let area = PI * (ri * ri - x * x);
        let r_star = ri * rj / (ri + rj);
        let force = law.attraction(r_star, overlap, || {
            sphere_sphere_contact_radius2(ri, rj, dist * dist, overlap)
        });
        println!(
            "ri {ri} rj {rj} δ {overlap}: F {force:.6e} N, k A {:.6e} N",
            k * area
        );
        assert!((force / (k * area) - 1.0).abs() < 0.02);
        // Small overlaps: A ≈ 2 π R* δ.
        assert!((force / (k * 2.0 * PI * r_star * overlap) - 1.0).abs() < 0.06);
    }
    // Against a wall: the circle where the sphere cuts the plane, π (r² − (r − δ)²).
    let (r, overlap) = (1e-3, 2e-5);
    let force = law.attraction(r, overlap, || sphere_wall_contact_radius2(r, overlap));
    let area = PI * (r * r - (r - overlap).powi(2));
    assert!((force / (k * area) - 1.0).abs() < 0.02);
    // A zero coefficient is no cohesion at all.
    assert!(!CohesionLaw::new(
        &Cohesion::Linear {
            energy_density: 0.0
        },
        1e8
    )
    .is_on());
    assert!(!CohesionLaw::new(&Cohesion::None, 1e8).is_on());
}

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

fn world(cohesion: Cohesion, gravity: Vec3) -> World {
    let materials = table(cohesion);
    let dt = materials.rayleigh_time_step(GRAIN, RADIUS, 0.2);
    let mut config = WorldConfig::new(dt, Domain::closed(Vec3::repeat(-0.1), Vec3::repeat(0.1)));
    config.gravity = gravity;
    config.integrator = Integrator::SymplecticEuler;
    World::new(materials, config).unwrap()
}

fn grain(position: Vec3) -> ParticleSpec {
    ParticleSpec {
        position,
        velocity: Vec3::zeros(),
        angular_velocity: Vec3::zeros(),
        radius: RADIUS,
        material: GRAIN,
    }
}

/// A 100 mm square steel plate in the plane z = 0.
fn add_plate(world: &mut World) {
    world
        .add_geometry(Geometry {
            name: "plate".into(),
            mesh: plane(0.05, 10),
            motion: Motion::stationary(Pose::identity()),
            material: PLATE,
        })
        .unwrap();
}

/// A grain placed touching the underside of a plate at z = 0, with `overlap`, under gravity;
/// returns its centre height after `seconds`.
fn hanging_grain(cohesion: Cohesion, overlap: f64, seconds: f64) -> f64 {
    let mut world = world(cohesion, Vec3::new(0.0, 0.0, -9.81));
    add_plate(&mut world);
    world
        .add_particle(grain(Vec3::new(0.001, 0.002, -(RADIUS - overlap))))
        .unwrap();
    world.run_until(seconds);
    world.particles().position[0].z
}

#[test]
fn a_grain_hangs_under_a_cohesive_plate_and_falls_from_a_clean_one() {
    let k = 2.0e6;
    let e = e_star(&grain_material(), &plate_material());
    let weight = grain_mass() * 9.81;
    // Net upward force on the grain at overlap δ: cohesion − Hertz − weight. Its maximum is at
    // δ* = (π k sqrt(R) / E*)²; the stable equilibrium is the root above δ*.
    let net =
        |d: f64| k * PI * sphere_wall_contact_radius2(RADIUS, d) - hertz(e, RADIUS, d) - weight;
    let peak = (PI * k * RADIUS.sqrt() / e).powi(2);
    assert!(
        net(peak) > 0.0,
        "the weight exceeds the largest cohesive hold"
    );
    let expected = bisect(net, peak, 20.0 * peak);
    let z = hanging_grain(Cohesion::Linear { energy_density: k }, peak, 0.1);
    let overlap = RADIUS + z;
    println!(
        "linear k {k:.1e}: hangs at overlap {overlap:.4e} m, predicted {expected:.4e} m \
         (weight {weight:.3e} N)"
    );
    assert!((overlap / expected - 1.0).abs() < 0.01);
    // Without cohesion the same grain falls away.
    let z = hanging_grain(Cohesion::None, peak, 0.1);
    println!("no cohesion: centre at {z:.4} m after 0.1 s");
    assert!(z < -RADIUS - 0.02);
    // JKR holds it too (the plate's R* is the grain's radius; the weight is far below the
    // 8/9 of the pull-off force that acts at zero overlap).
    let gamma = 1.0;
    assert!(weight < 4.0 / 3.0 * PI * gamma * RADIUS);
    let z = hanging_grain(
        Cohesion::Jkr {
            surface_energy: gamma,
        },
        1e-6,
        0.1,
    );
    println!("JKR γ {gamma}: hangs at overlap {:.4e} m", RADIUS + z);
    assert!(RADIUS + z > 0.0);
}

/// Two grains placed in contact with no gravity; returns their overlap after `seconds`.
fn pair_overlap(cohesion: Cohesion, overlap: f64, seconds: f64) -> f64 {
    let mut world = world(cohesion, Vec3::zeros());
    let half = RADIUS - overlap / 2.0;
    world
        .add_particle(grain(Vec3::new(-half, 0.0, 0.0)))
        .unwrap();
    world
        .add_particle(grain(Vec3::new(half, 0.0, 0.0)))
        .unwrap();
    world.run_until(seconds);
    let p = world.particles();
    2.0 * RADIUS - (p.position[1] - p.position[0]).norm()
}

#[test]
fn two_cohesive_grains_settle_at_the_equilibrium_overlap_of_the_law() {
    let e = e_star(&grain_material(), &grain_material());
    let r_star = RADIUS / 2.0;
    // Linear: k A(δ) = Hertz(δ), A the exact intersection circle.
    let k = 2.0e6;
    let net = |d: f64| {
        let dist = 2.0 * RADIUS - d;
        k * PI * sphere_sphere_contact_radius2(RADIUS, RADIUS, dist * dist, d) - hertz(e, r_star, d)
    };
    let small = (1.5 * PI * k * r_star.sqrt() / e).powi(2);
    let expected = bisect(net, 0.2 * small, 5.0 * small);
    let overlap = pair_overlap(Cohesion::Linear { energy_density: k }, 0.5 * expected, 0.1);
    println!("linear k {k:.1e}: overlap {overlap:.5e} m, predicted {expected:.5e} m");
    assert!((overlap / expected - 1.0).abs() < 0.01);
    // JKR: zero load at x^1.5 = 3/2, δ = (x² − √x) a0²/R*.
    let gamma = 0.5;
    let a0 = (2.0 * PI * gamma * r_star * r_star / e).cbrt();
    let x = 1.5f64.powf(2.0 / 3.0);
    let expected = (x * x - x.sqrt()) * a0 * a0 / r_star;
    let overlap = pair_overlap(
        Cohesion::Jkr {
            surface_energy: gamma,
        },
        0.5 * expected,
        0.1,
    );
    println!("JKR γ {gamma}: overlap {overlap:.5e} m, predicted {expected:.5e} m");
    assert!((overlap / expected - 1.0).abs() < 0.01);
    // Without cohesion the grains push each other apart.
    assert!(pair_overlap(Cohesion::None, 0.5 * expected, 0.1) < 0.0);
}

/// A periodic box of grains thrown together with cohesion: the state hash after `steps`.
fn cohesive_cloud_hash(cohesion: Cohesion, threads: usize) -> (u64, usize) {
    use rand::{Rng, SeedableRng};
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let materials = table(cohesion);
        let dt = materials.rayleigh_time_step(GRAIN, 0.0024, 0.2);
        let size = 0.06;
        let domain = Domain {
            min: Vec3::new(0.0, 0.0, -0.01),
            max: Vec3::new(size, size, 0.08),
            periodic_x: true,
            periodic_y: true,
        };
        let mut config = WorldConfig::new(dt, domain);
        config.integrator = Integrator::VelocityVerlet;
        let mut world = World::new(materials, config).unwrap();
        world
            .add_geometry(Geometry {
                name: "floor".into(),
                mesh: plane(0.1, 4)
                    .transformed(&Pose::translation(size / 2.0, size / 2.0, 0.0))
                    .unwrap(),
                motion: Motion::stationary(Pose::identity()),
                material: PLATE,
            })
            .unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for x in 0..10 {
            for y in 0..10 {
                for z in 0..8 {
                    let position = Vec3::new(
                        (x as f64 + 0.5) * 0.006,
                        (y as f64 + 0.5) * 0.006,
                        0.004 + z as f64 * 0.006,
                    );
                    world
                        .add_particle(ParticleSpec {
                            position,
                            velocity: Vec3::new(
                                rng.gen_range(-0.3..0.3),
                                rng.gen_range(-0.3..0.3),
                                rng.gen_range(-0.3..0.3),
                            ),
                            angular_velocity: Vec3::zeros(),
                            radius: rng.gen_range(0.0018..0.0024),
                            material: GRAIN,
                        })
                        .unwrap();
                }
            }
        }
        world.run_until(0.08);
        (world.state_hash(), world.contact_count())
    })
}

#[test]
fn cohesive_runs_are_bit_identical_for_one_and_two_threads() {
    let none = cohesive_cloud_hash(Cohesion::None, 1);
    for cohesion in [
        Cohesion::Linear {
            energy_density: 5.0e5,
        },
        Cohesion::Jkr {
            surface_energy: 0.5,
        },
    ] {
        let one = cohesive_cloud_hash(cohesion, 1);
        let two = cohesive_cloud_hash(cohesion, 2);
        println!(
            "{cohesion:?}: 1 thread {:016x} ({} contacts), 2 threads {:016x}; none {:016x}",
            one.0, one.1, two.0, none.0
        );
        assert_eq!(one, two);
        assert_ne!(one.0, none.0, "cohesion changed nothing");
    }
}

#[test]
fn cohesion_reads_from_json_and_bad_values_name_the_field() {
    // A document without cohesion reads as none; none is written out explicitly.
    let plain = r#"{"restitution":0.5,"static_friction":0.4,"rolling_friction":0.1}"#;
    let interaction: Interaction = serde_json::from_str(plain).unwrap();
    assert_eq!(interaction.cohesion, Cohesion::None);
    assert_eq!(
        serde_json::to_string(&interaction).unwrap(),
        r#"{"restitution":0.5,"static_friction":0.4,"rolling_friction":0.1,"cohesion":{"model":"none"}}"#
    );
    let cohesive: Interaction = serde_json::from_str(
        r#"{"restitution":0.5,"static_friction":0.4,"rolling_friction":0.1,
            "cohesion":{"model":"linear","energy_density":3.0e5}}"#,
    )
    .unwrap();
    assert_eq!(
        cohesive.cohesion,
        Cohesion::Linear {
            energy_density: 3.0e5
        }
    );
    let jkr: Cohesion = serde_json::from_str(r#"{"model":"jkr","surface_energy":0.1}"#).unwrap();
    assert_eq!(
        jkr,
        Cohesion::Jkr {
            surface_energy: 0.1
        }
    );
    assert!(serde_json::from_str::<Cohesion>(r#"{"model":"glue"}"#).is_err());
    let mut set = MaterialSet::paper(cohesive, cohesive);
    set.interactions[0].coefficients.cohesion = Cohesion::Linear {
        energy_density: -1.0,
    };
    let message = set.build().unwrap_err().to_string();
    assert!(
        message.starts_with("interactions.soil-soil.cohesion.energy_density must be >= 0"),
        "{message}"
    );
    set.interactions[0].coefficients.cohesion = Cohesion::Jkr {
        surface_energy: f64::NAN,
    };
    let message = set.build().unwrap_err().to_string();
    assert!(
        message.starts_with("interactions.soil-soil.cohesion.surface_energy must be >= 0"),
        "{message}"
    );
}

#[test]
fn jkr_grains_pulled_apart_keep_attracting_past_zero_overlap() {
    // Two JKR grains leave each other at 0.1 m/s relative speed. Past zero overlap the contact
    // necks: it keeps pulling (and slowing them) until δ = −0.4725 a0²/R*; a contact lost at
    // zero overlap would leave the speed unchanged from there on.
    let gamma = 0.5;
    // A step a hundredth of the usual, so the grains cross the µm necking range in ~35 steps.
    let materials = table(Cohesion::Jkr {
        surface_energy: gamma,
    });
    let dt = materials.rayleigh_time_step(GRAIN, RADIUS, 0.002);
    let mut config = WorldConfig::new(dt, Domain::closed(Vec3::repeat(-0.1), Vec3::repeat(0.1)));
    config.gravity = Vec3::zeros();
    let mut world = World::new(materials, config).unwrap();
    let overlap = 1e-6;
    let half = RADIUS - overlap / 2.0;
    for (side, v) in [(-1.0, -0.05), (1.0, 0.05)] {
        world
            .add_particle(ParticleSpec {
                velocity: Vec3::new(v, 0.0, 0.0),
                ..grain(Vec3::new(side * half, 0.0, 0.0))
            })
            .unwrap();
    }
    let e = e_star(&grain_material(), &grain_material());
    let r_star = RADIUS / 2.0;
    let a0 = (2.0 * PI * gamma * r_star * r_star / e).cbrt();
    let separation = JKR_SEPARATION * a0 * a0 / r_star;
    let state = |w: &World| {
        let p = w.particles();
        let gap = (p.position[1] - p.position[0]).norm() - 2.0 * RADIUS;
        (gap, p.velocity[1].x - p.velocity[0].x)
    };
    let mut at_zero = None;
    // The largest gap at which the grains still slowed each other down.
    let mut deepest_pull = 0.0;
    let (mut previous_gap, mut previous_speed) = state(&world);
    for _ in 0..20_000 {
        world.step();
        let (gap, speed) = state(&world);
        if gap > 0.0 && at_zero.is_none() {
            at_zero = Some(speed);
        }
        if previous_gap > 0.0 && speed < previous_speed {
            deepest_pull = f64::max(deepest_pull, previous_gap);
        }
        (previous_gap, previous_speed) = (gap, speed);
        if gap > -3.0 * separation {
            break;
        }
    }
    let at_zero = at_zero.expect("the grains separated");
    let (_, last) = state(&world);
    println!(
        "relative speed at zero overlap {at_zero:.6e} m/s, after separation {last:.6e} m/s; \
         still in contact at a gap of {deepest_pull:.3e} m (separation at {:.3e} m)",
        -separation
    );
    assert!(last < at_zero * (1.0 - 1e-5), "no pull past zero overlap");
    // Pulling up to the separation gap (within one step's travel, ~27 nm), not beyond.
    assert!(deepest_pull > 0.5 * -separation, "{deepest_pull}");
    assert!(deepest_pull < -separation, "{deepest_pull}");
}

/// The funnel test's soil (the `default` aor preset: ρ 2664, E 3.67 MPa, ν 0.36; soil-soil e
/// 0.45, μs 0.442, μr 0.14; soil-steel e 0.40, μs 0.305, μr 0.50) with linear cohesion `k`
/// between grains only, and CDT rolling friction.
fn funnel_soil(k: f64) -> MaterialTable {
    let soil = Material {
        name: "soil".into(),
        density: 2664.0,
        youngs_modulus: 3.67e6,
        poisson: 0.36,
    };
    let entry = |a: &str, b: &str, e, mu, mu_r, cohesion| InteractionEntry {
        a: a.into(),
        b: b.into(),
        coefficients: Interaction {
            restitution: e,
            static_friction: mu,
            rolling_friction: mu_r,
            cohesion,
        },
    };
    MaterialSet {
        damping_law: DampingLaw::default(),
        materials: vec![soil, plate_material()],
        interactions: vec![
            entry(
                "soil",
                "soil",
                0.45,
                0.442,
                0.14,
                Cohesion::Linear { energy_density: k },
            ),
            entry("soil", "plate", 0.40, 0.305, 0.50, Cohesion::None),
            entry("plate", "plate", 0.5, 0.3, 0.01, Cohesion::None),
        ],
    }
    .build()
    .expect("valid materials")
}

/// 294 grains of 2 mm (a jittered 7 × 7 × 6 lattice, 2.2 radii apart) dropped 20 mm onto a
/// steel plate at Δt = 0.2 Rayleigh times; returns the kinetic energy (translational +
/// rotational) in units of m g d at `seconds`, and the largest |ω| then.
fn cohesive_clump_energy(k: f64, seconds: f64) -> (f64, f64) {
    use rand::{Rng, SeedableRng};
    let r = 0.001;
    let materials = funnel_soil(k);
    let soil = MaterialId(0);
    let dt = materials.rayleigh_time_step(soil, r, 0.2);
    let mut config = WorldConfig::new(dt, Domain::closed(Vec3::repeat(-0.1), Vec3::repeat(0.1)));
    config.gravity = Vec3::new(0.0, 0.0, -9.81);
    let mut world = World::new(materials, config).unwrap();
    add_plate(&mut world);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let a = 2.2 * r;
    for z in 0..6 {
        for y in 0..7 {
            for x in 0..7 {
                let mut jitter = || rng.gen_range(-0.05 * r..0.05 * r);
                let position = Vec3::new(
                    (x as f64 - 3.0) * a + jitter(),
                    (y as f64 - 3.0) * a + jitter(),
                    0.02 + r + z as f64 * a + jitter(),
                );
                world
                    .add_particle(ParticleSpec {
                        position,
                        velocity: Vec3::zeros(),
                        angular_velocity: Vec3::zeros(),
                        radius: r,
                        material: soil,
                    })
                    .unwrap();
            }
        }
    }
    world.run_until(seconds);
    let p = world.particles();
    let mgd = p.mass.iter().sum::<f64>() * 9.81 * 2.0 * r;
    let spin = p
        .angular_velocity
        .iter()
        .map(|w| w.norm())
        .fold(0.0, f64::max);
    (p.kinetic_energy() / mgd, spin)
}

#[test]
fn a_cohesive_clump_with_cdt_rolling_friction_comes_to_rest_at_the_presets_time_step() {
    // With k = 2e5 J/m³ (c ≈ 2.5 kPa in the shear test) the contacts sit at δ ≈ 5 % of R*,
    // stiff enough that CDT's old explicit rolling torque (its direction from the old ω)
    // fed a rotation-shear mode: this clump boiled at a kinetic energy of ~0.3 m g d
    // forever, and funnel heaps boiled at 1.16 m g d. The brake on the new spin
    // (`rolling_brake`) holds it: the clump comes to rest, its grains not turning at all.
    let (energy, spin) = cohesive_clump_energy(2.0e5, 1.5);
    println!("k = 2e5: kinetic energy {energy:.3e} m g d, max |ω| {spin:.3e} rad/s at 1.5 s");
    assert!(energy < 1e-6, "the cohesive clump comes to rest");
    assert!(spin < 1e-9, "its grains do not turn");
}

/// `World::for_each_contact` reports what each contact carries: in a column of grains at rest
/// on a plate, the contact under grain k holds the weight of k and the grains above it, with
/// cohesion as without (the bond's pull and the extra Hertz load cancel in the net force).
#[test]
fn contact_forces_of_a_resting_column_carry_the_weight_above() {
    let n = 5;
    let weight = grain_mass() * 9.81;
    for cohesion in [
        Cohesion::None,
        Cohesion::Linear {
            energy_density: 2.0e5,
        },
    ] {
        let mut world = world(cohesion, Vec3::new(0.0, 0.0, -9.81));
        add_plate(&mut world);
        for k in 0..n {
            let z = RADIUS + 2.0 * RADIUS * k as f64;
            world.add_particle(grain(Vec3::new(0.0, 0.0, z))).unwrap();
        }
        world.run_until(0.5);
        let mut contacts = Vec::new();
        world.for_each_contact(|c| contacts.push(c));
        assert_eq!(contacts.len(), n - 1, "{cohesion:?}: {contacts:?}");
        for c in &contacts {
            assert_eq!(
                c.j,
                c.i + 1,
                "{cohesion:?}: pairs are neighbours in the column"
            );
            let above = (n - c.j) as f64 * weight;
            println!(
                "{cohesion:?}: contact {}-{}: {:.6e} N up on the upper grain, weight above {:.6e} N",
                c.i, c.j, c.force_on_j.z, above
            );
            assert!(
                (c.force_on_j.z / above - 1.0).abs() < 1e-3,
                "{cohesion:?}: contact {}-{} carries {} N, weight above {above} N",
                c.i,
                c.j,
                c.force_on_j.z
            );
            assert!(c.force_on_j.x.abs() + c.force_on_j.y.abs() < 1e-9 * above);
            assert!((c.branch.z / (2.0 * RADIUS) - 1.0).abs() < 0.05 && c.branch.z > 0.0);
        }
    }
}
