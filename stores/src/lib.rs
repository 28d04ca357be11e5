//! What outlives a run on disk: settled beds ([`FileBedStore`], `<dir>/<bed key>.json`) and
//! checkpoints of long runs ([`FileCheckpointStore`], `<dir>/<key>.checkpoint`), the
//! file-backed [`BedStore`](repose_experiments::soil::BedStore) and
//! [`CheckpointStore`](repose_experiments::catalog::CheckpointStore) that the worker and the
//! command line share, and [`write_atomically`], their one way of writing a file.
//!
//! Unlike the libraries below it (no I/O), this crate does file I/O; it knows nothing of HTTP.

mod beds;
mod checkpoints;

pub use beds::FileBedStore;
pub use checkpoints::{write_atomically, FileCheckpointStore};
