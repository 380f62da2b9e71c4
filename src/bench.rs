//! `vkinverse bench`: GPU times from timestamp scopes, reported as medians.
//!
//! The buffer bench measures the bandwidth of the buffer kernels next to the plain copy
//! kernel's, in one run, plus the costs that bound small workloads: a minimal dispatch
//! and a submit + fence round trip. A host memcpy of the same size is the ceiling. The
//! fused optimiser passes are measured the same way ([`optimiser_bandwidth`]), on a
//! synthetic θ, for every bench. The scene bench is in `bench/scene.rs`, the medium bench
//! in `bench/media.rs`.

mod layouts;
mod media;
mod scene;

pub use layouts::{layout_bench, LayoutBench, LayoutTimes};
pub use media::{media_bench, MediaBench, MediaCase, MediaOptions, MediaPass};
pub use scene::{scene_bench, BvhThroughput, PassTime, Ratios, RayCount, SceneBench, SpecConstant, SpecialisationGain, TransferPerIteration};

use crate::gpu::{Access, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Profiler, Result, ScopeTime, SpecValue};
use crate::kernels::{Count4Push, CountPush, GatherPush};
use crate::ops::BufferOps;
use crate::optim::gpu::{GpuOptimiser, Group, OptimiserBuffers};
use crate::optim::{Optimiser, Range};
use serde::Serialize;
use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Instant;

/// Median of a list (0 for an empty one).
pub use crate::stats::median;

/// One kernel's measured bandwidth.
#[derive(Clone, Debug, Serialize)]
pub struct KernelResult {
    pub name: String,
    /// Bytes read plus written by one run.
    pub bytes: u64,
    pub median_ms: f64,
    pub gb_per_s: f64,
    /// GB/s relative to the `copy` kernel in the same run.
    pub ratio_to_copy: f64,
}

/// The buffer bench's results.
#[derive(Clone, Debug, Serialize)]
pub struct BufferBench {
    pub device: String,
    pub elements: u64,
    pub iterations: u32,
    /// `LP_NUM_THREADS` as set for lavapipe (unset: Mesa's default, one per core).
    pub lp_num_threads: Option<String>,
    pub validation: bool,
    pub kernels: Vec<KernelResult>,
    pub host_memcpy_gb_per_s: f64,
    /// GPU time of a 1-element fill dispatch.
    pub tiny_dispatch_us: f64,
    /// Host wall time of submitting an empty command buffer and waiting for its fence.
    pub submit_roundtrip_us: f64,
    /// The fused optimiser passes over `elements` parameters.
    pub optimisers: OptimiserBandwidth,
}

/// One fused optimiser pass (or the copy kernel) over a synthetic parameter buffer.
#[derive(Clone, Debug, Serialize)]
pub struct OptimiserPass {
    pub name: String,
    /// Bytes of the state arrays the pass reads plus those it writes, per parameter.
    pub bytes_per_param: u64,
    pub median_ms: f64,
    pub gb_per_s: f64,
    pub params_per_s: f64,
    /// GB/s relative to the `copy` kernel in the same submissions.
    pub ratio_to_copy: f64,
    /// GB/s relative to the `copy_vec4` kernel (float4 loads and stores) in the same
    /// submissions: the fastest plain copy, against which the optimiser passes' goal is
    /// stated (at least 0.5).
    pub ratio_to_copy_vec4: f64,
}

/// The optimiser passes (`optim_meta`, `optim_adam`), `copy` and `copy_vec4` over
/// `elements` floats.
#[derive(Clone, Debug, Serialize)]
pub struct OptimiserBandwidth {
    pub elements: u64,
    pub iterations: u32,
    pub passes: Vec<OptimiserPass>,
}

/// Bytes per parameter of each pass: the arrays of glsl/optim_meta.comp and
/// glsl/optim_adam.comp, each read or written once per element (the per-workgroup ‖Δπ‖²
/// partial sums, one float per 256 parameters, are left out).
/// The step number (from 1) at which the optimiser passes are timed: mid-run, where the
/// bias corrections' powers take several factors.
pub const BENCH_OPTIMISER_STEP: u32 = 100;

const OPTIMISER_BYTES: [(&str, u64); 4] = [
    // with the defaults (the centred variance): reads θ, grad, fd_grad, their two
    // half-sample sums and the 12 meta state arrays (src/optim/gpu.rs); writes θ_prev, θ,
    // the 12 state arrays and clears grad, fd_grad and both half sums: 17 + 18 floats.
    ("optim_meta", 4 * 35),
    // reads θ, grad, m, r; writes θ, m, r and clears grad: 4 + 4 floats.
    ("optim_adam", 4 * 8),
    ("copy", 4 * 2),
    ("copy_vec4", 4 * 2),
];

/// Times the fused meta and Adam passes (default hyperparameters, unbounded range, at step
/// [`BENCH_OPTIMISER_STEP`]) and the copy kernels (scalar and float4) over `elements`
/// parameters (rounded up to a multiple of 4, the float4 copy's unit), `iterations` times
/// each. The gradients are fixed pseudo-random values in [−1, 1], copied into the gradient
/// buffers before each pass (outside its timing: the passes clear them), so that every
/// element takes the full update with nonzero diagnostics, as in a run.
pub fn optimiser_bandwidth(ctx: &Arc<Context>, elements: u64, iterations: u32) -> Result<OptimiserBandwidth> {
    let n = elements.max(1).next_multiple_of(4) as usize;
    let iterations = iterations.max(1);
    let ops = BufferOps::new(ctx)?;
    let theta = Buffer::zeroed::<f32>(ctx, "bench theta", n, MemoryKind::Device)?;
    let values = |seed: u64| -> Vec<f32> { (0..n as u64).map(|i| crate::stats::unit_hash(i.wrapping_mul(2).wrapping_add(seed)) * 2.0 - 1.0).collect() };
    let grad_src = Buffer::from_slice(ctx, "bench grad values", &values(1), MemoryKind::Device)?;
    let fd_src = Buffer::from_slice(ctx, "bench fd grad values", &values(2), MemoryKind::Device)?;
    let grad = Buffer::zeroed::<f32>(ctx, "bench grad", n, MemoryKind::Device)?;
    let fd_grad = Buffer::zeroed::<f32>(ctx, "bench fd grad", n, MemoryKind::Device)?;
    let copy_dst = Buffer::new(ctx, "bench theta copy", n as u64 * 4, MemoryKind::Device)?;
    let frame = Buffer::from_slice(ctx, "bench frame", &[BENCH_OPTIMISER_STEP - 1], MemoryKind::Upload)?;
    let groups = [Group { offset: 0, len: n, lr: 0.02, range: Range::UNBOUNDED }];
    let buffers = OptimiserBuffers { theta: &theta, grad: &grad, fd_grad: Some(&fd_grad), frame: &frame, groups: &groups };
    let meta = GpuOptimiser::new(ctx, &Optimiser::Meta(Default::default()), &buffers)?;
    let adam = GpuOptimiser::new(ctx, &Optimiser::Adam(Default::default()), &OptimiserBuffers { fd_grad: None, ..buffers })?;
    let copy4 = ComputePipeline::new(ctx, "copy_vec4", &[])?;
    let copy4_group = copy4.bind(&[("Src", &theta), ("Dst", &copy_dst)])?;
    let n4 = (n / 4) as u64;

    let mut profiler = Profiler::new(ctx, 4)?;
    let mut cmd = CommandBuffer::new(ctx, "optimiser bench")?;
    cmd.record(|rec| {
        profiler.reset(rec);
        let bytes = n as u64 * 4;
        rec.copy(&grad_src, &grad, bytes)?;
        rec.copy(&fd_src, &fd_grad, bytes)?;
        profiler.scope(rec, "optim_meta", |rec, _| meta.record(rec, &ops))?;
        rec.copy(&grad_src, &grad, bytes)?;
        profiler.scope(rec, "optim_adam", |rec, _| adam.record(rec, &ops))?;
        // copy reads θ, which both passes wrote.
        rec.transition(&[(&theta, Access::ComputeRead), (&copy_dst, Access::ComputeWrite)])?;
        profiler.scope(rec, "copy", |rec, _| ops.copy(rec, &theta, &copy_dst))?;
        rec.barrier(&copy_dst, Access::ComputeWrite, Access::ComputeWrite)?;
        profiler.scope(rec, "copy_vec4", |rec, _| rec.dispatch_linear(&copy4, &copy4_group, &Count4Push { n4: n4 as u32 }, n4))?;
        Ok(())
    })?;
    let times = timed_scopes(&mut cmd, &profiler, iterations)?;
    let median_of = |name: &str| median_ms(&times, name);
    let gbps = |name: &str, bytes: u64| bytes as f64 * n as f64 / (median_of(name) * 1e-3).max(1e-12) / 1e9;
    let (copy_gbps, copy4_gbps) = (gbps("copy", 8), gbps("copy_vec4", 8));
    let passes = OPTIMISER_BYTES
        .iter()
        .map(|&(name, bytes)| OptimiserPass {
            name: name.into(),
            bytes_per_param: bytes,
            median_ms: median_of(name),
            gb_per_s: gbps(name, bytes),
            params_per_s: n as f64 / (median_of(name) * 1e-3).max(1e-12),
            ratio_to_copy: gbps(name, bytes) / copy_gbps,
            ratio_to_copy_vec4: gbps(name, bytes) / copy4_gbps,
        })
        .collect();
    Ok(OptimiserBandwidth { elements: n as u64, iterations, passes })
}

impl OptimiserBandwidth {
    /// A fixed-width table of the passes.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "optimiser passes on {} parameters (random gradients, step {}), median of {} runs; bytes = state arrays read + written",
            self.elements, BENCH_OPTIMISER_STEP, self.iterations
        );
        let _ = writeln!(s, "{:<16} {:>12} {:>10} {:>10} {:>12} {:>10} {:>10}", "pass", "bytes/param", "median ms", "GB/s", "Mparams/s", "vs copy", "vs vec4");
        for p in &self.passes {
            let _ = writeln!(
                s,
                "{:<16} {:>12} {:>10.3} {:>10.2} {:>12.1} {:>10.2} {:>10.2}",
                p.name,
                p.bytes_per_param,
                p.median_ms,
                p.gb_per_s,
                p.params_per_s * 1e-6,
                p.ratio_to_copy,
                p.ratio_to_copy_vec4
            );
        }
        s
    }
}

/// Submits the recorded round `cmd` once to warm up (lavapipe compiles a pipeline on its
/// first dispatch), then `iterations` times, calling `collect` after each timed round to
/// read its timestamps. One round per submission keeps each submission short: all rounds
/// in one submission run past the fence's timeout on a CPU device for large `--elements`
/// or `--iterations` (16M parameters take about 13 s a round on lavapipe), and a timed-out
/// wait reads as a hung device.
fn timed_rounds(cmd: &mut CommandBuffer, iterations: u32, mut collect: impl FnMut() -> Result<()>) -> Result<()> {
    cmd.submit_and_wait()?;
    for _ in 0..iterations {
        cmd.submit_and_wait()?;
        collect()?;
    }
    Ok(())
}

/// [`timed_rounds`] with one profiler: the scopes of every timed round.
fn timed_scopes(cmd: &mut CommandBuffer, profiler: &Profiler, iterations: u32) -> Result<Vec<ScopeTime>> {
    let mut times = Vec::new();
    timed_rounds(cmd, iterations, || {
        times.extend(profiler.results()?);
        Ok(())
    })?;
    Ok(times)
}

/// The median time of the scopes named `name`.
fn median_ms(times: &[ScopeTime], name: &str) -> f64 {
    let mut v: Vec<f64> = times.iter().filter(|t| t.name == name).map(|t| t.ms).collect();
    median(&mut v)
}

impl BufferBench {
    /// A fixed-width table of the results.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "buffer bench on {}: {} f32 elements ({:.0} MiB per buffer), median of {} runs, LP_NUM_THREADS={}",
            self.device,
            self.elements,
            self.elements as f64 * 4.0 / (1 << 20) as f64,
            self.iterations,
            self.lp_num_threads.as_deref().unwrap_or("unset")
        );
        let _ = writeln!(s, "{:<16} {:>12} {:>10} {:>10}", "kernel", "median ms", "GB/s", "vs copy");
        for k in &self.kernels {
            let _ = writeln!(s, "{:<16} {:>12.3} {:>10.2} {:>10.2}", k.name, k.median_ms, k.gb_per_s, k.ratio_to_copy);
        }
        let _ = writeln!(s, "host memcpy      {:>23.2} GB/s", self.host_memcpy_gb_per_s);
        let _ = writeln!(s, "tiny dispatch    {:>23.1} us (GPU time)", self.tiny_dispatch_us);
        let _ = writeln!(s, "submit + wait    {:>23.1} us (host time, empty command buffer)", self.submit_roundtrip_us);
        s.push_str(&self.optimisers.table());
        s
    }
}

/// Threads and dependent float4 reads per thread of the gather kernels in [`buffer_bench`].
const GATHER_THREADS: u64 = 65536;
const GATHER_ROUNDS: u32 = 64;
const GATHER_TABLE: u64 = 4096;

/// Measures fill, copy (scalar and vec4, several workgroup sizes), scale-add, the two
/// reductions over `elements` floats and incoherent float4 reads through a storage buffer
/// and a texel buffer (`gather`, `gather_texel`), `iterations` times each, one round per
/// submission.
/// Not split: one recording of every kernel, each in its scope, read back together; the
/// kernels' set-up and their scopes are the function.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// let device = vkinverse::Device::new(&vkinverse::Config::from_env().0)?;
/// let bench = vkinverse::bench::buffer_bench(&device, 1 << 14, 1)?;
/// println!("{}", bench.table());
/// # Ok(())
/// # }
/// ```
pub fn buffer_bench(device: &crate::device::Device, elements: u64, iterations: u32) -> Result<BufferBench> {
    let ctx = device.ctx();
    let n = elements - elements % 4;
    let iterations = iterations.max(1);
    let ops = BufferOps::new(ctx)?;
    let src_data: Vec<f32> = (0..n).map(|i| (i % 1024) as f32 * 0.001).collect();
    let a = Buffer::from_slice(ctx, "bench a", &src_data, MemoryKind::Device)?;
    let b = Buffer::new(ctx, "bench b", n * 4, MemoryKind::Device)?;
    let x = Buffer::from_slice(ctx, "bench x", &src_data, MemoryKind::Device)?;
    let tiny = Buffer::new(ctx, "bench tiny", 4, MemoryKind::Device)?;
    let copy4 = ComputePipeline::new(ctx, "copy_vec4", &[])?;
    let copy4_group = copy4.bind(&[("Src", &a), ("Dst", &b)])?;
    let wide_items = [4u32, 16, 64];
    let wide_pipes = wide_items.iter().map(|&k| ComputePipeline::new(ctx, "copy_wide", &[("ITEMS", SpecValue::U32(k))])).collect::<Result<Vec<_>>>()?;
    let wide_groups = wide_pipes.iter().map(|p| p.bind(&[("Src", &a), ("Dst", &b)])).collect::<Result<Vec<_>>>()?;
    let wg_sizes = [64u32, 128, 512, 1024];
    let wg_pipes = wg_sizes.iter().map(|&w| ComputePipeline::new(ctx, "copy", &[("local_size_x", SpecValue::U32(w))])).collect::<Result<Vec<_>>>()?;
    let wg_groups = wg_pipes.iter().map(|p| p.bind(&[("Src", &a), ("Dst", &b)])).collect::<Result<Vec<_>>>()?;
    let (sum, sq) = (ops.reduction(&a, false)?, ops.reduction(&a, true)?);
    // Incoherent float4 reads (glsl/gather.comp): GATHER_THREADS threads, GATHER_ROUNDS
    // dependent reads each, from a table of GATHER_TABLE float4 at the start of `a` (64 KiB:
    // cache-resident, as a small scene's BVH and records are), through a storage buffer and
    // through a texel buffer.
    let table_len = GATHER_TABLE.min(1u64 << (63 - (n / 4).max(1).leading_zeros()));
    let gather_push = GatherPush { threads: GATHER_THREADS as u32, table_len: table_len as u32, rounds: GATHER_ROUNDS };
    let gathers = [("gather", "Table"), ("gather_texel", "table_texels")]
        .iter()
        .map(|&(kernel, binding)| {
            let p = ComputePipeline::new(ctx, kernel, &[])?;
            let g = p.bind(&[(binding, &a), ("Sums", &b)])?;
            Ok((kernel, p, g))
        })
        .collect::<Result<Vec<_>>>()?;

    let mut profiler = Profiler::new(ctx, 24)?;
    let mut cmd = CommandBuffer::new(ctx, "buffer bench")?;
    cmd.record(|rec| {
        profiler.reset(rec);
        let n_push = CountPush::new(n);
        let n4_push = Count4Push { n4: (n / 4) as u32 };
        profiler.begin(rec, "fill")?;
        ops.fill(rec, &b, 1.0)?;
        profiler.end(rec)?;
        // Each kernel below overwrites b: order the writes.
        rec.barrier(&b, Access::ComputeWrite, Access::ComputeWrite)?;
        profiler.begin(rec, "copy")?;
        ops.copy(rec, &a, &b)?;
        profiler.end(rec)?;
        rec.barrier(&b, Access::ComputeWrite, Access::ComputeWrite)?;
        profiler.begin(rec, "copy_vec4")?;
        rec.dispatch_linear(&copy4, &copy4_group, &n4_push, n / 4)?;
        profiler.end(rec)?;
        for ((k, p), g) in wide_items.iter().zip(&wide_pipes).zip(&wide_groups) {
            rec.barrier(&b, Access::ComputeWrite, Access::ComputeWrite)?;
            profiler.begin(rec, &format!("copy_vec4_x{k}"))?;
            // One thread per ITEMS float4s.
            rec.dispatch_linear(p, g, &n4_push, (n / 4).div_ceil(*k as u64))?;
            profiler.end(rec)?;
        }
        for ((w, p), g) in wg_sizes.iter().zip(&wg_pipes).zip(&wg_groups) {
            rec.barrier(&b, Access::ComputeWrite, Access::ComputeWrite)?;
            profiler.begin(rec, &format!("copy_wg{w}"))?;
            rec.dispatch_linear(p, g, &n_push, n)?;
            profiler.end(rec)?;
        }
        profiler.begin(rec, "scale_add")?;
        ops.scale_add(rec, &x, 1.0, 0.0)?;
        profiler.end(rec)?;
        profiler.begin(rec, "reduce_sum")?;
        ops.record_reduction(rec, &sum)?;
        profiler.end(rec)?;
        profiler.begin(rec, "reduce_sumsq")?;
        ops.record_reduction(rec, &sq)?;
        profiler.end(rec)?;
        profiler.begin(rec, "tiny_dispatch")?;
        ops.fill(rec, &tiny, 0.0)?;
        profiler.end(rec)?;
        for (kernel, p, g) in &gathers {
            rec.barrier(&b, Access::ComputeWrite, Access::ComputeWrite)?;
            profiler.begin(rec, kernel)?;
            rec.dispatch_linear(p, g, &gather_push, GATHER_THREADS)?;
            profiler.end(rec)?;
        }
        Ok(())
    })?;
    let times = timed_scopes(&mut cmd, &profiler, iterations)?;

    let median_of = |name: &str| median_ms(&times, name);
    let bytes = |name: &str| match name {
        "fill" | "reduce_sum" | "reduce_sumsq" => 4 * n,
        "gather" | "gather_texel" => GATHER_THREADS * GATHER_ROUNDS as u64 * 16,
        _ => 8 * n,
    };
    let mut names: Vec<String> = ["copy", "copy_vec4"].iter().map(|s| s.to_string()).collect();
    names.extend(wide_items.iter().map(|k| format!("copy_vec4_x{k}")));
    names.extend(wg_sizes.iter().map(|w| format!("copy_wg{w}")));
    names.extend(["fill", "scale_add", "reduce_sum", "reduce_sumsq", "gather", "gather_texel"].iter().map(|s| s.to_string()));
    let gbps = |name: &str| bytes(name) as f64 / (median_of(name) * 1e-3).max(1e-12) / 1e9;
    let copy_gbps = gbps("copy");
    let kernels = names
        .iter()
        .map(|name| KernelResult {
            name: name.clone(),
            bytes: bytes(name),
            median_ms: median_of(name),
            gb_per_s: gbps(name),
            ratio_to_copy: gbps(name) / copy_gbps,
        })
        .collect();

    // Host ceiling: memcpy of the same size.
    let mut host_dst = vec![0f32; n as usize];
    let mut host = Vec::new();
    for _ in 0..iterations {
        let t = Instant::now();
        host_dst.copy_from_slice(&src_data);
        host.push(t.elapsed().as_secs_f64());
        std::hint::black_box(&host_dst);
    }
    let host_memcpy_gb_per_s = 8.0 * n as f64 / median(&mut host).max(1e-12) / 1e9;

    let mut empty = CommandBuffer::new(ctx, "empty")?;
    empty.record(|_| Ok(()))?;
    let mut rt = Vec::new();
    for _ in 0..iterations.max(20) {
        let t = Instant::now();
        empty.submit_and_wait()?;
        rt.push(t.elapsed().as_secs_f64() * 1e6);
    }

    Ok(BufferBench {
        device: ctx.info().name.clone(),
        elements: n,
        iterations,
        lp_num_threads: std::env::var("LP_NUM_THREADS").ok(),
        validation: ctx.validation_enabled(),
        kernels,
        host_memcpy_gb_per_s,
        tiny_dispatch_us: median_of("tiny_dispatch") * 1e3,
        submit_roundtrip_us: median(&mut rt),
        optimisers: optimiser_bandwidth(ctx, n, iterations)?,
    })
}
