//! The settled-bed benchmark without the CLI (a quicker build for profiling the engine alone):
//! `cargo run --release -p repose-engine --example bed -- PARTICLES THREADS STEPS`.
//! Prints particle-steps per second, contacts and pairs per particle, and bytes per particle.

use repose_engine::bench::{settled_bed, time_steps};

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("arguments are PARTICLES THREADS STEPS"))
        .collect();
    let particles = args.first().copied().unwrap_or(20_000);
    let threads = args.get(1).copied().unwrap_or(1);
    let steps = args.get(2).copied().unwrap_or(400) as u64;
    let bed = settled_bed(particles, 1).expect("building the bed");
    let r = time_steps(&bed, threads, steps);
    println!(
        "{} particles, {} threads, {} steps: {:.3} M particle-steps/s, {:.2} contacts/particle, \
         {:.2} pairs/particle, {:.0} B/particle, {} rebuilds",
        r.particles,
        r.threads,
        r.steps,
        r.particle_steps_per_second / 1e6,
        r.contacts_per_particle,
        r.pairs_per_particle,
        r.bytes_per_particle,
        r.rebuilds
    );
}
