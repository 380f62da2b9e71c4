//! vkinverse: inverse path tracing on any Vulkan device.
//!
//! Layers, bottom up:
//! - [`gpu`]: the only place raw Vulkan and `unsafe` appear; [`shared`], [`push`] and
//!   [`constants`]: what the host and the kernels share (struct mirrors, push blocks,
//!   constants), checked against the reflected SPIR-V or generated into GLSL;
//! - [`ops`]: buffer kernels (fill, copy, reductions); [`bvh`]: the BVH for the GPU;
//! - [`scene`] and [`image`]: loading and validating input, writing output atomically;
//!   [`npy`]: float32 arrays;
//! - [`bsdf`]: the material model's CPU reference; [`render`]: the scene on the device, the
//!   renderer, the gradient passes and the targets; [`optim`]: the optimisers (CPU
//!   references, GPU passes, replay);
//! - [`settings`]: the run settings, one declaration for the command line, scene and job
//!   files; [`engine`]: the iteration's passes, built once for `optimise`, `bench` and
//!   `gradcheck`; [`rundir`]: the run directory's lock and checkpoints;
//! - the commands' drivers: [`optimise`], [`compare`], [`batch`], [`gradcheck`], [`bench`],
//!   with [`report`] for tables, plots and progress; the command line is `main.rs`.

pub mod batch;
pub mod bench;
pub mod bsdf;
pub mod bvh;
pub mod cancel;
pub mod compare;
pub mod config;
pub mod constants;
pub mod device;
pub mod engine;
pub mod error;
pub mod gpu;
pub mod gradcheck;
pub mod image;
pub mod npy;
pub mod observer;
pub mod ops;
pub mod optim;
pub mod optimise;
pub mod push;
pub mod render;
pub mod renderer;
pub mod replay;
pub mod report;
pub mod rundir;
pub mod scene;
pub mod settings;
pub mod shared;
pub mod stats;
pub mod tensor;

pub use cancel::Cancel;
pub use config::Config;
pub use device::Device;
pub use error::{Error, Result};
pub use image::Image;
pub use observer::{LogRow, Observer};
pub use optim::spec::Spec;
pub use optim::Diagnostics;
pub use optimise::{optimise, Outcome, Run, RunOptions};
pub use renderer::{ParamInfo, RenderOptions, Renderer};
pub use rundir::Mode;
pub use scene::Scene;
pub use settings::{Loss, RunSettings, Settings};
pub use tensor::{ParamValue, Shape};
