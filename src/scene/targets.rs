//! What each kind of parameter target does, in one place: how its name reads in a scene
//! (`materials.NAME.base_color`), its channels, whether it may be a texture, the scene's own
//! value (the reference the optimisation is measured against), its sampler, and how a
//! recovered value is written back into the scene. Which feature reads it from θ on the
//! device is that feature's (`render::features`); the file formats write the scene back.

use super::model::{ColorValue, Environment, Filter, Light, Material, Medium, Mesh, ParamTarget, Reference, ScalarValue, Scene, Texture, TextureValue, Wrap};
use crate::tensor::ParamValue;

/// The parts of a scene that targets name, as a loader has them before the scene exists.
pub(crate) struct Parts<'a> {
    pub materials: &'a [Material],
    pub meshes: &'a [Mesh],
    pub lights: &'a [Light],
    pub environment: &'a Environment,
    pub media: &'a [Medium],
}

/// Why a target's name names nothing.
#[derive(Debug, PartialEq)]
pub(crate) enum TargetError {
    /// Not of any target's form.
    Malformed,
    /// Names a `kind` (material, mesh, light) the scene has no `name` of.
    Undefined { kind: &'static str, name: String, known: String },
    /// Names a property the thing it names does not have.
    Invalid(String),
}

/// The forms of a target's name, for errors.
pub(crate) const TARGET_FORMS: &str =
    "materials.NAME.base_color|roughness|metallic, meshes.NAME.emission, lights.NAME.color|intensity, media.NAME.density|emission or environment";

fn color_reference(v: &ColorValue) -> Reference {
    match v {
        ColorValue::Constant(c) => Reference::Constant(c.to_vec()),
        ColorValue::Texture(t) => Reference::Texture(t.clone()),
    }
}

fn scalar_reference(v: &ScalarValue) -> Reference {
    match v {
        ScalarValue::Constant(c) => Reference::Constant(vec![*c]),
        ScalarValue::Texture(t) => Reference::Texture(t.clone()),
    }
}

impl ParamTarget {
    /// The target that `name` names in a scene of `parts`.
    pub(crate) fn parse(name: &str, parts: &Parts) -> Result<ParamTarget, TargetError> {
        let undefined = |kind, name: &str| {
            let known = match kind {
                "material" => super::error::known_names(parts.materials.iter().map(|m| m.name.as_str())),
                "mesh" => super::error::known_names(parts.meshes.iter().map(|m| m.name.as_str())),
                "medium" => super::error::known_names(parts.media.iter().map(|m| m.name.as_str())),
                _ => super::error::known_names(parts.lights.iter().map(|l| l.name.as_str())),
            };
            TargetError::Undefined { kind, name: name.to_string(), known }
        };
        if name == "environment" {
            return Ok(ParamTarget::Environment);
        }
        if let Some((material_name, property)) = name.strip_prefix("materials.").and_then(|r| r.rsplit_once('.')) {
            if !matches!(property, "base_color" | "roughness" | "metallic") {
                return Err(TargetError::Malformed);
            }
            let material = parts.materials.iter().position(|m| m.name == material_name).ok_or_else(|| undefined("material", material_name))?;
            let m = &parts.materials[material];
            if property == "metallic" && m.kind != super::MaterialKind::Principled || property == "roughness" && !m.kind.has_roughness() {
                return Err(TargetError::Invalid(format!("material \"{material_name}\" is {} and has no {property}", m.kind.as_str())));
            }
            return Ok(match property {
                "base_color" => ParamTarget::BaseColor { material },
                "roughness" => ParamTarget::Roughness { material },
                _ => ParamTarget::Metallic { material },
            });
        }
        if let Some(mesh_name) = name.strip_prefix("meshes.").and_then(|r| r.strip_suffix(".emission")) {
            let mesh = parts.meshes.iter().position(|m| m.name == mesh_name).ok_or_else(|| undefined("mesh", mesh_name))?;
            return Ok(ParamTarget::Emission { mesh });
        }
        if let Some((light_name, property)) = name.strip_prefix("lights.").and_then(|r| r.rsplit_once('.')) {
            if !matches!(property, "color" | "intensity") {
                return Err(TargetError::Malformed);
            }
            let light = parts.lights.iter().position(|l| l.name == light_name).ok_or_else(|| undefined("light", light_name))?;
            return Ok(if property == "color" { ParamTarget::LightColor { light } } else { ParamTarget::LightIntensity { light } });
        }
        if let Some((medium_name, property)) = name.strip_prefix("media.").and_then(|r| r.rsplit_once('.')) {
            if !matches!(property, "density" | "emission" | "albedo") {
                return Err(TargetError::Malformed);
            }
            let medium = parts.media.iter().position(|m| m.name == medium_name).ok_or_else(|| undefined("medium", medium_name))?;
            if property == "emission" && parts.media[medium].scatters() {
                return Err(TargetError::Invalid(format!("medium \"{medium_name}\" scatters (albedo above 0) and emits nothing")));
            }
            if property == "albedo" && !parts.media[medium].scatters() {
                return Err(TargetError::Invalid(format!(
                    "medium \"{medium_name}\" does not scatter (albedo 0): give it an albedo above 0 to optimise its albedo"
                )));
            }
            return Ok(match property {
                "density" => ParamTarget::MediumDensity { medium },
                "emission" => ParamTarget::MediumEmission { medium },
                _ => ParamTarget::MediumAlbedo { medium },
            });
        }
        Err(TargetError::Malformed)
    }

    /// 3 for colours, emission and environment; 1 for roughness, metallic and intensity.
    pub fn channels(self) -> u32 {
        match self {
            Self::Roughness { .. } | Self::Metallic { .. } | Self::LightIntensity { .. } | Self::MediumDensity { .. } => 1,
            _ => 3,
        }
    }

    /// Whether the target may be optimised as a texture (a light's colour and intensity
    /// are constants).
    pub fn texturable(self) -> bool {
        !matches!(self, Self::LightColor { .. } | Self::LightIntensity { .. }) && self.medium().is_none()
    }

    /// The medium whose density or emission this is, if any (a grid, not a texture).
    pub fn medium(self) -> Option<usize> {
        match self {
            Self::MediumDensity { medium } | Self::MediumEmission { medium } | Self::MediumAlbedo { medium } => Some(medium),
            _ => None,
        }
    }

    /// The material whose property this is, if any.
    pub fn material(self) -> Option<usize> {
        match self {
            Self::BaseColor { material } | Self::Roughness { material } | Self::Metallic { material } => Some(material),
            _ => None,
        }
    }

    /// The scene's own value of the target.
    pub(crate) fn reference(self, parts: &Parts) -> Reference {
        match self {
            Self::BaseColor { material } => color_reference(&parts.materials[material].base_color),
            Self::Roughness { material } => scalar_reference(&parts.materials[material].roughness),
            Self::Metallic { material } => scalar_reference(&parts.materials[material].metallic),
            Self::Emission { mesh } => color_reference(&parts.meshes[mesh].emission),
            Self::Environment => color_reference(&parts.environment.value),
            Self::LightColor { light } => Reference::Constant(parts.lights[light].color.to_vec()),
            Self::LightIntensity { light } => Reference::Constant(vec![parts.lights[light].intensity]),
            Self::MediumDensity { medium } => Reference::Grid(parts.media[medium].density.clone()),
            Self::MediumEmission { medium } => Reference::Grid(parts.media[medium].emission.clone()),
            Self::MediumAlbedo { medium } => Reference::Grid(parts.media[medium].albedo.clone()),
        }
    }

    /// The filter, wrap modes and coordinate set of the scene's value, which a recovered
    /// texture keeps (the environment's are always bilinear and repeating).
    pub(crate) fn sampler(self, scene: &Scene) -> (Filter, [Wrap; 2], u32) {
        fn of(v: &impl TextureValue) -> (Filter, [Wrap; 2], u32) {
            (v.filter(), v.wrap(), v.uv_set())
        }
        match self {
            Self::BaseColor { material } => of(&scene.materials[material].base_color),
            Self::Roughness { material } => of(&scene.materials[material].roughness),
            Self::Metallic { material } => of(&scene.materials[material].metallic),
            Self::Emission { mesh } => of(&scene.meshes[mesh].emission),
            Self::Environment
            | Self::LightColor { .. }
            | Self::LightIntensity { .. }
            | Self::MediumDensity { .. }
            | Self::MediumEmission { .. }
            | Self::MediumAlbedo { .. } => (Filter::Bilinear, [Wrap::Repeat; 2], 0),
        }
    }

    /// Writes `value` into `scene` as the target's value: a texture (`texture`, the value as
    /// an image) or a constant (its first three channels, one channel repeated).
    pub(crate) fn set(self, scene: &mut Scene, value: &ParamValue, texture: Option<Texture>) {
        let constant = constant3(value);
        let color = || match texture.clone() {
            Some(t) => ColorValue::Texture(t),
            None => ColorValue::Constant(constant),
        };
        let scalar = || match texture.clone() {
            Some(t) => ScalarValue::Texture(t),
            None => ScalarValue::Constant(constant[0]),
        };
        match self {
            Self::BaseColor { material } => scene.materials[material].base_color = color(),
            Self::Roughness { material } => scene.materials[material].roughness = scalar(),
            Self::Metallic { material } => scene.materials[material].metallic = scalar(),
            Self::Emission { mesh } => scene.meshes[mesh].emission = color(),
            Self::Environment => scene.environment.value = color(),
            Self::LightColor { light } => scene.lights[light].color = constant,
            Self::LightIntensity { light } => scene.lights[light].intensity = constant[0],
            Self::MediumDensity { medium } => scene.media[medium].density = value.clone(),
            Self::MediumEmission { medium } => scene.media[medium].emission = value.clone(),
            Self::MediumAlbedo { medium } => scene.media[medium].albedo = value.clone(),
        }
    }
}

/// A constant value's first three channels (one channel repeated); zeros for a texture.
pub(crate) fn constant3(v: &ParamValue) -> [f32; 3] {
    match v.data.as_slice() {
        _ if !v.shape.is_constant() => [0.0; 3],
        [r, g, b, ..] => [*r, *g, *b],
        [x] => [*x; 3],
        _ => [0.0; 3],
    }
}
