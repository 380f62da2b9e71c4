//! Test harness: every GPU test runs on a context with the validation layer and
//! synchronization validation on; any validation message, or any allocation still alive
//! at the end, fails the test.
#![allow(dead_code)]

pub mod binary;
pub mod pictures;
pub mod scenes;

use std::sync::Arc;
use vkinverse::gpu::{Context, ContextOptions};

/// A validating context (lavapipe in CI; whatever device `VKINVERSE_TEST_DEVICE` names).
/// With `VKINVERSE_UNMAPPABLE_DEVICE_MEMORY=1` in the environment its device buffers are
/// never mapped (the staging path of a discrete GPU; CI runs the suite once so).
pub fn context() -> Arc<Context> {
    context_with(options())
}

/// The options of [`context`]: validation on, the device `VKINVERSE_TEST_DEVICE` names, and
/// device memory never mapped with `VKINVERSE_UNMAPPABLE_DEVICE_MEMORY=1` (the tests read
/// the environment; the library does not).
pub fn options() -> ContextOptions {
    ContextOptions {
        device: std::env::var("VKINVERSE_TEST_DEVICE").ok(),
        validation: true,
        unmappable_device_memory: std::env::var("VKINVERSE_UNMAPPABLE_DEVICE_MEMORY").is_ok_and(|v| v == "1"),
        ..Default::default()
    }
}

fn context_with(options: ContextOptions) -> Arc<Context> {
    Context::new(&options).expect("Vulkan context with validation (needs mesa-vulkan-drivers and vulkan-validationlayers)")
}

/// The library's device over a test context, with the default configuration.
pub fn device(ctx: &Arc<Context>) -> vkinverse::Device {
    vkinverse::Device::from_context(ctx.clone(), vkinverse::Config::default())
}

/// Runs `f` on a fresh validating context, then checks that the validation layer said
/// nothing and that `f` freed every allocation.
pub fn with_gpu<R>(f: impl FnOnce(&Arc<Context>) -> R) -> R {
    with_gpu_options(options(), f)
}

/// [`with_gpu`] on a context made with `options` (which should keep validation on).
pub fn with_gpu_options<R>(options: ContextOptions, f: impl FnOnce(&Arc<Context>) -> R) -> R {
    let ctx = context_with(options);
    let r = f(&ctx);
    ctx.wait_idle().expect("wait idle");
    let messages = ctx.take_validation_messages();
    assert!(messages.is_empty(), "validation messages:\n{}", messages.join("\n"));
    let live = ctx.live_allocations();
    assert!(live.is_empty(), "allocations leaked: {live:?}");
    r
}

/// Asserts that kernel `kernel` declares struct `name` with exactly the members `rust`
/// (name, byte offset of the Rust mirror's field), in order, and `size` bytes: the host and
/// GPU layouts agree.
pub fn check_layout(kernel: &str, name: &str, rust: &[(&str, usize)], size: usize) {
    let spirv = vkinverse::gpu::shaders::get(kernel).unwrap_or_else(|| panic!("no kernel {kernel}"));
    let r = vkinverse::gpu::reflect::Reflection::new(kernel, spirv).unwrap();
    let layout = r.struct_layout(name).unwrap_or_else(|| panic!("{name} not reflected in {kernel}"));
    let got: Vec<(&str, usize)> = layout.iter().map(|(n, o)| (n.as_str(), *o)).collect();
    assert_eq!(got, rust, "{name} in {kernel}: members and offsets");
    assert_eq!(r.struct_size(name), Some(size), "{name} in {kernel}: size");
}

/// A Radiance HDR (RGBE) file of `image`, scanlines stored flat (not run-length encoded),
/// as Walter's rgbe.c writes them: the largest component's binary exponent shared, each
/// mantissa truncated to 8 bits, so that components k·2^(e−8) with e the exponent of the
/// largest are stored exactly.
pub fn radiance_hdr(image: &vkinverse::image::Image) -> Vec<u8> {
    let mut out = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {} +X {}\n", image.height, image.width).into_bytes();
    for px in &image.data {
        let v = px[0].max(px[1]).max(px[2]);
        if v < 1e-32 {
            out.extend([0; 4]);
            continue;
        }
        // v = m·2^e with m in [0.5, 1).
        let e = v.log2().floor() as i32 + 1;
        let scale = 256.0 / 2f32.powi(e);
        out.extend(px.map(|c| (c * scale) as u8));
        out.push((e + 128) as u8);
    }
    out
}
