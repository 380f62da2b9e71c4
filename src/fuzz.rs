//! Fuzz targets: one function per input format, taking arbitrary bytes the way a user's file
//! would reach vkinverse, and running everything that reading such a file runs on the CPU
//! (parsing, the checks, the BVH build for meshes). A target may return an error; it must
//! never panic, abort, hang or allocate without bound.
//!
//! The libFuzzer targets in `fuzz/` call [`Fixture::run`] (`scripts/fuzz.sh` runs them for a
//! given time), and the test suite runs the same targets on mutated seeds for a short time
//! and replays every file in `tests/data/fuzz/<target>/`.

use crate::scene::{LoadOptions, Scene};
use std::fs;
use std::io;
use std::path::{Path, PathBuf};

/// An input format under fuzzing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    Toml,
    Gltf,
    Glb,
    Xml,
    Ply,
    Obj,
    Exr,
    Hdr,
    Npy,
    Vol,
}

impl Target {
    pub const ALL: [Target; 10] =
        [Target::Toml, Target::Gltf, Target::Glb, Target::Xml, Target::Ply, Target::Obj, Target::Exr, Target::Hdr, Target::Npy, Target::Vol];

    /// The target's name, which is also its files' extension.
    pub fn name(self) -> &'static str {
        match self {
            Target::Toml => "toml",
            Target::Gltf => "gltf",
            Target::Glb => "glb",
            Target::Xml => "xml",
            Target::Ply => "ply",
            Target::Obj => "obj",
            Target::Exr => "exr",
            Target::Hdr => "hdr",
            Target::Npy => "npy",
            Target::Vol => "vol",
        }
    }

    pub fn from_name(name: &str) -> Option<Target> {
        Target::ALL.into_iter().find(|t| t.name() == name)
    }
}

/// Where the scene targets' inputs are written: a temporary directory holding (as links)
/// every file that the repository's scenes refer to, so that a seed's meshes, textures and
/// buffers resolve and its mutations reach past the first reference.
pub struct Fixture {
    dir: PathBuf,
}

/// The directories whose files seed the targets and which the fixture mirrors.
const SEED_DIRS: [&str; 2] = ["scenes", "tests/data"];

impl Fixture {
    /// A fixture for the repository at `repo` in a new temporary directory.
    pub fn new(repo: &Path) -> io::Result<Fixture> {
        let dir = std::env::temp_dir().join(format!("vkinverse-fuzz-{}-{}", std::process::id(), unique()));
        fs::create_dir_all(&dir)?;
        for seeds in SEED_DIRS {
            for d in directories(&repo.join(seeds))? {
                merge_links(&d, &dir, 0)?;
            }
        }
        fs::write(dir.join("wrap-obj.toml"), WRAP_OBJ)?;
        fs::write(dir.join("wrap-ply.xml"), WRAP_PLY)?;
        Ok(Fixture { dir })
    }

    /// Runs `target` on `data`: `Ok` or the one-line error that a user would see.
    pub fn run(&self, target: Target, data: &[u8]) -> Result<(), String> {
        let input = self.dir.join(format!("input.{}", target.name()));
        let scene = |path: &Path| -> Result<(), String> {
            let scene = Scene::load_with(path, &LoadOptions::default()).map_err(|e| crate::error::one_line(&e))?;
            let geometry = scene.flatten();
            if !geometry.indices.is_empty() {
                let bvh = crate::bvh::CwBvh::build(&geometry.positions, &geometry.indices);
                assert_eq!(bvh.triangles.len(), geometry.indices.len());
            }
            Ok(())
        };
        let image = |image: crate::image::Image| {
            assert_eq!(image.data.len(), image.width as usize * image.height as usize);
        };
        match target {
            Target::Toml | Target::Gltf | Target::Glb | Target::Xml => {
                fs::write(&input, data).map_err(|e| e.to_string())?;
                scene(&input)
            }
            Target::Obj => {
                fs::write(&input, data).map_err(|e| e.to_string())?;
                scene(&self.dir.join("wrap-obj.toml"))
            }
            Target::Ply => {
                fs::write(&input, data).map_err(|e| e.to_string())?;
                scene(&self.dir.join("wrap-ply.xml"))
            }
            Target::Exr => crate::image::decode_exr(data, &input).map(image).map_err(|e| crate::error::one_line(&e)),
            Target::Hdr => crate::image::decode_hdr(data, &input).map(image).map_err(|e| crate::error::one_line(&e)),
            Target::Npy => crate::npy::parse_bytes(data, &input)
                .map(|a| assert_eq!(Some(a.data.len()), a.shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d))))
                .map_err(|e| crate::error::one_line(&e)),
            Target::Vol => crate::vol::parse_bytes(data, &input)
                .map(|g| assert_eq!(g.data.len(), g.size.iter().map(|&s| s as usize).product::<usize>() * g.channels as usize))
                .map_err(|e| crate::error::one_line(&e)),
        }
    }

    /// The fixture's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Drop for Fixture {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.dir);
    }
}

/// The seed files of `target` in the repository at `repo`: every file with its extension
/// under `scenes/` and `tests/data/`.
pub fn seeds(repo: &Path, target: Target) -> io::Result<Vec<(String, Vec<u8>)>> {
    let mut out = Vec::new();
    for seeds in SEED_DIRS {
        for d in directories(&repo.join(seeds))? {
            for entry in fs::read_dir(&d)? {
                let path = entry?.path();
                if path.is_file() && path.extension().is_some_and(|e| e.eq_ignore_ascii_case(target.name())) {
                    let name = path.strip_prefix(repo).unwrap_or(&path).to_string_lossy().replace(['/', '\\'], "_");
                    out.push((name, fs::read(&path)?));
                }
            }
        }
    }
    out.sort();
    Ok(out)
}

/// A TOML scene around the OBJ target's input.
const WRAP_OBJ: &str = r#"
[film]
width = 8
height = 8

[[sensors]]
origin = [0.0, 0.0, 5.0]
target = [0.0, 0.0, 0.0]
fov_y = 40.0

[[materials]]
name = "m"
base_color = [0.5, 0.5, 0.5]

[[meshes]]
file = "input.obj"
material = "m"
"#;

/// A Mitsuba scene around the PLY target's input.
const WRAP_PLY: &str = r#"<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
  </sensor>
  <shape type="ply"><string name="filename" value="input.ply"/></shape>
</scene>
"#;

/// `dir` and every directory below it, in a stable order.
fn directories(dir: &Path) -> io::Result<Vec<PathBuf>> {
    let mut out = vec![dir.to_path_buf()];
    let mut i = 0;
    while i < out.len() {
        let mut subs: Vec<PathBuf> = fs::read_dir(&out[i])?.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_dir()).collect();
        subs.sort();
        out.extend(subs);
        i += 1;
    }
    Ok(out)
}

/// Links every file of `src` into `dst` (subdirectories merged; the first file of a name
/// wins).
fn merge_links(src: &Path, dst: &Path, depth: u32) -> io::Result<()> {
    if depth > 8 {
        return Ok(());
    }
    for entry in fs::read_dir(src)? {
        let path = entry?.path();
        let Some(name) = path.file_name() else { continue };
        let to = dst.join(name);
        if path.is_dir() {
            fs::create_dir_all(&to)?;
            merge_links(&path, &to, depth + 1)?;
        } else if path.is_file() && !to.exists() {
            link(&path, &to)?;
        }
    }
    Ok(())
}

#[cfg(unix)]
fn link(from: &Path, to: &Path) -> io::Result<()> {
    std::os::unix::fs::symlink(fs::canonicalize(from)?, to)
}

#[cfg(not(unix))]
fn link(from: &Path, to: &Path) -> io::Result<()> {
    fs::copy(from, to).map(|_| ())
}

fn unique() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A mutation of `seed` (and sometimes of `other`) by `rng`, the way byte-level fuzzers
/// mutate: flipped bits, replaced or repeated bytes, interesting numbers, cut or spliced
/// ranges, and digits grown into huge or negative numbers (text formats check values).
pub fn mutate(seed: &[u8], other: &[u8], rng: &mut u64) -> Vec<u8> {
    let mut next = move || {
        *rng ^= *rng << 13;
        *rng ^= *rng >> 7;
        *rng ^= *rng << 17;
        *rng
    };
    let mut out = seed.to_vec();
    let rounds = 1 + next() % 4;
    for _ in 0..rounds {
        let len = out.len().max(1) as u64;
        let at = (next() % len) as usize;
        match next() % 8 {
            0 if !out.is_empty() => out[at] ^= 1 << (next() % 8),
            1 if !out.is_empty() => out[at] = next() as u8,
            2 => {
                let n = (next() % 16) as usize;
                let end = (at + n).min(out.len());
                out.drain(at.min(end)..end);
            }
            3 => {
                let n = ((next() % 64) as usize).min(out.len() - at.min(out.len()));
                let piece: Vec<u8> = out[at.min(out.len())..at.min(out.len()) + n].to_vec();
                let times = 1 + next() % 8;
                for _ in 0..times {
                    out.splice(at.min(out.len())..at.min(out.len()), piece.iter().copied());
                }
            }
            4 => {
                const WORDS: [&[u8]; 10] = [b"1e20", b"-1", b"0", b"nan", b"inf", b"4294967295", b"\xff\xff\xff\x7f", b"\0\0\0\0", b"-0.0", b"99999999999"];
                let w = WORDS[(next() % WORDS.len() as u64) as usize];
                let at = at.min(out.len());
                out.splice(at..at, w.iter().copied());
            }
            5 if !other.is_empty() => {
                let from = (next() % other.len() as u64) as usize;
                let n = ((next() % 256) as usize).min(other.len() - from);
                let at = at.min(out.len());
                out.splice(at..at, other[from..from + n].iter().copied());
            }
            6 if !out.is_empty() => {
                let n = 4.min(out.len() - at);
                let v = [0u32, 1, 0x7fff_ffff, 0xffff_ffff, 0x8000_0000, 65536][(next() % 6) as usize].to_le_bytes();
                out[at..at + n].copy_from_slice(&v[..n]);
            }
            _ => out.truncate(at),
        }
    }
    out
}
