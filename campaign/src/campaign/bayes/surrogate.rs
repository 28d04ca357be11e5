//! Gaussian-process surrogates: one per response (and one for feasibility), fitted with the
//! `friedrich` crate (its Cholesky factorisation, its marginal likelihood and its ADAM fit of
//! the kernel parameters). This module supplies the kernel: an anisotropic squared exponential
//! (one length-scale per factor; the crate's kernels are isotropic) plus a white-noise term, and
//! normalises the inputs to `[0, 1]` and standardises the outputs before fitting.
//!
//! The noise is a kernel parameter rather than the crate's own `noise`, whose update multiplies
//! the logarithm of the noise (a step in the wrong direction whenever the noise is below 1). The
//! crate's noise is held at exactly 1 (its logarithm, 0, is a fixed point of that update) and
//! the outputs are scaled by [`OUTPUT_SCALE`] standard deviations, so it is a nugget of
//! `1/OUTPUT_SCALE` of the response's spread. The white-noise term must act on an observation
//! with itself only, not between replicates at the same setting, so each row carries its
//! observation's index as a last column (`-1` for points predicted at: no noise term).

use friedrich::gaussian_process::GaussianProcess;
use friedrich::kernel::Kernel;
use friedrich::prior::{Prior, ZeroPrior};
use friedrich::{SMatrix, SRowVector, SVector};
use nalgebra::{storage::Storage, Dyn, U1};

/// Standardised outputs are multiplied by this, so that the crate's unit noise is a small
/// nugget (2 % of the response's standard deviation).
const OUTPUT_SCALE: f64 = 50.0;

/// Anisotropic squared exponential plus white noise:
/// `σ² exp(-½ Σ ((x_i - y_i)/ℓ_i)²) + σ_n² [same observation]`, parameters
/// `[ℓ_1, …, ℓ_d, σ², σ_n²]` (all positive; the crate's update is multiplicative).
#[derive(Debug, Clone, Default)]
pub(crate) struct ArdSquaredExp {
    ls: Vec<f64>,
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
    fn new(dims: usize, ls: f64, noise_var: f64) -> Self {
        Self {
            ls: vec![ls; dims],
            var: OUTPUT_SCALE * OUTPUT_SCALE,
            noise_var,
        }
    }

    /// Length-scales in normalised units.
    pub(crate) fn length_scales(&self) -> Vec<f64> {
        self.ls.iter().map(|l| l.abs().max(1e-6)).collect()
    }

    fn squared_exp<S1: Storage<f64, U1, Dyn>, S2: Storage<f64, U1, Dyn>>(
        &self,
        x1: &SRowVector<S1>,
        x2: &SRowVector<S2>,
    ) -> f64 {
        let r2: f64 = self
            .ls
            .iter()
            .enumerate()
            .map(|(i, l)| ((x1[i] - x2[i]) / l.abs().max(1e-6)).powi(2))
            .sum();
        self.var.abs() * (-0.5 * r2).exp()
    }
}

impl Kernel for ArdSquaredExp {
    fn nb_parameters(&self) -> usize {
        self.ls.len() + 2
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
        // ∂k/∂ℓ_i = k (x_i - y_i)² / ℓ_i³; ∂k/∂σ² = k / σ²; ∂k/∂σ_n² = [same observation].
        let mut g: Vec<f64> = self
            .ls
            .iter()
            .enumerate()
            .map(|(i, l)| {
                let l = l.abs().max(1e-6);
                k * (x1[i] - x2[i]).powi(2) / (l * l * l)
            })
            .collect();
        g.push(k / self.var.abs().max(1e-12));
        g.push(if same_observation(x1, x2) { 1.0 } else { 0.0 });
        g
    }

    fn get_parameters(&self) -> Vec<f64> {
        let mut p = self.ls.clone();
        p.push(self.var);
        p.push(self.noise_var);
        p
    }

    fn set_parameters(&mut self, parameters: &[f64]) {
        let d = self.ls.len();
        self.ls.copy_from_slice(&parameters[..d]);
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

/// A fitted surrogate of one response over the normalised box.
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

/// Optimiser iterations per start, and the starting length-scales (normalised units).
const FIT_ITERATIONS: usize = 200;
const START_LENGTH_SCALES: [f64; 3] = [0.15, 0.4, 1.2];

/// A row: the normalised point and the observation index (`-1`: none).
fn row(u: &[f64], id: f64) -> Vec<f64> {
    let mut r = u.to_vec();
    r.push(id);
    r
}

impl Surrogate {
    /// Fits `y` over the normalised points `u` (each in `[0, 1]^d`); `None` with fewer than two
    /// points. Several starts of the likelihood fit, the most likely kept.
    pub(crate) fn fit(u: &[Vec<f64>], y: &[f64]) -> Option<Surrogate> {
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
        let mut best: Option<(f64, GaussianProcess<ArdSquaredExp, ZeroPrior>)> = None;
        for ls in START_LENGTH_SCALES {
            for noise in [0.01, 0.2] {
                let noise_var = (noise * OUTPUT_SCALE).powi(2);
                let mut gp = GaussianProcess::new(
                    <ZeroPrior as Prior>::default(dims + 1),
                    ArdSquaredExp::new(dims, ls, noise_var),
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
                let likelihood = gp.likelihood();
                if !likelihood.is_finite() {
                    continue;
                }
                if best.as_ref().is_none_or(|(l, _)| likelihood > *l) {
                    best = Some((likelihood, gp));
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
        let s = Surrogate::fit(&u, &y).unwrap();
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
        let s = Surrogate::fit(&points, &y).unwrap();
        let noise = s.noise_sd();
        assert!((0.06..0.15).contains(&noise), "noise sd {noise}, true 0.1");
        let test = design::latin_hypercube(10, 3, &mut design::rng(6, 0, 1));
        for (x, p) in test.iter().zip(s.predict(&test)) {
            // The mean of many noisy runs is known much better than one run.
            assert!((p.mean - truth(x)).abs() < 0.15, "{x:?}: {p:?}");
            assert!(p.sd < noise, "{p:?}");
        }
    }
}
