#version 460
// Fused meta-estimator pass over one parameter group (Balint et al. 2023): one invocation
// per element loads its state, steps both Moment2 EMAs, the Wiener step's second moment, the
// meta-estimate and the secant curvature, takes the step (rule, schedule: lib/optim.glsl), clamps to [lo, hi],
// records theta_prev <- theta and clears the gradient buffers for the next iteration's
// accumulation. Each workgroup writes the diagnostics record of its elements to
// partials[first_partial + workgroup]; optim_diag merges them into diag[group], whose sum
// of squared steps is the |dpi|^2 this pass reads at the next iteration. Non-finite inputs
// leave the element unchanged (step 0) and are counted in `nonfinite` (never reset here).

layout(local_size_x = 256) in;
#include "lib/common.glsl"
#include "lib/optim.glsl"
#include "lib/optim_reduce.glsl"

layout(set = 0, binding = 0, scalar) buffer Theta { float theta[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer ThetaPrev { float theta_prev[]; };
layout(set = 0, binding = 2, scalar) buffer Grad { float grad[]; };
layout(set = 0, binding = 3, scalar) buffer FdGrad { float fd_grad[]; };
// The sums of half of the samples of grad and fd_grad (read and cleared when centred).
layout(set = 0, binding = 4, scalar) buffer GradHalf { float grad_half[]; };
layout(set = 0, binding = 5, scalar) buffer FdGradHalf { float fd_grad_half[]; };
layout(set = 0, binding = 6, scalar) buffer MetaMean { float meta_mean[]; };
layout(set = 0, binding = 7, scalar) buffer MetaSd { float meta_sd[]; };
layout(set = 0, binding = 8, scalar) buffer MetaRmsF { float meta_rms_f[]; };
layout(set = 0, binding = 9, scalar) buffer MetaRmsD { float meta_rms_d[]; };
layout(set = 0, binding = 10, scalar) buffer MetaWsumD { float meta_wsum_d[]; };
layout(set = 0, binding = 11, scalar) buffer MetaNEff { float meta_n_eff[]; };
layout(set = 0, binding = 12, scalar) buffer MetaV { float meta_v[]; };
layout(set = 0, binding = 13, scalar) buffer MetaCurv { float meta_curv[]; };
layout(set = 0, binding = 14, scalar) buffer MetaCurvW { float meta_curv_w[]; };
layout(set = 0, binding = 15, scalar) buffer MetaLast { float meta_last[]; };
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
    uint j = thread_index();
    uint i = pc.offset + j;
    uint t = frame_iteration + 1u;
    // Every invocation joins the reduction below; out-of-range and skipped ones add nothing.
    DiagRecord rec = diag_empty();
    if (j < pc.n) {
        Schedule sched = Schedule(pc.sched_decay, pc.sched_warmup, pc.sched_horizon, pc.sched_every,
                                  pc.sched_floor, pc.sched_gamma);
        bool centred = pc.centred != 0u;
        MetaParams p = MetaParams(t, pc.lr * schedule_factor(sched, t), pc.decay_f, pc.decay_d, pc.eps,
                                  pc.lo, pc.hi, pc.step_rule, pc.beta2, centred, pc.fd_raw != 0u,
                                  pc.decay_h, pc.sig, pc.settle);
        MetaElem s = MetaElem(meta_mean[i], meta_sd[i], meta_rms_f[i], meta_rms_d[i], meta_wsum_d[i],
                              meta_n_eff[i], meta_v[i], meta_curv[i], meta_curv_w[i], meta_last[i]);
        MetaInput x = MetaInput(grad[i], fd_grad[i], centred ? grad_half[i] : 0.0,
                                centred ? fd_grad_half[i] : 0.0);
        float th = theta[i];
        // theta_prev is the previous iterate for the next finite-difference pass, so it is
        // written for skipped elements too (their step is 0).
        theta_prev[i] = th;
        ElemDiag d;
        if (meta_update(p, th, x, ssq_total(diag[pc.group].step), s, d)) {
            theta[i] = th;
            meta_mean[i] = s.mean;
            meta_sd[i] = s.sd;
            meta_rms_f[i] = s.rms_f;
            meta_rms_d[i] = s.rms_d;
            meta_wsum_d[i] = s.wsum_d;
            meta_n_eff[i] = s.n_eff;
            meta_v[i] = s.v;
            meta_curv[i] = s.curv;
            meta_curv_w[i] = s.curv_w;
            meta_last[i] = s.last;
            rec = diag_of(d);
        } else {
            // The element did not move: the next finite difference spans no step of it.
            meta_last[i] = 0.0;
            atomicAdd(nonfinite, 1u);
        }
        grad[i] = 0.0;
        fd_grad[i] = 0.0;
        if (centred) {
            grad_half[i] = 0.0;
            fd_grad_half[i] = 0.0;
        }
    }
    rec = diag_workgroup(rec);
    // A dispatch folded into two dimensions may have workgroups past the group's last one.
    if (gl_LocalInvocationID.x == 0u && workgroup_index() * gl_WorkGroupSize.x < pc.n)
        partials[pc.first_partial + workgroup_index()] = rec;
}
