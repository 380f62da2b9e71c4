// Scene buffers (bindings 20-27) and the parameter buffers (30-31), with the lookups that
// read a material or emission value from a constant, a texture, or the parameters being
// optimised, and (ADJOINT) scatter gradients back through the same lookup.
#ifndef SCENE_ACCESS_GLSL
#define SCENE_ACCESS_GLSL
#include "shared/scene.glsl"
#include "shared/material.glsl"

layout(set = 0, binding = 20, scalar) readonly buffer Materials { MaterialRecord materials[]; };
layout(set = 0, binding = 21, scalar) readonly buffer Shading { TriShading shading[]; };
layout(set = 0, binding = 22, scalar) readonly buffer Meshes { MeshRecord meshes[]; };
layout(set = 0, binding = 23, scalar) readonly buffer Emitters { EmitterTri emitters[]; };
layout(set = 0, binding = 24, scalar) readonly buffer Sensors { SensorRecord sensors[]; };
layout(set = 0, binding = 25, scalar) readonly buffer SceneGlobals { Globals globals; };
layout(set = 0, binding = 26, scalar) readonly buffer MaterialData { float material_data[]; };
// The environment map's sampling distribution (src/render/envmap.rs): row cdf (H), per-row
// column cdfs (H × W), cell densities in solid angle (H × W); W × H = the map's size.
layout(set = 0, binding = 27, scalar) readonly buffer EnvDistribution { float env_dist[]; };
layout(set = 0, binding = 30, scalar) readonly buffer Theta { float theta[]; };

// Parameter states a kernel evaluates along each path: 1, or 2 for the fused finite
// difference (state 0 = θ_i, which samples the path; state 1 = θ_{i-1}).
#ifdef FD
#define NSTATES 2
layout(set = 0, binding = 32, scalar) readonly buffer ThetaPrev { float theta_prev[]; };
#else
#define NSTATES 1
#endif
#ifdef ADJOINT
#extension GL_EXT_shader_atomic_float : require
layout(set = 0, binding = 31, scalar) buffer Grad { float grad[]; };
#endif

float value_at(ValueRef r, int index, int state) {
    if (r.in_theta == 0u) return material_data[r.offset + index];
#ifdef FD
    if (state == 1) return theta_prev[r.offset + index];
#endif
    return theta[r.offset + index];
}

// Bilinear lookup footprint: four texel indices (repeat wrapping) and their weights.
// A constant is one "texel" with weight 1 in slot 0.
void footprint(ValueRef r, vec2 uv, out ivec4 texel, out vec4 weight) {
    if (r.width == 0u) {
        texel = ivec4(0);
        weight = vec4(1.0, 0.0, 0.0, 0.0);
        return;
    }
    // uv (0,0) is the bottom-left of the image (OBJ convention); rows are stored top first.
    vec2 p = vec2(uv.x, 1.0 - uv.y) * vec2(r.width, r.height) - 0.5;
    vec2 f = floor(p);
    vec2 t = p - f;
    ivec2 size = ivec2(r.width, r.height);
    ivec2 a = ivec2(mod(f, vec2(size)));
    ivec2 b = (a + 1) % size;
    texel = ivec4(a.y * size.x + a.x, a.y * size.x + b.x, b.y * size.x + a.x, b.y * size.x + b.x);
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
        v += w[k] * vec3(value_at(r, base, state), value_at(r, base + 1, state), value_at(r, base + 2, state));
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

#ifdef ADJOINT
// Gradients of up to LOCAL_GRADS_CAPACITY parameters are summed per thread in registers and
// added to grad[] once per subgroup at the end (grad_flush), instead of one float atomic
// per path vertex. Besides contention, this is about precision: a float32 running sum
// over millions of tiny atomic additions of both signs drops every addend below half an
// ulp of the running total, which biased scalar gradients by tens of percent at a few
// hundred spp. LOCAL_GRADS is θ's length when it fits (set by the host), else 0: large θ
// (textures) has few contributions per element and keeps the direct atomics.
layout(constant_id = 5) const uint LOCAL_GRADS = 0;
const uint LOCAL_GRADS_CAPACITY = 32u;
float local_grads[LOCAL_GRADS_CAPACITY];

void grad_init() {
    for (uint k = 0u; k < LOCAL_GRADS_CAPACITY; ++k) local_grads[k] = 0.0;
}

void grad_add(int index, float v) {
    if (LOCAL_GRADS != 0u) local_grads[index] += v;
    else atomicAdd(grad[index], v);
}

// Adds the thread's sums into grad[], one atomic per parameter and subgroup.
void grad_flush() {
    if (LOCAL_GRADS == 0u) return;
    for (uint k = 0u; k < LOCAL_GRADS_CAPACITY; ++k) {
        if (k >= LOCAL_GRADS) break;
        float total = subgroupAdd(local_grads[k]);
        if (subgroupElect() && total != 0.0) atomicAdd(grad[k], total);
    }
}

// Adds g (the gradient of the loss with respect to the looked-up value) to the gradients
// of the parameters the lookup read, if they are being optimised.
void scatter3(ValueRef r, vec2 uv, vec3 g) {
    if (r.in_theta == 0u || all(equal(g, vec3(0.0)))) return;
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
    if (r.in_theta == 0u || g == 0.0) return;
    ivec4 texel;
    vec4 w;
    footprint(r, uv, texel, w);
    for (int k = 0; k < 4; ++k) {
        if (w[k] != 0.0) grad_add(r.offset + texel[k], w[k] * g);
    }
}
#endif

// The material at a surface point, in parameter state `state`.
Material fetch_material(uint id, vec2 uv, int state) {
    MaterialRecord r = materials[id];
    Material m;
    m.base_color = fetch3(r.base_color, uv, state);
    m.roughness = fetch1(r.roughness, uv, state);
    m.metallic = fetch1(r.metallic, uv, state);
    m.kind = r.kind;
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
    return globals.environment_scale * fetch3(globals.environment, environment_uv(dir), state);
}

// Environment-map light sampling (src/render/envmap.rs describes the distribution). The
// map's texel cells are picked by a piecewise-constant distribution and a direction is
// uniform in solid angle inside its cell, so the density is constant per cell. Sampling
// is by cell while the radiance is the bilinear lookup; both stay consistent because
// the density is positive everywhere (the distribution's uniform share).

// Density in solid angle of sampling direction dir, given that the environment is sampled.
float environment_density(vec3 dir) {
    uint w = globals.environment.width;
    uint h = globals.environment.height;
    vec2 uv = environment_uv(dir);
    uint c = min(uint(max(uv.x, 0.0) * float(w)), w - 1u);
    uint r = min(uint(max(1.0 - uv.y, 0.0) * float(h)), h - 1u);
    return env_dist[h + h * w + r * w + c];
}

// Index of the first entry of the inclusive cdf env_dist[base .. base + n) that exceeds x,
// and x rescaled to [0, 1] within that entry's interval.
uint environment_pick(uint base, uint n, float x, out float rescaled) {
    uint lo = 0u, hi = n - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (env_dist[base + mid] > x) hi = mid; else lo = mid + 1u;
    }
    float c0 = lo == 0u ? 0.0 : env_dist[base + lo - 1u];
    rescaled = clamp((x - c0) / max(env_dist[base + lo] - c0, 1e-30), 0.0, 1.0);
    return lo;
}

// A direction from two uniform numbers (each picks a row or column, then places the
// direction inside the cell) and its density in solid angle. Inside row r, cos θ is
// uniform between the row's bounds θ0 = πr/H and θ1 = π(r+1)/H; it is interpolated as
// 1 − cos θ = 2 sin²(θ/2) in the upper half and 1 + cos θ = 2 cos²(θ/2) in the lower, which
// keeps rows near the poles free of cancellation.
vec3 environment_sample(vec2 u, out float pdf) {
    const float PI = 3.14159265358979;
    uint w = globals.environment.width;
    uint h = globals.environment.height;
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
    pdf = env_dist[h + h * w + r * w + c];
    return vec3(st * sin(phi), ct, -st * cos(phi));
}
#endif
