// Workgroup reduction of optimiser diagnostics (DiagRecord, glsl/shared/optim.glsl): a
// subgroup reduction, one record per subgroup through shared memory, then a subgroup
// reduction of those, as lib/reduce.glsl does for sums. Every invocation of the workgroup
// must call it (it contains barriers); invocations without an element pass diag_empty().
// Kernels include it after declaring their workgroup size.
#ifndef OPTIM_REDUCE_GLSL
#define OPTIM_REDUCE_GLSL
#include "lib/common.glsl"
#include "lib/optim.glsl"

// Enough slots for subgroups as small as 4 (as lib/reduce.glsl).
shared DiagRecord diag_slots[gl_WorkGroupSize.x / 4u];

Ssq ssq_subgroup(Ssq a) {
    // subgroupMax is uniform over the subgroup, so the branch is too.
    float m = subgroupMax(a.scale);
    if (m == 0.0) return Ssq(0.0, 0.0);
    float r = a.scale / m;
    return Ssq(m, subgroupAdd(a.sum * (r * r)));
}

DiagRecord diag_subgroup(DiagRecord a) {
    return DiagRecord(subgroupAdd(a.count), sat(subgroupAdd(a.n_eff_sum)), subgroupMin(a.n_eff_min),
                      subgroupMax(a.n_eff_max), subgroupAdd(a.clipped), subgroupAdd(a.newton), ssq_subgroup(a.f),
                      ssq_subgroup(a.df), ssq_subgroup(a.sd_d), ssq_subgroup(a.step), ssq_subgroup(a.mean),
                      ssq_subgroup(a.sd), ssq_subgroup(a.sd_f), ssq_subgroup(a.curv));
}

// The workgroup's merged record, valid in subgroup 0.
DiagRecord diag_workgroup(DiagRecord a) {
    DiagRecord s = diag_subgroup(a);
    if (subgroupElect()) diag_slots[gl_SubgroupID] = s;
    barrier();
    DiagRecord acc = diag_empty();
    if (gl_SubgroupID == 0u) {
        for (uint k = gl_SubgroupInvocationID; k < gl_NumSubgroups; k += gl_SubgroupSize)
            acc = diag_merge(acc, diag_slots[k]);
        acc = diag_subgroup(acc);
    }
    // The slots may be reused by a following call.
    barrier();
    return acc;
}
#endif
