//! Mitsuba media that vkinverse renders as they are: a `homogeneous` or `heterogeneous`
//! medium, the interior of a closed shape (an axis-aligned box, or any closed mesh: the
//! medium's boundary) with a `null` BSDF or a visible one (glass filled with smoke),
//! rendered by `volpath`, `volpathmis` or `prbvolpath`, with the sensors and surfaces
//! inside it that say so (their `medium`, their `exterior`). The medium's box is the
//! shape's world bounds; its density is `sigma_t`
//! (a number, an equal `rgb`, a `constvolume` or a one-channel `gridvolume` whose
//! `to_world` places it on that box) and its `scale` is
//! Mitsuba's; its `albedo` is a constant (a number or an RGB colour) and its phase
//! function `isotropic` or `hg`; it emits nothing. Everything else about a medium is
//! refused in one line that names the plugin and the property.

use glam::{Mat3, Mat4, Vec3};
use roxmltree::Node;

use super::{elements, Importer, Items};
use crate::scene::media::{albedo_error, g_error, DEFAULT_STEP};
use crate::scene::model::{GridFormat, Medium, MediumBoundary, Mesh};
use crate::scene::SceneError;
use crate::tensor::{ParamValue, Shape};

/// A medium's `sigma_t` or `albedo` as read.
#[derive(Clone)]
pub(super) enum Values<'a, 'i> {
    Constant([f32; 3]),
    /// A `gridvolume`: its grid, its `to_world` and `use_grid_bbox`, and its element.
    Grid {
        grid: crate::vol::Grid,
        to_world: Mat4,
        use_grid_bbox: bool,
        node: Node<'a, 'i>,
    },
}

/// A `<medium>` as read, before the shape around it gives it its box.
#[derive(Clone)]
pub(super) struct MediumDef<'a, 'i> {
    node: Node<'a, 'i>,
    sigma_t: Values<'a, 'i>,
    scale: f32,
    albedo: Values<'a, 'i>,
    g: f32,
}

/// Relative tolerance of the box checks (of the box's largest side).
const BOX_TOLERANCE: f32 = 1e-4;

/// A visible shape that names a medium as its `exterior`: it stands inside the medium
/// (checked at the end), and `filled` where its `interior` is the same medium.
pub(super) struct InMedium<'a, 'i> {
    /// Its index in the imported meshes.
    pub mesh: usize,
    pub node: Node<'a, 'i>,
    pub id: String,
    pub filled: bool,
}

/// A sensor's `medium` (the medium its rays start in), and its `near_clip` where given.
pub(super) struct SensorMedium<'a, 'i> {
    pub node: Node<'a, 'i>,
    pub id: Option<String>,
    pub near_clip: Option<f32>,
}

/// Where the scene's medium is: its box, the box checks' tolerance, and its mesh.
struct Region {
    id: String,
    min: Vec3,
    max: Vec3,
    inset: f32,
    boundary: Option<MediumBoundary>,
}

impl Region {
    fn of(m: &Medium) -> Region {
        let (min, max) = (Vec3::from(m.min), Vec3::from(m.max));
        Region { id: m.name.clone(), min, max, inset: BOX_TOLERANCE * (max - min).max_element(), boundary: m.boundary.clone() }
    }

    /// Inside the medium: clear of its box's faces, and inside its mesh.
    fn inside(&self, p: Vec3) -> bool {
        p.cmpgt(self.min + self.inset).all() && p.cmplt(self.max - self.inset).all() && self.boundary.as_ref().is_none_or(|b| b.contains(p.to_array()))
    }

    /// Clear of the medium: outside its box by the tolerance, or outside its mesh.
    fn outside(&self, p: Vec3) -> bool {
        !(p.cmpge(self.min - self.inset).all() && p.cmple(self.max + self.inset).all()) || self.boundary.as_ref().is_some_and(|b| !b.contains(p.to_array()))
    }
}

impl<'a, 'i> Importer<'a, 'i> {
    /// A `<medium>` (inside a shape or at the top level with an id).
    pub(super) fn medium_def(&mut self, node: Node<'a, 'i>) -> Result<MediumDef<'a, 'i>, SceneError> {
        let kind = self.plugin_type(node)?;
        if kind != "homogeneous" && kind != "heterogeneous" {
            return Err(self.err(node, format!("medium \"{kind}\" is unsupported (homogeneous and heterogeneous media are)")));
        }
        let mut items = elements(node);
        // Mitsuba's default albedo is 0.75.
        let albedo = match self.take(&mut items, "albedo") {
            Some(n) => self.medium_values(n, true)?,
            None => Values::Constant([0.75; 3]),
        };
        if let Values::Constant(c) = albedo {
            if let Some(message) = albedo_error(&c) {
                return Err(self.err(node, message));
            }
        }
        let sigma_t = match self.take(&mut items, "sigma_t") {
            Some(n) => {
                let v = self.medium_values(n, false)?;
                match &v {
                    Values::Constant(c) if c[0] != c[1] || c[1] != c[2] => {
                        return Err(self.err(n, format!("sigma_t {c:?} differs between channels: a medium's density has one channel")))
                    }
                    Values::Grid { grid, node, .. } if grid.channels != 1 => {
                        return Err(self.err(*node, format!("sigma_t has {} channels: a medium's density has one", grid.channels)))
                    }
                    Values::Grid { node, .. } if kind == "homogeneous" => {
                        return Err(self.err(*node, "a homogeneous medium's sigma_t is a constant (a grid is a heterogeneous medium's)"))
                    }
                    _ => {}
                }
                v
            }
            None => Values::Constant([1.0; 3]),
        };
        let scale = self.take_float(&mut items, "scale", 1.0)?;
        if scale <= 0.0 {
            return Err(self.err(node, format!("scale {scale} is not positive")));
        }
        let phase = match self.take_tag(&mut items, "phase") {
            Some(phase) => Some(phase),
            None => self.take(&mut items, "phase"),
        };
        let g = match phase {
            Some(phase) => self.phase(phase)?,
            None => 0.0,
        };
        // Sampling emitters or not changes the noise only.
        if let Some(n) = self.take(&mut items, "sample_emitters") {
            self.boolean(n)?;
        }
        self.rest(&items, node)?;
        Ok(MediumDef { node, sigma_t, scale, albedo, g })
    }

    /// A `<phase>`: `isotropic` (g 0) or `hg` (its `g`, Mitsuba's default 0.8); the
    /// Henyey–Greenstein g of either.
    fn phase(&mut self, node: Node<'a, 'i>) -> Result<f32, SceneError> {
        let kind = self.plugin_type(node)?;
        let mut items = elements(node);
        let g = match kind.as_str() {
            "isotropic" => 0.0,
            "hg" => self.take_float(&mut items, "g", 0.8)?,
            _ => return Err(self.err(node, format!("phase \"{kind}\" is unsupported (isotropic and hg are)"))),
        };
        if let Some(message) = g_error(g) {
            return Err(self.err(node, message));
        }
        self.rest(&items, node)?;
        Ok(g)
    }

    /// A medium's property: a `<float>`, an `<rgb>` (or, for a reflectance such as
    /// `albedo`, a `<spectrum>`), or a `<volume>` of type `constvolume` or `gridvolume`.
    fn medium_values(&mut self, node: Node<'a, 'i>, reflectance: bool) -> Result<Values<'a, 'i>, SceneError> {
        let property = node.attribute("name").unwrap_or("value").to_string();
        match node.tag_name().name() {
            "float" => Ok(Values::Constant([self.float(node)?; 3])),
            "rgb" => Ok(Values::Constant(self.rgb(node)?)),
            "spectrum" if reflectance => Ok(Values::Constant(self.rgb(node)?)),
            "spectrum" => Err(self.err(node, format!("{property} as a <spectrum> is unsupported (a <float>, an <rgb> or a <volume> is)"))),
            "volume" => {
                let kind = self.plugin_type(node)?;
                let mut items = elements(node);
                match kind.as_str() {
                    "constvolume" | "const" => {
                        let value = self.take(&mut items, "value").ok_or_else(|| self.err(node, "a constvolume needs a `value`"))?;
                        let value = match value.tag_name().name() {
                            "float" | "rgb" => self.medium_values(value, reflectance)?,
                            _ => return Err(self.err(value, "expected a <float> or an <rgb>")),
                        };
                        self.rest(&items, node)?;
                        Ok(value)
                    }
                    "gridvolume" | "grid" => self.grid_volume(node, items),
                    _ => Err(self.err(node, format!("volume \"{kind}\" is unsupported (constvolume and gridvolume are)"))),
                }
            }
            _ => Err(self.err(node, format!("{property}: expected a <float>, an <rgb> or a <volume>"))),
        }
    }

    /// A `gridvolume`: its `.vol` file ([`crate::vol`]) and where `to_world` puts it.
    fn grid_volume(&mut self, node: Node<'a, 'i>, mut items: Items<'a, 'i>) -> Result<Values<'a, 'i>, SceneError> {
        let rel = self.take(&mut items, "filename").map(|n| self.string(n)).transpose()?.ok_or_else(|| self.err(node, "no filename"))?;
        let to_world = self.take_transform(&mut items, "to_world")?.unwrap_or(Mat4::IDENTITY);
        if let Some(n) = self.take(&mut items, "filter_type") {
            let filter = self.string(n)?;
            if filter != "trilinear" {
                return Err(self.err(n, format!("filter_type \"{filter}\" is unsupported (trilinear is)")));
            }
        }
        if let Some(n) = self.take(&mut items, "wrap_mode") {
            let wrap = self.string(n)?;
            if wrap != "clamp" {
                return Err(self.err(n, format!("wrap_mode \"{wrap}\" is unsupported (clamp is)")));
            }
        }
        // Colour conversion (of three channels), hardware interpolation and the majorant
        // change nothing here.
        for key in ["raw", "accel"] {
            if let Some(n) = self.take(&mut items, key) {
                self.boolean(n)?;
            }
        }
        if let Some(n) = self.take(&mut items, "max_value") {
            self.float(n)?;
        }
        let use_grid_bbox = self.take_bool(&mut items, "use_grid_bbox", false)?;
        self.rest(&items, node)?;
        let (path, bytes) = self.read_file(node, &rel)?;
        let grid = crate::vol::parse_bytes(&bytes, &path).map_err(|e| self.err(node, e.to_string()))?;
        Ok(Values::Grid { grid, to_world, use_grid_bbox, node })
    }

    /// The id of the top-level medium that a shape's `exterior` or `interior`, or a
    /// sensor's `medium`, names with a `<ref>`.
    pub(super) fn medium_ref(&self, node: Node<'a, 'i>, role: &str) -> Result<String, SceneError> {
        if node.tag_name().name() != "ref" {
            return Err(self.err(node, format!("the medium named \"{role}\" must be a <ref> to the medium inside a closed shape")));
        }
        let id = self.required(node, "id")?;
        if !self.media.contains_key(&id) && !self.out.media.iter().any(|m| m.name == id) {
            return Err(self.err(node, format!("no <medium> with id \"{id}\"")));
        }
        Ok(id)
    }

    /// A shape with an interior medium (`interior`: a `<medium>` or a `<ref>` to one):
    /// the medium in the shape's bounds, bounded by the shape where it is not an
    /// axis-aligned box. With a null BSDF the shape is no mesh (it shows nothing): None.
    /// With another BSDF (glass filled with smoke) it is also a surface, made from the
    /// `items` returned. `positions` are the shape's, before `to_world`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn medium_shape(
        &mut self,
        node: Node<'a, 'i>,
        name: &str,
        interior: Node<'a, 'i>,
        to_world: Mat4,
        positions: &[[f32; 3]],
        indices: &[[u32; 3]],
        items: Items<'a, 'i>,
    ) -> Result<Option<Items<'a, 'i>>, SceneError> {
        let (def, id) = match interior.tag_name().name() {
            "medium" => (self.medium_def(interior)?, self.attr(interior, "id")?),
            "ref" => {
                let id = self.required(interior, "id")?;
                let def = self.media.get(&id).cloned().ok_or_else(|| self.err(interior, format!("no <medium> with id \"{id}\"")))?;
                (def, Some(id))
            }
            _ => return Err(self.err(interior, "expected a <medium> or a <ref> to one")),
        };
        // The BSDF, looked at in a copy of the items: a surface keeps them all.
        let mut rest = items.clone();
        let null = match (self.take_tag(&mut rest, "bsdf"), self.take_tag(&mut rest, "ref").or_else(|| self.take(&mut rest, "bsdf"))) {
            (Some(b), None) => self.plugin_type(b)? == "null" && elements(b).is_empty(),
            (None, Some(r)) => {
                let id = self.required(r, "id")?;
                let null = self.null_bsdfs.contains_key(&id);
                if null && !self.null_used.contains(&id) {
                    self.null_used.push(id);
                }
                null
            }
            _ => false,
        };
        if null {
            self.rest(&rest, node)?;
        }
        let world: Vec<Vec3> = positions.iter().map(|&p| to_world.transform_point3(Vec3::from(p))).collect();
        // An axis-aligned box is the medium's box; any other closed shape bounds it.
        let ((min, max), boundary) = match Self::medium_box(&world, indices) {
            Some(bounds) => (bounds, None),
            None => {
                let flat: Vec<[f32; 3]> = world.iter().map(|p| p.to_array()).collect();
                let b = MediumBoundary::new(&flat, indices).map_err(|why| self.err(node, format!("the shape around a medium must be closed: {why}")))?;
                let (lo, hi) = b.bounds();
                ((Vec3::from(lo), Vec3::from(hi)), Some(b))
            }
        };
        let density = self.values_in_box(&def.sigma_t, min, max, 1)?;
        let albedo = self.values_in_box(&def.albedo, min, max, 3)?;
        if let Some(message) = albedo_error(&albedo.data) {
            return Err(self.err(def.node, message));
        }
        if let Some(v) = density.data.iter().find(|&&v| v < 0.0) {
            return Err(self.err(def.node, format!("sigma_t holds {v}, below 0")));
        }
        if self.medium_shape.is_some() {
            return Err(self.err(node, "a second medium: a scene holds at most one"));
        }
        self.medium_shape = Some(node);
        let format = |v: &Values| if matches!(v, Values::Grid { .. }) { GridFormat::Vol } else { GridFormat::Npy };
        self.out.media.push(Medium {
            name: id.unwrap_or_else(|| name.to_string()),
            min: min.to_array(),
            max: max.to_array(),
            density,
            emission: ParamValue { shape: Shape::constant(3), data: vec![0.0; 3] },
            scale: def.scale,
            step: DEFAULT_STEP,
            albedo,
            g: def.g,
            majorant: None,
            formats: [format(&def.sigma_t), GridFormat::Npy, format(&def.albedo)],
            boundary,
        });
        Ok((!null).then_some(items))
    }

    /// A medium's property as a value of `channels` channels in its box (`min`, `max`): a
    /// constant (its first channel where `channels` is 1), or a grid whose `to_world` (on
    /// the unit cube, or on the file's box with `use_grid_bbox`) fills the box, moved and
    /// scaled but not turned or mirrored. A one-channel grid gives every channel.
    fn values_in_box(&self, values: &Values<'a, 'i>, min: Vec3, max: Vec3, channels: u32) -> Result<ParamValue, SceneError> {
        let (grid, to_world, use_grid_bbox, at) = match values {
            Values::Constant(c) => return Ok(ParamValue { shape: Shape::constant(channels), data: c[..channels as usize].to_vec() }),
            Values::Grid { grid, to_world, use_grid_bbox, node } => (grid, to_world, *use_grid_bbox, *node),
        };
        let (lo, hi) = match use_grid_bbox {
            true => (Vec3::from_slice(&grid.bbox[..3]), Vec3::from_slice(&grid.bbox[3..])),
            false => (Vec3::ZERO, Vec3::ONE),
        };
        let linear = Mat3::from_mat4(*to_world);
        let diagonal = Vec3::new(linear.x_axis.x, linear.y_axis.y, linear.z_axis.z);
        let off = linear - Mat3::from_diagonal(diagonal);
        if !(off.abs_diff_eq(Mat3::ZERO, 1e-6 * diagonal.abs().max_element()) && diagonal.min_element() > 0.0) {
            return Err(self.err(at, "the grid's to_world turns or mirrors it (a translation and a positive scale are supported)"));
        }
        let (a, b) = (to_world.transform_point3(lo), to_world.transform_point3(hi));
        let tolerance = BOX_TOLERANCE * (max - min).max_element();
        if !(lo.cmplt(hi).all() && a.abs_diff_eq(min, tolerance) && b.abs_diff_eq(max, tolerance)) {
            return Err(self.err(
                at,
                format!(
                    "the grid spans {a} to {b} and its shape {min} to {max}: a grid must fill its medium's box (its to_world maps the unit cube onto the box)"
                ),
            ));
        }
        let [x, y, z] = grid.size;
        let data = match (grid.channels, channels) {
            (c, want) if c == want => grid.data.clone(),
            (1, want) => grid.data.iter().flat_map(|&v| std::iter::repeat_n(v, want as usize)).collect(),
            (c, want) => return Err(self.err(at, format!("the grid has {c} channels; this property has {want} (or 1 for every channel)"))),
        };
        Ok(ParamValue { shape: Shape::grid(x, y, z, channels), data })
    }

    /// The world bounds of a medium's shape where it is a closed axis-aligned box: every
    /// vertex on a corner of the bounds, the faces' area the box's.
    fn medium_box(world: &[Vec3], indices: &[[u32; 3]]) -> Option<(Vec3, Vec3)> {
        let min = world.iter().copied().fold(Vec3::INFINITY, Vec3::min);
        let max = world.iter().copied().fold(Vec3::NEG_INFINITY, Vec3::max);
        let side = max - min;
        if side.is_nan() || side.min_element() <= 0.0 {
            return None;
        }
        let tolerance = BOX_TOLERANCE * side.max_element();
        let on_corner = |p: Vec3| (0..3).all(|a| (p[a] - min[a]).abs() <= tolerance || (p[a] - max[a]).abs() <= tolerance);
        if !world.iter().all(|&p| on_corner(p)) {
            return None;
        }
        let area: f32 = indices
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| world.get(i as usize).copied().unwrap_or(Vec3::ZERO));
                0.5 * (b - a).cross(c - a).length()
            })
            .sum();
        let want = 2.0 * (side.x * side.y + side.y * side.z + side.z * side.x);
        ((area - want).abs() <= 1e-3 * want).then_some((min, max))
    }

    /// What a scene with a medium must also be for Mitsuba to render the medium as vkinverse
    /// does: a volumetric integrator; a sensor inside the medium names it as its `medium`
    /// (and one outside names none). A surface that names no medium keeps the ray's medium
    /// in Mitsuba, as the position does in vkinverse: it may stand anywhere. One that names
    /// the medium as its `exterior` gives it to the rays it reflects, so it must stand
    /// inside it, and name it as its `interior` too where light passes into its inside.
    /// Where a shape or sensor says otherwise, Mitsuba's volpath would see no medium where
    /// vkinverse sees one, or the reverse.
    pub(super) fn check_media(&mut self) -> Result<(), SceneError> {
        let unused: Vec<String> = self.null_bsdfs.keys().filter(|id| !self.null_used.contains(id)).cloned().collect();
        if let Some(id) = unused.into_iter().min() {
            // A null BSDF that bounds no medium: refused as every other unsupported BSDF.
            let node = self.null_bsdfs[&id];
            self.bsdf(node, &id)?;
        }
        let (Some(node), Some(m)) = (self.medium_shape, self.out.media.first()) else {
            let named = self.sensor_media.iter().find_map(|s| s.id.clone().map(|id| (s.node, id)));
            if let Some((at, id)) = named.or_else(|| self.in_medium.first().map(|s| (s.node, s.id.clone()))) {
                return Err(self.err(at, format!("medium \"{id}\" fills no shape: a medium must be the interior of a closed shape")));
            }
            return Ok(());
        };
        match self.integrator_kind.as_deref() {
            Some("volpath" | "volpathmis" | "prbvolpath") => {}
            other => {
                let kind = other.unwrap_or("path");
                return Err(self.err(
                    node,
                    format!("Mitsuba's {kind} integrator renders no medium: a scene with a medium is imported for volpath, volpathmis or prbvolpath"),
                ));
            }
        }
        let region = Region::of(m);
        let mut warnings = self.check_sensors(&region)?;
        if region.boundary.is_none() {
            warnings.extend(self.face_warnings(&region).into_iter().map(|w| (node, w)));
        }
        for (node, w) in warnings {
            self.warn(node, w);
        }
        self.check_in_medium(&region)
    }

    /// Each sensor against the medium: inside it, it names it as its `medium`; outside,
    /// it names none. The warnings of those inside with a `near_clip`.
    fn check_sensors(&self, region: &Region) -> Result<Vec<(Node<'a, 'i>, String)>, SceneError> {
        let id = &region.id;
        let mut warnings = Vec::new();
        for (s, sm) in self.out.sensors.iter().zip(&self.sensor_media) {
            let at = s.origin;
            match &sm.id {
                Some(named) if named != id => {
                    return Err(self.err(sm.node, format!("the sensor's medium \"{named}\" fills no shape (the scene's medium is \"{id}\")")));
                }
                Some(_) if !region.inside(at) => {
                    return Err(self.err(sm.node, format!("the sensor at {at} names medium \"{id}\" as its own but is not inside it")));
                }
                None if !region.outside(at) => {
                    return Err(self.err(
                        sm.node,
                        format!("the sensor at {at} is inside medium \"{id}\" (or on its boundary): give it <ref name=\"medium\" id=\"{id}\"/>, its rays start in the medium"),
                    ));
                }
                Some(_) => {
                    if let Some(near) = sm.near_clip.filter(|&n| n > 0.0) {
                        warnings.push((
                            sm.node,
                            format!("Mitsuba starts this sensor's rays at near_clip = {near}, past the medium's first {near}; vkinverse at the sensor"),
                        ));
                    }
                }
                None => {}
            }
        }
        Ok(warnings)
    }

    /// A warning for each surface on a face of the medium's box: Mitsuba's rays, offset
    /// off the surface, may pass the coincident face without entering or leaving the
    /// medium.
    fn face_warnings(&self, region: &Region) -> Vec<String> {
        let (min, max, inset) = (region.min, region.max, region.inset);
        let on_face = |mesh: &Mesh| {
            mesh.indices.iter().any(|t| {
                let p = t.map(|i| mesh.positions.get(i as usize).map_or(Vec3::ZERO, |&p| Vec3::from(p)));
                let (lo, hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
                (0..3).any(|a| {
                    let overlaps = (0..3).filter(|&b| b != a).all(|b| hi[b] > min[b] + inset && lo[b] < max[b] - inset);
                    let flat_on = |face: f32| p.iter().all(|q| (q[a] - face).abs() <= inset);
                    overlaps && (flat_on(min[a]) || flat_on(max[a]))
                })
            })
        };
        // The medium's own surface (glass around it) is its boundary, not beside it.
        let own = |k: usize| self.medium_surface == Some(k);
        self.out.meshes.iter().enumerate().filter(|&(k, m)| !own(k) && on_face(m)).map(|(_, mesh)| format!(
            "shape \"{}\" lies on a face of the box of medium \"{}\": Mitsuba's rays may cross that face there without entering or leaving the medium, so its renders near the face can differ; move the shape off the face",
            mesh.name, region.id
        )).collect()
    }

    /// Each shape that names the medium as its `exterior` stands inside it, and names it
    /// as its `interior` too where light passes into its inside (glass).
    fn check_in_medium(&self, region: &Region) -> Result<(), SceneError> {
        let id = &region.id;
        for s in &self.in_medium {
            let mesh = &self.out.meshes[s.mesh];
            if s.id != *id {
                return Err(
                    self.err(s.node, format!("shape \"{}\": its exterior medium \"{}\" fills no shape (the scene's medium is \"{id}\")", mesh.name, s.id))
                );
            }
            let vertex = |i: &u32| mesh.positions.get(*i as usize).map_or(Vec3::ZERO, |&p| Vec3::from(p));
            // Each vertex once: a mesh's triangles share each about six times, and a test
            // against a mesh boundary reads every boundary triangle.
            let mut seen = std::collections::HashSet::new();
            if let Some(p) = mesh.indices.iter().flatten().filter(|&&i| seen.insert(i)).map(vertex).find(|&p| !region.inside(p)) {
                return Err(self.err(s.node, format!("shape \"{}\" names medium \"{id}\" as its exterior but reaches out of it (at {p})", mesh.name)));
            }
            if self.out.materials[mesh.material].kind.is_dielectric() && !s.filled {
                return Err(self.err(
                    s.node,
                    format!(
                        "shape \"{}\" lets light into its inside, where Mitsuba has no medium and vkinverse has \"{id}\": give it <ref name=\"interior\" id=\"{id}\"/> too",
                        mesh.name
                    ),
                ));
            }
        }
        Ok(())
    }
}
