//! What the soil tests' records share: the centred running mean that smooths a jittering
//! record before its peak is read (the shear window's, the triaxial's deviator).

/// The centred running mean of `values` over `width` samples (fewer at the ends, where the
/// window is cut to the record).
pub fn running_mean(values: &[f64], width: usize) -> Vec<f64> {
    let half = width.max(1) / 2;
    let mut prefix = Vec::with_capacity(values.len() + 1);
    prefix.push(0.0);
    for v in values {
        prefix.push(prefix.last().copied().unwrap_or(0.0) + v);
    }
    (0..values.len())
        .map(|k| {
            let (lo, hi) = (k.saturating_sub(half), (k + half + 1).min(values.len()));
            (prefix[hi] - prefix[lo]) / (hi - lo) as f64
        })
        .collect()
}
