//! Prescribed motion of rigid geometry (funnel lift, auger rotation and feed).
//!
//! A [`Motion`] is a set of constant-velocity segments, so the pose is integrated exactly
//! (piecewise-analytically) instead of step by step: no drift after millions of time steps and
//! the same pose whatever the time step.
//!
//! Conventions:
//! * Translation velocities are in the world frame (m/s).
//! * Rotations are about one axis fixed in the body (direction and point given in the body
//!   frame). `rpm > 0` turns counter-clockwise when looking down the axis direction toward
//!   the point (right-hand rule). A drill turning *clockwise seen from above* about a +z axis
//!   therefore has **negative** rpm.
//! * `pose(t) = translate(offset(t)) · placement · rotate(angle(t) about the body axis)`, where
//!   `placement` is the body's pose at t = 0, `offset(t)` = Σ v·(time the segment has been
//!   active) and `angle(t)` = Σ ω·(time active).
//!
//! All rotation segments share one body axis, so angles simply add. (Rotations about
//! different axes do not commute, and no test rig needs them.)

use serde::{Deserialize, Serialize};

use crate::math::{Pose, Rotation, Vec3};

/// Why a motion description was rejected. `segment` is the index within its list.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MotionError {
    #[error("{list}[{segment}].{field} = {value} is not finite")]
    NotFinite {
        list: &'static str,
        segment: usize,
        field: &'static str,
        value: f64,
    },
    #[error("{list}[{segment}]: stop = {stop} s must be later than start = {start} s")]
    EmptyInterval {
        list: &'static str,
        segment: usize,
        start: f64,
        stop: f64,
    },
    #[error("rotations[{segment}].axis is the zero vector")]
    ZeroAxis { segment: usize },
    #[error(
        "rotations[{segment}] turns about a different axis than rotations[0]; all rotation \
         segments must share one body axis (same direction and a point on the same line)"
    )]
    DifferentAxis { segment: usize },
    #[error("placement is not finite")]
    NonFinitePlacement,
    #[error("{name} = {value} must be finite and > 0")]
    NotPositive { name: &'static str, value: f64 },
}

/// Constant world-frame velocity between `start` and `stop` (s).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TranslationSegment {
    /// m/s, world frame.
    pub velocity: Vec3,
    pub start: f64,
    pub stop: f64,
}

/// Constant spin about a body-fixed axis between `start` and `stop` (s).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RotationSegment {
    /// Axis direction in the body frame (need not be unit length).
    pub axis: Vec3,
    /// A point on the axis, in the body frame (m).
    pub axis_point: Vec3,
    /// Revolutions per minute, right-hand rule about `axis` (clockwise seen from above about
    /// +z is negative).
    pub rpm: f64,
    pub start: f64,
    pub stop: f64,
}

impl RotationSegment {
    /// Angular speed in rad/s (signed).
    pub fn angular_speed(&self) -> f64 {
        self.rpm * std::f64::consts::TAU / 60.0
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct MotionData {
    #[serde(default = "Pose::identity")]
    placement: Pose,
    #[serde(default)]
    translations: Vec<TranslationSegment>,
    #[serde(default)]
    rotations: Vec<RotationSegment>,
}

/// Validated piecewise-constant-velocity motion of a rigid body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "MotionData", into = "MotionData")]
pub struct Motion {
    placement: Pose,
    translations: Vec<TranslationSegment>,
    rotations: Vec<RotationSegment>,
    /// Unit axis and a point on it (body frame); `+z` through the origin if there are no
    /// rotation segments.
    unit_axis: Vec3,
    axis_point: Vec3,
}

impl TryFrom<MotionData> for Motion {
    type Error = MotionError;
    fn try_from(d: MotionData) -> Result<Self, MotionError> {
        Motion::new(d.placement, d.translations, d.rotations)
    }
}

impl From<Motion> for MotionData {
    fn from(m: Motion) -> Self {
        MotionData {
            placement: m.placement,
            translations: m.translations,
            rotations: m.rotations,
        }
    }
}

fn check_finite(
    list: &'static str,
    segment: usize,
    field: &'static str,
    values: &[f64],
) -> Result<(), MotionError> {
    match values.iter().find(|v| !v.is_finite()) {
        Some(&value) => Err(MotionError::NotFinite {
            list,
            segment,
            field,
            value,
        }),
        None => Ok(()),
    }
}

fn check_interval(
    list: &'static str,
    segment: usize,
    start: f64,
    stop: f64,
) -> Result<(), MotionError> {
    check_finite(list, segment, "start", &[start])?;
    check_finite(list, segment, "stop", &[stop])?;
    if stop > start {
        Ok(())
    } else {
        Err(MotionError::EmptyInterval {
            list,
            segment,
            start,
            stop,
        })
    }
}

/// Time in `[start, stop]` that lies before `t`.
fn active_time(start: f64, stop: f64, t: f64) -> f64 {
    (t.min(stop) - start).max(0.0)
}

fn is_active(start: f64, stop: f64, t: f64) -> bool {
    start <= t && t < stop
}

impl Motion {
    /// Validates and builds a motion. `placement` is the pose at t = 0 before any segment
    /// acts.
    pub fn new(
        placement: Pose,
        translations: Vec<TranslationSegment>,
        rotations: Vec<RotationSegment>,
    ) -> Result<Motion, MotionError> {
        let p = placement.to_homogeneous();
        if !p.iter().all(|x| x.is_finite()) {
            return Err(MotionError::NonFinitePlacement);
        }
        for (i, s) in translations.iter().enumerate() {
            check_finite("translations", i, "velocity", s.velocity.as_slice())?;
            check_interval("translations", i, s.start, s.stop)?;
        }
        let mut unit_axis = Vec3::z();
        let mut axis_point = Vec3::zeros();
        for (i, s) in rotations.iter().enumerate() {
            check_finite("rotations", i, "axis", s.axis.as_slice())?;
            check_finite("rotations", i, "axis_point", s.axis_point.as_slice())?;
            check_finite("rotations", i, "rpm", &[s.rpm])?;
            check_interval("rotations", i, s.start, s.stop)?;
            let norm = s.axis.norm();
            if norm <= 0.0 {
                return Err(MotionError::ZeroAxis { segment: i });
            }
            let axis = s.axis / norm;
            if i == 0 {
                unit_axis = axis;
                axis_point = s.axis_point;
            } else {
                // Same line: parallel directions (either sense) and the point on that line.
                let scale = 1.0 + axis_point.norm() + s.axis_point.norm();
                let off_line = (s.axis_point - axis_point).cross(&unit_axis).norm();
                if axis.cross(&unit_axis).norm() > 1e-9 || off_line > 1e-9 * scale {
                    return Err(MotionError::DifferentAxis { segment: i });
                }
            }
        }
        Ok(Motion {
            placement,
            translations,
            rotations,
            unit_axis,
            axis_point,
        })
    }

    /// A body at `placement` at time `start` that translates at `velocity` (world frame, m/s)
    /// from then on, without turning: what a servo-controlled geometry is given at each control
    /// step ([`World::set_geometry_motion`](crate::world::World::set_geometry_motion)), with
    /// `placement` the pose the body has reached at `start`, so its path is continuous.
    pub fn translating(placement: Pose, velocity: Vec3, start: f64) -> Result<Motion, MotionError> {
        // "From then on": the segment ends at the largest finite time.
        Motion::new(
            placement,
            vec![TranslationSegment {
                velocity,
                start,
                stop: f64::MAX,
            }],
            Vec::new(),
        )
    }

    /// True if the body never moves (no translation or rotation segments).
    pub fn is_stationary(&self) -> bool {
        self.translations.is_empty() && self.rotations.is_empty()
    }

    /// A body that never moves from `placement`.
    pub fn stationary(placement: Pose) -> Motion {
        Motion {
            placement,
            translations: Vec::new(),
            rotations: Vec::new(),
            unit_axis: Vec3::z(),
            axis_point: Vec3::zeros(),
        }
    }

    /// The auger test: starting at `start` (s), spin at `rpm` about the body +z axis through
    /// the body origin; feed down at `feed_speed` (m/s, > 0) until `depth` (m) has been
    /// travelled, then withdraw upward at `withdraw_speed` back to the start height, still
    /// spinning. E.g. 400 rpm clockwise from above is `rpm = -400`.
    pub fn drilling(
        placement: Pose,
        start: f64,
        rpm: f64,
        feed_speed: f64,
        depth: f64,
        withdraw_speed: f64,
    ) -> Result<Motion, MotionError> {
        for (name, value) in [
            ("feed_speed", feed_speed),
            ("depth", depth),
            ("withdraw_speed", withdraw_speed),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(MotionError::NotPositive { name, value });
            }
        }
        let feed_stop = start + depth / feed_speed;
        let withdraw_stop = feed_stop + depth / withdraw_speed;
        Motion::new(
            placement,
            vec![
                TranslationSegment {
                    velocity: Vec3::new(0.0, 0.0, -feed_speed),
                    start,
                    stop: feed_stop,
                },
                TranslationSegment {
                    velocity: Vec3::new(0.0, 0.0, withdraw_speed),
                    start: feed_stop,
                    stop: withdraw_stop,
                },
            ],
            vec![RotationSegment {
                axis: Vec3::z(),
                axis_point: Vec3::zeros(),
                rpm,
                start,
                stop: withdraw_stop,
            }],
        )
    }

    pub fn placement(&self) -> &Pose {
        &self.placement
    }

    pub fn translations(&self) -> &[TranslationSegment] {
        &self.translations
    }

    pub fn rotations(&self) -> &[RotationSegment] {
        &self.rotations
    }

    /// Time after which the body no longer moves (0 for a stationary body).
    pub fn end_time(&self) -> f64 {
        self.translations
            .iter()
            .map(|s| s.stop)
            .chain(self.rotations.iter().map(|s| s.stop))
            .fold(0.0, f64::max)
    }

    /// World-frame translation accumulated by time `t` (m).
    pub fn offset_at(&self, t: f64) -> Vec3 {
        self.translations
            .iter()
            .map(|s| s.velocity * active_time(s.start, s.stop, t))
            .sum()
    }

    /// Rotation angle about the body axis accumulated by time `t` (rad, signed as rpm).
    pub fn angle_at(&self, t: f64) -> f64 {
        self.rotations
            .iter()
            .map(|s| s.angular_speed() * active_time(s.start, s.stop, t))
            .sum()
    }

    /// Body → world pose at time `t`.
    pub fn pose_at(&self, t: f64) -> Pose {
        let spin = Rotation::from_axis_angle(
            &nalgebra::Unit::new_unchecked(self.unit_axis),
            self.angle_at(t),
        );
        // Rotation about the line through `axis_point`: x ↦ p + R (x − p).
        let about_axis = Pose::from_parts((self.axis_point - spin * self.axis_point).into(), spin);
        Pose::from_parts(self.offset_at(t).into(), Rotation::identity())
            * self.placement
            * about_axis
    }

    /// World position of the body-frame axis point at `t`: the point about which the geometry
    /// turns and about which its torque is reported.
    pub fn reference_point_at(&self, t: f64) -> Vec3 {
        // The axis point is a fixed point of the spin, so only placement and offset move it.
        self.offset_at(t)
            + self
                .placement
                .transform_point(&self.axis_point.into())
                .coords
    }

    /// World-frame translational velocity at `t` (m/s). Segments are active on
    /// `[start, stop)`.
    pub fn linear_velocity_at(&self, t: f64) -> Vec3 {
        self.translations
            .iter()
            .filter(|s| is_active(s.start, s.stop, t))
            .map(|s| s.velocity)
            .sum()
    }

    /// World-frame angular velocity at `t` (rad/s).
    pub fn angular_velocity_at(&self, t: f64) -> Vec3 {
        let speed: f64 = self
            .rotations
            .iter()
            .filter(|s| is_active(s.start, s.stop, t))
            .map(RotationSegment::angular_speed)
            .sum();
        // The spin axis is fixed in the body and the spin leaves it invariant, so its world
        // direction only depends on the placement.
        self.placement.rotation * self.unit_axis * speed
    }

    /// World velocity at `t` of the body point currently at `world_point`:
    /// `v + ω × (p − reference point)`.
    pub fn velocity_of_point(&self, world_point: Vec3, t: f64) -> Vec3 {
        self.linear_velocity_at(t)
            + self
                .angular_velocity_at(t)
                .cross(&(world_point - self.reference_point_at(t)))
    }
}
