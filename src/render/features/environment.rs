//! Light from infinitely far away: its value (a constant, or a lat-long map, always bilinear
//! and repeating, as its sampling assumes), and for a map the distribution that next-event
//! estimation samples it by ([`crate::render::envmap`]). Its parameter: the environment.
//! A constant environment is not light-sampled: its radiance is the same in every
//! direction, so BSDF sampling already samples its integrand's directional factor.

use super::{Feature, Upload};
use crate::gpu::{self, Buffer, SpecValue};
use crate::render::envmap::EnvDistribution;
use super::values;
use crate::render::texel_buffer;
use crate::scene::{ColorValue, ParamTarget};
use crate::shared::ValueRef;

pub struct Environment {
    buffer: Buffer,
    /// The environment's value (`Globals::environment`).
    pub value: ValueRef,
    /// Whether it gives any light: an optimised environment, or a positive one.
    pub present: bool,
    /// The map's sampling distribution, when it is light-sampled.
    pub distribution: Option<EnvDistribution>,
}

impl Environment {
    pub fn build(up: &mut Upload) -> gpu::Result<Environment> {
        let (scene, layout) = (up.scene, up.layout);
        let env = &scene.environment;
        let scene_value = ValueRef { flags: 0, ..up.data.color(&env.value) };
        let slot = layout.slot(ParamTarget::Environment);
        let value = values::optimised(slot, scene_value);
        let present = slot.is_some()
            || match &env.value {
                ColorValue::Constant(c) => c.iter().any(|&v| v > 0.0),
                ColorValue::Texture(_) => true,
            } && env.scale > 0.0;
        // The map's texels as the kernels first see them: θ's start value for an optimised
        // map, the scene's map otherwise. A constant has no distribution.
        let texels: Option<(Vec<f32>, u32, u32)> = match slot {
            Some(slot) => slot.shape.texture_size().map(|[w, h]| (slot.init.clone(), w, h)),
            None => match &env.value {
                ColorValue::Texture(t) => Some((t.image.data.iter().flatten().copied().collect(), t.image.width, t.image.height)),
                ColorValue::Constant(_) => None,
            },
        };
        let distribution = match texels {
            Some((texels, w, h)) if present && env.scale > 0.0 => Some(EnvDistribution::new(&texels, w, h)),
            _ => None,
        };
        let gpu_data = distribution.as_ref().map(|d| d.gpu_data()).unwrap_or_default();
        Ok(Environment { buffer: texel_buffer(up.ctx, "environment distribution", &gpu_data)?, value, present, distribution })
    }
}

impl Feature for Environment {
    fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        vec![("EnvDistribution", &self.buffer)]
    }

    fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        vec![("HAS_ENVIRONMENT", SpecValue::Bool(self.present)), ("ENVIRONMENT_SAMPLED", SpecValue::Bool(self.distribution.is_some()))]
    }

    fn values(&self) -> Vec<ValueRef> {
        vec![self.value]
    }
}
