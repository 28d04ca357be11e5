//! The benchmark's bed on the GPU: it settles like the CPU engine's, and the same run twice is
//! bit-identical on one adapter.

use crate::common;

use repose_engine::bench::{bed_lattice, settled_bed};
use repose_engine_gpu::GpuWorld;

fn mean_height(z: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = z.fold((0.0, 0usize), |(s, n), z| (s + z, n + 1));
    sum / n as f64
}

#[test]
fn a_bed_settles_on_the_gpu_as_on_the_cpu() {
    let Some(gpu) = common::gpu() else { return };
    let n = 600;
    let cpu = settled_bed(n, 3).unwrap();
    let (gpu_bed, settle_steps) = repose_engine_gpu::bench::settled_bed(gpu, n, 3).unwrap();
    let cpu_h = mean_height(cpu.particles().position.iter().map(|x| x.z));
    let gpu_h = mean_height(gpu_bed.particles().position.iter().map(|x| x.z));
    let cpu_top = cpu
        .particles()
        .position
        .iter()
        .map(|x| x.z)
        .fold(0.0, f64::max);
    let gpu_top = gpu_bed
        .particles()
        .position
        .iter()
        .map(|x| x.z)
        .fold(0.0, f64::max);
    eprintln!(
        "mean height cpu {cpu_h:.6} m, gpu {gpu_h:.6} m; top {cpu_top:.6} / {gpu_top:.6}; \
         GPU settling steps {settle_steps}"
    );
    // Random packings of the same lattice differ grain by grain; the bed's mean height agrees
    // within 2 % (a tenth of a grain on a bed a few grains deep).
    assert!(
        (gpu_h - cpu_h).abs() < 0.02 * cpu_h,
        "mean height: GPU {gpu_h} vs CPU {cpu_h}"
    );
    assert!(gpu_bed
        .particles()
        .position
        .iter()
        .all(|x| x.z > 0.0 && x.z.is_finite()));
}

#[test]
fn the_same_run_twice_is_bit_identical() {
    let Some(gpu) = common::gpu() else { return };
    let (world, _) = bed_lattice(500, 5).unwrap();
    let run = || {
        let mut w = GpuWorld::new(gpu, &world).unwrap();
        w.run(600).unwrap();
        w.state_bytes().unwrap()
    };
    let (a, b) = (run(), run());
    assert_eq!(a.len(), b.len());
    assert!(a == b, "two runs of the same world differ");
}

/// Every pair touching now is in both particles' lists (built at the last rebuild, with a skin
/// for the motion since), lists are ascending and symmetric — also across the periodic faces,
/// in a lattice whose grains fly about without gravity.
#[test]
fn neighbour_lists_hold_every_touching_pair_across_periodic_faces() {
    use rand::{Rng, SeedableRng};
    let Some(gpu) = common::gpu() else { return };
    let (mut world, _) = bed_lattice(600, 3).unwrap();
    let mut json = serde_json::to_value(&world).unwrap();
    json["config"]["gravity"] = serde_json::json!([0.0, 0.0, 0.0]);
    world = serde_json::from_value(json).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    for v in world.particles_mut().velocity.iter_mut() {
        *v =
            repose_engine::math::Vec3::new(rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.3), 0.0);
    }
    let radius = world.particles().radius.clone();
    let mut g = GpuWorld::new(gpu, &world).unwrap();
    let mut touching_pairs = 0;
    for _ in 0..4 {
        g.run(50).unwrap();
        let lists = g.neighbour_lists().unwrap();
        let voxels = g.voxels().unwrap();
        let grid = *g.grid();
        for (i, list) in lists.iter().enumerate() {
            assert!(
                list.windows(2).all(|w| w[0] < w[1]),
                "list {i} not ascending: {list:?}"
            );
            for &j in list {
                assert!(
                    lists[j as usize].contains(&(i as u32)),
                    "{j} in {i}'s list, not back"
                );
            }
        }
        for i in 0..voxels.len() {
            for j in i + 1..voxels.len() {
                let d = grid.difference(voxels[i], voxels[j]);
                let dist = (d[0] as f64).hypot(d[1] as f64).hypot(d[2] as f64);
                if dist < radius[i] + radius[j] {
                    touching_pairs += 1;
                    assert!(
                        lists[i].contains(&(j as u32)),
                        "step {}: {i} and {j} touch ({dist} m apart) but are not listed",
                        g.steps()
                    );
                }
            }
        }
    }
    assert!(touching_pairs > 0, "the test saw no contact");
    // No gravity, damped contacts: kinetic energy can only fall.
    let kinetic = |v: &[repose_engine::math::Vec3]| -> f64 {
        v.iter()
            .zip(&world.particles().mass)
            .map(|(v, m)| 0.5 * m * v.norm_squared())
            .sum()
    };
    let start = kinetic(&world.particles().velocity);
    let end = kinetic(&g.particles().unwrap().velocity);
    println!("kinetic energy {start:.3e} J -> {end:.3e} J");
    assert!(
        end <= start * 1.000_1,
        "kinetic energy rose from {start} J to {end} J"
    );
}

/// A grain leaving through any periodic face comes back through the opposite one at the place
/// the motion says (a wrap of the voxel index, both directions, both axes and a corner).
#[test]
fn grains_crossing_the_periodic_faces_come_back_on_the_far_side() {
    use repose_engine::material::MaterialId;
    use repose_engine::math::Vec3;
    use repose_engine::neighbor::Domain;
    use repose_engine::particles::ParticleSpec;
    use repose_engine::world::{World, WorldConfig};
    let Some(gpu) = common::gpu() else { return };
    let side = 0.03;
    let domain = Domain {
        min: Vec3::zeros(),
        max: Vec3::repeat(side),
        periodic_x: true,
        periodic_y: true,
    };
    let materials = common::grain_materials(0.0);
    let dt = 1.0e-5;
    let mut config = WorldConfig::new(dt, domain);
    config.gravity = Vec3::zeros();
    let mut world = World::new(materials, config).unwrap();
    let r = 1.0e-3;
    let start = [
        (Vec3::new(0.0015, 0.015, 0.015), Vec3::new(-1.0, 0.0, 0.0)),
        (Vec3::new(0.0285, 0.005, 0.015), Vec3::new(1.0, 0.0, 0.0)),
        (Vec3::new(0.015, 0.0015, 0.005), Vec3::new(0.0, -1.0, 0.0)),
        (Vec3::new(0.025, 0.0285, 0.025), Vec3::new(0.0, 1.0, 0.0)),
        (Vec3::new(0.0015, 0.0015, 0.010), Vec3::new(-1.0, -1.0, 0.0)),
    ];
    for &(position, velocity) in &start {
        world
            .add_particle(ParticleSpec {
                position,
                velocity,
                angular_velocity: Vec3::zeros(),
                radius: r,
                material: MaterialId(0),
            })
            .unwrap();
    }
    let mut g = GpuWorld::new(gpu, &world).unwrap();
    let steps = 300;
    g.run(steps).unwrap();
    let p = g.particles().unwrap();
    let t = steps as f64 * dt;
    for (k, &(x0, v)) in start.iter().enumerate() {
        let mut d = p.position[k] - (x0 + v * t);
        for a in 0..2 {
            d[a] -= (d[a] / side).round() * side;
        }
        assert!(
            d.norm() < 1e-6,
            "grain {k} is at {:?}, {:.3e} m from where it should be",
            p.position[k],
            d.norm()
        );
        assert!(!p.removed[k], "grain {k} was removed");
    }
}
