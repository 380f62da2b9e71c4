#version 460
// trace_primal: renders `spp` samples per pixel of one sensor and adds their mean times
// `weight` to accum (so that a render split into several submissions sums correctly).
// trace_adjoint (same source, ADJOINT): replays every sample twice, once for its
// radiance and once to scatter dLoss/dPixel into the parameter gradients.
// variant: trace_adjoint ADJOINT
// trace_primal_count (COUNT_RAYS) counts the rays it casts and trace_primal_generic
// (GENERIC) reads the integrator's limits at run time: both for `vkinverse bench`.
// variant: trace_primal_count COUNT_RAYS
// variant: trace_primal_generic GENERIC
layout(local_size_x = 64, local_size_x_id = 0) in;
#include "lib/common.glsl"
#include "lib/integrator.glsl"

#ifdef ADJOINT
layout(set = 0, binding = 1, scalar) readonly buffer AdjointImage { vec3 adjoint_image[]; };
#else
layout(set = 0, binding = 0, scalar) buffer Accum { vec3 accum[]; };
#endif

// Iteration counter written by the host before each submission, so that a recording
// that is resubmitted every iteration still draws fresh samples.
layout(set = 0, binding = 2, scalar) readonly buffer Frame { uint frame_iteration; };

layout(push_constant, scalar) uniform Push {
    uint width;
    uint height;
    uint sensor;
    uint spp;          // samples per pixel in this dispatch
    uint first_sample; // index of the first of them (for the RNG)
    uint seed;         // combined with frame_iteration
    float weight;      // primal: added value = weight * sum of samples; adjoint: delta scale
} pc;

void main() {
    uint i = thread_index();
    if (i >= pc.width * pc.height) return;
    uvec2 pixel = uvec2(i % pc.width, i / pc.width);
    SensorRecord s = sensors[pc.sensor];
#ifdef ADJOINT
    vec3 delta = adjoint_image[i] * pc.weight;
    if (all(equal(delta, vec3(0.0)))) return;
#endif
    vec3 sum = vec3(0.0);
    for (uint k = 0u; k < pc.spp; ++k) {
        // 0x9E3779B9: the golden-ratio increment spreads iterations over the seed space.
        Rng rng = rng_init(i, pc.first_sample + k, pc.seed + frame_iteration * 0x9E3779B9u);
        vec3 o, d;
        camera_ray(s, pixel, uvec2(pc.width, pc.height), rng, o, d);
#ifdef ADJOINT
        Rng replay = rng;
        vec3 L = trace_path(rng, o, d, vec3(0.0), vec3(0.0));
        trace_path(replay, o, d, L, delta);
#else
        sum += trace_path(rng, o, d, vec3(0.0), vec3(0.0));
#endif
    }
#ifndef ADJOINT
    accum[i] += pc.weight * sum;
#endif
}
