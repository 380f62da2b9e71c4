// Material parameters shared by host and kernels, mirrored by `Material` in src/shared.rs
// (the offsets are compared with the reflected SPIR-V by tests/bsdf.rs). The model each
// kind selects is defined in glsl/lib/bsdf.glsl.
#ifndef MATERIAL_GLSL
#define MATERIAL_GLSL

// The kinds (MATERIAL_DIFFUSE: roughness and metallic are ignored; MATERIAL_PRINCIPLED;
// MATERIAL_DIELECTRIC: base_color is the transmittance, ior the relative index of
// refraction, roughness and metallic are ignored; MATERIAL_THIN_DIELECTRIC likewise;
// MATERIAL_ROUGH_DIELECTRIC: as MATERIAL_DIELECTRIC with a roughness (GGX);
// MATERIAL_ROUGH_DIELECTRIC_BECKMANN likewise with Beckmann's distribution;
// MATERIAL_CONDUCTOR: a metal on GGX microfacets, base_color its specular tint, eta and k
// its complex index of refraction, metallic and ior ignored; MATERIAL_CONDUCTOR_BECKMANN
// likewise with Beckmann's distribution; MATERIAL_PLASTIC: a diffuse base of reflectance
// base_color under a dielectric coating of index ior on GGX microfacets, with the
// coating's tabulated transmittance at `table` and its internal reflectance `internal`,
// metallic ignored; MATERIAL_PLASTIC_BECKMANN likewise with Beckmann's distribution),
// defined in src/constants.rs.
#include "vkinverse_constants.glsl"

// 80 bytes under the scalar block layout: base_color 0, roughness 12, metallic 16, kind 20,
// ior 24, eta 28, k 40, table 52, internal 56, coating 60, specular 64, pad 76.
struct Material {
    vec3 base_color;
    float roughness;
    float metallic;
    uint kind;
    // A dielectric's: the index of refraction of the side a ray refracts into over that of
    // the side it comes from (the integrator inverts the material's interior over exterior
    // ratio for rays leaving the interior; a thin dielectric's is the same from both
    // sides). Unused by the other kinds.
    float ior;
    // A conductor's complex index of refraction eta + i k per channel, relative to the
    // medium outside (Mitsuba's `eta` and `k`). Unused by the other kinds.
    vec3 eta;
    vec3 k;
    // A plastic's coating (Mitsuba's `roughplastic`): where its transmittance table starts
    // (PLASTIC_TABLE_SIZE entries, read by bsdf_table), its internal diffuse reflectance,
    // and its flags: COATING_NONLINEAR where the base's reflectance also scales the
    // internal reflections (Mitsuba's `nonlinear`), COATING_UNLAYERED where the base is
    // seen through two smooth refractions alone (Mitsuba's `pplastic`). Unused by the
    // other kinds.
    uint table;
    float internal;
    uint coating;
    // A plastic's specular tint, per channel (Mitsuba's specular_reflectance): it scales
    // the coating's reflection. Unused by the other kinds.
    vec3 specular;
    uint pad;
};

// Whether `kind` is smooth glass of either kind (delta lobes, an index of refraction).
bool material_is_dielectric(uint kind) {
    return kind == MATERIAL_DIELECTRIC || kind == MATERIAL_THIN_DIELECTRIC;
}

// Whether `kind` is rough glass, of either microfacet distribution.
bool material_is_rough_glass(uint kind) {
    return kind == MATERIAL_ROUGH_DIELECTRIC || kind == MATERIAL_ROUGH_DIELECTRIC_BECKMANN;
}

// Whether `kind` is a conductor, of either microfacet distribution.
bool material_is_conductor(uint kind) {
    return kind == MATERIAL_CONDUCTOR || kind == MATERIAL_CONDUCTOR_BECKMANN;
}

// Whether `kind` is a plastic, of either microfacet distribution.
bool material_is_plastic(uint kind) {
    return kind == MATERIAL_PLASTIC || kind == MATERIAL_PLASTIC_BECKMANN;
}

// Whether `kind` is glass, smooth or rough (an index of refraction).
bool material_is_glass(uint kind) {
    return material_is_dielectric(kind) || material_is_rough_glass(kind);
}
#endif
