// Common prologue of every kernel. Kernels declare their workgroup size *before*
// including this file: until that declaration gl_WorkGroupSize is the constant (1, 1, 1),
// and functions compiled earlier would use it.
// the extensions the host checks for at device creation
// (scalar block layout, subgroup arithmetic) and small helpers.
#ifndef COMMON_GLSL
#define COMMON_GLSL
#extension GL_EXT_scalar_block_layout : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require

// Linear workgroup index of a 1-D dispatch; the host folds more than 65535 workgroups
// into the y axis (Recorder::dispatch_linear), so x alone is not enough.
uint workgroup_index() { return gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x; }

// Linear thread index of a 1-D dispatch.
uint thread_index() { return workgroup_index() * gl_WorkGroupSize.x + gl_LocalInvocationID.x; }
#endif
