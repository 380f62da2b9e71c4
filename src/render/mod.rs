//! The forward renderer: the scene uploaded once ([`GpuScene`]), the path-tracing kernels
//! specialised for it, and renders split into short submissions.
//!
//! Specialisation: the integrator is built with the scene's max depth, Russian-roulette
//! depth, emitter count and whether an environment exists as specialization constants, so
//! a scene without emitters compiles light sampling out, one without an environment
//! skips its lookup, and a depth ≤ 2 scene has a loop the compiler can bound.
//!
//! Light sampling: next-event estimation picks a point on an emissive triangle (in
//! proportion to area × luminance) or a direction from a lat-long environment map
//! ([`envmap`]), each with probability ½ when the scene has both. A constant environment
//! is not light-sampled: its radiance is the same in every direction, so BSDF sampling
//! already samples its integrand's directional factor (exactly, for a Lambertian surface)
//! and a second strategy would only add variance.

pub mod envmap;
pub mod filter;
pub mod gradient;
pub mod params;
pub mod targets;

use crate::bvh::{self, BvhBuffers, BvhLayout};
use crate::constants::{
    MATERIAL_CONDUCTOR, MATERIAL_CONDUCTOR_BECKMANN, MATERIAL_DIELECTRIC, MATERIAL_DIFFUSE, MATERIAL_PLASTIC, MATERIAL_PLASTIC_BECKMANN, MATERIAL_PRINCIPLED,
    MATERIAL_ROUGH_DIELECTRIC, MATERIAL_ROUGH_DIELECTRIC_BECKMANN, MATERIAL_THIN_DIELECTRIC,
};
use crate::gpu::{self, BindGroup, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Recorder, SpecValue, TEXEL_BYTES};
use crate::image::Image;
pub use crate::kernels::TracePush;
use crate::scene::{
    AlphaMode, Bitangent, ColorValue, LightKind, Material, MaterialKind, ParamTarget, Perturbation, ScalarValue, Scene, SpotFalloff, TextureValue as _, Wrap,
};
use crate::shared::{EmitterTri, Globals, LightRecord, MaterialRecord, SensorRecord, TriShading, ValueRef};
use glam::{Vec2, Vec3};
pub use params::{ParamLayout, ParamSlot};
use std::sync::Arc;

/// The scene's buffers on the device, and θ.
pub struct GpuScene {
    pub ctx: Arc<Context>,
    pub layout: ParamLayout,
    pub width: u32,
    pub height: u32,
    pub sensors: usize,
    pub max_depth: u32,
    pub rr_depth: u32,
    /// Whether emitters seen directly are hidden (the kernels' HIDE_EMITTERS).
    pub hide_emitters: bool,
    pub emitters: u32,
    pub has_environment: bool,
    /// Point, spot and directional lights (all sampled at every path vertex).
    pub lights: u32,
    /// Whether any value the kernels look up (material, emission, light, environment) is
    /// a texture; without one, every lookup reads one texel.
    pub has_textures: bool,
    /// Whether any material is principled; without one, the kernels build the diffuse
    /// model alone.
    pub has_principled: bool,
    /// Whether any material is a dielectric: the kernels' HAS_DIELECTRICS, without which
    /// they build no specular branch.
    pub has_dielectrics: bool,
    /// Whether any material is a rough dielectric: the kernels' HAS_ROUGH_DIELECTRICS,
    /// without which the BSDF functions do not test for it and no light sample or
    /// continuation passes through a surface.
    pub has_rough_dielectrics: bool,
    /// Whether any material is a conductor: the kernels' HAS_CONDUCTORS, without which the
    /// BSDF functions do not test for it and no material reads its complex index.
    pub has_conductors: bool,
    /// Whether any material is a plastic: the kernels' HAS_PLASTICS, without which the
    /// BSDF functions do not test for it and no material reads its coating.
    pub has_plastics: bool,
    /// Whether any triangle has vertex normals; without them the kernels shade with the
    /// geometric normal and read no vertex normals.
    pub has_normals: bool,
    /// Whether any triangle is normal-mapped (its material has a map and its texture
    /// coordinates a tangent): the kernels' HAS_NORMAL_MAPS.
    pub has_normal_maps: bool,
    /// Whether any mesh's emission is a texture (its own or an optimised one): the
    /// kernels' HAS_EMISSION_TEXTURES, without which a light sample reads no texture
    /// coordinates.
    pub has_emission_textures: bool,
    /// Whether any triangle's material has an alpha test that applies to it: the kernels'
    /// HAS_ALPHA_MASKS, without which traversal tests no candidate hit's alpha.
    pub has_alpha_masks: bool,
    /// The environment map's sampling distribution, when it is light-sampled.
    pub environment_distribution: Option<envmap::EnvDistribution>,
    /// Whether every ray cast of a path fits the adjoint kernels' replay cache
    /// (`max_depth` ≤ [`crate::constants::CACHED_BOUNCES`]): the `CACHE_ALL` constant of
    /// the adjoint kernels, which then trace each path once.
    pub replay_cached: bool,
    /// Whether the adjoint kernels add each gradient contribution to their per-thread sums
    /// in an unrolled loop (`LOCAL_GRADS_UNROLLED`): θ has at most
    /// [`crate::constants::LOCAL_GRADS_UNROLL_MAX`] elements.
    pub local_grads_unrolled: bool,
    pub triangles: usize,
    /// The compressed BVH's traversal stack in an array instead of registers
    /// ([`crate::Config::bvh_stack_array`]).
    pub bvh_stack_array: bool,
    globals: Globals,
    bvh: BvhBuffers,
    buffers: Vec<(&'static str, Buffer)>,
    /// The parameters (θ), `layout.len` floats padded to whole texels (at least one, unused,
    /// when empty), followed from [`Self::const_base`] on by the material data: every
    /// constant value the kernels look up. The optimisers move θ's elements alone.
    pub theta: Buffer,
    /// Where the material data start in [`Self::theta`] (the kernels' `CONST_BASE`).
    pub const_base: u32,
    /// The material data, as uploaded after θ.
    constants: Vec<f32>,
    /// The iteration counter the kernels mix into their seeds (host-written).
    pub frame: Buffer,
}

/// The [`ValueRef`] flags of texture `t`'s filter and wrap modes (u, v).
pub fn sampler_flags(t: &crate::scene::Texture) -> u32 {
    use crate::scene::{Filter, Wrap};
    let code = |w: Wrap| match w {
        Wrap::Repeat => 0,
        Wrap::Clamp => 1,
        Wrap::Mirror => 2,
    };
    let filter = match t.filter {
        Filter::Bilinear => 0,
        Filter::Nearest => ValueRef::NEAREST,
    };
    filter | code(t.wrap[0]) << 2 | code(t.wrap[1]) << 4
}

/// Appends a constant or texture (its image, channels and sampler flags,
/// [`sampler_flags`]) to the material data and returns its reference.
fn push_value(data: &mut Vec<f32>, constant: &[f32], texture: Option<(&Image, usize, u32)>) -> ValueRef {
    let offset = data.len() as i32;
    match texture {
        None => {
            data.extend_from_slice(constant);
            ValueRef { offset, width: 0, height: 0, flags: 0 }
        }
        Some((img, channels, sampler)) => {
            for px in &img.data {
                data.extend_from_slice(&px[..channels]);
            }
            ValueRef { offset, width: img.width, height: img.height, flags: sampler }
        }
    }
}

/// The reference to parameter slot `slot`, whose scene value is `scene` (a texture slot
/// keeps that value's filter and wrap modes).
fn theta_ref(slot: &ParamSlot, scene: ValueRef) -> ValueRef {
    let [width, height] = slot.shape.texture_size().unwrap_or([0, 0]);
    ValueRef { offset: slot.offset as i32, width, height, flags: ValueRef::IN_THETA | scene.flags & ValueRef::SAMPLER }
}

fn color_ref(data: &mut Vec<f32>, v: &ColorValue) -> ValueRef {
    match v {
        ColorValue::Constant(c) => push_value(data, c, None),
        ColorValue::Texture(t) => push_value(data, &[], Some((&t.image, 3, sampler_flags(t)))),
    }
}

/// The material data of material `m`'s normal map (its decoded, scaled vectors,
/// [`crate::scene::NormalMap::vectors`]) or bump map (its heights,
/// [`crate::scene::BumpMap::heights`], flagged
/// [`ValueRef::BUMP`]), or a ValueRef of width 0 for neither.
fn normal_map_ref(data: &mut Vec<f32>, m: &Material) -> ValueRef {
    match &m.perturbation {
        None => ValueRef::default(),
        Some(Perturbation::Normal(n)) => {
            let image = Image { data: n.vectors(), width: n.texture.image.width, height: n.texture.image.height };
            push_value(data, &[], Some((&image, 3, sampler_flags(&n.texture))))
        }
        Some(Perturbation::Bump(b)) => {
            let image = Image { data: b.heights().into_iter().map(|h| [h, 0.0, 0.0]).collect(), width: b.texture.image.width, height: b.texture.image.height };
            let r = push_value(data, &[], Some((&image, 1, sampler_flags(&b.texture))));
            ValueRef { flags: r.flags | ValueRef::BUMP, ..r }
        }
    }
}

/// Per triangle of `geo`: 0, or 1 + its material where the material has an alpha test that
/// applies to it ([`crate::shared::TriShading::alpha_material`]). A textured alpha needs
/// texture coordinates: on a mesh without them it does not apply (a warning says so). An
/// alpha that never cuts is no test: the kernels are built without it.
fn alpha_materials(scene: &Scene, geo: &crate::scene::SceneGeometry) -> Vec<u32> {
    // Per material, not per mesh: never_cuts scans a texture's texels, and a material's
    // meshes may be many.
    let cuts: Vec<bool> = scene.materials.iter().map(|m| m.alpha.as_ref().is_some_and(|a| !a.never_cuts())).collect();
    let applies: Vec<bool> = scene
        .meshes
        .iter()
        .map(|mesh| match &scene.materials[mesh.material].alpha {
            Some(a) if cuts[mesh.material] => !mesh.uvs.is_empty() || matches!(a.value, ScalarValue::Constant(_)),
            _ => false,
        })
        .collect();
    geo.triangle_mesh.iter().zip(&geo.triangle_material).map(|(&mesh, &material)| if applies[mesh as usize] { material + 1 } else { 0 }).collect()
}

/// The unit tangent dp/du of a triangle with corners p and texture coordinates uv, and the
/// bitangent's handedness against its geometric normal ng (TriShading::tangent); zero where
/// the coordinates span no area.
fn triangle_tangent(p: [Vec3; 3], uv: [[f32; 2]; 3], ng: Vec3) -> [f32; 4] {
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let (d1, d2) = (Vec2::from(uv[1]) - Vec2::from(uv[0]), Vec2::from(uv[2]) - Vec2::from(uv[0]));
    let det = d1.x * d2.y - d2.x * d1.y;
    if det == 0.0 || !det.is_finite() {
        return [0.0; 4];
    }
    let dp_du = (e1 * d2.y - e2 * d1.y) / det;
    let dp_dv = (e2 * d1.x - e1 * d2.x) / det;
    let t = dp_du.normalize_or_zero();
    if t == Vec3::ZERO || !t.is_finite() {
        return [0.0; 4];
    }
    let w = if ng.cross(t).dot(dp_dv) < 0.0 { -1.0 } else { 1.0 };
    [t.x, t.y, t.z, w]
}

/// The orthonormal pair (t, b) that the kernels' `shading_frame` (lib/bsdf.glsl) builds
/// for unit normal `n` (Duff et al. 2017), the same arithmetic in the same order.
pub fn tangent_frame(n: Vec3) -> (Vec3, Vec3) {
    let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    (Vec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x), Vec3::new(b, s + n.y * n.y * a, -n.y))
}

/// A bump-mapped triangle's tangent record ([`TriShading::tangent`]): the world-space
/// gradients of its texture coordinates u and v (in its plane: the vectors g with g·e = the
/// coordinate's change along each edge e) in the basis [`tangent_frame`]`(ng)`. Zero for a
/// triangle without area.
fn uv_gradients(p: [Vec3; 3], uv: [[f32; 2]; 3], ng: Vec3) -> [f32; 4] {
    let (e1, e2) = ((p[1] - p[0]).as_dvec3(), (p[2] - p[0]).as_dvec3());
    let (a, b, c) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = a * c - b * b;
    if !det.is_finite() || det <= 0.0 || ng == Vec3::ZERO {
        return [0.0; 4];
    }
    // The gradient x e1 + y e2 of a coordinate whose changes along e1 and e2 are d1, d2:
    // the Gram system [a b; b c] (x, y) = (d1, d2).
    let gradient = |k: usize| {
        let (d1, d2) = ((uv[1][k] - uv[0][k]) as f64, (uv[2][k] - uv[0][k]) as f64);
        (e1 * (c * d1 - b * d2) + e2 * (a * d2 - b * d1)) / det
    };
    let (gu, gv) = (gradient(0), gradient(1));
    let (t, bt) = tangent_frame(ng);
    let (t, bt) = (t.as_dvec3(), bt.as_dvec3());
    [gu.dot(t), gu.dot(bt), gv.dot(t), gv.dot(bt)].map(|x| x as f32)
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

/// A plastic's coating ([`crate::bsdf::coating`]) for its roughness, distribution and
/// index; None for the other kinds. Computed once per combination in a process (a few
/// hundred milliseconds each).
fn plastic_coating(m: &crate::scene::Material) -> Option<([f64; crate::bsdf::TABLE], f64)> {
    type Key = (bool, u32, u32);
    static CACHE: std::sync::Mutex<Vec<(Key, ([f64; crate::bsdf::TABLE], f64))>> = std::sync::Mutex::new(Vec::new());
    if m.kind != MaterialKind::Plastic {
        return None;
    }
    let ScalarValue::Constant(roughness) = m.roughness else { unreachable!("a plastic's roughness is a constant (the loaders refuse a texture)") };
    let beckmann = m.distribution == crate::scene::Distribution::Beckmann;
    let key = (beckmann, roughness.to_bits(), m.ior.to_bits());
    let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, c)) = cache.iter().find(|(k, _)| *k == key) {
        return Some(*c);
    }
    let c = crate::bsdf::coating(beckmann, f64::from(roughness), f64::from(m.ior));
    cache.push((key, c));
    Some(c)
}

fn scalar_ref(data: &mut Vec<f32>, v: &ScalarValue) -> ValueRef {
    match v {
        ScalarValue::Constant(c) => push_value(data, &[*c], None),
        ScalarValue::Texture(t) => push_value(data, &[], Some((&t.image, 1, sampler_flags(t)))),
    }
}

/// A device buffer holding `v` followed by zeros up to a whole number of 16-byte texels
/// (at least one, so that an empty array still has a buffer to bind), for kernels that read
/// it as a uniform texel buffer.
pub fn texel_buffer<T: bytemuck::Pod>(ctx: &Arc<Context>, name: &str, v: &[T]) -> gpu::Result<Buffer> {
    let bytes: &[u8] = bytemuck::cast_slice(v);
    let mut padded = bytes.to_vec();
    let texel = TEXEL_BYTES as usize;
    padded.resize(bytes.len().div_ceil(texel).max(1) * texel, 0);
    Buffer::from_slice(ctx, name, &padded, MemoryKind::Device)
}

impl GpuScene {
    /// Builds the BVH and uploads geometry, materials, lights, sensors and θ (set to the
    /// parameters' initial values), with the default BVH layout.
    pub fn new(ctx: &Arc<Context>, scene: &Scene) -> gpu::Result<Self> {
        Self::with_bvh_layout(ctx, scene, BvhLayout::default())
    }

    /// [`Self::new`] with the BVH layout and traversal stack that `config` asks for.
    pub fn configured(ctx: &Arc<Context>, scene: &Scene, config: &crate::Config) -> gpu::Result<Self> {
        let mut gs = Self::with_bvh_layout(ctx, scene, config.bvh_layout)?;
        gs.bvh_stack_array = config.bvh_stack_array;
        Ok(gs)
    }

    /// [`Self::new`] with the BVH in `bvh_layout`; the scene's kernels are then the builds
    /// for that layout ([`Self::kernel`]).
    pub fn with_bvh_layout(ctx: &Arc<Context>, scene: &Scene, bvh_layout: BvhLayout) -> gpu::Result<Self> {
        let layout = ParamLayout::new(scene);
        let geo = scene.flatten();
        let alpha_material = alpha_materials(scene, &geo);
        let bvh = bvh::build_as(ctx, &geo.positions, &geo.indices, &alpha_material, bvh_layout)?;

        let mut data = Vec::new();
        let materials: Vec<MaterialRecord> = scene
            .materials
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let pick = |target, fallback: ValueRef| layout.slot(target).map_or(fallback, |s| theta_ref(s, fallback));
                let base = color_ref(&mut data, &m.base_color);
                let rough = scalar_ref(&mut data, &m.roughness);
                let metal = scalar_ref(&mut data, &m.metallic);
                // A plastic's coating: its transmittance table in the material data.
                let (internal, table) = match plastic_coating(m) {
                    Some((transmittance, internal)) => {
                        let entries: Vec<f32> = transmittance.iter().map(|t| *t as f32).collect();
                        (internal as f32, push_value(&mut data, &entries, None).offset as u32)
                    }
                    None => (0.0, 0),
                };
                MaterialRecord {
                    base_color: pick(ParamTarget::BaseColor { material: i }, base),
                    roughness: pick(ParamTarget::Roughness { material: i }, rough),
                    metallic: pick(ParamTarget::Metallic { material: i }, metal),
                    kind: match m.kind {
                        MaterialKind::Diffuse => MATERIAL_DIFFUSE,
                        MaterialKind::Principled => MATERIAL_PRINCIPLED,
                        MaterialKind::Dielectric => MATERIAL_DIELECTRIC,
                        MaterialKind::ThinDielectric => MATERIAL_THIN_DIELECTRIC,
                        MaterialKind::RoughDielectric if m.distribution == crate::scene::Distribution::Beckmann => MATERIAL_ROUGH_DIELECTRIC_BECKMANN,
                        MaterialKind::RoughDielectric => MATERIAL_ROUGH_DIELECTRIC,
                        MaterialKind::Conductor if m.distribution == crate::scene::Distribution::Beckmann => MATERIAL_CONDUCTOR_BECKMANN,
                        MaterialKind::Conductor => MATERIAL_CONDUCTOR,
                        MaterialKind::Plastic if m.distribution == crate::scene::Distribution::Beckmann => MATERIAL_PLASTIC_BECKMANN,
                        MaterialKind::Plastic => MATERIAL_PLASTIC,
                    },
                    one_sided: m.one_sided as u32,
                    // Blend: a negative cutoff, for which the kernels draw one per ray.
                    alpha_cutoff: match m.alpha.as_ref().map(|a| a.mode) {
                        None => 0.0,
                        Some(AlphaMode::Mask { cutoff }) => cutoff,
                        Some(AlphaMode::Blend) => -1.0,
                    },
                    ior: if m.kind.has_ior() { m.ior } else { 0.0 },
                    normal_map: normal_map_ref(&mut data, m),
                    alpha: m.alpha.as_ref().map_or(ValueRef::default(), |a| scalar_ref(&mut data, &a.value)),
                    absorption: m.absorption,
                    internal,
                    eta: m.eta,
                    table,
                    k: m.k,
                    nonlinear: m.nonlinear as u32,
                }
            })
            .collect();
        // Each mesh's emission, which its triangles' shading records and emitter records
        // carry. A texture that several meshes share (one glTF material's) is stored once.
        let mut shared_textures: Vec<(*const Image, ValueRef)> = Vec::new();
        let mesh_emission: Vec<ValueRef> = scene
            .meshes
            .iter()
            .enumerate()
            .map(|(i, m)| match layout.slot(ParamTarget::Emission { mesh: i }) {
                // An optimised emission lives in θ; of the scene's value only its sampler
                // flags are kept.
                Some(s) => theta_ref(s, ValueRef { flags: m.emission.texture().map_or(0, sampler_flags), ..ValueRef::default() }),
                None => match &m.emission {
                    ColorValue::Texture(t) => *per_image(&mut shared_textures, &t.image, || color_ref(&mut data, &m.emission)),
                    ColorValue::Constant(_) => color_ref(&mut data, &m.emission),
                },
            })
            .collect();
        let lights: Vec<LightRecord> = scene
            .lights
            .iter()
            .enumerate()
            .map(|(i, l)| {
                let color = push_value(&mut data, &l.color, None);
                let intensity = push_value(&mut data, &[l.intensity], None);
                let (kind, inner, outer, falloff) = match l.kind {
                    LightKind::Point => (crate::constants::LIGHT_POINT, 0.0, 0.0, SpotFalloff::Smooth),
                    LightKind::Spot { inner, outer, falloff } => (crate::constants::LIGHT_SPOT, inner, outer, falloff),
                    LightKind::Directional => (crate::constants::LIGHT_DIRECTIONAL, 0.0, 0.0, SpotFalloff::Smooth),
                };
                LightRecord {
                    position: l.position.into(),
                    kind,
                    direction: l.direction.into(),
                    falloff: match falloff {
                        SpotFalloff::Smooth => crate::constants::FALLOFF_SMOOTH,
                        SpotFalloff::Linear => crate::constants::FALLOFF_LINEAR,
                    },
                    color: layout.slot(ParamTarget::LightColor { light: i }).map_or(color, |s| theta_ref(s, color)),
                    intensity: layout.slot(ParamTarget::LightIntensity { light: i }).map_or(intensity, |s| theta_ref(s, intensity)),
                    cos_inner: inner.cos(),
                    cos_outer: outer.cos(),
                    inner,
                    outer,
                }
            })
            .collect();
        // The pixel filter's table, after the other material data.
        let filter_table = match filter::table(scene.pixel_filter) {
            None => 0,
            Some(table) => {
                let at = data.len() as u32;
                data.extend(table);
                1 + at
            }
        };
        // The environment map is always bilinear and repeating (its sampling assumes so).
        let env_value = ValueRef { flags: 0, ..color_ref(&mut data, &scene.environment.value) };
        let env_slot = layout.slot(ParamTarget::Environment);
        let environment = env_slot.map_or(env_value, |s| theta_ref(s, env_value));
        let has_environment = env_slot.is_some()
            || match &scene.environment.value {
                ColorValue::Constant(c) => c.iter().any(|&v| v > 0.0),
                ColorValue::Texture(_) => true,
            } && scene.environment.scale > 0.0;
        // The environment map's texels as the kernels first see them: θ's start value for
        // an optimised map, the scene's map otherwise. A constant has no distribution.
        let env_texels: Option<(Vec<f32>, u32, u32)> = match env_slot {
            Some(slot) => slot.shape.texture_size().map(|[w, h]| (slot.init.clone(), w, h)),
            None => match &scene.environment.value {
                ColorValue::Texture(t) => Some((t.image.data.iter().flatten().copied().collect(), t.image.width, t.image.height)),
                ColorValue::Constant(_) => None,
            },
        };
        let environment_distribution = match env_texels {
            Some((texels, w, h)) if has_environment && scene.environment.scale > 0.0 => Some(envmap::EnvDistribution::new(&texels, w, h)),
            _ => None,
        };

        // Emitters: triangles of meshes that emit or whose emission is optimised. Picked
        // in proportion to area × luminance (of a texture, its mean over the texels the
        // triangle's lookups can reach: none for a triangle that reaches only black
        // texels), or to area alone when any emission is being optimised (its current
        // value is not known when the table is built).
        let optimised_emission = scene.meshes.iter().enumerate().any(|(i, _)| layout.slot(ParamTarget::Emission { mesh: i }).is_some());
        let mut luminance_tables: Vec<(*const Image, LuminanceTable)> = Vec::new();
        let mesh_emits: Vec<bool> =
            scene.meshes.iter().enumerate().map(|(i, m)| layout.slot(ParamTarget::Emission { mesh: i }).is_some() || m.emission.any_positive()).collect();
        let mut shading: Vec<TriShading> = Vec::with_capacity(geo.indices.len());
        let mut emitters: Vec<EmitterTri> = Vec::new();
        let mut weights = Vec::new();
        for (t, idx) in geo.indices.iter().enumerate() {
            let [a, b, c] = idx.map(|i| Vec3::from(geo.positions[i as usize]));
            let cross = (b - a).cross(c - a);
            let area = 0.5 * cross.length();
            let ng = cross.normalize_or_zero();
            let mesh = geo.triangle_mesh[t] as usize;
            let two_sided = scene.meshes[mesh].two_sided_emission as u32;
            let uvs = idx.map(|i| geo.uvs[i as usize]);
            let luminance = match &scene.meshes[mesh].emission {
                _ if optimised_emission => 1.0,
                ColorValue::Constant(c) => luminance(*c).max(1e-6),
                ColorValue::Texture(t) => per_image(&mut luminance_tables, &t.image, || LuminanceTable::new(&t.image)).footprint_mean(uvs, t.wrap),
            };
            if mesh_emits[mesh] && area > 0.0 && luminance > 0.0 {
                weights.push(area * luminance);
                emitters.push(EmitterTri {
                    p0: a.into(),
                    e1: (b - a).into(),
                    e2: (c - a).into(),
                    ng: ng.into(),
                    prim: t as u32,
                    cdf: 0.0,
                    pdf: area,
                    two_sided,
                    emission: mesh_emission[mesh],
                });
            }
            let material = geo.triangle_material[t];
            let m = &scene.materials[material as usize];
            let tangent = match &m.perturbation {
                None => [0.0; 4],
                Some(Perturbation::Bump(_)) => uv_gradients([a, b, c], uvs, ng),
                Some(Perturbation::Normal(n)) => {
                    let [x, y, z, w] = triangle_tangent([a, b, c], uvs, ng);
                    [x, y, z, if n.bitangent == Bitangent::Cross { w.abs() } else { w }]
                }
            };
            shading.push(TriShading {
                ng: ng.into(),
                material,
                emitter_pdf: 0.0,
                emitter_flags: two_sided | if mesh_emits[mesh] { TriShading::EMITTING_MESH } else { 0 },
                one_sided: materials[material as usize].one_sided,
                mesh: mesh as u32,
                emission: mesh_emission[mesh],
                n0: geo.normals[idx[0] as usize],
                n1: geo.normals[idx[1] as usize],
                n2: geo.normals[idx[2] as usize],
                uv0: uvs[0],
                uv1: uvs[1],
                uv2: uvs[2],
                alpha_material: alpha_material[t],
                tangent,
            });
        }
        let total: f64 = weights.iter().map(|&w| w as f64).sum();
        let mut acc = 0.0f64;
        for (em, w) in emitters.iter_mut().zip(&weights) {
            acc += *w as f64;
            // pmf / area: the area-measure density of a uniform point on this triangle.
            let pmf = *w as f64 / total;
            let pdf = (pmf / em.pdf as f64) as f32;
            em.cdf = (acc / total) as f32;
            em.pdf = pdf;
            shading[em.prim as usize].emitter_pdf = pdf;
        }
        if let Some(last) = emitters.last_mut() {
            // Guards the binary search against rounding: the last cdf is exactly 1.
            last.cdf = 1.0;
        }
        let globals = Globals {
            environment,
            environment_scale: scene.environment.scale,
            environment_sample_prob: Self::environment_sample_prob(environment_distribution.is_some(), emitters.len()),
            num_lights: lights.len() as u32,
            filter_table,
        };
        let env_data = environment_distribution.as_ref().map(|d| d.gpu_data()).unwrap_or_default();

        let has_normal_maps = shading.iter().any(|s| s.tangent != [0.0; 4]);
        let has_alpha_masks = alpha_material.iter().any(|&m| m != 0);
        let has_emission_textures = mesh_emission.iter().any(|r| r.width != 0);
        let has_textures = materials
            .iter()
            .flat_map(|m| [m.base_color, m.roughness, m.metallic, m.normal_map, m.alpha])
            .chain(mesh_emission.iter().copied())
            .chain(lights.iter().flat_map(|l| [l.color, l.intensity]))
            .chain([environment])
            .any(|r| r.width != 0);
        let has_principled = materials.iter().any(|m| m.kind == MATERIAL_PRINCIPLED);
        let has_dielectrics = scene.materials.iter().any(|m| m.kind.is_dielectric());
        let has_rough_dielectrics = scene.materials.iter().any(|m| m.kind == MaterialKind::RoughDielectric);
        let has_conductors = scene.materials.iter().any(|m| m.kind == MaterialKind::Conductor);
        let has_plastics = scene.materials.iter().any(|m| m.kind == MaterialKind::Plastic);
        let has_normals = shading.iter().flat_map(|s| [s.n0, s.n1, s.n2]).any(|n| n != [0.0; 3]);

        let aspect = scene.film.width as f32 / scene.film.height as f32;
        let sensors: Vec<SensorRecord> = scene
            .sensors
            .iter()
            .map(|s| SensorRecord {
                origin: s.origin.into(),
                right: s.right.into(),
                up: s.up.into(),
                forward: s.forward.into(),
                tan_half_fov_y: (s.fov_y.to_radians() * 0.5).tan(),
                aspect,
                ortho_half_height: s.ortho_height.map_or(0.0, |h| 0.5 * h),
                lens_radius: s.lens.map_or(0.0, |l| l.aperture_radius),
                focus_distance: s.lens.map_or(0.0, |l| l.focus_distance),
                pad: [0; 3],
            })
            .collect();

        let buffers = vec![
            ("Materials", texel_buffer(ctx, "materials", &materials)?),
            ("Shading", texel_buffer(ctx, "shading", &shading)?),
            ("Emitters", texel_buffer(ctx, "emitters", &emitters)?),
            ("Sensors", texel_buffer(ctx, "sensors", &sensors)?),
            ("SceneGlobals", texel_buffer(ctx, "globals", &[globals])?),
            ("EnvDistribution", texel_buffer(ctx, "environment distribution", &env_data)?),
            ("Lights", texel_buffer(ctx, "lights", &lights)?),
        ];
        // θ is read as texels by the integrator kernels and as floats by the optimisers;
        // its length is a whole number of texels (the padding is never read or moved), and
        // the material data follow it in the same buffer.
        let const_base = gpu::texel_padded(layout.len) as u32;
        let theta = texel_buffer(ctx, "theta", &targets::with_constants(const_base, &data, layout.initial()))?;
        let frame = Buffer::from_slice(ctx, "frame", &[0u32], MemoryKind::Upload)?;
        Ok(Self {
            ctx: ctx.clone(),
            width: scene.film.width,
            height: scene.film.height,
            sensors: scene.sensors.len(),
            max_depth: scene.integrator.max_depth,
            rr_depth: scene.integrator.rr_depth,
            hide_emitters: scene.integrator.hide_emitters,
            emitters: emitters.len() as u32,
            has_environment,
            lights: lights.len() as u32,
            has_textures,
            has_principled,
            has_dielectrics,
            has_rough_dielectrics,
            has_conductors,
            has_plastics,
            has_normals,
            has_normal_maps,
            has_emission_textures,
            has_alpha_masks,
            environment_distribution,
            replay_cached: scene.integrator.max_depth <= crate::constants::CACHED_BOUNCES,
            local_grads_unrolled: (1..=crate::constants::LOCAL_GRADS_UNROLL_MAX as usize).contains(&layout.len),
            triangles: geo.indices.len(),
            bvh_stack_array: false,
            globals,
            layout,
            bvh,
            buffers,
            theta,
            const_base,
            constants: data,
            frame,
        })
    }

    /// Probability that next-event estimation samples the environment map: 1 without
    /// emissive triangles, ½ with (0 when the environment is not light-sampled).
    fn environment_sample_prob(sampled: bool, emitters: usize) -> f32 {
        match (sampled, emitters) {
            (false, _) => 0.0,
            (true, 0) => 1.0,
            (true, _) => 0.5,
        }
    }

    /// Whether next-event estimation samples the environment map (a scene with a lat-long
    /// map does by default). Turned off, the map is reached by BSDF sampling only, the
    /// baseline that tests and benchmarks compare against; the image's expectation is
    /// the same. Has no effect on a scene whose environment is not a map.
    pub fn set_environment_sampling(&mut self, enabled: bool) -> gpu::Result<()> {
        let sampled = enabled && self.environment_distribution.is_some();
        self.globals.environment_sample_prob = Self::environment_sample_prob(sampled, self.emitters as usize);
        let buffer = &self.buffers.iter().find(|(n, _)| *n == "SceneGlobals").expect("globals buffer").1;
        buffer.write(&[self.globals])
    }

    /// Whether next-event estimation currently samples the environment map.
    pub fn environment_sampling(&self) -> bool {
        self.globals.environment_sample_prob > 0.0
    }

    /// (GLSL block name, buffer) of every scene buffer and θ, for a kernel's bind list.
    pub fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        self.bindings_with(&self.theta)
    }

    /// The scene's bindings with `theta` as the parameters (e.g. the previous iterate).
    pub fn bindings_with<'a>(&'a self, theta: &'a Buffer) -> Vec<(&'static str, &'a Buffer)> {
        let mut v: Vec<(&'static str, &Buffer)> = self.bvh.bindings().into_iter().collect();
        v.extend(self.buffers.iter().map(|(n, b)| (*n, b)));
        v.push(("Theta", theta));
        v.push(("Frame", &self.frame));
        v
    }

    /// Writes θ (padded to the buffer's length).
    pub fn set_theta(&self, values: Vec<f32>) -> gpu::Result<()> {
        self.theta.write(&targets::padded(self, values))
    }

    /// Sets the iteration counter that the next submissions mix into their seeds.
    pub fn set_frame(&self, iteration: u32) -> gpu::Result<()> {
        self.frame.write(&[iteration])
    }

    /// The specialization constants of the integrator kernels for this scene (with the
    /// compressed BVH layout, whether its traversal stack fits in registers).
    pub fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        let mut spec = vec![
            ("MAX_DEPTH", SpecValue::U32(self.max_depth)),
            ("RR_DEPTH", SpecValue::U32(self.rr_depth)),
            ("HIDE_EMITTERS", SpecValue::Bool(self.hide_emitters)),
            ("NUM_EMITTERS", SpecValue::U32(self.emitters)),
            ("HAS_ENVIRONMENT", SpecValue::Bool(self.has_environment)),
            ("ENVIRONMENT_SAMPLED", SpecValue::Bool(self.environment_distribution.is_some())),
            ("HAS_DELTA_LIGHTS", SpecValue::Bool(self.lights > 0)),
            ("HAS_TEXTURES", SpecValue::Bool(self.has_textures)),
            ("HAS_PRINCIPLED", SpecValue::Bool(self.has_principled)),
            ("HAS_NORMALS", SpecValue::Bool(self.has_normals)),
            ("HAS_NORMAL_MAPS", SpecValue::Bool(self.has_normal_maps)),
            ("HAS_EMISSION_TEXTURES", SpecValue::Bool(self.has_emission_textures)),
            ("HAS_ALPHA_MASKS", SpecValue::Bool(self.has_alpha_masks)),
            ("HAS_DIELECTRICS", SpecValue::Bool(self.has_dielectrics)),
            ("HAS_ROUGH_DIELECTRICS", SpecValue::Bool(self.has_rough_dielectrics)),
            ("HAS_CONDUCTORS", SpecValue::Bool(self.has_conductors)),
            ("HAS_PLASTICS", SpecValue::Bool(self.has_plastics)),
            self.const_base_spec(),
        ];
        if self.bvh.layout == BvhLayout::Cw8 {
            spec.push(("BVH_STACK_REGISTERS", SpecValue::Bool(BvhLayout::stack_in_registers(&self.bvh, self.bvh_stack_array))));
        }
        spec
    }

    /// Where the material data start in θ's buffer: a constant every build of a kernel that
    /// reads the scene's values needs, the unspecialised ones too.
    pub fn const_base_spec(&self) -> (&'static str, SpecValue) {
        ("CONST_BASE", SpecValue::U32(self.const_base))
    }

    /// The material data that follow θ in its buffer.
    pub fn constants(&self) -> &[f32] {
        &self.constants
    }

    /// The run-time values of the integrator's limits that the unspecialised variant
    /// `trace_primal_generic` reads (binding `IntegratorLimits`): the same as [`Self::spec`].
    pub fn integrator_limits(&self) -> [u32; 4] {
        [self.max_depth, self.rr_depth, self.emitters, self.has_environment as u32 | (self.hide_emitters as u32) << 1]
    }

    /// The scene's BVH on the device.
    pub fn bvh(&self) -> &BvhBuffers {
        &self.bvh
    }

    /// The build of a kernel that traces the scene's BVH (e.g. `trace_primal`) for the
    /// BVH's layout.
    pub fn kernel(&self, kernel: &str) -> String {
        self.bvh.layout.kernel(kernel)
    }

    /// Pixels of one sensor image.
    pub fn pixels(&self) -> usize {
        (self.width * self.height) as usize
    }
}

/// Samples per pixel per submission: keeps each submission short on slow devices.
pub const SPP_PER_SUBMISSION: u32 = 4;

/// Samples per pixel that one trace dispatch takes at most, for paths of up to
/// `max_depth` vertices.
///
/// lavapipe's shader compiler (gallivm) caps the loop iterations of one shader invocation
/// (a SIMD batch of 8 threads) at 65535 (`LP_MAX_TGSI_LOOP_ITERATIONS`): one counter,
/// decremented by every iteration of every loop of the kernel and never reset, and once
/// it reaches zero every loop exits after its current iteration. A thread that loops over
/// too many samples therefore returns truncated paths, silently (1024 spp of the Cornell
/// box in one dispatch lose 61 % of the image: tests/suite/render.rs). A path vertex costs up to
/// a few hundred iterations on the bundled scenes (the traversal's node and triangle loops,
/// twice in the adjoint kernels), so every pass splits its samples into dispatches of at
/// most 16 / max_depth samples (at least 1, at most 4), well inside the cap.
pub fn spp_per_dispatch(max_depth: u32) -> u32 {
    (16 / max_depth.max(1)).clamp(1, 4)
}

/// Records `pipeline` (a trace kernel taking [`TracePush`]) over `spp` samples per pixel
/// starting at `push.first_sample`, in dispatches of at most
/// [`spp_per_dispatch`]`(scene.max_depth)` samples, each adding to what the previous one
/// accumulated (the recorder puts the barrier between them).
pub fn record_samples(rec: &mut Recorder, scene: &GpuScene, pipeline: &ComputePipeline, group: &BindGroup, push: TracePush, spp: u32) -> gpu::Result<()> {
    let step = spp_per_dispatch(scene.max_depth);
    let mut done = 0;
    while done < spp {
        let chunk = step.min(spp - done);
        let p = TracePush { spp: chunk, first_sample: push.first_sample + done, ..push };
        rec.dispatch_linear(pipeline, group, &p, p.invocations())?;
        done += chunk;
    }
    Ok(())
}

/// Renders sensor `sensor` of `scene` as written (optimised parameters at their reference
/// values) with `spp` samples per pixel; `progress(done, total)` follows the submissions,
/// and `stop()`, asked after each, may end the render early ([`PrimalRenderer::render_until`]).
/// Returns the image and the samples per pixel it holds.
pub fn render_reference(
    ctx: &Arc<Context>,
    scene: &Scene,
    sensor: u32,
    spp: u32,
    seed: u64,
    progress: impl FnMut(u32, u32),
    stop: impl Fn() -> bool,
) -> gpu::Result<(Image, u32)> {
    let renderer = PrimalRenderer::new(GpuScene::new(ctx, scene)?)?;
    renderer.scene.set_theta(renderer.scene.layout.reference())?;
    renderer.render_until(sensor, spp, crate::settings::gpu_seed(seed), progress, stop)
}

/// Renders images of a [`GpuScene`] with the primal kernel.
pub struct PrimalRenderer {
    pub scene: GpuScene,
    primal: ComputePipeline,
}

impl PrimalRenderer {
    pub fn new(scene: GpuScene) -> gpu::Result<Self> {
        let primal = ComputePipeline::new(&scene.ctx, &scene.kernel("trace_primal"), &scene.spec())?;
        Ok(Self { scene, primal })
    }

    /// The kernel that renders (trace_primal's build for the scene's BVH layout).
    pub fn kernel(&self) -> &str {
        self.primal.name()
    }

    /// Renders sensor `sensor` with `spp` samples per pixel, in submissions of at most
    /// [`SPP_PER_SUBMISSION`] samples; `progress(done, total)` is called after each.
    pub fn render(&self, sensor: u32, spp: u32, seed: u32, progress: impl FnMut(u32, u32)) -> gpu::Result<Image> {
        Ok(self.render_until(sensor, spp, seed, progress, || false)?.0)
    }

    /// [`Self::render`], asking `stop()` after each submission whether to end early: the
    /// image is then the mean of the samples rendered so far (the first submission's at
    /// least), equal up to rounding to a render of that many samples with this seed. Returns the image
    /// and its samples per pixel.
    pub fn render_until(&self, sensor: u32, spp: u32, seed: u32, mut progress: impl FnMut(u32, u32), stop: impl Fn() -> bool) -> gpu::Result<(Image, u32)> {
        let ctx = &self.scene.ctx;
        let n = self.scene.pixels();
        let accum = Buffer::zeroed::<[f32; 3]>(ctx, "accum", n, MemoryKind::Device)?;
        let mut binds = self.scene.bindings();
        binds.push(("Accum", &accum));
        let group = self.primal.bind(&binds)?;
        let mut cmd = CommandBuffer::new(ctx, "render")?;
        let mut done = 0;
        while done < spp {
            let chunk = SPP_PER_SUBMISSION.min(spp - done);
            let push = TracePush {
                width: self.scene.width,
                height: self.scene.height,
                sensor,
                spp: chunk,
                first_sample: done,
                seed,
                weight: 1.0 / spp as f32,
                stride: 1,
                phase: 0,
            };
            cmd.record(|rec| record_samples(rec, &self.scene, &self.primal, &group, push, chunk))?;
            cmd.submit_and_wait()?;
            done += chunk;
            progress(done, spp);
            if done < spp && stop() {
                break;
            }
        }
        let mut data: Vec<[f32; 3]> = accum.read()?;
        if done < spp {
            // Each sample was weighted 1 / spp.
            let scale = spp as f32 / done as f32;
            data.iter_mut().flatten().for_each(|v| *v *= scale);
        }
        Ok((Image { width: self.scene.width, height: self.scene.height, data }, done))
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
