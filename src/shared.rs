//! `#[repr(C)]` mirrors of the structs in `glsl/shared/*.glsl`.
//!
//! Kernels use the scalar block layout, so a mirror needs no padding beyond what the
//! GLSL struct has; tests compare every mirror's `offset_of!` with the offsets reflected
//! from the SPIR-V, so a drift on either side fails a test. Records that kernels read from
//! texel buffers are a whole number of 16-byte texels ([`TEXEL_RECORDS`]).

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

pub use crate::constants::{
    COATING_NONLINEAR, COATING_UNLAYERED, MATERIAL_CONDUCTOR, MATERIAL_CONDUCTOR_BECKMANN, MATERIAL_DIELECTRIC, MATERIAL_DIFFUSE, MATERIAL_PLASTIC, MATERIAL_PLASTIC_BECKMANN, MATERIAL_PRINCIPLED,
    MATERIAL_ROUGH_DIELECTRIC, MATERIAL_ROUGH_DIELECTRIC_BECKMANN, MATERIAL_THIN_DIELECTRIC, PLASTIC_TABLE_SIZE,
};

/// Mirror of `Material` (glsl/shared/material.glsl): 80 bytes, offsets checked against the
/// reflected SPIR-V in tests/suite/bsdf.rs (the kind constants are defined once, in
/// [`crate::constants`]). The model is defined in glsl/lib/bsdf.glsl and
/// mirrored in f64 by [`crate::bsdf`].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Material {
    pub base_color: [f32; 3],
    pub roughness: f32,
    pub metallic: f32,
    /// [`MATERIAL_DIFFUSE`], [`MATERIAL_PRINCIPLED`], [`MATERIAL_DIELECTRIC`],
    /// [`MATERIAL_THIN_DIELECTRIC`], [`MATERIAL_ROUGH_DIELECTRIC`],
    /// [`MATERIAL_ROUGH_DIELECTRIC_BECKMANN`], [`MATERIAL_CONDUCTOR`],
    /// [`MATERIAL_CONDUCTOR_BECKMANN`], [`MATERIAL_PLASTIC`] or [`MATERIAL_PLASTIC_BECKMANN`];
    /// any other value behaves as diffuse.
    pub kind: u32,
    /// A dielectric's relative index of refraction: the far side's over wo's; a plastic's
    /// coating's, interior over exterior.
    pub ior: f32,
    /// A conductor's complex index of refraction, eta + i k, per channel.
    pub eta: [f32; 3],
    pub k: [f32; 3],
    /// A plastic's coating: the index of its transmittance table's first entry
    /// ([`PLASTIC_TABLE_SIZE`] entries, wherever the kernel keeps them), its internal
    /// diffuse reflectance, and its flags ([`crate::constants::COATING_NONLINEAR`],
    /// [`crate::constants::COATING_UNLAYERED`]).
    pub table: u32,
    pub internal: f32,
    pub coating: u32,
    /// A plastic's specular tint (Mitsuba's `specular_reflectance`), scaling its coating's
    /// reflection; unused by the other kinds.
    pub specular: [f32; 3],
    pub pad: u32,
}

/// Mirror of `ValueRef` (glsl/shared/scene.glsl): 16 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ValueRef {
    pub offset: i32,
    pub width: u32,
    pub height: u32,
    /// [`ValueRef::IN_THETA`], [`ValueRef::NEAREST`], the wrap modes in u (bits 2–3)
    /// and v (bits 4–5): 0 repeat, 1 clamp, 2 mirror, [`ValueRef::BUMP`] and
    /// [`ValueRef::UV1`].
    pub flags: u32,
}

impl ValueRef {
    /// The floats are elements of θ (`VALUE_IN_THETA`).
    pub const IN_THETA: u32 = 1;
    /// A texture looked up at its nearest texel (`VALUE_NEAREST`).
    pub const NEAREST: u32 = 2;
    /// A material's normal-map slot holds a bump map's heights (`VALUE_BUMP`).
    pub const BUMP: u32 = crate::constants::VALUE_BUMP;

    /// A texture looked up at a surface's second set of texture coordinates
    /// (`VALUE_UV1`).
    pub const UV1: u32 = 128;

    /// The sampler bits of the flags (filter, wrap modes and coordinate set).
    pub const SAMPLER: u32 = Self::NEAREST | 0b11_1100 | Self::UV1;
}

/// Mirror of `MaterialRecord`: 160 bytes (10 texels; `pad` is zero).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MaterialRecord {
    pub base_color: ValueRef,
    pub roughness: ValueRef,
    pub metallic: ValueRef,
    pub kind: u32,
    /// 1: the material reflects nothing from behind (its triangles' clockwise side).
    pub one_sided: u32,
    /// The alpha test's threshold (with `alpha`); negative for a blend, whose threshold
    /// the kernels draw per ray.
    pub alpha_cutoff: f32,
    /// A dielectric's or a plastic's index of refraction, interior over exterior; 0 for
    /// other kinds.
    pub ior: f32,
    /// The normal map's tangent-space normals (3 floats per texel, decoded and scaled);
    /// width 0: no normal map.
    pub normal_map: ValueRef,
    /// The alpha test's value (1 float per texel); unused (zero) where the material has
    /// none: the BVH's triangle records say which materials do.
    pub alpha: ValueRef,
    /// A dielectric's interior absorption coefficient per unit length; zero otherwise.
    pub absorption: [f32; 3],
    /// A plastic's internal diffuse reflectance; zero otherwise.
    pub internal: f32,
    /// A conductor's complex index of refraction, eta + i k; zero otherwise.
    pub eta: [f32; 3],
    /// A plastic's transmittance table: the index of its first entry in the material
    /// data (which follow θ); zero otherwise.
    pub table: u32,
    pub k: [f32; 3],
    /// A plastic's coating flags (`Material::coating`); zero otherwise.
    pub coating: u32,
    /// A plastic's specular tint (`Material::specular`); zero otherwise.
    pub specular: [f32; 3],
    pub pad: u32,
}

/// Mirror of `TriShading`: 128 bytes (8 texels; `pad` is zero).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TriShading {
    pub ng: [f32; 3],
    pub material: u32,
    pub emitter_pdf: f32,
    /// [`TriShading::TWO_SIDED`] and [`TriShading::EMITTING_MESH`].
    pub emitter_flags: u32,
    /// Its material's `one_sided`.
    pub one_sided: u32,
    pub mesh: u32,
    /// Its mesh's emission.
    pub emission: ValueRef,
    pub n0: [f32; 3],
    pub n1: [f32; 3],
    pub n2: [f32; 3],
    pub uv0: [f32; 2],
    pub uv1: [f32; 2],
    pub uv2: [f32; 2],
    /// 0, or 1 + the material whose alpha test the triangle's points must pass (as its
    /// BVH record's, [`crate::bvh::BvhTriangle::alpha_material`]).
    pub alpha_material: u32,
    /// Normal-mapped materials only: the unit dp/du of the texture coordinates and the
    /// bitangent's handedness (+1: dp/dv along cross(ng, tangent), -1: against it).
    /// Bump-mapped ones: the world-space gradients of u and v on the triangle, in the
    /// orthonormal basis (t, b) the kernels build from `ng` (`shading_frame`, mirrored by
    /// `render::tangent_frame`): (∇u·t, ∇u·b, ∇v·t, ∇v·b). Zero elsewhere.
    pub tangent: [f32; 4],
}

impl TriShading {
    /// `emitter_flags` bit 0: an emitter that shines from both sides (else from its front
    /// only).
    pub const TWO_SIDED: u32 = crate::constants::EMITTER_TWO_SIDED;
    /// `emitter_flags` bit 1: its mesh emits, or its emission is optimised (whatever
    /// `emitter_pdf` says): a camera ray passes through it where emitters are hidden.
    pub const EMITTING_MESH: u32 = crate::constants::EMITTER_MESH;
}

/// Mirror of `TriUv1`: 32 bytes (2 texels; `pad` is zero). A triangle's second set of
/// texture coordinates (glTF's `TEXCOORD_1`) at its vertices.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TriUv1 {
    pub uv0: [f32; 2],
    pub uv1: [f32; 2],
    pub uv2: [f32; 2],
    pub pad: [u32; 2],
}

/// Mirror of `EmitterTri`: 80 bytes (5 texels).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct EmitterTri {
    pub p0: [f32; 3],
    pub e1: [f32; 3],
    pub e2: [f32; 3],
    pub ng: [f32; 3],
    pub prim: u32,
    pub cdf: f32,
    pub pdf: f32,
    pub two_sided: u32,
    pub emission: ValueRef,
}

/// Mirror of `LightRecord`: 80 bytes (5 texels).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct LightRecord {
    pub position: [f32; 3],
    pub kind: u32,
    pub direction: [f32; 3],
    pub falloff: u32,
    pub color: ValueRef,
    pub intensity: ValueRef,
    pub cos_inner: f32,
    pub cos_outer: f32,
    pub inner: f32,
    pub outer: f32,
}

/// Mirror of `MediumRecord`: 112 bytes (7 texels); `max_steps` 0 where the scene has no
/// medium. The `boundary_texels` of its closed mesh follow it in the medium's buffer (a
/// texel of its BVH's node and triangle counts, the nodes, the triangles), then a majorant grid of `majorant_cells` (x | y << 10 |
/// z << 20; 0 for none), one texel per cell (the majorant in its first word), x fastest.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MediumRecord {
    pub box_min: [f32; 3],
    pub step: f32,
    pub box_max: [f32; 3],
    pub scale: f32,
    pub density: ValueRef,
    pub emission: ValueRef,
    pub density_depth: u32,
    pub emission_depth: u32,
    pub max_steps: u32,
    pub albedo_depth: u32,
    pub albedo: ValueRef,
    pub g: f32,
    /// A scattering medium's majorant extinction where it has no majorant grid (0 for one
    /// that does not scatter).
    pub majorant: f32,
    pub majorant_cells: u32,
    /// The texels of the closed mesh that bounds the medium in its box (0: none): a
    /// texel of counts, the BVH's nodes and its triangles.
    pub boundary_texels: u32,
}

/// Mirror of `SensorRecord`: 80 bytes (`pad` is zero; `ortho_half_height` 0 but for an
/// orthographic camera, `lens_radius` 0 but for a thin lens).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct SensorRecord {
    pub origin: [f32; 3],
    pub right: [f32; 3],
    pub up: [f32; 3],
    pub forward: [f32; 3],
    pub tan_half_fov_y: f32,
    pub aspect: f32,
    pub ortho_half_height: f32,
    pub lens_radius: f32,
    pub focus_distance: f32,
    pub pad: [u32; 3],
}

/// Mirror of `Globals`: 32 bytes (`pad` is zero).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Globals {
    pub environment: ValueRef,
    pub environment_scale: f32,
    /// Probability that next-event estimation samples the environment map rather than an
    /// emissive triangle; 0: the environment is not light-sampled.
    pub environment_sample_prob: f32,
    /// Delta lights in the `Lights` buffer.
    pub num_lights: u32,
    /// 0: a box pixel filter; else 1 + the offset in the material data of the filter's
    /// sampling table ([`crate::render::filter`]).
    pub filter_table: u32,
}

/// The records kernels read from uniform texel buffers, with their sizes: each a whole
/// number of 16-byte texels, checked at compile time below and against the GLSL structs
/// by tests/suite/render.rs.
pub const TEXEL_RECORDS: [(&str, usize); 8] = [
    ("MaterialRecord", std::mem::size_of::<MaterialRecord>()),
    ("TriShading", std::mem::size_of::<TriShading>()),
    ("TriUv1", std::mem::size_of::<TriUv1>()),
    ("EmitterTri", std::mem::size_of::<EmitterTri>()),
    ("SensorRecord", std::mem::size_of::<SensorRecord>()),
    ("LightRecord", std::mem::size_of::<LightRecord>()),
    ("MediumRecord", std::mem::size_of::<MediumRecord>()),
    ("Globals", std::mem::size_of::<Globals>()),
];
const _: () = {
    let mut i = 0;
    while i < TEXEL_RECORDS.len() {
        assert!(TEXEL_RECORDS[i].1.is_multiple_of(16), "a texel-buffer record is not a whole number of texels");
        i += 1;
    }
};

/// Mirror of `Ssq` (glsl/shared/optim.glsl): 8 bytes, a sum of squares as scale·√sum.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Ssq {
    pub scale: f32,
    pub sum: f32,
}

/// Mirror of `DiagRecord` (glsl/shared/optim.glsl): 88 bytes, one parameter group's
/// optimiser diagnostics as the GPU reduces them; [`crate::optim::reference::DiagRecord`]
/// is the same record in the CPU reference.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct DiagRecord {
    pub count: f32,
    pub n_eff_sum: f32,
    pub n_eff_min: f32,
    pub n_eff_max: f32,
    pub clipped: f32,
    pub newton: f32,
    pub f: Ssq,
    pub df: Ssq,
    pub sd_d: Ssq,
    pub step: Ssq,
    pub mean: Ssq,
    pub sd: Ssq,
    pub sd_f: Ssq,
    pub curv: Ssq,
}
