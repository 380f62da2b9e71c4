//! The scene file as written: serde mirrors of the TOML tables of DESIGN.md, before any
//! path is resolved or any value is checked. Unknown keys are rejected here so that a typo
//! is an error with a line number rather than a silently ignored setting.

use serde::Deserialize;

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// A glTF or Mitsuba XML file whose sensors, materials, meshes and lights the scene
    /// starts from (relative to the scene file).
    pub import: Option<String>,
    #[serde(default)]
    pub film: FilmFile,
    #[serde(default)]
    pub integrator: IntegratorFile,
    #[serde(default)]
    pub sensors: Vec<SensorFile>,
    #[serde(default)]
    pub materials: Vec<MaterialFile>,
    #[serde(default)]
    pub meshes: Vec<MeshFile>,
    #[serde(default)]
    pub lights: Vec<LightFile>,
    pub environment: Option<EnvironmentFile>,
    #[serde(default)]
    pub media: Vec<MediumFile>,
    pub optimise: Option<crate::settings::OptimiseTable<ParamFile>>,
}

/// Unset values come from the imported file, else from the defaults (256 × 256, depth 6,
/// roulette from depth 5).
#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct FilmFile {
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// The pixel filter: "box" (the default), "gaussian" or "tent" ([`super::PixelFilter`]).
    pub filter: Option<String>,
    /// A Gaussian filter's standard deviation in pixels (0.5 by default).
    pub filter_stddev: Option<f32>,
    /// A tent filter's radius in pixels (1 by default).
    pub filter_radius: Option<f32>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct IntegratorFile {
    pub max_depth: Option<u32>,
    pub rr_depth: Option<u32>,
    pub hide_emitters: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorFile {
    pub origin: [f32; 3],
    pub target: [f32; 3],
    #[serde(default = "default_up")]
    pub up: [f32; 3],
    /// A pinhole camera's vertical field of view in degrees, in (0, 180).
    pub fov_y: Option<f32>,
    /// An orthographic camera's view height in world units (its width is that times the
    /// film's aspect ratio). Exactly one of `fov_y` and `ortho_height` is given.
    pub ortho_height: Option<f32>,
    /// A pinhole camera's thin lens: the radius of its aperture and the distance along the
    /// view at which it is in focus, both or neither.
    pub aperture_radius: Option<f32>,
    pub focus_distance: Option<f32>,
    pub target_image: Option<String>,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum MaterialType {
    Principled,
    Diffuse,
    Dielectric,
    #[serde(rename = "thin_dielectric")]
    ThinDielectric,
    #[serde(rename = "rough_dielectric")]
    RoughDielectric,
    Conductor,
    Plastic,
}

impl MaterialType {
    /// Every material type.
    pub const ALL: [MaterialType; 7] =
        [Self::Principled, Self::Diffuse, Self::Dielectric, Self::ThinDielectric, Self::RoughDielectric, Self::Conductor, Self::Plastic];

    /// Whether a `[[materials]]` entry of this type may give `key`: the loader rejects
    /// every other material key for the type, naming it.
    pub fn accepts(self, key: &str) -> bool {
        match key {
            "name" | "type" | "base_color" => true,
            // A plastic's roughness is its coating's (a number, never optimised).
            "roughness" => self.has_roughness() || self == Self::Plastic,
            "metallic" => self == Self::Principled,
            "one_sided" | "normal_map" | "bump_map" | "alpha" | "alpha_mode" | "alpha_cutoff" => !self.is_dielectric(),
            "ior" => self.has_ior(),
            "absorption" => matches!(self, Self::Dielectric | Self::RoughDielectric),
            "distribution" => self.has_distribution(),
            "nonlinear" | "layered" | "specular" => self == Self::Plastic,
            "metal" | "eta" | "k" => self == Self::Conductor,
            _ => false,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Principled => "principled",
            Self::Diffuse => "diffuse",
            Self::Dielectric => "dielectric",
            Self::ThinDielectric => "thin_dielectric",
            Self::RoughDielectric => "rough_dielectric",
            Self::Conductor => "conductor",
            Self::Plastic => "plastic",
        }
    }

    /// Glass of any kind: an index of refraction, a transmittance, no metallic.
    pub fn is_dielectric(self) -> bool {
        matches!(self, Self::Dielectric | Self::ThinDielectric | Self::RoughDielectric)
    }

    /// Whether the material has a roughness of its own (one that can be optimised).
    pub fn has_roughness(self) -> bool {
        matches!(self, Self::Principled | Self::RoughDielectric | Self::Conductor)
    }

    /// Whether the material has a distribution of microfacets to choose.
    pub fn has_distribution(self) -> bool {
        matches!(self, Self::RoughDielectric | Self::Conductor | Self::Plastic)
    }

    /// Whether the material has an index of refraction (glass, a plastic's coating, and
    /// the dielectric part of a principled material, whose normal-incidence reflectance
    /// it sets).
    pub fn has_ior(self) -> bool {
        self.is_dielectric() || self == Self::Plastic || self == Self::Principled
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialFile {
    pub name: String,
    #[serde(rename = "type")]
    pub kind: MaterialType,
    /// Required, except for a dielectric (whose transmittance is white by default).
    pub base_color: Option<ColorInput>,
    pub roughness: Option<ScalarInput>,
    pub metallic: Option<ScalarInput>,
    /// Black from behind (the clockwise side of its triangles).
    #[serde(default)]
    pub one_sided: bool,
    pub normal_map: Option<NormalMapFile>,
    /// `bump_map = { texture = "height.exr", scale = 0.01 }`: a height field (model::BumpMap).
    pub bump_map: Option<BumpMapFile>,
    /// `alpha = 0.4` or `{ texture = "mask.exr" }` (its R channel), in [0, 1]: the surface
    /// is cut out where the alpha is below `alpha_cutoff` (model::AlphaMask).
    pub alpha: Option<ScalarInput>,
    /// "mask" (the default: cut out below `alpha_cutoff`) or "blend" (there with
    /// probability alpha). Only with `alpha`.
    pub alpha_mode: Option<String>,
    /// In [0, 1]; 0.5 by default. Only with `alpha` in mode "mask".
    pub alpha_cutoff: Option<f32>,
    /// An index of refraction, interior over exterior (1.5 by default): a dielectric's, a
    /// plastic's coating's, or a principled material's, whose dielectric part then reflects
    /// ((ior − 1)/(ior + 1))² at normal incidence (0.04 at 1.5).
    pub ior: Option<f32>,
    /// A dielectric's interior absorption coefficient per unit length, per channel (0 by
    /// default). Only with `type = "dielectric"`.
    pub absorption: Option<[f32; 3]>,
    /// A rough dielectric's, a conductor's or a plastic's distribution of microfacets:
    /// "ggx" (the default) or "beckmann".
    pub distribution: Option<String>,
    /// A plastic's `nonlinear` (Mitsuba's): the base's reflectance also scales the light
    /// that the coating reflects back into it, which saturates colours. False by default.
    pub nonlinear: Option<bool>,
    /// A plastic's coating is layered (true, the default): the light that enters it
    /// bounces between coating and base. False: the base is seen through two smooth
    /// refractions and nothing more (Mitsuba's `pplastic`).
    pub layered: Option<bool>,
    /// A plastic's specular tint `[r, g, b]` in [0, 1] (Mitsuba's `specular_reflectance`);
    /// 1 by default.
    pub specular: Option<[f32; 3]>,
    /// A conductor's named metal (its complex index of refraction); "none", a perfect
    /// mirror, by default. Not with `eta` and `k`.
    pub metal: Option<String>,
    /// A conductor's complex index of refraction eta + i k, per channel. Both or neither.
    pub eta: Option<[f32; 3]>,
    pub k: Option<[f32; 3]>,
}

/// `normal_map = { texture = "normals.exr", scale = 1.0 }`: a tangent-space normal map
/// (model::NormalMap).
/// `bump_map = { texture = "height.exr", scale = 0.01 }`: the height scale × the texel's
/// luminance, in scene units (model::BumpMap).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BumpMapFile {
    pub texture: String,
    /// 1 by default.
    pub scale: Option<f32>,
    /// As [`NormalMapFile::filter`].
    pub filter: Option<String>,
    /// As [`TextureRef::wrap`].
    pub wrap: Option<WrapInput>,
    /// As [`TextureRef::uv_set`].
    pub uv_set: Option<u32>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NormalMapFile {
    pub texture: String,
    pub scale: Option<f32>,
    /// "bilinear" (the default) or "nearest" ([`super::Filter`]).
    pub filter: Option<String>,
    /// As [`TextureRef::wrap`].
    pub wrap: Option<WrapInput>,
    /// As [`TextureRef::uv_set`].
    pub uv_set: Option<u32>,
    /// "uv" (the default: y along increasing v, glTF's) or "cross" (y along
    /// cross(n, tangent) everywhere, Mitsuba's).
    pub bitangent: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureRef {
    pub texture: String,
    /// "bilinear" (the default) or "nearest" ([`super::Filter`]).
    pub filter: Option<String>,
    /// "repeat" (the default), "clamp" or "mirror" ([`super::Wrap`]), or one for u and one
    /// for v.
    pub wrap: Option<WrapInput>,
    /// The set of texture coordinates it is looked up at: 0 (the default: the OBJ's `vt`)
    /// or 1 (the mesh's `uv1`).
    pub uv_set: Option<u32>,
}

/// `wrap = "clamp"` or `wrap = ["clamp", "repeat"]` (u, v).
#[derive(Debug, Deserialize)]
#[serde(untagged, expecting = "expected a wrap mode or [u, v] wrap modes")]
pub enum WrapInput {
    Both(String),
    Each([String; 2]),
}

#[derive(Debug, Deserialize)]
#[serde(untagged, expecting = "expected [r, g, b] or { texture = \"file.exr\" }")]
pub enum ColorInput {
    Constant([f32; 3]),
    Texture(TextureRef),
}

#[derive(Debug, Deserialize)]
#[serde(untagged, expecting = "expected a number or { texture = \"file.exr\" }")]
pub enum ScalarInput {
    Constant(f32),
    Texture(TextureRef),
}

fn no_emission() -> ColorInput {
    ColorInput::Constant([0.0; 3])
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshFile {
    /// Defaults to the OBJ file's stem; `meshes.NAME.emission` targets refer to it.
    pub name: Option<String>,
    pub file: String,
    pub material: String,
    /// Emitted radiance: a colour or an EXR texture (linear RGB, read with the mesh's
    /// texture coordinates).
    #[serde(default = "no_emission")]
    pub emission: ColorInput,
    /// Emit from both sides instead of the counter-clockwise front only.
    #[serde(default)]
    pub two_sided: bool,
    /// A second set of texture coordinates (textures with `uv_set = 1` read it): an `.npy`
    /// file of float32, shape (triangles, 3, 2), the (u, v) of each triangle's corners in
    /// the OBJ's face order.
    pub uv1: Option<String>,
}

#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum LightType {
    Point,
    Spot,
    Directional,
}

impl LightType {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Point => "point",
            Self::Spot => "spot",
            Self::Directional => "directional",
        }
    }
}

/// A delta light: `color × intensity` is a radiant intensity (point, spot) or an
/// irradiance (directional).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightFile {
    pub name: String,
    #[serde(rename = "type")]
    pub kind: LightType,
    /// Point and spot lights.
    pub position: Option<[f32; 3]>,
    /// Spot and directional lights: the direction the light travels.
    pub direction: Option<[f32; 3]>,
    #[serde(default = "white")]
    pub color: [f32; 3],
    #[serde(default = "one")]
    pub intensity: f32,
    /// Spot lights: full intensity within `inner_angle` degrees of the axis, none beyond
    /// `outer_angle`, and `falloff` in between.
    pub inner_angle: Option<f32>,
    pub outer_angle: Option<f32>,
    #[serde(default)]
    pub falloff: FalloffType,
}

fn white() -> [f32; 3] {
    [1.0; 3]
}

#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum FalloffType {
    /// glTF's: the square of a linear ramp in cos θ.
    #[default]
    Smooth,
    /// Mitsuba's: linear in θ.
    Linear,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentFile {
    pub constant: Option<[f32; 3]>,
    pub file: Option<String>,
    #[serde(default = "one")]
    pub scale: f32,
}

fn one() -> f32 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(untagged, expecting = "expected a number, [r, g, b] or { texture = \"file.exr\" }")]
pub enum InitInput {
    Scalar(f32),
    Color([f32; 3]),
    /// Every texel's start value from an image (a parameter with `texture = [w, h]` only),
    /// e.g. a texture an earlier run recovered (its `params/NAME.exr`).
    Texture(TextureRef),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamFile {
    pub target: String,
    pub init: InitInput,
    pub range: [f32; 2],
    pub texture: Option<[u32; 2]>,
    /// A medium's grid parameter's size `[x, y, z]` (a medium's grid target only).
    pub grid: Option<[u32; 3]>,
    pub lr: Option<f32>,
}

/// A medium's density or emission: a number, a colour, or a grid file (`.npy` or `.vol`).
#[derive(Debug, Deserialize, Clone)]
#[serde(untagged, expecting = "expected a number, [r, g, b], \"file.npy\" or \"file.vol\"")]
pub enum GridInput {
    Scalar(f32),
    Color([f32; 3]),
    File(String),
}

/// `[[media]]`: a box of emitting and absorbing or scattering medium, or the part of one
/// inside a closed mesh.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MediumFile {
    pub name: String,
    /// The box's corners: the mesh's bounds where there is a mesh and they are left out.
    pub min: Option<[f32; 3]>,
    pub max: Option<[f32; 3]>,
    /// A closed OBJ mesh that bounds the medium ([`super::MediumBoundary`]).
    pub mesh: Option<String>,
    pub density: GridInput,
    pub emission: Option<GridInput>,
    pub scale: Option<f32>,
    pub step: Option<f32>,
    pub albedo: Option<GridInput>,
    pub g: Option<f32>,
    /// A scattering medium's density bound for tracking ([`super::Medium::majorant`]).
    pub majorant: Option<f32>,
}
