//! Errors of the campaign library. Statistical dead ends (a fit that cannot be computed, no
//! completed runs) are not errors but [`crate::Next::NeedsAttention`]; these are misuse.

/// Why a request or a call was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CampaignError {
    /// The request is invalid; `field` is a dotted path into it.
    #[error("{field}: {reason}")]
    InvalidRequest {
        /// Offending field, e.g. `factors[2].low`.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// `advance` was given a result for a batch that is not the one outstanding.
    #[error("batch {got} is not the campaign's outstanding batch (expected {expected})")]
    UnexpectedBatch {
        /// Index the caller passed.
        got: usize,
        /// Index of the outstanding batch.
        expected: usize,
    },
    /// The campaign has finished or stopped; nothing is outstanding.
    #[error("the campaign is {state}; there is no outstanding batch")]
    NotRunning {
        /// `finished` or `needs attention`.
        state: String,
    },
    /// A run of the batch lacks a factor the campaign designed.
    #[error("run {run} of batch {batch} has no value for factor `{factor}`")]
    MissingFactor {
        /// Batch index.
        batch: usize,
        /// Run index within the batch.
        run: u32,
        /// Missing factor.
        factor: String,
    },
    /// The campaign issues several batches at once: use `Campaign::begin` and `Campaign::step`.
    #[error(
        "this campaign keeps several batches outstanding at once; drive it with begin and step"
    )]
    SeveralBatches,
    /// A design could not be built (a bug or an impossible setting), with the design error.
    #[error("could not build the {stage} design: {reason}")]
    Design {
        /// Stage name.
        stage: String,
        /// The design error.
        reason: String,
    },
}
