//! Target images: a sensor's `target_image`, or the reference scene rendered at high spp
//! and cached beside the scene (`.vkinverse-cache/`), keyed by the scene's content hash,
//! the sensor and the sample count, so that editing the scene invalidates the cache.

use super::{GpuScene, Renderer};
use crate::error::{Error, Result};
use crate::image::{self, Image};
use crate::scene::Scene;
use std::path::PathBuf;

/// Samples per pixel of rendered targets.
pub const TARGET_SPP: u32 = 1024;

/// Seed of rendered targets: far from the optimisation's seeds.
const TARGET_SEED: u32 = 0x7A46_E701;

fn cache_path(scene: &Scene, sensor: usize, spp: u32) -> PathBuf {
    scene.dir().join(".vkinverse-cache").join(format!("target-{:016x}-s{sensor}-{spp}spp.exr", scene.content_hash()))
}

/// One target image per sensor. `progress(sensor, done, total)` reports rendering.
pub fn targets(renderer: &Renderer, scene: &Scene, spp: u32, mut progress: impl FnMut(usize, u32, u32)) -> Result<Vec<Image>> {
    let mut out = Vec::new();
    let mut reference_set = false;
    for (s, sensor) in scene.sensors.iter().enumerate() {
        if let Some(t) = &sensor.target_image {
            out.push(t.image.clone());
            continue;
        }
        let path = cache_path(scene, s, spp);
        if let Ok(img) = image::read_exr(&path) {
            if img.width == scene.film.width && img.height == scene.film.height {
                out.push(img);
                continue;
            }
        }
        if !reference_set {
            renderer.scene.theta.write(&padded(&renderer.scene, renderer.scene.layout.reference()))?;
            reference_set = true;
        }
        let img = renderer.render(s as u32, spp, TARGET_SEED, |d, t| progress(s, d, t))?;
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|source| Error::Io { path: dir.to_path_buf(), source })?;
        }
        image::write_exr(&path, &img)?;
        out.push(img);
    }
    if reference_set {
        renderer.scene.theta.write(&padded(&renderer.scene, renderer.scene.layout.initial()))?;
    }
    Ok(out)
}

/// θ values padded to the buffer's length (one unused float when nothing is optimised).
pub fn padded(scene: &GpuScene, mut v: Vec<f32>) -> Vec<f32> {
    v.resize((scene.theta.len() / 4) as usize, 0.0);
    v
}
