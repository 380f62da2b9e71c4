//! The optimised parameters laid out in one flat float buffer θ.
//!
//! Each `[[optimise.params]]` entry becomes a [`ParamSlot`]: `channels` floats per texel,
//! `texels` texels (1 for a constant), starting at `offset` in θ. Kernels read a slot
//! through a `ValueRef` flagged `IN_THETA`; the optimiser updates slots in place.

use crate::scene::write::Recovered;
use crate::scene::{ParamTarget, Reference, Scene};

/// One optimised parameter.
#[derive(Clone, Debug)]
pub struct ParamSlot {
    pub name: String,
    pub target: ParamTarget,
    pub channels: u32,
    /// Texture size, or `[0, 0]` for a constant.
    pub size: [u32; 2],
    pub offset: usize,
    pub len: usize,
    pub range: [f32; 2],
    /// The scene's learning rate for this parameter, if it sets one.
    pub lr: Option<f32>,
    /// Start values (`len` floats).
    pub init: Vec<f32>,
    /// The scene's own values resampled to this slot's layout (`len` floats).
    pub reference: Vec<f32>,
}

/// All parameter slots and the total length of θ.
#[derive(Clone, Debug, Default)]
pub struct ParamLayout {
    pub slots: Vec<ParamSlot>,
    pub len: usize,
}

impl ParamLayout {
    pub fn new(scene: &Scene) -> Self {
        let mut layout = ParamLayout::default();
        for p in &scene.optimise.params {
            let size = p.texture.unwrap_or([0, 0]);
            let texels = if p.texture.is_some() { (size[0] * size[1]) as usize } else { 1 };
            let len = texels * p.channels as usize;
            let init: Vec<f32> = p.init.iter().copied().cycle().take(len).collect();
            let reference = match &p.reference {
                Reference::Constant(v) => v.iter().copied().cycle().take(len).collect(),
                Reference::Texture(t) => {
                    let (w, h) = if p.texture.is_some() { (size[0], size[1]) } else { (1, 1) };
                    t.image.resample(p.channels, w, h)
                }
            };
            layout.slots.push(ParamSlot {
                name: p.name.clone(),
                target: p.target,
                channels: p.channels,
                size,
                offset: layout.len,
                len,
                range: p.range,
                lr: p.lr,
                init,
                reference,
            });
            layout.len += len;
        }
        layout
    }

    /// The slot optimising `target`, if any.
    pub fn slot(&self, target: ParamTarget) -> Option<&ParamSlot> {
        self.slots.iter().find(|s| s.target == target)
    }

    /// θ at the start of an optimisation.
    pub fn initial(&self) -> Vec<f32> {
        self.slots.iter().flat_map(|s| s.init.iter().copied()).collect()
    }

    /// θ at the scene's own (reference) values.
    pub fn reference(&self) -> Vec<f32> {
        self.slots.iter().flat_map(|s| s.reference.iter().copied()).collect()
    }

    /// Every slot's values in θ as a recovered parameter, for writing the scene back.
    pub fn recovered(&self, theta: &[f32]) -> Vec<(ParamTarget, Recovered)> {
        self.slots
            .iter()
            .map(|s| {
                let v = theta[s.offset..s.offset + s.len].to_vec();
                let r = if s.size == [0, 0] {
                    Recovered::Constant(v)
                } else {
                    Recovered::Texture { width: s.size[0], height: s.size[1], channels: s.channels, data: v }
                };
                (s.target, r)
            })
            .collect()
    }

    /// Root-mean-square error of θ against the reference, overall and per slot.
    pub fn errors(&self, theta: &[f32]) -> (f64, Vec<f64>) {
        let mut total = 0.0;
        let per = self
            .slots
            .iter()
            .map(|s| {
                let se: f64 = theta[s.offset..s.offset + s.len].iter().zip(&s.reference).map(|(a, b)| (*a as f64 - *b as f64).powi(2)).sum();
                total += se;
                (se / s.len.max(1) as f64).sqrt()
            })
            .collect();
        ((total / self.len.max(1) as f64).sqrt(), per)
    }
}
