//! Angle of repose of a settled granular pile, measured from the final particle positions.
//!
//! Two complementary readings are made, because they answer different questions:
//!
//! * **Half-plane profiles** (the "3-D" reading, [`AngleOfRepose::angle_deg`]): the pile surface
//!   is sampled in `K` vertical half-planes through the pile axis, a straight line is fitted to
//!   each flank, and the `K` angles are averaged. The spread across directions tells how
//!   axisymmetric the pile is, which a single photograph cannot.
//! * **Side projection** (the paper's reading, [`AngleOfRepose::left_deg`] /
//!   [`AngleOfRepose::right_deg`]): all particles are projected onto a vertical plane, exactly
//!   like a photograph taken from the side, and a line is fitted to the left and to the right flank
//!   of the silhouette. This is what the reference experiment measured (binarised photo, edge
//!   detection, one line per flank), so it is the number to compare with the paper's 34.85°.
//!
//! Both fits use only the part of the flank whose height lies between 20 % and 80 % of the pile
//! height (configurable): the rounded apex and the toe, where grains roll out onto the base, are
//! not part of the "repose" slope and would bias a straight-line fit.
//!
//! # Robustness choices (documented here once)
//!
//! * **Which particles belong to the pile.** Particles that are not finite, have a non-positive
//!   radius, or whose centre is more than one radius below the base plane (they fell off the
//!   plate or tunnelled through it) are discarded. The remaining particles are grouped into
//!   clusters of grains that touch or nearly touch (surface gap at most `contact_gap_diameters`);
//!   the pile is the largest cluster that rests on the base (or, when the funnel axis is given,
//!   the cluster resting on the base nearest to it). A grain that bounced away, or one still in
//!   flight above the heap, is its own cluster and is ignored; every grain of the pile is
//!   supported down to the base through a chain of contacts. (A flying grain closer than the gap
//!   to the surface is counted as resting on it; at half a grain that changes no slope.)
//! * **Pile axis.** The given funnel axis, else the centroid of the grains in the lower third of
//!   the pile (the footprint centre; the lower part is wide and well populated, the apex is not).
//!   Each half-plane is a slab of half-width `slab_half_width_diameters` that starts half a slab
//!   behind the axis, so the axis column is seen whole by every direction.
//! * **Surface height of a column** (a radial bin of a half-plane, or one abscissa of the
//!   silhouette) is the top (`z + radius`) of the highest grain of the pile in it. A half-plane bin
//!   is a surface point only if it holds at least `min_particles_per_bin` grains, so a single grain
//!   that rolled out beyond the toe does not extend the profile.
//! * **Radial contiguity.** A profile is followed outward from the axis and ends at the toe: after
//!   more than `max_missing_bins` consecutive bins without a valid surface point nothing further
//!   out is used. The silhouette is followed left and right from its highest point the same way.
//! * **Robust line fits.** Within the band, a least-squares line is fitted, then points further
//!   from it than `outlier_rejection_sigmas` robust standard deviations (and more than half a
//!   grain) are dropped and the line refitted, up to three times. A loose surface has holes (a bin
//!   whose highest grain sits a grain or two below its neighbours); one such hole in a dozen bins
//!   would otherwise tilt a direction by a few degrees. `FlankFit::rejected` says how many went.
//! * **Pile height** is the top of the highest grain found in any half-plane profile above the
//!   base (the maximum of `h` near the axis; robust because flying grains are already excluded).
//!   The side projection has its own apex and height, used for its own band.
//! * **Base diameter** is twice the mean, over the `K` directions, of the radius at which the
//!   fitted flank line reaches the base plane (extrapolating the fit, rather than looking for the
//!   outermost grain, so that a single grain that rolled out does not change it).
//!
//! # Errors rather than angles
//!
//! A run whose grains escaped, never settled into a heap, or spread into a single layer has no
//! angle of repose, so [`measure_angle_of_repose`] returns `Err(MeasureError)` in that case
//! instead of a meaningless number. A heap that is merely low is not such a case: a mound two or
//! three grains high on a carpet of grains has a slope, and its (low) angle is the result. The
//! line between the two is a second layer of grains (`min_height_diameters`). Every `Ok` result
//! has all its numbers finite.

use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use thiserror::Error;

/// Knobs of the measurement. Lengths are given in particle diameters where they are about the
/// granularity of the surface (so the same settings work for any grain size), in metres where they
/// are about the experiment's geometry.
///
/// The particle diameter `d` used throughout is twice the median radius of the usable particles,
/// so a polydisperse sample is measured at the scale of its typical grain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MeasureSettings {
    /// Number `K` of vertical half-planes through the axis, at evenly spaced azimuths starting at
    /// +x and going counter-clockwise.
    pub directions: usize,
    /// Lower edge of the fit band, as a fraction of the pile height (excludes the toe).
    pub band_low_fraction: f64,
    /// Upper edge of the fit band, as a fraction of the pile height (excludes the rounded apex).
    pub band_high_fraction: f64,
    /// Radial bin width of the half-plane profiles, in particle diameters.
    pub bin_width_diameters: f64,
    /// Half-width of the slab around each half-plane whose particles are used, in particle
    /// diameters. Wider slabs see more grains per bin (fewer holes) but blur the direction.
    pub slab_half_width_diameters: f64,
    /// A radial bin is a surface point only if its supported column has at least this many
    /// particles; a lone grain that rolled out is not a pile.
    pub min_particles_per_bin: usize,
    /// Two grains whose surfaces are at most this far apart (in particle diameters) count as
    /// touching when the pile is separated from strays and grains in flight. Settled DEM grains
    /// overlap slightly, so a small value suffices; it is generous so that loose synthetic packings
    /// stay connected too.
    pub contact_gap_diameters: f64,
    /// Consecutive missing radial bins (or the equivalent silhouette length) tolerated before a
    /// profile is considered to have reached its toe.
    pub max_missing_bins: usize,
    /// Height of the base plane on which the pile rests, in metres.
    pub base_z_m: f64,
    /// The pile axis (x, y) in metres, e.g. the funnel axis. `None`: estimated as the centroid of
    /// the lower third of the pile (the footprint centre).
    pub axis_xy_m: Option<[f64; 2]>,
    /// Fewer usable particles than this is "no pile".
    pub min_particles: usize,
    /// A pile lower than this many particle diameters is "no pile": one layer of grains on the
    /// base (its tops at 1 d) has no slope. Any grain resting on a layer reaches at least 1.82 d
    /// (the top of a grain in the hollow of three touching ones, 1 + √(2/3)), so the default 1.5
    /// asks for no more than a second layer begun: a heap that low is a low angle, not a failure.
    pub min_height_diameters: f64,
    /// Fewer surface points than this inside the fit band of any flank is "no pile".
    pub min_fit_points: usize,
    /// Band points further from the fitted line than this many robust standard deviations (and
    /// more than half a grain) are dropped and the line refitted; 0 disables the rejection.
    pub outlier_rejection_sigmas: f64,
    /// Sampling step of the side-projection silhouette along the horizontal axis, in particle
    /// diameters.
    pub silhouette_step_diameters: f64,
}

impl Default for MeasureSettings {
    fn default() -> Self {
        Self {
            directions: 8,
            band_low_fraction: 0.2,
            band_high_fraction: 0.8,
            bin_width_diameters: 1.0,
            slab_half_width_diameters: 1.5,
            min_particles_per_bin: 2,
            contact_gap_diameters: 0.5,
            max_missing_bins: 1,
            base_z_m: 0.0,
            axis_xy_m: None,
            min_particles: 20,
            min_height_diameters: 1.5,
            min_fit_points: 3,
            outlier_rejection_sigmas: 2.5,
            silhouette_step_diameters: 0.25,
        }
    }
}

impl MeasureSettings {
    fn validate(&self) -> Result<(), MeasureError> {
        let bad = |what: &str| Err(MeasureError::InvalidSettings(what.to_owned()));
        if self.directions == 0 {
            return bad("directions must be at least 1");
        }
        let (lo, hi) = (self.band_low_fraction, self.band_high_fraction);
        if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi && hi <= 1.0) {
            return bad("band fractions must satisfy 0 <= low < high <= 1");
        }
        for (name, value) in [
            ("bin_width_diameters", self.bin_width_diameters),
            ("slab_half_width_diameters", self.slab_half_width_diameters),
            ("silhouette_step_diameters", self.silhouette_step_diameters),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return bad(&format!("{name} must be finite and positive"));
            }
        }
        if !(self.contact_gap_diameters.is_finite() && self.contact_gap_diameters >= 0.0) {
            return bad("contact_gap_diameters must be finite and non-negative");
        }
        if !self.outlier_rejection_sigmas.is_finite() {
            return bad("outlier_rejection_sigmas must be finite");
        }
        if !(self.min_height_diameters.is_finite() && self.min_height_diameters >= 0.0) {
            return bad("min_height_diameters must be finite and non-negative");
        }
        if !self.base_z_m.is_finite() {
            return bad("base_z_m must be finite");
        }
        if let Some([x, y]) = self.axis_xy_m {
            if !(x.is_finite() && y.is_finite()) {
                return bad("axis_xy_m must be finite");
            }
        }
        Ok(())
    }
}

/// Why no angle of repose could be read: the run is not a pile (or the input is malformed).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum MeasureError {
    /// `positions` and `radii` must describe the same particles.
    #[error("{positions} positions but {radii} radii: one radius per particle is required")]
    LengthMismatch {
        /// Number of positions given.
        positions: usize,
        /// Number of radii given.
        radii: usize,
    },
    /// A settings value is out of range.
    #[error("invalid measurement settings: {0}")]
    InvalidSettings(String),
    /// Too few particles rest on the base in one connected heap (empty input, or the grains
    /// escaped / scattered).
    #[error(
        "no pile: only {found} particles form a connected heap on the base, at least {required} needed"
    )]
    TooFewParticles {
        /// Particles found (usable ones, or those in the connected heap).
        found: usize,
        /// [`MeasureSettings::min_particles`].
        required: usize,
    },
    /// The heap is lower than [`MeasureSettings::min_height_diameters`] particle diameters: a
    /// single layer of grains, which has no slope (grains that spread out and never built one).
    #[error(
        "no pile: height {height_m:.5} m is below the minimum {required_m:.5} m (pile too flat)"
    )]
    PileTooFlat {
        /// Measured apex height above the base.
        height_m: f64,
        /// Minimum height required.
        required_m: f64,
    },
    /// One flank has too few surface points inside the fit band for a line fit (a column, a
    /// one-sided heap, or a badly ragged surface).
    #[error(
        "no pile flank in {profile}: {found} surface points in the fit band, at least {required} needed"
    )]
    TooFewFitPoints {
        /// Which profile failed, e.g. "half-plane 3 (azimuth 135°)" or "x-z projection, left flank".
        profile: String,
        /// Points found in the band.
        found: usize,
        /// [`MeasureSettings::min_fit_points`].
        required: usize,
    },
}

/// A straight line `z = intercept_m + slope * s` fitted by least squares to one flank, where `s`
/// is the horizontal abscissa of its profile (the radius for a half-plane, x or y for a side
/// projection).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlankFit {
    /// dz/ds of the fitted line (negative on a flank that descends with increasing `s`).
    pub slope: f64,
    /// Height of the line at `s = 0`, in metres (absolute z, not above the base).
    pub intercept_m: f64,
    /// `atan(|slope|)` in degrees.
    pub angle_deg: f64,
    /// Coefficient of determination of the fit (1 = all points on the line).
    pub r_squared: f64,
    /// Number of surface points the line was fitted to.
    pub points: usize,
    /// Points of the band dropped as outliers (holes, protruding grains) before the final fit.
    pub rejected: usize,
    /// Smallest abscissa of the fitted points, metres.
    pub band_start_m: f64,
    /// Largest abscissa of the fitted points, metres.
    pub band_end_m: f64,
    /// Abscissa at which the line reaches the base plane, metres. For a horizontal line (no
    /// intersection) the fitted point furthest from the apex is used instead, so it stays finite.
    pub toe_m: f64,
}

impl FlankFit {
    /// Height of the fitted line at abscissa `s` (metres, absolute z).
    pub fn height_at(&self, s: f64) -> f64 {
        self.intercept_m + self.slope * s
    }
}

/// The surface profile of the pile in one vertical half-plane through the axis, and its fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DirectionProfile {
    /// Azimuth of the half-plane, degrees counter-clockwise from +x.
    pub azimuth_deg: f64,
    /// Surface points `[r, z]`: horizontal distance from the axis and absolute height of the top
    /// of the highest supported sphere of each radial bin, in metres, from the axis outwards.
    pub surface: Vec<[f64; 2]>,
    /// Line fitted to the points of `surface` inside the height band (`s` = r).
    pub fit: FlankFit,
}

/// Which vertical plane the particles are projected onto for the side view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ProjectionPlane {
    /// Viewed along -y: the horizontal abscissa is x.
    Xz,
    /// Viewed along +x: the horizontal abscissa is y.
    Yz,
}

impl ProjectionPlane {
    /// Short label ("x-z" / "y-z").
    pub fn label(self) -> &'static str {
        match self {
            ProjectionPlane::Xz => "x-z",
            ProjectionPlane::Yz => "y-z",
        }
    }

    /// Name of the horizontal axis of the view ("x" / "y").
    pub fn abscissa_name(self) -> &'static str {
        match self {
            ProjectionPlane::Xz => "x",
            ProjectionPlane::Yz => "y",
        }
    }

    fn abscissa(self, p: &[f64; 3]) -> f64 {
        match self {
            ProjectionPlane::Xz => p[0],
            ProjectionPlane::Yz => p[1],
        }
    }
}

/// The pile as a side photograph would show it: silhouette of all projected grains, and one line
/// fitted to each flank.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SideProjection {
    /// The projection plane.
    pub plane: ProjectionPlane,
    /// Upper envelope of the projected disks `[s, z]` (metres), sampled every
    /// `silhouette_step_diameters` over the connected pile, left to right.
    pub silhouette: Vec<[f64; 2]>,
    /// Highest point of the silhouette `[s, z]`.
    pub apex: [f64; 2],
    /// Apex height of the silhouette above the base, metres.
    pub pile_height_m: f64,
    /// Line on the left flank (s below the apex): positive slope.
    pub left: FlankFit,
    /// Line on the right flank (s above the apex): negative slope.
    pub right: FlankFit,
    /// Left angle, degrees.
    pub left_deg: f64,
    /// Right angle, degrees.
    pub right_deg: f64,
    /// Mean of left and right, degrees.
    pub mean_deg: f64,
    /// Distance between the two toes of the fitted lines, metres.
    pub base_width_m: f64,
}

/// Result of [`measure_angle_of_repose`]. All lengths in metres, angles in degrees.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AngleOfRepose {
    /// Mean of the `K` half-plane angles: the headline angle of repose.
    pub angle_deg: f64,
    /// Angle in each half-plane, in order of increasing azimuth (see `directions`).
    pub per_direction_deg: Vec<f64>,
    /// Sample standard deviation of `per_direction_deg` (0 when K = 1).
    pub std_dev_deg: f64,
    /// Smallest per-direction angle.
    pub min_deg: f64,
    /// Largest per-direction angle.
    pub max_deg: f64,
    /// Left flank angle of the x-z side projection (the paper's photograph).
    pub left_deg: f64,
    /// Right flank angle of the x-z side projection.
    pub right_deg: f64,
    /// Mean of `left_deg` and `right_deg`.
    pub projection_mean_deg: f64,
    /// Apex height above the base.
    pub pile_height_m: f64,
    /// Twice the mean radius at which the half-plane flank lines meet the base.
    pub base_diameter_m: f64,
    /// Top of the highest supported grain `[x, y, z]` (absolute z).
    pub apex: [f64; 3],
    /// Pile axis used for the half-planes (given, or the footprint centroid).
    pub axis_xy_m: [f64; 2],
    /// Base plane height used.
    pub base_z_m: f64,
    /// Fit band `[low, high]` as fractions of the pile height (from the settings), kept so that a
    /// picture can show the band.
    pub band_fractions: [f64; 2],
    /// Characteristic particle diameter (twice the median radius).
    pub particle_diameter_m: f64,
    /// Number of particles given.
    pub particles_total: usize,
    /// Particles in the connected heap that was measured (strays and escaped grains excluded).
    pub particles_considered: usize,
    /// The `K` half-plane profiles and their fits.
    pub directions: Vec<DirectionProfile>,
    /// Side view onto the x-z plane (source of `left_deg` / `right_deg`).
    pub projection_xz: SideProjection,
    /// Side view onto the y-z plane, a second "photograph" at 90°.
    pub projection_yz: SideProjection,
}

impl AngleOfRepose {
    /// The side projection onto `plane`.
    pub fn projection(&self, plane: ProjectionPlane) -> &SideProjection {
        match plane {
            ProjectionPlane::Xz => &self.projection_xz,
            ProjectionPlane::Yz => &self.projection_yz,
        }
    }
}

/// Measures the angle of repose of the pile formed by spheres at `positions` (centres, metres,
/// z up) with `radii` (metres), resting on the plane `z = settings.base_z_m`.
///
/// Returns `Err` when the particles do not form a measurable pile (see [`MeasureError`]); the
/// module documentation explains every robustness rule.
pub fn measure_angle_of_repose(
    positions: &[[f64; 3]],
    radii: &[f64],
    settings: &MeasureSettings,
) -> Result<AngleOfRepose, MeasureError> {
    if positions.len() != radii.len() {
        return Err(MeasureError::LengthMismatch {
            positions: positions.len(),
            radii: radii.len(),
        });
    }
    settings.validate()?;
    let base_z = settings.base_z_m;

    let usable: Vec<Grain> = positions
        .iter()
        .zip(radii)
        .filter(|(p, r)| {
            p.iter().all(|c| c.is_finite())
                && r.is_finite()
                && **r > 0.0
                && p[2] >= base_z - **r
                && (p[2] + **r).is_finite()
        })
        .map(|(p, r)| Grain {
            centre: *p,
            radius: *r,
        })
        .collect();
    let required = settings.min_particles.max(1);
    if usable.len() < required {
        return Err(MeasureError::TooFewParticles {
            found: usable.len(),
            required,
        });
    }
    let diameter = 2.0 * median(usable.iter().map(|g| g.radius).collect());

    let pile = contact_cluster(
        &usable,
        settings.contact_gap_diameters * diameter,
        base_z,
        settings.axis_xy_m,
    );
    if pile.len() < required {
        return Err(MeasureError::TooFewParticles {
            found: pile.len(),
            required,
        });
    }
    let axis = settings
        .axis_xy_m
        .unwrap_or_else(|| footprint_centroid(&pile, base_z, diameter));

    // Half-plane surface profiles.
    let k = settings.directions;
    let profiles: Vec<(f64, Vec<SurfacePoint>)> = (0..k)
        .map(|i| {
            let azimuth = std::f64::consts::TAU * i as f64 / k as f64;
            (
                azimuth,
                half_plane_profile(&pile, axis, azimuth, diameter, settings),
            )
        })
        .collect();

    let apex_point = profiles
        .iter()
        .flat_map(|(_, pts)| pts.iter())
        .max_by(|a, b| a.z.total_cmp(&b.z));
    let pile_height = apex_point.map_or(0.0, |p| p.z - base_z);
    let required_height = settings.min_height_diameters * diameter;
    if !(pile_height >= required_height && pile_height > 0.0) {
        return Err(MeasureError::PileTooFlat {
            height_m: pile_height.max(0.0),
            required_m: required_height,
        });
    }
    let apex = apex_point.map_or([axis[0], axis[1], base_z], |p| {
        let g = &pile[p.grain];
        [g.centre[0], g.centre[1], g.centre[2] + g.radius]
    });

    let band = HeightBand {
        low_z: base_z + settings.band_low_fraction * pile_height,
        high_z: base_z + settings.band_high_fraction * pile_height,
        base_z,
    };
    let rules = FitRules::new(settings, diameter);
    let mut directions = Vec::with_capacity(k);
    for (i, (azimuth, points)) in profiles.iter().enumerate() {
        let samples: Vec<[f64; 2]> = points.iter().map(|p| [p.r, p.z]).collect();
        let in_band: Vec<[f64; 2]> = samples
            .iter()
            .copied()
            .filter(|p| band.contains(p[1]))
            .collect();
        let profile_name = || format!("half-plane {i} (azimuth {:.1}°)", azimuth.to_degrees());
        let fit = fit_flank(&in_band, &band, &rules, FarSide::High).ok_or_else(|| {
            MeasureError::TooFewFitPoints {
                profile: profile_name(),
                found: in_band.len(),
                required: settings.min_fit_points,
            }
        })?;
        directions.push(DirectionProfile {
            azimuth_deg: azimuth.to_degrees(),
            surface: samples,
            fit,
        });
    }

    let per_direction_deg: Vec<f64> = directions.iter().map(|d| d.fit.angle_deg).collect();
    let angle_deg = mean(&per_direction_deg);
    let std_dev_deg = sample_std_dev(&per_direction_deg);
    let min_deg = per_direction_deg
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let max_deg = per_direction_deg
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    let base_radius = mean(
        &directions
            .iter()
            .map(|d| d.fit.toe_m.max(0.0))
            .collect::<Vec<_>>(),
    );

    let projection_xz = side_projection(&pile, ProjectionPlane::Xz, diameter, settings)?;
    let projection_yz = side_projection(&pile, ProjectionPlane::Yz, diameter, settings)?;

    Ok(AngleOfRepose {
        angle_deg,
        per_direction_deg,
        std_dev_deg,
        min_deg,
        max_deg,
        left_deg: projection_xz.left_deg,
        right_deg: projection_xz.right_deg,
        projection_mean_deg: projection_xz.mean_deg,
        pile_height_m: pile_height,
        base_diameter_m: 2.0 * base_radius,
        apex,
        axis_xy_m: axis,
        base_z_m: base_z,
        band_fractions: [settings.band_low_fraction, settings.band_high_fraction],
        particle_diameter_m: diameter,
        particles_total: positions.len(),
        particles_considered: pile.len(),
        directions,
        projection_xz,
        projection_yz,
    })
}

#[derive(Debug, Clone, Copy)]
struct Grain {
    centre: [f64; 3],
    radius: f64,
}

impl Grain {
    fn bottom(&self) -> f64 {
        self.centre[2] - self.radius
    }
    fn top(&self) -> f64 {
        self.centre[2] + self.radius
    }
}

/// One surface point of a half-plane profile, remembering which grain made it.
#[derive(Debug, Clone, Copy)]
struct SurfacePoint {
    r: f64,
    z: f64,
    grain: usize,
}

#[derive(Debug, Clone, Copy)]
struct HeightBand {
    low_z: f64,
    high_z: f64,
    base_z: f64,
}

impl HeightBand {
    fn contains(&self, z: f64) -> bool {
        self.low_z <= z && z <= self.high_z
    }
}

/// Which end of the fitted abscissa range is away from the apex (used for a horizontal line's toe).
#[derive(Debug, Clone, Copy)]
enum FarSide {
    Low,
    High,
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n == 0 {
        return 0.0;
    }
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

fn mean(values: &[f64]) -> f64 {
    if values.is_empty() {
        0.0
    } else {
        values.iter().sum::<f64>() / values.len() as f64
    }
}

fn sample_std_dev(values: &[f64]) -> f64 {
    if values.len() < 2 {
        return 0.0;
    }
    let m = mean(values);
    let ss: f64 = values.iter().map(|v| (v - m) * (v - m)).sum();
    (ss / (values.len() - 1) as f64).sqrt()
}

/// The pile: the cluster of (nearly) touching grains that rests on the base, chosen as the largest
/// such cluster, or the one with the base grain nearest to `axis` when the axis is known.
/// Grains are neighbours when their surfaces are at most `gap` apart; clusters are found with a
/// cell list and union-find, so the cost is linear in the number of grains for sane radii.
fn contact_cluster(grains: &[Grain], gap: f64, base_z: f64, axis: Option<[f64; 2]>) -> Vec<Grain> {
    if grains.is_empty() {
        return Vec::new();
    }
    let max_radius = grains.iter().map(|g| g.radius).fold(0.0, f64::max);
    // Any two neighbours lie in the same or adjacent cells. Saturating casts keep absurd
    // coordinates from panicking (they merely crowd one cell).
    let cell = (2.0 * max_radius + gap).max(f64::MIN_POSITIVE);
    let key = |g: &Grain| {
        (
            (g.centre[0] / cell).floor() as i64,
            (g.centre[1] / cell).floor() as i64,
            (g.centre[2] / cell).floor() as i64,
        )
    };
    let mut cells: HashMap<(i64, i64, i64), Vec<usize>> = HashMap::new();
    for (i, g) in grains.iter().enumerate() {
        cells.entry(key(g)).or_default().push(i);
    }
    let mut parent: Vec<usize> = (0..grains.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for (i, g) in grains.iter().enumerate() {
        let (cx, cy, cz) = key(g);
        for dx in -1i64..=1 {
            for dy in -1i64..=1 {
                for dz in -1i64..=1 {
                    let neighbour_cell = (
                        cx.saturating_add(dx),
                        cy.saturating_add(dy),
                        cz.saturating_add(dz),
                    );
                    let Some(list) = cells.get(&neighbour_cell) else {
                        continue;
                    };
                    for &j in list {
                        if j <= i {
                            continue;
                        }
                        let h = &grains[j];
                        let distance = ((g.centre[0] - h.centre[0]).powi(2)
                            + (g.centre[1] - h.centre[1]).powi(2)
                            + (g.centre[2] - h.centre[2]).powi(2))
                        .sqrt();
                        if distance - g.radius - h.radius <= gap {
                            let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                            if a != b {
                                parent[a.max(b)] = a.min(b);
                            }
                        }
                    }
                }
            }
        }
    }
    let roots: Vec<usize> = (0..grains.len()).map(|i| root(&mut parent, i)).collect();
    let mut size = vec![0usize; grains.len()];
    for &r in &roots {
        size[r] += 1;
    }
    let on_base = |g: &Grain| g.bottom() <= base_z + gap;
    let chosen = match axis {
        Some([ax, ay]) => grains
            .iter()
            .enumerate()
            .filter(|(_, g)| on_base(g))
            .min_by(|(_, a), (_, b)| {
                let da = (a.centre[0] - ax).hypot(a.centre[1] - ay);
                let db = (b.centre[0] - ax).hypot(b.centre[1] - ay);
                da.total_cmp(&db)
            })
            .map(|(i, _)| roots[i]),
        None => {
            let mut best: Option<usize> = None;
            for (i, g) in grains.iter().enumerate() {
                let r = roots[i];
                if on_base(g) && best.is_none_or(|b| size[r] > size[b]) {
                    best = Some(r);
                }
            }
            best
        }
    };
    let Some(chosen) = chosen else {
        return Vec::new();
    };
    grains
        .iter()
        .zip(&roots)
        .filter(|(_, r)| **r == chosen)
        .map(|(g, _)| *g)
        .collect()
}

/// Centroid (x, y) of the grains in the lower third of the heap: the base footprint is the
/// widest, best-populated part of the pile, so its centre is the most stable axis estimate.
/// The heap height here is a 98 % quantile of grain tops so that one grain on top cannot move it.
fn footprint_centroid(pile: &[Grain], base_z: f64, diameter: f64) -> [f64; 2] {
    let mut tops: Vec<f64> = pile.iter().map(|g| g.top() - base_z).collect();
    tops.sort_by(f64::total_cmp);
    let q98 = tops[((tops.len() - 1) as f64 * 0.98).round() as usize];
    let limit = (q98 / 3.0).max(diameter);
    let lower: Vec<&Grain> = pile
        .iter()
        .filter(|g| g.centre[2] - base_z <= limit)
        .collect();
    let chosen: Vec<&Grain> = if lower.is_empty() {
        pile.iter().collect()
    } else {
        lower
    };
    let n = chosen.len() as f64;
    let sx: f64 = chosen.iter().map(|g| g.centre[0]).sum();
    let sy: f64 = chosen.iter().map(|g| g.centre[1]).sum();
    [sx / n, sy / n]
}

/// Surface points of the half-plane at `azimuth` (radians from +x): grains within the slab
/// `|across| <= half-width` on the positive side, binned by their true horizontal distance from
/// the axis; each bin gives the top of its highest grain, at that grain's radius.
fn half_plane_profile(
    pile: &[Grain],
    axis: [f64; 2],
    azimuth: f64,
    diameter: f64,
    settings: &MeasureSettings,
) -> Vec<SurfacePoint> {
    let (sin, cos) = azimuth.sin_cos();
    let half_width = settings.slab_half_width_diameters * diameter;
    let bin_width = settings.bin_width_diameters * diameter;
    // (bin, top, r, grain)
    let mut members: Vec<(usize, f64, f64, usize)> = pile
        .iter()
        .enumerate()
        .filter_map(|(i, g)| {
            let dx = g.centre[0] - axis[0];
            let dy = g.centre[1] - axis[1];
            let along = dx * cos + dy * sin;
            let across = -dx * sin + dy * cos;
            // The slab starts half a slab behind the axis so that the axis column is not cut
            // in half by the sign of `along` (grains there are all at small r anyway).
            if along < -half_width || across.abs() > half_width {
                return None;
            }
            let r = dx.hypot(dy);
            let bin = (r / bin_width).floor() as usize; // saturating: far grains get a huge bin
            Some((bin, g.top(), r, i))
        })
        .collect();
    members.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));

    let mut points = Vec::new();
    let mut last_good: Option<usize> = None;
    let mut start = 0;
    while start < members.len() {
        let bin = members[start].0;
        let end = start + members[start..].partition_point(|m| m.0 == bin);
        let next_expected = last_good.map_or(0, |b| b.saturating_add(1));
        if bin.saturating_sub(next_expected) > settings.max_missing_bins {
            break; // reached the toe: what lies further out is not this pile's surface
        }
        // Sorted by top within the bin: the last member is the highest grain.
        let highest = members[end - 1];
        if end - start >= settings.min_particles_per_bin {
            points.push(SurfacePoint {
                r: highest.2,
                z: highest.1,
                grain: highest.3,
            });
            last_good = Some(bin);
        }
        start = end;
    }
    points
}

/// How a flank line is fitted (from the settings and the grain size).
#[derive(Debug, Clone, Copy)]
struct FitRules {
    min_points: usize,
    outlier_sigmas: f64,
    outlier_floor_m: f64,
}

impl FitRules {
    fn new(settings: &MeasureSettings, diameter: f64) -> Self {
        Self {
            min_points: settings.min_fit_points.max(2),
            outlier_sigmas: settings.outlier_rejection_sigmas,
            outlier_floor_m: OUTLIER_FLOOR_DIAMETERS * diameter,
        }
    }
}

/// Residuals smaller than this many grain diameters are never treated as outliers: that much
/// roughness is the granular surface itself.
const OUTLIER_FLOOR_DIAMETERS: f64 = 0.5;

/// Ordinary least squares `z = intercept + slope * s`; `None` if the abscissas do not vary.
fn least_squares(points: &[[f64; 2]]) -> Option<(f64, f64)> {
    let n = points.len() as f64;
    let ms = points.iter().map(|p| p[0]).sum::<f64>() / n;
    let mz = points.iter().map(|p| p[1]).sum::<f64>() / n;
    let (mut sss, mut ssz) = (0.0, 0.0);
    for p in points {
        sss += (p[0] - ms) * (p[0] - ms);
        ssz += (p[0] - ms) * (p[1] - mz);
    }
    if !(sss > 0.0 && sss.is_finite() && ssz.is_finite()) {
        return None;
    }
    let slope = ssz / sss;
    Some((slope, mz - slope * ms))
}

/// Least-squares line through the band points `[s, z]` of one flank, made robust by up to three
/// passes of outlier rejection: points further from the line than `outlier_sigmas` robust
/// standard deviations (1.4826 × median absolute residual), and more than half a grain, are
/// dropped and the line refitted. This removes holes in a loose surface (a bin whose top grain
/// sits well below its neighbours) and single protruding grains without touching an ordinary
/// rough flank. `None` if fewer than `min_points` points remain or the abscissas do not vary.
fn fit_flank(
    points: &[[f64; 2]],
    band: &HeightBand,
    rules: &FitRules,
    far_side: FarSide,
) -> Option<FlankFit> {
    if points.len() < rules.min_points {
        return None;
    }
    let mut kept: Vec<[f64; 2]> = points.to_vec();
    let (mut slope, mut intercept) = least_squares(&kept)?;
    if rules.outlier_sigmas > 0.0 {
        for _ in 0..3 {
            let residual = |p: &[f64; 2]| p[1] - (intercept + slope * p[0]);
            let mad = median(kept.iter().map(|p| residual(p).abs()).collect());
            let limit = (rules.outlier_sigmas * 1.4826 * mad).max(rules.outlier_floor_m);
            let next: Vec<[f64; 2]> = kept
                .iter()
                .copied()
                .filter(|p| residual(p).abs() <= limit)
                .collect();
            if next.len() == kept.len() || next.len() < rules.min_points {
                break;
            }
            let Some(line) = least_squares(&next) else {
                break;
            };
            kept = next;
            (slope, intercept) = line;
        }
    }
    let n = kept.len() as f64;
    let mz = kept.iter().map(|p| p[1]).sum::<f64>() / n;
    let total: f64 = kept.iter().map(|p| (p[1] - mz) * (p[1] - mz)).sum();
    let unexplained: f64 = kept
        .iter()
        .map(|p| (p[1] - intercept - slope * p[0]).powi(2))
        .sum();
    let r_squared = if total > 0.0 {
        (1.0 - unexplained / total).clamp(0.0, 1.0)
    } else {
        1.0
    };
    let band_start = kept.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min);
    let band_end = kept.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max);
    let far_end = match far_side {
        FarSide::Low => band_start,
        FarSide::High => band_end,
    };
    let toe = if slope.abs() > 1e-12 {
        let t = (band.base_z - intercept) / slope;
        if t.is_finite() {
            t
        } else {
            far_end
        }
    } else {
        far_end
    };
    let fit = FlankFit {
        slope,
        intercept_m: intercept,
        angle_deg: slope.abs().atan().to_degrees(),
        r_squared,
        points: kept.len(),
        rejected: points.len() - kept.len(),
        band_start_m: band_start,
        band_end_m: band_end,
        toe_m: toe,
    };
    let all_finite = [
        fit.slope,
        fit.intercept_m,
        fit.angle_deg,
        fit.r_squared,
        fit.band_start_m,
        fit.band_end_m,
        fit.toe_m,
    ]
    .iter()
    .all(|v| v.is_finite());
    all_finite.then_some(fit)
}

/// Most silhouette samples allowed; the step grows beyond this so that a huge, sparse heap can not
/// exhaust memory.
const MAX_SILHOUETTE_SAMPLES: usize = 200_000;

/// Side view: every grain becomes a disk in the plane; at each sampled abscissa the upper
/// envelope of the disks covering it is the silhouette height. The silhouette is followed
/// left and right from its highest point until it has been missing for more than the tolerated
/// gap, and a line is fitted to each flank within the height band.
fn side_projection(
    pile: &[Grain],
    plane: ProjectionPlane,
    diameter: f64,
    settings: &MeasureSettings,
) -> Result<SideProjection, MeasureError> {
    let base_z = settings.base_z_m;
    let too_few = |side: &str, found: usize| MeasureError::TooFewFitPoints {
        profile: format!("{} projection, {side} flank", plane.label()),
        found,
        required: settings.min_fit_points,
    };
    let s_min = pile
        .iter()
        .map(|g| plane.abscissa(&g.centre) - g.radius)
        .fold(f64::INFINITY, f64::min);
    let s_max = pile
        .iter()
        .map(|g| plane.abscissa(&g.centre) + g.radius)
        .fold(f64::NEG_INFINITY, f64::max);
    let span = s_max - s_min;
    if !(span.is_finite() && span > 0.0) {
        return Err(too_few("left", 0));
    }
    let step =
        (settings.silhouette_step_diameters * diameter).max(span / MAX_SILHOUETTE_SAMPLES as f64);
    let samples = ((span / step).floor() as usize).min(MAX_SILHOUETTE_SAMPLES) + 1;

    // Highest chord top at every sample.
    let mut heights: Vec<Option<f64>> = vec![None; samples];
    for g in pile {
        let s = plane.abscissa(&g.centre);
        let first = ((s - g.radius - s_min) / step).ceil().max(0.0) as usize;
        let last = (((s + g.radius - s_min) / step).floor() as usize).min(samples - 1);
        let covered = heights.iter_mut().enumerate().take(last + 1).skip(first);
        for (j, height) in covered {
            let ds = s_min + j as f64 * step - s;
            let half = (g.radius * g.radius - ds * ds).max(0.0).sqrt();
            let top = g.centre[2] + half;
            if top > base_z && height.is_none_or(|h| top > h) {
                *height = Some(top);
            }
        }
    }

    let Some(apex_index) = (0..samples)
        .filter(|j| heights[*j].is_some())
        .max_by(|a, b| {
            heights[*a]
                .unwrap_or(f64::NEG_INFINITY)
                .total_cmp(&heights[*b].unwrap_or(f64::NEG_INFINITY))
                .then(b.cmp(a))
        })
    else {
        return Err(too_few("left", 0));
    };
    let allowed_missing = ((settings.max_missing_bins as f64 * settings.bin_width_diameters
        / settings.silhouette_step_diameters)
        .round() as usize)
        .max(1);
    let walk = |indices: &mut dyn Iterator<Item = usize>| -> Vec<usize> {
        let mut kept = Vec::new();
        let mut missing = 0usize;
        for j in indices {
            if heights[j].is_some() {
                kept.push(j);
                missing = 0;
            } else {
                missing += 1;
                if missing > allowed_missing {
                    break;
                }
            }
        }
        kept
    };
    let mut left_indices = walk(&mut (0..apex_index).rev());
    left_indices.reverse();
    let right_indices = walk(&mut (apex_index + 1..samples));
    let point = |j: usize| [s_min + j as f64 * step, heights[j].unwrap_or(base_z)];

    let apex = point(apex_index);
    let pile_height = apex[1] - base_z;
    let band = HeightBand {
        low_z: base_z + settings.band_low_fraction * pile_height,
        high_z: base_z + settings.band_high_fraction * pile_height,
        base_z,
    };
    let left_band: Vec<[f64; 2]> = left_indices
        .iter()
        .map(|j| point(*j))
        .filter(|p| band.contains(p[1]))
        .collect();
    let right_band: Vec<[f64; 2]> = right_indices
        .iter()
        .map(|j| point(*j))
        .filter(|p| band.contains(p[1]))
        .collect();
    let rules = FitRules::new(settings, diameter);
    let left = fit_flank(&left_band, &band, &rules, FarSide::Low)
        .ok_or_else(|| too_few("left", left_band.len()))?;
    let right = fit_flank(&right_band, &band, &rules, FarSide::High)
        .ok_or_else(|| too_few("right", right_band.len()))?;

    let silhouette: Vec<[f64; 2]> = left_indices
        .iter()
        .chain(std::iter::once(&apex_index))
        .chain(right_indices.iter())
        .map(|j| point(*j))
        .collect();
    Ok(SideProjection {
        plane,
        silhouette,
        apex,
        pile_height_m: pile_height,
        left_deg: left.angle_deg,
        right_deg: right.angle_deg,
        mean_deg: 0.5 * (left.angle_deg + right.angle_deg),
        base_width_m: (right.toe_m - left.toe_m).abs(),
        left,
        right,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plain_rules() -> FitRules {
        FitRules {
            min_points: 3,
            outlier_sigmas: 0.0,
            outlier_floor_m: 0.0,
        }
    }

    #[test]
    fn outlier_rejection_removes_a_hole() {
        let mut pts: Vec<[f64; 2]> = (0..12)
            .map(|i| {
                let r = i as f64;
                [r, 20.0 - r + if i % 2 == 0 { 0.1 } else { -0.1 }]
            })
            .collect();
        pts[5][1] -= 4.0; // a hole: the top grain of this bin sits deep in the surface
        let rules = FitRules {
            min_points: 3,
            outlier_sigmas: 2.5,
            outlier_floor_m: 0.5,
        };
        let robust = fit_flank(&pts, &band(0.0, 30.0), &rules, FarSide::High).unwrap();
        assert_eq!(robust.rejected, 1);
        assert!(
            (robust.angle_deg - 45.0).abs() < 1.0,
            "{}",
            robust.angle_deg
        );
        let plain = fit_flank(&pts, &band(0.0, 30.0), &plain_rules(), FarSide::High).unwrap();
        assert_eq!(plain.rejected, 0);
        assert!(plain.r_squared < robust.r_squared);
    }

    fn band(low: f64, high: f64) -> HeightBand {
        HeightBand {
            low_z: low,
            high_z: high,
            base_z: 0.0,
        }
    }

    #[test]
    fn line_fit_recovers_exact_line_and_toe() {
        let pts: Vec<[f64; 2]> = (0..10)
            .map(|i| {
                let r = i as f64 * 0.001;
                [r, 0.02 - r * 35f64.to_radians().tan()]
            })
            .collect();
        let fit = fit_flank(&pts, &band(0.0, 1.0), &plain_rules(), FarSide::High).unwrap();
        assert!((fit.angle_deg - 35.0).abs() < 1e-9);
        assert!((fit.r_squared - 1.0).abs() < 1e-12);
        assert!((fit.toe_m - 0.02 / 35f64.to_radians().tan()).abs() < 1e-12);
        assert!((fit.height_at(0.0) - 0.02).abs() < 1e-12);
    }

    #[test]
    fn line_fit_refuses_degenerate_input() {
        assert!(fit_flank(
            &[[0.0, 1.0], [0.0, 2.0], [0.0, 3.0]],
            &band(0.0, 5.0),
            &plain_rules(),
            FarSide::High
        )
        .is_none());
        assert!(fit_flank(
            &[[0.0, 1.0], [1.0, 2.0]],
            &band(0.0, 5.0),
            &plain_rules(),
            FarSide::High
        )
        .is_none());
        // A horizontal line has no toe: the far end of the fitted range stands in for it.
        let flat = fit_flank(
            &[[0.0, 1.0], [1.0, 1.0], [2.0, 1.0]],
            &band(0.0, 5.0),
            &plain_rules(),
            FarSide::High,
        )
        .unwrap();
        assert_eq!(flat.toe_m, 2.0);
        assert_eq!(flat.angle_deg, 0.0);
    }

    fn grain(x: f64, y: f64, z: f64) -> Grain {
        Grain {
            centre: [x, y, z],
            radius: 0.5,
        }
    }

    #[test]
    fn contact_cluster_drops_strays_and_grains_in_flight() {
        let mut grains: Vec<Grain> = (0..5)
            .flat_map(|i| (0..5).map(move |j| grain(i as f64, j as f64, 0.5)))
            .collect();
        grains.push(grain(2.0, 2.0, 1.5)); // resting on the layer
        grains.push(grain(2.0, 2.0, 6.0)); // in flight
        grains.push(grain(50.0, 50.0, 0.5)); // bounced away
        let heap = contact_cluster(&grains, 0.25, 0.0, None);
        assert_eq!(heap.len(), 26);
        let heap = contact_cluster(&grains, 0.25, 0.0, Some([49.0, 49.0]));
        assert_eq!(heap.len(), 1, "the given axis selects the heap under it");
        assert!(contact_cluster(&[grain(0.0, 0.0, 9.0)], 0.25, 0.0, None).is_empty());
    }

    #[test]
    fn settings_round_trip_and_validate() {
        let s = MeasureSettings::default();
        let json = serde_json::to_string(&s).unwrap();
        let back: MeasureSettings = serde_json::from_str(&json).unwrap();
        assert_eq!(s, back);
        let partial: MeasureSettings = serde_json::from_str(r#"{"directions": 12}"#).unwrap();
        assert_eq!(partial.directions, 12);
        assert_eq!(partial.band_low_fraction, 0.2);
        let bad = MeasureSettings {
            band_low_fraction: 0.9,
            ..MeasureSettings::default()
        };
        assert!(matches!(
            measure_angle_of_repose(&[], &[], &bad),
            Err(MeasureError::InvalidSettings(_))
        ));
    }
}
