//! What a caller hears while a run goes: target renders, every iteration's log row and
//! optimiser diagnostics, resumes, warnings and notices. The library prints nothing: the
//! command line's observer draws progress bars and writes the messages to stderr.

use crate::optim::Diagnostics;
use std::ops::ControlFlow;

/// One row of `log.csv`: where a run stood after an iteration (row 0: the start).
#[derive(Clone, Debug, PartialEq)]
pub struct LogRow {
    pub iteration: u32,
    /// Wall time since the first iteration started, without evaluation renders, logging
    /// and checkpoints.
    pub time_s: f64,
    pub gpu_time_s: f64,
    /// None for row 0 (the start, before any render).
    pub loss: Option<f64>,
    /// Parameter RMSE overall and per parameter; None when the reference is unknown.
    pub param_error: Option<f64>,
    pub param_errors: Vec<Option<f64>>,
}

/// Hears about a run while it goes. Every method has a default that does nothing, so an
/// observer implements what it needs; `()` hears nothing.
///
/// ```
/// use std::ops::ControlFlow;
/// use vkinverse::{LogRow, Observer};
///
/// /// Stops a run once its loss falls below a threshold.
/// struct StopBelow(f64);
///
/// impl Observer for StopBelow {
///     fn iteration(&mut self, row: &LogRow, _diagnostics: &[vkinverse::Diagnostics]) -> ControlFlow<()> {
///         match row.loss {
///             Some(loss) if loss < self.0 => ControlFlow::Break(()),
///             _ => ControlFlow::Continue(()),
///         }
///     }
/// }
/// ```
pub trait Observer {
    /// A target image is being rendered: `done` of `total` samples of sensor `sensor`.
    fn target_progress(&mut self, _sensor: usize, _done: u32, _total: u32) {}
    /// An iteration finished: its log row and the optimiser's diagnostics of its step, one
    /// per optimised parameter in the scene's order. `Break` stops the run after this
    /// iteration, as a cancellation does (its outputs are written; it can be resumed).
    fn iteration(&mut self, _row: &LogRow, _diagnostics: &[Diagnostics]) -> ControlFlow<()> {
        ControlFlow::Continue(())
    }
    /// The run continues from the checkpoint at `iteration`, with `changes` (one
    /// `key: old -> new` per setting that differs from the checkpoint's).
    fn resumed(&mut self, _iteration: u32, _changes: &[String]) {}
    /// Something the user should know that does not stop the work (a target that could not
    /// be cached, say).
    fn warning(&mut self, _message: &str) {}
    /// What the work does about something the caller did (a cancellation, say).
    fn notice(&mut self, _message: &str) {}
    /// A run of a comparison or a batch starts: its label (a job's with its number) and its
    /// iterations where a count bounds it. Its targets, iterations and messages follow.
    fn run_started(&mut self, _label: &str, _iterations: Option<u32>) {}
    /// A run of a comparison or a batch ended: its label and how (`ok`, `failed: WHY`,
    /// `interrupted: WHERE`).
    fn run_ended(&mut self, _label: &str, _status: &str) {}
}

/// An observer that hears nothing.
impl Observer for () {}
