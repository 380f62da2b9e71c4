//! The run directory of `optimise -o OUTDIR`: one run at a time, never a mix of two runs'
//! files, and a checkpoint that survives a kill at any instant.
//!
//! - **Lock.** A run holds an advisory lock on `OUTDIR/.lock` (`File::try_lock`) for its
//!   whole life; a second run into the directory fails at once, naming it. The operating
//!   system drops the lock when the process ends, however it ends.
//! - **A used directory** (one holding any of [`RUN_FILES`]) is refused unless the run
//!   resumes it ([`Mode::Resume`]) or replaces it ([`Mode::Overwrite`]); a refusal deletes
//!   nothing. Replacing removes the old run's files (those of [`RUN_FILES`] and every
//!   sensor's pictures, [`crate::preview::SENSOR_FILES`]) before the new run writes any,
//!   the checkpoint pointer first, so a kill midway leaves neither a resumable old run nor
//!   a mix.
//! - **Checkpoints** are numbered directories `checkpoint/<iteration>/` (θ and the
//!   optimiser state as `.npy`, `state.json`, the log rows so far as `log.csv`, the
//!   optimiser diagnostics so far as `optimiser.csv`) and the
//!   pointer file `checkpoint/current`, which names the committed one. A commit writes the
//!   new directory completely (each file flushed), replaces the pointer atomically
//!   (rename), and only then removes older directories: at every instant the pointer names
//!   a complete checkpoint. Directories the pointer does not name are leftovers of an
//!   interrupted commit and are ignored (and removed by the next commit).
//!
//! Debug builds stop at named steps for tests ([`crate::config::DebugStops`]; the command
//! line's `VKINVERSE_DEBUG_ABORT_AT=STEP[:N]` aborts the process the N-th time, default 1,
//! it reaches STEP, `VKINVERSE_DEBUG_PAUSE_AT=STEP` prints `vkinverse: paused at STEP` to
//! stderr and sleeps a minute there). The steps:
//! `run.locked` (lock held, nothing written), `overwrite.cleared` (the old run's pointer
//! removed, its other files not yet), `checkpoint.written` (new checkpoint directory
//! complete, pointer not yet replaced), `checkpoint.committed` (pointer replaced, older
//! directories not yet removed), `run.checkpointed` (a finished run's last checkpoint
//! committed, its outputs not yet written).

use crate::config::DebugStops;
use crate::error::{Error, Result};
use crate::image::write_bytes_atomic;
use serde::{Deserialize, Serialize};
use std::fs::{self, File};
use std::path::{Path, PathBuf};

/// What a run writes into its directory; a directory holding any of them holds a run.
pub const RUN_FILES: [&str; 9] =
    ["checkpoint", "log.csv", "summary.json", "params", "final.exr", "final", "error_vs_time.png", "optimiser.csv", "optimiser.png"];

/// What only a single optimisation writes at the top of its directory.
const SINGLE_RUN_FILES: [&str; 6] = ["checkpoint", "log.csv", "summary.json", "params", "final.exr", "final"];

/// What a comparison or a batch writes at the top of its directory.
const TABLE_FILES: [&str; 3] = ["compare.json", "compare.csv", "results.csv"];

/// How a run treats a directory that already holds a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Refuse it.
    New,
    /// Continue it from its committed checkpoint.
    Resume,
    /// Remove it first.
    Overwrite,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> Error + '_ {
    move |source| Error::Io { path: path.to_path_buf(), source }
}

/// How many times this process reached each step, for [`DebugStops::abort_at`]'s count.
#[cfg(debug_assertions)]
static REACHED: std::sync::Mutex<Vec<(String, u32)>> = std::sync::Mutex::new(Vec::new());

/// Stops the process at `step` when a debug build is told to by `stops` (module
/// documentation).
fn debug_point(stops: &DebugStops, step: &str) {
    #[cfg(debug_assertions)]
    {
        let count = {
            let mut reached = REACHED.lock().unwrap_or_else(|e| e.into_inner());
            match reached.iter_mut().find(|(s, _)| s == step) {
                Some((_, n)) => {
                    *n += 1;
                    *n
                }
                None => {
                    reached.push((step.to_string(), 1));
                    1
                }
            }
        };
        if let Some((name, nth)) = &stops.abort_at {
            if name == step && *nth == count {
                eprintln!("vkinverse: aborting at {step}");
                std::process::abort();
            }
        }
        if stops.pause_at.as_deref() == Some(step) {
            eprintln!("vkinverse: paused at {step}");
            std::thread::sleep(std::time::Duration::from_secs(60));
        }
    }
    #[cfg(not(debug_assertions))]
    let _ = (stops, step);
}

/// A run directory held by this process (the lock is released on drop).
pub struct RunDir {
    pub path: PathBuf,
    _lock: File,
    stops: DebugStops,
}

impl RunDir {
    /// Stops the process at `step` where the debug stops say so.
    pub fn debug_point(&self, step: &str) {
        debug_point(&self.stops, step);
    }

    /// Creates (if need be) and locks `path`, then applies `mode` to a run found there. A
    /// directory that holds a comparison's or a batch's table is refused whatever the mode:
    /// replacing its run files would leave a mix of the two.
    pub fn open(path: &Path, mode: Mode, stops: &DebugStops) -> Result<RunDir> {
        let dir = Self::lock(path, stops)?;
        if let Some(table) = TABLE_FILES.iter().find(|f| path.join(f).exists()) {
            return Err(Error::Invalid(format!("{}: holds a comparison's or a batch's results ({table}); give an optimisation a directory of its own", path.display())));
        }
        dir.apply(mode)
    }

    /// Opens and locks the output directory of a comparison or a batch, whose runs have
    /// directories of their own below it. A new one is refused where the directory holds
    /// results already; a directory that holds a single optimisation's run is refused
    /// unless `mode` replaces it (a resume does not continue it as a comparison).
    pub fn open_table(path: &Path, mode: Mode, stops: &DebugStops) -> Result<RunDir> {
        let dir = Self::lock(path, stops)?;
        let single: Vec<&str> = SINGLE_RUN_FILES.iter().copied().filter(|f| path.join(f).exists()).collect();
        let table: Vec<&str> = TABLE_FILES.iter().copied().filter(|f| path.join(f).exists()).collect();
        match mode {
            Mode::Overwrite if !single.is_empty() => dir.clear().map(|()| dir),
            _ if !single.is_empty() => Err(Error::Invalid(format!(
                "{}: holds an optimisation's run ({}); give --overwrite to replace it, or another directory",
                path.display(),
                single.join(", ")
            ))),
            Mode::New if !table.is_empty() => Err(Error::Invalid(format!(
                "{}: holds results ({}); give --resume to continue them or --overwrite to replace them",
                path.display(),
                table.join(", ")
            ))),
            _ => Ok(dir),
        }
    }

    /// Creates (if need be) and locks `path`.
    fn lock(path: &Path, stops: &DebugStops) -> Result<RunDir> {
        if path.exists() && !path.is_dir() {
            return Err(Error::Invalid(format!("{}: is a file, not a directory", path.display())));
        }
        fs::create_dir_all(path).map_err(io(path))?;
        let lock_path = path.join(".lock");
        let lock = File::options().create(true).truncate(false).write(true).open(&lock_path).map_err(io(&lock_path))?;
        match lock.try_lock() {
            Ok(()) => {}
            Err(fs::TryLockError::WouldBlock) => {
                return Err(Error::Invalid(format!("{}: another run is using this directory (it holds {})", path.display(), lock_path.display())))
            }
            Err(fs::TryLockError::Error(e)) => return Err(io(&lock_path)(e)),
        }
        let dir = RunDir { path: path.to_path_buf(), _lock: lock, stops: stops.clone() };
        dir.debug_point("run.locked");
        Ok(dir)
    }

    /// Applies `mode` to the run this locked directory holds, if any.
    fn apply(self, mode: Mode) -> Result<RunDir> {
        let path = self.path.clone();
        let (dir, path) = (self, path.as_path());
        let used: Vec<&str> = RUN_FILES.iter().copied().filter(|f| path.join(f).exists()).collect();
        match mode {
            Mode::New if !used.is_empty() => {
                Err(Error::Invalid(format!("{}: holds a run ({}); give --resume to continue it or --overwrite to replace it", path.display(), used.join(", "))))
            }
            Mode::Resume if !dir.pointer().exists() => {
                Err(Error::Invalid(format!("{}: no committed checkpoint to resume ({} is missing)", path.display(), dir.pointer().display())))
            }
            Mode::Overwrite => dir.clear().map(|()| dir),
            _ => Ok(dir),
        }
    }

    fn checkpoints(&self) -> PathBuf {
        self.path.join("checkpoint")
    }

    fn pointer(&self) -> PathBuf {
        pointer_path(&self.path)
    }

    /// Removes the old run's files: the checkpoint pointer first.
    fn clear(&self) -> Result<()> {
        let pointer = self.pointer();
        if pointer.exists() {
            fs::remove_file(&pointer).map_err(io(&pointer))?;
        }
        self.debug_point("overwrite.cleared");
        let pictures = fs::read_dir(&self.path).map_err(io(&self.path))?;
        let mut names: Vec<String> = RUN_FILES.iter().map(|f| f.to_string()).collect();
        for entry in pictures {
            let name = entry.map_err(io(&self.path))?.file_name().to_string_lossy().into_owned();
            if crate::preview::is_sensor_file(&name) {
                names.push(name);
            }
        }
        for name in names {
            let p = self.path.join(name);
            let removed = if p.is_dir() { fs::remove_dir_all(&p) } else { fs::remove_file(&p) };
            match removed {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(io(&p)(e)),
                _ => {}
            }
        }
        Ok(())
    }

    /// The directory of the committed checkpoint, if any.
    pub fn committed(&self) -> Result<Option<PathBuf>> {
        let pointer = self.pointer();
        let name = match fs::read_to_string(&pointer) {
            Ok(text) => text.trim().to_string(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(io(&pointer)(e)),
        };
        if name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.') {
            return Err(Error::Invalid(format!("{}: does not name a checkpoint directory", pointer.display())));
        }
        Ok(Some(self.checkpoints().join(name)))
    }

    /// Commits checkpoint `name`: `write` fills its fresh directory, then the pointer is
    /// replaced and older checkpoint directories are removed.
    pub fn commit(&self, name: &str, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
        let root = self.checkpoints();
        let dir = root.join(name);
        if self.committed()?.as_deref() == Some(dir.as_path()) {
            // Removing it first would leave nothing resumable until the new one is written.
            return Err(Error::Invalid(format!("{}: the committed checkpoint; a checkpoint is not written over it", dir.display())));
        }
        if dir.exists() {
            // A leftover of an interrupted commit (the pointer never named it).
            fs::remove_dir_all(&dir).map_err(io(&dir))?;
        }
        fs::create_dir_all(&dir).map_err(io(&dir))?;
        write(&dir)?;
        sync_dir(&dir)?;
        self.debug_point("checkpoint.written");
        write_bytes_atomic(&self.pointer(), format!("{name}\n").as_bytes()).map_err(io(&self.pointer()))?;
        sync_dir(&root)?;
        self.debug_point("checkpoint.committed");
        for entry in fs::read_dir(&root).map_err(io(&root))? {
            let entry = entry.map_err(io(&root))?;
            let p = entry.path();
            if p.is_dir() && entry.file_name() != name {
                fs::remove_dir_all(&p).map_err(io(&p))?;
            }
        }
        Ok(())
    }
}

/// Flushes a directory's entries (new files, renames) to disk where the platform can.
fn sync_dir(dir: &Path) -> Result<()> {
    #[cfg(unix)]
    File::open(dir).and_then(|d| d.sync_all()).map_err(io(dir))?;
    #[cfg(not(unix))]
    let _ = dir;
    Ok(())
}

/// Whether the run directory `path` holds a committed checkpoint (its pointer file), read
/// without taking the directory's lock.
pub fn has_checkpoint(path: &Path) -> bool {
    pointer_path(path).exists()
}

/// The checkpoint pointer file of run directory `path`.
fn pointer_path(path: &Path) -> PathBuf {
    path.join("checkpoint").join("current")
}

/// A checkpoint's directory name for `iteration`: sorts by iteration.
pub fn checkpoint_name(iteration: u32) -> String {
    format!("{iteration:010}")
}

/// What identifies a run across `--resume`: the scene's content and parameter set.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunIdentity {
    /// [`crate::scene::Scene::content_hash`] as hex.
    pub scene_hash: String,
    /// Each optimised parameter's name and element count, in θ order.
    pub params: Vec<(String, usize)>,
}

impl RunIdentity {
    /// Why `now` cannot continue a run of `self`, naming the difference; None if it can.
    pub fn mismatch(&self, now: &RunIdentity) -> Option<String> {
        if self.scene_hash != now.scene_hash {
            return Some(format!(
                "the scene's content differs from the checkpoint's (hash {} now, {} then): meshes, materials, lights, sensors or film changed",
                now.scene_hash, self.scene_hash
            ));
        }
        if self.params == now.params {
            return None;
        }
        let show = |p: &[(String, usize)]| p.iter().map(|(n, l)| format!("{n} ({l})")).collect::<Vec<_>>().join(", ");
        let missing: Vec<_> = self.params.iter().filter(|p| !now.params.contains(p)).cloned().collect();
        let added: Vec<_> = now.params.iter().filter(|p| !self.params.contains(p)).cloned().collect();
        Some(match (missing.is_empty(), added.is_empty()) {
            (false, false) => format!("the optimised parameters differ: the checkpoint has {}, the scene has {}", show(&missing), show(&added)),
            (false, true) => format!("the scene no longer optimises {}", show(&missing)),
            (true, false) => format!("the scene also optimises {}, which the checkpoint lacks", show(&added)),
            (true, true) => format!("the optimised parameters are in another order: {} now, {} then", show(&now.params), show(&self.params)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(hash: &str, params: &[(&str, usize)]) -> RunIdentity {
        RunIdentity { scene_hash: hash.into(), params: params.iter().map(|(n, l)| (n.to_string(), *l)).collect() }
    }

    #[test]
    fn mismatches_name_the_difference() {
        let a = id("01", &[("materials.red.base_color", 3)]);
        assert_eq!(a.mismatch(&a), None);
        assert!(a.mismatch(&id("02", &[("materials.red.base_color", 3)])).unwrap().contains("hash 02 now, 01 then"));
        let other = a.mismatch(&id("01", &[("materials.green.base_color", 3)])).unwrap();
        assert!(other.contains("materials.red.base_color (3)") && other.contains("materials.green.base_color (3)"), "{other}");
        let texture = a.mismatch(&id("01", &[("materials.red.base_color", 48)])).unwrap();
        assert!(texture.contains("(48)"), "{texture}");
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("vkinverse-rundir-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn commits_replace_the_pointer_and_then_the_old_directory() {
        let path = scratch("commit");
        let dir = RunDir::open(&path, Mode::New, &DebugStops::default()).unwrap();
        assert_eq!(dir.committed().unwrap(), None);
        dir.commit(&checkpoint_name(3), |d| {
            fs::write(d.join("x"), "3").unwrap();
            Ok(())
        })
        .unwrap();
        // A leftover of an interrupted commit is not the committed checkpoint.
        fs::create_dir_all(path.join("checkpoint").join(checkpoint_name(9))).unwrap();
        let cp = dir.committed().unwrap().unwrap();
        assert_eq!(fs::read_to_string(cp.join("x")).unwrap(), "3");
        dir.commit(&checkpoint_name(6), |d| {
            fs::write(d.join("x"), "6").unwrap();
            Ok(())
        })
        .unwrap();
        let mut names: Vec<_> = fs::read_dir(path.join("checkpoint")).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
        names.sort();
        assert_eq!(names, [checkpoint_name(6), "current".into()]);
        // A failed write leaves the committed checkpoint as it was.
        let failed = dir.commit(&checkpoint_name(9), |_| Err(Error::Invalid("disk full".into())));
        assert!(failed.is_err());
        assert_eq!(fs::read_to_string(dir.committed().unwrap().unwrap().join("x")).unwrap(), "6");
    }

    #[test]
    fn a_second_holder_and_a_used_directory_are_refused() {
        let path = scratch("lock");
        let first = RunDir::open(&path, Mode::New, &DebugStops::default()).unwrap();
        let busy = RunDir::open(&path, Mode::Overwrite, &DebugStops::default()).err().unwrap().to_string();
        assert!(busy.contains("another run") && busy.contains(&path.display().to_string()), "{busy}");
        first.commit("0000000001", |_| Ok(())).unwrap();
        drop(first);
        let used = RunDir::open(&path, Mode::New, &DebugStops::default()).err().unwrap().to_string();
        assert!(used.contains("--resume") && used.contains("checkpoint"), "{used}");
        assert!(path.join("checkpoint/current").exists(), "a refusal deletes nothing");
        RunDir::open(&path, Mode::Resume, &DebugStops::default()).unwrap();
        drop(RunDir::open(&path, Mode::Overwrite, &DebugStops::default()).unwrap());
        assert!(!path.join("checkpoint").exists());
        let none = RunDir::open(&path, Mode::Resume, &DebugStops::default()).err().unwrap().to_string();
        assert!(none.contains("no committed checkpoint"), "{none}");
    }
}
