#version 460
// trace_primal: renders `spp` samples per pixel of one sensor and adds their mean times
// `weight` to accum (so that a render split into several submissions sums correctly).
// trace_adjoint (ADJOINT): replays every sample twice, once for its radiance and once to
// scatter dLoss/dPixel into the parameter gradients; adds the mean of the first replays'
// radiance to accum, a render of θ at the pass's spp with the pass's own random numbers
// (the meta-estimator's carried image takes it in: src/engine.rs, glsl/carry_adjoint.comp).
// trace_fd_primal (FD): renders the same samples in both parameter states (θ_i into
// accum, θ_{i-1} into accum_prev), paths sampled with θ_i.
// trace_fd_adjoint (FD, ADJOINT): the gradient at θ_i minus the gradient at θ_{i-1}
// along the same paths, scattered into grad.
// variant: trace_adjoint ADJOINT
// variant: trace_fd_primal FD
// variant: trace_fd_adjoint FD ADJOINT
// trace_primal_count (COUNT_RAYS) counts the rays it casts and trace_primal_generic
// (GENERIC) reads the integrator's limits at run time: both for `vkinverse bench`.
// variant: trace_primal_count COUNT_RAYS
// variant: trace_primal_generic GENERIC
// trace_primal_sampled (TEXELS_SAMPLED) reads the scene's texel buffers by texel fetches
// instead of image loads (lib/texels.glsl), the same bits: for `vkinverse bench`.
// variant: trace_primal_sampled TEXELS_SAMPLED
// Each has a copy for the wide BVH layout (BVH_WIDE, lib/bvh_traverse.glsl), named with
// the suffix _wide, and one for the compressed layout (BVH_CW8), suffix _cw8
// (vkinverse::bvh::BvhLayout::kernel).
// variant: trace_primal_wide BVH_WIDE
// variant: trace_adjoint_wide ADJOINT BVH_WIDE
// variant: trace_fd_primal_wide FD BVH_WIDE
// variant: trace_fd_adjoint_wide FD ADJOINT BVH_WIDE
// variant: trace_primal_count_wide COUNT_RAYS BVH_WIDE
// variant: trace_primal_generic_wide GENERIC BVH_WIDE
// variant: trace_primal_sampled_wide TEXELS_SAMPLED BVH_WIDE
// variant: trace_primal_cw8 BVH_CW8
// variant: trace_adjoint_cw8 ADJOINT BVH_CW8
// variant: trace_fd_primal_cw8 FD BVH_CW8
// variant: trace_fd_adjoint_cw8 FD ADJOINT BVH_CW8
// variant: trace_primal_count_cw8 COUNT_RAYS BVH_CW8
// variant: trace_primal_generic_cw8 GENERIC BVH_CW8
// variant: trace_primal_sampled_cw8 TEXELS_SAMPLED BVH_CW8
// The four passes of a scene whose medium scatters (SCATTERING, lib/media.glsl), and the
// bench's three builds of trace_primal, for the compressed layout only
// (vkinverse::render::GpuScene::kernel).
// variant: trace_primal_scatter_cw8 SCATTERING BVH_CW8
// variant: trace_adjoint_scatter_cw8 ADJOINT SCATTERING BVH_CW8
// variant: trace_fd_primal_scatter_cw8 FD SCATTERING BVH_CW8
// variant: trace_fd_adjoint_scatter_cw8 FD ADJOINT SCATTERING BVH_CW8
// variant: trace_primal_count_scatter_cw8 COUNT_RAYS SCATTERING BVH_CW8
// variant: trace_primal_generic_scatter_cw8 GENERIC SCATTERING BVH_CW8
// variant: trace_primal_sampled_scatter_cw8 TEXELS_SAMPLED SCATTERING BVH_CW8
layout(local_size_x = 64, local_size_x_id = 0) in;
#include "lib/common.glsl"
#include "lib/integrator.glsl"

#ifdef ADJOINT
layout(set = 0, binding = 1, scalar) readonly buffer AdjointImage { vec3 adjoint_image[]; };
#ifdef FD
layout(set = 0, binding = 4, scalar) readonly buffer AdjointImagePrev { vec3 adjoint_image_prev[]; };
#else
layout(set = 0, binding = 0, scalar) buffer Accum { vec3 accum[]; };
#endif
#else
layout(set = 0, binding = 0, scalar) buffer Accum { vec3 accum[]; };
#ifdef FD
layout(set = 0, binding = 3, scalar) buffer AccumPrev { vec3 accum_prev[]; };
#endif
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
    uint stride;       // trace every stride-th pixel of each row (1: all) ...
    uint phase;        // ... from column (row + iteration + phase) mod stride: a moving checkerboard
} pc;

void main() {
    // One invocation per traced pixel: ceil(width / stride) of each row.
    uint stride = max(pc.stride, 1u);
    uint per_row = (pc.width + stride - 1u) / stride;
    uint t = thread_index();
    if (t >= per_row * pc.height) return;
    uint y = t / per_row;
    uint x = (t % per_row) * stride + (y + frame_iteration + pc.phase) % stride;
    if (x >= pc.width) return;
    // The pixel's index in every image: its random numbers and half do not depend on stride.
    uint i = y * pc.width + x;
    uvec2 pixel = uvec2(x, y);
    SensorRecord s = sensor_record(pc.sensor);
    vec3 zero[NSTATES];
    vec3 delta[NSTATES];
    for (int k = 0; k < NSTATES; ++k) zero[k] = vec3(0.0);
#ifdef ADJOINT
    delta[0] = adjoint_image[i] * pc.weight;
#ifdef FD
    delta[1] = adjoint_image_prev[i] * pc.weight;
#endif
    bool any_delta = false;
    for (int k = 0; k < NSTATES; ++k) any_delta = any_delta || any(notEqual(delta[k], vec3(0.0)));
#ifdef FD
    if (!any_delta) return;
#endif
    // (trace_adjoint renders every pixel: a pixel without gradient still adds its radiance.)
    grad_init();
#endif
    vec3 sum[NSTATES];
    for (int k = 0; k < NSTATES; ++k) sum[k] = vec3(0.0);
#ifdef ADJOINT
    // SPLIT (lib/scene_access.glsl): a random half of the pixels, drawn per iteration from a
    // hash of (pixel, seed, iteration). Whole pixels, not samples: a pixel's adjoint weight
    // comes from its primal image, which all of its samples share, so only halves of the
    // pixels are independent estimates.
    grad_in_half = (pcg4d(uvec4(i, pc.seed, frame_iteration, 0x4841u)).x & 1u) == 1u;
#endif
    for (uint k = 0u; k < pc.spp; ++k) {
        Rng rng = rng_init(i, pc.first_sample + k, rng_pass_seed(pc.seed, frame_iteration));
        vec3 o, d;
        camera_ray(s, pixel, uvec2(pc.width, pc.height), rng, o, d);
        vec3 radiance[NSTATES];
#ifdef ADJOINT
        Rng replay = rng;
        trace_path(rng, o, d, zero, zero, false, radiance);
        vec3 unused[NSTATES];
        if (any_delta) trace_path(replay, o, d, radiance, delta, true, unused);
        sum[0] += radiance[0];
#else
        trace_path(rng, o, d, zero, zero, false, radiance);
        for (int j = 0; j < NSTATES; ++j) sum[j] += radiance[j];
#endif
    }
#ifdef ADJOINT
    grad_flush();
#ifndef FD
    // pc.weight is the gradient's 1 / spp (stride 1: every pixel traced).
    accum[i] += pc.weight * sum[0];
#endif
#else
    accum[i] += pc.weight * sum[0];
#ifdef FD
    accum_prev[i] += pc.weight * sum[1];
#endif
#endif
}
