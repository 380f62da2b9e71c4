//! Result pictures: what a run and a comparison show of their images.
//!
//! `optimise -o OUTDIR` writes, per sensor, its target (`target.exr`), the scene rendered
//! with the initial parameters (`start.exr`), the result (`final.exr`) and `preview.png`:
//! four panels side by side, left to right target | start | final | difference, separated
//! by [`PANEL_GAP`] white columns. A scene of several sensors names them per sensor,
//! `target-K.exr`, `start-K.exr`, `final-K.exr`, `preview-K.png` for sensor K
//! ([`sensor_file`]; `final.exr` is then sensor 0's as well). The start and the final image
//! are each the mean of two renders of `summary.json`'s `image_error_spp` samples per pixel
//! with the same seeds (the renders that measure the image error).
//!
//! Every panel is tone-mapped as `vkinverse render -o IMAGE.png` writes an image
//! ([`crate::image::write_png`]: each channel clamped to [0, 1], sRGB-encoded, no
//! exposure), so that a panel's pixels are what `render` would write for its EXR. The
//! difference panel is |final − target| per pixel and channel divided by the target's
//! mean value (over its pixels and channels; [`difference_over_mean`]): a difference as
//! large as the target's mean brightness shows as white.
//!
//! `compare -o OUTDIR` writes `finals.png` (`finals-K.png` for sensor K of several): the
//! target, then each optimiser's final image, in the order of `--optimisers` (the rows of
//! `compare.csv`), panels and tone mapping as above.

use crate::error::{Error, Result};
use crate::image::{read_exr, write_exr, write_panels, Image};
use std::path::{Path, PathBuf};

pub use crate::image::{difference_over_mean, PANEL_GAP};

/// The pictures a run writes per sensor, as (stem, extension), in [`sensor_file`]'s names.
pub const SENSOR_FILES: [(&str, &str); 4] = [("target", "exr"), ("start", "exr"), ("final", "exr"), ("preview", "png")];

/// The stem of the picture of a comparison's final images.
pub const FINALS: &str = "finals";

/// The name of picture `stem`.`ext` of `sensor` in a scene of `sensors` sensors:
/// `STEM.EXT` for a single sensor, `STEM-K.EXT` for sensor K of several.
pub fn sensor_file(stem: &str, ext: &str, sensor: usize, sensors: usize) -> String {
    match sensors {
        1 => format!("{stem}.{ext}"),
        _ => format!("{stem}-{sensor}.{ext}"),
    }
}

/// Whether `name` is one of [`SENSOR_FILES`] of some sensor (`STEM.EXT` or `STEM-K.EXT`).
pub fn is_sensor_file(name: &str) -> bool {
    SENSOR_FILES.iter().any(|(stem, ext)| {
        let rest = name.strip_prefix(stem).and_then(|r| r.strip_suffix(ext)).and_then(|r| r.strip_suffix('.'));
        rest.is_some_and(|r| r.is_empty() || r.strip_prefix('-').is_some_and(|k| !k.is_empty() && k.bytes().all(|b| b.is_ascii_digit())))
    })
}

/// Writes a run's pictures into `dir` (module documentation): per sensor its target, start
/// and final image as EXR and the preview of the three; `final.exr` is sensor 0's.
pub fn write_run_pictures(dir: &Path, targets: &[Image], starts: &[Image], finals: &[Image]) -> Result<()> {
    let n = targets.len();
    if starts.len() != n || finals.len() != n {
        return Err(Error::Invalid(format!("{} target images, {} start images and {} final images", n, starts.len(), finals.len())));
    }
    if let Some(first) = finals.first() {
        write_exr(&dir.join("final.exr"), first)?;
    }
    for (k, ((target, start), fin)) in targets.iter().zip(starts).zip(finals).enumerate() {
        write_exr(&dir.join(sensor_file("target", "exr", k, n)), target)?;
        write_exr(&dir.join(sensor_file("start", "exr", k, n)), start)?;
        if n > 1 {
            write_exr(&dir.join(sensor_file("final", "exr", k, n)), fin)?;
        }
        let difference = difference_over_mean(fin, target);
        write_panels(&dir.join(sensor_file("preview", "png", k, n)), &[target, start, fin, &difference])?;
    }
    Ok(())
}

/// Writes a comparison's `finals.png` (`finals-K.png` per sensor of several) into
/// `out_dir`: the target, then the final image of each run in `runs` (their directories,
/// in order), read from the runs' EXRs. Where a run lacks one of them (a run finished
/// before runs wrote their pictures, read back by a resume) nothing is written and the
/// missing file is returned.
pub fn write_finals(out_dir: &Path, sensors: usize, runs: &[&Path]) -> Result<Option<PathBuf>> {
    let Some(first) = runs.first() else { return Ok(None) };
    let targets = (0..sensors).map(|k| first.join(sensor_file("target", "exr", k, sensors)));
    let finals = runs.iter().flat_map(|r| (0..sensors).map(move |k| r.join(sensor_file("final", "exr", k, sensors))));
    if let Some(missing) = targets.chain(finals).find(|p| !p.exists()) {
        return Ok(Some(missing));
    }
    for k in 0..sensors {
        let target = read_exr(&first.join(sensor_file("target", "exr", k, sensors)))?;
        let finals: Vec<Image> = runs.iter().map(|r| read_exr(&r.join(sensor_file("final", "exr", k, sensors)))).collect::<std::result::Result<_, _>>()?;
        let panels: Vec<&Image> = std::iter::once(&target).chain(&finals).collect();
        write_panels(&out_dir.join(sensor_file(FINALS, "png", k, sensors)), &panels)?;
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image;

    #[test]
    fn sensor_files_are_named_per_sensor_only_with_several() {
        assert_eq!(sensor_file("preview", "png", 0, 1), "preview.png");
        assert_eq!(sensor_file("preview", "png", 2, 3), "preview-2.png");
        for name in ["preview.png", "preview-0.png", "target-12.exr", "start.exr", "final-1.exr", "final.exr"] {
            assert!(is_sensor_file(name), "{name}");
        }
        for name in ["preview.exr", "preview-.png", "preview-a.png", "previews.png", "target-1-2.exr", "log.csv", "final"] {
            assert!(!is_sensor_file(name), "{name}");
        }
    }

    #[test]
    fn the_difference_is_divided_by_the_targets_mean() {
        let target = Image { width: 2, height: 1, data: vec![[0.5, 1.0, 1.5], [1.0, 1.0, 1.0]] };
        let fin = Image { width: 2, height: 1, data: vec![[1.0, 1.0, 1.0], [0.0, 3.0, 1.0]] };
        assert_eq!(difference_over_mean(&fin, &target).data, vec![[0.5, 0.0, 0.5], [1.0, 2.0, 0.0]]);
        // A black target leaves the difference as it is.
        let black = Image::filled(2, 1, [0.0; 3]);
        assert_eq!(difference_over_mean(&fin, &black).data, fin.data);
    }

    #[test]
    fn panels_are_the_png_pixels_side_by_side() {
        let dir = std::env::temp_dir().join(format!("vkinverse-preview-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a = Image { width: 2, height: 2, data: vec![[0.0, 0.5, 1.0], [2.0, -1.0, 0.2], [0.1; 3], [0.9; 3]] };
        let b = Image::filled(2, 2, [0.25, 0.75, 0.0]);
        let path = dir.join("panels.png");
        write_panels(&path, &[&a, &b]).unwrap();
        let decoder = png::Decoder::new(std::fs::File::open(&path).unwrap());
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (4 + PANEL_GAP, 2));
        let row = 3 * info.width as usize;
        let (sa, sb) = (image::srgb_bytes(&a), image::srgb_bytes(&b));
        for y in 0..2 {
            let line = &buf[y * row..(y + 1) * row];
            assert_eq!(&line[..6], &sa[y * 6..y * 6 + 6]);
            assert!(line[6..6 + 3 * PANEL_GAP as usize].iter().all(|&v| v == 255));
            assert_eq!(&line[6 + 3 * PANEL_GAP as usize..], &sb[y * 6..y * 6 + 6]);
        }
        let wide = Image::filled(3, 2, [0.0; 3]);
        assert!(write_panels(&dir.join("bad.png"), &[&a, &wide]).unwrap_err().to_string().contains("differ in size"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
