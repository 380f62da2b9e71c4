//! Target images: a sensor's `target_image`, or the reference scene rendered at high spp
//! and cached beside the scene (`.vkinverse-cache/`), or in the user's cache directory
//! (`$XDG_CACHE_HOME/vkinverse`, `~/.cache/vkinverse`; `VKINVERSE_CACHE_DIR` replaces it)
//! when the scene's directory cannot be written. The cache is optional: when neither can be
//! written the target is used uncached, with a warning.
//!
//! A cached target is keyed by the scene's content hash, the SPIR-V of the kernel that
//! renders it, the sensor and the sample count: editing the scene or changing the renderer
//! (a new build, another BVH layout) renders it anew.

use super::{GpuScene, Renderer};
use crate::error::{Error, Result};
use crate::image::{self, Image};
use crate::scene::Scene;
use std::path::PathBuf;

/// Seed of rendered targets: far from the optimisation's seeds.
const TARGET_SEED: u32 = 0x7A46_E701;

/// FNV-1a 64 of the renderer's kernel: part of the cache key.
fn kernel_hash(renderer: &Renderer) -> u64 {
    let spirv = crate::gpu::shaders::get(renderer.kernel()).unwrap_or_default();
    spirv.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3))
}

/// The cache file's name for `sensor` at `spp` samples.
pub fn cache_name(scene: &Scene, renderer: &Renderer, sensor: usize, spp: u32) -> String {
    format!("target-{:016x}-{:016x}-s{sensor}-{spp}spp.exr", scene.content_hash(), kernel_hash(renderer))
}

/// Where cached targets may live, in order: beside the scene, then the user's cache.
pub fn cache_dirs(scene: &Scene) -> Vec<PathBuf> {
    let user = std::env::var_os("VKINVERSE_CACHE_DIR").map(PathBuf::from).or_else(|| dirs::cache_dir().map(|d| d.join("vkinverse")));
    std::iter::once(scene.dir().join(".vkinverse-cache")).chain(user).collect()
}

/// Writes `img` as `name` into the first cache directory that takes it.
fn store(scene: &Scene, name: &str, img: &Image) {
    let mut failures = Vec::new();
    for dir in cache_dirs(scene) {
        let written = std::fs::create_dir_all(&dir).map_err(|e| e.to_string()).and_then(|()| image::write_exr(&dir.join(name), img).map_err(|e| e.to_string()));
        match written {
            Ok(()) => return,
            Err(e) => failures.push(format!("{}: {e}", dir.display())),
        }
    }
    crate::report::warn(&format!("the rendered target is not cached ({})", failures.join("; ")));
}

/// One target image per sensor. `progress(sensor, done, total)` reports rendering; a
/// Ctrl-C ([`crate::interrupt`]) ends it with [`Error::Interrupted`].
pub fn targets(renderer: &Renderer, scene: &Scene, spp: u32, mut progress: impl FnMut(usize, u32, u32)) -> Result<Vec<Image>> {
    let mut out = Vec::new();
    let mut reference_set = false;
    for (s, sensor) in scene.sensors.iter().enumerate() {
        if let Some(t) = &sensor.target_image {
            out.push((*t.image).clone());
            continue;
        }
        let name = cache_name(scene, renderer, s, spp);
        let cached = cache_dirs(scene).iter().find_map(|d| image::read_exr(&d.join(&name)).ok());
        if let Some(img) = cached.filter(|img| img.width == scene.film.width && img.height == scene.film.height) {
            out.push(img);
            continue;
        }
        if !reference_set {
            renderer.scene.theta.write(&padded(&renderer.scene, renderer.scene.layout.reference()))?;
            reference_set = true;
        }
        let (img, done) = renderer.render_until(s as u32, spp, TARGET_SEED, |d, t| progress(s, d, t), crate::interrupt::requested)?;
        if done < spp {
            // A Ctrl-C (crate::interrupt): a target of fewer samples is not the target.
            return Err(Error::Interrupted(format!("while rendering the target of sensor {s} ({done} of {spp} samples per pixel); no iteration ran")));
        }
        store(scene, &name, &img);
        out.push(img);
    }
    if reference_set {
        renderer.scene.theta.write(&padded(&renderer.scene, renderer.scene.layout.initial()))?;
    }
    Ok(out)
}

/// θ values as θ's buffer holds them: padded to whole texels (one unused texel when nothing
/// is optimised), then the scene's material data.
pub fn padded(scene: &GpuScene, v: Vec<f32>) -> Vec<f32> {
    with_constants(scene.const_base, scene.constants(), v)
}

/// `theta` padded with zeros to `const_base` floats, then `constants`.
pub fn with_constants(const_base: u32, constants: &[f32], mut theta: Vec<f32>) -> Vec<f32> {
    theta.resize(const_base as usize, 0.0);
    theta.extend_from_slice(constants);
    theta
}
