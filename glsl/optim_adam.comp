#version 460
// Fused Adam pass over one parameter buffer: one invocation per element loads its state,
// steps (bias-corrected moments, step, clamp to [lo, hi]) and clears the gradient for the
// next iteration's accumulation. Non-finite gradients leave the element unchanged and are
// counted in `nonfinite` (never reset here).

layout(local_size_x = 256) in;
#include "lib/common.glsl"
#include "lib/optim.glsl"

layout(set = 0, binding = 0, scalar) buffer Theta { float theta[]; };
layout(set = 0, binding = 1, scalar) buffer Grad { float grad[]; };
layout(set = 0, binding = 2, scalar) buffer AdamM { float adam_m[]; };
layout(set = 0, binding = 3, scalar) buffer AdamR { float adam_r[]; };
layout(set = 0, binding = 4, scalar) buffer NonFinite { uint nonfinite; };

// The iteration counter (host-written before each submission): step t = iteration + 1,
// so a recording resubmitted every iteration needs no new push constants.
layout(set = 0, binding = 5, scalar) readonly buffer Frame { uint frame_iteration; };

layout(push_constant, scalar) uniform Push {
    uint n;
    uint offset; // first element of this parameter group in every array
    float lr;
    float beta1;
    float beta2;
    float eps;
    float lo;
    float hi;
} pc;

void main() {
    uint j = thread_index();
    uint i = pc.offset + j;
    if (j >= pc.n) return;
    AdamParams p = AdamParams(frame_iteration + 1u, pc.lr, pc.beta1, pc.beta2, pc.eps, pc.lo, pc.hi);
    AdamElem s = AdamElem(adam_m[i], adam_r[i]);
    float th = theta[i];
    if (adam_update(p, th, grad[i], s)) {
        theta[i] = th;
        adam_m[i] = s.m;
        adam_r[i] = s.r;
    } else {
        atomicAdd(nonfinite, 1u);
    }
    grad[i] = 0.0;
}
