// Per-group optimiser diagnostics as the fused optimiser passes reduce them: each
// workgroup writes one DiagRecord of its elements, optim_diag merges a group's records into
// one. Mirrored by `DiagRecordGpu` in src/shared.rs (offsets checked by reflection) and by
// `DiagRecord` in src/optim/reference.rs (the same merge, the CPU reference).
#ifndef SHARED_OPTIM_GLSL
#define SHARED_OPTIM_GLSL

// A sum of squares kept as scale * sqrt(sum) = its root: scale is the largest magnitude, sum
// the sum of the squares divided by scale^2, so values near 1e30 do not overflow and values
// near 1e-30 do not vanish. 8 bytes.
struct Ssq {
    float scale;
    float sum;
};

// 88 bytes.
struct DiagRecord {
    float count;      // elements that stepped (not skipped for non-finite input)
    float n_eff_sum;  // meta: 1/(1 - alpha) summed over them
    float n_eff_min;
    float n_eff_max;
    float clipped;    // meta: elements whose alpha the clip alpha <= 1/(2 - alpha_prev) limited
    float newton;     // meta, STEP_NEWTON: elements that took Newton's step
    Ssq f;            // <F>
    Ssq df;           // meta: <dF> as used (0 where the dF terms were skipped)
    Ssq sd_d;         // meta: sqrt(Var[<dF>]), the FD term's standard deviation
    Ssq step;         // the step taken; its total is the group's |dpi|^2
    Ssq mean;         // meta: <F>_M; adam: m
    Ssq sd;           // meta: sqrt(Var[<F>_M])
    Ssq sd_f;         // meta: sqrt(Var[<F>]) (its Moment2); adam: sqrt(v)
    Ssq curv;         // meta: the secant curvature of STEP_NEWTON (kept for every rule)
};
#endif
