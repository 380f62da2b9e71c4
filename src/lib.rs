//! vkinverse: inverse path tracing on any Vulkan device.
//!
//! Layers, bottom up: [`gpu`] (the only place raw Vulkan appears), [`ops`] (buffer
//! kernels: fill, copy, reductions), [`scene`] and [`image`] (loading and validating
//! input, writing output atomically), [`optim`] (the optimisers' reference and host
//! side), [`npy`], and the command line in `main.rs`.

pub mod bench;
pub mod bsdf;
pub mod bvh;
pub mod error;
pub mod gpu;
pub mod gradcheck;
pub mod image;
pub mod npy;
pub mod ops;
pub mod optim;
pub mod optimise;
pub mod render;
pub mod report;
pub mod scene;
pub mod shared;
