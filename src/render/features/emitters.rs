//! Area emitters and light sampling: each mesh's emission (a constant or a texture, in the
//! material data or, optimised, in θ), and the table that next-event estimation picks an
//! emitting triangle from. Its parameter: a mesh's emission.
//!
//! The table holds the triangles of meshes that emit or whose emission is optimised. A
//! triangle's weight is its area × luminance (of a texture, its mean over the texels the
//! triangle's lookups can reach: none for a triangle that reaches only black texels), or its
//! area alone when any emission is being optimised (its current value is not known when the
//! table is built). A mesh is picked with probability ½ / meshes + ½ × its share of the
//! weights, then a triangle of it by weight. With an environment map too, each strategy is
//! picked with probability ½.
//!
//! A mesh that tessellates a sphere (`Mesh::sphere`, Mitsuba's `sphere` shape) is sampled by
//! the solid angle it subtends instead, as Mitsuba samples its spheres: where the table picks
//! one of its triangles and the shading point lies outside the sphere, the light sample is a
//! direction uniform in the sphere's cone, and its point is where that direction first meets
//! the mesh (every point of the inscribed mesh lies in the cone). The sphere's records
//! follow the triangles' in the buffer: 2 texels each, (centre, radius) and (the probability
//! of picking any of its triangles, 0, 0, 0).

use super::values::{optimised, sampler_flags};
use super::{Feature, Upload};
use crate::gpu::{self, Buffer, SpecValue};
use crate::image::Image;
use crate::render::texel_buffer;
use crate::scene::{ColorValue, ParamTarget, SceneGeometry, TextureValue as _, Wrap};
use crate::shared::{EmitterTri, ValueRef};
use glam::Vec3;

/// The share of light samples spread evenly over the emitting meshes (the rest follow
/// their power).
const UNIFORM_SHARE: f64 = 0.5;

pub struct Emitters {
    buffer: Buffer,
    /// Each mesh's emission.
    pub mesh_emission: Vec<ValueRef>,
    /// Whether each mesh emits (or has its emission optimised).
    pub mesh_emits: Vec<bool>,
    /// Each triangle's area-measure density when picked by the table (0: not in it).
    pub triangle_pdf: Vec<f32>,
    /// Each mesh's sphere emitter: 1 + its index among the records, 0 for none (the
    /// `EMITTER_SPHERE_SHIFT` bits of its triangles' flags).
    pub mesh_sphere: Vec<u32>,
    count: u32,
}

impl Emitters {
    pub fn build(up: &mut Upload, geo: &SceneGeometry) -> gpu::Result<Emitters> {
        let (scene, layout) = (up.scene, up.layout);
        let mesh_emission: Vec<ValueRef> = scene
            .meshes
            .iter()
            .enumerate()
            .map(|(i, m)| match layout.slot(ParamTarget::Emission { mesh: i }) {
                // An optimised emission lives in θ; of the scene's value only its sampler
                // flags are kept.
                Some(s) => optimised(Some(s), ValueRef { flags: m.emission.texture().map_or(0, sampler_flags), ..ValueRef::default() }),
                None => up.data.color(&m.emission),
            })
            .collect();
        let optimised_emission = (0..scene.meshes.len()).any(|i| layout.slot(ParamTarget::Emission { mesh: i }).is_some());
        let mesh_emits: Vec<bool> =
            scene.meshes.iter().enumerate().map(|(i, m)| layout.slot(ParamTarget::Emission { mesh: i }).is_some() || m.emission.any_positive()).collect();
        let mut luminance_tables: Vec<(*const Image, LuminanceTable)> = Vec::new();
        let mut emitters: Vec<EmitterTri> = Vec::new();
        let mut weights = Vec::new();
        for (t, idx) in geo.indices.iter().enumerate() {
            let mesh = geo.triangle_mesh[t] as usize;
            if !mesh_emits[mesh] {
                continue;
            }
            let [a, b, c] = idx.map(|i| Vec3::from(geo.positions[i as usize]));
            let cross = (b - a).cross(c - a);
            let area = 0.5 * cross.length();
            let luminance = match &scene.meshes[mesh].emission {
                _ if optimised_emission => 1.0,
                ColorValue::Constant(c) => luminance(*c).max(1e-6),
                ColorValue::Texture(tex) => {
                    let set = geo.uvs_of(tex.uv_set);
                    let uvs = idx.map(|i| set[i as usize]);
                    per_image(&mut luminance_tables, &tex.image, || LuminanceTable::new(&tex.image)).footprint_mean(uvs, tex.wrap)
                }
            };
            if area > 0.0 && luminance > 0.0 {
                weights.push(area * luminance);
                emitters.push(EmitterTri {
                    p0: a.into(),
                    e1: (b - a).into(),
                    e2: (c - a).into(),
                    ng: cross.normalize_or_zero().into(),
                    prim: t as u32,
                    cdf: 0.0,
                    pdf: area,
                    two_sided: scene.meshes[mesh].two_sided_emission as u32,
                    emission: mesh_emission[mesh],
                });
            }
        }
        // The emitting spheres, in mesh order, and each one's probability of being picked.
        let mut mesh_sphere = vec![0u32; scene.meshes.len()];
        let mut spheres: Vec<([f32; 3], f32)> = Vec::new();
        for (i, m) in scene.meshes.iter().enumerate() {
            if let (Some(s), true) = (m.sphere, mesh_emits[i]) {
                spheres.push((s.center, s.radius));
                mesh_sphere[i] = spheres.len() as u32;
            }
        }
        let mut sphere_pmf = vec![0.0f64; spheres.len()];
        let mut triangle_pdf = vec![0.0; geo.indices.len()];
        mix_meshes(&mut weights, &emitters, geo, scene.meshes.len());
        let total: f64 = weights.iter().map(|&w| w as f64).sum();
        let mut acc = 0.0f64;
        for (em, w) in emitters.iter_mut().zip(&weights) {
            acc += *w as f64;
            // pmf / area: the area-measure density of a uniform point on this triangle.
            let pmf = *w as f64 / total;
            let pdf = (pmf / em.pdf as f64) as f32;
            em.cdf = (acc / total) as f32;
            em.pdf = pdf;
            triangle_pdf[em.prim as usize] = pdf;
            if let Some(k) = mesh_sphere[geo.triangle_mesh[em.prim as usize] as usize].checked_sub(1) {
                sphere_pmf[k as usize] += pmf;
            }
        }
        if let Some(last) = emitters.last_mut() {
            // Guards the binary search against rounding: the last cdf is exactly 1.
            last.cdf = 1.0;
        }
        let mut texels: Vec<[f32; 4]> = bytemuck::cast_slice(&emitters).to_vec();
        for ((c, r), pmf) in spheres.iter().zip(&sphere_pmf) {
            texels.push([c[0], c[1], c[2], *r]);
            texels.push([*pmf as f32, 0.0, 0.0, 0.0]);
        }
        let buffer = texel_buffer(up.ctx, "emitters", &texels)?;
        Ok(Emitters { buffer, mesh_emission, mesh_emits, triangle_pdf, mesh_sphere, count: emitters.len() as u32 })
    }

    /// Emitting triangles in the table (`NUM_EMITTERS`).
    pub fn count(&self) -> u32 {
        self.count
    }
}

impl Feature for Emitters {
    fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        vec![("Emitters", &self.buffer)]
    }

    fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        let textured = self.mesh_emission.iter().any(|r| r.width != 0);
        let spheres = self.mesh_sphere.iter().any(|&k| k != 0);
        vec![
            ("NUM_EMITTERS", SpecValue::U32(self.count)),
            ("HAS_EMISSION_TEXTURES", SpecValue::Bool(textured)),
            ("SPHERE_EMITTERS", SpecValue::Bool(spheres)),
        ]
    }

    fn values(&self) -> Vec<ValueRef> {
        self.mesh_emission.clone()
    }
}

/// Each emitting mesh is picked with probability ½ / meshes + ½ × its share of the
/// weights, then one of its triangles by its weight: `weights` (of the triangles of
/// `emitters`) rescaled so. A mesh of little power near what it lights (a small lamp by a
/// wall, under a bright sun) keeps a fair share of the samples, at most halving the share
/// of the most powerful.
fn mix_meshes(weights: &mut [f32], emitters: &[EmitterTri], geo: &SceneGeometry, meshes: usize) {
    let mut per_mesh = vec![0.0f64; meshes];
    for (em, w) in emitters.iter().zip(weights.iter()) {
        per_mesh[geo.triangle_mesh[em.prim as usize] as usize] += *w as f64;
    }
    let count = per_mesh.iter().filter(|&&w| w > 0.0).count() as f64;
    let all: f64 = per_mesh.iter().sum();
    for (em, w) in emitters.iter().zip(weights.iter_mut()) {
        let of_mesh = per_mesh[geo.triangle_mesh[em.prim as usize] as usize];
        *w = (*w as f64 / of_mesh * (UNIFORM_SHARE / count + (1.0 - UNIFORM_SHARE) * of_mesh / all)) as f32;
    }
}

/// What `make` builds for image `img`, built once per image: `cache` holds it by the image's
/// address (one shared image: several meshes' emission texture).
fn per_image<'a, V>(cache: &'a mut Vec<(*const Image, V)>, img: &std::sync::Arc<Image>, make: impl FnOnce() -> V) -> &'a V {
    let key = std::sync::Arc::as_ptr(img);
    let i = match cache.iter().position(|(k, _)| *k == key) {
        Some(i) => i,
        None => {
            cache.push((key, make()));
            cache.len() - 1
        }
    };
    &cache[i].1
}

/// Rec. 709 luminance ([`crate::bsdf::LUMINANCE`]) in single precision.
fn luminance(c: [f32; 3]) -> f32 {
    let k = crate::bsdf::LUMINANCE.as_vec3();
    k.x * c[0] + k.y * c[1] + k.z * c[2]
}

/// Sums of a texture's texel luminances over rectangles of texels (a summed-area table),
/// for the light-sampling weights of the triangles of a textured emitter.
struct LuminanceTable {
    width: i64,
    height: i64,
    /// (width + 1) × (height + 1) prefix sums; row 0 and column 0 are zero.
    sums: Vec<f64>,
}

impl LuminanceTable {
    fn new(img: &Image) -> Self {
        let (w, h) = (img.width as usize, img.height as usize);
        let mut sums = vec![0.0f64; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0.0;
            for x in 0..w {
                row += luminance(img.data[y * w + x]) as f64;
                sums[(y + 1) * (w + 1) + x + 1] = sums[y * (w + 1) + x + 1] + row;
            }
        }
        Self { width: w as i64, height: h as i64, sums }
    }

    /// The sum over texels [x0, x1) × [y0, y1) inside the image.
    fn rect(&self, x0: i64, x1: i64, y0: i64, y1: i64) -> f64 {
        let at = |x: i64, y: i64| self.sums[(y * (self.width + 1) + x) as usize];
        at(x1, y1) - at(x0, y1) - at(x1, y0) + at(x0, y0)
    }

    /// The mean luminance of the texels that a bilinear lookup (repeat wrapping, as the
    /// kernels' `footprint`) at any point of the triangle with texture coordinates `uvs`
    /// can read: those in its bounding box in texel space, widened by a texel for the
    /// bilinear neighbours and by one more for rounding. Zero only if every one is black,
    /// so that a triangle weighted by it is never left unsampled where it could emit. Along
    /// an axis that `wrap` does not repeat, every texel counts.
    fn footprint_mean(&self, uvs: [[f32; 2]; 3], wrap: [Wrap; 2]) -> f32 {
        let (w, h) = (self.width, self.height);
        let lo = |k: usize| uvs.iter().map(|t| t[k]).fold(f32::INFINITY, f32::min);
        let hi = |k: usize| uvs.iter().map(|t| t[k]).fold(f32::NEG_INFINITY, f32::max);
        // Texels [a, b] (inclusive, unwrapped) along an axis of n texels, as up to two
        // ranges [start, end) inside the image; all n where the box spans them (or a
        // coordinate is not finite).
        let ranges = |lo: f32, hi: f32, n: i64| -> Vec<(i64, i64)> {
            let (a, b) = ((lo as f64 * n as f64 - 0.5).floor() - 1.0, (hi as f64 * n as f64 - 0.5).floor() + 2.0);
            if !(a.is_finite() && b.is_finite()) || b - a + 1.0 >= n as f64 {
                return vec![(0, n)];
            }
            let (a, b) = (a as i64, b as i64 + 1);
            let start = a.rem_euclid(n);
            let end = start + (b - a);
            if end <= n {
                vec![(start, end)]
            } else {
                vec![(start, n), (0, end - n)]
            }
        };
        // Rows are stored top first: v = 1 is row 0.
        let (xs, ys) = match wrap {
            [Wrap::Repeat, Wrap::Repeat] => (ranges(lo(0), hi(0), w), ranges(1.0 - hi(1), 1.0 - lo(1), h)),
            [Wrap::Repeat, _] => (ranges(lo(0), hi(0), w), vec![(0, h)]),
            [_, Wrap::Repeat] => (vec![(0, w)], ranges(1.0 - hi(1), 1.0 - lo(1), h)),
            _ => (vec![(0, w)], vec![(0, h)]),
        };
        let (mut sum, mut count) = (0.0, 0i64);
        for &(x0, x1) in &xs {
            for &(y0, y1) in &ys {
                sum += self.rect(x0, x1, y0, y1);
                count += (x1 - x0) * (y1 - y0);
            }
        }
        (sum / count as f64) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The summed-area table's footprint means against a plain loop over the same texels
    /// (the bounding box widened by two texels, wrapped), on boxes inside the image, across
    /// its edges (negative and above-one coordinates) and wider than it.
    #[test]
    fn footprint_means_match_a_loop_over_the_texels() {
        let (w, h) = (7u32, 5u32);
        let data = (0..w * h).map(|i| [((i * 37) % 11) as f32, ((i * 13) % 5) as f32, (i % 3) as f32]).collect();
        let img = Image { width: w, height: h, data };
        let table = LuminanceTable::new(&img);
        let brute = |uvs: [[f32; 2]; 3]| -> f32 {
            let lo = |k: usize| uvs.iter().map(|t| t[k]).fold(f32::INFINITY, f32::min) as f64;
            let hi = |k: usize| uvs.iter().map(|t| t[k]).fold(f32::NEG_INFINITY, f32::max) as f64;
            let axis = |lo: f64, hi: f64, n: i64| -> Vec<i64> {
                let (a, b) = ((lo * n as f64 - 0.5).floor() as i64 - 1, (hi * n as f64 - 0.5).floor() as i64 + 2);
                if b - a + 1 >= n {
                    (0..n).collect()
                } else {
                    (a..=b).map(|x| x.rem_euclid(n)).collect()
                }
            };
            let (xs, ys) = (axis(lo(0), hi(0), w as i64), axis(1.0 - hi(1), 1.0 - lo(1), h as i64));
            let texels = &img.data;
            let sum: f64 = ys.iter().flat_map(|&y| xs.iter().map(move |&x| luminance(texels[(y * w as i64 + x) as usize]) as f64)).sum();
            (sum / (xs.len() * ys.len()) as f64) as f32
        };
        let cases = [
            [[0.3, 0.4], [0.35, 0.45], [0.32, 0.5]],
            [[-0.1, 0.9], [0.05, 1.1], [0.0, 0.95]],
            [[0.9, -0.2], [1.05, -0.1], [0.95, 0.05]],
            [[2.3, 3.4], [2.35, 3.45], [2.32, 3.5]],
            [[0.0, 0.0], [1.0, 0.0], [1.0, 0.3]],
            [[0.5, 0.5]; 3],
        ];
        for uvs in cases {
            let (got, want) = (table.footprint_mean(uvs, [Wrap::Repeat; 2]), brute(uvs));
            assert!((got - want).abs() <= 1e-5 * want.abs().max(1.0), "{uvs:?}: {got} vs {want}");
        }
        // Zero only where every reachable texel is black.
        let mut dark = Image::filled(16, 1, [0.0; 3]);
        dark.data[12] = [1.0, 0.0, 0.0];
        let table = LuminanceTable::new(&dark);
        assert_eq!(table.footprint_mean([[0.1, 0.5], [0.3, 0.5], [0.2, 0.5]], [Wrap::Repeat; 2]), 0.0);
        // Clamped in u, every texel of the row counts.
        assert!(table.footprint_mean([[0.1, 0.5], [0.3, 0.5], [0.2, 0.5]], [Wrap::Clamp, Wrap::Repeat]) > 0.0);
        assert!(table.footprint_mean([[0.7, 0.5], [0.72, 0.5], [0.71, 0.5]], [Wrap::Repeat; 2]) > 0.0, "a lookup at u = 0.72 reads texel 12");
    }
}
