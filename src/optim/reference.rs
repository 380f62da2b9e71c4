//! The float32-safe optimiser element updates, mirrored line for line by
//! `glsl/lib/optim.glsl`. Generic over [`Real`]: f64 is the reference the GPU is checked
//! against; f32 reproduces the GPU's arithmetic so that the float32-safety claims of the
//! module docs are tested on the CPU.
//!
//! Invariants per element, for any finite inputs: θ stays finite and inside its range; state
//! values are finite and non-negative where they are RMS / standard deviations / weights;
//! `sd == 0` implies `mean == 0`; `n_eff` ≤ the number of steps the element has taken.

use super::{AdamHyper, MetaHyper, OptimError, Optimiser, Range, ALPHA_REG};
use std::fmt::Debug;
use std::ops::{Add, Div, Mul, Neg, Sub};

/// The floating-point types the reference runs in.
pub trait Real:
    Copy
    + Debug
    + Default
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    const ZERO: Self;
    const ONE: Self;
    /// The largest finite value: where overflowing results saturate.
    const MAX: Self;
    fn of(x: f64) -> Self;
    fn to_f64(self) -> f64;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    fn is_finite(self) -> bool;
    fn min(self, other: Self) -> Self;
    fn max(self, other: Self) -> Self;
}

macro_rules! impl_real {
    ($t:ty) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const MAX: Self = <$t>::MAX;
            fn of(x: f64) -> Self {
                x as $t
            }
            fn to_f64(self) -> f64 {
                self as f64
            }
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            fn min(self, other: Self) -> Self {
                <$t>::min(self, other)
            }
            fn max(self, other: Self) -> Self {
                <$t>::max(self, other)
            }
        }
    };
}
impl_real!(f32);
impl_real!(f64);

/// Clamps ±infinity (an overflowed product) to ±MAX. Never sees NaN.
pub fn sat<R: Real>(x: R) -> R {
    x.max(-R::MAX).min(R::MAX)
}

/// √(x² + y²) without forming the squares, so no overflow or underflow in between.
pub fn hypot<R: Real>(x: R, y: R) -> R {
    let (x, y) = (x.abs(), y.abs());
    let big = x.max(y);
    if big == R::ZERO {
        return R::ZERO;
    }
    let small = x.min(y) / big;
    sat(big * (R::ONE + small * small).sqrt())
}

/// 1 − (1 − q)^t by binary powering in the form 1 − d: (1−a)(1−b) = 1 − (a + b(1−a)) has only
/// non-negative terms, so no cancellation, unlike `1 - pow(1 - q, t)`.
pub fn one_minus_pow<R: Real>(q: R, mut t: u32) -> R {
    let mut d = R::ZERO;
    let mut e = q;
    while t != 0 {
        if t & 1 != 0 {
            d = d + e * (R::ONE - d);
        }
        e = e + e * (R::ONE - e);
        t >>= 1;
    }
    d
}

/// Weight of the t-th sample (t ≥ 1) in a bias-corrected EMA of decay β: the seed Moment2's
/// w / w_sum = (1−β)/(1−β^t). The first sample gets weight 1.
pub fn ema_weight<R: Real>(beta: R, t: u32) -> R {
    let q = R::ONE - beta;
    q / one_minus_pow(q, t.max(1))
}

/// Inverse-variance weight s_a²/(s_a² + s_b²) from standard deviations, scaled by the larger
/// so that neither square overflows. Needs s_a > 0 or s_b > 0.
fn inverse_variance_weight<R: Real>(s_a: R, s_b: R) -> R {
    let big = s_a.max(s_b);
    let a = s_a / big;
    let b = s_b / big;
    a * a / (a * a + b * b)
}

/// Adam's per-element state: the bias-corrected first moment m̂ and the bias-corrected RMS √v̂.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdamElem<R> {
    pub m: R,
    pub r: R,
}

/// Adam's per-step parameters (the push constants of `optim_adam.comp`). `t` counts from 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamParams<R> {
    pub t: u32,
    pub lr: R,
    pub beta1: R,
    pub beta2: R,
    pub eps: R,
    pub lo: R,
    pub hi: R,
}

impl<R: Real> AdamParams<R> {
    pub fn new(h: &AdamHyper, t: u32, lr: f64, range: Range) -> Self {
        AdamParams {
            t,
            lr: R::of(lr),
            beta1: R::of(h.beta1),
            beta2: R::of(h.beta2),
            eps: R::of(h.eps),
            lo: R::of(range.lo),
            hi: R::of(range.hi),
        }
    }
}

/// One Adam step of one element: returns (θ', state') or `None` for a non-finite gradient,
/// in which case θ and the state stay as they are.
pub fn adam_update<R: Real>(
    p: &AdamParams<R>,
    theta: R,
    g: R,
    s: AdamElem<R>,
) -> Option<(R, AdamElem<R>)> {
    if !g.is_finite() {
        return None;
    }
    let k1 = ema_weight(p.beta1, p.t);
    let k2 = ema_weight(p.beta2, p.t);
    let m = (R::ONE - k1) * s.m + k1 * g;
    let r = hypot((R::ONE - k2).sqrt() * s.r, k2.sqrt() * g);
    let step = sat(-p.lr * (m / (r + p.eps)));
    let theta = sat(theta + step).max(p.lo).min(p.hi);
    Some((theta, AdamElem { m, r }))
}

/// The meta-estimator's per-element state, all zero initially.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MetaElem<R> {
    /// The meta-estimate ⟨F_i⟩_M.
    pub mean: R,
    /// √Var[⟨F_i⟩_M].
    pub sd: R,
    /// √(Moment2 of ⟨F⟩), bias-corrected with the global count t.
    pub rms_f: R,
    /// √(Moment2 of ⟨ΔF⟩/‖Δπ‖), bias-corrected with `wsum_d`.
    pub rms_d: R,
    /// 1 − decay_d^count: the bias-correction sum of the ΔF Moment2's own samples.
    pub wsum_d: R,
    /// 1/(1 − α_prev): the effective number of samples averaged so far. The seed's clip
    /// α ≤ 1/(2 − α_prev) reads 1 − α ≥ 1/(1 + n_eff); n_eff = 0 is α_prev = −∞.
    pub n_eff: R,
}

/// Meta's per-step parameters (the push constants of `optim_meta.comp`). `t` counts from 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetaParams<R> {
    pub t: u32,
    pub lr: R,
    pub decay_f: R,
    pub decay_d: R,
    pub eps: R,
    pub lo: R,
    pub hi: R,
}

impl<R: Real> MetaParams<R> {
    pub fn new(h: &MetaHyper, t: u32, lr: f64, range: Range) -> Self {
        MetaParams {
            t,
            lr: R::of(lr),
            decay_f: R::of(h.decay_f),
            decay_d: R::of(h.decay_d),
            eps: R::of(h.eps),
            lo: R::of(range.lo),
            hi: R::of(range.hi),
        }
    }
}

/// One meta-estimator step of one element (supplementary B, Moment2 + Meta), given the
/// proportional gradient `f`, the finite-difference sample `df` and the buffer's ‖Δπ‖²
/// `dpi2` of the previous step. Returns (θ', state') or `None` for a non-finite `f` or `df`,
/// in which case θ and the state stay as they are.
pub fn meta_update<R: Real>(
    p: &MetaParams<R>,
    theta: R,
    f: R,
    df: R,
    dpi2: R,
    s: MetaElem<R>,
) -> Option<(R, MetaElem<R>)> {
    if !f.is_finite() || !df.is_finite() {
        return None;
    }
    let one = R::ONE;
    let kf = ema_weight(p.decay_f, p.t);
    let rms_f = hypot((one - kf).sqrt() * s.rms_f, kf.sqrt() * f);

    // ΔF terms: VD = Moment2(ΔF/‖Δπ‖)·‖Δπ‖², kept as the standard deviation sd_d.
    let (df, sd_d, rms_d, wsum_d) = if dpi2 > R::ZERO && dpi2.is_finite() {
        let step_len = dpi2.sqrt();
        let q = one - p.decay_d;
        let wsum_d = q + p.decay_d * s.wsum_d;
        let kd = q / wsum_d;
        let sd_d = hypot((one - kd).sqrt() * sat(s.rms_d * step_len), kd.sqrt() * df);
        (df, sd_d, sat(sd_d / step_len), wsum_d)
    } else {
        (R::ZERO, R::ZERO, s.rms_d, s.wsum_d)
    };

    // mean += ΔF; var += VD; α by inverse-variance weighting, clipped to perfect averaging.
    // Written with the gain g = 1 − α (the weight of the fresh sample), which f32 keeps
    // accurate as α → 1, and the update h + g·(F − h) on halves, which cannot overflow.
    let sd_pred = hypot(s.sd, sd_d);
    let reg = hypot(sd_pred, R::of(ALPHA_REG.sqrt()));
    let gain = inverse_variance_weight(reg, rms_f).max(one / (one + s.n_eff));
    let pred = sat(s.mean + df);
    let half_diff = R::of(0.5) * f - R::of(0.5) * pred;
    let mean = sat(pred + gain * half_diff + gain * half_diff);
    let sd = hypot((one - gain) * sd_pred, gain * rms_f);

    let step = sat(-p.lr * (mean / (sd + p.eps)));
    let theta = sat(theta + step).max(p.lo).min(p.hi);
    Some((
        theta,
        MetaElem {
            mean,
            sd,
            rms_f,
            rms_d,
            wsum_d,
            n_eff: one / gain,
        },
    ))
}

/// Hyperparameters and per-element state of one parameter buffer.
#[derive(Clone, Debug)]
enum Elems<R> {
    Adam(AdamHyper, Vec<AdamElem<R>>),
    Meta(MetaHyper, Vec<MetaElem<R>>),
}

/// The CPU twin of one parameter buffer's fused optimiser pass: per-element state, the
/// iteration count t and Meta's ‖Δπ‖² of the last step. θ_prev is not kept here: it belongs
/// to whoever produces the finite-difference samples.
#[derive(Clone, Debug)]
pub struct BufferOptimiser<R> {
    elems: Elems<R>,
    lr: f64,
    range: Range,
    t: u32,
    dpi2: R,
    nonfinite: u64,
}

impl<R: Real> BufferOptimiser<R> {
    pub fn new(optimiser: &Optimiser, n: usize, lr: f64, range: Range) -> Result<Self, OptimError> {
        optimiser.validate()?;
        if !(lr >= 0.0 && lr.is_finite()) {
            return Err(OptimError::BadHyper(format!(
                "lr = {lr} must be non-negative and finite"
            )));
        }
        let elems = match *optimiser {
            Optimiser::Adam(h) => Elems::Adam(h, vec![AdamElem::default(); n]),
            Optimiser::Meta(h) => Elems::Meta(h, vec![MetaElem::default(); n]),
        };
        Ok(BufferOptimiser {
            elems,
            lr,
            range,
            t: 0,
            dpi2: R::ZERO,
            nonfinite: 0,
        })
    }

    /// One step over the buffer, in place. `fd` is required by Meta and ignored by Adam.
    /// Returns the number of elements skipped for non-finite inputs.
    pub fn step(
        &mut self,
        theta: &mut [R],
        grad: &[R],
        fd: Option<&[R]>,
    ) -> Result<u64, OptimError> {
        let n = self.len();
        check_len("theta", n, theta.len())?;
        check_len("gradient", n, grad.len())?;
        let t = self.t + 1;
        let mut skipped = 0;
        match &mut self.elems {
            Elems::Adam(h, state) => {
                let p = AdamParams::new(h, t, self.lr, self.range);
                for ((th, &g), s) in theta.iter_mut().zip(grad).zip(state.iter_mut()) {
                    match adam_update(&p, *th, g, *s) {
                        Some((t2, s2)) => (*th, *s) = (t2, s2),
                        None => skipped += 1,
                    }
                }
            }
            Elems::Meta(h, state) => {
                let fd = fd.ok_or(OptimError::MissingFd)?;
                check_len("finite-difference gradient", n, fd.len())?;
                let p = MetaParams::new(h, t, self.lr, self.range);
                let mut dpi2 = R::ZERO;
                for (((th, &f), &df), s) in theta.iter_mut().zip(grad).zip(fd).zip(state.iter_mut())
                {
                    match meta_update(&p, *th, f, df, self.dpi2, *s) {
                        Some((t2, s2)) => {
                            let d = t2 - *th;
                            dpi2 = dpi2 + d * d;
                            (*th, *s) = (t2, s2);
                        }
                        None => skipped += 1,
                    }
                }
                self.dpi2 = dpi2;
            }
        }
        self.t = t;
        self.nonfinite += skipped;
        Ok(skipped)
    }

    pub fn len(&self) -> usize {
        match &self.elems {
            Elems::Adam(_, s) => s.len(),
            Elems::Meta(_, s) => s.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Steps taken so far (the t of the last step).
    pub fn iteration(&self) -> u32 {
        self.t
    }

    /// ‖Δπ‖² of the last step (Meta; 0 for Adam).
    pub fn dpi2(&self) -> R {
        self.dpi2
    }

    /// Elements skipped for non-finite inputs, over all steps.
    pub fn nonfinite(&self) -> u64 {
        self.nonfinite
    }

    pub fn adam_state(&self) -> Option<&[AdamElem<R>]> {
        match &self.elems {
            Elems::Adam(_, s) => Some(s),
            Elems::Meta(..) => None,
        }
    }

    pub fn meta_state(&self) -> Option<&[MetaElem<R>]> {
        match &self.elems {
            Elems::Meta(_, s) => Some(s),
            Elems::Adam(..) => None,
        }
    }
}

fn check_len(what: &'static str, expected: usize, found: usize) -> Result<(), OptimError> {
    if expected == found {
        Ok(())
    } else {
        Err(OptimError::Length {
            what,
            expected,
            found,
        })
    }
}
