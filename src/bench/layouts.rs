//! `vkinverse bench SCENE.toml --bvh-layouts`: the BVH layouts (binary and wide) against
//! each other on one scene, in one process, alternating.
//!
//! Each layout gets its own scene upload, trace_test (closest hit only, any hit only, on
//! the camera rays of `bench`'s BVH measurement) and primal pass (every sensor at the
//! scene's primal_spp), recorded once with a profiler scope per kernel. A round submits
//! every layout's recording once, in alternating order from round to round (binary first
//! in even rounds), so that a slow drift of the machine's load affects both alike. Reported
//! are per-layout medians over the rounds and the median over rounds of each round's
//! wide/binary time ratio.

use super::median;
use super::scene::camera_rays;
use crate::bvh::{BvhLayout, TraceResult};
use crate::error::Result;
use crate::gpu::{Access, BindGroup, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Profiler, SpecValue};
use crate::push::CountPush;
use crate::settings::{gpu_seed, RunSettings};
use crate::render::gradient::SEED_PRIMAL;
use crate::render::{record_samples, GpuScene, TracePush};
use crate::scene::Scene;
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
    pub layouts: Vec<LayoutTimes>,
    /// Median over rounds of wide time / binary time: below 1, the wide layout is faster.
    pub closest_wide_over_binary: f64,
    pub any_wide_over_binary: f64,
    pub primal_wide_over_binary: f64,
    /// Rays on which the layouts' any-hit results disagree, of `rays`.
    pub any_hit_disagreements: u64,
    /// Σ|wide − binary| / Σ|binary| over the pixels of the first round's primal images.
    pub primal_image_rel_diff: f64,
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
            ComputePipeline::new(
                ctx,
                &gs.kernel("trace_test"),
                &[("TRACE_CLOSEST", SpecValue::Bool(closest)), ("TRACE_ANY", SpecValue::Bool(!closest))],
            )
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
        let (mut closest_prof, mut any_prof, mut primal_prof) =
            (Profiler::new(ctx, 1)?, Profiler::new(ctx, 1)?, Profiler::new(ctx, sensors)?);
        let mut cmd = CommandBuffer::new(ctx, "bvh layout bench")?;
        cmd.record(|rec| {
            closest_prof.reset(rec);
            any_prof.reset(rec);
            primal_prof.reset(rec);
            rec.transition(&[(&results, Access::ComputeWrite)])?;
            closest_prof.scope(rec, "trace_test", |rec, _| rec.dispatch_linear(&closest, &closest_group, &push, n))?;
            // Both kernels write the results.
            rec.barrier(&results, Access::ComputeWrite, Access::ComputeWrite)?;
            any_prof.scope(rec, "trace_test", |rec, _| rec.dispatch_linear(&any, &any_group, &push, n))?;
            for s in 0..sensors {
                // Each submission accumulates every sensor's render onto the image.
                rec.transition(&[(&image, Access::ComputeReadWrite)])?;
                let push = TracePush {
                    width: gs.width,
                    height: gs.height,
                    sensor: s,
                    spp: st.primal_spp,
                    first_sample: 0,
                    seed: gpu_seed(st.seed).wrapping_add(SEED_PRIMAL),
                    weight: 1.0 / st.primal_spp as f32,
                };
                primal_prof.scope(rec, "trace_primal", |rec, _| {
                    record_samples(rec, &gs, &primal, &primal_group, push, push.spp, &[&image])
                })?;
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

/// Runs the comparison over `rounds` rounds.
pub fn layout_bench(ctx: &Arc<Context>, scene: &Scene, rounds: u32) -> Result<LayoutBench> {
    let rounds = rounds.max(1);
    let st = RunSettings::of_scene(scene);
    let mut setups = BvhLayout::ALL.map(|layout| Setup::new(ctx, scene, &st, layout)).into_iter().collect::<Result<Vec<_>>>()?;
    // Warm-up (lavapipe compiles a pipeline on its first dispatch); its results (the
    // any-hit trace's, written last, and the primal image) are compared.
    for s in &mut setups {
        s.gs.set_frame(0)?;
        s.run()?;
    }
    let images: Vec<Vec<[f32; 3]>> = setups.iter().map(|s| s.image.read()).collect::<std::result::Result<_, _>>()?;
    let primal_image_rel_diff = super::scene::rel_diff(&images[0], &images[1]);
    let hits: Vec<Vec<TraceResult>> = setups.iter().map(|s| s.results.read()).collect::<std::result::Result<_, _>>()?;
    let any_hit_disagreements = hits[0].iter().zip(&hits[1]).filter(|(a, b)| a.any_hit != b.any_hit).count() as u64;

    let mut times: Vec<[Vec<f64>; 3]> = setups.iter().map(|_| Default::default()).collect();
    let mut ratios: [Vec<f64>; 3] = Default::default();
    for round in 0..rounds {
        let mut this = [[0.0; 3]; 2];
        let order: [usize; 2] = if round % 2 == 0 { [0, 1] } else { [1, 0] };
        for i in order {
            this[i] = setups[i].run()?;
        }
        for k in 0..3 {
            for i in 0..2 {
                times[i][k].push(this[i][k]);
            }
            ratios[k].push(this[1][k] / this[0][k].max(1e-12));
        }
    }
    let n = setups[0].rays;
    let mrays = |ms: f64| n as f64 / (ms * 1e-3).max(1e-12) * 1e-6;
    let layouts = setups
        .iter()
        .zip(times.iter_mut())
        .map(|(s, t)| {
            let [c, a, p] = t;
            let (closest_ms, any_ms, primal_ms) = (median(c), median(a), median(p));
            LayoutTimes {
                layout: s.layout.name().to_string(),
                nodes_bytes: s.gs.bvh().nodes.len(),
                closest_ms,
                closest_mrays_per_s: mrays(closest_ms),
                any_ms,
                any_mrays_per_s: mrays(any_ms),
                primal_ms,
            }
        })
        .collect();
    let [rc, ra, rp] = &mut ratios;
    Ok(LayoutBench {
        scene: scene.path.display().to_string(),
        device: ctx.info().name.clone(),
        rounds,
        lp_num_threads: std::env::var("LP_NUM_THREADS").ok(),
        rays: n,
        triangles: setups[0].gs.triangles,
        primal_spp: st.primal_spp,
        layouts,
        closest_wide_over_binary: median(rc),
        any_wide_over_binary: median(ra),
        primal_wide_over_binary: median(rp),
        any_hit_disagreements,
        primal_image_rel_diff,
    })
}

impl LayoutBench {
    /// The results as a table.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{} on {} (LP_NUM_THREADS {}), {} rounds alternating, medians; trace_test: {} camera rays, {} triangles; trace_primal: every sensor at {} spp",
            self.scene,
            self.device,
            self.lp_num_threads.as_deref().unwrap_or("unset"),
            self.rounds,
            self.rays,
            self.triangles,
            self.primal_spp
        );
        let _ = writeln!(s, "{:<8} {:>10} {:>12} {:>10} {:>10} {:>10} {:>12}", "layout", "nodes KiB", "closest ms", "Mrays/s", "any ms", "Mrays/s", "primal ms");
        for l in &self.layouts {
            let _ = writeln!(
                s,
                "{:<8} {:>10.1} {:>12.3} {:>10.2} {:>10.3} {:>10.2} {:>12.3}",
                l.layout,
                l.nodes_bytes as f64 / 1024.0,
                l.closest_ms,
                l.closest_mrays_per_s,
                l.any_ms,
                l.any_mrays_per_s,
                l.primal_ms
            );
        }
        let _ = writeln!(
            s,
            "wide/binary time, median of per-round ratios: closest {:.3}, any {:.3}, primal {:.3}",
            self.closest_wide_over_binary, self.any_wide_over_binary, self.primal_wide_over_binary
        );
        let _ = writeln!(
            s,
            "agreement: any hit differs on {} of {} rays; primal images differ by {:.1e} (relative L1)",
            self.any_hit_disagreements, self.rays, self.primal_image_rel_diff
        );
        s
    }
}
