#version 460
// Fused meta-estimator pass over one parameter buffer (Balint et al. 2023): one invocation per
// element loads its state, steps both Moment2 EMAs and the meta-estimate, takes the step,
// clamps to [lo, hi], records theta_prev <- theta and clears both gradient buffers for the
// next iteration's accumulation. Each workgroup writes the sum of its elements' squared
// steps to dpi2_partial[workgroup_index()]; a reduction recorded after the pass sums the
// partials into `dpi2` on the GPU for the next pass (src/optim/gpu.rs). Non-finite inputs leave the element unchanged (step 0) and are counted in
// `nonfinite` (never reset here).

layout(local_size_x = 256) in;
#include "lib/common.glsl"
#include "lib/optim.glsl"

layout(set = 0, binding = 0, scalar) buffer Theta { float theta[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer ThetaPrev { float theta_prev[]; };
layout(set = 0, binding = 2, scalar) buffer Grad { float grad[]; };
layout(set = 0, binding = 3, scalar) buffer FdGrad { float fd_grad[]; };
layout(set = 0, binding = 4, scalar) buffer MetaMean { float meta_mean[]; };
layout(set = 0, binding = 5, scalar) buffer MetaSd { float meta_sd[]; };
layout(set = 0, binding = 6, scalar) buffer MetaRmsF { float meta_rms_f[]; };
layout(set = 0, binding = 7, scalar) buffer MetaRmsD { float meta_rms_d[]; };
layout(set = 0, binding = 8, scalar) buffer MetaWsumD { float meta_wsum_d[]; };
layout(set = 0, binding = 9, scalar) buffer MetaNEff { float meta_n_eff[]; };
layout(set = 0, binding = 10, scalar) readonly buffer Dpi2 { float dpi2; };
layout(set = 0, binding = 11, scalar) writeonly buffer Dpi2Partial { float dpi2_partial[]; };
layout(set = 0, binding = 12, scalar) buffer NonFinite { uint nonfinite; };

// The iteration counter (host-written before each submission): step t = iteration + 1,
// so a recording resubmitted every iteration needs no new push constants.
layout(set = 0, binding = 13, scalar) readonly buffer Frame { uint frame_iteration; };

layout(push_constant, scalar) uniform Push {
    uint n;
    uint offset; // first element of this parameter group in every array
    float lr;
    float decay_f;
    float decay_d;
    float eps;
    float lo;
    float hi;
} pc;

// One slot per subgroup; a workgroup has at most as many subgroups as invocations, whatever
// the device's subgroup size.
shared float subgroup_sums[gl_WorkGroupSize.x];

void main() {
    uint j = thread_index();
    uint i = pc.offset + j;
    // Every invocation joins the reduction below; out-of-range and skipped ones add 0.
    float step2 = 0.0;
    if (j < pc.n) {
        MetaParams p = MetaParams(frame_iteration + 1u, pc.lr, pc.decay_f, pc.decay_d, pc.eps, pc.lo, pc.hi);
        MetaElem s = MetaElem(meta_mean[i], meta_sd[i], meta_rms_f[i], meta_rms_d[i],
                              meta_wsum_d[i], meta_n_eff[i]);
        float th = theta[i];
        float th_new = th;
        // theta_prev is the previous iterate for the next finite-difference pass, so it is
        // written for skipped elements too (their step is 0).
        theta_prev[i] = th;
        if (meta_update(p, th_new, grad[i], fd_grad[i], dpi2, s)) {
            theta[i] = th_new;
            meta_mean[i] = s.mean;
            meta_sd[i] = s.sd;
            meta_rms_f[i] = s.rms_f;
            meta_rms_d[i] = s.rms_d;
            meta_wsum_d[i] = s.wsum_d;
            meta_n_eff[i] = s.n_eff;
            float d = th_new - th;
            step2 = d * d;
        } else {
            atomicAdd(nonfinite, 1u);
        }
        grad[i] = 0.0;
        fd_grad[i] = 0.0;
    }

    float sum = subgroupAdd(step2);
    if (subgroupElect()) subgroup_sums[gl_SubgroupID] = sum;
    barrier();
    if (gl_SubgroupID == 0u) {
        float acc = 0.0;
        for (uint k = gl_SubgroupInvocationID; k < gl_NumSubgroups; k += gl_SubgroupSize) {
            acc += subgroup_sums[k];
        }
        acc = subgroupAdd(acc);
        if (subgroupElect()) dpi2_partial[workgroup_index()] = acc;
    }
}
