//! vkinverse: inverse path tracing on any Vulkan device.
//!
//! Layers, bottom up: [`gpu`] (the only place raw Vulkan appears), [`ops`] (buffer
//! kernels: fill, copy, reductions), [`scene`] and [`image`] (loading and validating
//! input, writing output atomically), [`optim`] (the optimisers' reference and host
//! side), [`npy`], the commands' drivers ([`optimise`], [`compare`], [`batch`], with
//! [`overrides`] for settings given outside the scene), and the command line in `main.rs`.

pub mod batch;
pub mod bench;
pub mod bsdf;
pub mod bvh;
pub mod compare;
pub mod error;
pub mod gpu;
pub mod gradcheck;
pub mod image;
pub mod npy;
pub mod ops;
pub mod optim;
pub mod optimise;
pub mod overrides;
pub mod render;
pub mod report;
pub mod scene;
pub mod shared;
pub mod stats;
