use super::literal::replay_literal;
use super::push::{GroupSlots, MetaPush};
use super::reference::{centred_sample, one_minus_pow, BufferOptimiser, DiagRecord, MetaInput, MetaParams, Real, Ssq, StepInput};
use super::*;

/// SplitMix64 with Box–Muller normals: deterministic test streams without a dependency.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let u = 1.0 - self.uniform();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * self.uniform()).cos()
    }
}

fn adam() -> Optimiser {
    Optimiser::Adam(AdamHyper::default())
}
/// The seed's configuration.
fn meta() -> Optimiser {
    Optimiser::Meta(MetaHyper::seed())
}
fn meta_with(step: StepRule, variance: VarianceEstimate) -> Optimiser {
    Optimiser::Meta(MetaHyper { step, variance, ..MetaHyper::seed() })
}
/// The default's step rule where no noisy estimate is significant: the Wiener step
/// (settle = 1) within lr.
fn wiener() -> MetaHyper {
    MetaHyper { sig: 1e6, settle: 1.0, ..MetaHyper::default() }
}

/// Every meta variant the stability and GPU tests cover: each step rule with each variance
/// estimate and ⟨ΔF⟩ variance model, significances, and a schedule.
fn meta_variants() -> Vec<Optimiser> {
    let mut v = Vec::new();
    for step in [StepRule::Snr, StepRule::Newton] {
        for var in [VarianceEstimate::Zero, VarianceEstimate::Centred] {
            v.push(meta_with(step, var));
        }
        let Optimiser::Meta(h) = meta_with(step, VarianceEstimate::Centred) else { unreachable!() };
        v.push(Optimiser::Meta(MetaHyper { fdvar: FdVariance::Raw, ..h }));
    }
    v.push(Optimiser::Meta(MetaHyper::default()));
    v.push(Optimiser::Meta(MetaHyper { sig: 3.0, settle: 0.5, decay_h: 0.5, ..MetaHyper::default() }));
    v.push(Optimiser::Meta(wiener()));
    v.push(Optimiser::Meta(MetaHyper { decay_f: 0.99, decay_d: 0.0, ..MetaHyper::seed() }));
    let Optimiser::Meta(mut h) = meta_with(StepRule::Newton, VarianceEstimate::Zero) else { unreachable!() };
    h.schedule = Schedule { decay: Decay::Cosine, warmup: 5, horizon: 40, floor: 0.1, ..Default::default() };
    v.push(Optimiser::Meta(h));
    v
}

/// Adam, with and without a schedule, and every meta variant.
fn all_optimisers() -> Vec<Optimiser> {
    let stepped =
        Optimiser::Adam(AdamHyper { schedule: Schedule { decay: Decay::Step, every: 10, gamma: 0.5, warmup: 3, ..Default::default() }, ..Default::default() });
    let mut v = vec![adam(), stepped];
    v.extend(meta_variants());
    v
}

/// |Δθ_t| / lr bound of the module docs (None: no bound in terms of lr: the seed's rule with
/// the centred estimate, whose √V_M can be far below |⟨F⟩_M|).
fn step_bound(opt: &Optimiser, t: u32) -> Option<f64> {
    match *opt {
        Optimiser::Adam(_) => Some(ADAM_STEP_BOUND),
        Optimiser::Meta(h) => match h.step {
            StepRule::Snr if h.variance == VarianceEstimate::Centred => None,
            StepRule::Snr => Some((1.0 + (t as f64 - 1.0) * (1.0 / (1.0 - h.decay_f) + 1.0 / (1.0 - h.decay_d))).sqrt()),
            StepRule::Newton => Some(1.0),
        },
    }
}

/// Half-sample sums for a stream value: a deterministic share of it, so that the halves
/// differ and scale with it (and are non-finite where it is).
fn half_of(x: f64, t: u32, _i: usize, salt: u64) -> f64 {
    // The same share for every element: streams that scale one row keep their halves scaled.
    x * (0.5 + 0.3 * noise(t, 0, salt))
}

/// Ordinary streams: per-element gradient offsets plus unit noise, small FD samples.
fn ordinary_streams(seed: u64, iters: usize, n: usize) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let mut rng = Rng(seed);
    let offset: Vec<f64> = (0..n).map(|_| 2.0 * rng.normal()).collect();
    let grads = (0..iters).map(|_| offset.iter().map(|o| (o + rng.normal()) as f32).collect()).collect();
    let fds = (0..iters).map(|_| (0..n).map(|_| (0.1 * rng.normal()) as f32).collect()).collect();
    (grads, fds)
}

fn close(a: f64, b: f64, rel: f64, scale: f64) -> bool {
    (a - b).abs() <= rel * (a.abs().max(b.abs()) + scale)
}

#[test]
fn reference_equals_seed_transcription() {
    let range = Range::new(-3.0, 3.0).unwrap();
    for seed in 0..6 {
        let (grads, fds) = ordinary_streams(seed, 300, 37);
        let init: Vec<f32> = (0..37).map(|i| (i as f32 - 18.0) / 10.0).collect();
        let f64rows = |rows: &[Vec<f32>]| -> Vec<Vec<f64>> { rows.iter().map(|r| r.iter().map(|&x| x as f64).collect()).collect() };
        let init64: Vec<f64> = init.iter().map(|&x| x as f64).collect();
        for (opt, lr) in [(meta(), 0.02), (adam(), 0.05)] {
            let got = replay_cpu::<f64>(&opt, &grads, Some(&fds), &init, range, lr).unwrap();
            let want = replay_literal(&opt, &f64rows(&grads), Some(&f64rows(&fds)), &init64, range, lr);
            assert_eq!(got.theta.len(), 301);
            for (t, (g, w)) in got.theta.iter().zip(&want).enumerate() {
                for (a, b) in g.iter().zip(w) {
                    assert!(close(*a, *b, 1e-9, 1e-3), "{opt} seed {seed} t {t}: {a} vs {b}");
                }
            }
        }
    }
}

#[test]
fn float32_run_matches_reference() {
    // What the GPU pass must reproduce: 1e-5 relative on ordinary streams, relative to each
    // element's magnitude over its trajectory (θ crossing 0 has no relative precision in f32).
    for seed in 0..4 {
        let (grads, fds) = ordinary_streams(100 + seed, 300, 53);
        let init = vec![0.25f32; 53];
        for (opt, lr) in [(meta(), 0.01), (adam(), 0.01)] {
            let r64 = replay_cpu::<f64>(&opt, &grads, Some(&fds), &init, Range::UNBOUNDED, lr).unwrap();
            let r32 = replay_cpu::<f32>(&opt, &grads, Some(&fds), &init, Range::UNBOUNDED, lr).unwrap();
            for i in 0..53 {
                let scale = r64.theta.iter().map(|row| row[i].abs()).fold(0.0, f64::max);
                for (a, b) in r32.theta.iter().zip(&r64.theta) {
                    let dev = (a[i] - b[i]).abs() / scale;
                    assert!(dev < 1e-5, "{opt} seed {seed} element {i}: relative deviation {dev:e}");
                }
            }
        }
    }
}

#[test]
fn one_minus_pow_is_accurate_in_f32() {
    for q in [0.5f64, 0.1, 1e-3, 1e-5] {
        for t in (1..20_000).step_by(7) {
            let exact = -((t as f64) * (-q).ln_1p()).exp_m1();
            let got = one_minus_pow(q as f32, t) as f64;
            let q32 = (q as f32) as f64;
            let exact32 = -((t as f64) * (-q32).ln_1p()).exp_m1();
            assert!(close(got, exact32, 2e-6, 0.0), "q {q} t {t}: {got} vs {exact32}");
            assert!(close(one_minus_pow(q, t), exact, 1e-13, 0.0));
        }
    }
}

#[test]
fn adam_step_bound_constant() {
    let (b1, b2) = (0.9f64, 0.999f64);
    let sup = (1..100_000)
        .map(|t| {
            let t = t as f64;
            let geo = (1.0 - (b1 * b1 / b2).powf(t)) / (1.0 - b1 * b1 / b2);
            ((1.0 - b1).powi(2) * (1.0 - b2.powf(t)) / ((1.0 - b1.powf(t)).powi(2) * (1.0 - b2)) * geo).sqrt()
        })
        .fold(0.0, f64::max);
    assert!(sup < ADAM_STEP_BOUND && sup > 7.2, "{sup}");
}

// ---- stability -----------------------------------------------------------------------------

/// A gradient stream case: (t from 1, element) -> (F, ΔF).
struct Case<'a> {
    n: usize,
    iters: u32,
    lr: f64,
    range: Range,
    init: f64,
    input: &'a dyn Fn(u32, usize) -> (f64, f64),
}

/// Runs a case, asserting after every step that θ and the state are finite, θ is in range,
/// |Δθ| ≤ lr·C(t), and that skipped elements kept θ and state. Returns the trajectory and
/// the non-finite count.
fn run_case<R: Real>(opt: &Optimiser, case: &Case) -> (Vec<Vec<f64>>, u64) {
    let mut o = BufferOptimiser::<R>::new(opt, case.n, case.lr, case.range).unwrap();
    let mut theta = vec![R::of(case.init); case.n];
    let mut traj = vec![theta.iter().map(|x| x.to_f64()).collect::<Vec<_>>()];
    let mut expected_skips = 0;
    for t in 1..=case.iters {
        let (mut f, mut df, mut fh, mut dh) = (vec![], vec![], vec![], vec![]);
        for i in 0..case.n {
            let (a, b) = (case.input)(t, i);
            f.push(R::of(a));
            df.push(R::of(b));
            fh.push(R::of(half_of(a, t, i, 21)));
            dh.push(R::of(half_of(b, t, i, 22)));
        }
        let bad: Vec<bool> = (0..case.n).map(|i| !f[i].is_finite() || (opt.needs_fd() && !df[i].is_finite())).collect();
        expected_skips += bad.iter().filter(|&&b| b).count() as u64;
        let (before, adam_before, meta_before) = (theta.clone(), o.adam_state().map(<[_]>::to_vec), o.meta_state().map(<[_]>::to_vec));
        let input = StepInput { grad: &f, fd: Some(&df), grad_half: Some(&fh), fd_half: Some(&dh) };
        o.step_with(&mut theta, input).unwrap();
        let d = o.diagnostics();
        assert!(d.values().iter().all(|v| v.is_finite()), "{opt} t {t}: diagnostics {d:?}");
        assert_eq!(d.elements, bad.iter().filter(|&&b| !b).count() as u64, "{opt} t {t}");
        for i in 0..case.n {
            let (th, prev) = (theta[i].to_f64(), before[i].to_f64());
            assert!(th.is_finite() && th >= case.range.lo && th <= case.range.hi, "{opt} t {t} i {i}: θ {th}");
            let tol = 1.0 + 1e-5;
            if let Some(bound) = step_bound(opt, t) {
                let lr_t = case.lr * opt.schedule().factor(t);
                assert!((th - prev).abs() <= lr_t * bound * tol, "{opt:?} t {t} i {i}: step {}", th - prev);
            }
            if let Some(s) = o.adam_state() {
                assert!(s[i].m.is_finite() && s[i].r.is_finite() && s[i].r >= R::ZERO, "{:?}", s[i]);
                if bad[i] {
                    assert_eq!((th, s[i]), (prev, adam_before.as_ref().unwrap()[i]));
                }
            }
            if let Some(s) = o.meta_state() {
                let e = s[i];
                for v in [e.mean, e.sd, e.rms_f, e.rms_d, e.wsum_d, e.n_eff, e.v, e.curv, e.curv_w, e.last] {
                    assert!(v.is_finite(), "{opt} t {t} i {i}: {e:?}");
                }
                assert!(e.sd >= R::ZERO && e.rms_f >= R::ZERO && e.rms_d >= R::ZERO && e.v >= R::ZERO, "{e:?}");
                assert!(e.curv >= R::ZERO && e.curv_w >= R::ZERO, "{e:?}");
                // The state's last step is the step this element just took (0 if skipped).
                assert_eq!(e.last, theta[i] - before[i], "{opt} t {t} i {i}");
                assert!(e.n_eff <= R::of(t as f64) * R::of(1.0 + 1e-6), "{e:?}");
                if bad[i] {
                    // Unchanged but for the last step, which was none.
                    let kept = MetaElem { last: R::ZERO, ..meta_before.as_ref().unwrap()[i] };
                    assert_eq!((th, e), (prev, kept));
                }
            }
        }
        assert!(o.dpi2().is_finite());
        traj.push(theta.iter().map(|x| x.to_f64()).collect());
    }
    assert_eq!(o.nonfinite(), expected_skips);
    (traj, o.nonfinite())
}

/// Runs a case for every optimiser and variant in f32 (the GPU's arithmetic) and f64.
fn stable_everywhere(case: &Case) -> Vec<(Optimiser, Vec<Vec<f64>>, u64)> {
    let mut out = vec![];
    for opt in all_optimisers() {
        let (t32, n32) = run_case::<f32>(&opt, case);
        let (t64, n64) = run_case::<f64>(&opt, case);
        assert_eq!(n32, n64);
        out.push((opt, t32, n32));
        out.push((opt, t64, n64));
    }
    out
}

/// Deterministic noise in [-1, 1) for stream closures.
fn noise(t: u32, i: usize, salt: u64) -> f64 {
    let mut r = Rng((t as u64) << 32 ^ (i as u64) << 8 ^ salt);
    2.0 * r.uniform() - 1.0
}

#[test]
fn stable_for_tiny_and_huge_gradients() {
    for scale in [1e-30, 1e-20, 1e20, 1e30, 1e38] {
        let input = |t: u32, i: usize| (scale * (0.5 + noise(t, i, 1)), 0.1 * scale * noise(t, i, 2));
        let case = Case { n: 16, iters: 60, lr: 0.01, range: Range::UNBOUNDED, init: 0.0, input: &input };
        for (opt, traj, _) in stable_everywhere(&case) {
            let moved = traj[60].iter().map(|x| x.abs()).fold(0.0, f64::max);
            // Newton's step −⟨F⟩_M/h is a ratio of two quantities of the gradient's scale: no ε
            // enters it, and it moves wherever the estimate is significant, at any scale.
            let newton = matches!(opt, Optimiser::Meta(h) if h.step == StepRule::Newton);
            if scale >= 1.0 {
                assert!(moved > 0.01, "{opt} at scale {scale:e} did not move: {moved}");
            } else if !newton {
                // ε = 1e-8 dominates the denominator, as in Adam: tiny but finite steps.
                assert!(moved < 1e-10, "{opt} at scale {scale:e}: {moved}");
            }
        }
    }
}

#[test]
fn scales_1e60_apart_in_one_buffer_follow_one_trajectory() {
    // Every element sees the same normalised stream times its own scale, 1e-30 .. 1e30.
    let n = 31;
    let scale = |i: usize| 10f64.powf(-30.0 + 60.0 * i as f64 / (n - 1) as f64);
    let input = |t: u32, i: usize| (scale(i) * (0.3 + noise(t, 0, 3)), 0.2 * scale(i) * noise(t, 0, 4));
    let case = Case { n, iters: 80, lr: 0.01, range: Range::UNBOUNDED, init: 0.0, input: &input };
    for (opt, traj, _) in stable_everywhere(&case) {
        let unit = n / 2; // scale 1
        for i in (0..n).filter(|&i| scale(i) >= 1e-2) {
            for row in &traj {
                assert!(close(row[i], row[unit], 1e-4, 0.01), "{opt}: element {i} {} vs {}", row[i], row[unit]);
            }
        }
    }
}

#[test]
fn zero_gradients_do_not_move() {
    let input = |_: u32, _: usize| (0.0, 0.0);
    let case = Case { n: 8, iters: 20, lr: 0.1, range: Range::UNBOUNDED, init: 0.5, input: &input };
    for (opt, traj, _) in stable_everywhere(&case) {
        assert!(traj.iter().flatten().all(|&x| x == 0.5), "{opt}");
    }
}

#[test]
fn zero_steps_skip_the_fd_terms() {
    // lr = 0: ‖Δπ‖² stays 0, so ΔF (here garbage) must never enter the state.
    let mut o = BufferOptimiser::<f32>::new(&meta(), 4, 0.0, Range::UNBOUNDED).unwrap();
    let mut theta = vec![1.0f32; 4];
    for t in 0..30 {
        let f: Vec<f32> = (0..4).map(|i| 1.0 + noise(t, i, 5) as f32).collect();
        o.step(&mut theta, &f, Some(&[1e30, -1e30, 5.0, 0.0])).unwrap();
        assert_eq!(o.dpi2(), 0.0);
    }
    assert_eq!(theta, vec![1.0; 4]);
    for e in o.meta_state().unwrap() {
        assert_eq!((e.rms_d, e.wsum_d), (0.0, 0.0));
        // Without ΔF terms meta averages F: its mean lies within the range of the samples.
        assert!(e.mean > 0.0 && e.mean < 2.0 && e.sd > 0.0, "{e:?}");
    }
}

#[test]
fn pinned_at_a_bound_stays_there() {
    let input = |t: u32, i: usize| (-1.0 + 0.3 * noise(t, i, 6), 0.1 * noise(t, i, 7));
    let case = Case { n: 8, iters: 40, lr: 0.05, range: Range::new(0.0, 1.0).unwrap(), init: 1.0, input: &input };
    for (opt, traj, _) in stable_everywhere(&case) {
        assert!(traj.iter().flatten().all(|&x| x == 1.0), "{opt}");
    }
    // Meta: the group never moved, so the ΔF Moment2 never started.
    let mut o = BufferOptimiser::<f64>::new(&meta(), 1, 0.05, Range::new(0.0, 1.0).unwrap()).unwrap();
    let mut theta = vec![1.0];
    for _ in 0..10 {
        o.step(&mut theta, &[-1.0], Some(&[0.3])).unwrap();
    }
    assert_eq!(o.meta_state().unwrap()[0].wsum_d, 0.0);
}

#[test]
fn sign_flips() {
    // Alternating every step, and a sudden flip at t = 30 whose change a common-random-number
    // finite difference reports exactly (ΔF = F_t − F_{t−1}).
    let alternating = |t: u32, _: usize| {
        let f = if t.is_multiple_of(2) { 1.0 } else { -1.0 };
        (f, 2.0 * f)
    };
    let sudden = |t: u32, _: usize| {
        let f = if t < 30 { 1.0 } else { -1.0 };
        (f, if t == 30 { -2.0 } else { 0.0 })
    };
    let case = Case { n: 2, iters: 60, lr: 0.01, range: Range::UNBOUNDED, init: 0.0, input: &alternating };
    stable_everywhere(&case);
    let case = Case { input: &sudden, ..case };
    for (opt, traj, _) in stable_everywhere(&case) {
        let step = |t: usize| traj[t][0] - traj[t - 1][0];
        assert!(step(29) < 0.0, "{opt}");
        // The first step that goes the other way.
        let turn = (30..=60).find(|&t| step(t) > 0.0).unwrap();
        let limit = if opt.needs_fd() { 30 } else { 40 };
        assert!(turn <= limit, "{opt} turned at {turn}");
    }
}

#[test]
fn nonfinite_inputs_are_counted_and_skipped() {
    let input = |t: u32, i: usize| {
        let f = 1.0 + noise(t, i, 8);
        let df = 0.1 * noise(t, i, 9);
        match (t % 5, i) {
            (0, 0) => (f64::NAN, df),
            (0, 1) => (f, f64::INFINITY),
            (0, 2) => (f64::NEG_INFINITY, f64::NAN),
            (3, 3) => (f64::INFINITY, df),
            _ => (f, df),
        }
    };
    let case = Case { n: 6, iters: 40, lr: 0.02, range: Range::UNBOUNDED, init: 0.0, input: &input };
    for (opt, traj, count) in stable_everywhere(&case) {
        // Adam reads no ΔF, so a non-finite ΔF alone is no input error for it.
        let per_round = if opt.needs_fd() { 4 } else { 3 };
        assert_eq!(count, 8 * per_round, "{opt}");
        assert!(traj[40][4] != 0.0 && traj[40][0] != 0.0);
    }
}

// ---- the noisy quadratic -------------------------------------------------------------------

/// f(π) = ½a(π−π*)² per element, a ∈ [0.5, 2], π* ∈ [−3, 3], θ_0 = 0; ⟨F⟩ = a(π−π*) + 3ξ;
/// ⟨ΔF⟩ = a(π_i − π_{i−1}) + σ_d ξ' (common random numbers cancel the noise up to σ_d). Each
/// estimate is the mean of two independent halves (its half-sample sum is half the second),
/// as the gradient passes split their samples. Returns the final parameter RMSE and, for
/// Meta, the element-mean n_eff at 3/4 and at the end of the run.
fn quadratic(opt: &Optimiser, lr: f64, seed: u64, iters: u32, sigma_d: f64) -> (f64, f64, f64) {
    quadratic_with(opt, lr, seed, iters, 3.0, sigma_d)
}

/// [`quadratic`] with ⟨F⟩'s noise `sigma`.
fn quadratic_with(opt: &Optimiser, lr: f64, seed: u64, iters: u32, sigma: f64, sigma_d: f64) -> (f64, f64, f64) {
    let n = 64;
    let mut rng = Rng(seed);
    let a: Vec<f64> = (0..n).map(|_| 0.5 + 1.5 * rng.uniform()).collect();
    let target: Vec<f64> = (0..n).map(|_| 6.0 * rng.uniform() - 3.0).collect();
    let mut o = BufferOptimiser::<f64>::new(opt, n, lr, Range::new(-4.0, 4.0).unwrap()).unwrap();
    let mut theta = vec![0.0; n];
    let mut prev = theta.clone();
    let n_eff = |o: &BufferOptimiser<f64>| o.meta_state().map_or(0.0, |s| s.iter().map(|e| e.n_eff).sum::<f64>() / n as f64);
    // (total, half-sample sum) of an estimate with expectation `mean` and noise `sigma`.
    let mut halves = |mean: f64, sigma: f64| {
        let (x, y) = (rng.normal(), rng.normal());
        let (a, b) = (mean + sigma * std::f64::consts::SQRT_2 * x, mean + sigma * std::f64::consts::SQRT_2 * y);
        ((a + b) / 2.0, b / 2.0)
    };
    let mut n_eff_3q = 0.0;
    for t in 1..=iters {
        let (f, fh): (Vec<f64>, Vec<f64>) = (0..n).map(|i| halves(a[i] * (theta[i] - target[i]), sigma)).unzip();
        let (df, dh): (Vec<f64>, Vec<f64>) = (0..n).map(|i| halves(a[i] * (theta[i] - prev[i]), sigma_d)).unzip();
        prev.clone_from(&theta);
        let input = StepInput { grad: &f, fd: Some(&df), grad_half: Some(&fh), fd_half: Some(&dh) };
        o.step_with(&mut theta, input).unwrap();
        if t == iters * 3 / 4 {
            n_eff_3q = n_eff(&o);
        }
    }
    let rmse = (theta.iter().zip(&target).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / n as f64).sqrt();
    (rmse, n_eff_3q, n_eff(&o))
}

fn mean_error(opt: &Optimiser, lr: f64, seeds: std::ops::Range<u64>, iters: u32) -> f64 {
    let k = seeds.end - seeds.start;
    seeds.map(|s| quadratic(opt, lr, s, iters, 0.01).0).sum::<f64>() / k as f64
}

#[test]
fn meta_beats_adam_on_a_noisy_quadratic() {
    // Fair learning rates: each optimiser gets the best of one grid on its own tuning seeds
    // (1000..1004); both are then scored on fresh seeds (0..8) at equal iterations.
    let grid = [0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2];
    for iters in [100, 300] {
        let best = |opt: &Optimiser| {
            let scored = grid.iter().map(|&lr| (mean_error(opt, lr, 1000..1004, iters), lr));
            scored.fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a }).1
        };
        let (lr_meta, lr_adam) = (best(&meta()), best(&adam()));
        let err_meta = mean_error(&meta(), lr_meta, 0..8, iters);
        let err_adam = mean_error(&adam(), lr_adam, 0..8, iters);
        assert!(err_meta < 0.85 * err_adam, "{iters} iterations: meta {err_meta} (lr {lr_meta}) vs adam {err_adam} (lr {lr_adam})");
    }
}

#[test]
fn alpha_approaches_the_averaging_bound_with_exact_fd() {
    // At the bound α_t = 1 − 1/(1 + n_eff_{t−1}): n_eff grows by one sample per step.
    // A linear objective, ⟨F⟩ = 1 + ξ, has the exact finite difference 0. There α stays below
    // the bound only through the noise of the VF EMA, which vanishes as β_F → 1.
    for (decay_f, at_least) in [(0.9, 0.4), (0.999, 0.9)] {
        // The seed's zero-centred variance: this stream has no half sums.
        let opt = Optimiser::Meta(MetaHyper { decay_f, ..MetaHyper::seed() });
        let (n, iters) = (64, 400);
        let mut rng = Rng(3);
        let mut o = BufferOptimiser::<f64>::new(&opt, n, 0.01, Range::UNBOUNDED).unwrap();
        let mut theta = vec![0.0; n];
        for _ in 0..iters {
            let f: Vec<f64> = (0..n).map(|_| 1.0 + rng.normal()).collect();
            o.step(&mut theta, &f, Some(&vec![0.0; n])).unwrap();
        }
        let n_eff = o.meta_state().unwrap().iter().map(|e| e.n_eff).sum::<f64>() / n as f64;
        assert!(n_eff > at_least * iters as f64, "decay_f {decay_f}: n_eff {n_eff} after {iters} steps");
    }
    // The noisy quadratic: exact ⟨ΔF⟩ keep n_eff growing; noisy ones (σ_d = σ) hold it near 2.
    let (_, early, late) = quadratic(&meta(), 0.02, 7, 400, 0.0);
    assert!(late - early > 20.0, "n_eff {early} -> {late} over the last 100 steps");
    let (_, _, noisy) = quadratic(&meta(), 0.02, 7, 400, 3.0);
    assert!(noisy < 3.0, "n_eff {noisy} with noisy finite differences");
}

#[test]
fn raw_fd_variance_survives_steps_of_varying_length() {
    // ⟨ΔF⟩ with a noise floor that does not shrink with the step (σ_d = 0.05 of ⟨F⟩'s noise),
    // and steps whose length alternates between 1e-6 and 1e-2 (as the Wiener rule's do near
    // the optimum). The scaled model learns ⟨ΔF⟩/‖Δπ‖ from the tiny steps and predicts a
    // variance 1e4² too large after the large ones, so the history loses its weight; the raw
    // model keeps averaging.
    // n_eff of each of 200 steps of one element: ⟨F⟩ = 1 + ξ, ⟨ΔF⟩ = sigma_d·ξ', and
    // ‖Δπ‖² = dpi2(t) for the step before t (0 before the first).
    let n_eff = |fdvar: FdVariance, dpi2: &dyn Fn(u32) -> f64, sigma_d: f64, seed: u64| -> Vec<f64> {
        let h = MetaHyper { fdvar, ..MetaHyper::seed() };
        let mut rng = Rng(seed);
        let mut s = MetaElem::<f64>::default();
        (1..=200u32)
            .map(|t| {
                let x = MetaInput { f: 1.0 + rng.normal(), df: sigma_d * rng.normal(), ..Default::default() };
                let p = MetaParams::<f64>::new(&h, 1, t, 0.01, Range::UNBOUNDED);
                let (_, next, d) = reference::meta_update(&p, 0.5, x, if t == 1 { 0.0 } else { dpi2(t) }, s).unwrap();
                s = next;
                d.n_eff
            })
            .collect()
    };
    let alternating = |t: u32| if t.is_multiple_of(2) { 1e-12 } else { 1e-4 };
    let late_mean = |v: Vec<f64>| v[100..].iter().sum::<f64>() / 100.0;
    let scaled = late_mean(n_eff(FdVariance::Scaled, &alternating, 0.05, 11));
    let raw = late_mean(n_eff(FdVariance::Raw, &alternating, 0.05, 11));
    assert!(scaled < 2.5, "scaled: n_eff {scaled}");
    assert!(raw > 10.0, "raw: n_eff {raw}");
    // With a step-proportional ⟨ΔF⟩ noise (3‖Δπ‖) and steady steps both models agree.
    let steady = |t: u32| if t > 0 { 1e-4 } else { 0.0 };
    let a = *n_eff(FdVariance::Scaled, &steady, 0.03, 12).last().unwrap();
    let b = *n_eff(FdVariance::Raw, &steady, 0.03, 12).last().unwrap();
    assert!((a - b).abs() < 1e-9 * a, "steady steps: {a} vs {b}");
}

// ---- GPU-side contracts --------------------------------------------------------------------

#[test]
fn glsl_mirrors_constants_and_push_blocks() {
    let lib = include_str!("../../glsl/lib/optim.glsl");
    assert!(lib.contains("const float META_ALPHA_REG = 1e-30;") && ALPHA_REG == 1e-30);
    // The step-rule and schedule numbers are the generated constants (src/constants.rs).
    assert_eq!([StepRule::Snr, StepRule::Newton].map(StepRule::code), [0, 1]);
    assert_eq!([Decay::Constant, Decay::Cosine, Decay::Step].map(Decay::code), [0, 1, 2]);
    // Push blocks are checked against their mirrors for every kernel (tests/suite/contracts.rs).
    use std::mem::offset_of;
    let owned = |v: &[(&str, usize)]| v.iter().map(|(n, o)| (n.to_string(), *o)).collect::<Vec<_>>();
    // The diagnostics record, as every kernel that writes or reads it declares it.
    use crate::shared::{DiagRecord as Rec, Ssq as S};
    for kernel in ["optim_adam", "optim_meta", "optim_diag"] {
        let r = crate::gpu::reflect::Reflection::new(kernel, crate::gpu::shaders::get(kernel).unwrap()).unwrap();
        assert_eq!(
            r.struct_layout("DiagRecord").unwrap(),
            owned(&[
                ("count", offset_of!(Rec, count)),
                ("n_eff_sum", offset_of!(Rec, n_eff_sum)),
                ("n_eff_min", offset_of!(Rec, n_eff_min)),
                ("n_eff_max", offset_of!(Rec, n_eff_max)),
                ("clipped", offset_of!(Rec, clipped)),
                ("newton", offset_of!(Rec, newton)),
                ("f", offset_of!(Rec, f)),
                ("df", offset_of!(Rec, df)),
                ("sd_d", offset_of!(Rec, sd_d)),
                ("step", offset_of!(Rec, step)),
                ("mean", offset_of!(Rec, mean)),
                ("sd", offset_of!(Rec, sd)),
                ("sd_f", offset_of!(Rec, sd_f)),
                ("curv", offset_of!(Rec, curv)),
            ]),
            "{kernel}"
        );
        assert_eq!(r.struct_size("DiagRecord"), Some(std::mem::size_of::<Rec>()), "{kernel}");
        assert_eq!(r.struct_layout("Ssq").unwrap(), owned(&[("scale", offset_of!(S, scale)), ("sum", offset_of!(S, sum))]));
    }
    let g = GroupSlots { n: 5, offset: 1, group: 2, first_partial: 3 };
    let p = MetaPush::new(&MetaHyper::default(), g, 0.1, Range::UNBOUNDED);
    assert_eq!((p.lo, p.hi, p.offset, p.group, p.first_partial), (f32::MIN, f32::MAX, 1, 2, 3));
    // The Wiener step's normaliser decays as Adam's default second moment; the significance
    // is Bonferroni's for the group's five elements.
    assert_eq!((p.beta2, p.step_rule, p.sig), (0.999, crate::constants::STEP_NEWTON, bonferroni_sig(1.5, 5) as f32));
}

// ---- variants ------------------------------------------------------------------------------

#[test]
fn sums_of_squares_neither_overflow_nor_vanish() {
    for scale in [1e-30f64, 1.0, 1e30] {
        let xs: Vec<f64> = (0..1000).map(|i| scale * (i as f64 - 400.0) / 100.0).collect();
        let exact = xs.iter().map(|x| (x / scale).powi(2)).sum::<f64>().sqrt() * scale;
        // In f32, in two different merge orders (sequential, and pairwise as the GPU does).
        let seq = xs.iter().fold(Ssq::<f32>::default(), |a, &x| a.merge(Ssq::of(x as f32)));
        let mut level: Vec<Ssq<f32>> = xs.iter().map(|&x| Ssq::of(x as f32)).collect();
        while level.len() > 1 {
            level = level.chunks(2).map(|c| c.iter().fold(Ssq::default(), |a, b| a.merge(*b))).collect();
        }
        for got in [seq.norm(), level[0].norm()] {
            assert!(close(got as f64, exact, 1e-5, 0.0), "scale {scale:e}: {got} vs {exact}");
        }
        assert!(seq.total().is_finite());
    }
    assert_eq!(Ssq::<f64>::of(0.0).merge(Ssq::of(0.0)), Ssq::default());
}

#[test]
fn diagnostics_summarise_the_step() {
    // The record of a step equals the statistics computed directly from the states.
    let (grads, fds) = ordinary_streams(5, 30, 41);
    let opt = meta_with(StepRule::Newton, VarianceEstimate::Zero);
    let mut o = BufferOptimiser::<f64>::new(&opt, 41, 0.02, Range::new(-5.0, 5.0).unwrap()).unwrap();
    let mut theta = vec![0.0f64; 41];
    for (t, (g, fd)) in grads.iter().zip(&fds).enumerate() {
        let g: Vec<f64> = g.iter().map(|&x| x as f64).collect();
        let fd: Vec<f64> = fd.iter().map(|&x| x as f64).collect();
        let before = theta.clone();
        let dpi2_before = o.dpi2();
        o.step(&mut theta, &g, Some(&fd)).unwrap();
        let s = o.meta_state().unwrap();
        let d = o.diagnostics();
        let n = 41.0;
        let rms = |v: &mut dyn Iterator<Item = f64>| (v.map(|x| x * x).sum::<f64>() / n).sqrt();
        let steps: Vec<f64> = theta.iter().zip(&before).map(|(a, b)| a - b).collect();
        assert_eq!(d.elements, 41);
        assert!(close(d.n_eff_mean, s.iter().map(|e| e.n_eff).sum::<f64>() / n, 1e-12, 0.0));
        assert_eq!(d.n_eff_max, s.iter().map(|e| e.n_eff).fold(0.0, f64::max));
        assert_eq!(d.n_eff_min, s.iter().map(|e| e.n_eff).fold(f64::MAX, f64::min));
        assert!(close(d.rms_f, rms(&mut g.iter().copied()), 1e-12, 0.0));
        // The ΔF used: none at the first step (no previous one).
        let used = if dpi2_before > 0.0 { rms(&mut fd.iter().copied()) } else { 0.0 };
        assert!(close(d.rms_df, used, 1e-12, 0.0), "t {t}");
        assert!(close(d.rms_mean, rms(&mut s.iter().map(|e| e.mean)), 1e-12, 0.0));
        assert!(close(d.sd_mean, rms(&mut s.iter().map(|e| e.sd)), 1e-12, 0.0));
        assert!(close(d.sd_f, rms(&mut s.iter().map(|e| e.rms_f)), 1e-12, 0.0));
        assert!(close(d.rms_step, rms(&mut steps.iter().copied()), 1e-12, 1e-300));
        assert!(close(d.step_norm * d.step_norm, o.dpi2(), 1e-12, 1e-300));
        assert!((0.0..=1.0).contains(&d.clipped) && d.lr == 0.02);
        if t == 0 {
            // The first step is clipped to α = 0: one sample, n_eff 1.
            assert_eq!((d.clipped, d.n_eff_max, d.sd_fd), (1.0, 1.0, 0.0));
        }
    }
}

#[test]
fn centred_variance_leaves_out_the_mean() {
    // ⟨F⟩ with mean 10 and standard deviation 1 from two halves: the zero-centred Moment2
    // holds E[F²] ≈ 101, the centred one Var[F] ≈ 1.
    let mut rng = Rng(11);
    let (n, iters) = (256, 200);
    let long = |variance| Optimiser::Meta(MetaHyper { variance, decay_f: 0.99, ..MetaHyper::seed() });
    let mut zero = BufferOptimiser::<f64>::new(&long(VarianceEstimate::Zero), n, 0.0, Range::UNBOUNDED).unwrap();
    let mut cent = BufferOptimiser::<f64>::new(&long(VarianceEstimate::Centred), n, 0.0, Range::UNBOUNDED).unwrap();
    let mut theta = vec![0.0; n];
    for _ in 0..iters {
        let (f, fh): (Vec<f64>, Vec<f64>) = (0..n)
            .map(|_| {
                let (a, b) = (10.0 + 2f64.sqrt() * rng.normal(), 10.0 + 2f64.sqrt() * rng.normal());
                ((a + b) / 2.0, b / 2.0)
            })
            .unzip();
        let zeros = vec![0.0; n];
        let input = StepInput { grad: &f, fd: Some(&zeros), grad_half: Some(&fh), fd_half: Some(&zeros) };
        zero.step_with(&mut theta.clone(), input).unwrap();
        cent.step_with(&mut theta, input).unwrap();
    }
    let mean_sq = |o: &BufferOptimiser<f64>| o.meta_state().unwrap().iter().map(|e| e.rms_f * e.rms_f).sum::<f64>() / n as f64;
    let (z, c) = (mean_sq(&zero), mean_sq(&cent));
    assert!((z - 101.0).abs() < 3.0, "zero-centred {z}");
    assert!((c - 1.0).abs() < 0.1, "centred {c}");
    assert_eq!(centred_sample(3.0f64, 1.0), 1.0);
    assert_eq!(centred_sample(f32::MAX, -f32::MAX), f32::MAX);
}

#[test]
fn step_rules_set_the_step_size() {
    // A constant gradient c with exact finite differences: the estimate is c and averages
    // every sample (n_eff = t). The Wiener step is lr (the rate is the typical change per
    // iteration) times the estimate's gain; the seed's grows like √n_eff while its noise
    // shrinks.
    let run = |h: MetaHyper, c: f64, t_end: u32| {
        let mut o = BufferOptimiser::<f64>::new(&Optimiser::Meta(h), 1, 0.01, Range::UNBOUNDED).unwrap();
        let mut theta = vec![0.0];
        let mut last = 0.0;
        for _ in 0..t_end {
            let before = theta[0];
            o.step(&mut theta, &[c], Some(&[0.0])).unwrap();
            last = theta[0] - before;
        }
        (last, o.meta_state().unwrap()[0].n_eff)
    };
    let zero = |h: MetaHyper| MetaHyper { variance: VarianceEstimate::Zero, ..h };
    for c in [1e-3, 1.0, 1e6] {
        // Wiener: the normalised step times ⟨F⟩_M²/(⟨F⟩_M² + V_M) = n/(n + 1).
        let (w, n) = run(zero(wiener()), c, 50);
        assert!(close(w, -0.01 * 50.0 / 51.0, 1e-4, 0.0) && close(n, 50.0, 1e-9, 0.0), "{w} {n}");
        let (snr, _) = run(MetaHyper::seed(), c, 50);
        // √V_M = rms_f/√n (all samples equal): the seed's step is lr·√50.
        assert!(close(snr, -0.01 * 50f64.sqrt(), 1e-4, 0.0), "{snr}");
    }
    // Pure noise around a zero gradient: the Wiener step is a fraction of lr.
    let mut rng = Rng(9);
    let n = 400;
    let mut o = BufferOptimiser::<f64>::new(&Optimiser::Meta(zero(wiener())), n, 0.01, Range::UNBOUNDED).unwrap();
    let mut theta = vec![0.0; n];
    let mut total = 0.0;
    for _ in 0..100 {
        let f: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let before = theta.clone();
        o.step(&mut theta, &f, Some(&vec![0.0; n])).unwrap();
        total += theta.iter().zip(&before).map(|(a, b)| (a - b).abs()).sum::<f64>();
    }
    assert!(total < 0.6 * 0.01 * (n * 100) as f64, "path {total}");
    // Newton's rule never steps past lr, whatever the input.
    let input = |t: u32, i: usize| (1e20 * noise(t, i, 30), 1e25 * noise(t, i, 31));
    let case = Case { n: 8, iters: 40, lr: 0.05, range: Range::UNBOUNDED, init: 0.0, input: &input };
    run_case::<f32>(&Optimiser::Meta(MetaHyper::default()), &case);
}

/// One element's exact quadratic: ⟨F⟩ = a(θ − θ*), ⟨ΔF⟩ = a·Δθ, halves equal (no noise).
/// Returns θ after each step, the final curvature state and each step's diagnostics.
fn exact_quadratic(h: MetaHyper, a: f64, target: f64, lr: f64, iters: u32) -> (Vec<f64>, f64, Vec<Diagnostics>) {
    secant_quadratic(h, a, target, lr, iters, 0.0)
}

/// One element's quadratic ⟨F⟩ = a(θ − θ*), ⟨ΔF⟩ = a·Δθ from θ = 0.5, whose half-sample
/// sums of ⟨F⟩ and ⟨ΔF⟩ are off by ±`c` (alternating by step, opposite for the two): with
/// c = 0 the halves are equal (no noise); above 0 the centred variance sees noise of about
/// 2c in both, so n_eff stays small and the estimate's standard deviation near c, while
/// the gradient itself stays exact and never changes sign. Returns θ after each step, the
/// final curvature state and each step's diagnostics.
fn secant_quadratic(h: MetaHyper, a: f64, target: f64, lr: f64, iters: u32, c: f64) -> (Vec<f64>, f64, Vec<Diagnostics>) {
    let opt = Optimiser::Meta(h);
    let mut o = BufferOptimiser::<f64>::new(&opt, 1, lr, Range::new(0.0, 1.0).unwrap()).unwrap();
    let (mut theta, mut prev) = (vec![0.5], 0.5);
    let (mut traj, mut diags) = (Vec::new(), Vec::new());
    for t in 0..iters {
        let f = a * (theta[0] - target);
        let df = a * (theta[0] - prev);
        prev = theta[0];
        let off = if t % 2 == 0 { c } else { -c };
        let input = StepInput { grad: &[f], fd: Some(&[df]), grad_half: Some(&[f / 2.0 + off]), fd_half: Some(&[df / 2.0 - off]) };
        o.step_with(&mut theta, input).unwrap();
        traj.push(theta[0]);
        diags.push(*o.diagnostics());
    }
    (traj, o.meta_state().unwrap()[0].curv, diags)
}

#[test]
fn newton_steps_to_the_optimum_of_an_exact_quadratic() {
    // The secant of exact finite differences is the curvature a, and a noiseless estimate
    // is significant: from the second step on the iterate moves by the distance to the
    // optimum, at most lr per step. Gradients of the renderer's scale and of unit scale.
    for a in [2e-3, 1.0] {
        for target in [0.2, 0.62, 0.9] {
            let (traj, curv, d) = exact_quadratic(MetaHyper::default(), a, target, 0.05, 12);
            let d = &d[2];
            let distance = (0.5f64 - target).abs();
            // The first step is the Wiener rule's (no curvature yet): lr towards the target
            // (less ε's share).
            assert!(close((traj[0] - 0.5).abs(), 0.05, 1e-4, 0.0), "{traj:?}");
            // Then lr per step until the target is within lr, then exactly there.
            let arrive = (distance / 0.05).ceil() as usize + 1;
            for (t, &x) in traj.iter().enumerate().skip(arrive) {
                assert!((x - target).abs() < 1e-12, "a {a} target {target} t {t}: {x}");
            }
            assert!(close(curv, a, 1e-12, 0.0), "curvature {curv} vs {a}");
            assert_eq!((d.newton, d.elements), (1.0, 1));
            assert!(close(d.rms_curv, a, 1e-12, 0.0));
            // The curvature is kept whatever the rule; only Newton steps on it.
            let (_, snr_curv, sd) = exact_quadratic(MetaHyper { step: StepRule::Snr, ..MetaHyper::default() }, a, target, 0.05, 12);
            assert!(close(snr_curv, a, 1e-12, 0.0) && sd.iter().all(|d| d.newton == 0.0));
        }
    }
}

#[test]
fn newton_beats_wiener_on_a_noisy_quadratic() {
    // Equal rates, equal iterations, a gradient whose noise (0.3) is below its signal far
    // from the optimum: Newton's rule moves by the estimated distance while the estimate is
    // significant, and near the optimum steps by a fraction of the Wiener step, so that the
    // estimate averages and its significant part corrects the iterate. Against the Wiener
    // step alone.
    let newton = Optimiser::Meta(MetaHyper::default());
    let wiener = Optimiser::Meta(wiener());
    for lr in [0.02, 0.05] {
        for iters in [100, 300] {
            let err = |opt: &Optimiser| (0..8).map(|s| quadratic_with(opt, lr, s, iters, 0.3, 0.01).0).sum::<f64>() / 8.0;
            let (e_newton, e_wiener) = (err(&newton), err(&wiener));
            assert!(e_newton < 0.85 * e_wiener, "lr {lr}, {iters} iterations: newton {e_newton} vs wiener {e_wiener}");
        }
    }
}

#[test]
fn newton_in_f32_follows_f64() {
    // The noisy quadratic closed over each run's own iterates (⟨ΔF⟩ spans the step each
    // precision took, as a renderer's does), the same noise in both precisions: Newton's
    // rule in f32 stays within 1e-4 of the f64 run's trajectory.
    let opt = Optimiser::Meta(MetaHyper { step: StepRule::Newton, ..MetaHyper::default() });
    // The trajectory and the targets.
    fn run<R: Real>(opt: &Optimiser, seed: u64) -> (Vec<Vec<f64>>, Vec<f64>) {
        let n = 16;
        let mut rng = Rng(seed);
        let a: Vec<f64> = (0..n).map(|_| 1e-3 * (0.5 + 1.5 * rng.uniform())).collect();
        let target: Vec<f64> = (0..n).map(|_| 0.1 + 0.8 * rng.uniform()).collect();
        let mut o = BufferOptimiser::<R>::new(opt, n, 0.02, Range::new(0.0, 1.0).unwrap()).unwrap();
        let mut theta = vec![R::of(0.5); n];
        let mut prev = theta.clone();
        let mut traj = Vec::new();
        for _ in 0..200 {
            let mut est = |mean: f64, sigma: f64| {
                let (x, y) = (mean + sigma * rng.normal(), mean + sigma * rng.normal());
                (R::of((x + y) / 2.0), R::of(y / 2.0))
            };
            let (f, fh): (Vec<R>, Vec<R>) = (0..n).map(|i| est(a[i] * (theta[i].to_f64() - target[i]), 3e-5)).unzip();
            let (df, dh): (Vec<R>, Vec<R>) = (0..n).map(|i| est(a[i] * (theta[i].to_f64() - prev[i].to_f64()), 1e-7)).unzip();
            prev.clone_from(&theta);
            let input = StepInput { grad: &f, fd: Some(&df), grad_half: Some(&fh), fd_half: Some(&dh) };
            o.step_with(&mut theta, input).unwrap();
            traj.push(theta.iter().map(|x| x.to_f64()).collect());
        }
        (traj, target)
    }
    for seed in 0..4 {
        let ((t32, _), (t64, target)) = (run::<f32>(&opt, seed), run::<f64>(&opt, seed));
        for (t, (a, b)) in t32.iter().zip(&t64).enumerate() {
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() < 1e-4, "seed {seed} t {t}: {x} vs {y}");
            }
        }
        // And it got there: the targets are recovered to the noise's level.
        let last = t64.last().unwrap();
        let rmse = (last.iter().zip(&target).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / 16.0).sqrt();
        assert!(rmse < 0.01, "seed {seed}: rmse {rmse}");
    }
}

#[test]
fn schedules_scale_the_step() {
    // Adam with a step schedule on a constant gradient: each step is lr·factor(t).
    let opt = Optimiser::Adam(AdamHyper {
        beta1: 0.0,
        schedule: Schedule { decay: Decay::Step, every: 5, gamma: 0.5, warmup: 2, ..Default::default() },
        ..Default::default()
    });
    let mut o = BufferOptimiser::<f64>::new(&opt, 1, 0.1, Range::UNBOUNDED).unwrap();
    let mut theta = vec![0.0];
    for t in 1..=20u32 {
        let before = theta[0];
        o.step(&mut theta, &[1.0], None).unwrap();
        let want = -0.1 * opt.schedule().factor(t);
        assert!(close(theta[0] - before, want, 1e-6, 0.0), "t {t}: {} vs {want}", theta[0] - before);
        assert_eq!(o.diagnostics().lr, 0.1 * opt.schedule().factor(t));
    }
}

#[test]
fn variants_in_f32_match_f64() {
    // Every variant, with its halves: what the GPU computes against the reference.
    for opt in all_optimisers() {
        let (grads, fds) = ordinary_streams(200, 150, 29);
        let halves = |rows: &[Vec<f32>], salt: u64| -> Vec<Vec<f32>> {
            rows.iter().enumerate().map(|(t, r)| r.iter().enumerate().map(|(i, &x)| half_of(x as f64, t as u32, i, salt) as f32).collect()).collect()
        };
        let (gh, fh) = (halves(&grads, 41), halves(&fds, 42));
        let streams = Streams { grads: &grads, fd_grads: Some(&fds), grad_halves: Some(&gh), fd_halves: Some(&fh) };
        let init = vec![0.25f32; 29];
        let r64 = replay::replay_streams::<f64>(&opt, &streams, &init, Range::new(-3.0, 3.0).unwrap(), 0.01).unwrap();
        let r32 = replay::replay_streams::<f32>(&opt, &streams, &init, Range::new(-3.0, 3.0).unwrap(), 0.01).unwrap();
        // Newton's step divides by a curvature fitted to ⟨ΔF⟩/Δθ; these streams' ⟨ΔF⟩ ignore
        // the steps, so its tiny steps, which f32 resolves to ~1e-7 of θ, set the curvature,
        // and f32 and f64 part ways (a renderer's ⟨ΔF⟩ spans the float32 step it was sampled
        // over: `newton_in_f32_follows_f64` checks that case).
        if matches!(opt, Optimiser::Meta(h) if h.step == StepRule::Newton) {
            continue;
        }
        for (a, b) in r32.theta.iter().zip(&r64.theta) {
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() < 2e-5, "{opt:?}: {x} vs {y}");
            }
        }
        for (a, b) in r32.diagnostics.iter().zip(&r64.diagnostics) {
            // Steps are differences of θ, which f32 resolves to ~1e-7 of θ's scale (0.25 here);
            // the secant curvature divides by them (these streams' ⟨ΔF⟩ ignore the steps, so
            // their tiny steps weigh in).
            for (k, (x, y)) in a.values().iter().zip(b.values()).enumerate() {
                let (rel, scale) = match Diagnostics::COLUMNS[k] {
                    "rms_curv" => (0.2, 1e-5),
                    "step_norm" | "rms_step" | "newton" => (1e-2, 1e-5),
                    _ => (1e-3, 1e-5),
                };
                assert!(close(*x, y, rel, scale), "{opt:?}: diagnostics {a:?} vs {b:?}");
            }
        }
    }
}

#[test]
fn missing_halves_are_an_error() {
    let g = vec![vec![1.0f32; 3]; 2];
    let opt = meta_with(StepRule::Snr, VarianceEstimate::Centred);
    assert!(matches!(replay_cpu::<f64>(&opt, &g, Some(&g), &[0.0; 3], Range::UNBOUNDED, 0.1), Err(OptimError::MissingHalves)));
    let rec = DiagRecord::<f64>::default();
    assert_eq!(Diagnostics::from_record(&rec, 0.1).elements, 0);
}

#[test]
fn input_errors() {
    assert!(matches!("sgd".parse::<Optimiser>(), Err(OptimError::UnknownOptimiser(_))));
    assert_eq!("0,1".parse::<Range>().unwrap(), Range::new(0.0, 1.0).unwrap());
    assert!("1,0".parse::<Range>().is_err() && "x".parse::<Range>().is_err());
    let g = vec![vec![1.0f32; 3]; 2];
    assert!(matches!(replay_cpu::<f64>(&meta(), &g, None, &[0.0; 3], Range::UNBOUNDED, 0.1), Err(OptimError::MissingFd)));
    assert!(matches!(replay_cpu::<f64>(&adam(), &g, None, &[0.0; 2], Range::UNBOUNDED, 0.1), Err(OptimError::Length { .. })));
    let bad = Optimiser::Meta(MetaHyper { decay_f: 1.0, ..Default::default() });
    assert!(matches!(BufferOptimiser::<f64>::new(&bad, 1, 0.1, Range::UNBOUNDED), Err(OptimError::BadHyper(_))));
}

#[test]
fn bonferroni_significance_keeps_a_groups_false_steps_at_one_elements() {
    use super::bonferroni_sig;
    // Two-sided normal quantiles: P(|Z| > 1.959964) = 0.05; 0.05/10 at 2.807034, 0.05/1000
    // at 4.055627, 0.05/1e6 at 5.451310.
    let z05 = 1.959_963_985;
    for (k, z) in [(1usize, z05), (10, 2.807_033_768), (1000, 4.055_626_981), (1_000_000, 5.451_310_438)] {
        let got = bonferroni_sig(z05, k);
        assert!((got - z).abs() < 2e-6, "k = {k}: {got} against {z}");
    }
    // The values the option's docs quote for sig = 2.
    for (k, z) in [(3usize, 2.43), (64, 3.39), (3072, 4.33)] {
        assert!((bonferroni_sig(2.0, k) - z).abs() < 0.005, "k = {k}: {}", bonferroni_sig(2.0, k));
    }
    // No test stays no test; one element keeps sig; the level rises with k and stays finite
    // for the largest sig the spec accepts.
    assert_eq!(bonferroni_sig(0.0, 1000), 0.0);
    assert_eq!(bonferroni_sig(3.0, 1), 3.0);
    let big = bonferroni_sig(1e6, 1 << 30);
    assert!((1e6..1e6 + 1.0).contains(&big), "{big}");
    let mut last = 3.0;
    for k in [2usize, 5, 50, 500, 5000] {
        let z = bonferroni_sig(3.0, k);
        assert!(z > last, "k = {k}: {z} after {last}");
        last = z;
    }
    // The spec: one level per group through sig_for.
    let h = MetaHyper { sig: 2.0, ..MetaHyper::default() };
    assert_eq!(h.sig_for(1), 2.0);
    assert_eq!(h.sig_for(64), bonferroni_sig(2.0, 64));
}

/// [`HostOptimiser`] over two groups steps as the f64 replay of each group alone, up to
/// θ's float32 storage between steps, and checks its inputs' lengths.
#[test]
fn host_optimiser_steps_each_group_as_the_reference_replay() {
    let mut rng = Rng(11);
    let (steps, sizes) = (20, [3usize, 2]);
    let n: usize = sizes.iter().sum();
    let mut row = |scale: f64, shift: f64| (0..n).map(|_| (shift + scale * rng.normal()) as f32).collect::<Vec<f32>>();
    let grads: Vec<Vec<f32>> = (0..steps).map(|_| row(1.0, 0.5)).collect();
    let fd: Vec<Vec<f32>> = (0..steps).map(|_| row(0.1, 0.0)).collect();
    let init = vec![0.4f32; n];
    let range = Range::new(0.0, 1.0).unwrap();
    for spec in ["meta-seed", "meta@var=zero", "adam"] {
        let s: spec::Spec = spec.parse().unwrap();
        let groups: Vec<HostGroup> = sizes.iter().zip([0.05, 0.02]).map(|(&len, lr)| HostGroup { len, lr, range }).collect();
        let mut host = HostOptimiser::new(spec, &groups, None).unwrap();
        let mut theta = init.clone();
        for i in 0..steps {
            host.step(&mut theta, HostStep { grad: &grads[i], fd: Some(&fd[i]), ..Default::default() }).unwrap();
        }
        let mut offset = 0;
        for g in &groups {
            let part = |rows: &[Vec<f32>]| rows.iter().map(|r| r[offset..offset + g.len].to_vec()).collect::<Vec<_>>();
            let r = replay_cpu::<f64>(&s.optimiser, &part(&grads), Some(&part(&fd)), &init[offset..offset + g.len], range, g.lr).unwrap();
            for (a, b) in theta[offset..offset + g.len].iter().zip(r.theta.last().unwrap()) {
                assert!((*a as f64 - b).abs() < 1e-5, "{spec}: {a} vs {b}");
            }
            offset += g.len;
        }
        assert_eq!(host.diagnostics().len(), 2);
        assert!((theta[0] - init[0]).abs() > 0.05, "{spec}: the streams move θ");
    }
    let mut host = HostOptimiser::new("meta", &[HostGroup { len: 2, lr: 0.1, range }], None).unwrap();
    let err = host.step(&mut [0.0; 2], HostStep { grad: &[1.0; 2], fd: Some(&[0.0; 2]), ..Default::default() }).unwrap_err();
    assert!(matches!(err, OptimError::MissingHalves), "{err}");
    let err = host.step(&mut [0.0; 2], HostStep { grad: &[1.0; 3], ..Default::default() }).unwrap_err();
    assert!(matches!(err, OptimError::Length { what: "gradient", expected: 2, found: 3 }), "{err}");
    assert!(HostOptimiser::new("meta", &[HostGroup { len: 1, lr: 0.1, range: Range { lo: 1.0, hi: 0.0 } }], None).is_err());
}
