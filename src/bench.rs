//! `vkinverse bench`: GPU times from timestamp scopes, reported as medians.
//!
//! The buffer bench measures the bandwidth of the buffer kernels next to the plain copy
//! kernel's, in one run, plus the costs that bound small workloads: a minimal dispatch
//! and a submit + fence round trip. A host memcpy of the same size is the ceiling.

use crate::gpu::{Access, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Profiler, Result, SpecValue};
use crate::ops::BufferOps;
use serde::Serialize;
use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Instant;

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
}

/// Median of a non-empty list (0 for an empty one).
pub fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(|a, b| a.total_cmp(b));
    let m = values.len() / 2;
    if values.len() % 2 == 1 {
        values[m]
    } else {
        0.5 * (values[m - 1] + values[m])
    }
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
        s
    }
}

/// Measures fill, copy (scalar and vec4, several workgroup sizes), scale-add and the two
/// reductions over `elements` floats, `iterations` times each, in one command buffer.
pub fn buffer_bench(ctx: &Arc<Context>, elements: u64, iterations: u32) -> Result<BufferBench> {
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
    let wide_pipes = wide_items
        .iter()
        .map(|&k| ComputePipeline::new(ctx, "copy_wide", &[("ITEMS", SpecValue::U32(k))]))
        .collect::<Result<Vec<_>>>()?;
    let wide_groups = wide_pipes.iter().map(|p| p.bind(&[("Src", &a), ("Dst", &b)])).collect::<Result<Vec<_>>>()?;
    let wg_sizes = [64u32, 128, 512, 1024];
    let wg_pipes = wg_sizes
        .iter()
        .map(|&w| ComputePipeline::new(ctx, "copy", &[("local_size_x", SpecValue::U32(w))]))
        .collect::<Result<Vec<_>>>()?;
    let wg_groups = wg_pipes.iter().map(|p| p.bind(&[("Src", &a), ("Dst", &b)])).collect::<Result<Vec<_>>>()?;
    let reductions = (0..iterations)
        .map(|_| Ok((ops.reduction(&a, false)?, ops.reduction(&a, true)?)))
        .collect::<Result<Vec<_>>>()?;

    let mut profiler = Profiler::new(ctx, 20 * iterations + 4)?;
    let mut cmd = CommandBuffer::new(ctx, "buffer bench")?;
    cmd.record(|rec| {
        profiler.reset(rec);
        let n_push = (n as u32).to_le_bytes();
        let n4_push = ((n / 4) as u32).to_le_bytes();
        for (r, (sum, sq)) in reductions.iter().enumerate() {
            if r > 0 {
                // b was written by the last kernel of the previous round; x by scale_add.
                rec.barrier(&b, Access::ComputeWrite, Access::ComputeWrite)?;
                rec.barrier(&x, Access::ComputeReadWrite, Access::ComputeReadWrite)?;
                rec.barrier(&tiny, Access::ComputeWrite, Access::ComputeWrite)?;
            }
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
            ops.record_reduction(rec, sum)?;
            profiler.end(rec)?;
            profiler.begin(rec, "reduce_sumsq")?;
            ops.record_reduction(rec, sq)?;
            profiler.end(rec)?;
            profiler.begin(rec, "tiny_dispatch")?;
            ops.fill(rec, &tiny, 0.0)?;
            profiler.end(rec)?;
        }
        Ok(())
    })?;
    cmd.submit_and_wait()?;
    let times = profiler.results()?;

    let median_of = |name: &str| {
        let mut v: Vec<f64> = times.iter().filter(|t| t.name == name).map(|t| t.ms).collect();
        median(&mut v)
    };
    let bytes = |name: &str| match name {
        "fill" | "reduce_sum" | "reduce_sumsq" => 4 * n,
        _ => 8 * n,
    };
    let mut names: Vec<String> = ["copy", "copy_vec4"].iter().map(|s| s.to_string()).collect();
    names.extend(wide_items.iter().map(|k| format!("copy_vec4_x{k}")));
    names.extend(wg_sizes.iter().map(|w| format!("copy_wg{w}")));
    names.extend(["fill", "scale_add", "reduce_sum", "reduce_sumsq"].iter().map(|s| s.to_string()));
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
    })
}
