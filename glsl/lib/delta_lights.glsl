// Delta lights (point, spot, directional) in next-event estimation. A delta light has no
// area, so BSDF sampling never reaches it and its light sample needs no MIS weight; every
// light is sampled at every path vertex, which draws no random numbers (the replay
// invariant of lib/rng.glsl is untouched) and costs one shadow ray per light.
//
// A light's emitted quantity E = color × intensity × falloff(θ) is a radiant intensity
// for point and spot lights, so the radiance it contributes at a point at distance r is
// f(wo, wi) E / r² with f the BSDF times cos θ_i (bsdf_eval); for a directional light E is
// an irradiance and the contribution f E. E is linear in color and in intensity, which
// are the optimisable parameters (their ValueRefs may point into θ).
//
// Included by lib/integrator.glsl after the functions it uses (bsdf_eval, fetch3/fetch1,
// trace_any and, ADJOINT, MatGrad, add_bsdf_grad, scatter3/scatter1, state_sign).
#ifndef DELTA_LIGHTS_GLSL
#define DELTA_LIGHTS_GLSL

#ifdef GENERIC
#define HAS_DELTA_LIGHTS true
#else
// false: the scene has no delta lights and this pass is compiled out.
layout(constant_id = 6) const bool HAS_DELTA_LIGHTS = false;
#endif

// Spot falloff at cos θ from the axis: glTF's (KHR_lights_punctual's recommended
// attenuation: the square of a clamped linear ramp in cos θ, with its 0.001 guard) or
// Mitsuba's (linear in θ between the beam width and the cutoff angle).
float spot_falloff(LightRecord l, float cos_theta) {
    if (l.falloff == FALLOFF_SMOOTH) {
        float t = clamp((cos_theta - l.cos_outer) / max(l.cos_inner - l.cos_outer, 0.001), 0.0, 1.0);
        return t * t;
    }
    if (cos_theta <= l.cos_outer) return 0.0;
    if (cos_theta >= l.cos_inner) return 1.0;
    return (l.outer - acos(clamp(cos_theta, -1.0, 1.0))) / (l.outer - l.inner);
}

// Direction wi from p towards light l, the shadow ray's length, and the geometric factor
// G (falloff / r² for point and spot lights, 1 for a directional light) by which E is
// scaled. G = 0: the light does not reach p.
void delta_light_incidence(LightRecord l, vec3 p, out vec3 wi, out float tmax, out float g) {
    if (l.kind == LIGHT_DIRECTIONAL) {
        wi = -l.direction;
        tmax = 1e30;
        g = 1.0;
        return;
    }
    vec3 to_l = l.position - p;
    float d2 = dot(to_l, to_l);
    float dist = sqrt(d2);
    wi = to_l / max(dist, 1e-30);
    tmax = dist * (1.0 - 1e-4);
    g = d2 > 0.0 ? 1.0 / d2 : 0.0;
    if (l.kind == LIGHT_SPOT) g *= spot_falloff(l, dot(l.direction, -wi));
}

// A shadow ray towards a delta light. Not taken from or written to the adjoint kernels'
// hit cache, whose shadow slot per depth belongs to the emitter sample.
bool delta_light_blocked(vec3 o, vec3 d, float tmax) {
#ifdef COUNT_RAYS
    atomicAdd(ray_count[workgroup_index()], 1u);
#endif
    return trace_any(o, d, tmax);
}

// The radiance that delta light l sends in state s per unit of its geometry term g:
// colour × intensity.
vec3 delta_light_le(LightRecord l, int s) { return fetch3(l.color, vec2(0.0), s) * fetch1(l.intensity, vec2(0.0), s); }

#ifdef ADJOINT
// Scatters the loss's derivatives by each state's light, dle[s] (by colour × intensity ×
// g, per channel), times g, to delta light l's colour and intensity.
void scatter_delta_light(LightRecord l, vec3 dle[NSTATES], float g) {
    vec3 g_color = vec3(0.0);
    float g_intensity = 0.0;
    for (int s = 0; s < NSTATES; ++s) {
        g_color += dle[s] * (g * fetch1(l.intensity, vec2(0.0), s));
        g_intensity += g * dot(dle[s], fetch3(l.color, vec2(0.0), s));
    }
    scatter3(l.color, vec2(0.0), g_color);
    scatter1(l.intensity, vec2(0.0), g_intensity);
}
#endif

// Adds every delta light's direct contribution at a path vertex (point p, geometric and
// shading normals ng and ns on wo's side, `through` a rough dielectric's surface, which
// lights on either side reach; material values mat[]) to
// radiance[] of each state, weighted by beta[]. ADJOINT: also takes it off remaining[] and,
// in the gradient replay, adds delta[] × its derivatives with respect to the material's
// values to mg and scatters those with respect to the lights' colour and intensity.
void delta_lights_nee(vec3 p, vec3 ng, vec3 ns, vec3 wo, bool through, Material mat[NSTATES], vec3 beta[NSTATES],
                      inout vec3 radiance[NSTATES]
#ifdef ADJOINT
                      , inout vec3 remaining[NSTATES], vec3 delta[NSTATES], bool grad_pass, inout MatGrad mg
#endif
) {
    uint n = scene_globals().num_lights;
    vec3 p_off = p + RAY_EPSILON * ng;
    for (uint i = 0u; i < n; ++i) {
        LightRecord l = light_record(i);
        vec3 wi;
        float tmax, g;
        delta_light_incidence(l, p_off, wi, tmax, g);
        vec3 o = through ? ray_origin(p, ng, wi) : p_off;
        if (g <= 0.0 || !passes_side(wi, ng, ns, through) || delta_light_blocked(o, wi, tmax)) continue;
        float tr[NSTATES];
        if (HAS_MEDIA) {
            medium_transmittance(o, wi, tmax, tr);
        } else {
            for (int s = 0; s < NSTATES; ++s) tr[s] = 1.0;
        }
#ifdef ADJOINT
        vec3 before[NSTATES] = radiance;
        // Every state reads the same parameters: their derivatives are summed before one
        // scatter each (the material's with the vertex's others, MatGrad).
        vec3 k_bsdf[NSTATES];
        vec3 dle[NSTATES];
#endif
        for (int s = 0; s < NSTATES; ++s) {
            vec3 le = delta_light_le(l, s) * (g * tr[s]);
            vec3 f = bsdf_eval(mat[s], ns, wo, wi);
            vec3 c = beta[s] * f * le;
            radiance[s] += c;
#ifdef ADJOINT
            remaining[s] -= c;
            vec3 k = state_sign(s) * delta[s] * beta[s];
            k_bsdf[s] = k * le;
            dle[s] = k * f * tr[s];  // d(loss)/d(color × intensity × g), per channel
#endif
        }
#ifdef ADJOINT
        if (grad_pass) {
            add_bsdf_grad(mg, mat, ns, wo, wi, k_bsdf);
            scatter_delta_light(l, dle, g);
            if (HAS_MEDIA) {
                float gw[NSTATES];
                medium_sample_weights(before, radiance, delta, gw);
                medium_transmittance_grad(o, wi, tmax, gw);
            }
        }
#endif
    }
}
#endif
