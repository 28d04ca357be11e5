//! Virtual experiments run on the DEM engine, and the measurements that turn their final
//! particle states into numbers (angle of repose, hole metrics). No I/O: pictures are
//! returned as SVG text for the caller to write.
//!
//! [`catalog`] puts every experiment kind behind one interface for the job server and workers.

pub mod aor;
pub mod backend;
pub mod catalog;
pub mod drill;
pub mod experiment;
pub mod formula;
pub mod progress;
pub mod replay;
pub mod shear;
pub mod soil;
mod spec_path;
mod svg;
pub mod triaxial;

pub use spec_path::{Spec, SpecError};

/// Version of the DEM engine these experiments run on (recorded with results).
pub use repose_engine::VERSION as ENGINE_VERSION;

/// 64-bit FNV-1a of `bytes`: the cache and checkpoint keys' hash (stable across builds).
pub(crate) fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}
