//! The TOML scene loader (`scene.toml`, the format of DESIGN.md), and the validation that
//! every loader's output passes: the TOML's own tables are resolved here, an imported glTF
//! or Mitsuba file's contents arrive as [`Imported`], and [`Loader::build`] joins both
//! into one checked [`Scene`].
//!
//! Override rules of `import = "FILE"`: the imported sensors come first and the TOML's
//! `[[sensors]]` are added after them; materials, meshes and lights likewise (names must
//! stay unique); `[film]` and `[integrator]` values the TOML sets replace the imported
//! ones key by key; a TOML `[environment]` replaces the imported one; `[optimise]` is the
//! TOML's alone. Command-line `--film` and `--max-depth` ([`LoadOptions`]) override both.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use glam::Vec3;

use super::file::{self, ColorInput, InitInput, ScalarInput, SceneFile};
use super::model::*;
use super::targets::{Parts, TargetError, TARGET_FORMS};
use super::{obj, LoadOptions, MaterialKind, SceneError};
use crate::image;
use crate::tensor::Shape;

/// Loads the TOML scene at `path` (text `text`), with the file it imports.
pub(super) fn load(path: &Path, text: &str, options: &LoadOptions) -> Result<Scene, SceneError> {
    let raw: SceneFile = toml::from_str(text).map_err(|e| SceneError::toml(path.to_path_buf(), text, e))?;
    let loader = Loader { scene: path.to_path_buf(), dir: path.parent().map(Path::to_path_buf).unwrap_or_default() };
    let imported = match &raw.import {
        Some(rel) => {
            let file = loader.dir.join(rel);
            let imported = match super::Format::of(&file) {
                Some(super::Format::Gltf) => super::gltf::import(&file)?,
                Some(super::Format::Mitsuba) => super::mitsuba::import(&file)?,
                _ => return Err(loader.invalid("import", &format!("{rel}: expected a .gltf, .glb or .xml file"))),
            };
            Some(imported)
        }
        None => None,
    };
    loader.build(raw, imported, options)
}

/// Vertical field of view of the camera that frames a glTF model without one, in degrees.
const FRAMING_FOV_Y: f32 = 45.0;

/// A camera for a glTF model without one, as model viewers frame it: looking down −z (the
/// glTF's forward) at the centre of the meshes' bounding box, with +y up, from as far as
/// makes the box's bounding sphere fit the film; and the line that announces it.
fn framing_sensor(meshes: &[Mesh], film: Film) -> Result<(Sensor, String), String> {
    let (lo, hi) = meshes
        .iter()
        .flat_map(|m| &m.positions)
        .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(Vec3::from(*p)), hi.max(Vec3::from(*p))));
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-3);
    let half_v = (FRAMING_FOV_Y * 0.5).to_radians();
    let half_h = (half_v.tan() * film.width as f32 / film.height as f32).atan();
    let distance = radius / half_v.min(half_h).sin();
    let origin = centre + Vec3::Z * distance;
    // Only a model far out of scale with its distance from the origin (1e12 away and 1e-3
    // across) leaves no room in float32 between the camera and what it looks at.
    let sensor = Sensor::looking_at(origin, centre, Vec3::Y, FRAMING_FOV_Y).map_err(|e| format!("no camera, and none frames the model: {e}"))?;
    let note = format!(
        "no camera: one with a {FRAMING_FOV_Y}° vertical field of view looks down -z at the model's centre ({:.3}, {:.3}, {:.3}) from {distance:.3} away, framing it",
        centre.x, centre.y, centre.z
    );
    Ok((sensor, note))
}

/// State of one load: the scene file (named in errors) and where relative paths start.
pub(super) struct Loader {
    pub scene: PathBuf,
    pub dir: PathBuf,
}

impl Loader {
    pub fn out_of_range(&self, key: &str, message: String) -> SceneError {
        SceneError::OutOfRange { scene: self.scene.clone(), key: key.into(), message }
    }

    pub fn invalid(&self, key: &str, message: &str) -> SceneError {
        SceneError::Invalid { scene: self.scene.clone(), key: key.into(), message: message.into() }
    }

    pub fn finite(&self, key: &str, values: &[f32]) -> Result<(), SceneError> {
        if values.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(SceneError::NonFinite { scene: self.scene.clone(), key: key.into() })
        }
    }

    /// A finite, non-negative colour (reflectance or radiance).
    pub fn color(&self, key: &str, c: [f32; 3]) -> Result<[f32; 3], SceneError> {
        self.finite(key, &c)?;
        if c.iter().any(|&v| v < 0.0) {
            return Err(self.out_of_range(key, format!("{c:?} has a negative component")));
        }
        Ok(c)
    }

    fn in_range<T: PartialOrd + std::fmt::Display>(&self, key: &str, v: T, lo: T, hi: T) -> Result<T, SceneError> {
        if v >= lo && v <= hi {
            Ok(v)
        } else {
            Err(self.out_of_range(key, format!("{v} is outside [{lo}, {hi}]")))
        }
    }

    /// Reads a file named at `key`, relative to the scene's directory.
    pub fn read(&self, key: &str, rel: &str) -> Result<(PathBuf, Vec<u8>), SceneError> {
        let file = self.dir.join(rel);
        let bytes =
            crate::files::read(&file).map_err(|source| SceneError::MissingFile { scene: self.scene.clone(), key: key.into(), file: file.clone(), source })?;
        Ok((file, bytes))
    }

    pub fn texture(&self, key: &str, rel: &str) -> Result<Texture, SceneError> {
        let (path, bytes) = self.read(key, rel)?;
        let image = image::decode_linear(&bytes, &path).map_err(|source| SceneError::Image { scene: self.scene.clone(), key: key.into(), source })?;
        if let Some((x, y)) = image.find_non_finite() {
            return Err(SceneError::NonFinitePixel { scene: self.scene.clone(), key: key.into(), image: path, x, y });
        }
        Ok(Texture::new(path, image.into()))
    }

    /// The texture a scene value names at `key` (`{ texture = …, filter = … }`).
    fn texture_ref(&self, key: &str, t: &file::TextureRef) -> Result<Texture, SceneError> {
        let filter = self.filter(key, t.filter.as_deref())?;
        let wrap = self.wrap(key, t.wrap.as_ref())?;
        let uv_set = self.uv_set(key, t.uv_set)?;
        Ok(Texture { filter, wrap, uv_set, ..self.texture(&format!("{key}.texture"), &t.texture)? })
    }

    /// The set of texture coordinates named at `key`.uv_set: 0 (the default) or 1.
    fn uv_set(&self, key: &str, set: Option<u32>) -> Result<u32, SceneError> {
        match set {
            None => Ok(0),
            Some(k @ (0 | 1)) => Ok(k),
            Some(k) => Err(self.invalid(&format!("{key}.uv_set"), &format!("{k} is not 0 or 1"))),
        }
    }

    /// The wrap modes named at `key`.wrap: one for both axes or one each for u and v.
    fn wrap(&self, key: &str, input: Option<&file::WrapInput>) -> Result<[Wrap; 2], SceneError> {
        let names = match input {
            None => return Ok([Wrap::Repeat; 2]),
            Some(file::WrapInput::Both(n)) => [n, n],
            Some(file::WrapInput::Each([u, v])) => [u, v],
        };
        let mode =
            |n: &String| Wrap::from_name(n).ok_or_else(|| self.invalid(&format!("{key}.wrap"), &format!("\"{n}\" is not \"repeat\", \"clamp\" or \"mirror\"")));
        Ok([mode(names[0])?, mode(names[1])?])
    }

    /// The pixel filter of `[film]`: its own where it names one, else the imported one.
    fn pixel_filter(&self, film: &file::FilmFile, imported: Option<PixelFilter>) -> Result<PixelFilter, SceneError> {
        let filter = match film.filter.as_deref() {
            None => imported.unwrap_or_default(),
            Some("box") => PixelFilter::Box,
            Some("gaussian") => PixelFilter::gaussian(film.filter_stddev).map_err(|e| self.invalid("film.filter_stddev", &e))?,
            Some("tent") => PixelFilter::tent(film.filter_radius).map_err(|e| self.invalid("film.filter_radius", &e))?,
            Some(other) => return Err(self.invalid("film.filter", &format!("\"{other}\" is not \"box\", \"gaussian\" or \"tent\""))),
        };
        let given = |key: &str, v: Option<f32>, applies: bool| match (v, applies) {
            (Some(_), false) => Err(self.invalid(
                key,
                &format!("applies to a {} filter only, not to \"{}\"", if key == "film.filter_stddev" { "gaussian" } else { "tent" }, filter.name()),
            )),
            _ => Ok(()),
        };
        let named = film.filter.is_some();
        given("film.filter_stddev", film.filter_stddev, named && matches!(filter, PixelFilter::Gaussian { .. }))?;
        given("film.filter_radius", film.filter_radius, named && matches!(filter, PixelFilter::Tent { .. }))?;
        Ok(filter)
    }

    /// The filter named at `key`.filter.
    fn filter(&self, key: &str, name: Option<&str>) -> Result<Filter, SceneError> {
        match name {
            None | Some("bilinear") => Ok(Filter::Bilinear),
            Some("nearest") => Ok(Filter::Nearest),
            Some(other) => Err(self.invalid(&format!("{key}.filter"), &format!("\"{other}\" is not \"bilinear\" or \"nearest\""))),
        }
    }

    fn color_value(&self, key: &str, input: ColorInput) -> Result<ColorValue, SceneError> {
        Ok(match input {
            ColorInput::Constant(c) => ColorValue::Constant(self.color(key, c)?),
            ColorInput::Texture(t) => {
                let tex = self.texture_ref(key, &t)?;
                self.texels_in(&format!("{key}.texture"), &tex, 3, 0.0, f32::INFINITY)?;
                ColorValue::Texture(tex)
            }
        })
    }

    /// Checks the first `channels` channels of every texel against [lo, hi]: the rule a
    /// constant of the same property obeys.
    fn texels_in(&self, key: &str, t: &Texture, channels: usize, lo: f32, hi: f32) -> Result<(), SceneError> {
        self.texels_in_or(key, t, channels, lo, hi, "")
    }

    /// [`Self::texels_in`] with `note` after the message.
    fn texels_in_or(&self, key: &str, t: &Texture, channels: usize, lo: f32, hi: f32, note: &str) -> Result<(), SceneError> {
        match t.image.find_outside(channels, lo, hi) {
            Some((x, y, v)) => Err(self.out_of_range(key, format!("{} has {v} at pixel ({x}, {y}), outside [{lo}, {hi}]{note}", t.path.display()))),
            None => Ok(()),
        }
    }

    fn scalar_value(&self, key: &str, input: ScalarInput) -> Result<ScalarValue, SceneError> {
        Ok(match input {
            ScalarInput::Constant(v) => {
                self.finite(key, &[v])?;
                ScalarValue::Constant(self.in_range(key, v, 0.0, 1.0)?)
            }
            ScalarInput::Texture(t) => {
                let tex = self.texture_ref(key, &t)?;
                self.texels_in(&format!("{key}.texture"), &tex, 1, 0.0, 1.0)?;
                ScalarValue::Texture(tex)
            }
        })
    }

    /// The scene of `raw` on top of what `imported` brought (see the module documentation
    /// for the override rules), with `options` over both.
    pub fn build(self, raw: SceneFile, imported: Option<Imported>, options: &LoadOptions) -> Result<Scene, SceneError> {
        let imported = imported.unwrap_or_default();
        let film = Film {
            width: options.film.map(|f| f.width).or(raw.film.width).or(imported.film.map(|f| f.width)).unwrap_or(256),
            height: options.film.map(|f| f.height).or(raw.film.height).or(imported.film.map(|f| f.height)).unwrap_or(256),
        };
        self.in_range("film.width", film.width, 1, MAX_IMAGE_SIDE)?;
        self.in_range("film.height", film.height, 1, MAX_IMAGE_SIDE)?;
        let pixel_filter = self.pixel_filter(&raw.film, imported.pixel_filter)?;
        let integrator = Integrator {
            max_depth: options.max_depth.or(raw.integrator.max_depth).or(imported.max_depth).unwrap_or(6),
            rr_depth: raw.integrator.rr_depth.or(imported.rr_depth).unwrap_or(5),
            hide_emitters: raw.integrator.hide_emitters.or(imported.hide_emitters).unwrap_or(false),
        };
        self.in_range("integrator.max_depth", integrator.max_depth, 1, MAX_DEPTH)?;
        self.in_range("integrator.rr_depth", integrator.rr_depth, 1, MAX_DEPTH)?;
        let mut sensors = imported.sensors;
        for (i, s) in raw.sensors.into_iter().enumerate() {
            sensors.push(self.sensor(&format!("sensors[{i}]"), s, film)?);
        }
        let mut materials = imported.materials;
        materials.extend(self.materials(raw.materials)?);
        let mut meshes = imported.meshes;
        meshes.extend(self.meshes(raw.meshes, &materials)?);
        let mut notes = Vec::new();
        let gltf = matches!(imported.source, Source::Gltf(_));
        if sensors.is_empty() {
            if !gltf || meshes.is_empty() {
                let what = if imported.source == Source::Toml { "" } else { " (the imported file has no camera)" };
                return Err(self.invalid("sensors", &format!("at least one sensor is needed{what}")));
            }
            let (sensor, note) = framing_sensor(&meshes, film).map_err(|e| self.invalid("sensors", &e))?;
            sensors.push(sensor);
            notes.push(format!("{}: {note}", self.scene.display()));
        }
        let mut lights = imported.lights;
        lights.extend(self.lights(raw.lights)?);
        for (kind, names) in [
            ("materials", materials.iter().map(|m| &m.name).collect::<Vec<_>>()),
            ("meshes", meshes.iter().map(|m| &m.name).collect()),
            ("lights", lights.iter().map(|l| &l.name).collect()),
        ] {
            let mut seen = HashSet::new();
            for (i, name) in names.into_iter().enumerate() {
                self.check_name(&format!("{kind}[{i}].name"), name, &mut seen)?;
            }
        }
        for mesh in &meshes {
            if mesh.material >= materials.len() {
                return Err(self.invalid(
                    &format!("meshes.{}.material", mesh.name),
                    &format!("material {} does not exist (the scene has {})", mesh.material, materials.len()),
                ));
            }
            self.check_mesh(mesh)?;
        }
        for light in &lights {
            self.check_light(light)?;
        }
        for material in &materials {
            self.check_material(material)?;
        }
        let own_environment = raw.environment.is_some() || imported.environment.is_some();
        let black = || Environment { value: ColorValue::Constant([0.0; 3]), scale: 1.0 };
        let environment = if raw.environment.is_some() { self.environment(raw.environment)? } else { imported.environment.unwrap_or_else(black) };
        self.check_environment(&environment)?;
        let media = self.all_media(imported.media, raw.media)?;
        let parts = Parts { materials: &materials, meshes: &meshes, lights: &lights, environment: &environment, media: &media };
        let optimise = self.optimise(raw.optimise.unwrap_or_default(), &parts)?;
        self.check_texture_coordinates(&meshes, &materials, &optimise)?;
        self.check_majorants(&media, &optimise)?;
        let mut scene = Scene {
            path: self.scene,
            source: imported.source,
            film,
            pixel_filter,
            integrator,
            sensors,
            materials,
            meshes,
            lights,
            environment,
            media,
            optimise,
            warnings: imported.warnings,
            content_hash: 0,
        };
        if gltf && !own_environment && !scene.has_light() {
            // A model without lights, as viewers show it: under a white sky.
            scene.environment = Environment { value: ColorValue::Constant([1.0; 3]), scale: 1.0 };
            notes.push(format!(
                "{}: no light: the model is lit by a uniform environment of radiance 1 (give lights or an [environment] to change it)",
                scene.path.display()
            ));
        }
        scene.warnings.extend(notes);
        scene.content_hash = super::hash::content_hash(&scene);
        Ok(scene)
    }

    /// The imported file's media and the scene's own: at most one in all.
    fn all_media(&self, imported: Vec<Medium>, raw: Vec<file::MediumFile>) -> Result<Vec<Medium>, SceneError> {
        let mut media = imported;
        media.extend(self.media(raw)?);
        if media.len() > 1 {
            return Err(self.invalid("media", &format!("{} media, the imported file's and the scene's: a scene holds at most one", media.len())));
        }
        Ok(media)
    }

    /// A fixed majorant bounds the density wherever the optimisation may take it: at least
    /// the range top of the density's parameter.
    fn check_majorants(&self, media: &[Medium], optimise: &Optimise) -> Result<(), SceneError> {
        for (i, m) in media.iter().enumerate() {
            let param = optimise.params.iter().find(|p| p.target == ParamTarget::MediumDensity { medium: i });
            if let (Some(b), Some(p)) = (m.majorant, param) {
                if p.range[1] > b {
                    let message = format!("{b} is below the range top {} of {}", p.range[1], p.name);
                    return Err(self.out_of_range(&format!("media.{}.majorant", m.name), message));
                }
            }
        }
        Ok(())
    }

    /// A mesh whose material is textured (or optimised as a texture), or whose emission is,
    /// has texture coordinates.
    fn check_texture_coordinates(&self, meshes: &[Mesh], materials: &[Material], optimise: &Optimise) -> Result<(), SceneError> {
        for (i, mesh) in meshes.iter().enumerate() {
            // A texture that reads the second set needs a mesh that has one.
            let second = materials[mesh.material].textures().chain(mesh.emission.texture()).find(|t| t.uv_set == 1);
            if let (Some(t), true) = (second, mesh.uvs1.is_empty()) {
                let message = format!("{} reads texture coordinate set 1 (uv_set = 1), which {} does not have", t.path.display(), mesh.path.display());
                return Err(self.invalid(&format!("meshes.{}", mesh.name), &message));
            }
            if !mesh.uvs.is_empty() {
                continue;
            }
            let material = &materials[mesh.material];
            let textured = material.is_textured() || optimise.params.iter().any(|p| !p.shape.is_constant() && p.target.material() == Some(mesh.material));
            let emission_textured = matches!(mesh.emission, ColorValue::Texture(_))
                || optimise.params.iter().any(|p| !p.shape.is_constant() && p.target == ParamTarget::Emission { mesh: i });
            let what = if textured {
                format!("material \"{}\" is textured", material.name)
            } else if emission_textured {
                "its emission is textured".to_string()
            } else {
                continue;
            };
            return Err(self.invalid(&format!("meshes.{}", mesh.name), &format!("{what} but {} has no texture coordinates", mesh.path.display())));
        }
        Ok(())
    }

    /// Checks what every loader must guarantee of a mesh (the module's invariants).
    fn check_mesh(&self, m: &Mesh) -> Result<(), SceneError> {
        let key = format!("meshes.{}", m.name);
        let n = m.positions.len();
        let problem = if m.indices.is_empty() {
            Some("has no triangles".to_string())
        } else if m.positions.iter().flatten().chain(m.normals.iter().flatten()).chain(m.uvs.iter().chain(&m.uvs1).flatten()).any(|v| !v.is_finite()) {
            Some("has a non-finite vertex value".into())
        } else if let Some(v) = m.positions.iter().flatten().find(|v| v.abs() > MAX_COORDINATE) {
            Some(format!("has a vertex coordinate of {v}, beyond the ±{MAX_COORDINATE:e} the BVH is built for"))
        } else if m.indices.iter().flatten().any(|&i| i as usize >= n) {
            Some("has a vertex index out of bounds".into())
        } else if [m.normals.len(), m.uvs.len(), m.uvs1.len()].iter().any(|&k| k != 0 && k != n) {
            Some("has normals or texture coordinates for some vertices only".into())
        } else {
            None
        };
        if let Some(p) = problem {
            return Err(self.invalid(&key, &format!("{} {p}", m.path.display())));
        }
        // Imported emission obeys the TOML's rule too: finite and not negative.
        let key = format!("{key}.emission");
        match &m.emission {
            ColorValue::Constant(c) => self.color(&key, *c).map(|_| ()),
            ColorValue::Texture(t) => self.texels_in(&key, t, 3, 0.0, f32::INFINITY),
        }
    }

    /// Checks what every loader must guarantee of a material's values: a base colour that is
    /// a finite, non-negative colour, and a roughness and metallic in [0, 1] (constants or
    /// every texel), as the TOML's own rules say.
    fn check_material(&self, m: &Material) -> Result<(), SceneError> {
        let key = format!("materials.{}", m.name);
        match &m.base_color {
            ColorValue::Constant(c) => self.color(&format!("{key}.base_color"), *c).map(|_| ())?,
            ColorValue::Texture(t) => self.texels_in(&format!("{key}.base_color"), t, 3, 0.0, f32::INFINITY)?,
        }
        for (name, v) in [("roughness", &m.roughness), ("metallic", &m.metallic)] {
            let k = format!("{key}.{name}");
            match v {
                ScalarValue::Constant(x) => {
                    self.finite(&k, &[*x])?;
                    self.in_range(&k, *x, 0.0, 1.0)?;
                }
                ScalarValue::Texture(t) => self.texels_in(&k, t, 1, 0.0, 1.0)?,
            }
        }
        Ok(())
    }

    fn check_light(&self, l: &Light) -> Result<(), SceneError> {
        let key = format!("lights.{}", l.name);
        self.finite(&key, &[l.position.to_array(), l.direction.to_array(), l.color, [l.intensity, 0.0, 0.0]].concat())?;
        self.color(&format!("{key}.color"), l.color)?;
        if l.intensity < 0.0 {
            return Err(self.out_of_range(&format!("{key}.intensity"), format!("{} is negative", l.intensity)));
        }
        // What the kernels multiply must stay finite in single precision.
        if l.color.iter().any(|c| !(c * l.intensity).is_finite()) {
            return Err(self.out_of_range(&key, format!("its colour {:?} times its intensity {} overflows single precision", l.color, l.intensity)));
        }
        if l.kind != LightKind::Point && (l.direction.length() - 1.0).abs() > 1e-3 {
            return Err(self.invalid(&format!("{key}.direction"), "the direction is zero"));
        }
        if let LightKind::Spot { inner, outer, .. } = l.kind {
            if !(0.0 <= inner && inner <= outer && outer > 0.0 && outer <= std::f32::consts::FRAC_PI_2 + 1e-6) {
                return Err(self.out_of_range(
                    &key,
                    format!("cone angles {}° and {}° are not 0 <= inner <= outer <= 90, outer > 0", inner.to_degrees(), outer.to_degrees()),
                ));
            }
        }
        Ok(())
    }

    fn lights(&self, raw: Vec<file::LightFile>) -> Result<Vec<Light>, SceneError> {
        raw.into_iter()
            .map(|l| {
                let key = format!("lights.{}", l.name);
                let needs = |what: &str, v: Option<[f32; 3]>| -> Result<Vec3, SceneError> {
                    let v = v.ok_or_else(|| self.invalid(&key, &format!("a {} light needs `{what}`", l.kind.as_str())))?;
                    self.finite(&format!("{key}.{what}"), &v)?;
                    Ok(Vec3::from(v))
                };
                let direction = |v| -> Result<Vec3, SceneError> {
                    needs("direction", v)?.try_normalize().ok_or_else(|| self.invalid(&format!("{key}.direction"), "the direction is zero"))
                };
                let (kind, position, dir) = match l.kind {
                    file::LightType::Point => (LightKind::Point, needs("position", l.position)?, Vec3::NEG_Y),
                    file::LightType::Directional => (LightKind::Directional, Vec3::ZERO, direction(l.direction)?),
                    file::LightType::Spot => {
                        let outer = l.outer_angle.unwrap_or(45.0);
                        let inner = l.inner_angle.unwrap_or(0.0);
                        self.finite(&key, &[inner, outer])?;
                        let falloff = match l.falloff {
                            file::FalloffType::Smooth => SpotFalloff::Smooth,
                            file::FalloffType::Linear => SpotFalloff::Linear,
                        };
                        (
                            LightKind::Spot { inner: inner.to_radians(), outer: outer.to_radians(), falloff },
                            needs("position", l.position)?,
                            direction(l.direction)?,
                        )
                    }
                };
                if l.kind != file::LightType::Spot && (l.inner_angle.is_some() || l.outer_angle.is_some()) {
                    return Err(self.invalid(&key, "only spot lights have cone angles"));
                }
                Ok(Light { name: l.name, kind, position, direction: dir, color: l.color, intensity: l.intensity })
            })
            .collect()
    }

    pub fn sensor(&self, key: &str, s: file::SensorFile, film: Film) -> Result<Sensor, SceneError> {
        for (name, v) in [("origin", s.origin), ("target", s.target), ("up", s.up)] {
            self.finite(&format!("{key}.{name}"), &v)?;
        }
        let (fov_y, ortho_height) = match (s.fov_y, s.ortho_height) {
            (Some(_), Some(_)) => return Err(self.invalid(key, "gives both fov_y (a pinhole camera) and ortho_height (an orthographic one)")),
            (None, None) => return Err(self.invalid(&format!("{key}.fov_y"), "is missing (or give ortho_height for an orthographic camera)")),
            (Some(fov_y), None) => {
                self.finite(&format!("{key}.fov_y"), &[fov_y])?;
                if !(fov_y > 0.0 && fov_y < 180.0) {
                    return Err(self.out_of_range(&format!("{key}.fov_y"), format!("{fov_y} is outside (0, 180) degrees")));
                }
                (fov_y, None)
            }
            (None, Some(height)) => {
                self.finite(&format!("{key}.ortho_height"), &[height])?;
                if height <= 0.0 {
                    return Err(self.out_of_range(&format!("{key}.ortho_height"), format!("{height} is not positive")));
                }
                (0.0, Some(height))
            }
        };
        let mut sensor = Sensor::looking_at(Vec3::from(s.origin), Vec3::from(s.target), Vec3::from(s.up), fov_y).map_err(|e| {
            let k = if e.starts_with("up") { format!("{key}.up") } else { key.to_string() };
            self.invalid(&k, e)
        })?;
        sensor.ortho_height = ortho_height;
        sensor.lens = match (s.aperture_radius, s.focus_distance) {
            (None, None) => None,
            (Some(_), None) => return Err(self.invalid(&format!("{key}.focus_distance"), "is missing (a thin lens needs aperture_radius and focus_distance)")),
            (None, Some(_)) => return Err(self.invalid(&format!("{key}.aperture_radius"), "is missing (a thin lens needs aperture_radius and focus_distance)")),
            (Some(_), Some(_)) if ortho_height.is_some() => return Err(self.invalid(key, "an orthographic camera has no thin lens")),
            (Some(radius), Some(focus)) => {
                for (name, v) in [("aperture_radius", radius), ("focus_distance", focus)] {
                    self.finite(&format!("{key}.{name}"), &[v])?;
                    if v <= 0.0 {
                        return Err(self.out_of_range(&format!("{key}.{name}"), format!("{v} is not positive")));
                    }
                }
                Some(ThinLens { aperture_radius: radius, focus_distance: focus })
            }
        };
        let target_image = match s.target_image {
            Some(rel) => {
                let k = format!("{key}.target_image");
                let t = self.texture(&k, &rel)?;
                if (t.image.width, t.image.height) != (film.width, film.height) {
                    return Err(self
                        .invalid(&k, &format!("{} is {}x{} but the film is {}x{}", t.path.display(), t.image.width, t.image.height, film.width, film.height)));
                }
                Some(t)
            }
            None => None,
        };
        sensor.target_image = target_image;
        Ok(sensor)
    }

    pub fn check_name(&self, key: &str, name: &str, seen: &mut HashSet<String>) -> Result<(), SceneError> {
        if name.is_empty() {
            return Err(self.invalid(key, "name is empty"));
        }
        if !seen.insert(name.to_string()) {
            return Err(SceneError::Duplicate { scene: self.scene.clone(), key: key.into(), name: name.into() });
        }
        Ok(())
    }

    /// Not split: one arm per material type, each checking that type's keys in the
    /// order the format documents them; the checks share the loop's name and key bookkeeping.
    fn materials(&self, raw: Vec<file::MaterialFile>) -> Result<Vec<Material>, SceneError> {
        let mut seen = HashSet::new();
        let mut out = Vec::with_capacity(raw.len());
        for (i, m) in raw.into_iter().enumerate() {
            self.check_name(&format!("materials[{i}].name"), &m.name, &mut seen)?;
            let key = format!("materials.{}", m.name);
            let kind = m.kind;
            // A key this type does not take (MaterialKind::accepts, the list the format documents).
            let refuses = |what: &str, given: bool| given && !kind.accepts(what);
            let base_color = match (m.base_color, m.kind) {
                (Some(c), _) => self.color_value(&format!("{key}.base_color"), c)?,
                (None, kind) if kind.is_dielectric() || kind == MaterialKind::Conductor => ColorValue::Constant([1.0; 3]),
                (None, _) => return Err(self.invalid(&format!("{key}.base_color"), "is missing")),
            };
            if refuses("ior", m.ior.is_some()) {
                return Err(self.invalid(&format!("{key}.ior"), "is a dielectric's, a plastic's or a principled material's (type = \"dielectric\", \"thin_dielectric\", \"rough_dielectric\", \"plastic\" or \"principled\")"));
            }
            if refuses("nonlinear", m.nonlinear.is_some()) {
                return Err(self.invalid(&format!("{key}.nonlinear"), "is a plastic's (type = \"plastic\")"));
            }
            if refuses("specular", m.specular.is_some()) {
                return Err(self.invalid(&format!("{key}.specular"), "is a plastic's (type = \"plastic\")"));
            }
            if let Some(s) = m.specular {
                self.finite(&format!("{key}.specular"), &s)?;
                if let Some(v) = s.iter().find(|v| !(0.0..=1.0).contains(*v)) {
                    return Err(self.out_of_range(&format!("{key}.specular"), format!("{v} is outside [0, 1]")));
                }
            }
            if refuses("layered", m.layered.is_some()) {
                return Err(self.invalid(&format!("{key}.layered"), "is a plastic's (type = \"plastic\")"));
            }
            if m.layered == Some(false) && m.nonlinear == Some(true) {
                return Err(self.invalid(&format!("{key}.nonlinear"), "needs a layered coating (layered = false has no internal reflections to scale)"));
            }
            let (roughness, metallic) = match m.kind {
                MaterialKind::Principled => (
                    self.scalar_value(&format!("{key}.roughness"), m.roughness.unwrap_or(ScalarInput::Constant(0.5)))?,
                    self.scalar_value(&format!("{key}.metallic"), m.metallic.unwrap_or(ScalarInput::Constant(0.0)))?,
                ),
                MaterialKind::Diffuse => {
                    if refuses("roughness", m.roughness.is_some()) || refuses("metallic", m.metallic.is_some()) {
                        return Err(self.invalid(&key, "a diffuse material takes no roughness or metallic"));
                    }
                    (ScalarValue::Constant(1.0), ScalarValue::Constant(0.0))
                }
                MaterialKind::Dielectric | MaterialKind::ThinDielectric | MaterialKind::RoughDielectric => {
                    let rough = m.kind == MaterialKind::RoughDielectric;
                    if refuses("metallic", m.metallic.is_some()) || refuses("roughness", m.roughness.is_some()) {
                        return Err(self.invalid(
                            &key,
                            if rough {
                                "a rough dielectric takes no metallic"
                            } else {
                                "a dielectric is smooth and takes no roughness or metallic (type = \"rough_dielectric\" has a roughness)"
                            },
                        ));
                    }
                    for (what, given) in
                        [("one_sided", m.one_sided), ("normal_map", m.normal_map.is_some()), ("bump_map", m.bump_map.is_some()), ("alpha", m.alpha.is_some())]
                    {
                        if refuses(what, given) {
                            return Err(self.invalid(&format!("{key}.{what}"), "is not supported on a dielectric"));
                        }
                    }
                    let roughness = match m.roughness {
                        Some(r) => self.scalar_value(&format!("{key}.roughness"), r)?,
                        None if rough => ScalarValue::Constant(DEFAULT_MICROFACET_ROUGHNESS),
                        None => ScalarValue::Constant(0.0),
                    };
                    (roughness, ScalarValue::Constant(0.0))
                }
                MaterialKind::Conductor => {
                    if refuses("metallic", m.metallic.is_some()) {
                        return Err(self.invalid(&format!("{key}.metallic"), "is not a conductor's (its reflectance comes from eta and k)"));
                    }
                    let roughness = m.roughness.unwrap_or(ScalarInput::Constant(DEFAULT_MICROFACET_ROUGHNESS));
                    (self.scalar_value(&format!("{key}.roughness"), roughness)?, ScalarValue::Constant(0.0))
                }
                MaterialKind::Plastic => {
                    if refuses("metallic", m.metallic.is_some()) {
                        return Err(self.invalid(&format!("{key}.metallic"), "is not a plastic's (its base is diffuse, its coating a dielectric)"));
                    }
                    let roughness = match m.roughness {
                        Some(ScalarInput::Texture(_)) => {
                            return Err(self.invalid(
                                &format!("{key}.roughness"),
                                "must be a number for a plastic (its coating's transmittance is tabulated for one roughness)",
                            ));
                        }
                        r => r.unwrap_or(ScalarInput::Constant(DEFAULT_MICROFACET_ROUGHNESS)),
                    };
                    (self.scalar_value(&format!("{key}.roughness"), roughness)?, ScalarValue::Constant(0.0))
                }
            };
            let absorption = match m.absorption {
                None => [0.0; 3],
                Some(_) if refuses("absorption", true) => {
                    return Err(
                        self.invalid(&format!("{key}.absorption"), "is a refracting dielectric's interior (type = \"dielectric\" or \"rough_dielectric\")")
                    );
                }
                Some(a) => {
                    self.finite(&format!("{key}.absorption"), &a)?;
                    if let Some(v) = a.iter().find(|v| **v < 0.0) {
                        return Err(self.out_of_range(&format!("{key}.absorption"), format!("{v} is negative")));
                    }
                    a
                }
            };
            let ior = match m.ior {
                None => DEFAULT_IOR,
                Some(ior) => {
                    self.finite(&format!("{key}.ior"), &[ior])?;
                    self.in_range(&format!("{key}.ior"), ior, MIN_IOR, MAX_IOR)?
                }
            };
            let distribution = match m.distribution.as_deref() {
                None => Distribution::Ggx,
                Some(_) if refuses("distribution", true) => {
                    return Err(self.invalid(
                        &format!("{key}.distribution"),
                        "is a rough dielectric's, a conductor's or a plastic's (type = \"rough_dielectric\", \"conductor\" or \"plastic\")",
                    ));
                }
                Some("ggx") => Distribution::Ggx,
                Some("beckmann") => Distribution::Beckmann,
                Some(other) => return Err(self.invalid(&format!("{key}.distribution"), &format!("\"{other}\" is not \"ggx\" or \"beckmann\""))),
            };
            let [eta, k] = self.complex_ior(&key, m.kind, m.metal.as_deref(), m.eta, m.k)?;
            if m.kind == MaterialKind::RoughDielectric && ior == 1.0 {
                return Err(self.invalid(&format!("{key}.ior"), "is 1: a rough dielectric needs two different media (its refraction would be a delta)"));
            }
            if m.kind == MaterialKind::Plastic && ior == 1.0 {
                return Err(self.invalid(&format!("{key}.ior"), "is 1: a plastic's coating needs two different media (it would reflect nothing)"));
            }
            let perturbation = match (m.normal_map, m.bump_map) {
                (None, None) => None,
                (Some(_), Some(_)) => return Err(self.invalid(&format!("{key}.bump_map"), "cannot be combined with a normal_map (one perturbs the normal)")),
                (Some(n), None) => {
                    let k = format!("{key}.normal_map.texture");
                    let filter = self.filter(&format!("{key}.normal_map"), n.filter.as_deref())?;
                    let wrap = self.wrap(&format!("{key}.normal_map"), n.wrap.as_ref())?;
                    let uv_set = self.uv_set(&format!("{key}.normal_map"), n.uv_set)?;
                    let texture = Texture { filter, wrap, uv_set, ..self.texture(&k, &n.texture)? };
                    self.texels_in_or(&k, &texture, 3, 0.0, 1.0, " (a normal map stores each normal n as (n + 1) / 2)")?;
                    let scale = n.scale.unwrap_or(1.0);
                    self.finite(&format!("{key}.normal_map.scale"), &[scale])?;
                    let bitangent = match n.bitangent.as_deref() {
                        None | Some("uv") => Bitangent::Uv,
                        Some("cross") => Bitangent::Cross,
                        Some(other) => return Err(self.invalid(&format!("{key}.normal_map.bitangent"), &format!("\"{other}\" is not \"uv\" or \"cross\""))),
                    };
                    Some(Perturbation::Normal(NormalMap { texture, scale, bitangent }))
                }
                (None, Some(b)) => {
                    let k = format!("{key}.bump_map.texture");
                    let filter = self.filter(&format!("{key}.bump_map"), b.filter.as_deref())?;
                    let wrap = self.wrap(&format!("{key}.bump_map"), b.wrap.as_ref())?;
                    let uv_set = self.uv_set(&format!("{key}.bump_map"), b.uv_set)?;
                    let texture = Texture { filter, wrap, uv_set, ..self.texture(&k, &b.texture)? };
                    let scale = b.scale.unwrap_or(1.0);
                    self.finite(&format!("{key}.bump_map.scale"), &[scale])?;
                    Some(Perturbation::Bump(BumpMap { texture, scale }))
                }
            };
            let alpha = match m.alpha {
                None => {
                    for (what, given) in [("alpha_mode", m.alpha_mode.is_some()), ("alpha_cutoff", m.alpha_cutoff.is_some())] {
                        if given {
                            return Err(self.invalid(&format!("{key}.{what}"), "needs an alpha (alpha = 0.4 or { texture = \"mask.exr\" })"));
                        }
                    }
                    None
                }
                Some(value) => {
                    let value = self.scalar_value(&format!("{key}.alpha"), value)?;
                    let k = format!("{key}.alpha_cutoff");
                    let mode = match (m.alpha_mode.as_deref(), m.alpha_cutoff) {
                        (None | Some("mask"), cutoff) => {
                            let cutoff = cutoff.unwrap_or(0.5);
                            self.finite(&k, &[cutoff])?;
                            AlphaMode::Mask { cutoff: self.in_range(&k, cutoff, 0.0, 1.0)? }
                        }
                        (Some("blend"), None) => AlphaMode::Blend,
                        (Some("blend"), Some(_)) => {
                            return Err(self.invalid(&k, "has no meaning with alpha_mode = \"blend\" (the surface is there with probability alpha)"))
                        }
                        (Some(other), _) => return Err(self.invalid(&format!("{key}.alpha_mode"), &format!("\"{other}\" is not \"mask\" or \"blend\""))),
                    };
                    Some(AlphaMask { value, mode })
                }
            };
            out.push(Material {
                name: m.name,
                kind: m.kind,
                base_color,
                roughness,
                metallic,
                one_sided: m.one_sided,
                perturbation,
                alpha,
                ior,
                absorption,
                distribution,
                eta,
                k,
                nonlinear: m.nonlinear.unwrap_or(false),
                layered: m.layered.unwrap_or(true),
                specular: m.specular.unwrap_or([1.0; 3]),
            });
        }
        Ok(out)
    }

    /// A conductor's complex index of refraction: a named metal's ([`super::model::METALS`];
    /// "none", a perfect mirror, by default), or `eta` and `k` given together, each finite and
    /// at least 0. Zero for the other kinds, which may give none of the three.
    fn complex_ior(&self, key: &str, kind: MaterialKind, metal: Option<&str>, eta: Option<[f32; 3]>, k: Option<[f32; 3]>) -> Result<[[f32; 3]; 2], SceneError> {
        for (what, given) in [("metal", metal.is_some()), ("eta", eta.is_some()), ("k", k.is_some())] {
            if given && !kind.accepts(what) {
                return Err(self.invalid(&format!("{key}.{what}"), "is a conductor's (type = \"conductor\")"));
            }
        }
        if kind != MaterialKind::Conductor {
            return Ok([[0.0; 3]; 2]);
        }
        match (metal, eta, k) {
            (Some(_), Some(_), _) | (Some(_), _, Some(_)) => {
                Err(self.invalid(&format!("{key}.metal"), "names a metal's eta and k: give either `metal` or `eta` and `k`"))
            }
            (_, Some(_), None) => Err(self.invalid(&format!("{key}.k"), "is missing (`eta` and `k` go together)")),
            (_, None, Some(_)) => Err(self.invalid(&format!("{key}.eta"), "is missing (`eta` and `k` go together)")),
            (_, Some(eta), Some(k)) => {
                for (what, v) in [("eta", eta), ("k", k)] {
                    self.finite(&format!("{key}.{what}"), &v)?;
                    if let Some(x) = v.iter().find(|x| **x < 0.0) {
                        return Err(self.out_of_range(&format!("{key}.{what}"), format!("{x} is negative")));
                    }
                }
                Ok([eta, k])
            }
            (name, None, None) => {
                let name = name.unwrap_or("none");
                super::model::metal(name).ok_or_else(|| {
                    let known: Vec<&str> = super::model::METALS.iter().map(|(n, _, _)| *n).collect();
                    self.invalid(&format!("{key}.metal"), &format!("\"{name}\" is not one of {}", known.join(", ")))
                })
            }
        }
    }

    fn meshes(&self, raw: Vec<file::MeshFile>, materials: &[Material]) -> Result<Vec<Mesh>, SceneError> {
        let mut seen = HashSet::new();
        let mut out = Vec::with_capacity(raw.len());
        for (i, m) in raw.into_iter().enumerate() {
            let name = m.name.unwrap_or_else(|| Path::new(&m.file).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default());
            self.check_name(&format!("meshes[{i}] (\"{name}\")"), &name, &mut seen)?;
            let key = format!("meshes.{name}");
            let material = materials.iter().position(|mat| mat.name == m.material).ok_or_else(|| SceneError::Undefined {
                scene: self.scene.clone(),
                key: format!("{key}.material"),
                kind: "material",
                name: m.material.clone(),
                known: super::error::known_names(materials.iter().map(|m| m.name.as_str())),
            })?;
            let emission = self.color_value(&format!("{key}.emission"), m.emission)?;
            let (path, bytes) = self.read(&format!("{key}.file"), &m.file)?;
            let data = obj::load(&path, &bytes)?;
            for (what, values) in [("positions", data.positions.as_flattened()), ("normals", data.normals.as_flattened())] {
                if values.iter().any(|v| !v.is_finite()) {
                    return Err(SceneError::Obj { path, line: 0, message: format!("non-finite {what}") });
                }
            }
            check_triangles(&out, data.indices.len()).map_err(|e| self.invalid(&format!("{key}.file"), &format!("{}: {e}", path.display())))?;
            let mut mesh = Mesh {
                name,
                path,
                positions: data.positions,
                normals: data.normals,
                uvs: data.uvs,
                uvs1: Vec::new(),
                indices: data.indices,
                material,
                emission,
                two_sided_emission: m.two_sided,
                sphere: None,
            };
            if let Some(rel) = &m.uv1 {
                let corners = self.corner_uvs(&format!("{key}.uv1"), rel, mesh.indices.len())?;
                mesh.set_corner_uvs1(&corners);
            }
            out.push(mesh);
        }
        Ok(out)
    }

    /// The per-corner texture coordinates in the `.npy` file `rel` names at `key`: float32
    /// of shape (triangles, 3, 2), finite.
    fn corner_uvs(&self, key: &str, rel: &str, triangles: usize) -> Result<Vec<[[f32; 2]; 3]>, SceneError> {
        let (path, bytes) = self.read(key, rel)?;
        let array = crate::npy::parse_bytes(&bytes, &path).map_err(|e| self.invalid(key, &e.to_string()))?;
        if array.shape != [triangles, 3, 2] {
            let message = format!("{} has shape {:?}, not [{triangles}, 3, 2] (the mesh's triangles, their corners, u and v)", path.display(), array.shape);
            return Err(self.invalid(key, &message));
        }
        if let Some(v) = array.data.iter().find(|v| !v.is_finite()) {
            return Err(self.invalid(key, &format!("{} holds {v}", path.display())));
        }
        Ok(array.data.chunks_exact(6).map(|c| [[c[0], c[1]], [c[2], c[3]], [c[4], c[5]]]).collect())
    }

    /// An imported environment obeys the TOML's rule too: finite, non-negative radiance.
    fn check_environment(&self, environment: &Environment) -> Result<(), SceneError> {
        match &environment.value {
            ColorValue::Constant(c) => self.color("environment", *c).map(|_| ())?,
            ColorValue::Texture(t) => self.texels_in("environment", t, 3, 0.0, f32::INFINITY)?,
        }
        if !(environment.scale.is_finite() && environment.scale >= 0.0) {
            return Err(self.out_of_range("environment.scale", format!("{} is not finite and non-negative", environment.scale)));
        }
        Ok(())
    }

    fn environment(&self, raw: Option<file::EnvironmentFile>) -> Result<Environment, SceneError> {
        let Some(env) = raw else {
            return Ok(Environment { value: ColorValue::Constant([0.0; 3]), scale: 1.0 });
        };
        self.finite("environment.scale", &[env.scale])?;
        if env.scale < 0.0 {
            return Err(self.out_of_range("environment.scale", format!("{} is negative", env.scale)));
        }
        let value = match (env.constant, env.file) {
            (Some(c), None) => ColorValue::Constant(self.color("environment.constant", c)?),
            (None, Some(rel)) => {
                let t = self.texture("environment.file", &rel)?;
                self.texels_in("environment.file", &t, 3, 0.0, f32::INFINITY)?;
                ColorValue::Texture(t)
            }
            _ => return Err(self.invalid("environment", "give exactly one of `constant` and `file`")),
        };
        Ok(Environment { value, scale: env.scale })
    }

    fn optimise(&self, raw: crate::settings::OptimiseTable<file::ParamFile>, parts: &Parts) -> Result<Optimise, SceneError> {
        raw.settings.validate().map_err(|e| self.out_of_range(&format!("optimise.{}", e.key), e.message))?;
        let mut seen = HashSet::new();
        let mut params = Vec::with_capacity(raw.params.len());
        for (i, p) in raw.params.into_iter().enumerate() {
            let key = format!("optimise.params[{i}]");
            self.check_name(&format!("{key}.target"), &p.target, &mut seen)?;
            params.push(self.param(&key, p, parts)?);
        }
        Ok(Optimise { settings: raw.settings, params, started_from: None })
    }

    pub fn positive(&self, key: &str, v: f32) -> Result<(), SceneError> {
        self.finite(key, &[v])?;
        if v > 0.0 {
            Ok(())
        } else {
            Err(self.out_of_range(key, format!("{v} is not positive")))
        }
    }

    fn param(&self, key: &str, p: file::ParamFile, parts: &Parts) -> Result<Param, SceneError> {
        let target_key = format!("{key}.target");
        let (target, reference) = self.resolve_target(&target_key, &p.target, parts)?;
        let channels = target.channels();

        let range_key = format!("{key}.range");
        self.finite(&range_key, &p.range)?;
        let [lo, hi] = p.range;
        if lo >= hi {
            return Err(self.out_of_range(&range_key, format!("lower bound {lo} is not below upper bound {hi}")));
        }
        if let Some(lr) = p.lr {
            self.positive(&format!("{key}.lr"), lr)?;
        }
        if let Some([w, h]) = p.texture {
            let k = format!("{key}.texture");
            self.in_range(&k, w, 1, MAX_IMAGE_SIDE)?;
            self.in_range(&k, h, 1, MAX_IMAGE_SIDE)?;
            if !target.texturable() {
                return Err(self.invalid(&k, "a light's colour and intensity are constants and cannot be textures"));
            }
        } else if matches!(reference, Reference::Texture(_)) {
            return Err(self.invalid(key, &format!("{} is a texture in the scene; give `texture = [w, h]`", p.target)));
        }
        if let Some(sides) = p.grid {
            let k = format!("{key}.grid");
            if target.medium().is_none() {
                return Err(self.invalid(&k, "only a medium's density, emission and albedo are grids"));
            }
            for s in sides {
                self.in_range(&k, s, 1, crate::tensor::MAX_GRID_SIDE)?;
            }
            if sides.iter().map(|&s| s as usize).product::<usize>() > crate::tensor::MAX_GRID_VOXELS {
                return Err(self.out_of_range(&k, format!("{sides:?} is more than {} voxels", crate::tensor::MAX_GRID_VOXELS)));
            }
        }
        if target.medium().is_some() && lo < 0.0 {
            return Err(self.out_of_range(&range_key, format!("a medium's values are not negative; the range starts at {lo}")));
        }
        if matches!(target, ParamTarget::MediumAlbedo { .. }) && p.range[1] > 1.0 {
            return Err(self.out_of_range(&range_key, format!("an albedo lies in [0, 1]; the range ends at {}", p.range[1])));
        }
        let shape = match (p.texture, p.grid, &reference) {
            (Some([w, h]), _, _) => Shape::texture(w, h, channels),
            (None, Some([x, y, z]), _) => Shape::grid(x, y, z, channels),
            // A medium's grid is optimised at its own resolution unless `grid` gives one.
            (None, None, Reference::Grid(v)) if !v.shape.is_constant() => Shape::from_dims(v.shape.dims(), channels).unwrap_or(Shape::constant(channels)),
            _ => Shape::constant(channels),
        };
        let init = self.init_values(&format!("{key}.init"), p.init, &p.target, shape, p.range)?;
        Ok(Param { name: p.target, target, shape, init, range: p.range, lr: p.lr, reference })
    }

    /// The start values of parameter `target` (of `shape`, in `range`) that `init` (read
    /// at `key`) gives: a number for every channel, a colour, or an image (relative to the
    /// loader's directory) resampled to the texture's size; a number or a colour is
    /// repeated for every texel.
    pub fn init_values(&self, key: &str, init: InitInput, target: &str, shape: Shape, range: [f32; 2]) -> Result<Vec<f32>, SceneError> {
        let [lo, hi] = range;
        let channels = shape.channels();
        let texel = match init {
            InitInput::Scalar(v) => vec![v; channels as usize],
            InitInput::Color(c) if channels == 3 => c.to_vec(),
            InitInput::Color(_) => return Err(self.invalid(key, &format!("{target} is a scalar; give one number"))),
            InitInput::Texture(t) => {
                let Some([w, h]) = shape.texture_size() else {
                    return Err(self.invalid(key, "an image as `init` needs a texture parameter; give `texture = [w, h]`"));
                };
                let k = format!("{key}.texture");
                if t.filter.is_some() || t.wrap.is_some() {
                    let what = if t.filter.is_some() { "filter" } else { "wrap" };
                    return Err(self.invalid(
                        &format!("{key}.{what}"),
                        "applies to a scene's textures, not to a start image (which is resampled to the parameter's size)",
                    ));
                }
                let tex = self.texture(&k, &t.texture)?;
                self.texels_in(&k, &tex, channels as usize, lo, hi)?;
                tex.image.resample(channels, w, h)
            }
        };
        let init: Vec<f32> = texel.iter().copied().cycle().take(shape.len()).collect();
        self.finite(key, &init)?;
        if let Some(v) = init.iter().find(|&&v| v < lo || v > hi) {
            return Err(self.out_of_range(key, format!("{v} is outside the range [{lo}, {hi}]")));
        }
        Ok(init)
    }

    /// The target named `target` (read at `key`) and the scene's own value of it.
    fn resolve_target(&self, key: &str, target: &str, parts: &Parts) -> Result<(ParamTarget, Reference), SceneError> {
        match ParamTarget::parse(target, parts) {
            Ok(t) => Ok((t, t.reference(parts))),
            Err(TargetError::Malformed) => Err(self.bad_target(key, target)),
            Err(TargetError::Undefined { kind, name, known }) => Err(SceneError::Undefined { scene: self.scene.clone(), key: key.into(), kind, name, known }),
            Err(TargetError::Invalid(why)) => Err(self.invalid(key, &why)),
        }
    }

    fn bad_target(&self, key: &str, target: &str) -> SceneError {
        self.invalid(key, &format!("\"{target}\" is not {TARGET_FORMS}"))
    }
}
