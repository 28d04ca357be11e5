//! Vector and pose types shared by every part of the engine.
//!
//! nalgebra's fixed-size types compile to plain arrays of `f64`, so they are as fast as
//! hand-rolled vectors in the hot loop while giving us tested quaternion and isometry code.

/// A 3-vector in metres, metres per second, newtons, ... (SI throughout).
pub type Vec3 = nalgebra::Vector3<f64>;
/// A rigid-body pose: rotation followed by translation.
pub type Pose = nalgebra::Isometry3<f64>;
/// A unit quaternion rotation.
pub type Rotation = nalgebra::UnitQuaternion<f64>;
