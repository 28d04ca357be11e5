//! STL import and export.

/// Why an STL file could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("STL `{source_name}`: {reason}")]
pub struct StlError {
    /// File name (or `<bytes>` when parsed from memory).
    pub source_name: String,
    pub reason: String,
}
