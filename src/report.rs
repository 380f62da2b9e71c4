//! Text and JSON reports: device information, plots and CSV tables.

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
