// Scene buffers (bindings 20-28) and the parameter buffers (30-32), with the lookups that
// read a material or emission value from a constant, a texture, or the parameters being
// optimised, and (ADJOINT) scatter gradients back through the same lookup.
//
// What is read per ray or path vertex comes from texel buffers of 16-byte texels
// (lib/texels.glsl: read-only storage texel buffers viewed R32G32B32A32_UINT; floats are
// read by their bits, so no value is converted or flushed): records (shared/scene.glsl, a
// whole number of texels each) through the accessors below, float arrays through
// texel_float. A texel load is a vector gather on lavapipe, where a storage-buffer load is a
// loop over the SIMD lanes with a bounds check per lane, and it reads through the texture
// path on GPUs. The host binds every buffer by the names below (src/render/mod.rs sizes them
// in whole texels).
#ifndef SCENE_ACCESS_GLSL
#define SCENE_ACCESS_GLSL
#include "shared/scene.glsl"
#include "shared/material.glsl"
#include "lib/texels.glsl"
#include "lib/rng.glsl"

TEXEL_BUFFER(0, 20) Materials;
TEXEL_BUFFER(0, 21) Shading;
// The triangles' second sets of texture coordinates (TriUv1; one texel where no mesh has one).
TEXEL_BUFFER(0, 22) ShadingUv1;
TEXEL_BUFFER(0, 23) Emitters;
TEXEL_BUFFER(0, 24) Sensors;
TEXEL_BUFFER(0, 25) SceneGlobals;
// The environment map's sampling distribution (src/render/envmap.rs): row cdf (H), per-row
// column cdfs (H × W), cell densities in solid angle (H × W); W × H = the map's size.
TEXEL_BUFFER(0, 27) EnvDistribution;
// Delta lights: scene_globals().num_lights LightRecords.
TEXEL_BUFFER(0, 28) Lights;
// θ, then from element CONST_BASE on the material data: every constant value (colours,
// roughness, textures, emission, lights, the environment). One buffer for both, so that a
// value read, which runs both sides of its branch on lavapipe, fetches from one buffer
// only (src/render/mod.rs builds it; the optimisers move only θ's elements).
TEXEL_BUFFER(0, 30) Theta;

// Parameter states a kernel evaluates along each path: 1, or 2 for the fused finite
// difference (state 0 = θ_i, which samples the path; state 1 = θ_{i-1}).
#ifdef FD
#define NSTATES 2
TEXEL_BUFFER(0, 32) ThetaPrev;
#else
#define NSTATES 1
#endif

// ---------------------------------------------------------------------------------------
// Texel-buffer reads
// ---------------------------------------------------------------------------------------

ValueRef value_ref(uvec4 t) { return ValueRef(int(t.x), t.y, t.z, t.w); }

// Material `id` (10 texels: three ValueRefs, kind, one_sided, alpha_cutoff and ior, the
// normal map's and the alpha's ValueRefs, absorption, eta, k, specular).
MaterialRecord material_record(uint id) {
    int b = int(id) * 10;
    MaterialRecord r;
    r.base_color = value_ref(texel_load(Materials, b));
    r.roughness = value_ref(texel_load(Materials, b + 1));
    r.metallic = value_ref(texel_load(Materials, b + 2));
    uvec4 t3 = texel_load(Materials, b + 3);
    r.kind = t3.x;
    r.one_sided = t3.y;
    r.alpha_cutoff = uintBitsToFloat(t3.z);
    r.ior = uintBitsToFloat(t3.w);
    r.normal_map = value_ref(texel_load(Materials, b + 4));
    r.alpha = value_ref(texel_load(Materials, b + 5));
    uvec4 t6 = texel_load(Materials, b + 6);
    r.absorption = uintBitsToFloat(t6.xyz);
    r.internal = uintBitsToFloat(t6.w);
    uvec4 t7 = texel_load(Materials, b + 7);
    r.eta = uintBitsToFloat(t7.xyz);
    r.table = t7.w;
    uvec4 t8 = texel_load(Materials, b + 8);
    r.k = uintBitsToFloat(t8.xyz);
    r.coating = t8.w;
    r.specular = uintBitsToFloat(texel_load(Materials, b + 9).xyz);
    r.pad = 0u;
    return r;
}

// Shading data of triangle `prim` (8 texels; words in TriShading's scalar layout: ng 0-2,
// material 3, emitter_pdf 4, emitter_flags 5, one_sided 6, mesh 7, emission 8-11, n0 12-14,
// n1 15-17, n2 18-20, uv0 21-22, uv1 23-24, uv2 25-26, alpha_material 27, tangent 28-31). Fetches of fields a
// caller does not use are dead code: a scene without vertex normals, textures and normal
// maps reads texels 0-2.
TriShading tri_shading(uint prim) {
    int b = int(prim) * 8;
    TriShading s;
    uvec4 t0 = texel_load(Shading, b);
    uvec4 t1 = texel_load(Shading, b + 1);
    s.ng = uintBitsToFloat(t0.xyz);
    s.material = t0.w;
    s.emitter_pdf = uintBitsToFloat(t1.x);
    s.emitter_flags = t1.y;
    s.one_sided = t1.z;
    s.mesh = t1.w;
    s.emission = value_ref(texel_load(Shading, b + 2));
    uvec3 n2z_uv0_uv1x;
    texel_vec3x3(Shading, b + 3, s.n0, s.n1, s.n2, n2z_uv0_uv1x);
    uvec4 t6 = texel_load(Shading, b + 6);
    s.uv0 = uintBitsToFloat(n2z_uv0_uv1x.xy);
    s.uv1 = uintBitsToFloat(uvec2(n2z_uv0_uv1x.z, t6.x));
    s.uv2 = uintBitsToFloat(t6.yz);
    s.alpha_material = t6.w;
    s.tangent = uintBitsToFloat(texel_load(Shading, b + 7));
    return s;
}

// The emitter flags of triangle `prim` (TriShading.emitter_flags): one word of its
// shading record.
uint tri_emitter_flags(uint prim) {
    return texel_load(Shading, int(prim) * 8 + 1).y;
}

// Where a surface point reads its textures: its first set of texture coordinates, and
// the triangle and barycentrics (the weights of vertices 1 and 2) that give its second set
// where a texture asks for it (VALUE_UV1, uv_of).
struct SurfaceUv {
    vec2 uv;
    vec2 bary;
    uint prim;
};

// The texture coordinates of triangle `prim` at barycentrics b: texels 5-6 of its shading
// record alone.
SurfaceUv triangle_uv(uint prim, vec2 b) {
    int base = int(prim) * 8;
    uvec4 t5 = texel_load(Shading, base + 5);
    uvec4 t6 = texel_load(Shading, base + 6);
    vec2 uv0 = uintBitsToFloat(t5.yz);
    vec2 uv1 = uintBitsToFloat(uvec2(t5.w, t6.x));
    vec2 uv2 = uintBitsToFloat(t6.yz);
    return SurfaceUv(uv0 + b.x * (uv1 - uv0) + b.y * (uv2 - uv0), b, prim);
}

// Emissive triangle `i` (5 texels: p0 0-2, e1 3-5, e2 6-8, ng 9-11, prim 12, cdf 13,
// pdf 14, two_sided 15, emission 16-19).
EmitterTri emitter_tri(uint i) {
    EmitterTri e;
    uvec3 ng;
    int b = int(i) * 5;
    texel_vec3x3(Emitters, b, e.p0, e.e1, e.e2, ng);
    e.ng = uintBitsToFloat(ng);
    uvec4 t3 = texel_load(Emitters, b + 3);
    e.prim = t3.x;
    e.cdf = uintBitsToFloat(t3.y);
    e.pdf = uintBitsToFloat(t3.z);
    e.two_sided = t3.w;
    e.emission = value_ref(texel_load(Emitters, b + 4));
    return e;
}

// Sensor `i` (5 texels: origin 0-2, right 3-5, up 6-8, forward 9-11, tan_half_fov_y 12,
// aspect 13, ortho_half_height 14, lens_radius 15, focus_distance 16).
SensorRecord sensor_record(uint i) {
    int b = int(i) * 5;
    SensorRecord s;
    uvec3 forward;
    texel_vec3x3(Sensors, b, s.origin, s.right, s.up, forward);
    s.forward = uintBitsToFloat(forward);
    uvec4 t3 = texel_load(Sensors, b + 3);
    s.tan_half_fov_y = uintBitsToFloat(t3.x);
    s.aspect = uintBitsToFloat(t3.y);
    s.ortho_half_height = uintBitsToFloat(t3.z);
    s.lens_radius = uintBitsToFloat(t3.w);
    uvec4 t4 = texel_load(Sensors, b + 4);
    s.focus_distance = uintBitsToFloat(t4.x);
    s.pad1 = 0u;
    s.pad2 = 0u;
    s.pad3 = 0u;
    return s;
}

// The scene-wide values (2 texels: environment 0-3, environment_scale 4,
// environment_sample_prob 5, num_lights 6).
Globals scene_globals() {
    uvec4 t0 = texel_load(SceneGlobals, 0);
    uvec4 t1 = texel_load(SceneGlobals, 1);
    return Globals(value_ref(t0), uintBitsToFloat(t1.x), uintBitsToFloat(t1.y), t1.z, t1.w);
}

// Delta light `i` (5 texels: position 0-2, kind 3, direction 4-6, falloff 7, color 8-11,
// intensity 12-15, cos_inner 16, cos_outer 17, inner 18, outer 19).
LightRecord light_record(uint i) {
    int b = int(i) * 5;
    uvec4 t0 = texel_load(Lights, b);
    uvec4 t1 = texel_load(Lights, b + 1);
    uvec4 t4 = texel_load(Lights, b + 4);
    LightRecord l;
    l.position = uintBitsToFloat(t0.xyz);
    l.kind = t0.w;
    l.direction = uintBitsToFloat(t1.xyz);
    l.falloff = t1.w;
    l.color = value_ref(texel_load(Lights, b + 2));
    l.intensity = value_ref(texel_load(Lights, b + 3));
    l.cos_inner = uintBitsToFloat(t4.x);
    l.cos_outer = uintBitsToFloat(t4.y);
    l.inner = uintBitsToFloat(t4.z);
    l.outer = uintBitsToFloat(t4.w);
    return l;
}

// The cdf of emissive triangle `i` alone (its fourth texel), for the binary search.
float emitter_cdf(uint i) { return uintBitsToFloat(texel_load(Emitters, int(i) * 5 + 3).y); }
#ifdef ADJOINT
#extension GL_EXT_shader_atomic_float : require
layout(set = 0, binding = 31, scalar) buffer Grad { float grad[]; };
// SPLIT: the contributions of half of the pixels are also summed into grad_half, so that
// the optimiser can estimate the gradient's variance from two independent halves
// (the centred variance estimate, src/optim/mod.rs). The kernel sets grad_in_half per pixel.
// With direct atomics the host binds a buffer of two interleaved sums per element here
// instead (grad_add).
layout(set = 0, binding = 33, scalar) buffer GradHalf { float grad_half[]; };
layout(constant_id = 7) const bool SPLIT = false;
bool grad_in_half = false;
#endif

// Scene features, set per scene by the host (GpuScene::spec) so that the compiler drops the
// code of what the scene does not have: no textured value (every lookup reads one texel,
// no bilinear footprint), no principled material (fetch_material reports the diffuse
// kind, and the principled model's sampling, evaluation and derivatives fold away) and no
// vertex normals. The defaults keep everything, for kernels built without them. This
// matters most on CPU drivers: lavapipe runs the body of every branch whose condition is
// not a constant, masked, even when no lane of the SIMD batch takes it (docs/lavapipe.md).
layout(constant_id = 8) const bool HAS_TEXTURES = true;
layout(constant_id = 9) const bool HAS_PRINCIPLED = true;
// Whether any triangle has vertex normals: without them the shading normal is the geometric
// one, and the normals' two texels of each shading record are not read.
layout(constant_id = 13) const bool HAS_NORMALS = true;
// Whether any material has a normal map: without one the interpolated normal is the
// shading normal, and neither the maps nor the tangents are read.
layout(constant_id = 16) const bool HAS_NORMAL_MAPS = true;
// Whether any texture is looked up at a second set of texture coordinates (VALUE_UV1):
// without one, binding ShadingUv1 is not read.
layout(constant_id = 26) const bool HAS_UV1 = true;
// Whether any mesh's emission is a texture: without one, a light sample's emission is read
// without its texture coordinates (which cost two texel fetches of its shading record).
layout(constant_id = 17) const bool HAS_EMISSION_TEXTURES = true;
// Whether any triangle's material has an alpha test (alpha_cut): without one, traversal
// tests no candidate hit's alpha and a light sample none either.
layout(constant_id = 18) const bool HAS_ALPHA_MASKS = true;
// Whether any material is a dielectric: without one the integrator's specular branch (no
// light sample, a refracted or mirrored continuation) is compiled out.
layout(constant_id = 19) const bool HAS_DIELECTRICS = true;
// Whether any material is a rough dielectric: without one the BSDF functions' rough glass
// (lib/bsdf.glsl, BSDF_ROUGH_DIELECTRICS) and the integrator's light samples and
// continuations through a surface are compiled out.
layout(constant_id = 20) const bool HAS_ROUGH_DIELECTRICS = true;
// Whether any material is a conductor: without one the BSDF functions' conductor
// (lib/bsdf.glsl, BSDF_CONDUCTORS) is compiled out and no material reads its complex index.
layout(constant_id = 21) const bool HAS_CONDUCTORS = true;
// Whether any material is a plastic: without one the BSDF functions' plastic
// (lib/bsdf.glsl, BSDF_PLASTICS) is compiled out and no material reads its coating.
layout(constant_id = 22) const bool HAS_PLASTICS = true;
// Where the material data start in Theta: θ's length padded to whole texels.
layout(constant_id = 14) const uint CONST_BASE = 0u;

// Reads element i of a value's data with `read` (texel_float or texel_vec3_at): a
// constant's from the material data at the end of Theta, an optimised value's from θ, or in
// parameter state 1 of the finite-difference kernels from θ of the previous iteration.
#define VALUE_INDEX(r, i) (((r).flags & VALUE_IN_THETA) == 0u ? int(CONST_BASE) + (i) : (i))
#ifdef FD
#define VALUE_READ(read, r, i, state) \
    ((state) == 1 && ((r).flags & VALUE_IN_THETA) != 0u ? read(ThetaPrev, i) : read(Theta, VALUE_INDEX(r, i)))
#else
#define VALUE_READ(read, r, i, state) read(Theta, VALUE_INDEX(r, i))
#endif

// Element `index` of value r in parameter state `state`.
float value_at(ValueRef r, int index, int state) { return VALUE_READ(texel_float, r, r.offset + index, state); }

// Elements index .. index + 2 of value r in parameter state `state`: value_at of each, in
// two texel fetches per buffer instead of three.
vec3 value3_at(ValueRef r, int index, int state) { return VALUE_READ(texel_vec3_at, r, r.offset + index, state); }

// Texel coordinate i (integral) wrapped into [0, n) by mode: 0 repeat, 1 clamp to the edge
// texel, 2 mirrored repeat (as OpenGL's modes of those names).
float wrap_texel(float i, float n, uint mode) {
    if (mode == 1u) return clamp(i, 0.0, n - 1.0);
    float m = mode == 2u ? 2.0 * n : n;
    float k = i - m * floor(i / m);
    // (The clamp guards against rounding at coordinates beyond 2^24 texels.)
    return clamp(k < n ? k : m - 1.0 - k, 0.0, n - 1.0);
}

// Lookup footprint: four texel indices and their bilinear weights, or for a
// nearest-filtered texture the texel whose square holds uv with weight 1 in slot 0; texel
// coordinates beyond the image wrapped by the value's modes (flag bits 2-3 for u, 4-5 for
// v). A constant is one "texel" with weight 1 in slot 0.
void footprint(ValueRef r, vec2 uv, out ivec4 texel, out vec4 weight) {
    uint width = HAS_TEXTURES ? r.width : 0u;
    if (width == 0u) {
        texel = ivec4(0);
        weight = vec4(1.0, 0.0, 0.0, 0.0);
        return;
    }
    // uv (0,0) is the bottom-left of the image (OBJ convention); rows are stored top first.
    vec2 size = vec2(r.width, r.height);
    uint wu = (r.flags >> 2) & 3u, wv = (r.flags >> 4) & 3u;
    if ((r.flags & VALUE_NEAREST) != 0u) {
        vec2 f = floor(vec2(uv.x, 1.0 - uv.y) * size);
        ivec2 a = ivec2(wrap_texel(f.x, size.x, wu), wrap_texel(f.y, size.y, wv));
        texel = ivec4(a.y * int(r.width) + a.x, 0, 0, 0);
        weight = vec4(1.0, 0.0, 0.0, 0.0);
        return;
    }
    vec2 p = vec2(uv.x, 1.0 - uv.y) * size - 0.5;
    vec2 f = floor(p);
    vec2 t = p - f;
    ivec2 a = ivec2(wrap_texel(f.x, size.x, wu), wrap_texel(f.y, size.y, wv));
    ivec2 b = ivec2(wrap_texel(f.x + 1.0, size.x, wu), wrap_texel(f.y + 1.0, size.y, wv));
    int w = int(r.width);
    texel = ivec4(a.y * w + a.x, a.y * w + b.x, b.y * w + a.x, b.y * w + b.x);
    weight = vec4((1.0 - t.x) * (1.0 - t.y), t.x * (1.0 - t.y), (1.0 - t.x) * t.y, t.x * t.y);
}

vec3 fetch3(ValueRef r, vec2 uv, int state) {
    ivec4 texel;
    vec4 w;
    footprint(r, uv, texel, w);
    vec3 v = vec3(0.0);
    for (int k = 0; k < 4; ++k) {
        if (w[k] == 0.0) continue;
        int base = texel[k] * 3;
        v += w[k] * value3_at(r, base, state);
    }
    return v;
}

float fetch1(ValueRef r, vec2 uv, int state) {
    ivec4 texel;
    vec4 w;
    footprint(r, uv, texel, w);
    float v = 0.0;
    for (int k = 0; k < 4; ++k) {
        if (w[k] != 0.0) v += w[k] * value_at(r, texel[k], state);
    }
    return v;
}

// The second-set record of triangle `prim` (2 texels: uv0 0-1, uv1 2-3, uv2 4-5).
TriUv1 tri_uv1(uint prim) {
    uvec4 t0 = texel_load(ShadingUv1, int(prim) * 2);
    uvec4 t1 = texel_load(ShadingUv1, int(prim) * 2 + 1);
    return TriUv1(uintBitsToFloat(t0.xy), uintBitsToFloat(t0.zw), uintBitsToFloat(t1.xy), t1.zw);
}

// The coordinates that value r reads at surface point s: the second set for a texture
// flagged VALUE_UV1 (two texel fetches of ShadingUv1), else the first.
vec2 uv_of(ValueRef r, SurfaceUv s) {
    if (HAS_UV1) {
        if ((r.flags & VALUE_UV1) != 0u) {
            TriUv1 t = tri_uv1(s.prim);
            return t.uv0 + s.bary.x * (t.uv1 - t.uv0) + s.bary.y * (t.uv2 - t.uv0);
        }
    }
    return s.uv;
}

// fetch3 and fetch1 at a surface point, each value at the set of coordinates it reads.
vec3 fetch3(ValueRef r, SurfaceUv s, int state) { return fetch3(r, uv_of(r, s), state); }
float fetch1(ValueRef r, SurfaceUv s, int state) { return fetch1(r, uv_of(r, s), state); }

// Whether the alpha test of material `alpha_material` - 1 (a triangle record's
// alpha_material; 0: no test) cuts the surface out at texture coordinates uv for the ray
// or sample `key` names: its alpha, looked up bilinearly, is below the material's cutoff,
// or for a blend (a negative cutoff) below a uniform number hashed from the key, so that
// the surface is there with probability alpha. The number is a function of the key alone
// (pcg4d of lib/rng.glsl): the replays of a path, which cast the same rays, make the same
// choices. The alpha is a material constant: every parameter state sees the same surface.
bool alpha_cut(uint alpha_material, SurfaceUv uv, uvec4 key) {
    // (Not `!HAS_ALPHA_MASKS || ...`: the reflection cannot fold the negation of a
    // specialisation constant.)
    if (HAS_ALPHA_MASKS && alpha_material != 0u) {
        MaterialRecord r = material_record(alpha_material - 1u);
        float cutoff = r.alpha_cutoff;
        if (cutoff < 0.0) cutoff = float(pcg4d(key).x >> 8u) * (1.0 / 16777216.0);
        return fetch1(r.alpha, uv, 0) < cutoff;
    }
    return false;
}

// The key of a ray's blend choices on triangle `prim` (alpha_cut): the ray's bits.
uvec4 alpha_ray_key(vec3 origin, vec3 dir, uint prim) {
    uvec3 o = floatBitsToUint(origin);
    uvec3 d = floatBitsToUint(dir);
    return uvec4(o.x ^ d.y, o.y ^ d.z, o.z ^ d.x, prim);
}

#ifdef ADJOINT
// Gradients of up to LOCAL_GRADS_CAPACITY parameters are summed per thread in registers and
// added to grad[] once per subgroup at the end (grad_flush), instead of one float atomic
// per path vertex. Besides contention, this is about precision: a float32 running sum
// over millions of tiny atomic additions of both signs drops every addend below half an
// ulp of the running total, which biased scalar gradients by tens of percent at a few
// hundred spp. LOCAL_GRADS is θ's length when it fits (set by the host), else 0: large θ
// (textures) has few contributions per element and keeps the direct atomics.
layout(constant_id = 5) const uint LOCAL_GRADS = 0;
// Set by the host when LOCAL_GRADS is at most LOCAL_GRADS_UNROLL_MAX: grad_add then adds to
// every one of the LOCAL_GRADS sums (v where the index matches, 0 elsewhere) in a loop that
// the compiler unrolls, so the arrays are indexed by constants and live in registers. With
// the per-lane index instead, lavapipe reads and writes the arrays lane by lane; that is
// cheaper only for many parameters (measured in docs/lavapipe.md).
layout(constant_id = 12) const bool LOCAL_GRADS_UNROLLED = false;
#include "vkinverse_constants.glsl"  // LOCAL_GRADS_CAPACITY
// A thread traces one pixel, whose half (grad_in_half) is fixed, so the half's sums are the
// thread's own sums where it is in the half and 0 elsewhere: no second array.
float local_grads[LOCAL_GRADS_CAPACITY];

// SPLIT with direct atomics (LOCAL_GRADS = 0): each contribution is one atomic addition
// into a buffer of the pass's own, bound as grad_half, that holds two sums per element,
// interleaved: [2k] from the pixels outside the half, [2k + 1] from those in it. One
// atomic with a per-lane address costs what the unsplit kernel's does, where an atomic
// into grad and a second, masked one into grad_half (or either of two, masked) cost a
// loop over the lanes each. The host afterwards adds both into grad and the second into
// the real grad_half (merge_half.comp).
void grad_init() {
    for (uint k = 0u; k < LOCAL_GRADS_CAPACITY; ++k) local_grads[k] = 0.0;
}

void grad_add(int index, float v) {
    if (LOCAL_GRADS_UNROLLED) {
        // Adding 0.0 leaves every other sum as it is: the same sums as below.
        for (uint k = 0u; k < LOCAL_GRADS_CAPACITY; ++k) {
            if (k >= LOCAL_GRADS) break;
            local_grads[k] += uint(index) == k ? v : 0.0;
        }
    } else if (LOCAL_GRADS != 0u) {
        local_grads[index] += v;
    } else if (SPLIT) {
        atomicAdd(grad_half[2 * index + (grad_in_half ? 1 : 0)], v);
    } else {
        atomicAdd(grad[index], v);
    }
}

// Adds the thread's sums into grad[] (and grad_half[]), one atomic per parameter and subgroup.
void grad_flush() {
    if (LOCAL_GRADS == 0u) return;
    for (uint k = 0u; k < LOCAL_GRADS_CAPACITY; ++k) {
        if (k >= LOCAL_GRADS) break;
        float total = subgroupAdd(local_grads[k]);
        if (subgroupElect() && total != 0.0) atomicAdd(grad[k], total);
        if (SPLIT) {
            float half_total = subgroupAdd(grad_in_half ? local_grads[k] : 0.0);
            if (subgroupElect() && half_total != 0.0) atomicAdd(grad_half[k], half_total);
        }
    }
}

// Adds g (the gradient of the loss with respect to the looked-up value) to the gradients
// of the parameters the lookup read, if they are being optimised.
void scatter3(ValueRef r, vec2 uv, vec3 g) {
    if ((r.flags & VALUE_IN_THETA) == 0u || all(equal(g, vec3(0.0)))) return;
    ivec4 texel;
    vec4 w;
    footprint(r, uv, texel, w);
    for (int k = 0; k < 4; ++k) {
        if (w[k] == 0.0) continue;
        int base = r.offset + texel[k] * 3;
        grad_add(base, w[k] * g.x);
        grad_add(base + 1, w[k] * g.y);
        grad_add(base + 2, w[k] * g.z);
    }
}

void scatter1(ValueRef r, vec2 uv, float g) {
    if ((r.flags & VALUE_IN_THETA) == 0u || g == 0.0) return;
    ivec4 texel;
    vec4 w;
    footprint(r, uv, texel, w);
    for (int k = 0; k < 4; ++k) {
        if (w[k] != 0.0) grad_add(r.offset + texel[k], w[k] * g);
    }
}

// scatter3 and scatter1 at a surface point (fetch3 and fetch1's coordinates).
void scatter3(ValueRef r, SurfaceUv s, vec3 g) { scatter3(r, uv_of(r, s), g); }
void scatter1(ValueRef r, SurfaceUv s, float g) { scatter1(r, uv_of(r, s), g); }
#endif

// The shading normal at a point of triangle `sh` with texture coordinates uv and
// interpolated (or geometric) unit normal n, perturbed by normal map `r` (the material's,
// not a bump map: perturbed_normal, lib/integrator.glsl), in the frame of the triangle's
// tangent made orthogonal to n (Gram-Schmidt), the bitangent cross(n, tangent) times the
// tangent's handedness, and n. n itself where the triangle has no tangent. The map is a
// material constant: every parameter state sees the same normal.
vec3 normal_mapped(TriShading sh, ValueRef r, vec3 n, SurfaceUv uv) {
    vec3 t = sh.tangent.xyz - n * dot(n, sh.tangent.xyz);
    if (sh.tangent.w != 0.0 && dot(t, t) > 1e-12) {
        t = normalize(t);
        vec3 m = fetch3(r, uv, 0);
        vec3 v = m.x * t + (m.y * sh.tangent.w) * cross(n, t) + m.z * n;
        if (dot(v, v) > 0.0) return normalize(v);
    }
    return n;
}

// The material at a surface point, in parameter state `state`.
Material fetch_material(uint id, SurfaceUv uv, int state) {
    MaterialRecord r = material_record(id);
    Material m;
    m.base_color = fetch3(r.base_color, uv, state);
    m.roughness = fetch1(r.roughness, uv, state);
    m.metallic = fetch1(r.metallic, uv, state);
    // Without principled materials every kind but glass and conductors reads as diffuse,
    // so that the principled model folds away (nested tests: the reflection cannot fold an
    // operation on specialisation constants).
    if (HAS_PRINCIPLED) {
        m.kind = r.kind;
    } else if (HAS_DIELECTRICS) {
        m.kind = material_is_glass(r.kind) || material_is_conductor(r.kind) || material_is_plastic(r.kind) ? r.kind : MATERIAL_DIFFUSE;
    } else if (HAS_CONDUCTORS) {
        m.kind = material_is_conductor(r.kind) || material_is_plastic(r.kind) ? r.kind : MATERIAL_DIFFUSE;
    } else if (HAS_PLASTICS) {
        m.kind = material_is_plastic(r.kind) ? r.kind : MATERIAL_DIFFUSE;
    } else {
        m.kind = MATERIAL_DIFFUSE;
    }
    m.ior = r.ior;
    if (HAS_CONDUCTORS) {
        m.eta = r.eta;
        m.k = r.k;
    } else {
        m.eta = vec3(0.0);
        m.k = vec3(0.0);
    }
    if (HAS_PLASTICS) {
        m.table = r.table;
        m.internal = r.internal;
        m.coating = r.coating;
        m.specular = r.specular;
    } else {
        m.table = 0u;
        m.internal = 0.0;
        m.coating = 0u;
        m.specular = vec3(0.0);
    }
    m.pad = 0u;
    return m;
}

// Lat-long coordinates of direction dir: u = azimuth around +y, v = polar angle from +y
// (top row = up).
vec2 environment_uv(vec3 dir) {
    float u = atan(dir.x, -dir.z) * (0.5 / 3.14159265358979) + 0.5;
    float v = 1.0 - acos(clamp(dir.y, -1.0, 1.0)) / 3.14159265358979;
    return vec2(u, v);
}

// Radiance emitted by the environment towards -dir, in parameter state `state`.
vec3 environment_radiance(vec3 dir, int state) {
    Globals g = scene_globals();
    return g.environment_scale * fetch3(g.environment, environment_uv(dir), state);
}

// Environment-map light sampling (src/render/envmap.rs describes the distribution). The
// map's texel cells are picked by a piecewise-constant distribution and a direction is
// uniform in solid angle inside its cell, so the density is constant per cell. Sampling
// is by cell while the radiance is the bilinear lookup; both stay consistent because
// the density is positive everywhere (the distribution's uniform share).

// Density in solid angle of sampling direction dir, given that the environment is sampled.
float environment_density(vec3 dir) {
    uint w = scene_globals().environment.width;
    uint h = scene_globals().environment.height;
    vec2 uv = environment_uv(dir);
    uint c = min(uint(max(uv.x, 0.0) * float(w)), w - 1u);
    uint r = min(uint(max(1.0 - uv.y, 0.0) * float(h)), h - 1u);
    return texel_float(EnvDistribution, int(h + h * w + r * w + c));
}

// Index of the first entry of the inclusive cdf EnvDistribution[base .. base + n) that exceeds x,
// and x rescaled to [0, 1] within that entry's interval.
uint environment_pick(uint base, uint n, float x, out float rescaled) {
    uint lo = 0u, hi = n - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (texel_float(EnvDistribution, int(base + mid)) > x) hi = mid; else lo = mid + 1u;
    }
    float c0 = lo == 0u ? 0.0 : texel_float(EnvDistribution, int(base + lo - 1u));
    rescaled = clamp((x - c0) / max(texel_float(EnvDistribution, int(base + lo)) - c0, 1e-30), 0.0, 1.0);
    return lo;
}

// A direction from two uniform numbers (each picks a row or column, then places the
// direction inside the cell) and its density in solid angle. Inside row r, cos θ is
// uniform between the row's bounds θ0 = πr/H and θ1 = π(r+1)/H; it is interpolated as
// 1 − cos θ = 2 sin²(θ/2) in the upper half and 1 + cos θ = 2 cos²(θ/2) in the lower, which
// keeps rows near the poles free of cancellation.
vec3 environment_sample(vec2 u, out float pdf) {
    const float PI = 3.14159265358979;
    uint w = scene_globals().environment.width;
    uint h = scene_globals().environment.height;
    float ur, uc;
    uint r = environment_pick(0u, h, u.x, ur);
    uint c = environment_pick(h + r * w, w, u.y, uc);
    float a0 = 0.5 * PI * float(r) / float(h);
    float a1 = 0.5 * PI * float(r + 1u) / float(h);
    float ct, st;
    if (2u * (r + 1u) <= h) {
        float s0 = sin(a0), s1 = sin(a1);
        float m = 2.0 * mix(s0 * s0, s1 * s1, ur);  // 1 − cos θ
        ct = 1.0 - m;
        st = sqrt(max(m * (2.0 - m), 0.0));
    } else if (2u * r >= h) {
        float k0 = cos(a0), k1 = cos(a1);
        float p = 2.0 * mix(k0 * k0, k1 * k1, ur);  // 1 + cos θ
        ct = p - 1.0;
        st = sqrt(max(p * (2.0 - p), 0.0));
    } else {
        ct = mix(cos(2.0 * a0), cos(2.0 * a1), ur);
        st = sqrt(max(1.0 - ct * ct, 0.0));
    }
    float phi = 2.0 * PI * ((float(c) + uc) / float(w) - 0.5);
    pdf = texel_float(EnvDistribution, int(h + h * w + r * w + c));
    return vec3(st * sin(phi), ct, -st * cos(phi));
}
#endif
