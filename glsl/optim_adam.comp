#version 460
// Fused Adam pass over one parameter group: each invocation takes OPTIM_CHUNKS vec4s of
// the group's elements; for each element it loads its state, steps (bias-corrected
// moments, scheduled rate, step, clamp to [lo, hi]) and clears the gradient for the next
// iteration's accumulation. Each workgroup writes the diagnostics record of its elements to partials[first_partial + workgroup] (merged by optim_diag).
// Non-finite gradients leave the element unchanged and are counted in `nonfinite` (never
// reset here).

layout(local_size_x = 256) in;
#extension GL_EXT_control_flow_attributes : require
#include "lib/common.glsl"
#include "lib/optim.glsl"
#include "lib/optim_reduce.glsl"

// Every per-element array as vec4s (four elements each, the array's element k at
// [k / 4][k % 4]): the buffers hold whole vec4s past the group's last element
// (GpuOptimiser::new checks).
layout(set = 0, binding = 0, std430) buffer Theta { vec4 theta[]; };
layout(set = 0, binding = 1, std430) buffer Grad { vec4 grad[]; };
layout(set = 0, binding = 2, std430) buffer AdamM { vec4 adam_m[]; };
layout(set = 0, binding = 3, std430) buffer AdamR { vec4 adam_r[]; };
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
    uint end = pc.offset + pc.n;  // one past the group's last element
    uint first = pc.offset / 4u;  // the vec4 of its first element
    uint chunks = (end + 3u) / 4u - first;
    // The workgroup's block of vec4s, each invocation taking every 256th of them:
    // neighbouring invocations touch neighbouring vec4s (coalesced on a GPU).
    uint c0 = workgroup_index() * gl_WorkGroupSize.x * OPTIM_CHUNKS + gl_LocalInvocationID.x;
    uint t = frame_iteration + 1u;
    DiagRecord rec = diag_empty();
    uint skipped = 0u;  // elements left unchanged for a non-finite input
    if (c0 < chunks) {
        Schedule sched = Schedule(pc.sched_decay, pc.sched_warmup, pc.sched_horizon, pc.sched_every,
                                  pc.sched_floor, pc.sched_gamma);
        AdamParams p = adam_params(t, pc.lr * schedule_factor(sched, t), pc.beta1, pc.beta2, pc.eps, pc.lo, pc.hi);
        for (uint q = 0u; q < OPTIM_CHUNKS; q++) {
            uint c = c0 + q * gl_WorkGroupSize.x;
            if (c >= chunks) break;
            uint v = first + c;
            vec4 th = theta[v], g = grad[v], m = adam_m[v], r = adam_r[v];
            [[unroll]] for (uint l = 0u; l < 4u; l++) {
                // The first and last vec4 may hold another group's elements (or none):
                // those are written back as they were read.
                uint e = 4u * v + l;
                if (e < pc.offset || e >= end) continue;
                AdamElem s = AdamElem(m[l], r[l]);
                float x = th[l];
                ElemDiag d;
                if (adam_update(p, x, g[l], s, d)) {
                    th[l] = x;
                    m[l] = s.m;
                    r[l] = s.r;
                    rec = diag_add(rec, d);
                } else {
                    skipped++;
                }
                g[l] = 0.0;
            }
            theta[v] = th;
            grad[v] = g;
            adam_m[v] = m;
            adam_r[v] = r;
        }
    }
    if (skipped != 0u) atomicAdd(nonfinite, skipped);
    rec = diag_workgroup(rec);
    // A dispatch folded into two dimensions may have workgroups past the group's last one.
    if (gl_LocalInvocationID.x == 0u && workgroup_index() * gl_WorkGroupSize.x * OPTIM_CHUNKS < chunks)
        partials[pc.first_partial + workgroup_index()] = rec;
}
