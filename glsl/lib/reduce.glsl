// Workgroup sum: subgroup reduction, then one value per subgroup through shared memory,
// then a subgroup reduction of those. Works for any subgroup size (lavapipe's is 8,
// NVIDIA's 32, AMD's 32/64), so nothing here assumes one. Every invocation of the
// workgroup must call it (it contains barriers); out-of-range threads pass 0.
#ifndef REDUCE_GLSL
#define REDUCE_GLSL
#include "lib/common.glsl"

// Enough slots for a 1024-thread workgroup with subgroups as small as 4.
shared float reduce_scratch[256];

float workgroup_sum(float v) {
    float s = subgroupAdd(v);
    if (subgroupElect()) reduce_scratch[gl_SubgroupID] = s;
    barrier();
    float total = 0.0;
    if (gl_SubgroupID == 0) {
        for (uint i = gl_SubgroupInvocationID; i < gl_NumSubgroups; i += gl_SubgroupSize)
            total += reduce_scratch[i];
        total = subgroupAdd(total);
    }
    // Scratch may be reused by a following call.
    barrier();
    return total;  // valid in subgroup 0 only
}
#endif
