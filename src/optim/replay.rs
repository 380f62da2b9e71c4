//! Replays recorded gradient streams through the CPU reference (what the GPU passes of
//! `vkinverse replay`, `super::gpu::replay_gpu`, are compared with element by element), and
//! reads and checks the command's input files ([`ReplayInput`]).
//!
//! Row i of `grads` is ⟨F_i⟩ and row i of `fd_grads` is ⟨ΔF_i⟩ (its row 0 is unused: the
//! first step has no previous one). Meta's ‖Δπ‖² at step i is that of step i − 1 after
//! clamping, exactly as the GPU pass reduces it.

use super::reference::{BufferOptimiser, Real};
use super::{OptimError, Optimiser, Range};
use std::path::Path;

/// The input of `vkinverse replay`, read from `.npy` files and checked: equally long rows,
/// the finite-difference stream of the same shape, finite start values.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayInput {
    pub grads: Vec<Vec<f32>>,
    pub fd_grads: Option<Vec<Vec<f32>>>,
    pub init: Vec<f32>,
}

impl ReplayInput {
    /// Reads `grads` (`[iterations, n]`), `fd_grads` (the same shape; required when
    /// `needs_fd`) and `init` (n finite values; zeros when absent).
    pub fn load(grads: &Path, fd_grads: Option<&Path>, init: Option<&Path>, needs_fd: bool) -> crate::error::Result<Self> {
        let bad = |path: &Path, what: String| crate::error::Error::Invalid(format!("{}: {what}", path.display()));
        let g = crate::npy::read(grads)?;
        if g.shape.len() != 2 {
            return Err(bad(grads, format!("expected shape [iterations, n], got {:?}", g.shape)));
        }
        let n = g.shape[1];
        let fd = match (fd_grads, needs_fd) {
            (Some(p), _) => {
                let a = crate::npy::read(p)?;
                if a.shape != g.shape {
                    return Err(bad(p, format!("shape {:?} differs from the gradients' {:?}", a.shape, g.shape)));
                }
                Some(a.rows())
            }
            (None, true) => return Err(crate::error::Error::Invalid("--optimiser meta needs FD_GRADS.npy (finite-difference samples) after GRADS.npy".into())),
            (None, false) => None,
        };
        let init = match init {
            Some(p) => {
                let a = crate::npy::read(p)?;
                if a.data.len() != n {
                    return Err(bad(p, format!("{} values, the gradients have {n} per row", a.data.len())));
                }
                if let Some((i, v)) = a.data.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                    return Err(bad(p, format!("value {i} is {v}: start values must be finite")));
                }
                a.data
            }
            None => vec![0.0; n],
        };
        Ok(ReplayInput { grads: g.rows(), fd_grads: fd, init })
    }
}

/// A replayed trajectory.
#[derive(Clone, Debug, PartialEq)]
pub struct Replay {
    /// θ before the first step and after each step: (iterations + 1) × n.
    pub theta: Vec<Vec<f64>>,
    /// Elements skipped for non-finite inputs, over all steps.
    pub nonfinite: u64,
}

impl Replay {
    /// The trajectory in float32, as written to `.npy`.
    pub fn rows_f32(&self) -> Vec<Vec<f32>> {
        self.theta
            .iter()
            .map(|row| row.iter().map(|&x| x as f32).collect())
            .collect()
    }
}

/// Replays in f64: the reference trajectory. Adam ignores `fd_grads`; Meta requires them.
pub fn replay_cpu(
    optimiser: &Optimiser,
    grads: &[Vec<f32>],
    fd_grads: Option<&[Vec<f32>]>,
    init: &[f32],
    range: Range,
    lr: f64,
) -> Result<Replay, OptimError> {
    replay_in::<f64>(optimiser, grads, fd_grads, init, range, lr)
}

/// Replays in f32 with the same formulation: what the GPU computes, up to the order of the
/// ‖Δπ‖² reduction and the accuracy of the device's `sqrt` and division.
pub fn replay_cpu_f32(
    optimiser: &Optimiser,
    grads: &[Vec<f32>],
    fd_grads: Option<&[Vec<f32>]>,
    init: &[f32],
    range: Range,
    lr: f64,
) -> Result<Replay, OptimError> {
    replay_in::<f32>(optimiser, grads, fd_grads, init, range, lr)
}

fn replay_in<R: Real>(
    optimiser: &Optimiser,
    grads: &[Vec<f32>],
    fd_grads: Option<&[Vec<f32>]>,
    init: &[f32],
    range: Range,
    lr: f64,
) -> Result<Replay, OptimError> {
    let n = init.len();
    let fd_grads = if optimiser.needs_fd() {
        let fd = fd_grads.ok_or(OptimError::MissingFd)?;
        if fd.len() != grads.len() {
            return Err(OptimError::Length {
                what: "finite-difference stream (iterations)",
                expected: grads.len(),
                found: fd.len(),
            });
        }
        Some(fd)
    } else {
        None
    };
    let to_r = |row: &[f32]| row.iter().map(|&x| R::of(x as f64)).collect::<Vec<R>>();
    let to_f64 = |row: &[R]| row.iter().map(|x| x.to_f64()).collect::<Vec<f64>>();

    let mut opt = BufferOptimiser::<R>::new(optimiser, n, lr, range)?;
    let mut theta = to_r(init);
    let mut traj = Vec::with_capacity(grads.len() + 1);
    traj.push(to_f64(&theta));
    for (i, g) in grads.iter().enumerate() {
        let fd = fd_grads.map(|fd| to_r(&fd[i]));
        opt.step(&mut theta, &to_r(g), fd.as_deref())?;
        traj.push(to_f64(&theta));
    }
    Ok(Replay {
        theta: traj,
        nonfinite: opt.nonfinite(),
    })
}
