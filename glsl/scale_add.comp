#version 460
// scale_add: x[i] = a * x[i] + b, a read-modify-write of one buffer (the access pattern
// of an optimiser step).
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) buffer X { float x[]; };
layout(push_constant, scalar) uniform Push { uint n; float a; float b; } pc;
void main() {
    uint i = thread_index();
    if (i < pc.n) x[i] = pc.a * x[i] + pc.b;
}
