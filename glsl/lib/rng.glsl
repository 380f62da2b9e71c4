// Counter-based random numbers: every number is a hash of (pixel, sample, seed, index).
//
// THE REPLAY INVARIANT. A path is a pure function of its (pixel, sample index, seed) and
// of the parameters. The adjoint pass and the finite-difference pass re-trace paths
// instead of storing them (path replay backpropagation, Vicini et al. 2021), so a
// replayed path must draw exactly the same numbers in exactly the same order as the
// primal one: every branch that draws in one pass draws the same count in the other,
// and nothing draws a data-dependent number of values. Each path vertex therefore takes
// a fixed block of RNG_DIMS_PER_BOUNCE numbers starting at a fixed index, whether it
// uses them or not, so even a divergent replay re-synchronises at the next vertex.
//
// Hash: pcg4d (Jarzynski and Olano, "Hash Functions for GPU Rendering", JCGT 2020).
//
// INDEPENDENT STREAMS. The passes of an iteration draw from streams that differ only in
// the seed (the host adds offsets such as 0x10000000 and 0x20000000, and the iteration
// counter times the golden ratio), and the l2 gradient is unbiased only if the adjoint's
// paths are independent of the primal image its residual comes from. pcg4d's rounds
// (multiply-add, one xorshift) carry a difference between two keys only towards higher
// bits, so seeds that differ in their high bits alone gave dependent streams: the
// numbers of the primal and adjoint streams at the same (pixel, sample, index) fell
// together in the outer 1 % of [0, 1) 1.4 times as often as independent numbers would,
// which biased the adjoint upwards wherever rare paths carry the image (the narrow-gap
// scene, scenes/gap). The seed is therefore hashed before it enters the key, with a
// full-avalanche hash, so that any two distinct seeds differ in about half of the key's
// bits.
#ifndef RNG_GLSL
#define RNG_GLSL

// Path vertices use all eight: light sample (3), BSDF sample (3), Russian roulette (1) and
// the light-sampling strategy (1), in that order (lib/integrator.glsl).
#define RNG_DIMS_PER_BOUNCE 8u

struct Rng {
    uvec3 key;   // pixel, sample, seed
    uint index;  // next dimension
};

uvec4 pcg4d(uvec4 v) {
    v = v * 1664525u + 1013904223u;
    v.x += v.y * v.w; v.y += v.z * v.x; v.z += v.x * v.y; v.w += v.y * v.z;
    v ^= v >> 16u;
    v.x += v.y * v.w; v.y += v.z * v.x; v.z += v.x * v.y; v.w += v.y * v.z;
    return v;
}

// A 32-bit hash in which every input bit flips every output bit with probability close
// to 1/2: "lowbias32" (C. Wellons, hash-prospector, 2018).
uint rng_hash_seed(uint x) {
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

// The seed of a pass's samples in iteration `frame`: the pass's seed, moved by the
// golden-ratio increment per iteration so that iterations spread over the seed space.
uint rng_pass_seed(uint pass_seed, uint frame) {
    return pass_seed + frame * 0x9E3779B9u;
}

Rng rng_init(uint pixel, uint sample_index, uint seed) {
    return Rng(uvec3(pixel, sample_index, rng_hash_seed(seed)), 0u);
}

// Moves to the start of the block of path vertex `bounce` (camera sample = block 0).
void rng_seek_bounce(inout Rng rng, uint bounce) {
    rng.index = bounce * RNG_DIMS_PER_BOUNCE;
}

// A float in [0, 1): the top 24 bits, so 1.0 is never returned.
float rng_next(inout Rng rng) {
    uint bits = pcg4d(uvec4(rng.key, rng.index)).x;
    rng.index += 1u;
    return float(bits >> 8u) * (1.0 / 16777216.0);
}

vec2 rng_next2(inout Rng rng) { return vec2(rng_next(rng), rng_next(rng)); }
vec3 rng_next3(inout Rng rng) { return vec3(rng_next(rng), rng_next(rng), rng_next(rng)); }
#endif
