//! The material data: every constant and texture the kernels look up (material values,
//! emission, lights, the environment), in one float array that follows θ in its buffer.
//! A value is referred to by a [`ValueRef`]; an optimised one refers to its slot of θ
//! instead.

use crate::image::Image;
use crate::render::ParamSlot;
use crate::scene::{ColorValue, Filter, ScalarValue, Texture, Wrap};
use crate::shared::ValueRef;
use std::sync::Arc;

/// The [`ValueRef`] flags of texture `t`'s filter, wrap modes (u, v) and coordinate set.
pub fn sampler_flags(t: &Texture) -> u32 {
    let code = |w: Wrap| match w {
        Wrap::Repeat => 0,
        Wrap::Clamp => 1,
        Wrap::Mirror => 2,
    };
    let filter = match t.filter {
        Filter::Bilinear => 0,
        Filter::Nearest => ValueRef::NEAREST,
    };
    let set = if t.uv_set == 1 { ValueRef::UV1 } else { 0 };
    filter | code(t.wrap[0]) << 2 | code(t.wrap[1]) << 4 | set
}

/// The material data being built.
#[derive(Default)]
pub struct MaterialData {
    pub data: Vec<f32>,
    /// The textures stored, their floats in `data`, and the largest one's (width, height):
    /// what an error names when the data do not fit the device.
    pub textures: usize,
    pub texture_floats: usize,
    pub largest_texture: (u32, u32),
    /// Textures stored already, by the address of their image, their channels and sampler
    /// flags (one shared image: several meshes' emission texture).
    stored: Vec<((*const Image, usize, u32), ValueRef)>,
}

impl MaterialData {
    /// Appends a constant and returns its reference.
    pub fn constant(&mut self, values: &[f32]) -> ValueRef {
        let offset = self.data.len() as i32;
        self.data.extend_from_slice(values);
        ValueRef { offset, width: 0, height: 0, flags: 0 }
    }

    /// Appends the first `channels` channels of every texel of `img`, with sampler flags
    /// `sampler` ([`sampler_flags`]), and returns its reference.
    pub fn texture(&mut self, img: &Image, channels: usize, sampler: u32) -> ValueRef {
        let offset = self.data.len() as i32;
        for px in &img.data {
            self.data.extend_from_slice(&px[..channels]);
        }
        self.textures += 1;
        self.texture_floats += img.data.len() * channels;
        if u64::from(img.width) * u64::from(img.height) > u64::from(self.largest_texture.0) * u64::from(self.largest_texture.1) {
            self.largest_texture = (img.width, img.height);
        }
        ValueRef { offset, width: img.width, height: img.height, flags: sampler }
    }

    /// A colour value's reference; a texture already stored is referred to again.
    pub fn color(&mut self, v: &ColorValue) -> ValueRef {
        match v {
            ColorValue::Constant(c) => self.constant(c),
            ColorValue::Texture(t) => self.shared_texture(&t.image, 3, sampler_flags(t)),
        }
    }

    /// A scalar value's reference (a texture's R channel).
    pub fn scalar(&mut self, v: &ScalarValue) -> ValueRef {
        match v {
            ScalarValue::Constant(c) => self.constant(&[*c]),
            ScalarValue::Texture(t) => self.texture(&t.image, 1, sampler_flags(t)),
        }
    }

    fn shared_texture(&mut self, img: &Arc<Image>, channels: usize, sampler: u32) -> ValueRef {
        let key = (Arc::as_ptr(img), channels, sampler);
        if let Some((_, r)) = self.stored.iter().find(|(k, _)| *k == key) {
            return *r;
        }
        let r = self.texture(img, channels, sampler);
        self.stored.push((key, r));
        r
    }

}

/// The reference to parameter slot `slot` where one optimises a value, else `value` (the
/// scene's). A texture slot keeps the filter and wrap modes of the scene's value.
pub fn optimised(slot: Option<&ParamSlot>, value: ValueRef) -> ValueRef {
    let Some(slot) = slot else { return value };
    let [width, height] = slot.shape.texture_size().unwrap_or([0, 0]);
    ValueRef { offset: slot.offset as i32, width, height, flags: ValueRef::IN_THETA | value.flags & ValueRef::SAMPLER }
}

/// Whether any of `refs` is a texture: the kernels look textures up only where one is
/// (`HAS_TEXTURES`).
pub fn any_texture(refs: impl IntoIterator<Item = ValueRef>) -> bool {
    refs.into_iter().any(|r| r.width != 0)
}
