#version 460
// rng_test: the numbers a trace kernel draws for pixel i, so that tests/rng.rs can check
// the streams of different passes and iterations for independence. Thread i writes the
// first `dims` numbers from path vertex 1 on (the blocks of vertices 1, 2, ...) of key (pixel i,
// sample `sample_index`, rng_pass_seed(seed, frame)), as trace_primal.comp seeds them.
layout(local_size_x = 64, local_size_x_id = 0) in;
#include "lib/common.glsl"
#include "lib/rng.glsl"

layout(set = 0, binding = 0, scalar) writeonly buffer Numbers { float numbers[]; };
layout(push_constant, scalar) uniform Push {
    uint n;             // threads (pixels)
    uint sample_index;
    uint seed;          // the pass's seed
    uint frame;         // the iteration counter
    uint dims;          // numbers per thread
} pc;

void main() {
    uint i = thread_index();
    if (i >= pc.n) return;
    Rng rng = rng_init(i, pc.sample_index, rng_pass_seed(pc.seed, pc.frame));
    rng_seek_bounce(rng, 1u);
    for (uint d = 0u; d < pc.dims; ++d) numbers[i * pc.dims + d] = rng_next(rng);
}
