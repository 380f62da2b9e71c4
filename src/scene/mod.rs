//! Scene loading and validation: the `scene.toml` format of DESIGN.md, its OBJ meshes and
//! OpenEXR images, resolved into a [`Scene`] that the renderer and optimiser use as is.
//!
//! Invariants of a loaded [`Scene`], all checked by [`Scene::load`] before it returns:
//! - every number is finite; film sizes are in 1..=16384; fields of view in (0, 180);
//! - every material and mesh name is unique; every mesh's material index is valid;
//! - every mesh has at least one triangle, all indices in bounds, and normals and UVs either
//!   absent or one per position; a mesh whose material is textured has UVs;
//! - every image is decoded, finite, and a sensor's target image has the film's size;
//! - every optimised parameter names an existing value, its `init` has its channel count and
//!   lies inside its `range`, and `range` is non-empty.
//!
//! Relative paths in the file are relative to the scene file's directory. Mesh names default
//! to the OBJ file's stem; `meshes.NAME.emission` targets use them.

mod error;
mod file;
mod obj;

use std::collections::HashSet;
use std::fs;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};

pub use error::SceneError;
pub use crate::settings::Loss;
pub use file::MaterialType as MaterialKind;

use crate::image::{self, Image};
use file::{ColorInput, InitInput, ScalarInput, SceneFile};

/// Largest film and texture side accepted; larger values are typos, not scenes.
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// Deepest path accepted; beyond this the GPU's per-path replay state is wasted.
pub const MAX_DEPTH: u32 = 1024;

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
    /// Unit direction through normalised device coordinates `ndc` in [-1, 1]² (x right,
    /// y up), for a film of aspect ratio `aspect` = width / height.
    pub fn ray_direction(&self, ndc: Vec2, aspect: f32) -> Vec3 {
        let t = (self.fov_y.to_radians() * 0.5).tan();
        (self.forward + ndc.x * t * aspect * self.right + ndc.y * t * self.up).normalize()
    }
}

/// An image loaded from a file named in the scene.
#[derive(Clone, Debug)]
pub struct Texture {
    pub path: PathBuf,
    pub image: Image,
}

#[derive(Clone, Debug)]
pub enum ColorValue {
    Constant([f32; 3]),
    Texture(Texture),
}

/// A scalar property; a texture's R channel holds it.
#[derive(Clone, Debug)]
pub enum ScalarValue {
    Constant(f32),
    Texture(Texture),
}

/// A glTF metallic-roughness material. A diffuse one has roughness 1 and metallic 0, which
/// the file may not set.
#[derive(Clone, Debug)]
pub struct Material {
    pub name: String,
    pub kind: MaterialKind,
    pub base_color: ColorValue,
    pub roughness: ScalarValue,
    pub metallic: ScalarValue,
}

impl Material {
    pub fn is_textured(&self) -> bool {
        matches!(self.base_color, ColorValue::Texture(_))
            || matches!(self.roughness, ScalarValue::Texture(_))
            || matches!(self.metallic, ScalarValue::Texture(_))
    }
}

/// A triangle mesh from one OBJ file. UVs are as written in the OBJ (v pointing up).
#[derive(Clone, Debug)]
pub struct Mesh {
    pub name: String,
    pub path: PathBuf,
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<[u32; 3]>,
    pub material: usize,
    pub emission: [f32; 3],
}

/// Light from infinitely far away: radiance `value * scale`, a texture being a lat-long map.
/// A scene without `[environment]` has a black one.
#[derive(Clone, Debug)]
pub struct Environment {
    pub value: ColorValue,
    pub scale: f32,
}

/// What an optimised parameter stands for. Indices are into `Scene::materials` / `meshes`.
/// An environment parameter replaces the environment's value before `scale`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ParamTarget {
    BaseColor { material: usize },
    Roughness { material: usize },
    Metallic { material: usize },
    Emission { mesh: usize },
    Environment,
}

impl ParamTarget {
    /// 3 for colours, emission and environment; 1 for roughness and metallic.
    /// The material whose property this is, if any.
    pub fn material(self) -> Option<usize> {
        match self {
            Self::BaseColor { material }
            | Self::Roughness { material }
            | Self::Metallic { material } => Some(material),
            _ => None,
        }
    }

    pub fn channels(self) -> u32 {
        match self {
            Self::Roughness { .. } | Self::Metallic { .. } => 1,
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
    /// Start value, one per channel (a scalar `init` is repeated).
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
}

/// A loaded, validated scene; see the module documentation for its invariants.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The scene file.
    pub path: PathBuf,
    pub film: Film,
    pub integrator: Integrator,
    pub sensors: Vec<Sensor>,
    pub materials: Vec<Material>,
    pub meshes: Vec<Mesh>,
    pub environment: Environment,
    pub optimise: Optimise,
    content_hash: u64,
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
    pub triangle_emission: Vec<[f32; 3]>,
}

impl Scene {
    /// Loads and validates `path` and everything it refers to.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, SceneError> {
        let path = path.as_ref().to_path_buf();
        let text = fs::read_to_string(&path).map_err(|source| SceneError::ReadScene {
            path: path.clone(),
            source,
        })?;
        let raw: SceneFile =
            toml::from_str(&text).map_err(|e| SceneError::toml(path.clone(), &text, e))?;
        let table: toml::Table =
            toml::from_str(&text).map_err(|e| SceneError::toml(path.clone(), &text, e))?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let mut loader = Loader {
            scene: path.clone(),
            dir,
            hash: Fnv64::new(),
        };
        loader.hash.bytes(b"vkinverse-scene-v1");
        hash_toml(&mut loader.hash, &table, true);
        loader.build(raw)
    }

    /// Directory that relative paths in the scene file, and cached targets, live in.
    pub fn dir(&self) -> &Path {
        self.path.parent().unwrap_or(Path::new(""))
    }

    /// FNV-1a 64 of everything that determines the reference rendering: the file's tables
    /// other than `[optimise]` (as parsed values, so comments and layout do not count) and
    /// the bytes of every mesh, texture and environment map. Stable across runs and
    /// platforms, so it can key a cache of rendered targets.
    pub fn content_hash(&self) -> u64 {
        self.content_hash
    }

    pub fn material_index(&self, name: &str) -> Option<usize> {
        self.materials.iter().position(|m| m.name == name)
    }

    pub fn mesh_index(&self, name: &str) -> Option<usize> {
        self.meshes.iter().position(|m| m.name == name)
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
            g.indices
                .extend(mesh.indices.iter().map(|t| t.map(|i| i + base)));
            let count = mesh.indices.len();
            g.triangle_material
                .extend(std::iter::repeat_n(mesh.material as u32, count));
            g.triangle_mesh
                .extend(std::iter::repeat_n(mesh_id as u32, count));
            g.triangle_emission
                .extend(std::iter::repeat_n(mesh.emission, count));
        }
        g
    }
}

/// FNV-1a, 64-bit: tiny, stable and good enough for a cache key (not for adversaries).
struct Fnv64(u64);

impl Fnv64 {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    fn bytes(&mut self, bytes: &[u8]) {
        // Length first, so that consecutive fields cannot run into each other.
        for &b in (bytes.len() as u64).to_le_bytes().iter().chain(bytes) {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

/// Hashes parsed TOML with sorted keys; `skip_optimise` drops the top-level `[optimise]`.
fn hash_toml(h: &mut Fnv64, table: &toml::Table, skip_optimise: bool) {
    let mut entries: Vec<_> = table
        .iter()
        .filter(|(k, _)| !(skip_optimise && *k == "optimise"))
        .collect();
    entries.sort_by(|a, b| a.0.cmp(b.0));
    h.bytes(b"{");
    for (key, value) in entries {
        h.bytes(key.as_bytes());
        hash_value(h, value);
    }
}

fn hash_value(h: &mut Fnv64, value: &toml::Value) {
    use toml::Value::*;
    match value {
        String(s) => h.bytes(&[b"s", s.as_bytes()].concat()),
        Integer(i) => h.bytes(&[&b"i"[..], &i.to_le_bytes()].concat()),
        Float(f) => h.bytes(&[&b"f"[..], &f.to_bits().to_le_bytes()].concat()),
        Boolean(b) => h.bytes(if *b { b"true" } else { b"false" }),
        Datetime(d) => h.bytes(&[b"d", d.to_string().as_bytes()].concat()),
        Array(items) => {
            h.bytes(b"[");
            items.iter().for_each(|v| hash_value(h, v));
            h.bytes(b"]");
        }
        Table(t) => hash_toml(h, t, false),
    }
}

/// State of one load: where relative paths start, and the content hash so far.
struct Loader {
    scene: PathBuf,
    dir: PathBuf,
    hash: Fnv64,
}

impl Loader {
    fn out_of_range(&self, key: &str, message: String) -> SceneError {
        SceneError::OutOfRange {
            scene: self.scene.clone(),
            key: key.into(),
            message,
        }
    }

    fn invalid(&self, key: &str, message: &str) -> SceneError {
        SceneError::Invalid {
            scene: self.scene.clone(),
            key: key.into(),
            message: message.into(),
        }
    }

    fn finite(&self, key: &str, values: &[f32]) -> Result<(), SceneError> {
        if values.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(SceneError::NonFinite {
                scene: self.scene.clone(),
                key: key.into(),
            })
        }
    }

    /// A finite, non-negative colour (reflectance or radiance).
    fn color(&self, key: &str, c: [f32; 3]) -> Result<[f32; 3], SceneError> {
        self.finite(key, &c)?;
        if c.iter().any(|&v| v < 0.0) {
            return Err(self.out_of_range(key, format!("{c:?} has a negative component")));
        }
        Ok(c)
    }

    fn in_range<T: PartialOrd + std::fmt::Display>(
        &self,
        key: &str,
        v: T,
        lo: T,
        hi: T,
    ) -> Result<T, SceneError> {
        if v >= lo && v <= hi {
            Ok(v)
        } else {
            Err(self.out_of_range(key, format!("{v} is outside [{lo}, {hi}]")))
        }
    }

    /// Reads a file named at `key`; `hashed` files count towards the content hash.
    fn read(
        &mut self,
        key: &str,
        rel: &str,
        hashed: bool,
    ) -> Result<(PathBuf, Vec<u8>), SceneError> {
        let file = self.dir.join(rel);
        let bytes = fs::read(&file).map_err(|source| SceneError::MissingFile {
            scene: self.scene.clone(),
            key: key.into(),
            file: file.clone(),
            source,
        })?;
        if hashed {
            self.hash.bytes(&bytes);
        }
        Ok((file, bytes))
    }

    fn texture(&mut self, key: &str, rel: &str, hashed: bool) -> Result<Texture, SceneError> {
        let (path, bytes) = self.read(key, rel, hashed)?;
        let image = image::decode_exr(&bytes, &path).map_err(|source| SceneError::Image {
            scene: self.scene.clone(),
            key: key.into(),
            source,
        })?;
        if let Some((x, y)) = image.find_non_finite() {
            return Err(SceneError::NonFinitePixel {
                scene: self.scene.clone(),
                key: key.into(),
                image: path,
                x,
                y,
            });
        }
        Ok(Texture { path, image })
    }

    fn color_value(&mut self, key: &str, input: ColorInput) -> Result<ColorValue, SceneError> {
        Ok(match input {
            ColorInput::Constant(c) => ColorValue::Constant(self.color(key, c)?),
            ColorInput::Texture(t) => {
                let k = format!("{key}.texture");
                let tex = self.texture(&k, &t.texture, true)?;
                self.texels_in(&k, &tex, 3, 0.0, f32::INFINITY)?;
                ColorValue::Texture(tex)
            }
        })
    }

    /// Checks the first `channels` channels of every texel against [lo, hi]: the rule a
    /// constant of the same property obeys.
    fn texels_in(&self, key: &str, t: &Texture, channels: usize, lo: f32, hi: f32) -> Result<(), SceneError> {
        for (i, px) in t.image.data.iter().enumerate() {
            if let Some(v) = px[..channels].iter().find(|v| !(lo..=hi).contains(*v)) {
                let (x, y) = (i as u32 % t.image.width, i as u32 / t.image.width);
                return Err(self.out_of_range(
                    key,
                    format!("{} has {v} at pixel ({x}, {y}), outside [{lo}, {hi}]", t.path.display()),
                ));
            }
        }
        Ok(())
    }

    fn scalar_value(&mut self, key: &str, input: ScalarInput) -> Result<ScalarValue, SceneError> {
        Ok(match input {
            ScalarInput::Constant(v) => {
                self.finite(key, &[v])?;
                ScalarValue::Constant(self.in_range(key, v, 0.0, 1.0)?)
            }
            ScalarInput::Texture(t) => {
                let k = format!("{key}.texture");
                let tex = self.texture(&k, &t.texture, true)?;
                self.texels_in(&k, &tex, 1, 0.0, 1.0)?;
                ScalarValue::Texture(tex)
            }
        })
    }

    fn build(mut self, raw: SceneFile) -> Result<Scene, SceneError> {
        let film = Film {
            width: self.in_range("film.width", raw.film.width, 1, MAX_IMAGE_SIDE)?,
            height: self.in_range("film.height", raw.film.height, 1, MAX_IMAGE_SIDE)?,
        };
        let integrator = Integrator {
            max_depth: self.in_range(
                "integrator.max_depth",
                raw.integrator.max_depth,
                1,
                MAX_DEPTH,
            )?,
            rr_depth: self.in_range(
                "integrator.rr_depth",
                raw.integrator.rr_depth,
                1,
                MAX_DEPTH,
            )?,
        };
        if raw.sensors.is_empty() {
            return Err(self.invalid("sensors", "at least one sensor is needed"));
        }
        let sensors = raw
            .sensors
            .into_iter()
            .enumerate()
            .map(|(i, s)| self.sensor(&format!("sensors[{i}]"), s, film))
            .collect::<Result<Vec<_>, _>>()?;
        let materials = self.materials(raw.materials)?;
        let meshes = self.meshes(raw.meshes, &materials)?;
        let environment = self.environment(raw.environment)?;
        let optimise = self.optimise(
            raw.optimise.unwrap_or_default(),
            &materials,
            &meshes,
            &environment,
        )?;
        for mesh in &meshes {
            let material = &materials[mesh.material];
            let textured = material.is_textured()
                || optimise
                    .params
                    .iter()
                    .any(|p| p.texture.is_some() && p.target.material() == Some(mesh.material));
            if textured && mesh.uvs.is_empty() {
                return Err(self.invalid(
                    &format!("meshes.{}", mesh.name),
                    &format!(
                        "material \"{}\" is textured but {} has no texture coordinates",
                        material.name,
                        mesh.path.display()
                    ),
                ));
            }
        }
        Ok(Scene {
            path: self.scene,
            film,
            integrator,
            sensors,
            materials,
            meshes,
            environment,
            optimise,
            content_hash: self.hash.0,
        })
    }

    fn sensor(&mut self, key: &str, s: file::SensorFile, film: Film) -> Result<Sensor, SceneError> {
        for (name, v) in [("origin", s.origin), ("target", s.target), ("up", s.up)] {
            self.finite(&format!("{key}.{name}"), &v)?;
        }
        self.finite(&format!("{key}.fov_y"), &[s.fov_y])?;
        if !(s.fov_y > 0.0 && s.fov_y < 180.0) {
            return Err(self.out_of_range(
                &format!("{key}.fov_y"),
                format!("{} is outside (0, 180) degrees", s.fov_y),
            ));
        }
        let (origin, look_at) = (Vec3::from(s.origin), Vec3::from(s.target));
        let forward = (look_at - origin)
            .try_normalize()
            .ok_or_else(|| self.invalid(key, "origin and target coincide"))?;
        // Nearly parallel vectors would give a basis dominated by rounding error.
        let right = forward.cross(Vec3::from(s.up).normalize_or_zero());
        if right.length() < 1e-4 {
            return Err(self.invalid(
                &format!("{key}.up"),
                "up is zero or parallel to the view direction",
            ));
        }
        let right = right.normalize();
        let up = right.cross(forward);
        let target_image = match s.target_image {
            Some(rel) => {
                let k = format!("{key}.target_image");
                let t = self.texture(&k, &rel, false)?;
                if (t.image.width, t.image.height) != (film.width, film.height) {
                    return Err(self.invalid(
                        &k,
                        &format!(
                            "{} is {}x{} but the film is {}x{}",
                            t.path.display(),
                            t.image.width,
                            t.image.height,
                            film.width,
                            film.height
                        ),
                    ));
                }
                Some(t)
            }
            None => None,
        };
        Ok(Sensor {
            origin,
            look_at,
            forward,
            right,
            up,
            fov_y: s.fov_y,
            target_image,
        })
    }

    fn check_name(
        &self,
        key: &str,
        name: &str,
        seen: &mut HashSet<String>,
    ) -> Result<(), SceneError> {
        if name.is_empty() {
            return Err(self.invalid(key, "name is empty"));
        }
        if !seen.insert(name.to_string()) {
            return Err(SceneError::Duplicate {
                scene: self.scene.clone(),
                key: key.into(),
                name: name.into(),
            });
        }
        Ok(())
    }

    fn materials(&mut self, raw: Vec<file::MaterialFile>) -> Result<Vec<Material>, SceneError> {
        let mut seen = HashSet::new();
        let mut out = Vec::with_capacity(raw.len());
        for (i, m) in raw.into_iter().enumerate() {
            self.check_name(&format!("materials[{i}].name"), &m.name, &mut seen)?;
            let key = format!("materials.{}", m.name);
            let base_color = self.color_value(&format!("{key}.base_color"), m.base_color)?;
            let (roughness, metallic) = match m.kind {
                MaterialKind::Principled => (
                    self.scalar_value(
                        &format!("{key}.roughness"),
                        m.roughness.unwrap_or(ScalarInput::Constant(0.5)),
                    )?,
                    self.scalar_value(
                        &format!("{key}.metallic"),
                        m.metallic.unwrap_or(ScalarInput::Constant(0.0)),
                    )?,
                ),
                MaterialKind::Diffuse => {
                    if m.roughness.is_some() || m.metallic.is_some() {
                        return Err(
                            self.invalid(&key, "a diffuse material takes no roughness or metallic")
                        );
                    }
                    (ScalarValue::Constant(1.0), ScalarValue::Constant(0.0))
                }
            };
            out.push(Material {
                name: m.name,
                kind: m.kind,
                base_color,
                roughness,
                metallic,
            });
        }
        Ok(out)
    }

    fn meshes(
        &mut self,
        raw: Vec<file::MeshFile>,
        materials: &[Material],
    ) -> Result<Vec<Mesh>, SceneError> {
        let mut seen = HashSet::new();
        let mut out = Vec::with_capacity(raw.len());
        for (i, m) in raw.into_iter().enumerate() {
            let name = m.name.unwrap_or_else(|| {
                Path::new(&m.file)
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default()
            });
            self.check_name(&format!("meshes[{i}] (\"{name}\")"), &name, &mut seen)?;
            let key = format!("meshes.{name}");
            let material = materials
                .iter()
                .position(|mat| mat.name == m.material)
                .ok_or_else(|| SceneError::Undefined {
                    scene: self.scene.clone(),
                    key: format!("{key}.material"),
                    kind: "material",
                    name: m.material.clone(),
                })?;
            let emission = self.color(&format!("{key}.emission"), m.emission)?;
            let (path, bytes) = self.read(&format!("{key}.file"), &m.file, true)?;
            let data = obj::load(&path, &bytes)?;
            for (what, values) in [
                ("positions", data.positions.as_flattened()),
                ("normals", data.normals.as_flattened()),
            ] {
                if values.iter().any(|v| !v.is_finite()) {
                    return Err(SceneError::Obj {
                        path,
                        line: 0,
                        message: format!("non-finite {what}"),
                    });
                }
            }
            out.push(Mesh {
                name,
                path,
                positions: data.positions,
                normals: data.normals,
                uvs: data.uvs,
                indices: data.indices,
                material,
                emission,
            });
        }
        Ok(out)
    }

    fn environment(
        &mut self,
        raw: Option<file::EnvironmentFile>,
    ) -> Result<Environment, SceneError> {
        let Some(env) = raw else {
            return Ok(Environment {
                value: ColorValue::Constant([0.0; 3]),
                scale: 1.0,
            });
        };
        self.finite("environment.scale", &[env.scale])?;
        if env.scale < 0.0 {
            return Err(
                self.out_of_range("environment.scale", format!("{} is negative", env.scale))
            );
        }
        let value = match (env.constant, env.file) {
            (Some(c), None) => ColorValue::Constant(self.color("environment.constant", c)?),
            (None, Some(rel)) => {
                ColorValue::Texture(self.texture("environment.file", &rel, true)?)
            }
            _ => {
                return Err(self.invalid("environment", "give exactly one of `constant` and `file`"))
            }
        };
        Ok(Environment {
            value,
            scale: env.scale,
        })
    }

    fn optimise(
        &mut self,
        raw: crate::settings::OptimiseTable<file::ParamFile>,
        materials: &[Material],
        meshes: &[Mesh],
        environment: &Environment,
    ) -> Result<Optimise, SceneError> {
        raw.settings
            .validate()
            .map_err(|e| self.out_of_range(&format!("optimise.{}", e.key), e.message))?;
        let mut seen = HashSet::new();
        let mut params = Vec::with_capacity(raw.params.len());
        for (i, p) in raw.params.into_iter().enumerate() {
            let key = format!("optimise.params[{i}]");
            self.check_name(&format!("{key}.target"), &p.target, &mut seen)?;
            params.push(self.param(&key, p, materials, meshes, environment)?);
        }
        Ok(Optimise {
            settings: raw.settings,
            params,
        })
    }

    fn positive(&self, key: &str, v: f32) -> Result<(), SceneError> {
        self.finite(key, &[v])?;
        if v > 0.0 {
            Ok(())
        } else {
            Err(self.out_of_range(key, format!("{v} is not positive")))
        }
    }

    fn param(
        &self,
        key: &str,
        p: file::ParamFile,
        materials: &[Material],
        meshes: &[Mesh],
        environment: &Environment,
    ) -> Result<Param, SceneError> {
        let target_key = format!("{key}.target");
        let (target, reference) =
            self.resolve_target(&target_key, &p.target, materials, meshes, environment)?;
        let channels = target.channels();

        let range_key = format!("{key}.range");
        self.finite(&range_key, &p.range)?;
        let [lo, hi] = p.range;
        if lo >= hi {
            return Err(self.out_of_range(
                &range_key,
                format!("lower bound {lo} is not below upper bound {hi}"),
            ));
        }
        let init_key = format!("{key}.init");
        let init = match p.init {
            InitInput::Scalar(v) => vec![v; channels as usize],
            InitInput::Color(c) if channels == 3 => c.to_vec(),
            InitInput::Color(_) => {
                return Err(self.invalid(
                    &init_key,
                    &format!("{} is a scalar; give one number", p.target),
                ))
            }
        };
        self.finite(&init_key, &init)?;
        if let Some(v) = init.iter().find(|&&v| v < lo || v > hi) {
            return Err(
                self.out_of_range(&init_key, format!("{v} is outside the range [{lo}, {hi}]"))
            );
        }
        if let Some(lr) = p.lr {
            self.positive(&format!("{key}.lr"), lr)?;
        }
        if let Some([w, h]) = p.texture {
            let k = format!("{key}.texture");
            self.in_range(&k, w, 1, MAX_IMAGE_SIDE)?;
            self.in_range(&k, h, 1, MAX_IMAGE_SIDE)?;
            if matches!(target, ParamTarget::Emission { .. }) {
                return Err(
                    self.invalid(&k, "mesh emission is one constant and cannot be a texture")
                );
            }
        } else if matches!(reference, Reference::Texture(_)) {
            return Err(self.invalid(
                key,
                &format!(
                    "{} is a texture in the scene; give `texture = [w, h]`",
                    p.target
                ),
            ));
        }
        Ok(Param {
            name: p.target,
            target,
            channels,
            init,
            range: p.range,
            texture: p.texture,
            lr: p.lr,
            reference,
        })
    }

    fn resolve_target(
        &self,
        key: &str,
        target: &str,
        materials: &[Material],
        meshes: &[Mesh],
        environment: &Environment,
    ) -> Result<(ParamTarget, Reference), SceneError> {
        let color = |v: &ColorValue| match v {
            ColorValue::Constant(c) => Reference::Constant(c.to_vec()),
            ColorValue::Texture(t) => Reference::Texture(t.clone()),
        };
        let scalar = |v: &ScalarValue| match v {
            ScalarValue::Constant(c) => Reference::Constant(vec![*c]),
            ScalarValue::Texture(t) => Reference::Texture(t.clone()),
        };
        let undefined = |kind, name: &str| SceneError::Undefined {
            scene: self.scene.clone(),
            key: key.into(),
            kind,
            name: name.into(),
        };
        if target == "environment" {
            return Ok((ParamTarget::Environment, color(&environment.value)));
        }
        if let Some((name, property)) = target
            .strip_prefix("materials.")
            .and_then(|r| r.rsplit_once('.'))
        {
            let material = materials.iter().position(|m| m.name == name);
            let (material, m) = match material {
                Some(i) if matches!(property, "base_color" | "roughness" | "metallic") => {
                    (i, &materials[i])
                }
                None if matches!(property, "base_color" | "roughness" | "metallic") => {
                    return Err(undefined("material", name))
                }
                _ => return Err(self.bad_target(key, target)),
            };
            if property != "base_color" && m.kind == MaterialKind::Diffuse {
                return Err(self.invalid(
                    key,
                    &format!("material \"{name}\" is diffuse and has no {property}"),
                ));
            }
            return Ok(match property {
                "base_color" => (ParamTarget::BaseColor { material }, color(&m.base_color)),
                "roughness" => (ParamTarget::Roughness { material }, scalar(&m.roughness)),
                _ => (ParamTarget::Metallic { material }, scalar(&m.metallic)),
            });
        }
        if let Some(name) = target
            .strip_prefix("meshes.")
            .and_then(|r| r.strip_suffix(".emission"))
        {
            let mesh = meshes
                .iter()
                .position(|m| m.name == name)
                .ok_or_else(|| undefined("mesh", name))?;
            return Ok((
                ParamTarget::Emission { mesh },
                Reference::Constant(meshes[mesh].emission.to_vec()),
            ));
        }
        Err(self.bad_target(key, target))
    }

    fn bad_target(&self, key: &str, target: &str) -> SceneError {
        self.invalid(
            key,
            &format!("\"{target}\" is not materials.NAME.base_color|roughness|metallic, meshes.NAME.emission or environment"),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sensor(origin: [f32; 3], target: [f32; 3], up: [f32; 3]) -> Result<Sensor, SceneError> {
        let mut loader = Loader {
            scene: "s.toml".into(),
            dir: PathBuf::new(),
            hash: Fnv64::new(),
        };
        let raw = file::SensorFile {
            origin,
            target,
            up,
            fov_y: 90.0,
            target_image: None,
        };
        loader.sensor(
            "sensors[0]",
            raw,
            Film {
                width: 4,
                height: 4,
            },
        )
    }

    #[test]
    fn camera_basis_is_orthonormal_and_right_handed() {
        let s = sensor([0.0, 1.0, 4.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.3]).unwrap();
        assert!(s.forward.abs_diff_eq(Vec3::NEG_Z, 1e-6));
        assert!(s.right.abs_diff_eq(Vec3::X, 1e-6));
        assert!(s.up.abs_diff_eq(Vec3::Y, 1e-6));
        assert!(s
            .ray_direction(Vec2::ZERO, 2.0)
            .abs_diff_eq(Vec3::NEG_Z, 1e-6));
        // fov_y = 90: the top edge of the film is 45 degrees up.
        let top = s.ray_direction(Vec2::new(0.0, 1.0), 1.0);
        assert!((top.y - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6);
    }

    #[test]
    fn degenerate_cameras_are_errors() {
        assert!(matches!(
            sensor([0.0; 3], [0.0; 3], [0.0, 1.0, 0.0]),
            Err(SceneError::Invalid { .. })
        ));
        let err = sensor([0.0; 3], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]).unwrap_err();
        assert!(err.to_string().contains("sensors[0].up"), "{err}");
    }

    #[test]
    fn fnv_matches_reference_and_separates_fields() {
        let mut h = Fnv64::new();
        for &b in b"a" {
            h.0 = (h.0 ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
        // Published FNV-1a 64 test vector for "a".
        assert_eq!(h.0, 0xaf63_dc4c_8601_ec8c);
        let (mut ab, mut a_b) = (Fnv64::new(), Fnv64::new());
        ab.bytes(b"ab");
        a_b.bytes(b"a");
        a_b.bytes(b"b");
        assert_ne!(ab.0, a_b.0);
    }

    #[test]
    fn toml_hash_ignores_layout_and_optimise() {
        let hash = |text: &str| {
            let mut h = Fnv64::new();
            hash_toml(&mut h, &toml::from_str(text).unwrap(), true);
            h.0
        };
        let a = hash("[film]\nwidth = 8\nheight = 8\n[optimise]\nlr = 0.1\n");
        assert_eq!(
            a,
            hash("# comment\n[film]\nheight = 8\nwidth = 8\n[optimise]\nlr = 0.5\n")
        );
        assert_ne!(a, hash("[film]\nwidth = 8\nheight = 9\n"));
    }
}
