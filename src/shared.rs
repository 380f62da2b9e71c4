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

/// `Material::kind` of a Lambertian material (`MATERIAL_DIFFUSE`, glsl/shared/material.glsl).
pub const MATERIAL_DIFFUSE: u32 = 0;
/// `Material::kind` of the glTF metallic-roughness model (`MATERIAL_PRINCIPLED`).
pub const MATERIAL_PRINCIPLED: u32 = 1;

/// Mirror of `Material` (glsl/shared/material.glsl): 24 bytes, offsets checked against the
/// reflected SPIR-V in tests/bsdf.rs (the kind constants are checked there too, by the
/// GPU/CPU comparison of both kinds). The model is defined in glsl/lib/bsdf.glsl and
/// mirrored in f64 by [`crate::bsdf`].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Material {
    pub base_color: [f32; 3],
    pub roughness: f32,
    pub metallic: f32,
    /// [`MATERIAL_DIFFUSE`] or [`MATERIAL_PRINCIPLED`]; any other value behaves as diffuse.
    pub kind: u32,
}
