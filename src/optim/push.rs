//! Push-constant blocks of `glsl/optim_adam.comp` and `glsl/optim_meta.comp` (scalar layout:
//! eight 4-byte members, 32 bytes). Field names and order are those of the GLSL `Push`
//! blocks; every dispatch checks them against the reflected SPIR-V (`crate::push`).

use super::{AdamHyper, MetaHyper, Range};
use bytemuck::{Pod, Zeroable};

/// An open side of a range is pushed as ±f32::MAX: the kernels saturate θ there anyway.
fn range_f32(range: Range) -> (f32, f32) {
    let side = |x: f64| (x as f32).clamp(f32::MIN, f32::MAX);
    (side(range.lo), side(range.hi))
}

/// `optim_adam.comp`'s `Push` block. `offset` is the group's first element; the step
/// number comes from the `Frame` buffer (iteration + 1).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct AdamPush {
    pub n: u32,
    pub offset: u32,
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    pub lo: f32,
    pub hi: f32,
}

impl AdamPush {
    pub fn new(h: &AdamHyper, n: u32, offset: u32, lr: f64, range: Range) -> Self {
        let (lo, hi) = range_f32(range);
        AdamPush {
            n,
            offset,
            lr: lr as f32,
            beta1: h.beta1 as f32,
            beta2: h.beta2 as f32,
            eps: h.eps as f32,
            lo,
            hi,
        }
    }
}

/// `optim_meta.comp`'s `Push` block. `offset` is the group's first element; the step
/// number comes from the `Frame` buffer (iteration + 1).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MetaPush {
    pub n: u32,
    pub offset: u32,
    pub lr: f32,
    pub decay_f: f32,
    pub decay_d: f32,
    pub eps: f32,
    pub lo: f32,
    pub hi: f32,
}

impl MetaPush {
    pub fn new(h: &MetaHyper, n: u32, offset: u32, lr: f64, range: Range) -> Self {
        let (lo, hi) = range_f32(range);
        MetaPush {
            n,
            offset,
            lr: lr as f32,
            decay_f: h.decay_f as f32,
            decay_d: h.decay_d as f32,
            eps: h.eps as f32,
            lo,
            hi,
        }
    }
}
