//! Design of experiments and response-surface statistics.
pub mod design;
