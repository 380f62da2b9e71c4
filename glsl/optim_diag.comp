#version 460
// optim_diag: merges the per-workgroup diagnostics records of one parameter group (written by
// optim_adam / optim_meta) into diag[group], one workgroup per group. The meta pass of the
// next iteration reads the group's |dpi|^2 from it (the total of its squared steps) and the
// host reads it for optimiser.csv.

layout(local_size_x = 256) in;
#include "lib/common.glsl"
#include "lib/optim_reduce.glsl"

layout(set = 0, binding = 0, scalar) readonly buffer DiagPartial { DiagRecord partials[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer Diag { DiagRecord diag[]; };

layout(push_constant, scalar) uniform Push {
    uint first;  // the group's first record in partials
    uint count;  // its number of records
    uint group;  // its slot in diag
} pc;

void main() {
    DiagRecord acc = diag_empty();
    for (uint k = gl_LocalInvocationID.x; k < pc.count; k += gl_WorkGroupSize.x)
        acc = diag_merge(acc, partials[pc.first + k]);
    acc = diag_workgroup(acc);
    if (gl_LocalInvocationID.x == 0u) diag[pc.group] = acc;
}
