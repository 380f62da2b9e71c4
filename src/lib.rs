//! vkinverse: inverse path tracing on any Vulkan device.

pub mod image;
pub mod scene;
