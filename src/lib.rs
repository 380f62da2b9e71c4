//! vkinverse: inverse path tracing on any Vulkan device.
//!
//! Layers, bottom up: [`gpu`] (the only place raw Vulkan appears), [`ops`] (buffer
//! kernels: fill, copy, reductions), [`scene`] and [`image`] (loading and validating
//! input, writing output atomically), and the command line in `main.rs`.

pub mod bench;
pub mod bvh;
pub mod gpu;
pub mod image;
pub mod ops;
pub mod report;
pub mod scene;
pub mod shared;
