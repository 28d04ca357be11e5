//! Where to simulate: the space-filling start (a maximin Latin hypercube) and the candidate
//! points a proposal is chosen from, all in the normalised box `[0, 1]^d` and reproducible from
//! the campaign seed and the round.

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// The random stream of one use (`purpose`) in one round, from the campaign seed alone, so a
/// campaign resumed from its stored state draws the same numbers.
pub(crate) fn rng(seed: u64, round: u32, purpose: u64) -> ChaCha8Rng {
    let mixed = repose_doe::design::splitmix64(
        seed ^ (u64::from(round) << 32) ^ purpose.wrapping_mul(0x9E37_79B9_7F4A_7C15),
    );
    ChaCha8Rng::seed_from_u64(mixed)
}

/// One Latin hypercube of `n` points in `d` dimensions (each stratum once per dimension, a
/// random position within it).
pub(crate) fn latin_hypercube(n: usize, d: usize, rng: &mut impl Rng) -> Vec<Vec<f64>> {
    let columns: Vec<Vec<f64>> = (0..d)
        .map(|_| {
            let mut strata: Vec<usize> = (0..n).collect();
            strata.shuffle(rng);
            strata
                .into_iter()
                .map(|s| (s as f64 + rng.gen::<f64>()) / n as f64)
                .collect()
        })
        .collect();
    (0..n)
        .map(|i| columns.iter().map(|c| c[i]).collect())
        .collect()
}

/// Smallest pairwise distance of a set.
pub(crate) fn min_distance(points: &[Vec<f64>]) -> f64 {
    let mut best = f64::INFINITY;
    for (i, a) in points.iter().enumerate() {
        for b in &points[i + 1..] {
            best = best.min(distance(a, b));
        }
    }
    best
}

pub(crate) fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The start design: of `tries` Latin hypercubes, the one whose closest two points are farthest
/// apart.
pub(crate) fn maximin_start(n: usize, d: usize, rng: &mut impl Rng) -> Vec<Vec<f64>> {
    let tries = 64;
    let mut best = latin_hypercube(n, d, rng);
    let mut score = min_distance(&best);
    for _ in 1..tries {
        let next = latin_hypercube(n, d, rng);
        let s = min_distance(&next);
        if s > score {
            best = next;
            score = s;
        }
    }
    best
}

/// `total` candidates: a Latin hypercube over the whole box (70 %) and Gaussian perturbations
/// of the `centres` (the best points so far) at two scales, clipped to the box.
pub(crate) fn candidates(
    total: usize,
    d: usize,
    centres: &[Vec<f64>],
    rng: &mut impl Rng,
) -> Vec<Vec<f64>> {
    let local = if centres.is_empty() {
        0
    } else {
        total * 3 / 10
    };
    let mut points = latin_hypercube(total - local, d, rng);
    let wide = Normal::new(0.0, 0.08).expect("valid sd");
    let narrow = Normal::new(0.0, 0.02).expect("valid sd");
    for i in 0..local {
        let centre = &centres[i % centres.len()];
        let spread = if i % 2 == 0 { &wide } else { &narrow };
        points.push(
            centre
                .iter()
                .map(|c| (c + spread.sample(rng)).clamp(0.0, 1.0))
                .collect(),
        );
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latin_hypercube_fills_every_stratum_once() {
        let mut r = rng(1, 0, 0);
        let n = 9;
        let points = latin_hypercube(n, 3, &mut r);
        for j in 0..3 {
            let mut strata: Vec<usize> = points
                .iter()
                .map(|p| (p[j] * n as f64).floor() as usize)
                .collect();
            strata.sort_unstable();
            assert_eq!(strata, (0..n).collect::<Vec<_>>());
        }
    }

    #[test]
    fn maximin_spreads_more_than_a_single_draw_and_is_reproducible() {
        let a = maximin_start(10, 4, &mut rng(7, 0, 1));
        let b = maximin_start(10, 4, &mut rng(7, 0, 1));
        assert_eq!(a, b);
        let single = latin_hypercube(10, 4, &mut rng(7, 0, 1));
        assert!(min_distance(&a) >= min_distance(&single));
    }

    #[test]
    fn candidates_stay_in_the_box_and_crowd_the_centres() {
        let centre = vec![0.9, 0.1];
        let c = candidates(1000, 2, std::slice::from_ref(&centre), &mut rng(3, 2, 2));
        assert_eq!(c.len(), 1000);
        assert!(c.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
        let near = c.iter().filter(|p| distance(p, &centre) < 0.1).count();
        // Uniformly about 1.6 % of the box lies within 0.1 of a corner-ish point; the local
        // perturbations put far more there.
        assert!(near > 150, "{near}");
    }
}
