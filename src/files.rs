//! Reading input files: regular files only (a device such as `/dev/zero`, a pipe or a
//! directory is refused instead of read without end), and no more than their size, up to
//! [`MAX_INPUT_BYTES`].

use std::io::Read;
use std::path::Path;

/// Largest input file read (a scene, mesh, image, buffer or array): far beyond the bundled
/// and sample scenes, small enough to be refused before memory runs out.
pub const MAX_INPUT_BYTES: u64 = 2 << 30;

/// The bytes of the regular file at `path`, at most `max` of them: an error (whose kind is
/// `InvalidInput`, and whose message says what the path is) for anything else.
pub fn read_bounded(path: &Path, max: u64) -> std::io::Result<Vec<u8>> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        let what = if meta.is_dir() { "a directory" } else { "not a regular file (a device, pipe or socket)" };
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, what));
    }
    if meta.len() > max {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("{} bytes, more than the {max} read at most", meta.len())));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    // A file that grows while read is cut at the bound.
    std::fs::File::open(path)?.take(max).read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// The first `len` bytes of the regular file at `path` (all of it when shorter).
pub fn read_prefix(path: &Path, len: u64) -> std::io::Result<Vec<u8>> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a regular file"));
    }
    let mut bytes = Vec::with_capacity(len.min(meta.len()) as usize);
    std::fs::File::open(path)?.take(len).read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// [`read_bounded`] at [`MAX_INPUT_BYTES`].
pub fn read(path: &Path) -> std::io::Result<Vec<u8>> {
    read_bounded(path, MAX_INPUT_BYTES)
}

/// [`read`] as UTF-8 text.
pub fn read_to_string(path: &Path) -> std::io::Result<String> {
    String::from_utf8(read(path)?).map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_directories_and_oversized_files_are_refused() {
        let e = read(Path::new("/dev/zero")).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
        assert!(e.to_string().contains("not a regular file"), "{e}");
        assert!(read(&std::env::temp_dir()).unwrap_err().to_string().contains("directory"));
        let path = std::env::temp_dir().join(format!("vkinverse-files-{}", std::process::id()));
        std::fs::write(&path, b"0123456789").unwrap();
        assert_eq!(read(&path).unwrap(), b"0123456789");
        assert!(read_bounded(&path, 4).unwrap_err().to_string().contains("10 bytes"));
        std::fs::remove_file(&path).unwrap();
    }
}
