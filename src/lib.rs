//! vkinverse: inverse path tracing on any Vulkan device.
