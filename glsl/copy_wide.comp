#version 460
// copy_wide: each thread copies ITEMS float4s, strided by the workgroup size so that
// neighbouring threads touch neighbouring memory. Fewer, fatter workgroups: on lavapipe
// the fixed cost per workgroup (~2 us) dominates thin kernels (see docs/lavapipe.md).
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(constant_id = 1) const uint ITEMS = 8;
layout(set = 0, binding = 0, scalar) readonly buffer Src { vec4 src[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer Dst { vec4 dst[]; };
layout(push_constant, scalar) uniform Push { uint n4; } pc;
void main() {
    uint base = workgroup_index() * gl_WorkGroupSize.x * ITEMS + gl_LocalInvocationID.x;
    for (uint k = 0; k < ITEMS; ++k) {
        uint i = base + k * gl_WorkGroupSize.x;
        if (i < pc.n4) dst[i] = src[i];
    }
}
