//! `.npy` float32 arrays (through the `npyz` crate): the gradient streams `vkinverse
//! replay` reads and the trajectories it writes, and checkpoints. Only what those need:
//! format versions 1.0 and 2.0, dtype `'<f4'`, C order, shapes `(n,)` and `(rows, cols)`.
//!
//! Reading validates everything before returning (magic, version, header, dtype, order,
//! shape, exact data length) and every error is one line naming the file. Writing is atomic
//! ([`crate::image::write_atomic`]), so a reader never sees a half-written array.

use std::fs;
use std::path::{Path, PathBuf};

const MAGIC: &[u8] = b"\x93NUMPY";

/// Errors reading or writing `.npy` files; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    #[error("{}: file not found", .0.display())]
    NotFound(PathBuf),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: not a .npy file (bad magic)", .0.display())]
    BadMagic(PathBuf),
    #[error("{}: unsupported .npy format version {major}.{minor} (expected 1.0 or 2.0)", path.display())]
    Version { path: PathBuf, major: u8, minor: u8 },
    #[error("{}: malformed .npy header: {reason}", path.display())]
    BadHeader { path: PathBuf, reason: String },
    #[error("{}: dtype {found} is not little-endian float32 ('<f4')", path.display())]
    WrongDtype { path: PathBuf, found: String },
    #[error("{}: Fortran-order arrays are not supported (save C order)", .0.display())]
    FortranOrder(PathBuf),
    #[error("{}: shape {found:?} has not 1 to {MAX_AXES} axes", path.display())]
    BadShape { path: PathBuf, found: Vec<usize> },
    #[error("{}: truncated data: {found} of {expected} bytes", path.display())]
    Truncated { path: PathBuf, expected: usize, found: usize },
    #[error("{}: {extra} bytes after the array data", path.display())]
    TrailingData { path: PathBuf, extra: usize },
    #[error("{}: rows of unequal length ({first} and {other})", path.display())]
    Ragged { path: PathBuf, first: usize, other: usize },
}

/// Most axes of an array: three texel axes of a grid parameter and its channels.
pub const MAX_AXES: usize = 4;

/// A float32 array of 1 to [`MAX_AXES`] axes in C order.
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    /// `[n]`, `[rows, cols]`, ...
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

impl Array {
    /// A 2-D array from equally long rows.
    pub fn from_rows(rows: &[Vec<f32>]) -> Option<Array> {
        let cols = rows.first().map_or(0, Vec::len);
        rows.iter().all(|r| r.len() == cols).then(|| Array { shape: vec![rows.len(), cols], data: rows.concat() })
    }

    /// Rows of a 2-D array; a 1-D array is one row.
    pub fn rows(&self) -> Vec<Vec<f32>> {
        let cols = self.shape.last().copied().unwrap_or(0);
        if cols == 0 {
            return vec![Vec::new(); self.shape.first().copied().unwrap_or(0)];
        }
        self.data.chunks(cols).map(<[f32]>::to_vec).collect()
    }
}

/// Reads a `.npy` float32 array.
///
/// ```
/// use vkinverse::npy::{read, write, Array};
/// let path = std::env::temp_dir().join(format!("vkinverse-doc-npy-{}.npy", std::process::id()));
/// let grid = Array { shape: vec![2, 3, 4, 1], data: (0..24).map(|i| i as f32).collect() };
/// write(&path, &grid).unwrap();
/// assert_eq!(read(&path).unwrap(), grid);
/// ```
pub fn read(path: &Path) -> Result<Array, NpyError> {
    let bytes = crate::files::read(path).map_err(|e| io_error(path, e))?;
    parse_bytes(&bytes, path)
}

/// Parses a `.npy` file's bytes; `path` names it in errors.
pub fn parse_bytes(bytes: &[u8], path: &Path) -> Result<Array, NpyError> {
    parse(bytes).map_err(|e| e.at(path))
}

/// Writes a `.npy` float32 array atomically (npyz picks version 1.0, or 2.0 for a header
/// over 64 KiB).
pub fn write(path: &Path, array: &Array) -> Result<(), NpyError> {
    let len: usize = array.shape.iter().product();
    if !(1..=MAX_AXES).contains(&array.shape.len()) || len != array.data.len() {
        return Err(NpyError::BadShape { path: path.into(), found: array.shape.clone() });
    }
    let shape: Vec<u64> = array.shape.iter().map(|&d| d as u64).collect();
    crate::image::write_atomic(path, |tmp| {
        use npyz::WriterBuilder;
        let mut w = npyz::WriteOptions::<f32>::new().default_dtype().shape(&shape).writer(std::io::BufWriter::new(fs::File::create(tmp)?)).begin_nd()?;
        w.extend(array.data.iter().copied())?;
        w.finish()
    })
    .map_err(|e| io_error(path, e))
}

/// Writes 2-D rows atomically.
pub fn write_rows(path: &Path, rows: &[Vec<f32>]) -> Result<(), NpyError> {
    let array = Array::from_rows(rows).ok_or_else(|| NpyError::Ragged {
        path: path.into(),
        first: rows[0].len(),
        other: rows.iter().map(Vec::len).find(|&l| l != rows[0].len()).unwrap_or(0),
    })?;
    write(path, &array)
}

fn io_error(path: &Path, e: std::io::Error) -> NpyError {
    if e.kind() == std::io::ErrorKind::NotFound {
        NpyError::NotFound(path.into())
    } else {
        NpyError::Io { path: path.into(), source: e }
    }
}

/// The header text of `.npy` bytes (after the magic and version checks); None where its
/// declared length runs past the file.
fn header_text(bytes: &[u8]) -> Option<&[u8]> {
    let (start, len): (usize, usize) = match bytes[6] {
        1 => (10, usize::from(u16::from_le_bytes([*bytes.get(8)?, *bytes.get(9)?]))),
        _ => (12, u32::from_le_bytes(bytes.get(8..12)?.try_into().ok()?) as usize),
    };
    bytes.get(start..start.checked_add(len)?)
}

/// The deepest nesting of brackets in a header.
fn nesting(header: &[u8]) -> usize {
    let (mut depth, mut deepest) = (0usize, 0usize);
    for &b in header {
        match b {
            b'(' | b'[' | b'{' => {
                depth += 1;
                deepest = deepest.max(depth);
            }
            b')' | b']' | b'}' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    deepest
}

/// The sides of the header's `'shape': (A, B, ...)`: None where the header has no `'shape'`
/// key (npyz reports that), Some(None) where its value is not a tuple of integers.
fn declared_shape(header: &[u8]) -> Option<Option<Vec<u64>>> {
    let text = String::from_utf8_lossy(header);
    let after = &text[text.find("'shape'")? + "'shape'".len()..];
    let tuple = || -> Option<Vec<u64>> {
        let rest = after.trim_start().strip_prefix(':')?.trim_start().strip_prefix('(')?;
        let close = rest.find(')')?;
        rest[..close].split(',').map(str::trim).filter(|d| !d.is_empty()).map(|d| d.parse::<u64>().ok()).collect()
    };
    Some(tuple())
}

/// A parse error before the path is known.
enum Malformed {
    BadMagic,
    Version(u8, u8),
    Header(String),
    Dtype(String),
    Fortran,
    Shape(Vec<usize>),
    Truncated(usize, usize),
    Trailing(usize),
}

impl Malformed {
    fn at(self, path: &Path) -> NpyError {
        let path = path.to_path_buf();
        match self {
            Malformed::BadMagic => NpyError::BadMagic(path),
            Malformed::Version(major, minor) => NpyError::Version { path, major, minor },
            Malformed::Header(reason) => NpyError::BadHeader { path, reason },
            Malformed::Dtype(found) => NpyError::WrongDtype { path, found },
            Malformed::Fortran => NpyError::FortranOrder(path),
            Malformed::Shape(found) => NpyError::BadShape { path, found },
            Malformed::Truncated(expected, found) => NpyError::Truncated { path, expected, found },
            Malformed::Trailing(extra) => NpyError::TrailingData { path, extra },
        }
    }
}

/// Parses the file's bytes: npyz reads the header; this checks what vkinverse needs
/// (versions 1.0 and 2.0, '<f4', C order, 1 to 4 axes, the exact data length) and puts
/// npyz's messages on one line.
fn parse(bytes: &[u8]) -> Result<Array, Malformed> {
    if bytes.len() < 8 || &bytes[..6] != MAGIC {
        return Err(Malformed::BadMagic);
    }
    if !matches!((bytes[6], bytes[7]), (1, 0) | (2, 0)) {
        return Err(Malformed::Version(bytes[6], bytes[7]));
    }
    // npyz's header parser takes exponential time in nested brackets; a header nests two
    // deep (a dict holding the shape's tuple).
    if let Some(header) = header_text(bytes) {
        let depth = nesting(header);
        if depth > 2 {
            return Err(Malformed::Header(format!("the header nests brackets {depth} deep (a .npy header nests 2)")));
        }
        // npyz multiplies the shape's sides unchecked, in any order (and evaluates arithmetic
        // in them): their product without the zeros must fit.
        match declared_shape(header) {
            Some(Some(shape)) if shape.iter().try_fold(4u64, |acc, &d| acc.checked_mul(d.max(1))).is_none() => {
                return Err(Malformed::Shape(shape.iter().map(|&d| usize::try_from(d).unwrap_or(usize::MAX)).collect()));
            }
            Some(None) => return Err(Malformed::Header("the shape is not a tuple of non-negative integers".into())),
            _ => {}
        }
    }
    let npy = npyz::NpyFile::new(bytes).map_err(|e| match e.kind() {
        std::io::ErrorKind::UnexpectedEof => Malformed::Header("the file ends inside the header".into()),
        _ => Malformed::Header(e.to_string().lines().map(str::trim).collect::<Vec<_>>().join(" ")),
    })?;
    match npy.dtype() {
        npyz::DType::Plain(t) if t.to_string() == "<f4" => {}
        other => return Err(Malformed::Dtype(other.descr())),
    }
    if npy.order() == npyz::Order::Fortran {
        return Err(Malformed::Fortran);
    }
    let shape: Vec<usize> = npy.shape().iter().map(|&d| d as usize).collect();
    if !(1..=MAX_AXES).contains(&shape.len()) {
        return Err(Malformed::Shape(shape));
    }
    let expected = shape.iter().try_fold(4usize, |acc, &d| acc.checked_mul(d)).ok_or_else(|| Malformed::Shape(shape.clone()))?;
    let data = npy.into_inner();
    if data.len() < expected {
        return Err(Malformed::Truncated(expected, data.len()));
    }
    if data.len() > expected {
        return Err(Malformed::Trailing(data.len() - expected));
    }
    let data = data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    Ok(Array { shape, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("vkinverse-npy-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    /// A file as numpy writes it, e.g. `np.save(p, np.arange(6, dtype='<f4').reshape(2, 3))`.
    fn numpy_bytes_v(version: u8, header: &str, data: &[f32]) -> Vec<u8> {
        let prefix = if version == 1 { 10 } else { 12 };
        let mut h = header.to_string();
        while !(prefix + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut out = b"\x93NUMPY".to_vec();
        out.extend_from_slice(&[version, 0]);
        if version == 1 {
            out.extend_from_slice(&(h.len() as u16).to_le_bytes());
        } else {
            out.extend_from_slice(&(h.len() as u32).to_le_bytes());
        }
        out.extend_from_slice(h.as_bytes());
        data.iter().for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
        out
    }

    fn numpy_bytes(header: &str, data: &[f32]) -> Vec<u8> {
        numpy_bytes_v(1, header, data)
    }

    const GOOD: &str = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }";

    #[test]
    fn round_trip_1d_and_2d() {
        let p = scratch("rt.npy");
        let a = Array { shape: vec![2, 3], data: vec![1.0, -2.5, 3.0, f32::MAX, 1e-30, 0.0] };
        write(&p, &a).unwrap();
        assert_eq!(read(&p).unwrap(), a);
        let bytes = fs::read(&p).unwrap();
        assert_eq!((bytes.len() - 24) % 64, 0);
        let b = Array { shape: vec![5], data: vec![0.5; 5] };
        write(&p, &b).unwrap();
        assert_eq!(read(&p).unwrap(), b);
        assert_eq!(read(&p).unwrap().rows(), vec![vec![0.5; 5]]);
        let rows = vec![vec![1.0, 2.0], vec![3.0, 4.0], vec![5.0, 6.0]];
        write_rows(&p, &rows).unwrap();
        assert_eq!(read(&p).unwrap().rows(), rows);
        // No temporary file is left beside the target.
        let leftovers = fs::read_dir(p.parent().unwrap()).unwrap().filter(|e| e.as_ref().unwrap().file_name().to_string_lossy().ends_with(".tmp"));
        assert_eq!(leftovers.count(), 0);
    }

    #[test]
    fn reads_numpy_headers() {
        let data = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let parsed = parse(&numpy_bytes(GOOD, &data)).ok().unwrap();
        // What npyz writes has numpy's layout: the data starts on a 64-byte boundary, after
        // a header that ends in a line break.
        let p = scratch("numpy.npy");
        write(&p, &Array { shape: vec![2, 3], data: data.to_vec() }).unwrap();
        let bytes = fs::read(&p).unwrap();
        assert_eq!(bytes.len() % 64, 24);
        assert_eq!(bytes[bytes.len() - 25], b'\n');
        assert_eq!(parsed.shape, vec![2, 3]);
        assert_eq!(parsed.data, data);
        let one_d = "{'descr': '<f4', 'fortran_order': False, 'shape': (6,), }";
        assert_eq!(parse(&numpy_bytes(one_d, &data)).ok().unwrap().shape, vec![6]);
        // Version 2.0: 4-byte header length.
        let v2 = numpy_bytes_v(2, GOOD, &data);
        assert_eq!(parse(&v2).ok().unwrap().data, data);
    }

    fn error_of(bytes: &[u8]) -> String {
        let p = scratch("bad.npy");
        fs::write(&p, bytes).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(e.starts_with(&p.display().to_string()) && !e.contains('\n'), "{e}");
        e
    }

    #[test]
    fn malformed_files_give_one_line_errors() {
        let data = [0.0f32; 6];
        let missing = read(Path::new("/nonexistent/dir/x.npy")).unwrap_err();
        assert!(matches!(missing, NpyError::NotFound(_)) && missing.to_string().ends_with("file not found"));
        assert!(error_of(b"PK\x03\x04 not numpy").contains("bad magic"));
        assert!(error_of(b"\x93NU").contains("bad magic"));
        let mut v3 = numpy_bytes(GOOD, &data);
        v3[6] = 3;
        assert!(error_of(&v3).contains("version 3.0"));
        let f8 = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }";
        assert!(error_of(&numpy_bytes(f8, &data)).contains("dtype '<f8'"));
        let be = "{'descr': '>f4', 'fortran_order': False, 'shape': (2, 3), }";
        assert!(error_of(&numpy_bytes(be, &data)).contains("dtype '>f4'"));
        let fortran = "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3), }";
        assert!(error_of(&numpy_bytes(fortran, &data)).contains("Fortran"));
        let five_d = "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 1, 2, 3), }";
        assert!(error_of(&numpy_bytes(five_d, &data)).contains("has not 1 to 4 axes"));
        let four_d = "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 2, 3), }";
        assert_eq!(parse(&numpy_bytes(four_d, &data)).ok().map(|a| a.shape), Some(vec![1, 1, 2, 3]));
        let full = numpy_bytes(GOOD, &data);
        assert!(error_of(&full[..full.len() - 5]).contains("truncated data: 19 of 24 bytes"));
        assert!(error_of(&full[..40]).contains("ends inside the header"));
        let mut extra = full.clone();
        extra.extend_from_slice(&[0; 4]);
        assert!(error_of(&extra).contains("4 bytes after"));
        assert!(error_of(&numpy_bytes("{'descr': '<f4'}", &data)).contains("missing"));
        assert!(error_of(&numpy_bytes("[1, 2]", &data)).contains("dict"));
    }

    #[test]
    fn write_rejects_inconsistent_shapes() {
        let p = scratch("never.npy");
        let a = Array { shape: vec![2, 2], data: vec![0.0; 3] };
        assert!(matches!(write(&p, &a), Err(NpyError::BadShape { .. })));
        assert!(matches!(write_rows(&p, &[vec![1.0], vec![1.0, 2.0]]), Err(NpyError::Ragged { .. })));
        assert!(!p.exists());
    }
}
