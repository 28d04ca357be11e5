//! Progress and cancellation, shared by every experiment: a run reports [`Progress`] to its
//! caller's callback, which answers [`Control::Continue`] or [`Control::Cancel`].

/// What the progress callback is told.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress<'a> {
    /// 0..1, monotonic over the whole run (a phase that ends early jumps ahead).
    pub fraction: f64,
    /// The phase's name, e.g. `filling`, `settling`, `feeding`, `measuring`.
    pub phase: &'a str,
    /// Simulated time of the current phase's world, s.
    pub time: f64,
    /// Grains in the world.
    pub particles: usize,
}

/// The callback's answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    Continue,
    Cancel,
}
