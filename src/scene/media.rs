//! The `[[media]]` tables: boxes of emitting and absorbing or of scattering medium (or
//! their parts inside a closed mesh), their density, emission and albedo as constants or
//! grids (`.npy`, or Mitsuba's `.vol`), and the trilinear resampling that turns a grid
//! into a parameter's resolution.

use std::collections::{HashMap, HashSet};

use super::file::{GridInput, MediumFile};
use super::loader::Loader;
use super::model::{GridFormat, Medium, MediumBoundary};
use super::SceneError;
use crate::tensor::{ParamValue, Shape};

pub use crate::tensor::{MAX_GRID_SIDE, MAX_GRID_VOXELS};
/// The marching step's default, in voxels.
pub const DEFAULT_STEP: f32 = 0.5;
/// Most steps a ray takes through one medium: a longer march takes longer steps.
pub const MAX_STEPS: u32 = 1024;

/// Most triangles of a medium's boundary mesh.
pub const MAX_BOUNDARY_TRIANGLES: usize = 1 << 20;

impl MediumBoundary {
    /// A closed mesh from triangles in world space, checked: vertices closer than a
    /// millionth of its bounds' diagonal are one, triangles that collapse are dropped, and
    /// then every edge must border exactly two triangles that cross it in opposite
    /// directions (a closed surface, wound alike). A mesh wound inward (its signed volume
    /// below 0) is turned out. The error says what is wrong, in words.
    pub fn new(positions: &[[f32; 3]], indices: &[[u32; 3]]) -> Result<MediumBoundary, String> {
        if indices.len() > MAX_BOUNDARY_TRIANGLES {
            return Err(format!("{} triangles; a medium's boundary has at most {MAX_BOUNDARY_TRIANGLES}", indices.len()));
        }
        let at = |i: u32| positions.get(i as usize).copied().ok_or_else(|| format!("index {i} is beyond its {} vertices", positions.len()));
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for &p in indices.iter().flatten() {
            let p = at(p)?;
            if p.iter().any(|v| !v.is_finite()) {
                return Err(format!("vertex {p:?} is not finite"));
            }
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let diagonal = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f32>().sqrt();
        if !diagonal.is_finite() || diagonal <= 0.0 {
            return Err("it has no triangles with extent".to_string());
        }
        // Weld: one vertex per cell of a millionth of the diagonal.
        let cell = 1e-6 * diagonal;
        let mut ids: HashMap<[i64; 3], u32> = HashMap::new();
        let mut welded: Vec<[f32; 3]> = Vec::new();
        let mut tris: Vec<[u32; 3]> = Vec::with_capacity(indices.len());
        for t in indices {
            let mut w = [0u32; 3];
            for (k, &i) in t.iter().enumerate() {
                let p = at(i)?;
                let key = [0, 1, 2].map(|a| ((p[a] - lo[a]) / cell).round() as i64);
                w[k] = *ids.entry(key).or_insert_with(|| {
                    welded.push(p);
                    welded.len() as u32 - 1
                });
            }
            if w[0] != w[1] && w[1] != w[2] && w[2] != w[0] {
                tris.push(w);
            }
        }
        // Every directed edge once, and its reverse once.
        let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(3 * tris.len());
        for t in &tris {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        let mut worst: Option<(u32, u32, String)> = None;
        for (&(a, b), &n) in &edges {
            let why = if n > 1 {
                format!("{n} triangles cross it in the same direction (wound unlike, or more than two meet there)")
            } else if !edges.contains_key(&(b, a)) {
                "it borders one triangle (the mesh is not closed)".to_string()
            } else {
                continue;
            };
            // The same edge named whichever the hash map's order.
            if worst.as_ref().is_none_or(|w| (a.min(b), a.max(b)) < (w.0.min(w.1), w.0.max(w.1))) {
                worst = Some((a, b, why));
            }
        }
        if let Some((a, b, why)) = worst {
            return Err(format!("the edge from {:?} to {:?}: {why}", welded[a as usize], welded[b as usize]));
        }
        let volume: f64 = tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| glam::DVec3::from(welded[i as usize].map(f64::from)));
                a.dot(b.cross(c)) / 6.0
            })
            .sum();
        if volume == 0.0 {
            return Err("it encloses no volume".to_string());
        }
        if volume < 0.0 {
            for t in &mut tris {
                t.swap(1, 2);
            }
        }
        Ok(MediumBoundary { positions: welded, indices: tris })
    }

    /// Its bounds: the corners of the box around its vertices.
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &self.positions {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        (lo, hi)
    }

    /// Whether `p` lies inside the mesh: the triangles that a ray from `p` crosses, counted
    /// +1 where it leaves through a triangle's front (the outward side) and −1 where it
    /// enters, sum to 1 inside and 0 outside. The ray's direction is skewed off every axis
    /// and diagonal, so that it meets edges and vertices only by accident.
    pub fn contains(&self, p: [f32; 3]) -> bool {
        let o = glam::DVec3::from(p.map(f64::from));
        let d = glam::DVec3::new(0.5183, 0.6427, 0.5641).normalize();
        let at = |i: u32| glam::DVec3::from(self.positions[i as usize].map(f64::from));
        let mut winding = 0i64;
        for t in &self.indices {
            let (a, b, c) = (at(t[0]), at(t[1]), at(t[2]));
            let (e1, e2) = (b - a, c - a);
            let q = d.cross(e2);
            let det = e1.dot(q);
            if det == 0.0 {
                continue;
            }
            let s = o - a;
            let u = s.dot(q) / det;
            let r = s.cross(e1);
            let v = d.dot(r) / det;
            let dist = e2.dot(r) / det;
            if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && dist > 0.0 {
                // det > 0: the ray runs against the front's normal e1 × e2, so it enters.
                winding += if det > 0.0 { -1 } else { 1 };
            }
        }
        winding > 0
    }
}

/// What is wrong with a medium's albedo (each channel of each voxel in [0, 1]), if
/// anything.
pub fn albedo_error(albedo: &[f32]) -> Option<String> {
    albedo.iter().find(|a| !(0.0..=1.0).contains(*a)).map(|a| format!("albedo {a} is outside [0, 1]"))
}

/// What is wrong with a Henyey–Greenstein g (in (−0.99, 0.99)), if anything.
pub fn g_error(g: f32) -> Option<String> {
    (g.is_nan() || g.abs() >= 0.99).then(|| format!("g {g} is outside (-0.99, 0.99)"))
}

impl Loader {
    /// The scene's media, checked: unique names, a box of positive size, finite values
    /// that are not negative, a positive scale and step.
    pub(super) fn media(&self, raw: Vec<MediumFile>) -> Result<Vec<Medium>, SceneError> {
        let mut seen = HashSet::new();
        let mut out = Vec::with_capacity(raw.len());
        for (i, m) in raw.into_iter().enumerate() {
            let key = format!("media[{i}]");
            self.check_name(&format!("{key}.name"), &m.name, &mut seen)?;
            let key = format!("media.{}", m.name);
            let boundary = match &m.mesh {
                Some(rel) => {
                    let mesh_key = format!("{key}.mesh");
                    let (path, bytes) = self.read(&mesh_key, rel)?;
                    let obj = super::obj::load(&path, &bytes)?;
                    let b = MediumBoundary::new(&obj.positions, &obj.indices).map_err(|e| self.invalid(&mesh_key, &format!("{}: {e}", path.display())))?;
                    Some(b)
                }
                None => None,
            };
            let (min, max) = match (m.min, m.max, &boundary) {
                (Some(min), Some(max), _) => (min, max),
                (None, None, Some(b)) => b.bounds(),
                (None, _, None) => return Err(self.invalid(&format!("{key}.min"), "missing: a medium is a box (min and max), or the inside of a mesh")),
                (Some(_), None, _) => return Err(self.invalid(&format!("{key}.max"), "missing: give both min and max, or neither (the mesh's bounds)")),
                (None, Some(_), Some(_)) => return Err(self.invalid(&format!("{key}.min"), "missing: give both min and max, or neither (the mesh's bounds)")),
            };
            self.finite(&format!("{key}.min"), &min)?;
            self.finite(&format!("{key}.max"), &max)?;
            if let Some(axis) = (0..3).find(|&a| min[a] >= max[a]) {
                let name = ["x", "y", "z"][axis];
                return Err(self.out_of_range(&format!("{key}.max"), format!("{name} {} is not above min's {}", max[axis], min[axis])));
            }
            let (density, density_format) = self.grid(&format!("{key}.density"), &m.density, 1)?;
            let (emission, emission_format) = match &m.emission {
                Some(e) => self.grid(&format!("{key}.emission"), e, 3)?,
                None => (ParamValue { shape: Shape::constant(3), data: vec![0.0; 3] }, GridFormat::Npy),
            };
            let (albedo, albedo_format) = match &m.albedo {
                Some(a) => self.grid(&format!("{key}.albedo"), a, 3)?,
                None => (ParamValue { shape: Shape::constant(3), data: vec![0.0; 3] }, GridFormat::Npy),
            };
            if let Some(message) = albedo_error(&albedo.data) {
                return Err(self.out_of_range(&format!("{key}.albedo"), message));
            }
            let scale = m.scale.unwrap_or(1.0);
            self.positive(&format!("{key}.scale"), scale)?;
            let step = m.step.unwrap_or(DEFAULT_STEP);
            self.positive(&format!("{key}.step"), step)?;
            let g = m.g.unwrap_or(0.0);
            self.finite(&format!("{key}.g"), &[g])?;
            if let Some(message) = g_error(g) {
                return Err(self.out_of_range(&format!("{key}.g"), message));
            }
            if let Some(b) = m.majorant {
                self.positive(&format!("{key}.majorant"), b)?;
                if let Some(v) = density.data.iter().find(|&&v| v > b) {
                    return Err(self.out_of_range(&format!("{key}.majorant"), format!("{b} is below the density's {v}")));
                }
            }
            let medium = Medium {
                name: m.name,
                min,
                max,
                density,
                emission,
                scale,
                step,
                albedo,
                g,
                majorant: m.majorant,
                formats: [density_format, emission_format, albedo_format],
                boundary,
            };
            if medium.scatters() && medium.emission.data.iter().any(|&v| v > 0.0) {
                return Err(self.invalid(
                    &format!("{key}.emission"),
                    "a scattering medium (albedo above 0) emits nothing here; give emission 0, or albedo 0 for an emitting one",
                ));
            }
            out.push(medium);
        }
        if out.len() > 1 {
            return Err(self.invalid("media", &format!("{} media: a scene holds at most one", out.len())));
        }
        Ok(out)
    }

    /// A density (`channels` 1), emission or albedo (3) value: a number (every channel), a
    /// colour (3 channels only), a `.npy` grid of shape [z, y, x] or [z, y, x, channels],
    /// or a Mitsuba `.vol` grid of `channels` channels (whose bounding box is not used: the
    /// medium's `min` and `max` place it). The format is the file's.
    fn grid(&self, key: &str, input: &GridInput, channels: u32) -> Result<(ParamValue, GridFormat), SceneError> {
        let (value, format) = match input {
            GridInput::Scalar(v) => (ParamValue { shape: Shape::constant(channels), data: vec![*v; channels as usize] }, GridFormat::Npy),
            GridInput::Color(c) if channels == 3 => (ParamValue { shape: Shape::constant(3), data: c.to_vec() }, GridFormat::Npy),
            GridInput::Color(_) => return Err(self.invalid(key, "a density has one channel; give one number or a grid")),
            GridInput::File(rel) if GridFormat::of(rel) == GridFormat::Vol => {
                let (path, bytes) = self.read(key, rel)?;
                let grid = crate::vol::parse_bytes(&bytes, &path).map_err(|e| self.invalid(key, &e.to_string()))?;
                if grid.channels != channels {
                    let what = if channels == 1 { "a density has 1" } else { "an emission or an albedo has 3" };
                    let has = if grid.channels == 1 { "1 channel".to_string() } else { format!("{} channels", grid.channels) };
                    return Err(self.invalid(key, &format!("{} has {has}; {what}", path.display())));
                }
                let [x, y, z] = grid.size;
                (ParamValue { shape: Shape::grid(x, y, z, channels), data: grid.data }, GridFormat::Vol)
            }
            GridInput::File(rel) => {
                let (path, bytes) = self.read(key, rel)?;
                let array = crate::npy::parse_bytes(&bytes, &path).map_err(|e| self.invalid(key, &e.to_string()))?;
                let dims: &[usize] = match array.shape.as_slice() {
                    [z, y, x] if channels == 1 => &[*z, *y, *x],
                    [z, y, x, c] if *c == channels as usize => &[*z, *y, *x],
                    other => {
                        let want = if channels == 1 { "[z, y, x] or [z, y, x, 1]" } else { "[z, y, x, 3]" };
                        return Err(self.invalid(key, &format!("{} has shape {other:?}; a grid here is {want}", path.display())));
                    }
                };
                let mut sides = [0u32; 3];
                for (s, &d) in sides.iter_mut().zip(dims) {
                    *s = u32::try_from(d)
                        .ok()
                        .filter(|d| (1..=MAX_GRID_SIDE).contains(d))
                        .ok_or_else(|| self.out_of_range(key, format!("{} has a side of {d} voxels; a side is 1 to {MAX_GRID_SIDE}", path.display())))?;
                }
                let shape = Shape::grid(sides[2], sides[1], sides[0], channels);
                if shape.texels() > MAX_GRID_VOXELS {
                    return Err(self.out_of_range(key, format!("{} has {} voxels; at most {MAX_GRID_VOXELS}", path.display(), shape.texels())));
                }
                (ParamValue { shape, data: array.data }, GridFormat::Npy)
            }
        };
        self.finite(key, &value.data)?;
        if let Some(v) = value.data.iter().find(|&&v| v < 0.0) {
            return Err(self.out_of_range(key, format!("{v} is negative")));
        }
        Ok((value, format))
    }
}

/// `value` (a constant or a grid) resampled to `shape`'s grid (or to one voxel, its mean,
/// for a constant `shape`): trilinear between voxel centres, clamped at the faces, as the
/// kernels look it up. Channels must agree.
pub fn resample(value: &ParamValue, shape: Shape) -> Vec<f32> {
    let c = value.shape.channels() as usize;
    if shape.is_constant() {
        let n = value.shape.texels().max(1) as f64;
        return (0..c).map(|k| (value.data.iter().skip(k).step_by(c).map(|&v| v as f64).sum::<f64>() / n) as f32).collect();
    }
    if value.shape.is_constant() {
        return value.data.iter().copied().cycle().take(shape.len()).collect();
    }
    let src = grid_dims(value.shape);
    let dst = grid_dims(shape);
    let mut out = Vec::with_capacity(shape.len());
    for z in 0..dst[2] {
        for y in 0..dst[1] {
            for x in 0..dst[0] {
                let p = [x, y, z].map(|i| i as f32 + 0.5);
                let q = [0, 1, 2].map(|a| p[a] / dst[a] as f32);
                out.extend(trilinear(value, src, q));
            }
        }
    }
    out
}

/// The grid's voxels along x, y and z.
pub fn grid_dims(shape: Shape) -> [usize; 3] {
    match *shape.dims() {
        [d, h, w] => [w as usize, h as usize, d as usize],
        _ => [1, 1, 1],
    }
}

/// The value of grid `value` (of `dims` voxels) at `q` in the box's unit coordinates.
pub fn trilinear(value: &ParamValue, dims: [usize; 3], q: [f32; 3]) -> Vec<f32> {
    let c = value.shape.channels() as usize;
    let mut lo = [0usize; 3];
    let mut hi = [0usize; 3];
    let mut t = [0f32; 3];
    for a in 0..3 {
        let n = dims[a];
        let p = (q[a] * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
        let f = p.floor();
        lo[a] = f as usize;
        hi[a] = (lo[a] + 1).min(n - 1);
        t[a] = p - f;
    }
    let mut v = vec![0.0f32; c];
    for corner in 0..8 {
        let pick = |a: usize| corner >> a & 1 == 1;
        let idx = [0, 1, 2].map(|a| if pick(a) { hi[a] } else { lo[a] });
        let w: f32 = (0..3).map(|a| if pick(a) { t[a] } else { 1.0 - t[a] }).product();
        if w == 0.0 {
            continue;
        }
        let base = ((idx[2] * dims[1] + idx[1]) * dims[0] + idx[0]) * c;
        for (out, &x) in v.iter_mut().zip(&value.data[base..base + c]) {
            *out += w * x;
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_keeps_a_linear_ramp_between_the_outer_voxel_centres() {
        // v = x over 4 voxels: 0.5, 1.5, 2.5, 3.5 at the centres.
        let src = ParamValue { shape: Shape::grid(4, 1, 1, 1), data: vec![0.5, 1.5, 2.5, 3.5] };
        let out = resample(&src, Shape::grid(8, 1, 1, 1));
        // Centres of 8 voxels at x = 0.25, 0.75, …: the ramp, clamped to [0.5, 3.5].
        let want = [0.5f32, 0.75, 1.25, 1.75, 2.25, 2.75, 3.25, 3.5];
        for (a, b) in out.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{out:?}");
        }
        assert_eq!(resample(&src, Shape::constant(1)), vec![2.0]);
        let constant = ParamValue { shape: Shape::constant(3), data: vec![1.0, 2.0, 3.0] };
        assert_eq!(resample(&constant, Shape::grid(2, 1, 1, 3)), vec![1.0, 2.0, 3.0, 1.0, 2.0, 3.0]);
    }
}
