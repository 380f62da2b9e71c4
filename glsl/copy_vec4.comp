#version 460
// copy_vec4: copy of n4 = n / 4 float4 elements; the bench's wide-load variant of `copy`.
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) readonly buffer Src { vec4 src[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer Dst { vec4 dst[]; };
layout(push_constant, scalar) uniform Push { uint n4; } pc;
void main() {
    uint i = thread_index();
    if (i < pc.n4) dst[i] = src[i];
}
