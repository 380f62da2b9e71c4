//! Scene loading and validation: a `scene.toml` (the format of DESIGN.md) with OBJ meshes
//! and OpenEXR images, a glTF 2.0 file (`.gltf`, `.glb`) or a Mitsuba 3 XML scene, taken by
//! extension and resolved into one [`Scene`] model that the renderer and optimiser use as
//! is; a TOML scene may start from an imported glTF or XML file (`import = "FILE"`).
//!
//! Layout: [`model`] (the types), `loader` (the TOML format, and the checks every
//! loader's output passes), `gltf`, `mitsuba` and `ply` (importers), `hash` (the content
//! hash) and `write` (the recovered scene written back as TOML and glTF).
//!
//! Invariants of a loaded [`Scene`], all checked before a load returns:
//! - every number is finite; film sizes are in 1..=16384; fields of view in (0, 180);
//! - every material, mesh and light name is unique; every mesh's material index is valid;
//! - every mesh has at least one triangle, all indices in bounds, and normals and UVs either
//!   absent or one per position; a mesh whose material is textured has UVs;
//! - every image is decoded, finite, and a sensor's target image has the film's size;
//! - every optimised parameter names an existing value, its `init` has its channel count and
//!   lies inside its `range`, and `range` is non-empty.
//!
//! Relative paths in a file are relative to that file's directory. TOML mesh names default
//! to the OBJ file's stem; imported things keep their names from the source file (glTF
//! node and material names, Mitsuba `id`s), and `meshes.NAME.emission`,
//! `materials.NAME.base_color` and `lights.NAME.intensity` targets use them.

mod checks;
mod error;
mod file;
mod gltf;
mod gltf_check;
mod hash;
mod keys;
mod loader;
pub mod media;
mod mitsuba;
pub mod model;
mod obj;
mod ply;
mod spectrum;
mod targets;
pub mod write;
mod write_xml;

use std::path::Path;

use serde::Deserialize;

pub use crate::settings::Loss;
pub use error::SceneError;
pub use file::MaterialType as MaterialKind;
pub use keys::{scene_keys, TEXTURE_SECTION};
pub use model::*;

/// Settings given outside the scene file that change what is rendered (the command line's
/// `--film WxH` and `--max-depth N`); they override the file's values.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoadOptions {
    pub film: Option<Film>,
    pub max_depth: Option<u32>,
}

/// Scene file formats, by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Format {
    Toml,
    Gltf,
    Mitsuba,
}

impl Format {
    pub(crate) fn of(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "toml" => Some(Format::Toml),
            "gltf" | "glb" => Some(Format::Gltf),
            "xml" => Some(Format::Mitsuba),
            _ => None,
        }
    }
}

impl crate::settings::Settings {
    /// The run settings of `scene` with this layer on top (defaults below the scene's).
    pub fn resolve_for(&self, scene: &Scene) -> crate::settings::RunSettings {
        crate::settings::Settings::resolve(&scene.optimise.settings, self)
    }
}

impl crate::settings::RunSettings {
    /// The settings of a scene alone.
    pub fn of_scene(scene: &Scene) -> crate::settings::RunSettings {
        crate::settings::Settings::default().resolve_for(scene)
    }
}

/// A scene built in code: what [`Scene::from_parts`] checks and joins, as a loader checks a
/// file's contents.
#[derive(Clone, Debug)]
pub struct SceneParts {
    pub film: Film,
    pub integrator: Integrator,
    pub sensors: Vec<Sensor>,
    pub materials: Vec<Material>,
    /// Each mesh's `material` indexes `materials`.
    pub meshes: Vec<Mesh>,
    pub lights: Vec<Light>,
    pub environment: Environment,
    pub media: Vec<Medium>,
    /// The scene's layer of run settings (its `[optimise]` table's).
    pub settings: crate::settings::Settings,
    pub params: Vec<ParamSpec>,
}

impl Default for SceneParts {
    fn default() -> Self {
        SceneParts {
            film: Film { width: 256, height: 256 },
            integrator: Integrator { max_depth: 6, rr_depth: 5, hide_emitters: false },
            sensors: Vec::new(),
            materials: Vec::new(),
            meshes: Vec::new(),
            lights: Vec::new(),
            environment: Environment { value: ColorValue::Constant([0.0; 3]), scale: 1.0 },
            media: Vec::new(),
            settings: Default::default(),
            params: Vec::new(),
        }
    }
}

/// An optimised parameter of a scene built in code, as a `[[optimise.params]]` entry gives
/// it: its target (`materials.NAME.base_color`), its start value (one number, or one per
/// channel), its range, and optionally a texture size and its own learning rate.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamSpec {
    pub target: String,
    pub init: Vec<f32>,
    pub range: [f32; 2],
    pub texture: Option<[u32; 2]>,
    /// A medium's grid parameter's size `[x, y, z]`.
    pub grid: Option<[u32; 3]>,
    pub lr: Option<f32>,
}

impl ParamSpec {
    /// A constant parameter of `target` starting at `init`, within `range`.
    pub fn new(target: &str, init: &[f32], range: [f32; 2]) -> Self {
        ParamSpec { target: target.to_string(), init: init.to_vec(), range, texture: None, grid: None, lr: None }
    }
}

impl Scene {
    /// The scene of `parts`, checked as a loaded scene is (every invariant of this module),
    /// its paths relative to the current directory.
    ///
    /// ```
    /// use glam::Vec3;
    /// use vkinverse::scene::{ColorValue, Film, Material, Mesh, ParamSpec, SceneParts, Sensor};
    /// let quad = |y: f32| vec![[-1.0, y, -1.0], [1.0, y, -1.0], [1.0, y, 1.0], [-1.0, y, 1.0]];
    /// let mut light = Mesh::new("light", quad(2.0), vec![[0, 1, 2], [0, 2, 3]], 0);
    /// light.emission = ColorValue::Constant([5.0; 3]);
    /// let parts = SceneParts {
    ///     film: Film { width: 8, height: 8 },
    ///     sensors: vec![Sensor::looking_at(Vec3::new(0.0, 1.0, 4.0), Vec3::new(0.0, 1.0, 0.0), Vec3::Y, 40.0).unwrap()],
    ///     materials: vec![Material::diffuse("floor", ColorValue::Constant([0.5; 3]))],
    ///     meshes: vec![Mesh::new("floor", quad(0.0), vec![[0, 2, 1], [0, 3, 2]], 0), light],
    ///     params: vec![ParamSpec::new("materials.floor.base_color", &[0.2], [0.0, 1.0])],
    ///     ..SceneParts::default()
    /// };
    /// let scene = vkinverse::Scene::from_parts(parts).unwrap();
    /// assert_eq!(scene.optimise.params[0].init, [0.2; 3]);
    /// ```
    pub fn from_parts(parts: SceneParts) -> Result<Scene, SceneError> {
        let dir = std::env::current_dir().unwrap_or_default();
        let loader = loader::Loader { scene: dir.join("scene (built in code)"), dir };
        let mut params = Vec::with_capacity(parts.params.len());
        for (i, p) in parts.params.into_iter().enumerate() {
            let init = match p.init.as_slice() {
                [v] => file::InitInput::Scalar(*v),
                [r, g, b] => file::InitInput::Color([*r, *g, *b]),
                _ => {
                    return Err(loader.invalid(&format!("optimise.params[{i}].init"), &format!("{} values: give one number, or one per channel", p.init.len())))
                }
            };
            params.push(file::ParamFile { init, target: p.target, range: p.range, texture: p.texture, grid: p.grid, lr: p.lr });
        }
        let raw = file::SceneFile { optimise: Some(crate::settings::OptimiseTable { settings: parts.settings, params }), ..Default::default() };
        let imported = model::Imported {
            film: Some(parts.film),
            max_depth: Some(parts.integrator.max_depth),
            rr_depth: Some(parts.integrator.rr_depth),
            hide_emitters: Some(parts.integrator.hide_emitters),
            sensors: parts.sensors,
            materials: parts.materials,
            meshes: parts.meshes,
            lights: parts.lights,
            environment: Some(parts.environment),
            media: parts.media,
            ..Default::default()
        };
        loader.build(raw, Some(imported), &LoadOptions::default())
    }
}

/// Film side of a bare glTF scene along the camera's longer axis.
pub const GLTF_FILM_SIDE: u32 = 512;
/// Path depth of a bare glTF scene.
pub const GLTF_MAX_DEPTH: u32 = 8;

impl Scene {
    /// Loads and validates `path` (`.toml`, `.gltf`, `.glb` or `.xml`) and everything it
    /// refers to.
    ///
    /// ```
    /// let scene = vkinverse::Scene::load("scenes/cornell/scene.toml").unwrap();
    /// assert_eq!((scene.film.width, scene.sensors.len()), (64, 1));
    /// assert_eq!(scene.optimise.params[0].name, "materials.red.base_color");
    /// ```
    pub fn load(path: impl AsRef<Path>) -> Result<Self, SceneError> {
        Self::load_with(path, &LoadOptions::default())
    }

    /// [`Self::load`] with film size and depth overridden by `options`.
    pub fn load_with(path: impl AsRef<Path>, options: &LoadOptions) -> Result<Self, SceneError> {
        let path = path.as_ref();
        let loader = loader::Loader { scene: path.to_path_buf(), dir: path.parent().map(Path::to_path_buf).unwrap_or_default() };
        let imported = match Format::of(path) {
            Some(Format::Gltf) => gltf::import(path)?,
            Some(Format::Mitsuba) => mitsuba::import(path)?,
            // Anything else is read as TOML, whose errors then say what is wrong.
            _ => {
                let text = crate::files::read_to_string(path).map_err(|source| SceneError::ReadScene { path: path.to_path_buf(), source })?;
                return loader::load(path, &text, options);
            }
        };
        loader.build(Default::default(), Some(imported), options)
    }

    /// Starts every optimised parameter from the values an earlier run recovered (its
    /// `params/`): `dir` is that run's directory or its `params/`, whose `params.json` gives
    /// each parameter's value as `init` would (a number, a colour, or `{ "texture":
    /// "NAME.exr" }` beside it, resampled to this scene's texture size), checked against this
    /// scene's range. Every parameter of this scene must be there; others are ignored.
    pub fn start_from_run(&mut self, dir: &Path) -> Result<(), SceneError> {
        let pdir = if dir.join("params.json").is_file() { dir.to_path_buf() } else { dir.join("params") };
        let path = pdir.join("params.json");
        let import_err = |message: String| SceneError::Import { path: path.clone(), location: String::new(), message };
        let text = crate::files::read_to_string(&path).map_err(|e| import_err(format!("cannot read an earlier run's parameters: {e}")))?;
        let values: std::collections::BTreeMap<String, serde_json::Value> =
            serde_json::from_str(&text).map_err(|e| import_err(format!("expected an object of parameter values ({e})")))?;
        let loader = loader::Loader { scene: path.clone(), dir: pdir };
        for p in &mut self.optimise.params {
            let Some(v) = values.get(&p.name) else {
                let names: Vec<&str> = values.keys().map(String::as_str).collect();
                return Err(loader.invalid(
                    &p.name,
                    &format!("no value for this parameter (the file has {})", if names.is_empty() { "none".into() } else { names.join(", ") }),
                ));
            };
            let init = file::InitInput::deserialize(v).map_err(|e| loader.invalid(&p.name, &e.to_string()))?;
            p.init = loader.init_values(&p.name, init, &p.name, p.shape, p.range)?;
        }
        self.optimise.started_from = Some(path);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Vec2, Vec3};

    fn sensor(origin: [f32; 3], target: [f32; 3], up: [f32; 3]) -> Result<Sensor, SceneError> {
        let loader = loader::Loader { scene: "s.toml".into(), dir: Default::default() };
        let raw =
            file::SensorFile { origin, target, up, fov_y: Some(90.0), ortho_height: None, aperture_radius: None, focus_distance: None, target_image: None };
        loader.sensor("sensors[0]", raw, Film { width: 4, height: 4 })
    }

    #[test]
    fn camera_basis_is_orthonormal_and_right_handed() {
        let s = sensor([0.0, 1.0, 4.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.3]).unwrap();
        assert!(s.forward.abs_diff_eq(Vec3::NEG_Z, 1e-6));
        assert!(s.right.abs_diff_eq(Vec3::X, 1e-6));
        assert!(s.up.abs_diff_eq(Vec3::Y, 1e-6));
        assert!(s.ray_direction(Vec2::ZERO, 2.0).abs_diff_eq(Vec3::NEG_Z, 1e-6));
        // fov_y = 90: the top edge of the film is 45 degrees up.
        let top = s.ray_direction(Vec2::new(0.0, 1.0), 1.0);
        assert!((top.y - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6);
    }

    #[test]
    fn degenerate_cameras_are_errors() {
        assert!(matches!(sensor([0.0; 3], [0.0; 3], [0.0, 1.0, 0.0]), Err(SceneError::Invalid { .. })));
        let err = sensor([0.0; 3], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]).unwrap_err();
        assert!(err.to_string().contains("sensors[0].up"), "{err}");
    }
}
