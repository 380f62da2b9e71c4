//! Literal f64 transcriptions, the oracles that [`super::reference`] is tested against:
//! the seed's `Moment2` and `Meta` classes (Bálint et al. 2023, supplementary B, with its
//! optimisation-loop snippet) and textbook Adam (Kingma & Ba 2015, Algorithm 1).
//!
//! The only departure from the seed: at ‖Δπ‖² = 0 (the first iteration, which has no previous
//! step) `Moment2.step(ΔF / sqrt(0))` is undefined, so there the ΔF Moment2 is not stepped and
//! ⟨ΔF⟩ is taken as 0. No guards against overflow or non-finite input: ordinary streams only.

use super::{Optimiser, Range};

/// Zero-centred, bias-corrected second-moment EMA; one count for the whole array.
pub struct Moment2 {
    decay: f64,
    count: i32,
    pub m2: Vec<f64>,
}

impl Moment2 {
    pub fn new(n: usize, decay: f64) -> Self {
        Moment2 { decay, count: 0, m2: vec![0.0; n] }
    }

    pub fn step(&mut self, x: &[f64]) {
        self.count += 1;
        let w = 1.0 - self.decay;
        let w_sum = 1.0 - self.decay.powi(self.count);
        for (m2, x) in self.m2.iter_mut().zip(x) {
            *m2 += (w / w_sum) * (x * x - *m2);
        }
    }
}

/// The meta-estimator: inverse-variance weighting with α clipping.
pub struct Meta {
    eta: f64,
    pub var: Vec<f64>,
    pub mean: Vec<f64>,
    pub alpha_prev: Vec<f64>,
}

impl Meta {
    pub fn new(n: usize, eta: f64) -> Self {
        Meta { eta, var: vec![0.0; n], mean: vec![0.0; n], alpha_prev: vec![f64::NEG_INFINITY; n] }
    }

    /// Returns the step, element by element.
    pub fn step(&mut self, f: &[f64], df: &[f64], var_f: &[f64], var_d: &[f64]) -> Vec<f64> {
        (0..f.len())
            .map(|i| {
                self.mean[i] += df[i];
                self.var[i] += var_d[i];
                let alpha = var_f[i] / (var_f[i] + self.var[i] + 1e-30);
                let alpha = alpha.min(1.0 / (2.0 - self.alpha_prev[i]));
                self.alpha_prev[i] = alpha;
                self.mean[i] = alpha * self.mean[i] + (1.0 - alpha) * f[i];
                self.var[i] = alpha.powi(2) * self.var[i] + (1.0 - alpha).powi(2) * var_f[i];
                -self.eta * self.mean[i] / (self.var[i].sqrt() + 1e-8)
            })
            .collect()
    }
}

/// Textbook Adam with uncorrected moments and bias correction at use.
pub struct Adam {
    lr: f64,
    beta1: f64,
    beta2: f64,
    eps: f64,
    t: i32,
    m: Vec<f64>,
    v: Vec<f64>,
}

impl Adam {
    pub fn new(n: usize, lr: f64, beta1: f64, beta2: f64, eps: f64) -> Self {
        Adam { lr, beta1, beta2, eps, t: 0, m: vec![0.0; n], v: vec![0.0; n] }
    }

    pub fn step(&mut self, g: &[f64]) -> Vec<f64> {
        self.t += 1;
        let (c1, c2) = (1.0 - self.beta1.powi(self.t), 1.0 - self.beta2.powi(self.t));
        (0..g.len())
            .map(|i| {
                self.m[i] = self.beta1 * self.m[i] + (1.0 - self.beta1) * g[i];
                self.v[i] = self.beta2 * self.v[i] + (1.0 - self.beta2) * g[i] * g[i];
                -self.lr * (self.m[i] / c1) / ((self.v[i] / c2).sqrt() + self.eps)
            })
            .collect()
    }
}

/// The seed's optimisation loop over recorded streams; returns the trajectory
/// (iterations + 1) × n. Meta's ‖Δπ‖² is that of the previous clamped step; without a
/// finite-difference row the ΔF terms are skipped as at ‖Δπ‖² = 0.
pub fn replay_literal(optimiser: &Optimiser, grads: &[Vec<f64>], fd_grads: Option<&[Vec<f64>]>, init: &[f64], range: Range, lr: f64) -> Vec<Vec<f64>> {
    let n = init.len();
    let mut theta = init.to_vec();
    let mut traj = vec![theta.clone()];
    let clamp = |x: f64| x.max(range.lo).min(range.hi);
    match *optimiser {
        Optimiser::Adam(h) => {
            let mut adam = Adam::new(n, lr, h.beta1, h.beta2, h.eps);
            for g in grads {
                let step = adam.step(g);
                theta.iter_mut().zip(&step).for_each(|(th, s)| *th = clamp(*th + s));
                traj.push(theta.clone());
            }
        }
        Optimiser::Meta(h) => {
            let (mut m2f, mut m2d, mut meta) = (Moment2::new(n, h.decay_f), Moment2::new(n, h.decay_d), Meta::new(n, lr));
            let mut dpi2 = 0.0f64;
            for (i, f) in grads.iter().enumerate() {
                m2f.step(f);
                let fd = fd_grads.and_then(|fd| fd.get(i));
                let (df, var_d) = if let (Some(fd), true) = (fd, dpi2 > 0.0) {
                    let scaled: Vec<f64> = fd.iter().map(|d| d / dpi2.sqrt()).collect();
                    m2d.step(&scaled);
                    (fd.clone(), m2d.m2.iter().map(|m| m * dpi2).collect())
                } else {
                    (vec![0.0; n], vec![0.0; n])
                };
                let step = meta.step(f, &df, &m2f.m2, &var_d);
                let prev = theta.clone();
                theta.iter_mut().zip(&step).for_each(|(th, s)| *th = clamp(*th + s));
                dpi2 = theta.iter().zip(&prev).map(|(a, b)| (a - b) * (a - b)).sum();
                traj.push(theta.clone());
            }
        }
    }
    traj
}
