//! The recovered scene as Mitsuba XML: `final/scene.xml` is the source file with each
//! recovered value written over the scene's own, so that Mitsuba (and vkinverse) load it
//! as it was, with the new values.
//!
//! - A material's value goes into the BSDF named by its id (a top-level `<bsdf id>`, or the
//!   inline BSDF of a `<shape id>`), through `twosided`, `mask`, `normalmap` and `bumpmap`
//!   wrappers: the base colour as `reflectance` (diffuse), `base_color` (principled),
//!   `specular_reflectance` (conductors), `diffuse_reflectance` (plastics) or
//!   `specular_transmittance` (dielectrics); the roughness as `roughness` (principled) or
//!   `alpha`, its square (rough conductors, plastics and dielectrics); `metallic`.
//! - A mesh's emission goes into its `<shape id>`'s area emitter's `radiance`; a light's
//!   colour × intensity into its `<emitter id>`'s `intensity` or `irradiance`; a constant
//!   environment into the `constant` emitter's `radiance` (times its scale).
//! - A texture is written as `textures/NAME.exr` beside the XML and referred to by a bitmap.
//! - The source's directory comes first among the `<path>`s and includes are made absolute,
//!   so that its meshes and textures resolve from `final/`.
//!
//! A value that has no place in the XML (a material of an unnamed BSDF, one in an included
//! file, a roughness of a smooth BSDF, an environment map) is left as it was, and a comment
//! at the top of the file says so.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;

use roxmltree::{Document, Node};

use super::model::*;
use super::MaterialKind;
use super::SceneError;
use crate::image::Image;
use crate::tensor::ParamValue;

/// Wrappers whose inner `<bsdf>` holds the material's values.
const WRAPPERS: [&str; 4] = ["twosided", "mask", "normalmap", "bumpmap"];

/// What to set on one element: (parameter name, the XML of its new value).
#[derive(Default)]
struct Sets<'a, 'i> {
    node: Option<Node<'a, 'i>>,
    values: Vec<(String, String)>,
}

fn rgb(name: &str, c: [f32; 3]) -> String {
    format!(r#"<rgb name="{name}" value="{}, {}, {}"/>"#, c[0], c[1], c[2])
}

fn float(name: &str, v: f32) -> String {
    format!(r#"<float name="{name}" value="{v}"/>"#)
}

fn bitmap(name: &str, file: &str) -> String {
    format!(r#"<texture type="bitmap" name="{name}"><string name="filename" value="{file}"/></texture>"#)
}

/// Writes a recovered texture (its parameter's name, the image) beside the XML and returns
/// its path relative to it.
pub(super) type WriteTexture<'a> = &'a dyn Fn(&str, &Image) -> Result<String, SceneError>;

/// Writes `dir/scene.xml` from the Mitsuba file `source` with `recovered`'s values of the
/// optimised parameters `values`, their textures through `write_texture`.
pub(super) fn write_mitsuba(
    dir: &Path,
    source: &Path,
    recovered: &Scene,
    values: &[(ParamTarget, ParamValue)],
    write_texture: WriteTexture,
) -> Result<(), SceneError> {
    let werr = |path: &Path, e: &dyn std::fmt::Display| SceneError::Write { path: path.to_path_buf(), message: e.to_string() };
    let text = crate::files::read_to_string(source).map_err(|e| werr(source, &e))?;
    let doc = Document::parse(&text).map_err(|e| werr(source, &e))?;
    let root = doc.root_element();
    let source_dir = std::fs::canonicalize(source.parent().unwrap_or(Path::new("."))).map_err(|e| werr(source, &e))?;
    let mut found: Vec<(Node, &str, String)> = Vec::new();
    let mut skipped = Vec::new();
    for (target, _) in values {
        let pname = recovered.optimise.params.iter().find(|p| p.target == *target).map_or("param".to_string(), |p| p.name.clone());
        let texture = |image: &Image, transform: fn(f32) -> f32| -> Result<String, SceneError> {
            let data = image.data.iter().map(|p| p.map(transform)).collect();
            write_texture(&pname, &Image { width: image.width, height: image.height, data })
        };
        let scalar_xml = |name: &str, v: &ScalarValue, transform: fn(f32) -> f32| -> Result<String, SceneError> {
            Ok(match v {
                ScalarValue::Constant(x) => float(name, transform(*x)),
                ScalarValue::Texture(t) => bitmap(name, &texture(&t.image, transform)?),
            })
        };
        let color_xml = |name: &str, v: &ColorValue| -> Result<String, SceneError> {
            Ok(match v {
                ColorValue::Constant(c) => rgb(name, *c),
                ColorValue::Texture(t) => bitmap(name, &texture(&t.image, |x| x)?),
            })
        };
        match *target {
            ParamTarget::BaseColor { material } | ParamTarget::Roughness { material } | ParamTarget::Metallic { material } => {
                let m = &recovered.materials[material];
                let Some(bsdf) = material_bsdf(root, &m.name) else {
                    skipped.push(format!("{pname}: no <bsdf id=\"{0}\"> or <shape id=\"{0}\"> in this file", m.name));
                    continue;
                };
                let kind = bsdf.attribute("type").unwrap_or_default().to_ascii_lowercase();
                match *target {
                    ParamTarget::BaseColor { .. } => {
                        let name = match m.kind {
                            MaterialKind::Diffuse => "reflectance",
                            MaterialKind::Principled => "base_color",
                            MaterialKind::Conductor => "specular_reflectance",
                            MaterialKind::Plastic => "diffuse_reflectance",
                            _ => "specular_transmittance",
                        };
                        found.push((bsdf, name, color_xml(name, &m.base_color)?));
                    }
                    ParamTarget::Roughness { .. } if kind == "principled" => found.push((bsdf, "roughness", scalar_xml("roughness", &m.roughness, |x| x)?)),
                    ParamTarget::Roughness { .. } if kind.starts_with("rough") || kind == "pplastic" => {
                        found.push((bsdf, "alpha", scalar_xml("alpha", &m.roughness, |x| x * x)?))
                    }
                    ParamTarget::Roughness { .. } => skipped.push(format!("{pname}: the BSDF of \"{}\" is a smooth {kind}", m.name)),
                    _ => found.push((bsdf, "metallic", scalar_xml("metallic", &m.metallic, |x| x)?)),
                }
            }
            ParamTarget::Emission { mesh } => {
                let mesh = &recovered.meshes[mesh];
                match by_id(root, "shape", &mesh.name).and_then(|s| s.children().find(|n| n.tag_name().name() == "emitter")) {
                    Some(e) => found.push((e, "radiance", color_xml("radiance", &mesh.emission)?)),
                    None => skipped.push(format!("{pname}: no <shape id=\"{}\"> with an <emitter> in this file", mesh.name)),
                }
            }
            ParamTarget::LightColor { light } | ParamTarget::LightIntensity { light } => {
                let l = &recovered.lights[light];
                match by_id(root, "emitter", &l.name) {
                    Some(e) => {
                        let name = if e.attribute("type") == Some("directional") { "irradiance" } else { "intensity" };
                        found.push((e, name, rgb(name, l.color.map(|c| c * l.intensity))));
                    }
                    None => skipped.push(format!("{pname}: no <emitter id=\"{}\"> in this file", l.name)),
                }
            }
            ParamTarget::MediumDensity { .. } | ParamTarget::MediumEmission { .. } | ParamTarget::MediumAlbedo { .. } => {
                skipped.push(format!("{pname}: media are written to scene.toml only"))
            }
            ParamTarget::Environment => {
                let constant = root.children().find(|n| n.tag_name().name() == "emitter" && n.attribute("type") == Some("constant"));
                match (constant, &recovered.environment.value) {
                    (Some(e), ColorValue::Constant(c)) => {
                        let scale = recovered.environment.scale;
                        found.push((e, "radiance", rgb("radiance", c.map(|v| v * scale))));
                        found.push((e, "scale", float("scale", 1.0)));
                    }
                    _ => skipped.push(format!("{pname}: the environment is not a constant emitter of this file")),
                }
            }
        }
    }
    let out = edited(&text, root, found, &source_dir, &skipped);
    let path = dir.join("scene.xml");
    crate::image::write_bytes_atomic(&path, out.as_bytes()).map_err(|e| werr(&path, &e))
}

/// The top-level `<tag id="id">`.
fn by_id<'a, 'i>(root: Node<'a, 'i>, tag: &str, id: &str) -> Option<Node<'a, 'i>> {
    root.children().find(|n| n.is_element() && n.tag_name().name() == tag && n.attribute("id") == Some(id))
}

/// The innermost BSDF (inside its wrappers) of material `name`: a top-level `<bsdf id>`, or
/// the inline BSDF of a `<shape id>`.
fn material_bsdf<'a, 'i>(root: Node<'a, 'i>, name: &str) -> Option<Node<'a, 'i>> {
    let inline = || by_id(root, "shape", name).and_then(|s| s.children().find(|n| n.tag_name().name() == "bsdf"));
    let mut bsdf = by_id(root, "bsdf", name).or_else(inline)?;
    while bsdf.attribute("type").is_some_and(|t| WRAPPERS.contains(&t.to_ascii_lowercase().as_str())) {
        match bsdf.children().find(|n| n.tag_name().name() == "bsdf") {
            Some(inner) => bsdf = inner,
            None => break,
        }
    }
    Some(bsdf)
}

/// `text` (whose document's root is `root`) with each (element, parameter, XML) of `found`
/// set (an existing parameter replaced, a missing one added), its includes and search
/// paths absolute, `source_dir` the first search path and `skipped` in a comment.
fn edited(text: &str, root: Node, found: Vec<(Node, &str, String)>, source_dir: &Path, skipped: &[String]) -> String {
    let mut sets: BTreeMap<usize, Sets> = BTreeMap::new();
    for (node, name, xml) in found {
        let entry = sets.entry(node.range().start).or_default();
        entry.node = Some(node);
        entry.values.push((name.to_string(), xml));
    }
    let mut edits: Vec<(Range<usize>, String)> = Vec::new();
    for s in sets.values() {
        let Some(node) = s.node else { continue };
        let mut insert = String::new();
        for (name, xml) in &s.values {
            match node.children().find(|n| n.is_element() && n.attribute("name") == Some(name.as_str())) {
                Some(child) => edits.push((child.range(), xml.clone())),
                None => insert.push_str(xml),
            }
        }
        if insert.is_empty() {
            continue;
        }
        let range = node.range();
        let whole = &text[range.clone()];
        if let Some(open) = whole.strip_suffix("/>") {
            let tag = node.tag_name().name();
            edits.push((range.clone(), format!("{}>{insert}</{tag}>", open.trim_end())));
        } else {
            let at = range.start + whole.find('>').map_or(0, |i| i + 1);
            edits.push((at..at, insert));
        }
    }
    // The source's directory, so that its meshes and textures resolve from here; includes
    // and search paths made absolute.
    for n in root.children().filter(|n| n.is_element()) {
        let attr = match n.tag_name().name() {
            "include" => "filename",
            "path" => "value",
            _ => continue,
        };
        if let Some(a) = n.attributes().find(|a| a.name() == attr) {
            edits.push((a.range_value(), source_dir.join(a.value()).display().to_string()));
        }
    }
    let first = root.first_child().map_or(root.range().end, |c| c.range().start);
    let mut head = format!("\n    <path value=\"{}\"/>\n    ", source_dir.display());
    if !skipped.is_empty() {
        head += &format!("<!-- Not written back (left as they were): {} -->\n    ", skipped.join("; ").replace("--", "-"));
    }
    edits.push((first..first, head));
    edits.sort_by_key(|(r, _)| std::cmp::Reverse((r.start, r.end)));
    let mut out = text.to_string();
    for (range, with) in edits {
        out.replace_range(range, &with);
    }
    out
}
