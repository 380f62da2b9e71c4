// Unidirectional path tracer with next-event estimation and multiple importance sampling,
// written once for the primal and the adjoint pass (path replay backpropagation, Vicini
// et al. 2021; the bookkeeping follows Mitsuba 3's prb integrator): the adjoint pass
// replays each path from its seed knowing the path's total radiance L, subtracts what
// each vertex emits or gathers directly, and attributes the remainder to the BSDF that
// scattered it. Sampling, MIS weights and Russian roulette are detached (constants with
// respect to the parameters), which keeps the material and emission gradients unbiased.
//
// FD (the fused finite-difference sample of the meta-estimator, Bálint et al. 2023):
// each path is sampled once with θ_i (state 0) and evaluated in both states. State 1
// (θ_{i-1}) follows the same vertices; at each BSDF sample its throughput is multiplied
// by f_{i-1}(wo, wi) / pdf_i(wi) instead of f_i / pdf_i: a shift that accounts for BSDF
// sampling, unbiased for θ_{i-1} wherever pdf_i > 0. Light sampling, MIS weights and
// Russian roulette come from state 0 and are shared, so every random choice is common.
// The adjoint variant scatters +gradient of state 0 and −gradient of state 1: the
// difference of gradients with common random numbers, ⟨ΔF_i⟩.
//
// Next-event estimation samples either an emissive triangle or (HAS_ENVIRONMENT and
// scene_globals().environment_sample_prob > 0) a direction from the environment map, picked by the
// bounce's eighth random number with probability environment_sample_prob for the map.
// Emission found by BSDF sampling (an emitter hit or an escaped ray) is MIS-weighted
// against the light-sampling density of the strategy that could have produced it, times
// the probability of picking that strategy. The map's distribution is built once on the
// host and does not depend on θ (src/render/envmap.rs), so it is detached like the rest.
//
// A dielectric vertex (HAS_DIELECTRICS) has delta lobes: it takes no light sample, its
// continuation is dielectric_sample's mirror or refraction (through the surface: the ray
// leaves from the far side), and the emission that continuation finds is not MIS-weighted,
// as seen by the camera. Its interior is on the back of its triangles (their clockwise
// side): a ray arriving from behind leaves the interior, so the relative index inverts
// (a thin dielectric has the same medium on both sides and keeps it).
// Its other states take the same lobe: their weights are their masses over state 0's
// probability, the lobe's choice shared like every other. A refraction into a dielectric's
// interior sets the path's absorption coefficient to the material's, one out of it back to
// 0 (the camera is outside every interior; nested interiors are not tracked), and each ray
// of the path keeps exp(-absorption t) over its length t (none if it escapes the scene
// inside). Light samples are not attenuated: they never cross glass, and a vertex inside
// an interior (an object embedded in glass) takes them as if in air.
//
// A rough dielectric vertex (HAS_ROUGH_DIELECTRICS) is no delta: its lobes go through the
// generic BSDF functions, which evaluate its transmission for directions below the surface.
// It takes light samples on both sides (a shadow ray below the surface leaves from the far
// side), and its continuation, on either side, is MIS-weighted as any other; a direction
// counts only where the geometric and the shading normal put it on the same side. Its
// index inverts and its interior's absorption switches as a smooth dielectric's.
//
// Depth convention (Mitsuba's): MAX_DEPTH = 1 sees emitters only, 2 adds direct light.
#ifndef INTEGRATOR_GLSL
#define INTEGRATOR_GLSL
#include "lib/rng.glsl"
#include "lib/sampling.glsl"
#include "lib/scene_access.glsl"
// The BSDF functions test for the rough dielectric, the conductor and the plastic only
// where the scene has one.
#define BSDF_ROUGH_DIELECTRICS HAS_ROUGH_DIELECTRICS
#define BSDF_CONDUCTORS HAS_CONDUCTORS
#define BSDF_PLASTICS HAS_PLASTICS
#include "lib/bsdf.glsl"

// A plastic's table entries (lib/bsdf.glsl) are material data: constants after θ.
float bsdf_table(uint table, int index) { return texel_float(Theta, int(CONST_BASE) + int(table) + index); }

// The shading normal at a point of triangle `sh` with texture coordinates uv and unit
// normal n (interpolated, or geometric), bent by bump map `r` (the material's) as Mitsuba's
// `bumpmap` does: dp/du and dp/dv, less their parts along n, gain n times the height's
// derivatives in u and v, and the normal is their cross product. Written with the
// world-space gradients of u and v on the triangle (∇u, ∇v: the triangle's tangent
// record, in the basis shading_frame(ng) builds) and the height's gradient g = h_u ∇u +
// h_v ∇v, that normal is along n − g + ng (m·g)/(n·ng), m = n − (n·ng) ng: n − g where n
// is the geometric normal. The heights are bilinear in each texel (a nearest-filtered
// field has no slope, and leaves n), and their derivatives those of the interpolation, as
// Mitsuba's eval_1_grad.
vec3 bump_mapped(TriShading sh, ValueRef r, vec3 n, SurfaceUv uv) {
    if ((r.flags & VALUE_NEAREST) != 0u) return n;
    ivec4 texel;
    vec4 w;
    footprint(r, uv_of(r, uv), texel, w);
    float h00 = value_at(r, texel.x, 0), h10 = value_at(r, texel.y, 0);
    float h01 = value_at(r, texel.z, 0), h11 = value_at(r, texel.w, 0);
    // The interpolation's fractions (footprint's weights are their products); texel rows
    // run down the image, against v.
    float tx = w.y + w.w, ty = w.z + w.w;
    float hu = float(r.width) * mix(h10 - h00, h11 - h01, ty);
    float hv = -float(r.height) * mix(h01 - h00, h11 - h10, tx);
    ShadingFrame f = shading_frame(sh.ng);
    vec3 g = hu * (sh.tangent.x * f.t + sh.tangent.y * f.b) + hv * (sh.tangent.z * f.t + sh.tangent.w * f.b);
    float a = dot(n, sh.ng);
    if (abs(a) < 1e-6) return n;
    vec3 v = n - g + sh.ng * (dot(n - a * sh.ng, g) / a);
    if (dot(v, v) > 0.0) return normalize(v);
    return n;
}

// n perturbed by the material's normal map (normal_mapped, lib/scene_access.glsl) or bump
// map (bump_mapped), which share the material record's slot (a bump map's heights flagged
// VALUE_BUMP); n itself where the material has neither.
vec3 perturbed_normal(TriShading sh, vec3 n, SurfaceUv uv) {
    // (Not `if (!HAS_NORMAL_MAPS) return n;`: the reflection cannot fold the negation of a
    // specialisation constant.)
    if (HAS_NORMAL_MAPS) {
        ValueRef r = material_record(sh.material).normal_map;
        if (r.width != 0u) return (r.flags & VALUE_BUMP) != 0u ? bump_mapped(sh, r, n, uv) : normal_mapped(sh, r, n, uv);
    }
    return n;
}
#include "lib/bvh_traverse.glsl"

#ifdef GENERIC
// The unspecialised build (variant trace_primal_generic) that `vkinverse bench` times
// against the specialised one: the same values, read at run time as a pipeline shared by
// every scene would read them, so both render the same image.
layout(set = 0, binding = 41, scalar) readonly buffer IntegratorLimits {
    uint limit_max_depth;
    uint limit_rr_depth;
    uint limit_num_emitters;
    uint limit_flags;   // bit 0: HAS_ENVIRONMENT, bit 1: HIDE_EMITTERS
};
#define MAX_DEPTH limit_max_depth
#define RR_DEPTH limit_rr_depth
#define NUM_EMITTERS limit_num_emitters
#define HAS_ENVIRONMENT ((limit_flags & 1u) != 0u)
#define HIDE_EMITTERS ((limit_flags & 2u) != 0u)
#define ENVIRONMENT_SAMPLED HAS_ENVIRONMENT
#define CACHE_ALL false
#define SPHERE_EMITTERS true
#else
layout(constant_id = 1) const uint MAX_DEPTH = 6;
layout(constant_id = 2) const uint RR_DEPTH = 5;
// 0: no emissive triangles, light sampling is compiled out. (Tests on specialization
// constants use == and != only: spirq, which reflects the SPIR-V, cannot fold other
// comparisons of them.)
layout(constant_id = 3) const uint NUM_EMITTERS = 0;
// Whether an emitter is a sphere sampled by its solid angle (src/render/features/
// emitters.rs); false compiles those samples out.
layout(constant_id = 25) const bool SPHERE_EMITTERS = false;
layout(constant_id = 4) const bool HAS_ENVIRONMENT = false;
// Whether next-event estimation may sample the environment (a lat-long map: it has a
// sampling distribution); false compiles that strategy out, which a constant environment
// never uses. lavapipe would otherwise run it, masked, at every path vertex, shadow ray
// included (docs/lavapipe.md).
layout(constant_id = 10) const bool ENVIRONMENT_SAMPLED = false;
// Whether every ray cast of a path fits the adjoint kernels' cache (MAX_DEPTH <=
// CACHED_BOUNCES, set by the host): then the gradient replay's test for a cached cast is
// the constant `replay`, and the compiler drops the replay's traversal, which lavapipe
// would otherwise enter, masked, at every vertex (docs/lavapipe.md). Only the adjoint
// kernels use it (the compiler drops it from the others).
layout(constant_id = 11) const bool CACHE_ALL = false;
// Whether emitters seen directly are hidden (Mitsuba's hide_emitters): camera rays pass
// through every emitting mesh (cast_closest) and find no environment (trace_path).
layout(constant_id = 23) const bool HIDE_EMITTERS = false;
#endif

#ifdef COUNT_RAYS
// Variant trace_primal_count: every ray cast is counted, one counter per workgroup so that
// the atomics spread over many addresses; `vkinverse bench` sums them for its rays/s.
layout(set = 0, binding = 40, scalar) buffer RayCount { uint ray_count[]; };
#endif

#ifdef ADJOINT
// The adjoint kernels replay every path twice: once to learn its radiance L, once to
// scatter gradients. Both replays draw the same numbers and so cast the same rays; the
// second takes the results of the first path vertices' casts from this cache instead of
// traversing the BVH again, which leaves the gradient pass about one trace instead of two.
// Memory stays constant per thread (path replay's point): vertices past the cache are
// traced again as before. Depth d's closest hit is cached_hits[d - 1]; bit d - 1 of
// cached_shadow says whether depth d's shadow ray was blocked. The replay is the constant
// argument `replay` of trace_path, so that with CACHE_ALL the cached test folds away.
#include "vkinverse_constants.glsl"  // CACHED_BOUNCES
Hit cached_hits[CACHED_BOUNCES];
uint cached_shadow;
#endif

// trace_closest and trace_any as the integrator casts them at path depth `depth` (counted
// in COUNT_RAYS). `replay` (adjoint kernels only; a constant at each call): take the result
// of the first replay's cast from the cache; otherwise cast, and cache the result in the
// adjoint kernels.
bool cast_closest(vec3 o, vec3 d, float tmax, uint depth, bool replay, out Hit hit) {
#ifdef ADJOINT
    if (replay && (CACHE_ALL || depth <= CACHED_BOUNCES)) {
        hit = cached_hits[depth - 1u];
        return hit.prim != BVH_NO_HIT;
    }
#endif
#ifdef COUNT_RAYS
    atomicAdd(ray_count[workgroup_index()], 1u);
#endif
    bool found = trace_closest(o, d, tmax, hit);
    // Hidden emitters: a camera ray goes on through each emitting mesh it meets, from the
    // hit along the same line, as Mitsuba's skip_area_emitters (t counts from o).
    if (HIDE_EMITTERS && depth == 1u) {
        float skipped = 0.0;
        while (found && (tri_emitter_flags(hit.prim) & EMITTER_MESH) != 0u) {
            skipped += hit.t;
            found = trace_closest(o + skipped * d, d, tmax - skipped, hit);
        }
        hit.t += skipped;
    }
#ifdef ADJOINT
    if (depth <= CACHED_BOUNCES) cached_hits[depth - 1u] = hit;
#endif
    return found;
}

bool cast_any(vec3 o, vec3 d, float tmax, uint depth, bool replay) {
#ifdef ADJOINT
    uint bit = depth <= CACHED_BOUNCES ? 1u << (depth - 1u) : 0u;
    if (replay && (CACHE_ALL || bit != 0u)) return (cached_shadow & bit) != 0u;
#endif
#ifdef COUNT_RAYS
    atomicAdd(ray_count[workgroup_index()], 1u);
#endif
    bool blocked = trace_any(o, d, tmax);
#ifdef ADJOINT
    if (blocked) cached_shadow |= bit;
    else cached_shadow &= ~bit;
#endif
    return blocked;
}

// Offsets of ray origins from surfaces, relative to the scene scale (the kernels' scenes
// are a few units across; this is ~1e-4 of that).
const float RAY_EPSILON = 1e-4;

// Whether light may travel between wo and direction wi at a surface point (ng and ns, the
// geometric and shading normals, flipped to wo's side): wi on wo's side of the surface, or,
// through a rough dielectric (`through`), on either side as long as the shading normal puts
// it on the same one as the geometric normal (else the BSDF would evaluate the lobe of the
// other side).
bool passes_side(vec3 wi, vec3 ng, vec3 ns, bool through) {
    float g = dot(wi, ng);
    return through ? g * dot(wi, ns) > 0.0 : g > 0.0;
}

// The origin of a ray from surface point p in direction d: p offset along the geometric
// normal ng to d's side of the surface (the far side for a refraction or a light sample
// through rough glass).
vec3 ray_origin(vec3 p, vec3 ng, vec3 d) {
    return p + RAY_EPSILON * (dot(d, ng) < 0.0 ? -ng : ng);
}

// Picks an emissive triangle by its probability and a point on it: returns its record,
// the point in `p` (its pdf in area measure is the record's pdf) and its barycentrics (the
// weights of vertices 1 and 2) in `b`.
EmitterTri sample_emitter(vec3 u, out vec3 p, out vec2 b) {
    // Binary search for the first triangle whose inclusive cdf exceeds u.x.
    uint lo = 0u, hi = NUM_EMITTERS - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (emitter_cdf(mid) > u.x) hi = mid; else lo = mid + 1u;
    }
    EmitterTri e = emitter_tri(lo);
    b = sample_triangle_barycentrics(u.yz);
    p = e.p0 + b.x * e.e1 + b.y * e.e2;
    return e;
}

// Sphere emitter k's record (src/render/features/emitters.rs), after the triangles' 5
// texels each: its centre, radius and the probability of picking any of its triangles.
struct EmitterSphere {
    vec3 center;
    float radius;
    float pmf;
};

EmitterSphere emitter_sphere(uint k) {
    int b = int(NUM_EMITTERS) * 5 + 2 * int(k);
    uvec4 t0 = texel_load(Emitters, b);
    return EmitterSphere(uintBitsToFloat(t0.xyz), uintBitsToFloat(t0.w), uintBitsToFloat(texel_load(Emitters, b + 1).x));
}

// The cap that sphere `s` subtends at o, 1 − cos θmax (written without cancellation), in
// which light sampling picks its directions; 0 where o is inside the sphere (its triangles
// are then sampled by area).
float sphere_cap(EmitterSphere s, vec3 o) {
    vec3 w = s.center - o;
    float d2 = dot(w, w);
    float r2 = s.radius * s.radius;
    if (d2 <= r2) return 0.0;
    float sin2 = r2 / d2;
    return sin2 / (1.0 + sqrt(1.0 - sin2));
}

// The solid-angle density of a light sample in the cone, of cap `cap`, of sphere `s`: the
// probability of picking the sphere over the cap's solid angle.
float sphere_cone_pdf(EmitterSphere s, float cap) { return s.pmf / (2.0 * 3.14159265358979 * cap); }

// The solid-angle density at o with which light sampling reaches a point of the sphere
// emitter of a triangle of emitter flags `flags` (TriShading.emitter_flags); 0 where the
// triangle is of no sphere or o is inside it (its area density applies then).
float sphere_light_pdf(uint flags, vec3 o) {
    uint k = flags >> EMITTER_SPHERE_SHIFT;
    // (SPHERE_EMITTERS in a branch of its own: the reflection cannot fold an operation on
    // a specialisation constant.)
    if (SPHERE_EMITTERS) {
        if (k != 0u) {
            EmitterSphere s = emitter_sphere(k - 1u);
            float cap = sphere_cap(s, o);
            if (cap > 0.0) return sphere_cone_pdf(s, cap);
        }
    }
    return 0.0;
}

// A direction from o uniform in the cone of sphere `s`, of cap `cap` (sphere_cap > 0).
vec3 sphere_cone_direction(EmitterSphere s, float cap, vec3 o, vec2 u) {
    float one_minus_cos = u.x * cap;
    float cos_t = 1.0 - one_minus_cos;
    float sin_t = sqrt(max(0.0, one_minus_cos * (2.0 - one_minus_cos)));
    float phi = 2.0 * 3.14159265358979 * u.y;
    ShadingFrame f = shading_frame(normalize(s.center - o));
    return shading_to_world(f, vec3(sin_t * cos(phi), sin_t * sin(phi), cos_t));
}

// Where direction wi from o first meets the scene, if that is a triangle of sphere emitter
// `k` (1 + its index): the emitter point of a light sample in the sphere's cone, its
// triangle's record (as sample_emitter's, without the table's cdf) and barycentrics. Its
// visibility is the closest hit's, so it needs no shadow ray. Not cached for the replay
// (cast_closest's cache holds the path's own vertices): the gradient pass casts it again.
bool sphere_light_point(uint k, vec3 o, vec3 wi, out EmitterTri light, out vec3 pl, out vec2 bary) {
#ifdef COUNT_RAYS
    atomicAdd(ray_count[workgroup_index()], 1u);
#endif
    Hit h;
    light = EmitterTri(vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0), 0u, 0.0, 0.0, 0u, ValueRef(0, 0u, 0u, 0u));
    pl = o;
    bary = vec2(0.0);
    if (!trace_closest(o, wi, 1e30, h)) return false;
    TriShading sh = tri_shading(h.prim);
    if ((sh.emitter_flags >> EMITTER_SPHERE_SHIFT) != k) return false;
    light.ng = sh.ng;
    light.prim = h.prim;
    light.pdf = sh.emitter_pdf;
    light.two_sided = sh.emitter_flags & EMITTER_TWO_SIDED;
    light.emission = sh.emission;
    pl = o + h.t * wi;
    bary = vec2(h.u, h.v);
    return true;
}

// Next-event estimation's emitter point from surface or medium point p (ng: a surface's
// geometric normal): sample_emitter's triangle and point, or, where that triangle belongs
// to a sphere that p is outside of, the point that a direction in the sphere's cone meets
// (sphere_light_point), from `origin` (p offset to the direction's side of a surface).
// pdf_sa: the second's density in solid angle at p (0 for an area sample); found: false
// where the cone's direction met no point of the sphere (the sample is void). A point in
// the cone is visible from `origin`: it needs no shadow ray.
struct LightPoint {
    EmitterTri light;
    vec3 pl;
    vec2 bary;
    float pdf_sa;
    bool found;
    vec3 origin;
};

LightPoint sample_light_point(vec3 u, vec3 p, vec3 ng, bool surface) {
    LightPoint r;
    r.light = sample_emitter(u, r.pl, r.bary);
    r.pdf_sa = 0.0;
    r.found = true;
    r.origin = p;
    uint k = 0u;
    if (SPHERE_EMITTERS) k = tri_emitter_flags(r.light.prim) >> EMITTER_SPHERE_SHIFT;
    if (k != 0u) {
        EmitterSphere s = emitter_sphere(k - 1u);
        float cap = sphere_cap(s, p);
        if (cap > 0.0) {
            vec3 wi = sphere_cone_direction(s, cap, p, u.yz);
            r.origin = surface ? ray_origin(p, ng, wi) : p;
            r.found = sphere_light_point(k, r.origin, wi, r.light, r.pl, r.bary);
            r.pdf_sa = sphere_cone_pdf(s, cap);
        }
    }
    return r;
}

#ifdef ADJOINT
// Gradient contributions of one state carry its sign: + for θ_i, − for θ_{i-1} (FD).
float state_sign(int s) { return s == 0 ? 1.0 : -1.0; }

// The derivatives of the loss with respect to a path vertex's material values (base
// colour, roughness, metallic), summed over everything at the vertex that reads them (its
// light samples and its continuation) and over the parameter states, then scattered once
// per vertex (scatter_material). Every term reads the same parameters at the same uv, so
// one scatter does what one per term did, with a fraction of the atomics (or of the
// per-thread additions); the finite-difference kernels add each difference once instead
// of both of its large terms.
struct MatGrad {
    vec3 base;
    float rough;
    float metal;
};

MatGrad mat_grad_zero() { return MatGrad(vec3(0.0), 0.0, 0.0); }

// Adds the sum over states of k[s] · d bsdf_eval(m[s]; ns, wo, wi) / d(material values) to
// g (k[s] carries the state's sign).
void add_bsdf_grad(inout MatGrad g, Material m[NSTATES], vec3 ns, vec3 wo, vec3 wi, vec3 k[NSTATES]) {
    for (int s = 0; s < NSTATES; ++s) {
        vec3 d_base, d_rough, d_metal;
        bsdf_eval_grad(m[s], ns, wo, wi, d_base, d_rough, d_metal);
        g.base += k[s] * d_base;
        g.rough += dot(k[s], d_rough);
        g.metal += dot(k[s], d_metal);
    }
}

// Scatters g into the gradients of material `id`'s parameters at texture coordinate uv.
void scatter_material(uint id, SurfaceUv uv, MatGrad g) {
    MaterialRecord mr = material_record(id);
    scatter3(mr.base_color, uv, g.base);
    scatter1(mr.roughness, uv, g.rough);
    scatter1(mr.metallic, uv, g.metal);
}

// The sum of g[] over the states, for one scatter of a value every state reads alike.
vec3 state_sum(vec3 g[NSTATES]) {
    vec3 t = vec3(0.0);
    for (int s = 0; s < NSTATES; ++s) t += g[s];
    return t;
}
#endif

// One light sample arriving along wi with radiance le[s] in each state and weight w (its
// MIS weight over its pdf): adds beta·f·le·w to each state's radiance. ADJOINT: also takes
// it off remaining[] and, in the gradient replay, adds its derivative with respect to the
// material's values to mg; dle[s] is then the factor of the derivative with respect to the
// emitted radiance (state sign × δ × beta × f × w), zero outside the gradient replay.
void add_light_sample(Material mat[NSTATES], vec3 ns, vec3 wo, vec3 wi, vec3 le[NSTATES], float w,
                      vec3 beta[NSTATES], inout vec3 radiance[NSTATES]
#ifdef ADJOINT
                      , inout vec3 remaining[NSTATES], vec3 delta[NSTATES], bool grad_pass, out vec3 dle[NSTATES], inout MatGrad mg
#endif
) {
#ifdef ADJOINT
    vec3 k_bsdf[NSTATES];
#endif
    for (int s = 0; s < NSTATES; ++s) {
        vec3 f = bsdf_eval(mat[s], ns, wo, wi);
        vec3 c = beta[s] * f * le[s] * w;
        radiance[s] += c;
#ifdef ADJOINT
        remaining[s] -= c;
        vec3 k = state_sign(s) * delta[s] * beta[s];
        k_bsdf[s] = k * le[s] * w;
        dle[s] = grad_pass ? k * f * w : vec3(0.0);
#endif
    }
#ifdef ADJOINT
    if (grad_pass) add_bsdf_grad(mg, mat, ns, wo, wi, k_bsdf);
#endif
}

#include "lib/media.glsl"
#include "lib/delta_lights.glsl"

// Where emitter point pl (at barycentrics bary of `light`, from sample_emitter) reads its
// emission and alpha, and whether its alpha test cuts it out: such a point emits nothing
// (the emitter is sampled over its whole area, so the estimate stays unbiased); a blend's
// choice is keyed by the point.
SurfaceUv emitter_point_uv(EmitterTri light, vec2 bary, vec3 pl, out bool cut) {
    SurfaceUv uv = SurfaceUv(vec2(0.0), bary, light.prim);
    // (Two branches, not `HAS_EMISSION_TEXTURES || HAS_ALPHA_MASKS`: the reflection
    // cannot fold an operation on specialisation constants.)
    if (HAS_EMISSION_TEXTURES) {
        uv = triangle_uv(light.prim, bary);
    } else if (HAS_ALPHA_MASKS) {
        uv = triangle_uv(light.prim, bary);
    }
    cut = HAS_ALPHA_MASKS && alpha_cut(tri_shading(light.prim).alpha_material, uv, uvec4(floatBitsToUint(pl), light.prim));
    return uv;
}

// The direction wi, distance and squared distance from o to emitter point pl, and the
// emitter's cosine towards o (either face of a two-sided one; at most 0 where it faces away).
float emitter_towards(EmitterTri light, vec3 pl, vec3 o, out vec3 wi, out float dist, out float dist2) {
    vec3 to_l = pl - o;
    dist2 = dot(to_l, to_l);
    dist = sqrt(dist2);
    wi = to_l / dist;
    float cos_l = dot(light.ng, -wi);
    return light.two_sided != 0u ? abs(cos_l) : cos_l;
}

#ifdef SCATTERING
// A light sample at a medium vertex p: radiance le[s] arriving along wi from tmax away,
// with weight w (phase function, MIS, 1 / pdf), through the medium's transmittance; added
// to each state's radiance. ADJOINT: also taken off remaining[], the transmittance's
// derivative scattered in the gradient replay, and g[s] = sign_s δ_s β_s w tr_s returned:
// the derivative of the loss by state s's le.
void medium_light_sample(vec3 p, vec3 wi, float tmax, float w, vec3 le[NSTATES], vec3 beta[NSTATES], inout vec3 radiance[NSTATES]
#ifdef ADJOINT
                         , inout vec3 remaining[NSTATES], vec3 delta[NSTATES], bool grad_pass, out vec3 g[NSTATES]
#endif
) {
    float tr[NSTATES];
    medium_transmittance(p, wi, tmax, tr);
#ifdef ADJOINT
    vec3 before[NSTATES] = radiance;
#endif
    for (int s = 0; s < NSTATES; ++s) {
        vec3 c = beta[s] * le[s] * (w * tr[s]);
        radiance[s] += c;
#ifdef ADJOINT
        remaining[s] -= c;
        g[s] = state_sign(s) * delta[s] * beta[s] * (w * tr[s]);
#endif
    }
#ifdef ADJOINT
    if (grad_pass) {
        float gw[NSTATES];
        medium_sample_weights(before, radiance, delta, gw);
        medium_transmittance_grad(p, wi, tmax, gw);
    }
#endif
}

// Next-event estimation at a collision p inside a scattering medium, reached along d: one
// light sample (an emissive triangle, or the environment map when env_nee) and every delta
// light, each weighted by the phase function hg (of mean cosine g) and the transmittance of
// its shadow ray, MIS against phase sampling as at a surface.
void medium_vertex_nee(vec3 p, vec3 d, float g, vec3 u_light, bool env_nee, float p_env, uint depth, bool replay,
                       vec3 beta[NSTATES], inout vec3 radiance[NSTATES]
#ifdef ADJOINT
                       , inout vec3 remaining[NSTATES], vec3 delta[NSTATES], bool grad_pass
#endif
) {
    vec3 le[NSTATES];
#ifdef ADJOINT
    vec3 dle[NSTATES];
#define MEDIUM_LIGHT_SAMPLE(wi, tmax, w) medium_light_sample(p, wi, tmax, w, le, beta, radiance, remaining, delta, grad_pass, dle)
#else
#define MEDIUM_LIGHT_SAMPLE(wi, tmax, w) medium_light_sample(p, wi, tmax, w, le, beta, radiance)
#endif
    if (NUM_EMITTERS != 0u && !env_nee) {
        LightPoint lp = sample_light_point(u_light, p, vec3(0.0), false);
        EmitterTri light = lp.light;
        vec3 pl = lp.pl;
        vec3 wi;
        float dist, dist2;
        float cos_l = lp.found ? emitter_towards(light, pl, p, wi, dist, dist2) : 0.0;
        bool cut;
        SurfaceUv light_uv = emitter_point_uv(light, lp.bary, pl, cut);
        float t_shadow = dist * (1.0 - 1e-4);
        if (!cut && cos_l > 0.0 && light.pdf > 0.0 && (lp.pdf_sa > 0.0 || !cast_any(p, wi, t_shadow, depth, replay))) {
            float pdf_light = (1.0 - p_env) * (lp.pdf_sa > 0.0 ? lp.pdf_sa : light.pdf * dist2 / cos_l);
            float ph = hg_phase(g, d, wi);
            for (int s = 0; s < NSTATES; ++s) le[s] = fetch3(light.emission, light_uv, s);
            MEDIUM_LIGHT_SAMPLE(wi, t_shadow, power_heuristic(pdf_light, ph) * ph / pdf_light);
#ifdef ADJOINT
            if (grad_pass) scatter3(light.emission, light_uv, state_sum(dle));
#endif
        }
    }
    if (HAS_ENVIRONMENT && env_nee) {
        float density;
        vec3 wi = environment_sample(u_light.xy, density);
        float pdf_light = p_env * density;
        if (pdf_light > 0.0 && !cast_any(p, wi, 1e30, depth, replay)) {
            float ph = hg_phase(g, d, wi);
            for (int s = 0; s < NSTATES; ++s) le[s] = environment_radiance(wi, s);
            MEDIUM_LIGHT_SAMPLE(wi, 1e30, power_heuristic(pdf_light, ph) * ph / pdf_light);
#ifdef ADJOINT
            if (grad_pass) scatter3(scene_globals().environment, environment_uv(wi), state_sum(dle) * scene_globals().environment_scale);
#endif
        }
    }
    if (HAS_DELTA_LIGHTS) {
        uint n = scene_globals().num_lights;
        for (uint i = 0u; i < n; ++i) {
            LightRecord l = light_record(i);
            vec3 wi;
            float tmax, gl;
            delta_light_incidence(l, p, wi, tmax, gl);
            if (gl <= 0.0 || delta_light_blocked(p, wi, tmax)) continue;
            for (int s = 0; s < NSTATES; ++s) le[s] = delta_light_le(l, s) * gl;
            MEDIUM_LIGHT_SAMPLE(wi, tmax, hg_phase(g, d, wi));
#ifdef ADJOINT
            // (dle: by le = colour × intensity × gl.)
            if (grad_pass) scatter_delta_light(l, dle, gl);
#endif
        }
    }
#undef MEDIUM_LIGHT_SAMPLE
}
#endif

// Whether a path goes on past vertex `depth` with throughput beta: Russian roulette from
// vertex RR_DEPTH on (Mitsuba's rule: survive with probability min(max(beta), 0.95) of
// state 0, every state divided by it, u_rr its number), and some state's beta not zero.
bool path_survives(inout vec3 beta[NSTATES], uint depth, float u_rr) {
    if (depth >= RR_DEPTH) {
        float q = min(max_component(beta[0]), 0.95);
        if (u_rr >= q) return false;
        for (int s = 0; s < NSTATES; ++s) beta[s] /= q;
    }
    bool alive = false;
    for (int s = 0; s < NSTATES; ++s) alive = alive || any(notEqual(beta[s], vec3(0.0)));
    return alive;
}

// Traces the path that starts with ray (o, d) and uses `rng` from bounce 1 on, in every
// parameter state. Primal: returns each state's radiance in `radiance`. ADJOINT: `L` is
// that radiance (from a primal replay) and `delta` each state's pixel adjoint (dLoss/dI
// times the sample weight); gradients go into grad[] (delta all zero: primal replay).
// `replay` (a constant at each call): this is the gradient replay (delta not all zero),
// whose ray casts the primal replay of the same sample just cached (ADJOINT; false in the
// primal kernels). Being a constant, it also compiles the gradient code out of the primal
// replay and its tests out of the gradient replay.
void trace_path(inout Rng rng, vec3 o, vec3 d, vec3 L[NSTATES], vec3 delta[NSTATES], bool replay, out vec3 radiance[NSTATES]) {
    vec3 beta[NSTATES];
#ifdef ADJOINT
    vec3 remaining[NSTATES];   // radiance still to be accounted for along the path
    bool grad_pass = replay;
#endif
    for (int s = 0; s < NSTATES; ++s) {
        radiance[s] = vec3(0.0);
        beta[s] = vec3(1.0);
#ifdef ADJOINT
        remaining[s] = L[s];
#endif
    }
    float prev_bsdf_pdf = 0.0;   // 0: the previous vertex is the camera (no MIS)
    vec3 absorption = vec3(0.0);  // of the interior the path is in (HAS_DIELECTRICS)
    // Probability that next-event estimation samples the environment map.
    float p_env = 0.0;
    if (ENVIRONMENT_SAMPLED) p_env = scene_globals().environment_sample_prob;
    for (uint depth = 1u; ; ++depth) {
        rng_seek_bounce(rng, depth);
        Hit hit;
        bool found = cast_closest(o, d, 1e30, depth, replay, hit);
        // The medium between the ray's origin and what it finds (or its way out): its
        // emission gathered, or (scattering) where the ray collides in it sampled. A
        // collision is a path vertex: light samples weighted by the phase function, then
        // a direction sampled from it.
#ifndef SCATTERING
        if (HAS_MEDIA) {
#ifdef ADJOINT
            medium_segment(o, d, found ? hit.t : 1e30, beta, radiance, remaining, delta, grad_pass);
#else
            medium_segment(o, d, found ? hit.t : 1e30, beta, radiance);
#endif
        }
#endif
#ifdef SCATTERING
        if (HAS_MEDIA) {
            // The bounce's numbers, in the order a surface draws them (one more for the
            // collision's distance, which a surface does not use).
            vec3 u_light = rng_next3(rng);
            vec3 u_bsdf = rng_next3(rng);
            float u_rr = rng_next(rng);
            float u_select = rng_next(rng);
            float u_flight = rng_next(rng);
            float ts;
#ifdef ADJOINT
            bool collided = medium_free_flight(o, d, found ? hit.t : 1e30, u_flight, beta, ts, remaining, delta, grad_pass);
#else
            bool collided = medium_free_flight(o, d, found ? hit.t : 1e30, u_flight, beta, ts);
#endif
            if (collided) {
                if (depth >= MAX_DEPTH) break;
                vec3 p = o + ts * d;
                float g = medium_record().g;
                bool env_nee = ENVIRONMENT_SAMPLED && u_select < p_env;
#ifdef ADJOINT
                medium_vertex_nee(p, d, g, u_light, env_nee, p_env, depth, replay, beta, radiance, remaining, delta, grad_pass);
#else
                medium_vertex_nee(p, d, g, u_light, env_nee, p_env, depth, replay, beta, radiance);
#endif
                vec3 wi = hg_sample(g, d, u_bsdf.xy);
                prev_bsdf_pdf = hg_phase(g, d, wi);
                if (!path_survives(beta, depth, u_rr)) break;
                o = p;
                d = wi;
                continue;
            }
            // No collision: the surface's bounce draws its numbers afresh.
            rng_seek_bounce(rng, depth);
        }
#endif
        // Beer-Lambert over the ray inside an interior (all of it, if it escapes there).
        if (HAS_DIELECTRICS && any(greaterThan(absorption, vec3(0.0)))) {
            vec3 kept = found ? exp(-absorption * hit.t) : vec3(0.0);
            for (int s = 0; s < NSTATES; ++s) beta[s] *= kept;
        }
        if (!found) {
            // (Where emitters are hidden, a camera ray that escapes finds nothing.)
            if (HAS_ENVIRONMENT && !(HIDE_EMITTERS && depth == 1u)) {
                float mis = 1.0;
                // The map's light-sampling density of this direction (it was reached by a
                // BSDF sample unless the previous vertex is the camera).
                if (prev_bsdf_pdf > 0.0 && p_env > 0.0) mis = power_heuristic(prev_bsdf_pdf, p_env * environment_density(d));
#ifdef ADJOINT
                vec3 g_env[NSTATES];
#endif
                for (int s = 0; s < NSTATES; ++s) {
                    vec3 e = beta[s] * environment_radiance(d, s) * mis;
                    radiance[s] += e;
#ifdef ADJOINT
                    remaining[s] -= e;
                    // Emission enters linearly: d(beta * mis * scale * E)/dE = beta * mis *
                    // scale, at the texel(s) of the lookup for an environment map.
                    g_env[s] = state_sign(s) * delta[s] * beta[s] * (mis * scene_globals().environment_scale);
#endif
                }
#ifdef ADJOINT
                if (grad_pass) scatter3(scene_globals().environment, environment_uv(d), state_sum(g_env));
#endif
            }
            break;
        }
        vec3 p = o + hit.t * d;
        TriShading sh = tri_shading(hit.prim);
        vec3 wo = -d;
        float w_bary = 1.0 - hit.u - hit.v;
        SurfaceUv uv = SurfaceUv(w_bary * sh.uv0 + hit.u * sh.uv1 + hit.v * sh.uv2, vec2(hit.u, hit.v), hit.prim);
        vec3 ng = sh.ng;

        // Emission reached by the previous BSDF sample (or seen by the camera). Emitters
        // shine from their front (counter-clockwise) side, two-sided ones from both.
        if (sh.emitter_pdf > 0.0 && (dot(ng, wo) > 0.0 || (sh.emitter_flags & EMITTER_TWO_SIDED) != 0u)) {
            float mis = 1.0;
            if (prev_bsdf_pdf > 0.0 && NUM_EMITTERS != 0u) {
                // The light-sampling pdf of this point, in solid angle at the previous vertex
                // (a sphere's, where it is one and the vertex is outside it).
                float pdf_sa = sphere_light_pdf(sh.emitter_flags, o);
                float pdf_light = (1.0 - p_env) * (pdf_sa > 0.0 ? pdf_sa : sh.emitter_pdf * hit.t * hit.t / max(abs(dot(ng, wo)), 1e-8));
                mis = power_heuristic(prev_bsdf_pdf, pdf_light);
            }
#ifdef ADJOINT
            vec3 g_em[NSTATES];
#endif
            for (int s = 0; s < NSTATES; ++s) {
                vec3 e = beta[s] * fetch3(sh.emission, uv, s) * mis;
                radiance[s] += e;
#ifdef ADJOINT
                remaining[s] -= e;
                g_em[s] = state_sign(s) * delta[s] * beta[s] * mis;
#endif
            }
#ifdef ADJOINT
            if (grad_pass) scatter3(sh.emission, uv, state_sum(g_em));
#endif
        }
        if (depth >= MAX_DEPTH) break;
        // A one-sided material seen from behind reflects nothing.
        if (dot(ng, wo) < 0.0 && sh.one_sided != 0u) break;

        // Shading frame: interpolated normal if the mesh has normals, perturbed by the
        // material's normal or bump map, flipped to the side of wo; the geometric normal likewise.
        vec3 ns = HAS_NORMALS ? w_bary * sh.n0 + hit.u * sh.n1 + hit.v * sh.n2 : vec3(0.0);
        ns = dot(ns, ns) > 0.0 ? normalize(ns) : ng;
        ns = perturbed_normal(sh, ns, uv);
        bool from_behind = dot(ng, wo) < 0.0;
        if (from_behind) ng = -ng;
        if (dot(ns, ng) < 0.0) ns = -ns;
        Material mat[NSTATES];
        for (int s = 0; s < NSTATES; ++s) mat[s] = fetch_material(sh.material, uv, s);
        bool dielectric = HAS_DIELECTRICS && material_is_dielectric(mat[0].kind);
        // A rough dielectric scatters into both sides by lobes light samples can reach.
        bool rough = HAS_ROUGH_DIELECTRICS && material_is_rough_glass(mat[0].kind);
        if ((rough || (dielectric && mat[0].kind == MATERIAL_DIELECTRIC)) && from_behind) {
            for (int s = 0; s < NSTATES; ++s) mat[s].ior = 1.0 / mat[s].ior;
        }
        vec3 p_off = p + RAY_EPSILON * ng;
#ifdef ADJOINT
        MatGrad mg = mat_grad_zero();
#endif

        // The bounce's random numbers, drawn up front in a fixed order whatever the branches
        // below use, so replays stay in step (lib/rng.glsl): light sample (3), BSDF sample
        // (3), Russian roulette (1), light strategy (1).
        vec3 u_light = rng_next3(rng);
        vec3 u_bsdf = rng_next3(rng);
        float u_rr = rng_next(rng);
        float u_select = rng_next(rng);
        bool env_nee = ENVIRONMENT_SAMPLED && u_select < p_env;

        // Next-event estimation: one point on an emissive triangle, MIS with BSDF sampling
        // (pdfs of state 0).
        if (NUM_EMITTERS != 0u && !env_nee && !dielectric) {
            LightPoint lp = sample_light_point(u_light, p, ng, true);
            EmitterTri light = lp.light;
            vec3 pl = lp.pl;
            float pdf_area = light.pdf;
            vec3 wi;
            float dist, dist2;
            vec3 o_l = lp.pdf_sa > 0.0 ? lp.origin : p_off;
            float cos_l = lp.found ? emitter_towards(light, pl, o_l, wi, dist, dist2) : 0.0;
            // Through a rough dielectric the shadow ray leaves from the far side.
            if (lp.pdf_sa == 0.0 && rough && dot(wi, ng) < 0.0) {
                o_l = ray_origin(p, ng, wi);
                cos_l = emitter_towards(light, pl, o_l, wi, dist, dist2);
            }
            bool cut;
            SurfaceUv light_uv = emitter_point_uv(light, lp.bary, pl, cut);
            if (!cut && cos_l > 0.0 && passes_side(wi, ng, ns, rough) && pdf_area > 0.0
                && (lp.pdf_sa > 0.0 || !cast_any(o_l, wi, dist * (1.0 - 1e-4), depth, replay))) {
                float pdf_light = (1.0 - p_env) * (lp.pdf_sa > 0.0 ? lp.pdf_sa : pdf_area * dist2 / cos_l);
                float mis = power_heuristic(pdf_light, bsdf_pdf(mat[0], ns, wo, wi));
                ValueRef emission = light.emission;
                vec3 le[NSTATES];
                float tr[NSTATES];
                float t_shadow = dist * (1.0 - 1e-4);
                if (HAS_MEDIA) {
                    medium_transmittance(o_l, wi, t_shadow, tr);
                } else {
                    for (int s = 0; s < NSTATES; ++s) tr[s] = 1.0;
                }
                for (int s = 0; s < NSTATES; ++s) le[s] = fetch3(emission, light_uv, s) * tr[s];
#ifdef ADJOINT
                vec3 dle[NSTATES];
                vec3 before[NSTATES] = radiance;
                add_light_sample(mat, ns, wo, wi, le, mis / pdf_light, beta, radiance, remaining, delta, grad_pass, dle, mg);
                for (int s = 0; s < NSTATES; ++s) dle[s] *= tr[s];
                if (grad_pass) scatter3(emission, light_uv, state_sum(dle));
                if (HAS_MEDIA && grad_pass) {
                    float gw[NSTATES];
                    medium_sample_weights(before, radiance, delta, gw);
                    medium_transmittance_grad(o_l, wi, t_shadow, gw);
                }
#else
                add_light_sample(mat, ns, wo, wi, le, mis / pdf_light, beta, radiance);
#endif
            }
        }
        // Or a direction from the environment map, MIS with BSDF sampling likewise.
        if (HAS_ENVIRONMENT && env_nee && !dielectric) {
            float density;
            vec3 wi = environment_sample(u_light.xy, density);
            float pdf_light = p_env * density;
            vec3 o_e = rough ? ray_origin(p, ng, wi) : p_off;
            if (pdf_light > 0.0 && passes_side(wi, ng, ns, rough) && !cast_any(o_e, wi, 1e30, depth, replay)) {
                float mis = power_heuristic(pdf_light, bsdf_pdf(mat[0], ns, wo, wi));
                vec3 le[NSTATES];
                float tr[NSTATES];
                if (HAS_MEDIA) {
                    medium_transmittance(o_e, wi, 1e30, tr);
                } else {
                    for (int s = 0; s < NSTATES; ++s) tr[s] = 1.0;
                }
                for (int s = 0; s < NSTATES; ++s) le[s] = environment_radiance(wi, s) * tr[s];
#ifdef ADJOINT
                vec3 dle[NSTATES];
                vec3 before[NSTATES] = radiance;
                add_light_sample(mat, ns, wo, wi, le, mis / pdf_light, beta, radiance, remaining, delta, grad_pass, dle, mg);
                for (int s = 0; s < NSTATES; ++s) dle[s] *= tr[s];
                if (HAS_MEDIA && grad_pass) {
                    float gw[NSTATES];
                    medium_sample_weights(before, radiance, delta, gw);
                    medium_transmittance_grad(o_e, wi, 1e30, gw);
                }
                if (grad_pass) {
                    vec2 env_uv = environment_uv(wi);
                    float scale = scene_globals().environment_scale;
                    scatter3(scene_globals().environment, env_uv, state_sum(dle) * scale);
                }
#else
                add_light_sample(mat, ns, wo, wi, le, mis / pdf_light, beta, radiance);
#endif
            }
        }

        // Delta lights: each sampled once, without MIS (BSDF sampling never reaches one).
        if (HAS_DELTA_LIGHTS && !dielectric) {
            delta_lights_nee(p, ng, ns, wo, rough, mat, beta, radiance
#ifdef ADJOINT
                             , remaining, delta, grad_pass, mg
#endif
            );
        }

        // Continue by sampling the BSDF of state 0 (a dielectric's lobe: pdf is then the
        // lobe's probability, and f its mass).
        vec3 wi, weight;
        float pdf;
        bool sampled;
        if (dielectric) {
            sampled = dielectric_sample(mat[0], ns, wo, u_bsdf.x, wi, weight, pdf);
        } else {
            sampled = bsdf_sample(mat[0], ns, wo, u_bsdf, wi, weight, pdf) && pdf > 0.0 && passes_side(wi, ng, ns, rough);
        }
        // State 0: weight = f_0 / pdf_0 as sampled; other states: their own f over state
        // 0's pdf (the shift).
        vec3 f[NSTATES];
        for (int s = 0; s < NSTATES; ++s) {
            if (s == 0) f[s] = weight * pdf;
            else f[s] = dielectric ? dielectric_mass(mat[s], ns, wo, wi) : bsdf_eval(mat[s], ns, wo, wi);
        }
#ifdef ADJOINT
        // The vertex's material derivatives, with the continuation's when there is one, are
        // scattered here, from one place whether or not the path goes on (lavapipe runs
        // both sides of a branch: a scatter on each would cost two).
        if (grad_pass) {
            if (sampled) {
                // Everything the path gathers from here on is proportional to f(wo, wi): its
                // derivative is remaining * (df/dθ) / f, per channel.
                vec3 k_bsdf[NSTATES];
                for (int s = 0; s < NSTATES; ++s) {
                    vec3 inv_f = vec3(f[s].x > 0.0 ? 1.0 / f[s].x : 0.0, f[s].y > 0.0 ? 1.0 / f[s].y : 0.0, f[s].z > 0.0 ? 1.0 / f[s].z : 0.0);
                    k_bsdf[s] = state_sign(s) * delta[s] * remaining[s] * inv_f;
                }
                if (dielectric) {
                    for (int s = 0; s < NSTATES; ++s) mg.base += k_bsdf[s] * dielectric_mass_grad(mat[s], ns, wo, wi);
                } else {
                    add_bsdf_grad(mg, mat, ns, wo, wi, k_bsdf);
                }
            }
            scatter_material(sh.material, uv, mg);
        }
#endif
        if (!sampled) break;
        for (int s = 0; s < NSTATES; ++s) beta[s] *= f[s] / pdf;
        // After a delta lobe, emission found next is not MIS-weighted (no light sample here).
        prev_bsdf_pdf = dielectric ? 0.0 : pdf;

        if (!path_survives(beta, depth, u_rr)) break;
        // A refracted ray leaves from the surface's far side, into or out of the interior.
        bool refracted = (dielectric || rough) && dot(wi, ng) < 0.0;
        if (refracted && mat[0].kind != MATERIAL_THIN_DIELECTRIC) absorption = from_behind ? vec3(0.0) : material_record(sh.material).absorption;
        o = dielectric || rough ? ray_origin(p, ng, wi) : p_off;
        d = wi;
    }
}

// The offset from a pixel's centre, in pixels along one axis, of a camera sample drawn by
// uniform number u from the pixel filter's sampling table (Globals.filter_table, in the
// material data; src/render/filter.rs, whose `sample` is this function): the segment
// whose cumulative masses bracket u, then the point of its linear density's inverse.
float filter_offset(uint table, float u) {
    const int n = int(FILTER_TABLE_SIZE);
    int base = int(CONST_BASE) + int(table) - 1;
    float r = texel_float(Theta, base);
    int w = base + 1;       // weights, n + 1
    int c = w + n + 1;      // cumulative masses, n + 1
    int lo = 0;
    int hi = n;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (texel_float(Theta, c + mid) <= u) lo = mid;
        else hi = mid;
    }
    float c0 = texel_float(Theta, c + lo);
    float span = texel_float(Theta, c + lo + 1) - c0;
    float v = span > 0.0 ? clamp((u - c0) / span, 0.0, 1.0) : 0.0;
    float w0 = texel_float(Theta, w + lo);
    float w1 = texel_float(Theta, w + lo + 1);
    float m = v * 0.5 * (w0 + w1);
    float den = w0 + sqrt(max(w0 * w0 + 2.0 * (w1 - w0) * m, 0.0));
    float t = den > 0.0 ? min(2.0 * m / den, 1.0) : 0.0;
    return r * (2.0 * (float(lo) + t) / float(n) - 1.0);
}

// The camera ray of a pixel sample (block 0 of the RNG: the position in the pixel, then
// the point on a thin lens); pixel (0, 0) is the top left. With a box filter the position
// is uniform over the pixel; with another it is drawn from the filter, around the pixel's
// centre, and may lie in a neighbouring pixel (filter importance sampling).
void camera_ray(SensorRecord s, uvec2 pixel, uvec2 size, inout Rng rng, out vec3 o, out vec3 d) {
    rng_seek_bounce(rng, 0u);
    vec2 jitter = rng_next2(rng);
    uint table = scene_globals().filter_table;
    if (table != 0u) jitter = 0.5 + vec2(filter_offset(table, jitter.x), filter_offset(table, jitter.y));
    vec2 ndc = (vec2(pixel) + jitter) / vec2(size) * 2.0 - 1.0;
    ndc.y = -ndc.y;
    if (s.ortho_half_height > 0.0) {
        o = s.origin + s.ortho_half_height * (ndc.x * s.aspect * s.right + ndc.y * s.up);
        d = s.forward;
    } else {
        o = s.origin;
        vec3 through = s.forward + ndc.x * s.tan_half_fov_y * s.aspect * s.right + ndc.y * s.tan_half_fov_y * s.up;
        // A thin lens: from a point uniform on the lens (polar map) towards where the
        // pinhole's ray meets the plane of focus (through's forward component is 1).
        vec2 u = rng_next2(rng);
        if (s.lens_radius > 0.0) {
            float r = s.lens_radius * sqrt(u.x);
            float phi = 6.28318530717959 * u.y;
            vec3 lens = r * (cos(phi) * s.right + sin(phi) * s.up);
            o = s.origin + lens;
            d = normalize(through * s.focus_distance - lens);
        } else {
            d = normalize(through);
        }
    }
}
#endif
