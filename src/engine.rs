//! The iteration engine: the passes of one optimisation iteration, built once for a scene
//! and its run settings, for `optimise`, the scene `bench` and `gradcheck` alike.
//!
//! An [`Engine`] owns the scene on the device and its target images, the gradient buffers,
//! the proportional gradient estimate ⟨F_i⟩ (primal → loss → adjoint), for the
//! meta-estimator the finite-difference sample ⟨ΔF_i⟩ ([`FdSample`]), and the fused
//! optimiser passes. [`Engine::record`] records them in that order, each pass in a
//! profiler scope named after its kernel (`trace_primal`, `loss` with its reduction,
//! `trace_adjoint`, `trace_fd_primal`, `trace_fd_adjoint`, `sub`, `optim_meta`,
//! `optim_adam`), once per sensor where a pass is per sensor. With meta's carried primal
//! image ([`Carry`]) both samples' primal passes come first, then `carry_image`, then the
//! losses and adjoint passes of both, then (meta `carry_adjoint`) `carry_adjoint`, which
//! mixes the adjoint pass's render of θ_i into the carried image. [`Iteration`] is that
//! recording resubmitted with a fresh iteration counter; [`Step`] is what one submission
//! reports, the optimiser's diagnostics (`optimiser.csv`) included.
//!
//! Seeds: the run's `u64` seed is hashed down to the GPU's 32 bits by
//! [`crate::settings::gpu_seed`]; the finite-difference sample adds [`SEED_FD`] so that its
//! random numbers are independent of the proportional sample's.

use crate::cancel::Cancel;
use crate::device::Device;
use crate::error::{Error, Result};
use crate::gpu::{self, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Profiler, Recorder, ScopeTime};
use crate::image::Image;
use crate::observer::Observer;
use crate::ops::BufferOps;
use crate::optim::gpu::{GpuOptimiser, Group, OptimiserBuffers};
use crate::optim::{CarryWeight, Diagnostics, MetaHyper, Optimiser, Range};
use crate::kernels::{CarryWeightPush, CountPush};
use crate::render::gradient::{GradientInputs, GradientPass};
use crate::render::targets::{padded, targets, TargetSource};
use crate::render::{GpuScene, PrimalRenderer};
use crate::scene::Scene;
use crate::settings::{gpu_seed, Loss, RunSettings};
use std::collections::BTreeMap;
use std::sync::Arc;

/// Seed offset of the finite-difference sample: independent of the proportional one.
pub const SEED_FD: u32 = 0x4000_0000;

/// The meta-estimator's finite-difference sample.
pub enum FdSample {
    /// One trace evaluates both parameter states (the default).
    Fused(GradientPass),
    /// One gradient estimate per state with the same seeds, then their difference.
    TwoTrace { cur: GradientPass, prv: GradientPass, at_cur: Buffer, at_prev: Buffer },
}

impl FdSample {
    /// Records ⟨ΔF⟩ into `fd_grad` (which the optimiser pass reads and clears).
    pub fn record(&self, rec: &mut Recorder, gs: &GpuScene, ops: &BufferOps, fd_grad: &Buffer) -> gpu::Result<()> {
        match self {
            FdSample::Fused(pass) => pass.record_passes(rec, gs, ops, true),
            FdSample::TwoTrace { cur, prv, at_cur, at_prev } => {
                rec.zero(at_cur)?;
                rec.zero(at_prev)?;
                cur.record_passes(rec, gs, ops, true)?;
                prv.record_passes(rec, gs, ops, true)?;
                rec.begin_scope("sub")?;
                ops.sub(rec, at_cur, at_prev, fd_grad)?;
                rec.end_scope()
            }
        }
    }
}

/// The meta-estimator's carried primal image (meta `carry` > 0; glsl/carry_image.comp):
/// after the primal passes of ⟨F⟩ and of the fused ⟨ΔF⟩, per sensor `carry_stats` sums the
/// squared differences of the three renders, `carry_weight` chooses the fresh render's weight
/// from them and tracks the carried image's variance, and `carry_image` carries the previous
/// iteration's image to θ_i by the difference of ⟨ΔF⟩'s two images, mixes in the fresh
/// render, and puts the result in the images the losses read. With `carry_adjoint`,
/// `carry_adjoint` then mixes the adjoint pass's render of θ_i into the carried image, by the
/// weight `carry_weight` chose for it (glsl/carry_adjoint.comp).
pub struct Carry {
    image: ComputePipeline,
    stats: ComputePipeline,
    weight: ComputePipeline,
    /// carry_adjoint, with the adjoint pass's render taken in (meta `carry_adjoint`).
    adjoint: Option<ComputePipeline>,
    sensors: Vec<CarrySensor>,
    /// Carries so far (one float, incremented on the device after each pass); 0 in a new
    /// engine (the first carry takes the fresh image alone). Checkpointed with the images.
    count: Buffer,
    pixels: u32,
    push: CarryWeightPush,
}

/// One sensor's carried image, the weight's state, and the passes' bind groups over them and
/// the images they read (the fresh render of θ_i, the finite-difference sample's images of
/// θ_i and θ_{i-1}, the statistics' partial sums).
struct CarrySensor {
    carried: Buffer,
    /// (w, the carried image's variance, the fresh render's, the bound on the difference's,
    /// the adjoint render's weight u), per pixel and channel, after the last iteration.
    state: Buffer,
    image: gpu::BindGroup,
    stats: gpu::BindGroup,
    weight: gpu::BindGroup,
    /// The adjoint pass's render and carry_adjoint's bind group over it.
    adjoint: Option<(Buffer, gpu::BindGroup)>,
}

/// Floats of a sensor's carry state on the device.
const CARRY_STATE_FLOATS: usize = 5;
/// Bytes of a sensor's carry state on the device.
const CARRY_STATE_BYTES: u64 = 4 * CARRY_STATE_FLOATS as u64;

/// What a sensor's carry did in an iteration (its `carry_weight` state).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CarryState {
    /// The fresh render's weight.
    pub weight: f32,
    /// The carried image's tracked variance, per pixel and channel.
    pub var_carried: f32,
    /// The fresh render's estimated variance.
    pub var_fresh: f32,
    /// The bound on the variance the finite-difference images' difference adds.
    pub var_diff: f32,
    /// The adjoint pass's render's weight (0 where it is not taken in).
    pub weight_adjoint: f32,
}

impl CarryState {
    /// The CSV columns of [`Self::values`].
    pub const COLUMNS: [&'static str; CARRY_STATE_FLOATS] = ["weight", "var_carried", "var_fresh", "var_diff", "weight_adjoint"];

    /// The state from its floats in [`Self::COLUMNS`]' order; a state without the last
    /// (written before the adjoint render was taken in) has its weight 0.
    pub fn from_floats(v: &[f32]) -> Self {
        CarryState { weight: v[0], var_carried: v[1], var_fresh: v[2], var_diff: v[3], weight_adjoint: v.get(4).copied().unwrap_or(0.0) }
    }

    pub fn values(&self) -> [f32; CARRY_STATE_FLOATS] {
        [self.weight, self.var_carried, self.var_fresh, self.var_diff, self.weight_adjoint]
    }
}

/// What a [`Carry`] carries: `images`, one (fresh, cur, prev) triple of `pixels` RGB pixels
/// per sensor, the fresh render at `spp.0` samples per pixel and the finite-difference
/// images at `spp.1`; the fresh image's least weight `w_min`, and how it is weighed above
/// that. With `adjoint` (one render per sensor, at `adjoint.1` samples per pixel), each
/// sensor's adjoint render of θ_i is mixed into its carried image after the adjoint pass
/// ([`Carry::record_adjoint`]).
pub struct CarryInputs<'a> {
    pub pixels: usize,
    pub images: &'a [(&'a Buffer, &'a Buffer, &'a Buffer)],
    pub w_min: f64,
    pub weight: CarryWeight,
    pub spp: (u32, u32),
    pub adjoint: Option<(Vec<&'a Buffer>, u32)>,
}

impl Carry {
    /// The carry of `inputs` ([`CarryInputs`]).
    pub fn new(ctx: &Arc<Context>, inputs: CarryInputs) -> gpu::Result<Self> {
        let CarryInputs { pixels, images, w_min, weight, spp, adjoint } = inputs;
        let image = ComputePipeline::new(ctx, "carry_image", &[])?;
        let mix = adjoint.as_ref().map(|_| ComputePipeline::new(ctx, "carry_adjoint", &[])).transpose()?;
        let stats = ComputePipeline::new(ctx, "carry_stats", &[])?;
        let weigh = ComputePipeline::new(ctx, "carry_weight", &[])?;
        let count = Buffer::zeroed::<f32>(ctx, "carry count", 1, MemoryKind::Device)?;
        let groups = (pixels as u64).div_ceil(stats.local_size()[0] as u64) as usize;
        let mut sensors = Vec::new();
        for (s, (fresh, cur, prev)) in images.iter().enumerate() {
            let carried = Buffer::zeroed::<[f32; 3]>(ctx, &format!("carried image {s}"), pixels, MemoryKind::Device)?;
            let partials = Buffer::zeroed::<f32>(ctx, &format!("carry partials {s}"), 2 * groups.max(1), MemoryKind::Device)?;
            let state = Buffer::zeroed::<f32>(ctx, &format!("carry state {s}"), CARRY_STATE_FLOATS, MemoryKind::Device)?;
            let image_group = image.bind(&[("Fresh", fresh), ("Cur", cur), ("Prev", prev), ("Carried", &carried), ("State", &state)])?;
            let stats_group = stats.bind(&[("Fresh", fresh), ("Cur", cur), ("Prev", prev), ("Partials", &partials)])?;
            let weight_group = weigh.bind(&[("Partials", &partials), ("Count", &count), ("State", &state)])?;
            let adjoint_mix = match (&mix, &adjoint) {
                (Some(p), Some((renders, _))) => {
                    let r = renders[s].clone();
                    let group = p.bind(&[("Carried", &carried), ("Adjoint", &r), ("State", &state)])?;
                    Some((r, group))
                }
                _ => None,
            };
            sensors.push(CarrySensor { carried, state, image: image_group, stats: stats_group, weight: weight_group, adjoint: adjoint_mix });
        }
        // The least weight of an iteration's new samples: the fresh render's alone, or shared
        // with the adjoint render by their samples, so that the carried image's memory at the
        // floor is the same (1/w_min iterations) with or without it.
        let s_a = adjoint.as_ref().map_or(0, |(_, s_a)| *s_a);
        let new_samples = (spp.0 + s_a).max(1) as f64;
        let push = CarryWeightPush {
            groups: groups as u32,
            scale: 1.0 / (3.0 * pixels.max(1) as f32),
            fresh_share: spp.1 as f32 / (spp.0 + spp.1).max(1) as f32,
            w_min: (w_min * spp.0 as f64 / new_samples) as f32,
            variance: (weight == CarryWeight::Variance) as u32,
            adjoint_ratio: if s_a > 0 { spp.0 as f32 / s_a as f32 } else { 0.0 },
            u_min: (w_min * s_a as f64 / new_samples) as f32,
        };
        Ok(Carry { image, stats, weight: weigh, adjoint: mix, sensors, count, pixels: pixels as u32, push })
    }

    /// The carry of a gradient estimate's images by a fused finite-difference sample's.
    fn of_passes(ctx: &Arc<Context>, gs: &GpuScene, gradient: &GradientPass, fd: &GradientPass, h: &MetaHyper) -> gpu::Result<Self> {
        let images: Vec<_> = (0..gradient.sensors())
            .map(|s| (gradient.image(s), fd.image(s), fd.prev_image(s).expect("the fused finite-difference sample renders θ_{i-1}")))
            .collect();
        let adjoint = h.carry_adjoint.then(|| {
            let renders = (0..gradient.sensors()).map(|s| gradient.adjoint_radiance(s).expect("the gradient estimate's adjoint pass renders θ")).collect();
            (renders, gradient.spp)
        });
        let spp = (gradient.primal_spp, fd.primal_spp);
        Self::new(ctx, CarryInputs { pixels: gs.pixels(), images: &images, w_min: h.carry, weight: h.carry_weight, spp, adjoint })
    }

    /// Records the mix of every sensor's adjoint render into its carried image (after the
    /// adjoint pass; nothing without `carry_adjoint`).
    pub fn record_adjoint(&self, rec: &mut Recorder) -> gpu::Result<()> {
        let Some(mix) = &self.adjoint else { return Ok(()) };
        rec.begin_scope("carry_adjoint")?;
        let n = CountPush { n: self.pixels };
        for c in &self.sensors {
            if let Some((_, group)) = &c.adjoint {
                rec.dispatch_linear(mix, group, &n, self.pixels as u64)?;
            }
        }
        rec.end_scope()
    }

    /// Records the passes over every sensor's images and the count's increment.
    pub fn record(&self, rec: &mut Recorder, ops: &BufferOps) -> gpu::Result<()> {
        rec.begin_scope("carry_image")?;
        let n = CountPush { n: self.pixels };
        for c in &self.sensors {
            rec.dispatch_linear(&self.stats, &c.stats, &n, self.pixels as u64)?;
        }
        for c in &self.sensors {
            rec.dispatch_groups(&self.weight, &c.weight, &self.push, [1, 1, 1])?;
        }
        for c in &self.sensors {
            rec.dispatch_linear(&self.image, &c.image, &n, self.pixels as u64)?;
        }
        ops.scale_add(rec, &self.count, 1.0, 1.0)?;
        rec.end_scope()
    }

    /// Sensor s's carried image (after the recorded work ran).
    pub fn image(&self, s: usize) -> &Buffer {
        &self.sensors[s].carried
    }

    /// Sensor s's state after the last recorded carry ran (read back from the device).
    pub fn sensor_state(&self, s: usize) -> gpu::Result<CarryState> {
        let v: Vec<f32> = self.sensors[s].state.read()?;
        Ok(CarryState::from_floats(&v))
    }

    /// What a checkpoint saves: every sensor's carried image, then the count, then every
    /// sensor's weight state.
    pub fn state(&self) -> Vec<&Buffer> {
        let images = self.sensors.iter().map(|c| &c.carried);
        let states = self.sensors.iter().map(|c| &c.state);
        images.chain(std::iter::once(&self.count)).chain(states).collect()
    }
}

/// What the host reads back after every iteration: each sensor's loss, each parameter
/// group's diagnostics record (with an optimiser) and θ, copied on the device into one
/// host-visible buffer at the end of the iteration's recording. A discrete GPU then reads
/// an iteration's results without a staged copy or a submission of its own.
pub struct Report {
    buffer: Buffer,
    /// The sources in their order in `buffer`, with their bytes.
    sources: Vec<(Buffer, u64)>,
    sensors: usize,
    /// Sensors whose carried image's state follows the records (0 without a carry).
    carried: usize,
    theta_len: usize,
}

impl Report {
    fn new(
        ctx: &Arc<Context>,
        gradient: &GradientPass,
        optimiser: Option<&GpuOptimiser>,
        carry: Option<&Carry>,
        theta: &Buffer,
        theta_len: usize,
    ) -> gpu::Result<Self> {
        let mut sources: Vec<(Buffer, u64)> = (0..gradient.sensors()).map(|s| (gradient.loss_buffer(s).clone(), 4)).collect();
        if let Some(opt) = optimiser {
            let (b, n) = opt.records_buffer();
            sources.push((b.clone(), n));
        }
        let carried = carry.map_or(0, |c| c.sensors.len());
        if let Some(c) = carry {
            sources.extend(c.sensors.iter().map(|sensor| (sensor.state.clone(), CARRY_STATE_BYTES)));
        }
        sources.push((theta.clone(), 4 * theta_len as u64));
        let total: u64 = sources.iter().map(|(_, n)| n).sum();
        let buffer = Buffer::new(ctx, "iteration report", total, MemoryKind::Readback)?;
        Ok(Report { buffer, sources, sensors: gradient.sensors(), carried, theta_len })
    }

    /// Records the copies into the report, after everything that writes its sources. The
    /// copies write disjoint ranges of the report, so they go as one unordered batch.
    pub fn record(&self, rec: &mut Recorder) -> gpu::Result<()> {
        rec.unordered(|rec| {
            let mut at = 0;
            for (b, n) in &self.sources {
                rec.copy_range(b, 0, &self.buffer, at, *n)?;
                at += n;
            }
            // The recording's closing barrier makes the copies visible to the host.
            Ok(())
        })
    }

    /// (total loss, the optimiser's record bytes, each carried sensor's state, θ) from the
    /// report of the last submission.
    fn read(&self) -> gpu::Result<(f64, Vec<u8>, Vec<CarryState>, Vec<f32>)> {
        let bytes: Vec<u8> = self.buffer.read()?;
        let floats = |b: &[u8]| -> Vec<f32> { b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect() };
        let loss_bytes = 4 * self.sensors;
        let theta_at = bytes.len() - 4 * self.theta_len;
        let carry_at = theta_at - self.carried * CARRY_STATE_BYTES as usize;
        let loss = floats(&bytes[..loss_bytes]).iter().map(|&l| l as f64).sum();
        let records = bytes[loss_bytes..carry_at].to_vec();
        let carry = floats(&bytes[carry_at..theta_at]).chunks_exact(CARRY_STATE_FLOATS).map(CarryState::from_floats).collect();
        Ok((loss, records, carry, floats(&bytes[theta_at..])))
    }
}

/// One optimiser group per optimised parameter, with its learning rate and range: the
/// scene's per-parameter rate where it has one, unless the settings' rate replaces it.
pub fn param_groups(gs: &GpuScene, settings: &RunSettings) -> Vec<Group> {
    gs.layout
        .slots
        .iter()
        .map(|s| {
            let lr = match s.lr {
                Some(lr) if !settings.lr_replaces_param_rates => lr as f64,
                _ => settings.lr,
            };
            Group { offset: s.offset, len: s.len, lr, range: Range { lo: s.range[0] as f64, hi: s.range[1] as f64 } }
        })
        .collect()
}

/// The passes of one iteration, on one scene; see the module documentation.
pub struct Engine {
    pub renderer: PrimalRenderer,
    pub ops: BufferOps,
    /// One target image per sensor.
    pub targets: Vec<Image>,
    pub settings: RunSettings,
    /// dLoss/dθ of the proportional estimate (read and cleared by the optimiser pass).
    pub grad: Buffer,
    /// ⟨ΔF⟩ (read and cleared by the meta optimiser pass).
    pub fd_grad: Buffer,
    pub gradient: GradientPass,
    pub fd: Option<FdSample>,
    /// The carried primal image (meta `carry` > 0).
    pub carry: Option<Carry>,
    pub optimiser: Option<GpuOptimiser>,
    /// The iteration's results for the host, in one buffer.
    pub report: Report,
}

impl Engine {
    /// Uploads `scene`, renders or loads its targets (the observer hears the renders, and
    /// `cancel` stops them) and builds every pass the settings' optimiser needs.
    pub fn new(device: &Device, scene: &Scene, settings: &RunSettings, observer: &mut dyn Observer, cancel: &Cancel) -> Result<Self> {
        Self::build(device, scene, settings, true, observer, cancel)
    }

    /// The gradient estimate alone, without finite-difference sample or optimiser (for
    /// checking gradients).
    pub fn gradient_only(device: &Device, scene: &Scene, settings: &RunSettings) -> Result<Self> {
        Self::build(device, scene, settings, false, &mut (), &Cancel::new())
    }

    fn build(device: &Device, scene: &Scene, settings: &RunSettings, optimise: bool, observer: &mut dyn Observer, cancel: &Cancel) -> Result<Self> {
        // The optimiser (its spec with the run's schedule) is checked before any GPU work.
        let optimiser = match optimise {
            true => Some(settings.optimiser().map_err(|e| Error::Invalid(format!("{}: {}", e.key, e.message)))?),
            false => None,
        };
        let ctx = device.ctx();
        let config = device.config();
        let renderer = PrimalRenderer::new(GpuScene::configured(ctx, scene, config)?)?;
        let source = TargetSource { spp: settings.target_spp, cache_dir: config.cache_dir.as_deref(), cancel };
        let targets = targets(&renderer, scene, source, observer)?;
        let ops = BufferOps::new(ctx)?;
        let gs = &renderer.scene;
        // Whole texels: the optimiser passes step whole vec4s.
        let n = gpu::texel_padded(gs.layout.len);
        let grad = Buffer::zeroed::<f32>(ctx, "grad", n, MemoryKind::Device)?;
        let fd_grad = Buffer::zeroed::<f32>(ctx, "fd grad", n, MemoryKind::Device)?;
        let groups = param_groups(gs, settings);
        // Built before the gradient passes: with the centred variance estimate the optimiser
        // owns the half-pixel sums those passes add into.
        let opt = match &optimiser {
            Some(o) => Some(GpuOptimiser::new(ctx, o, &OptimiserBuffers { theta: &gs.theta, grad: &grad, fd_grad: Some(&fd_grad), frame: &gs.frame, groups: &groups })?),
            None => None,
        };
        let halves = opt.as_ref().and_then(|o| o.halves.as_ref());
        let seed = gpu_seed(settings.seed);
        let gradient = GradientPass::new(
            gs,
            &ops,
            &GradientInputs {
                targets: &targets,
                loss: settings.loss,
                spp: settings.spp,
                primal_spp: settings.primal_spp,
                seed,
                theta: &gs.theta,
                theta_prev: None,
                grad: &grad,
                grad_half: halves.map(|h| &h.grad),
            },
        )?;
        let report = Report::new(ctx, &gradient, opt.as_ref(), None, &gs.theta, gs.layout.len)?;
        let mut engine = Engine { renderer, ops, targets, settings: settings.clone(), grad, fd_grad, gradient, fd: None, carry: None, optimiser: opt, report };
        let fd = match engine.optimiser.as_ref() {
            Some(opt) => match &opt.theta_prev {
                Some(prev) => Some(engine.fd_sample(prev, settings.fd_two_trace, opt.halves.as_ref().map(|h| &h.fd_grad))?),
                None => None,
            },
            None => None,
        };
        engine.fd = fd;
        // The carried image needs the fused finite-difference sample on every pixel; with a
        // stride or two traces the losses read each iteration's own render.
        if let (Some(Optimiser::Meta(h)), Some(FdSample::Fused(fd))) = (optimiser, &engine.fd) {
            if h.carry > 0.0 && fd.stride == 1 {
                engine.carry = Some(Carry::of_passes(ctx, engine.scene(), &engine.gradient, fd, &h)?);
                // The report then also carries each sensor's carry state.
                let gs = engine.scene();
                engine.report = Report::new(ctx, &engine.gradient, engine.optimiser.as_ref(), engine.carry.as_ref(), &gs.theta, gs.layout.len)?;
            }
        }
        Ok(engine)
    }

    pub fn scene(&self) -> &GpuScene {
        &self.renderer.scene
    }

    pub fn loss(&self) -> Loss {
        self.settings.loss
    }

    /// A fused optimiser pass of `optimiser` over the scene's θ and this engine's gradients,
    /// with the run's parameter groups.
    pub fn extra_optimiser(&self, optimiser: &Optimiser) -> Result<GpuOptimiser> {
        let gs = self.scene();
        let groups = param_groups(gs, &self.settings);
        let buffers = OptimiserBuffers { theta: &gs.theta, grad: &self.grad, fd_grad: Some(&self.fd_grad), frame: &gs.frame, groups: &groups };
        Ok(GpuOptimiser::new(&gs.ctx, optimiser, &buffers)?)
    }

    /// Another gradient estimate on this scene and its targets, adding into `grad`.
    pub fn extra_gradient(&self, spp: u32, primal_spp: u32, seed: u32, grad: &Buffer) -> Result<GradientPass> {
        let gs = self.scene();
        Ok(GradientPass::new(
            gs,
            &self.ops,
            &GradientInputs { targets: &self.targets, loss: self.loss(), spp, primal_spp, seed, theta: &gs.theta, theta_prev: None, grad, grad_half: None },
        )?)
    }

    /// ⟨ΔF⟩ between θ (the scene's) and `theta_prev` (set to the initial values) at the
    /// settings' fd_spp on every fd_stride-th pixel, into this engine's `fd_grad`: fused, or
    /// from two traces. The fused sample also sums half of its pixels into `fd_half` when
    /// given (the centred variance estimate); the two-trace sample cannot.
    pub fn fd_sample(&self, theta_prev: &Buffer, two_trace: bool, fd_half: Option<&Buffer>) -> Result<FdSample> {
        let gs = self.scene();
        theta_prev.write(&padded(gs, gs.layout.initial()))?;
        let seed = gpu_seed(self.settings.seed).wrapping_add(SEED_FD);
        let spp = self.settings.fd_spp;
        let loss = self.loss();
        let stride = self.settings.fd_stride;
        if !two_trace {
            let mut pass = GradientPass::new(
                gs,
                &self.ops,
                &GradientInputs {
                    targets: &self.targets,
                    loss,
                    spp,
                    primal_spp: spp,
                    seed,
                    theta: &gs.theta,
                    theta_prev: Some(theta_prev),
                    grad: &self.fd_grad,
                    grad_half: fd_half,
                },
            )?;
            pass.stride = stride;
            return Ok(FdSample::Fused(pass));
        }
        if fd_half.is_some() {
            return Err(Error::Invalid("the centred variance estimate (var=centred) needs the fused finite difference, not fd_two_trace".into()));
        }
        let n = gs.layout.len.max(1);
        let at_cur = Buffer::zeroed::<f32>(&gs.ctx, "fd grad at theta", n, MemoryKind::Device)?;
        let at_prev = Buffer::zeroed::<f32>(&gs.ctx, "fd grad at theta prev", n, MemoryKind::Device)?;
        // The primal images of the difference use fd_spp samples too: with common random
        // numbers most of their noise cancels in the difference.
        // Both traces take the same pixels: the checkerboard follows the iteration.
        let mut cur = GradientPass::new(
            gs,
            &self.ops,
            &GradientInputs { targets: &self.targets, loss, spp, primal_spp: spp, seed, theta: &gs.theta, theta_prev: None, grad: &at_cur, grad_half: None },
        )?;
        let mut prv = GradientPass::new(
            gs,
            &self.ops,
            &GradientInputs { targets: &self.targets, loss, spp, primal_spp: spp, seed, theta: theta_prev, theta_prev: None, grad: &at_prev, grad_half: None },
        )?;
        (cur.stride, prv.stride) = (stride, stride);
        Ok(FdSample::TwoTrace { cur, prv, at_cur, at_prev })
    }

    /// Records the proportional gradient estimate.
    pub fn record_gradient(&self, rec: &mut Recorder) -> gpu::Result<()> {
        self.gradient.record_passes(rec, self.scene(), &self.ops, true)
    }

    /// Records the finite-difference sample, if the optimiser takes one.
    pub fn record_fd(&self, rec: &mut Recorder) -> gpu::Result<()> {
        match &self.fd {
            Some(fd) => fd.record(rec, self.scene(), &self.ops, &self.fd_grad),
            None => Ok(()),
        }
    }

    /// Records `optimiser`'s pass in a scope named after its kernel.
    pub fn record_step(&self, rec: &mut Recorder, optimiser: &GpuOptimiser) -> gpu::Result<()> {
        rec.begin_scope(optimiser.kernel())?;
        optimiser.record(rec, &self.ops)?;
        rec.end_scope()
    }

    /// Records the whole iteration: gradient, finite-difference sample (with the carried
    /// image between their primal passes and their losses), optimiser step, and the copies
    /// of its results into the report.
    pub fn record(&self, rec: &mut Recorder) -> gpu::Result<()> {
        match (&self.carry, &self.fd) {
            (Some(carry), Some(FdSample::Fused(fd))) => {
                // Both samples' primal images first: the carried image replaces them before
                // the losses read them.
                let gs = self.scene();
                self.gradient.record_primal(rec, gs)?;
                fd.record_primal(rec, gs)?;
                carry.record(rec, &self.ops)?;
                self.gradient.record_loss_adjoint(rec, gs, &self.ops)?;
                fd.record_loss_adjoint(rec, gs, &self.ops)?;
                carry.record_adjoint(rec)?;
            }
            _ => {
                self.record_gradient(rec)?;
                self.record_fd(rec)?;
            }
        }
        if let Some(opt) = &self.optimiser {
            self.record_step(rec, opt)?;
        }
        self.report.record(rec)
    }

    /// Runs the rendering passes once, untimed, and clears what they accumulated: lavapipe
    /// (and some drivers) compile a pipeline on its first dispatch, which would otherwise
    /// land in the first timed iteration.
    pub fn warm_up(&self) -> Result<()> {
        let mut warm = CommandBuffer::new(&self.scene().ctx, "warm-up")?;
        warm.record(|rec| {
            self.record_gradient(rec)?;
            self.record_fd(rec)?;
            let mut sums = vec![&self.grad, &self.fd_grad];
            if let Some(h) = self.optimiser.as_ref().and_then(|o| o.halves.as_ref()) {
                sums.extend([&h.grad, &h.fd_grad]);
            }
            for b in sums {
                rec.zero(b)?;
            }
            Ok(())
        })?;
        warm.submit_and_wait()?;
        Ok(())
    }

    /// The iteration recorded once, with a profiler scope per pass, to be resubmitted.
    pub fn iteration(&self) -> Result<Iteration> {
        let ctx = &self.scene().ctx;
        let mut profiler = Profiler::new(ctx, Profiler::SCOPES)?;
        let mut cmd = CommandBuffer::new(ctx, "iteration")?;
        cmd.record_profiled(&mut profiler, |rec| self.record(rec))?;
        Ok(Iteration { cmd, profiler })
    }

    /// Runs iteration `index` (its counter seeds the passes' random numbers) and reads back
    /// what it reports.
    pub fn step(&self, iteration: &mut Iteration, index: u32) -> Result<Step> {
        self.scene().set_frame(index)?;
        iteration.cmd.submit_and_wait()?;
        let times = iteration.profiler.results()?;
        let (loss, diagnostics, carry, theta) = self.read_step(index)?;
        Ok(Step { loss, pass_ms: pass_totals(&times), diagnostics, carry, theta })
    }

    /// What the host reads back after iteration `index` ran, from the report (one read of
    /// one buffer): the total loss, the optimiser's diagnostics of its step t = index + 1
    /// (one record per group), each sensor's carry state (with a carried image) and θ.
    pub fn read_step(&self, index: u32) -> Result<(f64, Vec<Diagnostics>, Vec<CarryState>, Vec<f32>)> {
        let (loss, records, carry, theta) = self.report.read()?;
        let diagnostics = match &self.optimiser {
            Some(opt) => opt.diagnostics_from_bytes(&records, index + 1),
            None => Vec::new(),
        };
        Ok((loss, diagnostics, carry, theta))
    }

    /// The image error at θ = `theta` (the optimised θ when None): the mean over sensors,
    /// pixels and channels of (A − T)(B − T), where A and B are two renders of `spp`
    /// samples with the two `seeds` and T is the sensor's target. A and B are independent
    /// and unbiased, so this estimates the mean squared difference between θ's expected
    /// image and the target without the renders' own variance, which mean((A − T)²) would
    /// add; it can fall below zero by its own noise. Also returns each sensor's (A + B)/2.
    /// θ's buffer holds `theta` only while this renders.
    pub fn image_error(&self, theta: Option<&[f32]>, spp: u32, seeds: [u32; 2]) -> Result<(f64, Vec<Image>)> {
        let gs = self.scene();
        let saved: Option<Vec<f32>> = match theta {
            Some(values) => {
                let all = gs.read_theta()?;
                let mut set = all.clone();
                set[..values.len()].copy_from_slice(values);
                gs.set_theta(set)?;
                Some(all)
            }
            None => None,
        };
        let measured = self.measure_image_error(spp, seeds);
        if let Some(all) = saved {
            gs.set_theta(all)?;
        }
        measured
    }

    fn measure_image_error(&self, spp: u32, seeds: [u32; 2]) -> Result<(f64, Vec<Image>)> {
        let mut total = 0.0;
        let mut means = Vec::with_capacity(self.targets.len());
        for (sensor, target) in self.targets.iter().enumerate() {
            let a = self.renderer.render(sensor as u32, spp, seeds[0], |_, _| {})?;
            let b = self.renderer.render(sensor as u32, spp, seeds[1], |_, _| {})?;
            let mut sum = 0.0;
            for ((pa, pb), pt) in a.data.iter().zip(&b.data).zip(&target.data) {
                for c in 0..3 {
                    sum += (f64::from(pa[c]) - f64::from(pt[c])) * (f64::from(pb[c]) - f64::from(pt[c]));
                }
            }
            total += sum / (3 * target.data.len().max(1)) as f64;
            let data = a.data.iter().zip(&b.data).map(|(pa, pb)| [0, 1, 2].map(|c| 0.5 * (pa[c] + pb[c]))).collect();
            means.push(Image { width: a.width, height: a.height, data });
        }
        Ok((total / self.targets.len().max(1) as f64, means))
    }

    /// θ as the host sees it after the last submission.
    pub fn theta(&self) -> Result<Vec<f32>> {
        Ok(self.scene().read_theta()?)
    }

    /// The optimiser's pass, for its state.
    pub fn optimiser(&self) -> Result<&GpuOptimiser> {
        self.optimiser.as_ref().ok_or_else(|| Error::Invalid("the engine was built without an optimiser".into()))
    }
}

/// Sums the times of the scopes of each name (a pass recorded once per sensor is one entry).
pub fn pass_totals(times: &[ScopeTime]) -> BTreeMap<String, f64> {
    let mut sums = BTreeMap::new();
    for t in times {
        *sums.entry(t.name.clone()).or_default() += t.ms;
    }
    sums
}

/// The iteration's recording and its profiler.
pub struct Iteration {
    cmd: CommandBuffer,
    profiler: Profiler,
}

/// What one iteration reports.
#[derive(Clone, Debug)]
pub struct Step {
    /// The image loss of the proportional estimate's primal render (summed over sensors).
    pub loss: f64,
    /// GPU milliseconds of each pass (by kernel name).
    pub pass_ms: BTreeMap<String, f64>,
    /// The optimiser's diagnostics of the step, one per parameter group (the scene's
    /// optimised parameters, in layout order); empty without an optimiser.
    pub diagnostics: Vec<Diagnostics>,
    /// Each sensor's carried-image state (meta `carry`); empty without one.
    pub carry: Vec<CarryState>,
    /// θ after the step (the scene's optimised parameters).
    pub theta: Vec<f32>,
}

impl Step {
    /// GPU milliseconds of the whole iteration.
    pub fn gpu_ms(&self) -> f64 {
        self.pass_ms.values().sum()
    }
}
