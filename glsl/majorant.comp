#version 460
// majorant: a scattering medium's majorant from its optimised density, before every pass
// that tracks it (lib/media.glsl): factor × the largest density in θ's slot and in the
// previous θ's (the finite-difference kernels track both states against one majorant),
// written over the medium record's majorant word. One workgroup: each thread takes a
// strided share, the workgroup reduces them.
layout(local_size_x = 256) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) readonly buffer Theta { float theta[]; };
layout(set = 0, binding = 1, scalar) readonly buffer ThetaPrev { float theta_prev[]; };
layout(set = 0, binding = 2, scalar) buffer Record { uint record[]; };
layout(push_constant, scalar) uniform Push {
    uint offset;  // the density's first element in θ
    uint n;       // its elements
    uint word;    // the majorant's word in the record
    float factor; // the margin times the medium's scale
} pc;
shared float partial[256];
void main() {
    uint t = gl_LocalInvocationID.x;
    float m = 0.0;
    for (uint i = t; i < pc.n; i += 256u) m = max(m, max(theta[pc.offset + i], theta_prev[pc.offset + i]));
    partial[t] = m;
    barrier();
    for (uint s = 128u; s > 0u; s >>= 1) {
        if (t < s) partial[t] = max(partial[t], partial[t + s]);
        barrier();
    }
    if (t == 0u) record[pc.word] = floatBitsToUint(pc.factor * partial[0]);
}
