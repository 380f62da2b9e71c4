#version 460
// majorant: a scattering medium's majorant grid from its optimised density, before every
// pass that tracks it (lib/media.glsl), in two stages.
// Stage 0, one thread per cell: factor × the largest density that a lookup in the cell
// weighs, in θ's slot and, where a pass binds two states, in the previous θ's (the
// finite-difference kernels track both against one majorant), written over the first
// word of the cell's texel in the medium's buffer. The voxels a cell weighs are those of
// src/render/features/media.rs's cell_voxels, in the same integers.
// Stage 1, one workgroup: the largest cell, written as the record's majorant, and whether
// the kernels walk the grid (the record's majorant_cells: the packed cells, or 0 to track
// against that largest cell over the whole box), as media.rs's walks_grid decides.
layout(local_size_x = 64) in;
#include "lib/common.glsl"
layout(set = 0, binding = 0, scalar) readonly buffer Theta { float theta[]; };
layout(set = 0, binding = 1, scalar) readonly buffer ThetaPrev { float theta_prev[]; };
layout(set = 0, binding = 2, scalar) buffer Record { uint record[]; };
layout(push_constant, scalar) uniform Push {
    uint offset;      // the density's first element in θ
    uvec3 dims;       // its voxels per axis
    uvec3 cells;      // the majorant grid's cells per axis
    uint grid_word;   // the grid's first word in the medium's buffer
    uint record_word; // the record's majorant word (majorant_cells follows it)
    float factor;     // the margin times the medium's scale
    float walk_cost;  // what walking the grid costs per unit length, in tentative collisions
    uint stage;
    uint states;      // 2 where the previous θ is another buffer than θ
} pc;
shared float most[64];
shared float total[64];

// The first and last voxel along one axis of n that a lookup in cell c of `cells` weighs.
ivec2 cell_voxels(int c, int cells, int n) {
    int lo = max((2 * c * n - cells) / (2 * cells), 0);
    int hi = min((2 * (c + 1) * n - cells) / (2 * cells) + 1, n - 1);
    return ivec2(lo, hi);
}

void main() {
    uint count = pc.cells.x * pc.cells.y * pc.cells.z;
    if (pc.stage == 1u) {
        uint t = gl_LocalInvocationID.x;
        float m = 0.0, sum = 0.0;
        for (uint j = t; j < count; j += 64u) {
            float v = uintBitsToFloat(record[pc.grid_word + 4u * j]);
            m = max(m, v);
            sum += v;
        }
        most[t] = m;
        total[t] = sum;
        barrier();
        for (uint s = 32u; s > 0u; s >>= 1) {
            if (t < s) {
                most[t] = max(most[t], most[t + s]);
                total[t] += total[t + s];
            }
            barrier();
        }
        if (t == 0u) {
            bool walk = most[0] - total[0] / float(count) >= pc.walk_cost;
            record[pc.record_word] = floatBitsToUint(most[0]);
            record[pc.record_word + 1u] = walk ? pc.cells.x | pc.cells.y << 10 | pc.cells.z << 20 : 0u;
        }
        return;
    }
    uint j = thread_index();
    if (j >= count) return;
    ivec3 c = ivec3(j % pc.cells.x, (j / pc.cells.x) % pc.cells.y, j / (pc.cells.x * pc.cells.y));
    ivec3 n = ivec3(pc.dims);
    ivec3 k = ivec3(pc.cells);
    ivec2 x = cell_voxels(c.x, k.x, n.x);
    ivec2 y = cell_voxels(c.y, k.y, n.y);
    ivec2 z = cell_voxels(c.z, k.z, n.z);
    float m = 0.0;
    for (int vz = z.x; vz <= z.y; ++vz) {
        for (int vy = y.x; vy <= y.y; ++vy) {
            uint row = pc.offset + uint((vz * n.y + vy) * n.x);
            for (int vx = x.x; vx <= x.y; ++vx) m = max(m, theta[row + uint(vx)]);
            if (pc.states == 2u) {
                for (int vx = x.x; vx <= x.y; ++vx) m = max(m, theta_prev[row + uint(vx)]);
            }
        }
    }
    record[pc.grid_word + 4u * j] = floatBitsToUint(pc.factor * m);
}
