//! The DEM engine (Hertz-Mindlin no-slip, rolling friction, triangle meshes).

pub mod math;
pub mod mesh;
pub mod kinematics;
pub mod distribution;
pub mod factory;
