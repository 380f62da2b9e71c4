#version 460
// Fused meta-estimator pass over one parameter group (Balint et al. 2023): each invocation
// takes OPTIM_CHUNKS vec4s of the group's elements; for each element it loads its state,
// steps both Moment2 EMAs, the Wiener step's second moment, the meta-estimate and the
// secant curvature, takes the step (rule, schedule: lib/optim.glsl), clamps to [lo, hi],
// records theta_prev <- theta and clears the gradient buffers for the next iteration's
// accumulation. Each workgroup writes the diagnostics record of its elements to
// partials[first_partial + workgroup]; optim_diag merges them into diag[group], whose sum
// of squared steps is the |dpi|^2 this pass reads at the next iteration. Non-finite inputs
// leave the element unchanged (step 0) and are counted in `nonfinite` (never reset here).

layout(local_size_x = 256) in;
#extension GL_EXT_control_flow_attributes : require
#include "lib/common.glsl"
#include "lib/optim.glsl"
#include "lib/optim_reduce.glsl"

// Every per-element array as vec4s (four elements each, the array's element k at
// [k / 4][k % 4]): the buffers hold whole vec4s past the group's last element
// (GpuOptimiser::new checks). GradHalf and FdGradHalf are the sums of half of the samples
// of grad and fd_grad (read and cleared when centred).
layout(set = 0, binding = 0, std430) buffer Theta { vec4 theta[]; };
layout(set = 0, binding = 1, std430) buffer ThetaPrev { vec4 theta_prev[]; };
layout(set = 0, binding = 2, std430) buffer Grad { vec4 grad[]; };
layout(set = 0, binding = 3, std430) buffer FdGrad { vec4 fd_grad[]; };
layout(set = 0, binding = 4, std430) buffer GradHalf { vec4 grad_half[]; };
layout(set = 0, binding = 5, std430) buffer FdGradHalf { vec4 fd_grad_half[]; };
layout(set = 0, binding = 6, std430) buffer MetaMean { vec4 meta_mean[]; };
layout(set = 0, binding = 7, std430) buffer MetaSd { vec4 meta_sd[]; };
layout(set = 0, binding = 8, std430) buffer MetaRmsF { vec4 meta_rms_f[]; };
layout(set = 0, binding = 9, std430) buffer MetaRmsD { vec4 meta_rms_d[]; };
layout(set = 0, binding = 10, std430) buffer MetaWsumD { vec4 meta_wsum_d[]; };
layout(set = 0, binding = 11, std430) buffer MetaNEff { vec4 meta_n_eff[]; };
layout(set = 0, binding = 12, std430) buffer MetaV { vec4 meta_v[]; };
layout(set = 0, binding = 13, std430) buffer MetaCurv { vec4 meta_curv[]; };
layout(set = 0, binding = 14, std430) buffer MetaCurvW { vec4 meta_curv_w[]; };
layout(set = 0, binding = 15, std430) buffer MetaLast { vec4 meta_last[]; };
layout(set = 0, binding = 16, scalar) readonly buffer Diag { DiagRecord diag[]; };
layout(set = 0, binding = 17, scalar) writeonly buffer DiagPartial { DiagRecord partials[]; };
layout(set = 0, binding = 18, scalar) buffer NonFinite { uint nonfinite; };

// The iteration counter (host-written before each submission): step t = iteration + 1,
// so a recording resubmitted every iteration needs no new push constants.
layout(set = 0, binding = 19, scalar) readonly buffer Frame { uint frame_iteration; };
layout(push_constant, scalar) uniform Push {
    uint n;
    uint offset;        // first element of this parameter group in every array
    uint group;         // its slot in diag
    uint first_partial; // its first record in partials
    float lr;
    float decay_f;
    float decay_d;
    float eps;
    float lo;
    float hi;
    float beta2;      // the decay of the Wiener step's normaliser v (META_BETA2)
    uint step_rule;   // STEP_*
    uint centred;
    uint sched_decay;
    uint sched_warmup;
    uint sched_horizon;
    uint sched_every;
    float sched_floor;
    float sched_gamma;
    uint fd_raw;      // nonzero: the dF variance is Moment2(dF), not Moment2(dF/|dpi|)*|dpi|^2
    float decay_h;    // STEP_NEWTON: the curvature fit's forgetting per sample
    float sig;        // STEP_NEWTON: the significance its Newton step needs
    float settle;     // STEP_NEWTON: the Wiener step's fraction where Newton's is shorter
} pc;

void main() {
    uint end = pc.offset + pc.n;  // one past the group's last element
    uint first = pc.offset / 4u;  // the vec4 of its first element
    uint chunks = (end + 3u) / 4u - first;
    // The workgroup's block of vec4s, each invocation taking every 256th of them:
    // neighbouring invocations touch neighbouring vec4s (coalesced on a GPU).
    uint c0 = workgroup_index() * gl_WorkGroupSize.x * OPTIM_CHUNKS + gl_LocalInvocationID.x;
    uint t = frame_iteration + 1u;
    // Every invocation joins the reduction below; out-of-range and skipped ones add nothing.
    DiagRecord rec = diag_empty();
    uint skipped = 0u;  // elements left unchanged for a non-finite input
    if (c0 < chunks) {
        Schedule sched = Schedule(pc.sched_decay, pc.sched_warmup, pc.sched_horizon, pc.sched_every,
                                  pc.sched_floor, pc.sched_gamma);
        bool centred = pc.centred != 0u;
        MetaParams p = MetaParams(ema_of(pc.decay_f, t), ema_of(pc.beta2, t), pc.lr * schedule_factor(sched, t),
                                  pc.decay_d, pc.eps, pc.lo, pc.hi, pc.step_rule, centred, pc.fd_raw != 0u,
                                  sqrt(pc.decay_h), pc.sig, pc.settle);
        float dpi2 = ssq_total(diag[pc.group].step);
        for (uint q = 0u; q < OPTIM_CHUNKS; q++) {
            uint c = c0 + q * gl_WorkGroupSize.x;
            if (c >= chunks) break;
            uint v = first + c;
            vec4 th = theta[v], th_prev = theta_prev[v], g = grad[v], fd = fd_grad[v];
            vec4 g_half = centred ? grad_half[v] : vec4(0.0), fd_half = centred ? fd_grad_half[v] : vec4(0.0);
            vec4 mean = meta_mean[v], sd = meta_sd[v], rms_f = meta_rms_f[v], rms_d = meta_rms_d[v];
            vec4 wsum_d = meta_wsum_d[v], n_eff = meta_n_eff[v], mv = meta_v[v], curv = meta_curv[v];
            vec4 curv_w = meta_curv_w[v], last = meta_last[v];
            [[unroll]] for (uint l = 0u; l < 4u; l++) {
                // The first and last vec4 may hold another group's elements (or none):
                // those are written back as they were read.
                uint e = 4u * v + l;
                if (e < pc.offset || e >= end) continue;
                MetaElem s = MetaElem(mean[l], sd[l], rms_f[l], rms_d[l], wsum_d[l], n_eff[l], mv[l], curv[l],
                                      curv_w[l], last[l]);
                MetaInput x = MetaInput(g[l], fd[l], g_half[l], fd_half[l]);
                float y = th[l];
                // theta_prev is the previous iterate for the next finite-difference pass, so
                // it is written for skipped elements too (their step is 0).
                th_prev[l] = y;
                ElemDiag d;
                if (meta_update(p, y, x, dpi2, s, d)) {
                    th[l] = y;
                    mean[l] = s.mean;
                    sd[l] = s.sd;
                    rms_f[l] = s.rms_f;
                    rms_d[l] = s.rms_d;
                    wsum_d[l] = s.wsum_d;
                    n_eff[l] = s.n_eff;
                    mv[l] = s.v;
                    curv[l] = s.curv;
                    curv_w[l] = s.curv_w;
                    last[l] = s.last;
                    rec = diag_add(rec, d);
                } else {
                    // The element did not move: the next finite difference spans no step of it.
                    last[l] = 0.0;
                    skipped++;
                }
                g[l] = 0.0;
                fd[l] = 0.0;
                g_half[l] = 0.0;
                fd_half[l] = 0.0;
            }
            theta[v] = th;
            theta_prev[v] = th_prev;
            grad[v] = g;
            fd_grad[v] = fd;
            if (centred) {
                grad_half[v] = g_half;
                fd_grad_half[v] = fd_half;
            }
            meta_mean[v] = mean;
            meta_sd[v] = sd;
            meta_rms_f[v] = rms_f;
            meta_rms_d[v] = rms_d;
            meta_wsum_d[v] = wsum_d;
            meta_n_eff[v] = n_eff;
            meta_v[v] = mv;
            meta_curv[v] = curv;
            meta_curv_w[v] = curv_w;
            meta_last[v] = last;
        }
    }
    if (skipped != 0u) atomicAdd(nonfinite, skipped);
    rec = diag_workgroup(rec);
    // A dispatch folded into two dimensions may have workgroups past the group's last one.
    if (gl_LocalInvocationID.x == 0u && workgroup_index() * gl_WorkGroupSize.x * OPTIM_CHUNKS < chunks)
        partials[pc.first_partial + workgroup_index()] = rec;
}
