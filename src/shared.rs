//! `#[repr(C)]` mirrors of the structs in `glsl/shared/*.glsl`.
//!
//! Kernels use the scalar block layout, so a mirror needs no padding beyond what the
//! GLSL struct has; `tests/gpu_layer.rs` compares every mirror's `offset_of!` with the
//! offsets reflected from the SPIR-V, so a drift on either side fails a test.

use bytemuck::{Pod, Zeroable};

/// Mirror of `ProbeStruct` (glsl/shared/types.glsl): 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct ProbeStruct {
    pub a: [f32; 3],
    pub b: [f32; 3],
    pub c: f32,
    pub d: u32,
}
