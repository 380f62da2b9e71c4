//! The optimised parameters laid out in one flat float buffer θ.
//!
//! Each `[[optimise.params]]` entry becomes a [`ParamSlot`]: `shape.len()` floats (its
//! texels, each of its channels) starting at `offset` in θ, whatever its shape. Kernels read
//! a slot through a `ValueRef` flagged `IN_THETA`; the optimiser updates slots in place.

use crate::scene::{ParamTarget, Reference, Scene};
use crate::tensor::{ParamValue, Shape};

/// One optimised parameter.
#[derive(Clone, Debug)]
pub struct ParamSlot {
    pub name: String,
    pub target: ParamTarget,
    pub shape: Shape,
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

impl ParamSlot {
    /// The slot's values in θ.
    pub fn value(&self, theta: &[f32]) -> ParamValue {
        ParamValue { shape: self.shape, data: theta[self.offset..self.offset + self.len].to_vec() }
    }
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
            let len = p.shape.len();
            let init: Vec<f32> = p.init.iter().copied().cycle().take(len).collect();
            // A texture is resampled to a texture parameter's size, and to one texel (its
            // mean) for a constant one.
            let per_texel = match &p.reference {
                Reference::Constant(v) => v.clone(),
                Reference::Texture(t) => {
                    let [w, h] = p.shape.texture_size().unwrap_or([1, 1]);
                    t.image.resample(p.shape.channels(), w, h)
                }
                Reference::Grid(v) => crate::scene::media::resample(v, p.shape),
            };
            let reference = per_texel.iter().copied().cycle().take(len).collect();
            layout.slots.push(ParamSlot {
                name: p.name.clone(),
                target: p.target,
                shape: p.shape,
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

    /// Every slot's values in θ with its target, for writing the scene back.
    pub fn recovered(&self, theta: &[f32]) -> Vec<(ParamTarget, ParamValue)> {
        self.slots.iter().map(|s| (s.target, s.value(theta))).collect()
    }

    /// Every slot's values in θ by name, in the scene's order.
    pub fn values(&self, theta: &[f32]) -> Vec<(String, ParamValue)> {
        self.slots.iter().map(|s| (s.name.clone(), s.value(theta))).collect()
    }

    /// The slot named `name`.
    pub fn named(&self, name: &str) -> Option<&ParamSlot> {
        self.slots.iter().find(|s| s.name == name)
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
