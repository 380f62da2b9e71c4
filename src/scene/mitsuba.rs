//! Mitsuba 3 XML import (a subset, parsed with `roxmltree`).
//!
//! Files as Mitsuba reads them: `<include filename>` splices the included scene's children
//! in (found beside the including file, else in the scene's directory; loops refused;
//! errors name the included file and its line); `<path value>` adds a
//! directory where file names are looked for (after the scene's own, before the included
//! files'); textures, BSDFs, area emitters and samplers with an `id` may be referred to
//! from anywhere in the file; plugin types are read case-insensitively; spectra (uniform,
//! `wavelength:value` lists, files, `regular`, `irregular`, `blackbody`) become RGB as in
//! Mitsuba's RGB variants ([`super::spectrum`]); a perspective sensor without `fov` has
//! Mitsuba's 50 mm default; a missing integrator or `max_depth` is Mitsuba's unlimited
//! depth (64 here, with a warning); `<rotate>` uses Mitsuba's arithmetic (a non-unit axis
//! shears, with a warning); `moment` and `aov` wrappers render the integrator inside them.
//!
//! Read: `<default>` values and `$name` substitution in attributes; `<integrator
//! type="path|prb|volpath|volpathmis|prbvolpath">` `max_depth` (−1, unlimited, becomes 64) and
//! `rr_depth`, `<integrator type="direct">` (depth 2), each's `hide_emitters`; `<sensor
//! type="perspective|thinlens|orthographic">` with `fov` and `fov_axis` (perspective and
//! thin lens), `aperture_radius` and `focus_distance` (thin lens) and `to_world`
//! (whose scale sets an orthographic camera's extent, uniform in x and y), its `<film
//! type="hdrfilm">` size and `<rfilter type="box|gaussian|tent">` (`stddev`, `radius`;
//! Gaussian by default, as Mitsuba's); `<shape type="obj|ply|serialized|rectangle|cube|sphere|disk|cylinder">` with
//! `to_world`, `face_normals`, `shape_index` (serialized, versions 3 and 4),
//! `flip_normals`, `flip_tex_coords` (OBJ), a `<bsdf>` or `<ref>` and an `<emitter
//! type="area">` (its `radiance` an `rgb` or a bitmap); `<bsdf
//! type="diffuse|twosided|principled|conductor|roughconductor|plastic|roughplastic|pplastic|dielectric|thindielectric|roughdielectric">` and the
//! wrappers `normalmap`, `bumpmap` and `mask`; `<emitter
//! type="constant|envmap|point|spot|directional">`; `<texture type="bitmap">` (EXR,
//! Radiance HDR, PNG, JPEG; `filter_type` bilinear or nearest, `wrap_mode` repeat, clamp
//! or mirror) and `<texture
//! type="checkerboard">` (constant colours: a 2 × 2 nearest-filtered image), each with a
//! `to_uv` map that moves the texture coordinates of the shapes using it (one per
//! shape); `<transform>` with `lookat`, `matrix`, `translate`, `rotate`, `scale`; `id` and
//! `<ref>`; a `<medium type="homogeneous|heterogeneous">` inside a closed shape (with a
//! `null` BSDF or a visible one) under `volpath`, `volpathmis` or `prbvolpath`, with the
//! sensors and surfaces that stand in it ([`media`]). Names: a shape's mesh, bsdf's material
//! and emitter's light are its `id` (else `shape<k>`, the enclosing shape's name,
//! `light<k>`); a medium's is its `id`, else its shape's name.
//!
//! Exact: bitmap and checkerboard textures, diffuse (black from behind unless wrapped in twosided, as in Mitsuba), twosided,
//! `mask` (a coverage: rays pass through with probability 1 − opacity), dielectric,
//! thindielectric and roughdielectric (glass: [`MaterialKind::Dielectric`],
//! [`MaterialKind::ThinDielectric`], [`MaterialKind::RoughDielectric`]), roughconductor
//! ([`MaterialKind::Conductor`], either distribution, a named material's or a given
//! complex index of refraction), roughplastic ([`MaterialKind::Plastic`]), pplastic (a
//! plastic whose coating is not layered, as Mitsuba's RGB variants render it), area
//! lights, the constant environment, point and directional lights, the film and camera,
//! the box, gaussian and tent filters. Approximate, each with a one-line warning: `principled`
//! (Mitsuba's Disney diffuse lobe becomes Lambert and its dielectric Fresnel term
//! Schlick's of the same index, `specular` or `eta`), a smooth `conductor` (the smallest roughness), a bitmap `alpha` of
//! roughconductor or roughdielectric (interpolated as √alpha), a smooth `plastic` (its
//! coating's terms exact, its mirror the smallest roughness), spot
//! lights (Mitsuba's linear-in-angle falloff is kept, its texture is not), spheres
//! (tessellated into 96 × 48 quads with exact normals), disks and cylinders (96 triangles
//! and 96 quads), `envmap` (EXR or Radiance HDR, turned or
//! mirrored by its `to_world`: resampled from Mitsuba's texel positions to the renderer's,
//! see [`envmap_from_mitsuba`]), reconstruction filters
//! other than those three (as `box`). Every other element, plugin type or parameter is an error naming its
//! line.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Affine2, Mat3, Mat4, Vec2, Vec3};
use roxmltree::{Document, Node};

use super::model::Imported;
use super::model::*;
use super::{obj, ply, MaterialKind, SceneError};
use crate::image::{self, srgb_decode, Image};

mod media;

/// The 2-D affine map that Mitsuba makes of a texture's 4 × 4 `to_uv`: its upper-left
/// 2 × 2 block and the x and y of its translation.
fn uv_affine(m: Mat4) -> Affine2 {
    Affine2::from_cols(m.x_axis.truncate().truncate(), m.y_axis.truncate().truncate(), m.w_axis.truncate().truncate())
}

/// Depth that Mitsuba's unlimited `max_depth = -1` becomes: Russian roulette ends nearly
/// every path long before it.
pub const UNLIMITED_DEPTH: u32 = 64;
/// The largest `specular` of a Mitsuba principled BSDF that is imported: the one whose
/// index of refraction is [`MAX_IOR`] (Schlick's reflectance 0.08 specular =
/// ((MAX_IOR − 1)/(MAX_IOR + 1))²).
fn max_specular() -> f64 {
    let r = f64::from(MAX_IOR - 1.0) / f64::from(MAX_IOR + 1.0);
    r * r / 0.08
}

/// Tessellation of a sphere: quads around the equator (half as many from pole to pole).
const SPHERE_SEGMENTS: u32 = 96;

/// The indices of refraction Mitsuba names (its `ior.h`).
const IORS: [(&str, f32); 23] = [
    ("vacuum", 1.0),
    ("helium", 1.000036),
    ("hydrogen", 1.000132),
    ("air", 1.000277),
    ("carbon dioxide", 1.00045),
    ("water", 1.3330),
    ("acetone", 1.36),
    ("ethanol", 1.361),
    ("carbon tetrachloride", 1.461),
    ("glycerol", 1.4729),
    ("benzene", 1.501),
    ("silicone oil", 1.52045),
    ("bromine", 1.661),
    ("water ice", 1.31),
    ("fused quartz", 1.458),
    ("pyrex", 1.470),
    ("acrylic glass", 1.49),
    ("polypropylene", 1.49),
    ("bk7", 1.5046),
    ("sodium chloride", 1.544),
    ("amber", 1.55),
    ("pet", 1.5750),
    ("diamond", 2.419),
];

type Items<'a, 'i> = Vec<Node<'a, 'i>>;

struct Importer<'a, 'i> {
    path: &'a Path,
    dir: PathBuf,
    /// Where relative file names are looked for after `dir`: the `<path>`s, then the
    /// included files' directories.
    search: Vec<PathBuf>,
    expanded: &'a Expanded,
    doc: &'a Document<'i>,
    defaults: Vec<(String, String)>,
    /// Material index of each top-level `<bsdf id>`.
    bsdfs: HashMap<String, usize>,
    /// Top-level `<texture id>`s.
    textures: HashMap<String, ColorValue>,
    /// Each texture image with a `to_uv` other than the identity, and that map (in
    /// Mitsuba's texture space, v down the image).
    uv_maps: Vec<(Arc<Image>, Affine2)>,
    /// Radiance of each top-level `<emitter type="area" id>`, for the shapes that refer
    /// to it.
    area_emitters: HashMap<String, ColorValue>,
    /// Ids of top-level samplers (a sensor may refer to one).
    samplers: Vec<String>,
    out: Imported,
    principled_warned: bool,
    /// A `direct` integrator's emitter samples (warned about with delta lights).
    direct_emitter_samples: Option<i64>,
    /// The integrator's type (inside a `moment` or `aov`); None without one.
    integrator_kind: Option<String>,
    /// Top-level `<medium id>`s, for the shapes whose interior they are.
    media: HashMap<String, media::MediumDef<'a, 'i>>,
    /// Top-level `<bsdf type="null" id>`s (a medium's shape's), and those a medium's shape used.
    null_bsdfs: HashMap<String, Node<'a, 'i>>,
    null_used: Vec<String>,
    /// The shape whose interior is the scene's medium.
    medium_shape: Option<Node<'a, 'i>>,
    /// The mesh of the visible shape whose interior is the medium (glass around it).
    medium_surface: Option<usize>,
    /// The shapes inside a medium (their `exterior`), checked against it at the end.
    in_medium: Vec<media::InMedium<'a, 'i>>,
    /// Each sensor's medium (its `medium`), in the order of `out.sensors`.
    sensor_media: Vec<media::SensorMedium<'a, 'i>>,
}

/// Deepest nesting of elements read: far beyond a scene's (a shape in a BSDF in a twosided
/// in a scene is 4), and shallow enough for the parser's recursion.
const MAX_XML_DEPTH: usize = 64;

/// The line where elements first nest deeper than [`MAX_XML_DEPTH`], and that depth; None
/// within it. A scan of tags, before the parser (which recurses into every element) sees
/// the text: comments, CDATA, declarations and processing instructions are skipped.
fn too_deep(text: &str) -> Option<(usize, usize)> {
    let bytes = text.as_bytes();
    let (mut depth, mut i) = (0usize, 0usize);
    let skip_to = |from: usize, end: &[u8]| bytes[from..].windows(end.len()).position(|w| w == end).map_or(bytes.len(), |p| from + p + end.len());
    while let Some(p) = bytes[i..].iter().position(|&b| b == b'<') {
        let at = i + p;
        let rest = &bytes[at..];
        i = if rest.starts_with(b"<!--") {
            skip_to(at, b"-->")
        } else if rest.starts_with(b"<![CDATA[") {
            skip_to(at, b"]]>")
        } else if rest.starts_with(b"<?") {
            skip_to(at, b"?>")
        } else if rest.starts_with(b"<!") || rest.starts_with(b"</") {
            depth = depth.saturating_sub(usize::from(rest.starts_with(b"</")));
            skip_to(at, b">")
        } else {
            let end = skip_to(at, b">");
            if end < 2 || bytes[end - 2] != b'/' {
                depth += 1;
                if depth > MAX_XML_DEPTH {
                    return Some((text[..at].matches('\n').count() + 1, depth));
                }
            }
            end
        };
    }
    None
}

/// Imports the Mitsuba 3 XML scene at `path`.
pub(super) fn import(path: &Path) -> Result<Imported, SceneError> {
    let text = crate::files::read_to_string(path).map_err(|source| SceneError::ReadScene { path: path.to_path_buf(), source })?;
    let mut expanded = Expanded { text: String::new(), spans: Vec::new(), dirs: Vec::new(), includes: 0 };
    expanded.include(path, &text, false, &mut vec![path.to_path_buf()])?;
    let doc = parse(path, &expanded.text)?;
    let mut imp = Importer {
        path,
        dir: path.parent().map(Path::to_path_buf).unwrap_or_default(),
        search: expanded.dirs.clone(),
        expanded: &expanded,
        doc: &doc,
        defaults: Vec::new(),
        bsdfs: HashMap::new(),
        textures: HashMap::new(),
        area_emitters: HashMap::new(),
        samplers: Vec::new(),
        uv_maps: Vec::new(),
        out: Imported { source: Source::Mitsuba(path.to_path_buf()), ..Default::default() },
        principled_warned: false,
        direct_emitter_samples: None,
        integrator_kind: None,
        media: HashMap::new(),
        null_bsdfs: HashMap::new(),
        null_used: Vec::new(),
        medium_shape: None,
        medium_surface: None,
        in_medium: Vec::new(),
        sensor_media: Vec::new(),
    };
    imp.scene(doc.root_element())?;
    imp.check_media()?;
    imp.finish();
    Ok(imp.out)
}

/// `text` (of `path`) parsed, after the nesting check.
fn parse<'t>(path: &Path, text: &'t str) -> Result<Document<'t>, SceneError> {
    if let Some((line, depth)) = too_deep(text) {
        return Err(SceneError::Import {
            path: path.to_path_buf(),
            location: format!("line {line}"),
            message: format!("elements nested {depth} deep; at most {MAX_XML_DEPTH}"),
        });
    }
    Document::parse(text).map_err(|e| SceneError::Import { path: path.to_path_buf(), location: String::new(), message: format!("malformed XML: {e}") })
}

/// Most `<include>`s read in one import, and most bytes of scene text they make: far
/// beyond a real scene's, and a bound on a file that includes another many times over.
const MAX_INCLUDES: usize = 256;
const MAX_EXPANDED_BYTES: usize = 64 << 20;

/// The scene text with every `<include filename>` replaced by the children of the included
/// file's `<scene>` (recursively, as Mitsuba reads them), and where each piece came from,
/// for error locations.
struct Expanded {
    text: String,
    /// (first line of the piece in `text`, its file, its first line there), in order.
    spans: Vec<(usize, PathBuf, usize)>,
    /// The directories of the included files: searched for relative file names after the
    /// scene's own and its `<path>`s.
    dirs: Vec<PathBuf>,
    includes: usize,
}

impl Expanded {
    /// Appends `text` of `path` (only its root's children when `inner`), with its includes
    /// expanded; `stack` holds the files being included, outermost first.
    fn include(&mut self, path: &Path, text: &str, inner: bool, stack: &mut Vec<PathBuf>) -> Result<(), SceneError> {
        let doc = parse(path, text)?;
        let root = doc.root_element();
        let err = |node: Node, message: String| SceneError::Import {
            path: path.to_path_buf(),
            location: format!("line {}: <{}>", doc.text_pos_at(node.range().start).row, node.tag_name().name()),
            message,
        };
        if inner && root.tag_name().name() != "scene" {
            return Err(err(root, "an included file's root element must be <scene>".into()));
        }
        let (start, end) = match (inner, root.first_child(), root.last_child()) {
            (false, _, _) => (0, text.len()),
            (true, Some(first), Some(last)) => (first.range().start, last.range().end),
            (true, _, _) => return Ok(()),
        };
        let mut at = start;
        for node in root.children().filter(|n| n.is_element() && n.tag_name().name() == "include") {
            self.push(path, text, at, node.range().start)?;
            let rel = node.attribute("filename").ok_or_else(|| err(node, "<include> needs a filename".into()))?;
            // Relative to the including file, else (as Mitsuba's file resolver finds it) to
            // the scene's directory.
            let dir = path.parent().unwrap_or(Path::new(""));
            let file = match (dir.join(rel), stack.first().and_then(|top| top.parent())) {
                (file, Some(top)) if !file.exists() && top.join(rel).exists() => top.join(rel),
                (file, _) => file,
            };
            let canonical = std::fs::canonicalize(&file).map_err(|e| err(node, format!("cannot read {}: {e}", file.display())))?;
            if let Some(i) = stack.iter().position(|p| std::fs::canonicalize(p).is_ok_and(|c| c == canonical)) {
                let chain: Vec<String> = stack[i..].iter().chain([&file]).map(|p| p.display().to_string()).collect();
                return Err(err(node, format!("include loop: {}", chain.join(" includes "))));
            }
            self.includes += 1;
            if self.includes > MAX_INCLUDES {
                return Err(err(node, format!("more than {MAX_INCLUDES} includes")));
            }
            let included = crate::files::read_to_string(&file).map_err(|e| err(node, format!("cannot read {}: {e}", file.display())))?;
            if let Some(d) = file.parent().filter(|d| !self.dirs.iter().any(|x| x == d)) {
                self.dirs.push(d.to_path_buf());
            }
            stack.push(file.clone());
            self.include(&file, &included, true, stack)?;
            stack.pop();
            at = node.range().end;
        }
        self.push(path, text, at, end)
    }

    fn push(&mut self, path: &Path, text: &str, from: usize, to: usize) -> Result<(), SceneError> {
        if to <= from {
            return Ok(());
        }
        let out_line = self.text.matches('\n').count() + 1;
        let line = text[..from].matches('\n').count() + 1;
        self.spans.push((out_line, path.to_path_buf(), line));
        self.text.push_str(&text[from..to]);
        if self.text.len() > MAX_EXPANDED_BYTES {
            return Err(SceneError::Import {
                path: path.to_path_buf(),
                location: String::new(),
                message: format!("the scene and its includes exceed {} MiB", MAX_EXPANDED_BYTES >> 20),
            });
        }
        Ok(())
    }

    /// The file and line of line `row` of the expanded text.
    fn origin(&self, row: u32) -> (&Path, usize) {
        let row = row as usize;
        let i = self.spans.partition_point(|s| s.0 <= row).saturating_sub(1);
        match self.spans.get(i) {
            Some((out, file, line)) => (file, line + row.saturating_sub(*out)),
            None => (Path::new(""), row),
        }
    }
}

/// The rotation by `angle` radians about `axis` as Mitsuba builds it: Rodrigues' formula
/// with the axis as given, which is a rotation only for a unit axis.
fn rotation(axis: Vec3, angle: f32) -> Mat4 {
    let (s, c) = angle.sin_cos();
    let cm = 1.0 - c;
    let Vec3 { x, y, z } = axis;
    let (xy, xz, yz) = (x * y * cm, x * z * cm, y * z * cm);
    Mat4::from_cols(
        glam::Vec4::new(x * x * cm + c, xy + z * s, xz - y * s, 0.0),
        glam::Vec4::new(xy - z * s, y * y * cm + c, yz + x * s, 0.0),
        glam::Vec4::new(xz + y * s, yz - x * s, z * z * cm + c, 0.0),
        glam::Vec4::W,
    )
}

fn elements<'a, 'i>(node: Node<'a, 'i>) -> Items<'a, 'i> {
    node.children().filter(Node::is_element).collect()
}

impl<'a, 'i> Importer<'a, 'i> {
    /// `line N: <tag type=".." name=".." id="..">` of `node`.
    fn loc(&self, node: Node) -> String {
        let pos = self.doc.text_pos_at(node.range().start);
        let (file, line) = self.expanded.origin(pos.row);
        let mut s = match file == self.path {
            true => format!("line {line}: <{}", node.tag_name().name()),
            false => format!("{} line {line}: <{}", file.display(), node.tag_name().name()),
        };
        for a in ["type", "name", "id"] {
            if let Some(v) = node.attribute(a) {
                s += &format!(" {a}=\"{v}\"");
            }
        }
        s + ">"
    }

    fn err(&self, node: Node, message: impl Into<String>) -> SceneError {
        SceneError::Import { path: self.path.to_path_buf(), location: self.loc(node), message: message.into() }
    }

    fn warn(&mut self, node: Node, message: impl std::fmt::Display) {
        let line = format!("{}: {}: {message}", self.path.display(), self.loc(node));
        self.out.warnings.push(line);
    }

    /// Attribute `name` of `node` with `$default` references substituted.
    fn attr(&self, node: Node, name: &str) -> Result<Option<String>, SceneError> {
        let Some(raw) = node.attribute(name) else { return Ok(None) };
        let mut v = String::with_capacity(raw.len());
        let mut rest = raw;
        while let Some(i) = rest.find('$') {
            v.push_str(&rest[..i]);
            let after = &rest[i + 1..];
            let len = after.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).unwrap_or(after.len());
            let key = &after[..len];
            let value = self.defaults.iter().find(|(k, _)| k == key).map(|(_, val)| val);
            v.push_str(value.ok_or_else(|| self.err(node, format!("undefined parameter ${key} in {name}=\"{raw}\"")))?);
            rest = &after[len..];
        }
        v.push_str(rest);
        Ok(Some(v))
    }

    /// A file name as Mitsuba resolves it: relative to the scene's directory, then to each
    /// `<path>` and included file's directory; the scene's directory where none has it.
    fn resolve(&self, rel: &str) -> PathBuf {
        let rel = Path::new(rel);
        if rel.is_absolute() {
            return rel.to_path_buf();
        }
        std::iter::once(&self.dir).chain(&self.search).map(|d| d.join(rel)).find(|p| p.exists()).unwrap_or_else(|| self.dir.join(rel))
    }

    /// The file `rel` names (resolved as [`Self::resolve`] does) and its bytes; a file that
    /// cannot be read is an error at `node`.
    fn read_file(&self, node: Node, rel: &str) -> Result<(PathBuf, Vec<u8>), SceneError> {
        let path = self.resolve(rel);
        let bytes = crate::files::read(&path).map_err(|e| self.err(node, format!("cannot read {}: {e}", path.display())))?;
        Ok((path, bytes))
    }

    fn required(&self, node: Node, name: &str) -> Result<String, SceneError> {
        self.attr(node, name)?.ok_or_else(|| self.err(node, format!("the `{name}` attribute is missing")))
    }

    /// The plugin's type, in lower case (Blender's exporter writes "Rectangle").
    fn plugin_type(&self, node: Node) -> Result<String, SceneError> {
        Ok(self.required(node, "type")?.to_ascii_lowercase())
    }

    /// Removes and returns the parameter child named `name`.
    fn take(&self, items: &mut Items<'a, 'i>, name: &str) -> Option<Node<'a, 'i>> {
        let i = items.iter().position(|n| n.attribute("name") == Some(name))?;
        Some(items.remove(i))
    }

    /// Removes and returns the first unnamed child element with tag `tag`.
    fn take_tag(&self, items: &mut Items<'a, 'i>, tag: &str) -> Option<Node<'a, 'i>> {
        let i = items.iter().position(|n| n.tag_name().name() == tag && n.attribute("name").is_none())?;
        Some(items.remove(i))
    }

    /// Errors on the first child that no reader took.
    fn rest(&self, items: &Items, owner: Node) -> Result<(), SceneError> {
        match items.first() {
            Some(n) => Err(self.err(*n, format!("unsupported in {}", self.loc(owner)))),
            None => Ok(()),
        }
    }

    fn numbers(&self, node: Node, text: &str) -> Result<Vec<f32>, SceneError> {
        text.split(|c: char| c == ',' || c.is_whitespace())
            .filter(|w| !w.is_empty())
            .map(|w| w.parse::<f32>().ok().filter(|v| v.is_finite()).ok_or_else(|| self.err(node, format!("`{w}` is not a finite number"))))
            .collect()
    }

    fn float(&self, node: Node) -> Result<f32, SceneError> {
        match node.tag_name().name() {
            "float" | "integer" => {
                let v = self.numbers(node, &self.required(node, "value")?)?;
                v.first().copied().filter(|_| v.len() == 1).ok_or_else(|| self.err(node, "expected one number"))
            }
            _ => Err(self.err(node, "expected a <float>")),
        }
    }

    fn int(&self, node: Node) -> Result<i64, SceneError> {
        let v = self.required(node, "value")?;
        match node.tag_name().name() {
            "integer" => v.trim().parse().map_err(|_| self.err(node, format!("`{v}` is not an integer"))),
            _ => Err(self.err(node, "expected an <integer>")),
        }
    }

    fn boolean(&self, node: Node) -> Result<bool, SceneError> {
        match (node.tag_name().name(), self.required(node, "value")?.as_str()) {
            ("boolean", "true") => Ok(true),
            ("boolean", "false") => Ok(false),
            _ => Err(self.err(node, "expected <boolean value=\"true|false\">")),
        }
    }

    fn string(&self, node: Node) -> Result<String, SceneError> {
        match node.tag_name().name() {
            "string" => self.required(node, "value"),
            _ => Err(self.err(node, "expected a <string>")),
        }
    }

    /// `<rgb>`, a `<spectrum>` or a `<float>` as an RGB triple. A spectrum (a uniform
    /// value, a `wavelength:value` list, a file of such pairs, or `type="uniform"`,
    /// `"regular"`, `"irregular"` or `"blackbody"`) is converted as Mitsuba's RGB variants
    /// convert it ([`spectrum`](super::spectrum)): as a radiance for parameters named
    /// `radiance`, `intensity` or `irradiance`, as a reflectance (clamped to [0, 1], with a
    /// warning) otherwise.
    fn rgb(&mut self, node: Node) -> Result<[f32; 3], SceneError> {
        if node.tag_name().name() == "spectrum" {
            return self.spectrum(node);
        }
        let v = match node.tag_name().name() {
            "rgb" | "float" => self.numbers(node, &self.required(node, "value")?)?,
            _ => return Err(self.err(node, "expected <rgb>, <spectrum> or <float>")),
        };
        match (node.tag_name().name(), v.as_slice()) {
            (_, &[x]) => Ok([x; 3]),
            ("rgb", &[r, g, b]) => Ok([r, g, b]),
            _ => Err(self.err(node, "expected one or three numbers")),
        }
    }

    fn spectrum(&mut self, node: Node) -> Result<[f32; 3], SceneError> {
        use super::spectrum::{blackbody, list_to_rgb, SpectrumKind};
        let kind = match node.attribute("name") {
            Some("radiance" | "intensity" | "irradiance") => SpectrumKind::Radiance,
            _ => SpectrumKind::Reflectance,
        };
        // One (wavelength, value) of an entry `whole`, split into `w` and `v`.
        let point = |whole: &str, w: &str, v: &str| -> Result<(f32, f32), String> {
            match (w.trim().parse::<f32>(), v.trim().parse::<f32>()) {
                (Ok(w), Ok(v)) if w.is_finite() && v.is_finite() => Ok((w, v)),
                _ => Err(format!("`{whole}` is not wavelength:value")),
            }
        };
        let pairs = |text: &str| -> Result<Vec<(f32, f32)>, String> {
            let entries = text.split(',').map(str::trim).filter(|p| !p.is_empty());
            entries.map(|p| p.split_once(':').map_or_else(|| Err(format!("`{p}` is not wavelength:value")), |(w, v)| point(p, w, v))).collect()
        };
        let mut items = elements(node);
        let plugin = self.attr(node, "type")?;
        let result = match (plugin.as_deref(), self.attr(node, "value")?, self.attr(node, "filename")?) {
            (None, Some(v), None) if !v.contains(':') => {
                let v = self.numbers(node, &v)?;
                let &[x] = v.as_slice() else { return Err(self.err(node, "a spectrum's value is one number or a wavelength:value list")) };
                return Ok([x; 3]);
            }
            (None, Some(v), None) => pairs(&v).and_then(|p| list_to_rgb(&p, kind)),
            (None, None, Some(file)) => {
                let (path, bytes) = self.read_file(node, &file)?;
                let text = String::from_utf8_lossy(&bytes);
                // Lines of `wavelength value`, `#` starting a comment.
                let entries = text.lines().map(|l| l.split('#').next().unwrap_or("").trim()).filter(|l| !l.is_empty());
                let points: Result<Vec<(f32, f32)>, String> = entries
                    .map(|l| match *l.split_whitespace().collect::<Vec<_>>() {
                        [w, v] => point(l, w, v),
                        _ => Err(format!("`{l}` is not wavelength:value")),
                    })
                    .collect();
                points.map_err(|e| format!("{}: {e}", path.display())).and_then(|p| list_to_rgb(&p, kind))
            }
            (Some("uniform"), None, None) => {
                let v = self.take_float(&mut items, "value", 1.0)?;
                self.rest(&items, node)?;
                return Ok([v; 3]);
            }
            (Some("blackbody"), None, None) => {
                let t = self.take(&mut items, "temperature").ok_or_else(|| self.err(node, "a blackbody needs <float name=\"temperature\">"))?;
                let t = self.float(t)?;
                self.rest(&items, node)?;
                blackbody(t).map(|rgb| (rgb, false))
            }
            (Some("regular"), None, None) => {
                let lo = self.take_float(&mut items, "wavelength_min", f32::NAN)?;
                let hi = self.take_float(&mut items, "wavelength_max", f32::NAN)?;
                let values = self.take(&mut items, "values").map(|n| self.string(n)).transpose()?.unwrap_or_default();
                self.rest(&items, node)?;
                let values = self.numbers(node, &values)?;
                let n = values.len();
                if n < 2 || lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
                    return Err(self.err(node, "a regular spectrum needs wavelength_min < wavelength_max and two or more values"));
                }
                let points: Vec<(f32, f32)> = values.iter().enumerate().map(|(i, &v)| (lo + (hi - lo) * i as f32 / (n - 1) as f32, v)).collect();
                list_to_rgb(&points, kind)
            }
            (Some("irregular"), None, None) => {
                let w = self.take(&mut items, "wavelengths").map(|n| self.string(n)).transpose()?.unwrap_or_default();
                let v = self.take(&mut items, "values").map(|n| self.string(n)).transpose()?.unwrap_or_default();
                self.rest(&items, node)?;
                let (w, v) = (self.numbers(node, &w)?, self.numbers(node, &v)?);
                if w.len() != v.len() {
                    return Err(self.err(node, format!("{} wavelengths and {} values", w.len(), v.len())));
                }
                list_to_rgb(&w.into_iter().zip(v).collect::<Vec<_>>(), kind)
            }
            (Some(other), _, _) => {
                return Err(self.err(node, format!("spectrum type \"{other}\" is unsupported (uniform, regular, irregular and blackbody are)")))
            }
            _ => return Err(self.err(node, "give a spectrum's value or filename")),
        };
        let (rgb, clamped) = result.map_err(|e| self.err(node, e))?;
        if clamped {
            self.warn(node, format!("the spectrum is outside the sRGB gamut: clamped to {rgb:?}, as Mitsuba clamps it"));
        }
        Ok(rgb)
    }

    fn point(&self, node: Node) -> Result<Vec3, SceneError> {
        if !matches!(node.tag_name().name(), "point" | "vector") {
            return Err(self.err(node, "expected <point> or <vector>"));
        }
        if let Some(v) = self.attr(node, "value")? {
            return match *self.numbers(node, &v)?.as_slice() {
                [x, y, z] => Ok(Vec3::new(x, y, z)),
                [x] => Ok(Vec3::splat(x)),
                _ => Err(self.err(node, "expected three numbers")),
            };
        }
        let c = |a| -> Result<f32, SceneError> {
            Ok(self.attr(node, a)?.map(|s| self.numbers(node, &s)).transpose()?.and_then(|v| v.first().copied()).unwrap_or(0.0))
        };
        Ok(Vec3::new(c("x")?, c("y")?, c("z")?))
    }

    /// A `<transform>`: each child is applied after those before it. A `<rotate>` about an
    /// axis that is not a unit vector shears, as in Mitsuba, with a warning.
    fn transform(&mut self, node: Node<'a, 'i>) -> Result<Mat4, SceneError> {
        if node.tag_name().name() != "transform" {
            return Err(self.err(node, "expected a <transform>"));
        }
        let mut shears = Vec::new();
        let m = self.transform_steps(node, &mut shears)?;
        for op in shears {
            self.warn(
                op,
                "the axis is not a unit vector: the rotation also shears and scales, as Mitsuba computes it (normalise the axis for a pure rotation)",
            );
        }
        Ok(m)
    }

    fn transform_steps(&self, node: Node<'a, 'i>, shears: &mut Vec<Node<'a, 'i>>) -> Result<Mat4, SceneError> {
        let mut m = Mat4::IDENTITY;
        for op in elements(node) {
            let xyz = |default: f32| -> Result<Vec3, SceneError> {
                if let Some(v) = self.attr(op, "value")? {
                    return match *self.numbers(op, &v)?.as_slice() {
                        [x, y, z] => Ok(Vec3::new(x, y, z)),
                        [x] => Ok(Vec3::splat(x)),
                        _ => Err(self.err(op, "expected one or three numbers")),
                    };
                }
                let c = |a| -> Result<f32, SceneError> {
                    Ok(self.attr(op, a)?.map(|s| self.numbers(op, &s)).transpose()?.and_then(|v| v.first().copied()).unwrap_or(default))
                };
                Ok(Vec3::new(c("x")?, c("y")?, c("z")?))
            };
            let step = match op.tag_name().name() {
                "translate" => Mat4::from_translation(xyz(0.0)?),
                "scale" => Mat4::from_scale(xyz(1.0)?),
                "rotate" => {
                    let axis = xyz(0.0)?;
                    if axis == Vec3::ZERO {
                        return Err(self.err(op, "the rotation axis is zero"));
                    }
                    let angle = self.numbers(op, &self.required(op, "angle")?)?;
                    let &[angle] = angle.as_slice() else { return Err(self.err(op, "expected one angle")) };
                    if (axis.length() - 1.0).abs() > 1e-3 {
                        shears.push(op);
                    }
                    rotation(axis, angle.to_radians())
                }
                "matrix" => {
                    let v = self.numbers(op, &self.required(op, "value")?)?;
                    match v.len() {
                        // Row-major, as written.
                        16 => Mat4::from_cols_slice(&v).transpose(),
                        9 => Mat4::from_mat3(Mat3::from_cols_slice(&v).transpose()),
                        n => return Err(self.err(op, format!("{n} values (16 or 9 expected)"))),
                    }
                }
                "lookat" => {
                    let vec = |a| -> Result<Vec3, SceneError> {
                        match self.numbers(op, &self.required(op, a)?)?.as_slice() {
                            &[x, y, z] => Ok(Vec3::new(x, y, z)),
                            _ => Err(self.err(op, format!("`{a}` needs three numbers"))),
                        }
                    };
                    let (origin, target) = (vec("origin")?, vec("target")?);
                    let up = if op.attribute("up").is_some() { vec("up")? } else { Vec3::Y };
                    let dir = (target - origin).try_normalize().ok_or_else(|| self.err(op, "origin and target coincide"))?;
                    let left = up.cross(dir).try_normalize().ok_or_else(|| self.err(op, "up is parallel to the view direction"))?;
                    let new_up = dir.cross(left);
                    Mat4::from_cols(left.extend(0.0), new_up.extend(0.0), dir.extend(0.0), origin.extend(1.0))
                }
                _ => return Err(self.err(op, format!("unsupported in {}", self.loc(node)))),
            };
            m = step * m;
        }
        if !m.is_finite() {
            return Err(self.err(node, "non-finite transform"));
        }
        Ok(m)
    }

    fn take_transform(&mut self, items: &mut Items<'a, 'i>, name: &str) -> Result<Option<Mat4>, SceneError> {
        self.take(items, name).map(|n| self.transform(n)).transpose()
    }

    fn take_float(&self, items: &mut Items<'a, 'i>, name: &str, default: f32) -> Result<f32, SceneError> {
        Ok(self.take(items, name).map(|n| self.float(n)).transpose()?.unwrap_or(default))
    }

    fn take_bool(&self, items: &mut Items<'a, 'i>, name: &str, default: bool) -> Result<bool, SceneError> {
        Ok(self.take(items, name).map(|n| self.boolean(n)).transpose()?.unwrap_or(default))
    }

    fn take_rgb(&mut self, items: &mut Items<'a, 'i>, name: &str, default: [f32; 3]) -> Result<[f32; 3], SceneError> {
        Ok(self.take(items, name).map(|n| self.rgb(n)).transpose()?.unwrap_or(default))
    }

    // -----------------------------------------------------------------------------------
    // The scene
    // -----------------------------------------------------------------------------------

    fn scene(&mut self, root: Node<'a, 'i>) -> Result<(), SceneError> {
        if root.tag_name().name() != "scene" {
            return Err(self.err(root, "the root element is not <scene>"));
        }
        let children = elements(root);
        // Defaults first: they may be used before they appear.
        for n in children.iter().filter(|n| n.tag_name().name() == "default") {
            let name = self.required(*n, "name")?;
            let value = self.required(*n, "value")?;
            if !self.defaults.iter().any(|(k, _)| *k == name) {
                self.defaults.push((name, value));
            }
        }
        // Search paths next: file names anywhere may use them.
        for n in children.iter().filter(|n| n.tag_name().name() == "path") {
            let dir = self.dir.join(self.required(*n, "value")?);
            self.search.insert(self.search.len() - self.expanded.dirs.len(), dir);
        }
        // Definitions that others refer to by id, wherever they are declared (Mitsuba
        // resolves references over the whole file): textures, then BSDFs, then area emitters
        // and samplers.
        let definition = |n: &Node, tag: &str| n.tag_name().name() == tag && n.attribute("id").is_some();
        for n in children.iter().filter(|n| definition(n, "texture")) {
            let id = self.required(*n, "id")?;
            let value = self.texture(*n)?;
            self.textures.insert(id, value);
        }
        for n in children.iter().filter(|n| definition(n, "bsdf")) {
            let id = self.required(*n, "id")?;
            if self.plugin_type(*n)? == "null" {
                // Only around a medium (checked once the shapes are read).
                self.null_bsdfs.insert(id, *n);
                continue;
            }
            let index = self.bsdf(*n, &id)?;
            self.bsdfs.insert(id, index);
        }
        for n in children.iter().filter(|n| definition(n, "medium")) {
            let id = self.required(*n, "id")?;
            let medium = self.medium_def(*n)?;
            self.media.insert(id, medium);
        }
        let area: Vec<Node> =
            children.iter().copied().filter(|n| definition(n, "emitter") && n.attribute("type").is_some_and(|t| t.eq_ignore_ascii_case("area"))).collect();
        for n in area.iter() {
            let id = self.required(*n, "id")?;
            let radiance = self.area_emitter(*n)?;
            self.area_emitters.insert(id, radiance);
        }
        for n in children.iter().filter(|n| definition(n, "sampler")) {
            // The sample count is the command line's; a sensor may refer to it.
            self.plugin_type(*n)?;
            self.samplers.push(self.required(*n, "id")?);
        }
        let mut shapes = 0;
        let mut lights = 0;
        let mut integrators = 0;
        for n in children {
            match n.tag_name().name() {
                "default" | "path" => {}
                "texture" | "bsdf" | "sampler" | "medium" if n.attribute("id").is_some() => {}
                "emitter" if area.contains(&n) => {}
                "integrator" => {
                    integrators += 1;
                    if integrators > 1 {
                        return Err(self.err(n, "a second <integrator>: a scene has one"));
                    }
                    self.integrator(n)?
                }
                "sensor" => self.sensor(n)?,
                "bsdf" | "texture" | "sampler" => return Err(self.err(n, "the `id` attribute is missing")),
                "medium" => return Err(self.err(n, "a top-level <medium> needs an id that a shape's <ref name=\"interior\"> names")),
                "shape" => {
                    shapes += 1;
                    self.shape(n, shapes)?;
                }
                "emitter" if self.plugin_type(n)? == "area" => {
                    return Err(self.err(n, "an area emitter belongs inside a <shape>, or has an id that shapes refer to"));
                }
                "emitter" => {
                    lights += 1;
                    self.emitter(n, lights)?;
                }
                tag => return Err(self.err(n, format!("<{tag}> is unsupported in <scene>"))),
            }
        }
        if integrators == 0 {
            // Mitsuba's default integrator: path, of unlimited depth.
            self.out.max_depth = Some(UNLIMITED_DEPTH);
            self.warn(root, format!("no <integrator>: Mitsuba's default (path, unlimited depth) is rendered at depth {UNLIMITED_DEPTH}"));
        }
        Ok(())
    }

    /// The radiance of an area emitter (inside a shape, or at the top level with an id).
    fn area_emitter(&mut self, e: Node<'a, 'i>) -> Result<ColorValue, SceneError> {
        let mut em = elements(e);
        let radiance = self.color_param(&mut em, "radiance", [1.0; 3])?;
        self.rest(&em, e)?;
        Ok(radiance)
    }

    /// Warnings that need the whole scene.
    fn finish(&mut self) {
        if let Some(n) = self.direct_emitter_samples.filter(|&n| n > 1) {
            if let Some(light) = self.out.lights.first() {
                let line = format!(
                    "{}: <integrator type=\"direct\">: Mitsuba weights point, spot and directional lights (here \"{}\") by emitter_samples ({n}); vkinverse counts them once, as Mitsuba's path integrator does",
                    self.path.display(),
                    light.name
                );
                self.out.warnings.push(line);
            }
        }
    }

    fn integrator(&mut self, node: Node<'a, 'i>) -> Result<(), SceneError> {
        let kind = self.plugin_type(node)?;
        let mut items = elements(node);
        if kind == "moment" || kind == "aov" || kind == "stokes" {
            // Wrappers that write extra images beside the inner integrator's (stokes: the
            // Stokes vector's other components; its first is the radiance, as rendered).
            self.take(&mut items, "aovs");
            let inner =
                self.take_tag(&mut items, "integrator").or_else(|| items.iter().position(|n| n.tag_name().name() == "integrator").map(|i| items.remove(i)));
            let inner = inner.ok_or_else(|| {
                self.err(node, format!("an {kind} integrator without a nested integrator is unsupported (its extra images are not rendered)"))
            })?;
            self.rest(&items, node)?;
            let what = if kind == "stokes" { "the Stokes components beyond the radiance".to_string() } else { format!("the {kind} images") };
            self.warn(node, format!("rendered as the integrator inside it; {what} are not written"));
            return self.integrator(inner);
        }
        self.integrator_kind = Some(kind.clone());
        match kind.as_str() {
            // Without media, the volumetric integrators render what path does; with a
            // medium, they render it as vkinverse does (path, prb and direct ignore media,
            // which is refused).
            "path" | "prb" | "volpath" | "volpathmis" | "prbvolpath" => {}
            // Emitters seen and direct illumination: the path tracer at depth 2. Its sample
            // counts per strategy change the noise only.
            "direct" => {
                for key in ["emitter_samples", "bsdf_samples", "shading_samples"] {
                    if let Some(n) = self.take(&mut items, key) {
                        let v = self.int(n)?;
                        if v < 0 {
                            return Err(self.err(n, format!("{key} is negative")));
                        }
                        if key != "bsdf_samples" {
                            self.direct_emitter_samples = Some(v);
                        }
                    }
                }
                self.out.max_depth = Some(2);
                self.out.hide_emitters = Some(self.take_bool(&mut items, "hide_emitters", false)?);
                return self.rest(&items, node);
            }
            _ => {
                return Err(self.err(
                    node,
                    format!(
                    "integrator \"{kind}\" is unsupported (path, prb, volpath, volpathmis, prbvolpath and direct are, and moment, aov or stokes around one of them)"
                ),
                ))
            }
        }
        match self.take(&mut items, "max_depth") {
            Some(n) => {
                let d = self.int(n)?;
                self.out.max_depth = Some(match d {
                    -1 => {
                        self.warn(n, format!("unlimited depth becomes {UNLIMITED_DEPTH}"));
                        UNLIMITED_DEPTH
                    }
                    d if d >= 1 && d <= MAX_DEPTH as i64 => d as u32,
                    _ => return Err(self.err(n, format!("{d} is not -1 or in 1..={MAX_DEPTH}"))),
                });
            }
            None => {
                // Mitsuba's default is −1, unlimited.
                self.warn(node, format!("no max_depth: Mitsuba's default (unlimited) becomes {UNLIMITED_DEPTH}"));
                self.out.max_depth = Some(UNLIMITED_DEPTH);
            }
        }
        if let Some(n) = self.take(&mut items, "rr_depth") {
            let d = self.int(n)?;
            self.out.rr_depth =
                Some(u32::try_from(d).ok().filter(|d| (1..=MAX_DEPTH).contains(d)).ok_or_else(|| self.err(n, format!("{d} is not in 1..={MAX_DEPTH}")))?);
        }
        self.out.hide_emitters = Some(self.take_bool(&mut items, "hide_emitters", false)?);
        self.rest(&items, node)
    }

    /// A sensor's field of view in degrees and the axis it is along by default: its `fov`,
    /// or its `focal_length` (35 mm film, across the diagonal), or Mitsuba's 50 mm default;
    /// 90 (unused) for an orthographic one.
    fn field_of_view(&mut self, items: &mut Items<'a, 'i>, orthographic: bool) -> Result<(f32, &'static str), SceneError> {
        Ok(match (orthographic, self.take(items, "fov"), self.take(items, "focal_length")) {
            (true, _, _) => (90.0, "x"),
            (false, Some(f), None) => (self.float(f)?, "x"),
            (false, None, f) => {
                // Mitsuba's default: a 50 mm lens on 35 mm film, across the film's diagonal.
                let mm = match f {
                    None => 50.0,
                    Some(f) => {
                        let text = self.string(f)?;
                        text.trim()
                            .trim_end_matches("mm")
                            .trim()
                            .parse::<f32>()
                            .ok()
                            .filter(|v| v.is_finite() && *v > 0.0)
                            .ok_or_else(|| self.err(f, format!("focal_length \"{text}\" is not a length in mm")))?
                    }
                };
                (2.0 * (36.0f32.hypot(24.0) / (2.0 * mm)).atan().to_degrees(), "diagonal")
            }
            (false, Some(_), Some(f)) => return Err(self.err(f, "give fov or focal_length, not both")),
        })
    }

    fn sensor(&mut self, node: Node<'a, 'i>) -> Result<(), SceneError> {
        let kind = self.plugin_type(node)?;
        let orthographic = match kind.as_str() {
            "perspective" | "thinlens" => false,
            "orthographic" => true,
            _ => return Err(self.err(node, format!("sensor \"{kind}\" is unsupported (perspective, thinlens and orthographic are)"))),
        };
        let mut items = elements(node);
        let lens = if kind == "thinlens" {
            let mut get = |name: &str| -> Result<f32, SceneError> {
                let n = self.take(&mut items, name).ok_or_else(|| self.err(node, format!("a thinlens sensor needs <float name=\"{name}\">")))?;
                let v = self.float(n)?;
                if !(v.is_finite() && v > 0.0) {
                    return Err(self.err(n, format!("{name} = {v} is not positive")));
                }
                Ok(v)
            };
            Some(ThinLens { aperture_radius: get("aperture_radius")?, focus_distance: get("focus_distance")? })
        } else {
            None
        };
        if kind == "perspective" {
            // Mitsuba reads it on every projective camera; a pinhole has no plane of focus.
            if let Some(n) = self.take(&mut items, "focus_distance") {
                self.float(n)?;
            }
        }
        let (fov, default_axis) = self.field_of_view(&mut items, orthographic)?;
        let axis = if orthographic {
            "x".into()
        } else {
            self.take(&mut items, "fov_axis").map(|n| self.string(n)).transpose()?.unwrap_or_else(|| default_axis.into())
        };
        let to_world = self.take_transform(&mut items, "to_world")?.unwrap_or(Mat4::IDENTITY);
        let mut near_clip = None;
        for clip in ["near_clip", "far_clip"] {
            if let Some(n) = self.take(&mut items, clip) {
                let v = self.float(n)?;
                self.warn(n, "ignored: nothing is clipped");
                if clip == "near_clip" {
                    near_clip = Some(v);
                }
            }
        }
        let medium = self.take(&mut items, "medium").map(|n| self.medium_ref(n, "medium")).transpose()?;
        let film = match self.take_tag(&mut items, "film") {
            Some(f) => self.film(f)?,
            None => Film { width: 768, height: 576 },
        };
        if let Some(s) = self.take_tag(&mut items, "sampler") {
            // The sampler's pattern and count do not change the expected image; the
            // command line sets the sample count.
            self.plugin_type(s)?;
        }
        items.retain(|n| !(n.tag_name().name() == "ref" && n.attribute("id").is_some_and(|id| self.samplers.iter().any(|s| s == id))));
        self.rest(&items, node)?;
        let film = *self.out.film.get_or_insert(film);
        let aspect = film.width as f32 / film.height as f32;
        let t = (fov.to_radians() * 0.5).tan();
        let tan_y = match axis.as_str() {
            "x" => t / aspect,
            "y" => t,
            "diagonal" => t / (1.0 + aspect * aspect).sqrt(),
            "smaller" if aspect >= 1.0 => t,
            "smaller" => t / aspect,
            "larger" if aspect >= 1.0 => t / aspect,
            "larger" => t,
            _ => return Err(self.err(node, format!("fov_axis \"{axis}\" is not x, y, diagonal, smaller or larger"))),
        };
        let fov_y = 2.0 * tan_y.atan().to_degrees();
        if !(fov_y > 0.0 && fov_y < 180.0) {
            return Err(self.err(node, format!("field of view {fov} is outside (0, 180)")));
        }
        // Mitsuba's camera looks along local +z with +y up and +x to the left of the
        // image; a transform with a negative determinant would mirror the image.
        if Mat3::from_mat4(to_world).determinant() <= 0.0 {
            return Err(self.err(node, "a mirroring (or degenerate) to_world is not supported"));
        }
        let origin = to_world.transform_point3(Vec3::ZERO);
        let forward = to_world.transform_vector3(Vec3::Z);
        let up = to_world.transform_vector3(Vec3::Y);
        let mut sensor = Sensor::looking_at(origin, origin + forward, up, fov_y).map_err(|e| self.err(node, e))?;
        // Mitsuba's lens and plane of focus are in camera space: scaled by to_world.
        sensor.lens = lens.map(|l| ThinLens {
            aperture_radius: l.aperture_radius * to_world.transform_vector3(Vec3::X).length(),
            focus_distance: l.focus_distance * forward.length(),
        });
        if orthographic {
            // Mitsuba's orthographic camera sees local x in [-1, 1] across the film's width
            // and y in [-1/aspect, 1/aspect] up its height, scaled by to_world.
            let (sx, sy) = (to_world.transform_vector3(Vec3::X).length(), up.length());
            if (sx - sy).abs() > 1e-4 * sx.max(sy) {
                return Err(self.err(node, format!("an orthographic to_world scaled differently in x ({sx}) and y ({sy}) is not supported")));
            }
            sensor = Sensor { fov_y: 0.0, ..sensor }.orthographic(2.0 * sy / aspect);
        }
        self.out.sensors.push(sensor);
        self.sensor_media.push(media::SensorMedium { node, id: medium, near_clip });
        Ok(())
    }

    fn film(&mut self, node: Node<'a, 'i>) -> Result<Film, SceneError> {
        if self.plugin_type(node)? != "hdrfilm" {
            return Err(self.err(node, format!("film \"{}\" is unsupported (hdrfilm is)", self.plugin_type(node)?)));
        }
        let mut items = elements(node);
        let mut side = |name: &str, default: u32| -> Result<u32, SceneError> {
            match self.take(&mut items, name) {
                Some(n) => {
                    let v = self.int(n)?;
                    u32::try_from(v).ok().filter(|v| (1..=MAX_IMAGE_SIDE).contains(v)).ok_or_else(|| self.err(n, format!("{v} is not in 1..={MAX_IMAGE_SIDE}")))
                }
                None => Ok(default),
            }
        };
        let film = Film { width: side("width", 768)?, height: side("height", 576)? };
        // Output settings: the renderer writes its own formats.
        for name in ["pixel_format", "component_format", "file_format", "banner", "sample_border"] {
            self.take(&mut items, name);
        }
        // The pixel filter (Mitsuba's default: a Gaussian of standard deviation 0.5).
        let filter = match self.take_tag(&mut items, "rfilter") {
            None => PixelFilter::Gaussian { stddev: 0.5 },
            Some(f) => {
                let kind = self.plugin_type(f)?;
                let mut params = elements(f);
                let mut size = |name: &str, make: fn(Option<f32>) -> Result<PixelFilter, String>| -> Result<PixelFilter, SceneError> {
                    let v = self.take(&mut params, name).map(|n| self.float(n)).transpose()?;
                    make(v).map_err(|e| self.err(f, format!("{name} {e}")))
                };
                let filter = match kind.as_str() {
                    "box" => PixelFilter::Box,
                    "gaussian" => size("stddev", PixelFilter::gaussian)?,
                    "tent" => size("radius", PixelFilter::tent)?,
                    // Filters with negative lobes: a sample's weight would need a sign.
                    _ => {
                        self.warn(f, "rendered with a box filter (uniform samples over each pixel); gaussian and tent are exact");
                        params.clear();
                        PixelFilter::Box
                    }
                };
                self.rest(&params, f)?;
                filter
            }
        };
        self.out.pixel_filter = Some(filter);
        self.rest(&items, node)?;
        Ok(film)
    }

    // -----------------------------------------------------------------------------------
    // Materials and textures
    // -----------------------------------------------------------------------------------

    /// A `<texture type="bitmap|checkerboard">`, its `to_uv` recorded in
    /// [`Self::uv_maps`].
    fn texture(&mut self, node: Node<'a, 'i>) -> Result<ColorValue, SceneError> {
        let kind = self.plugin_type(node)?;
        let mut items = elements(node);
        let to_uv = self.take_transform(&mut items, "to_uv")?.map(uv_affine).filter(|a| *a != Affine2::IDENTITY);
        let texture = match kind.as_str() {
            "bitmap" => self.bitmap(node, &mut items)?,
            "checkerboard" => {
                let mut color = |name: &str, default: f32| match self.take(&mut items, name) {
                    None => Ok([default; 3]),
                    Some(n) if n.tag_name().name() == "texture" || n.tag_name().name() == "ref" => {
                        Err(self.err(n, "a checkerboard's colours must be constants"))
                    }
                    Some(n) => self.rgb(n),
                };
                // Mitsuba's defaults; color0 where the fractional parts of u and v
                // (Mitsuba's, v down the image) are both below or both above 1/2.
                let (c0, c1) = (color("color0", 0.4)?, color("color1", 0.2)?);
                let line = self.doc.text_pos_at(node.range().start).row;
                Texture {
                    path: PathBuf::from(format!("{}#checkerboard(line {line})", self.path.display())),
                    image: Image { width: 2, height: 2, data: vec![c0, c1, c1, c0] }.into(),
                    filter: Filter::Nearest,
                    wrap: [Wrap::Repeat; 2],
                    uv_set: 0,
                }
            }
            _ => return Err(self.err(node, format!("texture \"{kind}\" is unsupported (bitmap and checkerboard are)"))),
        };
        self.rest(&items, node)?;
        if let Some(a) = to_uv {
            self.uv_maps.push((texture.image.clone(), a));
        }
        Ok(ColorValue::Texture(texture))
    }

    /// The image and filter of `<texture type="bitmap">` `node` (its other parameters in
    /// `items`).
    fn bitmap(&mut self, node: Node<'a, 'i>, items: &mut Items<'a, 'i>) -> Result<Texture, SceneError> {
        let file = self.take(items, "filename").map(|n| self.string(n)).transpose()?.ok_or_else(|| self.err(node, "no filename"))?;
        let raw = self.take_bool(items, "raw", false)?;
        let filter = match self.take(items, "filter_type") {
            None => Filter::Bilinear,
            Some(n) => match self.string(n)?.as_str() {
                "bilinear" => Filter::Bilinear,
                "nearest" => Filter::Nearest,
                other => return Err(self.err(n, format!("filter_type \"{other}\" is not bilinear or nearest"))),
            },
        };
        let wrap = match self.take(items, "wrap_mode") {
            None => Wrap::Repeat,
            Some(n) => {
                let mode = self.string(n)?;
                Wrap::from_name(&mode).ok_or_else(|| self.err(n, format!("wrap_mode \"{mode}\" is not repeat, clamp or mirror")))?
            }
        };
        let (path, bytes) = self.read_file(node, &file)?;
        let is_linear = path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("exr") || e.eq_ignore_ascii_case("hdr"));
        let image = if is_linear {
            image::decode_linear(&bytes, &path).map_err(|e| self.err(node, e.to_string()))?
        } else {
            let mut img = image::decode_ldr(&bytes, &path).map_err(|e| self.err(node, e.to_string()))?;
            if !raw {
                img.data.iter_mut().flatten().for_each(|c| *c = srgb_decode(*c));
            }
            img
        };
        if image.find_non_finite().is_some() {
            return Err(self.err(node, format!("{} has non-finite pixels", path.display())));
        }
        Ok(Texture { path, image: image.into(), filter, wrap: [wrap; 2], uv_set: 0 })
    }

    /// The `to_uv` of a texture image (identity for one without).
    fn uv_map(&self, image: &Arc<Image>) -> Affine2 {
        self.uv_maps.iter().find(|(i, _)| Arc::ptr_eq(i, image)).map_or(Affine2::IDENTITY, |(_, a)| *a)
    }

    /// The one `to_uv` that every texture of material `material` and of `emission` shares
    /// (the model has one set of texture coordinates per mesh), at shape `node`.
    fn shape_uv_map(&self, node: Node, material: usize, emission: &ColorValue) -> Result<Affine2, SceneError> {
        let m = &self.out.materials[material];
        let mut images: Vec<&Arc<Image>> = Vec::new();
        for v in [&m.base_color, emission] {
            if let ColorValue::Texture(t) = v {
                images.push(&t.image);
            }
        }
        for v in [Some(&m.roughness), Some(&m.metallic), m.alpha.as_ref().map(|a| &a.value)].into_iter().flatten() {
            if let ScalarValue::Texture(t) = v {
                images.push(&t.image);
            }
        }
        if let Some(p) = &m.perturbation {
            images.push(&p.texture().image);
        }
        let mut maps = images.into_iter().map(|i| self.uv_map(i));
        let first = maps.next().unwrap_or(Affine2::IDENTITY);
        if maps.any(|a| a != first) {
            return Err(self.err(node, "the textures of one shape have different to_uv transforms (one set of texture coordinates per mesh)"));
        }
        Ok(first)
    }

    /// A colour parameter: a constant, a nested bitmap or a `<ref>` to a texture.
    fn color_param(&mut self, items: &mut Items<'a, 'i>, name: &str, default: [f32; 3]) -> Result<ColorValue, SceneError> {
        let Some(n) = self.take(items, name) else { return Ok(ColorValue::Constant(default)) };
        match n.tag_name().name() {
            "texture" => self.texture(n),
            "ref" => {
                let id = self.required(n, "id")?;
                self.textures.get(&id).cloned().ok_or_else(|| self.err(n, format!("no texture with id \"{id}\"")))
            }
            _ => Ok(ColorValue::Constant(self.rgb(n)?)),
        }
    }

    fn scalar_param(&mut self, items: &mut Items<'a, 'i>, name: &str, default: f32) -> Result<ScalarValue, SceneError> {
        let node = items.iter().find(|n| n.attribute("name") == Some(name)).copied();
        Ok(match self.color_param(items, name, [default; 3])? {
            ColorValue::Constant(c) => {
                let v = c[0];
                if !(0.0..=1.0).contains(&v) {
                    return Err(self.err(node.unwrap_or(self.doc.root_element()), format!("{v} is outside [0, 1]")));
                }
                ScalarValue::Constant(v)
            }
            ColorValue::Texture(t) => ScalarValue::Texture(t),
        })
    }

    /// Adds the material of `<bsdf>` `node` named `name` and returns its index. The
    /// wrappers `twosided`, `normalmap` or `bumpmap` (one of the two) and `mask` may enclose
    /// the BSDF, once each, in any order.
    fn bsdf(&mut self, node: Node<'a, 'i>, name: &str) -> Result<usize, SceneError> {
        let (mut node, mut one_sided, mut perturbation, mut mask) = (node, true, None, None);
        loop {
            let kind = self.plugin_type(node)?;
            if (kind == "normalmap" || kind == "bumpmap") && perturbation.is_some() {
                return Err(self.err(node, format!("{kind} inside a normalmap or bumpmap is not supported (one perturbation of the normal per BSDF)")));
            }
            if kind == "twosided" && !one_sided || kind == "mask" && mask.is_some() {
                return Err(self.err(node, format!("{kind} inside a {kind} is not supported (one {kind} per BSDF)")));
            }
            if !(kind == "twosided" || kind == "normalmap" || kind == "bumpmap" || kind == "mask") {
                break;
            }
            let mut items = elements(node);
            let inner = self.take_tag(&mut items, "bsdf").ok_or_else(|| self.err(node, format!("{kind} needs one nested <bsdf>")))?;
            match kind.as_str() {
                "twosided" => one_sided = false,
                "normalmap" => perturbation = Some(Perturbation::Normal(self.normal_map(&mut items, node)?)),
                "bumpmap" => perturbation = Some(Perturbation::Bump(self.bump_map(&mut items, node)?)),
                _ => mask = Some(self.mask(&mut items)?),
            }
            self.rest(&items, node)?;
            node = inner;
        }
        let index = self.bsdf_material(node, name, one_sided)?;
        if self.out.materials[index].kind.is_dielectric() && (perturbation.is_some() || mask.is_some()) {
            return Err(self.err(node, "a normalmap, bumpmap or mask around a dielectric is not supported"));
        }
        self.out.materials[index].perturbation = perturbation;
        self.out.materials[index].alpha = mask.flatten();
        Ok(index)
    }

    /// The alpha test of a `<bsdf type="mask">`: its `opacity` (a number or a bitmap, 0.5
    /// by default) as a coverage ([`AlphaMode::Blend`]): a ray passes through with
    /// probability 1 − opacity, as in Mitsuba. None for an opacity of 1 everywhere.
    fn mask(&mut self, items: &mut Items<'a, 'i>) -> Result<Option<AlphaMask>, SceneError> {
        let value = self.scalar_param(items, "opacity", 0.5)?;
        Ok(Some(AlphaMask { value, mode: AlphaMode::Blend }).filter(|a| !a.never_cuts()))
    }

    /// The height field of a `<bsdf type="bumpmap">` (`node`): its one texture (a bitmap or
    /// a `<ref>` to one, under any name) and `scale` (1 by default).
    fn bump_map(&mut self, items: &mut Items<'a, 'i>, node: Node<'a, 'i>) -> Result<BumpMap, SceneError> {
        let i = items
            .iter()
            .position(|n| matches!(n.tag_name().name(), "texture" | "ref"))
            .ok_or_else(|| self.err(node, "bumpmap needs a height texture (a nested <texture>)"))?;
        let at = items.remove(i);
        let texture = match at.tag_name().name() {
            "texture" => self.texture(at)?,
            _ => {
                let id = self.required(at, "id")?;
                self.textures.get(&id).cloned().ok_or_else(|| self.err(at, format!("no texture with id \"{id}\"")))?
            }
        };
        let ColorValue::Texture(texture) = texture else { return Err(self.err(at, "a bump map's heights must be a bitmap texture")) };
        let scale = self.take_float(items, "scale", 1.0)?;
        if !scale.is_finite() {
            return Err(self.err(node, format!("scale {scale} is not finite")));
        }
        self.perturbation_refinements(items, node)?;
        Ok(BumpMap { texture, scale })
    }

    /// Mitsuba's refinements of a `normalmap`'s or `bumpmap`'s perturbed frame, which the
    /// model does not make: a warning where they are on (Mitsuba's default).
    fn perturbation_refinements(&mut self, items: &mut Items<'a, 'i>, node: Node<'a, 'i>) -> Result<(), SceneError> {
        let shadowing = self.take_bool(items, "use_shadowing_function", true)?;
        let flip = self.take_bool(items, "flip_invalid_normals", true)?;
        if shadowing || flip {
            let what: Vec<&str> = [
                (shadowing, "the shadow-terminator factor (use_shadowing_function)"),
                (flip, "the turning of normals that face away from the viewer (flip_invalid_normals)"),
            ]
            .iter()
            .filter(|(on, _)| *on)
            .map(|(_, w)| *w)
            .collect();
            self.warn(node, format!("approximate: rendered without {}", what.join(" and ")));
        }
        Ok(())
    }

    /// The `normalmap` texture of a `<bsdf type="normalmap">` (`node`): a bitmap whose RGB
    /// in [0, 1] encodes tangent-space normals as the model's normal maps do, with Mitsuba's
    /// bitangent cross(n, tangent) everywhere ([`Bitangent::Cross`]).
    fn normal_map(&mut self, items: &mut Items<'a, 'i>, node: Node<'a, 'i>) -> Result<NormalMap, SceneError> {
        let at = items.iter().find(|n| n.attribute("name") == Some("normalmap")).copied().unwrap_or(node);
        let texture = match self.color_param(items, "normalmap", [0.5, 0.5, 1.0])? {
            ColorValue::Texture(t) => t,
            ColorValue::Constant(_) if at == node => return Err(self.err(node, "normalmap needs a `normalmap` bitmap texture")),
            ColorValue::Constant(_) => return Err(self.err(at, "a normal map must be a bitmap texture")),
        };
        if let Some((x, y, v)) = texture.image.find_outside(3, 0.0, 1.0) {
            return Err(self.err(at, format!("{} has {v} at pixel ({x}, {y}), outside [0, 1]", texture.path.display())));
        }
        self.perturbation_refinements(items, node)?;
        Ok(NormalMap { texture, scale: 1.0, bitangent: Bitangent::Cross })
    }

    /// Adds the material of BSDF `node` (any type but twosided) named `name`; `one_sided`
    /// when it is not wrapped in a twosided: black from behind, as in Mitsuba.
    /// Not split: one arm per Mitsuba BSDF plugin, each mapping that plugin's properties,
    /// as Mitsuba's plugin documentation lists them.
    fn bsdf_material(&mut self, node: Node<'a, 'i>, name: &str, one_sided: bool) -> Result<usize, SceneError> {
        let kind = self.plugin_type(node)?;
        let mut items = elements(node);
        let material = match kind.as_str() {
            "diffuse" => Material { one_sided, ..Material::diffuse(name, self.color_param(&mut items, "reflectance", [0.5; 3])?) },
            "principled" => {
                let base_color = self.color_param(&mut items, "base_color", [0.5; 3])?;
                let roughness = self.scalar_param(&mut items, "roughness", 0.5)?;
                let metallic = self.scalar_param(&mut items, "metallic", 0.0)?;
                // Mitsuba's `specular` s is Schlick's normal-incidence reflectance 0.08 s, the
                // index (1 + √(0.08 s)) / (1 − √(0.08 s)); or the index is given as `eta`.
                let ior = match (self.take(&mut items, "specular"), self.take(&mut items, "eta")) {
                    (Some(_), Some(e)) => return Err(self.err(e, "a principled BSDF takes `specular` or `eta`, not both")),
                    (None, None) => DEFAULT_IOR,
                    (None, Some(e)) => {
                        let eta = self.float(e)?;
                        if !(MIN_IOR..=MAX_IOR).contains(&eta) {
                            return Err(self.err(e, format!("eta = {eta} is outside [{MIN_IOR}, {MAX_IOR}]")));
                        }
                        eta
                    }
                    (Some(n), None) => {
                        let specular = self.float(n)?;
                        let r = (0.08 * f64::from(specular)).sqrt();
                        let eta = ((1.0 + r) / (1.0 - r)) as f32;
                        if specular.is_nan() || specular < 0.0 || !(MIN_IOR..=MAX_IOR).contains(&eta) {
                            return Err(self.err(n, format!("specular = {specular} is outside [0, {:.3}] (an index of refraction in [1, {MAX_IOR}])", max_specular())));
                        }
                        eta
                    }
                };
                for zero in ["spec_tint", "anisotropic", "sheen", "sheen_tint", "clearcoat", "spec_trans", "flatness"] {
                    if let Some(n) = self.take(&mut items, zero) {
                        if self.float(n)? != 0.0 {
                            return Err(self.err(n, "only 0 is supported"));
                        }
                    }
                }
                if !self.principled_warned {
                    self.principled_warned = true;
                    self.warn(node, "approximate: Mitsuba's Disney diffuse lobe is rendered as Lambert, and its dielectric Fresnel term as Schlick's of the same index (glTF metallic-roughness)");
                }
                Material { name: name.into(), kind: MaterialKind::Principled, base_color, roughness, metallic, one_sided, perturbation: None, alpha: None, ior, absorption: [0.0; 3], distribution: Distribution::Ggx, eta: [0.0; 3], k: [0.0; 3], nonlinear: false, layered: true, specular: [1.0; 3] }
            }
            "roughconductor" | "conductor" => {
                let rough = kind == "roughconductor";
                let (roughness, distribution) = self.microfacet_roughness(&mut items, node, rough)?;
                if rough {
                    // Sampling only: the same material either way.
                    self.take_bool(&mut items, "sample_visible", true)?;
                } else {
                    self.warn(node, "approximate: a smooth conductor is rendered at the smallest roughness (alpha 0.001)");
                }
                let complex_ior = match (self.take(&mut items, "material"), self.take(&mut items, "eta"), self.take(&mut items, "k")) {
                    (m, None, None) => {
                        let name = m.map(|n| self.string(n)).transpose()?.unwrap_or_else(|| "none".into());
                        metal(&name).ok_or_else(|| {
                            let known: Vec<&str> = METALS.iter().map(|(k, _, _)| *k).collect();
                            self.err(node, format!("conductor \"{name}\" is not one of {}", known.join(", ")))
                        })?
                    }
                    (None, Some(eta), Some(k)) => {
                        let (eta, k) = (self.rgb(eta)?, self.rgb(k)?);
                        if eta.iter().chain(&k).any(|v| *v < 0.0) {
                            return Err(self.err(node, "eta and k must not be negative"));
                        }
                        [eta, k]
                    }
                    _ => return Err(self.err(node, "give either `material` or both `eta` and `k`")),
                };
                let tint = self.color_param(&mut items, "specular_reflectance", [1.0; 3])?;
                Material::conductor(name.into(), tint, roughness, distribution, complex_ior, one_sided)
            }
            "dielectric" | "thindielectric" | "roughdielectric" => {
                let (roughness, distribution) = self.microfacet_roughness(&mut items, node, kind == "roughdielectric")?;
                if kind == "roughdielectric" {
                    // Sampling only: the same material either way.
                    self.take_bool(&mut items, "sample_visible", true)?;
                }
                if !one_sided {
                    return Err(self.err(node, "a dielectric has two sides of its own: remove the twosided around it"));
                }
                let eta = self.relative_ior(&mut items, node, "bk7")?;
                if let Some(n) = self.take(&mut items, "specular_reflectance") {
                    if self.rgb(n)? != [1.0; 3] {
                        return Err(self.err(n, "only 1 is supported (the reflection is untinted)"));
                    }
                }
                let base_color = self.color_param(&mut items, "specular_transmittance", [1.0; 3])?;
                let kind = match kind.as_str() {
                    "dielectric" => MaterialKind::Dielectric,
                    "thindielectric" => MaterialKind::ThinDielectric,
                    _ => MaterialKind::RoughDielectric,
                };
                if kind == MaterialKind::RoughDielectric && eta == 1.0 {
                    return Err(self.err(node, "int_ior equals ext_ior: a rough dielectric needs two different media"));
                }
                let mut glass = Material::glass(name.into(), kind, base_color, eta);
                if kind == MaterialKind::RoughDielectric {
                    glass.roughness = roughness;
                    glass.distribution = distribution;
                }
                glass
            }
            "plastic" | "roughplastic" => {
                let rough = kind == "roughplastic";
                let (alpha, distribution) = self.microfacet_alpha(&mut items, node, rough, true)?;
                if rough {
                    // Sampling only: the same material either way.
                    self.take_bool(&mut items, "sample_visible", true)?;
                } else {
                    self.warn(node, "approximate: a smooth plastic's mirror reflection is rendered as a lobe of the smallest roughness (alpha 0.001)");
                }
                let eta = self.relative_ior(&mut items, node, "polypropylene")?;
                if eta == 1.0 {
                    return Err(self.err(node, "int_ior and ext_ior are equal: no interface"));
                }
                let diffuse = self.color_param(&mut items, "diffuse_reflectance", [0.5; 3])?;
                let specular = self.plastic_specular(&mut items, node)?;
                let nonlinear = self.take_bool(&mut items, "nonlinear", false)?;
                Material { nonlinear, one_sided, specular, ..Material::plastic(name.into(), diffuse, alpha.sqrt(), distribution, eta) }
            }
            "pplastic" => {
                // Unpolarised, as Mitsuba's RGB variants render it: a rough reflection plus
                // the base seen through two smooth refractions.
                let (alpha, distribution) = self.microfacet_alpha(&mut items, node, true, true)?;
                self.take_bool(&mut items, "sample_visible", true)?;
                let eta = self.relative_ior(&mut items, node, "polypropylene")?;
                if eta == 1.0 {
                    return Err(self.err(node, "int_ior and ext_ior are equal: no interface"));
                }
                let diffuse = self.color_param(&mut items, "diffuse_reflectance", [0.5; 3])?;
                let specular = self.plastic_specular(&mut items, node)?;
                Material { one_sided, layered: false, specular, ..Material::plastic(name.into(), diffuse, alpha.sqrt(), distribution, eta) }
            }
            _ => return Err(self.err(node, format!("bsdf \"{kind}\" is unsupported (diffuse, twosided, normalmap, bumpmap, mask, principled, conductor, roughconductor, plastic, roughplastic, pplastic, dielectric, thindielectric and roughdielectric are)"))),
        };
        self.rest(&items, node)?;
        self.out.materials.push(material);
        Ok(self.out.materials.len() - 1)
    }

    /// A plastic's `specular_reflectance`: a constant colour in [0, 1] (Mitsuba's default
    /// 1); a texture of it is unsupported.
    fn plastic_specular(&mut self, items: &mut Items<'a, 'i>, node: Node<'a, 'i>) -> Result<[f32; 3], SceneError> {
        if let Some(n) = items.iter().find(|n| n.attribute("name") == Some("specular_reflectance")) {
            if n.tag_name().name() == "texture" {
                return Err(self.err(*n, "a textured specular_reflectance is unsupported (a constant colour is)"));
            }
        }
        let tint = self.take_rgb(items, "specular_reflectance", [1.0; 3])?;
        if let Some(v) = tint.iter().find(|v| !(0.0..=1.0).contains(*v)) {
            return Err(self.err(node, format!("specular_reflectance {v} is outside [0, 1]")));
        }
        Ok(tint)
    }

    /// The alpha of a rough BSDF's `alpha` (`rough`; Mitsuba's default 0.1) and its
    /// distribution ([`Self::microfacet_distribution`]); alpha 0 for a smooth BSDF
    /// (rendered as the model's smallest roughness).
    fn microfacet_alpha(&mut self, items: &mut Items<'a, 'i>, node: Node<'a, 'i>, rough: bool, beckmann: bool) -> Result<(f32, Distribution), SceneError> {
        if !rough {
            return Ok((0.0, Distribution::Ggx));
        }
        let alpha = match (self.take(items, "alpha_u"), self.take(items, "alpha_v")) {
            (None, None) => self.take_float(items, "alpha", 0.1)?,
            (Some(u), Some(v)) if u.tag_name().name() == "float" && v.tag_name().name() == "float" => {
                let (au, av) = (self.float(u)?, self.float(v)?);
                let alpha = (au * av).max(0.0).sqrt();
                self.warn(
                    node,
                    format!("approximate: anisotropic roughness (alpha_u {au}, alpha_v {av}) is rendered isotropic at their geometric mean {alpha}"),
                );
                alpha
            }
            (Some(n), _) | (_, Some(n)) => {
                return Err(self
                    .err(n, "anisotropic roughness is supported as two <float>s alpha_u and alpha_v (rendered isotropic); textures of them are unsupported"))
            }
        };
        if !(0.0..=1.0).contains(&alpha) {
            return Err(self.err(node, format!("alpha {alpha} is outside [0, 1]")));
        }
        Ok((alpha, self.microfacet_distribution(items, node, beckmann)?))
    }

    /// The roughness (√alpha) of a rough BSDF whose model has both distributions: its
    /// `alpha` a number (Mitsuba's default 0.1) or a bitmap, whose texels (R channel, in
    /// [0, 1]) become √alpha, interpolated as such (with a warning: Mitsuba interpolates
    /// alpha); and its distribution. 0 for a smooth BSDF.
    fn microfacet_roughness(&mut self, items: &mut Items<'a, 'i>, node: Node<'a, 'i>, rough: bool) -> Result<(ScalarValue, Distribution), SceneError> {
        let textured = rough && items.iter().any(|n| n.attribute("name") == Some("alpha") && matches!(n.tag_name().name(), "texture" | "ref"));
        if !textured {
            let (alpha, distribution) = self.microfacet_alpha(items, node, rough, true)?;
            return Ok((ScalarValue::Constant(alpha.sqrt()), distribution));
        }
        let ColorValue::Texture(mut t) = self.color_param(items, "alpha", [0.1; 3])? else { unreachable!("a bitmap or a reference to one") };
        if let Some(v) = t.image.data.iter().map(|p| p[0]).find(|v| !(0.0..=1.0).contains(v)) {
            return Err(self.err(node, format!("alpha texel {v} of {} is outside [0, 1]", t.path.display())));
        }
        std::sync::Arc::make_mut(&mut t.image).data.iter_mut().for_each(|p| *p = [p[0].sqrt(); 3]);
        self.warn(node, "approximate: the alpha bitmap is interpolated as its square root, the model's roughness (exact at texel centres)");
        Ok((ScalarValue::Texture(t), self.microfacet_distribution(items, node, true)?))
    }

    /// A rough BSDF's `distribution`: Beckmann (Mitsuba's default) where the material has it
    /// (`beckmann`), otherwise rendered as GGX with a warning.
    fn microfacet_distribution(&mut self, items: &mut Items<'a, 'i>, node: Node<'a, 'i>, beckmann: bool) -> Result<Distribution, SceneError> {
        let distribution = self.take(items, "distribution").map(|n| self.string(n)).transpose()?.unwrap_or_else(|| "beckmann".into());
        if distribution == "beckmann" && beckmann {
            return Ok(Distribution::Beckmann);
        }
        if distribution != "ggx" {
            self.warn(node, format!("approximate: the {distribution} distribution is rendered as GGX"));
        }
        Ok(Distribution::Ggx)
    }

    /// `int_ior` (`int_default` when absent) over `ext_ior` (air when absent), within the
    /// model's [MIN_IOR, MAX_IOR].
    fn relative_ior(&self, items: &mut Items<'a, 'i>, node: Node<'a, 'i>, int_default: &str) -> Result<f32, SceneError> {
        let eta = self.ior(items, "int_ior", int_default)? / self.ior(items, "ext_ior", "air")?;
        if !(MIN_IOR..=MAX_IOR).contains(&eta) {
            return Err(self.err(node, format!("int_ior / ext_ior = {eta} is outside [{MIN_IOR}, {MAX_IOR}]")));
        }
        Ok(eta)
    }

    /// An index of refraction: a number, or one of the materials Mitsuba names (`default`
    /// when absent).
    fn ior(&self, items: &mut Items<'a, 'i>, name: &str, default: &str) -> Result<f32, SceneError> {
        let named = |node: Option<Node>, key: &str| {
            IORS.iter().find(|(k, _)| *k == key).map(|(_, v)| *v).ok_or_else(|| {
                let known: Vec<&str> = IORS.iter().map(|(k, _)| *k).collect();
                self.err(node.unwrap_or(self.doc.root_element()), format!("{name} \"{key}\" is not one of {}", known.join(", ")))
            })
        };
        match self.take(items, name) {
            None => named(None, default),
            Some(n) if n.tag_name().name() == "string" => named(Some(n), &self.string(n)?),
            Some(n) => {
                let v = self.float(n)?;
                if v > 0.0 {
                    Ok(v)
                } else {
                    Err(self.err(n, format!("{name} {v} is not positive")))
                }
            }
        }
    }

    /// The default material of a shape without a BSDF: Mitsuba's (one-sided) diffuse 0.5,
    /// or for an emitting shape (`emitter`) diffuse 0, as Mitsuba gives it.
    fn default_material(&mut self, emitter: bool) -> usize {
        let (name, reflectance) = if emitter { ("default_emitter", 0.0) } else { ("default", 0.5) };
        if let Some(i) = self.out.materials.iter().position(|m| m.name == name) {
            return i;
        }
        self.out.materials.push(Material { one_sided: true, ..Material::diffuse(name, ColorValue::Constant([reflectance; 3])) });
        self.out.materials.len() - 1
    }

    // -----------------------------------------------------------------------------------
    // Shapes and emitters
    // -----------------------------------------------------------------------------------

    /// Not split: one arm per Mitsuba shape plugin, each making that shape's mesh, then
    /// what every shape shares (its BSDF, emitter and transform).
    fn shape(&mut self, node: Node<'a, 'i>, count: usize) -> Result<(), SceneError> {
        let kind = self.plugin_type(node)?;
        let name = self.attr(node, "id")?.unwrap_or_else(|| format!("shape{count}"));
        let mut items = elements(node);
        let to_world = self.take_transform(&mut items, "to_world")?.unwrap_or(Mat4::IDENTITY);
        let flip_normals = self.take_bool(&mut items, "flip_normals", false)?;
        // A sphere's centre and radius in its own space.
        let mut local_sphere = None;
        let (mut positions, mut normals, mut uvs, mut indices, file): (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<[u32; 3]>, PathBuf) = match kind
            .as_str()
        {
            "obj" | "ply" | "serialized" => {
                let rel = self.take(&mut items, "filename").map(|n| self.string(n)).transpose()?.ok_or_else(|| self.err(node, "no filename"))?;
                let (path, bytes) = self.read_file(node, &rel)?;
                let mut face_normals = self.take_bool(&mut items, "face_normals", false)?;
                let (p, mut n, mut t, i) = match kind.as_str() {
                    "obj" => {
                        // Mitsuba flips OBJ texture coordinates by default, which keeps the
                        // OBJ convention (v up) that the model uses.
                        let flip = self.take_bool(&mut items, "flip_tex_coords", true)?;
                        let d = obj::load(&path, &bytes)?;
                        let uvs = if flip { d.uvs } else { d.uvs.iter().map(|&[u, v]| [u, 1.0 - v]).collect() };
                        (d.positions, d.normals, uvs, d.indices)
                    }
                    "ply" => {
                        let d = ply::load(&path, &bytes)?;
                        (d.positions, d.normals, d.uvs.iter().map(|&[u, v]| [u, 1.0 - v]).collect(), d.indices)
                    }
                    _ => {
                        let index = match self.take(&mut items, "shape_index") {
                            Some(n) => u32::try_from(self.int(n)?).map_err(|_| self.err(n, "shape_index is negative"))?,
                            None => 0,
                        };
                        let d = serialized_mesh(&bytes, index).map_err(|e| self.err(node, format!("{}: {e}", path.display())))?;
                        face_normals |= d.face_normals;
                        // Mitsuba's texture coordinates (v down), as PLY's.
                        (d.positions, d.normals, d.uvs.iter().map(|&[u, v]| [u, 1.0 - v]).collect(), d.indices)
                    }
                };
                if face_normals {
                    n.clear();
                } else if n.is_empty() {
                    // Mitsuba smooths a mesh without normals unless told not to.
                    n = vertex_normals(&p, &i);
                }
                if t.len() != p.len() {
                    t.clear();
                }
                (p, n, t, i, path)
            }
            "rectangle" => (
                vec![[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]],
                vec![[0.0, 0.0, 1.0]; 4],
                vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
                vec![[0, 1, 2], [2, 3, 0]],
                self.path.to_path_buf(),
            ),
            "cube" => {
                let (p, n, t, i) = cube();
                (p, n, t, i, self.path.to_path_buf())
            }
            "sphere" => {
                let center = self.take(&mut items, "center").map(|n| self.point(n)).transpose()?.unwrap_or(Vec3::ZERO);
                let radius = self.take_float(&mut items, "radius", 1.0)?;
                if radius <= 0.0 {
                    return Err(self.err(node, "the radius is not positive"));
                }
                self.warn(node, format!("approximate: tessellated into {} triangles with exact normals", 2 * SPHERE_SEGMENTS * (SPHERE_SEGMENTS / 2 - 1)));
                local_sphere = Some((center, radius));
                let (p, n, t, i) = sphere(center, radius);
                (p, n, t, i, self.path.to_path_buf())
            }
            "disk" => {
                self.warn(node, format!("approximate: tessellated into {SPHERE_SEGMENTS} triangles"));
                let (p, n, t, i) = disk();
                (p, n, t, i, self.path.to_path_buf())
            }
            "cylinder" => {
                let p0 = self.take(&mut items, "p0").map(|n| self.point(n)).transpose()?.unwrap_or(Vec3::ZERO);
                let p1 = self.take(&mut items, "p1").map(|n| self.point(n)).transpose()?.unwrap_or(Vec3::Z);
                let radius = self.take_float(&mut items, "radius", 1.0)?;
                if radius <= 0.0 {
                    return Err(self.err(node, "the radius is not positive"));
                }
                if p0 == p1 {
                    return Err(self.err(node, "p0 and p1 are the same point"));
                }
                self.warn(node, format!("approximate: tessellated into {} triangles with exact normals", 2 * SPHERE_SEGMENTS));
                let (p, n, t, i) = cylinder(p0, p1, radius);
                (p, n, t, i, self.path.to_path_buf())
            }
            _ => return Err(self.err(node, format!("shape \"{kind}\" is unsupported (obj, ply, serialized, rectangle, cube, sphere, disk and cylinder are)"))),
        };
        let exterior = self.take(&mut items, "exterior").map(|n| self.medium_ref(n, "exterior")).transpose()?;
        let interior = self.take(&mut items, "interior");
        let in_medium = match (exterior, interior) {
            (None, Some(interior)) => match self.medium_shape(node, &name, interior, to_world, &positions, &indices, items)? {
                // A null BSDF: the shape is the medium's and nothing else.
                None => return Ok(()),
                // Another BSDF: a surface around the medium, made below.
                Some(rest) => {
                    items = rest;
                    self.medium_surface = Some(self.out.meshes.len());
                    None
                }
            },
            (None, None) => None,
            (Some(outside), None) => Some(media::InMedium { mesh: self.out.meshes.len(), node, id: outside, filled: false }),
            (Some(outside), Some(interior)) => {
                let inside = self.medium_ref(interior, "interior")?;
                if inside != outside {
                    return Err(self.err(
                        interior,
                        format!("a surface between two media (\"{outside}\" outside, \"{inside}\" inside) is unsupported: a scene holds one medium"),
                    ));
                }
                Some(media::InMedium { mesh: self.out.meshes.len(), node, id: outside, filled: true })
            }
        };
        // A <ref> may name an area emitter declared at the top level.
        let mut emitter_ref = None;
        while let Some(i) = items.iter().position(|n| n.tag_name().name() == "ref" && n.attribute("id").is_some_and(|id| self.area_emitters.contains_key(id))) {
            let r = items.remove(i);
            if emitter_ref.is_some() {
                return Err(self.err(r, "a shape takes one emitter"));
            }
            emitter_ref = Some(self.area_emitters[r.attribute("id").unwrap_or_default()].clone());
        }
        let material = match (self.take_tag(&mut items, "bsdf"), self.take_tag(&mut items, "ref").or_else(|| self.take(&mut items, "bsdf"))) {
            (Some(b), None) => self.bsdf(b, &name)?,
            (None, Some(r)) => {
                let id = self.required(r, "id")?;
                if let Some(&null) = self.null_bsdfs.get(&id) {
                    // A null BSDF around no medium: refused as the BSDF it is.
                    self.bsdf(null, &id)?;
                }
                *self.bsdfs.get(&id).ok_or_else(|| {
                    let mut known: Vec<&str> = self.bsdfs.keys().map(String::as_str).collect();
                    known.sort();
                    self.err(r, format!("no bsdf or area emitter with id \"{id}\" (bsdfs: {})", known.join(", ")))
                })?
            }
            (None, None) => self.default_material(emitter_ref.is_some() || items.iter().any(|n| n.tag_name().name() == "emitter")),
            (Some(_), Some(r)) => return Err(self.err(r, "a shape takes one bsdf")),
        };
        let emission = match (self.take_tag(&mut items, "emitter"), emitter_ref) {
            (Some(e), None) => {
                if self.plugin_type(e)? != "area" {
                    return Err(self.err(e, "a shape's emitter must be an area light"));
                }
                self.area_emitter(e)?
            }
            (None, Some(radiance)) => radiance,
            (None, None) => ColorValue::Constant([0.0; 3]),
            (Some(e), Some(_)) => return Err(self.err(e, "a shape takes one emitter")),
        };
        self.rest(&items, node)?;
        let uv_map = self.shape_uv_map(node, material, &emission)?;
        if uv_map != Affine2::IDENTITY {
            // The model's v runs up the image, Mitsuba's down.
            for t in &mut uvs {
                let [u, v] = uv_map.transform_point2(Vec2::new(t[0], 1.0 - t[1])).to_array();
                *t = [u, 1.0 - v];
            }
        }
        // Positions and normals to world space (normals by the inverse transpose).
        let nm = Mat3::from_mat4(to_world).inverse().transpose();
        for p in &mut positions {
            *p = to_world.transform_point3(Vec3::from(*p)).to_array();
        }
        for n in &mut normals {
            *n = (nm * Vec3::from(*n)).normalize_or_zero().to_array();
        }
        if flip_normals {
            for t in &mut indices {
                t.swap(1, 2);
            }
            for n in &mut normals {
                *n = n.map(|c| -c);
            }
        }
        if uvs.len() != positions.len() {
            uvs.clear();
        }
        check_triangles(&self.out.meshes, indices.len()).map_err(|e| self.err(node, e))?;
        // A sphere stays one where to_world turns, scales uniformly and moves it.
        let sphere = local_sphere.and_then(|(c, r)| {
            let m = Mat3::from_mat4(to_world);
            let s = m.x_axis.length();
            let similar = s > 0.0
                && [m.y_axis, m.z_axis].iter().all(|a| (a.length() - s).abs() <= 1e-5 * s)
                && [m.x_axis.dot(m.y_axis), m.y_axis.dot(m.z_axis), m.z_axis.dot(m.x_axis)].iter().all(|d| d.abs() <= 1e-5 * s * s);
            similar.then(|| Sphere { center: to_world.transform_point3(c).to_array(), radius: r * s })
        });
        self.out.meshes.push(Mesh {
            name,
            path: file,
            positions,
            normals,
            uvs,
            uvs1: Vec::new(),
            indices,
            material,
            emission,
            two_sided_emission: false,
            sphere,
        });
        self.in_medium.extend(in_medium);
        Ok(())
    }

    fn emitter(&mut self, node: Node<'a, 'i>, count: usize) -> Result<(), SceneError> {
        let kind = self.plugin_type(node)?;
        let name = self.attr(node, "id")?.unwrap_or_else(|| format!("light{count}"));
        let mut items = elements(node);
        let to_world = self.take_transform(&mut items, "to_world")?;
        let light = |kind, position, direction, color| Light { name: name.clone(), kind, position, direction, color, intensity: 1.0 };
        match kind.as_str() {
            "constant" | "envmap" => {
                if self.out.environment.is_some() {
                    return Err(self.err(node, "only one environment emitter is supported"));
                }
                let value = if kind == "constant" {
                    if to_world.is_some() {
                        return Err(self.err(node, "a constant emitter takes no to_world"));
                    }
                    self.color_param(&mut items, "radiance", [1.0; 3])?
                } else {
                    // Mitsuba looks directions up through the inverse of to_world's linear
                    // part (its translation moves no direction); only a rotation or a
                    // mirroring keeps them unit vectors, which its lookup assumes.
                    let rotation = Mat3::from_mat4(to_world.unwrap_or(Mat4::IDENTITY));
                    if !(rotation.transpose() * rotation).abs_diff_eq(Mat3::IDENTITY, 1e-4) {
                        return Err(self.err(node, "an environment map's to_world must be a rotation (scaling or shearing it is not supported)"));
                    }
                    let rel = self.take(&mut items, "filename").map(|n| self.string(n)).transpose()?.ok_or_else(|| self.err(node, "no filename"))?;
                    let (path, bytes) = self.read_file(node, &rel)?;
                    let map = image::decode_linear(&bytes, &path).map_err(|e| self.err(node, e.to_string()))?;
                    if map.width < 2 || map.height < 3 || map.find_non_finite().is_some() {
                        return Err(self.err(node, format!("{} is smaller than 2 × 3 or has non-finite pixels", path.display())));
                    }
                    self.warn(
                        node,
                        format!(
                            "approximate: resampled from Mitsuba's texel positions (pole-to-pole rows) to a grid {}× finer of centred texels",
                            envmap_refinement(map.width)
                        ),
                    );
                    // Sampling only: the expected image is the same either way.
                    self.take_bool(&mut items, "mis_compensation", false)?;
                    ColorValue::Texture(Texture::new(path, envmap_from_mitsuba(&map, rotation).into()))
                };
                let scale = self.take_float(&mut items, "scale", 1.0)?;
                if scale < 0.0 {
                    return Err(self.err(node, "the scale is negative"));
                }
                self.rest(&items, node)?;
                self.out.environment = Some(Environment { value, scale });
                return Ok(());
            }
            "point" => {
                let position = match (self.take(&mut items, "position"), to_world) {
                    (Some(p), None) => self.point(p)?,
                    (None, m) => m.unwrap_or(Mat4::IDENTITY).transform_point3(Vec3::ZERO),
                    (Some(_), Some(_)) => return Err(self.err(node, "give position or to_world, not both")),
                };
                let intensity = self.take_rgb(&mut items, "intensity", [1.0; 3])?;
                self.out.lights.push(light(LightKind::Point, position, Vec3::NEG_Y, intensity));
            }
            "spot" => {
                let m = to_world.unwrap_or(Mat4::IDENTITY);
                let intensity = self.take_rgb(&mut items, "intensity", [1.0; 3])?;
                let cutoff = self.take_float(&mut items, "cutoff_angle", 20.0)?;
                let beam = self.take_float(&mut items, "beam_width", cutoff * 0.75)?;
                if !(0.0 < cutoff && cutoff <= 90.0 && 0.0 <= beam && beam <= cutoff) {
                    return Err(self.err(node, format!("beam_width {beam} and cutoff_angle {cutoff} are not 0 <= beam_width <= cutoff_angle <= 90")));
                }
                let direction = m.transform_vector3(Vec3::Z).try_normalize().ok_or_else(|| self.err(node, "degenerate to_world"))?;
                let kind = LightKind::Spot { inner: beam.to_radians(), outer: cutoff.to_radians(), falloff: SpotFalloff::Linear };
                self.out.lights.push(light(kind, m.transform_point3(Vec3::ZERO), direction, intensity));
            }
            "directional" => {
                let direction = match (self.take(&mut items, "direction"), to_world) {
                    (Some(d), None) => self.point(d)?,
                    (None, m) => m.unwrap_or(Mat4::IDENTITY).transform_vector3(Vec3::Z),
                    (Some(_), Some(_)) => return Err(self.err(node, "give direction or to_world, not both")),
                };
                let direction = direction.try_normalize().ok_or_else(|| self.err(node, "the direction is zero"))?;
                let irradiance = self.take_rgb(&mut items, "irradiance", [1.0; 3])?;
                self.out.lights.push(light(LightKind::Directional, Vec3::ZERO, direction, irradiance));
            }
            _ => return Err(self.err(node, format!("emitter \"{kind}\" is unsupported (area, constant, envmap, point, spot and directional are)"))),
        }
        self.rest(&items, node)
    }
}

/// Width below which the renderer's copy of a Mitsuba environment map is a finer grid than
/// the map ([`envmap_from_mitsuba`]).
pub const ENVMAP_MIN_WIDTH: u32 = 1024;

/// The factor by which [`envmap_from_mitsuba`] refines a map `width` texels wide: the
/// smallest odd integer that brings it to [`ENVMAP_MIN_WIDTH`] (1 at or above it).
pub fn envmap_refinement(width: u32) -> u32 {
    ENVMAP_MIN_WIDTH.div_ceil(width.max(1)) | 1
}

/// A Mitsuba lat-long map, seen through its emitter's `to_world` rotation, as the
/// renderer's map, `s` = [`envmap_refinement`] times as many texels along each axis. Each
/// of the renderer's texels takes Mitsuba's radiance in the direction of the texel's
/// centre: the renderer's column x and row k (centred: u = (x + ½)/(sW), polar angle θ =
/// π (k + ½)/(sH), azimuth φ = 2π (u − ½) from −z towards +x, as `environment_uv`) give a
/// world direction d, Mitsuba looks it up in its own frame at `rotation`ᵀ d (the rotation
/// is orthogonal: a mirroring is allowed), and Mitsuba's lookup is bilinear between texels
/// centred at u = (x + ½)/W from −z (columns wrapping around) and placed at θ = π j/(H − 1)
/// (rows from pole to pole). The renderer's bilinear lookup of these values then departs
/// from Mitsuba's only within one of the renderer's texels of Mitsuba's texel centres,
/// where Mitsuba's interpolation bends, which refining keeps to a small fraction of a
/// texel of the map. Unturned, and with an even width, Mitsuba's texel centres fall on the
/// renderer's column centres (s is odd), so each row is Mitsuba's exactly; rows are
/// interpolated between Mitsuba's.
pub fn envmap_from_mitsuba(map: &Image, rotation: Mat3) -> Image {
    use std::f64::consts::PI;
    let (w, h) = (map.width as usize, map.height as usize);
    let s = envmap_refinement(map.width) as usize;
    let (out_w, out_h) = (s * w, s * h);
    let r = rotation.as_dmat3().transpose();
    let texel = |x: usize, y: usize| glam::DVec3::from(map.data[y * w + x].map(f64::from));
    let mut data = Vec::with_capacity(out_w * out_h);
    for k in 0..out_h {
        let (sin_theta, cos_theta) = (PI * (k as f64 + 0.5) / out_h as f64).sin_cos();
        for x in 0..out_w {
            let (sin_phi, cos_phi) = (2.0 * PI * ((x as f64 + 0.5) / out_w as f64 - 0.5)).sin_cos();
            let d = glam::DVec3::new(sin_theta * sin_phi, cos_theta, -sin_theta * cos_phi);
            let l = r * d;
            let u = (l.x.atan2(-l.z) / (2.0 * PI)).rem_euclid(1.0) * w as f64 - 0.5;
            let v = l.y.clamp(-1.0, 1.0).acos() / PI * (h - 1) as f64;
            let (x0, y0) = ((u.floor() as i64).rem_euclid(w as i64) as usize, (v.floor() as usize).min(h - 2));
            let (tu, tv) = (u - u.floor(), v - y0 as f64);
            let x1 = (x0 + 1) % w;
            let top = texel(x0, y0) * (1.0 - tu) + texel(x1, y0) * tu;
            let bottom = texel(x0, y0 + 1) * (1.0 - tu) + texel(x1, y0 + 1) * tu;
            data.push((top * (1.0 - tv) + bottom * tv).as_vec3().to_array());
        }
    }
    Image { width: out_w as u32, height: out_h as u32, data }
}

/// Mitsuba's vertex normals of a mesh that has none: each face's unit normal weighted by
/// the face's angle at the vertex, summed over the faces sharing the vertex.
fn vertex_normals(positions: &[[f32; 3]], indices: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let mut n = vec![Vec3::ZERO; positions.len()];
    for t in indices {
        let p = t.map(|i| Vec3::from(positions[i as usize]));
        let Some(face) = (p[1] - p[0]).cross(p[2] - p[0]).try_normalize() else { continue };
        for k in 0..3 {
            let (a, b) = ((p[(k + 1) % 3] - p[k]).normalize_or_zero(), (p[(k + 2) % 3] - p[k]).normalize_or_zero());
            n[t[k] as usize] += face * a.dot(b).clamp(-1.0, 1.0).acos();
        }
    }
    n.into_iter().map(|v| v.normalize_or_zero().to_array()).collect()
}

type Geometry = (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<[u32; 3]>);

/// Mitsuba's cube: [−1, 1]³, each face two counter-clockwise triangles seen from outside,
/// with flat normals and Mitsuba's texture coordinates (each face mapped onto [0, 1]²): face
/// s has vertices 4s .. 4s + 3 at the corners `CUBE_CORNERS` names (bit k of a corner: the
/// sign of axis k), with Mitsuba's uv (0, 1), (1, 1), (1, 0), (0, 0) (v down the image:
/// 1 − v in the model's), and triangles (4s, 4s + 1, 4s + 2) and (4s + 3, 4s, 4s + 2).
fn cube() -> Geometry {
    const NORMALS: [[f32; 3]; 6] = [[0.0, -1.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]];
    const CUBE_CORNERS: [u32; 24] = [1, 5, 4, 0, 3, 2, 6, 7, 1, 3, 7, 5, 5, 7, 6, 4, 4, 6, 2, 0, 3, 1, 0, 2];
    const UVS: [[f32; 2]; 4] = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
    let mut g: Geometry = Default::default();
    for (s, n) in NORMALS.iter().enumerate() {
        let base = 4 * s as u32;
        for k in 0..4 {
            let c = CUBE_CORNERS[4 * s + k];
            g.0.push(std::array::from_fn(|axis| if c & (1 << axis) != 0 { 1.0 } else { -1.0 }));
            g.1.push(*n);
            g.2.push([UVS[k][0], 1.0 - UVS[k][1]]);
        }
        g.3.push([base, base + 1, base + 2]);
        g.3.push([base + 3, base, base + 2]);
    }
    g
}

/// One mesh of a Mitsuba `.serialized` file.
struct SerializedMesh {
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    indices: Vec<[u32; 3]>,
    /// The file asks for face normals.
    face_normals: bool,
}

/// Mesh `index` of a Mitsuba `.serialized` file (`bytes`), in the format's versions 3 and 4:
/// a little-endian header (magic 0x041C, version), then a zlib stream of the flags (0x1
/// normals, 0x2 texture coordinates, 0x8 colours, 0x10 face normals, 0x2000 double
/// precision), the name (version 4: null-terminated), the vertex and triangle counts (u64)
/// and the arrays, one mesh after another; the meshes' offsets close the file (u64 in
/// version 4, u32 in 3) before their count (u32).
fn serialized_mesh(bytes: &[u8], index: u32) -> Result<SerializedMesh, String> {
    use std::io::Read;
    const MAGIC: u16 = 0x041C;
    let u16_at = |at: usize| bytes.get(at..at + 2).map(|b| u16::from_le_bytes([b[0], b[1]]));
    let (magic, version) = (u16_at(0), u16_at(2));
    if magic != Some(MAGIC) {
        return Err("not a Mitsuba serialized file (no 0x041C header)".into());
    }
    let version = version.unwrap_or(0);
    if !(3..=4).contains(&version) {
        return Err(format!("format version {version} is not supported (versions 3 and 4 are)"));
    }
    let truncated = || "the file is truncated".to_string();
    let start = if index == 0 {
        0
    } else {
        let count_at = bytes.len().checked_sub(4).ok_or_else(truncated)?;
        let count = u32::from_le_bytes(bytes[count_at..].try_into().unwrap());
        if index >= count {
            return Err(format!("shape_index {index} is out of range: the file holds {count} meshes"));
        }
        let width = if version == 4 { 8 } else { 4 };
        let at = count_at.checked_sub(width * (count - index) as usize).ok_or_else(truncated)?;
        let mut offset = [0u8; 8];
        offset[..width].copy_from_slice(&bytes[at..at + width]);
        usize::try_from(u64::from_le_bytes(offset)).map_err(|_| truncated())?
    };
    if u16_at(start) != Some(MAGIC) {
        return Err(format!("mesh {index} does not start with the 0x041C header at its offset {start}"));
    }
    let mut z = flate2::read::ZlibDecoder::new(bytes.get(start + 4..).ok_or_else(truncated)?);
    // Reads n bytes, growing the buffer with what the stream holds (a corrupt count
    // fails when the data end, without allocating what it claims).
    let mut read = |n: usize| -> Result<Vec<u8>, String> {
        let mut buf = Vec::new();
        (&mut z).take(n as u64).read_to_end(&mut buf).map_err(|e| format!("mesh {index}: its compressed data are damaged or end early ({e})"))?;
        if buf.len() == n {
            Ok(buf)
        } else {
            Err(format!("mesh {index}: its data end early"))
        }
    };
    let u32_of = |b: &[u8]| u32::from_le_bytes(b.try_into().unwrap());
    let flags = u32_of(&read(4)?);
    if version == 4 {
        while read(1)?[0] != 0 {}
    }
    let count = |b: Vec<u8>| usize::try_from(u64::from_le_bytes(b.try_into().unwrap())).map_err(|_| "a count beyond memory".to_string());
    let (vertices, triangles) = (count(read(8)?)?, count(read(8)?)?);
    if vertices > u32::MAX as usize || triangles > u32::MAX as usize {
        return Err(format!("mesh {index}: {vertices} vertices and {triangles} triangles are more than 32-bit indices address"));
    }
    let double = flags & 0x2000 != 0;
    let mut floats = |n: usize| -> Result<Vec<f32>, String> {
        Ok(if double {
            read(8 * n)?.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap()) as f32).collect()
        } else {
            read(4 * n)?.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
        })
    };
    let triples = |v: Vec<f32>| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let positions = triples(floats(3 * vertices)?);
    let normals = if flags & 0x1 != 0 { triples(floats(3 * vertices)?) } else { Vec::new() };
    let uvs = if flags & 0x2 != 0 { floats(2 * vertices)?.chunks_exact(2).map(|c| [c[0], c[1]]).collect() } else { Vec::new() };
    if flags & 0x8 != 0 {
        floats(3 * vertices)?;
    }
    let indices: Vec<[u32; 3]> = read(12 * triangles)?.chunks_exact(12).map(|c| [0, 4, 8].map(|k| u32_of(&c[k..k + 4]))).collect();
    if let Some(bad) = indices.iter().flatten().find(|&&i| i as usize >= vertices) {
        return Err(format!("mesh {index}: vertex index {bad} is out of range ({vertices} vertices)"));
    }
    if positions.iter().flatten().chain(normals.iter().flatten()).chain(uvs.iter().flatten()).any(|v| !v.is_finite()) {
        return Err(format!("mesh {index}: a non-finite value"));
    }
    Ok(SerializedMesh { positions, normals, uvs, indices, face_normals: flags & 0x10 != 0 })
}

/// Mitsuba's disk, the unit disk in the xy-plane facing +z, as `SPHERE_SEGMENTS` triangles
/// around its centre, with Mitsuba's polar texture coordinates (u the radius, v the angle
/// over 2π down the image, 1 − v in the model's: the centre is repeated per triangle at its
/// middle angle).
fn disk() -> Geometry {
    let n = SPHERE_SEGMENTS;
    let mut g: Geometry = Default::default();
    for i in 0..n {
        let base = g.0.len() as u32;
        let v = |k: f32| k / n as f32;
        let rim = |k: f32| {
            let phi = std::f32::consts::TAU * v(k);
            [phi.cos(), phi.sin(), 0.0]
        };
        let (a, b) = (i as f32, i as f32 + 1.0);
        g.0.extend([[0.0, 0.0, 0.0], rim(a), rim(b)]);
        g.1.extend([[0.0, 0.0, 1.0]; 3]);
        g.2.extend([[0.0, 1.0 - v(a + 0.5)], [1.0, 1.0 - v(a)], [1.0, 1.0 - v(b)]]);
        g.3.push([base, base + 1, base + 2]);
    }
    g
}

/// Mitsuba's cylinder: the open tube of `radius` around the segment from `p0` to `p1`, as
/// `SPHERE_SEGMENTS` quads around it, counter-clockwise from outside, with the exact normals
/// and Mitsuba's texture coordinates (u the angle over 2π from the first axis of the
/// segment's frame, Mitsuba's `coordinate_system`, which glam's `any_orthonormal_pair` is;
/// v along the axis from p0, down the image: 1 − v in the model's).
fn cylinder(p0: Vec3, p1: Vec3, radius: f32) -> Geometry {
    let n = SPHERE_SEGMENTS;
    let axis = p1 - p0;
    let (t1, t2) = axis.normalize().any_orthonormal_pair();
    let mut g: Geometry = Default::default();
    for j in 0..2u32 {
        for i in 0..=n {
            let phi = std::f32::consts::TAU * i as f32 / n as f32;
            let normal = phi.cos() * t1 + phi.sin() * t2;
            g.0.push((p0 + j as f32 * axis + radius * normal).to_array());
            g.1.push(normal.to_array());
            g.2.push([i as f32 / n as f32, 1.0 - j as f32]);
        }
    }
    for i in 0..n {
        let (a, b, c, d) = (i, i + 1, n + 2 + i, n + 1 + i);
        g.3.push([a, b, c]);
        g.3.push([c, d, a]);
    }
    g
}

/// A UV sphere of `SPHERE_SEGMENTS` × `SPHERE_SEGMENTS / 2` quads (triangles at the
/// poles), counter-clockwise from outside, with the exact normals.
fn sphere(center: Vec3, radius: f32) -> Geometry {
    let (nu, nv) = (SPHERE_SEGMENTS, SPHERE_SEGMENTS / 2);
    let mut g: Geometry = Default::default();
    for j in 0..=nv {
        let theta = std::f32::consts::PI * j as f32 / nv as f32;
        for i in 0..=nu {
            let phi = std::f32::consts::TAU * i as f32 / nu as f32;
            // Mitsuba's parameterisation: θ from the local +z axis, φ around it from +x,
            // u = φ / 2π and v = θ / π (v down the image: 1 − θ / π in the model's).
            let n = Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
            g.0.push((center + radius * n).to_array());
            g.1.push(n.to_array());
            g.2.push([i as f32 / nu as f32, 1.0 - j as f32 / nv as f32]);
        }
    }
    let at = |i: u32, j: u32| j * (nu + 1) + i;
    for j in 0..nv {
        for i in 0..nu {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            if j > 0 {
                g.3.push([a, d, b]);
            }
            if j + 1 < nv {
                g.3.push([b, d, c]);
            }
        }
    }
    g
}
