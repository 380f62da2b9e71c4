//! The scene model: what every loader (TOML, glTF, Mitsuba XML) produces and the renderer,
//! optimiser and writers consume. Nothing here reads a file.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};

use super::file::MaterialType as MaterialKind;
use crate::image::Image;

/// Largest film and texture side accepted; larger values are typos, not scenes.
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Deepest path accepted; beyond this the GPU's per-path replay state is wasted.
pub const MAX_DEPTH: u32 = 1024;
/// A dielectric's index of refraction (interior over exterior) when none is given: glass
/// in air.
pub const DEFAULT_IOR: f32 = 1.5;
/// The range of relative indices of refraction a dielectric may have (below 1: a less
/// dense interior, such as a bubble in water).
pub const MIN_IOR: f32 = 0.25;
pub const MAX_IOR: f32 = 4.0;
/// A rough dielectric's roughness when the scene gives none (GGX alpha 0.09, near
/// Mitsuba's default alpha of 0.1).
pub const DEFAULT_GLASS_ROUGHNESS: f32 = 0.3;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Film {
    pub width: u32,
    pub height: u32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Integrator {
    /// Longest path in segments: 1 sees emitters only, 2 adds direct light.
    pub max_depth: u32,
    /// Depth from which Russian roulette may end a path.
    pub rr_depth: u32,
}

/// A pinhole camera with an orthonormal right-handed basis: it looks along `forward`,
/// `right = forward × up_hint`, `up = right × forward`.
#[derive(Clone, Debug)]
pub struct Sensor {
    pub origin: Vec3,
    pub look_at: Vec3,
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    /// Vertical field of view in degrees.
    pub fov_y: f32,
    pub target_image: Option<Texture>,
}

impl Sensor {
    /// The camera at `origin` looking at `target` with `up` as the up hint; `Err` names
    /// the degenerate input. `fov_y` is checked by the caller.
    pub fn looking_at(origin: Vec3, target: Vec3, up: Vec3, fov_y: f32) -> Result<Self, &'static str> {
        let forward = (target - origin).try_normalize().ok_or("origin and target coincide")?;
        // Nearly parallel vectors would give a basis dominated by rounding error.
        let right = forward.cross(up.normalize_or_zero());
        if right.length() < 1e-4 {
            return Err("up is zero or parallel to the view direction");
        }
        let right = right.normalize();
        Ok(Sensor { origin, look_at: target, forward, right, up: right.cross(forward), fov_y, target_image: None })
    }

    /// Unit direction through normalised device coordinates `ndc` in [-1, 1]² (x right,
    /// y up), for a film of aspect ratio `aspect` = width / height.
    pub fn ray_direction(&self, ndc: Vec2, aspect: f32) -> Vec3 {
        let t = (self.fov_y.to_radians() * 0.5).tan();
        (self.forward + ndc.x * t * aspect * self.right + ndc.y * t * self.up).normalize()
    }
}

/// An image loaded from a file named in the scene (or embedded in one: then `path` is the
/// scene file followed by `#` and where in it the image is).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    pub path: PathBuf,
    /// Shared between the values that use one image (a glTF emissive material's texture
    /// on each of its meshes), so that it is held, and uploaded, once.
    pub image: std::sync::Arc<Image>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum ColorValue {
    Constant([f32; 3]),
    Texture(Texture),
}

impl ColorValue {
    /// Whether any channel of the constant, or of any texel, is above zero.
    pub fn any_positive(&self) -> bool {
        match self {
            Self::Constant(c) => c.iter().any(|&v| v > 0.0),
            Self::Texture(t) => t.image.data.iter().flatten().any(|&v| v > 0.0),
        }
    }
}

/// A scalar property; a texture's R channel holds it.
#[derive(Clone, Debug)]
pub enum ScalarValue {
    Constant(f32),
    Texture(Texture),
}

/// A glTF metallic-roughness material. A diffuse one has roughness 1 and metallic 0, which
/// the file may not set. A dielectric (glass) is a smooth interface whose base colour is
/// its transmittance; its roughness and metallic are 0 and unused.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    pub kind: MaterialKind,
    pub base_color: ColorValue,
    pub roughness: ScalarValue,
    pub metallic: ScalarValue,
    /// Reflects nothing from behind (the clockwise side of its triangles), as Mitsuba's
    /// BSDFs not wrapped in `twosided`; otherwise both sides shade alike.
    pub one_sided: bool,
    /// Perturbs the shading normal (never optimised).
    pub normal_map: Option<NormalMap>,
    /// Cuts the surface out where its alpha is below a threshold (never optimised).
    pub alpha: Option<AlphaMask>,
    /// A dielectric's index of refraction, its interior (the back of its triangles; a thin
    /// dielectric's sheet) over its exterior, in [MIN_IOR, MAX_IOR] (never optimised); [`DEFAULT_IOR`] and unused
    /// for the other kinds.
    pub ior: f32,
    /// A (refracting) dielectric's interior absorption coefficient per unit length, per
    /// channel, at least 0: a ray that travels a distance t inside keeps exp(−absorption t)
    /// of its radiance (never optimised). Zero for the other kinds.
    pub absorption: [f32; 3],
    /// A rough dielectric's distribution of microfacets ([`Distribution::Ggx`] for the
    /// other kinds).
    pub distribution: Distribution,
}

/// The distribution of a rough dielectric's microfacet normals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Distribution {
    /// Trowbridge–Reitz (GGX), as the principled model's.
    #[default]
    Ggx,
    /// Beckmann's (Mitsuba 3's default for `roughdielectric`).
    Beckmann,
}

impl Distribution {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ggx => "ggx",
            Self::Beckmann => "beckmann",
        }
    }
}

impl Material {
    /// Glass of `kind` (any dielectric kind) with transmittance `base_color` and index of
    /// refraction `ior`: no metallic, normal map or alpha, both sides alike, roughness 0 and
    /// GGX (a rough dielectric's caller sets its own).
    pub fn glass(name: String, kind: MaterialKind, base_color: ColorValue, ior: f32) -> Self {
        debug_assert!(kind.is_dielectric());
        Self {
            name,
            kind,
            base_color,
            roughness: ScalarValue::Constant(0.0),
            metallic: ScalarValue::Constant(0.0),
            one_sided: false,
            normal_map: None,
            alpha: None,
            ior,
            absorption: [0.0; 3],
            distribution: Distribution::Ggx,
        }
    }
}

/// An alpha test: whether the surface is there at a point, by its alpha there (looked up
/// bilinearly, for a texture, at the point's texture coordinates). Where it is not, rays
/// pass through it as if it were not there.
#[derive(Clone, Debug)]
pub struct AlphaMask {
    /// In [0, 1]; a texture's R channel holds it.
    pub value: ScalarValue,
    pub mode: AlphaMode,
}

/// How an alpha decides whether the surface is there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AlphaMode {
    /// Where the alpha is at least `cutoff` (glTF's `MASK`): a cut-out.
    Mask { cutoff: f32 },
    /// With probability alpha, drawn anew for each ray that reaches the point (glTF's
    /// `BLEND`, Mitsuba's `mask`): a coverage, which in expectation lets 1 − alpha of the
    /// light through.
    Blend,
}

impl AlphaMask {
    /// Whether the surface is there at every point for every ray: every texel (so every
    /// bilinear lookup) at or above the cutoff, or for a blend at 1.
    pub fn never_cuts(&self) -> bool {
        let there = |a: f32| match self.mode {
            AlphaMode::Mask { cutoff } => a >= cutoff,
            AlphaMode::Blend => a >= 1.0,
        };
        match &self.value {
            ScalarValue::Constant(a) => there(*a),
            ScalarValue::Texture(t) => t.image.data.iter().all(|p| there(p[0])),
        }
    }
}

impl AlphaMode {
    /// The TOML name (`alpha_mode`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Mask { .. } => "mask",
            Self::Blend => "blend",
        }
    }
}

/// A tangent-space normal map: each texel's RGB in [0, 1] encodes the unit normal
/// (2R − 1, 2G − 1, 2B − 1) with x along the surface's tangent (the direction of increasing
/// u), y along its bitangent and z along the interpolated normal, as glTF's
/// `normalTexture` and Mitsuba's `normalmap` store it; `scale` multiplies x and y (glTF's
/// `normalTexture.scale`).
#[derive(Clone, Debug)]
pub struct NormalMap {
    pub texture: Texture,
    pub scale: f32,
    pub bitangent: Bitangent,
}

/// Which way a normal map's y points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bitangent {
    /// Along increasing v, the image's up: cross(n, tangent) turned where the texture
    /// coordinates are mirrored (glTF's convention, MikkTSpace's handedness).
    Uv,
    /// cross(n, tangent) everywhere (Mitsuba's `normalmap`).
    Cross,
}

impl Bitangent {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Uv => "uv",
            Self::Cross => "cross",
        }
    }
}

impl NormalMap {
    /// The decoded, scaled tangent-space vectors (not normalised: the kernels normalise
    /// after filtering).
    pub fn vectors(&self) -> Vec<[f32; 3]> {
        self.texture.image.data.iter().map(|p| [(2.0 * p[0] - 1.0) * self.scale, (2.0 * p[1] - 1.0) * self.scale, 2.0 * p[2] - 1.0]).collect()
    }
}

impl Material {
    pub fn is_textured(&self) -> bool {
        matches!(self.base_color, ColorValue::Texture(_))
            || matches!(self.roughness, ScalarValue::Texture(_))
            || matches!(self.metallic, ScalarValue::Texture(_))
    }
}

/// A triangle mesh in world space. UVs follow the OBJ convention (v pointing up, (0, 0)
/// the bottom left of an image); importers convert theirs.
#[derive(Clone, Debug)]
pub struct Mesh {
    pub name: String,
    /// The file the triangles came from.
    pub path: PathBuf,
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<[u32; 3]>,
    pub material: usize,
    /// Radiance emitted from the front (counter-clockwise) side, or both sides when
    /// `two_sided_emission`: a colour, or a texture read with the mesh's texture coordinates.
    pub emission: ColorValue,
    pub two_sided_emission: bool,
}

/// How a spot light's intensity falls off between its inner and outer cone.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpotFalloff {
    /// glTF's (KHR_lights_punctual): the square of a linear ramp in cos θ.
    Smooth,
    /// Mitsuba's: linear in the angle θ.
    Linear,
}

impl SpotFalloff {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Smooth => "smooth",
            Self::Linear => "linear",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    /// Radiant intensity `color × intensity` in every direction from `position`.
    Point,
    /// A point light restricted to a cone around `direction`: full intensity inside
    /// `inner` radians of the axis, none beyond `outer`.
    Spot { inner: f32, outer: f32, falloff: SpotFalloff },
    /// Irradiance `color × intensity` on a surface facing the light, arriving along
    /// `direction` from infinitely far away.
    Directional,
}

impl LightKind {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Point => "point",
            Self::Spot { .. } => "spot",
            Self::Directional => "directional",
        }
    }
}

/// A delta light (no area, so never hit by a ray): sampled by next-event estimation only.
/// Its emitted quantity (radiant intensity, or irradiance for a directional light) is
/// `color × intensity`; both factors can be optimised.
#[derive(Clone, Debug)]
pub struct Light {
    pub name: String,
    pub kind: LightKind,
    pub position: Vec3,
    /// Unit direction the light travels along (spot axis, directional light's rays).
    pub direction: Vec3,
    pub color: [f32; 3],
    pub intensity: f32,
}

/// Light from infinitely far away: radiance `value * scale`, a texture being a lat-long map.
/// A scene without `[environment]` has a black one.
#[derive(Clone, Debug)]
pub struct Environment {
    pub value: ColorValue,
    pub scale: f32,
}

/// What an optimised parameter stands for. Indices are into `Scene::materials` / `meshes`
/// / `lights`. An environment parameter replaces the environment's value before `scale`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ParamTarget {
    BaseColor { material: usize },
    Roughness { material: usize },
    Metallic { material: usize },
    Emission { mesh: usize },
    Environment,
    LightColor { light: usize },
    LightIntensity { light: usize },
}

impl ParamTarget {
    /// The material whose property this is, if any.
    pub fn material(self) -> Option<usize> {
        match self {
            Self::BaseColor { material } | Self::Roughness { material } | Self::Metallic { material } => Some(material),
            _ => None,
        }
    }

    /// 3 for colours, emission and environment; 1 for roughness, metallic and intensity.
    pub fn channels(self) -> u32 {
        match self {
            Self::Roughness { .. } | Self::Metallic { .. } | Self::LightIntensity { .. } => 1,
            _ => 3,
        }
    }
}

/// The scene's own value of a parameter, against which parameter error is measured.
#[derive(Clone, Debug)]
pub enum Reference {
    /// One value per channel.
    Constant(Vec<f32>),
    /// A texture in the scene; its resolution may differ from the parameter's.
    Texture(Texture),
}

#[derive(Clone, Debug)]
pub struct Param {
    /// The target as written, e.g. `materials.wall.base_color`; unique within a scene.
    pub name: String,
    pub target: ParamTarget,
    pub channels: u32,
    /// Start value, one per channel (a scalar `init` is repeated), or with an image as
    /// `init` every texel's, row by row (the image resampled to `texture`'s size).
    pub init: Vec<f32>,
    /// Inclusive bounds, `range[0] < range[1]`.
    pub range: [f32; 2],
    /// Optimise as a texture of this width and height instead of one constant.
    pub texture: Option<[u32; 2]>,
    /// Learning rate for this parameter instead of the run's `lr` (unless a rate given
    /// outside the scene replaces it).
    pub lr: Option<f32>,
    pub reference: Reference,
}

/// The scene's `[optimise]` table: its layer of run settings (checked, not resolved: the
/// command line and job files may override them) and the optimised parameters.
#[derive(Clone, Debug, Default)]
pub struct Optimise {
    pub settings: crate::settings::Settings,
    pub params: Vec<Param>,
    /// The earlier run's `params.json` the parameters start from instead of their `init`
    /// ([`Scene::start_from_run`]), if any.
    pub started_from: Option<std::path::PathBuf>,
}

/// Where a scene came from, for writing it back: the TOML alone, or the glTF or Mitsuba
/// file it is or imports.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Source {
    #[default]
    Toml,
    Gltf(GltfSource),
    Mitsuba(PathBuf),
}

/// An imported glTF file and where the model's imported materials and lights are in it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GltfSource {
    pub path: PathBuf,
    /// glTF material index of each imported material, in model order (`None`: glTF's
    /// default material); materials after these came from the TOML.
    pub materials: Vec<Option<usize>>,
    /// `KHR_lights_punctual` index of each imported light, in model order.
    pub lights: Vec<usize>,
}

/// A loaded, validated scene; see the module documentation for its invariants.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The scene file.
    pub path: PathBuf,
    pub source: Source,
    pub film: Film,
    pub integrator: Integrator,
    pub sensors: Vec<Sensor>,
    pub materials: Vec<Material>,
    pub meshes: Vec<Mesh>,
    pub lights: Vec<Light>,
    pub environment: Environment,
    pub optimise: Optimise,
    /// What loading approximated or left out, one line each (printed by the command line).
    pub warnings: Vec<String>,
    pub(super) content_hash: u64,
}

/// All meshes as one triangle list, for the BVH builder and the GPU. Vertex arrays are
/// parallel; a zero normal means "use the face normal", a mesh without UVs gets zeros.
#[derive(Clone, Debug, Default)]
pub struct SceneGeometry {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<[u32; 3]>,
    pub triangle_material: Vec<u32>,
    pub triangle_mesh: Vec<u32>,
}

impl Scene {
    /// Directory that relative paths in the scene file, and cached targets, live in.
    pub fn dir(&self) -> &Path {
        self.path.parent().unwrap_or(Path::new(""))
    }

    /// A hash of everything that determines the reference rendering (see
    /// [`super::hash`]): stable across runs and platforms, so it can key a cache of
    /// rendered targets.
    pub fn content_hash(&self) -> u64 {
        self.content_hash
    }

    pub fn material_index(&self, name: &str) -> Option<usize> {
        self.materials.iter().position(|m| m.name == name)
    }

    pub fn mesh_index(&self, name: &str) -> Option<usize> {
        self.meshes.iter().position(|m| m.name == name)
    }

    pub fn light_index(&self, name: &str) -> Option<usize> {
        self.lights.iter().position(|l| l.name == name)
    }

    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.indices.len()).sum()
    }

    /// Concatenates all meshes, in order, into one [`SceneGeometry`].
    pub fn flatten(&self) -> SceneGeometry {
        let mut g = SceneGeometry::default();
        for (mesh_id, mesh) in self.meshes.iter().enumerate() {
            let base = g.positions.len() as u32;
            let n = mesh.positions.len();
            g.positions.extend_from_slice(&mesh.positions);
            if mesh.normals.is_empty() {
                g.normals.resize(g.normals.len() + n, [0.0; 3]);
            } else {
                g.normals.extend_from_slice(&mesh.normals);
            }
            if mesh.uvs.is_empty() {
                g.uvs.resize(g.uvs.len() + n, [0.0; 2]);
            } else {
                g.uvs.extend_from_slice(&mesh.uvs);
            }
            g.indices.extend(mesh.indices.iter().map(|t| t.map(|i| i + base)));
            let count = mesh.indices.len();
            g.triangle_material.extend(std::iter::repeat_n(mesh.material as u32, count));
            g.triangle_mesh.extend(std::iter::repeat_n(mesh_id as u32, count));
        }
        g
    }
}
