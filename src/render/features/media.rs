//! The scene's medium: one record (a box, its scale and marching step, and references to
//! its density, emission and albedo, constants or grids in the material data or θ). Its
//! parameters: the density, the emission and the albedo, of any grid size.

use super::{Feature, Upload};
use crate::gpu::{self, Buffer, SpecValue};
use crate::render::{texel_buffer, ParamSlot};
use crate::scene::media::{grid_dims, MAX_STEPS};
use crate::scene::ParamTarget;
use crate::shared::{MediumRecord, ValueRef};
use crate::tensor::ParamValue;

pub struct Media {
    buffer: Buffer,
    present: bool,
    /// Whether the medium scatters: the scene's trace kernels are then the `_scatter`
    /// builds ([`crate::render::GpuScene::kernel`]).
    pub scattering: bool,
}

/// A grid's reference and depth: the scene's value in the material data, or its slot of θ.
fn grid_ref(up: &mut Upload, slot: Option<&ParamSlot>, value: &ParamValue) -> (ValueRef, u32) {
    let (shape, r) = match slot {
        Some(s) => (s.shape, ValueRef { offset: s.offset as i32, width: 0, height: 0, flags: ValueRef::IN_THETA }),
        None => (value.shape, up.data.constant(&value.data)),
    };
    if shape.is_constant() {
        return (r, 0);
    }
    let [x, y, z] = grid_dims(shape).map(|d| d as u32);
    (ValueRef { width: x, height: y, ..r }, z)
}

impl Media {
    pub fn build(up: &mut Upload) -> gpu::Result<Media> {
        let (scene, layout) = (up.scene, up.layout);
        let mut record = MediumRecord::default();
        let present = !scene.media.is_empty();
        let scattering = scene.media.iter().any(|m| m.scatters());
        if let Some(m) = scene.media.first() {
            let (density, density_depth) = grid_ref(up, layout.slot(ParamTarget::MediumDensity { medium: 0 }), &m.density);
            let (emission, emission_depth) = grid_ref(up, layout.slot(ParamTarget::MediumEmission { medium: 0 }), &m.emission);
            let (albedo, albedo_depth) = grid_ref(up, layout.slot(ParamTarget::MediumAlbedo { medium: 0 }), &m.albedo);
            // The step in voxels of the finest grid that renders: the parameters' own
            // where they are optimised.
            let mut stepped = m.clone();
            for (target, v) in [(ParamTarget::MediumDensity { medium: 0 }, &mut stepped.density), (ParamTarget::MediumEmission { medium: 0 }, &mut stepped.emission)] {
                if let Some(slot) = layout.slot(target) {
                    v.shape = slot.shape;
                }
            }
            record = MediumRecord {
                box_min: m.min,
                step: stepped.world_step(),
                box_max: m.max,
                scale: m.scale,
                density,
                emission,
                density_depth,
                emission_depth,
                max_steps: MAX_STEPS,
                albedo_depth,
                albedo,
                g: m.g,
                pad: [0; 3],
            };
        }
        Ok(Media { buffer: texel_buffer(up.ctx, "media", &[record])?, present, scattering })
    }
}

impl Feature for Media {
    fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        vec![("Media", &self.buffer)]
    }

    fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        vec![("HAS_MEDIA", SpecValue::Bool(self.present))]
    }
}
