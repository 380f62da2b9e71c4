#version 460
// carry_stats: per-workgroup sums, over one sensor's pixels and channels, of the squared
// differences from which carry_weight.comp chooses the fresh image's weight in the carried
// primal image (meta `carry`, src/engine.rs):
//   partials[2 w]     = Σ |fresh − cur|²  fresh and cur are independent renders of θ_i (the
//                      primal pass's and the finite-difference sample's), so its expectation
//                      is the sum of their sampling variances;
//   partials[2 w + 1] = Σ |cur − prev|²   the finite-difference sample's two images: its
//                      expectation bounds the variance their difference adds to the carried
//                      image from above (it also holds the squared change of the expected
//                      image).
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/reduce.glsl"
layout(set = 0, binding = 0, scalar) readonly buffer Fresh { vec3 fresh[]; };
layout(set = 0, binding = 1, scalar) readonly buffer Cur { vec3 cur[]; };
layout(set = 0, binding = 2, scalar) readonly buffer Prev { vec3 prev[]; };
layout(set = 0, binding = 3, scalar) writeonly buffer Partials { float partials[]; };
layout(push_constant, scalar) uniform Push { uint n; } pc;

void main() {
    uint i = thread_index();
    float a = 0.0;
    float b = 0.0;
    if (i < pc.n) {
        vec3 fc = fresh[i] - cur[i];
        vec3 cp = cur[i] - prev[i];
        a = dot(fc, fc);
        b = dot(cp, cp);
    }
    float sa = workgroup_sum(a);
    float sb = workgroup_sum(b);
    if (gl_LocalInvocationID.x == 0u) {
        partials[2u * workgroup_index()] = sa;
        partials[2u * workgroup_index() + 1u] = sb;
    }
}
