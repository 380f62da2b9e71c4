#version 460
// fill: dst[i] = value for i < n.
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) writeonly buffer Dst { float dst[]; };
layout(push_constant, scalar) uniform Push { uint n; float value; } pc;
void main() {
    uint i = thread_index();
    if (i < pc.n) dst[i] = pc.value;
}
