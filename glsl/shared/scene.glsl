// Scene records shared by the host (src/shared.rs mirrors them; a reflection test checks
// every member offset) and the integrator kernels. Scalar block layout throughout.
//
// Every record is a whole number of 16-byte texels, padded where needed: kernels read them
// from uniform texel buffers (lib/scene_access.glsl).
#ifndef SCENE_GLSL
#define SCENE_GLSL

// Where a material or emission value comes from. 16 bytes.
// width == 0: a constant of `channels` floats at `offset`; otherwise a width x height
// texture of `channels` floats per texel, row-major from the top row, at `offset`.
// flags & VALUE_IN_THETA: the floats are elements of θ (they are being optimised);
// otherwise they are material data, stored in θ's buffer after θ (from CONST_BASE on).
// flags & VALUE_NEAREST: a texture looked up at its nearest texel instead of bilinearly.
// flags & VALUE_UV1: a texture looked up at a surface's second set of texture coordinates
// (glTF's TEXCOORD_1) instead of its first.
#define VALUE_IN_THETA 1u
#define VALUE_NEAREST 2u
#define VALUE_UV1 128u
struct ValueRef {
    int offset;
    uint width;
    uint height;
    uint flags;
};

// One material. 160 bytes (10 texels).
struct MaterialRecord {
    ValueRef base_color;
    ValueRef roughness;
    ValueRef metallic;
    uint kind;  // MATERIAL_* (shared/material.glsl)
    uint one_sided;  // 1: black from behind (the back of its triangles' winding), as Mitsuba's BSDFs
    float alpha_cutoff;  // the surface is there where its alpha is at least this; negative:
                         // a blend, there with probability alpha
    float ior;  // a dielectric's or a plastic's index of refraction, interior over exterior (0 otherwise)
    // The normal map: a texture of tangent-space unit normals (x along the triangle's
    // tangent, y along its bitangent, z along the interpolated normal), already decoded
    // from the image's [0, 1] and scaled; width 0: none. Read only by scenes that have one.
    ValueRef normal_map;
    // The alpha test's value (1 channel); zero, with alpha_cutoff 0, where the material
    // has none. Read only by scenes that have one, and only at a ray's candidate hits on
    // triangles whose BVH record names the material (shared/bvh.glsl).
    ValueRef alpha;
    // A dielectric's interior absorption coefficient per unit length (Beer-Lambert: a
    // segment of length t inside keeps exp(-absorption t)); zero otherwise. Read only at a
    // dielectric's refractions.
    vec3 absorption;
    // A plastic's internal diffuse reflectance (Material.internal); zero otherwise.
    float internal;
    // A conductor's complex index of refraction eta + i k; zero otherwise. Read only by
    // scenes that have a conductor.
    vec3 eta;
    // A plastic's transmittance table: its first entry's index in the material data
    // (after θ, from CONST_BASE on); zero otherwise.
    uint table;
    vec3 k;
    // A plastic's coating flags (Material.coating); zero otherwise.
    uint coating;
    // A plastic's specular tint (Material.specular); zero otherwise.
    vec3 specular;
    uint pad;
};

// Per-triangle shading data, indexed by the original triangle id. 128 bytes (8 texels).
// What every path vertex reads comes first (texels 0-2), with what it would otherwise read
// from the material's and the mesh's records (one_sided, emission); the vertex normals
// (texels 3-5), texture coordinates (5-6) and tangent (7) follow, read only by scenes that
// have them.
struct TriShading {
    vec3 ng;          // unit geometric normal (front side = counter-clockwise winding)
    uint material;
    float emitter_pdf;  // probability density (area measure) of light sampling picking this point; 0: not an emitter
    uint emitter_flags; // bit 0: an emitter that shines from both sides (else from its front only); bit 1: its mesh emits
    uint one_sided;     // its material's one_sided
    uint mesh;
    ValueRef emission;  // its mesh's emission: 3 channels, radiance emitted from the front side
    vec3 n0;          // vertex normals; all zero when the mesh has none
    vec3 n1;
    vec3 n2;
    vec2 uv0;
    vec2 uv1;
    vec2 uv2;
    uint alpha_material;  // 0, or 1 + the material whose alpha test its points must pass
                          // (as its BVH record's; read by light samples on emitters)
    // Normal-mapped materials only: the unit tangent dp/du of the triangle's texture
    // coordinates (xyz) and the bitangent's handedness w, +1 where dp/dv lies along
    // cross(ng, tangent), -1 where it lies against it (mirrored coordinates); all zero
    // without a normal map or where the coordinates span no area.
    vec4 tangent;
};

// An emissive triangle for light sampling. 80 bytes (5 texels): everything light sampling
// needs of the triangle, so that it reads this record alone instead of the triangle's
// shading record as well.
struct EmitterTri {
    vec3 p0;
    vec3 e1;
    vec3 e2;
    vec3 ng;     // the triangle's geometric normal (its shading record's ng)
    uint prim;   // original triangle id
    float cdf;   // inclusive cumulative probability of picking triangles 0..this one
    float pdf;   // probability density (area measure) of a point sampled on it
    uint two_sided; // its mesh emits from both sides
    ValueRef emission; // its mesh's emission
};

// Delta lights (lib/delta_lights.glsl): kinds LIGHT_* and spot falloffs FALLOFF_*,
// defined in src/constants.rs.
#include "vkinverse_constants.glsl"

// A point, spot or directional light. 80 bytes (5 texels). Its emitted quantity (radiant
// intensity; irradiance for a directional light) is color × intensity × the spot falloff.
struct LightRecord {
    vec3 position;
    uint kind;        // LIGHT_*
    vec3 direction;   // unit: the spot's axis, or the direction a directional light travels
    uint falloff;     // FALLOFF_*
    ValueRef color;      // 3 channels
    ValueRef intensity;  // 1 channel
    float cos_inner;  // spot: full intensity where cos θ >= cos_inner
    float cos_outer;  // spot: none where cos θ <= cos_outer
    float inner;      // the same two angles in radians
    float outer;
};

// The scene's medium (src/render/features/media.rs): a box of emitting and absorbing
// medium (where boundary_triangles is not 0, the part of the box inside a closed mesh)
// whose density and emission are constants (width 0) or grids of width × height ×
// depth voxels, x fastest, looked up trilinearly between voxel centres. max_steps 0: none.
// albedo > 0: a scattering medium (the SCATTERING builds), its albedo a constant or a
// grid as the others, its phase function Henyey-Greenstein's of mean cosine g, tracked
// against its majorant. 112 bytes
// (7 texels).
struct MediumRecord {
    vec3 box_min;
    float step;       // marching step along a ray, world units
    vec3 box_max;
    float scale;      // extinction = scale × density
    ValueRef density;   // 1 channel
    ValueRef emission;  // 3 channels
    uint density_depth;
    uint emission_depth;
    uint max_steps;   // most steps of one march (a longer one takes longer steps)
    uint albedo_depth;
    ValueRef albedo;    // 3 channels
    float g;
    // A scattering medium's majorant: an extinction above any the density can take (its
    // parameter's range, or its values), against which its free flights are delta-tracked
    // and its shadow rays ratio-tracked (lib/media.glsl), where it has no majorant grid.
    // 0 for one that does not scatter.
    float majorant;
    // The majorant grid's cells per axis, x | y << 10 | z << 20 (0: none, the majorant
    // above holds everywhere). Its cells follow the record in the medium's buffer, one
    // texel each (the majorant in its first word), x fastest: each bounds the extinction
    // wherever a point of its part of the box looks the density up.
    uint majorant_cells;
    // The texels of the closed mesh that bounds the medium in its box (0: none, the whole
    // box holds it). They follow the record in the medium's buffer: a texel (its BVH's
    // node count, its triangle count), the binary BVH's nodes (BvhNode, 4 texels each,
    // root first) and its triangles (BvhTriangle, 3 texels each, in leaf order, world
    // space, wound so that cross(e1, e2) points out). The majorant grid follows them.
    uint boundary_texels;
};
// The texels of a MediumRecord: its boundary's triangles, then its majorant grid, start
// after them.
const int MEDIUM_RECORD_TEXELS = 7;

// A pinhole camera; an orthographic one where ortho_half_height > 0: its rays leave the
// plane through origin spanned by right and up (half the view's height along up, that
// times aspect along right), all along forward; a thin lens where lens_radius > 0: its
// rays leave a disk of that radius around origin in the same plane, through the point the
// pinhole's ray reaches at focus_distance along forward. 80 bytes (5 texels).
struct SensorRecord {
    vec3 origin;
    vec3 right;
    vec3 up;
    vec3 forward;
    float tan_half_fov_y;
    float aspect;
    float ortho_half_height;
    float lens_radius;
    float focus_distance;
    uint pad1;
    uint pad2;
    uint pad3;
};

// Scene-wide values. 32 bytes (2 texels).
struct Globals {
    ValueRef environment;  // constant (width 0) or lat-long map; 3 channels
    float environment_scale;
    // Probability that next-event estimation samples the environment map (its
    // distribution: binding EnvDistribution, src/render/envmap.rs) rather than an emissive
    // triangle; 0: the environment is found by BSDF sampling only.
    float environment_sample_prob;
    uint num_lights;  // delta lights (binding Lights), all sampled at every path vertex
    // 0: a box pixel filter (camera samples uniform over the pixel); else 1 + where in the
    // material data the filter's sampling table starts (src/render/filter.rs).
    uint filter_table;
};

// A triangle's second set of texture coordinates (glTF's TEXCOORD_1), at its three
// vertices; its first set where its mesh has no second. Indexed by the original triangle
// id, in binding ShadingUv1, where any mesh has a second set. 32 bytes (2 texels).
struct TriUv1 {
    vec2 uv0;
    vec2 uv1;
    vec2 uv2;
    uvec2 pad;
};
#endif
