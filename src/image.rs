//! RGB float images and the files they travel in: OpenEXR in and out, tone-mapped PNG out.
//!
//! Invariants: an [`Image`] is row-major with the top row first (the OpenEXR and PNG order),
//! and `data.len() == width * height`. Every writer goes through [`write_atomic`], so a file
//! on disk is either its old content or the complete new one, never half-written.

use std::fs::{self, File};
use std::io::{self, Cursor, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use thiserror::Error;

/// Errors of image input and output; each names the file it concerns.
#[derive(Debug, Error)]
pub enum ImageError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: io::Error },
    #[error("{}: not a readable OpenEXR file: {source}", path.display())]
    Exr { path: PathBuf, source: exr::error::Error },
    #[error("{}: no layer has R, G and B channels (channels: {channels})", path.display())]
    MissingRgb { path: PathBuf, channels: String },
    #[error("{}: PNG encoding failed: {source}", path.display())]
    Png { path: PathBuf, source: png::EncodingError },
    #[error("{}: not a readable PNG or JPEG image: {message}", path.display())]
    Decode { path: PathBuf, message: String },
    #[error("{}: not a readable Radiance HDR image: {message}", path.display())]
    Hdr { path: PathBuf, message: String },
    #[error("{}: {width}x{height} pixels: each side must be in 1..={}", path.display(), MAX_IMAGE_SIDE)]
    TooLarge { path: PathBuf, width: u64, height: u64 },
    #[error("{}: image is {width}x{height} but holds {len} pixels", path.display())]
    Size { path: PathBuf, width: u32, height: u32, len: usize },
    #[error("{}: the panels differ in size ({}x{} and {}x{})", path.display(), first.0, first.1, other.0, other.1)]
    Panels { path: PathBuf, first: (u32, u32), other: (u32, u32) },
}

/// A linear RGB float image.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub data: Vec<[f32; 3]>,
}

impl Image {
    /// An image of one colour.
    pub fn filled(width: u32, height: u32, value: [f32; 3]) -> Self {
        Self { width, height, data: vec![value; width as usize * height as usize] }
    }

    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        self.data[y as usize * self.width as usize + x as usize]
    }

    /// Nearest-texel resampling of the first `channels` channels to `w` × `h`, row by row,
    /// `channels` floats per texel.
    pub fn resample(&self, channels: u32, w: u32, h: u32) -> Vec<f32> {
        let mut out = Vec::with_capacity((w * h * channels) as usize);
        for y in 0..h {
            for x in 0..w {
                let sx = ((x as f64 + 0.5) * self.width as f64 / w as f64) as u32;
                let sy = ((y as f64 + 0.5) * self.height as f64 / h as f64) as u32;
                let px = self.get(sx.min(self.width - 1), sy.min(self.height - 1));
                out.extend_from_slice(&px[..channels as usize]);
            }
        }
        out
    }

    /// The first pixel (x, y) holding a NaN or an infinity, if any.
    pub fn find_non_finite(&self) -> Option<(u32, u32)> {
        let i = self.data.iter().position(|p| p.iter().any(|c| !c.is_finite()))?;
        let w = self.width.max(1) as usize;
        Some(((i % w) as u32, (i / w) as u32))
    }

    /// The first pixel (x, y, in row order) whose first `channels` channels hold a value
    /// outside [lo, hi], with that value.
    pub fn find_outside(&self, channels: usize, lo: f32, hi: f32) -> Option<(u32, u32, f32)> {
        let w = self.width.max(1) as usize;
        self.data.iter().enumerate().find_map(|(i, p)| p[..channels].iter().find(|v| !(lo..=hi).contains(*v)).map(|&v| ((i % w) as u32, (i / w) as u32, v)))
    }

    fn check_size(&self, path: &Path) -> Result<(), ImageError> {
        if self.data.len() == self.width as usize * self.height as usize {
            Ok(())
        } else {
            Err(ImageError::Size { path: path.to_path_buf(), width: self.width, height: self.height, len: self.data.len() })
        }
    }
}

/// The longest side of an image read or made (film, texture, target): 16384, which bounds
/// an image's memory (4 GiB of float RGB) before it is decoded.
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// Refuses a `width` × `height` image beyond [`MAX_IMAGE_SIDE`] (or of no pixels).
fn check_size(path: &Path, width: u64, height: u64) -> Result<(), ImageError> {
    let max = u64::from(MAX_IMAGE_SIDE);
    if width == 0 || height == 0 || width > max || height > max {
        return Err(ImageError::TooLarge { path: path.to_path_buf(), width, height });
    }
    Ok(())
}

/// Reads the first layer with R, G and B channels (half, float or uint; alpha is ignored).
///
/// ```
/// use vkinverse::image::{read_exr, write_exr, Image};
/// let path = std::env::temp_dir().join(format!("vkinverse-doc-image-{}.exr", std::process::id()));
/// let image = Image::filled(4, 2, [0.25, 0.5, 1.0]);
/// write_exr(&path, &image).unwrap();
/// assert_eq!(read_exr(&path).unwrap(), image);
/// ```
pub fn read_exr(path: &Path) -> Result<Image, ImageError> {
    let bytes = crate::files::read(path).map_err(|source| ImageError::Io { path: path.to_path_buf(), source })?;
    decode_exr(&bytes, path)
}

/// Decodes an OpenEXR file already in memory; `path` is only used in error messages.
pub fn decode_exr(bytes: &[u8], path: &Path) -> Result<Image, ImageError> {
    use exr::prelude::{read, MetaData, ReadChannels, ReadLayers, RgbChannels, Vec2};
    let exr_err = |source| ImageError::Exr { path: path.to_path_buf(), source };
    // Checked before decoding because exr's own error for this case does not say which
    // channels the file does have, and that is what the user needs to know.
    let meta = MetaData::read_from_buffered(Cursor::new(bytes), false).map_err(exr_err)?;
    // Every layer's size before any pixel is allocated: a small file may claim a huge one.
    for h in &meta.headers {
        check_size(path, h.layer_size.0 as u64, h.layer_size.1 as u64)?;
    }
    let has = |h: &exr::meta::header::Header, name: &str| h.channels.list.iter().any(|c| c.name.eq(name));
    if !meta.headers.iter().any(|h| has(h, "R") && has(h, "G") && has(h, "B")) {
        let channels: Vec<String> = meta.headers.iter().flat_map(|h| h.channels.list.iter().map(|c| c.name.to_string())).collect();
        return Err(ImageError::MissingRgb { path: path.to_path_buf(), channels: channels.join(", ") });
    }
    let decoded = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgb_channels(
            |size: Vec2<usize>, _: &RgbChannels| Image::filled(size.0 as u32, size.1 as u32, [0.0; 3]),
            |img: &mut Image, pos: Vec2<usize>, (r, g, b): (f32, f32, f32)| {
                let i = pos.1 * img.width as usize + pos.0;
                img.data[i] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
        .map_err(exr_err)?;
    Ok(decoded.layer_data.channel_data.pixels)
}

/// Whether a file's first bytes are a Radiance HDR (RGBE) header: `#?RADIANCE`, `#?RGBE`
/// or any other `#?` program name, as Radiance's own readers accept.
pub fn is_radiance_hdr(bytes: &[u8]) -> bool {
    bytes.starts_with(b"#?")
}

/// Decodes a Radiance HDR (RGBE, `.hdr`) file already in memory into linear RGB; `path` is
/// only used in error messages.
pub fn decode_hdr(bytes: &[u8], path: &Path) -> Result<Image, ImageError> {
    let hdr_err = |message: String| ImageError::Hdr { path: path.to_path_buf(), message };
    let reader = || ::image::ImageReader::with_format(Cursor::new(bytes), ::image::ImageFormat::Hdr);
    let (width, height) = reader().into_dimensions().map_err(|e| hdr_err(e.to_string()))?;
    check_size(path, width.into(), height.into())?;
    let img = reader().decode().map_err(|e| hdr_err(e.to_string()))?;
    Ok(rgb_image(&img))
}

/// The RGB channels of a decoded image as floats, as stored (grey repeated into R, G and
/// B, alpha dropped).
fn rgb_image(img: &::image::DynamicImage) -> Image {
    let rgb = img.to_rgb32f();
    Image { width: rgb.width(), height: rgb.height(), data: rgb.pixels().map(|p| p.0).collect() }
}

/// Decodes a linear (high dynamic range) image already in memory: a Radiance HDR file when
/// it starts with a Radiance header ([`is_radiance_hdr`]), otherwise OpenEXR (so that a
/// file that is neither gets the OpenEXR reader's error, the format a scene names first).
pub fn decode_linear(bytes: &[u8], path: &Path) -> Result<Image, ImageError> {
    if is_radiance_hdr(bytes) {
        decode_hdr(bytes, path)
    } else {
        decode_exr(bytes, path)
    }
}

/// Writes a float32 RGB OpenEXR file atomically.
pub fn write_exr(path: &Path, image: &Image) -> Result<(), ImageError> {
    use exr::prelude::{SpecificChannels, Vec2, WritableImage};
    image.check_size(path)?;
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let [r, g, b] = image.data[y * image.width as usize + x];
        (r, g, b)
    });
    let mut bytes = Cursor::new(Vec::new());
    exr::image::Image::from_channels((image.width as usize, image.height as usize), channels)
        .write()
        .to_buffered(&mut bytes)
        .map_err(|source| ImageError::Exr { path: path.to_path_buf(), source })?;
    write_bytes_atomic(path, bytes.get_ref()).map_err(|source| ImageError::Io { path: path.to_path_buf(), source })
}

/// Writes an 8-bit sRGB PNG atomically: each channel clamped to [0, 1] (NaN as 0), then
/// encoded with the sRGB transfer function. No exposure or tone curve is applied.
pub fn write_png(path: &Path, image: &Image) -> Result<(), ImageError> {
    write_png_with_alpha(path, image, None)
}

/// [`write_png`] with an alpha channel where `alpha` (one value per pixel, linear in
/// [0, 1], as PNG stores alpha) is given.
pub fn write_png_with_alpha(path: &Path, image: &Image, alpha: Option<&[f32]>) -> Result<(), ImageError> {
    image.check_size(path)?;
    let linear8 = |a: f32| (a.clamp(0.0, 1.0) * 255.0).round() as u8;
    let pixels: Vec<u8> = match alpha {
        None => srgb_bytes(image),
        Some(alpha) => image.data.iter().zip(alpha).flat_map(|(p, &a)| [srgb_encode(p[0]), srgb_encode(p[1]), srgb_encode(p[2]), linear8(a)]).collect(),
    };
    let color = if alpha.is_some() { png::ColorType::Rgba } else { png::ColorType::Rgb };
    encode_png(path, image.width, image.height, color, &pixels)
}

/// The 8-bit sRGB bytes [`write_png`] stores for `image`: R, G, B per pixel, row by row.
pub fn srgb_bytes(image: &Image) -> Vec<u8> {
    image.data.iter().flatten().map(|&c| srgb_encode(c)).collect()
}

/// Encodes 8-bit `pixels` (`color`, row by row) as an sRGB PNG and writes it atomically.
fn encode_png(path: &Path, width: u32, height: u32, color: png::ColorType, pixels: &[u8]) -> Result<(), ImageError> {
    let png_err = |source| ImageError::Png { path: path.to_path_buf(), source };
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(color);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    let mut writer = encoder.write_header().map_err(png_err)?;
    writer.write_image_data(pixels).map_err(png_err)?;
    writer.finish().map_err(png_err)?;
    write_bytes_atomic(path, &bytes).map_err(|source| ImageError::Io { path: path.to_path_buf(), source })
}

/// The white columns between the panels of [`write_panels`], in pixels.
pub const PANEL_GAP: u32 = 2;

/// Writes `panels` side by side, left to right, as one 8-bit sRGB PNG, atomically: each
/// panel tone-mapped as [`write_png`] does (so that its pixels are those `write_png` would
/// store for it alone), [`PANEL_GAP`] white columns between neighbours. The panels must
/// share one size W × H; the picture is n·W + (n − 1)·`PANEL_GAP` by H.
pub fn write_panels(path: &Path, panels: &[&Image]) -> Result<(), ImageError> {
    let Some(first) = panels.first() else {
        return Err(ImageError::TooLarge { path: path.to_path_buf(), width: 0, height: 0 });
    };
    let (w, h) = (first.width, first.height);
    for p in panels {
        p.check_size(path)?;
        if (p.width, p.height) != (w, h) {
            return Err(ImageError::Panels { path: path.to_path_buf(), first: (w, h), other: (p.width, p.height) });
        }
    }
    let n = panels.len() as u32;
    let width = n * w + (n - 1) * PANEL_GAP;
    check_size(path, width.into(), h.into())?;
    let encoded: Vec<Vec<u8>> = panels.iter().map(|p| srgb_bytes(p)).collect();
    let gap = vec![255u8; 3 * PANEL_GAP as usize];
    let mut pixels = Vec::with_capacity(3 * (width * h) as usize);
    for y in 0..h as usize {
        for (k, panel) in encoded.iter().enumerate() {
            if k > 0 {
                pixels.extend_from_slice(&gap);
            }
            let row = 3 * w as usize;
            pixels.extend_from_slice(&panel[y * row..(y + 1) * row]);
        }
    }
    encode_png(path, width, h, png::ColorType::Rgb, &pixels)
}

/// |`a` − `b`| per pixel and channel, divided by the mean of `b` (over its pixels and
/// channels, finite values only; 1 where that mean is not positive): a difference as large
/// as `b`'s mean brightness is 1, white once tone-mapped. Both images must be of one size.
pub fn difference_over_mean(a: &Image, b: &Image) -> Image {
    let values = b.data.iter().flatten().filter(|c| c.is_finite());
    let (sum, count) = values.fold((0.0f64, 0usize), |(s, n), &c| (s + f64::from(c), n + 1));
    let mean = sum / count.max(1) as f64;
    let scale = if mean > 0.0 && mean.is_finite() { (1.0 / mean) as f32 } else { 1.0 };
    let data = a.data.iter().zip(&b.data).map(|(pa, pb)| [0, 1, 2].map(|c| (pa[c] - pb[c]).abs() * scale)).collect();
    Image { width: a.width, height: a.height, data }
}

/// An sRGB-encoded value in [0, 1] to linear (IEC 61966-2-1 EOTF), the inverse of the
/// encoding [`write_png`] applies.
pub fn srgb_decode(encoded: f32) -> f32 {
    if encoded <= 0.040_45 {
        encoded / 12.92
    } else {
        ((encoded + 0.055) / 1.055).powf(2.4)
    }
}

/// Decodes a PNG or JPEG file already in memory into values in [0, 1] as stored (no
/// transfer function applied; grey images are repeated into R, G and B, alpha is dropped).
/// `path` is only used in error messages.
pub fn decode_ldr(bytes: &[u8], path: &Path) -> Result<Image, ImageError> {
    let decode_err = |e: ::image::ImageError| ImageError::Decode { path: path.to_path_buf(), message: e.to_string() };
    let reader = || ::image::ImageReader::new(Cursor::new(bytes)).with_guessed_format().map_err(|e| ImageError::Io { path: path.to_path_buf(), source: e });
    let (width, height) = reader()?.into_dimensions().map_err(decode_err)?;
    check_size(path, width.into(), height.into())?;
    Ok(rgb_image(&reader()?.decode().map_err(decode_err)?))
}

/// Linear [0, 1] to 8-bit sRGB (IEC 61966-2-1 OETF).
fn srgb_encode(linear: f32) -> u8 {
    let c = if linear.is_nan() { 0.0 } else { linear.clamp(0.0, 1.0) };
    let encoded = if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
    (encoded * 255.0).round() as u8
}

/// Runs `write` on a fresh temporary path in `path`'s directory, flushes that file to disk
/// and renames it over `path`. The rename is atomic on one file system, which is why the
/// temporary file lives beside the target rather than in the system temp directory. On any
/// error the temporary file is removed and `path` is untouched.
pub fn write_atomic<T, E: From<io::Error>>(path: &Path, write: impl FnOnce(&Path) -> Result<T, E>) -> Result<T, E> {
    // Unique per process and call, so concurrent writers of one path never share a temp file.
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, format!("{}: not a file path", path.display())))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp.{}.{}", std::process::id(), COUNTER.fetch_add(1, Ordering::Relaxed)));
    let tmp = path.with_file_name(tmp_name);
    let result = write(&tmp).and_then(|value| {
        File::open(&tmp)?.sync_all()?;
        fs::rename(&tmp, path)?;
        Ok(value)
    });
    if result.is_err() {
        // The write already failed; a leftover that cannot be removed changes nothing more.
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// [`write_atomic`] for a byte buffer.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomic(path, |tmp| File::create(tmp)?.write_all(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("vkinverse-image-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn gradient(w: u32, h: u32) -> Image {
        let data = (0..w * h).map(|i| [i as f32 * 0.25, -(i as f32), 1.0e6 + i as f32]).collect();
        Image { width: w, height: h, data }
    }

    #[test]
    fn exr_round_trip_is_exact() {
        let dir = temp_dir("exr");
        let path = dir.join("a.exr");
        let img = gradient(5, 3);
        write_exr(&path, &img).unwrap();
        assert_eq!(read_exr(&path).unwrap(), img);
    }

    #[test]
    fn exr_without_rgb_names_its_channels() {
        let dir = temp_dir("norgb");
        let path = dir.join("y.exr");
        use exr::prelude::WritableImage;
        exr::prelude::Image::from_channels((2, 2), exr::prelude::SpecificChannels::build().with_channel("Y").with_pixel_fn(|_| (0.5f32,)))
            .write()
            .to_file(&path)
            .unwrap();
        let err = read_exr(&path).unwrap_err();
        assert!(matches!(err, ImageError::MissingRgb { .. }), "{err}");
        let msg = err.to_string();
        assert!(msg.contains("y.exr") && msg.contains("channels: Y"), "{msg}");
    }

    #[test]
    fn garbage_is_an_exr_error() {
        let dir = temp_dir("garbage");
        let path = dir.join("g.exr");
        fs::write(&path, b"not an exr").unwrap();
        assert!(matches!(read_exr(&path), Err(ImageError::Exr { .. })));
    }

    #[test]
    fn png_is_valid_and_srgb_encoded() {
        let dir = temp_dir("png");
        let path = dir.join("a.png");
        let img = Image { width: 4, height: 1, data: vec![[0.0, 1.0, 2.0], [0.5, -1.0, f32::NAN], [0.2; 3], [1.0; 3]] };
        write_png(&path, &img).unwrap();
        let decoder = png::Decoder::new(File::open(&path).unwrap());
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height, info.color_type), (4, 1, png::ColorType::Rgb));
        assert_eq!(&buf[..6], &[0, 255, 255, 188, 0, 0]);
        assert_eq!(buf[6], 124);
    }

    #[test]
    fn writers_reject_inconsistent_sizes() {
        let dir = temp_dir("size");
        let img = Image { width: 3, height: 3, data: vec![[0.0; 3]; 4] };
        assert!(matches!(write_png(&dir.join("a.png"), &img), Err(ImageError::Size { .. })));
        assert!(matches!(write_exr(&dir.join("a.exr"), &img), Err(ImageError::Size { .. })));
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 0);
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp_file() {
        let dir = temp_dir("atomic");
        let path = dir.join("out.bin");
        write_bytes_atomic(&path, b"old").unwrap();
        write_bytes_atomic(&path, b"new content").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"new content");
        let names: Vec<_> = fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.bin")]);
    }

    #[test]
    fn failed_atomic_write_keeps_the_old_file() {
        let dir = temp_dir("atomic-fail");
        let path = dir.join("out.bin");
        write_bytes_atomic(&path, b"old").unwrap();
        let result: io::Result<()> = write_atomic(&path, |tmp| {
            fs::write(tmp, b"half")?;
            Err(io::Error::other("interrupted"))
        });
        assert!(result.is_err());
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 1);
    }
}
