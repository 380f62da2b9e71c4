// The scene's medium (src/render/features/media.rs): a box that absorbs and emits light,
// with no scattering, or the part of the box inside a closed mesh (its boundary): a ray
// crosses it in parts, between where it enters the boundary and where it leaves it (by
// the winding of the triangles it crosses), each marched or tracked as below. Along a
// ray it is marched in steps of equal length, stratified with one jitter per ray: step k of length dt at density σ_k keeps a_k = exp(−σ_k dt) of what
// lies behind it and adds L_e,k (1 − a_k), each times the transmittance of the steps
// before it. The jitter is a hash of the ray's bits, so that the primal and gradient
// replays of a path, and both parameter states of the finite-difference kernels, march
// the same points.
//
// Gradients (ADJOINT) by path replay in closed form, in O(1) memory: with R_k the radiance
// still to be accounted for where step k begins (the primal's minus what the replay has
// gathered so far, beta_k the throughput there),
//     dL/dσ_k = dt (beta_k L_e,k − R_k),    dL/dL_e,k = beta_k (1 − a_k),
// with no division by a transmittance, so that opaque steps (σ dt of 1e4) stay finite. A
// shadow ray's contribution c (which includes its transmittance) has dc/dσ_k = −dt c.
// Each is scattered to the 8 voxels of the step's trilinear lookup.
//
// A scattering medium (the SCATTERING builds) is tracked instead, exactly, against its
// majorant σ̄: tentative collisions at exponential distances of rate σ̄, each real with
// probability σ(x)/σ̄ (delta tracking: where a path collides) or weighted by 1 − σ(x)/σ̄
// (ratio tracking: a shadow ray's transmittance). σ̄ is piecewise constant: a grid of
// cells over the box, each bounding the extinction that its lookups can see, walked cell
// by cell along the ray (a 3-D DDA: the optical depth to the next tentative collision is
// spent cell by cell; an empty cell costs no lookup), or one value over the box
// (MediumRecord.majorant) where the medium has no grid. The random numbers are hashed
// from the ray, so every replay and both parameter states see the same tentative points.
#ifndef MEDIA_GLSL
#define MEDIA_GLSL

TEXEL_BUFFER(0, 29) Media;
// Whether the scene has a medium: without one every function here is compiled out. True
// by default, as the other features' constants, so that the unspecialised build
// (trace_primal_generic) renders any scene (a record of max_steps 0 holds no medium).
layout(constant_id = 24) const bool HAS_MEDIA = true;
// Whether a scattering medium has a majorant grid (its kernels walk it where the record's
// majorant_cells is not 0): without one the walk is compiled out.
layout(constant_id = 27) const bool MAJORANT_GRID = true;
// Whether the medium has a boundary mesh: without one the boundary's search is compiled
// out, and a ray crosses the medium in one part (its box's).
layout(constant_id = 28) const bool MEDIUM_BOUNDARY = true;
// A medium that scatters (albedo > 0) is rendered by the kernels' SCATTERING builds (the
// _scatter variants): their rays sample where they collide (medium_free_flight) instead
// of gathering emission (medium_segment). The other builds leave the collision and its
// light samples out.

MediumRecord medium_record() {
    uvec4 t0 = texel_load(Media, 0);
    uvec4 t1 = texel_load(Media, 1);
    uvec4 t4 = texel_load(Media, 4);
    uvec4 t6 = texel_load(Media, 6);
    MediumRecord m;
    m.box_min = uintBitsToFloat(t0.xyz);
    m.step = uintBitsToFloat(t0.w);
    m.box_max = uintBitsToFloat(t1.xyz);
    m.scale = uintBitsToFloat(t1.w);
    m.density = value_ref(texel_load(Media, 2));
    m.emission = value_ref(texel_load(Media, 3));
    m.density_depth = t4.x;
    m.emission_depth = t4.y;
    m.max_steps = t4.z;
    m.albedo_depth = t4.w;
    m.albedo = value_ref(texel_load(Media, 5));
    m.g = uintBitsToFloat(t6.x);
    m.majorant = uintBitsToFloat(t6.y);
    m.majorant_cells = t6.z;
    m.boundary_texels = t6.w;
    return m;
}

// The most parts of the medium that one ray crosses, where it has a boundary: a ray
// through more separate insides than this (a mesh of many shells or folds) leaves the
// rest out.
const uint MEDIUM_MAX_PARTS = 16u;

// The texel where the majorant grid starts: after the record and the boundary.
int majorant_grid_texel(MediumRecord m) {
    return MEDIUM_RECORD_TEXELS + int(m.boundary_texels);
}

// Entries of the boundary BVH's traversal stack: its builder keeps inner nodes at depth
// 16 at most (src/render/features/media.rs), and the stack holds one per level.
const int BOUNDARY_STACK = 18;

// Whether ray (o, inv_dir) passes through box [lo, hi] between from and tmax (the scene
// BVH's slab test).
bool boundary_box_hit(vec3 lo, vec3 hi, vec3 o, vec3 inv_dir, float from, float tmax) {
    vec2 span = bvh_box_span(lo, hi, o, inv_dir, tmax);
    return span.x <= span.y && span.y >= from;
}

// The three nearest crossings of the boundary after `from` along ray (o, d) (3e38 where
// there are fewer), and whether the ray enters it at the first: its BVH's boxes that the
// ray passes through between `from` and the third are opened, their triangles
// intersected as the scene's (bvh_hit_triangle). The third tells whether another part
// follows the first (through a convex boundary none does: one search per ray).
void boundary_crossings(vec3 o, vec3 d, float from, out float first, out float second, out float third, out bool enters) {
    first = 3.0e38;
    second = 3.0e38;
    third = 3.0e38;
    enters = false;
    int nodes = MEDIUM_RECORD_TEXELS + 1;
    int triangles = nodes + 4 * int(texel_load(Media, MEDIUM_RECORD_TEXELS).x);
    vec3 inv_dir = 1.0 / bvh_safe_dir(d);
    uint stack[BOUNDARY_STACK];
    int sp = 0;
    stack[sp++] = 0u;
    while (sp > 0) {
        int b = nodes + 4 * int(stack[--sp]);
        for (int side = 0; side < 2; ++side) {
            uvec4 lo = texel_load(Media, b + 2 * side);
            uvec4 hi = texel_load(Media, b + 2 * side + 1);
            if (!boundary_box_hit(uintBitsToFloat(lo.xyz), uintBitsToFloat(hi.xyz), o, inv_dir, from, third)) continue;
            if (hi.w == BVH_INNER) {
                if (sp < BOUNDARY_STACK) stack[sp++] = lo.w;
                continue;
            }
            for (uint i = lo.w; i < lo.w + hi.w; ++i) {
                BvhTriangle tri;
                uvec3 rest;
                texel_vec3x3(Media, triangles + 3 * int(i), tri.v0, tri.e1, tri.e2, rest);
                float t, u, v;
                if (!bvh_hit_triangle(tri, o, d, third, t, u, v) || !(t > from)) continue;
                if (t < first) {
                    third = second;
                    second = first;
                    first = t;
                    enters = dot(cross(tri.e1, tri.e2), d) < 0.0;
                } else if (t < second) {
                    third = second;
                    second = t;
                } else {
                    third = t;
                }
            }
        }
    }
}

// The first part [t0, t1] after `from` of ray (o, d) over [0, tmax] that holds the
// medium: in its box and, where it has a boundary, inside it; false where none does.
// `more`: whether another part follows, after t1 (call again with from = t1).
//
// Inside the boundary: where the ray crosses it first after `from` it leaves (the
// triangle faces along d), or between where it enters and where it crosses next.
bool medium_clip(MediumRecord m, vec3 o, vec3 d, float tmax, float from, out float t0, out float t1, out bool more) {
    // A zero direction component gets a tiny one of its sign (no 0 · ∞).
    vec3 dd = mix(d, vec3(1e-30), equal(d, vec3(0.0)));
    vec3 ta = (m.box_min - o) / dd;
    vec3 tb = (m.box_max - o) / dd;
    vec3 lo = min(ta, tb);
    vec3 hi = max(ta, tb);
    t0 = max(max(lo.x, lo.y), max(lo.z, from));
    t1 = min(min(hi.x, hi.y), min(hi.z, tmax));
    more = false;
    if (m.max_steps == 0u || !(t0 < t1)) return false;
    if (MEDIUM_BOUNDARY) {
        if (m.boundary_texels != 0u) {
            float first, second, third;
            bool enters;
            boundary_crossings(o, d, from, first, second, third, enters);
            // No crossing ahead: outside for good.
            if (first == 3.0e38) return false;
            // Where the part ends, and the crossing after that (where another part
            // begins), if it comes before the box's end.
            more = (enters ? third : second) < t1;
            if (enters) t0 = max(t0, first);
            t1 = min(t1, enters ? second : first);
        }
    }
    return t0 < t1;
}

// The 8 taps of a trilinear lookup at q (unit coordinates in the box) in a grid of
// r.width × r.height × depth voxels: element indices (times `channels`) and weights.
void grid_taps(ValueRef r, uint depth, uint channels, vec3 q, out int index[8], out float weight[8]) {
    vec3 n = vec3(r.width, r.height, depth);
    vec3 g = clamp(q * n - 0.5, vec3(0.0), n - 1.0);
    vec3 f = floor(g);
    vec3 t = g - f;
    ivec3 a = ivec3(f);
    ivec3 b = min(a + 1, ivec3(n) - 1);
    int w = int(r.width), h = int(r.height);
    for (int k = 0; k < 8; ++k) {
        bvec3 hi = bvec3((k & 1) != 0, (k & 2) != 0, (k & 4) != 0);
        ivec3 v = ivec3(mix(a, b, hi));
        vec3 wt = mix(1.0 - t, t, hi);
        index[k] = ((v.z * h + v.y) * w + v.x) * int(channels);
        weight[k] = wt.x * wt.y * wt.z;
    }
}

// A one-channel grid value (a constant where r.width is 0) at q in parameter state `state`.
float grid1(ValueRef r, uint depth, vec3 q, int state) {
    if (r.width == 0u) return value_at(r, 0, state);
    int index[8];
    float weight[8];
    grid_taps(r, depth, 1u, q, index, weight);
    float v = 0.0;
    for (int k = 0; k < 8; ++k) v += weight[k] * value_at(r, index[k], state);
    return v;
}

// A three-channel grid value at q in parameter state `state`.
vec3 grid3(ValueRef r, uint depth, vec3 q, int state) {
    if (r.width == 0u) return value3_at(r, 0, state);
    int index[8];
    float weight[8];
    grid_taps(r, depth, 3u, q, index, weight);
    vec3 v = vec3(0.0);
    for (int k = 0; k < 8; ++k) v += weight[k] * value3_at(r, index[k], state);
    return v;
}

// A ray's march through one part of the medium: the medium, where the ray enters the part
// (t0) and leaves it (t1), its steps, their length and the ray's jitter.
struct March {
    MediumRecord m;
    vec3 o;
    vec3 d;
    float t0;
    float t1;
    bool more; // whether another part follows (medium_clip)
    uint n;
    float dt;
    float u;
};

// The march of ray (o, d) over [0, tmax] through its first part of the medium after
// `from` (medium_clip): stratified steps with one jitter per part, hashed from the ray's
// bits and the part's end (both parameter states and both replays march the same
// points). False where there is none.
bool medium_march(vec3 o, vec3 d, float tmax, float from, out March mr) {
    mr.m = medium_record();
    mr.o = o;
    mr.d = d;
    if (!medium_clip(mr.m, o, d, tmax, from, mr.t0, mr.t1, mr.more)) return false;
    float t1 = mr.t1;
    float len = t1 - mr.t0;
    mr.n = uint(clamp(ceil(len / mr.m.step), 1.0, float(mr.m.max_steps)));
    mr.dt = len / float(mr.n);
    uvec3 ob = floatBitsToUint(o);
    uvec3 db = floatBitsToUint(d);
    mr.u = float(pcg4d(uvec4(ob.x ^ db.y, ob.y ^ db.z, ob.z ^ db.x, floatBitsToUint(t1) ^ 0x4d454449u)).x >> 8u) * (1.0 / 16777216.0);
    return true;
}

// The march of ray (o, d) over [0, tmax] through the part of the medium after march mr's
// part, where one follows (a boundary's): false where none does.
bool march_next_part(vec3 o, vec3 d, float tmax, inout March mr) {
    if (!mr.more) return false;
    float from = mr.t1;
    return medium_march(o, d, tmax, from, mr);
}

// Where step k's sample point lies, in the box's unit coordinates.
vec3 march_point(March mr, uint k) {
    vec3 p = mr.o + (mr.t0 + (float(k) + mr.u) * mr.dt) * mr.d;
    return (p - mr.m.box_min) / (mr.m.box_max - mr.m.box_min);
}

#ifdef ADJOINT
void grid_scatter1(ValueRef r, uint depth, vec3 q, float g) {
    if ((r.flags & VALUE_IN_THETA) == 0u || g == 0.0) return;
    if (r.width == 0u) {
        grad_add(r.offset, g);
        return;
    }
    int index[8];
    float weight[8];
    grid_taps(r, depth, 1u, q, index, weight);
    for (int k = 0; k < 8; ++k) {
        if (weight[k] != 0.0) grad_add(r.offset + index[k], weight[k] * g);
    }
}

void grid_scatter3(ValueRef r, uint depth, vec3 q, vec3 g) {
    if ((r.flags & VALUE_IN_THETA) == 0u || all(equal(g, vec3(0.0)))) return;
    int index[8];
    float weight[8];
    if (r.width == 0u) {
        index[0] = 0;
        weight[0] = 1.0;
        for (int k = 1; k < 8; ++k) weight[k] = 0.0;
    } else {
        grid_taps(r, depth, 3u, q, index, weight);
    }
    for (int k = 0; k < 8; ++k) {
        if (weight[k] == 0.0) continue;
        int base = r.offset + index[k];
        grad_add(base, weight[k] * g.x);
        grad_add(base + 1, weight[k] * g.y);
        grad_add(base + 2, weight[k] * g.z);
    }
}
#endif

// One part of medium_segment: march mr's steps.
void segment_part(March mr, inout vec3 beta[NSTATES], inout vec3 radiance[NSTATES]
#ifdef ADJOINT
                  , inout vec3 remaining[NSTATES], vec3 delta[NSTATES], bool grad_pass
#endif
) {
    MediumRecord m = mr.m;
    float dt = mr.dt;
    for (uint k = 0u; k < mr.n; ++k) {
        vec3 q = march_point(mr, k);
#ifdef ADJOINT
        float g_sigma = 0.0;
        vec3 g_le = vec3(0.0);
#endif
        for (int s = 0; s < NSTATES; ++s) {
            float sigma = m.scale * grid1(m.density, m.density_depth, q, s);
            vec3 le = grid3(m.emission, m.emission_depth, q, s);
            float a = exp(-sigma * dt);
            vec3 c = beta[s] * le * (1.0 - a);
            radiance[s] += c;
#ifdef ADJOINT
            vec3 kd = state_sign(s) * delta[s];
            g_sigma += dot(kd, dt * (beta[s] * le - remaining[s]));
            g_le += kd * beta[s] * (1.0 - a);
            remaining[s] -= c;
#endif
            beta[s] *= a;
        }
#ifdef ADJOINT
        if (grad_pass) {
            grid_scatter1(m.density, m.density_depth, q, g_sigma * m.scale);
            grid_scatter3(m.emission, m.emission_depth, q, g_le);
        }
#endif
    }
}

// The medium along [0, tmax] of a path's ray (o, d): each state's emission gathered into
// radiance (times beta) and beta attenuated. ADJOINT: also takes the emission off
// remaining[] and, in the gradient replay, scatters the derivatives above.
void medium_segment(vec3 o, vec3 d, float tmax, inout vec3 beta[NSTATES], inout vec3 radiance[NSTATES]
#ifdef ADJOINT
                    , inout vec3 remaining[NSTATES], vec3 delta[NSTATES], bool grad_pass
#endif
) {
    March mr;
    if (!medium_march(o, d, tmax, 0.0, mr)) return;
#ifdef ADJOINT
    segment_part(mr, beta, radiance, remaining, delta, grad_pass);
#else
    segment_part(mr, beta, radiance);
#endif
    // The boundary's further parts (compiled out without one: one part, one loop).
    if (MEDIUM_BOUNDARY) {
        for (uint part = 1u; part < MEDIUM_MAX_PARTS && march_next_part(o, d, tmax, mr); ++part) {
#ifdef ADJOINT
            segment_part(mr, beta, radiance, remaining, delta, grad_pass);
#else
            segment_part(mr, beta, radiance);
#endif
        }
    }
}

#ifdef SCATTERING
// The most tentative collisions one tracking loop takes (σ̄ times the box's diagonal is
// far below this in any scene that renders in reasonable time; a loop cut here is biased).
const uint TRACKING_MAX = 65536u;

// The extinction of state s at q for tracking: scale × density, kept below 0.99 times
// the majorant mj of q's cell (which lies 20 % above what the density can take there, so
// the bound never binds), so that the null collisions' weights (σ̄ − σ_1)/(σ̄ − σ_0) stay
// finite.
float tracked_sigma(MediumRecord m, vec3 q, int s, float mj) {
    return min(m.scale * grid1(m.density, m.density_depth, q, s), 0.99 * mj);
}

// The majorant's cells along a ray: where it is, and where it crosses the next cell
// boundary on each axis (the rest, recomputed from the record and the ray where needed,
// so that little stays live through the tracking loops).
struct MajorantWalk {
    ivec3 cell;
    vec3 t_next;
    float t_end; // the ray's end in the box
};

// The majorant grid's cells per axis (0 where the medium has none).
ivec3 majorant_cells(MediumRecord m) {
    return ivec3(m.majorant_cells & 1023u, (m.majorant_cells >> 10) & 1023u, m.majorant_cells >> 20);
}

// Ray direction d in cell coordinates per unit length, with no zero component (a
// vanishing one crosses no boundary: its next one stays at 3e38).
vec3 walk_rate(MediumRecord m, vec3 d) {
    vec3 b = d * (vec3(majorant_cells(m)) / (m.box_max - m.box_min));
    return mix(b, vec3(1e-30), equal(b, vec3(0.0)));
}

// The walk of ray (o, d) from t0, where it enters the box, to t1.
MajorantWalk majorant_walk(MediumRecord m, vec3 o, vec3 d, float t0, float t1) {
    MajorantWalk w;
    w.t_end = t1;
    w.cell = ivec3(0);
    w.t_next = vec3(3.0e38);
    if (MAJORANT_GRID) {
        if (m.majorant_cells != 0u) {
            // Cell coordinates along the ray: a + t b. Per axis (with no indexing by a
            // variable, which lavapipe spills to memory): the next boundary ahead.
            ivec3 cells = majorant_cells(m);
            vec3 a = (o - m.box_min) * (vec3(cells) / (m.box_max - m.box_min));
            vec3 b = walk_rate(m, d);
            w.cell = clamp(ivec3(floor(a + t0 * b)), ivec3(0), cells - 1);
            vec3 ahead = vec3(w.cell) + vec3(greaterThan(b, vec3(0.0)));
            w.t_next = min((ahead - a) / b, vec3(3.0e38));
        }
    }
    return w;
}

// The majorant of the walk's cell.
float walk_majorant(MediumRecord m, MajorantWalk w) {
    ivec3 cells = majorant_cells(m);
    int j = (w.cell.z * cells.y + w.cell.y) * cells.x + w.cell.x;
    return uintBitsToFloat(texel_load(Media, majorant_grid_texel(m) + j).x);
}

// Where the ray leaves the walk's cell (the ray's end at the last).
float walk_cell_end(MajorantWalk w) {
    return min(min(w.t_next.x, w.t_next.y), min(w.t_next.z, w.t_end));
}

// Into the next cell along ray direction d. A step out of the grid (rounding, at the
// box's faces) stays in the last cell on that axis.
void walk_advance(MediumRecord m, vec3 d, inout MajorantWalk w) {
    vec3 b = walk_rate(m, d);
    bvec3 first = bvec3(w.t_next.x <= w.t_next.y && w.t_next.x <= w.t_next.z, false, false);
    first.y = !first.x && w.t_next.y <= w.t_next.z;
    first.z = !first.x && !first.y;
    w.cell += ivec3(first) * ivec3(sign(b));
    w.t_next += vec3(first) * min(1.0 / abs(b), vec3(3.0e38));
    ivec3 cells = majorant_cells(m);
    bvec3 out_of_grid = bvec3(ivec3(lessThan(w.cell, ivec3(0))) | ivec3(greaterThanEqual(w.cell, cells)));
    w.cell = clamp(w.cell, ivec3(0), cells - 1);
    w.t_next = mix(w.t_next, vec3(3.0e38), out_of_grid);
}

// The next tentative collision along the walk from t: spends the optical depth tau of
// the majorant cell by cell, and returns true with t at the collision and mj its cell's
// majorant, or false at the ray's end.
bool next_tentative(MediumRecord m, vec3 d, inout MajorantWalk w, inout float t, float tau, out float mj) {
    if (MAJORANT_GRID) {
        if (m.majorant_cells != 0u) {
            for (uint i = 0u; i < TRACKING_MAX; ++i) {
                mj = walk_majorant(m, w);
                float te = walk_cell_end(w);
                float room = mj * max(te - t, 0.0);
                if (tau < room) {
                    t += tau / mj;
                    return true;
                }
                if (te >= w.t_end) return false;
                tau -= room;
                t = te;
                walk_advance(m, d, w);
            }
            return false;
        }
    }
    // One majorant over the box: no cells to walk (none at all where it is 0).
    mj = m.majorant;
    if (!(mj > 0.0)) return false;
    t += tau / mj;
    return t < w.t_end;
}

// Whether ray (o, d) over [0, tmax] crosses a part of the tracked medium after `from`: the
// part [t0, t1] (medium_clip) and its walk. A medium of no density anywhere is crossed
// too: it stops nothing, but its density's derivatives along the ray are not 0.
bool medium_tracked(MediumRecord m, vec3 o, vec3 d, float tmax, float from, out float t0, out float t1, out bool more, out MajorantWalk w) {
    if (!medium_clip(m, o, d, tmax, from, t0, t1, more)) return false;
    w = majorant_walk(m, o, d, t0, t1);
    return true;
}

// The part of the tracked medium after part [t0, t1] of ray (o, d), where one follows (a
// boundary's): the part, its `more` and its walk in place of the last's; false where none
// does.
bool tracked_next_part(MediumRecord m, vec3 o, vec3 d, float tmax, inout float t0, inout float t1, inout bool more, inout MajorantWalk w) {
    if (!more) return false;
    float from = t1;
    return medium_tracked(m, o, d, tmax, from, t0, t1, more, w);
}

// The exponential optical depth of tracking draw u.
float tracking_depth(vec2 u) {
    return -log(1.0 - u.x);
}

// The i-th pair of uniform numbers in [0, 1) of tracking stream `key`.
vec2 tracking_uniforms(uvec4 key, uint i) {
    uvec4 h = pcg4d(uvec4(key.x, key.y, key.z ^ i, key.w + i * 0x9e3779b9u));
    return vec2(h.xy >> 8u) * (1.0 / 16777216.0);
}

// The tracking stream of ray (o, d) with salt `salt`.
uvec4 tracking_key(vec3 o, vec3 d, uint salt) {
    uvec3 ob = floatBitsToUint(o);
    uvec3 db = floatBitsToUint(d);
    return uvec4(ob.x ^ db.y, ob.y ^ db.z, ob.z ^ db.x, salt);
}

#ifdef ADJOINT
// Scatters g ∫ dσ over [ta, tb] of ray (o, d), the integral estimated at n stratified
// points (one offset hashed from `key`, apart from its tracking numbers): each point
// scatters g (tb − ta) / n. Unbiased for any n.
void medium_integral_grad(MediumRecord m, vec3 o, vec3 d, float ta, float tb, uint n, uvec4 key, float g) {
    if (g == 0.0 || !(tb > ta)) return;
    float len = (tb - ta) / float(n);
    float u = tracking_uniforms(uvec4(key.xyz, key.w ^ 0x494e5447u), TRACKING_MAX).x;
    vec3 extent = m.box_max - m.box_min;
    for (uint k = 0u; k < n; ++k) {
        vec3 q = (o + (ta + (float(k) + u) * len) * d - m.box_min) / extent;
        grid_scatter1(m.density, m.density_depth, q, g * len);
    }
}
#endif

// Delta tracking over one part [t0, t1] of a flight (medium_free_flight), its draws from
// `draw` on in stream `key` (draw is left after the part's: memoryless, the next part
// starts afresh): whether it collides, at ts and q_hit (unit coordinates), with each
// state's weight w multiplied as there. ADJOINT: the collision's term, and the part's
// −∫ dσ at as many stratified points as it had tentative collisions.
bool flight_part(MediumRecord m, vec3 o, vec3 d, float t0, float t1, MajorantWalk walk, uvec4 key, inout uint draw, inout float w[NSTATES], inout float ts, inout vec3 q_hit
#ifdef ADJOINT
                 , float gs[NSTATES], float g_all, bool grad_pass
#endif
) {
    vec3 extent = m.box_max - m.box_min;
    bool collided = false;
    float t = t0;
    uint tentative = 0u;
    for (uint i = 0u; i < TRACKING_MAX; ++i) {
        vec2 u = tracking_uniforms(key, draw + i);
        float mj;
        if (!next_tentative(m, d, walk, t, tracking_depth(u), mj)) break;
        vec3 q = (o + t * d - m.box_min) / extent;
        float sigma[NSTATES];
        for (int s = 0; s < NSTATES; ++s) sigma[s] = tracked_sigma(m, q, s, mj);
        tentative = i + 1u;
        if (u.y * mj < sigma[0]) {
            for (int s = 1; s < NSTATES; ++s) w[s] *= sigma[s] / sigma[0];
            collided = true;
            ts = t;
            q_hit = q;
#ifdef ADJOINT
            if (grad_pass) {
                float g = 0.0;
                for (int s = 0; s < NSTATES; ++s) {
                    if (sigma[s] > 0.0) g += gs[s] / sigma[s];
                }
                grid_scatter1(m.density, m.density_depth, q, g * m.scale);
            }
#endif
            break;
        }
        for (int s = 1; s < NSTATES; ++s) w[s] *= (mj - sigma[s]) / (mj - sigma[0]);
    }
#ifdef ADJOINT
    // The transmittance's part: −∫ dσ over the flight, estimated at as many stratified
    // points as it had tentative collisions (one offset, from a stream of its own:
    // independent of the tracking, so the product stays unbiased).
    if (grad_pass) medium_integral_grad(m, o, d, t0, collided ? ts : t1, max(tentative, 1u), key, -g_all * m.scale);
#endif
    draw += tentative + 1u;
    return collided;
}

// A scattering medium along [0, tmax] of a path's ray (o, d): where the ray first
// collides, delta-tracked with state 0's extinction (the stream's salt is the path's
// u_flight), part by part. Returns whether it collides, at distance ts, and weighs each
// state's beta by its own probability of this outcome over state 0's: per null collision
// (σ̄ − σ_s)/(σ̄ − σ_0), and at the real one albedo_s σ_s / σ_0 (σ_0 at most 0.99 σ̄: no
// division by a vanishing number).
// ADJOINT, gradient replay: the derivative of each state's log-probability of the flight
// (σ_s(x) e^(−∫σ_s)) with the sampling held fixed (detached), times g_s = sign_s δ_s ·
// remaining_s (everything the path gathers from here on): +1/σ_s at the collision, and
// −∫ dσ along the flight at stratified points (medium_integral_grad; the null collisions'
// −1/(σ̄ − σ) would estimate it too, with a variance that grows as σ̄ approaches σ); each
// times the scale and scattered to the point's 8 voxels. And the albedo's, looked up at
// the collision point: remaining / albedo per channel.
bool medium_free_flight(vec3 o, vec3 d, float tmax, float u_flight, inout vec3 beta[NSTATES], out float ts
#ifdef ADJOINT
                        , vec3 remaining[NSTATES], vec3 delta[NSTATES], bool grad_pass
#endif
) {
    ts = 0.0;
    MediumRecord m = medium_record();
    float t0, t1;
    bool more;
    MajorantWalk walk;
    if (!medium_tracked(m, o, d, tmax, 0.0, t0, t1, more, walk)) return false;
#ifdef ADJOINT
    float gs[NSTATES];
    float g_all = 0.0;
    for (int s = 0; s < NSTATES; ++s) {
        gs[s] = grad_pass ? state_sign(s) * dot(delta[s], remaining[s]) : 0.0;
        g_all += gs[s];
    }
#endif
    uvec4 key = tracking_key(o, d, floatBitsToUint(u_flight));
    float w[NSTATES];
    for (int s = 0; s < NSTATES; ++s) w[s] = 1.0;
    vec3 q_hit = vec3(0.0);
    uint draw = 0u;
#ifdef ADJOINT
#define FLIGHT_PART() flight_part(m, o, d, t0, t1, walk, key, draw, w, ts, q_hit, gs, g_all, grad_pass)
#else
#define FLIGHT_PART() flight_part(m, o, d, t0, t1, walk, key, draw, w, ts, q_hit)
#endif
    // The first part, then the boundary's others (compiled out without one: a loop
    // around the tracking loop, even run once, costs a box 7 % of its instructions).
    bool collided = FLIGHT_PART();
    if (MEDIUM_BOUNDARY) {
        for (uint part = 1u; part < MEDIUM_MAX_PARTS && !collided && tracked_next_part(m, o, d, tmax, t0, t1, more, walk); ++part) collided = FLIGHT_PART();
    }
#undef FLIGHT_PART
    // The collision's albedo, each state's own, scales its beta.
    vec3 albedo_hit[NSTATES];
    for (int s = 0; s < NSTATES; ++s) {
        if (collided) {
            albedo_hit[s] = grid3(m.albedo, m.albedo_depth, q_hit, s);
            beta[s] *= albedo_hit[s] * w[s];
        } else {
            beta[s] *= w[s];
        }
    }
#ifdef ADJOINT
    // The albedo scales everything the path gathers after the collision: d/dα of each
    // state's remaining radiance is remaining / α, per channel (0 where α is 0, which
    // ends the channel's path).
    if (grad_pass && collided) {
        vec3 g_albedo = vec3(0.0);
        for (int s = 0; s < NSTATES; ++s) {
            bvec3 live = greaterThan(albedo_hit[s], vec3(0.0));
            vec3 per_albedo = mix(vec3(0.0), remaining[s] / albedo_hit[s], live);
            g_albedo += state_sign(s) * delta[s] * per_albedo;
        }
        grid_scatter3(m.albedo, m.albedo_depth, q_hit, g_albedo);
    }
#endif
    return collided;
}

// Salt of a shadow ray's ratio-tracking stream (with the ray's bits and its end).
const uint SHADOW_SALT = 0x52415449u;

// Ratio tracking over one part, from t0, of shadow ray (o, d) (medium_transmittance), its
// draws from `draw` on in stream `key` (left after the part's): each state's tr
// multiplied by its factors. False once nothing is left to carry.
bool ratio_part(MediumRecord m, vec3 o, vec3 d, float t0, MajorantWalk walk, uvec4 key, inout uint draw, inout float tr[NSTATES]) {
    vec3 extent = m.box_max - m.box_min;
    float t = t0;
    uint i = 0u;
    for (; i < TRACKING_MAX; ++i) {
        float mj;
        if (!next_tentative(m, d, walk, t, tracking_depth(tracking_uniforms(key, draw + i)), mj)) break;
        vec3 q = (o + t * d - m.box_min) / extent;
        float most = 0.0;
        for (int s = 0; s < NSTATES; ++s) {
            tr[s] *= 1.0 - tracked_sigma(m, q, s, mj) / mj;
            most = max(most, tr[s]);
        }
        // Nothing left to carry (the factors are at least 0.01: only after thousands).
        if (most == 0.0) return false;
    }
    draw += i + 1u;
    return true;
}

// Each state's transmittance along [0, tmax] of shadow ray (o, d) (1 outside the box), by
// ratio tracking: the product of 1 − σ_s/σ̄ over tentative collisions at rate σ̄ (shared
// by the states: one stream per ray, hashed from its bits and end).
void medium_transmittance(vec3 o, vec3 d, float tmax, out float tr[NSTATES]) {
    for (int s = 0; s < NSTATES; ++s) tr[s] = 1.0;
    MediumRecord m = medium_record();
    float t0, t1;
    bool more;
    MajorantWalk walk;
    if (!medium_tracked(m, o, d, tmax, 0.0, t0, t1, more, walk)) return;
    // One stream per ray, keyed by its first part's end, over all its parts.
    uvec4 key = tracking_key(o, d, floatBitsToUint(t1) ^ SHADOW_SALT);
    uint draw = 0u;
    // The first part, then the boundary's others (as in medium_free_flight).
    bool left = ratio_part(m, o, d, t0, walk, key, draw, tr);
    if (MEDIUM_BOUNDARY) {
        for (uint part = 1u; part < MEDIUM_MAX_PARTS && left && tracked_next_part(m, o, d, tmax, t0, t1, more, walk); ++part) {
            left = ratio_part(m, o, d, t0, walk, key, draw, tr);
        }
    }
}

#ifdef ADJOINT
// Scatters g ∫ dσ over one part [t0, t1] of shadow ray (o, d) (medium_transmittance_grad)
// at as many stratified points as its ratio tracking had tentative collisions, counted
// from the same draws (distances alone, no density lookups); draw is left after them.
void integral_grad_part(MediumRecord m, vec3 o, vec3 d, float t0, float t1, MajorantWalk walk, uvec4 key, inout uint draw, float g) {
    uint n = 0u;
    float t = t0;
    for (uint i = 0u; i < TRACKING_MAX; ++i) {
        float mj;
        if (!next_tentative(m, d, walk, t, tracking_depth(tracking_uniforms(key, draw + i)), mj)) break;
        n = i + 1u;
    }
    medium_integral_grad(m, o, d, t0, t1, max(n, 1u), key, g);
    draw += n + 1u;
}

// Scatters the derivative of the loss through the ratio-tracked transmittance of shadow
// ray (o, d) over [0, tmax], given g_s = sign_s ⟨δ_s, c_s⟩ of the contributions c_s that
// it carried: dc_s = −c_s ∫ dσ_s, the integral estimated at as many stratified points as
// the tracking had tentative collisions (medium_integral_grad), independent of them.
void medium_transmittance_grad(vec3 o, vec3 d, float tmax, float g[NSTATES]) {
    float g_all = 0.0;
    for (int s = 0; s < NSTATES; ++s) g_all += g[s];
    MediumRecord m = medium_record();
    float t0, t1;
    bool more;
    MajorantWalk walk;
    if (g_all == 0.0 || !medium_tracked(m, o, d, tmax, 0.0, t0, t1, more, walk)) return;
    uvec4 key = tracking_key(o, d, floatBitsToUint(t1) ^ SHADOW_SALT);
    uint draw = 0u;
    // The first part, then the boundary's others (as in medium_free_flight).
    integral_grad_part(m, o, d, t0, t1, walk, key, draw, -g_all * m.scale);
    if (MEDIUM_BOUNDARY) {
        for (uint part = 1u; part < MEDIUM_MAX_PARTS && tracked_next_part(m, o, d, tmax, t0, t1, more, walk); ++part) {
            integral_grad_part(m, o, d, t0, t1, walk, key, draw, -g_all * m.scale);
        }
    }
}
#endif

// The Henyey-Greenstein phase function of mean cosine g between the propagation
// directions d (in) and wi (out), per steradian.
float hg_phase(float g, vec3 d, vec3 wi) {
    float c = dot(d, wi);
    float den = 1.0 + g * g - 2.0 * g * c;
    return (1.0 - g * g) / (4.0 * 3.14159265358979 * den * sqrt(den));
}

// A direction sampled from the Henyey-Greenstein phase function around d (its density is
// hg_phase(g, d, wi)).
vec3 hg_sample(float g, vec3 d, vec2 u) {
    float c;
    if (abs(g) < 1e-3) {
        c = 1.0 - 2.0 * u.x;
    } else {
        float s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u.x);
        c = (1.0 + g * g - s * s) / (2.0 * g);
    }
    c = clamp(c, -1.0, 1.0);
    float sn = sqrt(max(0.0, 1.0 - c * c));
    float phi = 2.0 * 3.14159265358979 * u.y;
    ShadingFrame f = shading_frame(d);
    return shading_to_world(f, vec3(sn * cos(phi), sn * sin(phi), c));
}
#endif

#ifndef SCATTERING
// Adds each state's optical depth over march mr's part to tau.
void optical_depth_part(March mr, inout float tau[NSTATES]) {
    for (uint k = 0u; k < mr.n; ++k) {
        vec3 q = march_point(mr, k);
        for (int s = 0; s < NSTATES; ++s) tau[s] += mr.m.scale * grid1(mr.m.density, mr.m.density_depth, q, s) * mr.dt;
    }
}

// Each state's transmittance along [0, tmax] of shadow ray (o, d) (1 outside the box).
void medium_transmittance(vec3 o, vec3 d, float tmax, out float tr[NSTATES]) {
    for (int s = 0; s < NSTATES; ++s) tr[s] = 1.0;
    March mr;
    if (!medium_march(o, d, tmax, 0.0, mr)) return;
    float tau[NSTATES];
    for (int s = 0; s < NSTATES; ++s) tau[s] = 0.0;
    optical_depth_part(mr, tau);
    if (MEDIUM_BOUNDARY) {
        for (uint part = 1u; part < MEDIUM_MAX_PARTS && march_next_part(o, d, tmax, mr); ++part) optical_depth_part(mr, tau);
    }
    for (int s = 0; s < NSTATES; ++s) tr[s] = exp(-tau[s]);
}

#ifdef ADJOINT
// Scatters g times the derivative of the optical depth over march mr's part.
void optical_depth_grad_part(March mr, float g) {
    for (uint k = 0u; k < mr.n; ++k) grid_scatter1(mr.m.density, mr.m.density_depth, march_point(mr, k), -mr.dt * mr.m.scale * g);
}

// Scatters the derivative of the loss through the transmittance of shadow ray (o, d) over
// [0, tmax], given g_s = sign_s ⟨δ_s, c_s⟩ of the contributions c_s that it carried (all
// states share the march: their sum).
void medium_transmittance_grad(vec3 o, vec3 d, float tmax, float gs[NSTATES]) {
    float g = 0.0;
    for (int s = 0; s < NSTATES; ++s) g += gs[s];
    March mr;
    if (g == 0.0 || !medium_march(o, d, tmax, 0.0, mr)) return;
    optical_depth_grad_part(mr, g);
    if (MEDIUM_BOUNDARY) {
        for (uint part = 1u; part < MEDIUM_MAX_PARTS && march_next_part(o, d, tmax, mr); ++part) optical_depth_grad_part(mr, g);
    }
}

#endif
#endif

#ifdef ADJOINT
// sign_s ⟨δ_s, after_s − before_s⟩ per state: what medium_transmittance_grad needs of a
// light sample that added after − before to each state's radiance.
void medium_sample_weights(vec3 before[NSTATES], vec3 after[NSTATES], vec3 delta[NSTATES], out float g[NSTATES]) {
    for (int s = 0; s < NSTATES; ++s) g[s] = state_sign(s) * dot(delta[s], after[s] - before[s]);
}
#endif
#endif
