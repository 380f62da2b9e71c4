// Reads from uniform texel buffers of 16-byte texels viewed R32G32B32A32_UINT
// (usamplerBuffer): floats are read by their bits, so no value is converted or flushed.
// Pure functions of the buffer they are given; no bindings (see lib/scene_access.glsl for
// why the kernels read scene data this way).
#ifndef TEXELS_GLSL
#define TEXELS_GLSL

// Float i of a texel buffer read as an array of floats.
float texel_float(usamplerBuffer b, int i) { return uintBitsToFloat(texelFetch(b, i >> 2)[i & 3]); }

// Floats i, i + 1 and i + 2 of a texel buffer read as an array of floats, in two fetches
// instead of three: the texels of the first and of the last float (the same texel when
// all three lie in it; both exist whenever float i + 2 does). A SIMD build evaluates both
// sides of each select, so the component indices are clamped to stay inside the texel.
vec3 texel_vec3_at(usamplerBuffer b, int i) {
    uvec4 t0 = texelFetch(b, i >> 2);
    uvec4 t1 = texelFetch(b, (i + 2) >> 2);
    int k = i & 3;
    return uintBitsToFloat(uvec3(t0[k], k < 3 ? t0[min(k + 1, 3)] : t1.x, k < 2 ? t0[min(k + 2, 3)] : t1[max(k - 2, 0)]));
}

// Words 0-11 of the record that starts at texel `base` (three texels): words 0-2, 3-5 and
// 6-8 as three vec3 of floats, words 9-11 as they are. Triangles (a vertex and two edges),
// emitters, shading records (three normals) and sensors (three frame vectors) begin so.
void texel_vec3x3(usamplerBuffer b, int base, out vec3 w0, out vec3 w3, out vec3 w6, out uvec3 w9) {
    uvec4 t0 = texelFetch(b, base);
    uvec4 t1 = texelFetch(b, base + 1);
    uvec4 t2 = texelFetch(b, base + 2);
    w0 = uintBitsToFloat(t0.xyz);
    w3 = uintBitsToFloat(uvec3(t0.w, t1.xy));
    w6 = uintBitsToFloat(uvec3(t1.zw, t2.x));
    w9 = t2.yzw;
}
#endif
