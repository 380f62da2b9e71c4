//! Text and JSON reports for the command line.

use crate::gpu::Context;
use std::fmt::Write as _;

/// `vkinverse info` as text: every device, the chosen one marked, its limits and features.
pub fn info_text(ctx: &Context) -> String {
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
    let _ = writeln!(s, "  max workgroup invocations  {}", d.max_workgroup_invocations);
    let _ = writeln!(s, "  max workgroup count        {:?}", d.max_workgroup_count);
    let _ = writeln!(s, "  subgroup size              {}", d.subgroup_size);
    let _ = writeln!(s, "  timestamp period           {} ns", d.timestamp_period_ns);
    let _ = writeln!(s, "  device-local heap          {:.1} GiB", d.device_local_heap_bytes as f64 / (1u64 << 30) as f64);
    let _ = writeln!(s, "features used by vkinverse:");
    for (name, has) in d.features.list() {
        let _ = writeln!(s, "  {:<58} {}", name, if has { "yes" } else { "MISSING" });
    }
    let _ = writeln!(s, "validation layer: {}", if ctx.validation_enabled() { "on" } else { "off" });
    s
}

/// `vkinverse info --json`.
pub fn info_json(ctx: &Context) -> String {
    let device = |d: &crate::gpu::DeviceInfo| {
        serde_json::json!({
            "index": d.index,
            "name": d.name,
            "type": d.device_type,
            "api_version": d.api_version,
            "driver": d.driver.trim(),
            "max_storage_buffer_range": d.max_storage_buffer_range,
            "max_workgroup_invocations": d.max_workgroup_invocations,
            "max_workgroup_count": d.max_workgroup_count,
            "subgroup_size": d.subgroup_size,
            "timestamp_period_ns": d.timestamp_period_ns,
            "device_local_heap_bytes": d.device_local_heap_bytes,
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
