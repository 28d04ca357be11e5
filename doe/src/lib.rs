//! Design of experiments and response-surface statistics.
