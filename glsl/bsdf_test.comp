// variant: bsdf_sample_test SAMPLE_ONLY
#version 460
// bsdf_test: runs the functions of glsl/lib/bsdf.glsl on a buffer of cases (material,
// normal, wo, wi, u) so that tests/bsdf.rs can compare them with the f64 mirror in
// src/bsdf.rs. Variant bsdf_sample_test draws `count` samples of one (material, n, wo)
// with per-thread random numbers, for the chi-square test of bsdf_sample.
layout(local_size_x = 64) in;
#include "lib/common.glsl"
#include "lib/bsdf.glsl"

#ifdef SAMPLE_ONLY
// wi of sample i, or (0, 0, 0) when bsdf_sample returned false.
layout(set = 0, binding = 0, scalar) writeonly buffer Samples { vec3 samples[]; };
layout(push_constant, scalar) uniform Push {
    Material material;
    vec3 n;
    vec3 wo;
    uint count;
    uint seed;
} pc;
// The plastics' transmittance tables (Material.table indexes them).
layout(set = 0, binding = 1, scalar) readonly buffer Tables { float tables[]; };

// pcg3d of Jarzynski and Olano 2020, "Hash Functions for GPU Rendering" (JCGT 9(3)): three
// well-mixed 32-bit words per (thread, seed), enough for a test of 10^6 samples.
uvec3 pcg3d(uvec3 v) {
    v = v * 1664525u + 1013904223u;
    v.x += v.y * v.z;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    v ^= v >> 16u;
    v.x += v.y * v.z;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    return v;
}

float bsdf_table(uint table, int index) { return tables[int(table) + index]; }

void main() {
    uint i = thread_index();
    if (i >= pc.count) return;
    // The top 24 bits give floats in [0, 1) exactly.
    vec3 u = vec3(pcg3d(uvec3(i, pc.seed, 0x9e3779b9u)) >> 8u) * (1.0 / 16777216.0);
    vec3 wi, weight;
    float pdf;
    samples[i] = bsdf_sample(pc.material, pc.n, pc.wo, u, wi, weight, pdf) ? wi : vec3(0.0);
}
#else
// 48 bytes: one input case. Mirrored in tests/bsdf.rs and checked there by reflection.
struct BsdfCase {
    vec3 n;
    vec3 wo;
    vec3 wi;
    vec3 u;
};
// 84 bytes: everything the functions return for one case.
struct BsdfResult {
    vec3 value;          // bsdf_eval(wo, wi)
    float pdf;           // bsdf_pdf(wo, wi)
    vec3 sample_wi;      // bsdf_sample(wo, u) ...
    vec3 sample_weight;
    float sample_pdf;
    uint sample_ok;      // its return value
    vec3 d_base_color;   // bsdf_eval_grad(wo, wi)
    vec3 d_roughness;
    vec3 d_metallic;
};
layout(set = 0, binding = 0, scalar) readonly buffer Materials { Material materials[]; };
layout(set = 0, binding = 1, scalar) readonly buffer Cases { BsdfCase cases[]; };
layout(set = 0, binding = 2, scalar) writeonly buffer Results { BsdfResult results[]; };
layout(push_constant, scalar) uniform Push { uint n; } pc;
// The plastics' transmittance tables (Material.table indexes them).
layout(set = 0, binding = 3, scalar) readonly buffer Tables { float tables[]; };

float bsdf_table(uint table, int index) { return tables[int(table) + index]; }

void main() {
    uint i = thread_index();
    if (i >= pc.n) return;
    Material m = materials[i];
    BsdfCase c = cases[i];
    BsdfResult r;
    if (material_is_dielectric(m.kind)) {
        // The delta lobes' functions in the same slots: mass, lobe probability, sample,
        // the mass's base-colour derivative.
        r.value = dielectric_mass(m, c.n, c.wo, c.wi);
        r.pdf = dielectric_prob(m, c.n, c.wo, c.wi);
        r.sample_ok = dielectric_sample(m, c.n, c.wo, c.u.x, r.sample_wi, r.sample_weight, r.sample_pdf) ? 1u : 0u;
        r.d_base_color = dielectric_mass_grad(m, c.n, c.wo, c.wi);
        r.d_roughness = vec3(0.0);
        r.d_metallic = vec3(0.0);
        results[i] = r;
        return;
    }
    r.value = bsdf_eval(m, c.n, c.wo, c.wi);
    r.pdf = bsdf_pdf(m, c.n, c.wo, c.wi);
    r.sample_ok = bsdf_sample(m, c.n, c.wo, c.u, r.sample_wi, r.sample_weight, r.sample_pdf) ? 1u : 0u;
    bsdf_eval_grad(m, c.n, c.wo, c.wi, r.d_base_color, r.d_roughness, r.d_metallic);
    results[i] = r;
}
#endif
