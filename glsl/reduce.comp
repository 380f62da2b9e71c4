#version 460
// reduce: partials[w] = sum over the ITEMS * local_size elements of workgroup w of
// src[i] (or src[i]^2 when SQUARE). The host applies it repeatedly to the partials until
// one value is left; the order of additions is fixed, so results are deterministic on a
// given device.
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/reduce.glsl"
layout(constant_id = 1) const bool SQUARE = false;
// Elements per thread: amortises the workgroup reduction over more loads.
layout(constant_id = 2) const uint ITEMS = 4;
layout(set = 0, binding = 0, scalar) readonly buffer Src { float src[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer Partials { float partials[]; };
layout(push_constant, scalar) uniform Push { uint n; } pc;
void main() {
    uint base = workgroup_index() * gl_WorkGroupSize.x * ITEMS + gl_LocalInvocationID.x;
    float acc = 0.0;
    for (uint k = 0; k < ITEMS; ++k) {
        // Strided by the workgroup size so that neighbouring threads load neighbours.
        uint i = base + k * gl_WorkGroupSize.x;
        if (i < pc.n) {
            float v = src[i];
            acc += SQUARE ? v * v : v;
        }
    }
    float total = workgroup_sum(acc);
    if (gl_LocalInvocationID.x == 0) partials[workgroup_index()] = total;
}
