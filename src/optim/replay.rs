//! Replays recorded gradient streams through the CPU reference (what the GPU passes of
//! `vkinverse replay`, `super::gpu::replay_gpu`, are compared with element by element).
//!
//! Row i of `grads` is ⟨F_i⟩ and row i of `fd_grads` is ⟨ΔF_i⟩ (its row 0 is unused: the
//! first step has no previous one). Meta's ‖Δπ‖² at step i is that of step i − 1 after
//! clamping, exactly as the GPU pass reduces it. For the centred variance estimate the
//! streams also hold, per row, the sums of half of the samples of each (`grad_halves`,
//! `fd_halves`; see [`super::reference::centred_sample`]).

use super::reference::{BufferOptimiser, Diagnostics, Real, StepInput};
use super::{OptimError, Optimiser, Range};

/// Recorded gradient streams, `iterations` rows of `n` values each.
#[derive(Clone, Copy, Debug, Default)]
pub struct Streams<'a> {
    pub grads: &'a [Vec<f32>],
    pub fd_grads: Option<&'a [Vec<f32>]>,
    pub grad_halves: Option<&'a [Vec<f32>]>,
    pub fd_halves: Option<&'a [Vec<f32>]>,
}

impl<'a> Streams<'a> {
    /// Gradients and finite differences only.
    pub fn new(grads: &'a [Vec<f32>], fd_grads: Option<&'a [Vec<f32>]>) -> Self {
        Streams { grads, fd_grads, ..Default::default() }
    }

    /// Checks that every stream `optimiser` reads is there with one row per gradient row.
    pub fn check(&self, optimiser: &Optimiser) -> Result<(), OptimError> {
        let rows = |what: &'static str, s: Option<&[Vec<f32>]>| match s {
            Some(s) if s.len() != self.grads.len() => Err(OptimError::Length { what, expected: self.grads.len(), found: s.len() }),
            _ => Ok(()),
        };
        if optimiser.needs_fd() && self.fd_grads.is_none() {
            return Err(OptimError::MissingFd);
        }
        if optimiser.needs_halves() && (self.grad_halves.is_none() || self.fd_halves.is_none()) {
            return Err(OptimError::MissingHalves);
        }
        rows("finite-difference stream (iterations)", self.fd_grads)?;
        rows("half-sample gradient stream (iterations)", self.grad_halves)?;
        rows("half-sample finite-difference stream (iterations)", self.fd_halves)
    }
}

/// A replayed trajectory.
#[derive(Clone, Debug, PartialEq)]
pub struct Replay {
    /// θ before the first step and after each step: (iterations + 1) × n.
    pub theta: Vec<Vec<f64>>,
    /// Elements skipped for non-finite inputs, over all steps.
    pub nonfinite: u64,
    /// Each step's diagnostics.
    pub diagnostics: Vec<Diagnostics>,
}

impl Replay {
    /// The trajectory in float32, as written to `.npy`.
    pub fn rows_f32(&self) -> Vec<Vec<f32>> {
        self.theta.iter().map(|row| row.iter().map(|&x| x as f32).collect()).collect()
    }
}

/// Replays in the arithmetic `R`: f64 is the reference trajectory; f32 the same
/// formulation as the GPU's, up to the order of the ‖Δπ‖² reduction and the accuracy of the
/// device's `sqrt` and division. Adam ignores `fd_grads`; Meta requires them.
pub fn replay_cpu<R: Real>(
    optimiser: &Optimiser,
    grads: &[Vec<f32>],
    fd_grads: Option<&[Vec<f32>]>,
    init: &[f32],
    range: Range,
    lr: f64,
) -> Result<Replay, OptimError> {
    replay_streams::<R>(optimiser, &Streams::new(grads, fd_grads), init, range, lr)
}

/// Replays every stream in the arithmetic `R` (f64: the reference; f32: the GPU's).
pub fn replay_streams<R: Real>(optimiser: &Optimiser, streams: &Streams, init: &[f32], range: Range, lr: f64) -> Result<Replay, OptimError> {
    streams.check(optimiser)?;
    let n = init.len();
    let to_r = |row: &[f32]| row.iter().map(|&x| R::of(x as f64)).collect::<Vec<R>>();
    let to_f64 = |row: &[R]| row.iter().map(|x| x.to_f64()).collect::<Vec<f64>>();
    let row = |s: Option<&[Vec<f32>]>, i: usize| s.map(|s| to_r(&s[i]));

    let mut opt = BufferOptimiser::<R>::new(optimiser, n, lr, range)?;
    let mut theta = to_r(init);
    let mut traj = Vec::with_capacity(streams.grads.len() + 1);
    let mut diagnostics = Vec::with_capacity(streams.grads.len());
    traj.push(to_f64(&theta));
    for (i, g) in streams.grads.iter().enumerate() {
        let fd = if optimiser.needs_fd() { row(streams.fd_grads, i) } else { None };
        let (gh, fh) = if optimiser.needs_halves() { (row(streams.grad_halves, i), row(streams.fd_halves, i)) } else { (None, None) };
        let grad = to_r(g);
        let input = StepInput { grad: &grad, fd: fd.as_deref(), grad_half: gh.as_deref(), fd_half: fh.as_deref() };
        opt.step_with(&mut theta, input)?;
        traj.push(to_f64(&theta));
        diagnostics.push(*opt.diagnostics());
    }
    Ok(Replay { theta: traj, nonfinite: opt.nonfinite(), diagnostics })
}
