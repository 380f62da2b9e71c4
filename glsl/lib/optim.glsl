// Optimiser element updates: Adam (Kingma & Ba 2015) and the gradient meta-estimator of
// Balint et al., "Joint Sampling and Optimisation for Inverse Rendering" (SIGGRAPH Asia 2023,
// supplementary B: Moment2 + Meta). Pure functions, no bindings.
//
// src/optim/reference.rs mirrors this file function for function (in f64 as the reference
// the GPU is tested against, in f32 for the tests of the float32 behaviour); a change here is
// a change there. The module docs of src/optim/mod.rs explain each choice below.
//
// Float32-safe formulation (the seed's squares overflow f32 for gradients near 1e30 and
// vanish near 1e-30):
//  - second moments and variances are stored as RMS / standard deviations and combined with
//    a scaled hypot, never squared;
//  - EMAs are stored bias-corrected and updated as convex combinations with weight
//    k = (1-b)/(1-b^t); 1-b^t comes from one_minus_pow, free of cancellation;
//  - alpha = VF/(VF + var + 1e-30) is evaluated on standard deviations divided by the larger;
//  - alpha is carried as the gain g = 1 - alpha, accurate in f32 as alpha -> 1; the clip
//    alpha <= 1/(2 - alpha_prev) is g >= 1/(1 + n_eff) with n_eff = 1/(1 - alpha_prev) the
//    effective number of averaged samples, 0 (zeroed state) for alpha_prev = -inf;
//  - the mean update is a convex combination at every stage (on halves), so it cannot overflow;
//  - the dF Moment2 (of dF/|dpi|) is updated through the current step's standard deviation
//    sd_d = hypot(sqrt(1-k)*rms_d*|dpi|, sqrt(k)*|dF|), never through dF/|dpi| itself;
//  - |dpi|^2 == 0 (first iteration, buffer did not move) or non-finite: the dF terms are
//    skipped (dF = 0 with variance 0, dF Moment2 not stepped): a common-random-number
//    finite difference over a zero step is exactly 0;
//  - the dF Moment2 counts its own samples per element (wsum_d = 1 - decay_d^count);
//  - a non-finite F or dF leaves theta and the element's state unchanged (returns false);
//  - results that can leave the f32 range saturate at +-FLT_MAX.

#ifndef OPTIM_GLSL
#define OPTIM_GLSL

const float FLT_MAX = 3.40282347e38;
// The seed's regulariser in the alpha denominator: alpha = VF / (VF + var + 1e-30).
const float META_ALPHA_REG = 1e-30;

bool is_finite(float x) { return !isnan(x) && !isinf(x); }

// Clamps +-inf (an overflowed product) to +-FLT_MAX.
float sat(float x) { return clamp(x, -FLT_MAX, FLT_MAX); }

// sqrt(x^2 + y^2) without forming the squares.
float hypot_safe(float x, float y) {
    x = abs(x);
    y = abs(y);
    float big = max(x, y);
    if (big == 0.0) return 0.0;
    float small = min(x, y) / big;
    return sat(big * sqrt(1.0 + small * small));
}

// 1 - (1-q)^t by binary powering in the form 1 - d: (1-a)(1-b) = 1 - (a + b(1-a)) has only
// non-negative terms, unlike 1 - pow(1-q, t), which loses 4 digits at q = 1e-3.
float one_minus_pow(float q, uint t) {
    float d = 0.0;
    float e = q;
    while (t != 0u) {
        if ((t & 1u) != 0u) d = d + e * (1.0 - d);
        e = e + e * (1.0 - e);
        t >>= 1u;
    }
    return d;
}

// Weight of the t-th sample (t >= 1) of a bias-corrected EMA of decay beta: the seed
// Moment2's w / w_sum = (1-beta)/(1-beta^t).
float ema_weight(float beta, uint t) {
    float q = 1.0 - beta;
    return q / one_minus_pow(q, max(t, 1u));
}

// s_a^2 / (s_a^2 + s_b^2) from standard deviations, scaled by the larger; s_a or s_b > 0.
float inverse_variance_weight(float s_a, float s_b) {
    float big = max(s_a, s_b);
    float a = s_a / big;
    float b = s_b / big;
    return a * a / (a * a + b * b);
}

// ---- Adam --------------------------------------------------------------------------------

// Bias-corrected first moment and bias-corrected RMS (sqrt of the second moment).
struct AdamElem {
    float m;
    float r;
};

struct AdamParams {
    uint t;      // step number, from 1
    float lr;
    float beta1;
    float beta2;
    float eps;
    float lo;
    float hi;
};

// One Adam step of one element. False for a non-finite gradient: nothing is changed.
bool adam_update(AdamParams p, inout float theta, float g, inout AdamElem s) {
    if (!is_finite(g)) return false;
    float k1 = ema_weight(p.beta1, p.t);
    float k2 = ema_weight(p.beta2, p.t);
    float m = (1.0 - k1) * s.m + k1 * g;
    float r = hypot_safe(sqrt(1.0 - k2) * s.r, sqrt(k2) * g);
    float step = sat(-p.lr * (m / (r + p.eps)));
    theta = min(max(sat(theta + step), p.lo), p.hi);
    s = AdamElem(m, r);
    return true;
}

// ---- Meta-estimator ----------------------------------------------------------------------

// All zero initially.
struct MetaElem {
    float mean;   // meta-estimate <F_i>_M
    float sd;     // sqrt(Var[<F_i>_M])
    float rms_f;  // sqrt(Moment2 of <F>), bias-corrected with the global count t
    float rms_d;  // sqrt(Moment2 of <dF>/|dpi|), bias-corrected with wsum_d
    float wsum_d; // 1 - decay_d^count of the dF Moment2's own samples
    float n_eff;  // 1/(1 - alpha_prev): effective number of averaged samples
};

struct MetaParams {
    uint t;      // step number, from 1
    float lr;
    float decay_f;
    float decay_d;
    float eps;
    float lo;
    float hi;
};

// One meta-estimator step of one element from the proportional gradient f, the
// finite-difference sample df and the buffer's |dpi|^2 of the previous step.
// False for a non-finite f or df: nothing is changed.
bool meta_update(MetaParams p, inout float theta, float f, float df, float dpi2,
                 inout MetaElem s) {
    if (!is_finite(f) || !is_finite(df)) return false;
    float kf = ema_weight(p.decay_f, p.t);
    float rms_f = hypot_safe(sqrt(1.0 - kf) * s.rms_f, sqrt(kf) * f);

    // dF terms: VD = Moment2(dF/|dpi|) * |dpi|^2, kept as the standard deviation sd_d.
    float sd_d = 0.0;
    float rms_d = s.rms_d;
    float wsum_d = s.wsum_d;
    if (dpi2 > 0.0 && is_finite(dpi2)) {
        float step_len = sqrt(dpi2);
        float q = 1.0 - p.decay_d;
        wsum_d = q + p.decay_d * s.wsum_d;
        float kd = q / wsum_d;
        sd_d = hypot_safe(sqrt(1.0 - kd) * sat(s.rms_d * step_len), sqrt(kd) * df);
        rms_d = sat(sd_d / step_len);
    } else {
        df = 0.0;
    }

    // mean += dF; var += VD; alpha by inverse-variance weighting, clipped to perfect averaging.
    // Written with the gain g = 1 - alpha (the weight of the fresh sample), which f32 keeps
    // accurate as alpha -> 1, and the update h + g*(F - h) on halves, which cannot overflow.
    float sd_pred = hypot_safe(s.sd, sd_d);
    float reg = hypot_safe(sd_pred, sqrt(META_ALPHA_REG));
    float gain = max(inverse_variance_weight(reg, rms_f), 1.0 / (1.0 + s.n_eff));
    float pred = sat(s.mean + df);
    float half_diff = 0.5 * f - 0.5 * pred;
    float mean = sat(pred + gain * half_diff + gain * half_diff);
    float sd = hypot_safe((1.0 - gain) * sd_pred, gain * rms_f);

    float step = sat(-p.lr * (mean / (sd + p.eps)));
    theta = min(max(sat(theta + step), p.lo), p.hi);
    s = MetaElem(mean, sd, rms_f, rms_d, wsum_d, 1.0 / gain);
    return true;
}

#endif
