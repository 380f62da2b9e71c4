//! Meshes and the BVH: the triangles of every mesh in one list, the BVH over them (in the
//! configured node layout), and a shading record per triangle (its material, normals,
//! texture coordinates (and, in a buffer of their own, the second sets), tangent frame for a normal or bump map, alpha test, and the
//! emission and emitter density the emitters feature gave it).

use super::emitters::Emitters;
use super::materials::Materials;
use super::{Feature, Upload};
use crate::bvh::{self, BvhBuffers, BvhLayout};
use crate::gpu::{self, Buffer, SpecValue};
use crate::render::texel_buffer;
use crate::scene::{Bitangent, Perturbation, Scene, SceneGeometry, TextureValue as _};
use crate::shared::{TriShading, TriUv1};
use glam::{Vec2, Vec3};

pub struct Geometry {
    pub bvh: BvhBuffers,
    shading: Buffer,
    /// The triangles' second sets of texture coordinates; one zero texel where no mesh has one.
    uv1: Buffer,
    pub triangles: usize,
    has_normals: bool,
    has_normal_maps: bool,
    has_alpha_masks: bool,
    has_uv1: bool,
    /// The compressed BVH's traversal stack in an array instead of registers
    /// ([`crate::Config::bvh_stack_array`]).
    pub stack_array: bool,
}

impl Geometry {
    pub fn build(up: &mut Upload, geo: SceneGeometry, materials: &Materials, emitters: &Emitters, bvh_layout: BvhLayout) -> gpu::Result<Geometry> {
        let scene = up.scene;
        // The shading records are the largest buffer per triangle: refused before the BVH
        // is built where the device cannot hold them.
        let bytes = (geo.indices.len() * std::mem::size_of::<TriShading>()) as u64;
        let max = up.ctx.info().max_texel_buffer_bytes();
        if bytes > max {
            return Err(gpu::GpuError::BufferTooLarge {
                name: format!("shading records of {} triangles", geo.indices.len()),
                size: bytes,
                max,
                limit: "texel-buffer range",
            });
        }
        let alpha_material = alpha_materials(scene, &geo);
        let bvh = bvh::build_as(up.ctx, &geo.positions, &geo.indices, &alpha_material, bvh_layout)?;
        let mut shading: Vec<TriShading> = Vec::with_capacity(geo.indices.len());
        for (t, idx) in geo.indices.iter().enumerate() {
            let [a, b, c] = idx.map(|i| Vec3::from(geo.positions[i as usize]));
            let ng = (b - a).cross(c - a).normalize_or_zero();
            let mesh = geo.triangle_mesh[t] as usize;
            let two_sided = scene.meshes[mesh].two_sided_emission as u32;
            let uvs = idx.map(|i| geo.uvs[i as usize]);
            let material = geo.triangle_material[t];
            let m = &scene.materials[material as usize];
            // A map's tangent frame is that of the coordinates it is looked up at.
            let map_uvs = match &m.perturbation {
                Some(p) => idx.map(|i| geo.uvs_of(p.texture().uv_set)[i as usize]),
                None => uvs,
            };
            let tangent = match &m.perturbation {
                None => [0.0; 4],
                Some(Perturbation::Bump(_)) => uv_gradients([a, b, c], map_uvs, ng),
                Some(Perturbation::Normal(n)) => {
                    let [x, y, z, w] = triangle_tangent([a, b, c], map_uvs, ng);
                    [x, y, z, if n.bitangent == Bitangent::Cross { w.abs() } else { w }]
                }
            };
            shading.push(TriShading {
                ng: ng.into(),
                material,
                emitter_pdf: emitters.triangle_pdf[t],
                emitter_flags: two_sided
                    | if emitters.mesh_emits[mesh] { TriShading::EMITTING_MESH } else { 0 }
                    | emitters.mesh_sphere[mesh] << crate::constants::EMITTER_SPHERE_SHIFT,
                one_sided: materials.records[material as usize].one_sided,
                mesh: mesh as u32,
                emission: emitters.mesh_emission[mesh],
                n0: geo.normals[idx[0] as usize],
                n1: geo.normals[idx[1] as usize],
                n2: geo.normals[idx[2] as usize],
                uv0: uvs[0],
                uv1: uvs[1],
                uv2: uvs[2],
                alpha_material: alpha_material[t],
                tangent,
            });
        }
        let uv1: Vec<TriUv1> = if geo.uvs1.is_empty() {
            Vec::new()
        } else {
            geo.indices
                .iter()
                .map(|idx| {
                    let [uv0, uv1, uv2] = idx.map(|i| geo.uvs1[i as usize]);
                    TriUv1 { uv0, uv1, uv2, pad: [0; 2] }
                })
                .collect()
        };
        Ok(Geometry {
            bvh,
            uv1: texel_buffer(up.ctx, "shading uv1", &uv1)?,
            triangles: geo.indices.len(),
            has_normals: shading.iter().flat_map(|s| [s.n0, s.n1, s.n2]).any(|n| n != [0.0; 3]),
            has_normal_maps: shading.iter().any(|s| s.tangent != [0.0; 4]),
            has_alpha_masks: alpha_material.iter().any(|&m| m != 0),
            shading: texel_buffer(up.ctx, "shading", &shading)?,
            has_uv1: !geo.uvs1.is_empty(),
            stack_array: false,
        })
    }
}

impl Feature for Geometry {
    fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        let mut v: Vec<(&'static str, &Buffer)> = self.bvh.bindings().into_iter().collect();
        v.push(("Shading", &self.shading));
        v.push(("ShadingUv1", &self.uv1));
        v
    }

    fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        let mut spec = vec![
            ("HAS_NORMALS", SpecValue::Bool(self.has_normals)),
            ("HAS_NORMAL_MAPS", SpecValue::Bool(self.has_normal_maps)),
            ("HAS_ALPHA_MASKS", SpecValue::Bool(self.has_alpha_masks)),
            ("HAS_UV1", SpecValue::Bool(self.has_uv1)),
        ];
        if self.bvh.layout == BvhLayout::Cw8 {
            spec.push(("BVH_STACK_REGISTERS", SpecValue::Bool(BvhLayout::stack_in_registers(&self.bvh, self.stack_array))));
        }
        spec
    }
}

/// Per triangle of `geo`: 0, or 1 + its material where the material has an alpha test that
/// applies to it ([`crate::shared::TriShading::alpha_material`]). A textured alpha needs
/// texture coordinates: on a mesh without them it does not apply (a warning says so). An
/// alpha that never cuts is no test: the kernels are built without it.
fn alpha_materials(scene: &Scene, geo: &SceneGeometry) -> Vec<u32> {
    // Per material, not per mesh: never_cuts scans a texture's texels, and a material's
    // meshes may be many.
    let cuts: Vec<bool> = scene.materials.iter().map(|m| m.alpha.as_ref().is_some_and(|a| !a.never_cuts())).collect();
    let applies: Vec<bool> = scene
        .meshes
        .iter()
        .map(|mesh| match &scene.materials[mesh.material].alpha {
            Some(a) if cuts[mesh.material] => a.value.texture().is_none_or(|t| mesh.has_uvs(t.uv_set)),
            _ => false,
        })
        .collect();
    geo.triangle_mesh.iter().zip(&geo.triangle_material).map(|(&mesh, &material)| if applies[mesh as usize] { material + 1 } else { 0 }).collect()
}

/// The unit tangent dp/du of a triangle with corners p and texture coordinates uv, and the
/// bitangent's handedness against its geometric normal ng (TriShading::tangent); zero where
/// the coordinates span no area.
fn triangle_tangent(p: [Vec3; 3], uv: [[f32; 2]; 3], ng: Vec3) -> [f32; 4] {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (Vec2::from(uv[1]) - Vec2::from(uv[0]), Vec2::from(uv[2]) - Vec2::from(uv[0]));
    let det = d1.x * d2.y - d2.x * d1.y;
    if det == 0.0 || !det.is_finite() {
        return [0.0; 4];
    }
    let dp_du = (e1 * d2.y - e2 * d1.y) / det;
    let dp_dv = (e2 * d1.x - e1 * d2.x) / det;
    let t = dp_du.normalize_or_zero();
    if t == Vec3::ZERO || !t.is_finite() {
        return [0.0; 4];
    }
    let w = if ng.cross(t).dot(dp_dv) < 0.0 { -1.0 } else { 1.0 };
    [t.x, t.y, t.z, w]
}

/// The orthonormal pair (t, b) that the kernels' `shading_frame` (lib/bsdf.glsl) builds
/// for unit normal `n` (Duff et al. 2017), the same arithmetic in the same order.
pub fn tangent_frame(n: Vec3) -> (Vec3, Vec3) {
    let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    (Vec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x), Vec3::new(b, s + n.y * n.y * a, -n.y))
}

/// A bump-mapped triangle's tangent record ([`TriShading::tangent`]): the world-space
/// gradients of its texture coordinates u and v (in its plane: the vectors g with g·e = the
/// coordinate's change along each edge e) in the basis [`tangent_frame`]`(ng)`. Zero for a
/// triangle without area.
fn uv_gradients(p: [Vec3; 3], uv: [[f32; 2]; 3], ng: Vec3) -> [f32; 4] {
    let (e1, e2) = ((p[1] - p[0]).as_dvec3(), (p[2] - p[0]).as_dvec3());
    let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = a * c - b * b;
    if !det.is_finite() || det <= 0.0 || ng == Vec3::ZERO {
        return [0.0; 4];
    }
    // The gradient x e1 + y e2 of a coordinate whose changes along e1 and e2 are d1, d2:
    // the Gram system [a b; b c] (x, y) = (d1, d2).
    let gradient = |k: usize| {
        let (d1, d2) = ((uv[1][k] - uv[0][k]) as f64, (uv[2][k] - uv[0][k]) as f64);
        (e1 * (c * d1 - b * d2) + e2 * (a * d2 - b * d1)) / det
    };
    let (gu, gv) = (gradient(0), gradient(1));
    let (t, bt) = tangent_frame(ng);
    let (t, bt) = (t.as_dvec3(), bt.as_dvec3());
    [gu.dot(t), gu.dot(bt), gv.dot(t), gv.dot(bt)].map(|x| x as f32)
}
