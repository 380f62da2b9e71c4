//! The forward renderer: the scene uploaded once ([`GpuScene`], feature by feature:
//! [`features`]), the path-tracing kernels specialised for it, and renders split into
//! short submissions.
//!
//! Specialisation: the integrator is built with the scene's max depth and Russian-roulette
//! depth, and each feature's constants ([`features::Feature::spec`]), so a scene without
//! emitters compiles light sampling out, one without an environment skips its lookup, and
//! a depth ≤ 2 scene has a loop the compiler can bound.

pub mod envmap;
pub mod features;
pub mod filter;
pub mod gradient;
pub mod params;
pub mod targets;

use crate::bvh::{BvhBuffers, BvhLayout};
use crate::gpu::{self, BindGroup, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Recorder, SpecValue, TEXEL_BYTES};
use crate::image::Image;
pub use crate::kernels::TracePush;
use crate::scene::Scene;
use crate::shared::Globals;
pub use features::geometry::tangent_frame;
use features::{Features, Upload};
pub use features::values::sampler_flags;
pub use params::{ParamLayout, ParamSlot};
use std::sync::Arc;

/// The scene's buffers on the device, and θ.
pub struct GpuScene {
    pub ctx: Arc<Context>,
    pub layout: ParamLayout,
    pub width: u32,
    pub height: u32,
    pub sensors: usize,
    pub max_depth: u32,
    pub rr_depth: u32,
    /// Whether emitters seen directly are hidden (the kernels' HIDE_EMITTERS).
    pub hide_emitters: bool,
    /// The scene's features on the device.
    pub features: Features,
    /// Build the kernels with every feature's code in, whatever the scene has: every
    /// boolean `HAS_*` constant true (tests compare this build with the specialised one).
    pub every_feature: bool,
    /// Whether every ray cast of a path fits the adjoint kernels' replay cache
    /// (`max_depth` ≤ [`crate::constants::CACHED_BOUNCES`]): the `CACHE_ALL` constant of
    /// the adjoint kernels, which then trace each path once.
    pub replay_cached: bool,
    /// Whether the adjoint kernels add each gradient contribution to their per-thread sums
    /// in an unrolled loop (`LOCAL_GRADS_UNROLLED`): θ has at most
    /// [`crate::constants::LOCAL_GRADS_UNROLL_MAX`] elements.
    pub local_grads_unrolled: bool,
    pub triangles: usize,
    globals: Globals,
    globals_buffer: Buffer,
    /// The parameters (θ), `layout.len` floats padded to whole texels (at least one, unused,
    /// when empty), followed from [`Self::const_base`] on by the material data: every
    /// constant value the kernels look up. The optimisers move θ's elements alone.
    pub theta: Buffer,
    /// Where the material data start in [`Self::theta`] (the kernels' `CONST_BASE`).
    pub const_base: u32,
    /// The iteration counter the kernels mix into their seeds (host-written).
    pub frame: Buffer,
}

/// A device buffer holding `v` followed by zeros up to a whole number of 16-byte texels
/// (at least one, so that an empty array still has a buffer to bind), for kernels that read
/// it as a uniform texel buffer.
pub fn texel_buffer<T: bytemuck::Pod>(ctx: &Arc<Context>, name: &str, v: &[T]) -> gpu::Result<Buffer> {
    let bytes: &[u8] = bytemuck::cast_slice(v);
    let mut padded = bytes.to_vec();
    let texel = TEXEL_BYTES as usize;
    padded.resize(bytes.len().div_ceil(texel).max(1) * texel, 0);
    Buffer::from_slice(ctx, name, &padded, MemoryKind::Device)
}

impl GpuScene {
    /// Builds the BVH and uploads geometry, materials, lights, sensors and θ (set to the
    /// parameters' initial values), with the default BVH layout.
    pub fn new(ctx: &Arc<Context>, scene: &Scene) -> gpu::Result<Self> {
        Self::with_bvh_layout(ctx, scene, BvhLayout::default())
    }

    /// [`Self::new`] with the BVH layout and traversal stack that `config` asks for.
    pub fn configured(ctx: &Arc<Context>, scene: &Scene, config: &crate::Config) -> gpu::Result<Self> {
        let mut gs = Self::with_bvh_layout(ctx, scene, config.bvh_layout)?;
        gs.features.geometry.stack_array = config.bvh_stack_array;
        Ok(gs)
    }

    /// [`Self::new`] with the BVH in `bvh_layout`; the scene's kernels are then the builds
    /// for that layout ([`Self::kernel`]).
    pub fn with_bvh_layout(ctx: &Arc<Context>, scene: &Scene, bvh_layout: BvhLayout) -> gpu::Result<Self> {
        let layout = ParamLayout::new(scene);
        let mut data = features::values::MaterialData::default();
        if scene.media.iter().any(|m| m.scatters()) && bvh_layout != BvhLayout::Cw8 {
            return Err(gpu::GpuError::Unsupported(format!(
                "a scattering medium renders with the default BVH layout ({}), not {}",
                BvhLayout::Cw8.name(),
                bvh_layout.name()
            )));
        }
        let features = Features::build(&mut Upload { ctx, scene, layout: &layout, data: &mut data }, bvh_layout)?;
        let env = &features.environment;
        let globals = Globals {
            environment: env.value,
            environment_scale: scene.environment.scale,
            environment_sample_prob: Self::environment_sample_prob(env.distribution.is_some(), features.emitters.count()),
            num_lights: features.lights.count(),
            filter_table: features.sensors.filter_table,
        };
        // θ is read as texels by the integrator kernels and as floats by the optimisers;
        // its length is a whole number of texels (the padding is never read or moved), and
        // the material data follow it in the same buffer.
        let const_base = gpu::texel_padded(layout.len) as u32;
        let mut contents = layout.initial();
        contents.resize(const_base as usize, 0.0);
        let (textures, (w, h), texture_floats) = (data.textures, data.largest_texture, data.texture_floats);
        contents.extend(data.data);
        contents.resize(contents.len().next_multiple_of(4).max(4), 0.0);
        // The kernels read all of it through a texel-buffer view, which reaches further than
        // a storage-buffer binding on most devices (lavapipe: 2 GiB against 128 MiB); the
        // optimisers bind θ's part alone as a storage buffer. Textures are most of a large
        // scene's data: a buffer beyond the texel range says how much of it they are.
        let bytes = (contents.len() * 4) as u64;
        let max = ctx.info().max_texel_buffer_bytes();
        if bytes > max && textures > 0 {
            let mib = (texture_floats * 4) as f64 / (1024.0 * 1024.0);
            let name = format!("theta: the parameters and material data, {mib:.1} MiB of it in {textures} texture(s), the largest {w} x {h}; smaller textures fit");
            return Err(gpu::GpuError::BufferTooLarge { name, size: bytes, max, limit: "texel-buffer range" });
        }
        let params = u64::from(const_base) * 4;
        let max_storage = ctx.info().max_storage_buffer_range;
        if params > max_storage {
            let name = format!("theta: the {} optimised parameters (the optimiser passes bind them as one storage buffer)", layout.len);
            return Err(gpu::GpuError::BufferTooLarge { name, size: params, max: max_storage, limit: "storage-buffer range" });
        }
        // (Whole texels already: no padded copy of what may be gigabytes.)
        let theta = Buffer::from_slice(ctx, "theta", &contents, MemoryKind::Device)?;
        drop(contents);
        theta.set_storage_extent(params);
        Ok(Self {
            ctx: ctx.clone(),
            width: scene.film.width,
            height: scene.film.height,
            sensors: scene.sensors.len(),
            max_depth: scene.integrator.max_depth,
            rr_depth: scene.integrator.rr_depth,
            hide_emitters: scene.integrator.hide_emitters,
            every_feature: false,
            replay_cached: scene.integrator.max_depth <= crate::constants::CACHED_BOUNCES,
            local_grads_unrolled: (1..=crate::constants::LOCAL_GRADS_UNROLL_MAX as usize).contains(&layout.len),
            triangles: features.geometry.triangles,
            globals_buffer: texel_buffer(ctx, "globals", &[globals])?,
            globals,
            features,
            layout,
            theta,
            const_base,
            frame: Buffer::from_slice(ctx, "frame", &[0u32], MemoryKind::Upload)?,
        })
    }

    /// Probability that next-event estimation samples the environment map: 1 without
    /// emissive triangles, ½ with (0 when the environment is not light-sampled).
    fn environment_sample_prob(sampled: bool, emitters: u32) -> f32 {
        match (sampled, emitters) {
            (false, _) => 0.0,
            (true, 0) => 1.0,
            (true, _) => 0.5,
        }
    }

    /// Whether next-event estimation samples the environment map (a scene with a lat-long
    /// map does by default). Turned off, the map is reached by BSDF sampling only, the
    /// baseline that tests and benchmarks compare against; the image's expectation is
    /// the same. Has no effect on a scene whose environment is not a map.
    pub fn set_environment_sampling(&mut self, enabled: bool) -> gpu::Result<()> {
        let sampled = enabled && self.features.environment.distribution.is_some();
        self.globals.environment_sample_prob = Self::environment_sample_prob(sampled, self.features.emitters.count());
        self.globals_buffer.write(&[self.globals])
    }

    /// Whether next-event estimation currently samples the environment map.
    pub fn environment_sampling(&self) -> bool {
        self.globals.environment_sample_prob > 0.0
    }

    /// (GLSL block name, buffer) of every scene buffer and θ, for a kernel's bind list.
    pub fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        self.bindings_with(&self.theta)
    }

    /// The scene's bindings with `theta` as the parameters (e.g. the previous iterate).
    pub fn bindings_with<'a>(&'a self, theta: &'a Buffer) -> Vec<(&'static str, &'a Buffer)> {
        let mut v: Vec<(&'static str, &Buffer)> = self.features.all().iter().flat_map(|f| f.bindings()).collect();
        v.push(("SceneGlobals", &self.globals_buffer));
        v.push(("Theta", theta));
        v.push(("Frame", &self.frame));
        v
    }

    /// Writes θ: `values` (θ's elements), padded to whole texels, at the start of its
    /// buffer. The material data after them stay as uploaded.
    pub fn set_theta(&self, values: Vec<f32>) -> gpu::Result<()> {
        self.theta.write(&targets::padded(self, values))
    }

    /// Sets the iteration counter that the next submissions mix into their seeds.
    pub fn set_frame(&self, iteration: u32) -> gpu::Result<()> {
        self.frame.write(&[iteration])
    }

    /// The specialization constants of the integrator kernels for this scene: the
    /// integrator's, then each feature's ([`features`]); with [`Self::every_feature`], every
    /// boolean `HAS_*` constant true.
    pub fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        let mut spec = vec![
            ("MAX_DEPTH", SpecValue::U32(self.max_depth)),
            ("RR_DEPTH", SpecValue::U32(self.rr_depth)),
            ("HIDE_EMITTERS", SpecValue::Bool(self.hide_emitters)),
            ("HAS_TEXTURES", SpecValue::Bool(self.features.textured())),
            self.const_base_spec(),
        ];
        spec.extend(self.features.all().iter().flat_map(|f| f.spec()));
        if self.every_feature {
            for (name, value) in &mut spec {
                if name.starts_with("HAS_") && matches!(value, SpecValue::Bool(_)) {
                    *value = SpecValue::Bool(true);
                }
            }
        }
        spec
    }

    /// Whether the kernels are built with boolean specialisation constant `name` on (e.g.
    /// `HAS_TEXTURES`: the scene has a feature).
    pub fn has(&self, name: &str) -> bool {
        self.spec().iter().any(|(n, v)| *n == name && matches!(v, SpecValue::Bool(true)))
    }

    /// Emitting triangles that next-event estimation samples.
    pub fn emitters(&self) -> u32 {
        self.features.emitters.count()
    }

    /// The environment map's sampling distribution, when it is light-sampled.
    pub fn environment_distribution(&self) -> Option<&envmap::EnvDistribution> {
        self.features.environment.distribution.as_ref()
    }

    /// Where the material data start in θ's buffer: a constant every build of a kernel that
    /// reads the scene's values needs, the unspecialised ones too.
    pub fn const_base_spec(&self) -> (&'static str, SpecValue) {
        ("CONST_BASE", SpecValue::U32(self.const_base))
    }

    /// θ's values as its buffer holds them (the first `layout.len` floats).
    pub fn read_theta(&self) -> gpu::Result<Vec<f32>> {
        self.theta.read_prefix(self.layout.len)
    }

    /// The run-time values of the integrator's limits that the unspecialised variant
    /// `trace_primal_generic` reads (binding `IntegratorLimits`): the same as [`Self::spec`].
    pub fn integrator_limits(&self) -> [u32; 4] {
        let environment = self.features.environment.present;
        [self.max_depth, self.rr_depth, self.emitters(), environment as u32 | (self.hide_emitters as u32) << 1]
    }

    /// The scene's BVH on the device.
    pub fn bvh(&self) -> &BvhBuffers {
        &self.features.geometry.bvh
    }

    /// The build of a kernel that traces the scene's BVH (e.g. `trace_primal`) for the
    /// BVH's layout; for a scene whose medium scatters, of the four passes' builds with
    /// the collision code (`trace_primal_scatter_cw8`, ...: the compressed layout only,
    /// which [`Self::with_bvh_layout`] then requires).
    pub fn kernel(&self, kernel: &str) -> String {
        if self.features.media.scattering && SCATTER_KERNELS.contains(&kernel) {
            return self.bvh().layout.kernel(&format!("{kernel}_scatter"));
        }
        self.bvh().layout.kernel(kernel)
    }

    /// Pixels of one sensor image.
    pub fn pixels(&self) -> usize {
        (self.width * self.height) as usize
    }
}

/// The passes that have a build for scattering media (glsl/trace_primal.comp's
/// SCATTERING), the bench's builds of trace_primal among them.
const SCATTER_KERNELS: [&str; 7] =
    ["trace_primal", "trace_adjoint", "trace_fd_primal", "trace_fd_adjoint", "trace_primal_count", "trace_primal_generic", "trace_primal_sampled"];

/// Samples per pixel per submission: keeps each submission short on slow devices.
pub const SPP_PER_SUBMISSION: u32 = 4;

/// Samples per pixel that one trace dispatch takes at most, for paths of up to
/// `max_depth` vertices.
///
/// lavapipe's shader compiler (gallivm) caps the loop iterations of one shader invocation
/// (a SIMD batch of 8 threads) at 65535 (`LP_MAX_TGSI_LOOP_ITERATIONS`): one counter,
/// decremented by every iteration of every loop of the kernel and never reset, and once
/// it reaches zero every loop exits after its current iteration. A thread that loops over
/// too many samples therefore returns truncated paths, silently (1024 spp of the Cornell
/// box in one dispatch lose 61 % of the image: tests/suite/render.rs). A path vertex costs up to
/// a few hundred iterations on the bundled scenes (the traversal's node and triangle loops,
/// twice in the adjoint kernels), so every pass splits its samples into dispatches of at
/// most 16 / max_depth samples (at least 1, at most 4), well inside the cap.
pub fn spp_per_dispatch(max_depth: u32) -> u32 {
    (16 / max_depth.max(1)).clamp(1, 4)
}

/// Records `pipeline` (a trace kernel taking [`TracePush`]) over `spp` samples per pixel
/// starting at `push.first_sample`, in dispatches of at most
/// [`spp_per_dispatch`]`(scene.max_depth)` samples, each adding to what the previous one
/// accumulated (the recorder puts the barrier between them).
pub fn record_samples(rec: &mut Recorder, scene: &GpuScene, pipeline: &ComputePipeline, group: &BindGroup, push: TracePush, spp: u32) -> gpu::Result<()> {
    // A tracked medium's majorant, from the θ (and previous θ) these samples read.
    let bound = |name: &str| pipeline.reflection().binding(name).and_then(|b| group.bound(b.binding));
    if let Some(theta) = bound("Theta") {
        scene.features.media.record_majorant(rec, theta, bound("ThetaPrev").unwrap_or(theta))?;
    }
    let step = spp_per_dispatch(scene.max_depth);
    let mut done = 0;
    while done < spp {
        let chunk = step.min(spp - done);
        let p = TracePush { spp: chunk, first_sample: push.first_sample + done, ..push };
        rec.dispatch_linear(pipeline, group, &p, p.invocations())?;
        done += chunk;
    }
    Ok(())
}

/// Renders images of a [`GpuScene`] with the primal kernel.
pub struct PrimalRenderer {
    pub scene: GpuScene,
    primal: ComputePipeline,
}

impl PrimalRenderer {
    pub fn new(scene: GpuScene) -> gpu::Result<Self> {
        let primal = ComputePipeline::new(&scene.ctx, &scene.kernel("trace_primal"), &scene.spec())?;
        Ok(Self { scene, primal })
    }

    /// The kernel that renders (trace_primal's build for the scene's BVH layout).
    pub fn kernel(&self) -> &str {
        self.primal.name()
    }

    /// Renders sensor `sensor` with `spp` samples per pixel, in submissions of at most
    /// [`SPP_PER_SUBMISSION`] samples; `progress(done, total)` is called after each.
    pub fn render(&self, sensor: u32, spp: u32, seed: u32, progress: impl FnMut(u32, u32)) -> gpu::Result<Image> {
        Ok(self.render_until(sensor, spp, seed, progress, || false)?.0)
    }

    /// [`Self::render`], asking `stop()` after each submission whether to end early: the
    /// image is then the mean of the samples rendered so far (the first submission's at
    /// least), equal up to rounding to a render of that many samples with this seed. Returns the image
    /// and its samples per pixel.
    pub fn render_until(&self, sensor: u32, spp: u32, seed: u32, mut progress: impl FnMut(u32, u32), stop: impl Fn() -> bool) -> gpu::Result<(Image, u32)> {
        let ctx = &self.scene.ctx;
        let n = self.scene.pixels();
        let accum = Buffer::zeroed::<[f32; 3]>(ctx, "accum", n, MemoryKind::Device)?;
        let mut binds = self.scene.bindings();
        binds.push(("Accum", &accum));
        let group = self.primal.bind(&binds)?;
        let mut cmd = CommandBuffer::new(ctx, "render")?;
        let mut done = 0;
        while done < spp {
            let chunk = SPP_PER_SUBMISSION.min(spp - done);
            let push = TracePush {
                width: self.scene.width,
                height: self.scene.height,
                sensor,
                spp: chunk,
                first_sample: done,
                seed,
                weight: 1.0 / spp as f32,
                stride: 1,
                phase: 0,
            };
            cmd.record(|rec| record_samples(rec, &self.scene, &self.primal, &group, push, chunk))?;
            cmd.submit_and_wait()?;
            done += chunk;
            progress(done, spp);
            if done < spp && stop() {
                break;
            }
        }
        let mut data: Vec<[f32; 3]> = accum.read()?;
        if done < spp {
            // Each sample was weighted 1 / spp.
            let scale = spp as f32 / done as f32;
            data.iter_mut().flatten().for_each(|v| *v *= scale);
        }
        Ok((Image { width: self.scene.width, height: self.scene.height, data }, done))
    }
}

