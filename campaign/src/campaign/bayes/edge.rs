//! A target the surrogates put out of reach, though runs met it within their noise: where those
//! runs lie. When every one of them sits at the same edge of the factor box (a factor within
//! [`EDGE`] of one end of its range), the target is met only at that edge, and the campaign
//! says so (the factor and which end) instead of calling it out of reach: a smooth surrogate
//! cannot tell whether the band lies just inside the edge or beyond it. Runs that met it in
//! the interior leave the surrogates' verdict standing: one noisy run is not evidence enough.

use super::acquisition::Band;
use super::Response;

/// A run within this share of a factor's range from one end is at that edge.
pub(crate) const EDGE: f64 = 0.1;
/// A run met the band within its noise when it lies within this many noise standard
/// deviations of it: its own mean may lie in the band.
pub(crate) const WITHIN_NOISE: f64 = 2.0;
/// How far inward (share of the range) the surrogate's trend is read from the edge.
const INWARD: f64 = 0.25;

/// One end of one factor's range (the factor's index in request order).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct UnitEdge {
    pub factor: usize,
    pub high: bool,
}

/// The runs of a target that met it within their noise, all at the same edges.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct AtEdge {
    /// How many runs met it (within the band, or within [`WITHIN_NOISE`] noise standard
    /// deviations of it).
    pub runs: usize,
    /// The one closest to the band: its index among the runs given.
    pub closest: usize,
    /// The edges they share where the surrogate's mean moves away from the target inward, the
    /// steepest first, or every edge they share when it does so at none.
    pub edges: Vec<UnitEdge>,
}

/// How far `v` lies outside the band (0 inside).
fn gap(v: f64, band: Band) -> f64 {
    let (lo, hi) = (band.target - band.half_width, band.target + band.half_width);
    (lo - v).max(v - hi).max(0.0)
}

/// Of `runs` (each run's normalised setting, every factor, and its value of the target), the
/// ones within [`WITHIN_NOISE`] of the response's noise standard deviations of the band, and the edges they all share among the factors the
/// response ranges over; `None` when none met the band or they share no edge.
pub(crate) fn at_edge(runs: &[(Vec<f64>, f64)], band: Band, response: &Response) -> Option<AtEdge> {
    let noise_sd = response.surrogate.noise_sd();
    let met: Vec<usize> = (0..runs.len())
        .filter(|&i| gap(runs[i].1, band) <= WITHIN_NOISE * noise_sd)
        .collect();
    let closest = *met
        .iter()
        .min_by(|&&a, &&b| gap(runs[a].1, band).total_cmp(&gap(runs[b].1, band)))?;
    let shared: Vec<UnitEdge> = response
        .columns
        .iter()
        .filter_map(|&j| {
            let low = met.iter().all(|&i| runs[i].0[j] <= EDGE);
            let high = met.iter().all(|&i| runs[i].0[j] >= 1.0 - EDGE);
            (low || high).then_some(UnitEdge { factor: j, high })
        })
        .collect();
    if shared.is_empty() {
        return None;
    }
    // The surrogate's trend at the closest run: an edge matters where stepping inward from it
    // moves the mean away from the target.
    let base = &runs[closest].0;
    let inward: Vec<Vec<f64>> = shared
        .iter()
        .map(|e| {
            let mut p = base.clone();
            p[e.factor] = if e.high {
                (p[e.factor] - INWARD).max(0.0)
            } else {
                (p[e.factor] + INWARD).min(1.0)
            };
            p
        })
        .collect();
    let mut at = vec![base.clone()];
    at.extend(inward);
    let means: Vec<f64> = response.predict(&at).iter().map(|p| p.mean).collect();
    let off = |m: f64| (m - band.target).abs();
    let mut outward: Vec<(UnitEdge, f64)> = shared
        .iter()
        .zip(&means[1..])
        .map(|(e, m)| (*e, off(*m) - off(means[0])))
        .filter(|(_, away)| *away > 0.0)
        .collect();
    // The steepest first.
    outward.sort_by(|a, b| b.1.total_cmp(&a.1));
    let outward: Vec<UnitEdge> = outward.into_iter().map(|(e, _)| e).collect();
    Some(AtEdge {
        runs: met.len(),
        closest,
        edges: if outward.is_empty() { shared } else { outward },
    })
}
