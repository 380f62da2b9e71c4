//! `vkinverse bench SCENE.toml --bvh-layouts`: the BVH layouts (binary, wide, cw8)
//! against each other on one scene, in one process, alternating.
//!
//! Each layout gets its own scene upload, trace_test (closest hit only, any hit only, on
//! the camera rays of `bench`'s BVH measurement) and primal pass (every sensor at the
//! scene's primal_spp), recorded once with a profiler scope per kernel. A round submits
//! every layout's recording once, in an order rotated from round to round, so that a slow
//! drift of the machine's load affects all alike. Reported are per-layout medians over the
//! rounds and the median over rounds of each round's time ratio to the binary layout. The
//! primal pass's rays are counted once per layout, untimed, by trace_primal_count.

use super::median;
use super::scene::camera_rays;
use crate::bvh::{BvhLayout, TraceResult};
use crate::error::Result;
use crate::gpu::{BindGroup, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Profiler, SpecValue};
use crate::kernels::CountPush;
use crate::render::gradient::SEED_PRIMAL;
use crate::render::{record_samples, GpuScene, TracePush};
use crate::scene::Scene;
use crate::settings::{gpu_seed, RunSettings};
use serde::Serialize;
use std::fmt::Write as _;
use std::sync::Arc;

/// One layout's medians.
#[derive(Clone, Debug, Serialize)]
pub struct LayoutTimes {
    pub layout: String,
    pub nodes_bytes: u64,
    pub closest_ms: f64,
    pub closest_mrays_per_s: f64,
    pub any_ms: f64,
    pub any_mrays_per_s: f64,
    /// The primal pass over every sensor at primal_spp.
    pub primal_ms: f64,
    /// Rays the primal pass casts (counted by trace_primal_count) over `primal_ms`.
    pub primal_mrays_per_s: f64,
    /// Medians over rounds of this layout's time / the binary layout's time.
    pub closest_over_binary: f64,
    pub any_over_binary: f64,
    pub primal_over_binary: f64,
    /// Rays on which this layout's any-hit result differs from the binary layout's.
    pub any_hit_disagreements: u64,
    /// Σ|this − binary| / Σ|binary| over the pixels of the first round's primal images.
    pub primal_image_rel_diff: f64,
}

/// The comparison's results.
#[derive(Clone, Debug, Serialize)]
pub struct LayoutBench {
    pub scene: String,
    pub device: String,
    pub rounds: u32,
    pub lp_num_threads: Option<String>,
    pub rays: u64,
    pub triangles: usize,
    pub primal_spp: u32,
    pub width: u32,
    pub height: u32,
    /// Per layout, the first one binary.
    pub layouts: Vec<LayoutTimes>,
}

/// One layout's scene, kernels and recording. Everything the recording uses lives here.
struct Setup {
    layout: BvhLayout,
    gs: GpuScene,
    rays: u64,
    _buffers: [Buffer; 2],
    results: Buffer,
    image: Buffer,
    _pipelines: [ComputePipeline; 3],
    _groups: [BindGroup; 3],
    closest_prof: Profiler,
    any_prof: Profiler,
    primal_prof: Profiler,
    cmd: CommandBuffer,
}

impl Setup {
    fn new(ctx: &Arc<Context>, scene: &Scene, st: &RunSettings, layout: BvhLayout) -> Result<Self> {
        let gs = GpuScene::with_bvh_layout(ctx, scene, layout)?;
        let rays = camera_rays(scene, &gs);
        let n = rays.len() as u64;
        let ray_buf = Buffer::from_slice(ctx, "bvh bench rays", &rays, MemoryKind::Device)?;
        let results = Buffer::zeroed::<TraceResult>(ctx, "bvh bench results", rays.len(), MemoryKind::Device)?;
        let trace = |closest: bool| {
            ComputePipeline::new(ctx, &gs.kernel("trace_test"), &[("TRACE_CLOSEST", SpecValue::Bool(closest)), ("TRACE_ANY", SpecValue::Bool(!closest))])
        };
        let (closest, any) = (trace(true)?, trace(false)?);
        let primal = ComputePipeline::new(ctx, &gs.kernel("trace_primal"), &gs.spec())?;
        let image = Buffer::zeroed::<[f32; 3]>(ctx, "layout bench image", gs.pixels(), MemoryKind::Device)?;
        let bind_trace = |p: &ComputePipeline| {
            let mut b = vec![("Rays", &ray_buf), ("Results", &results)];
            b.extend(gs.bvh().bindings());
            p.bind(&b)
        };
        let (closest_group, any_group) = (bind_trace(&closest)?, bind_trace(&any)?);
        let mut b = gs.bindings();
        b.push(("Accum", &image));
        let primal_group = primal.bind(&b)?;
        let push = CountPush::new(n);
        let sensors = gs.sensors as u32;
        let (mut closest_prof, mut any_prof, mut primal_prof) = (Profiler::new(ctx, 1)?, Profiler::new(ctx, 1)?, Profiler::new(ctx, sensors)?);
        let mut cmd = CommandBuffer::new(ctx, "bvh layout bench")?;
        cmd.record(|rec| {
            closest_prof.reset(rec);
            any_prof.reset(rec);
            primal_prof.reset(rec);
            closest_prof.scope(rec, "trace_test", |rec, _| rec.dispatch_linear(&closest, &closest_group, &push, n))?;
            // Both kernels write the results (the recorder orders them).
            any_prof.scope(rec, "trace_test", |rec, _| rec.dispatch_linear(&any, &any_group, &push, n))?;
            for s in 0..sensors {
                // Each submission accumulates every sensor's render onto the image.
                let push = primal_push(&gs, st, s);
                primal_prof.scope(rec, "trace_primal", |rec, _| record_samples(rec, &gs, &primal, &primal_group, push, push.spp))?;
            }
            Ok(())
        })?;
        Ok(Setup {
            layout,
            gs,
            rays: n,
            _buffers: [ray_buf, results.clone()],
            results,
            image,
            _pipelines: [closest, any, primal],
            _groups: [closest_group, any_group, primal_group],
            closest_prof,
            any_prof,
            primal_prof,
            cmd,
        })
    }

    /// Submits the recording; (closest, any, primal) ms.
    fn run(&mut self) -> Result<[f64; 3]> {
        self.cmd.submit_and_wait()?;
        Ok([
            Profiler::total_ms(&self.closest_prof.results()?, "trace_test"),
            Profiler::total_ms(&self.any_prof.results()?, "trace_test"),
            Profiler::total_ms(&self.primal_prof.results()?, "trace_primal"),
        ])
    }
}

/// The push constants of sensor `s`'s primal pass: primal_spp samples, the primal seed.
fn primal_push(gs: &GpuScene, st: &RunSettings, s: u32) -> TracePush {
    TracePush {
        width: gs.width,
        height: gs.height,
        sensor: s,
        spp: st.primal_spp,
        first_sample: 0,
        seed: gpu_seed(st.seed).wrapping_add(SEED_PRIMAL),
        weight: 1.0 / st.primal_spp as f32,
        stride: 1,
        phase: 0,
    }
}

/// Rays one primal pass of `gs` casts (every sensor at `st.primal_spp`), counted by
/// trace_primal_count.
fn count_primal_rays(ctx: &Arc<Context>, gs: &GpuScene, st: &RunSettings) -> Result<u64> {
    let counting = ComputePipeline::new(ctx, &gs.kernel("trace_primal_count"), &gs.spec())?;
    let image = Buffer::zeroed::<[f32; 3]>(ctx, "layout bench counted image", gs.pixels(), MemoryKind::Device)?;
    let counters =
        Buffer::zeroed::<u32>(ctx, "layout bench ray count", (gs.pixels() as u64).div_ceil(counting.local_size()[0] as u64) as usize, MemoryKind::Device)?;
    let mut b = gs.bindings();
    b.push(("Accum", &image));
    b.push(("RayCount", &counters));
    let group = counting.bind(&b)?;
    let mut cmd = CommandBuffer::new(ctx, "layout bench ray count")?;
    cmd.record(|rec| {
        for s in 0..gs.sensors as u32 {
            // Each sensor's render and count accumulate onto the previous one's.
            let push = primal_push(gs, st, s);
            record_samples(rec, gs, &counting, &group, push, push.spp)?;
        }
        Ok(())
    })?;
    cmd.submit_and_wait()?;
    Ok(counters.read::<u32>()?.iter().map(|&c| u64::from(c)).sum())
}

/// Runs the comparison over `rounds` rounds.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::scene::{Film, LoadOptions};
/// let small = LoadOptions { film: Some(Film { width: 16, height: 16 }), max_depth: Some(2) };
/// let scene = vkinverse::Scene::load_with("scenes/cornell/scene.toml", &small)?;
/// let device = vkinverse::Device::new(&vkinverse::Config::from_env().0)?;
/// let bench = vkinverse::bench::layout_bench(&device, &scene, 1)?;
/// println!("{}", bench.table());
/// # Ok(())
/// # }
/// ```
pub fn layout_bench(device: &crate::device::Device, scene: &Scene, rounds: u32) -> Result<LayoutBench> {
    let ctx = device.ctx();
    let rounds = rounds.max(1);
    let st = RunSettings::of_scene(scene);
    let mut setups = BvhLayout::ALL.map(|layout| Setup::new(ctx, scene, &st, layout)).into_iter().collect::<Result<Vec<_>>>()?;
    let n_layouts = setups.len();
    // Warm-up (lavapipe compiles a pipeline on its first dispatch); its results (the
    // any-hit trace's, written last, and the primal image) are compared.
    for s in &mut setups {
        s.gs.set_frame(0)?;
        s.run()?;
    }
    let images: Vec<Vec<[f32; 3]>> = setups.iter().map(|s| s.image.read()).collect::<std::result::Result<_, _>>()?;
    let hits: Vec<Vec<TraceResult>> = setups.iter().map(|s| s.results.read()).collect::<std::result::Result<_, _>>()?;
    let primal_rays: Vec<u64> = setups.iter().map(|s| count_primal_rays(ctx, &s.gs, &st)).collect::<Result<_>>()?;

    // times[layout][kind], ratios[layout][kind] to the binary layout (index 0).
    let mut times: Vec<[Vec<f64>; 3]> = setups.iter().map(|_| Default::default()).collect();
    let mut ratios: Vec<[Vec<f64>; 3]> = setups.iter().map(|_| Default::default()).collect();
    for round in 0..rounds as usize {
        let mut this = vec![[0.0; 3]; n_layouts];
        for k in 0..n_layouts {
            let i = (round + k) % n_layouts;
            this[i] = setups[i].run()?;
        }
        for i in 0..n_layouts {
            for k in 0..3 {
                times[i][k].push(this[i][k]);
                ratios[i][k].push(this[i][k] / this[0][k].max(1e-12));
            }
        }
    }
    let n = setups[0].rays;
    let mrays = |rays: u64, ms: f64| rays as f64 / (ms * 1e-3).max(1e-12) * 1e-6;
    let layouts = setups
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let [c, a, p] = &mut times[i];
            let [rc, ra, rp] = &mut ratios[i];
            let (closest_ms, any_ms, primal_ms) = (median(c), median(a), median(p));
            LayoutTimes {
                layout: s.layout.name().to_string(),
                nodes_bytes: s.gs.bvh().nodes.len(),
                closest_ms,
                closest_mrays_per_s: mrays(n, closest_ms),
                any_ms,
                any_mrays_per_s: mrays(n, any_ms),
                primal_ms,
                primal_mrays_per_s: mrays(primal_rays[i], primal_ms),
                closest_over_binary: median(rc),
                any_over_binary: median(ra),
                primal_over_binary: median(rp),
                any_hit_disagreements: hits[0].iter().zip(&hits[i]).filter(|(a, b)| a.any_hit != b.any_hit).count() as u64,
                primal_image_rel_diff: super::scene::rel_diff(&images[0], &images[i]),
            }
        })
        .collect();
    Ok(LayoutBench {
        scene: scene.path.display().to_string(),
        device: ctx.info().name.clone(),
        rounds,
        lp_num_threads: std::env::var("LP_NUM_THREADS").ok(),
        rays: n,
        triangles: setups[0].gs.triangles,
        primal_spp: st.primal_spp,
        width: setups[0].gs.width,
        height: setups[0].gs.height,
        layouts,
    })
}

impl LayoutBench {
    /// The results as a table.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{} ({}x{}) on {} (LP_NUM_THREADS {}), {} rounds rotating, medians; trace_test: {} camera rays, {} triangles; trace_primal: every sensor at {} spp",
            self.scene,
            self.width,
            self.height,
            self.device,
            self.lp_num_threads.as_deref().unwrap_or("unset"),
            self.rounds,
            self.rays,
            self.triangles,
            self.primal_spp
        );
        let _ = writeln!(
            s,
            "{:<8} {:>9} {:>10} {:>8} {:>9} {:>8} {:>10} {:>8} {:>21} {:>9} {:>9}",
            "layout", "nodes KiB", "closest ms", "Mrays/s", "any ms", "Mrays/s", "primal ms", "Mrays/s", "/binary clo/any/pri", "any diff", "image diff"
        );
        for l in &self.layouts {
            let _ = writeln!(
                s,
                "{:<8} {:>9.1} {:>10.3} {:>8.2} {:>9.3} {:>8.2} {:>10.3} {:>8.2} {:>7.3}/{:>6.3}/{:>6.3} {:>9} {:>9.1e}",
                l.layout,
                l.nodes_bytes as f64 / 1024.0,
                l.closest_ms,
                l.closest_mrays_per_s,
                l.any_ms,
                l.any_mrays_per_s,
                l.primal_ms,
                l.primal_mrays_per_s,
                l.closest_over_binary,
                l.any_over_binary,
                l.primal_over_binary,
                l.any_hit_disagreements,
                l.primal_image_rel_diff
            );
        }
        let _ = writeln!(
            s,
            "/binary: median over rounds of the layout's time / the binary layout's; any diff: rays whose any-hit result differs from binary's; image diff: relative L1 of the primal image to binary's"
        );
        s
    }
}
