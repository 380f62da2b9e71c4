//! vkinverse: inverse path tracing on any Vulkan device.
//!
//! Layers, bottom up: [`gpu`] (the only place raw Vulkan appears), [`ops`] (buffer
//! kernels: fill, copy, reductions), and the command line in `main.rs`.

pub mod gpu;
pub mod ops;
pub mod shared;
pub mod bench;
pub mod report;
