#version 460
// trace_test: one ray per thread through trace_closest and trace_any, both results
// written; tests/bvh.rs compares them with the CPU reference and `vkinverse bench SCENE`
// times the traversal.
// TRACE_CLOSEST / TRACE_ANY switch either trace off (a skipped one writes a miss / 0), so
// that each can be timed alone.
// trace_test_wide (BVH_WIDE) and trace_test_cw8 (BVH_CW8) trace the other BVH layouts.
// variant: trace_test_wide BVH_WIDE
// variant: trace_test_cw8 BVH_CW8
layout(local_size_x = 64, local_size_x_id = 0) in;
#include "lib/common.glsl"
#include "lib/bvh_traverse.glsl"

layout(constant_id = 1) const bool TRACE_CLOSEST = true;
layout(constant_id = 2) const bool TRACE_ANY = true;

layout(set = 0, binding = 0, scalar) readonly buffer Rays { TraceRay rays[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer Results { TraceResult results[]; };
layout(push_constant, scalar) uniform Push { uint n; } pc;

void main() {
    uint i = thread_index();
    if (i >= pc.n) return;
    TraceRay ray = rays[i];
    Hit hit = Hit(ray.tmax, BVH_NO_HIT, 0.0, 0.0);
    if (TRACE_CLOSEST) trace_closest(ray.origin, ray.dir, ray.tmax, hit);
    bool any_hit = TRACE_ANY && trace_any(ray.origin, ray.dir, ray.tmax);
    results[i] = TraceResult(hit, any_hit ? 1u : 0u);
}
