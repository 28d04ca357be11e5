//! Particle size distributions: where new particles' radii come from.
//!
//! Written in run configurations as [`SizeDistributionSpec`] (a tagged enum) and validated into
//! a [`SizeDistribution`], which is the only thing that can be sampled, so sampling never sees
//! an invalid table.
//!
//! Fixed, uniform and normal distributions are given as **radii** and are number-based (every
//! particle is an independent draw). A sieve table is given as **sieve sizes** (apertures,
//! i.e. particle diameters) against the cumulative **mass** fraction passing, as in a
//! laboratory grading curve; sampling converts it so that the *mass* of the sampled particles
//! follows the table.

use rand::Rng;
use serde::{Deserialize, Serialize};

/// Why a size distribution was rejected; names the field and value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DistributionError {
    #[error("{field} = {value} must be finite and > 0")]
    NotPositive { field: String, value: f64 },
    #[error("{field} = {value} must not be smaller than {other_field} = {other}")]
    Order {
        field: String,
        value: f64,
        other_field: String,
        other: f64,
    },
    #[error("normal distribution: the window [{min_radius}, {max_radius}] holds only {probability:.2e} of the probability (at least 1e-3 needed)")]
    EmptyWindow {
        min_radius: f64,
        max_radius: f64,
        probability: f64,
    },
    #[error("sieve table is empty")]
    EmptyTable,
    #[error("sieve table row {row}: passing = {value} must be within [0, 1]")]
    FractionOutOfRange { row: usize, value: f64 },
    #[error(
        "sieve table row {row}: size = {size} m must be larger than the previous size {previous} m"
    )]
    SizesNotIncreasing {
        row: usize,
        size: f64,
        previous: f64,
    },
    #[error("sieve table row {row}: passing = {value} is less than the previous row's {previous} (must be cumulative)")]
    FractionsDecreasing {
        row: usize,
        value: f64,
        previous: f64,
    },
    #[error(
        "sieve table: last row's passing = {value} must be 1 (all mass passes the largest size)"
    )]
    LastFractionNotOne { value: f64 },
}

/// One row of a grading curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SieveRow {
    /// Sieve aperture = particle diameter (m).
    pub size: f64,
    /// Cumulative mass fraction passing this sieve, in [0, 1].
    pub passing: f64,
}

/// A size distribution as written in a configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SizeDistributionSpec {
    /// Every particle has `radius` (m).
    Fixed { radius: f64 },
    /// Radius uniform in `[min_radius, max_radius]` (m).
    Uniform { min_radius: f64, max_radius: f64 },
    /// Normal radius distribution truncated to `[min_radius, max_radius]` (m).
    Normal {
        mean_radius: f64,
        std_dev: f64,
        min_radius: f64,
        max_radius: f64,
    },
    /// Grading curve: rows sorted by size, cumulative mass fraction passing, last = 1.
    /// Mass passing the smallest sieve (the pan) is given the smallest size; within each
    /// sieve interval diameters are number-uniform.
    SieveTable { rows: Vec<SieveRow> },
}

/// A bin of the sieve table prepared for sampling.
#[derive(Debug, Clone, PartialEq)]
struct SieveBin {
    /// Diameter range (m); equal for the pan bin.
    lo: f64,
    hi: f64,
    /// Cumulative number probability up to and including this bin.
    cumulative_number: f64,
}

/// A validated size distribution; sample radii with [`SizeDistribution::sample`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "SizeDistributionSpec", into = "SizeDistributionSpec")]
pub struct SizeDistribution {
    spec: SizeDistributionSpec,
    sieve_bins: Vec<SieveBin>,
}

impl TryFrom<SizeDistributionSpec> for SizeDistribution {
    type Error = DistributionError;
    fn try_from(spec: SizeDistributionSpec) -> Result<Self, DistributionError> {
        SizeDistribution::new(spec)
    }
}

impl From<SizeDistribution> for SizeDistributionSpec {
    fn from(d: SizeDistribution) -> Self {
        d.spec
    }
}

fn positive(field: &str, value: f64) -> Result<(), DistributionError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(DistributionError::NotPositive {
            field: field.to_owned(),
            value,
        })
    }
}

fn ordered(
    field: &str,
    value: f64,
    other_field: &str,
    other: f64,
) -> Result<(), DistributionError> {
    if value >= other {
        Ok(())
    } else {
        Err(DistributionError::Order {
            field: field.to_owned(),
            value,
            other_field: other_field.to_owned(),
            other,
        })
    }
}

/// Standard normal CDF (Abramowitz & Stegun 7.1.26 erf, |error| < 1.5e-7): only used to check
/// that a truncation window is not hopelessly far in a tail.
fn standard_normal_cdf(x: f64) -> f64 {
    let z = x.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * z);
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erf = 1.0 - poly * (-z * z).exp();
    if x >= 0.0 {
        0.5 * (1.0 + erf)
    } else {
        0.5 * (1.0 - erf)
    }
}

/// Attempts before truncated-normal rejection sampling gives up and returns the window's
/// nearest point to the mean; with ≥ 1e-3 of the mass in the window this essentially never
/// happens (probability < e^-10).
const NORMAL_MAX_ATTEMPTS: usize = 10_000;

impl SizeDistribution {
    pub fn new(spec: SizeDistributionSpec) -> Result<SizeDistribution, DistributionError> {
        let mut sieve_bins = Vec::new();
        match &spec {
            SizeDistributionSpec::Fixed { radius } => positive("radius", *radius)?,
            SizeDistributionSpec::Uniform {
                min_radius,
                max_radius,
            } => {
                positive("min_radius", *min_radius)?;
                positive("max_radius", *max_radius)?;
                ordered("max_radius", *max_radius, "min_radius", *min_radius)?;
            }
            SizeDistributionSpec::Normal {
                mean_radius,
                std_dev,
                min_radius,
                max_radius,
            } => {
                positive("mean_radius", *mean_radius)?;
                positive("std_dev", *std_dev)?;
                positive("min_radius", *min_radius)?;
                positive("max_radius", *max_radius)?;
                ordered("max_radius", *max_radius, "min_radius", *min_radius)?;
                let probability = standard_normal_cdf((max_radius - mean_radius) / std_dev)
                    - standard_normal_cdf((min_radius - mean_radius) / std_dev);
                if probability.is_nan() || probability < 1e-3 {
                    return Err(DistributionError::EmptyWindow {
                        min_radius: *min_radius,
                        max_radius: *max_radius,
                        probability,
                    });
                }
            }
            SizeDistributionSpec::SieveTable { rows } => sieve_bins = sieve_bins_from(rows)?,
        }
        Ok(SizeDistribution { spec, sieve_bins })
    }

    pub fn spec(&self) -> &SizeDistributionSpec {
        &self.spec
    }

    /// Smallest radius that can be sampled (m).
    pub fn min_radius(&self) -> f64 {
        match &self.spec {
            SizeDistributionSpec::Fixed { radius } => *radius,
            SizeDistributionSpec::Uniform { min_radius, .. }
            | SizeDistributionSpec::Normal { min_radius, .. } => *min_radius,
            SizeDistributionSpec::SieveTable { .. } => {
                0.5 * self.sieve_bins.first().map_or(0.0, |b| b.lo)
            }
        }
    }

    /// Mean of the cubed diameter over the particles drawn, E[d³] (m³; number-weighted): a mass
    /// M of density ρ makes M / (ρ π/6 E[d³]) particles in expectation.
    pub fn mean_cubed_diameter(&self) -> f64 {
        // E[d³] for d number-uniform on [lo, hi] (diameters).
        let uniform = |lo: f64, hi: f64| {
            if hi > lo {
                (hi.powi(4) - lo.powi(4)) / (4.0 * (hi - lo))
            } else {
                lo.powi(3)
            }
        };
        match &self.spec {
            SizeDistributionSpec::Fixed { radius } => (2.0 * radius).powi(3),
            SizeDistributionSpec::Uniform {
                min_radius,
                max_radius,
            } => uniform(2.0 * min_radius, 2.0 * max_radius),
            SizeDistributionSpec::Normal {
                mean_radius,
                std_dev,
                min_radius,
                max_radius,
            } => {
                // Simpson's rule over the truncation window, weight ∝ the normal density.
                const INTERVALS: usize = 2000;
                let h = (max_radius - min_radius) / INTERVALS as f64;
                let (mut weight, mut moment) = (0.0, 0.0);
                for k in 0..=INTERVALS {
                    let r = min_radius + h * k as f64;
                    let simpson = if k == 0 || k == INTERVALS {
                        1.0
                    } else if k % 2 == 1 {
                        4.0
                    } else {
                        2.0
                    };
                    let density = (-0.5 * ((r - mean_radius) / std_dev).powi(2)).exp();
                    weight += simpson * density;
                    moment += simpson * density * (2.0 * r).powi(3);
                }
                if weight > 0.0 {
                    moment / weight
                } else {
                    (2.0 * mean_radius.clamp(*min_radius, *max_radius)).powi(3)
                }
            }
            SizeDistributionSpec::SieveTable { .. } => {
                let mut previous = 0.0;
                self.sieve_bins
                    .iter()
                    .map(|b| {
                        let p = b.cumulative_number - previous;
                        previous = b.cumulative_number;
                        p * uniform(b.lo, b.hi)
                    })
                    .sum()
            }
        }
    }

    /// Largest radius that can be sampled (m).
    pub fn max_radius(&self) -> f64 {
        match &self.spec {
            SizeDistributionSpec::Fixed { radius } => *radius,
            SizeDistributionSpec::Uniform { max_radius, .. }
            | SizeDistributionSpec::Normal { max_radius, .. } => *max_radius,
            SizeDistributionSpec::SieveTable { .. } => {
                0.5 * self.sieve_bins.last().map_or(0.0, |b| b.hi)
            }
        }
    }

    /// Draws one particle radius (m).
    pub fn sample(&self, rng: &mut impl Rng) -> f64 {
        match &self.spec {
            SizeDistributionSpec::Fixed { radius } => *radius,
            SizeDistributionSpec::Uniform {
                min_radius,
                max_radius,
            } => min_radius + (max_radius - min_radius) * rng.gen::<f64>(),
            SizeDistributionSpec::Normal {
                mean_radius,
                std_dev,
                min_radius,
                max_radius,
            } => {
                for _ in 0..NORMAL_MAX_ATTEMPTS {
                    // Box–Muller; 1 - u keeps the logarithm's argument in (0, 1].
                    let u1: f64 = 1.0 - rng.gen::<f64>();
                    let u2: f64 = rng.gen();
                    let z = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
                    let r = mean_radius + std_dev * z;
                    if (*min_radius..=*max_radius).contains(&r) {
                        return r;
                    }
                }
                mean_radius.clamp(*min_radius, *max_radius)
            }
            SizeDistributionSpec::SieveTable { .. } => {
                let u: f64 = rng.gen();
                let bin = self
                    .sieve_bins
                    .iter()
                    .find(|b| u < b.cumulative_number)
                    .or(self.sieve_bins.last());
                match bin {
                    Some(b) => 0.5 * (b.lo + (b.hi - b.lo) * rng.gen::<f64>()),
                    None => 0.0, // unreachable: validation guarantees at least one bin
                }
            }
        }
    }
}

/// Turns a grading curve into bins with cumulative *number* probabilities.
///
/// Bin i holds mass fraction Δᵢ. With diameters number-uniform on [a, b] the mean particle
/// mass is ∝ E[d³] = (b⁴ − a⁴) / (4 (b − a)), so the number of particles needed is ∝ Δᵢ / E[d³];
/// drawing bins with those probabilities reproduces Δᵢ in expectation exactly.
fn sieve_bins_from(rows: &[SieveRow]) -> Result<Vec<SieveBin>, DistributionError> {
    let Some(last) = rows.last() else {
        return Err(DistributionError::EmptyTable);
    };
    for (row, r) in rows.iter().enumerate() {
        positive(&format!("rows[{row}].size"), r.size)?;
        if !(0.0..=1.0).contains(&r.passing) {
            return Err(DistributionError::FractionOutOfRange {
                row,
                value: r.passing,
            });
        }
        if row > 0 {
            let previous = rows[row - 1];
            if r.size <= previous.size {
                return Err(DistributionError::SizesNotIncreasing {
                    row,
                    size: r.size,
                    previous: previous.size,
                });
            }
            if r.passing < previous.passing {
                return Err(DistributionError::FractionsDecreasing {
                    row,
                    value: r.passing,
                    previous: previous.passing,
                });
            }
        }
    }
    if (last.passing - 1.0).abs() > 1e-6 {
        return Err(DistributionError::LastFractionNotOne {
            value: last.passing,
        });
    }
    // (lo, hi, mass fraction); the pan bin is the point at the smallest size.
    let mut bins: Vec<(f64, f64, f64)> = vec![(rows[0].size, rows[0].size, rows[0].passing)];
    for w in rows.windows(2) {
        bins.push((w[0].size, w[1].size, w[1].passing - w[0].passing));
    }
    bins.retain(|&(_, _, mass)| mass > 0.0);
    let mean_cube = |lo: f64, hi: f64| {
        if hi > lo {
            (hi.powi(4) - lo.powi(4)) / (4.0 * (hi - lo))
        } else {
            lo.powi(3)
        }
    };
    let weights: Vec<f64> = bins
        .iter()
        .map(|&(lo, hi, mass)| mass / mean_cube(lo, hi))
        .collect();
    let total: f64 = weights.iter().sum();
    let mut cumulative = 0.0;
    let mut out: Vec<SieveBin> = bins
        .iter()
        .zip(&weights)
        .map(|(&(lo, hi, _), w)| {
            cumulative += w / total;
            SieveBin {
                lo,
                hi,
                cumulative_number: cumulative,
            }
        })
        .collect();
    if let Some(b) = out.last_mut() {
        b.cumulative_number = 1.0; // no rounding gap at the top
    }
    Ok(out)
}
