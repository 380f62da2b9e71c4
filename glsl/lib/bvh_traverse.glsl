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
// Slab test (Kay & Kajiya 1986) with a precomputed inverse direction. Direction components
// below 1e-20 in magnitude (zero: rays parallel to box faces) become +-1e-20, which keeps every
// product finite (no 0 * inf = NaN when the origin lies on a face plane) and, for an origin
// inside the slab, an interval covering every reachable t. The exit distance is widened by
// 1 + 2 gamma(3) (Ize 2013, "Robust BVH ray traversal") so that rounding never culls a box
// that the ray grazes.
//
// Declares the geometry buffers at bindings 10 and 11 (bindings 10-19 are scene geometry);
// a kernel that includes this file binds them with BvhBuffers::bindings(). Kernels declare
// their workgroup size before including this file (see lib/common.glsl).
#ifndef BVH_TRAVERSE_GLSL
#define BVH_TRAVERSE_GLSL
#include "lib/common.glsl"
#include "shared/bvh.glsl"

layout(set = 0, binding = 10, scalar) readonly buffer BvhNodes { BvhNode bvh_nodes[]; };
layout(set = 0, binding = 11, scalar) readonly buffer BvhTriangles { BvhTriangle bvh_triangles[]; };

// The float just above 1 + 2 gamma(3), gamma(n) = n eps / (1 - n eps), eps = 2^-24: the
// widening of Ize 2013 that covers the rounding of the slab distances.
const float BVH_EXIT_SCALE = 1.00000048;

// The entry distance of a missed box.
const float BVH_MISS = 1.0 / 0.0;

// Entry distance of the ray into the box [lo, hi] within [0, tmax], or BVH_MISS (+inf).
float bvh_box_entry(vec3 lo, vec3 hi, vec3 origin, vec3 inv_dir, float tmax) {
    vec3 t0 = (lo - origin) * inv_dir;
    vec3 t1 = (hi - origin) * inv_dir;
    vec3 tn = min(t0, t1);
    vec3 tf = max(t0, t1);
    float enter = max(max(tn.x, tn.y), max(tn.z, 0.0));
    float exit = min(min(tf.x, tf.y), min(tf.z, tmax)) * BVH_EXIT_SCALE;
    return enter <= exit ? enter : BVH_MISS;
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
        BvhTriangle tri = bvh_triangles[i];
        float t, u, v;
        if (bvh_hit_triangle(tri, origin, dir, hit.t, t, u, v)) {
            hit = Hit(t, tri.prim, u, v);
            found = true;
        }
    }
    return found;
}

// The traversal behind trace_closest (any_hit false) and trace_any (any_hit true: returns
// at the first hit). Callers pass a constant any_hit, so each copy is specialised.
bool bvh_traverse(vec3 origin, vec3 dir, float tmax, bool any_hit, out Hit hit) {
    hit = Hit(tmax, BVH_NO_HIT, 0.0, 0.0);
    vec3 safe_dir = mix(dir, mix(vec3(-1e-20), vec3(1e-20), greaterThanEqual(dir, vec3(0.0))),
                        lessThan(abs(dir), vec3(1e-20)));
    vec3 inv_dir = 1.0 / safe_dir;

    uint stack[BVH_STACK_SIZE];
    uint sp = 0u;
    // Node 0 is the root and never anyone's child, so 0 also means "no next node".
    uint node = 0u;
    while (true) {
        BvhNode n = bvh_nodes[node];
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
