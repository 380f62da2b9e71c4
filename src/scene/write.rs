//! The recovered scene written back: `OUTDIR/final/` holds `scene.toml` (the project's
//! format, self-contained but for the original OBJ files of a TOML scene: imported meshes
//! as OBJ in `meshes/`, every texture as EXR in `textures/`), and for a glTF scene (or a
//! TOML that imports one) `scene.gltf`: the source document with the recovered factors,
//! textures and lights written into it, its buffers and images beside it; for a Mitsuba
//! scene `scene.xml`, the source file with the recovered values ([`super::write_xml`]).
//!
//! In the glTF, recovered textures are PNG: base colour and emission sRGB-encoded (an
//! emission texture divided by its peak where that is above 1, the peak going into
//! `KHR_materials_emissive_strength`), roughness and metallic packed into the G and B
//! channels of a linear metallic-roughness texture (the other channel from the material's
//! other value); 8 bits per channel, so a texture round-trips to within 1/255 of its range
//! (the TOML's EXRs hold the exact values). Constant factors,
//! emission (with `KHR_materials_emissive_strength` above 1) and light values round-trip
//! exactly. The environment has no glTF counterpart and is written to the TOML only.
//!
//! `final/` is written into `final.tmp/` and renamed into place, so it is either the old
//! directory or the complete new one.

use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use super::model::*;
use super::{MaterialKind, SceneError};
use crate::image::{self, Image};
use crate::tensor::ParamValue;

/// A recovered parameter's value as an image (a 2-D shape), or None.
fn value_image(v: &ParamValue) -> Option<Image> {
    let [width, height] = v.shape.texture_size()?;
    let c = v.shape.channels() as usize;
    let data = v.data.chunks(c).map(|t| if c == 1 { [t[0]; 3] } else { [t[0], t[1], t[2]] }).collect();
    Some(Image { width, height, data })
}

fn write_err(path: &Path, message: impl std::fmt::Display) -> SceneError {
    SceneError::Write { path: path.to_path_buf(), message: message.to_string() }
}

/// A name made safe for a file name: ASCII letters, digits, `-` and `.` kept, every other
/// character `_` (a run's `params/` and checkpoint files use it too).
pub(crate) fn file_name(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '.' { c } else { '_' }).collect()
}

/// `scene` with every recovered value in place of the scene's own. Recovered textures get
/// the path `textures/<parameter>.exr` (where [`write_final`] puts them) and the filter,
/// wrap modes and coordinate set of the scene's value.
pub fn apply(scene: &Scene, values: &[(ParamTarget, ParamValue)]) -> Scene {
    let mut out = scene.clone();
    for (target, value) in values {
        let name = scene.optimise.params.iter().find(|p| p.target == *target).map_or("param".to_string(), |p| p.name.clone());
        let (filter, wrap, uv_set) = target.sampler(scene);
        let path = PathBuf::from(format!("textures/{}.exr", file_name(&name)));
        let texture = value_image(value).map(|image| Texture { path, image: image.into(), filter, wrap, uv_set });
        target.set(&mut out, value, texture);
    }
    out.content_hash = super::hash::content_hash(&out);
    out
}

/// Writes `out_dir/final/` for `scene` with the recovered `values` (see the module
/// documentation).
pub fn write_final(out_dir: &Path, scene: &Scene, values: &[(ParamTarget, ParamValue)]) -> Result<(), SceneError> {
    let recovered = apply(scene, values);
    let tmp = out_dir.join("final.tmp");
    let _ = std::fs::remove_dir_all(&tmp);
    for sub in ["meshes", "textures", "grids"] {
        std::fs::create_dir_all(tmp.join(sub)).map_err(|e| write_err(&tmp, e))?;
    }
    let toml = toml_text(&recovered, &tmp)?;
    image::write_bytes_atomic(&tmp.join("scene.toml"), toml.as_bytes()).map_err(|e| write_err(&tmp.join("scene.toml"), e))?;
    if let Source::Gltf(source) = &scene.source {
        write_gltf(&tmp, source, &recovered, values)?;
    }
    if let Source::Mitsuba(source) = &scene.source {
        super::write_xml::write_mitsuba(&tmp, source, &recovered, values, &|name, image| exr(&tmp, name, image))?;
    }
    let dst = out_dir.join("final");
    let old = out_dir.join("final.old");
    let _ = std::fs::remove_dir_all(&old);
    if dst.exists() {
        std::fs::rename(&dst, &old).map_err(|e| write_err(&dst, e))?;
    }
    std::fs::rename(&tmp, &dst).map_err(|e| write_err(&dst, e))?;
    let _ = std::fs::remove_dir_all(&old);
    Ok(())
}

/// An f32 as the TOML/JSON number that prints shortest and reads back as the same f32.
fn num(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(v as f64)
}

fn arr(v: &[f32]) -> toml::Value {
    toml::Value::Array(v.iter().map(|&x| toml::Value::Float(num(x))).collect())
}

/// Writes `t` as `textures/<name>.exr` under `dir` and returns the relative path.
fn exr(dir: &Path, name: &str, image: &Image) -> Result<String, SceneError> {
    let rel = format!("textures/{}.exr", file_name(name));
    image::write_exr(&dir.join(&rel), image).map_err(|e| write_err(&dir.join(&rel), e))?;
    Ok(rel)
}

/// The recovered scene as `scene.toml`, its textures and imported meshes written beside it
/// in `dir`. Not split: one block per table of the format, in the format's order, so that
/// the writer reads against the loader.
fn toml_text(scene: &Scene, dir: &Path) -> Result<String, SceneError> {
    use toml::{Table, Value};
    let table = |pairs: Vec<(&str, Value)>| -> Value { Value::Table(pairs.into_iter().map(|(k, v)| (k.to_string(), v)).collect::<Table>()) };
    // `{ texture = file, filter = …, wrap = …, uv_set = … }` (the filter, wrap modes and
    // coordinate set only where they are not the defaults) with `more` after.
    let texture_table = |file: String, t: &Texture, more: Vec<(&str, Value)>| -> Value {
        let mut pairs = vec![("texture", Value::String(file))];
        if t.filter != Filter::Bilinear {
            pairs.push(("filter", Value::String(t.filter.name().into())));
        }
        match t.wrap {
            [Wrap::Repeat, Wrap::Repeat] => {}
            [u, v] if u == v => pairs.push(("wrap", Value::String(u.name().into()))),
            [u, v] => pairs.push(("wrap", Value::Array(vec![Value::String(u.name().into()), Value::String(v.name().into())]))),
        }
        if t.uv_set != 0 {
            pairs.push(("uv_set", Value::Integer(t.uv_set.into())));
        }
        pairs.extend(more);
        table(pairs)
    };
    let mut root = Table::new();
    let mut film = vec![("width", Value::Integer(scene.film.width.into())), ("height", Value::Integer(scene.film.height.into()))];
    match scene.pixel_filter {
        PixelFilter::Box => {}
        PixelFilter::Gaussian { stddev } => film.extend([("filter", Value::String("gaussian".into())), ("filter_stddev", Value::Float(num(stddev)))]),
        PixelFilter::Tent { radius } => film.extend([("filter", Value::String("tent".into())), ("filter_radius", Value::Float(num(radius)))]),
    }
    root.insert("film".into(), table(film));
    let mut integrator = vec![("max_depth", Value::Integer(scene.integrator.max_depth.into())), ("rr_depth", Value::Integer(scene.integrator.rr_depth.into()))];
    if scene.integrator.hide_emitters {
        integrator.push(("hide_emitters", Value::Boolean(true)));
    }
    root.insert("integrator".into(), table(integrator));
    let sensors = scene
        .sensors
        .iter()
        .map(|s| {
            let projection = match s.ortho_height {
                Some(h) => ("ortho_height", Value::Float(num(h))),
                None => ("fov_y", Value::Float(num(s.fov_y))),
            };
            let mut pairs = vec![("origin", arr(&s.origin.to_array())), ("target", arr(&s.look_at.to_array())), ("up", arr(&s.up.to_array())), projection];
            if let Some(lens) = s.lens {
                pairs.push(("aperture_radius", Value::Float(num(lens.aperture_radius))));
                pairs.push(("focus_distance", Value::Float(num(lens.focus_distance))));
            }
            table(pairs)
        })
        .collect();
    root.insert("sensors".into(), Value::Array(sensors));
    let mut materials = Vec::new();
    for m in &scene.materials {
        let tex = |what: &str, t: &Texture| -> Result<Value, SceneError> { Ok(texture_table(exr(dir, &format!("{}.{what}", m.name), &t.image)?, t, vec![])) };
        let mut pairs = vec![("name", Value::String(m.name.clone())), ("type", Value::String(m.kind.as_str().into()))];
        pairs.push((
            "base_color",
            match &m.base_color {
                ColorValue::Constant(c) => arr(c),
                ColorValue::Texture(t) => tex("base_color", t)?,
            },
        ));
        if m.one_sided {
            pairs.push(("one_sided", Value::Boolean(true)));
        }
        match &m.perturbation {
            None => {}
            Some(Perturbation::Normal(n)) => {
                let file = exr(dir, &format!("{}.normal_map", m.name), &n.texture.image)?;
                let mut map = vec![("scale", Value::Float(num(n.scale)))];
                if n.bitangent != Bitangent::Uv {
                    map.push(("bitangent", Value::String(n.bitangent.as_str().into())));
                }
                pairs.push(("normal_map", texture_table(file, &n.texture, map)));
            }
            Some(Perturbation::Bump(b)) => {
                let file = exr(dir, &format!("{}.bump_map", m.name), &b.texture.image)?;
                pairs.push(("bump_map", texture_table(file, &b.texture, vec![("scale", Value::Float(num(b.scale)))])));
            }
        }
        let scalar = |key: &str, v: &ScalarValue| -> Result<Value, SceneError> {
            Ok(match v {
                ScalarValue::Constant(c) => Value::Float(num(*c)),
                ScalarValue::Texture(t) => tex(key, t)?,
            })
        };
        if m.kind.has_roughness() || m.kind == MaterialKind::Plastic {
            pairs.push(("roughness", scalar("roughness", &m.roughness)?));
        }
        if m.kind == MaterialKind::Principled {
            pairs.push(("metallic", scalar("metallic", &m.metallic)?));
        }
        // A principled material's default index is left implicit.
        if m.kind.has_ior() && !(m.kind == MaterialKind::Principled && m.ior == DEFAULT_IOR) {
            pairs.push(("ior", Value::Float(num(m.ior))));
        }
        if m.nonlinear {
            pairs.push(("nonlinear", Value::Boolean(true)));
        }
        if !m.layered {
            pairs.push(("layered", Value::Boolean(false)));
        }
        if m.specular != [1.0; 3] {
            pairs.push(("specular", arr(&m.specular)));
        }
        if m.absorption != [0.0; 3] {
            pairs.push(("absorption", arr(&m.absorption)));
        }
        if m.distribution != Distribution::Ggx {
            pairs.push(("distribution", Value::String(m.distribution.as_str().into())));
        }
        if m.kind == MaterialKind::Conductor {
            pairs.push(("eta", arr(&m.eta)));
            pairs.push(("k", arr(&m.k)));
        }
        if let Some(a) = &m.alpha {
            pairs.push(("alpha", scalar("alpha", &a.value)?));
            pairs.push(("alpha_mode", Value::String(a.mode.as_str().into())));
            if let AlphaMode::Mask { cutoff } = a.mode {
                pairs.push(("alpha_cutoff", Value::Float(num(cutoff))));
            }
        }
        materials.push(table(pairs));
    }
    root.insert("materials".into(), Value::Array(materials));
    let mut meshes = Vec::new();
    for m in &scene.meshes {
        let is_obj = m.path.extension().is_some_and(|e| e.eq_ignore_ascii_case("obj"));
        let file = if scene.source == Source::Toml && is_obj {
            // A TOML scene's OBJ files hold its meshes as they are: refer to them.
            std::fs::canonicalize(&m.path).map_err(|e| write_err(&m.path, e))?.display().to_string()
        } else {
            let rel = format!("meshes/{}.obj", file_name(&m.name));
            image::write_bytes_atomic(&dir.join(&rel), obj_text(m).as_bytes()).map_err(|e| write_err(&dir.join(&rel), e))?;
            rel
        };
        let mut pairs = vec![
            ("name", Value::String(m.name.clone())),
            ("file", Value::String(file)),
            ("material", Value::String(scene.materials[m.material].name.clone())),
            (
                "emission",
                match &m.emission {
                    ColorValue::Constant(c) => arr(c),
                    ColorValue::Texture(t) => texture_table(exr(dir, &format!("{}.emission", m.name), &t.image)?, t, vec![]),
                },
            ),
        ];
        if m.two_sided_emission {
            pairs.push(("two_sided", Value::Boolean(true)));
        }
        // The second set of texture coordinates, per corner in the OBJ's face order (an
        // OBJ file holds one set).
        let corners = m.corner_uvs1();
        if !corners.is_empty() {
            let rel = format!("meshes/{}.uv1.npy", file_name(&m.name));
            let array = crate::npy::Array { shape: vec![corners.len(), 3, 2], data: corners.as_flattened().as_flattened().to_vec() };
            crate::npy::write(&dir.join(&rel), &array).map_err(|e| write_err(&dir.join(&rel), e))?;
            pairs.push(("uv1", Value::String(rel)));
        }
        meshes.push(table(pairs));
    }
    root.insert("meshes".into(), Value::Array(meshes));
    let lights: Vec<Value> = scene
        .lights
        .iter()
        .map(|l| {
            let mut pairs = vec![
                ("name", Value::String(l.name.clone())),
                ("type", Value::String(l.kind.as_str().into())),
                ("color", arr(&l.color)),
                ("intensity", Value::Float(num(l.intensity))),
            ];
            if l.kind != LightKind::Directional {
                pairs.push(("position", arr(&l.position.to_array())));
            }
            if l.kind != LightKind::Point {
                pairs.push(("direction", arr(&l.direction.to_array())));
            }
            if let LightKind::Spot { inner, outer, falloff } = l.kind {
                pairs.push(("inner_angle", Value::Float(num(inner.to_degrees()))));
                pairs.push(("outer_angle", Value::Float(num(outer.to_degrees()))));
                pairs.push(("falloff", Value::String(falloff.as_str().into())));
            }
            table(pairs)
        })
        .collect();
    if !lights.is_empty() {
        root.insert("lights".into(), Value::Array(lights));
    }
    let env = match &scene.environment.value {
        ColorValue::Constant(c) => ("constant", arr(c)),
        ColorValue::Texture(t) => ("file", Value::String(exr(dir, "environment", &t.image)?)),
    };
    root.insert("environment".into(), table(vec![env, ("scale", Value::Float(num(scene.environment.scale)))]));
    let mut media = Vec::new();
    for m in &scene.media {
        let mut pairs = vec![("name", Value::String(m.name.clone())), ("min", arr(&m.min)), ("max", arr(&m.max))];
        if let Some(b) = &m.boundary {
            // The boundary as the scene holds it: welded, wound out, in world space.
            let rel = format!("meshes/{}.boundary.obj", file_name(&m.name));
            image::write_bytes_atomic(&dir.join(&rel), boundary_obj_text(b).as_bytes()).map_err(|e| write_err(&dir.join(&rel), e))?;
            pairs.push(("mesh", Value::String(rel)));
        }
        // A scattering medium's albedo in place of the emission (it emits nothing).
        let grids =
            if m.scatters() { [("density", &m.density, 0), ("albedo", &m.albedo, 2)] } else { [("density", &m.density, 0), ("emission", &m.emission, 1)] };
        for (key, v, k) in grids {
            let value = if v.shape.is_constant() {
                if v.data.len() == 1 {
                    Value::Float(num(v.data[0]))
                } else {
                    arr(&v.data)
                }
            } else {
                // Each grid goes back in the format it came in.
                let format = m.formats[k];
                let rel = format!("grids/{}.{}", file_name(&format!("{}.{key}", m.name)), format.extension());
                let path = dir.join(&rel);
                match format {
                    GridFormat::Npy => {
                        let array = crate::npy::Array { shape: v.shape.array(), data: v.data.clone() };
                        crate::npy::write(&path, &array).map_err(|e| write_err(&path, e))?;
                    }
                    GridFormat::Vol => {
                        let [x, y, z] = super::media::grid_dims(v.shape).map(|d| d as u32);
                        let bbox = [m.min[0], m.min[1], m.min[2], m.max[0], m.max[1], m.max[2]];
                        let grid = crate::vol::Grid { size: [x, y, z], channels: v.shape.channels(), bbox, data: v.data.clone() };
                        crate::vol::write(&path, &grid).map_err(|e| write_err(&path, e))?;
                    }
                }
                Value::String(rel)
            };
            pairs.push((key, value));
        }
        pairs.push(("scale", Value::Float(num(m.scale))));
        pairs.push(("step", Value::Float(num(m.step))));
        if m.scatters() {
            pairs.push(("g", Value::Float(num(m.g))));
            if let Some(b) = m.majorant {
                pairs.push(("majorant", Value::Float(num(b))));
            }
        }
        media.push(table(pairs));
    }
    if !media.is_empty() {
        root.insert("media".into(), Value::Array(media));
    }
    let text = toml::to_string(&root).map_err(|e| write_err(dir, e))?;
    Ok(format!("# The recovered scene: the optimised values in place of the scene's own.\n{text}"))
}

/// A medium's boundary as OBJ text, positions shortest-exact.
fn boundary_obj_text(b: &MediumBoundary) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    for p in &b.positions {
        let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
    }
    for t in &b.indices {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s
}

/// A mesh as OBJ text, positions, texture coordinates and normals shortest-exact.
fn obj_text(m: &Mesh) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    for p in &m.positions {
        let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
    }
    for t in &m.uvs {
        let _ = writeln!(s, "vt {} {}", t[0], t[1]);
    }
    for n in &m.normals {
        let _ = writeln!(s, "vn {} {} {}", n[0], n[1], n[2]);
    }
    for tri in &m.indices {
        let corner = |i: u32| {
            let k = i + 1;
            match (m.uvs.is_empty(), m.normals.is_empty()) {
                (true, true) => format!("{k}"),
                (false, true) => format!("{k}/{k}"),
                (true, false) => format!("{k}//{k}"),
                (false, false) => format!("{k}/{k}/{k}"),
            }
        };
        let _ = writeln!(s, "f {} {} {}", corner(tri[0]), corner(tri[1]), corner(tri[2]));
    }
    s
}

// ---------------------------------------------------------------------------------------
// glTF
// ---------------------------------------------------------------------------------------

/// The source glTF's JSON and, for a GLB, its binary chunk.
fn read_gltf(path: &Path) -> Result<(Value, Option<Vec<u8>>), SceneError> {
    let bytes = std::fs::read(path).map_err(|e| write_err(path, e))?;
    let (json, blob) = if bytes.starts_with(b"glTF") {
        let glb = gltf::binary::Glb::from_slice(&bytes).map_err(|e| write_err(path, e))?;
        (glb.json.into_owned(), glb.bin.map(|b| b.into_owned()))
    } else {
        (bytes, None)
    };
    Ok((serde_json::from_slice(&json).map_err(|e| write_err(path, e))?, blob))
}

/// Copies the file at `uri` (relative to `from`) into `to`, as `prefix` + its file name,
/// and returns the new relative URI; data URIs stay as they are.
fn carry(uri: &str, from: &Path, to: &Path, prefix: &str) -> Result<String, SceneError> {
    if uri.starts_with("data:") {
        return Ok(uri.to_string());
    }
    let decoded = urlencoding_decode(uri);
    let src = from.join(&decoded);
    let name = format!("{prefix}{}", file_name(&Path::new(&decoded).file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default()));
    std::fs::copy(&src, to.join(&name)).map_err(|e| write_err(&src, e))?;
    Ok(name)
}

/// Percent-decoding of a relative URI (glTF URIs are RFC 3986 references).
fn urlencoding_decode(uri: &str) -> String {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |b: u8| (b as char).to_digit(16);
        if bytes[i] == b'%' && i + 2 < bytes.len() {
            if let (Some(h), Some(l)) = (hex(bytes[i + 1]), hex(bytes[i + 2])) {
                out.push((h * 16 + l) as u8);
                i += 3;
                continue;
            }
        }
        out.push(bytes[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The recovered values written into the imported glTF document (`scene.gltf` in `dir`).
/// Not split: one arm per parameter kind, each patching the JSON the way glTF stores that
/// value, around one read and one write of the document.
fn write_gltf(dir: &Path, source: &GltfSource, scene: &Scene, values: &[(ParamTarget, ParamValue)]) -> Result<(), SceneError> {
    let (mut root, blob) = read_gltf(&source.path)?;
    let from = source.path.parent().map(Path::to_path_buf).unwrap_or_default();
    // Buffers and images travel with the document.
    if let Some(buffers) = root.get_mut("buffers").and_then(Value::as_array_mut) {
        for (i, b) in buffers.iter_mut().enumerate() {
            let uri = match b.get("uri").and_then(Value::as_str) {
                Some(uri) => carry(uri, &from, dir, &format!("buffer{i}-"))?,
                None => {
                    let data = blob.as_deref().ok_or_else(|| write_err(&source.path, format!("buffers[{i}] has no uri and the file no binary chunk")))?;
                    let name = "scene.bin".to_string();
                    image::write_bytes_atomic(&dir.join(&name), data).map_err(|e| write_err(&dir.join(&name), e))?;
                    name
                }
            };
            b["uri"] = json!(uri);
        }
    }
    if let Some(images) = root.get_mut("images").and_then(Value::as_array_mut) {
        for (i, img) in images.iter_mut().enumerate() {
            if let Some(uri) = img.get("uri").and_then(Value::as_str) {
                let new = carry(uri, &from, dir, &format!("image{i}-"))?;
                img["uri"] = json!(new);
            }
        }
    }
    let material_of = |m: usize| source.materials.get(m).copied().flatten();
    for (target, _) in values {
        match *target {
            ParamTarget::BaseColor { material } => {
                let Some(g) = material_of(material) else { continue };
                let m = &scene.materials[material];
                let name = format!("{}.base_color", m.name);
                // A textured alpha lives in the base colour texture's alpha channel: the
                // written texture carries it (its factor then 1). (A glTF material with a
                // textured alpha has a textured base colour, which is optimised as a
                // texture: the loader refuses a constant for it.)
                let alpha_texture = match &m.alpha {
                    Some(AlphaMask { value: ScalarValue::Texture(a), .. }) => Some(&*a.image),
                    _ => None,
                };
                match (&m.base_color, alpha_texture) {
                    (ColorValue::Constant(c), _) => {
                        let pbr = pbr(&mut root, g);
                        let alpha = pbr.get("baseColorFactor").and_then(|f| f.get(3)).and_then(Value::as_f64).unwrap_or(1.0);
                        pbr["baseColorFactor"] = json!([num(c[0]), num(c[1]), num(c[2]), alpha]);
                        if let Some(obj) = pbr.as_object_mut() {
                            obj.remove("baseColorTexture");
                        }
                    }
                    (ColorValue::Texture(t), alpha_texture) => {
                        let index = add_png(&mut root, dir, &name, &t.image, true, alpha_texture, (t.filter, t.wrap))?;
                        let pbr = pbr(&mut root, g);
                        let alpha = match alpha_texture {
                            Some(_) => 1.0,
                            None => pbr.get("baseColorFactor").and_then(|f| f.get(3)).and_then(Value::as_f64).unwrap_or(1.0),
                        };
                        pbr["baseColorFactor"] = json!([1.0, 1.0, 1.0, alpha]);
                        pbr["baseColorTexture"] = texture_info(pbr.get("baseColorTexture"), index, t.uv_set);
                    }
                }
            }
            ParamTarget::Roughness { material } | ParamTarget::Metallic { material } => {
                let Some(g) = material_of(material) else { continue };
                let m = &scene.materials[material];
                match (&m.roughness, &m.metallic) {
                    (ScalarValue::Constant(rough), ScalarValue::Constant(metal)) => {
                        let pbr = pbr(&mut root, g);
                        pbr["roughnessFactor"] = json!(num(*rough));
                        pbr["metallicFactor"] = json!(num(*metal));
                        if let Some(obj) = pbr.as_object_mut() {
                            obj.remove("metallicRoughnessTexture");
                        }
                    }
                    (rough, metal) => {
                        let packed = pack_metallic_roughness(rough, metal);
                        // One texture holds both: nearest where either is, the wrap modes
                        // of the textured one (the roughness where both are).
                        let filter = if rough.filter() == Filter::Nearest || metal.filter() == Filter::Nearest { Filter::Nearest } else { Filter::Bilinear };
                        let wrap = if matches!(rough, ScalarValue::Texture(_)) { rough.wrap() } else { metal.wrap() };
                        let index = add_png(&mut root, dir, &format!("{}.metallic_roughness", m.name), &packed, false, None, (filter, wrap))?;
                        let pbr = pbr(&mut root, g);
                        pbr["roughnessFactor"] = json!(1.0);
                        pbr["metallicFactor"] = json!(1.0);
                        let set = if matches!(rough, ScalarValue::Texture(_)) { rough.uv_set() } else { metal.uv_set() };
                        pbr["metallicRoughnessTexture"] = texture_info(pbr.get("metallicRoughnessTexture"), index, set);
                    }
                }
            }
            ParamTarget::Emission { mesh } => {
                let Some(g) = material_of(scene.meshes[mesh].material) else { continue };
                let mesh = &scene.meshes[mesh];
                // glTF's factor and texture are in [0, 1]: a brighter emission moves its peak
                // into KHR_materials_emissive_strength.
                let set = mesh.emission.uv_set();
                let (e, texture) = match &mesh.emission {
                    ColorValue::Constant(c) => (*c, None),
                    ColorValue::Texture(t) => {
                        let peak = t.image.data.iter().flatten().copied().fold(0.0f32, f32::max);
                        let scale = if peak > 1.0 { 1.0 / peak } else { 1.0 };
                        let scaled = Image { data: t.image.data.iter().map(|p| p.map(|c| c * scale)).collect(), width: t.image.width, height: t.image.height };
                        let index = add_png(&mut root, dir, &format!("{}.emission", mesh.name), &scaled, true, None, (t.filter, t.wrap))?;
                        ([peak.max(1.0); 3], Some(index))
                    }
                };
                let strength = e.iter().copied().fold(0.0f32, f32::max);
                let m = &mut root["materials"][g];
                match texture {
                    Some(index) => m["emissiveTexture"] = texture_info(m.get("emissiveTexture"), index, set),
                    None => {
                        if let Some(obj) = m.as_object_mut() {
                            obj.remove("emissiveTexture");
                        }
                    }
                }
                if strength > 1.0 {
                    m["emissiveFactor"] = json!([num(e[0] / strength), num(e[1] / strength), num(e[2] / strength)]);
                    m["extensions"]["KHR_materials_emissive_strength"] = json!({ "emissiveStrength": num(strength) });
                    used(&mut root, "KHR_materials_emissive_strength");
                } else {
                    m["emissiveFactor"] = json!([num(e[0]), num(e[1]), num(e[2])]);
                    if let Some(ext) = m.get_mut("extensions").and_then(Value::as_object_mut) {
                        ext.remove("KHR_materials_emissive_strength");
                    }
                }
            }
            ParamTarget::LightColor { light } | ParamTarget::LightIntensity { light } => {
                let Some(&g) = source.lights.get(light) else { continue };
                let l = &scene.lights[light];
                // glTF colours are in [0, 1]: a brighter recovered colour moves into the
                // intensity.
                let peak = l.color.iter().copied().fold(0.0f32, f32::max);
                let (color, intensity) = if peak > 1.0 { (l.color.map(|c| c / peak), l.intensity * peak) } else { (l.color, l.intensity) };
                let entry = &mut root["extensions"]["KHR_lights_punctual"]["lights"][g];
                entry["color"] = json!([num(color[0]), num(color[1]), num(color[2])]);
                entry["intensity"] = json!(num(intensity));
            }
            ParamTarget::Environment | ParamTarget::MediumDensity { .. } | ParamTarget::MediumEmission { .. } | ParamTarget::MediumAlbedo { .. } => {}
        }
    }
    let text = serde_json::to_string_pretty(&root).map_err(|e| write_err(dir, e))?;
    let path = dir.join("scene.gltf");
    image::write_bytes_atomic(&path, text.as_bytes()).map_err(|e| write_err(&path, e))
}

/// `materials[g].pbrMetallicRoughness`, created if absent.
fn pbr(root: &mut Value, g: usize) -> &mut Value {
    let m = &mut root["materials"][g];
    if !m.get("pbrMetallicRoughness").is_some_and(Value::is_object) {
        m["pbrMetallicRoughness"] = json!({});
    }
    &mut m["pbrMetallicRoughness"]
}

fn used(root: &mut Value, ext: &str) {
    if !root.get("extensionsUsed").is_some_and(Value::is_array) {
        root["extensionsUsed"] = json!([]);
    }
    if let Some(list) = root["extensionsUsed"].as_array_mut() {
        if !list.iter().any(|v| v == ext) {
            list.push(json!(ext));
        }
    }
}

/// Roughness in G and metallic in B (R is unused, 0) at the larger texture's size, the
/// other value sampled nearest or constant.
fn pack_metallic_roughness(rough: &ScalarValue, metal: &ScalarValue) -> Image {
    let size = |v: &ScalarValue| match v {
        ScalarValue::Texture(t) => (t.image.width, t.image.height),
        ScalarValue::Constant(_) => (1, 1),
    };
    let (w, h) = {
        let (a, b) = (size(rough), size(metal));
        (a.0.max(b.0), a.1.max(b.1))
    };
    let at = |v: &ScalarValue, x: u32, y: u32| match v {
        ScalarValue::Constant(c) => *c,
        ScalarValue::Texture(t) => t.image.get((x * t.image.width / w).min(t.image.width - 1), (y * t.image.height / h).min(t.image.height - 1))[0],
    };
    let data = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| [0.0, at(rough, x, y), at(metal, x, y)]).collect();
    Image { width: w, height: h, data }
}

/// Writes `img` as `textures/<name>.png` (sRGB-encoded if `srgb`, else linear 8-bit), with
/// `alpha`'s R channel (resampled to `img`'s size, nearest texel) as its alpha channel
/// where given, and adds an image and a texture referring to it (with a sampler whose
/// magnification filter is NEAREST for [`Filter::Nearest`] and whose wrapping modes are
/// `wrap`'s, where these are not the defaults); returns the texture index.
#[allow(clippy::too_many_arguments)]
fn add_png(
    root: &mut Value,
    dir: &Path,
    name: &str,
    img: &Image,
    srgb: bool,
    alpha: Option<&Image>,
    (filter, wrap): (Filter, [Wrap; 2]),
) -> Result<usize, SceneError> {
    let rel = format!("textures/{}.png", file_name(name));
    let path = dir.join(&rel);
    let encoded = if srgb { img.clone() } else { Image { data: img.data.iter().map(|p| p.map(image::srgb_decode)).collect(), ..img.clone() } };
    let alpha = alpha.map(|a| a.resample(1, img.width, img.height));
    // write_png encodes with the sRGB curve; a linear texture is pre-decoded so that the
    // stored bytes are its linear values.
    image::write_png_with_alpha(&path, &encoded, alpha.as_deref()).map_err(|e| write_err(&path, e))?;
    let image_index = push(root, "images", json!({ "uri": rel }));
    let texture = if filter == Filter::Bilinear && wrap == [Wrap::Repeat; 2] {
        json!({ "source": image_index })
    } else {
        // glTF's codes: NEAREST 9728; REPEAT 10497, CLAMP_TO_EDGE 33071, MIRRORED_REPEAT 33648.
        let code = |w: Wrap| match w {
            Wrap::Repeat => 10497,
            Wrap::Clamp => 33071,
            Wrap::Mirror => 33648,
        };
        let mut sampler = json!({ "wrapS": code(wrap[0]), "wrapT": code(wrap[1]) });
        if filter == Filter::Nearest {
            sampler["magFilter"] = json!(9728);
            sampler["minFilter"] = json!(9728);
        }
        let sampler = push(root, "samplers", sampler);
        json!({ "source": image_index, "sampler": sampler })
    };
    Ok(push(root, "textures", texture))
}

/// A texture reference to texture `index` in place of `old`: `old`'s other properties kept
/// (its coordinate set and its `KHR_texture_transform`, which the scene's texture
/// coordinates were read with), else one that reads coordinate set `uv_set`.
fn texture_info(old: Option<&Value>, index: usize, uv_set: u32) -> Value {
    match old {
        Some(v @ Value::Object(_)) => {
            let mut v = v.clone();
            v["index"] = json!(index);
            v
        }
        _ if uv_set != 0 => json!({ "index": index, "texCoord": uv_set }),
        _ => json!({ "index": index }),
    }
}

/// Appends `v` to the array `root[key]` (created if absent) and returns its index.
fn push(root: &mut Value, key: &str, v: Value) -> usize {
    match root.get_mut(key).and_then(Value::as_array_mut) {
        Some(list) => {
            list.push(v);
            list.len() - 1
        }
        None => {
            root[key] = json!([v]);
            0
        }
    }
}
