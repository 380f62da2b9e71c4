//! The scene on the device, feature by feature. Each feature owns its upload (its records
//! and buffers, and its values in the material data), the specialisation constants that
//! compile its code in or out of the kernels, and the parameter kinds it reads from θ:
//!
//! | feature | buffers (GLSL blocks) | constants | parameters |
//! |---|---|---|---|
//! | [`sensors`]: cameras and the film | `Sensors` | | |
//! | [`materials`] | `Materials` | `HAS_PRINCIPLED`, `HAS_DIELECTRICS`, `HAS_ROUGH_DIELECTRICS`, `HAS_CONDUCTORS`, `HAS_PLASTICS` | base colour, roughness, metallic |
//! | [`lights`]: point, spot and directional | `Lights` | `HAS_DELTA_LIGHTS` | colour, intensity |
//! | [`environment`] | `EnvDistribution` | `HAS_ENVIRONMENT`, `ENVIRONMENT_SAMPLED` | the environment |
//! | [`emitters`]: area emitters and light sampling | `Emitters` | `NUM_EMITTERS`, `HAS_EMISSION_TEXTURES` | emission |
//! | [`geometry`]: meshes and the BVH | the BVH's, `Shading`, `ShadingUv1` | `HAS_NORMALS`, `HAS_NORMAL_MAPS`, `HAS_ALPHA_MASKS`, `HAS_UV1`, `BVH_STACK_REGISTERS` | |
//! | [`media`]: a box of emitting and absorbing or scattering medium, bounded by a closed mesh or not | `Media` | `HAS_MEDIA`, `MAJORANT_GRID`, `MEDIUM_BOUNDARY` | density, emission, albedo (grids) |
//!
//! Textures (`HAS_TEXTURES`) are looked up wherever a feature's value is one
//! ([`values`]). A new feature is a module here that implements [`Feature`], the GLSL it
//! needs, and one line in [`Features`].

pub mod emitters;
pub mod environment;
pub mod geometry;
pub mod lights;
pub mod materials;
pub mod media;
pub mod sensors;
pub mod values;

use crate::bvh::BvhLayout;
use crate::gpu::{self, Buffer, Context, SpecValue};
use crate::render::ParamLayout;
use crate::scene::Scene;
use crate::shared::ValueRef;
use std::sync::Arc;
use values::MaterialData;

/// What a feature builds from: the scene, its parameters' slots in θ, and the material data
/// it appends its values to.
pub struct Upload<'a> {
    pub ctx: &'a Arc<Context>,
    pub scene: &'a Scene,
    pub layout: &'a ParamLayout,
    pub data: &'a mut MaterialData,
}

/// A scene feature on the device.
pub trait Feature {
    /// Its buffers, by the GLSL block that reads each.
    fn bindings(&self) -> Vec<(&'static str, &Buffer)>;
    /// Its specialisation constants.
    fn spec(&self) -> Vec<(&'static str, SpecValue)>;
    /// The values it refers to in the material data or θ (for `HAS_TEXTURES`).
    fn values(&self) -> Vec<ValueRef> {
        Vec::new()
    }
}

/// Every feature of a scene on the device, built in the order their dependencies need.
pub struct Features {
    pub sensors: sensors::Sensors,
    pub materials: materials::Materials,
    pub lights: lights::Lights,
    pub environment: environment::Environment,
    pub emitters: emitters::Emitters,
    pub geometry: geometry::Geometry,
    pub media: media::Media,
}

impl Features {
    /// Builds every feature of `up.scene` with its BVH in `bvh_layout`.
    pub fn build(up: &mut Upload, bvh_layout: BvhLayout) -> gpu::Result<Features> {
        let sensors = sensors::Sensors::build(up)?;
        let materials = materials::Materials::build(up)?;
        let lights = lights::Lights::build(up)?;
        let environment = environment::Environment::build(up)?;
        let geo = up.scene.flatten();
        let emitters = emitters::Emitters::build(up, &geo)?;
        let geometry = geometry::Geometry::build(up, geo, &materials, &emitters, bvh_layout)?;
        let media = media::Media::build(up)?;
        Ok(Features { sensors, materials, lights, environment, emitters, geometry, media })
    }

    /// Every feature: the one registration a new feature needs besides its build.
    pub fn all(&self) -> [&dyn Feature; 7] {
        [&self.sensors, &self.materials, &self.lights, &self.environment, &self.emitters, &self.geometry, &self.media]
    }

    /// Whether any feature's value is a texture (`HAS_TEXTURES`).
    pub fn textured(&self) -> bool {
        values::any_texture(self.all().iter().flat_map(|f| f.values()))
    }
}
