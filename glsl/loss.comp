#version 460
// loss: per-pixel image loss against the target, its gradient with respect to the
// rendered image (the adjoint image that trace_adjoint consumes), and per-workgroup
// partial sums of the loss for reporting. The loss is the mean over pixels and channels:
//   l2           (I - T)^2
//   l1           |I - T|
//   relative_l2  (I - T)^2 / (T^2 + 0.01)   (the denominator uses the target, so it is a
//                constant: relative MSE in the spirit of Lehtinen et al. 2018)
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/reduce.glsl"
#include "vkinverse_constants.glsl"
layout(constant_id = 1) const uint LOSS = LOSS_L2;  // LOSS_L2, LOSS_L1 or LOSS_RELATIVE_L2
layout(set = 0, binding = 0, scalar) readonly buffer Rendered { vec3 rendered[]; };
layout(set = 0, binding = 1, scalar) readonly buffer Target { vec3 target[]; };
layout(set = 0, binding = 2, scalar) writeonly buffer AdjointImage { vec3 adjoint_image[]; };
layout(set = 0, binding = 3, scalar) writeonly buffer LossPartials { float loss_partials[]; };
layout(push_constant, scalar) uniform Push {
    uint n;       // pixels
    float scale;  // 1 / (3 n): the mean over pixels and channels
} pc;

void main() {
    uint i = thread_index();
    float value = 0.0;
    if (i < pc.n) {
        vec3 d = rendered[i] - target[i];
        vec3 g;
        if (LOSS == LOSS_L1) {
            value = abs(d.x) + abs(d.y) + abs(d.z);
            g = sign(d);
        } else if (LOSS == LOSS_RELATIVE_L2) {
            vec3 w = 1.0 / (target[i] * target[i] + 0.01);
            value = dot(d * d, w);
            g = 2.0 * d * w;
        } else {
            value = dot(d, d);
            g = 2.0 * d;
        }
        adjoint_image[i] = g * pc.scale;
        value *= pc.scale;
    }
    float total = workgroup_sum(value);
    if (gl_LocalInvocationID.x == 0u) loss_partials[workgroup_index()] = total;
}
