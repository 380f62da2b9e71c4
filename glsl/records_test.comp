#version 460
// records_test: reads every record of a scene's texel buffers through the accessors of
// lib/scene_access.glsl and lib/bvh_traverse.glsl and writes it out as a storage-buffer
// struct. tests/render.rs compares the output with the buffers' bytes read through the
// Rust mirrors, and the reflection tests compare these structs' layouts with the mirrors:
// together they check, member by member, that the host's bytes and the kernels' view of
// them agree. Thread i copies element i of every array that has one.
// variant: records_test_wide BVH_WIDE
// variant: records_test_cw8 BVH_CW8
layout(local_size_x = 64, local_size_x_id = 0) in;
#include "lib/common.glsl"
#include "lib/scene_access.glsl"
#include "lib/bvh_traverse.glsl"

layout(set = 0, binding = 0, scalar) writeonly buffer OutMaterials { MaterialRecord out_materials[]; };
layout(set = 0, binding = 1, scalar) writeonly buffer OutShading { TriShading out_shading[]; };
layout(set = 0, binding = 3, scalar) writeonly buffer OutEmitters { EmitterTri out_emitters[]; };
#if defined(BVH_CW8)
layout(set = 0, binding = 4, scalar) writeonly buffer OutNodes { BvhCwNode out_nodes[]; };
#elif defined(BVH_WIDE)
layout(set = 0, binding = 4, scalar) writeonly buffer OutNodes { BvhWideNode out_nodes[]; };
#else
layout(set = 0, binding = 4, scalar) writeonly buffer OutNodes { BvhNode out_nodes[]; };
#endif
layout(set = 0, binding = 5, scalar) writeonly buffer OutTriangles { BvhTriangle out_triangles[]; };
// Material data, θ and the environment distribution, one after another.
layout(set = 0, binding = 6, scalar) writeonly buffer OutFloats { float out_floats[]; };
// The emitters' cdfs as the light-sampling search reads them.
layout(set = 0, binding = 7, scalar) writeonly buffer OutCdfs { float out_cdfs[]; };
layout(set = 0, binding = 8, scalar) writeonly buffer OutSensors { SensorRecord out_sensors[]; };
layout(set = 0, binding = 9, scalar) writeonly buffer OutGlobals { Globals out_globals; };
layout(set = 0, binding = 15, scalar) writeonly buffer OutLights { LightRecord out_lights[]; };
// Material data and θ as fetch3 reads them (texel_vec3_at): thread i writes the three floats
// from float i, for every i with i + 2 inside the array (the rest stays zero), so every
// alignment of a vec3 within a texel is read.
layout(set = 0, binding = 16, scalar) writeonly buffer OutTriples { vec3 out_triples[]; };
layout(set = 0, binding = 17, scalar) writeonly buffer OutUv1 { TriUv1 out_uv1[]; };

layout(push_constant, scalar) uniform Push {
    uint materials;
    uint triangles;
    uint emitters;
    uint nodes;
    uint material_data;
    uint theta;
    uint env_dist;
    uint sensors;
    uint lights;
    uint uv1s;
} pc;

void main() {
    uint i = thread_index();
    if (i < pc.materials) out_materials[i] = material_record(i);
    if (i < pc.triangles) {
        out_shading[i] = tri_shading(i);
        out_triangles[i] = bvh_triangle(i);
    }
    if (i < pc.emitters) {
        out_emitters[i] = emitter_tri(i);
        out_cdfs[i] = emitter_cdf(i);
    }
    if (i < pc.nodes) out_nodes[i] = bvh_node(i);
    if (i < pc.material_data) out_floats[i] = texel_float(Theta, int(CONST_BASE + i));
    if (i < pc.theta) out_floats[pc.material_data + i] = texel_float(Theta, int(i));
    if (i + 2u < pc.material_data) out_triples[i] = texel_vec3_at(Theta, int(CONST_BASE + i));
    if (i + 2u < pc.theta) out_triples[pc.material_data + i] = texel_vec3_at(Theta, int(i));
    if (i < pc.env_dist) out_floats[pc.material_data + pc.theta + i] = texel_float(EnvDistribution, int(i));
    if (i < pc.sensors) out_sensors[i] = sensor_record(i);
    if (i < pc.lights) out_lights[i] = light_record(i);
    if (i < pc.uv1s) out_uv1[i] = tri_uv1(i);
    if (i == 0u) out_globals = scene_globals();
}
