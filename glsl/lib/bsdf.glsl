// BSDFs of the materials in glsl/shared/material.glsl: evaluation, pdf, importance
// sampling and the parameter derivatives the adjoint pass needs. Pure functions, no
// bindings. src/bsdf.rs mirrors every function in f64 and tests/bsdf.rs holds the two
// to each other, to finite differences and to a chi-square test of the sampling.
//
// Conventions (pbrt-v4): wo and wi are unit vectors pointing away from the surface; n is
// the unit shading normal. The BSDF is one-sided: eval and pdf are 0 when wo or wi lies on
// or below the surface (dot with n <= 0); a caller that wants the back side flips n. The
// rough dielectric alone also has values for wi below the surface (its transmission).
// bsdf_eval returns f(wo, wi) |cos theta_i|, the integrand of the rendering equation.
//
// "principled" is the glTF 2.0 metallic-roughness model:
//   f = (1 - metallic) base_color / pi (1 - F_d(cos_o)) (1 - F_d(cos_i))
//     + F(wo.h) D(h) G2(wo, wi) / (4 cos_o cos_i)
//   F0 = mix(F0_d, base_color, metallic); F = Schlick with F0; F_d = Schlick with F0_d;
//   F0_d = ((ior - 1) / (ior + 1))^2, the dielectric part's normal-incidence reflectance
//   (glTF's KHR_materials_ior; 0.04 at the default ior 1.5, glTF 2.0's dielectric);
//   alpha = max(roughness^2, BSDF_ALPHA_MIN); D = GGX (Walter et al. 2007, eq. 33);
//   G2 = height-correlated Smith, 1 / (1 + Lambda(wo) + Lambda(wi)) (Heitz 2014, eq. 99).
// The diffuse Fresnel factor (1 - F_d(cos_o)) (1 - F_d(cos_i)) is the energy term: without
// it a white dielectric reflects more than it receives (Lambert alone already has albedo
// 1). glTF's sample implementation weights the diffuse lobe by 1 - F_d(wo.h) instead,
// which still gains energy at grazing angles, where the specular lobe reflects most and
// wo.h stays large for most wi; with the separable factor a white dielectric's albedo
// stays below 0.99 (tests/bsdf.rs, white furnace). The factor is symmetric in wo and wi,
// so the whole BSDF stays reciprocal, and it depends on no parameter, so the derivatives
// stay simple. It uses the dielectric F0_d because only the dielectric part (weight
// 1 - metallic) has a diffuse lobe. ior is a constant of the material (never optimised).
//
// "dielectric" is a smooth interface between two transparent media (Mitsuba 3's
// `dielectric`): with m.ior = eta, the index of refraction of the side below the surface
// over that of wo's side, it mirrors wo with the unpolarised Fresnel reflectance F and
// refracts it by Snell's law with 1 - F (all of it mirrored under total internal
// reflection). Its lobes are Dirac deltas, so bsdf_eval, bsdf_pdf, bsdf_sample and
// bsdf_eval_grad return 0 (false) for it, as for any direction a light sample can pick; the
// integrator draws its continuation with dielectric_sample instead. Radiance crossing
// into the denser side is compressed into a smaller solid angle: the refracted weight
// carries 1 / eta^2 (Veach 1997, section 5.2; Mitsuba's radiance mode). base_color
// tints the refracted light only (Mitsuba's specular_transmittance).
//
// "rough dielectric" is the dielectric's interface on GGX microfacets (Walter et al. 2007;
// Mitsuba 3's `roughdielectric` with the GGX distribution and visible-normal sampling):
// each microfacet mirrors with the Fresnel reflectance at wo.h and refracts the rest,
// into lobes that bsdf_eval, bsdf_pdf, bsdf_sample and bsdf_eval_grad handle like any
// other (light samples reach it from both sides); see rough_glass_terms for the formulas.
// base_color tints the transmission (with the smooth dielectric's 1/eta^2), roughness is
// the principled model's (alpha = roughness^2) and can be optimised.
//
// "conductor" is a metal's interface on microfacets (Mitsuba 3's `roughconductor`, of
// either distribution, with visible-normal sampling): each microfacet mirrors with
// the Fresnel reflectance of the complex index of refraction m.eta + i m.k at wo.h, tinted
// by base_color (Mitsuba's specular_reflectance); nothing is transmitted. Its terms are
// the rough dielectric's reflection (see microfacet_terms); roughness is the principled
// model's and can be optimised, as can base_color.
//
// "plastic" is a diffuse base under a dielectric coating on microfacets (Mitsuba 3's
// `roughplastic`, of either distribution, with visible-normal sampling): the coating
// mirrors with the Fresnel reflectance F(wo.h) of its index m.ior on the microfacets (the
// conductor's terms with the real Fresnel term, tinted by m.specular, Mitsuba's
// specular_reflectance), and the light it transmits
// reaches the base, whose reflectance base_color is raised by the coating's internal
// reflections to base_color / (1 - m.internal) (base_color / (1 - base_color m.internal)
// with COATING_NONLINEAR), and leaves through the coating again:
//   diffuse = base / (pi eta^2) T(cos_o) T(cos_i) cos_i
// An unlayered coating (COATING_UNLAYERED, Mitsuba 3's `pplastic` in RGB) has neither the
// internal reflections nor the 1 / eta^2: diffuse = base / pi T(cos_o) T(cos_i) cos_i
// with T = 1 - F, its smooth interface's transmittance (exact, not tabulated), at any
// roughness.
// T is the coating's directional transmittance, tabulated at PLASTIC_TABLE_SIZE
// cosines (bsdf_table) and m.internal its internal diffuse reflectance, both computed on
// the host as Mitsuba computes them (src/bsdf.rs, coating). base_color can be optimised;
// roughness and the index cannot (the table depends on them).
//
// "thin dielectric" is a sheet of no thickness with that interface on both faces (Mitsuba
// 3's `thindielectric`): the light that enters it leaves it again, after any number of
// internal reflections, on one side or the other, so it mirrors with R = F + (1 - F)^2 F /
// (1 - F^2) = 2F / (1 + F) and lets 1 - R straight through (wi = -wo, tinted by
// base_color, no 1/eta^2: the medium is the same on both sides).
#ifndef BSDF_GLSL
#define BSDF_GLSL
#include "shared/material.glsl"

// Whether the interface functions below handle MATERIAL_ROUGH_DIELECTRIC. A kernel whose
// scene may have none defines it as a specialisation constant before including this file
// (lib/integrator.glsl: HAS_ROUGH_DIELECTRICS), so that the compiler can drop the branch,
// which lavapipe would otherwise run, masked, at every evaluation (docs/lavapipe.md).
#ifndef BSDF_ROUGH_DIELECTRICS
#define BSDF_ROUGH_DIELECTRICS true
#endif
// Likewise for MATERIAL_CONDUCTOR (lib/integrator.glsl: HAS_CONDUCTORS).
#ifndef BSDF_CONDUCTORS
#define BSDF_CONDUCTORS true
#endif
// Likewise for MATERIAL_PLASTIC (lib/integrator.glsl: HAS_PLASTICS).
#ifndef BSDF_PLASTICS
#define BSDF_PLASTICS true
#endif

// Entry `index` of the table that starts at `table` (a plastic's transmittance): defined by
// each kernel that includes this file, from wherever it keeps the tables.
float bsdf_table(uint table, int index);

const float BSDF_PI = 3.14159265358979;
// Smallest GGX alpha: keeps D (peak 1 / (pi alpha^2) = 3.2e5) and its derivatives finite
// in float32 for roughness 0. Below roughness sqrt(BSDF_ALPHA_MIN) ~ 0.032 the model does
// not change with roughness, so its roughness derivative is 0 there. Mirrored in
// src/bsdf.rs (ALPHA_MIN); the GPU/CPU comparison at roughness 0 checks that they agree.
const float BSDF_ALPHA_MIN = 1e-3;
// Rec. 709 luminance, used only to choose between lobes.
const vec3 BSDF_LUMINANCE = vec3(0.2126, 0.7152, 0.0722);

// ---------------------------------------------------------------------------------------
// Local shading frame
// ---------------------------------------------------------------------------------------

// An orthonormal basis (t, b, n); local coordinates are (x, y, z) = (t, b, n) components.
struct ShadingFrame {
    vec3 t;
    vec3 b;
    vec3 n;
};

// Branchless orthonormal basis from a unit normal: Duff et al. 2017, "Building an
// Orthonormal Basis, Revisited" (JCGT 6(1)), listing 3. The sign must be +1 at n.z = 0
// (GLSL's sign() returns 0 there).
ShadingFrame shading_frame(vec3 n) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float b = n.x * n.y * a;
    ShadingFrame f;
    f.t = vec3(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
    f.b = vec3(b, s + n.y * n.y * a, -n.y);
    f.n = n;
    return f;
}

vec3 shading_to_local(ShadingFrame f, vec3 v) { return vec3(dot(v, f.t), dot(v, f.b), dot(v, f.n)); }

vec3 shading_to_world(ShadingFrame f, vec3 v) { return v.x * f.t + v.y * f.b + v.z * f.n; }

// ---------------------------------------------------------------------------------------
// Building blocks (local frame)
// ---------------------------------------------------------------------------------------

float bsdf_alpha(float roughness) { return max(roughness * roughness, BSDF_ALPHA_MIN); }

// d alpha / d roughness; 0 where the clamp holds alpha at BSDF_ALPHA_MIN.
float bsdf_dalpha_droughness(float roughness) {
    return roughness * roughness > BSDF_ALPHA_MIN ? 2.0 * roughness : 0.0;
}

// (1 - c)^5, the Schlick (1994) Fresnel weight.
float bsdf_schlick_weight(float c) {
    float m = clamp(1.0 - c, 0.0, 1.0);
    float m2 = m * m;
    return m2 * m2 * m;
}

// The principled model's dielectric normal-incidence reflectance F0_d from its index of
// refraction: ((ior - 1) / (ior + 1))^2, the same for ior and 1 / ior.
float principled_f0(float ior) {
    float r = (ior - 1.0) / (ior + 1.0);
    return r * r;
}

// Schlick's Fresnel reflectance of normal-incidence reflectance f0 at cosine c.
float bsdf_fresnel_schlick(float f0, float c) {
    return f0 + (1.0 - f0) * bsdf_schlick_weight(c);
}

// Everything the principled model needs at one (wo, wi), both above the surface.
struct PrincipledTerms {
    float alpha;
    vec3 h;           // unit half vector
    float k;          // alpha^2 h.z^2 + h.x^2 + h.y^2: D = alpha^2 / (pi k^2)
    float s;          // Schlick weight at wo.h
    float q_o;        // sqrt(cos_o^2 + alpha^2 sin_o^2)
    float q_i;        // sqrt(cos_i^2 + alpha^2 sin_i^2)
    float denom_o;    // cos_o (1 + Lambda(wo)): the VNDF pdf is D / (4 denom_o)
    float denom;      // cos_o (1 + Lambda(wo) + Lambda(wi)): D G2 / (4 cos_o) = D / (4 denom)
    float d;          // GGX D(h)
    float specular;   // D G2 / (4 cos_o), the specular value per unit Fresnel
    float diffuse;    // (1 - F_d(cos_o)) (1 - F_d(cos_i)) cos_i / pi, per unit (1 - metallic) base_color
    float f0_d;       // principled_f0(ior)
};

// D is written as alpha^2 / (pi (alpha^2 h.z^2 + h.x^2 + h.y^2)^2), which equals Walter et
// al.'s alpha^2 / (pi (h.z^2 (alpha^2 - 1) + 1)^2) for unit h without the cancellation in
// 1 - h.z^2 that float32 cannot afford near the peak at small alpha. Likewise
// cos Lambda = (q - cos) / 2 (Heitz 2014, eq. 72, times cos) is computed as
// alpha^2 sin^2 / (2 (q + cos)), which stays finite for grazing directions.
//
// h is normalize(wo + wi), passed in so that bsdf_sample can use the microfacet normal it
// sampled (as pbrt-v4 and Mitsuba 3 do): recomputing it from the float32 reflected wi
// moves its tangential part by ~1e-7, which changes D by up to ~1% at alpha = 1e-3, and
// the sample's weight and pdf should describe the microfacet that was drawn.
PrincipledTerms principled_terms(Material m, vec3 wo, vec3 wi, vec3 h) {
    PrincipledTerms t;
    t.alpha = bsdf_alpha(m.roughness);
    t.f0_d = principled_f0(m.ior);
    float a2 = t.alpha * t.alpha;
    t.h = h;
    t.k = a2 * t.h.z * t.h.z + t.h.x * t.h.x + t.h.y * t.h.y;
    t.s = bsdf_schlick_weight(dot(wo, t.h));
    float sin2_o = wo.x * wo.x + wo.y * wo.y;
    float sin2_i = wi.x * wi.x + wi.y * wi.y;
    t.q_o = sqrt(wo.z * wo.z + a2 * sin2_o);
    t.q_i = sqrt(wi.z * wi.z + a2 * sin2_i);
    float cos_lambda_o = a2 * sin2_o / (2.0 * (t.q_o + wo.z));
    float cos_o_lambda_i = (wo.z / wi.z) * a2 * sin2_i / (2.0 * (t.q_i + wi.z));
    t.denom_o = wo.z + cos_lambda_o;
    t.denom = t.denom_o + cos_o_lambda_i;
    t.d = a2 / (BSDF_PI * t.k * t.k);
    t.specular = t.d / (4.0 * t.denom);
    t.diffuse = (1.0 - bsdf_fresnel_schlick(t.f0_d, wo.z)) * (1.0 - bsdf_fresnel_schlick(t.f0_d, wi.z)) * wi.z / BSDF_PI;
    return t;
}

// Probabilities of sampling the (diffuse, specular) lobe: their shares of the luminance of
// the two lobes' weights at the viewing angle, Schlick F(cos_o) against (1 - metallic)
// base_color (1 - F_d(cos_o)). They depend on wo only, so bsdf_pdf can recompute them;
// (0, 1) when both weights are 0 (a black metal seen head-on), (1, 0) for the diffuse
// kind. Both are returned, not p and 1 - p: when one is near 1 the other would lose its
// digits to cancellation, and the mixture pdf needs it to full relative precision.
vec2 bsdf_lobe_probabilities(Material m, float cos_o) {
    if (m.kind != MATERIAL_PRINCIPLED) return vec2(1.0, 0.0);
    float f0_d = principled_f0(m.ior);
    vec3 f0 = mix(vec3(f0_d), m.base_color, m.metallic);
    float s = bsdf_schlick_weight(cos_o);
    float spec = max(dot(BSDF_LUMINANCE, f0 + (1.0 - f0) * s), 0.0);
    float diff = max((1.0 - m.metallic) * dot(BSDF_LUMINANCE, m.base_color) * (1.0 - bsdf_fresnel_schlick(f0_d, cos_o)), 0.0);
    float total = spec + diff;
    return total > 0.0 ? vec2(diff, spec) / total : vec2(0.0, 1.0);
}

// f cos_i of the principled model from its terms.
vec3 principled_value(Material m, PrincipledTerms t) {
    vec3 f0 = mix(vec3(t.f0_d), m.base_color, m.metallic);
    vec3 fresnel = f0 + (1.0 - f0) * t.s;
    return (1.0 - m.metallic) * t.diffuse * m.base_color + fresnel * t.specular;
}

// Mixture pdf of the principled model from its terms and the lobe probabilities p.
float principled_pdf(vec2 p, float cos_i, PrincipledTerms t) {
    // Cosine-weighted hemisphere for the diffuse lobe. Visible normals for the specular
    // one: D_wo(h) = G1(wo) max(0, wo.h) D(h) / cos_o (Heitz 2018, eq. 1), times the
    // reflection Jacobian 1 / (4 wo.h) (Walter et al. 2007, eq. 14).
    return p.x * (cos_i / BSDF_PI) + p.y * (t.d / (4.0 * t.denom_o));
}

// The unpolarised Fresnel reflectance of an interface with relative index eta (the far
// side's over wo's) at cos_i = cos(wo, n) > 0, and the cosine of the refracted direction
// in cos_t (0 under total internal reflection, where the reflectance is 1).
float dielectric_fresnel(float cos_i, float eta, out float cos_t) {
    float sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0) {
        cos_t = 0.0;
        return 1.0;
    }
    cos_t = sqrt(1.0 - sin2_t);
    float rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    float rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

// ---------------------------------------------------------------------------------------
// The rough dielectric (local frame, wo.z > 0; wi above the surface for the reflected
// lobe, below it for the transmitted one)
// ---------------------------------------------------------------------------------------

// The microfacet terms of the rough dielectric and the conductor at one (wo, wi). With
// h the microfacet normal that takes wo to wi (normalize(wo + wi) for a reflection,
// normalize(wo + eta wi) for a refraction, on the upper side), every lobe is
//   value = mass D(h) G1(wo) G1(wi) (wo.h) jac / cos_o,   pdf = prob density
// where jac = |dh/dwi| is 1 / (4 wo.h) for the reflection (Walter et al. 2007, eq. 14)
// and eta^2 |wi.h| / (wo.h + eta wi.h)^2 for the refraction (eq. 17), and density the
// sampled normals' density times jac: the visible normals' D(h) G1(wo) (wo.h) / cos_o, of
// either distribution (Heitz 2018 for GGX, Jakob 2014 for Beckmann, whose density has
// Smith's exact G1(wo) where the value has Walter et al.'s approximation). The rough dielectric's reflection has mass = prob = F(wo.h), its transmission
// prob = 1 - F and mass = (1 - F) base_color / eta^2 (radiance mode, as the smooth
// dielectric); the conductor has one lobe, the reflection, of prob 1 and mass F_c(wo.h)
// base_color with the conductor's Fresnel reflectance. G1 is Smith's masking of each
// direction separately: the shadowing-masking G1(wo) G1(wi) of Mitsuba 3's
// roughdielectric and roughconductor, not the height-correlated form of the principled
// model; Beckmann's G1 is Walter et al.'s rational approximation (eq. 27), as Mitsuba's.
// Directions that see the back of their microfacet (wo.h <= 0, or wi.h on the wrong side)
// have value and pdf 0.
struct MicrofacetTerms {
    bool valid;
    float dln_d;     // d ln D / d alpha
    float dln_g1;    // d ln (G1(wo) G1(wi)) / d alpha
    float value;     // D G1(wo) G1(wi) (wo.h) jac / cos_o: the value per unit lobe mass
    float density;   // the pdf per unit lobe probability
    float oh;        // wo.h
    float fresnel;   // the rough dielectric's F(wo.h) (rough_glass_terms; 0 otherwise)
    bool reflect;
};

// Smith's G1 of GGX for direction v (either side), 1 / (1 + Lambda) with Lambda written as
// alpha^2 sin^2 / (2 |cos| (q + |cos|)), q = sqrt(cos^2 + alpha^2 sin^2) (Heitz 2014,
// eq. 72, without the cancellation in q - |cos|); d ln G1 / d alpha in dln.
float ggx_g1(vec3 v, float alpha, out float dln) {
    float a2 = alpha * alpha;
    float c = abs(v.z);
    float s2 = v.x * v.x + v.y * v.y;
    float q = sqrt(c * c + a2 * s2);
    float lambda = a2 * s2 / (2.0 * c * (q + c));
    // d Lambda / d alpha = alpha sin^2 / (2 |cos| q)
    dln = -(alpha * s2 / (2.0 * c * q)) / (1.0 + lambda);
    return 1.0 / (1.0 + lambda);
}

// Smith's G1 of Beckmann for direction v (either side): Walter et al. 2007's rational
// approximation in a = |cos| / (alpha sin), 1 from a = 1.6 on; d ln G1 / d alpha in dln.
float beckmann_g1(vec3 v, float alpha, out float dln) {
    float c = abs(v.z);
    float s = sqrt(v.x * v.x + v.y * v.y);
    dln = 0.0;
    if (c >= 1.6 * alpha * s) return 1.0;
    float a = c / (alpha * s);
    float num = (3.535 + 2.181 * a) * a;
    float den = 1.0 + (2.276 + 2.577 * a) * a;
    float dnum = 3.535 + 4.362 * a;
    float dden = 2.276 + 5.154 * a;
    // d ln G1 / da = dnum / num - dden / den, and da / d alpha = -a / alpha.
    dln = (dden / den - dnum / num) * a / alpha;
    return num / den;
}

// 1 + erf(x), from Abramowitz and Stegun's 7.1.26 (absolute error below 1.5e-7): for
// x < 0 it is erfc(-x) = t poly(t) exp(-x^2), taken as is, without the cancellation of
// 1 + erf(x) in the tail.
float bsdf_one_plus_erf(float x) {
    float t = 1.0 / (1.0 + 0.3275911 * abs(x));
    float q = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))) * exp(-x * x);
    return x < 0.0 ? q : 2.0 - q;
}

// The inverse of erf at x in (-1, 1) given (1 - x)(1 + x), which the caller can often
// compute without cancellation: Giles 2010, "Approximating the erfinv function", the
// single-precision polynomials.
float bsdf_erfinv(float x, float one_minus_x2) {
    float w = -log(one_minus_x2);
    float p;
    if (w < 5.0) {
        w -= 2.5;
        p = 2.81022636e-08;
        p = 3.43273939e-07 + p * w;
        p = -3.5233877e-06 + p * w;
        p = -4.39150654e-06 + p * w;
        p = 0.00021858087 + p * w;
        p = -0.00125372503 + p * w;
        p = -0.00417768164 + p * w;
        p = 0.246640727 + p * w;
        p = 1.50140941 + p * w;
    } else {
        w = sqrt(w) - 3.0;
        p = -0.000200214257;
        p = 0.000100950558 + p * w;
        p = 0.00134934322 + p * w;
        p = -0.00367342844 + p * w;
        p = 0.00573950773 + p * w;
        p = -0.0076224613 + p * w;
        p = 0.00943887047 + p * w;
        p = 1.00167406 + p * w;
        p = 2.83297682 + p * w;
    }
    return p * x;
}

// 1 / sqrt(pi)
const float BSDF_INV_SQRT_PI = 0.56418958354775628;

// A Beckmann normal distributed as the visible normals seen from wo (local, wo.z > 0), the
// density G1(wo) D(h) max(0, wo.h) / cos_o with Smith's exact G1 (beckmann_g1_exact). In
// the configuration stretched to alpha = 1 and turned so that wo lies in the xz plane, the
// slope along x of the normals that face wo (x < cot_o) has the CDF
//   C(x) = (1 + erf(x) + tan_o exp(-x^2) / sqrt(pi)) / (1 + erf(cot_o) + tan_o exp(-cot_o^2) / sqrt(pi)),
// inverted by Newton's method safeguarded by bisection on [-6, min(cot_o, 6)], 10 steps
// from Jakob's initial guess (Jakob 2014, "An Improved Visible Normal Sampling Routine for
// the Beckmann Distribution"), in the slope itself rather than in erf's range, so that
// the tails keep float32's precision; the slope along y is Gaussian, erfinv(2 u - 1). The
// slopes are turned back and scaled by alpha; the normal is (-slope, 1) normalised.
vec3 beckmann_sample_visible_normal(vec3 wo, float alpha, vec2 u) {
    vec3 v = normalize(vec3(alpha * wo.x, alpha * wo.y, wo.z));
    // (The tangential part's length, not sqrt(1 - cos^2), which loses sin_o near the pole.)
    float sin_o = sqrt(v.x * v.x + v.y * v.y);
    float tan_o = sin_o / v.z;
    float cot_o = sin_o > 0.0 ? v.z / sin_o : 1e15;
    float ux = max(u.x, 1e-6);
    float e_cot = bsdf_one_plus_erf(cot_o);
    float norm = 1.0 / (e_cot + BSDF_INV_SQRT_PI * tan_o * exp(-cot_o * cot_o));
    // Jakob's fit of the inverse, in erf's range, as the start.
    float theta = atan(sin_o, v.z);
    float fit = 1.0 + theta * (-0.876 + theta * (0.4265 - 0.0594 * theta));
    float c = e_cot - 1.0;
    float b = c - (1.0 + c) * pow(1.0 - ux, fit);
    float lo = -6.0;
    float hi = min(cot_o, 6.0);
    float x = bsdf_erfinv(b, (1.0 - b) * (1.0 + b));
    for (int k = 0; k < 10; ++k) {
        // (Written so that a NaN x fails the test too.)
        if (!(x >= lo && x <= hi)) x = 0.5 * (lo + hi);
        float g = exp(-x * x);
        float value = norm * (bsdf_one_plus_erf(x) + BSDF_INV_SQRT_PI * tan_o * g) - ux;
        float density = norm * (2.0 * BSDF_INV_SQRT_PI) * g * (1.0 - x * tan_o);
        if (value > 0.0) hi = x; else lo = x;
        x -= value / density;
    }
    if (!(x >= lo && x <= hi)) x = 0.5 * (lo + hi);
    float uy = clamp(u.y, 1e-6, 1.0 - 1e-6);
    vec2 slope = vec2(x, bsdf_erfinv(2.0 * uy - 1.0, 4.0 * uy * (1.0 - uy)));
    float cos_phi = sin_o > 0.0 ? v.x / sin_o : 1.0;
    float sin_phi = sin_o > 0.0 ? v.y / sin_o : 0.0;
    slope = alpha * vec2(cos_phi * slope.x - sin_phi * slope.y, sin_phi * slope.x + cos_phi * slope.y);
    return normalize(vec3(-slope.x, -slope.y, 1.0));
}

// Smith's exact G1 of Beckmann for direction v (either side), 2 / (1 + erf(a) +
// exp(-a^2) / (a sqrt(pi))) with a = |cos| / (alpha sin): the normalisation of the visible
// normals that beckmann_sample_visible_normal draws, so the density of its samples. The
// value keeps Walter et al.'s approximation (beckmann_g1), within 0.35 % of it, as
// Mitsuba's does.
float beckmann_g1_exact(vec3 v, float alpha) {
    float c = abs(v.z);
    float s = sqrt(v.x * v.x + v.y * v.y);
    if (!(s > 0.0)) return 1.0;
    float a = c / (alpha * s);
    return 2.0 / (bsdf_one_plus_erf(a) + BSDF_INV_SQRT_PI * exp(-a * a) / a);
}

// The terms at (wo, wi) with microfacet normal h (computed from wo and wi by the caller, or
// the sampled one), for either distribution; eta (the refraction's) enters only the
// transmission's Jacobian.
MicrofacetTerms microfacet_terms(float roughness, bool beckmann, float eta, vec3 wo, vec3 wi, vec3 h) {
    MicrofacetTerms t;
    t.reflect = wi.z > 0.0;
    float a = bsdf_alpha(roughness);
    float a2 = a * a;
    t.oh = dot(wo, h);
    float ih = dot(wi, h);
    t.valid = wo.z > 0.0 && wi.z != 0.0 && t.oh > 0.0 && (t.reflect ? ih > 0.0 : ih < 0.0);
    float d, g1_o, g1_i, dln_o, dln_i;
    if (beckmann) {
        float t2 = (h.x * h.x + h.y * h.y) / (h.z * h.z);
        float c2 = h.z * h.z;
        d = exp(-t2 / a2) / (BSDF_PI * a2 * c2 * c2);
        t.dln_d = 2.0 * t2 / (a2 * a) - 2.0 / a;
        g1_o = beckmann_g1(wo, a, dln_o);
        g1_i = beckmann_g1(wi, a, dln_i);
    } else {
        // D = alpha^2 / (pi k^2) with k = alpha^2 h.z^2 + h.x^2 + h.y^2 (principled_terms).
        float k = a2 * h.z * h.z + h.x * h.x + h.y * h.y;
        d = a2 / (BSDF_PI * k * k);
        t.dln_d = 2.0 / a - 4.0 * a * h.z * h.z / k;
        g1_o = ggx_g1(wo, a, dln_o);
        g1_i = ggx_g1(wi, a, dln_i);
    }
    t.dln_g1 = dln_o + dln_i;
    t.fresnel = 0.0;
    float jac;
    if (t.reflect) {
        jac = 1.0 / (4.0 * t.oh);
    } else {
        float den = t.oh + eta * ih;
        jac = eta * eta * abs(ih) / (den * den);
    }
    float visible = d * g1_o * t.oh * jac / wo.z;
    t.value = visible * g1_i;
    t.density = beckmann ? visible * (beckmann_g1_exact(wo, a) / g1_o) : visible;
    if (!t.valid || !(t.density > 0.0)) {
        t.valid = false;
        t.value = 0.0;
        t.density = 0.0;
    }
    return t;
}

// The rough dielectric's terms: the microfacet terms and the Fresnel reflectance at wo.h.
MicrofacetTerms rough_glass_terms(Material m, vec3 wo, vec3 wi, vec3 h) {
    MicrofacetTerms t = microfacet_terms(m.roughness, m.kind == MATERIAL_ROUGH_DIELECTRIC_BECKMANN, m.ior, wo, wi, h);
    float cos_t;
    t.fresnel = dielectric_fresnel(t.oh, m.ior, cos_t);
    return t;
}

// The microfacet normal that takes wo to wi, on the upper side (either lobe).
vec3 rough_glass_half(Material m, vec3 wo, vec3 wi) {
    vec3 h = normalize(wi.z > 0.0 ? wo + wi : wo + m.ior * wi);
    return h.z < 0.0 ? -h : h;
}

// The lobe's mass over its probability: 1 for the reflection, base_color / eta^2 for the
// transmission.
vec3 rough_glass_tint(Material m, MicrofacetTerms t) {
    return t.reflect ? vec3(1.0) : m.base_color / (m.ior * m.ior);
}

vec3 rough_glass_value(Material m, MicrofacetTerms t) {
    if (!t.valid) return vec3(0.0);
    float prob = t.reflect ? t.fresnel : 1.0 - t.fresnel;
    return (prob * t.value) * rough_glass_tint(m, t);
}

float rough_glass_pdf(MicrofacetTerms t) {
    if (!t.valid) return 0.0;
    return (t.reflect ? t.fresnel : 1.0 - t.fresnel) * t.density;
}

// ---------------------------------------------------------------------------------------
// The conductor (local frame, wo.z > 0, wi above the surface)
// ---------------------------------------------------------------------------------------

// The unpolarised Fresnel reflectance at cos_i = cos(wo, h) in (0, 1] of a conductor with
// complex index of refraction eta + i k per channel, relative to wo's side: with
// a^2 + b^2 = |(eta + i k)^2 - sin^2|, a = sqrt((a^2 + b^2 + eta^2 - k^2 - sin^2) / 2),
//   R_s = (a^2 + b^2 + cos^2 - 2 a cos) / (a^2 + b^2 + cos^2 + 2 a cos),
//   R_p = R_s (cos^2 (a^2 + b^2) + sin^4 - 2 a cos sin^2) / (cos^2 (a^2 + b^2) + sin^4 + 2 a cos sin^2)
// (Born and Wolf; k = 0 gives the dielectric's, eta = 0 and k = 1 a perfect mirror).
vec3 conductor_fresnel(float c, vec3 eta, vec3 k) {
    float c2 = c * c;
    float s2 = 1.0 - c2;
    vec3 t0 = eta * eta - k * k - s2;
    vec3 a2b2 = sqrt(t0 * t0 + 4.0 * eta * eta * k * k);
    vec3 a = sqrt(max(0.5 * (a2b2 + t0), vec3(0.0)));
    vec3 t1 = a2b2 + c2;
    vec3 t2 = 2.0 * c * a;
    vec3 rs = (t1 - t2) / (t1 + t2);
    vec3 t3 = c2 * a2b2 + s2 * s2;
    vec3 t4 = t2 * s2;
    vec3 rp = rs * (t3 - t4) / (t3 + t4);
    return 0.5 * (rs + rp);
}

// The conductor's terms at (wo, wi) with microfacet normal h: the reflection's.
MicrofacetTerms conductor_terms(Material m, vec3 wo, vec3 wi, vec3 h) {
    return microfacet_terms(m.roughness, m.kind == MATERIAL_CONDUCTOR_BECKMANN, 1.0, wo, wi, h);
}

vec3 conductor_value(Material m, MicrofacetTerms t) {
    if (!t.valid) return vec3(0.0);
    return t.value * conductor_fresnel(t.oh, m.eta, m.k) * m.base_color;
}

// ---------------------------------------------------------------------------------------
// The plastic (local frame, wo.z > 0, wi above the surface)
// ---------------------------------------------------------------------------------------

// The coating's directional transmittance at cos theta c in [0, 1]: its table's entries
// at i / (PLASTIC_TABLE_SIZE - 1), interpolated linearly (as Mitsuba's lerp_gather); an
// unlayered coating's 1 - F(c), its smooth interface's, exact (it has no table).
float plastic_transmittance(Material m, float c) {
    if ((m.coating & COATING_UNLAYERED) != 0u) {
        float cos_t;
        return 1.0 - dielectric_fresnel(c, m.ior, cos_t);
    }
    float x = c * float(PLASTIC_TABLE_SIZE - 1u);
    int i = min(int(x), int(PLASTIC_TABLE_SIZE) - 2);
    return mix(bsdf_table(m.table, i), bsdf_table(m.table, i + 1), x - float(i));
}

// The coating's reflection terms at (wo, wi) with microfacet normal h.
MicrofacetTerms plastic_terms(Material m, vec3 wo, vec3 wi, vec3 h) {
    return microfacet_terms(m.roughness, m.kind == MATERIAL_PLASTIC_BECKMANN, 1.0, wo, wi, h);
}

// The diffuse lobe per unit reflectance of the base as seen through the coating:
// T(cos_o) T(cos_i) cos_i / (pi eta^2), without the 1 / eta^2 for an unlayered coating.
float plastic_diffuse(Material m, vec3 wo, vec3 wi) {
    float spread = (m.coating & COATING_UNLAYERED) != 0u ? 1.0 : m.ior * m.ior;
    return wi.z * plastic_transmittance(m, wo.z) * plastic_transmittance(m, wi.z) / (BSDF_PI * spread);
}

// 1 - the share of the base's light that the coating's internal reflections keep:
// 1 - r, or 1 - b r with COATING_NONLINEAR (r = 0 for an unlayered coating).
vec3 plastic_kept(Material m) {
    return 1.0 - ((m.coating & COATING_NONLINEAR) != 0u ? m.base_color * m.internal : vec3(m.internal));
}

// The base's reflectance with the coating's internal reflections.
vec3 plastic_base(Material m) {
    return m.base_color / plastic_kept(m);
}

vec3 plastic_value(Material m, vec3 wo, vec3 wi, MicrofacetTerms t) {
    float cos_t;
    float spec = t.valid ? t.value * dielectric_fresnel(t.oh, m.ior, cos_t) : 0.0;
    return m.specular * spec + plastic_base(m) * plastic_diffuse(m, wo, wi);
}

// The probability of sampling the coating's reflection at cos_o: Mitsuba's, (1 - T) w
// against T (1 - w) with w = s / (s + d), s and d the means of the specular tint and of
// base_color (1 / (1 + d) for an untinted coating).
float plastic_specular_prob(Material m, float cos_o) {
    float t = plastic_transmittance(m, cos_o);
    float s = max((m.specular.r + m.specular.g + m.specular.b) / 3.0, 0.0);
    float d = max((m.base_color.r + m.base_color.g + m.base_color.b) / 3.0, 0.0);
    float w = s + d > 0.0 ? s / (s + d) : 0.5;
    float spec = (1.0 - t) * w;
    float total = spec + t * (1.0 - w);
    return total > 0.0 ? spec / total : 1.0;
}

float plastic_pdf(float prob, vec3 wi, MicrofacetTerms t) {
    return prob * (t.valid ? t.density : 0.0) + (1.0 - prob) * wi.z / BSDF_PI;
}

vec3 bsdf_eval_local(Material m, vec3 wo, vec3 wi) {
    if (BSDF_ROUGH_DIELECTRICS && material_is_rough_glass(m.kind)) {
        return rough_glass_value(m, rough_glass_terms(m, wo, wi, rough_glass_half(m, wo, wi)));
    }
    if (wo.z <= 0.0 || wi.z <= 0.0) return vec3(0.0);
    if (BSDF_CONDUCTORS && material_is_conductor(m.kind)) {
        return conductor_value(m, conductor_terms(m, wo, wi, normalize(wo + wi)));
    }
    if (BSDF_PLASTICS && material_is_plastic(m.kind)) {
        return plastic_value(m, wo, wi, plastic_terms(m, wo, wi, normalize(wo + wi)));
    }
    if (material_is_dielectric(m.kind)) return vec3(0.0);
    if (m.kind != MATERIAL_PRINCIPLED) return m.base_color * (wi.z / BSDF_PI);
    return principled_value(m, principled_terms(m, wo, wi, normalize(wo + wi)));
}

float bsdf_pdf_local(Material m, vec3 wo, vec3 wi) {
    if (BSDF_ROUGH_DIELECTRICS && material_is_rough_glass(m.kind)) {
        return rough_glass_pdf(rough_glass_terms(m, wo, wi, rough_glass_half(m, wo, wi)));
    }
    if (wo.z <= 0.0 || wi.z <= 0.0) return 0.0;
    if (BSDF_CONDUCTORS && material_is_conductor(m.kind)) {
        return conductor_terms(m, wo, wi, normalize(wo + wi)).density;
    }
    if (BSDF_PLASTICS && material_is_plastic(m.kind)) {
        return plastic_pdf(plastic_specular_prob(m, wo.z), wi, plastic_terms(m, wo, wi, normalize(wo + wi)));
    }
    if (material_is_dielectric(m.kind)) return 0.0;
    if (m.kind != MATERIAL_PRINCIPLED) return wi.z / BSDF_PI;
    vec2 p = bsdf_lobe_probabilities(m, wo.z);
    return principled_pdf(p, wi.z, principled_terms(m, wo, wi, normalize(wo + wi)));
}

// Cosine-weighted hemisphere by Malley's method (pbrt-v4 SampleCosineHemisphere, with the
// polar disk mapping).
vec3 bsdf_sample_cosine_hemisphere(vec2 u) {
    float r = sqrt(u.x);
    float phi = 2.0 * BSDF_PI * u.y;
    return vec3(r * cos(phi), r * sin(phi), sqrt(max(0.0, 1.0 - u.x)));
}

// A GGX normal distributed as the visible normals seen from wo (local, wo.z > 0): Heitz
// 2018, "Sampling the GGX Distribution of Visible Normals" (JCGT 7(4)), listing 1, for an
// isotropic alpha.
vec3 ggx_sample_visible_normal(vec3 wo, float alpha, vec2 u) {
    // Section 3.2: stretch to the hemisphere configuration.
    vec3 vh = normalize(vec3(alpha * wo.x, alpha * wo.y, wo.z));
    // Section 4.1: basis around vh (any basis when vh is the pole).
    float lensq = vh.x * vh.x + vh.y * vh.y;
    vec3 t1 = lensq > 0.0 ? vec3(-vh.y, vh.x, 0.0) * inversesqrt(lensq) : vec3(1.0, 0.0, 0.0);
    vec3 t2 = cross(vh, t1);
    // Section 4.2: uniform point on the projected half disk.
    float r = sqrt(u.x);
    float phi = 2.0 * BSDF_PI * u.y;
    float p1 = r * cos(phi);
    float p2 = r * sin(phi);
    float s = 0.5 * (1.0 + vh.z);
    p2 = (1.0 - s) * sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2;
    // Section 4.3: back onto the hemisphere; section 3.4: unstretch.
    vec3 nh = p1 * t1 + p2 * t2 + sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2)) * vh;
    return normalize(vec3(alpha * nh.x, alpha * nh.y, max(0.0, nh.z)));
}

// The direction of a glossy and a diffuse lobe, from u: with probability `prob` (u.x <
// prob) the mirror of wo about a visible normal h of either distribution, else a
// cosine-weighted direction, h halfway between it and wo.
vec3 bsdf_sample_two_lobes(float prob, bool beckmann, vec3 wo, float alpha, vec3 u, out vec3 h) {
    if (u.x < prob) {
        h = beckmann ? beckmann_sample_visible_normal(wo, alpha, u.yz) : ggx_sample_visible_normal(wo, alpha, u.yz);
        return 2.0 * dot(wo, h) * h - wo;
    }
    vec3 wi = bsdf_sample_cosine_hemisphere(u.yz);
    h = normalize(wo + wi);
    return wi;
}

// ---------------------------------------------------------------------------------------
// Interface (world space)
// ---------------------------------------------------------------------------------------

// f(wo, wi) |cos theta_i|; 0 when wo or wi is on or below the surface.
vec3 bsdf_eval(Material m, vec3 n, vec3 wo, vec3 wi) {
    ShadingFrame f = shading_frame(n);
    return bsdf_eval_local(m, shading_to_local(f, wo), shading_to_local(f, wi));
}

// Solid-angle density of the wi that bsdf_sample returns: the mixture of both lobes with
// the selection probabilities of bsdf_lobe_probabilities, as MIS needs.
float bsdf_pdf(Material m, vec3 n, vec3 wo, vec3 wi) {
    ShadingFrame f = shading_frame(n);
    return bsdf_pdf_local(m, shading_to_local(f, wo), shading_to_local(f, wi));
}

// Draws wi from u in [0, 1)^3: u.x selects the specular lobe with probability
// bsdf_lobe_probabilities(m, cos_o).y, u.yz place the direction (GGX visible normals
// reflected about wo, or cosine-weighted). Returns false (weight 0) when wo is below the
// surface or the reflected direction falls below it; the lost probability is what makes
// bsdf_pdf integrate to less than 1. weight = bsdf_eval / pdf and pdf = bsdf_pdf at wi,
// both evaluated at the sampled microfacet normal (see principled_terms).
bool bsdf_sample(Material m, vec3 n, vec3 wo, vec3 u, out vec3 wi, out vec3 weight, out float pdf) {
    wi = vec3(0.0);
    weight = vec3(0.0);
    pdf = 0.0;
    ShadingFrame f = shading_frame(n);
    vec3 wo_l = shading_to_local(f, wo);
    if (wo_l.z <= 0.0 || material_is_dielectric(m.kind)) return false;
    if (BSDF_ROUGH_DIELECTRICS && material_is_rough_glass(m.kind)) {
        // A visible normal h (of either distribution); the mirror about it with probability F(wo.h), else the refraction through it
        // (Snell's law about h; F = 1 under total internal reflection, so the refraction
        // is never picked there).
        float alpha = bsdf_alpha(m.roughness);
        vec3 h = m.kind == MATERIAL_ROUGH_DIELECTRIC_BECKMANN ? beckmann_sample_visible_normal(wo_l, alpha, u.yz) : ggx_sample_visible_normal(wo_l, alpha, u.yz);
        float oh = dot(wo_l, h);
        float cos_t;
        float fr = dielectric_fresnel(oh, m.ior, cos_t);
        vec3 wi_l = u.x < fr ? 2.0 * oh * h - wo_l : normalize((oh * h - wo_l) / m.ior - cos_t * h);
        MicrofacetTerms t = rough_glass_terms(m, wo_l, wi_l, h);
        pdf = rough_glass_pdf(t);
        if (!(pdf > 0.0)) {
            pdf = 0.0;
            return false;
        }
        wi = shading_to_world(f, wi_l);
        weight = rough_glass_value(m, t) / pdf;
        return true;
    }
    if (BSDF_CONDUCTORS && material_is_conductor(m.kind)) {
        // The mirror about a visible normal h (of either distribution).
        float alpha = bsdf_alpha(m.roughness);
        vec3 h = m.kind == MATERIAL_CONDUCTOR_BECKMANN ? beckmann_sample_visible_normal(wo_l, alpha, u.yz) : ggx_sample_visible_normal(wo_l, alpha, u.yz);
        vec3 wi_l = 2.0 * dot(wo_l, h) * h - wo_l;
        if (wi_l.z <= 0.0) return false;
        MicrofacetTerms t = conductor_terms(m, wo_l, wi_l, h);
        pdf = t.density;
        if (!(pdf > 0.0)) {
            pdf = 0.0;
            return false;
        }
        wi = shading_to_world(f, wi_l);
        weight = conductor_value(m, t) / pdf;
        return true;
    }
    if (BSDF_PLASTICS && material_is_plastic(m.kind)) {
        // The coating's mirror with probability plastic_specular_prob, else the base.
        float prob = plastic_specular_prob(m, wo_l.z);
        vec3 h;
        vec3 wi_l = bsdf_sample_two_lobes(prob, m.kind == MATERIAL_PLASTIC_BECKMANN, wo_l, bsdf_alpha(m.roughness), u, h);
        if (wi_l.z <= 0.0) return false;
        MicrofacetTerms t = plastic_terms(m, wo_l, wi_l, h);
        pdf = plastic_pdf(prob, wi_l, t);
        if (!(pdf > 0.0)) {
            pdf = 0.0;
            return false;
        }
        wi = shading_to_world(f, wi_l);
        weight = plastic_value(m, wo_l, wi_l, t) / pdf;
        return true;
    }
    if (m.kind != MATERIAL_PRINCIPLED) {
        // Lambert: pdf cos_i / pi, weight base_color exactly.
        vec3 wi_l = bsdf_sample_cosine_hemisphere(u.yz);
        if (wi_l.z <= 0.0) return false;
        wi = shading_to_world(f, wi_l);
        pdf = wi_l.z / BSDF_PI;
        weight = m.base_color;
        return true;
    }
    vec2 p = bsdf_lobe_probabilities(m, wo_l.z);
    vec3 h;
    vec3 wi_l = bsdf_sample_two_lobes(p.y, false, wo_l, bsdf_alpha(m.roughness), u, h);
    if (wi_l.z <= 0.0) return false;
    PrincipledTerms t = principled_terms(m, wo_l, wi_l, h);
    pdf = principled_pdf(p, wi_l.z, t);
    if (!(pdf > 0.0)) {
        pdf = 0.0;
        return false;
    }
    wi = shading_to_world(f, wi_l);
    weight = principled_value(m, t) / pdf;
    return true;
}

// Derivatives of bsdf_eval's value v (per colour channel c) with respect to the material
// parameters: d_base_color[c] = dv_c / dbase_color_c (the Jacobian is diagonal),
// d_roughness[c] = dv_c / droughness, d_metallic[c] = dv_c / dmetallic. With
// F_c = F0_c (1 - s) + s, F0_c = F0_d (1 - metallic) + metallic base_color_c and
// v_c = (1 - metallic) base_color_c diffuse + F_c specular:
//   dv_c/dbase_color_c = (1 - metallic) diffuse + metallic (1 - s) specular
//   dv_c/dmetallic     = -base_color_c diffuse + (base_color_c - F0_d) (1 - s) specular
//   dv_c/droughness    = F_c specular (dln D/dalpha - d ln(denom)/dalpha) dalpha/droughness
// with dln D/dalpha = 2 / alpha - 4 alpha h.z^2 / k and, from cos Lambda = (q - cos) / 2,
// d denom/dalpha = alpha sin_o^2 / (2 q_o) + (cos_o / cos_i) alpha sin_i^2 / (2 q_i).
void bsdf_eval_grad(Material m, vec3 n, vec3 wo, vec3 wi, out vec3 d_base_color, out vec3 d_roughness, out vec3 d_metallic) {
    d_base_color = vec3(0.0);
    d_roughness = vec3(0.0);
    d_metallic = vec3(0.0);
    ShadingFrame f = shading_frame(n);
    vec3 wo_l = shading_to_local(f, wo);
    vec3 wi_l = shading_to_local(f, wi);
    if (BSDF_ROUGH_DIELECTRICS && material_is_rough_glass(m.kind)) {
        MicrofacetTerms t = rough_glass_terms(m, wo_l, wi_l, rough_glass_half(m, wo_l, wi_l));
        // Linear in base_color through the transmission only; through alpha in D and
        // both G1.
        if (t.valid && !t.reflect) d_base_color = vec3((1.0 - t.fresnel) * t.value / (m.ior * m.ior));
        float dalpha = bsdf_dalpha_droughness(m.roughness);
        if (t.valid && dalpha != 0.0) d_roughness = rough_glass_value(m, t) * ((t.dln_d + t.dln_g1) * dalpha);
        return;
    }
    if (wo_l.z <= 0.0 || wi_l.z <= 0.0 || material_is_dielectric(m.kind)) return;
    if (BSDF_CONDUCTORS && material_is_conductor(m.kind)) {
        // Linear in base_color; through alpha in D and both G1.
        MicrofacetTerms t = conductor_terms(m, wo_l, wi_l, normalize(wo_l + wi_l));
        if (!t.valid) return;
        d_base_color = t.value * conductor_fresnel(t.oh, m.eta, m.k);
        float dalpha = bsdf_dalpha_droughness(m.roughness);
        if (dalpha != 0.0) d_roughness = conductor_value(m, t) * ((t.dln_d + t.dln_g1) * dalpha);
        return;
    }
    if (BSDF_PLASTICS && material_is_plastic(m.kind)) {
        // Through the base alone: d (b / (1 - r)) / db = 1 / (1 - r), and with nonlinear
        // d (b / (1 - b r)) / db = 1 / (1 - b r)^2.
        vec3 kept = plastic_kept(m);
        d_base_color = plastic_diffuse(m, wo_l, wi_l) / ((m.coating & COATING_NONLINEAR) != 0u ? kept * kept : kept);
        return;
    }
    if (m.kind != MATERIAL_PRINCIPLED) {
        d_base_color = vec3(wi_l.z / BSDF_PI);
        return;
    }
    PrincipledTerms t = principled_terms(m, wo_l, wi_l, normalize(wo_l + wi_l));
    vec3 f0 = mix(vec3(t.f0_d), m.base_color, m.metallic);
    vec3 fresnel = f0 + (1.0 - f0) * t.s;
    d_base_color = vec3((1.0 - m.metallic) * t.diffuse + m.metallic * (1.0 - t.s) * t.specular);
    d_metallic = -m.base_color * t.diffuse + (m.base_color - t.f0_d) * ((1.0 - t.s) * t.specular);
    float dalpha = bsdf_dalpha_droughness(m.roughness);
    if (dalpha != 0.0) {
        float a = t.alpha;
        float dln_d = 2.0 / a - 4.0 * a * t.h.z * t.h.z / t.k;
        float sin2_o = wo_l.x * wo_l.x + wo_l.y * wo_l.y;
        float sin2_i = wi_l.x * wi_l.x + wi_l.y * wi_l.y;
        float ddenom = a * sin2_o / (2.0 * t.q_o) + (wo_l.z / wi_l.z) * a * sin2_i / (2.0 * t.q_i);
        d_roughness = fresnel * (t.specular * (dln_d - ddenom / t.denom) * dalpha);
    }
}

// ---------------------------------------------------------------------------------------
// The smooth dielectric (delta lobes; world space, n the shading normal on wo's side)
// ---------------------------------------------------------------------------------------

// The reflectance of the material's interface at cos_i = cos(wo, n) > 0: the Fresnel
// reflectance for a dielectric, the sheet's 2F / (1 + F) for a thin one; the refracted
// cosine in cos_t (unused for a thin dielectric, whose transmission is not bent).
float dielectric_reflectance(Material m, float cos_i, out float cos_t) {
    float fr = dielectric_fresnel(cos_i, m.ior, cos_t);
    return m.kind == MATERIAL_THIN_DIELECTRIC ? 2.0 * fr / (1.0 + fr) : fr;
}

// The radiance factor of the transmitted lobe per unit (1 - reflectance) and unit
// base_color: 1 / eta^2 through an interface (the solid angle's compression), 1 through a
// thin sheet.
float dielectric_crossing(Material m) {
    return m.kind == MATERIAL_THIN_DIELECTRIC ? 1.0 : 1.0 / (m.ior * m.ior);
}

// The probability that dielectric_sample picks wi's lobe (the mirror when wi is above the
// surface, the transmission when below): R or 1 - R. 0 when wo is on or below the surface.
float dielectric_prob(Material m, vec3 n, vec3 wo, vec3 wi) {
    float cos_i = dot(wo, n);
    if (cos_i <= 0.0) return 0.0;
    float cos_t;
    float r = dielectric_reflectance(m, cos_i, cos_t);
    return dot(wi, n) > 0.0 ? r : 1.0 - r;
}

// The lobe's mass at wi (the discrete counterpart of f cos_i: the radiance that arrives
// along wi leaves along wo times this): R for the mirror, (1 - R) dielectric_crossing
// base_color for the transmission. wi is taken to be the lobe's direction; only its side is looked at.
vec3 dielectric_mass(Material m, vec3 n, vec3 wo, vec3 wi) {
    float cos_i = dot(wo, n);
    if (cos_i <= 0.0) return vec3(0.0);
    float cos_t;
    float r = dielectric_reflectance(m, cos_i, cos_t);
    return dot(wi, n) > 0.0 ? vec3(r) : ((1.0 - r) * dielectric_crossing(m)) * m.base_color;
}

// d dielectric_mass / d base_color, per channel (the Jacobian is diagonal): 0 for the
// mirror, the transmission's mass per unit base_color.
vec3 dielectric_mass_grad(Material m, vec3 n, vec3 wo, vec3 wi) {
    float cos_i = dot(wo, n);
    if (cos_i <= 0.0 || dot(wi, n) > 0.0) return vec3(0.0);
    float cos_t;
    float r = dielectric_reflectance(m, cos_i, cos_t);
    return vec3((1.0 - r) * dielectric_crossing(m));
}

// Picks the mirror with probability R (u < R) or the transmission: wi, its lobe's
// probability `prob` (not a density) and weight = dielectric_mass / prob. False when wo is
// on or below the surface.
bool dielectric_sample(Material m, vec3 n, vec3 wo, float u, out vec3 wi, out vec3 weight, out float prob) {
    wi = vec3(0.0);
    weight = vec3(0.0);
    prob = 0.0;
    float cos_i = dot(wo, n);
    if (cos_i <= 0.0) return false;
    float cos_t;
    float r = dielectric_reflectance(m, cos_i, cos_t);
    if (u < r) {
        wi = 2.0 * cos_i * n - wo;
        prob = r;
        weight = vec3(1.0);
    } else {
        // Snell: the tangential part scales by 1 / eta, the normal part is -cos_t; a thin
        // sheet lets the ray through unbent.
        wi = m.kind == MATERIAL_THIN_DIELECTRIC ? -wo : normalize((cos_i * n - wo) / m.ior - cos_t * n);
        prob = 1.0 - r;
        weight = dielectric_crossing(m) * m.base_color;
    }
    return prob > 0.0;
}
#endif
