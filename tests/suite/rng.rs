//! The random number streams of the trace kernels (glsl/lib/rng.glsl, drawn through
//! glsl/rng_test.comp): the streams that different passes of one iteration and
//! consecutive iterations use must be independent, because the l2 gradient is unbiased
//! only if the adjoint's paths are independent of the primal image its residual comes
//! from (render::gradient).
//!
//! The statistic is the one that caught the defect: how often two streams' numbers at the
//! same (pixel, sample, index) fall together into the outer 1 % of [0, 1) (both below 0.01
//! or both at or above 0.99). Independent uniforms do so with probability 2·10⁻⁴; the
//! count over N pairs is binomial, and |z| > 5 fails. With pcg4d keyed by the raw seeds,
//! the primal and adjoint streams (seeds 0x10000000 apart) fell together 1.4 times as
//! often as that (z ≈ +10 at the N here), which biased the adjoint upwards in scenes
//! carried by rare paths (scenes/gap).

use crate::common;

use common::with_gpu;
use std::sync::Arc;
use vkinverse::engine::SEED_FD;
use vkinverse::gpu::{Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind};
use vkinverse::kernels::RngTestPush;
use vkinverse::render::gradient::{SEED_ADJOINT, SEED_PRIMAL};
use vkinverse::settings::gpu_seed;

/// Pixels, samples, iterations and numbers per key drawn for each stream.
const PIXELS: u32 = 4096;
const SAMPLES: u32 = 8;
const FRAMES: u32 = 2;
const DIMS: u32 = 32;
/// The tail width and the z beyond which two streams count as dependent.
const TAIL: f64 = 0.01;
const Z_MAX: f64 = 5.0;

/// The numbers of stream `seed` at iteration `frame`, sample `sample` for every pixel
/// (PIXELS × DIMS).
fn numbers(ctx: &Arc<Context>, pipe: &ComputePipeline, seed: u32, frame: u32, sample: u32) -> Vec<f32> {
    let out = Buffer::zeroed::<f32>(ctx, "numbers", (PIXELS * DIMS) as usize, MemoryKind::Device).unwrap();
    let group = pipe.bind(&[("Numbers", &out)]).unwrap();
    let push = RngTestPush { n: PIXELS, sample_index: sample, seed, frame, dims: DIMS };
    let mut cmd = CommandBuffer::new(ctx, "rng_test").unwrap();
    cmd.record(|rec| rec.dispatch_linear(pipe, &group, &push, PIXELS as u64)).unwrap();
    cmd.submit_and_wait().unwrap();
    out.read().unwrap()
}

/// z of `count` successes in `n` trials of probability `p` (binomial), and the expected count.
fn binomial_z(count: u64, n: u64, p: f64) -> (f64, f64) {
    let expected = n as f64 * p;
    ((count as f64 - expected) / (expected * (1.0 - p)).sqrt(), expected)
}

/// z of the tail co-occurrence count of streams `a` and `b` (each a function of the
/// iteration), over FRAMES iterations and SAMPLES samples.
fn tail_z(ctx: &Arc<Context>, pipe: &ComputePipeline, a: impl Fn(u32) -> (u32, u32), b: impl Fn(u32) -> (u32, u32)) -> (f64, u64, f64) {
    let mut pairs = 0u64;
    let mut together = 0u64;
    let mut in_range = true;
    for f in 0..FRAMES {
        for s in 0..SAMPLES {
            let (sa, fa) = a(f);
            let (sb, fb) = b(f);
            let x = numbers(ctx, pipe, sa, fa, s);
            let y = numbers(ctx, pipe, sb, fb, s);
            for (u, v) in x.iter().zip(&y) {
                in_range &= (0.0..1.0).contains(u) && (0.0..1.0).contains(v);
                let (u, v) = (*u as f64, *v as f64);
                if (u < TAIL && v < TAIL) || (u >= 1.0 - TAIL && v >= 1.0 - TAIL) {
                    together += 1;
                }
                pairs += 1;
            }
        }
    }
    assert!(in_range, "numbers outside [0, 1)");
    let (z, expected) = binomial_z(together, pairs, 2.0 * TAIL * TAIL);
    (z, together, expected)
}

#[test]
fn streams_of_passes_and_iterations_are_independent() {
    with_gpu(|ctx| {
        let pipe = ComputePipeline::new(ctx, "rng_test", &[]).unwrap();
        // The user's seed (0: the scene default; 1: gradcheck's) plus each pass's offset;
        // the meta-estimator's finite-difference sample adds SEED_FD to the user's seed.
        for user in [0u64, 1] {
            let seed = gpu_seed(user);
            let primal = |f: u32| (seed.wrapping_add(SEED_PRIMAL), f);
            let adjoint = |f: u32| (seed.wrapping_add(SEED_ADJOINT), f);
            let fd_primal = |f: u32| (seed.wrapping_add(SEED_FD).wrapping_add(SEED_PRIMAL), f);
            let fd_adjoint = |f: u32| (seed.wrapping_add(SEED_FD).wrapping_add(SEED_ADJOINT), f);
            let next_primal = |f: u32| (seed.wrapping_add(SEED_PRIMAL), f + 1);
            let cases: [(&str, &dyn Fn(u32) -> (u32, u32), &dyn Fn(u32) -> (u32, u32)); 5] = [
                ("primal / adjoint", &primal, &adjoint),
                ("primal / finite-difference primal", &primal, &fd_primal),
                ("adjoint / finite-difference adjoint", &adjoint, &fd_adjoint),
                ("finite-difference primal / adjoint", &fd_primal, &fd_adjoint),
                ("primal / next iteration's primal", &primal, &next_primal),
            ];
            for (name, a, b) in cases {
                let (z, together, expected) = tail_z(ctx, &pipe, a, b);
                eprintln!("seed {seed}, {name}: {together} pairs in the outer {} % tails together, {expected:.0} expected (z {z:+.2})", TAIL * 100.0);
                assert!(z.abs() <= Z_MAX, "seed {seed}, {name}: streams not independent ({together} tail pairs, {expected:.0} expected, z {z:+.2})");
            }
        }
    });
}

/// The numbers within one stream: every number a path draws is a hash of its key and its
/// index (lib/rng.glsl), and the indices of one path vertex, of consecutive vertices and of
/// the same dimension at consecutive vertices differ only in their low bits, which pcg4d
/// carries only upwards; the numbers must still be independent of one another, and each
/// dimension uniform.
#[test]
fn numbers_within_a_stream_are_independent_and_uniform() {
    with_gpu(|ctx| {
        let pipe = ComputePipeline::new(ctx, "rng_test", &[]).unwrap();
        let seed = gpu_seed(0).wrapping_add(SEED_PRIMAL);
        let mut draws: Vec<Vec<f32>> = Vec::new();
        // 8× the samples of the test above: the tail count of one pair has ~100 expected.
        for f in 0..FRAMES {
            for s in 0..8 * SAMPLES {
                draws.push(numbers(ctx, &pipe, seed, f, s));
            }
        }
        let dims = DIMS as usize;
        // Pairs of dimensions: neighbours within vertex 1, its first and last, across the
        // vertices 1 and 2, and the same dimension at vertices 1 and 2.
        let pairs = [(0usize, 1usize), (0, 3), (1, 2), (2, 3), (3, 4), (0, 4), (7, 8), (0, 8), (5, 13)];
        for (a, b) in pairs {
            let mut together = 0u64;
            let mut n = 0u64;
            let mut prod = 0.0f64;
            for x in &draws {
                for key in x.chunks_exact(dims) {
                    let (u, v) = (key[a] as f64, key[b] as f64);
                    if (u < TAIL && v < TAIL) || (u >= 1.0 - TAIL && v >= 1.0 - TAIL) {
                        together += 1;
                    }
                    prod += (u - 0.5) * (v - 0.5);
                    n += 1;
                }
            }
            let (z, expected) = binomial_z(together, n, 2.0 * TAIL * TAIL);
            // Correlation of two independent uniforms: mean 0, sd 1/sqrt(n).
            let corr = prod / n as f64 * 12.0;
            let z_corr = corr * (n as f64).sqrt();
            eprintln!("dimensions {a} and {b}: {together} tail pairs, {expected:.0} expected (z {z:+.2}); correlation {corr:+.5} (z {z_corr:+.2})");
            assert!(z.abs() <= Z_MAX, "dimensions {a} and {b}: tails not independent (z {z:+.2})");
            assert!(z_corr.abs() <= Z_MAX, "dimensions {a} and {b}: correlated ({corr:+.5}, z {z_corr:+.2})");
        }
        // Uniformity of each dimension: 16 bins, each count binomial.
        const BINS: usize = 16;
        for d in 0..dims {
            let mut counts = [0u64; BINS];
            let mut n = 0u64;
            for x in &draws {
                for key in x.chunks_exact(dims) {
                    let u = key[d];
                    assert!((0.0..1.0).contains(&u), "dimension {d}: {u} outside [0, 1)");
                    counts[(u * BINS as f32) as usize] += 1;
                    n += 1;
                }
            }
            for (k, &c) in counts.iter().enumerate() {
                let (z, expected) = binomial_z(c, n, 1.0 / BINS as f64);
                assert!(z.abs() <= Z_MAX, "dimension {d}: bin {k} holds {c}, {expected:.0} expected (z {z:+.2})");
            }
        }
    });
}
