//! The scene's medium: one record (a box, its scale and marching step, and references to
//! its density, emission and albedo, constants or grids in the material data or θ). Its
//! parameters: the density, the emission and the albedo, of any grid size.

use super::{Feature, Upload};
use crate::gpu::{self, Buffer, ComputePipeline, Recorder, SpecValue};
use crate::kernels::MajorantPush;
use crate::render::{texel_buffer, ParamSlot};
use crate::scene::media::{grid_dims, MAX_STEPS};
use crate::scene::ParamTarget;
use crate::shared::{MediumRecord, ValueRef};
use crate::tensor::ParamValue;

/// How far a scattering medium's majorant lies above the most its extinction can be. The
/// tracking costs lookups in proportion to the majorant; the finite-difference kernels'
/// second state is weighted (σ̄ − σ_1)/(σ̄ − σ_0) at each null collision, whose spread
/// grows as σ̄ approaches σ: 20 % above keeps a 1 % change of the density to a 5 % weight.
pub const MAJORANT_MARGIN: f32 = 1.2;

pub struct Media {
    buffer: Buffer,
    present: bool,
    /// Whether the medium scatters: the scene's trace kernels are then the `_scatter`
    /// builds ([`crate::render::GpuScene::kernel`]).
    pub scattering: bool,
    /// A scattering medium whose density is optimised: the pass that sets its majorant
    /// from θ before each pass that tracks it ([`Media::record_majorant`]).
    majorant: Option<(ComputePipeline, MajorantPush)>,
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
        let mut majorant_pass = None;
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
            // A scattering medium is tracked against a majorant above the most its
            // extinction can be: its density parameter's range, or its values.
            let density_bound = match (m.majorant, layout.slot(ParamTarget::MediumDensity { medium: 0 })) {
                (Some(b), _) => b,
                (None, Some(slot)) => slot.range[1],
                (None, None) => m.density.data.iter().copied().fold(0.0f32, f32::max),
            };
            let majorant = if m.scatters() { MAJORANT_MARGIN * m.scale * density_bound.max(0.0) } else { 0.0 };
            // An optimised density moves: its majorant follows θ (the range above holds
            // until the first pass sets it).
            if let (true, None, Some(slot)) = (m.scatters(), m.majorant, layout.slot(ParamTarget::MediumDensity { medium: 0 })) {
                let push = MajorantPush {
                    offset: slot.offset as u32,
                    n: slot.len as u32,
                    word: (std::mem::offset_of!(MediumRecord, majorant) / 4) as u32,
                    factor: MAJORANT_MARGIN * m.scale,
                };
                majorant_pass = Some((ComputePipeline::new(up.ctx, "majorant", &[])?, push));
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
                majorant,
                pad: [0; 2],
            };
        }
        Ok(Media { buffer: texel_buffer(up.ctx, "media", &[record])?, present, scattering, majorant: majorant_pass })
    }

    /// Records the pass that sets a scattering medium's majorant from the density in
    /// `theta` and `theta_prev` (the buffers a tracking pass binds as its θ and previous
    /// θ: the same one twice for a single state), where the density is optimised. Every
    /// pass that tracks the medium follows one (`render::record_samples`), so that the
    /// majorant holds whoever wrote θ, and the primal and adjoint passes of one θ track
    /// against the same one.
    pub fn record_majorant(&self, rec: &mut Recorder, theta: &Buffer, theta_prev: &Buffer) -> gpu::Result<()> {
        let Some((pipeline, push)) = &self.majorant else { return Ok(()) };
        let group = pipeline.bind(&[("Theta", theta), ("ThetaPrev", theta_prev), ("Record", &self.buffer)])?;
        rec.dispatch(pipeline, &group, push, [1, 1, 1])
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
