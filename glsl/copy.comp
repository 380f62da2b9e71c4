#version 460
// copy: dst[i] = src[i] for i < n. The reference kernel every bandwidth figure is
// compared with.
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) readonly buffer Src { float src[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer Dst { float dst[]; };
layout(push_constant, scalar) uniform Push { uint n; } pc;
void main() {
    uint i = thread_index();
    if (i < pc.n) dst[i] = src[i];
}
