#version 460
// sub: dst[i] = a[i] - b[i] for i < n (the two-trace finite difference of gradients).
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) readonly buffer A { float a[]; };
layout(set = 0, binding = 1, scalar) readonly buffer B { float b[]; };
layout(set = 0, binding = 2, scalar) writeonly buffer Dst { float dst[]; };
layout(push_constant, scalar) uniform Push { uint n; } pc;
void main() {
    uint i = thread_index();
    if (i < pc.n) dst[i] = a[i] - b[i];
}
