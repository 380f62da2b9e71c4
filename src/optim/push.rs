//! Push-constant blocks of `glsl/optim_adam.comp`, `glsl/optim_meta.comp` and
//! `glsl/optim_diag.comp` (scalar layout, 4-byte members). Field names and order are those of
//! the GLSL `Push` blocks; every dispatch checks them against the reflected SPIR-V
//! (`crate::kernels`).

use super::{AdamHyper, FdVariance, MetaHyper, Range, Schedule, VarianceEstimate, META_BETA2};
use crate::gpu::push_block;
use crate::shared;
use bytemuck::{Pod, Zeroable};

/// An open side of a range is pushed as ±f32::MAX: the kernels saturate θ there anyway.
fn range_f32(range: Range) -> (f32, f32) {
    let side = |x: f64| (x as f32).clamp(f32::MIN, f32::MAX);
    (side(range.lo), side(range.hi))
}

/// Where a parameter group sits: its elements in every array, its diagnostics slot and its
/// first per-workgroup diagnostics record.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GroupSlots {
    pub n: u32,
    pub offset: u32,
    pub group: u32,
    pub first_partial: u32,
}

/// The schedule's members of a `Push` block, in order (flattened into each block).
struct SchedulePush {
    decay: u32,
    warmup: u32,
    horizon: u32,
    every: u32,
    floor: f32,
    gamma: f32,
}

impl From<&Schedule> for SchedulePush {
    fn from(s: &Schedule) -> Self {
        SchedulePush { decay: s.decay.code(), warmup: s.warmup, horizon: s.horizon, every: s.every, floor: s.floor as f32, gamma: s.gamma as f32 }
    }
}

/// `optim_adam.comp`'s `Push` block: 64 bytes. The step number comes from the `Frame`
/// buffer (iteration + 1).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct AdamPush {
    pub n: u32,
    pub offset: u32,
    pub group: u32,
    pub first_partial: u32,
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    pub lo: f32,
    pub hi: f32,
    pub sched_decay: u32,
    pub sched_warmup: u32,
    pub sched_horizon: u32,
    pub sched_every: u32,
    pub sched_floor: f32,
    pub sched_gamma: f32,
}

impl AdamPush {
    pub fn new(h: &AdamHyper, g: GroupSlots, lr: f64, range: Range) -> Self {
        let (lo, hi) = range_f32(range);
        let sc = SchedulePush::from(&h.schedule);
        AdamPush {
            n: g.n,
            offset: g.offset,
            group: g.group,
            first_partial: g.first_partial,
            lr: lr as f32,
            beta1: h.beta1 as f32,
            beta2: h.beta2 as f32,
            eps: h.eps as f32,
            lo,
            hi,
            sched_decay: sc.decay,
            sched_warmup: sc.warmup,
            sched_horizon: sc.horizon,
            sched_every: sc.every,
            sched_floor: sc.floor,
            sched_gamma: sc.gamma,
        }
    }
}

/// `optim_meta.comp`'s `Push` block: 92 bytes (within the 128 every Vulkan device accepts).
/// The step number comes from the `Frame` buffer (iteration + 1).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MetaPush {
    pub n: u32,
    pub offset: u32,
    pub group: u32,
    pub first_partial: u32,
    pub lr: f32,
    pub decay_f: f32,
    pub decay_d: f32,
    pub eps: f32,
    pub lo: f32,
    pub hi: f32,
    /// [`META_BETA2`]: the decay of the Wiener step's normaliser.
    pub beta2: f32,
    pub step_rule: u32,
    pub centred: u32,
    pub sched_decay: u32,
    pub sched_warmup: u32,
    pub sched_horizon: u32,
    pub sched_every: u32,
    pub sched_floor: f32,
    pub sched_gamma: f32,
    pub fd_raw: u32,
    pub decay_h: f32,
    pub sig: f32,
    pub settle: f32,
}

impl MetaPush {
    pub fn new(h: &MetaHyper, g: GroupSlots, lr: f64, range: Range) -> Self {
        let (lo, hi) = range_f32(range);
        let sc = SchedulePush::from(&h.schedule);
        MetaPush {
            n: g.n,
            offset: g.offset,
            group: g.group,
            first_partial: g.first_partial,
            lr: lr as f32,
            decay_f: h.decay_f as f32,
            decay_d: h.decay_d as f32,
            eps: h.eps as f32,
            lo,
            hi,
            beta2: META_BETA2 as f32,
            step_rule: h.step.code(),
            centred: u32::from(h.variance == VarianceEstimate::Centred),
            sched_decay: sc.decay,
            sched_warmup: sc.warmup,
            sched_horizon: sc.horizon,
            sched_every: sc.every,
            sched_floor: sc.floor,
            sched_gamma: sc.gamma,
            fd_raw: u32::from(h.fdvar == FdVariance::Raw),
            decay_h: h.decay_h as f32,
            sig: h.sig_for(g.n as usize) as f32,
            settle: h.settle as f32,
        }
    }
}

/// `optim_diag.comp`'s `Push` block: 12 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct DiagPush {
    pub first: u32,
    pub count: u32,
    pub group: u32,
}

/// The GPU's record as the CPU reference's.
impl From<shared::DiagRecord> for super::reference::DiagRecord<f32> {
    fn from(r: shared::DiagRecord) -> Self {
        let s = |x: shared::Ssq| super::reference::Ssq { scale: x.scale, sum: x.sum };
        super::reference::DiagRecord {
            count: r.count,
            n_eff_sum: r.n_eff_sum,
            n_eff_min: r.n_eff_min,
            n_eff_max: r.n_eff_max,
            clipped: r.clipped,
            newton: r.newton,
            f: s(r.f),
            df: s(r.df),
            sd_d: s(r.sd_d),
            step: s(r.step),
            mean: s(r.mean),
            sd: s(r.sd),
            sd_f: s(r.sd_f),
            curv: s(r.curv),
        }
    }
}

push_block!(AdamPush {
    n,
    offset,
    group,
    first_partial,
    lr,
    beta1,
    beta2,
    eps,
    lo,
    hi,
    sched_decay,
    sched_warmup,
    sched_horizon,
    sched_every,
    sched_floor,
    sched_gamma,
});
push_block!(MetaPush {
    n,
    offset,
    group,
    first_partial,
    lr,
    decay_f,
    decay_d,
    eps,
    lo,
    hi,
    beta2,
    step_rule,
    centred,
    sched_decay,
    sched_warmup,
    sched_horizon,
    sched_every,
    sched_floor,
    sched_gamma,
    fd_raw,
    decay_h,
    sig,
    settle,
});
push_block!(DiagPush { first, count, group });
