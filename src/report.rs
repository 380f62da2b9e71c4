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
    let _ = writeln!(s, "  max texel buffer elements  {}", d.max_texel_buffer_elements);
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
            "max_texel_buffer_elements": d.max_texel_buffer_elements,
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

/// One curve of an error-against-time plot.
pub struct Curve {
    pub name: String,
    /// (seconds, error) points; non-positive errors are skipped on the log axis.
    pub points: Vec<(f64, f64)>,
}

/// Registers a system sans-serif font for plot labels once; false if none is installed
/// (plots are then drawn without text).
fn register_font() -> bool {
    static FONT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *FONT.get_or_init(|| {
        let candidates = [
            "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/TTF/DejaVuSans.ttf",
            "/System/Library/Fonts/Supplemental/Arial.ttf",
            "C:\\Windows\\Fonts\\arial.ttf",
        ];
        candidates.iter().find_map(|p| std::fs::read(p).ok()).is_some_and(|bytes| {
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            plotters::style::register_font("sans-serif", plotters::style::FontStyle::Normal, bytes).is_ok()
        })
    })
}

/// Writes a PNG plot of `curves` (log-scale error against time), atomically.
pub fn plot_error_vs_time(path: &std::path::Path, title: &str, y_label: &str, curves: &[Curve]) -> Result<(), String> {
    use plotters::prelude::*;
    let text = register_font();
    let pts = curves.iter().flat_map(|c| c.points.iter().filter(|p| p.1 > 0.0 && p.1.is_finite()));
    let (mut tmax, mut ymin, mut ymax) = (0.0f64, f64::MAX, f64::MIN);
    for &(t, y) in pts {
        tmax = tmax.max(t);
        ymin = ymin.min(y);
        ymax = ymax.max(y);
    }
    if ymin > ymax {
        (ymin, ymax) = (1e-6, 1.0);
    }
    if ymax <= ymin * 1.0001 {
        ymax = ymin * 10.0;
    }
    let tmax = if tmax > 0.0 { tmax * 1.02 } else { 1.0 };
    // The axis spans at least a decade, from a power of ten, so that errors within one
    // decade still get labelled ticks.
    let ylo = 10f64.powf((ymin * 0.9).log10().floor()).min(ymax * 0.11);
    let (w, h) = (800u32, 500u32);
    let mut pixels = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mut builder = ChartBuilder::on(&root);
        builder.margin(15);
        if text {
            builder.caption(title, ("sans-serif", 22)).x_label_area_size(40).y_label_area_size(70);
        }
        let mut chart = builder
            .build_cartesian_2d(0.0..tmax, (ylo..ymax * 1.1).log_scale())
            .map_err(|e| e.to_string())?;
        let mut mesh = chart.configure_mesh();
        if text {
            mesh.x_desc("time (s)").y_desc(y_label).y_label_formatter(&|v| format!("{v:.1e}"));
        } else {
            mesh.disable_x_axis().disable_y_axis();
        }
        mesh.draw().map_err(|e| e.to_string())?;
        for (k, c) in curves.iter().enumerate() {
            let color = Palette99::pick(k).to_rgba();
            let series = LineSeries::new(c.points.iter().copied().filter(|p| p.1 > 0.0 && p.1.is_finite()), color.stroke_width(2));
            let drawn = chart.draw_series(series).map_err(|e| e.to_string())?;
            if text {
                drawn.label(c.name.clone()).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
            }
        }
        if text {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| e.to_string())?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    let mut png_bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut png_bytes, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(|e| e.to_string())?;
        writer.write_image_data(&pixels).map_err(|e| e.to_string())?;
    }
    crate::image::write_bytes_atomic(path, &png_bytes).map_err(|e| format!("{}: {e}", path.display()))
}

/// Writes `curves` as `label,time_s,error` rows to `csv_path` and plots them (log-scale
/// error against time) to `png_path`, each file atomically.
pub fn write_curves(csv_path: &std::path::Path, png_path: &std::path::Path, title: &str, y_label: &str, curves: &[Curve]) -> Result<(), String> {
    use std::fmt::Write as _;
    let mut csv = String::from("label,time_s,error\n");
    for c in curves {
        for (t, e) in &c.points {
            let _ = writeln!(csv, "{},{t},{e}", csv_field(&c.name));
        }
    }
    crate::image::write_bytes_atomic(csv_path, csv.as_bytes()).map_err(|e| format!("{}: {e}", csv_path.display()))?;
    plot_error_vs_time(png_path, title, y_label, curves)
}

/// `text` as one CSV field (RFC 4180): quoted, with quotes doubled, when it holds a comma,
/// a quote or a line break, so that error messages keep a table's columns aligned.
pub fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}
