//! The DEM engine (Hertz-Mindlin no-slip, rolling friction, triangle meshes).

/// The engine's version, recorded with every result for provenance.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

pub mod bench;
pub mod contact;
pub mod distribution;
pub mod factory;
pub mod integrate;
pub mod kinematics;
pub mod material;
pub mod math;
pub mod mesh;
pub mod neighbor;
pub mod output;
pub mod particles;
pub mod scene;
pub mod world;
