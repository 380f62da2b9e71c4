//! Coarse to fine (the `upsample` setting): after given iterations every grid parameter
//! doubles its voxels along each axis. The run goes on with a scene whose grid parameters
//! have the new size ([`stage_scene`]); θ and every per-element array of the optimiser's
//! state are carried over, each slot resampled trilinearly between voxel centres as the
//! kernels look a grid up ([`relayout`]).

use crate::error::{Error, Result};
use crate::image::Image;
use crate::render::ParamLayout;
use crate::scene::media::resample;
use crate::scene::{Scene, Texture};
use crate::tensor::{ParamValue, Shape, MAX_GRID_SIDE, MAX_GRID_VOXELS};
use std::borrow::Cow;
use std::path::PathBuf;
use std::sync::Arc;

/// `shape` with 2^stage times its voxels along each axis (a grid; any other shape as it is).
fn upsampled(shape: Shape, stage: usize) -> Result<Shape> {
    let [d, h, w] = match *shape.dims() {
        [d, h, w] => [d, h, w],
        _ => return Ok(shape),
    };
    let grow = |n: u32| n.checked_shl(stage as u32).filter(|&m| m <= MAX_GRID_SIDE && m >> stage == n);
    match (grow(w), grow(h), grow(d)) {
        (Some(w), Some(h), Some(d)) if (w as usize) * (h as usize) * (d as usize) <= MAX_GRID_VOXELS => Ok(Shape::grid(w, h, d, shape.channels())),
        _ => Err(Error::Invalid(format!(
            "upsample: {stage} doublings of a {w} x {h} x {d} grid exceed the largest grid ({MAX_GRID_SIDE} voxels per side, {MAX_GRID_VOXELS} in all)"
        ))),
    }
}

/// Checks, before any work, that `stages` upsamplings of `scene` can be done: it has a grid
/// parameter to upsample, and its finest grids fit.
pub fn check(scene: &Scene, stages: usize) -> Result<()> {
    if stages == 0 {
        return Ok(());
    }
    if !scene.optimise.params.iter().any(|p| p.shape.ndim() == 3) {
        return Err(Error::Invalid("upsample: the scene optimises no grid (a medium's density or emission)".into()));
    }
    scene.optimise.params.iter().try_for_each(|p| upsampled(p.shape, stages).map(|_| ()))
}

/// `scene` at coarse-to-fine stage `stage` (after `stage` upsamplings): every grid
/// parameter at 2^stage times its voxels along each axis, its start values resampled.
/// With `targets`, the sensors' target images are those (the first stage's renders, so
/// that a later stage renders none). Stage 0 without targets is `scene` itself.
pub fn stage_scene<'s>(scene: &'s Scene, stage: usize, targets: Option<&[Image]>) -> Result<Cow<'s, Scene>> {
    if stage == 0 && targets.is_none() {
        return Ok(Cow::Borrowed(scene));
    }
    let mut out = scene.clone();
    for p in &mut out.optimise.params {
        let shape = upsampled(p.shape, stage)?;
        if shape != p.shape {
            p.init = resample(&ParamValue { shape: p.shape, data: std::mem::take(&mut p.init) }, shape);
            p.shape = shape;
        }
    }
    if let Some(targets) = targets {
        for (k, (sensor, image)) in out.sensors.iter_mut().zip(targets).enumerate() {
            if sensor.target_image.is_none() {
                let path = PathBuf::from(format!("<sensor {k}'s rendered target>"));
                sensor.target_image = Some(Texture::new(path, Arc::new(image.clone())));
            }
        }
    }
    Ok(Cow::Owned(out))
}

/// A θ-shaped array (θ's floats: each slot at its offset in `from`) laid out as `to`, in
/// `len` floats: each slot copied, or resampled where its shape changed; the rest zero.
pub fn relayout(values: &[f32], from: &ParamLayout, to: &ParamLayout, len: usize) -> Vec<f32> {
    let mut out = vec![0.0; len];
    for (a, b) in from.slots.iter().zip(&to.slots) {
        let old = &values[a.offset..a.offset + a.len];
        let new = if a.shape == b.shape { old.to_vec() } else { resample(&ParamValue { shape: a.shape, data: old.to_vec() }, b.shape) };
        out[b.offset..b.offset + b.len].copy_from_slice(&new);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_double_per_stage_within_the_limits() {
        let g = Shape::grid(4, 3, 2, 3);
        assert_eq!(upsampled(g, 0).unwrap(), g);
        assert_eq!(upsampled(g, 2).unwrap(), Shape::grid(16, 12, 8, 3));
        assert_eq!(upsampled(Shape::constant(3), 5).unwrap(), Shape::constant(3));
        let err = upsampled(Shape::grid(512, 8, 8, 1), 2).unwrap_err().to_string();
        assert!(err.contains("2 doublings of a 512 x 8 x 8 grid exceed the largest grid"), "{err}");
        assert!(upsampled(Shape::grid(256, 256, 256, 1), 1).is_err(), "512³ voxels exceed the total");
    }
}
