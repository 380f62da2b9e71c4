//! The scene's content hash: XXH3-64 of the loaded model, every value that changes the
//! reference rendering and nothing else.
//!
//! Hashing the model rather than the files makes the key the same for every source format
//! and covers what the files refer to (meshes, images, imported glTF and Mitsuba files,
//! command-line film and depth overrides) by construction: two scenes with equal hashes
//! render equal reference images. Left out, because the reference render does not read
//! them: names, target images, and the `[optimise]` table, except the size of a texture
//! parameter whose scene value is a texture (its reference is that texture resampled to
//! the parameter's size, and the reference render uses it).
//!
//! Every field is written in little-endian with a tag and, for arrays, a length, so that
//! fields cannot run into each other and the key is the same on every platform.

use xxhash_rust::xxh3::Xxh3;

use super::model::*;
use super::MaterialKind;

/// Bumped when the hashed fields or their encoding change, so that old cache entries miss.
const VERSION: &str = "vkinverse-scene-hash-v3";

struct Hasher(Xxh3);

impl Hasher {
    fn tag(&mut self, tag: &str) {
        self.u64(tag.len() as u64);
        self.0.update(tag.as_bytes());
    }

    fn u64(&mut self, v: u64) {
        self.0.update(&v.to_le_bytes());
    }

    fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        for x in v {
            self.0.update(&x.to_bits().to_le_bytes());
        }
    }

    fn u32s(&mut self, v: &[u32]) {
        self.u64(v.len() as u64);
        for x in v {
            self.0.update(&x.to_le_bytes());
        }
    }

    fn texture(&mut self, t: &Texture) {
        self.u32s(&[t.image.width, t.image.height]);
        self.f32s(t.image.data.as_flattened());
        // Only a nearest filter and other wrap modes add to the hash, so the hashes of
        // bilinear, repeating textures stay.
        if t.filter == Filter::Nearest {
            self.tag("filter=nearest");
        }
        if t.wrap != [Wrap::Repeat; 2] {
            self.tag(&format!("wrap={}/{}", t.wrap[0].name(), t.wrap[1].name()));
        }
        if t.uv_set != 0 {
            self.tag(&format!("uv_set={}", t.uv_set));
        }
    }

    fn color(&mut self, v: &ColorValue) {
        match v {
            ColorValue::Constant(c) => {
                self.tag("constant");
                self.f32s(c);
            }
            ColorValue::Texture(t) => {
                self.tag("texture");
                self.texture(t);
            }
        }
    }

    fn scalar(&mut self, v: &ScalarValue) {
        match v {
            ScalarValue::Constant(c) => {
                self.tag("constant");
                self.f32s(&[*c]);
            }
            ScalarValue::Texture(t) => {
                self.tag("texture");
                self.texture(t);
            }
        }
    }
}

/// The content hash of `scene` (see the module documentation).
///
/// Not split: the order in which the fields are hashed is the hash; one function keeps it
/// readable from top to bottom.
pub fn content_hash(scene: &Scene) -> u64 {
    let mut h = Hasher(Xxh3::new());
    h.tag(VERSION);
    h.tag("film");
    h.u32s(&[scene.film.width, scene.film.height]);
    // Only where not the box, so that the hashes of scenes without one stay as they were.
    match scene.pixel_filter {
        PixelFilter::Box => {}
        PixelFilter::Gaussian { stddev } => {
            h.tag("gaussian");
            h.f32s(&[stddev]);
        }
        PixelFilter::Tent { radius } => {
            h.tag("tent");
            h.f32s(&[radius]);
        }
    }
    h.tag("integrator");
    h.u32s(&[scene.integrator.max_depth, scene.integrator.rr_depth]);
    // Only where set, so that the hashes of scenes without it stay as they were.
    if scene.integrator.hide_emitters {
        h.tag("hide_emitters");
    }
    h.tag("sensors");
    h.u64(scene.sensors.len() as u64);
    for s in &scene.sensors {
        h.f32s(&[s.origin.to_array(), s.forward.to_array(), s.right.to_array(), s.up.to_array()].concat());
        h.f32s(&[s.fov_y]);
        if let Some(height) = s.ortho_height {
            h.tag("orthographic");
            h.f32s(&[height]);
        }
        if let Some(lens) = s.lens {
            h.tag("thin lens");
            h.f32s(&[lens.aperture_radius, lens.focus_distance]);
        }
    }
    h.tag("materials");
    h.u64(scene.materials.len() as u64);
    for m in &scene.materials {
        h.tag(m.kind.as_str());
        h.color(&m.base_color);
        h.scalar(&m.roughness);
        h.scalar(&m.metallic);
        h.u64(m.one_sided as u64);
        // Hashed only where present, so that the hashes (and cached targets) of scenes
        // without normal maps are what they were before normal maps existed.
        match &m.perturbation {
            None => {}
            Some(Perturbation::Normal(n)) => {
                h.tag("normal_map");
                h.texture(&n.texture);
                h.f32s(&[n.scale]);
                h.tag(n.bitangent.as_str());
            }
            Some(Perturbation::Bump(b)) => {
                h.tag("bump_map");
                h.texture(&b.texture);
                h.f32s(&[b.scale]);
            }
        }
        if let Some(a) = &m.alpha {
            h.tag("alpha");
            h.scalar(&a.value);
            h.tag(a.mode.as_str());
            if let AlphaMode::Mask { cutoff } = a.mode {
                h.f32s(&[cutoff]);
            }
        }
        if m.kind.has_ior() {
            h.f32s(&[m.ior]);
        }
        if m.nonlinear {
            h.tag("nonlinear");
        }
        if !m.layered {
            h.tag("unlayered");
        }
        if m.specular != [1.0; 3] {
            h.tag("specular");
            h.f32s(&m.specular);
        }
        if m.absorption != [0.0; 3] {
            h.tag("absorption");
            h.f32s(&m.absorption);
        }
        if m.distribution != Distribution::Ggx {
            h.tag(m.distribution.as_str());
        }
        if m.kind == MaterialKind::Conductor {
            h.tag("complex ior");
            h.f32s(&m.eta);
            h.f32s(&m.k);
        }
    }
    h.tag("meshes");
    h.u64(scene.meshes.len() as u64);
    for m in &scene.meshes {
        h.f32s(m.positions.as_flattened());
        h.f32s(m.normals.as_flattened());
        h.f32s(m.uvs.as_flattened());
        if !m.uvs1.is_empty() {
            h.tag("uvs1");
            h.f32s(m.uvs1.as_flattened());
        }
        h.u32s(m.indices.as_flattened());
        h.u64(m.material as u64);
        // A constant hashes as before textured emission existed (its values alone).
        match &m.emission {
            ColorValue::Constant(c) => h.f32s(c),
            ColorValue::Texture(t) => {
                h.tag("emission_texture");
                h.texture(t);
            }
        }
        h.u64(m.two_sided_emission as u64);
    }
    h.tag("lights");
    h.u64(scene.lights.len() as u64);
    for l in &scene.lights {
        h.tag(l.kind.as_str());
        if let LightKind::Spot { inner, outer, falloff } = l.kind {
            h.f32s(&[inner, outer]);
            h.tag(falloff.as_str());
        }
        h.f32s(&[l.position.to_array(), l.direction.to_array(), l.color].concat());
        h.f32s(&[l.intensity]);
    }
    h.tag("environment");
    h.color(&scene.environment.value);
    h.f32s(&[scene.environment.scale]);
    // Only where there are media, so that the hashes of scenes without stay as they were.
    if !scene.media.is_empty() {
        h.tag("media");
        h.u64(scene.media.len() as u64);
        for m in &scene.media {
            h.f32s(&[m.min, m.max].concat());
            h.f32s(&[m.scale, m.step, m.g]);
            if let Some(b) = m.majorant {
                h.tag("majorant");
                h.f32s(&[b]);
            }
            for v in [&m.density, &m.emission, &m.albedo] {
                h.u32s(&v.shape.array().iter().map(|&d| d as u32).collect::<Vec<_>>());
                h.f32s(&v.data);
            }
            // Only where there is one, so that the hashes of boxes stay as they were.
            if let Some(b) = &m.boundary {
                h.tag("boundary");
                h.f32s(&b.positions.concat());
                h.u32s(&b.indices.concat());
            }
        }
    }
    // Only a texture optimised at another resolution than the scene's changes the
    // reference render (its reference is resampled); every other parameter renders its
    // scene value as it is.
    h.tag("resampled");
    for p in &scene.optimise.params {
        if let (Some(size), Reference::Texture(_)) = (p.shape.texture_size(), &p.reference) {
            h.tag(&p.name);
            h.u32s(&size);
        }
        if let Reference::Grid(v) = &p.reference {
            if v.shape.dims() != p.shape.dims() {
                h.tag(&p.name);
                h.u32s(p.shape.dims());
            }
        }
    }
    h.0.digest()
}
