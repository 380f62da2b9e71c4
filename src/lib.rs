//! vkinverse: inverse path tracing on any Vulkan device.
//!
//! It recovers scene parameters (material colours, roughness, metalness, emission,
//! textures) from target images by gradient descent on Monte Carlo gradients, with Adam or
//! the gradient meta-estimator of Bálint et al. (SIGGRAPH Asia 2023).
//!
//! # The API
//! - [`Device`]: a Vulkan device, chosen and configured by a [`Config`] (the command line
//!   fills one from the environment: [`Config::from_env`]).
//! - [`Scene`]: a scene loaded from TOML, glTF or Mitsuba XML ([`Scene::load`]), or built in
//!   code from the types of [`scene`]. Its optimised parameters are its
//!   `[[optimise.params]]`, named by their targets (`materials.wall.base_color`).
//! - [`Renderer`]: a scene on a device. It reads and sets parameters by name
//!   ([`Renderer::param`], [`Renderer::set_param`]; values are [`ParamValue`]s of any
//!   [`Shape`]), renders a sensor to an f32 [`Image`] ([`Renderer::render`]), and gives every
//!   parameter's gradient for an image-space adjoint dL/dImage ([`Renderer::gradient`], what
//!   a loss of your own needs) or for a built-in [`Loss`] ([`Renderer::loss_gradient`]).
//! - [`optimise`]: a whole optimisation with an optimiser [`Spec`] and run [`Settings`],
//!   optionally into a run directory ([`RunOptions`]); an [`Observer`] hears every
//!   iteration's [`LogRow`] and [`Diagnostics`] and can stop the run; a [`Cancel`] token
//!   stops it from elsewhere.
//! - The command line's other tools, as functions: [`compare`](mod@compare), [`batch`],
//!   [`bench`](mod@bench), [`gradcheck`](mod@gradcheck) and [`replay`](mod@replay).
//!
//! Errors are [`Error`]s, each one line with its cause ([`error::one_line`]). The library
//! holds no process state: it reads no environment variable, installs no signal handler and
//! prints nothing.
//!
//! ```
//! # fn main() -> vkinverse::Result<()> {
//! use vkinverse::{Config, Device, RenderOptions, Renderer, Scene};
//! let device = Device::new(&Config::from_env().0)?;
//! let scene = Scene::load("scenes/cornell/scene.toml")?;
//! let renderer = Renderer::new(&device, &scene)?;
//! let image = renderer.render(&RenderOptions { spp: 16, ..Default::default() })?;
//! assert!(image.data.iter().flatten().any(|&v| v > 0.0), "the box is lit");
//! # Ok(())
//! # }
//! ```
//!
//! # Layers
//! Bottom up: `gpu` (the only place raw Vulkan and `unsafe` appear), `shared`, `kernels` and
//! `constants` (what the host and the kernels share, checked against the reflected
//! SPIR-V); `ops` (buffer kernels) and `bvh`; [`scene`], [`image`] and [`npy`] (input and
//! output); `bsdf` (the material model's CPU reference), `render` (the scene on the device,
//! the renderer, the gradient passes, the targets) and `optim` (the optimisers); [`settings`];
//! `engine` (an iteration's passes), [`preview`] (the result pictures) and `rundir` (the
//! run directory); [`run`] and the tools. The internal modules are public with the
//! `internals` feature, for vkinverse's own tests.

/// Declares modules that are public with the `internals` feature (vkinverse's own test
/// suite turns it on) and crate-private otherwise.
macro_rules! internal_modules {
    ($($(#[$meta:meta])* $name:ident;)*) => {
        $(
            $(#[$meta])*
            #[cfg(feature = "internals")]
            pub mod $name;
            $(#[$meta])*
            #[cfg(not(feature = "internals"))]
            #[allow(dead_code, unreachable_pub, unused_imports)]
            pub(crate) mod $name;
        )*
    };
}

internal_modules! {
    bsdf;
    bvh;
    constants;
    engine;
    files;
    /// Fuzz targets for every input format.
    fuzz;
    gpu;
    kernels;
    ops;
    optim;
    render;
    report;
    rundir;
    shared;
    stats;
}

pub mod batch;
pub mod bench;
pub mod compare;
pub mod config;
pub mod error;
pub mod gradcheck;
pub mod image;
pub mod npy;
pub mod preview;
pub mod replay;
pub mod run;
pub mod scene;
pub mod settings;
pub mod vol;

mod cancel;
mod coarse;
mod device;
mod observer;
mod renderer;
mod tensor;

pub use cancel::Cancel;
pub use config::Config;
pub use device::{Device, DeviceFeatures, DeviceInfo};
pub use error::{Error, Result};
/// The vector types of the scene model (positions, directions).
pub use glam;
pub use image::Image;
pub use observer::{LogRow, Observer};
pub use optim::spec::Spec;
pub use optim::{Diagnostics, HostGroup, HostOptimiser, HostStep};
pub use renderer::{ParamInfo, RenderOptions, Renderer};
pub use run::{optimise, Outcome, Run, RunOptions};
pub use rundir::Mode;
pub use scene::Scene;
pub use settings::{Loss, RunSettings, Settings};
pub use tensor::{ParamValue, Shape};

/// The README's Rust examples, run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
