// Scene-geometry structs shared by the host BVH builder (src/bvh/mod.rs) and the kernels.
// Each is mirrored by a #[repr(C)] Pod struct in src/bvh/mod.rs; tests/bvh.rs compares the
// reflected member offsets and sizes with the Rust ones. Scalar block layout: members are
// packed at their scalar alignment, so a vec3 takes 12 bytes.
#ifndef SHARED_BVH_GLSL
#define SHARED_BVH_GLSL

// Entries of the traversal stack in lib/bvh_traverse.glsl. The builder keeps every inner
// node at depth < BVH_STACK_SIZE (root at depth 0), which bounds the stack; tests/bvh.rs
// checks that this value equals vkinverse::bvh::STACK_SIZE.
#define BVH_STACK_SIZE 64

// Entries of the traversal stack of the wide layout (BVH_WIDE): a wide node pushes at
// most 3 of its 4 children, and wide inner nodes are at depth <= BVH_STACK_SIZE / 2 (see
// BvhWideNode), so at most 3 entries for each of the BVH_STACK_SIZE / 2 levels that can
// push; tests/bvh.rs checks that this value equals vkinverse::bvh::WIDE_STACK_SIZE.
#define BVH_WIDE_STACK_SIZE 96

// Entries of the traversal stack of the compressed layout (BVH_CW8): one node group per
// level, and the builder keeps inner nodes at depth <= BVH_CW_STACK_SIZE (see BvhCwNode);
// tests/bvh.rs checks that this value equals vkinverse::bvh::CW_STACK_SIZE.
#define BVH_CW_STACK_SIZE 32

// Entries of the compressed layout's register stack (BVH_STACK_REGISTERS in
// lib/bvh_traverse.glsl), for trees whose inner depth is at most this; tests/bvh.rs checks
// that this value equals vkinverse::bvh::CW_STACK_REGISTERS.
#define BVH_CW_STACK_REGISTERS 4

// Hits at t <= BVH_T_MIN (in units of |dir|) are ignored, so that a ray leaving a surface
// does not find that surface again. Absolute, sized for scenes of unit scale (1 to 100
// units across); tests/bvh.rs checks that it equals vkinverse::bvh::T_MIN.
#define BVH_T_MIN 1e-4

// A child reference whose count is BVH_INNER is an inner node; any other count, including
// 0 (an empty child), is a leaf of that many triangles.
#define BVH_INNER 0xFFFFFFFFu

// Prim of a Hit that found nothing.
#define BVH_NO_HIT 0xFFFFFFFFu

// 64 bytes: an inner node of a binary BVH holding the boxes of its two children, as in
// Aila & Laine 2009, so that one node fetch tests both children. A child is an inner node
// (count == BVH_INNER, index into the node array) or a leaf (count triangles starting at
// index in the triangle array). Nodes are in depth-first order: the root is node 0 and an
// inner child has a larger index than its parent.
struct BvhNode {
    vec3 left_min;
    uint left_index;
    vec3 left_max;
    uint left_count;
    vec3 right_min;
    uint right_index;
    vec3 right_max;
    uint right_count;
};

// 128 bytes: an inner node of the wide (4-ary) BVH, the layout of kernels built with
// BVH_WIDE. It holds the boxes of its four child slots as structure of arrays (component
// k of each vector is slot k) so that one fetch tests all four. A slot is an inner node
// (count == BVH_INNER, index into the node array), a leaf (count triangles from index) or
// empty (count 0, box min = max = +inf, which no ray enters). A wide node is a binary node
// of BvhNode's layout with descendants pulled up into its slots, every inner slot at least
// two binary levels below it (vkinverse::bvh::WideBvh), so wide inner nodes are at depth
// <= BVH_STACK_SIZE / 2; leaves and triangles are the binary tree's. Nodes are in depth-first order: the root is
// node 0 and an inner child has a larger index than its parent.
struct BvhWideNode {
    vec4 min_x;
    vec4 min_y;
    vec4 min_z;
    vec4 max_x;
    vec4 max_y;
    vec4 max_z;
    uvec4 index;
    uvec4 count;
};

// 80 bytes (5 texels): an inner node of the compressed 8-wide BVH of Ylitie, Karras &
// Laine 2017, the layout of kernels built with BVH_CW8 (obvhs's CwBvhNode byte for byte;
// vkinverse::bvh::CwBvh). Child c's box is p + q * scale per axis, with the 8-bit grid
// coordinates q in byte c (min) and byte 8 + c (max) of quant_x, quant_y, quant_z, and
// scale the float whose exponent bits are byte k of e_imask for axis k. Byte 3 of
// e_imask has bit c set when child c is an inner node. Meta byte c (of the 8 in meta):
// 0 for an empty slot; 001sssss with s = 24 + c for an inner child, which is node
// child_base + (number of inner children in slots below c); else a leaf of the triangles
// triangle_base + (low 5 bits) onwards, as many as the high 3 bits hold in unary (1 to
// 3). Slots are ordered by direction, so that XOR-ing the slot with the ray's octant
// gives a front-to-back priority. Every child's grid box contains everything below it
// in exact arithmetic; inner nodes are at depth <= BVH_CW_STACK_SIZE.
struct BvhCwNode {
    vec3 p;
    uint e_imask;
    uint child_base;
    uint triangle_base;
    uvec2 meta;
    uvec4 quant_x;
    uvec4 quant_y;
    uvec4 quant_z;
};

// 48 bytes (3 texels): a triangle in Möller–Trumbore form (v0 and the edges v1 - v0,
// v2 - v0), in leaf order, with the index of the triangle in the scene's triangle list.
// alpha_material: 0, or 1 + the material whose alpha test a candidate hit must pass
// (lib/bvh_traverse.glsl).
struct BvhTriangle {
    vec3 v0;
    vec3 e1;
    vec3 e2;
    uint prim;
    uint alpha_material;
    uint pad;
};

// 16 bytes: the closest hit of a ray. prim is the scene's triangle index (BVH_NO_HIT for a
// miss); u and v are the barycentric weights of v1 and v2, so the hit point is
// v0 + u * (v1 - v0) + v * (v2 - v0).
struct Hit {
    float t;
    uint prim;
    float u;
    float v;
};

// 28 bytes: one ray of the trace_test kernel.
struct TraceRay {
    vec3 origin;
    float tmax;
    vec3 dir;
};

// 20 bytes: what trace_test writes per ray: the closest hit, and whether trace_any found
// any hit within tmax (1) or not (0).
struct TraceResult {
    Hit hit;
    uint any_hit;
};
#endif
