//! `vkinverse optimise`: the optimisation loop and its outputs.
//!
//! One iteration is recorded once and resubmitted: the proportional gradient estimate
//! (primal → loss → adjoint), for the meta-estimator the finite-difference sample (the
//! gradient at θ_i minus the gradient at θ_{i−1} with the same random numbers, traced
//! twice), then the fused optimiser passes. Between submissions the host writes the
//! iteration counter and reads back only what the log needs (the loss, and θ for the
//! parameter error).
//!
//! Outputs in OUTDIR (names and formats as in the design document): `log.csv`,
//! `summary.json`, `params/`, `final.exr`, `error_vs_time.png`, `checkpoint/`.

use crate::error::{Error, Result};
use crate::gpu::{Access, Buffer, CommandBuffer, Context, MemoryKind, Profiler};
use crate::image::{self, Image};
use crate::ops::BufferOps;
use crate::optim::gpu::{GpuOptimiser, Group};
use crate::optim::{Optimiser, Range};
use crate::render::gradient::GradientPass;
use crate::render::targets::{padded, targets, TARGET_SPP};
use crate::render::{GpuScene, Renderer};
use crate::scene::Scene;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// Seed offsets of the finite-difference sample: independent of the proportional one.
pub const SEED_FD: u32 = 0x4000_0000;

/// What to run; command-line values override the scene's `[optimise]` table.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    pub optimiser: Optimiser,
    pub iterations: u32,
    pub time_budget: Option<f64>,
    pub spp: u32,
    pub fd_spp: u32,
    pub primal_spp: u32,
    pub lr: f32,
    pub seed: u32,
    pub checkpoint_every: u32,
    pub loss: String,
    /// Meta only: compute ⟨ΔF⟩ by tracing each state separately (two gradient estimates
    /// with the same seeds) instead of the fused single trace.
    pub fd_two_trace: bool,
}

impl Settings {
    /// The scene's settings.
    pub fn from_scene(scene: &Scene) -> Self {
        let o = &scene.optimise;
        Settings {
            optimiser: match o.optimiser {
                crate::scene::OptimiserKind::Meta => Optimiser::Meta(Default::default()),
                crate::scene::OptimiserKind::Adam => Optimiser::Adam(Default::default()),
            },
            iterations: o.iterations,
            time_budget: o.time_budget,
            spp: o.spp,
            fd_spp: o.fd_spp,
            primal_spp: o.primal_spp,
            lr: o.lr,
            seed: o.seed as u32,
            checkpoint_every: o.checkpoint_every.unwrap_or(50),
            loss: o.loss.as_str().to_string(),
            fd_two_trace: false,
        }
    }

    fn validate(&self) -> Result<()> {
        if self.spp == 0 || self.primal_spp == 0 || (self.optimiser.needs_fd() && self.fd_spp == 0) {
            return Err(Error::Invalid("spp, primal_spp and (for meta) fd_spp must be at least 1".into()));
        }
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return Err(Error::Invalid(format!("learning rate {} must be positive", self.lr)));
        }
        // A NaN budget would never be reached and a negative one ends before the first step.
        if let Some(t) = self.time_budget.filter(|t| !(t.is_finite() && *t > 0.0)) {
            return Err(Error::Invalid(format!("time budget {t} s must be positive")));
        }
        if self.iterations == 0 && self.time_budget.is_none() {
            return Err(Error::Invalid("nothing to do: 0 iterations and no time budget".into()));
        }
        Ok(())
    }
}

/// Progress reported after every iteration.
pub struct Progress {
    pub iteration: u32,
    pub time_s: f64,
    pub loss: f64,
    pub param_error: Option<f64>,
}

/// One optimiser group per optimised parameter, with its learning rate and range.
pub fn param_groups(gs: &GpuScene) -> Vec<Group> {
    gs.layout
        .slots
        .iter()
        .map(|s| Group { offset: s.offset, len: s.len, lr: s.lr as f64, range: Range { lo: s.range[0] as f64, hi: s.range[1] as f64 } })
        .collect()
}

/// The meta-estimator's finite-difference sample.
pub enum FdSample {
    /// One trace evaluates both parameter states (the default).
    Fused(GradientPass),
    /// One gradient estimate per state with the same seeds, then their difference.
    TwoTrace { cur: GradientPass, prv: GradientPass, at_cur: Buffer, at_prev: Buffer },
}

impl FdSample {
    /// ⟨ΔF⟩ between θ (the scene's) and `theta_prev` (set to the initial values) at
    /// `settings.fd_spp` samples, with seeds independent of the proportional sample's.
    pub fn new(
        gs: &GpuScene,
        ops: &BufferOps,
        targets: &[Image],
        loss: crate::scene::Loss,
        settings: &Settings,
        theta_prev: &Buffer,
        fd_grad: &Buffer,
    ) -> Result<Self> {
        theta_prev.write(&padded(gs, gs.layout.initial()))?;
        let seed = settings.seed.wrapping_add(SEED_FD);
        let spp = settings.fd_spp;
        if !settings.fd_two_trace {
            return Ok(FdSample::Fused(GradientPass::new_fd(gs, ops, targets, loss, spp, seed, theta_prev, fd_grad)?));
        }
        let n = gs.layout.len.max(1);
        let at_cur = Buffer::zeroed::<f32>(&gs.ctx, "fd grad at theta", n, MemoryKind::Device)?;
        let at_prev = Buffer::zeroed::<f32>(&gs.ctx, "fd grad at theta prev", n, MemoryKind::Device)?;
        // The primal images of the difference use fd_spp samples too: with common random
        // numbers most of their noise cancels in the difference.
        let cur = GradientPass::new(gs, ops, targets, loss, spp, spp, seed, &gs.theta, &at_cur)?;
        let prv = GradientPass::new(gs, ops, targets, loss, spp, spp, seed, theta_prev, &at_prev)?;
        Ok(FdSample::TwoTrace { cur, prv, at_cur, at_prev })
    }

    /// Records ⟨ΔF⟩ into `fd_grad` (which the optimiser pass reads and clears).
    pub fn record(&self, rec: &mut crate::gpu::Recorder, gs: &GpuScene, ops: &BufferOps, fd_grad: &Buffer) -> crate::gpu::Result<()> {
        match self {
            FdSample::Fused(pass) => pass.record(rec, gs, ops),
            FdSample::TwoTrace { cur, prv, at_cur, at_prev } => {
                rec.transition(&[(at_cur, Access::TransferWrite), (at_prev, Access::TransferWrite)])?;
                rec.zero(at_cur)?;
                rec.zero(at_prev)?;
                cur.record(rec, gs, ops)?;
                prv.record(rec, gs, ops)?;
                rec.transition(&[(at_cur, Access::ComputeRead), (at_prev, Access::ComputeRead), (fd_grad, Access::ComputeWrite)])?;
                ops.sub(rec, at_cur, at_prev, fd_grad)
            }
        }
    }
}

/// What `summary.json` holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Summary {
    pub scene: String,
    pub optimiser: String,
    pub settings: serde_json::Value,
    pub iterations: u32,
    pub total_time_s: f64,
    pub total_gpu_time_s: f64,
    pub final_loss: f64,
    pub final_param_error: Option<f64>,
    pub initial_param_error: Option<f64>,
    /// Median GPU milliseconds per iteration of each pass.
    pub pass_ms: std::collections::BTreeMap<String, f64>,
    pub nonfinite_gradients: u32,
    /// Meta only: per optimised parameter, the mean over its elements of the
    /// meta-estimator's effective number of averaged gradient samples at the last step,
    /// n_eff = 1/(1 − α). Near 1 the estimator is using little history (its
    /// finite-difference samples are too noisy to carry the past forward).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub meta_n_eff: Option<std::collections::BTreeMap<String, f64>>,
    pub device: String,
}

#[derive(Serialize, Deserialize)]
struct CheckpointMeta {
    iteration: u32,
    time_s: f64,
    gpu_time_s: f64,
    optimiser: String,
}

fn file_name(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '.' || c == '-' { c } else { '_' }).collect()
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> Error + '_ {
    move |source| Error::Io { path: path.to_path_buf(), source }
}

/// Writes θ and the optimiser state into `dir/checkpoint` atomically (a complete new
/// directory replaces the old one).
fn save_checkpoint(dir: &Path, theta: &Buffer, opt: &GpuOptimiser, meta: &CheckpointMeta) -> Result<()> {
    let tmp = dir.join("checkpoint.tmp");
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).map_err(io_err(&tmp))?;
    for b in std::iter::once(theta).chain(opt.state()) {
        let data: Vec<f32> = b.read()?;
        crate::npy::write(&tmp.join(format!("{}.npy", file_name(b.name()))), &crate::npy::Array { shape: vec![data.len()], data })?;
    }
    let json = serde_json::to_string_pretty(meta).map_err(|e| Error::Invalid(e.to_string()))?;
    image::write_bytes_atomic(&tmp.join("state.json"), json.as_bytes()).map_err(io_err(&tmp))?;
    let dst = dir.join("checkpoint");
    let old = dir.join("checkpoint.old");
    let _ = std::fs::remove_dir_all(&old);
    if dst.exists() {
        std::fs::rename(&dst, &old).map_err(io_err(&dst))?;
    }
    std::fs::rename(&tmp, &dst).map_err(io_err(&dst))?;
    let _ = std::fs::remove_dir_all(&old);
    Ok(())
}

fn load_checkpoint(dir: &Path, theta: &Buffer, opt: &GpuOptimiser, optimiser: &str) -> Result<CheckpointMeta> {
    let cp = dir.join("checkpoint");
    let text = std::fs::read_to_string(cp.join("state.json")).map_err(io_err(&cp.join("state.json")))?;
    let meta: CheckpointMeta = serde_json::from_str(&text).map_err(|e| Error::Invalid(format!("{}: {e}", cp.join("state.json").display())))?;
    if meta.optimiser != optimiser {
        return Err(Error::Invalid(format!("{}: checkpoint of optimiser {}, resuming with {optimiser}", cp.display(), meta.optimiser)));
    }
    for b in std::iter::once(theta).chain(opt.state()) {
        let path = cp.join(format!("{}.npy", file_name(b.name())));
        let a = crate::npy::read(&path)?;
        if a.data.len() * 4 != b.len() as usize {
            return Err(Error::Invalid(format!("{}: {} values, expected {}", path.display(), a.data.len(), b.len() / 4)));
        }
        b.write(&a.data)?;
    }
    Ok(meta)
}

/// Writes `params/`: `params.json` with every constant parameter, one EXR per texture.
fn write_params(dir: &Path, scene: &GpuScene, theta: &[f32]) -> Result<()> {
    let pdir = dir.join("params");
    std::fs::create_dir_all(&pdir).map_err(io_err(&pdir))?;
    let mut json = serde_json::Map::new();
    for s in &scene.layout.slots {
        let v = &theta[s.offset..s.offset + s.len];
        if s.size == [0, 0] {
            json.insert(s.name.clone(), if v.len() == 1 { serde_json::json!(v[0]) } else { serde_json::json!(v) });
        } else {
            let c = s.channels as usize;
            let data = v.chunks(c).map(|t| if c == 1 { [t[0]; 3] } else { [t[0], t[1], t[2]] }).collect();
            let img = Image { width: s.size[0], height: s.size[1], data };
            let path = pdir.join(format!("{}.exr", file_name(&s.name)));
            image::write_exr(&path, &img)?;
            json.insert(s.name.clone(), serde_json::json!({ "texture": path.file_name().map(|f| f.to_string_lossy().into_owned()) }));
        }
    }
    let text = serde_json::to_string_pretty(&serde_json::Value::Object(json)).map_err(|e| Error::Invalid(e.to_string()))?;
    image::write_bytes_atomic(&pdir.join("params.json"), text.as_bytes()).map_err(io_err(&pdir))
}

/// Runs the optimisation of `scene` into `out_dir` (resuming from its checkpoint if
/// `resume`), calling `progress` after each iteration.
pub fn optimise(
    ctx: &Arc<Context>,
    scene: &Scene,
    settings: &Settings,
    out_dir: &Path,
    resume: bool,
    mut progress: impl FnMut(&Progress),
    mut on_targets: impl FnMut(usize, u32, u32),
) -> Result<Summary> {
    settings.validate()?;
    if scene.optimise.params.is_empty() {
        return Err(Error::Invalid(format!("{}: no [[optimise.params]] to optimise", scene.path.display())));
    }
    std::fs::create_dir_all(out_dir).map_err(io_err(out_dir))?;
    let renderer = Renderer::new(GpuScene::new(ctx, scene)?)?;
    let gs = &renderer.scene;
    let target_images = targets(&renderer, scene, TARGET_SPP, &mut on_targets)?;
    let ops = BufferOps::new(ctx)?;
    let n = gs.layout.len.max(1);
    let loss: crate::scene::Loss = settings.loss.parse().map_err(|_| Error::Invalid(format!("unknown loss '{}'", settings.loss)))?;

    let grad = Buffer::zeroed::<f32>(ctx, "grad", n, MemoryKind::Device)?;
    let proportional = GradientPass::new(gs, &ops, &target_images, loss, settings.spp, settings.primal_spp, settings.seed, &gs.theta, &grad)?;
    let fd_grad = Buffer::zeroed::<f32>(ctx, "fd grad", n, MemoryKind::Device)?;
    let groups = param_groups(gs);
    let opt = GpuOptimiser::new(ctx, &ops, &settings.optimiser, &gs.theta, &grad, Some(&fd_grad), &gs.frame, &groups)?;
    // Finite differences (meta): the gradient at θ_i minus the gradient at θ_{i−1} with
    // common random numbers, from the fused single trace, or (fd_two_trace) from two
    // gradient estimates with the same seeds, one per state.
    let fd = match &opt.theta_prev {
        Some(prev) => Some(FdSample::new(gs, &ops, &target_images, loss, settings, prev, &fd_grad)?),
        None => None,
    };

    // Warm-up: lavapipe (and some drivers) compile a pipeline on its first dispatch, which
    // would land in the first timed iteration. Run the rendering passes once, untimed,
    // and clear what they accumulated.
    let mut warm = CommandBuffer::new(ctx, "warm-up")?;
    warm.record(|rec| {
        proportional.record(rec, gs, &ops)?;
        if let Some(fd) = &fd {
            fd.record(rec, gs, &ops, &fd_grad)?;
        }
        rec.transition(&[(&grad, Access::TransferWrite), (&fd_grad, Access::TransferWrite)])?;
        rec.zero(&grad)?;
        rec.zero(&fd_grad)
    })?;
    warm.submit_and_wait()?;

    let mut profiler = Profiler::new(ctx, 8)?;
    let mut cmd = CommandBuffer::new(ctx, "iteration")?;
    cmd.record(|rec| {
        profiler.reset(rec);
        profiler.scope(rec, "gradient", |rec, _| proportional.record(rec, gs, &ops))?;
        if let Some(fd) = &fd {
            profiler.scope(rec, "finite_difference", |rec, _| fd.record(rec, gs, &ops, &fd_grad))?;
        }
        profiler.scope(rec, "optimiser", |rec, _| opt.record(rec, &ops))
    })?;

    let mut first = 0u32;
    let mut time_offset = 0.0;
    let mut gpu_total = 0.0;
    let log_path = out_dir.join("log.csv");
    let mut log = String::new();
    let has_reference = scene.sensors.iter().all(|s| s.target_image.is_none());
    if resume {
        let meta = load_checkpoint(out_dir, &gs.theta, &opt, settings.optimiser.name())?;
        first = meta.iteration;
        time_offset = meta.time_s;
        gpu_total = meta.gpu_time_s;
        let old = std::fs::read_to_string(&log_path).map_err(io_err(&log_path))?;
        // Keep the header and the rows up to the checkpoint.
        for line in old.lines().take(first as usize + 2) {
            log.push_str(line);
            log.push('\n');
        }
    } else {
        let _ = std::fs::remove_dir_all(out_dir.join("checkpoint"));
        log.push_str("iteration,time_s,gpu_time_s,loss,param_error");
        for s in &gs.layout.slots {
            let _ = write!(log, ",param_error.{}", s.name);
        }
        log.push('\n');
    }
    // The error at the start of the run, also when resuming from a later θ.
    let initial_error = has_reference.then(|| gs.layout.errors(&gs.layout.initial()).0);
    let theta0: Vec<f32> = gs.theta.read()?;
    if !resume {
        // Row 0: the start, before any step.
        let (e, per) = gs.layout.errors(&theta0);
        let _ = write!(log, "0,0,0,,{}", if has_reference { e.to_string() } else { String::new() });
        for p in per {
            let _ = write!(log, ",{}", if has_reference { p.to_string() } else { String::new() });
        }
        log.push('\n');
    }

    let start = Instant::now();
    // Wall time spent on logging and checkpoints, which `time_s` leaves out.
    let mut untimed = 0.0;
    let timed = |untimed: f64| time_offset + start.elapsed().as_secs_f64() - untimed;
    let mut pass_samples: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
    let mut last_loss = f64::NAN;
    let mut last_error = initial_error;
    let mut it = first;
    loop {
        let elapsed = timed(untimed);
        if settings.time_budget.is_some_and(|b| elapsed >= b) || (settings.time_budget.is_none() && it >= settings.iterations) {
            break;
        }
        if settings.time_budget.is_some() && settings.iterations > 0 && it >= settings.iterations {
            break;
        }
        gs.set_frame(it)?;
        cmd.submit_and_wait()?;
        let time_s = timed(untimed);
        let times = profiler.results()?;
        let gpu_ms: f64 = times.iter().filter(|t| t.depth == 0).map(|t| t.ms).sum();
        for t in times.iter().filter(|t| t.depth == 0) {
            pass_samples.entry(t.name.clone()).or_default().push(t.ms);
        }
        gpu_total += gpu_ms * 1e-3;
        it += 1;
        // Logged outside the timed span: reading back the loss and θ.
        last_loss = proportional.total_loss()?;
        let theta: Vec<f32> = gs.theta.read()?;
        let (e, per) = gs.layout.errors(&theta);
        last_error = has_reference.then_some(e);
        let _ = write!(log, "{it},{time_s:.6},{gpu_total:.6},{last_loss:e},{}", if has_reference { e.to_string() } else { String::new() });
        for p in per {
            let _ = write!(log, ",{}", if has_reference { p.to_string() } else { String::new() });
        }
        log.push('\n');
        progress(&Progress { iteration: it, time_s, loss: last_loss, param_error: last_error });
        if settings.checkpoint_every > 0 && it % settings.checkpoint_every == 0 {
            image::write_bytes_atomic(&log_path, log.as_bytes()).map_err(io_err(&log_path))?;
            let meta = CheckpointMeta { iteration: it, time_s, gpu_time_s: gpu_total, optimiser: settings.optimiser.name().into() };
            save_checkpoint(out_dir, &gs.theta, &opt, &meta)?;
        }
        untimed += timed(untimed) - time_s;
    }
    let total_time_s = timed(untimed);
    image::write_bytes_atomic(&log_path, log.as_bytes()).map_err(io_err(&log_path))?;
    let meta = CheckpointMeta { iteration: it, time_s: total_time_s, gpu_time_s: gpu_total, optimiser: settings.optimiser.name().into() };
    save_checkpoint(out_dir, &gs.theta, &opt, &meta)?;

    let theta: Vec<f32> = gs.theta.read()?;
    write_params(out_dir, gs, &theta)?;
    let final_img = renderer.render(0, settings.primal_spp.max(64), settings.seed ^ 0x5EED, |_, _| {})?;
    image::write_exr(&out_dir.join("final.exr"), &final_img)?;
    write_plot(out_dir, &log, &scene.path.display().to_string(), settings.optimiser.name())?;

    let pass_ms = pass_samples.into_iter().map(|(k, mut v)| (k, crate::bench::median(&mut v))).collect();
    let summary = Summary {
        scene: scene.path.display().to_string(),
        optimiser: settings.optimiser.name().into(),
        settings: serde_json::to_value(settings).unwrap_or_default(),
        iterations: it,
        total_time_s,
        total_gpu_time_s: gpu_total,
        final_loss: last_loss,
        final_param_error: last_error,
        initial_param_error: initial_error,
        pass_ms,
        nonfinite_gradients: opt.nonfinite_count()?,
        meta_n_eff: opt.meta_n_eff()?.map(|n_eff| {
            gs.layout
                .slots
                .iter()
                .map(|s| {
                    let v = &n_eff[s.offset..s.offset + s.len];
                    (s.name.clone(), v.iter().map(|&x| x as f64).sum::<f64>() / s.len.max(1) as f64)
                })
                .collect()
        }),
        device: ctx.info().name.clone(),
    };
    let text = serde_json::to_string_pretty(&summary).map_err(|e| Error::Invalid(e.to_string()))?;
    image::write_bytes_atomic(&out_dir.join("summary.json"), text.as_bytes()).map_err(io_err(out_dir))?;
    Ok(summary)
}

/// Parses `log.csv` text into (time, param_error) and (time, loss) curves.
pub fn log_curves(log: &str) -> (Vec<(f64, f64)>, Vec<(f64, f64)>) {
    let mut err = Vec::new();
    let mut loss = Vec::new();
    for line in log.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() < 5 {
            continue;
        }
        let t = f[1].parse::<f64>().unwrap_or(0.0);
        if let Ok(e) = f[4].parse::<f64>() {
            err.push((t, e));
        }
        if let Ok(l) = f[3].parse::<f64>() {
            loss.push((t, l));
        }
    }
    (err, loss)
}

fn write_plot(out_dir: &Path, log: &str, scene: &str, optimiser: &str) -> Result<()> {
    let (err, loss) = log_curves(log);
    let (points, label) = if err.is_empty() { (loss, "image loss") } else { (err, "parameter RMSE") };
    let curves = [crate::report::Curve { name: optimiser.to_string(), points }];
    let path = out_dir.join("error_vs_time.png");
    crate::report::plot_error_vs_time(&path, &format!("{scene}: {label} vs time"), label, &curves)
        .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))
}
