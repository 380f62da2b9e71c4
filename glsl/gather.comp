#version 460
// gather: every thread reads ROUNDS float4 elements of a table at scattered (hashed)
// indices, each depending on the last, and writes their sum: the access pattern of BVH
// node and triangle fetches by incoherent rays. The bench times it against gather_texel,
// which reads the same table as a texel buffer, to show what each fetch costs a device.
// variant: gather_texel TEXEL
layout(local_size_x = 64, local_size_x_id = 0) in;
#include "lib/common.glsl"
#ifdef TEXEL
layout(set = 0, binding = 0) uniform samplerBuffer table_texels;
#else
layout(set = 0, binding = 0, scalar) readonly buffer Table { vec4 table[]; };
#endif
layout(set = 0, binding = 1, scalar) writeonly buffer Sums { vec4 sums[]; };
layout(push_constant, scalar) uniform Push {
    uint threads;
    uint table_len;  // a power of two
    uint rounds;
} pc;

void main() {
    uint i = thread_index();
    if (i >= pc.threads) return;
    vec4 sum = vec4(0.0);
    uint k = i * 0x9E3779B9u;
    for (uint r = 0u; r < pc.rounds; ++r) {
        // Murmur3's finaliser: neighbouring threads read unrelated elements.
        k ^= k >> 16u;
        k *= 0x85EBCA6Bu;
        k ^= k >> 13u;
        uint index = k & (pc.table_len - 1u);
#ifdef TEXEL
        vec4 v = texelFetch(table_texels, int(index));
#else
        vec4 v = table[index];
#endif
        sum += v;
        // The next index depends on the value read, as a traversal's does.
        k += floatBitsToUint(v.x);
    }
    sums[i] = sum;
}
