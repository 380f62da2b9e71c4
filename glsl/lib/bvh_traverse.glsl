// Ray traversal of the scene BVH built by src/bvh/mod.rs (layout: shared/bvh.glsl).
//
//   bool trace_closest(vec3 origin, vec3 dir, float tmax, out Hit hit)
//   bool trace_any(vec3 origin, vec3 dir, float tmax)
//
// Hit policy, shared with the CPU reference vkinverse::bvh::intersect_brute_force:
// - a hit counts if BVH_T_MIN < t < tmax, with t in units of |dir| (dir need not be
//   normalised; tmax may be +inf). BVH_T_MIN is a last guard against a ray finding the
//   surface it leaves; spawning rays at an offset from the surface is the caller's job;
// - edges and vertices belong to the triangle (u >= 0, v >= 0, u + v <= 1), so that in
//   exact arithmetic a ray through a shared edge hits one of its two triangles. In floating
//   point the two triangles' barycentrics are computed separately, so a ray within about an
//   ulp of the edge can still slip through: "watertight enough", not the watertight test of
//   Woop et al. 2013, which would need the three vertices and a per-ray shear;
// - back faces count (no culling); a ray parallel to the triangle's plane misses it;
// - trace_closest keeps the first of equally distant hits it meets (traversal order).
//
// Traversal: one stack of inner-node indices (Aila & Laine 2009, "Understanding the
// efficiency of ray traversal on GPUs"): each node holds both children's boxes; the hit
// children are visited nearest first, the farther inner one pushed; leaf children are
// intersected at once. Only the farther child of a node is pushed, so the stack holds at
// most one entry per level above the current node: the builder keeps every inner node at
// depth <= BVH_STACK_SIZE, and the stack never overflows.
//
// Wide layout (kernels built with BVH_WIDE, nodes of BvhWideNode): each node's four slots
// are tested at once and sorted by entry distance (a five-comparator sorting network).
// The triangles of the hit leaf slots are intersected at once, nearest leaf first, in a
// single loop of one triangle per iteration (on a SIMD device the invocations of a group
// then test triangles together whichever slots their leaves are in); of the hit inner slots the
// nearest is visited next and the others are pushed, farthest first, with their entry
// distance, so that an entry the ray has since been shortened past is dropped when popped
// without fetching its node. A node pushes at most 3 entries and the stack holds entries
// of the current node's ancestors only, at most 3 per level; wide inner nodes are at depth
// <= BVH_STACK_SIZE / 2, so only nodes at depth < BVH_STACK_SIZE / 2 push, and the stack
// never holds more than 3 * BVH_STACK_SIZE / 2 = BVH_WIDE_STACK_SIZE entries.
//
// Compressed layout (kernels built with BVH_CW8, nodes of BvhCwNode): Ylitie, Karras &
// Laine 2017, eight children per 5-texel node with quantised boxes; see bvh_traverse
// below.
//
// Slab test (Kay & Kajiya 1986) with a precomputed inverse direction. Direction components
// below 1e-20 in magnitude (zero: rays parallel to box faces) become +-1e-20, which keeps every
// product finite (no 0 * inf = NaN when the origin lies on a face plane) and, for an origin
// inside the slab, an interval covering every reachable t. The exit distance is widened by
// 1 + 2 gamma(3) (Ize 2013, "Robust BVH ray traversal") so that rounding never culls a box
// that the ray grazes.
//
// Declares the geometry buffers at bindings 10 and 11 (bindings 10-19 are scene geometry)
// as texel buffers of 16-byte texels (lib/texels.glsl; see lib/scene_access.glsl for why), read
// through bvh_node and bvh_triangle; a kernel that includes this file binds them with
// BvhBuffers::bindings(). Kernels declare their workgroup size before including this file
// (see lib/common.glsl).
#ifndef BVH_TRAVERSE_GLSL
#define BVH_TRAVERSE_GLSL
#include "lib/common.glsl"
#include "lib/texels.glsl"
#include "shared/bvh.glsl"

TEXEL_BUFFER(0, 10) BvhNodes;
TEXEL_BUFFER(0, 11) BvhTriangles;

#if defined(BVH_CW8)
// Compressed node i: 5 texels.
BvhCwNode bvh_node(uint i) {
    int b = int(i) * 5;
    uvec4 t0 = texel_load(BvhNodes, b);
    uvec4 t1 = texel_load(BvhNodes, b + 1);
    return BvhCwNode(uintBitsToFloat(t0.xyz), t0.w, t1.x, t1.y, t1.zw, texel_load(BvhNodes, b + 2),
                     texel_load(BvhNodes, b + 3), texel_load(BvhNodes, b + 4));
}
#elif defined(BVH_WIDE)
// Wide node i: 8 texels, one per member.
BvhWideNode bvh_node(uint i) {
    int b = int(i) * 8;
    BvhWideNode n;
    n.min_x = uintBitsToFloat(texel_load(BvhNodes, b));
    n.min_y = uintBitsToFloat(texel_load(BvhNodes, b + 1));
    n.min_z = uintBitsToFloat(texel_load(BvhNodes, b + 2));
    n.max_x = uintBitsToFloat(texel_load(BvhNodes, b + 3));
    n.max_y = uintBitsToFloat(texel_load(BvhNodes, b + 4));
    n.max_z = uintBitsToFloat(texel_load(BvhNodes, b + 5));
    n.index = texel_load(BvhNodes, b + 6);
    n.count = texel_load(BvhNodes, b + 7);
    return n;
}
#else
// Binary node i: 4 texels, each a box corner and an index or count.
BvhNode bvh_node(uint i) {
    int b = int(i) * 4;
    uvec4 t0 = texel_load(BvhNodes, b);
    uvec4 t1 = texel_load(BvhNodes, b + 1);
    uvec4 t2 = texel_load(BvhNodes, b + 2);
    uvec4 t3 = texel_load(BvhNodes, b + 3);
    return BvhNode(uintBitsToFloat(t0.xyz), t0.w, uintBitsToFloat(t1.xyz), t1.w,
                   uintBitsToFloat(t2.xyz), t2.w, uintBitsToFloat(t3.xyz), t3.w);
}
#endif

// Triangle i in leaf order: 3 texels (v0 0-2, e1 3-5, e2 6-8, prim 9).
BvhTriangle bvh_triangle(uint i) {
    BvhTriangle t;
    uvec3 rest;
    texel_vec3x3(BvhTriangles, int(i) * 3, t.v0, t.e1, t.e2, rest);
    t.prim = rest.x;
    t.alpha_material = rest.y;
    t.pad = 0u;
    return t;
}

// Alpha tests (materials with an alpha mask): a candidate hit on a triangle whose record
// names such a material counts only where the material's alpha at the hit passes its
// test (a cutoff, or for a blend a number hashed from the ray: the ray `origin`, `dir` of
// the calling function); elsewhere the ray goes on as if the triangle were not there. Kernels that
// include lib/scene_access.glsl first get the test (alpha_cut); the others (the BVH tests'
// trace_test) have no materials and none.
#ifdef SCENE_ACCESS_GLSL
#define BVH_CUT_OUT(tri, u, v) (HAS_ALPHA_MASKS && (tri).alpha_material != 0u && alpha_cut((tri).alpha_material, triangle_uv((tri).prim, vec2(u, v)), alpha_ray_key(origin, dir, (tri).prim)))
#else
#define BVH_CUT_OUT(tri, u, v) false
#endif

// The float just above 1 + 2 gamma(3), gamma(n) = n eps / (1 - n eps), eps = 2^-24: the
// widening of Ize 2013 that covers the rounding of the slab distances.
const float BVH_EXIT_SCALE = 1.00000048;

// The entry distance of a missed box.
const float BVH_MISS = 1.0 / 0.0;

// Entry and exit distances of the ray through the box [lo, hi] within [0, tmax], the exit
// widened (above): the ray misses it where the entry lies beyond the exit.
vec2 bvh_box_span(vec3 lo, vec3 hi, vec3 origin, vec3 inv_dir, float tmax) {
    vec3 t0 = (lo - origin) * inv_dir;
    vec3 t1 = (hi - origin) * inv_dir;
    vec3 tn = min(t0, t1);
    vec3 tf = max(t0, t1);
    float enter = max(max(tn.x, tn.y), max(tn.z, 0.0));
    float exit = min(min(tf.x, tf.y), min(tf.z, tmax)) * BVH_EXIT_SCALE;
    return vec2(enter, exit);
}

// Entry distance of the ray into the box [lo, hi] within [0, tmax], or BVH_MISS (+inf).
float bvh_box_entry(vec3 lo, vec3 hi, vec3 origin, vec3 inv_dir, float tmax) {
    vec2 span = bvh_box_span(lo, hi, origin, inv_dir, tmax);
    return span.x <= span.y ? span.x : BVH_MISS;
}

// Möller & Trumbore 1997, "Fast, minimum storage ray-triangle intersection", with the
// edges stored: t, u, v of the hit and whether it counts (see the policy above). No early
// exits: on a SIMD device every lane runs every test anyway.
bool bvh_hit_triangle(BvhTriangle tri, vec3 origin, vec3 dir, float tmax, out float t, out float u, out float v) {
    vec3 p = cross(dir, tri.e2);
    float det = dot(tri.e1, p);
    // det == 0: parallel ray or degenerate triangle; the products below are then inf or
    // NaN, and every comparison with NaN fails.
    float inv_det = 1.0 / det;
    vec3 s = origin - tri.v0;
    u = dot(s, p) * inv_det;
    vec3 q = cross(s, tri.e1);
    v = dot(dir, q) * inv_det;
    t = dot(tri.e2, q) * inv_det;
    return det != 0.0 && u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > BVH_T_MIN && t < tmax;
}

// Intersects the triangles [first, first + count) and shortens `hit` to the closest.
bool bvh_hit_leaf(uint first, uint count, vec3 origin, vec3 dir, inout Hit hit) {
    bool found = false;
    for (uint i = first; i < first + count; i++) {
        BvhTriangle tri = bvh_triangle(i);
        float t, u, v;
        if (bvh_hit_triangle(tri, origin, dir, hit.t, t, u, v) && !BVH_CUT_OUT(tri, u, v)) {
            hit = Hit(t, tri.prim, u, v);
            found = true;
        }
    }
    return found;
}

// Direction components below 1e-20 in magnitude become +-1e-20 (see the slab test above).
vec3 bvh_safe_dir(vec3 dir) {
    return mix(dir, mix(vec3(-1e-20), vec3(1e-20), greaterThanEqual(dir, vec3(0.0))),
               lessThan(abs(dir), vec3(1e-20)));
}

#if defined(BVH_CW8)
// Whether the traversal stack lives in BVH_CW_STACK_REGISTERS (4) registers instead of a
// private array: set by the host (GpuScene::spec) where the tree is shallow enough that the
// stack never holds more (its inner depth). lavapipe reads and writes a private array indexed
// per lane lane by lane, and runs both the push and the pop at every outer iteration; the
// registers shift instead, a few selects (docs/lavapipe.md).
layout(constant_id = 15) const bool BVH_STACK_REGISTERS = false;

// The grid coordinates in bytes 0-3 (`hi` false) or 4-7 (true) of a pair of words.
vec4 bvh_cw_bytes(uvec2 w, bool hi) {
    return vec4((uvec4(hi ? w.y : w.x) >> uvec4(0u, 8u, 16u, 24u)) & 0xFFu);
}

// The hit bits of children 4h .. 4h + 3 (see bvh_cw_intersect).
uint bvh_cw_half(BvhCwNode n, bool h, vec3 E, vec3 P, float pad, float tmax, uint oct_inv) {
    vec4 tx0 = bvh_cw_bytes(n.quant_x.xy, h) * E.x + P.x;
    vec4 tx1 = bvh_cw_bytes(n.quant_x.zw, h) * E.x + P.x;
    vec4 ty0 = bvh_cw_bytes(n.quant_y.xy, h) * E.y + P.y;
    vec4 ty1 = bvh_cw_bytes(n.quant_y.zw, h) * E.y + P.y;
    vec4 tz0 = bvh_cw_bytes(n.quant_z.xy, h) * E.z + P.z;
    vec4 tz1 = bvh_cw_bytes(n.quant_z.zw, h) * E.z + P.z;
    vec4 enter = max(max(min(tx0, tx1), min(ty0, ty1)), max(min(tz0, tz1), vec4(0.0))) - pad;
    vec4 exit = min(min(min(max(tx0, tx1), max(ty0, ty1)), max(tz0, tz1)) + pad, vec4(tmax));
    uvec4 meta = (uvec4(h ? n.meta.y : n.meta.x) >> uvec4(0u, 8u, 16u, 24u)) & 0xFFu;
    bvec4 inner = equal(meta & 0x18u, uvec4(0x18u));
    // Inner child: one bit at 24 + (slot ^ octant), its traversal priority; leaf: its
    // count in unary at its triangle offset. An empty slot (meta 0) sets nothing.
    uvec4 shift = mix(meta & 31u, (meta & 31u) ^ oct_inv, inner);
    uvec4 bits = mix(meta >> 5, uvec4(1u), inner);
    uvec4 hits = mix(uvec4(0u), bits << shift, lessThanEqual(enter, exit));
    return hits.x | hits.y | hits.z | hits.w;
}

// The children of node n that the ray enters within [0, tmax]: bits 24-31 the inner
// children by priority (the highest bit first), bits 0-23 the hit leaves' triangles
// relative to n.triangle_base. The slab test runs on the grid coordinates with the ray
// moved into the node's frame (t = q * scale / dir + (p - origin) / dir, Ylitie et al.):
// scale is a power of two, so E is exact, and the rounding of P and of the product and
// sum is below 2^-21 (|P| + 255 |E|) on each axis; the entry is lowered and the exit
// raised by that much, so that rounding never culls a box the ray touches.
uint bvh_cw_intersect(BvhCwNode n, vec3 origin, vec3 inv_dir, float tmax, uint oct_inv) {
    uvec3 e = (uvec3(n.e_imask) >> uvec3(0u, 8u, 16u)) & 0xFFu;
    vec3 E = uintBitsToFloat(e << 23) * inv_dir;
    vec3 P = (n.p - origin) * inv_dir;
    vec3 slack = (abs(P) + 255.0 * abs(E)) * 4.76837158e-7;
    float pad = max(max(slack.x, slack.y), slack.z);
    return bvh_cw_half(n, false, E, P, pad, tmax, oct_inv) | bvh_cw_half(n, true, E, P, pad, tmax, oct_inv);
}

// The traversal behind trace_closest (any_hit false) and trace_any (any_hit true: returns
// at the first hit). Callers pass a constant any_hit, so each copy is specialised.
// Ylitie et al.'s loop: a node group (child base, hit inner children in bits 24-31 and
// the node's inner-child mask in bits 0-7) and a triangle group (triangle base, hit
// triangles in bits 0-23). Each iteration of the outer loop takes the highest-priority
// child of the node group (an empty group pops the stack first; an empty stack ends),
// pushes the rest of the group if any, fetches and intersects the child, and tests the
// triangles it hit in an inner loop, one per iteration. Each push is one level deeper
// than the entries below it, so the stack never holds more than the tree's depth.
// The order (node, then its triangles, with the pop in the same iteration) matters on
// lavapipe, which enters every loop at least once, masked, even when no lane has work in
// it (docs/lavapipe.md): testing the triangles first, in their own outer iteration,
// cost a wasted triangle test at the first iteration, at every pop and at the end.
bool bvh_traverse(vec3 origin, vec3 dir, float tmax, bool any_hit, out Hit hit) {
    hit = Hit(tmax, BVH_NO_HIT, 0.0, 0.0);
    vec3 inv_dir = 1.0 / bvh_safe_dir(dir);
    // obvhs's octant code: XOR-ed into a slot, the front-to-back priority.
    uint oct_inv = (dir.x < 0.0 ? 0u : 4u) | (dir.y < 0.0 ? 0u : 2u) | (dir.z < 0.0 ? 0u : 1u);

    uvec2 stack[BVH_CW_STACK_SIZE];
    // The register stack: r0 is its top.
    uvec2 r0 = uvec2(0u), r1 = uvec2(0u), r2 = uvec2(0u), r3 = uvec2(0u);
    uint sp = 0u;
    // The root, as the single hit child of a group at base 0.
    uvec2 group = uvec2(0u, 0x80000000u);
    while (true) {
        // A group without hit inner children left: take the next one from the stack
        // (every pushed group has one), or end.
        if ((group.y & 0xFF000000u) == 0u) {
            if (sp == 0u) {
                break;
            }
            --sp;
            if (BVH_STACK_REGISTERS) {
                group = r0;
                r0 = r1;
                r1 = r2;
                r2 = r3;
            } else {
                group = stack[sp];
            }
        }
        uint hits = group.y;
        int k = findMSB(hits);
        group.y &= ~(1u << k);
        if ((group.y & 0xFF000000u) != 0u) {
            if (BVH_STACK_REGISTERS) {
                r3 = r2;
                r2 = r1;
                r1 = r0;
                r0 = group;
            } else {
                stack[sp] = group;
            }
            ++sp;
        }
        uint slot = uint(k - 24) ^ oct_inv;
        uint node = group.x + bitCount(hits & ~(0xFFFFFFFFu << slot));
        BvhCwNode n = bvh_node(node);
        uint mask = bvh_cw_intersect(n, origin, inv_dir, hit.t, oct_inv);
        group = uvec2(n.child_base, (mask & 0xFF000000u) | (n.e_imask >> 24));
        uvec2 tris = uvec2(n.triangle_base, mask & 0x00FFFFFFu);
        while (tris.y != 0u) {
            int j = findMSB(tris.y);
            tris.y &= ~(1u << j);
            BvhTriangle triangle = bvh_triangle(tris.x + uint(j));
            float th, u, v;
            if (bvh_hit_triangle(triangle, origin, dir, hit.t, th, u, v) && !BVH_CUT_OUT(triangle, u, v)) {
                hit = Hit(th, triangle.prim, u, v);
                if (any_hit) {
                    return true;
                }
            }
        }
    }
    return hit.prim != BVH_NO_HIT;
}
#elif defined(BVH_WIDE)
// Sorts the slots a and b (vector components) of (t, index, count) by t; equal distances
// keep their slot order. Static components only: no dynamic indexing into vectors.
#define BVH_SORT2(a, b)                          \
    {                                            \
        bool swap = t.b < t.a;                   \
        float t_a = t.a;                         \
        uint index_a = index.a;                  \
        uint count_a = count.a;                  \
        t.a = swap ? t.b : t_a;                  \
        t.b = swap ? t_a : t.b;                  \
        index.a = swap ? index.b : index_a;      \
        index.b = swap ? index_a : index.b;      \
        count.a = swap ? count.b : count_a;      \
        count.b = swap ? count_a : count.b;      \
    }

// Marks slot k (bit k of leaves) if it is a leaf the ray enters before its current end.
#define BVH_LEAF(k, bit)                                                              \
    if (t.k != BVH_MISS && t.k <= hit.t && count.k != BVH_INNER) {                   \
        leaves |= bit;                                                                \
    }

// Makes slot k the next node if it is an inner node the ray enters before its current
// end, pushing the previous next node (a farther one).
#define BVH_INNER_SLOT(k)                                                             \
    if (t.k != BVH_MISS && t.k <= hit.t && count.k == BVH_INNER) {                   \
        if (next != 0u) {                                                             \
            stack_node[sp] = next;                                                    \
            stack_t[sp] = next_t;                                                     \
            sp++;                                                                     \
        }                                                                             \
        next = index.k;                                                               \
        next_t = t.k;                                                                 \
    }

// The traversal behind trace_closest (any_hit false) and trace_any (any_hit true: returns
// at the first hit). Callers pass a constant any_hit, so each copy is specialised.
bool bvh_traverse(vec3 origin, vec3 dir, float tmax, bool any_hit, out Hit hit) {
    hit = Hit(tmax, BVH_NO_HIT, 0.0, 0.0);
    vec3 inv_dir = 1.0 / bvh_safe_dir(dir);

    uint stack_node[BVH_WIDE_STACK_SIZE];
    float stack_t[BVH_WIDE_STACK_SIZE];
    uint sp = 0u;
    // Node 0 is the root and never anyone's child, so 0 also means "no next node".
    uint node = 0u;
    while (true) {
        BvhWideNode n = bvh_node(node);
        // bvh_box_entry on the four slots, with the same operations in the same order.
        vec4 tx0 = (n.min_x - origin.x) * inv_dir.x;
        vec4 tx1 = (n.max_x - origin.x) * inv_dir.x;
        vec4 ty0 = (n.min_y - origin.y) * inv_dir.y;
        vec4 ty1 = (n.max_y - origin.y) * inv_dir.y;
        vec4 tz0 = (n.min_z - origin.z) * inv_dir.z;
        vec4 tz1 = (n.max_z - origin.z) * inv_dir.z;
        vec4 enter = max(max(min(tx0, tx1), min(ty0, ty1)), max(min(tz0, tz1), vec4(0.0)));
        vec4 exit = min(min(max(tx0, tx1), max(ty0, ty1)), min(max(tz0, tz1), vec4(hit.t))) * BVH_EXIT_SCALE;
        vec4 t = mix(vec4(BVH_MISS), enter, lessThanEqual(enter, exit));
        uvec4 index = n.index;
        uvec4 count = n.count;
        // Nearest first (a sorting network of five comparators).
        BVH_SORT2(x, y)
        BVH_SORT2(z, w)
        BVH_SORT2(x, z)
        BVH_SORT2(y, w)
        BVH_SORT2(y, z)
        // The hit leaves' triangles, nearest leaf first, in one loop of one triangle per
        // iteration, so that the invocations of a SIMD group test triangles together
        // whichever slots their leaves are in. A leaf the ray has since been shortened
        // past is skipped.
        uint leaves = 0u;
        BVH_LEAF(x, 1u)
        BVH_LEAF(y, 2u)
        BVH_LEAF(z, 4u)
        BVH_LEAF(w, 8u)
        uint tri = 0u;
        uint tri_end = 0u;
        while (true) {
            if (tri == tri_end) {
                if (leaves == 0u) {
                    break;
                }
                int k = findLSB(leaves);
                leaves &= leaves - 1u;
                tri = index[k];
                tri_end = t[k] <= hit.t ? tri + count[k] : tri;
                continue;
            }
            BvhTriangle triangle = bvh_triangle(tri);
            float th, u, v;
            if (bvh_hit_triangle(triangle, origin, dir, hit.t, th, u, v) && !BVH_CUT_OUT(triangle, u, v)) {
                hit = Hit(th, triangle.prim, u, v);
                if (any_hit) {
                    return true;
                }
            }
            tri++;
        }
        // Inner slots, farthest first: the nearest ends up as `next`, the others pushed.
        uint next = 0u;
        float next_t = 0.0;
        BVH_INNER_SLOT(w)
        BVH_INNER_SLOT(z)
        BVH_INNER_SLOT(y)
        BVH_INNER_SLOT(x)
        while (next == 0u) {
            if (sp == 0u) {
                return hit.prim != BVH_NO_HIT;
            }
            sp--;
            // (hit.t stays tmax until an any-hit traversal returns: no distances needed.)
            if (any_hit || stack_t[sp] <= hit.t) {
                next = stack_node[sp];
            }
        }
        node = next;
    }
    return false;
}
#else
// The traversal behind trace_closest (any_hit false) and trace_any (any_hit true: returns
// at the first hit). Callers pass a constant any_hit, so each copy is specialised.
bool bvh_traverse(vec3 origin, vec3 dir, float tmax, bool any_hit, out Hit hit) {
    hit = Hit(tmax, BVH_NO_HIT, 0.0, 0.0);
    vec3 inv_dir = 1.0 / bvh_safe_dir(dir);

    uint stack[BVH_STACK_SIZE];
    uint sp = 0u;
    // Node 0 is the root and never anyone's child, so 0 also means "no next node".
    uint node = 0u;
    while (true) {
        BvhNode n = bvh_node(node);
        float t_left = bvh_box_entry(n.left_min, n.left_max, origin, inv_dir, hit.t);
        float t_right = bvh_box_entry(n.right_min, n.right_max, origin, inv_dir, hit.t);
        // Nearer child first; a missed child sorts last.
        bool swap = t_right < t_left;
        float t_near = swap ? t_right : t_left;
        float t_far = swap ? t_left : t_right;
        uint near_index = swap ? n.right_index : n.left_index;
        uint near_count = swap ? n.right_count : n.left_count;
        uint far_index = swap ? n.left_index : n.right_index;
        uint far_count = swap ? n.left_count : n.right_count;

        uint next = 0u;
        if (t_near != BVH_MISS) {
            if (near_count == BVH_INNER) {
                next = near_index;
            } else if (bvh_hit_leaf(near_index, near_count, origin, dir, hit) && any_hit) {
                return true;
            }
        }
        // The near leaf may have shortened the ray past the far child's entry.
        if (t_far != BVH_MISS && t_far <= hit.t) {
            if (far_count != BVH_INNER) {
                if (bvh_hit_leaf(far_index, far_count, origin, dir, hit) && any_hit) {
                    return true;
                }
            } else if (next == 0u) {
                next = far_index;
            } else {
                stack[sp++] = far_index;
            }
        }
        if (next == 0u) {
            if (sp == 0u) {
                break;
            }
            next = stack[--sp];
        }
        node = next;
    }
    return hit.prim != BVH_NO_HIT;
}
#endif

// The closest hit of the ray in (BVH_T_MIN, tmax). On a miss returns false and sets
// hit = Hit(tmax, BVH_NO_HIT, 0, 0).
bool trace_closest(vec3 origin, vec3 dir, float tmax, out Hit hit) {
    return bvh_traverse(origin, dir, tmax, false, hit);
}

// Whether the ray hits anything in (BVH_T_MIN, tmax): shadow rays. Stops at the first hit.
bool trace_any(vec3 origin, vec3 dir, float tmax) {
    Hit hit;
    return bvh_traverse(origin, dir, tmax, true, hit);
}
#endif
