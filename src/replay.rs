//! `vkinverse replay`: the GPU optimiser passes run on recorded gradient streams, as the
//! renderer runs them, for studying an optimiser apart from rendering.

use crate::device::Device;
use crate::error::{Error, Result};
use crate::optim::replay::ReplayInput;
use crate::optim::spec::Spec;
use std::path::Path;

pub use crate::optim::Range;

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
