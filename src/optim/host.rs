//! The optimiser passes on host arrays, for a caller that produces the gradient streams
//! itself (the Python package's loop over a loss written in Python): the f64 reference of
//! [`super::reference`] behind a spec, parameter groups and float32 buffers, stepping
//! exactly as `vkinverse replay` and the renderer's optimiser pass do.
//!
//! ```
//! use vkinverse::replay::Range;
//! use vkinverse::{HostGroup, HostOptimiser, HostStep};
//! // f(θ) = θ²/2 from θ = 1: exact gradients θ and finite differences θ_i − θ_{i−1}, whose
//! // halves are half of them (no variance).
//! let group = HostGroup { len: 1, lr: 0.1, range: Range::UNBOUNDED };
//! let mut opt = HostOptimiser::new("meta", &[group], None).unwrap();
//! let (mut theta, mut prev) = ([1.0f32], 1.0f32);
//! for _ in 0..100 {
//!     let (grad, fd) = ([theta[0]], [theta[0] - prev]);
//!     let (grad_half, fd_half) = ([grad[0] / 2.0], [fd[0] / 2.0]);
//!     prev = theta[0];
//!     let input = HostStep { grad: &grad, fd: Some(&fd), grad_half: Some(&grad_half), fd_half: Some(&fd_half) };
//!     opt.step(&mut theta, input).unwrap();
//! }
//! assert!(theta[0].abs() < 1e-3, "{theta:?}");
//! ```

use super::reference::{GroupedOptimiser, StepInput};
use super::spec::Spec;
use super::{Diagnostics, OptimError, Optimiser, Range};

/// One parameter group: its number of elements, learning rate and range. The groups of a
/// buffer lie one after the other in it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HostGroup {
    pub len: usize,
    pub lr: f64,
    pub range: Range,
}

/// One step's inputs over the whole buffer: the gradient ⟨F_i⟩, for meta the
/// finite-difference sample ⟨ΔF_i⟩ (ignored on the first step, which has no previous one),
/// and for meta with `var=centred` the sums of half of the samples of each (the total is
/// their mean's double: with halves A and B estimated alike, `grad` = (A + B)/2 and
/// `grad_half` = A/2).
#[derive(Clone, Copy, Debug, Default)]
pub struct HostStep<'a> {
    pub grad: &'a [f32],
    pub fd: Option<&'a [f32]>,
    pub grad_half: Option<&'a [f32]>,
    pub fd_half: Option<&'a [f32]>,
}

/// An optimiser named by a spec (`adam`, `meta`, `meta-seed`, with `@KEY=VALUE`
/// hyperparameters) over a float32 buffer of parameter groups, its state kept in f64.
#[derive(Clone, Debug)]
pub struct HostOptimiser {
    spec: Spec,
    groups: GroupedOptimiser<f64>,
    len: usize,
}

impl HostOptimiser {
    /// The optimiser of `spec` over `groups`; `iterations`, where known, is the horizon of a
    /// cosine schedule that does not give one (as for a run or a replay).
    pub fn new(spec: &str, groups: &[HostGroup], iterations: Option<u32>) -> Result<Self, OptimError> {
        let mut spec: Spec = spec.parse()?;
        if let Some(n) = iterations {
            spec.optimiser = spec.optimiser.resolve(n);
        }
        let mut offset = 0;
        let mut table = Vec::with_capacity(groups.len());
        for g in groups {
            let range = Range::new(g.range.lo, g.range.hi)?;
            table.push((offset, g.len, g.lr, range));
            offset += g.len;
        }
        let groups = GroupedOptimiser::new(&spec.optimiser, &table)?;
        Ok(HostOptimiser { spec, groups, len: offset })
    }

    /// The spec as parsed (its label is the text that named it).
    pub fn spec(&self) -> &Spec {
        &self.spec
    }

    pub fn optimiser(&self) -> &Optimiser {
        &self.spec.optimiser
    }

    /// The buffer's number of elements (all groups).
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// One step of every group over `theta`, in place; returns the number of elements
    /// skipped for a non-finite input (they keep their value).
    pub fn step(&mut self, theta: &mut [f32], input: HostStep) -> Result<u64, OptimError> {
        let n = self.len;
        let check = |what: &'static str, found: usize| if found == n { Ok(()) } else { Err(OptimError::Length { what, expected: n, found }) };
        check("theta", theta.len())?;
        check("gradient", input.grad.len())?;
        let wide = |s: &[f32]| s.iter().map(|&x| x as f64).collect::<Vec<f64>>();
        let wide_opt = |what: &'static str, s: Option<&[f32]>| -> Result<Option<Vec<f64>>, OptimError> {
            s.map(|s| {
                check(what, s.len())?;
                Ok(wide(s))
            })
            .transpose()
        };
        let fd = wide_opt("finite-difference gradient", input.fd)?;
        let grad_half = wide_opt("half-sample gradient", input.grad_half)?;
        let fd_half = wide_opt("half-sample finite-difference gradient", input.fd_half)?;
        let grad = wide(input.grad);
        let mut th = wide(theta);
        let skipped = self.groups.step_with(
            &mut th,
            StepInput { grad: &grad, fd: fd.as_deref(), grad_half: grad_half.as_deref(), fd_half: fd_half.as_deref() },
        )?;
        for (t, x) in theta.iter_mut().zip(th) {
            *t = x as f32;
        }
        Ok(skipped)
    }

    /// The last step's diagnostics, one per group (zeros before the first step).
    pub fn diagnostics(&self) -> Vec<Diagnostics> {
        self.groups.diagnostics()
    }
}
