//! The Vulkan compute layer: the only home of raw `ash` calls and `unsafe` in vkinverse.
//!
//! Everything above this module speaks in named buffers, reflected pipelines, recorded
//! command buffers and named profiler scopes:
//! - [`Context`]: instance, device, one compute queue, the allocator; every other object
//!   holds an `Arc<Context>`, so the device is destroyed last.
//! - [`Buffer`]: a named allocation freed on drop.
//! - [`ComputePipeline`]: built from SPIR-V whose bindings, push-constant size and
//!   workgroup size are reflected, bound by GLSL name into a [`BindGroup`].
//! - [`CommandBuffer`] / [`Recorder`]: recorded once, submitted many times; every buffer
//!   access is tracked and the barriers it needs are derived from its previous use.
//! - [`Profiler`]: named timestamp scopes, one per pass.

mod buffer;
mod commands;
mod context;
mod pipeline;
mod profiler;
pub mod reflect;
mod staging;
mod sync;
mod transfers;

pub use buffer::{Buffer, MemoryKind};
pub use commands::{CommandBuffer, Recorder};
pub use context::{check_features, Context, ContextOptions, DescriptorLimits, DeviceFeatures, DeviceInfo};
pub use pipeline::{check_descriptor_limits, texel_padded, BindGroup, ComputePipeline, SpecValue, TEXEL_BYTES};
pub use profiler::{Profiler, ScopeTime};
pub use staging::STAGING_BYTES;
pub use transfers::TransferStats;
pub use sync::Access;

use ash::vk;

/// Embedded SPIR-V kernels compiled by build.rs from `glsl/*.comp`.
pub mod shaders {
    include!(concat!(env!("OUT_DIR"), "/shaders.rs"));

    /// The SPIR-V of kernel `name` (file stem or declared variant).
    pub fn get(name: &str) -> Option<&'static [u8]> {
        KERNELS.iter().find(|(n, _)| *n == name).map(|(_, s)| *s)
    }
}

/// A kernel's push-constant block mirrored in Rust: a `#[repr(C)]` Pod struct whose
/// members (names and byte offsets, from `offset_of!`) are those of the GLSL block, in
/// order. Every dispatch checks them against the kernel's reflected block
/// ([`ComputePipeline::check_push`]), so a drift on either side is an error naming the
/// kernel rather than garbage pushed. Implement it with [`push_block!`]; `()` is the empty
/// block of a kernel without push constants.
pub trait PushBlock: bytemuck::Pod {
    const MEMBERS: &'static [(&'static str, usize)];
}

impl PushBlock for () {
    const MEMBERS: &'static [(&'static str, usize)] = &[];
}

/// Implements [`PushBlock`] for a `#[repr(C)]` struct from its field names, in order:
/// `push_block!(TracePush { width, height, ... });`.
macro_rules! push_block {
    ($ty:ty { $($field:ident),* $(,)? }) => {
        impl $crate::gpu::PushBlock for $ty {
            const MEMBERS: &'static [(&'static str, usize)] = &[$((stringify!($field), std::mem::offset_of!($ty, $field))),*];
        }
    };
}
pub(crate) use push_block;

/// Errors of the GPU layer. Vulkan failures keep their `vk::Result`.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error("cannot load the Vulkan library: {0} (install libvulkan1 and a driver, e.g. mesa-vulkan-drivers)")]
    Loader(String),
    #[error("{what} failed: {result}")]
    Vk { what: &'static str, result: vk::Result },
    #[error("no Vulkan device found (install a driver, e.g. mesa-vulkan-drivers for lavapipe)")]
    NoDevice,
    #[error(
        "no Vulkan driver could be loaded (vkCreateInstance: {0}): install one (mesa-vulkan-drivers for lavapipe, or the GPU's), \
         check VK_DRIVER_FILES and VK_ICD_FILENAMES if set, and that the driver's own libraries load \
         (NVIDIA's needs libglvnd0); VK_LOADER_DEBUG=error says which"
    )]
    NoDriver(vk::Result),
    #[error("no Vulkan device matches '{0}' (see `vkinverse info`)")]
    DeviceNotFound(String),
    #[error("device '{device}' lacks required feature {feature}")]
    MissingFeature { device: String, feature: &'static str },
    #[error("validation layer VK_LAYER_KHRONOS_validation requested but not installed (package vulkan-validationlayers)")]
    NoValidationLayer,
    #[error("GPU memory allocation for '{name}' failed: {source}")]
    Alloc { name: String, source: gpu_allocator::AllocationError },
    #[error("buffer '{name}': {size} bytes exceeds the device's {limit} of {max} bytes")]
    BufferTooLarge { name: String, size: u64, max: u64, limit: &'static str },
    #[error("buffer '{name}': {what}")]
    BufferAccess { name: String, what: String },
    #[error("kernel '{0}' is not among the compiled shaders")]
    UnknownKernel(String),
    #[error("reflection of kernel '{kernel}': {msg}")]
    Reflect { kernel: String, msg: String },
    #[error("kernel '{kernel}' uses {count} {what}, more than the {max} per shader stage that device '{device}' allows ({limit})")]
    TooManyDescriptors { kernel: String, device: String, what: &'static str, count: u32, max: u32, limit: &'static str },
    #[error("kernel '{kernel}' has no binding named '{name}' (it has: {known})")]
    UnknownBinding { kernel: String, name: String, known: String },
    #[error("kernel '{kernel}': binding '{name}' was not bound")]
    UnboundBinding { kernel: String, name: String },
    #[error("kernel '{kernel}' has no specialization constant named '{name}'")]
    UnknownSpecConstant { kernel: String, name: String },
    #[error("kernel '{kernel}': specialization constant '{name}' is {expected}, got {got}")]
    SpecConstantType { kernel: String, name: String, expected: String, got: &'static str },
    #[error("kernel '{kernel}' takes {expected} bytes of push constants, got {got}")]
    PushConstantSize { kernel: String, expected: u32, got: usize },
    #[error("kernel '{kernel}': push block members {reflected} do not match the host's {host}")]
    PushLayout { kernel: String, reflected: String, host: String },
    #[error("hazard in '{pass}': buffer '{buffer}' accessed as {now:?} after {previous:?} within one unordered batch")]
    Hazard { pass: String, buffer: String, previous: Access, now: Access },
    #[error("barrier on buffer '{buffer}' declares previous access {declared:?}, but the last access was {actual:?}")]
    BarrierMismatch { buffer: String, declared: Access, actual: Access },
    #[error("kernel '{kernel}': {groups} workgroups along one axis exceed the device limit of {max}")]
    DispatchTooLarge { kernel: String, groups: u64, max: u32 },
    #[error("profiler: {0}")]
    Profiler(String),
    #[error("GPU work did not finish within {0} ms (device hung or too much work per submission)")]
    Timeout(u64),
    #[error("the Vulkan device was lost")]
    DeviceLost,
    /// A scene the kernels cannot render in the configuration asked for.
    #[error("{0}")]
    Unsupported(String),
}

/// Result of the GPU layer.
pub type Result<T> = std::result::Result<T, GpuError>;

/// Wraps a `vk::Result` with the name of the call that returned it.
pub(crate) fn vk_err(what: &'static str) -> impl FnOnce(vk::Result) -> GpuError {
    move |result| match result {
        vk::Result::ERROR_DEVICE_LOST => GpuError::DeviceLost,
        result => GpuError::Vk { what, result },
    }
}
