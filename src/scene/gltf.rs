//! glTF 2.0 import (`.gltf` with external or data-URI buffers and images, `.glb`) through
//! the `gltf` crate.
//!
//! What is read: the default scene's node hierarchy with its transforms; every indexed or
//! non-indexed triangle primitive (positions, normals, TEXCOORD_0) as one mesh in world
//! space; metallic-roughness materials with their factors and textures (base colour decoded
//! from sRGB, roughness from the metallic-roughness texture's G channel and metallic from
//! its B, each multiplied by its factor, and `KHR_materials_ior`'s index setting the
//! dielectric reflectance) and normal textures; `emissiveFactor` ×
//! `KHR_materials_emissive_strength`, times the sRGB-decoded `emissiveTexture` where there
//! is one, as the mesh's area emission, on both sides when the material is `doubleSided`;
//! `alphaMode` `MASK` and `BLEND` as alpha tests; `KHR_materials_transmission` as glass (a
//! dielectric of `KHR_materials_ior`'s index, tinted by the base colour: refracting where
//! `KHR_materials_volume` gives it a thickness, a thin sheet where it is thin-walled); every
//! camera as a sensor (looking down its node's −Z, in node order; an orthographic one's
//! view 2·ymag high); and
//! `KHR_lights_punctual` lights, their intensities taken as the renderer's radiant
//! intensity (point, spot) and irradiance (directional) with no photometric conversion.
//! A file without a camera gets one that frames its meshes' bounding box (on a 512² film),
//! and one without light a uniform environment of radiance 1, each announced in a warning.
//!
//! Names: a mesh is its node's name (else the glTF mesh's, else `node<i>`), with
//! `.primitive<j>` added when the mesh has several primitives; materials and lights keep
//! their names (else `material<i>`, `light<i>`). A name that repeats gets `#<index>`
//! added, the glTF index of what it names.
//!
//! Anything that would change the image and is not read is an error naming its JSON path
//! (texture sets other than 0, non-triangle primitives, required extensions other than
//! the two above); what does not
//! change a path-traced image, or only as an approximation the user should know of
//! (occlusion textures, optional extensions, animation, vertex colours), is a one-line
//! warning.
//! Samplers' wrapping modes and NEAREST magnification filter are the textures' [`Wrap`]
//! and [`Filter`]. `alphaMode` `MASK` and `BLEND` are alpha tests ([`AlphaMask`]) on the
//! base colour's alpha.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Vec3};
use gltf::texture::WrappingMode;

use super::model::Imported;
use super::model::*;
use super::{MaterialKind, SceneError, GLTF_FILM_SIDE, GLTF_MAX_DEPTH};
use crate::image::{srgb_decode, Image};

/// Where material `m` is in the document: `materials[i]`, or for glTF's default material
/// (no index) the primitive that uses it (`used_at`).
fn material_at(m: &gltf::Material, used_at: &str) -> String {
    match m.index() {
        Some(i) => format!("materials[{i}]"),
        None => format!("{used_at}.material"),
    }
}

/// Extensions whose content is read.
pub const SUPPORTED_EXTENSIONS: [&str; 6] = [
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_texture_transform",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_materials_ior",
];

/// The filter of `texture`'s sampler: nearest where its magnification filter is NEAREST
/// (the renderer does not minify: its minification filter does not apply).
fn filter(texture: &gltf::Texture) -> Filter {
    match texture.sampler().mag_filter() {
        Some(gltf::texture::MagFilter::Nearest) => Filter::Nearest,
        _ => Filter::Bilinear,
    }
}

/// The wrapping modes (s, t) of `texture`'s sampler.
fn wrap(texture: &gltf::Texture) -> [Wrap; 2] {
    let mode = |m: WrappingMode| match m {
        WrappingMode::Repeat => Wrap::Repeat,
        WrappingMode::ClampToEdge => Wrap::Clamp,
        WrappingMode::MirroredRepeat => Wrap::Mirror,
    };
    let s = texture.sampler();
    [mode(s.wrap_s()), mode(s.wrap_t())]
}

/// The texture of `image` (known by `path`) that glTF texture `texture` samples, looked up at
/// texture coordinate set `uv_set`.
fn sampled(path: PathBuf, image: Image, texture: &gltf::Texture, uv_set: u32) -> Texture {
    Texture { path, image: image.into(), filter: filter(texture), wrap: wrap(texture), uv_set }
}

/// The texture coordinate set a texture reference reads: its `texCoord`, or its
/// `KHR_texture_transform`'s `texCoord`, which overrides it.
fn coord_set(tex_coord: u32, transform: Option<&serde_json::Value>) -> u32 {
    transform.and_then(|t| t.get("texCoord")).and_then(serde_json::Value::as_u64).map_or(tex_coord, |k| k.min(u64::from(u32::MAX)) as u32)
}

/// The coordinate set of texture reference `info`.
fn info_set(info: &gltf::texture::Info) -> u32 {
    coord_set(info.tex_coord(), info.extension_value("KHR_texture_transform"))
}

/// What a material's textures ask of a primitive's texture coordinates
/// ([`Importer::uv_transform`]), per set.
#[derive(Default)]
struct UvSets {
    transform: [Option<UvTransform>; 2],
    used: [bool; 2],
}

/// A texture reference's `KHR_texture_transform`: uv ↦ offset + R(rotation) (scale ∘ uv) in
/// glTF's texture space (v down the image), R turning counter-clockwise.
#[derive(Clone, Copy, Debug, PartialEq)]
struct UvTransform {
    offset: [f32; 2],
    rotation: f32,
    scale: [f32; 2],
}

impl UvTransform {
    fn apply(&self, [u, v]: [f32; 2]) -> [f32; 2] {
        let (s, c) = self.rotation.sin_cos();
        let (x, y) = (u * self.scale[0], v * self.scale[1]);
        [self.offset[0] + c * x + s * y, self.offset[1] - s * x + c * y]
    }
}

struct Importer<'a> {
    path: &'a Path,
    base: PathBuf,
    doc: gltf::Document,
    buffers: Vec<gltf::buffer::Data>,
    /// Decoded images by index, values in [0, 1] as stored.
    images: HashMap<usize, Image>,
    /// Each decoded image's alpha channel (grey repeated), where it has one.
    alphas: HashMap<usize, Option<Image>>,
    /// Model material index of each glTF material used so far (`None`: the default).
    materials: HashMap<Option<usize>, usize>,
    /// Emission of each glTF material used so far: its meshes share one texture.
    emissions: HashMap<Option<usize>, ColorValue>,
    out: Imported,
    sources: GltfSource,
}

fn err(path: &Path, location: impl Into<String>, message: impl Into<String>) -> SceneError {
    SceneError::Import { path: path.to_path_buf(), location: location.into(), message: message.into() }
}

/// Imports the glTF or GLB file at `path`. Its buffers are loaded (a file's first
/// `byteLength` bytes) and the document checked ([`super::gltf_check`]) before the `gltf`
/// crate reads anything from them.
pub(super) fn import(path: &Path) -> Result<Imported, SceneError> {
    let bytes = crate::files::read(path).map_err(|source| SceneError::ReadScene { path: path.to_path_buf(), source })?;
    let (json, bin): (std::borrow::Cow<[u8]>, Option<Vec<u8>>) = if bytes.starts_with(b"glTF") {
        // The gltf crate subtracts the header's size from its declared length unchecked.
        let declared = bytes.get(8..12).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
        if !declared.is_some_and(|l| (12..=bytes.len()).contains(&l)) {
            return Err(err(
                path,
                "",
                format!("not a valid GLB file: the header's length ({}) is not between 12 and the file's {} bytes", declared.unwrap_or(0), bytes.len()),
            ));
        }
        let glb = gltf::binary::Glb::from_slice(&bytes).map_err(|e| err(path, "", format!("not a valid GLB file: {e}")))?;
        (glb.json.into_owned().into(), glb.bin.map(|b| b.into_owned()))
    } else {
        (bytes.as_slice().into(), None)
    };
    let mut root: serde_json::Value = serde_json::from_slice(&json).map_err(|e| err(path, "", format!("not valid JSON: {e}")))?;
    let mut warnings = check_extensions(path, &root)?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let buffers = load_buffers(path, &root, &base, bin)?;
    let lengths: Vec<u64> = buffers.iter().map(|b| b.len() as u64).collect();
    super::gltf_check::check(&root, &lengths).map_err(|(at, what)| err(path, at, what))?;
    // Animations are not rendered: they are left out before the gltf crate reads the
    // document, so that a channel it cannot read (one whose target names no node, which
    // glTF 2.0 allows) does not refuse the file.
    let json = match root.as_object_mut().and_then(|o| o.remove("animations")) {
        Some(animations) => {
            if animations.as_array().is_some_and(|a| !a.is_empty()) {
                warnings.push("animations are ignored: the scene is rendered at rest".into());
            }
            serde_json::to_vec(&root).map_err(|e| err(path, "", format!("not valid JSON: {e}")))?.into()
        }
        None => json,
    };
    let gltf = gltf::Gltf::from_slice(&json).map_err(|e| err(path, "", format!("not a valid glTF 2.0 file: {e}")))?;
    let doc = gltf.document;
    let buffers = buffers.into_iter().map(gltf::buffer::Data).collect();
    if doc.skins().next().is_some() {
        warnings.push("skins are ignored: meshes are rendered in their bind pose".into());
    }
    let mut imp = Importer {
        path,
        base,
        doc,
        buffers,
        images: HashMap::new(),
        alphas: HashMap::new(),
        materials: HashMap::new(),
        emissions: HashMap::new(),
        out: Imported { warnings, max_depth: Some(GLTF_MAX_DEPTH), ..Default::default() },
        sources: GltfSource { path: path.to_path_buf(), materials: Vec::new(), lights: Vec::new() },
    };
    let doc = imp.doc.clone();
    let scene = doc.default_scene().or_else(|| doc.scenes().next()).ok_or_else(|| err(path, "scenes", "the file has no scene"))?;
    for node in scene.nodes() {
        imp.node(&node, Mat4::IDENTITY)?;
    }
    imp.uniquify();
    if imp.out.sensors.is_empty() {
        // The loader adds a camera that frames the model, on a square film.
        imp.out.film = Some(Film { width: GLTF_FILM_SIDE, height: GLTF_FILM_SIDE });
    }
    imp.out.source = Source::Gltf(imp.sources);
    Ok(imp.out)
}

/// A URI's `%XX` escapes decoded (glTF URIs are percent-encoded).
fn percent_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |b: u8| (b as char).to_digit(16);
        match (bytes[i], bytes.get(i + 1).copied().and_then(hex), bytes.get(i + 2).copied().and_then(hex)) {
            (b'%', Some(h), Some(l)) => {
                out.push((h * 16 + l) as u8);
                i += 3;
            }
            (b, _, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The bytes of a `data:` URI (base64), or of the file a relative URI names under `base`
/// (its first `max` bytes).
fn uri_bytes(uri: &str, base: &Path, max: u64) -> Result<Vec<u8>, String> {
    if let Some(data) = uri.strip_prefix("data:") {
        let (_, payload) = data.split_once(";base64,").ok_or("a data URI that is not base64")?;
        return base64::decode(payload).map_err(|e| format!("its base64 does not decode: {e}"));
    }
    let file = base.join(percent_decode(uri));
    crate::files::read_prefix(&file, max).map_err(|e| format!("{}: {e}", file.display()))
}

/// Every buffer's bytes: a GLB's binary chunk, a data URI's or a file's, at most its
/// `byteLength` (a buffer that holds fewer is an error naming it).
fn load_buffers(path: &Path, root: &serde_json::Value, base: &Path, mut bin: Option<Vec<u8>>) -> Result<Vec<Vec<u8>>, SceneError> {
    let list = root.get("buffers").and_then(|b| b.as_array()).map(Vec::as_slice).unwrap_or(&[]);
    let mut out = Vec::with_capacity(list.len());
    for (i, b) in list.iter().enumerate() {
        let location = format!("buffers[{i}]");
        let declared = b.get("byteLength").and_then(|l| l.as_u64()).ok_or_else(|| err(path, &location, "has no byteLength"))?;
        let mut data = match b.get("uri").and_then(|u| u.as_str()) {
            Some(uri) => uri_bytes(uri, base, declared).map_err(|e| err(path, &location, e))?,
            None => bin.take().ok_or_else(|| err(path, &location, "has no uri and the file no binary chunk for it"))?,
        };
        if (data.len() as u64) < declared {
            return Err(err(path, location, format!("holds {} bytes, {declared} declared", data.len())));
        }
        data.truncate(declared as usize);
        out.push(data);
    }
    Ok(out)
}

/// An image's pixels as stored (no colour transform), grey repeated, and its alpha channel
/// (grey repeated) where it has one; its size checked against [`super::MAX_IMAGE_SIDE`]
/// before it is decoded.
fn decode_image(bytes: &[u8]) -> Result<(Image, Option<Image>), String> {
    let reader = || image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format().map_err(|e| e.to_string());
    let (w, h) = reader()?.into_dimensions().map_err(|e| e.to_string())?;
    let max = super::MAX_IMAGE_SIDE;
    if w == 0 || h == 0 || w > max || h > max {
        return Err(format!("{w}x{h} pixels: each side must be in 1..={max}"));
    }
    let decoded = reader()?.decode().map_err(|e| e.to_string())?;
    let has_alpha = decoded.color().has_alpha();
    let rgba = decoded.to_rgba32f();
    let data = rgba.pixels().map(|p| [p[0], p[1], p[2]]).collect();
    let alpha = has_alpha.then(|| Image { width: w, height: h, data: rgba.pixels().map(|p| [p[3]; 3]).collect() });
    Ok((Image { width: w, height: h, data }, alpha))
}

/// Finds every `extensions` object in the document: an extension this importer does not
/// read is an error (at its JSON path) when the file lists it in `extensionsRequired`,
/// else a warning.
fn check_extensions(path: &Path, root: &serde_json::Value) -> Result<Vec<String>, SceneError> {
    let required: HashSet<&str> =
        root.get("extensionsRequired").and_then(|v| v.as_array()).map(|a| a.iter().filter_map(|v| v.as_str()).collect()).unwrap_or_default();
    let mut found = Vec::new();
    walk_extensions(root, String::new(), &mut found);
    let mut warnings = Vec::new();
    for (location, name) in found {
        if SUPPORTED_EXTENSIONS.contains(&name.as_str()) {
            continue;
        }
        if required.contains(name.as_str()) {
            return Err(err(path, location, format!("extension {name} is not supported")));
        }
        warnings.push(format!("{}: {location}: optional extension {name} is ignored", path.display()));
    }
    // A required extension that no object uses (one that changes how the file is read).
    for (i, name) in root.get("extensionsRequired").and_then(|v| v.as_array()).into_iter().flatten().enumerate() {
        if let Some(name) = name.as_str().filter(|n| !SUPPORTED_EXTENSIONS.contains(n)) {
            return Err(err(path, format!("extensionsRequired[{i}]"), format!("extension {name} is not supported")));
        }
    }
    Ok(warnings)
}

fn walk_extensions(v: &serde_json::Value, at: String, found: &mut Vec<(String, String)>) {
    match v {
        serde_json::Value::Object(map) => {
            for (k, child) in map {
                let here = if at.is_empty() { k.clone() } else { format!("{at}.{k}") };
                if k == "extensions" {
                    if let Some(exts) = child.as_object() {
                        for name in exts.keys() {
                            found.push((format!("{here}.{name}"), name.clone()));
                        }
                    }
                }
                walk_extensions(child, here, found);
            }
        }
        serde_json::Value::Array(items) => {
            for (i, child) in items.iter().enumerate() {
                walk_extensions(child, format!("{at}[{i}]"), found);
            }
        }
        _ => {}
    }
}

impl Importer<'_> {
    fn err(&self, location: impl Into<String>, message: impl Into<String>) -> SceneError {
        err(self.path, location, message)
    }

    fn warn(&mut self, location: impl std::fmt::Display, message: impl std::fmt::Display) {
        self.out.warnings.push(format!("{}: {location}: {message}", self.path.display()));
    }

    fn node(&mut self, node: &gltf::Node, parent: Mat4) -> Result<(), SceneError> {
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if !world.is_finite() {
            return Err(self.err(format!("nodes[{}]", node.index()), "non-finite transform"));
        }
        let node_name = node.name().map(str::to_owned);
        if let Some(mesh) = node.mesh() {
            let name = node_name.clone().or_else(|| mesh.name().map(str::to_owned)).unwrap_or_else(|| format!("node{}", node.index()));
            let several = mesh.primitives().len() > 1;
            for prim in mesh.primitives() {
                let name = if several { format!("{name}.primitive{}", prim.index()) } else { name.clone() };
                self.primitive(&mesh, &prim, world, name, node.index())?;
            }
        }
        if let Some(camera) = node.camera() {
            self.camera(&camera, world)?;
        }
        if let Some(light) = node.light() {
            self.light(&light, world, node.index())?;
        }
        for child in node.children() {
            self.node(&child, world)?;
        }
        Ok(())
    }

    fn primitive(&mut self, mesh: &gltf::Mesh, prim: &gltf::Primitive, world: Mat4, name: String, node: usize) -> Result<(), SceneError> {
        let at = format!("meshes[{}].primitives[{}]", mesh.index(), prim.index());
        if prim.mode() != gltf::mesh::Mode::Triangles {
            return Err(self.err(format!("{at}.mode"), format!("{:?} primitives are not supported (triangles only)", prim.mode())));
        }
        if prim.morph_targets().next().is_some() {
            self.warn(&at, "morph targets are ignored");
        }
        if prim.get(&gltf::Semantic::Colors(0)).is_some() {
            self.warn(format!("{at}.attributes.COLOR_0"), "vertex colours are ignored: the material's base colour alone is rendered");
        }
        let buffers = &self.buffers;
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let positions: Vec<[f32; 3]> = reader.read_positions().ok_or_else(|| self.err(format!("{at}.attributes"), "no POSITION"))?.collect();
        let normals: Vec<[f32; 3]> = reader.read_normals().map(|n| n.collect()).unwrap_or_default();
        // glTF's v points down from the image's top row; the model's points up.
        let sets = self.uv_transform(&prim.material(), &at)?;
        let coords = |set: u32| -> Vec<[f32; 2]> {
            let transform = sets.transform[set as usize];
            reader
                .read_tex_coords(set)
                .map(|t| {
                    t.into_f32()
                        .map(|uv| {
                            let [u, v] = transform.map_or(uv, |t| t.apply(uv));
                            [u, 1.0 - v]
                        })
                        .collect()
                })
                .unwrap_or_default()
        };
        let uvs = coords(0);
        // The second set is read only where a texture reads it, and must be there.
        let uvs1 = if sets.used[1] { coords(1) } else { Vec::new() };
        if sets.used[1] && uvs1.is_empty() {
            let material = material_at(&prim.material(), &at);
            return Err(self.err(format!("{at}.attributes"), format!("no TEXCOORD_1, which a texture of {material} reads")));
        }
        let flat: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..positions.len() as u32).collect(),
        };
        if !flat.len().is_multiple_of(3) {
            return Err(self.err(format!("{at}.indices"), format!("{} indices are not whole triangles", flat.len())));
        }
        let n = positions.len();
        if flat.iter().any(|&i| i as usize >= n) {
            return Err(self.err(format!("{at}.indices"), format!("an index is out of bounds ({n} vertices)")));
        }
        for (what, len) in [("NORMAL", normals.len()), ("TEXCOORD_0", uvs.len()), ("TEXCOORD_1", uvs1.len())] {
            if len != 0 && len != n {
                return Err(self.err(format!("{at}.attributes.{what}"), format!("{len} values for {n} vertices")));
            }
        }
        let normal_matrix = Mat3::from_mat4(world).inverse().transpose();
        // A mirroring transform turns counter-clockwise triangles clockwise.
        let mirrored = Mat3::from_mat4(world).determinant() < 0.0;
        let indices = flat.chunks_exact(3).map(|t| if mirrored { [t[0], t[2], t[1]] } else { [t[0], t[1], t[2]] }).collect();
        check_triangles(&self.out.meshes, flat.len() / 3).map_err(|e| self.err(&at, e))?;
        let material = self.material(prim.material(), &at)?;
        let emission = self.emission(&prim.material(), &at)?;
        let m = prim.material();
        self.out.meshes.push(Mesh {
            name: if self.out.meshes.iter().any(|x| x.name == name) { format!("{name}#{node}") } else { name },
            path: self.path.to_path_buf(),
            positions: positions.iter().map(|&p| world.transform_point3(Vec3::from(p)).to_array()).collect(),
            normals: normals.iter().map(|&v| (normal_matrix * Vec3::from(v)).normalize_or_zero().to_array()).collect(),
            uvs,
            uvs1,
            indices,
            material,
            emission,
            two_sided_emission: m.double_sided(),
            sphere: None,
        });
        Ok(())
    }

    /// The emission of material `m`: `emissiveFactor` × `KHR_materials_emissive_strength`,
    /// times the sRGB-decoded `emissiveTexture` where there is one (and the factor is not
    /// black), decoded once per material.
    fn emission(&mut self, m: &gltf::Material, used_at: &str) -> Result<ColorValue, SceneError> {
        if let Some(e) = self.emissions.get(&m.index()) {
            return Ok(e.clone());
        }
        let strength = m.emissive_strength().unwrap_or(1.0);
        let [r, g, b] = m.emissive_factor().map(|e| e * strength);
        let emission = match m.emissive_texture() {
            Some(info) if r > 0.0 || g > 0.0 || b > 0.0 => {
                let (img, path) = self.texture(&info, &format!("{}.emissiveTexture", material_at(m, used_at)))?;
                let data = img.data.iter().map(|p| [srgb_decode(p[0]) * r, srgb_decode(p[1]) * g, srgb_decode(p[2]) * b]).collect();
                ColorValue::Texture(sampled(path, Image { data, ..img }, &info.texture(), info_set(&info)))
            }
            _ => ColorValue::Constant([r, g, b]),
        };
        self.emissions.insert(m.index(), emission.clone());
        Ok(emission)
    }

    /// The model index of glTF material `m` (`index() == None`: glTF's default material),
    /// created on first use.
    fn material(&mut self, m: gltf::Material, used_at: &str) -> Result<usize, SceneError> {
        if let Some(&i) = self.materials.get(&m.index()) {
            return Ok(i);
        }
        let at = material_at(&m, used_at);
        if m.occlusion_texture().is_some() {
            self.warn(format!("{at}.occlusionTexture"), "ignored: the path tracer computes occlusion itself");
        }
        let alpha = self.alpha(&m, &at)?;
        let pbr = m.pbr_metallic_roughness();
        let [r, g, b, _] = pbr.base_color_factor();
        let base_color = match pbr.base_color_texture() {
            None => ColorValue::Constant([r, g, b]),
            Some(info) => {
                let (img, path) = self.texture(&info, &format!("{at}.pbrMetallicRoughness.baseColorTexture"))?;
                let data = img.data.iter().map(|p| [srgb_decode(p[0]) * r, srgb_decode(p[1]) * g, srgb_decode(p[2]) * b]).collect();
                ColorValue::Texture(sampled(path, Image { data, ..img }, &info.texture(), info_set(&info)))
            }
        };
        let (metallic_factor, roughness_factor) = (pbr.metallic_factor(), pbr.roughness_factor());
        let (roughness, metallic) = match pbr.metallic_roughness_texture() {
            None => (ScalarValue::Constant(roughness_factor), ScalarValue::Constant(metallic_factor)),
            Some(info) => {
                let (img, path) = self.texture(&info, &format!("{at}.pbrMetallicRoughness.metallicRoughnessTexture"))?;
                let channel = |c: usize, k: f32| {
                    let image = Image { data: img.data.iter().map(|p| [p[c] * k; 3]).collect(), width: img.width, height: img.height };
                    sampled(path.clone(), image, &info.texture(), info_set(&info))
                };
                (ScalarValue::Texture(channel(1, roughness_factor)), ScalarValue::Texture(channel(2, metallic_factor)))
            }
        };
        for (what, v) in [("roughnessFactor", roughness_factor), ("metallicFactor", metallic_factor)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(self.err(format!("{at}.pbrMetallicRoughness.{what}"), format!("{v} is outside [0, 1]")));
            }
        }
        let perturbation = match m.normal_texture() {
            None => None,
            Some(n) => {
                let key = format!("{at}.normalTexture");
                let set = coord_set(n.tex_coord(), n.extension_value("KHR_texture_transform"));
                let (image, path) = self.image(n.texture(), set, &key)?;
                let scale = n.scale();
                if !scale.is_finite() {
                    return Err(self.err(format!("{key}.scale"), format!("{scale} is not finite")));
                }
                Some(Perturbation::Normal(NormalMap { texture: sampled(path, image, &n.texture(), set), scale, bitangent: Bitangent::Uv }))
            }
        };
        let name = match (m.name(), m.index()) {
            (Some(n), Some(i)) if self.out.materials.iter().any(|x| x.name == n) => format!("{n}#{i}"),
            (Some(n), _) => n.to_string(),
            (None, Some(i)) => format!("material{i}"),
            (None, None) => "default".to_string(),
        };
        let (ior, glass) = self.transmission(&m, &at, &roughness, &metallic, perturbation.is_some(), alpha.is_some())?;
        let material = match glass {
            Some((kind, absorption)) => {
                let rough = if kind == MaterialKind::RoughDielectric { roughness } else { ScalarValue::Constant(0.0) };
                Material { absorption, roughness: rough, ..Material::glass(name, kind, base_color, ior) }
            }
            None => Material {
                name,
                kind: MaterialKind::Principled,
                base_color,
                roughness,
                metallic,
                one_sided: false,
                perturbation,
                alpha,
                ior,
                absorption: [0.0; 3],
                distribution: Distribution::Ggx,
                eta: [0.0; 3],
                k: [0.0; 3],
                nonlinear: false,
                layered: true,
                specular: [1.0; 3],
            },
        };
        self.out.materials.push(material);
        self.sources.materials.push(m.index());
        let index = self.out.materials.len() - 1;
        self.materials.insert(m.index(), index);
        Ok(index)
    }

    /// The `KHR_texture_transform` that the textures of material `m` (used at `used_at`)
    /// reading each set of texture coordinates share, applied to that set of the
    /// primitives that use it (None: the identity), and which sets its textures read. The
    /// model has the coordinates per mesh: textures of one material that read one set with
    /// different transforms are refused.
    fn uv_transform(&self, m: &gltf::Material, used_at: &str) -> Result<UvSets, SceneError> {
        let at = material_at(m, used_at);
        let pbr = m.pbr_metallic_roughness();
        let of = |i: gltf::texture::Info| (i.tex_coord(), i.extension_value("KHR_texture_transform").cloned());
        let refs = [
            ("pbrMetallicRoughness.baseColorTexture", pbr.base_color_texture().map(of)),
            ("pbrMetallicRoughness.metallicRoughnessTexture", pbr.metallic_roughness_texture().map(of)),
            ("normalTexture", m.normal_texture().map(|n| (n.tex_coord(), n.extension_value("KHR_texture_transform").cloned()))),
            ("emissiveTexture", m.emissive_texture().map(of)),
        ];
        let mut sets = UvSets::default();
        let mut shared: [Option<(String, Option<UvTransform>)>; 2] = [None, None];
        for (key, reference) in refs {
            let Some((tex_coord, ext)) = reference else { continue };
            let set = coord_set(tex_coord, ext.as_ref());
            let key = format!("{at}.{key}");
            if set > 1 {
                return Err(self.err(format!("{key}.texCoord"), format!("texture coordinate set {set} is not supported (TEXCOORD_0 and TEXCOORD_1 are)")));
            }
            let key = format!("{key}.extensions.KHR_texture_transform");
            let t = match ext {
                None => None,
                Some(v) => {
                    let bad = |what: &str| self.err(&key, format!("{what} is not valid"));
                    let pair = |name: &str, default: [f32; 2]| -> Result<[f32; 2], SceneError> {
                        match v.get(name) {
                            None => Ok(default),
                            Some(x) => match x.as_array().map(|a| a.iter().map(|c| c.as_f64()).collect::<Option<Vec<f64>>>()) {
                                Some(Some(a)) if a.len() == 2 && a.iter().all(|c| c.is_finite()) => Ok([a[0] as f32, a[1] as f32]),
                                _ => Err(bad(name)),
                            },
                        }
                    };
                    let rotation = match v.get("rotation") {
                        None => 0.0,
                        Some(x) => x.as_f64().filter(|r| r.is_finite()).ok_or_else(|| bad("rotation"))? as f32,
                    };
                    if v.get("texCoord").is_some_and(|k| k.as_u64().is_none()) {
                        return Err(bad("texCoord"));
                    }
                    let t = UvTransform { offset: pair("offset", [0.0; 2])?, rotation, scale: pair("scale", [1.0; 2])? };
                    (t != UvTransform { offset: [0.0; 2], rotation: 0.0, scale: [1.0; 2] }).then_some(t)
                }
            };
            sets.used[set as usize] = true;
            match &shared[set as usize] {
                None => shared[set as usize] = Some((key, t)),
                Some((first, s)) if *s != t => {
                    return Err(self.err(
                        &key,
                        format!("differs from {first}: the textures of one material that read one set of texture coordinates must share one texture transform"),
                    ));
                }
                Some(_) => {}
            }
        }
        sets.transform = shared.map(|s| s.and_then(|(_, t)| t));
        Ok(sets)
    }

    /// The image of a texture reference (values as stored) and the path it is known by.
    fn texture(&mut self, info: &gltf::texture::Info, at: &str) -> Result<(Image, PathBuf), SceneError> {
        self.image(info.texture(), info_set(info), at)
    }

    /// The image of `texture` read with texture coordinate set `tex_coord` (values as
    /// stored) and the path it is known by.
    fn image(&mut self, texture: gltf::Texture, tex_coord: u32, at: &str) -> Result<(Image, PathBuf), SceneError> {
        if tex_coord > 1 {
            return Err(self.err(format!("{at}.texCoord"), format!("texture coordinate set {tex_coord} is not supported (TEXCOORD_0 and TEXCOORD_1 are)")));
        }
        let source = texture.source();
        let index = source.index();
        let path = match source.source() {
            gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => self.base.join(uri),
            _ => PathBuf::from(format!("{}#images[{index}]", self.path.display())),
        };
        if let Some(img) = self.images.get(&index) {
            return Ok((img.clone(), path));
        }
        let bytes = match source.source() {
            gltf::image::Source::View { view, .. } => {
                // Inside its buffer (gltf_check).
                let buffer = &self.buffers[view.buffer().index()].0;
                Ok(buffer[view.offset()..view.offset() + view.length()].to_vec())
            }
            gltf::image::Source::Uri { uri, .. } => uri_bytes(uri, &self.base, crate::files::MAX_INPUT_BYTES),
        };
        let (img, alpha) =
            bytes.and_then(|b| decode_image(&b)).map_err(|e| self.err(format!("images[{index}]"), format!("cannot decode {}: {e}", path.display())))?;
        self.images.insert(index, img.clone());
        self.alphas.insert(index, alpha);
        Ok((img, path))
    }

    /// The alpha channel of `info`'s image (as stored), None where the image has none.
    fn texture_alpha(&mut self, info: &gltf::texture::Info, at: &str) -> Result<(Option<Image>, PathBuf), SceneError> {
        let (_, path) = self.texture(info, at)?;
        Ok((self.alphas.get(&info.texture().source().index()).cloned().flatten(), path))
    }

    /// The alpha test of material `m` at JSON path `at` on the base colour's alpha
    /// (`baseColorFactor`'s fourth component times the texture's alpha channel where it has
    /// one): none for `OPAQUE`; a cut-out at `alphaCutoff` (0.5 by default) for `MASK`; a
    /// coverage for `BLEND` (the surface there with probability alpha, which in
    /// expectation is what blending it over what lies behind shows). An alpha that never
    /// cuts (a constant or every texel that always passes: many `BLEND` materials are
    /// opaque) is no test.
    /// The glass that `KHR_materials_transmission` makes of material `m` (at JSON path `at`),
    /// if any: a dielectric of `KHR_materials_ior`'s index (1.5 by default) where
    /// `KHR_materials_volume` gives it a thickness (a rough dielectric where its roughness
    /// is not 0), otherwise glTF's thin-walled transmission, a thin dielectric; the base
    /// colour is its transmittance. Exact for a fully transmissive, non-metallic material
    /// with a volume (but for a rough one's masking term: Smith's separable form, as
    /// Mitsuba's, where glTF's reference has the height-correlated one) or a smooth one
    /// without; otherwise one warning names what is dropped
    /// (a thin-walled material's roughness, metallic, a transmission below 1, a
    /// transmission texture, a normal map or alpha). The volume's `attenuationColor` and `attenuationDistance` are
    /// the interior's absorption. A transmission below 0.5 is dropped
    /// instead (the material stays principled), with a warning. Returned with the index,
    /// which a material without transmission keeps as its principled model's (its
    /// dielectric reflectance ((ior − 1)/(ior + 1))² at normal incidence, as glTF's).
    /// An index outside [MIN_IOR, MAX_IOR] is an error.
    fn transmission(
        &mut self,
        m: &gltf::Material,
        at: &str,
        roughness: &ScalarValue,
        metallic: &ScalarValue,
        normal_map: bool,
        alpha: bool,
    ) -> Result<(f32, Option<(MaterialKind, [f32; 3])>), SceneError> {
        let ext = |name: &str| m.extension_value(name);
        let number = |this: &Self, name: &str, field: &str, default: f32| -> Result<f32, SceneError> {
            let key = format!("{at}.extensions.{name}.{field}");
            match ext(name).and_then(|v| v.get(field)) {
                None => Ok(default),
                Some(v) => match v.as_f64() {
                    Some(x) if x.is_finite() => Ok(x as f32),
                    _ => Err(this.err(key, format!("{v} is not a finite number"))),
                },
            }
        };
        let factor = number(self, "KHR_materials_transmission", "transmissionFactor", 0.0)?;
        if !(0.0..=1.0).contains(&factor) {
            return Err(self.err(format!("{at}.extensions.KHR_materials_transmission.transmissionFactor"), format!("{factor} is outside [0, 1]")));
        }
        let ior = number(self, "KHR_materials_ior", "ior", DEFAULT_IOR)?;
        if !(MIN_IOR..=MAX_IOR).contains(&ior) {
            return Err(self.err(format!("{at}.extensions.KHR_materials_ior.ior"), format!("{ior} is outside [{MIN_IOR}, {MAX_IOR}]")));
        }
        if factor == 0.0 {
            return Ok((ior, None));
        }
        if factor < 0.5 {
            self.warn(format!("{at}.extensions.KHR_materials_transmission"), format!("approximate: a transmission of {factor} is dropped (rendered opaque)"));
            return Ok((ior, None));
        }
        let thickness = number(self, "KHR_materials_volume", "thicknessFactor", 0.0)?;
        let smooth = matches!(roughness, ScalarValue::Constant(r) if *r == 0.0);
        let kind = match (thickness > 0.0, smooth) {
            (true, true) => MaterialKind::Dielectric,
            (true, false) if ior != 1.0 => MaterialKind::RoughDielectric,
            // Index-matched: the rough interface's refraction would be a delta.
            (true, false) => MaterialKind::Dielectric,
            (false, _) => MaterialKind::ThinDielectric,
        };
        let mut dropped = Vec::new();
        if factor < 1.0 {
            dropped.push(format!("its transmission {factor} (rendered as 1)"));
        }
        if ext("KHR_materials_transmission").and_then(|v| v.get("transmissionTexture")).is_some() {
            dropped.push("its transmissionTexture".into());
        }
        if !smooth && kind != MaterialKind::RoughDielectric {
            dropped.push("its roughness (rendered smooth)".into());
        }
        if !matches!(metallic, ScalarValue::Constant(v) if *v == 0.0) {
            dropped.push("its metallic".into());
        }
        if normal_map {
            dropped.push("its normal map".into());
        }
        if alpha {
            dropped.push("its alpha".into());
        }
        // The volume's absorption: attenuationColor is what remains of white light after
        // attenuationDistance inside, so the coefficient is −ln(colour) / distance (a
        // thin-walled material has no volume: glTF ignores it there).
        let mut absorption = [0.0; 3];
        let distance = number(self, "KHR_materials_volume", "attenuationDistance", f32::INFINITY)?;
        if kind != MaterialKind::ThinDielectric && distance.is_finite() {
            let vkey = |field: &str| format!("{at}.extensions.KHR_materials_volume.{field}");
            if distance <= 0.0 {
                return Err(self.err(vkey("attenuationDistance"), format!("{distance} is not positive")));
            }
            let colour = match ext("KHR_materials_volume").and_then(|v| v.get("attenuationColor")) {
                None => [1.0; 3],
                Some(v) => v
                    .as_array()
                    .filter(|a| a.len() == 3)
                    .and_then(|a| {
                        let c: Vec<f32> = a.iter().filter_map(|x| x.as_f64()).map(|x| x as f32).collect();
                        <[f32; 3]>::try_from(c).ok()
                    })
                    .filter(|c| c.iter().all(|x| *x > 0.0 && *x <= 1.0))
                    .ok_or_else(|| self.err(vkey("attenuationColor"), format!("{v} is not three numbers in (0, 1]")))?,
            };
            absorption = colour.map(|c| -c.ln() / distance);
        }
        if !dropped.is_empty() {
            let glass = match kind {
                MaterialKind::Dielectric => "smooth",
                MaterialKind::RoughDielectric => "rough",
                _ => "smooth thin-walled",
            };
            self.warn(at, format!("approximate: rendered as {glass} glass without {}", dropped.join(", ")));
        }
        Ok((ior, Some((kind, absorption))))
    }

    fn alpha(&mut self, m: &gltf::Material, at: &str) -> Result<Option<AlphaMask>, SceneError> {
        let mode = match m.alpha_mode() {
            gltf::material::AlphaMode::Opaque => return Ok(None),
            gltf::material::AlphaMode::Mask => AlphaMode::Mask { cutoff: m.alpha_cutoff().unwrap_or(0.5) },
            gltf::material::AlphaMode::Blend => AlphaMode::Blend,
        };
        if let AlphaMode::Mask { cutoff } = mode {
            if !(0.0..=1.0).contains(&cutoff) {
                return Err(self.err(format!("{at}.alphaCutoff"), format!("{cutoff} is outside [0, 1]")));
            }
        }
        let pbr = m.pbr_metallic_roughness();
        let factor = pbr.base_color_factor()[3];
        let value = match pbr.base_color_texture() {
            Some(info) => match self.texture_alpha(&info, &format!("{at}.pbrMetallicRoughness.baseColorTexture"))? {
                (Some(img), path) => {
                    let data = img.data.iter().map(|p| [p[0] * factor; 3]).collect();
                    ScalarValue::Texture(sampled(path, Image { data, ..img }, &info.texture(), info_set(&info)))
                }
                (None, _) => ScalarValue::Constant(factor),
            },
            None => ScalarValue::Constant(factor),
        };
        Ok(Some(AlphaMask { value, mode }).filter(|a| !a.never_cuts()))
    }

    fn camera(&mut self, camera: &gltf::Camera, world: Mat4) -> Result<(), SceneError> {
        let at = format!("cameras[{}]", camera.index());
        // A perspective camera's field of view, or an orthographic one's view height (twice
        // ymag; its film's aspect ratio is xmag / ymag), and the aspect ratio its film
        // should have.
        let (fov_y, ortho_height, aspect) = match camera.projection() {
            gltf::camera::Projection::Perspective(p) => {
                let fov_y = p.yfov().to_degrees();
                if !(fov_y > 0.0 && fov_y < 180.0) {
                    return Err(self.err(format!("{at}.perspective.yfov"), format!("{} radians is outside (0, π)", p.yfov())));
                }
                (fov_y, None, p.aspect_ratio())
            }
            gltf::camera::Projection::Orthographic(o) => {
                for (name, v) in [("xmag", o.xmag()), ("ymag", o.ymag())] {
                    if !(v.is_finite() && v > 0.0) {
                        return Err(self.err(format!("{at}.orthographic.{name}"), format!("{v} is not a positive number")));
                    }
                }
                (0.0, Some(2.0 * o.ymag()), Some(o.xmag() / o.ymag()))
            }
        };
        let origin = world.transform_point3(Vec3::ZERO);
        let forward = world.transform_vector3(Vec3::NEG_Z);
        let up = world.transform_vector3(Vec3::Y);
        let mut sensor =
            Sensor::looking_at(origin, origin + forward, up, fov_y).map_err(|e| self.err(&at, format!("its node's transform is degenerate: {e}")))?;
        sensor.ortho_height = ortho_height;
        if self.out.sensors.is_empty() {
            let side = GLTF_FILM_SIDE as f32;
            self.out.film = Some(match aspect {
                Some(a) if a.is_finite() && a >= 1.0 => Film { width: GLTF_FILM_SIDE, height: ((side / a).round() as u32).max(1) },
                Some(a) if a.is_finite() && a > 0.0 => Film { width: ((side * a).round() as u32).max(1), height: GLTF_FILM_SIDE },
                _ => Film { width: GLTF_FILM_SIDE, height: GLTF_FILM_SIDE },
            });
        }
        self.out.sensors.push(sensor);
        Ok(())
    }

    fn light(&mut self, light: &gltf::khr_lights_punctual::Light, world: Mat4, node: usize) -> Result<(), SceneError> {
        use gltf::khr_lights_punctual::Kind;
        let at = format!("extensions.KHR_lights_punctual.lights[{}]", light.index());
        if light.range().is_some() {
            self.warn(&at, "range is ignored: the light falls off with the inverse square of distance everywhere");
        }
        let kind = match light.kind() {
            Kind::Point => LightKind::Point,
            Kind::Directional => LightKind::Directional,
            Kind::Spot { inner_cone_angle, outer_cone_angle } => {
                LightKind::Spot { inner: inner_cone_angle, outer: outer_cone_angle, falloff: SpotFalloff::Smooth }
            }
        };
        let direction =
            world.transform_vector3(Vec3::NEG_Z).try_normalize().ok_or_else(|| self.err(format!("nodes[{node}]"), "degenerate transform of a light"))?;
        let name = match light.name() {
            Some(n) if self.out.lights.iter().any(|l| l.name == n) => format!("{n}#{}", light.index()),
            Some(n) => n.to_string(),
            None => format!("light{}", light.index()),
        };
        self.out.lights.push(Light { name, kind, position: world.transform_point3(Vec3::ZERO), direction, color: light.color(), intensity: light.intensity() });
        self.sources.lights.push(light.index());
        Ok(())
    }

    /// Mesh names made unique where `#<node>` was not enough (a node instanced twice).
    fn uniquify(&mut self) {
        let mut seen = HashSet::new();
        for m in &mut self.out.meshes {
            let mut k = 1;
            let base = m.name.clone();
            while !seen.insert(m.name.clone()) {
                k += 1;
                m.name = format!("{base}#{k}");
            }
        }
    }
}
