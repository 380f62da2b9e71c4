//! Delta lights (point, spot, directional): one record each, sampled at every path vertex.
//! Their parameters: colour and intensity.

use super::values::optimised;
use super::{Feature, Upload};
use crate::constants::{FALLOFF_LINEAR, FALLOFF_SMOOTH, LIGHT_DIRECTIONAL, LIGHT_POINT, LIGHT_SPOT};
use crate::gpu::{self, Buffer, SpecValue};
use crate::render::texel_buffer;
use crate::scene::{LightKind, ParamTarget, SpotFalloff};
use crate::shared::{LightRecord, ValueRef};

pub struct Lights {
    buffer: Buffer,
    records: Vec<LightRecord>,
}

impl Lights {
    pub fn build(up: &mut Upload) -> gpu::Result<Lights> {
        let (scene, layout) = (up.scene, up.layout);
        let records: Vec<LightRecord> = scene
            .lights
            .iter()
            .enumerate()
            .map(|(i, l)| {
                let color = up.data.constant(&l.color);
                let intensity = up.data.constant(&[l.intensity]);
                let (kind, inner, outer, falloff) = match l.kind {
                    LightKind::Point => (LIGHT_POINT, 0.0, 0.0, SpotFalloff::Smooth),
                    LightKind::Spot { inner, outer, falloff } => (LIGHT_SPOT, inner, outer, falloff),
                    LightKind::Directional => (LIGHT_DIRECTIONAL, 0.0, 0.0, SpotFalloff::Smooth),
                };
                LightRecord {
                    position: l.position.into(),
                    kind,
                    direction: l.direction.into(),
                    falloff: match falloff {
                        SpotFalloff::Smooth => FALLOFF_SMOOTH,
                        SpotFalloff::Linear => FALLOFF_LINEAR,
                    },
                    color: optimised(layout.slot(ParamTarget::LightColor { light: i }), color),
                    intensity: optimised(layout.slot(ParamTarget::LightIntensity { light: i }), intensity),
                    cos_inner: inner.cos(),
                    cos_outer: outer.cos(),
                    inner,
                    outer,
                }
            })
            .collect();
        Ok(Lights { buffer: texel_buffer(up.ctx, "lights", &records)?, records })
    }

    pub fn count(&self) -> u32 {
        self.records.len() as u32
    }
}

impl Feature for Lights {
    fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        vec![("Lights", &self.buffer)]
    }

    fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        vec![("HAS_DELTA_LIGHTS", SpecValue::Bool(!self.records.is_empty()))]
    }

    fn values(&self) -> Vec<ValueRef> {
        self.records.iter().flat_map(|l| [l.color, l.intensity]).collect()
    }
}
