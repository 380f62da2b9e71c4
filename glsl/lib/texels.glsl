// Reads from texel buffers of 16-byte texels viewed R32G32B32A32_UINT: floats are read by
// their bits, so no value is converted or flushed. Buffers are declared with TEXEL_BUFFER
// and read with texel_load; the helpers below are pure functions of the texels they read
// (see lib/scene_access.glsl for why the kernels read scene data this way).
//
// By default a texel buffer is a read-only storage texel buffer (`readonly uimageBuffer`,
// rgba32ui) read by image loads; with TEXELS_SAMPLED (the variants trace_primal_sampled*,
// timed by `vkinverse bench`) it is a uniform texel buffer (`usamplerBuffer`) read by texel
// fetches. Both read the same bits. lavapipe compiles a texel fetch into a call to a routine
// of the sampler's, around which every live vector register is spilled and reloaded (the
// caller saves them all), and an image load inline (docs/lavapipe.md).
#ifndef TEXELS_GLSL
#define TEXELS_GLSL

#ifdef TEXELS_SAMPLED
#define TEXEL_BUFFER(s_, b_) layout(set = s_, binding = b_) uniform usamplerBuffer
#define texel_load(b, i) texelFetch(b, i)
#else
#define TEXEL_BUFFER(s_, b_) layout(set = s_, binding = b_, rgba32ui) uniform readonly uimageBuffer
#define texel_load(b, i) imageLoad(b, i)
#endif

// The helpers are macros over the buffer's name (an image can be passed to a function only
// with its format): each reads its texels with texel_load and hands them to a function.

// Float i of a texel buffer read as an array of floats.
#define texel_float(b, i) uintBitsToFloat(texel_load(b, (i) >> 2)[(i) & 3])

// Floats i, i + 1 and i + 2 of a texel buffer read as an array of floats, in two fetches
// instead of three: the texels of the first and of the last float (the same texel when
// all three lie in it; both exist whenever float i + 2 does).
#define texel_vec3_at(b, i) texel_vec3_pick(texel_load(b, (i) >> 2), texel_load(b, ((i) + 2) >> 2), (i) & 3)

// The floats k, k + 1, k + 2 of the texels t0, t1 read as eight words. A SIMD build evaluates
// both sides of each select, so the component indices are clamped to stay inside the texel.
vec3 texel_vec3_pick(uvec4 t0, uvec4 t1, int k) {
    return uintBitsToFloat(uvec3(t0[k], k < 3 ? t0[min(k + 1, 3)] : t1.x, k < 2 ? t0[min(k + 2, 3)] : t1[max(k - 2, 0)]));
}

// Words 0-11 of the record that starts at texel `base` (three texels): words 0-2, 3-5 and
// 6-8 as three vec3 of floats, words 9-11 as they are. Triangles (a vertex and two edges),
// emitters, shading records (three normals) and sensors (three frame vectors) begin so.
#define texel_vec3x3(b, base, w0, w3, w6, w9) \
    texel_vec3x3_of(texel_load(b, base), texel_load(b, (base) + 1), texel_load(b, (base) + 2), w0, w3, w6, w9)

void texel_vec3x3_of(uvec4 t0, uvec4 t1, uvec4 t2, out vec3 w0, out vec3 w3, out vec3 w6, out uvec3 w9) {
    w0 = uintBitsToFloat(t0.xyz);
    w3 = uintBitsToFloat(uvec3(t0.w, t1.xy));
    w6 = uintBitsToFloat(uvec3(t1.zw, t2.x));
    w9 = t2.yzw;
}
#endif
