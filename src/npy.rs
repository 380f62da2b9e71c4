//! `.npy` float32 arrays: the gradient streams `vkinverse replay` reads and the trajectories
//! it writes. Only what those need: format versions 1.0 and 2.0, dtype `'<f4'`, C order,
//! shapes `(n,)` and `(rows, cols)`.
//!
//! Reading validates everything before returning (magic, version, header, dtype, order,
//! shape, exact data length) and every error is one line naming the file. Writing is atomic:
//! the bytes go to a temporary file in the target's directory, which is then renamed over the
//! target, so a reader never sees a half-written array.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

const MAGIC: &[u8] = b"\x93NUMPY";

/// Errors reading or writing `.npy` files; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    #[error("{}: file not found", .0.display())]
    NotFound(PathBuf),
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
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
    #[error("{}: shape {found:?} is not 1-D or 2-D", path.display())]
    BadShape { path: PathBuf, found: Vec<usize> },
    #[error("{}: truncated data: {found} of {expected} bytes", path.display())]
    Truncated {
        path: PathBuf,
        expected: usize,
        found: usize,
    },
    #[error("{}: {extra} bytes after the array data", path.display())]
    TrailingData { path: PathBuf, extra: usize },
    #[error("{}: rows of unequal length ({first} and {other})", path.display())]
    Ragged {
        path: PathBuf,
        first: usize,
        other: usize,
    },
}

/// A 1-D or 2-D float32 array in C order.
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    /// `[n]` or `[rows, cols]`.
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

impl Array {
    /// A 2-D array from equally long rows.
    pub fn from_rows(rows: &[Vec<f32>]) -> Option<Array> {
        let cols = rows.first().map_or(0, Vec::len);
        rows.iter().all(|r| r.len() == cols).then(|| Array {
            shape: vec![rows.len(), cols],
            data: rows.concat(),
        })
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
pub fn read(path: &Path) -> Result<Array, NpyError> {
    let bytes = fs::read(path).map_err(|e| io_error(path, e))?;
    parse(&bytes).map_err(|e| e.at(path))
}

/// Writes a `.npy` float32 array atomically (version 1.0, or 2.0 for a header over 64 KiB).
pub fn write(path: &Path, array: &Array) -> Result<(), NpyError> {
    let at = |e| io_error(path, e);
    let len: usize = array.shape.iter().product();
    if !(1..=2).contains(&array.shape.len()) || len != array.data.len() {
        return Err(NpyError::BadShape {
            path: path.into(),
            found: array.shape.clone(),
        });
    }
    let bytes = encode(array);
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .ok_or_else(|| at(std::io::ErrorKind::InvalidInput.into()))?;
    let tmp = dir.join(format!(
        ".{}.{}.tmp",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut file = fs::File::create(&tmp)?;
        file.write_all(&bytes)?;
        file.sync_all()?;
        fs::rename(&tmp, path)
    })();
    if result.is_err() {
        // Best effort: the temporary file is garbage whether or not it can be removed.
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(at)
}

/// Writes 2-D rows atomically.
pub fn write_rows(path: &Path, rows: &[Vec<f32>]) -> Result<(), NpyError> {
    let array = Array::from_rows(rows).ok_or_else(|| NpyError::Ragged {
        path: path.into(),
        first: rows[0].len(),
        other: rows
            .iter()
            .map(Vec::len)
            .find(|&l| l != rows[0].len())
            .unwrap_or(0),
    })?;
    write(path, &array)
}

fn io_error(path: &Path, e: std::io::Error) -> NpyError {
    if e.kind() == std::io::ErrorKind::NotFound {
        NpyError::NotFound(path.into())
    } else {
        NpyError::Io {
            path: path.into(),
            source: e,
        }
    }
}

fn encode(array: &Array) -> Vec<u8> {
    let shape = match array.shape[..] {
        [n] => format!("({n},)"),
        ref dims => format!(
            "({})",
            dims.iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    // The header ends in '\n' and the data starts on a 64-byte boundary (the format's rule);
    // version 2.0 only where the padded header outgrows version 1.0's 16-bit length.
    let padded_v1 = (10 + header.len() + 1).div_ceil(64) * 64;
    let (version, prefix) = if padded_v1 - 10 <= u16::MAX as usize {
        (1u8, 10)
    } else {
        (2u8, 12)
    };
    let padded = (prefix + header.len() + 1).div_ceil(64) * 64;
    header.extend(std::iter::repeat_n(' ', padded - prefix - header.len() - 1));
    header.push('\n');

    let mut out = Vec::with_capacity(padded + 4 * array.data.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[version, 0]);
    if version == 1 {
        out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    } else {
        out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    }
    out.extend_from_slice(header.as_bytes());
    for x in &array.data {
        out.extend_from_slice(&x.to_le_bytes());
    }
    out
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
            Malformed::Truncated(expected, found) => NpyError::Truncated {
                path,
                expected,
                found,
            },
            Malformed::Trailing(extra) => NpyError::TrailingData { path, extra },
        }
    }
}

fn parse(bytes: &[u8]) -> Result<Array, Malformed> {
    if bytes.len() < 8 || &bytes[..6] != MAGIC {
        return Err(Malformed::BadMagic);
    }
    let (header_len, start) = match (bytes[6], bytes[7]) {
        (1, 0) if bytes.len() >= 10 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        (2, 0) if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        (1, 0) | (2, 0) => {
            return Err(Malformed::Header(
                "file ends inside the header length".into(),
            ))
        }
        (major, minor) => return Err(Malformed::Version(major, minor)),
    };
    let header = bytes
        .get(start..start + header_len)
        .ok_or_else(|| Malformed::Header("file ends inside the header".into()))?;
    let header =
        std::str::from_utf8(header).map_err(|_| Malformed::Header("header is not ASCII".into()))?;
    let (descr, fortran, shape) = parse_header(header)?;
    if descr != "<f4" {
        return Err(Malformed::Dtype(format!("'{descr}'")));
    }
    if fortran {
        return Err(Malformed::Fortran);
    }
    if !(1..=2).contains(&shape.len()) {
        return Err(Malformed::Shape(shape));
    }
    let expected = shape
        .iter()
        .try_fold(4usize, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| Malformed::Shape(shape.clone()))?;
    let data = &bytes[start + header_len..];
    if data.len() < expected {
        return Err(Malformed::Truncated(expected, data.len()));
    }
    if data.len() > expected {
        return Err(Malformed::Trailing(data.len() - expected));
    }
    let data = data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok(Array { shape, data })
}

/// Parses the header's Python dict literal, e.g.
/// `{'descr': '<f4', 'fortran_order': False, 'shape': (3, 4), }`.
fn parse_header(header: &str) -> Result<(String, bool, Vec<usize>), Malformed> {
    let bad = |reason: &str| Malformed::Header(reason.to_string());
    let body = header
        .trim()
        .strip_prefix('{')
        .and_then(|h| h.strip_suffix('}'))
        .ok_or_else(|| bad("not a dict"))?;
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    // Split at top-level commas: the shape tuple has commas of its own.
    let mut depth = 0;
    let mut items = vec![];
    let mut from = 0;
    for (i, c) in body.char_indices() {
        match c {
            '(' => depth += 1,
            ')' => depth -= 1,
            ',' if depth == 0 => {
                items.push(&body[from..i]);
                from = i + 1;
            }
            _ => {}
        }
    }
    items.push(&body[from..]);
    for item in items.iter().map(|s| s.trim()).filter(|s| !s.is_empty()) {
        let (key, value) = item
            .split_once(':')
            .ok_or_else(|| bad("entry without ':'"))?;
        let value = value.trim();
        match unquote(key.trim()) {
            Some("descr") => {
                descr = Some(
                    unquote(value)
                        .ok_or_else(|| bad("descr is not a string"))?
                        .to_string(),
                )
            }
            Some("fortran_order") => {
                fortran = Some(match value {
                    "True" => true,
                    "False" => false,
                    _ => return Err(bad("fortran_order is not True or False")),
                })
            }
            Some("shape") => {
                let inner = value
                    .strip_prefix('(')
                    .and_then(|v| v.strip_suffix(')'))
                    .ok_or_else(|| bad("shape is not a tuple"))?;
                let dims = inner.split(',').map(str::trim).filter(|d| !d.is_empty());
                shape = Some(
                    dims.map(|d| d.trim_end_matches('L').parse::<usize>())
                        .collect::<Result<Vec<_>, _>>()
                        .map_err(|_| bad("shape has a non-integer dimension"))?,
                );
            }
            _ => return Err(bad(&format!("unexpected key {}", key.trim()))),
        }
    }
    match (descr, fortran, shape) {
        (Some(d), Some(f), Some(s)) => Ok((d, f, s)),
        _ => Err(bad("missing descr, fortran_order or shape")),
    }
}

fn unquote(s: &str) -> Option<&str> {
    s.strip_prefix('\'')
        .and_then(|s| s.strip_suffix('\''))
        .or_else(|| s.strip_prefix('"').and_then(|s| s.strip_suffix('"')))
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
        data.iter()
            .for_each(|x| out.extend_from_slice(&x.to_le_bytes()));
        out
    }

    fn numpy_bytes(header: &str, data: &[f32]) -> Vec<u8> {
        numpy_bytes_v(1, header, data)
    }

    const GOOD: &str = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }";

    #[test]
    fn round_trip_1d_and_2d() {
        let p = scratch("rt.npy");
        let a = Array {
            shape: vec![2, 3],
            data: vec![1.0, -2.5, 3.0, f32::MAX, 1e-30, 0.0],
        };
        write(&p, &a).unwrap();
        assert_eq!(read(&p).unwrap(), a);
        let bytes = fs::read(&p).unwrap();
        assert_eq!((bytes.len() - 24) % 64, 0);
        let b = Array {
            shape: vec![5],
            data: vec![0.5; 5],
        };
        write(&p, &b).unwrap();
        assert_eq!(read(&p).unwrap(), b);
        assert_eq!(read(&p).unwrap().rows(), vec![vec![0.5; 5]]);
        let rows = vec![vec![1.0, 2.0], vec![3.0, 4.0], vec![5.0, 6.0]];
        write_rows(&p, &rows).unwrap();
        assert_eq!(read(&p).unwrap().rows(), rows);
        // No temporary file is left beside the target.
        let leftovers = fs::read_dir(p.parent().unwrap()).unwrap().filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".tmp")
        });
        assert_eq!(leftovers.count(), 0);
    }

    #[test]
    fn reads_numpy_headers() {
        let data = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let parsed = parse(&numpy_bytes(GOOD, &data)).ok().unwrap();
        assert_eq!(parsed.shape, vec![2, 3]);
        assert_eq!(parsed.data, data);
        let one_d = "{'descr': '<f4', 'fortran_order': False, 'shape': (6,), }";
        assert_eq!(
            parse(&numpy_bytes(one_d, &data)).ok().unwrap().shape,
            vec![6]
        );
        // Version 2.0: 4-byte header length.
        let v2 = numpy_bytes_v(2, GOOD, &data);
        assert_eq!(parse(&v2).ok().unwrap().data, data);
    }

    fn error_of(bytes: &[u8]) -> String {
        let p = scratch("bad.npy");
        fs::write(&p, bytes).unwrap();
        let e = read(&p).unwrap_err().to_string();
        assert!(
            e.starts_with(&p.display().to_string()) && !e.contains('\n'),
            "{e}"
        );
        e
    }

    #[test]
    fn malformed_files_give_one_line_errors() {
        let data = [0.0f32; 6];
        let missing = read(Path::new("/nonexistent/dir/x.npy")).unwrap_err();
        assert!(
            matches!(missing, NpyError::NotFound(_))
                && missing.to_string().ends_with("file not found")
        );
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
        let three_d = "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 2, 3), }";
        assert!(error_of(&numpy_bytes(three_d, &data)).contains("not 1-D or 2-D"));
        let full = numpy_bytes(GOOD, &data);
        assert!(error_of(&full[..full.len() - 5]).contains("truncated data: 19 of 24 bytes"));
        assert!(error_of(&full[..40]).contains("ends inside the header"));
        let mut extra = full.clone();
        extra.extend_from_slice(&[0; 4]);
        assert!(error_of(&extra).contains("4 bytes after"));
        assert!(error_of(&numpy_bytes("{'descr': '<f4'}", &data)).contains("missing"));
        assert!(error_of(&numpy_bytes("[1, 2]", &data)).contains("not a dict"));
    }

    #[test]
    fn write_rejects_inconsistent_shapes() {
        let p = scratch("never.npy");
        let a = Array {
            shape: vec![2, 2],
            data: vec![0.0; 3],
        };
        assert!(matches!(write(&p, &a), Err(NpyError::BadShape { .. })));
        assert!(matches!(
            write_rows(&p, &[vec![1.0], vec![1.0, 2.0]]),
            Err(NpyError::Ragged { .. })
        ));
        assert!(!p.exists());
    }
}
