//! Text and JSON reports for the command line: device information, plots and CSV tables,
//! progress on stderr and warnings.

use crate::gpu::Context;
use std::fmt::Write as _;
use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

static QUIET: AtomicBool = AtomicBool::new(false);

/// Silences [`warn`] (the command line's `--quiet`).
pub fn set_quiet(quiet: bool) {
    QUIET.store(quiet, Ordering::Relaxed);
}

/// Prints `vkinverse: warning: MESSAGE` on stderr unless quiet.
pub fn warn(message: &str) {
    if !QUIET.load(Ordering::Relaxed) {
        eprintln!("vkinverse: warning: {message}");
    }
}

/// Prints `vkinverse: MESSAGE` on stderr unless quiet: what the run does about something the
/// user did.
pub fn notice(message: &str) {
    if !QUIET.load(Ordering::Relaxed) {
        eprintln!("vkinverse: {message}");
    }
}

/// Progress of a long task on stderr: a bar on a terminal; elsewhere (a log file, a batch
/// scheduler's output) one line every `VKINVERSE_PROGRESS_SECS` seconds (default 10), so
/// that a long render is not silent for minutes. Nothing with `quiet`.
pub struct ProgressReport {
    bar: Option<indicatif::ProgressBar>,
    lines: Option<(Duration, Instant)>,
    label: String,
    unit: String,
    start: Instant,
    total: u64,
}

impl ProgressReport {
    pub fn new(quiet: bool, label: &str, total: u64, unit: &str) -> Self {
        let terminal = std::io::stderr().is_terminal();
        let bar = (!quiet && terminal).then(|| {
            let bar = indicatif::ProgressBar::new(total);
            let template = format!("{{bar:40}} {{pos}}/{{len}} {unit} ({{elapsed}}, eta {{eta}}) {{msg}}");
            bar.set_style(indicatif::ProgressStyle::with_template(&template).unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()));
            bar
        });
        let every = std::env::var("VKINVERSE_PROGRESS_SECS").ok().and_then(|s| s.parse::<f64>().ok()).filter(|s| s.is_finite() && *s >= 0.0).unwrap_or(10.0);
        let lines = (!quiet && !terminal).then(|| (Duration::from_secs_f64(every), Instant::now()));
        ProgressReport { bar, lines, label: label.into(), unit: unit.into(), start: Instant::now(), total }
    }

    pub fn set_total(&mut self, total: u64) {
        self.total = total;
        if let Some(b) = &self.bar {
            b.set_length(total);
        }
    }

    /// Reports `position` of the total, with `message` (e.g. the current loss).
    pub fn set(&mut self, position: u64, message: &str) {
        if let Some(b) = &self.bar {
            b.set_position(position);
            b.set_message(message.to_string());
        }
        if let Some((every, last)) = &mut self.lines {
            if last.elapsed() >= *every {
                *last = Instant::now();
                let of = if self.total > 0 { format!("/{} ({:.0} %)", self.total, 100.0 * position as f64 / self.total as f64) } else { String::new() };
                let sep = if message.is_empty() { "" } else { "; " };
                eprintln!("{}: {position}{of} {} after {:.0} s{sep}{message}", self.label, self.unit, self.start.elapsed().as_secs_f64());
            }
        }
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

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
    plot_panels(path, title, "time (s)", &[Panel { y_label: y_label.to_string(), curves }], (800, 500))
}

/// One chart of a [`plot_panels`] figure: log-scale values against a shared x axis.
pub struct Panel<'a> {
    pub y_label: String,
    pub curves: &'a [Curve],
}

/// The log-scale y range of `curves` (positive finite values), spanning at least a decade
/// from a power of ten so that values within one decade still get labelled ticks, and the
/// x range.
fn chart_ranges(curves: &[Curve]) -> (f64, f64, f64) {
    let pts = curves.iter().flat_map(|c| c.points.iter().filter(|p| p.1 > 0.0 && p.1.is_finite()));
    let (mut xmax, mut ymin, mut ymax) = (0.0f64, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        xmax = xmax.max(x);
        ymin = ymin.min(y);
        ymax = ymax.max(y);
    }
    if ymin > ymax {
        (ymin, ymax) = (1e-6, 1.0);
    }
    if ymax <= ymin * 1.0001 {
        ymax = ymin * 10.0;
    }
    let xmax = if xmax > 0.0 { xmax * 1.02 } else { 1.0 };
    let ylo = 10f64.powf((ymin * 0.9).log10().floor()).min(ymax * 0.11);
    (xmax, ylo, ymax * 1.1)
}

/// Writes a PNG of `panels` stacked vertically (the title over the first), `size` pixels in
/// all, atomically.
pub fn plot_panels(path: &std::path::Path, title: &str, x_label: &str, panels: &[Panel], size: (u32, u32)) -> Result<(), String> {
    use plotters::prelude::*;
    let text = register_font();
    let (w, h) = size;
    let mut pixels = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let areas = root.split_evenly((panels.len().max(1), 1));
        for (k, (panel, area)) in panels.iter().zip(&areas).enumerate() {
            let (xmax, ylo, yhi) = chart_ranges(panel.curves);
            let mut builder = ChartBuilder::on(area);
            builder.margin(15);
            if text {
                if k == 0 {
                    builder.caption(title, ("sans-serif", 22));
                }
                builder.x_label_area_size(40).y_label_area_size(70);
            }
            let mut chart = builder.build_cartesian_2d(0.0..xmax, (ylo..yhi).log_scale()).map_err(|e| e.to_string())?;
            let mut mesh = chart.configure_mesh();
            if text {
                mesh.x_desc(x_label).y_desc(panel.y_label.as_str()).y_label_formatter(&|v| format!("{v:.1e}"));
            } else {
                mesh.disable_x_axis().disable_y_axis();
            }
            mesh.draw().map_err(|e| e.to_string())?;
            for (j, c) in panel.curves.iter().enumerate() {
                let color = Palette99::pick(j).to_rgba();
                let series = LineSeries::new(c.points.iter().copied().filter(|p| p.1 > 0.0 && p.1.is_finite()), color.stroke_width(2));
                let drawn = chart.draw_series(series).map_err(|e| e.to_string())?;
                if text {
                    drawn.label(c.name.clone()).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
                }
            }
            if text && !panel.curves.is_empty() {
                chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(|e| e.to_string())?;
            }
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
    let header = ["label", "time_s", "error"].map(String::from);
    let rows = curves.iter().flat_map(|c| c.points.iter().map(|(t, e)| vec![c.name.clone(), t.to_string(), e.to_string()]));
    let csv = csv_bytes(&header, rows)?;
    crate::image::write_bytes_atomic(csv_path, &csv).map_err(|e| format!("{}: {e}", csv_path.display()))?;
    plot_error_vs_time(png_path, title, y_label, curves)
}

/// A CSV table (RFC 4180: a field holding a comma, quote or line break is quoted).
pub fn csv_bytes(header: &[String], rows: impl IntoIterator<Item = Vec<String>>) -> Result<Vec<u8>, String> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(header).map_err(|e| e.to_string())?;
    for row in rows {
        w.write_record(&row).map_err(|e| e.to_string())?;
    }
    w.into_inner().map_err(|e| e.to_string())
}
