#version 460
// carry_image: the meta-estimator's primal image, carried from θ_{i-1} to θ_i by the
// finite-difference sample's two images and mixed with the fresh primal image (meta
// `carry`, src/engine.rs). Per pixel:
//   carried = fresh                                          on the first carry,
//   carried = w fresh + (1 − w) (carried + cur − prev)       after it,
// with the weight w that carry_weight.comp chose for this sensor (1 at the first carry; then
// the running mean's 1/(k + 1) down to a least weight, or the inverse-variance weight).
// cur − prev is the difference of the finite-difference sample's images of θ_i and
// θ_{i-1} with common random numbers, an unbiased estimate of E[I(θ_i)] − E[I(θ_{i-1})], so
// `carried` is an unbiased estimate of E[I(θ_i)] with the variance of many iterations' primal
// samples. The images the losses read are then replaced: fresh by carried (the adjoint image
// of ⟨F⟩), cur by carried and prev by carried − (cur − prev) (the adjoint images of the
// finite-difference sample's two states, whose difference is unchanged).
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) buffer Fresh { vec3 fresh[]; };
layout(set = 0, binding = 1, scalar) buffer Cur { vec3 cur[]; };
layout(set = 0, binding = 2, scalar) buffer Prev { vec3 prev[]; };
layout(set = 0, binding = 3, scalar) buffer Carried { vec3 carried[]; };
layout(set = 0, binding = 4, scalar) readonly buffer State { float w; };
layout(push_constant, scalar) uniform Push { uint n; } pc;

void main() {
    uint i = thread_index();
    if (i >= pc.n) return;
    vec3 diff = cur[i] - prev[i];
    vec3 c = fresh[i];
    // w = 1 on the first carry: the carried image (zeros, or a checkpoint's) is not read.
    // A non-finite carried pixel (from an earlier render's NaN or overflow) restarts from
    // the fresh one instead of staying non-finite for good.
    vec3 moved = carried[i] + diff;
    if (w < 1.0 && !any(isnan(moved)) && !any(isinf(moved))) c = w * fresh[i] + (1.0 - w) * moved;
    carried[i] = c;
    fresh[i] = c;
    cur[i] = c;
    prev[i] = c - diff;
}
