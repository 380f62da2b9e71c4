//! A Vulkan device chosen by a [`Config`], and the configuration the work on it follows.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::gpu::Context;
use std::fmt::Write as _;
use std::sync::Arc;

pub use crate::gpu::{DeviceFeatures, DeviceInfo};

/// A Vulkan device and its compute queue, with the [`Config`] it was made with. Cheap to
/// clone (clones share the device); the device is released when the last clone, and
/// everything made on it, is gone.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// let device = vkinverse::Device::new(&vkinverse::Config::from_env().0)?;
/// println!("rendering on {}", device.info().name);
/// assert!(device.devices().iter().any(|d| d.name == device.info().name));
/// # Ok(())
/// # }
/// ```
#[derive(Clone)]
pub struct Device {
    ctx: Arc<Context>,
    config: Config,
}

impl Device {
    /// Opens the device `config` names (the best one when it names none) and checks that
    /// it has every feature vkinverse needs.
    pub fn new(config: &Config) -> Result<Device> {
        let ctx = Context::new(&config.context_options())?;
        Ok(Device { ctx, config: config.clone() })
    }

    /// A device over a context the GPU layer made (vkinverse's own tests).
    #[cfg(feature = "internals")]
    pub fn from_context(ctx: Arc<Context>, config: Config) -> Device {
        Device { ctx, config }
    }

    /// The chosen device: name, type, driver, limits and features.
    pub fn info(&self) -> &DeviceInfo {
        self.ctx.info()
    }

    /// Every device the Vulkan loader reported, chosen or not.
    pub fn devices(&self) -> &[DeviceInfo] {
        self.ctx.devices()
    }

    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Whether the validation layer is on.
    pub fn validation(&self) -> bool {
        self.ctx.validation_enabled()
    }

    pub(crate) fn ctx(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// Fails with the validation layer's messages if it reported any since the last call
    /// (nothing to do without validation): every public operation ends with this check.
    pub(crate) fn validated<T>(&self, value: T) -> Result<T> {
        if !self.ctx.validation_enabled() {
            return Ok(value);
        }
        let messages = self.ctx.take_validation_messages();
        match messages.first() {
            None => Ok(value),
            Some(first) => Err(Error::Validation { count: messages.len(), first: first.clone() }),
        }
    }
}

impl Device {
    /// `vkinverse info` as text: every device, the chosen one marked, its limits and features.
    pub fn info_text(&self) -> String {
        let ctx = &self.ctx;
        let mut s = String::new();
        let chosen = ctx.info().index;
        let _ = writeln!(s, "Vulkan devices:");
        for d in ctx.devices() {
            let mark = if d.index == chosen { "*" } else { " " };
            let _ = writeln!(s, " {mark} [{}] {} ({}, Vulkan {}, {})", d.index, d.name, d.device_type, d.api_version, d.driver.trim());
        }
        let d = ctx.info();
        let _ = writeln!(s, "chosen device: [{}] {}", d.index, d.name);
        let _ = writeln!(s, "limits:");
        let _ = writeln!(s, "  max storage buffer range   {} bytes", d.max_storage_buffer_range);
        let _ = writeln!(s, "  max texel buffer elements  {}", d.max_texel_buffer_elements);
        let _ = writeln!(s, "  max workgroup invocations  {}", d.max_workgroup_invocations);
        let _ = writeln!(s, "  max workgroup count        {:?}", d.max_workgroup_count);
        let _ = writeln!(s, "  subgroup size              {}", d.subgroup_size);
        let _ = writeln!(s, "  timestamp period           {} ns", d.timestamp_period_ns);
        let _ = writeln!(s, "  device-local heap          {:.1} GiB", d.device_local_heap_bytes as f64 / (1u64 << 30) as f64);
        let l = d.descriptor_limits;
        let _ = writeln!(
            s,
            "  per-stage descriptors      {} storage buffers, {} storage images, {} sampled images, {} in all",
            l.storage_buffers, l.storage_images, l.sampled_images, l.resources
        );
        let _ = writeln!(s, "features used by vkinverse:");
        for (name, has) in d.features.list() {
            let _ = writeln!(s, "  {:<58} {}", name, if has { "yes" } else { "MISSING" });
        }
        let _ = writeln!(s, "validation layer: {}", if ctx.validation_enabled() { "on" } else { "off" });
        s
    }

    /// `vkinverse info --json`.
    pub fn info_json(&self) -> String {
        let ctx = &self.ctx;
        let device = |d: &crate::gpu::DeviceInfo| {
            serde_json::json!({
                "index": d.index,
                "name": d.name,
                "type": d.device_type,
                "api_version": d.api_version,
                "driver": d.driver.trim(),
                "max_storage_buffer_range": d.max_storage_buffer_range,
                "max_texel_buffer_elements": d.max_texel_buffer_elements,
                "max_workgroup_invocations": d.max_workgroup_invocations,
                "max_workgroup_count": d.max_workgroup_count,
                "subgroup_size": d.subgroup_size,
                "timestamp_period_ns": d.timestamp_period_ns,
                "device_local_heap_bytes": d.device_local_heap_bytes,
                "max_per_stage_descriptors": {
                    "storage_buffers": d.descriptor_limits.storage_buffers,
                    "storage_images": d.descriptor_limits.storage_images,
                    "sampled_images": d.descriptor_limits.sampled_images,
                    "resources": d.descriptor_limits.resources,
                },
                "features": d.features.list().iter().map(|(n, h)| (n.to_string(), *h)).collect::<std::collections::BTreeMap<_, _>>(),
            })
        };
        let v = serde_json::json!({
            "devices": ctx.devices().iter().map(device).collect::<Vec<_>>(),
            "chosen": ctx.info().index,
            "validation": ctx.validation_enabled(),
        });
        serde_json::to_string_pretty(&v).unwrap_or_default()
    }
}

impl std::fmt::Debug for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Device").field("name", &self.info().name).field("config", &self.config).finish()
    }
}
