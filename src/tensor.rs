//! A parameter's shape and values: 0 to 3 dimensions of texels (none for a constant, two for
//! a texture, three for a grid), times its channels.
//!
//! Everything that holds a parameter goes through these types, whatever its shape: θ's
//! slots on the device, the optimiser passes (which see floats), checkpoints, the run's
//! `params/NAME.npy` and the recovered scene. A new shape is a new [`Shape`], not a new path.

use std::fmt;

/// Most voxels along one axis of a grid (a medium's density or emission).
pub const MAX_GRID_SIDE: u32 = 1024;
/// Most voxels a grid may hold (before its channels).
pub const MAX_GRID_VOXELS: usize = 1 << 24;

/// Texels along up to three axes (outermost first: depth, height, width), times `channels`
/// floats per texel, stored row-major with the channels innermost.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Shape {
    dims: [u32; 3],
    ndim: u8,
    channels: u32,
}

impl Shape {
    /// One value of `channels` floats (a colour, a roughness).
    pub const fn constant(channels: u32) -> Shape {
        Shape { dims: [1; 3], ndim: 0, channels }
    }

    /// A texture of `width` × `height` texels (rows from the top).
    pub const fn texture(width: u32, height: u32, channels: u32) -> Shape {
        Shape { dims: [height, width, 1], ndim: 2, channels }
    }

    /// A grid of `width` × `height` × `depth` texels (slices of rows).
    pub const fn grid(width: u32, height: u32, depth: u32, channels: u32) -> Shape {
        Shape { dims: [depth, height, width], ndim: 3, channels }
    }

    /// The shape of `dims` texels (outermost first, at most 3) of `channels` floats.
    pub fn from_dims(dims: &[u32], channels: u32) -> Option<Shape> {
        match *dims {
            [] => Some(Shape::constant(channels)),
            [n] => Some(Shape { dims: [n, 1, 1], ndim: 1, channels }),
            [h, w] => Some(Shape::texture(w, h, channels)),
            [d, h, w] => Some(Shape::grid(w, h, d, channels)),
            _ => None,
        }
    }

    /// The texel axes, outermost first (empty for a constant).
    pub fn dims(&self) -> &[u32] {
        &self.dims[..self.ndim as usize]
    }

    pub fn ndim(&self) -> usize {
        self.ndim as usize
    }

    pub fn channels(&self) -> u32 {
        self.channels
    }

    /// Texels (1 for a constant).
    pub fn texels(&self) -> usize {
        self.dims().iter().map(|&d| d as usize).product()
    }

    /// Floats: texels × channels.
    pub fn len(&self) -> usize {
        self.texels() * self.channels as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn is_constant(&self) -> bool {
        self.ndim == 0
    }

    /// Width and height of a 2-D shape (a texture), else None.
    pub fn texture_size(&self) -> Option<[u32; 2]> {
        (self.ndim == 2).then_some([self.dims[1], self.dims[0]])
    }

    /// The array shape of the values: the texel axes, then the channels (`[channels]` for a
    /// constant), as `params/NAME.npy` and Python's arrays have it.
    pub fn array(&self) -> Vec<usize> {
        self.dims().iter().map(|&d| d as usize).chain(std::iter::once(self.channels as usize)).collect()
    }

    /// The shape whose [`Self::array`] is `array`: at least the channel axis, at most three
    /// texel axes before it.
    pub fn from_array(array: &[usize]) -> Option<Shape> {
        let (&channels, dims) = array.split_last()?;
        let dims: Vec<u32> = dims.iter().map(|&d| u32::try_from(d).ok()).collect::<Option<_>>()?;
        Shape::from_dims(&dims, u32::try_from(channels).ok()?)
    }
}

impl fmt::Debug for Shape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{self}")
    }
}

/// `[3]`, `[64, 64, 3]`, `[32, 32, 32, 1]`: the array shape.
impl fmt::Display for Shape {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let axes: Vec<String> = self.array().iter().map(usize::to_string).collect();
        write!(f, "[{}]", axes.join(", "))
    }
}

/// A parameter's values with their shape.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamValue {
    pub shape: Shape,
    /// `shape.len()` floats, row-major with the channels innermost.
    pub data: Vec<f32>,
}

impl ParamValue {
    /// `data` as a value of `shape`, or None if the lengths differ.
    pub fn new(shape: Shape, data: Vec<f32>) -> Option<ParamValue> {
        (data.len() == shape.len()).then_some(ParamValue { shape, data })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_of_every_rank_agree_with_their_arrays() {
        let cases = [
            (Shape::constant(3), vec![3], 3),
            (Shape::from_dims(&[5], 1).unwrap(), vec![5, 1], 5),
            (Shape::texture(4, 2, 3), vec![2, 4, 3], 24),
            (Shape::grid(4, 3, 2, 1), vec![2, 3, 4, 1], 24),
        ];
        for (shape, array, len) in cases {
            assert_eq!(shape.array(), array, "{shape}");
            assert_eq!(shape.len(), len, "{shape}");
            assert_eq!(Shape::from_array(&array), Some(shape), "{shape}");
            assert_eq!(Shape::from_dims(shape.dims(), shape.channels()), Some(shape));
        }
        assert_eq!(Shape::texture(4, 2, 3).texture_size(), Some([4, 2]));
        assert_eq!(Shape::grid(4, 3, 2, 1).texture_size(), None);
        assert_eq!(Shape::from_array(&[1, 2, 3, 4, 5]), None, "four texel axes");
        assert_eq!(Shape::from_array(&[]), None, "no channel axis");
        assert_eq!(Shape::grid(4, 3, 2, 1).to_string(), "[2, 3, 4, 1]");
        assert!(ParamValue::new(Shape::constant(3), vec![0.0; 2]).is_none());
    }
}
