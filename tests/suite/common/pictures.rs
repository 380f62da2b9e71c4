//! Checks of the result pictures (`preview.png` of a run, `finals.png` of a comparison):
//! panels side by side, each what `vkinverse render -o IMAGE.png` writes for its image.
#![allow(dead_code)]

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use vkinverse::image::{read_exr, write_png, Image};
use vkinverse::preview::PANEL_GAP;

/// An 8-bit RGB PNG's width, height and pixel bytes.
pub fn decode_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut reader = png::Decoder::new(file).read_info().unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!((info.color_type, info.bit_depth), (png::ColorType::Rgb, png::BitDepth::Eight), "{}", path.display());
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// The pixels `render -o IMAGE.png` stores for `image`: written as it writes them, read back.
fn png_pixels(image: &Image, scratch: &Path) -> Vec<u8> {
    write_png(scratch, image).unwrap();
    decode_png(scratch).2
}

/// Asserts that `picture` holds `panels` side by side, left to right: n·W + (n − 1)·gap by
/// H pixels, white columns between the panels, and each panel's pixels within one code
/// value of what `render -o IMAGE.png` writes for its image.
pub fn assert_panels(picture: &Path, panels: &[Image]) {
    let (w, h) = (panels[0].width, panels[0].height);
    let n = panels.len() as u32;
    let (width, height, pixels) = decode_png(picture);
    assert_eq!((width, height), (n * w + (n - 1) * PANEL_GAP, h), "{}: {n} panels of {w}x{h}", picture.display());
    static CALLS: AtomicU64 = AtomicU64::new(0);
    let scratch = std::env::temp_dir().join(format!("vkinverse-panel-check-{}-{}.png", std::process::id(), CALLS.fetch_add(1, Ordering::Relaxed)));
    for (k, panel) in panels.iter().enumerate() {
        let expected = png_pixels(panel, &scratch);
        let left = k as u32 * (w + PANEL_GAP);
        for y in 0..h {
            for x in 0..w {
                let at = 3 * (y * width + left + x) as usize;
                let want = 3 * (y * w + x) as usize;
                for c in 0..3 {
                    let (got, want) = (pixels[at + c], expected[want + c]);
                    assert!(got.abs_diff(want) <= 1, "{}: panel {k} pixel ({x}, {y}) channel {c}: {got}, expected {want}", picture.display());
                }
            }
            if k > 0 {
                let gap = 3 * (y * width + left - PANEL_GAP) as usize;
                assert!(pixels[gap..gap + 3 * PANEL_GAP as usize].iter().all(|&v| v == 255), "{}: the gap before panel {k} is not white", picture.display());
            }
        }
    }
    let _ = std::fs::remove_file(&scratch);
}

/// |`fin` − `target`| per pixel and channel over the target's mean value (over its pixels
/// and channels), as the preview's fourth panel is documented to be.
pub fn difference(fin: &Image, target: &Image) -> Image {
    let mean = target.data.iter().flatten().map(|&c| f64::from(c)).sum::<f64>() / (3 * target.data.len()) as f64;
    assert!(mean > 0.0, "a black target");
    let data = fin.data.iter().zip(&target.data).map(|(f, t)| [0, 1, 2].map(|c| ((f64::from(f[c]) - f64::from(t[c])).abs() / mean) as f32)).collect();
    Image { width: target.width, height: target.height, data }
}

/// A run directory's picture of `stem`.`ext` for `sensor` of `sensors`.
pub fn sensor_file(dir: &Path, stem: &str, ext: &str, sensor: usize, sensors: usize) -> std::path::PathBuf {
    match sensors {
        1 => dir.join(format!("{stem}.{ext}")),
        _ => dir.join(format!("{stem}-{sensor}.{ext}")),
    }
}

/// Asserts a run directory's pictures for a scene of `sensors` sensors of `w`×`h` pixels:
/// per sensor `target`, `start` and `final` EXRs of that size (`final.exr` is sensor 0's),
/// and the preview of target | start | final | difference. Returns each sensor's (target,
/// start, final).
pub fn assert_run_pictures(dir: &Path, sensors: usize, (w, h): (u32, u32)) -> Vec<(Image, Image, Image)> {
    let mut out = Vec::new();
    for k in 0..sensors {
        let read = |stem: &str| read_exr(&sensor_file(dir, stem, "exr", k, sensors)).unwrap_or_else(|e| panic!("sensor {k}: {e}"));
        let (target, start, fin) = (read("target"), read("start"), read("final"));
        for image in [&target, &start, &fin] {
            assert_eq!((image.width, image.height), (w, h));
        }
        assert_ne!(start, fin, "sensor {k}: the start and the result are one image");
        let difference = difference(&fin, &target);
        assert_panels(&sensor_file(dir, "preview", "png", k, sensors), &[target.clone(), start.clone(), fin.clone(), difference]);
        out.push((target, start, fin));
    }
    assert_eq!(read_exr(&dir.join("final.exr")).unwrap(), out[0].2, "final.exr is sensor 0's");
    out
}
