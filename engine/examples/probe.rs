//! A few-grain probe for the side-by-side comparison with LIGGGHTS
//! (`bench/liggghts-funnel/probes/`): runs a scene (JSON) plus particles given with their
//! velocity, angular velocity and an optional `frozen` flag (held in place, never moving), and
//! prints the state of every particle every `print_every` steps as
//! `t id x y z vx vy vz wx wy wz`.
//!
//! `cargo run --release -p repose-engine --example probe -- PROBE.json`
//!
//! PROBE.json: `{ "scene": <a Scene>, "particles": [{ "material": "soil", "radius": R,
//! "position": [..], "velocity": [..], "angular_velocity": [..], "frozen": false }],
//! "steps": N, "print_every": K }`.

use repose_engine::math::Vec3;
use repose_engine::particles::ParticleSpec;
use repose_engine::scene::Scene;
use serde::Deserialize;

#[derive(Deserialize)]
struct Probe {
    scene: Scene,
    particles: Vec<Grain>,
    steps: u64,
    print_every: u64,
}

#[derive(Deserialize)]
struct Grain {
    material: String,
    radius: f64,
    position: Vec3,
    #[serde(default = "Vec3::zeros")]
    velocity: Vec3,
    #[serde(default = "Vec3::zeros")]
    angular_velocity: Vec3,
    #[serde(default)]
    frozen: bool,
}

fn main() {
    let path = std::env::args().nth(1).expect("usage: probe PROBE.json");
    let text = std::fs::read_to_string(&path).expect("reading the probe file");
    let probe: Probe = serde_json::from_str(&text).expect("parsing the probe file");
    let prepared = probe
        .scene
        .prepare(&|p| std::fs::read(p).map_err(|e| e.to_string()))
        .expect("preparing the scene");
    let mut world = prepared.world;
    eprintln!("time step {:.6e} s", prepared.time_step);
    let mut frozen = Vec::new();
    for g in &probe.particles {
        let material = world.materials().id(&g.material).expect("unknown material");
        let id = world
            .add_particle(ParticleSpec {
                position: g.position,
                velocity: g.velocity,
                angular_velocity: g.angular_velocity,
                radius: g.radius,
                material,
            })
            .expect("adding a particle");
        if g.frozen {
            frozen.push((id, g.position));
        }
    }
    let print = |world: &repose_engine::world::World| {
        let p = world.particles();
        for k in 0..p.len() {
            let (x, v, w) = (p.position[k], p.velocity[k], p.angular_velocity[k]);
            println!(
                "{:.7e} {} {:.9e} {:.9e} {:.9e} {:.6e} {:.6e} {:.6e} {:.6e} {:.6e} {:.6e}",
                world.time(),
                p.id[k] + 1,
                x.x,
                x.y,
                x.z,
                v.x,
                v.y,
                v.z,
                w.x,
                w.y,
                w.z
            );
        }
    };
    print(&world);
    for s in 1..=probe.steps {
        world.step();
        if !frozen.is_empty() {
            let p = world.particles_mut();
            for &(id, at) in &frozen {
                if let Some(k) = p.id.iter().position(|&i| i == id) {
                    p.position[k] = at;
                    p.velocity[k] = Vec3::zeros();
                    p.angular_velocity[k] = Vec3::zeros();
                }
            }
        }
        if s % probe.print_every == 0 {
            print(&world);
        }
    }
}
