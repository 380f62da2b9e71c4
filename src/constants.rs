//! Constants shared by the host and the kernels, defined here only: build.rs reads this
//! file and writes each constant into the kernels' header `vkinverse_constants.glsl` as a
//! GLSL `const uint`, so the two sides cannot disagree. Every item is a line
//! `pub const NAME: u32 = VALUE;` (build.rs refuses anything else).

/// `Material::kind` of a Lambertian material: f = base_color / π.
pub const MATERIAL_DIFFUSE: u32 = 0;
/// `Material::kind` of the glTF 2.0 metallic-roughness model (Lambert diffuse + GGX/Smith
/// specular).
pub const MATERIAL_PRINCIPLED: u32 = 1;
/// A smooth dielectric (glass): an ideal specular interface that reflects with the
/// Fresnel reflectance and refracts the rest (Mitsuba 3's `dielectric`).
pub const MATERIAL_DIELECTRIC: u32 = 2;
/// A thin dielectric (a pane, a soap film): the same interface on both sides of a sheet of
/// no thickness, which reflects with the sheet's Fresnel reflectance (its internal
/// reflections summed) and lets the rest through unbent (Mitsuba 3's `thindielectric`).
pub const MATERIAL_THIN_DIELECTRIC: u32 = 3;
/// A rough dielectric (frosted glass): the smooth dielectric's interface on GGX
/// microfacets, which reflect and refract into lobes that light samples can reach (Mitsuba
/// 3's `roughdielectric` with the GGX distribution).
pub const MATERIAL_ROUGH_DIELECTRIC: u32 = 4;
/// The rough dielectric with Beckmann's distribution of microfacets (Mitsuba 3's default
/// for `roughdielectric`).
pub const MATERIAL_ROUGH_DIELECTRIC_BECKMANN: u32 = 5;
/// A conductor (a metal): a complex index of refraction's Fresnel reflectance on GGX
/// microfacets, tinted by the base colour (Mitsuba 3's `roughconductor` with the GGX
/// distribution).
pub const MATERIAL_CONDUCTOR: u32 = 6;
/// The conductor with Beckmann's distribution of microfacets (Mitsuba 3's default for
/// `roughconductor`).
pub const MATERIAL_CONDUCTOR_BECKMANN: u32 = 7;
/// A plastic: a diffuse base under a dielectric coating on GGX microfacets, which
/// reflects glossily and passes the rest to the base and back (Mitsuba 3's `roughplastic`
/// with the GGX distribution).
pub const MATERIAL_PLASTIC: u32 = 8;
/// The plastic with Beckmann's distribution of microfacets (Mitsuba 3's default for
/// `roughplastic`).
pub const MATERIAL_PLASTIC_BECKMANN: u32 = 9;
/// Entries of a plastic's coating transmittance table, at cos θ = i / (size − 1)
/// (Mitsuba 3's resolution for `roughplastic`).
pub const PLASTIC_TABLE_SIZE: u32 = 64;
/// A plastic's `coating` flag: the base's reflectance also scales the light the coating
/// reflects back into it (Mitsuba 3's `nonlinear`).
pub const COATING_NONLINEAR: u32 = 1;
/// A plastic's `coating` flag: the base is seen through two smooth refractions and
/// nothing more (Mitsuba 3's `pplastic` without polarisation): its table is 1 − F, with no
/// 1/η² and no internal reflections.
pub const COATING_UNLAYERED: u32 = 2;

/// `LightRecord::kind` (glsl/shared/scene.glsl) of a point light.
pub const LIGHT_POINT: u32 = 0;
/// A spot light.
pub const LIGHT_SPOT: u32 = 1;
/// A directional light.
pub const LIGHT_DIRECTIONAL: u32 = 2;
/// `LightRecord::falloff` of glTF's spot falloff: the square of a linear ramp in cos θ.
pub const FALLOFF_SMOOTH: u32 = 0;
/// Mitsuba's spot falloff: linear in θ.
pub const FALLOFF_LINEAR: u32 = 1;

/// Parameters whose gradients the adjoint kernels sum per thread in registers before the
/// atomics (glsl/lib/scene_access.glsl); a larger θ takes the direct atomics.
pub const LOCAL_GRADS_CAPACITY: u32 = 32;

/// Up to this many parameters, the adjoint kernels add each gradient contribution to all of
/// the per-thread sums in an unrolled loop (the `LOCAL_GRADS_UNROLLED` specialization
/// constant) rather than indexing them per lane; measured on lavapipe (experiments/lavapipe-speed.md).
pub const LOCAL_GRADS_UNROLL_MAX: u32 = 16;

/// Path vertices whose ray casts the adjoint kernels cache between a path's two replays
/// (glsl/lib/integrator.glsl); with `max_depth` at most this, every cast is cached and the
/// `CACHE_ALL` specialization constant lets the compiler drop the second traversal.
pub const CACHED_BOUNCES: u32 = 8;

/// The `LOSS` specialization constant of glsl/loss.comp: mean squared difference.
pub const LOSS_L2: u32 = 0;
/// Mean absolute difference.
pub const LOSS_L1: u32 = 1;
/// Squared difference over (target² + 0.01).
pub const LOSS_RELATIVE_L2: u32 = 2;

/// `StepRule::code` (src/optim/mod.rs) of the meta-estimator's step rules, as the fused pass
/// (glsl/lib/optim.glsl) numbers them: the seed's −lr·⟨F⟩_M/√V_M.
pub const STEP_SNR: u32 = 0;
/// Newton's step on the secant curvature of the finite-difference samples where the
/// estimate is significant, else the Wiener step scaled down.
pub const STEP_NEWTON: u32 = 1;

/// vec4s (four consecutive parameters each, from a multiple of 4 in θ) each invocation of
/// the fused optimiser passes (`optim_adam`, `optim_meta`) steps: one diagnostics record,
/// and one share of the workgroup's reduction, per 4 × this many parameters.
pub const OPTIM_CHUNKS: u32 = 16;

/// `Decay::code` (src/optim/schedule.rs) of the learning-rate schedules: constant.
pub const SCHEDULE_CONSTANT: u32 = 0;
/// Cosine decay to a floor.
pub const SCHEDULE_COSINE: u32 = 1;
/// Step decay.
pub const SCHEDULE_STEP: u32 = 2;

/// Segments of a pixel filter's sampling table (src/render/filter.rs): its weight and
/// cumulative mass at this many + 1 offsets.
pub const FILTER_TABLE_SIZE: u32 = 256;

/// `TriShading::emitter_flags` bit: an emitter that shines from both sides (else from its
/// front only).
pub const EMITTER_TWO_SIDED: u32 = 1;
/// `TriShading::emitter_flags` bit: its mesh emits, or its emission is optimised (whatever
/// `emitter_pdf` says): a camera ray passes through it where emitters are hidden.
pub const EMITTER_MESH: u32 = 2;
/// `TriShading::emitter_flags` from this bit up: 1 + the index of the sphere emitter whose
/// mesh the triangle belongs to (`EmitterSphere`, src/render/features/emitters.rs), 0 for
/// none. Light samples from outside that sphere pick a direction in its cone.
pub const EMITTER_SPHERE_SHIFT: u32 = 8;

/// `ValueRef::flags` bit of a material's normal-map slot: it holds a bump map's heights
/// (one float per texel), its triangles' `tangent` the world-space gradients of u and v.
pub const VALUE_BUMP: u32 = 64;
