//! The optimisers on the GPU: one fused pass per parameter group (`glsl/optim_adam.comp`,
//! `glsl/optim_meta.comp`), then one diagnostics merge per group (`glsl/optim_diag.comp`),
//! recorded into the iteration's command buffer.
//!
//! All groups share one θ buffer (and state arrays of the same length); a group is a
//! range of it with its own learning rate and bounds. Each pass writes one diagnostics
//! record per workgroup; the merge reduces a group's records into its slot of the `diag`
//! buffer. For the meta-estimator that slot's sum of squared steps is the group's ‖Δπ‖²,
//! which the next iteration's pass reads, so no value crosses to the host inside an
//! iteration; the host reads the slots after the iteration for `optimiser.csv`.
//!
//! The centred variance estimate needs each gradient pass to sum half of its samples into
//! a second buffer: the optimiser owns those buffers ([`GpuOptimiser::halves`]) and clears
//! them with the gradients.

use super::push::{AdamPush, DiagPush, GroupSlots, MetaPush};
use super::reference::{DiagRecord, Diagnostics};
use super::replay::Streams;
use super::{Optimiser, Range};
use crate::gpu::{self, BindGroup, Buffer, ComputePipeline, Context, MemoryKind, Recorder};
use crate::ops::BufferOps;
use crate::shared;
use crate::constants::OPTIM_CHUNKS;
use std::sync::Arc;

/// The vec4s of θ (from element 0) that hold group `g`'s elements.
fn vec4_chunks(g: &Group) -> u64 {
    if g.len == 0 {
        return 0;
    }
    ((g.offset + g.len).div_ceil(4) - g.offset / 4) as u64
}

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
    /// The vec4s that hold the group's elements.
    chunks: u64,
    diag_push: DiagPush,
}

/// The sums of half of the samples of the gradient and of the finite-difference sample.
pub struct Halves {
    pub grad: Buffer,
    pub fd_grad: Buffer,
}

/// What the optimiser passes read and write: θ, the gradient and for meta the
/// finite-difference sample (both read and cleared by the passes), the iteration counter
/// (step t = iteration + 1), and θ's parameter groups.
#[derive(Clone, Copy)]
pub struct OptimiserBuffers<'a> {
    pub theta: &'a Buffer,
    pub grad: &'a Buffer,
    pub fd_grad: Option<&'a Buffer>,
    pub frame: &'a Buffer,
    pub groups: &'a [Group],
}

/// The fused optimiser passes of one θ buffer.
pub struct GpuOptimiser {
    optimiser: Optimiser,
    groups: Vec<Group>,
    pipeline: ComputePipeline,
    diag_pipeline: ComputePipeline,
    diag_group: BindGroup,
    passes: Vec<Pass>,
    /// The optimiser's own state arrays (what a checkpoint must save besides θ).
    state: Vec<Buffer>,
    /// One [`shared::DiagRecord`] per group: the last step's diagnostics.
    diag: Buffer,
    /// θ of the previous iteration (meta only): the finite-difference pass reads it.
    pub theta_prev: Option<Buffer>,
    /// The half-sample sums (meta with the centred variance estimate only).
    pub halves: Option<Halves>,
    /// Count of non-finite gradient elements skipped so far.
    pub nonfinite: Buffer,
}

impl GpuOptimiser {
    /// Builds the passes of `optimiser` over `buffers`.
    ///
    /// Not split: one arm per optimiser, each binding its own state arrays per group.
    pub fn new(ctx: &Arc<Context>, optimiser: &Optimiser, buffers: &OptimiserBuffers) -> gpu::Result<Self> {
        let OptimiserBuffers { theta, grad, fd_grad, frame, groups } = *buffers;
        // The state arrays cover θ's elements, the groups' extent in whole texels (θ's
        // buffer may hold more after them: a scene's material data, which no optimiser reads
        // or moves).
        let n_total = gpu::texel_padded(groups.iter().map(|g| g.offset + g.len).max().unwrap_or(0));
        let zeros = |name: &str| Buffer::zeroed::<f32>(ctx, name, n_total, MemoryKind::Device);
        let nonfinite = Buffer::zeroed::<u32>(ctx, "nonfinite", 1, MemoryKind::Device)?;
        // The passes read and write whole vec4s: every per-element buffer they bind holds the
        // vec4 of each group's last element.
        let extent = groups.iter().map(|g| (g.offset + g.len).next_multiple_of(4)).max().unwrap_or(0);
        for (name, b) in [("theta", Some(theta)), ("grad", Some(grad)), ("fd grad", fd_grad)] {
            if let Some(b) = b.filter(|b| b.storage_extent() < extent as u64 * 4) {
                return Err(gpu::GpuError::BufferAccess {
                    name: name.into(),
                    what: format!("{} bytes bound as a storage buffer: the optimiser passes step whole vec4s, {} bytes", b.storage_extent(), extent * 4),
                });
            }
        }
        let mut slots = Vec::new();
        let mut first = 0u32;
        for (k, g) in groups.iter().enumerate() {
            let count = vec4_chunks(g).div_ceil(256 * OPTIM_CHUNKS as u64) as u32;
            slots.push((GroupSlots { n: g.len as u32, offset: g.offset as u32, group: k as u32, first_partial: first }, count));
            first += count;
        }
        let partials = Buffer::zeroed::<shared::DiagRecord>(ctx, "diag partials", (first as usize).max(1), MemoryKind::Device)?;
        let diag = Buffer::zeroed::<shared::DiagRecord>(ctx, "optimiser diagnostics", groups.len().max(1), MemoryKind::Device)?;
        let diag_pipeline = ComputePipeline::new(ctx, "optim_diag", &[])?;
        let diag_group = diag_pipeline.bind(&[("DiagPartial", &partials), ("Diag", &diag)])?;
        let diag_push = |(g, count): (GroupSlots, u32)| DiagPush { first: g.first_partial, count, group: g.group };
        let mut passes = Vec::new();
        let mut state = Vec::new();
        let (pipeline, theta_prev, halves) = match optimiser {
            Optimiser::Adam(h) => {
                let pipeline = ComputePipeline::new(ctx, "optim_adam", &[])?;
                let (m, r) = (zeros("adam m")?, zeros("adam r")?);
                state.extend([m.clone(), r.clone()]);
                for (g, s) in groups.iter().zip(&slots) {
                    let group = pipeline.bind(&[
                        ("Theta", theta),
                        ("Grad", grad),
                        ("AdamM", &m),
                        ("AdamR", &r),
                        ("DiagPartial", &partials),
                        ("NonFinite", &nonfinite),
                        ("Frame", frame),
                    ])?;
                    let push = AdamPush::new(h, s.0, g.lr, g.range);
                    passes.push(Pass { group, push: Push::Adam(push), chunks: vec4_chunks(g), diag_push: diag_push(*s) });
                }
                (pipeline, None, None)
            }
            Optimiser::Meta(h) => {
                let pipeline = ComputePipeline::new(ctx, "optim_meta", &[])?;
                let fd = fd_grad.ok_or_else(|| gpu::GpuError::BufferAccess {
                    name: "fd grad".into(),
                    what: "the meta-estimator needs a finite-difference gradient buffer".into(),
                })?;
                // Shaped like θ's buffer: the finite-difference kernels read the previous
                // iterate through it, and the two-trace sample binds it as θ, material
                // data included (copied here; θ's writes leave them as they are).
                let theta_prev = theta.duplicate("theta prev")?;
                let halves = if optimiser.needs_halves() { Some(Halves { grad: zeros("grad half")?, fd_grad: zeros("fd grad half")? }) } else { None };
                // Without the centred estimate the kernel never touches the half buffers.
                let unused = match &halves {
                    Some(_) => None,
                    None => Some(Buffer::zeroed::<f32>(ctx, "half sums (unused)", 1, MemoryKind::Device)?),
                };
                let (grad_half, fd_half) = match (&halves, &unused) {
                    (Some(hv), _) => (hv.grad.clone(), hv.fd_grad.clone()),
                    (None, Some(u)) => (u.clone(), u.clone()),
                    (None, None) => unreachable!("one of the two is set"),
                };
                let names = [
                    "meta mean",
                    "meta sd",
                    "meta rms f",
                    "meta rms d",
                    "meta wsum d",
                    "meta n eff",
                    "meta v",
                    "meta curv",
                    "meta curv w",
                    "meta last",
                ];
                let meta_state: Vec<Buffer> = names.iter().map(|n| zeros(n)).collect::<gpu::Result<_>>()?;
                state.extend(meta_state.iter().cloned());
                state.push(theta_prev.clone());
                for (g, s) in groups.iter().zip(&slots) {
                    let group = pipeline.bind(&[
                        ("Theta", theta),
                        ("ThetaPrev", &theta_prev),
                        ("Grad", grad),
                        ("FdGrad", fd),
                        ("GradHalf", &grad_half),
                        ("FdGradHalf", &fd_half),
                        ("MetaMean", &meta_state[0]),
                        ("MetaSd", &meta_state[1]),
                        ("MetaRmsF", &meta_state[2]),
                        ("MetaRmsD", &meta_state[3]),
                        ("MetaWsumD", &meta_state[4]),
                        ("MetaNEff", &meta_state[5]),
                        ("MetaV", &meta_state[6]),
                        ("MetaCurv", &meta_state[7]),
                        ("MetaCurvW", &meta_state[8]),
                        ("MetaLast", &meta_state[9]),
                        ("Diag", &diag),
                        ("DiagPartial", &partials),
                        ("NonFinite", &nonfinite),
                        ("Frame", frame),
                    ])?;
                    let push = MetaPush::new(h, s.0, g.lr, g.range);
                    passes.push(Pass { group, push: Push::Meta(push), chunks: vec4_chunks(g), diag_push: diag_push(*s) });
                }
                (pipeline, Some(theta_prev), halves)
            }
        };
        // The diagnostics hold the meta-estimator's ‖Δπ‖² between iterations.
        state.push(diag.clone());
        Ok(Self { optimiser: *optimiser, groups: groups.to_vec(), pipeline, diag_pipeline, diag_group, passes, state, diag, theta_prev, halves, nonfinite })
    }

    /// Records every group's pass, then the merge of each group's diagnostics (for meta,
    /// the next iteration's ‖Δπ‖²).
    ///
    /// Groups touch disjoint ranges, and each merge writes its own slot, but storage
    /// buffers are bound whole, so the recorder orders the dispatches as it would any others
    /// (the validation layer's synchronization check sees whole bindings too).
    pub fn record(&self, rec: &mut Recorder, _ops: &BufferOps) -> gpu::Result<()> {
        for p in &self.passes {
            match &p.push {
                Push::Adam(push) => rec.dispatch_linear(&self.pipeline, &p.group, push, p.chunks.div_ceil(OPTIM_CHUNKS as u64))?,
                Push::Meta(push) => rec.dispatch_linear(&self.pipeline, &p.group, push, p.chunks.div_ceil(OPTIM_CHUNKS as u64))?,
            }
        }
        for p in &self.passes {
            rec.dispatch_groups(&self.diag_pipeline, &self.diag_group, &p.diag_push, [1, 1, 1])?;
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

    /// Whether `buffer` is one of the state arrays of one value per element of θ (all but
    /// the diagnostics, one record per group).
    pub fn per_element(&self, buffer: &Buffer) -> bool {
        !buffer.same(&self.diag) && self.state.iter().any(|s| s.same(buffer))
    }

    /// Non-finite gradient elements skipped so far.
    pub fn nonfinite_count(&self) -> gpu::Result<u32> {
        Ok(self.nonfinite.read::<u32>()?[0])
    }

    /// The last step's records, one per group, as the GPU merged them.
    pub fn records(&self) -> gpu::Result<Vec<DiagRecord<f32>>> {
        let raw: Vec<shared::DiagRecord> = self.diag.read()?;
        Ok(raw.into_iter().take(self.groups.len()).map(DiagRecord::from).collect())
    }

    /// The diagnostics of step `t` (counted from 1), one per group, after it ran.
    pub fn diagnostics(&self, t: u32) -> gpu::Result<Vec<Diagnostics>> {
        Ok(self.diagnostics_of(&self.records()?, t))
    }

    /// The buffer of the last step's records (one [`shared::DiagRecord`] per group first),
    /// and the bytes they take, for a copy of them.
    pub fn records_buffer(&self) -> (&Buffer, u64) {
        (&self.diag, (self.groups.len() * std::mem::size_of::<shared::DiagRecord>()) as u64)
    }

    /// The diagnostics of step `t` from the records of its groups as the GPU wrote them
    /// (bytes as [`Self::records_buffer`] names them).
    pub fn diagnostics_from_bytes(&self, bytes: &[u8], t: u32) -> Vec<Diagnostics> {
        let records: Vec<DiagRecord<f32>> = bytes
            .chunks_exact(std::mem::size_of::<shared::DiagRecord>())
            .map(|c| DiagRecord::from(bytemuck::pod_read_unaligned::<shared::DiagRecord>(c)))
            .collect();
        self.diagnostics_of(&records, t)
    }

    fn diagnostics_of(&self, records: &[DiagRecord<f32>], t: u32) -> Vec<Diagnostics> {
        let factor = self.optimiser.schedule().factor(t);
        records.iter().zip(&self.groups).map(|(r, g)| Diagnostics::from_record(r, g.lr * factor)).collect()
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

/// What [`replay_gpu_groups`] returns.
pub struct GpuReplay {
    /// θ before the first step and after each step.
    pub theta: Vec<Vec<f32>>,
    /// Elements skipped for non-finite inputs.
    pub nonfinite: u32,
    /// Each step's diagnostics, one per group.
    pub diagnostics: Vec<Vec<Diagnostics>>,
    /// Each step's records as the GPU merged them, one per group.
    pub records: Vec<Vec<DiagRecord<f32>>>,
}

/// Runs the GPU optimiser passes on recorded gradient streams (`vkinverse replay`), the
/// half-sample sums of the centred variance estimate too, returning the trajectory
/// (`iterations + 1` rows), the count of skipped non-finite elements and each step's
/// diagnostics; the buffer is one group.
pub fn replay_gpu_streams(ctx: &Arc<Context>, optimiser: &Optimiser, streams: &Streams, init: &[f32], range: Range, lr: f64) -> gpu::Result<GpuReplay> {
    replay_gpu_groups(ctx, optimiser, streams, init, &[Group { offset: 0, len: init.len(), lr, range }])
}

/// [`replay_gpu_streams`] with the buffer split into parameter groups, as a scene's
/// parameters are.
pub fn replay_gpu_groups(ctx: &Arc<Context>, optimiser: &Optimiser, streams: &Streams, init: &[f32], groups: &[Group]) -> gpu::Result<GpuReplay> {
    streams.check(optimiser).map_err(|e| gpu::GpuError::BufferAccess { name: "replay streams".into(), what: e.to_string() })?;
    // Whole vec4s, as the optimiser passes step them.
    let n = init.len().next_multiple_of(4).max(4);
    let ops = BufferOps::new(ctx)?;
    let mut padded = init.to_vec();
    padded.resize(n, 0.0);
    let theta = Buffer::from_slice(ctx, "theta", &padded, MemoryKind::Device)?;
    let grad = Buffer::zeroed::<f32>(ctx, "grad", n, MemoryKind::Upload)?;
    let fd = Buffer::zeroed::<f32>(ctx, "fd grad", n, MemoryKind::Upload)?;
    let frame = Buffer::from_slice(ctx, "frame", &[0u32], MemoryKind::Upload)?;
    let opt = GpuOptimiser::new(ctx, optimiser, &OptimiserBuffers { theta: &theta, grad: &grad, fd_grad: Some(&fd), frame: &frame, groups })?;
    let mut cmd = gpu::CommandBuffer::new(ctx, "replay")?;
    cmd.record(|rec| opt.record(rec, &ops))?;
    let mut out = GpuReplay { theta: vec![init.to_vec()], nonfinite: 0, diagnostics: Vec::new(), records: Vec::new() };
    for (i, g) in streams.grads.iter().enumerate() {
        frame.write(&[i as u32])?;
        grad.write(g)?;
        if let Some(fd_rows) = streams.fd_grads {
            fd.write(&fd_rows[i])?;
        }
        if let (Some(h), Some(gh), Some(fh)) = (&opt.halves, streams.grad_halves, streams.fd_halves) {
            h.grad.write(&gh[i])?;
            h.fd_grad.write(&fh[i])?;
        }
        cmd.submit_and_wait()?;
        let mut t: Vec<f32> = theta.read()?;
        t.truncate(init.len());
        out.theta.push(t);
        out.diagnostics.push(opt.diagnostics(i as u32 + 1)?);
        out.records.push(opt.records()?);
    }
    out.nonfinite = opt.nonfinite_count()?;
    Ok(out)
}
