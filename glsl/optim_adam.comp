// Fused Adam pass over one parameter buffer: one invocation per element loads its state,
// steps (bias-corrected moments, step, clamp to [lo, hi]) and clears the gradient for the
// next iteration's accumulation. Non-finite gradients leave the element unchanged and are
// counted in `nonfinite` (never reset here).
#version 460
#extension GL_EXT_scalar_block_layout : require
#extension GL_GOOGLE_include_directive : require

#include "lib/optim.glsl"

layout(local_size_x = 256) in;

layout(set = 0, binding = 0, scalar) buffer Theta { float theta[]; };
layout(set = 0, binding = 1, scalar) buffer Grad { float grad[]; };
layout(set = 0, binding = 2, scalar) buffer AdamM { float adam_m[]; };
layout(set = 0, binding = 3, scalar) buffer AdamR { float adam_r[]; };
layout(set = 0, binding = 4, scalar) buffer NonFinite { uint nonfinite; };

layout(push_constant, scalar) uniform Push {
    uint n;
    uint t;      // step number, from 1
    float lr;
    float beta1;
    float beta2;
    float eps;
    float lo;
    float hi;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) return;
    AdamParams p = AdamParams(pc.t, pc.lr, pc.beta1, pc.beta2, pc.eps, pc.lo, pc.hi);
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
