//! vkinverse: inverse path tracing on any Vulkan device.

pub mod npy;
pub mod optim;
