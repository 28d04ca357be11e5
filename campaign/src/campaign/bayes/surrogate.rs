//! Gaussian-process surrogates: one per response (and one for feasibility), fitted with the
//! `friedrich` crate (its Cholesky factorisation and its ADAM fit of the kernel parameters).
//! This module supplies the kernel: an anisotropic squared exponential (one length-scale per
//! factor; the crate's kernels are isotropic) plus a white-noise term, and normalises the inputs
//! to `[0, 1]` and standardises the outputs before fitting. A response's surrogate ranges only
//! over the factors its experiment is given (the caller passes those columns alone).
//!
//! The length-scales are bounded below by what the data can resolve: a multiple
//! ([`Smoothness`]) of the side of the cell each distinct setting stands for in the unit box,
//! `m^(-1/d)` for `m` settings of `d` factors. Maximum likelihood on some 30 noisy runs in six
//! or seven factors otherwise finds length-scales short enough to bend the surrogate through
//! every run, calls the rest noise-free, and shares the response out among factors that do not
//! move it. The kernel's parameter is `ℓ − ℓ_min`, so the bound holds through the crate's
//! multiplicative updates; [`MAX_LENGTH_SCALE`] caps a factor that moves nothing.
//!
//! The noise is a kernel parameter rather than the crate's own `noise`, whose update multiplies
//! the logarithm of the noise (a step in the wrong direction whenever the noise is below 1). The
//! crate's noise is held at exactly 1 (its logarithm, 0, is a fixed point of that update) and
//! the outputs are scaled by [`OUTPUT_SCALE`] standard deviations, so it is a nugget of
//! `1/OUTPUT_SCALE` of the response's spread. The white-noise term must act on an observation
//! with itself only, not between replicates at the same setting, so each row carries its
//! observation's index as a last column (`-1` for points predicted at: no noise term).
//!
//! Of several starts of the fit, the one with the highest log marginal likelihood is kept,
//! computed here (`log_evidence`) from the covariance's Cholesky factor: the crate's own
//! `likelihood` sums the logarithms of the covariance's diagonal instead of its determinant, so
//! it does not penalise a surrogate that bends through every run.
//!
//! A factor's influence is its total-effect (Sobol) index under the surrogate's mean
//! ([`Surrogate::total_effects`]): the share of the response's variation over the box that is
//! left when every other factor is fixed, which a factor that moves nothing does not get however
//! its length-scale came out.

use friedrich::gaussian_process::GaussianProcess;
use friedrich::kernel::Kernel;
use friedrich::prior::{Prior, ZeroPrior};
use friedrich::{SMatrix, SRowVector, SVector};
use nalgebra::{storage::Storage, DMatrix, DVector, Dyn, U1};

use super::design;

/// Standardised outputs are multiplied by this, so that the crate's unit noise is a small
/// nugget (2 % of the response's standard deviation).
const OUTPUT_SCALE: f64 = 50.0;

/// The longest length-scale (normalised units): across a factor's whole range this long, the
/// kernel lets the response move by 5 % of its spread (`√(2(1 − e^(−1/800)))`).
const MAX_LENGTH_SCALE: f64 = 20.0;

/// The side of the cell each of `settings` distinct settings stands for in the unit box of
/// `dims` factors, `m^(-1/d)`.
fn cell_side(settings: usize, dims: usize) -> f64 {
    if dims == 0 {
        return 1.0;
    }
    (settings.max(1) as f64).powf(-1.0 / dims as f64)
}

/// How short a surrogate's length-scales may be, in sides of the cell each distinct setting
/// stands for ([`cell_side`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Smoothness {
    /// A measured response: two cells (1.15 of the range for 27 settings of 6 factors, 1.25
    /// for 7), chosen on the recorded runs of the paper's three targets
    /// (`tests/campaign/data/three_targets_bayesian_runs.json`, each run left out and the
    /// surrogate refitted without it) among 0.5, 1, 1.5, 2 and 3 cells. At two cells the
    /// left-out errors match the surrogates' own uncertainty best short of losing the angle
    /// (mean squared standardised error 1.7-1.9, against 2.2-4.7 at one cell or less and
    /// 2.4-3.4 unbounded; 1.4-1.6 at three cells, where the angle's error grows from 2.8° to
    /// 3.4°); the errors are 2.8°, 0.24 kPa and 1.09° (unbounded: 4.2°, 0.31 kPa, 1.17°); and
    /// the estimated run noise (angle of repose 1.0°, cohesion 0.11 kPa, friction angle 0.69°)
    /// is of the order of the seeds' spread (docs/aor.md: 24.9-28.8° over five seeds;
    /// docs/shear.md: 0.4 kPa between two samples), where the unbounded fit estimated 0.16°,
    /// 0.10 kPa and 0.03°.
    Response,
    /// The feasibility classifier (+1 / −1), whose failure region has an edge: half a cell.
    Feasibility,
}

impl Smoothness {
    fn cells(self) -> f64 {
        match self {
            Smoothness::Response => 2.0,
            Smoothness::Feasibility => 0.5,
        }
    }
}

/// Anisotropic squared exponential plus white noise:
/// `σ² exp(-½ Σ ((x_i - y_i)/ℓ_i)²) + σ_n² [same observation]`, parameters
/// `[ℓ_1 − ℓ_min, …, ℓ_d − ℓ_min, σ², σ_n²]` (the crate's update is multiplicative, so each
/// stays positive and every `ℓ_i` above `ℓ_min`; `ℓ_i` is capped at [`MAX_LENGTH_SCALE`]).
#[derive(Debug, Clone, Default)]
pub(crate) struct ArdSquaredExp {
    /// `ℓ_i − ℓ_min`.
    excess: Vec<f64>,
    min: f64,
    var: f64,
    noise_var: f64,
}

/// Whether two rows are the same observation (last column: its index, `-1` for none).
fn same_observation<S1: Storage<f64, U1, Dyn>, S2: Storage<f64, U1, Dyn>>(
    x1: &SRowVector<S1>,
    x2: &SRowVector<S2>,
) -> bool {
    let d = x1.len() - 1;
    x1[d] >= 0.0 && x1[d] == x2[d]
}

impl ArdSquaredExp {
    fn new(dims: usize, ls: f64, min: f64, noise_var: f64) -> Self {
        Self {
            excess: vec![(ls - min).max(1e-3); dims],
            min,
            var: OUTPUT_SCALE * OUTPUT_SCALE,
            noise_var,
        }
    }

    fn length_scale(&self, excess: f64) -> f64 {
        (self.min + excess.abs()).clamp(1e-6, MAX_LENGTH_SCALE)
    }

    /// Length-scales in normalised units.
    pub(crate) fn length_scales(&self) -> Vec<f64> {
        self.excess.iter().map(|e| self.length_scale(*e)).collect()
    }

    fn squared_exp<S1: Storage<f64, U1, Dyn>, S2: Storage<f64, U1, Dyn>>(
        &self,
        x1: &SRowVector<S1>,
        x2: &SRowVector<S2>,
    ) -> f64 {
        let r2: f64 = self
            .excess
            .iter()
            .enumerate()
            .map(|(i, e)| ((x1[i] - x2[i]) / self.length_scale(*e)).powi(2))
            .sum();
        self.var.abs() * (-0.5 * r2).exp()
    }
}

impl Kernel for ArdSquaredExp {
    fn nb_parameters(&self) -> usize {
        self.excess.len() + 2
    }

    fn kernel<S1: Storage<f64, U1, Dyn>, S2: Storage<f64, U1, Dyn>>(
        &self,
        x1: &SRowVector<S1>,
        x2: &SRowVector<S2>,
    ) -> f64 {
        let white = if same_observation(x1, x2) {
            self.noise_var.abs()
        } else {
            0.0
        };
        self.squared_exp(x1, x2) + white
    }

    fn gradient<S1: Storage<f64, U1, Dyn>, S2: Storage<f64, U1, Dyn>>(
        &self,
        x1: &SRowVector<S1>,
        x2: &SRowVector<S2>,
    ) -> Vec<f64> {
        let k = self.squared_exp(x1, x2);
        // ∂k/∂ℓ_i = k (x_i - y_i)² / ℓ_i³ and ∂ℓ_i/∂e_i = sign(e_i) below the cap, 0 above;
        // ∂k/∂σ² = k / σ²; ∂k/∂σ_n² = [same observation].
        let mut g: Vec<f64> = self
            .excess
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let l = self.length_scale(*e);
                if l >= MAX_LENGTH_SCALE {
                    return 0.0;
                }
                e.signum() * k * (x1[i] - x2[i]).powi(2) / (l * l * l)
            })
            .collect();
        g.push(k / self.var.abs().max(1e-12));
        g.push(if same_observation(x1, x2) { 1.0 } else { 0.0 });
        g
    }

    fn get_parameters(&self) -> Vec<f64> {
        let mut p = self.excess.clone();
        p.push(self.var);
        p.push(self.noise_var);
        p
    }

    fn set_parameters(&mut self, parameters: &[f64]) {
        let d = self.excess.len();
        // Past the cap the length-scale is the cap (and its gradient zero).
        for (e, p) in self.excess.iter_mut().zip(&parameters[..d]) {
            *e = p.clamp(-MAX_LENGTH_SCALE, MAX_LENGTH_SCALE);
        }
        self.var = parameters[d];
        self.noise_var = parameters[d + 1];
    }

    fn heuristic_fit<SM: Storage<f64, Dyn, Dyn>, SV: Storage<f64, Dyn, U1>>(
        &mut self,
        _inputs: &SMatrix<SM>,
        _outputs: &SVector<SV>,
    ) {
    }
}

/// A fitted surrogate of one response over the normalised box of its own factors.
pub(crate) struct Surrogate {
    gp: GaussianProcess<ArdSquaredExp, ZeroPrior>,
    mean: f64,
    scale: f64,
    rows: usize,
}

impl std::fmt::Debug for Surrogate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Surrogate")
            .field("length_scales", &self.length_scales())
            .field("min_length_scale", &self.gp.kernel.min)
            .field("noise_sd", &self.noise_sd())
            .field("mean", &self.mean)
            .field("rows", &self.rows)
            .field("scale", &self.scale)
            .finish()
    }
}

/// A prediction in response units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Prediction {
    /// Posterior mean of the noise-free response.
    pub mean: f64,
    /// Posterior standard deviation of the noise-free response.
    pub sd: f64,
    /// Estimated standard deviation of one run's noise.
    pub noise_sd: f64,
}

/// The variation of a surrogate's mean over the box and each factor's part in it.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Effects {
    /// Variance of the mean over the uniform box, in response units squared.
    pub variance: f64,
    /// Each factor's total-effect index: the share of that variance left when every other
    /// factor is known (0 where the variance is 0).
    pub total: Vec<f64>,
}

/// Base samples of the total-effect estimate (each factor costs as many predictions more).
const EFFECT_SAMPLES: usize = 512;
/// The random stream of the estimate: fixed, so an assessment is reproducible.
const EFFECT_SEED: u64 = 0x5AB0_1E55;

/// Optimiser iterations per start, and the starting length-scales (normalised units; a start
/// below the data's shortest length-scale starts at it).
const FIT_ITERATIONS: usize = 200;
const START_LENGTH_SCALES: [f64; 3] = [0.15, 0.4, 1.2];

/// A row: the normalised point and the observation index (`-1`: none).
fn row(u: &[f64], id: f64) -> Vec<f64> {
    let mut r = u.to_vec();
    r.push(id);
    r
}

/// The number of distinct settings among `u`.
fn distinct(u: &[Vec<f64>]) -> usize {
    let mut seen: Vec<&Vec<f64>> = Vec::new();
    for p in u {
        if !seen.contains(&p) {
            seen.push(p);
        }
    }
    seen.len()
}

/// `ln p(z)`: the Gaussian log marginal likelihood `−½ zᵀK⁻¹z − ½ ln|K| − ½ n ln 2π` of the
/// standardised outputs `z` under `kernel` with the crate's `nugget`; `None` where the
/// covariance is not positive definite.
fn log_evidence(kernel: &ArdSquaredExp, nugget: f64, rows: &[Vec<f64>], z: &[f64]) -> Option<f64> {
    let n = rows.len();
    let r: Vec<DMatrix<f64>> = rows
        .iter()
        .map(|r| DMatrix::from_row_slice(1, r.len(), r))
        .collect();
    let k = DMatrix::from_fn(n, n, |i, j| {
        kernel.kernel(&r[i].row(0), &r[j].row(0)) + if i == j { nugget * nugget } else { 0.0 }
    });
    let chol = k.cholesky()?;
    let z = DVector::from_column_slice(z);
    let alpha = chol.solve(&z);
    let log_det: f64 = 2.0 * chol.l().diagonal().iter().map(|v| v.ln()).sum::<f64>();
    let evidence = -0.5 * (z.dot(&alpha) + log_det + n as f64 * (2.0 * std::f64::consts::PI).ln());
    evidence.is_finite().then_some(evidence)
}

impl Surrogate {
    /// Fits `y` over the normalised points `u` (each in `[0, 1]^d`), its length-scales bounded
    /// below as `smoothness` says; `None` with fewer than two points. Several starts of the
    /// likelihood fit, the most likely kept.
    pub(crate) fn fit(u: &[Vec<f64>], y: &[f64], smoothness: Smoothness) -> Option<Surrogate> {
        if u.len() < 2 || u.len() != y.len() {
            return None;
        }
        let n = y.len() as f64;
        let mean = y.iter().sum::<f64>() / n;
        let var = y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        let scale = if var.sqrt() > 1e-12 { var.sqrt() } else { 1.0 } / OUTPUT_SCALE;
        let z: Vec<f64> = y.iter().map(|v| (v - mean) / scale).collect();
        let rows: Vec<Vec<f64>> = u
            .iter()
            .enumerate()
            .map(|(i, p)| row(p, i as f64))
            .collect();
        let dims = u[0].len();
        let min = smoothness.cells() * cell_side(distinct(u), dims);
        let mut best: Option<(f64, GaussianProcess<ArdSquaredExp, ZeroPrior>)> = None;
        for ls in START_LENGTH_SCALES {
            for noise in [0.01, 0.2] {
                let noise_var = (noise * OUTPUT_SCALE).powi(2);
                let mut gp = GaussianProcess::new(
                    <ZeroPrior as Prior>::default(dims + 1),
                    ArdSquaredExp::new(dims, ls.max(min), min, noise_var),
                    1.0,
                    Some(1e-6),
                    rows.clone(),
                    z.clone(),
                );
                gp.fit_parameters(
                    false,
                    true,
                    FIT_ITERATIONS,
                    0.001,
                    chrono::Duration::hours(1),
                );
                let Some(evidence) = log_evidence(&gp.kernel, gp.noise, &rows, &z) else {
                    continue;
                };
                if best.as_ref().is_none_or(|(l, _)| evidence > *l) {
                    best = Some((evidence, gp));
                }
            }
        }
        best.map(|(_, gp)| Surrogate {
            gp,
            mean,
            scale,
            rows: u.len(),
        })
    }

    /// Predictions at the normalised points `u`.
    pub(crate) fn predict(&self, u: &[Vec<f64>]) -> Vec<Prediction> {
        if u.is_empty() {
            return Vec::new();
        }
        let rows: Vec<Vec<f64>> = u.iter().map(|p| row(p, -1.0)).collect();
        let (m, v) = self.gp.predict_mean_variance(&rows);
        let noise_sd = self.noise_sd();
        m.iter()
            .zip(&v)
            .map(|(m, v)| Prediction {
                mean: self.mean + m * self.scale,
                sd: v.max(0.0).sqrt() * self.scale,
                noise_sd,
            })
            .collect()
    }

    /// The posterior means alone at the normalised points `u` (response units).
    pub(crate) fn means(&self, u: &[Vec<f64>]) -> Vec<f64> {
        if u.is_empty() {
            return Vec::new();
        }
        let rows: Vec<Vec<f64>> = u.iter().map(|p| row(p, -1.0)).collect();
        self.gp
            .predict(&rows)
            .iter()
            .map(|m| self.mean + m * self.scale)
            .collect()
    }

    /// The total-effect (Sobol) indices of the posterior mean over the unit box, by Jansen's
    /// estimator on two Latin hypercubes `A` and `B`: `T_i = E[(f(A) − f(A with column i of
    /// B))²] / (2 Var f)`.
    pub(crate) fn total_effects(&self) -> Effects {
        let dims = self.gp.kernel.excess.len();
        let mut rng = design::rng(EFFECT_SEED, 0, 0);
        let a = design::latin_hypercube(EFFECT_SAMPLES, dims, &mut rng);
        let b = design::latin_hypercube(EFFECT_SAMPLES, dims, &mut rng);
        let fa = self.means(&a);
        let fb = self.means(&b);
        let all: Vec<f64> = fa.iter().chain(&fb).copied().collect();
        let m = all.iter().sum::<f64>() / all.len() as f64;
        let variance = all.iter().map(|v| (v - m).powi(2)).sum::<f64>() / all.len() as f64;
        // A mean flat to rounding has no variation to share out.
        if variance <= (1e-12 * self.scale * OUTPUT_SCALE).powi(2) {
            return Effects {
                variance: 0.0,
                total: vec![0.0; dims],
            };
        }
        let total = (0..dims)
            .map(|i| {
                let mixed: Vec<Vec<f64>> = a
                    .iter()
                    .zip(&b)
                    .map(|(pa, pb)| {
                        let mut p = pa.clone();
                        p[i] = pb[i];
                        p
                    })
                    .collect();
                let fm = self.means(&mixed);
                let s: f64 = fa.iter().zip(&fm).map(|(x, y)| (x - y).powi(2)).sum();
                s / (2.0 * EFFECT_SAMPLES as f64 * variance)
            })
            .collect();
        Effects { variance, total }
    }

    /// The shortest length-scale this surrogate's data support (normalised units).
    pub(crate) fn min_length_scale(&self) -> f64 {
        self.gp.kernel.min
    }

    /// Adds a point at its believed value (kriging believer), keeping the hyper-parameters.
    pub(crate) fn believe(&mut self, u: &[f64], value: f64) {
        let r = row(u, self.rows as f64);
        self.rows += 1;
        self.gp
            .add_samples(&vec![r], &vec![(value - self.mean) / self.scale]);
    }

    /// The fitted length-scales (normalised units).
    pub(crate) fn length_scales(&self) -> Vec<f64> {
        self.gp.kernel.length_scales()
    }

    /// The estimated noise standard deviation of one run, in response units (the white-noise
    /// term and the nugget).
    pub(crate) fn noise_sd(&self) -> f64 {
        (self.gp.kernel.noise_var.abs() + self.gp.noise * self.gp.noise).sqrt() * self.scale
    }
}

#[cfg(test)]
mod tests {
    use rand_distr::{Distribution, Normal};

    use super::*;
    use crate::campaign::bayes::design;

    fn truth(x: &[f64]) -> f64 {
        1.0 + 2.0 * x[2] + 0.8 * x[1] * x[1]
    }

    #[test]
    fn a_smooth_response_is_interpolated_and_its_idle_factor_found() {
        let u = design::maximin_start(16, 3, &mut design::rng(1, 0, 1));
        let y: Vec<f64> = u.iter().map(|x| truth(x)).collect();
        let s = Surrogate::fit(&u, &y, Smoothness::Response).unwrap();
        let test = design::latin_hypercube(20, 3, &mut design::rng(2, 0, 1));
        for (x, p) in test.iter().zip(s.predict(&test)) {
            assert!((p.mean - truth(x)).abs() < 0.06, "{x:?}: {p:?}");
            assert!(
                (p.mean - truth(x)).abs() < 4.0 * p.sd.max(0.01),
                "{x:?}: {p:?}"
            );
        }
        // Factor 0 moves nothing: its length-scale is the longest.
        let ls = s.length_scales();
        assert!(ls[0] > ls[1] && ls[0] > ls[2], "{ls:?}");
    }

    #[test]
    fn the_noise_of_replicates_is_estimated() {
        let u = design::maximin_start(20, 3, &mut design::rng(4, 0, 1));
        let normal = Normal::new(0.0, 0.1).unwrap();
        let mut rng = design::rng(5, 0, 0);
        let mut points = Vec::new();
        let mut y = Vec::new();
        for x in &u {
            for _ in 0..3 {
                points.push(x.clone());
                y.push(truth(x) + normal.sample(&mut rng));
            }
        }
        let s = Surrogate::fit(&points, &y, Smoothness::Response).unwrap();
        let noise = s.noise_sd();
        assert!((0.06..0.15).contains(&noise), "noise sd {noise}, true 0.1");
        let test = design::latin_hypercube(10, 3, &mut design::rng(6, 0, 1));
        for (x, p) in test.iter().zip(s.predict(&test)) {
            // The mean of many noisy runs is known much better than one run.
            assert!((p.mean - truth(x)).abs() < 0.15, "{x:?}: {p:?}");
            assert!(p.sd < noise, "{p:?}");
        }
    }

    #[test]
    fn total_effects_share_an_additive_response_by_its_terms() {
        // y = 3 x0 + x1: variances 9/12 and 1/12 over the box, shares 0.9 and 0.1; x2 idle.
        let u = design::maximin_start(30, 3, &mut design::rng(8, 0, 1));
        let y: Vec<f64> = u.iter().map(|x| 3.0 * x[0] + x[1]).collect();
        let s = Surrogate::fit(&u, &y, Smoothness::Response).unwrap();
        let e = s.total_effects();
        let sum: f64 = e.total.iter().sum();
        let share: Vec<f64> = e.total.iter().map(|t| t / sum).collect();
        assert!((share[0] - 0.9).abs() < 0.03, "{share:?}");
        assert!((share[1] - 0.1).abs() < 0.03, "{share:?}");
        assert!(share[2] < 0.01, "{share:?}");
        assert!((e.variance - 10.0 / 12.0).abs() < 0.05, "{e:?}");
        // No length-scale below two cells of 30 settings in three factors.
        let min = 2.0 * 30f64.powf(-1.0 / 3.0);
        assert!((s.min_length_scale() - min).abs() < 1e-12);
        assert!(s.length_scales().iter().all(|l| *l >= min), "{s:?}");
    }
}
