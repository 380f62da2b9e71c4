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
//  - a non-finite F or dF leaves theta and the element's state unchanged (returns false; the
//    pass zeroes the element's last step, since it took none);
//  - results that can leave the f32 range saturate at +-FLT_MAX;
//  - diagnostics are reduced as counts, sums, minima, maxima and scaled sums of squares
//    (Ssq, glsl/shared/optim.glsl), never as plain squares.
//
// Variants of the meta-estimator (src/optim/mod.rs): the step rule (STEP_*), the centred
// variance estimate from half-sample sums, the dF variance model, and the learning-rate
// schedule (SCHEDULE_*), a pure function of the step number.
//
// STEP_NEWTON's curvature is the RMS of the secants dF/dpi of the element's own steps,
// weighted by dpi^2 (a fit of dF = h dpi); it is kept as its root and the root of its
// weight sum, updated as a convex combination, and the secant saturates, so that neither a
// tiny step nor a huge dF leaves f32.

#ifndef OPTIM_GLSL
#define OPTIM_GLSL
#include "shared/optim.glsl"

const float FLT_MAX = 3.40282347e38;
const float PI = 3.14159265358979;

#include "vkinverse_constants.glsl"  // STEP_*, SCHEDULE_*
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

// An RMS EMA's weights at step t, uniform over a pass (computed once per invocation): the
// step's weight k = ema_weight(beta, t) as the factors of hypot(keep * rms, take * x),
// keep = sqrt(1 - k) and take = sqrt(k).
struct Ema {
    float keep;
    float take;
};

Ema ema_of(float beta, uint t) {
    float k = ema_weight(beta, t);
    return Ema(sqrt(1.0 - k), sqrt(k));
}

// s_a^2 / (s_a^2 + s_b^2) from standard deviations, scaled by the larger; s_a or s_b > 0.
float inverse_variance_weight(float s_a, float s_b) {
    float big = max(s_a, s_b);
    float a = s_a / big;
    float b = s_b / big;
    return a * a / (a * a + b * b);
}

// ---- Learning-rate schedule (src/optim/schedule.rs) ---------------------------------------

struct Schedule {
    uint decay;    // SCHEDULE_*
    uint warmup;   // iterations of the linear warm-up (0: none)
    uint horizon;  // cosine: where the factor reaches floor_ (0: no decay)
    uint every;    // step: iterations between decays
    float floor_;  // cosine: final factor
    float gamma;   // step: factor per decay
};

// The learning rate's factor at step t (t >= 1).
float schedule_factor(Schedule s, uint t) {
    float warm = t < s.warmup ? float(t) / float(s.warmup) : 1.0;
    float d = 1.0;
    if (s.decay == SCHEDULE_COSINE && s.horizon > 0u) {
        float x = float(min(t, s.horizon)) / float(s.horizon);
        d = s.floor_ + (1.0 - s.floor_) * 0.5 * (1.0 + cos(PI * x));
    } else if (s.decay == SCHEDULE_STEP) {
        d = pow(s.gamma, float(t / max(s.every, 1u)));
    }
    return warm * d;
}

// ---- Diagnostics ---------------------------------------------------------------------------

Ssq ssq_of(float x) {
    float a = abs(x);
    return a == 0.0 ? Ssq(0.0, 0.0) : Ssq(a, 1.0);
}

Ssq ssq_merge(Ssq a, Ssq b) {
    float m = max(a.scale, b.scale);
    if (m == 0.0) return Ssq(0.0, 0.0);
    float ra = a.scale / m;
    float rb = b.scale / m;
    return Ssq(m, a.sum * (ra * ra) + b.sum * (rb * rb));
}

// The sum of squares (saturating).
float ssq_total(Ssq a) { return sat(a.scale * a.scale * a.sum); }

// The empty record: the identity of diag_merge.
DiagRecord diag_empty() {
    Ssq z = Ssq(0.0, 0.0);
    return DiagRecord(0.0, 0.0, FLT_MAX, 0.0, 0.0, 0.0, z, z, z, z, z, z, z, z);
}

DiagRecord diag_merge(DiagRecord a, DiagRecord b) {
    return DiagRecord(a.count + b.count, sat(a.n_eff_sum + b.n_eff_sum), min(a.n_eff_min, b.n_eff_min),
                      max(a.n_eff_max, b.n_eff_max), a.clipped + b.clipped, a.newton + b.newton, ssq_merge(a.f, b.f),
                      ssq_merge(a.df, b.df), ssq_merge(a.sd_d, b.sd_d), ssq_merge(a.step, b.step),
                      ssq_merge(a.mean, b.mean), ssq_merge(a.sd, b.sd), ssq_merge(a.sd_f, b.sd_f),
                      ssq_merge(a.curv, b.curv));
}

// One element's diagnostics (ElemDiag in src/optim/reference.rs).
struct ElemDiag {
    float n_eff;
    bool clipped;
    bool newton;
    float f;
    float df;
    float sd_d;
    float step;
    float mean;
    float sd;
    float sd_f;
    float curv;
};

// One element's diagnostics folded into a record (one division per sum of squares).
Ssq ssq_add(Ssq a, float x) {
    // First, so that a field a pass leaves at 0 costs nothing.
    if (x == 0.0) return a;
    float m = max(a.scale, abs(x));
    float inv = 1.0 / m;
    float ra = a.scale * inv;
    float rx = abs(x) * inv;
    return Ssq(m, a.sum * (ra * ra) + rx * rx);
}

DiagRecord diag_add(DiagRecord a, ElemDiag e) {
    return DiagRecord(a.count + 1.0, sat(a.n_eff_sum + e.n_eff), min(a.n_eff_min, e.n_eff), max(a.n_eff_max, e.n_eff),
                      a.clipped + (e.clipped ? 1.0 : 0.0), a.newton + (e.newton ? 1.0 : 0.0), ssq_add(a.f, e.f),
                      ssq_add(a.df, e.df), ssq_add(a.sd_d, e.sd_d), ssq_add(a.step, e.step), ssq_add(a.mean, e.mean),
                      ssq_add(a.sd, e.sd), ssq_add(a.sd_f, e.sd_f), ssq_add(a.curv, e.curv));
}

// ---- Adam --------------------------------------------------------------------------------

// Bias-corrected first moment and bias-corrected RMS (sqrt of the second moment).
struct AdamElem {
    float m;
    float r;
};

struct AdamParams {
    float k1;    // the first moment's weight of step t, ema_weight(beta1, t)
    Ema r;       // the RMS's weights of step t (beta2)
    float lr;    // the scheduled rate of step t
    float eps;
    float lo;
    float hi;
};

AdamParams adam_params(uint t, float lr, float beta1, float beta2, float eps, float lo, float hi) {
    return AdamParams(ema_weight(beta1, t), ema_of(beta2, t), lr, eps, lo, hi);
}

// One Adam step of one element. False for a non-finite gradient: nothing is changed.
bool adam_update(AdamParams p, inout float theta, float g, inout AdamElem s, out ElemDiag d) {
    d = ElemDiag(0.0, false, false, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    if (!is_finite(g)) return false;
    float m = (1.0 - p.k1) * s.m + p.k1 * g;
    float r = hypot_safe(p.r.keep * s.r, p.r.take * g);
    float step = sat(-p.lr * (m / (r + p.eps)));
    float next = min(max(sat(theta + step), p.lo), p.hi);
    d = ElemDiag(0.0, false, false, g, 0.0, 0.0, next - theta, m, 0.0, r, 0.0);
    theta = next;
    s = AdamElem(m, r);
    return true;
}

// ---- Meta-estimator ----------------------------------------------------------------------

// All zero initially.
struct MetaElem {
    float mean;   // meta-estimate <F_i>_M
    float sd;     // sqrt(Var[<F_i>_M])
    float rms_f;  // sqrt(Moment2 of <F> or of its centred samples), bias-corrected with t
    float rms_d;  // sqrt(Moment2 of <dF>/|dpi| or of its centred samples), with wsum_d
    float wsum_d; // 1 - decay_d^count of the dF Moment2's own samples
    float n_eff;  // 1/(1 - alpha_prev): effective number of averaged samples
    float v;      // the bias-corrected sqrt(v) of <F> (beta2): the Wiener step's normaliser
    float curv;   // STEP_NEWTON: sqrt(sum w (dF/dpi)^2 / sum w), w = dpi^2, the secant curvature
    float curv_w; // sqrt(sum w), each earlier weight forgotten by decay_h per new sample
    float last;   // the element's last step theta_i - theta_{i-1}: the dpi of the next dF
};

struct MetaParams {
    Ema f;       // the Moment2 of <F>'s weights of step t (decay_f)
    Ema v;       // the Wiener step's normaliser's weights of step t (beta2)
    float lr;    // the scheduled rate of step t
    float decay_d;
    float eps;
    float lo;
    float hi;
    uint step_rule; // STEP_*
    bool centred;   // variance EMAs of centred half-sample differences instead of squares
    bool fd_raw;    // Moment2 of dF itself instead of dF/|dpi| (then times |dpi|^2)
    float keep_h;   // STEP_NEWTON: sqrt of the curvature fit's forgetting per sample
    float sig;      // STEP_NEWTON: significance (in standard deviations) Newton's step needs
    float settle;   // STEP_NEWTON: the Wiener step's fraction of lr where Newton's is smaller
};

// One element's inputs: <F>, <dF> and (centred) the sums of half of their samples.
struct MetaInput {
    float f;
    float df;
    float f_half;
    float df_half;
};

// The centred variance sample of an estimate x from the sum of half of its samples: the
// halves A = 2 half and B = 2 (x - half) give (A - B)/2 = x - 2 half. Saturates.
float centred_sample(float x, float half_sum) { return sat(2.0 * sat(0.5 * x - half_sum)); }

// One meta-estimator step of one element from its inputs and the buffer's |dpi|^2 of the
// previous step. False for a non-finite input: nothing is changed.
bool meta_update(MetaParams p, inout float theta, MetaInput x, float dpi2, inout MetaElem s,
                 out ElemDiag d) {
    d = ElemDiag(0.0, false, false, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    float f = x.f;
    float df = x.df;
    if (!is_finite(f) || !is_finite(df) || (p.centred && !(is_finite(x.f_half) && is_finite(x.df_half))))
        return false;
    // What the two Moment2 EMAs average the squares of.
    float sample_f = p.centred ? centred_sample(f, x.f_half) : f;
    float sample_d = p.centred ? centred_sample(df, x.df_half) : df;
    float rms_f = hypot_safe(p.f.keep * s.rms_f, p.f.take * sample_f);
    float v = hypot_safe(p.v.keep * s.v, p.v.take * f);

    // dF terms: VD = Moment2(dF/|dpi|) * |dpi|^2 (or Moment2(dF) with fd_raw), kept as the
    // standard deviation sd_d.
    float sd_d = 0.0;
    float rms_d = s.rms_d;
    float wsum_d = s.wsum_d;
    if (dpi2 > 0.0 && is_finite(dpi2)) {
        float step_len = p.fd_raw ? 1.0 : sqrt(dpi2);
        float q = 1.0 - p.decay_d;
        wsum_d = q + p.decay_d * s.wsum_d;
        float kd = q / wsum_d;
        sd_d = hypot_safe(sqrt(1.0 - kd) * sat(s.rms_d * step_len), sqrt(kd) * sample_d);
        rms_d = sat(sd_d / step_len);
    } else {
        df = 0.0;
    }

    // mean += dF; var += VD; alpha by inverse-variance weighting, clipped to perfect averaging.
    // Written with the gain g = 1 - alpha (the weight of the fresh sample), which f32 keeps
    // accurate as alpha -> 1, and the update h + g*(F - h) on halves, which cannot overflow.
    float sd_pred = hypot_safe(s.sd, sd_d);
    float reg = hypot_safe(sd_pred, sqrt(META_ALPHA_REG));
    float bound = 1.0 / (1.0 + s.n_eff);
    float weighted = inverse_variance_weight(reg, rms_f);
    float gain = max(weighted, bound);
    float pred = sat(s.mean + df);
    float half_diff = 0.5 * f - 0.5 * pred;
    float mean = sat(pred + gain * half_diff + gain * half_diff);
    float sd = hypot_safe((1.0 - gain) * sd_pred, gain * rms_f);

    // The secant curvature along the element's own last step (where dF spans it).
    float curv = s.curv;
    float curv_w = s.curv_w;
    if (dpi2 > 0.0 && is_finite(dpi2) && s.last != 0.0) {
        curv_w = hypot_safe(p.keep_h * s.curv_w, s.last);
        float kw = abs(s.last) / curv_w;
        float k = kw * kw;
        float secant = sat(df / s.last);
        curv = hypot_safe(sqrt(1.0 - k) * curv, sqrt(k) * secant);
    }
    float h = curv;

    float ratio;
    if (p.step_rule == STEP_NEWTON)
        // The Wiener step: the estimate over v, shrunk by its own significance.
        ratio = mean == 0.0 ? 0.0 : (mean / (v + p.eps)) * inverse_variance_weight(abs(mean), sd);
    else ratio = mean / (sd + p.eps);
    float step = sat(-p.lr * ratio);
    bool newton = false;
    float n_eff = 1.0 / gain;
    if (p.step_rule == STEP_NEWTON && h > 0.0) {
        // Newton's step -mean/h shrunk by the positive-part James-Stein factor
        // 1 - (sig sd/mean)^2 (zero unless mean is sig standard deviations from 0), or the
        // Wiener step times settle, whichever is longer, within |step| <= lr.
        float z2;
        if (mean == 0.0) {
            z2 = FLT_MAX;
        } else {
            float z = p.sig * (sd / abs(mean));
            z2 = z >= 1.0 ? 1.0 : z * z;
        }
        float shrink = z2 >= 1.0 ? 0.0 : 1.0 - z2;
        float newton_step = sat(-mean / h) * shrink;
        newton_step = clamp(newton_step, -p.lr, p.lr);
        float settle_step = p.settle * step;
        newton = abs(newton_step) > abs(settle_step);
        step = clamp(newton ? newton_step : settle_step, -p.lr, p.lr);
    }
    float next = min(max(sat(theta + step), p.lo), p.hi);
    float taken = next - theta;
    d = ElemDiag(n_eff, weighted < bound, newton, f, df, sd_d, taken, mean, sd, rms_f, h);
    theta = next;
    s = MetaElem(mean, sd, rms_f, rms_d, wsum_d, n_eff, v, curv, curv_w, taken);
    return true;
}

#endif
