//! The scene file as written: serde mirrors of the TOML tables of DESIGN.md, before any
//! path is resolved or any value is checked. Unknown keys are rejected here so that a typo
//! is an error with a line number rather than a silently ignored setting.

use serde::Deserialize;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    #[serde(default)]
    pub film: FilmFile,
    #[serde(default)]
    pub integrator: IntegratorFile,
    pub sensors: Vec<SensorFile>,
    #[serde(default)]
    pub materials: Vec<MaterialFile>,
    #[serde(default)]
    pub meshes: Vec<MeshFile>,
    pub environment: Option<EnvironmentFile>,
    pub optimise: Option<crate::settings::OptimiseTable<ParamFile>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FilmFile {
    pub width: u32,
    pub height: u32,
}

impl Default for FilmFile {
    fn default() -> Self {
        Self {
            width: 256,
            height: 256,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntegratorFile {
    pub max_depth: u32,
    pub rr_depth: u32,
}

impl Default for IntegratorFile {
    fn default() -> Self {
        Self {
            max_depth: 6,
            rr_depth: 5,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorFile {
    pub origin: [f32; 3],
    pub target: [f32; 3],
    #[serde(default = "default_up")]
    pub up: [f32; 3],
    pub fov_y: f32,
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
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialFile {
    pub name: String,
    #[serde(rename = "type")]
    pub kind: MaterialType,
    pub base_color: ColorInput,
    pub roughness: Option<ScalarInput>,
    pub metallic: Option<ScalarInput>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextureRef {
    pub texture: String,
}

#[derive(Debug, Deserialize)]
#[serde(
    untagged,
    expecting = "expected [r, g, b] or { texture = \"file.exr\" }"
)]
pub enum ColorInput {
    Constant([f32; 3]),
    Texture(TextureRef),
}

#[derive(Debug, Deserialize)]
#[serde(
    untagged,
    expecting = "expected a number or { texture = \"file.exr\" }"
)]
pub enum ScalarInput {
    Constant(f32),
    Texture(TextureRef),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshFile {
    /// Defaults to the OBJ file's stem; `meshes.NAME.emission` targets refer to it.
    pub name: Option<String>,
    pub file: String,
    pub material: String,
    #[serde(default)]
    pub emission: [f32; 3],
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
#[serde(untagged, expecting = "expected a number or [r, g, b]")]
pub enum InitInput {
    Scalar(f32),
    Color([f32; 3]),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamFile {
    pub target: String,
    pub init: InitInput,
    pub range: [f32; 2],
    pub texture: Option<[u32; 2]>,
    pub lr: Option<f32>,
}
