//! `vkinverse replay`: the GPU optimiser passes run on recorded gradient streams, as the
//! renderer runs them, for studying an optimiser apart from rendering.

use crate::device::Device;
use crate::error::{Error, Result};
use crate::optim::spec::Spec;
use std::path::Path;

pub use crate::optim::Range;

/// The input of `vkinverse replay`, read from `.npy` files and checked: equally long rows,
/// the finite-difference stream of the same shape, finite start values.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayInput {
    pub grads: Vec<Vec<f32>>,
    pub fd_grads: Option<Vec<Vec<f32>>>,
    pub init: Vec<f32>,
    /// The half-sample sums of both streams (the centred variance estimate).
    pub halves: Option<(Vec<Vec<f32>>, Vec<Vec<f32>>)>,
}

impl ReplayInput {
    /// Reads `grads` (`[iterations, n]`), `fd_grads` (the same shape; required when
    /// `needs_fd`) and `init` (n finite values; zeros when absent).
    pub fn load(grads: &Path, fd_grads: Option<&Path>, init: Option<&Path>, needs_fd: bool) -> Result<Self> {
        let bad = |path: &Path, what: String| Error::Invalid(format!("{}: {what}", path.display()));
        let g = crate::npy::read(grads)?;
        if g.shape.len() != 2 {
            return Err(bad(grads, format!("expected shape [iterations, n], got {:?}", g.shape)));
        }
        let n = g.shape[1];
        let fd = match (fd_grads, needs_fd) {
            (Some(p), _) => {
                let a = crate::npy::read(p)?;
                if a.shape != g.shape {
                    return Err(bad(p, format!("shape {:?} differs from the gradients' {:?}", a.shape, g.shape)));
                }
                Some(a.rows())
            }
            (None, true) => return Err(Error::Invalid("--optimiser meta needs FD_GRADS.npy (finite-difference samples) after GRADS.npy".into())),
            (None, false) => None,
        };
        let init = match init {
            Some(p) => {
                let a = crate::npy::read(p)?;
                if a.data.len() != n {
                    return Err(bad(p, format!("{} values, the gradients have {n} per row", a.data.len())));
                }
                if let Some((i, v)) = a.data.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                    return Err(bad(p, format!("value {i} is {v}: start values must be finite")));
                }
                a.data
            }
            None => vec![0.0; n],
        };
        Ok(ReplayInput { grads: g.rows(), fd_grads: fd, init, halves: None })
    }

    /// Reads the half-sample sums of the gradients and of the finite differences, each of
    /// the gradients' shape.
    pub fn load_halves(&mut self, grads: &Path, fd_grads: &Path) -> Result<()> {
        let read = |path: &Path| -> Result<Vec<Vec<f32>>> {
            let a = crate::npy::read(path)?;
            let rows = a.rows();
            if rows.len() != self.grads.len() || rows.iter().any(|r| r.len() != self.init.len()) {
                return Err(Error::Invalid(format!(
                    "{}: shape {:?} differs from the gradients' [{}, {}]",
                    path.display(),
                    a.shape,
                    self.grads.len(),
                    self.init.len()
                )));
            }
            Ok(rows)
        };
        self.halves = Some((read(grads)?, read(fd_grads)?));
        Ok(())
    }

    /// The streams, for the replays.
    pub fn streams(&self) -> crate::optim::replay::Streams<'_> {
        crate::optim::replay::Streams {
            grads: &self.grads,
            fd_grads: self.fd_grads.as_deref(),
            grad_halves: self.halves.as_ref().map(|h| h.0.as_slice()),
            fd_halves: self.halves.as_ref().map(|h| h.1.as_slice()),
        }
    }
}

/// The input files: `grads`, float32 `[iterations, n]` (proportional gradients), and for
/// meta `fd_grads` of the same shape (finite-difference samples); `init`, the `n` start
/// values (zeros without it); `halves`, the sums of half of the pixels of both streams (meta
/// with `var=centred`).
#[derive(Clone, Copy, Debug)]
pub struct Files<'a> {
    pub grads: &'a Path,
    pub fd_grads: Option<&'a Path>,
    pub init: Option<&'a Path>,
    pub halves: Option<(&'a Path, &'a Path)>,
}

/// What a replay produced.
pub struct Replay {
    /// θ before the first step and after each: `[iterations + 1][n]`.
    pub trajectory: Vec<Vec<f32>>,
    pub iterations: usize,
    pub parameters: usize,
    /// Gradient elements that were not finite (skipped: θ unchanged there).
    pub nonfinite: u32,
    diagnostics: Vec<Vec<crate::optim::Diagnostics>>,
}

impl Replay {
    /// Writes each step's optimiser diagnostics as `optimiser.csv` does.
    pub fn write_diagnostics(&self, path: &Path) -> Result<()> {
        let steps: Vec<Vec<(String, crate::optim::Diagnostics)>> =
            self.diagnostics.iter().map(|d| d.iter().map(|d| ("theta".to_string(), *d)).collect()).collect();
        crate::optim::csv::write(path, &steps).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))
    }
}

/// Replays the streams of `files` through optimiser `spec` with learning rate `lr`, θ kept
/// in `range`.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::npy::{write_rows};
/// use vkinverse::replay::{replay, Files, Range};
/// let dir = std::env::temp_dir().join(format!("vkinverse-doc-replay-{}", std::process::id()));
/// std::fs::create_dir_all(&dir).unwrap();
/// // Ten iterations of a constant gradient on two parameters.
/// write_rows(&dir.join("grads.npy"), &vec![vec![1.0, -1.0]; 10])?;
/// let files = Files { grads: &dir.join("grads.npy"), fd_grads: None, init: None, halves: None };
/// let device = vkinverse::Device::new(&vkinverse::Config::from_env().0)?;
/// let result = replay(&device, &"adam".parse()?, &files, Range::UNBOUNDED, 0.1)?;
/// let last = result.trajectory.last().unwrap();
/// assert!(last[0] < 0.0 && last[1] > 0.0, "each parameter moved against its gradient: {last:?}");
/// # Ok(())
/// # }
/// ```
pub fn replay(device: &Device, spec: &Spec, files: &Files, range: Range, lr: f64) -> Result<Replay> {
    let opt = spec.optimiser;
    let mut input = ReplayInput::load(files.grads, files.fd_grads, files.init, opt.needs_fd())?;
    match (files.halves, opt.needs_halves()) {
        (Some((gh, fh)), _) => input.load_halves(gh, fh)?,
        (None, true) => return Err(Error::Invalid("--optimiser with var=centred needs --halves GH.npy,FH.npy (the half-pixel sums of both streams)".into())),
        (None, false) => {}
    }
    // A cosine schedule without a horizon decays over the replayed iterations.
    let opt = opt.resolve(input.grads.len() as u32);
    let replay = crate::optim::gpu::replay_gpu_streams(device.ctx(), &opt, &input.streams(), &input.init, range, lr)?;
    let result = Replay {
        iterations: input.grads.len(),
        parameters: input.init.len(),
        trajectory: replay.theta,
        nonfinite: replay.nonfinite,
        diagnostics: replay.diagnostics,
    };
    device.validated(result)
}
