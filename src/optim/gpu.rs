//! The optimisers on the GPU: one fused pass per parameter group (`glsl/optim_adam.comp`,
//! `glsl/optim_meta.comp`), recorded into the iteration's command buffer.
//!
//! All groups share one θ buffer (and state arrays of the same length); a group is a
//! range of it with its own learning rate and bounds. For the meta-estimator each group
//! also owns its ‖Δπ‖² reduction: the pass writes per-workgroup partial sums of its
//! squared steps, a reduction sums them on the GPU into the 1-float buffer the next
//! iteration's pass reads, so no value crosses to the host inside an iteration.

use super::push::{AdamPush, MetaPush};
use super::{Optimiser, Range};
use crate::gpu::{self, Access, BindGroup, Buffer, ComputePipeline, Context, MemoryKind, Recorder};
use crate::ops::{BufferOps, Reduction};
use std::sync::Arc;

/// One parameter group: `len` elements of θ from `offset`.
#[derive(Clone, Copy, Debug)]
pub struct Group {
    pub offset: usize,
    pub len: usize,
    pub lr: f64,
    pub range: Range,
}

/// A group's push constants, of the optimiser's kernel.
enum Push {
    Adam(AdamPush),
    Meta(MetaPush),
}

struct Pass {
    group: BindGroup,
    push: Push,
    n: u64,
    dpi2: Option<Reduction>,
}

/// The fused optimiser passes of one θ buffer.
pub struct GpuOptimiser {
    pipeline: ComputePipeline,
    passes: Vec<Pass>,
    /// Buffers the passes write, for the barriers in front of them.
    written: Vec<Buffer>,
    /// The optimiser's own state arrays (what a checkpoint must save besides θ).
    state: Vec<Buffer>,
    /// θ of the previous iteration (meta only): the finite-difference pass reads it.
    pub theta_prev: Option<Buffer>,
    /// Count of non-finite gradient elements skipped so far.
    pub nonfinite: Buffer,
}

impl GpuOptimiser {
    /// Builds the passes. `grad` (and for meta `fd_grad`) are read and cleared by the
    /// passes; `frame` holds the iteration counter (step t = iteration + 1).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        ctx: &Arc<Context>,
        ops: &BufferOps,
        optimiser: &Optimiser,
        theta: &Buffer,
        grad: &Buffer,
        fd_grad: Option<&Buffer>,
        frame: &Buffer,
        groups: &[Group],
    ) -> gpu::Result<Self> {
        let n_total = (theta.len() / 4) as usize;
        let zeros = |name: &str| Buffer::zeroed::<f32>(ctx, name, n_total, MemoryKind::Device);
        let nonfinite = Buffer::zeroed::<u32>(ctx, "nonfinite", 1, MemoryKind::Device)?;
        let mut written = vec![theta.clone(), grad.clone(), nonfinite.clone()];
        let mut passes = Vec::new();
        let mut state = Vec::new();
        let (pipeline, theta_prev) = match optimiser {
            Optimiser::Adam(h) => {
                let pipeline = ComputePipeline::new(ctx, "optim_adam", &[])?;
                let (m, r) = (zeros("adam m")?, zeros("adam r")?);
                written.extend([m.clone(), r.clone()]);
                state.extend([m.clone(), r.clone()]);
                for g in groups {
                    let group = pipeline.bind(&[
                        ("Theta", theta),
                        ("Grad", grad),
                        ("AdamM", &m),
                        ("AdamR", &r),
                        ("NonFinite", &nonfinite),
                        ("Frame", frame),
                    ])?;
                    let push = AdamPush::new(h, g.len as u32, g.offset as u32, g.lr, g.range);
                    passes.push(Pass { group, push: Push::Adam(push), n: g.len as u64, dpi2: None });
                }
                (pipeline, None)
            }
            Optimiser::Meta(h) => {
                let pipeline = ComputePipeline::new(ctx, "optim_meta", &[])?;
                let fd = fd_grad.ok_or_else(|| gpu::GpuError::BufferAccess {
                    name: "fd grad".into(),
                    what: "the meta-estimator needs a finite-difference gradient buffer".into(),
                })?;
                let theta_prev = zeros("theta prev")?;
                let meta_state: Vec<Buffer> = ["meta mean", "meta sd", "meta rms f", "meta rms d", "meta wsum d", "meta n eff"]
                    .iter()
                    .map(|n| zeros(n))
                    .collect::<gpu::Result<_>>()?;
                written.extend(meta_state.iter().cloned());
                written.extend([fd.clone(), theta_prev.clone()]);
                state.extend(meta_state.iter().cloned());
                state.push(theta_prev.clone());
                let local = pipeline.local_size()[0] as u64;
                for (k, g) in groups.iter().enumerate() {
                    let partial_count = (g.len as u64).div_ceil(local).max(1) as usize;
                    let partials = Buffer::zeroed::<f32>(ctx, &format!("dpi2 partials {k}"), partial_count, MemoryKind::Device)?;
                    let reduction = ops.reduction(&partials, false)?;
                    let group = pipeline.bind(&[
                        ("Theta", theta),
                        ("ThetaPrev", &theta_prev),
                        ("Grad", grad),
                        ("FdGrad", fd),
                        ("MetaMean", &meta_state[0]),
                        ("MetaSd", &meta_state[1]),
                        ("MetaRmsF", &meta_state[2]),
                        ("MetaRmsD", &meta_state[3]),
                        ("MetaWsumD", &meta_state[4]),
                        ("MetaNEff", &meta_state[5]),
                        ("Dpi2", reduction.result()),
                        ("Dpi2Partial", &partials),
                        ("NonFinite", &nonfinite),
                        ("Frame", frame),
                    ])?;
                    written.push(partials);
                    state.push(reduction.result().clone());
                    let push = MetaPush::new(h, g.len as u32, g.offset as u32, g.lr, g.range);
                    passes.push(Pass { group, push: Push::Meta(push), n: g.len as u64, dpi2: Some(reduction) });
                }
                (pipeline, Some(theta_prev))
            }
        };
        Ok(Self { pipeline, passes, written, state, theta_prev, nonfinite })
    }

    /// Records every group's pass, then (meta) the ‖Δπ‖² reductions for the next iteration.
    pub fn record(&self, rec: &mut Recorder, ops: &BufferOps) -> gpu::Result<()> {
        let ready: Vec<(&Buffer, Access)> = self.written.iter().map(|b| (b, Access::ComputeReadWrite)).collect();
        rec.transition(&ready)?;
        for (k, p) in self.passes.iter().enumerate() {
            if k > 0 {
                // Groups touch disjoint ranges, but the tracker sees whole buffers: order them.
                rec.transition(&ready)?;
            }
            if let Some(red) = &p.dpi2 {
                rec.transition(&[(red.result(), Access::ComputeRead)])?;
            }
            match &p.push {
                Push::Adam(push) => rec.dispatch_linear(&self.pipeline, &p.group, push, p.n)?,
                Push::Meta(push) => rec.dispatch_linear(&self.pipeline, &p.group, push, p.n)?,
            }
        }
        for p in &self.passes {
            if let Some(red) = &p.dpi2 {
                ops.record_reduction(rec, red)?;
            }
        }
        Ok(())
    }

    /// The kernel of the passes (`optim_adam` or `optim_meta`), which names their profiler
    /// scope.
    pub fn kernel(&self) -> &str {
        self.pipeline.name()
    }

    /// The state arrays a checkpoint saves (with θ), each with a stable name.
    pub fn state(&self) -> &[Buffer] {
        &self.state
    }

    /// Non-finite gradient elements skipped so far.
    pub fn nonfinite_count(&self) -> gpu::Result<u32> {
        Ok(self.nonfinite.read::<u32>()?[0])
    }

    /// The meta-estimator's effective number of averaged samples per element,
    /// n_eff = 1/(1 − α) of its last step (None for Adam): how much history it is using.
    pub fn meta_n_eff(&self) -> gpu::Result<Option<Vec<f32>>> {
        match self.state.iter().find(|b| b.name() == "meta n eff") {
            Some(b) => Ok(Some(b.read()?)),
            None => Ok(None),
        }
    }
}

/// Runs the GPU optimiser passes on recorded gradient streams (`vkinverse replay`):
/// `grads` and `fd_grads` are `iterations` rows of `init.len()` values; returns the
/// trajectory, `iterations + 1` rows, and the count of skipped non-finite elements.
pub fn replay_gpu(
    ctx: &Arc<Context>,
    optimiser: &Optimiser,
    grads: &[Vec<f32>],
    fd_grads: Option<&[Vec<f32>]>,
    init: &[f32],
    range: Range,
    lr: f64,
) -> gpu::Result<(Vec<Vec<f32>>, u32)> {
    let n = init.len();
    let ops = BufferOps::new(ctx)?;
    let theta = Buffer::from_slice(ctx, "theta", init, MemoryKind::Device)?;
    let grad = Buffer::zeroed::<f32>(ctx, "grad", n, MemoryKind::Upload)?;
    let fd = Buffer::zeroed::<f32>(ctx, "fd grad", n, MemoryKind::Upload)?;
    let frame = Buffer::from_slice(ctx, "frame", &[0u32], MemoryKind::Upload)?;
    let groups = [Group { offset: 0, len: n, lr, range }];
    let opt = GpuOptimiser::new(ctx, &ops, optimiser, &theta, &grad, Some(&fd), &frame, &groups)?;
    let mut cmd = gpu::CommandBuffer::new(ctx, "replay")?;
    cmd.record(|rec| opt.record(rec, &ops))?;
    let mut trajectory = vec![init.to_vec()];
    for (i, g) in grads.iter().enumerate() {
        frame.write(&[i as u32])?;
        grad.write(g)?;
        if let Some(fd_rows) = fd_grads {
            fd.write(&fd_rows[i])?;
        }
        cmd.submit_and_wait()?;
        trajectory.push(theta.read()?);
    }
    Ok((trajectory, opt.nonfinite_count()?))
}
