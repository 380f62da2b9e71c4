#version 460
// carry_adjoint: after the adjoint pass of ⟨F⟩, mixes its render of θ_i (the mean radiance
// of its primal replays, glsl/trace_primal.comp ADJOINT) into the carried primal image with
// the weight u that carry_weight.comp chose for this sensor (meta `carry_adjoint`,
// src/engine.rs). Per pixel:
//   carried = (1 − u) carried + u adjoint.
// The losses of this iteration have read the carried image already; the next carry moves
// the mixed image to θ_{i+1}. The adjoint render's random numbers are its own, and no later
// pass that reads the carried image traces with them, so its noise is independent of every
// path it weighs later (though not of the step this iteration's gradient, from the same
// paths, takes). A non-finite adjoint pixel is not taken in.
layout(local_size_x = 256, local_size_x_id = 0) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) buffer Carried { vec3 carried[]; };
layout(set = 0, binding = 1, scalar) readonly buffer Adjoint { vec3 adjoint[]; };
layout(set = 0, binding = 2, scalar) readonly buffer State { float state[5]; };
layout(push_constant, scalar) uniform Push { uint n; } pc;
void main() {
    uint i = thread_index();
    if (i >= pc.n) return;
    float u = state[4];
    vec3 a = adjoint[i];
    if (u > 0.0 && !any(isnan(a)) && !any(isinf(a))) carried[i] = mix(carried[i], a, u);
}
