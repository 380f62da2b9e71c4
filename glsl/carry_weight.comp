#version 460
// carry_weight: one workgroup per sensor. Sums carry_stats' partials and chooses the fresh
// image's weight w of this iteration's carry (carry_image.comp), tracking the carried
// image's variance. All variances are per pixel and channel:
//   v_fresh = Σ|fresh − cur|² / (3n) · fresh_share   the fresh render's (fresh_share =
//             s_fd / (s_fd + s_primal): both renders sample alike, at s_primal and s_fd spp);
//   v_diff  = Σ|cur − prev|² / (3n)                   a bound on what the difference adds;
//   v_carried                                         the carried image's, tracked:
//             v ← w² v_fresh + (1 − w)² (v + v_diff).
// The weight: w = 1 at the first carry (count 0); then
//   fixed     w = max(1/(k + 1), w_min)     (the running mean, then an EMA);
//   variance  w = max(p / (p + v_fresh), w_min), p = v_carried + v_diff: the inverse-variance
//             weight of the fresh image against the carried one. With v_diff = 0 it is the
//             running mean's 1/(k + 1); a large step (large v_diff) gives the fresh render
//             most of the weight, a small one lets the carried image average more iterations.
// With the adjoint pass's render taken in (adjoint_ratio > 0; glsl/carry_adjoint.comp, after
// the adjoint pass), its weight u is chosen here too: that render of θ_i, at s_adjoint spp
// with its own random numbers, is independent of the carried image, so
//   v_adjoint = v_fresh · s_primal / s_adjoint,   u = max(v / (v + v_adjoint), u_min),
//   v ← (1 − u)² v + u² v_adjoint                 (with v the carried image's after the carry).
// state = (w, v_carried after this iteration's mixes, v_fresh, v_diff, u): the diagnostics
// read it.
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/reduce.glsl"
layout(set = 0, binding = 0, scalar) readonly buffer Partials { float partials[]; };
layout(set = 0, binding = 1, scalar) readonly buffer Count { float count; };
layout(set = 0, binding = 2, scalar) buffer State { float state[5]; };
layout(push_constant, scalar) uniform Push {
    uint groups;        // carry_stats' workgroups (two partials each)
    float scale;        // 1 / (3 n)
    float fresh_share;  // s_fd / (s_fd + s_primal)
    float w_min;        // the fresh image's least weight
    uint variance;      // 1: inverse-variance weights; 0: fixed
    float adjoint_ratio; // s_primal / s_adjoint; 0: no adjoint render
    float u_min;        // the adjoint render's least weight
} pc;

void main() {
    float a = 0.0;
    float b = 0.0;
    for (uint g = gl_LocalInvocationID.x; g < pc.groups; g += gl_WorkGroupSize.x) {
        a += partials[2u * g];
        b += partials[2u * g + 1u];
    }
    float sa = workgroup_sum(a);
    float sb = workgroup_sum(b);
    if (gl_LocalInvocationID.x != 0u) return;
    float v_fresh = sa * pc.scale * pc.fresh_share;
    float v_diff = sb * pc.scale;
    float v = state[1];
    float k = count;
    float w;
    if (k <= 0.0) {
        w = 1.0;
    } else if (pc.variance != 0u) {
        float p = v + v_diff;
        w = p / (p + v_fresh);
        // Renders with no noise (0 / 0), or with a non-finite pixel, take the fresh image
        // (tested before the floor: max() may drop a NaN operand).
        w = w >= 0.0 && w <= 1.0 ? max(w, pc.w_min) : 1.0;
    } else {
        w = max(1.0 / (k + 1.0), pc.w_min);
    }
    float v_next = w * w * v_fresh + (1.0 - w) * (1.0 - w) * (v + v_diff);
    // A non-finite estimate restarts the tracking from the fresh image's variance.
    if (isnan(v_next) || isinf(v_next)) v_next = isnan(v_fresh) || isinf(v_fresh) ? 0.0 : v_fresh;
    float u = 0.0;
    if (pc.adjoint_ratio > 0.0) {
        float v_adjoint = v_fresh * pc.adjoint_ratio;
        u = v_next / (v_next + v_adjoint);
        // Noiseless renders (0 / 0) or a non-finite estimate: the carried image as it is.
        u = u >= 0.0 && u <= 1.0 ? max(u, pc.u_min) : 0.0;
        v_next = (1.0 - u) * (1.0 - u) * v_next + u * u * v_adjoint;
    }
    state[0] = w;
    state[1] = v_next;
    state[2] = v_fresh;
    state[3] = v_diff;
    state[4] = u;
}
