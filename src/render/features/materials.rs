//! Materials: one record per material (its kind, values, alpha test, normal or bump map,
//! and a plastic's coating table in the material data). Its parameters: base colour,
//! roughness and metallic.

use super::values::{optimised, sampler_flags, MaterialData};
use super::{Feature, Upload};
use crate::constants::{
    COATING_NONLINEAR, COATING_UNLAYERED, MATERIAL_CONDUCTOR, MATERIAL_CONDUCTOR_BECKMANN, MATERIAL_DIELECTRIC, MATERIAL_DIFFUSE, MATERIAL_PLASTIC, MATERIAL_PLASTIC_BECKMANN, MATERIAL_PRINCIPLED,
    MATERIAL_ROUGH_DIELECTRIC, MATERIAL_ROUGH_DIELECTRIC_BECKMANN, MATERIAL_THIN_DIELECTRIC,
};
use crate::gpu::{self, Buffer, SpecValue};
use crate::image::Image;
use crate::render::texel_buffer;
use crate::scene::{AlphaMode, Distribution, Material, MaterialKind, ParamTarget, Perturbation, ScalarValue};
use crate::shared::{MaterialRecord, ValueRef};

pub struct Materials {
    buffer: Buffer,
    pub records: Vec<MaterialRecord>,
    kinds: Vec<MaterialKind>,
}

/// A layered plastic's coating ([`crate::bsdf::coating`]) for its roughness, distribution
/// and index; None for the other kinds and an unlayered plastic (whose transmittance the
/// kernels compute). Computed once per combination in a process (a few
/// hundred milliseconds each).
fn plastic_coating(m: &Material) -> Option<([f64; crate::bsdf::TABLE], f64)> {
    type Key = (bool, u32, u32);
    static CACHE: std::sync::Mutex<Vec<(Key, ([f64; crate::bsdf::TABLE], f64))>> = std::sync::Mutex::new(Vec::new());
    if m.kind != MaterialKind::Plastic || !m.layered {
        return None;
    }
    let ScalarValue::Constant(roughness) = m.roughness else { unreachable!("a plastic's roughness is a constant (the loaders refuse a texture)") };
    let beckmann = m.distribution == Distribution::Beckmann;
    let key = (beckmann, roughness.to_bits(), m.ior.to_bits());
    let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, c)) = cache.iter().find(|(k, _)| *k == key) {
        return Some(*c);
    }
    let c = crate::bsdf::coating(beckmann, f64::from(roughness), f64::from(m.ior));
    cache.push((key, c));
    Some(c)
}

/// The material data of material `m`'s normal map (its decoded, scaled vectors,
/// [`crate::scene::NormalMap::vectors`]) or bump map (its heights,
/// [`crate::scene::BumpMap::heights`], flagged [`ValueRef::BUMP`]), or a ValueRef of width
/// 0 for neither.
fn normal_map_ref(data: &mut MaterialData, m: &Material) -> ValueRef {
    match &m.perturbation {
        None => ValueRef::default(),
        Some(Perturbation::Normal(n)) => {
            let image = Image { data: n.vectors(), width: n.texture.image.width, height: n.texture.image.height };
            data.texture(&image, 3, sampler_flags(&n.texture))
        }
        Some(Perturbation::Bump(b)) => {
            let image = Image { data: b.heights().into_iter().map(|h| [h, 0.0, 0.0]).collect(), width: b.texture.image.width, height: b.texture.image.height };
            let r = data.texture(&image, 1, sampler_flags(&b.texture));
            ValueRef { flags: r.flags | ValueRef::BUMP, ..r }
        }
    }
}

/// The kernels' code of a material kind (glsl/shared/constants).
fn kind_code(m: &Material) -> u32 {
    let beckmann = m.distribution == Distribution::Beckmann;
    match m.kind {
        MaterialKind::Diffuse => MATERIAL_DIFFUSE,
        MaterialKind::Principled => MATERIAL_PRINCIPLED,
        MaterialKind::Dielectric => MATERIAL_DIELECTRIC,
        MaterialKind::ThinDielectric => MATERIAL_THIN_DIELECTRIC,
        MaterialKind::RoughDielectric if beckmann => MATERIAL_ROUGH_DIELECTRIC_BECKMANN,
        MaterialKind::RoughDielectric => MATERIAL_ROUGH_DIELECTRIC,
        MaterialKind::Conductor if beckmann => MATERIAL_CONDUCTOR_BECKMANN,
        MaterialKind::Conductor => MATERIAL_CONDUCTOR,
        MaterialKind::Plastic if beckmann => MATERIAL_PLASTIC_BECKMANN,
        MaterialKind::Plastic => MATERIAL_PLASTIC,
    }
}

impl Materials {
    pub fn build(up: &mut Upload) -> gpu::Result<Materials> {
        let (scene, layout) = (up.scene, up.layout);
        let data = &mut *up.data;
        let records: Vec<MaterialRecord> = scene
            .materials
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let base = data.color(&m.base_color);
                let rough = data.scalar(&m.roughness);
                let metal = data.scalar(&m.metallic);
                // A plastic's coating: its transmittance table in the material data.
                let (internal, table) = match plastic_coating(m) {
                    Some((transmittance, internal)) => {
                        let entries: Vec<f32> = transmittance.iter().map(|t| *t as f32).collect();
                        (internal as f32, data.constant(&entries).offset as u32)
                    }
                    None => (0.0, 0),
                };
                MaterialRecord {
                    base_color: optimised(layout.slot(ParamTarget::BaseColor { material: i }), base),
                    roughness: optimised(layout.slot(ParamTarget::Roughness { material: i }), rough),
                    metallic: optimised(layout.slot(ParamTarget::Metallic { material: i }), metal),
                    kind: kind_code(m),
                    one_sided: m.one_sided as u32,
                    // Blend: a negative cutoff, for which the kernels draw one per ray.
                    alpha_cutoff: match m.alpha.as_ref().map(|a| a.mode) {
                        None => 0.0,
                        Some(AlphaMode::Mask { cutoff }) => cutoff,
                        Some(AlphaMode::Blend) => -1.0,
                    },
                    ior: if m.kind.has_ior() { m.ior } else { 0.0 },
                    normal_map: normal_map_ref(data, m),
                    alpha: m.alpha.as_ref().map_or(ValueRef::default(), |a| data.scalar(&a.value)),
                    absorption: m.absorption,
                    internal,
                    eta: m.eta,
                    table,
                    k: m.k,
                    specular: if m.kind == MaterialKind::Plastic { m.specular } else { [0.0; 3] },
                    pad: 0,
                    coating: if m.nonlinear { COATING_NONLINEAR } else { 0 } | if m.layered { 0 } else { COATING_UNLAYERED },
                }
            })
            .collect();
        let kinds = scene.materials.iter().map(|m| m.kind).collect();
        Ok(Materials { buffer: texel_buffer(up.ctx, "materials", &records)?, records, kinds })
    }

    fn has(&self, kind: impl Fn(MaterialKind) -> bool) -> bool {
        self.kinds.iter().any(|&k| kind(k))
    }
}

impl Feature for Materials {
    fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        vec![("Materials", &self.buffer)]
    }

    fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        vec![
            ("HAS_PRINCIPLED", SpecValue::Bool(self.has(|k| k == MaterialKind::Principled))),
            ("HAS_DIELECTRICS", SpecValue::Bool(self.has(|k| k.is_dielectric()))),
            ("HAS_ROUGH_DIELECTRICS", SpecValue::Bool(self.has(|k| k == MaterialKind::RoughDielectric))),
            ("HAS_CONDUCTORS", SpecValue::Bool(self.has(|k| k == MaterialKind::Conductor))),
            ("HAS_PLASTICS", SpecValue::Bool(self.has(|k| k == MaterialKind::Plastic))),
        ]
    }

    fn values(&self) -> Vec<ValueRef> {
        self.records.iter().flat_map(|m| [m.base_color, m.roughness, m.metallic, m.normal_map, m.alpha]).collect()
    }
}
