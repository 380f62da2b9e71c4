//! One gradient estimate of the image loss: primal render → loss and adjoint image →
//! adjoint pass (path replay backpropagation) accumulating into the gradient buffer, for
//! every sensor, recorded once and resubmitted with a fresh iteration counter.
//!
//! The primal image of the loss and the adjoint pass use different seeds, so for the l2
//! loss the gradient is unbiased: E[2 (I − T) ∂I] = 2 (E[I] − T) E[∂I] when I and ∂I are
//! independent.

use super::{record_samples, GpuScene, TracePush};
use crate::constants::{LOCAL_GRADS_CAPACITY, LOSS_L1, LOSS_L2, LOSS_RELATIVE_L2};
use crate::gpu::{self, Buffer, ComputePipeline, MemoryKind, Recorder, SpecValue};
use crate::image::Image;
use crate::ops::{BufferOps, Reduction};
use crate::kernels::LossPush;
use crate::settings::Loss;

/// Seed offsets of the passes within an iteration: independent streams.
pub const SEED_PRIMAL: u32 = 0x1000_0000;
pub const SEED_ADJOINT: u32 = 0x2000_0000;

struct SensorBuffers {
    rendered: Buffer,
    target: Buffer,
    adjoint: Buffer,
    partials: Buffer,
    reduction: Reduction,
    primal_group: gpu::BindGroup,
    loss_group: gpu::BindGroup,
    adjoint_group: gpu::BindGroup,
    /// The θ_{i-1} image, adjoint image and loss of the fused finite difference.
    prev: Option<PrevBuffers>,
    /// The adjoint pass's render of θ (the mean radiance of its primal replays, `spp`
    /// samples per pixel); `None` in the fused finite-difference sample.
    adjoint_radiance: Option<Buffer>,
}

struct PrevBuffers {
    rendered: Buffer,
    adjoint: Buffer,
    partials: Buffer,
    loss_group: gpu::BindGroup,
}

/// What one gradient estimate computes: `targets` (one image per sensor, of the film's
/// size) under `loss`, with `spp` samples per pixel in the adjoint pass and `primal_spp` in
/// the primal render, seeded by `seed`. The passes read parameters from `theta` (the scene's
/// θ or another state of it) and add dLoss/dθ into `grad`. `theta_prev` and `grad_half`:
/// see [`GradientPass::new`].
#[derive(Clone, Copy)]
pub struct GradientInputs<'a> {
    pub targets: &'a [Image],
    pub loss: Loss,
    pub spp: u32,
    pub primal_spp: u32,
    pub seed: u32,
    pub theta: &'a Buffer,
    pub theta_prev: Option<&'a Buffer>,
    pub grad: &'a Buffer,
    pub grad_half: Option<&'a Buffer>,
}

/// The pipelines and buffers of the gradient estimate.
pub struct GradientPass {
    /// The kernels' names, which name their profiler scopes.
    primal_kernel: &'static str,
    adjoint_kernel: &'static str,
    primal: ComputePipeline,
    adjoint: ComputePipeline,
    loss: ComputePipeline,
    sensors: Vec<SensorBuffers>,
    /// dLoss/dθ, accumulated with atomics.
    pub grad: Buffer,
    /// The part of `grad` from half of the pixels (see [`Self::new`]), or an unused
    /// one-float buffer.
    grad_half: Buffer,
    /// With the half split and direct atomics (θ too long for the per-thread sums): the
    /// adjoint kernel adds every contribution here, two sums per element (outside and in
    /// the half), and each sensor's pass then merges them into `grad` and `grad_half`
    /// (glsl/merge_half.comp).
    fresh_half: Option<Buffer>,
    pub spp: u32,
    pub primal_spp: u32,
    pub seed: u32,
    /// Trace every `stride`-th pixel of each row, a checkerboard that moves every iteration
    /// (1: every pixel); the adjoint pass weighs each traced pixel by `stride`, so the
    /// gradient's expectation is the same. `phase` shifts the checkerboard (tests).
    pub stride: u32,
    pub phase: u32,
}

fn loss_index(loss: Loss) -> u32 {
    match loss {
        Loss::L2 => LOSS_L2,
        Loss::L1 => LOSS_L1,
        Loss::RelativeL2 => LOSS_RELATIVE_L2,
    }
}

impl GradientPass {
    /// The estimate of `inputs` ([`GradientInputs`]). Also adds the contributions of a
    /// random half of the pixels (drawn anew every iteration) into `grad_half` when given. The two halves are independent
    /// estimates, whose difference gives the optimiser's centred variance estimate. Halves of
    /// the samples would not be: every sample of a pixel shares its primal image, and so the
    /// image's noise.
    ///
    /// With `theta_prev`, the fused finite-difference sample ⟨ΔF⟩ (`theta` must then be the
    /// scene's θ and `primal_spp` equal `spp`): every path is sampled once at θ and evaluated
    /// at θ and at `theta_prev`; both primal images, both losses' adjoint images and the
    /// difference of the two gradients (+θ, −θ_prev) are computed in one trace per pass
    /// (glsl/lib/integrator.glsl, FD), and ⟨ΔF⟩ goes into `grad`.
    ///
    /// `theta` and `theta_prev` are shaped like the scene's θ buffer: θ padded to whole
    /// texels, then the scene's material data ([`crate::render::targets::padded`]).
    ///
    /// Not split: the pipelines, then each sensor's buffers and bind groups, which refer to
    /// each other by name.
    pub fn new(scene: &GpuScene, ops: &BufferOps, inputs: &GradientInputs) -> gpu::Result<Self> {
        let GradientInputs { targets, loss, spp, primal_spp, seed, theta, theta_prev, grad, grad_half } = *inputs;
        let ctx = &scene.ctx;
        for b in std::iter::once(theta).chain(theta_prev) {
            if b.len() != scene.theta.len() {
                return Err(gpu::GpuError::BufferAccess {
                    name: b.name().into(),
                    what: format!("{} bytes where the kernels read θ and the material data after it ({} bytes)", b.len(), scene.theta.len()),
                });
            }
        }
        let spec = scene.spec();
        let (primal_name, adjoint_name) = if theta_prev.is_some() { ("trace_fd_primal", "trace_fd_adjoint") } else { ("trace_primal", "trace_adjoint") };
        let primal = ComputePipeline::new(ctx, &scene.kernel(primal_name), &spec)?;
        // Small θ is accumulated per thread before the atomics (glsl/lib/scene_access.glsl).
        let mut adjoint_spec = spec.clone();
        let local = if (1..=LOCAL_GRADS_CAPACITY as usize).contains(&scene.layout.len) { scene.layout.len as u32 } else { 0 };
        adjoint_spec.push(("LOCAL_GRADS", SpecValue::U32(local)));
        adjoint_spec.push(("LOCAL_GRADS_UNROLLED", SpecValue::Bool(local != 0 && scene.local_grads_unrolled)));
        adjoint_spec.push(("SPLIT", SpecValue::Bool(grad_half.is_some())));
        adjoint_spec.push(("CACHE_ALL", SpecValue::Bool(scene.replay_cached)));
        let fresh_half = match grad_half {
            Some(_) if local == 0 => Some(Buffer::zeroed::<[f32; 2]>(ctx, "grad halves of one pass", scene.layout.len.max(1), MemoryKind::Device)?),
            _ => None,
        };
        let grad_half = match grad_half {
            Some(b) => b.clone(),
            None => Buffer::zeroed::<f32>(ctx, "grad half (unused)", 1, MemoryKind::Device)?,
        };
        let adjoint = ComputePipeline::new(ctx, &scene.kernel(adjoint_name), &adjoint_spec)?;
        let loss = ComputePipeline::new(ctx, "loss", &[("LOSS", SpecValue::U32(loss_index(loss)))])?;
        let grad = grad.clone();
        let n = scene.pixels();
        let groups = (n as u64).div_ceil(loss.local_size()[0] as u64).max(1);
        let mut sensors = Vec::new();
        for (s, target) in targets.iter().enumerate() {
            let rendered = Buffer::zeroed::<[f32; 3]>(ctx, &format!("rendered {s}"), n, MemoryKind::Device)?;
            let target = Buffer::from_slice(ctx, &format!("target {s}"), &target.data, MemoryKind::Device)?;
            let adjoint_img = Buffer::zeroed::<[f32; 3]>(ctx, &format!("adjoint image {s}"), n, MemoryKind::Device)?;
            let partials = Buffer::zeroed::<f32>(ctx, &format!("loss partials {s}"), groups as usize, MemoryKind::Device)?;
            let reduction = ops.reduction(&partials, false)?;
            let prev = match theta_prev {
                Some(_) => {
                    let rendered = Buffer::zeroed::<[f32; 3]>(ctx, &format!("rendered prev {s}"), n, MemoryKind::Device)?;
                    let adjoint = Buffer::zeroed::<[f32; 3]>(ctx, &format!("adjoint image prev {s}"), n, MemoryKind::Device)?;
                    let partials = Buffer::zeroed::<f32>(ctx, &format!("loss partials prev {s}"), groups as usize, MemoryKind::Device)?;
                    let loss_group = loss.bind(&[("Rendered", &rendered), ("Target", &target), ("AdjointImage", &adjoint), ("LossPartials", &partials)])?;
                    Some(PrevBuffers { rendered, adjoint, partials, loss_group })
                }
                None => None,
            };
            let mut b = scene.bindings_with(theta);
            b.push(("Accum", &rendered));
            if let (Some(tp), Some(pb)) = (theta_prev, &prev) {
                b.push(("ThetaPrev", tp));
                b.push(("AccumPrev", &pb.rendered));
            }
            let primal_group = primal.bind(&b)?;
            let loss_group = loss.bind(&[("Rendered", &rendered), ("Target", &target), ("AdjointImage", &adjoint_img), ("LossPartials", &partials)])?;
            let adjoint_radiance = match theta_prev {
                Some(_) => None,
                None => Some(Buffer::zeroed::<[f32; 3]>(ctx, &format!("adjoint radiance {s}"), n, MemoryKind::Device)?),
            };
            let mut b = scene.bindings_with(theta);
            b.push(("AdjointImage", &adjoint_img));
            if let Some(r) = &adjoint_radiance {
                b.push(("Accum", r));
            }
            b.push(("Grad", &grad));
            b.push(("GradHalf", fresh_half.as_ref().unwrap_or(&grad_half)));
            if let (Some(tp), Some(pb)) = (theta_prev, &prev) {
                b.push(("ThetaPrev", tp));
                b.push(("AdjointImagePrev", &pb.adjoint));
            }
            let adjoint_group = adjoint.bind(&b)?;
            sensors.push(SensorBuffers {
                rendered,
                target,
                adjoint: adjoint_img,
                partials,
                reduction,
                primal_group,
                loss_group,
                adjoint_group,
                prev,
                adjoint_radiance,
            });
        }
        Ok(Self {
            primal_kernel: primal_name,
            adjoint_kernel: adjoint_name,
            primal,
            adjoint,
            loss,
            sensors,
            grad,
            grad_half,
            fresh_half,
            spp,
            primal_spp,
            seed,
            stride: 1,
            phase: 0,
        })
    }

    /// Records the estimate for every sensor. Afterwards `grad` holds dLoss/dθ added to
    /// whatever it held, and `loss_value(s)` sensor s's loss.
    /// With a profiler attached to the recording, each pass is in a scope named after its
    /// kernel (`trace_primal` or `trace_fd_primal`, `loss` with its reduction,
    /// `trace_adjoint` or `trace_fd_adjoint`), once per sensor.
    pub fn record(&self, rec: &mut Recorder, scene: &GpuScene, ops: &BufferOps) -> gpu::Result<()> {
        self.record_passes(rec, scene, ops, true)
    }

    /// Records only the primal renders and the loss (for finite differences of the loss).
    pub fn record_loss(&self, rec: &mut Recorder, scene: &GpuScene, ops: &BufferOps) -> gpu::Result<()> {
        self.record_passes(rec, scene, ops, false)
    }

    /// Records the primal renders and the loss, and with `adjoint` the adjoint pass.
    pub fn record_passes(&self, rec: &mut Recorder, scene: &GpuScene, ops: &BufferOps, adjoint: bool) -> gpu::Result<()> {
        for s in 0..self.sensors.len() {
            self.record_sensor_primal(rec, scene, s)?;
            self.record_sensor_rest(rec, scene, ops, s, adjoint)?;
        }
        Ok(())
    }

    /// Records the primal renders of every sensor (the first half of [`Self::record_passes`],
    /// for a pass that changes the images before their loss).
    pub fn record_primal(&self, rec: &mut Recorder, scene: &GpuScene) -> gpu::Result<()> {
        (0..self.sensors.len()).try_for_each(|s| self.record_sensor_primal(rec, scene, s))
    }

    /// Records the losses and the adjoint passes of every sensor (the second half).
    pub fn record_loss_adjoint(&self, rec: &mut Recorder, scene: &GpuScene, ops: &BufferOps) -> gpu::Result<()> {
        (0..self.sensors.len()).try_for_each(|s| self.record_sensor_rest(rec, scene, ops, s, true))
    }

    /// The images of sensor `s` (one per parameter state) with their adjoint images,
    /// loss partials and loss bind groups.
    fn states(&self, s: usize) -> Vec<(&Buffer, &Buffer, &Buffer, &gpu::BindGroup)> {
        let b = &self.sensors[s];
        let mut states = vec![(&b.rendered, &b.adjoint, &b.partials, &b.loss_group)];
        if let Some(pb) = &b.prev {
            states.push((&pb.rendered, &pb.adjoint, &pb.partials, &pb.loss_group));
        }
        states
    }

    fn record_sensor_primal(&self, rec: &mut Recorder, scene: &GpuScene, s: usize) -> gpu::Result<()> {
        let b = &self.sensors[s];
        // The primal pass accumulates into the cleared images.
        for (rendered, _, _, _) in &self.states(s) {
            rec.zero(rendered)?;
        }
        let p = self.primal_push(scene, s as u32);
        // Short dispatches (see render::spp_per_dispatch), each adding to the images.
        rec.scope(self.primal_kernel, |rec| record_samples(rec, scene, &self.primal, &b.primal_group, p, self.primal_spp))
    }

    fn record_sensor_rest(&self, rec: &mut Recorder, scene: &GpuScene, ops: &BufferOps, s: usize, adjoint: bool) -> gpu::Result<()> {
        let n = scene.pixels();
        let b = &self.sensors[s];
        let lp = LossPush { n: n as u32, scale: (1.0 / (3.0 * n as f64)) as f32 };
        rec.scope("loss", |rec| {
            for (_, _, _, group) in &self.states(s) {
                rec.dispatch_linear(&self.loss, group, &lp, n as u64)?;
            }
            // The loss partials (of θ, the reported loss) are reduced.
            ops.record_reduction(rec, &b.reduction)
        })?;
        if !adjoint {
            return Ok(());
        }
        self.record_sensor_adjoint(rec, scene, ops, s)
    }

    /// Records sensor `s`'s adjoint pass alone: it reads the sensor's adjoint image as the
    /// loss left it, or as the host wrote it ([`Self::adjoint_image`]).
    pub fn record_sensor_adjoint(&self, rec: &mut Recorder, scene: &GpuScene, ops: &BufferOps, s: usize) -> gpu::Result<()> {
        let b = &self.sensors[s];
        // Every stride-th pixel stands for `stride` of them.
        let p = self.trace_push(scene, s as u32, self.spp, self.seed.wrapping_add(SEED_ADJOINT), self.stride as f32 / self.spp as f32);
        rec.scope(self.adjoint_kernel, |rec| {
            if let Some(r) = &b.adjoint_radiance {
                // The pass adds its render into the cleared image.
                rec.zero(r)?;
            }
            record_samples(rec, scene, &self.adjoint, &b.adjoint_group, p, self.spp)?;
            match &self.fresh_half {
                Some(fresh) => ops.merge_half(rec, &self.grad, &self.grad_half, fresh),
                None => Ok(()),
            }
        })
    }

    /// Sensor s's adjoint image dLoss/dImage, which the loss writes and the adjoint pass reads.
    pub fn adjoint_image(&self, s: usize) -> &Buffer {
        &self.sensors[s].adjoint
    }

    /// Sensor s's primal image buffer (of θ; after the primal pass, before the loss reads it).
    pub fn image(&self, s: usize) -> &Buffer {
        &self.sensors[s].rendered
    }

    /// Sensor s's render by the adjoint pass (after it ran): the mean radiance of its primal
    /// replays of θ, `spp` samples per pixel with the pass's own random numbers; `None` in the
    /// fused finite-difference sample.
    pub fn adjoint_radiance(&self, s: usize) -> Option<&Buffer> {
        self.sensors[s].adjoint_radiance.as_ref()
    }

    /// Sensor s's primal image of θ_{i-1} (the fused finite-difference sample's second state).
    pub fn prev_image(&self, s: usize) -> Option<&Buffer> {
        self.sensors[s].prev.as_ref().map(|p| &p.rendered)
    }

    /// The push constants of sensor `sensor`'s primal render: another primal kernel given
    /// them (e.g. a variant of trace_primal) traces the same paths.
    pub fn primal_push(&self, scene: &GpuScene, sensor: u32) -> TracePush {
        self.trace_push(scene, sensor, self.primal_spp, self.seed.wrapping_add(SEED_PRIMAL), 1.0 / self.primal_spp as f32)
    }

    /// The push constants of a trace pass over sensor `sensor` on this pass's pixels.
    fn trace_push(&self, scene: &GpuScene, sensor: u32, spp: u32, seed: u32, weight: f32) -> TracePush {
        TracePush { width: scene.width, height: scene.height, sensor, spp, first_sample: 0, seed, weight, stride: self.stride, phase: self.phase }
    }

    /// Sensor s's loss after the recorded work ran.
    pub fn loss_value(&self, s: usize) -> gpu::Result<f32> {
        Ok(self.sensors[s].reduction.result().read::<f32>()?[0])
    }

    /// The one-float buffer that holds sensor s's loss after the recorded work ran.
    pub fn loss_buffer(&self, s: usize) -> &Buffer {
        self.sensors[s].reduction.result()
    }

    /// Total loss over sensors.
    pub fn total_loss(&self) -> gpu::Result<f64> {
        (0..self.sensors.len()).map(|s| self.loss_value(s).map(|v| v as f64)).sum()
    }

    /// Sensor s's primal image of the last estimate.
    pub fn rendered(&self, s: usize, scene: &GpuScene) -> gpu::Result<Image> {
        Ok(Image { width: scene.width, height: scene.height, data: self.sensors[s].rendered.read()? })
    }

    pub fn sensors(&self) -> usize {
        self.sensors.len()
    }

    pub fn target(&self, s: usize) -> &Buffer {
        &self.sensors[s].target
    }
}
