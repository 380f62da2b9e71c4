#version 460
// Fused Adam pass over one parameter group: one invocation per element loads its state,
// steps (bias-corrected moments, scheduled rate, step, clamp to [lo, hi]) and clears the
// gradient for the next iteration's accumulation. Each workgroup writes the diagnostics
// record of its elements to partials[first_partial + workgroup] (merged by optim_diag).
// Non-finite gradients leave the element unchanged and are counted in `nonfinite` (never
// reset here).

layout(local_size_x = 256) in;
#include "lib/common.glsl"
#include "lib/optim.glsl"
#include "lib/optim_reduce.glsl"

layout(set = 0, binding = 0, scalar) buffer Theta { float theta[]; };
layout(set = 0, binding = 1, scalar) buffer Grad { float grad[]; };
layout(set = 0, binding = 2, scalar) buffer AdamM { float adam_m[]; };
layout(set = 0, binding = 3, scalar) buffer AdamR { float adam_r[]; };
layout(set = 0, binding = 4, scalar) writeonly buffer DiagPartial { DiagRecord partials[]; };
layout(set = 0, binding = 5, scalar) buffer NonFinite { uint nonfinite; };

// The iteration counter (host-written before each submission): step t = iteration + 1,
// so a recording resubmitted every iteration needs no new push constants.
layout(set = 0, binding = 6, scalar) readonly buffer Frame { uint frame_iteration; };

layout(push_constant, scalar) uniform Push {
    uint n;
    uint offset;        // first element of this parameter group in every array
    uint group;         // its slot in diag (optim_diag)
    uint first_partial; // its first record in partials
    float lr;
    float beta1;
    float beta2;
    float eps;
    float lo;
    float hi;
    uint sched_decay;
    uint sched_warmup;
    uint sched_horizon;
    uint sched_every;
    float sched_floor;
    float sched_gamma;
} pc;

void main() {
    uint j = thread_index();
    uint i = pc.offset + j;
    uint t = frame_iteration + 1u;
    DiagRecord rec = diag_empty();
    if (j < pc.n) {
        Schedule sched = Schedule(pc.sched_decay, pc.sched_warmup, pc.sched_horizon, pc.sched_every,
                                  pc.sched_floor, pc.sched_gamma);
        AdamParams p = AdamParams(t, pc.lr * schedule_factor(sched, t), pc.beta1, pc.beta2, pc.eps, pc.lo, pc.hi);
        AdamElem s = AdamElem(adam_m[i], adam_r[i]);
        float th = theta[i];
        ElemDiag d;
        if (adam_update(p, th, grad[i], s, d)) {
            theta[i] = th;
            adam_m[i] = s.m;
            adam_r[i] = s.r;
            rec = diag_of(d);
        } else {
            atomicAdd(nonfinite, 1u);
        }
        grad[i] = 0.0;
    }
    rec = diag_workgroup(rec);
    // A dispatch folded into two dimensions may have workgroups past the group's last one.
    if (gl_LocalInvocationID.x == 0u && workgroup_index() * gl_WorkGroupSize.x < pc.n)
        partials[pc.first_partial + workgroup_index()] = rec;
}
