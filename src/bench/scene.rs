//! `vkinverse bench SCENE.toml`: the GPU passes of a scene's optimisation iteration, timed
//! with profiler scopes over N submissions and reported as medians.
//!
//! The iteration's passes are the [`Engine`]'s, as `optimise` builds them (with the
//! meta-estimator), plus what the bench compares them with. One recording, resubmitted with
//! a fresh iteration counter, times everything in the same submission, under the same
//! load, in one profiler per group of passes (every scope named after its kernel, once per
//! sensor where a pass is per sensor):
//! - `gradient`: the proportional estimate (`trace_primal`, `loss`, `trace_adjoint`);
//! - `finite_difference`: the fused finite-difference sample (`trace_fd_primal`, `loss`,
//!   `trace_fd_adjoint`), and `finite_difference_two_trace`: the straightforward one (two
//!   gradient estimates and `sub`);
//! - `optimiser`: `optim_meta` and `optim_adam` (both step θ, so that both are timed on the
//!   scene's parameter groups), and `copy` over θ as the reference kernel;
//! - `iteration`: one scope around all of the above;
//! - `equal_spp`: the proportional estimate at fd_spp samples for primal and adjoint, for
//!   the cost ratios at equal sample counts;
//! - `generic`: `trace_primal` built from the unspecialised variant trace_primal_generic
//!   (the integrator's limits read at run time), for the specialisation gain;
//! - `sampled`: `trace_primal` built to read the scene's texel buffers by texel fetches
//!   (trace_primal_sampled) instead of image loads, the same bits (glsl/lib/texels.glsl).
//!
//! Rays are counted once, untimed, by the variant trace_primal_count, which traces the
//! same paths as the primal pass with the same push constants and counts every ray cast;
//! rays/s is that count over the median time of the uncounted primal pass. The same
//! submission renders the specialised, generic and sampled variants too and compares the
//! images, which must agree: the comparison is of speed only.
//!
//! The BVH throughput is trace_test (closest hit only, any hit only) on jittered camera
//! rays of the first sensor, in the default node layout (`bench SCENE --bvh-layouts`
//! compares the layouts: bench/layouts.rs).

use super::{median, optimiser_bandwidth, timed_rounds, OptimiserBandwidth};
use crate::bvh::TraceRay;
use crate::engine::{Engine, FdSample};
use crate::error::{Error, Result};
use crate::gpu::{self, Access, BindGroup, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Profiler, ScopeTime, SpecValue};
use crate::kernels::CountPush;
use crate::optim::gpu::GpuOptimiser;
use crate::optim::spec::Spec;
use crate::optim::Optimiser;
use crate::render::gradient::GradientPass;
use crate::render::{record_samples, GpuScene};
use crate::scene::Scene;
use crate::settings::{gpu_seed, RunSettings};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Camera rays per pixel of the BVH throughput measurement: enough work per dispatch that
/// the dispatch overhead does not dominate on small films.
const BVH_RAYS_PER_PIXEL: u32 = 16;

/// One pass's median GPU time per iteration (summed over sensors).
#[derive(Clone, Debug, Serialize)]
pub struct PassTime {
    /// The group of passes: gradient, finite_difference, finite_difference_two_trace,
    /// optimiser.
    pub group: String,
    /// The kernel.
    pub name: String,
    /// Samples per pixel of a rendering pass.
    pub spp: Option<u32>,
    pub median_ms: f64,
    /// trace_primal: the counted rays over its time.
    pub rays_per_s: Option<f64>,
    /// Optimiser passes: the scene's parameters over the pass time (none without parameters).
    pub params_per_s: Option<f64>,
    /// copy: bytes read plus written over its time.
    pub gb_per_s: Option<f64>,
}

/// Rays cast by one primal pass (every sensor, primal_spp samples), counted on the GPU.
#[derive(Clone, Debug, Serialize)]
pub struct RayCount {
    pub spp: u32,
    /// Primary, extension and shadow rays.
    pub rays: u64,
    pub rays_per_sample: f64,
    /// `rays` over the median time of the (uncounted) trace_primal pass.
    pub rays_per_s: f64,
}

/// A specialization constant of the integrator kernels as chosen for the scene.
#[derive(Clone, Debug, Serialize)]
pub struct SpecConstant {
    pub name: String,
    pub value: String,
}

/// trace_primal specialised for the scene against the generic build on the same scene.
#[derive(Clone, Debug, Serialize)]
pub struct SpecialisationGain {
    pub spp: u32,
    pub specialised_ms: f64,
    pub generic_ms: f64,
    /// generic_ms / specialised_ms.
    pub gain: f64,
    /// Σ|generic − specialised| / Σ|specialised| over the pixels of both renders (same seed).
    pub generic_image_rel_diff: f64,
    /// The same for the ray-counting variant.
    pub count_image_rel_diff: f64,
    /// trace_primal reading the scene's texel buffers by texel fetches (the sampler's path)
    /// instead of image loads.
    pub sampled_ms: f64,
    /// sampled_ms / specialised_ms.
    pub sampled_gain: f64,
    /// The image difference of the sampled variant (the same bits are read: 0).
    pub sampled_image_rel_diff: f64,
}

/// Cost ratios at equal samples per pixel.
#[derive(Clone, Debug, Serialize)]
pub struct Ratios {
    /// The samples per pixel of both sides (the scene's fd_spp).
    pub spp: u32,
    /// The proportional gradient estimate (primal, loss, adjoint).
    pub proportional_ms: f64,
    /// The finite-difference sample as `optimise` records it (fused: one trace, both states).
    pub finite_difference_ms: f64,
    pub fd_over_proportional: f64,
    /// The straightforward finite-difference sample (one gradient estimate per state).
    pub finite_difference_two_trace_ms: f64,
    pub fd_two_trace_over_proportional: f64,
    pub primal_ms: f64,
    pub adjoint_ms: f64,
    /// The project's goal is at most 2.
    pub adjoint_over_primal: f64,
}

/// trace_test on camera rays of the first sensor.
#[derive(Clone, Debug, Default, Serialize)]
pub struct BvhThroughput {
    /// The node layout traced (the default unless `VKINVERSE_BVH_LAYOUT` names another).
    pub layout: String,
    pub rays: u64,
    pub triangles: usize,
    pub closest_ms: f64,
    pub closest_mrays_per_s: f64,
    pub any_ms: f64,
    pub any_mrays_per_s: f64,
}

/// The scene bench's results.
#[derive(Clone, Debug, Serialize)]
pub struct SceneBench {
    pub scene: String,
    pub device: String,
    pub iterations: u32,
    /// `LP_NUM_THREADS` as set for lavapipe (unset: Mesa's default, one per core).
    pub lp_num_threads: Option<String>,
    pub validation: bool,
    pub width: u32,
    pub height: u32,
    pub sensors: usize,
    pub triangles: usize,
    pub parameters: usize,
    pub spp: u32,
    pub primal_spp: u32,
    pub fd_spp: u32,
    /// GpuScene::spec(): the integrator's specialization constants.
    pub specialisation: Vec<SpecConstant>,
    /// Per-pass medians, in iteration order.
    pub passes: Vec<PassTime>,
    /// Median of the whole timed iteration (every pass above and the barriers between).
    pub iteration_ms: f64,
    pub rays: RayCount,
    pub specialisation_gain: SpecialisationGain,
    pub ratios: Ratios,
    pub bvh: BvhThroughput,
    /// Bytes of device allocations alive for the iteration's passes (scene, gradient and
    /// finite-difference buffers, both optimisers' state).
    pub memory_bytes: u64,
    pub memory_allocations: usize,
    /// Host↔device traffic per timed iteration: the frame counter written, the loss and θ
    /// read back (as `optimise` does for its log).
    pub transfer: TransferPerIteration,
    /// The untimed rounds of the iteration before the timed ones.
    pub warm_up: WarmUp,
    /// The fused optimiser passes on a synthetic θ.
    pub optimisers: OptimiserBandwidth,
}

/// The untimed rounds of the scene's iteration before the timed ones: the first (lavapipe
/// and some drivers compile a pipeline at its first dispatch), then more until the warm-up
/// time has passed after it, so that a GPU whose clocks idle low has raised them.
#[derive(Clone, Debug, Default, Serialize)]
pub struct WarmUp {
    pub rounds: u32,
    /// The time the rounds after the first took.
    pub seconds: f64,
}

/// Means per iteration of the context's transfer statistics over the timed iterations.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TransferPerIteration {
    /// False when device memory is read and written through the staging buffers (a
    /// discrete GPU, or `VKINVERSE_UNMAPPABLE_DEVICE_MEMORY=1`).
    pub device_memory_mappable: bool,
    pub upload_bytes: f64,
    pub readback_bytes: f64,
    pub staged_bytes: f64,
    pub staged_submissions: f64,
    /// Buffers and staging buffers created during the timed iterations (0: an iteration
    /// allocates nothing).
    pub buffers_created: u64,
}

/// Per-submission sums of the scopes of each name, collected over submissions.
#[derive(Default)]
pub(super) struct Samples(BTreeMap<String, Vec<f64>>);

impl Samples {
    pub(super) fn add(&mut self, times: &[ScopeTime]) {
        let mut sums: BTreeMap<&str, f64> = BTreeMap::new();
        for t in times {
            *sums.entry(&t.name).or_default() += t.ms;
        }
        for (name, ms) in sums {
            self.0.entry(name.to_string()).or_default().push(ms);
        }
    }

    pub(super) fn median(&self, name: &str) -> f64 {
        median(&mut self.0.get(name).cloned().unwrap_or_default())
    }

    /// The median over submissions of the sum of every scope.
    pub(super) fn total(&self) -> f64 {
        let n = self.0.values().map(Vec::len).max().unwrap_or(0);
        let mut sums: Vec<f64> = (0..n).map(|i| self.0.values().filter_map(|v| v.get(i)).sum()).collect();
        median(&mut sums)
    }
}

fn spec_value(v: SpecValue) -> String {
    match v {
        SpecValue::Bool(b) => b.to_string(),
        SpecValue::U32(x) => x.to_string(),
        SpecValue::I32(x) => x.to_string(),
        SpecValue::F32(x) => x.to_string(),
    }
}

/// Σ|a − b| / Σ|a| over every channel of two images.
pub(super) fn rel_diff(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (p, q) in a.iter().zip(b) {
        for c in 0..3 {
            num += (p[c] as f64 - q[c] as f64).abs();
            den += (p[c] as f64).abs();
        }
    }
    num / den.max(f64::MIN_POSITIVE)
}

/// Benchmarks `scene`'s iteration over `iterations` submissions, and the optimiser
/// passes on a synthetic θ of `optimiser_elements` parameters.
/// `warm_up`: how long to repeat the scene's iteration, untimed, before timing it (at least
/// once).
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::scene::{Film, LoadOptions};
/// let small = LoadOptions { film: Some(Film { width: 16, height: 16 }), max_depth: Some(2) };
/// let scene = vkinverse::Scene::load_with("scenes/cornell/scene.toml", &small)?;
/// let device = vkinverse::Device::new(&vkinverse::Config::from_env().0)?;
/// let bench = vkinverse::bench::scene_bench(&device, &scene, 1, 1 << 10, std::time::Duration::ZERO)?;
/// assert!(bench.iteration_ms > 0.0);
/// # Ok(())
/// # }
/// ```
pub fn scene_bench(device: &crate::device::Device, scene: &Scene, iterations: u32, optimiser_elements: u64, warm_up: Duration) -> Result<SceneBench> {
    let ctx = device.ctx();
    let iterations = iterations.max(1);
    // First, so that its buffers (large at 16M parameters) are gone before the scene's.
    let optimisers = optimiser_bandwidth(ctx, optimiser_elements, iterations)?;
    measure_scene(device, scene, iterations, optimisers, warm_up)
}

/// The bench's own passes beside the engine's: the other optimiser, the two-trace
/// finite-difference sample, the gradient at equal spp, the unspecialised and sampled
/// builds of the primal kernel.
struct Extras {
    adam: GpuOptimiser,
    fd_two: FdSample,
    theta_copy: Buffer,
    _eq_grad: Buffer,
    equal: GradientPass,
    generic: Variant,
    sampled: Variant,
    memory_bytes: u64,
    memory_allocations: usize,
}

/// A build of trace_primal other than the engine's, bound to the scene with an image of its
/// own.
struct Variant {
    pipe: ComputePipeline,
    group: BindGroup,
    image: Buffer,
}

impl Variant {
    /// trace_primal_generic (the integrator's limits read from a buffer).
    fn generic(ctx: &Arc<Context>, gs: &GpuScene) -> Result<Self> {
        let limits = Buffer::from_slice(ctx, "integrator limits", &gs.integrator_limits(), MemoryKind::Device)?;
        Self::new(ctx, gs, "trace_primal_generic", &[gs.const_base_spec()], "generic accum", &[("IntegratorLimits", &limits)])
    }

    /// `kernel` (in the scene's node layout) with specialization constants `spec` and the
    /// scene's bindings, `extra` and an image named `image_name` as its accumulator.
    fn new(
        ctx: &Arc<Context>,
        gs: &GpuScene,
        kernel: &str,
        spec: &[(&'static str, SpecValue)],
        image_name: &str,
        extra: &[(&'static str, &Buffer)],
    ) -> Result<Self> {
        let pipe = ComputePipeline::new(ctx, &gs.kernel(kernel), spec)?;
        let image = Buffer::zeroed::<[f32; 3]>(ctx, image_name, gs.pixels(), MemoryKind::Device)?;
        let mut b = gs.bindings();
        b.push(("Accum", &image));
        b.extend_from_slice(extra);
        let group = pipe.bind(&b)?;
        Ok(Variant { pipe, group, image })
    }

    /// Adds its render of every sensor at the primal pass's push constants to its image
    /// (the renders accumulate into one image), each in a scope called `trace_primal`.
    fn record(&self, rec: &mut crate::gpu::Recorder, engine: &Engine) -> gpu::Result<()> {
        let gs = engine.scene();
        for s in 0..gs.sensors as u32 {
            let push = engine.gradient.primal_push(gs, s);
            rec.scope("trace_primal", |rec| record_samples(rec, gs, &self.pipe, &self.group, push, push.spp))?;
        }
        Ok(())
    }
}

fn extras(ctx: &Arc<Context>, engine: &Engine) -> Result<Extras> {
    let gs = engine.scene();
    let st = &engine.settings;
    let adam_kind = match &engine.settings.optimiser.optimiser {
        Optimiser::Adam(h) => Optimiser::Adam(*h),
        Optimiser::Meta(_) => Optimiser::Adam(Default::default()),
    };
    let adam = engine.extra_optimiser(&adam_kind)?;
    let theta_prev = engine.optimiser()?.theta_prev.as_ref().ok_or_else(|| Error::Invalid("the meta optimiser has no previous θ".into()))?;
    let fd_two = engine.fd_sample(theta_prev, true, None)?;
    let live = ctx.live_allocations();
    let theta_copy = Buffer::new(ctx, "theta copy", gs.theta.len(), MemoryKind::Device)?;
    let eq_grad = Buffer::zeroed::<f32>(ctx, "grad at equal spp", gs.layout.len.max(1), MemoryKind::Device)?;
    let equal = engine.extra_gradient(st.fd_spp, st.fd_spp, gpu_seed(st.seed), &eq_grad)?;
    let generic = Variant::generic(ctx, gs)?;
    let sampled = Variant::new(ctx, gs, "trace_primal_sampled", &gs.spec(), "sampled accum", &[])?;
    Ok(Extras {
        adam,
        fd_two,
        theta_copy,
        _eq_grad: eq_grad,
        equal,
        generic,
        sampled,
        memory_bytes: live.iter().map(|(_, size)| size).sum(),
        memory_allocations: live.len(),
    })
}

/// Rays cast by one primal pass (counted by trace_primal_count) and the relative image
/// differences of the generic, counting and sampled builds against the specialised one:
/// each renders every sensor once, at θ and the first iteration's counter, with the primal
/// pass's push constants (before the timed rounds, into the variants' own images).
fn count_rays(ctx: &Arc<Context>, engine: &Engine, x: &Extras) -> Result<(u64, [f64; 3])> {
    let gs = engine.scene();
    let specialised = Variant::new(ctx, gs, "trace_primal", &gs.spec(), "image specialised", &[])?;
    let counters = Buffer::zeroed::<u32>(ctx, "ray count", gs.pixels().div_ceil(specialised.pipe.local_size()[0] as usize), MemoryKind::Device)?;
    let counting = Variant::new(ctx, gs, "trace_primal_count", &gs.spec(), "image counted", &[("RayCount", &counters)])?;
    gs.set_frame(0)?;
    let mut check = CommandBuffer::new(ctx, "ray count")?;
    check.record(|rec| {
        for v in [&specialised, &x.generic, &x.sampled, &counting] {
            v.record(rec, engine)?;
        }
        Ok(())
    })?;
    check.submit_and_wait()?;
    let rays: u64 = counters.read::<u32>()?.iter().map(|&c| c as u64).sum();
    let reference: Vec<[f32; 3]> = specialised.image.read()?;
    let diff = |v: &Variant| -> Result<f64> { Ok(rel_diff(&reference, &v.image.read()?)) };
    Ok((rays, [diff(&x.generic)?, diff(&counting)?, diff(&x.sampled)?]))
}

/// The profilers of the timed recording, one per group of passes.
const GROUPS: [&str; 8] = ["gradient", "finite_difference", "finite_difference_two_trace", "optimiser", "iteration", "equal_spp", "generic", "sampled"];

/// Records the timed iteration: the engine's passes and the extras, each group in its own
/// profiler (see the module documentation).
fn record_timed(cmd: &mut CommandBuffer, profs: &mut [Profiler], engine: &Engine, x: &Extras) -> Result<()> {
    let gs = engine.scene();
    let ops = &engine.ops;
    cmd.record(|rec| {
        for p in profs.iter_mut() {
            p.reset(rec);
        }
        let [grad, fd, fd_two, opt, iter, eq, generic, sampled] = profs else { unreachable!("one profiler per group") };
        iter.begin(rec, "iteration")?;
        rec.with_profiler(grad, |rec| engine.record_gradient(rec))?;
        rec.with_profiler(fd, |rec| engine.record_fd(rec))?;
        rec.with_profiler(fd_two, |rec| x.fd_two.record(rec, gs, ops, &engine.fd_grad))?;
        rec.with_profiler(opt, |rec| {
            engine.record_step(rec, engine.optimiser.as_ref().expect("the engine's optimiser"))?;
            engine.record_step(rec, &x.adam)?;
            // The copy reads θ, which the optimisers wrote.
            rec.scope("copy", |rec| ops.copy(rec, &gs.theta, &x.theta_copy))
        })?;
        // What the host reads back, as an optimisation's iteration records it.
        engine.report.record(rec)?;
        iter.end(rec)?;
        rec.with_profiler(eq, |rec| x.equal.record_passes(rec, gs, ops, true))?;
        rec.with_profiler(generic, |rec| x.generic.record(rec, engine))?;
        rec.with_profiler(sampled, |rec| x.sampled.record(rec, engine))?;
        Ok(())
    })?;
    Ok(())
}

fn measure_scene(device: &crate::device::Device, scene: &Scene, iterations: u32, optimisers: OptimiserBandwidth, warm_up: Duration) -> Result<SceneBench> {
    let mut st = RunSettings::of_scene(scene);
    if !st.optimiser.optimiser.needs_fd() {
        st.optimiser = Spec::default();
    }
    st.fd_two_trace = false;
    let ctx = device.ctx();
    let engine = Engine::new(device, scene, &st, &mut (), &crate::cancel::Cancel::new())?;
    let x = extras(ctx, &engine)?;
    let (rays, [generic_image_rel_diff, count_image_rel_diff, sampled_image_rel_diff]) = count_rays(ctx, &engine, &x)?;
    let mut profs = GROUPS.iter().map(|_| Profiler::new(ctx, Profiler::SCOPES)).collect::<gpu::Result<Vec<_>>>()?;
    let mut cmd = CommandBuffer::new(ctx, "bench iteration")?;
    record_timed(&mut cmd, &mut profs, &engine, &x)?;
    // Warm-up: lavapipe (and some drivers) compile a pipeline on its first dispatch, and a
    // GPU raises its clocks only under load, so after that round more follow until the
    // warm-up time has passed.
    cmd.submit_and_wait()?;
    let start = Instant::now();
    let mut rounds = 1;
    while start.elapsed() < warm_up {
        cmd.submit_and_wait()?;
        rounds += 1;
    }
    let warm_up = WarmUp { rounds, seconds: start.elapsed().as_secs_f64() };
    let mut samples: Vec<Samples> = GROUPS.iter().map(|_| Samples::default()).collect();
    let before = ctx.transfer_stats();
    for i in 0..iterations {
        engine.scene().set_frame(i + 1)?;
        cmd.submit_and_wait()?;
        // The host's side of an optimisation iteration: the loss, the optimiser's
        // diagnostics of the step and θ for the log, from the iteration's report.
        engine.read_step(i + 1)?;
        for (s, p) in samples.iter_mut().zip(&profs) {
            s.add(&p.results()?);
        }
    }
    let moved = ctx.transfer_stats().since(&before);
    let per = |v: u64| v as f64 / f64::from(iterations.max(1));
    let transfer = TransferPerIteration {
        device_memory_mappable: ctx.device_memory_mappable(),
        upload_bytes: per(moved.upload_bytes),
        readback_bytes: per(moved.readback_bytes),
        staged_bytes: per(moved.staged_upload_bytes + moved.staged_readback_bytes),
        staged_submissions: per(moved.staged_submissions),
        buffers_created: moved.buffers_created + moved.staging_allocations,
    };
    let measured = Measured { engine: &engine, samples: &samples, rays, generic_image_rel_diff, count_image_rel_diff, sampled_image_rel_diff };
    let mut bench = measured.report(scene, iterations, &x, optimisers);
    bench.bvh = bvh_throughput(ctx, scene, engine.scene(), iterations)?;
    bench.transfer = transfer;
    bench.warm_up = warm_up;
    Ok(bench)
}

/// The medians of a bench run and what they are of.
struct Measured<'a> {
    engine: &'a Engine,
    samples: &'a [Samples],
    rays: u64,
    generic_image_rel_diff: f64,
    count_image_rel_diff: f64,
    sampled_image_rel_diff: f64,
}

impl Measured<'_> {
    fn group(&self, name: &str) -> &Samples {
        &self.samples[GROUPS.iter().position(|g| *g == name).expect("a bench group")]
    }

    fn report(&self, scene: &Scene, iterations: u32, x: &Extras, optimisers: OptimiserBandwidth) -> SceneBench {
        let (gs, st) = (self.engine.scene(), &self.engine.settings);
        let pixels = gs.pixels() as u64;
        let primal_ms = self.group("gradient").median("trace_primal");
        let rays_per_s = self.rays as f64 / (primal_ms * 1e-3).max(1e-12);
        let per_s = |ms: f64, items: f64| (items > 0.0).then(|| items / (ms * 1e-3).max(1e-12));
        let pass = |group: &str, name: &str, spp: Option<u32>| {
            let ms = self.group(group).median(name);
            PassTime {
                group: group.into(),
                name: name.into(),
                spp,
                median_ms: ms,
                rays_per_s: (group == "gradient" && name == "trace_primal").then_some(rays_per_s),
                params_per_s: if name.starts_with("optim_") { per_s(ms, gs.layout.len as f64) } else { None },
                gb_per_s: (name == "copy").then(|| gs.theta.len() as f64 * 2.0 / (ms * 1e-3).max(1e-12) / 1e9),
            }
        };
        let passes = vec![
            pass("gradient", "trace_primal", Some(st.primal_spp)),
            pass("gradient", "loss", None),
            pass("gradient", "trace_adjoint", Some(st.spp)),
            pass("finite_difference", "trace_fd_primal", Some(st.fd_spp)),
            pass("finite_difference", "loss", None),
            pass("finite_difference", "trace_fd_adjoint", Some(st.fd_spp)),
            pass("finite_difference_two_trace", "trace_primal", Some(st.fd_spp)),
            pass("finite_difference_two_trace", "loss", None),
            pass("finite_difference_two_trace", "trace_adjoint", Some(st.fd_spp)),
            pass("finite_difference_two_trace", "sub", None),
            pass("optimiser", "optim_meta", None),
            pass("optimiser", "optim_adam", None),
            pass("optimiser", "copy", None),
        ];
        let eq = self.group("equal_spp");
        let proportional_ms = eq.total();
        let (fd_ms, fd_two_ms) = (self.group("finite_difference").total(), self.group("finite_difference_two_trace").total());
        let generic_ms = self.group("generic").median("trace_primal");
        let sampled_ms = self.group("sampled").median("trace_primal");
        SceneBench {
            scene: scene.path.display().to_string(),
            device: gs.ctx.info().name.clone(),
            iterations,
            lp_num_threads: std::env::var("LP_NUM_THREADS").ok(),
            validation: gs.ctx.validation_enabled(),
            width: gs.width,
            height: gs.height,
            sensors: gs.sensors,
            triangles: gs.triangles,
            parameters: gs.layout.len,
            spp: st.spp,
            primal_spp: st.primal_spp,
            fd_spp: st.fd_spp,
            specialisation: gs.spec().into_iter().map(|(name, v)| SpecConstant { name: name.into(), value: spec_value(v) }).collect(),
            passes,
            iteration_ms: self.group("iteration").median("iteration"),
            rays: RayCount {
                spp: st.primal_spp,
                rays: self.rays,
                rays_per_sample: self.rays as f64 / (pixels * gs.sensors as u64 * st.primal_spp as u64) as f64,
                rays_per_s,
            },
            specialisation_gain: SpecialisationGain {
                spp: st.primal_spp,
                specialised_ms: primal_ms,
                generic_ms,
                gain: generic_ms / primal_ms.max(1e-12),
                generic_image_rel_diff: self.generic_image_rel_diff,
                count_image_rel_diff: self.count_image_rel_diff,
                sampled_ms,
                sampled_gain: sampled_ms / primal_ms.max(1e-12),
                sampled_image_rel_diff: self.sampled_image_rel_diff,
            },
            ratios: Ratios {
                spp: st.fd_spp,
                proportional_ms,
                finite_difference_ms: fd_ms,
                fd_over_proportional: fd_ms / proportional_ms.max(1e-12),
                finite_difference_two_trace_ms: fd_two_ms,
                fd_two_trace_over_proportional: fd_two_ms / proportional_ms.max(1e-12),
                primal_ms: eq.median("trace_primal"),
                adjoint_ms: eq.median("trace_adjoint"),
                adjoint_over_primal: eq.median("trace_adjoint") / eq.median("trace_primal").max(1e-12),
            },
            bvh: BvhThroughput::default(),
            transfer: TransferPerIteration::default(),
            warm_up: WarmUp::default(),
            memory_bytes: x.memory_bytes,
            memory_allocations: x.memory_allocations,
            optimisers,
        }
    }
}

/// BVH_RAYS_PER_PIXEL jittered camera rays per pixel of the first sensor, the same in
/// every run.
pub(super) fn camera_rays(scene: &Scene, gs: &GpuScene) -> Vec<TraceRay> {
    let sensor = &scene.sensors[0];
    let (w, h) = (gs.width, gs.height);
    let aspect = w as f32 / h as f32;
    // A fixed integer hash (lowbias32) as the jitter: the same rays in every run.
    let hash = |mut x: u32| {
        x ^= x >> 16;
        x = x.wrapping_mul(0x7feb_352d);
        x ^= x >> 15;
        x = x.wrapping_mul(0x846c_a68b);
        x ^= x >> 16;
        (x >> 8) as f32 / (1u32 << 24) as f32
    };
    let mut rays = Vec::with_capacity((w * h * BVH_RAYS_PER_PIXEL) as usize);
    for y in 0..h {
        for x in 0..w {
            for k in 0..BVH_RAYS_PER_PIXEL {
                let id = ((y * w + x) * BVH_RAYS_PER_PIXEL + k) * 2;
                let ndc = glam::Vec2::new((x as f32 + hash(id)) / w as f32 * 2.0 - 1.0, 1.0 - (y as f32 + hash(id + 1)) / h as f32 * 2.0);
                let (origin, dir) = sensor.ray(ndc, aspect);
                rays.push(TraceRay { origin: origin.to_array(), tmax: f32::INFINITY, dir: dir.to_array() });
            }
        }
    }
    rays
}

/// trace_test over BVH_RAYS_PER_PIXEL jittered camera rays per pixel of the first sensor,
/// closest hit only and any hit only, `iterations` times each.
fn bvh_throughput(ctx: &Arc<Context>, scene: &Scene, gs: &GpuScene, iterations: u32) -> Result<BvhThroughput> {
    let rays = camera_rays(scene, gs);
    let n = rays.len() as u64;
    let ray_buf = Buffer::from_slice(ctx, "bvh bench rays", &rays, MemoryKind::Device)?;
    let results = Buffer::zeroed::<crate::bvh::TraceResult>(ctx, "bvh bench results", rays.len(), MemoryKind::Device)?;
    let pipe = |closest: bool| {
        ComputePipeline::new(ctx, &gs.kernel("trace_test"), &[("TRACE_CLOSEST", SpecValue::Bool(closest)), ("TRACE_ANY", SpecValue::Bool(!closest))])
    };
    let (closest, any) = (pipe(true)?, pipe(false)?);
    let bind = |p: &ComputePipeline| {
        let mut b = vec![("Rays", &ray_buf), ("Results", &results)];
        b.extend(gs.bvh().bindings());
        p.bind(&b)
    };
    let (closest_group, any_group) = (bind(&closest)?, bind(&any)?);
    let push = CountPush::new(n);
    // Two profilers, so that both scopes carry the kernel's name.
    let mut closest_prof = Profiler::new(ctx, 1)?;
    let mut any_prof = Profiler::new(ctx, 1)?;
    let mut cmd = CommandBuffer::new(ctx, "bvh bench")?;
    cmd.record(|rec| {
        closest_prof.reset(rec);
        any_prof.reset(rec);
        rec.transition(&[(&results, Access::ComputeWrite)])?;
        closest_prof.scope(rec, "trace_test", |rec, _| rec.dispatch_linear(&closest, &closest_group, &push, n))?;
        // Both kernels write the results.
        rec.barrier(&results, Access::ComputeWrite, Access::ComputeWrite)?;
        any_prof.scope(rec, "trace_test", |rec, _| rec.dispatch_linear(&any, &any_group, &push, n))
    })?;
    let (mut c, mut a) = (Vec::new(), Vec::new());
    timed_rounds(&mut cmd, iterations, || {
        c.push(Profiler::total_ms(&closest_prof.results()?, "trace_test"));
        a.push(Profiler::total_ms(&any_prof.results()?, "trace_test"));
        Ok(())
    })?;
    let (closest_ms, any_ms) = (median(&mut c), median(&mut a));
    let mrays = |ms: f64| n as f64 / (ms * 1e-3).max(1e-12) * 1e-6;
    Ok(BvhThroughput {
        layout: gs.bvh().layout.name().to_string(),
        rays: n,
        triangles: gs.triangles,
        closest_ms,
        closest_mrays_per_s: mrays(closest_ms),
        any_ms,
        any_mrays_per_s: mrays(any_ms),
    })
}

impl SceneBench {
    /// The results as fixed-width tables.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "scene bench: {} on {}: {}x{}, {} sensor(s), {} triangles, {} parameters; median of {} iterations after {} untimed ({:.2} s of warm-up), LP_NUM_THREADS={}",
            self.scene,
            self.device,
            self.width,
            self.height,
            self.sensors,
            self.triangles,
            self.parameters,
            self.iterations,
            self.warm_up.rounds,
            self.warm_up.seconds,
            self.lp_num_threads.as_deref().unwrap_or("unset")
        );
        let spec: Vec<String> = self.specialisation.iter().map(|c| format!("{}={}", c.name, c.value)).collect();
        let _ = writeln!(s, "specialisation: {}", spec.join(" "));
        let _ = writeln!(s, "{:<46} {:>4} {:>11}  rate", "group / pass", "spp", "median ms");
        for p in &self.passes {
            let spp = p.spp.map(|v| v.to_string()).unwrap_or_default();
            let rate = match (p.rays_per_s, p.params_per_s, p.gb_per_s) {
                (Some(r), _, _) => format!("{:.2} Mrays/s", r * 1e-6),
                (_, Some(r), _) => format!("{:.3e} params/s", r),
                (_, _, Some(g)) => format!("{:.4} GB/s", g),
                _ => String::new(),
            };
            let _ = writeln!(s, "{:<46} {:>4} {:>11.3}  {}", format!("{} / {}", p.group, p.name), spp, p.median_ms, rate);
        }
        let _ = writeln!(s, "{:<46} {:>4} {:>11.3}  (all passes and barriers)", "iteration", "", self.iteration_ms);
        let r = &self.rays;
        let _ = writeln!(
            s,
            "rays: {} counted in trace_primal_count ({} spp, {:.2} per sample) / trace_primal time = {:.2} Mrays/s",
            r.rays,
            r.spp,
            r.rays_per_sample,
            r.rays_per_s * 1e-6
        );
        let g = &self.specialisation_gain;
        let _ = writeln!(
            s,
            "specialisation gain: trace_primal {} spp specialised {:.3} ms, generic {:.3} ms: {:.3}x (image difference generic {:.1e}, counted {:.1e})",
            g.spp, g.specialised_ms, g.generic_ms, g.gain, g.generic_image_rel_diff, g.count_image_rel_diff
        );
        let _ = writeln!(
            s,
            "texel reads: trace_primal {} spp by image loads {:.3} ms, by texel fetches (trace_primal_sampled) {:.3} ms: {:.3}x (image difference {:.1e})",
            g.spp, g.specialised_ms, g.sampled_ms, g.sampled_gain, g.sampled_image_rel_diff
        );
        let q = &self.ratios;
        let _ = writeln!(
            s,
            "at {} spp: finite_difference (fused) / gradient = {:.3} ms / {:.3} ms = {:.2} (goal <= 1.3); two-trace: {:.2}; trace_adjoint / trace_primal = {:.3} ms / {:.3} ms = {:.2} (goal <= 2)",
            q.spp, q.finite_difference_ms, q.proportional_ms, q.fd_over_proportional, q.fd_two_trace_over_proportional, q.adjoint_ms, q.primal_ms, q.adjoint_over_primal
        );
        let b = &self.bvh;
        let _ = writeln!(
            s,
            "BVH (trace_test, {} layout, {} camera rays, {} triangles): closest hit {:.3} ms = {:.2} Mrays/s, any hit {:.3} ms = {:.2} Mrays/s",
            b.layout, b.rays, b.triangles, b.closest_ms, b.closest_mrays_per_s, b.any_ms, b.any_mrays_per_s
        );
        let _ = writeln!(
            s,
            "memory: {:.2} MiB in {} allocations (scene, gradient and finite-difference passes, both optimisers)",
            self.memory_bytes as f64 / (1 << 20) as f64,
            self.memory_allocations
        );
        let t = &self.transfer;
        let _ = writeln!(
            s,
            "host<->device per iteration: {:.0} B up, {:.0} B down ({}; {:.0} B staged in {:.1} copy submissions); buffers created while iterating: {}",
            t.upload_bytes,
            t.readback_bytes,
            if t.device_memory_mappable { "device memory mapped" } else { "device memory unmappable: staging" },
            t.staged_bytes,
            t.staged_submissions,
            t.buffers_created
        );
        s.push_str(&self.optimisers.table());
        s
    }
}
