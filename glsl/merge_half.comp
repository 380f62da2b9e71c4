#version 460
// merge_half: a gradient pass with direct atomics and a half split adds every contribution
// once, into `fresh`, two sums per element: [2i] from the pixels outside the half, [2i + 1]
// from those in it (lib/scene_access.glsl, grad_add). Afterwards both are added into grad,
// the second into grad_half, and `fresh` is cleared for the next pass. For i < n.
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) buffer Grad { float grad[]; };
layout(set = 0, binding = 1, scalar) buffer GradHalf { float grad_half[]; };
layout(set = 0, binding = 2, scalar) buffer Fresh { vec2 fresh[]; };
layout(push_constant, scalar) uniform Push { uint n; } pc;
void main() {
    uint i = thread_index();
    if (i < pc.n) {
        vec2 v = fresh[i];
        grad[i] += v.x + v.y;
        grad_half[i] += v.y;
        fresh[i] = vec2(0.0);
    }
}
