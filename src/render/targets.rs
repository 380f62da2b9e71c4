//! Target images: a sensor's `target_image`, or the reference scene rendered at high spp
//! and cached beside the scene (`.vkinverse-cache/`), or in the configured cache directory
//! ([`crate::Config::cache_dir`]; the command line's is the user's cache directory) when the
//! scene's directory cannot be written. The cache is optional: when neither can be written
//! the target is used uncached, with a warning.
//!
//! A cached target is keyed by the scene's content hash, the SPIR-V of the kernel that
//! renders it, the sensor and the sample count: editing the scene or changing the renderer
//! (a new build, another BVH layout) renders it anew.

use super::{GpuScene, PrimalRenderer};
use crate::cancel::Cancel;
use crate::error::{Error, Result};
use crate::image::{self, Image};
use crate::observer::Observer;
use crate::scene::Scene;
use std::path::{Path, PathBuf};

/// Seed of rendered targets: far from the optimisation's seeds.
const TARGET_SEED: u32 = 0x7A46_E701;

/// FNV-1a 64 of the renderer's kernel: part of the cache key.
fn kernel_hash(renderer: &PrimalRenderer) -> u64 {
    let spirv = crate::gpu::shaders::get(renderer.kernel()).unwrap_or_default();
    spirv.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3))
}

/// The cache file's name for `sensor` at `spp` samples.
pub fn cache_name(scene: &Scene, renderer: &PrimalRenderer, sensor: usize, spp: u32) -> String {
    format!("target-{:016x}-{:016x}-s{sensor}-{spp}spp.exr", scene.content_hash(), kernel_hash(renderer))
}

/// Where cached targets may live, in order: beside the scene, then `cache_dir`.
pub fn cache_dirs(scene: &Scene, cache_dir: Option<&Path>) -> Vec<PathBuf> {
    std::iter::once(scene.dir().join(".vkinverse-cache")).chain(cache_dir.map(Path::to_path_buf)).collect()
}

/// Writes `img` as `name` into the first cache directory that takes it, or says why none
/// did.
fn store(dirs: &[PathBuf], name: &str, img: &Image, observer: &mut dyn Observer) {
    let mut failures = Vec::new();
    for dir in dirs {
        let written = std::fs::create_dir_all(dir).map_err(|e| e.to_string()).and_then(|()| image::write_exr(&dir.join(name), img).map_err(|e| e.to_string()));
        match written {
            Ok(()) => return,
            Err(e) => failures.push(format!("{}: {e}", dir.display())),
        }
    }
    observer.warning(&format!("the rendered target is not cached ({})", failures.join("; ")));
}

/// Where target images come from besides the scene: the sample count of a rendered one,
/// the cache beside the scene's and the token that stops a render.
#[derive(Clone, Copy)]
pub struct TargetSource<'a> {
    pub spp: u32,
    pub cache_dir: Option<&'a Path>,
    pub cancel: &'a Cancel,
}

/// One target image per sensor. The observer hears the renders' progress and a target that
/// could not be cached; a cancellation ends a render with [`Error::Interrupted`].
pub fn targets(renderer: &PrimalRenderer, scene: &Scene, source: TargetSource, observer: &mut dyn Observer) -> Result<Vec<Image>> {
    let spp = source.spp;
    let dirs = cache_dirs(scene, source.cache_dir);
    let mut out = Vec::new();
    let mut reference_set = false;
    for (s, sensor) in scene.sensors.iter().enumerate() {
        if let Some(t) = &sensor.target_image {
            out.push((*t.image).clone());
            continue;
        }
        let name = cache_name(scene, renderer, s, spp);
        let cached = dirs.iter().find_map(|d| image::read_exr(&d.join(&name)).ok());
        if let Some(img) = cached.filter(|img| img.width == scene.film.width && img.height == scene.film.height) {
            out.push(img);
            continue;
        }
        if !reference_set {
            renderer.scene.theta.write(&padded(&renderer.scene, renderer.scene.layout.reference()))?;
            reference_set = true;
        }
        let (img, done) = renderer.render_until(s as u32, spp, TARGET_SEED, |d, t| observer.target_progress(s, d, t), || source.cancel.is_cancelled())?;
        if done < spp {
            // Cancelled: a target of fewer samples is not the target.
            return Err(Error::Interrupted(format!("while rendering the target of sensor {s} ({done} of {spp} samples per pixel); no iteration ran")));
        }
        store(&dirs, &name, &img, observer);
        out.push(img);
    }
    if reference_set {
        renderer.scene.theta.write(&padded(&renderer.scene, renderer.scene.layout.initial()))?;
    }
    Ok(out)
}

/// θ values as the start of θ's buffer holds them: padded to whole texels (one unused
/// texel when nothing is optimised). The scene's material data follow them in the buffer
/// and are never written again: a write of this prefix leaves them as they are.
pub fn padded(scene: &GpuScene, mut v: Vec<f32>) -> Vec<f32> {
    v.resize(scene.const_base as usize, 0.0);
    v
}
