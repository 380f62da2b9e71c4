//! The fused GPU optimiser passes against the CPU references (float32 on lavapipe vs f64).

mod common;

use common::with_gpu;
use vkinverse::optim::{self, gpu::replay_gpu, Optimiser, Range};

/// Deterministic pseudo-random numbers in [-1, 1).
fn noise(seed: u64, n: usize) -> Vec<f32> {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (0..n)
        .map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}

/// Gradient streams of a noisy quadratic around 0.3 with common-random-number FD samples.
fn streams(iters: usize, n: usize, scale: f32) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let g = (0..iters).map(|i| noise(i as u64 + 1, n).iter().map(|x| scale * (x + 0.2)).collect()).collect();
    let fd = (0..iters).map(|i| noise(1000 + i as u64, n).iter().map(|x| scale * 0.05 * x).collect()).collect();
    (g, fd)
}

#[test]
fn gpu_trajectories_match_the_f64_reference() {
    with_gpu(|ctx| {
        // 1000 elements: not a multiple of the 256-thread workgroup.
        let n = 1000;
        let (g, fd) = streams(60, n, 1.0);
        let init = noise(99, n).iter().map(|x| 0.5 + 0.2 * x).collect::<Vec<_>>();
        for opt in [Optimiser::Adam(Default::default()), Optimiser::Meta(Default::default())] {
            let range = Range::new(0.0, 1.0).unwrap();
            let (gpu, skipped) = replay_gpu(ctx, &opt, &g, Some(&fd), &init, range, 0.01).unwrap();
            let cpu = optim::replay_cpu(&opt, &g, Some(&fd), &init, range, 0.01).unwrap();
            let cpu32 = optim::replay_cpu_f32(&opt, &g, Some(&fd), &init, range, 0.01).unwrap();
            assert_eq!(skipped, 0);
            assert_eq!(gpu.len(), cpu.theta.len());
            // Against the f64 reference: relative to the parameter's scale (the range is
            // [0, 1]); float32 rounding over 60 steps stays below 1e-5 of it.
            let mut worst = 0.0f64;
            // Against the same arithmetic in f32 on the CPU: only the order of the ‖Δπ‖²
            // sum and the device's sqrt/division differ.
            let mut worst32 = 0.0f64;
            for ((a, b), c) in gpu.iter().zip(&cpu.theta).zip(&cpu32.theta) {
                for ((x, y), z) in a.iter().zip(b).zip(c) {
                    worst = worst.max((*x as f64 - y).abs() / y.abs().max(0.1));
                    worst32 = worst32.max((*x as f64 - z).abs());
                }
            }
            assert!(worst < 1e-5, "{}: worst relative difference to f64 {worst}", opt.name());
            assert!(worst32 < 2e-6, "{}: worst difference to the f32 CPU run {worst32}", opt.name());
            // The optimiser moved: the test is not comparing two copies of `init`.
            let moved: f64 = gpu.last().unwrap().iter().zip(&init).map(|(a, b)| (a - b).abs() as f64).sum();
            assert!(moved > 0.1 * n as f64 * 0.01, "{} barely moved: {moved}", opt.name());
        }
    });
}

#[test]
fn extreme_streams_stay_finite_and_nonfinite_inputs_are_skipped() {
    with_gpu(|ctx| {
        let n = 300;
        let iters = 40;
        let mut g = Vec::new();
        let mut fd = Vec::new();
        let mut injected = 0u32;
        for i in 0..iters {
            let base = noise(i as u64 + 7, n);
            let row: Vec<f32> = base
                .iter()
                .enumerate()
                .map(|(k, x)| {
                    // Scales from 1e-30 to 1e30 across the buffer, sign flips every iteration.
                    let scale = 10f32.powi((k % 61) as i32 - 30);
                    let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
                    if k % 97 == 5 && i % 10 == 3 {
                        f32::NAN
                    } else if k % 89 == 7 && i % 10 == 6 {
                        f32::INFINITY
                    } else if k < 20 {
                        0.0
                    } else {
                        sign * scale * (x + 0.1)
                    }
                })
                .collect();
            injected += row.iter().filter(|v| !v.is_finite()).count() as u32;
            fd.push(base.iter().enumerate().map(|(k, x)| 10f32.powi((k % 61) as i32 - 31) * x).collect());
            g.push(row);
        }
        let init = vec![0.5f32; n];
        for opt in [Optimiser::Adam(Default::default()), Optimiser::Meta(Default::default())] {
            let lr = 0.01;
            let (traj, skipped) = replay_gpu(ctx, &opt, &g, Some(&fd), &init, Range::new(0.0, 1.0).unwrap(), lr).unwrap();
            assert_eq!(skipped, injected, "{}: every non-finite element is counted once", opt.name());
            for (i, pair) in traj.windows(2).enumerate() {
                for k in 0..n {
                    let (a, b) = (pair[0][k], pair[1][k]);
                    assert!(b.is_finite() && (0.0..=1.0).contains(&b), "{} it {i} el {k}: {b}", opt.name());
                    if !g[i][k].is_finite() {
                        assert_eq!(a, b, "{}: a non-finite gradient must not move theta", opt.name());
                    }
                    if k < 20 {
                        assert_eq!(b, 0.5, "{}: zero gradients never move theta", opt.name());
                    }
                    // Steps are bounded by a multiple of the learning rate (Adam: 7.3 lr;
                    // meta: lr * sqrt(1 + 20 (t - 1)), see src/optim).
                    let bound = lr as f32 * (1.0 + 20.0 * i as f32).sqrt() * 1.01 + 1e-6;
                    assert!((b - a).abs() <= bound, "{} it {i} el {k}: step {}", opt.name(), b - a);
                }
            }
        }
    });
}
