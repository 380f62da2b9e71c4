//! Mitsuba's `.vol` grids (the binary format of Mitsuba 3's `gridvolume`): a medium's
//! density or emission as Mitsuba writes it.
//!
//! The layout, little-endian: the bytes `VOL`, the version byte 3; int32 encoding (1, float32);
//! int32 voxels along x, y and z; int32 channels; six float32 of a bounding box (xmin, ymin,
//! zmin, xmax, ymax, zmax); then x·y·z·channels float32, x fastest, then y, then z, the
//! channels of a voxel together. That is the order of a grid parameter's values
//! ([`crate::tensor::Shape::grid`]).
//!
//! Reading checks everything before allocating (magic, version, encoding, each side within
//! [`MAX_GRID_SIDE`], the voxels within [`MAX_GRID_VOXELS`], the exact data length) and
//! refuses values that are not finite; every error is one line naming the file. Writing is
//! atomic ([`crate::image::write_atomic`]).

use std::io::Write as _;
use std::path::{Path, PathBuf};

pub use crate::tensor::{MAX_GRID_SIDE, MAX_GRID_VOXELS};

/// Most channels a grid may hold (Mitsuba's grids hold 1, 3 or 6).
pub const MAX_CHANNELS: u32 = 6;

/// Bytes before the voxels.
pub const HEADER_BYTES: usize = 48;

/// Errors reading or writing `.vol` files; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum VolError {
    #[error("{}: file not found", .0.display())]
    NotFound(PathBuf),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: not a .vol file (bad magic)", .0.display())]
    BadMagic(PathBuf),
    #[error("{}: the file ends inside the {HEADER_BYTES}-byte header ({found} bytes)", path.display())]
    ShortHeader { path: PathBuf, found: usize },
    #[error("{}: unsupported .vol version {found} (expected 3)", path.display())]
    Version { path: PathBuf, found: u8 },
    #[error("{}: unsupported .vol encoding {found} (expected 1, float32)", path.display())]
    Encoding { path: PathBuf, found: i32 },
    #[error("{}: {axis} has {found} voxels; a side is 1 to {MAX_GRID_SIDE}", path.display())]
    Side { path: PathBuf, axis: &'static str, found: i64 },
    #[error("{}: {found} voxels; at most {MAX_GRID_VOXELS}", path.display())]
    Voxels { path: PathBuf, found: usize },
    #[error("{}: {found} channels; a grid has 1 to {MAX_CHANNELS}", path.display())]
    Channels { path: PathBuf, found: i64 },
    #[error("{}: truncated data: {found} of {expected} bytes", path.display())]
    Truncated { path: PathBuf, expected: usize, found: usize },
    #[error("{}: {extra} bytes after the grid data", path.display())]
    TrailingData { path: PathBuf, extra: usize },
    #[error("{}: voxel ({x}, {y}, {z}) channel {channel} is {value}", path.display())]
    NonFinite { path: PathBuf, x: usize, y: usize, z: usize, channel: usize, value: f32 },
    #[error("{}: {reason}", path.display())]
    Invalid { path: PathBuf, reason: String },
}

/// A grid of float32 voxels.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    /// Voxels along x, y and z.
    pub size: [u32; 3],
    pub channels: u32,
    /// The bounding box the file declares, `[xmin, ymin, zmin, xmax, ymax, zmax]`; as in
    /// Mitsuba, where a grid lies is up to its user (a medium's `min` and `max`).
    pub bbox: [f32; 6],
    /// x·y·z·channels values, x fastest, channels innermost.
    pub data: Vec<f32>,
}

impl Grid {
    /// Voxels along z, y and x, then the channels: the `.npy` array shape of the same values.
    pub fn array_shape(&self) -> Vec<usize> {
        let [x, y, z] = self.size.map(|s| s as usize);
        vec![z, y, x, self.channels as usize]
    }
}

/// Reads a `.vol` grid.
///
/// ```
/// use vkinverse::vol::{read, write, Grid};
/// let path = std::env::temp_dir().join(format!("vkinverse-doc-vol-{}.vol", std::process::id()));
/// let grid = Grid { size: [4, 3, 2], channels: 1, bbox: [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], data: (0..24).map(|i| i as f32).collect() };
/// write(&path, &grid).unwrap();
/// assert_eq!(read(&path).unwrap(), grid);
/// ```
pub fn read(path: &Path) -> Result<Grid, VolError> {
    let bytes = crate::files::read(path).map_err(|e| io_error(path, e))?;
    parse_bytes(&bytes, path)
}

/// Parses a `.vol` file's bytes; `path` names it in errors.
pub fn parse_bytes(bytes: &[u8], path: &Path) -> Result<Grid, VolError> {
    let path = || path.to_path_buf();
    if bytes.len() < 3 || &bytes[..3] != b"VOL" {
        return Err(VolError::BadMagic(path()));
    }
    if bytes.len() < HEADER_BYTES {
        return Err(VolError::ShortHeader { path: path(), found: bytes.len() });
    }
    if bytes[3] != 3 {
        return Err(VolError::Version { path: path(), found: bytes[3] });
    }
    let int = |at: usize| i32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    let float = |at: usize| f32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    let encoding = int(4);
    if encoding != 1 {
        return Err(VolError::Encoding { path: path(), found: encoding });
    }
    let mut size = [0u32; 3];
    for (axis, (s, name)) in size.iter_mut().zip(["x", "y", "z"]).enumerate() {
        let v = int(8 + 4 * axis);
        *s = u32::try_from(v).ok().filter(|v| (1..=MAX_GRID_SIDE).contains(v)).ok_or(VolError::Side { path: path(), axis: name, found: v.into() })?;
    }
    let voxels = size.iter().map(|&s| s as usize).product::<usize>();
    if voxels > MAX_GRID_VOXELS {
        return Err(VolError::Voxels { path: path(), found: voxels });
    }
    let c = int(20);
    let channels = u32::try_from(c).ok().filter(|c| (1..=MAX_CHANNELS).contains(c)).ok_or(VolError::Channels { path: path(), found: c.into() })?;
    let bbox = [0, 1, 2, 3, 4, 5].map(|i| float(24 + 4 * i));
    // Sides and channels are bounded: the product fits (2^24 × 6 × 4 bytes).
    let expected = voxels * channels as usize * 4;
    let found = bytes.len() - HEADER_BYTES;
    if found < expected {
        return Err(VolError::Truncated { path: path(), expected, found });
    }
    if found > expected {
        return Err(VolError::TrailingData { path: path(), extra: found - expected });
    }
    let data: Vec<f32> = bytes[HEADER_BYTES..].chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        let c = channels as usize;
        let (nx, ny) = (size[0] as usize, size[1] as usize);
        let v = i / c;
        return Err(VolError::NonFinite { path: path(), x: v % nx, y: v / nx % ny, z: v / (nx * ny), channel: i % c, value: data[i] });
    }
    Ok(Grid { size, channels, bbox, data })
}

/// The bytes of `grid` as a `.vol` file (version 3, float32).
pub fn to_bytes(grid: &Grid) -> Result<Vec<u8>, String> {
    if grid.size.iter().any(|s| !(1..=MAX_GRID_SIDE).contains(s)) {
        return Err(format!("a side of {:?} voxels is not 1 to {MAX_GRID_SIDE}", grid.size));
    }
    if !(1..=MAX_CHANNELS).contains(&grid.channels) {
        return Err(format!("{} channels; a grid has 1 to {MAX_CHANNELS}", grid.channels));
    }
    let len = grid.size.iter().map(|&s| s as usize).product::<usize>() * grid.channels as usize;
    if len != grid.data.len() {
        return Err(format!("{} values for {:?} voxels of {} channels ({len})", grid.data.len(), grid.size, grid.channels));
    }
    let mut out = Vec::with_capacity(HEADER_BYTES + 4 * len);
    out.extend_from_slice(b"VOL\x03");
    out.extend_from_slice(&1i32.to_le_bytes());
    for v in grid.size.iter().chain([&grid.channels]) {
        out.extend_from_slice(&(*v as i32).to_le_bytes());
    }
    for v in grid.bbox.iter().chain(&grid.data) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

/// Writes `grid` as a `.vol` file atomically.
pub fn write(path: &Path, grid: &Grid) -> Result<(), VolError> {
    let bytes = to_bytes(grid).map_err(|reason| VolError::Invalid { path: path.into(), reason })?;
    crate::image::write_atomic(path, |tmp| {
        let mut f = std::fs::File::create(tmp)?;
        f.write_all(&bytes)?;
        f.flush()
    })
    .map_err(|e| io_error(path, e))
}

fn io_error(path: &Path, e: std::io::Error) -> VolError {
    if e.kind() == std::io::ErrorKind::NotFound {
        VolError::NotFound(path.into())
    } else {
        VolError::Io { path: path.into(), source: e }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("vkinverse-vol-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    fn grid() -> Grid {
        Grid { size: [3, 2, 2], channels: 3, bbox: [-1.0, -1.0, -0.5, 1.0, 1.0, 0.5], data: (0..36).map(|i| i as f32 * 0.25).collect() }
    }

    /// The header of `grid` with its fields as Mitsuba's `VolumeGrid::write` puts them.
    #[test]
    fn the_layout_is_mitsubas() {
        let bytes = to_bytes(&grid()).unwrap();
        assert_eq!(&bytes[..4], b"VOL\x03");
        let ints: Vec<i32> = (0..5).map(|i| i32::from_le_bytes(bytes[4 + 4 * i..8 + 4 * i].try_into().unwrap())).collect();
        assert_eq!(ints, [1, 3, 2, 2, 3]);
        assert_eq!(f32::from_le_bytes(bytes[24..28].try_into().unwrap()), -1.0);
        assert_eq!(f32::from_le_bytes(bytes[44..48].try_into().unwrap()), 0.5);
        assert_eq!(bytes.len(), HEADER_BYTES + 36 * 4);
        // Voxel (1, 0, 0) channel 2 is the fifth value after the header's.
        assert_eq!(f32::from_le_bytes(bytes[48 + 20..48 + 24].try_into().unwrap()), 5.0 * 0.25);
        assert_eq!(grid().array_shape(), vec![2, 2, 3, 3]);
    }

    #[test]
    fn round_trip_leaves_no_temporary_file() {
        let p = scratch("rt.vol");
        write(&p, &grid()).unwrap();
        assert_eq!(read(&p).unwrap(), grid());
        let leftovers = fs::read_dir(p.parent().unwrap()).unwrap().filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().contains(".tmp"));
        assert_eq!(leftovers.count(), 0);
        let bad = Grid { data: vec![0.0; 5], ..grid() };
        assert!(write(&scratch("never.vol"), &bad).unwrap_err().to_string().contains("5 values"));
        assert!(!scratch("never.vol").exists());
    }

    fn error_of(bytes: &[u8]) -> String {
        let p = Path::new("bad.vol");
        let e = parse_bytes(bytes, p).unwrap_err().to_string();
        assert!(e.starts_with("bad.vol: ") && !e.contains('\n'), "{e}");
        e
    }

    fn with_int(at: usize, v: i32) -> Vec<u8> {
        let mut b = to_bytes(&grid()).unwrap();
        b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        b
    }

    #[test]
    fn malformed_files_give_one_line_errors() {
        let good = to_bytes(&grid()).unwrap();
        assert!(matches!(read(Path::new("/nonexistent/x.vol")), Err(VolError::NotFound(_))));
        assert!(error_of(b"").contains("bad magic"));
        assert!(error_of(b"\x93NUMPY\x01\x00").contains("bad magic"));
        assert!(error_of(&good[..20]).contains("ends inside the 48-byte header (20 bytes)"));
        let mut v2 = good.clone();
        v2[3] = 2;
        assert!(error_of(&v2).contains("version 2"));
        assert!(error_of(&with_int(4, 2)).contains("encoding 2"));
        assert!(error_of(&with_int(8, 0)).contains("x has 0 voxels"));
        assert!(error_of(&with_int(12, -5)).contains("y has -5 voxels"));
        assert!(error_of(&with_int(16, i32::MAX)).contains("z has 2147483647 voxels"));
        let mut huge = with_int(8, 1024);
        huge[12..16].copy_from_slice(&1024i32.to_le_bytes());
        huge[16..20].copy_from_slice(&1024i32.to_le_bytes());
        assert!(error_of(&huge).contains("1073741824 voxels; at most 16777216"));
        assert!(error_of(&with_int(20, 0)).contains("0 channels"));
        assert!(error_of(&with_int(20, -1)).contains("-1 channels"));
        assert!(error_of(&good[..good.len() - 6]).contains("truncated data: 138 of 144 bytes"));
        let mut extra = good.clone();
        extra.push(0);
        assert!(error_of(&extra).contains("1 bytes after"));
        let mut nan = good.clone();
        // Voxel (2, 1, 0) of 3 × 2 × 2 is the sixth; its channel 1 the 17th value.
        let (x, y, nx, c) = (2, 1, 3, 3);
        let at = HEADER_BYTES + 4 * ((y * nx + x) * c + 1);
        nan[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(error_of(&nan).contains("voxel (2, 1, 0) channel 1 is NaN"), "{}", error_of(&nan));
        let mut inf = good;
        inf[HEADER_BYTES..HEADER_BYTES + 4].copy_from_slice(&f32::NEG_INFINITY.to_le_bytes());
        assert!(error_of(&inf).contains("voxel (0, 0, 0) channel 0 is -inf"));
    }
}
