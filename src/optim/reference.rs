//! The float32-safe optimiser element updates, mirrored line for line by
//! `glsl/lib/optim.glsl`. Generic over [`Real`]: f64 is the reference the GPU is checked
//! against; f32 reproduces the GPU's arithmetic so that the float32-safety claims of the
//! module docs are tested on the CPU.
//!
//! Invariants per element, for any finite inputs: θ stays finite and inside its range; state
//! values are finite and non-negative where they are RMS / standard deviations / weights;
//! `sd == 0` implies `mean == 0`; `n_eff` ≤ the number of steps the element has taken.
//!
//! Every step also yields per-element diagnostics ([`ElemDiag`]), reduced per parameter
//! group into a [`DiagRecord`] exactly as the GPU pass reduces them (sums, minima, maxima,
//! and sums of squares kept as a scale and a scaled sum, [`Ssq`], so that they cannot
//! overflow); the meta-estimator's ‖Δπ‖² is the record's sum of squared steps.

use super::{AdamHyper, MetaHyper, OptimError, Optimiser, Range, StepRule, VarianceEstimate, ALPHA_REG, META_BETA2};
use std::fmt::Debug;
use std::ops::{Add, Div, Mul, Neg, Sub};

/// The floating-point types the reference runs in.
pub trait Real:
    Copy + Debug + Default + PartialOrd + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> + Neg<Output = Self>
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
    fn powf(self, e: Self) -> Self;
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
            fn powf(self, e: Self) -> Self {
                <$t>::powf(self, e)
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

/// An RMS EMA's weights at step t, uniform over a pass: the step's weight
/// k = [`ema_weight`]`(β, t)` as the factors of hypot(keep·rms, take·x).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ema<R> {
    /// √(1 − k).
    pub keep: R,
    /// √k.
    pub take: R,
}

impl<R: Real> Ema<R> {
    pub fn of(beta: R, t: u32) -> Self {
        let k = ema_weight(beta, t);
        Ema { keep: (R::ONE - k).sqrt(), take: k.sqrt() }
    }
}

/// Inverse-variance weight s_a²/(s_a² + s_b²) from standard deviations, scaled by the larger
/// so that neither square overflows. Needs s_a > 0 or s_b > 0.
fn inverse_variance_weight<R: Real>(s_a: R, s_b: R) -> R {
    let big = s_a.max(s_b);
    let a = s_a / big;
    let b = s_b / big;
    a * a / (a * a + b * b)
}

/// The centred variance sample of an estimate from its total `x` (all samples) and `half`
/// (the sum of half of them, weighted as in the total): with halves A = 2·half and
/// B = 2·(x − half), (A − B)/2 = x − 2·half, whose square is an unbiased sample of Var[x]
/// when the halves are independent and identically distributed. Saturates.
pub fn centred_sample<R: Real>(x: R, half: R) -> R {
    sat(R::of(2.0) * sat(R::of(0.5) * x - half))
}

/// A sum of squares kept as `scale`·√`sum` = its root (the largest magnitude and the sum of
/// the squares divided by its square), so that values near 1e30 do not overflow and values
/// near 1e-30 do not vanish. Mirrored by `Ssq` in glsl/shared/optim.glsl.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ssq<R> {
    pub scale: R,
    pub sum: R,
}

impl<R: Real> Ssq<R> {
    pub fn of(x: R) -> Self {
        let a = x.abs();
        if a == R::ZERO {
            Ssq::default()
        } else {
            Ssq { scale: a, sum: R::ONE }
        }
    }

    pub fn merge(self, o: Self) -> Self {
        let m = self.scale.max(o.scale);
        if m == R::ZERO {
            return Ssq::default();
        }
        let (a, b) = (self.scale / m, o.scale / m);
        Ssq { scale: m, sum: self.sum * (a * a) + o.sum * (b * b) }
    }

    /// The sum of squares (saturating).
    pub fn total(self) -> R {
        sat(self.scale * self.scale * self.sum)
    }

    /// Its square root, the L2 norm.
    pub fn norm(self) -> R {
        sat(self.scale * self.sum.sqrt())
    }
}

/// One element's contribution to its group's diagnostics.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ElemDiag<R> {
    /// 1/(1 − α) after the step (Meta; 0 for Adam).
    pub n_eff: R,
    /// Whether α was limited by the clip α ≤ 1/(2 − α_prev) (Meta).
    pub clipped: bool,
    /// Whether the step was Newton's (Meta, `step = newton`).
    pub newton: bool,
    /// ⟨F⟩ (the proportional gradient).
    pub f: R,
    /// ⟨ΔF⟩ as used: 0 when the ΔF terms were skipped (Meta).
    pub df: R,
    /// √Var[⟨ΔF⟩], the FD term's standard deviation (Meta).
    pub sd_d: R,
    /// The step taken (after clamping to the range).
    pub step: R,
    /// ⟨F⟩_M (Meta) or Adam's first moment m̂.
    pub mean: R,
    /// √Var[⟨F⟩_M] (Meta).
    pub sd: R,
    /// √Var[⟨F⟩] (Meta's Moment2) or Adam's √v̂.
    pub sd_f: R,
    /// The secant curvature of `step = newton` (Meta, kept for every rule).
    pub curv: R,
}

/// A parameter group's diagnostics as the GPU reduces them (`DiagRecord` in
/// glsl/shared/optim.glsl): counts and sums, the n_eff range, sums of squares.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiagRecord<R> {
    /// Elements that stepped (not skipped for non-finite input).
    pub count: R,
    pub n_eff_sum: R,
    pub n_eff_min: R,
    pub n_eff_max: R,
    pub clipped: R,
    pub newton: R,
    pub f: Ssq<R>,
    pub df: Ssq<R>,
    pub sd_d: Ssq<R>,
    pub step: Ssq<R>,
    pub mean: Ssq<R>,
    pub sd: Ssq<R>,
    pub sd_f: Ssq<R>,
    pub curv: Ssq<R>,
}

impl<R: Real> Default for DiagRecord<R> {
    /// The empty record, the identity of [`DiagRecord::merge`].
    fn default() -> Self {
        DiagRecord {
            count: R::ZERO,
            n_eff_sum: R::ZERO,
            n_eff_min: R::MAX,
            n_eff_max: R::ZERO,
            clipped: R::ZERO,
            newton: R::ZERO,
            f: Ssq::default(),
            df: Ssq::default(),
            sd_d: Ssq::default(),
            step: Ssq::default(),
            mean: Ssq::default(),
            sd: Ssq::default(),
            sd_f: Ssq::default(),
            curv: Ssq::default(),
        }
    }
}

impl<R: Real> DiagRecord<R> {
    pub fn of(e: &ElemDiag<R>) -> Self {
        DiagRecord {
            count: R::ONE,
            n_eff_sum: e.n_eff,
            n_eff_min: e.n_eff,
            n_eff_max: e.n_eff,
            clipped: if e.clipped { R::ONE } else { R::ZERO },
            newton: if e.newton { R::ONE } else { R::ZERO },
            f: Ssq::of(e.f),
            df: Ssq::of(e.df),
            sd_d: Ssq::of(e.sd_d),
            step: Ssq::of(e.step),
            mean: Ssq::of(e.mean),
            sd: Ssq::of(e.sd),
            sd_f: Ssq::of(e.sd_f),
            curv: Ssq::of(e.curv),
        }
    }

    pub fn merge(self, o: Self) -> Self {
        DiagRecord {
            count: self.count + o.count,
            n_eff_sum: sat(self.n_eff_sum + o.n_eff_sum),
            n_eff_min: self.n_eff_min.min(o.n_eff_min),
            n_eff_max: self.n_eff_max.max(o.n_eff_max),
            clipped: self.clipped + o.clipped,
            newton: self.newton + o.newton,
            f: self.f.merge(o.f),
            df: self.df.merge(o.df),
            sd_d: self.sd_d.merge(o.sd_d),
            step: self.step.merge(o.step),
            mean: self.mean.merge(o.mean),
            sd: self.sd.merge(o.sd),
            sd_f: self.sd_f.merge(o.sd_f),
            curv: self.curv.merge(o.curv),
        }
    }
}

/// One step's diagnostics of one parameter group, as `optimiser.csv` reports them.
/// RMS values are over the elements that stepped.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Diagnostics {
    /// The learning rate of the step (the schedule applied).
    pub lr: f64,
    /// Elements that stepped.
    pub elements: u64,
    /// The meta-estimator's effective number of averaged samples, 1/(1 − α) (0 for Adam).
    pub n_eff_mean: f64,
    pub n_eff_min: f64,
    pub n_eff_max: f64,
    /// Fraction of elements whose α the clip α ≤ 1/(2 − α_prev) limited.
    pub clipped: f64,
    /// Fraction of elements that took Newton's step (`step = newton`).
    pub newton: f64,
    /// RMS of ⟨F⟩.
    pub rms_f: f64,
    /// RMS of ⟨ΔF⟩.
    pub rms_df: f64,
    /// RMS of the FD term's standard deviation √Var[⟨ΔF⟩].
    pub sd_fd: f64,
    /// RMS of the estimate the step uses (⟨F⟩_M, Adam's m̂).
    pub rms_mean: f64,
    /// RMS of √Var[⟨F⟩_M].
    pub sd_mean: f64,
    /// RMS of √Var[⟨F⟩] (Adam: √v̂).
    pub sd_f: f64,
    /// ‖Δπ‖ of the step.
    pub step_norm: f64,
    /// RMS of the step.
    pub rms_step: f64,
    /// RMS of the secant curvature (Meta).
    pub rms_curv: f64,
}

impl Diagnostics {
    /// The column names of a diagnostics row (`optimiser.csv`), in order.
    pub const COLUMNS: [&'static str; 16] = [
        "lr",
        "elements",
        "n_eff_mean",
        "n_eff_min",
        "n_eff_max",
        "clipped",
        "rms_f",
        "rms_df",
        "sd_fd",
        "rms_mean",
        "sd_mean",
        "sd_f",
        "step_norm",
        "rms_step",
        "newton",
        "rms_curv",
    ];

    pub fn from_record<R: Real>(r: &DiagRecord<R>, lr: f64) -> Self {
        let count = r.count.to_f64();
        let rms = |s: Ssq<R>| if count > 0.0 { s.norm().to_f64() / count.sqrt() } else { 0.0 };
        let per = |x: R| if count > 0.0 { x.to_f64() / count } else { 0.0 };
        Diagnostics {
            lr,
            elements: count as u64,
            n_eff_mean: per(r.n_eff_sum),
            n_eff_min: if count > 0.0 { r.n_eff_min.to_f64() } else { 0.0 },
            n_eff_max: r.n_eff_max.to_f64(),
            clipped: per(r.clipped),
            rms_f: rms(r.f),
            rms_df: rms(r.df),
            sd_fd: rms(r.sd_d),
            rms_mean: rms(r.mean),
            sd_mean: rms(r.sd),
            sd_f: rms(r.sd_f),
            step_norm: r.step.norm().to_f64(),
            rms_step: rms(r.step),
            newton: per(r.newton),
            rms_curv: rms(r.curv),
        }
    }

    /// The diagnostics from values in the order of [`Diagnostics::COLUMNS`].
    pub fn from_values(v: &[f64; Self::COLUMNS.len()]) -> Self {
        Diagnostics {
            lr: v[0],
            elements: v[1] as u64,
            n_eff_mean: v[2],
            n_eff_min: v[3],
            n_eff_max: v[4],
            clipped: v[5],
            rms_f: v[6],
            rms_df: v[7],
            sd_fd: v[8],
            rms_mean: v[9],
            sd_mean: v[10],
            sd_f: v[11],
            step_norm: v[12],
            rms_step: v[13],
            newton: v[14],
            rms_curv: v[15],
        }
    }

    /// The values in the order of [`Diagnostics::COLUMNS`].
    pub fn values(&self) -> [f64; Self::COLUMNS.len()] {
        [
            self.lr,
            self.elements as f64,
            self.n_eff_mean,
            self.n_eff_min,
            self.n_eff_max,
            self.clipped,
            self.rms_f,
            self.rms_df,
            self.sd_fd,
            self.rms_mean,
            self.sd_mean,
            self.sd_f,
            self.step_norm,
            self.rms_step,
            self.newton,
            self.rms_curv,
        ]
    }
}

/// Adam's per-element state: the bias-corrected first moment m̂ and the bias-corrected RMS √v̂.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdamElem<R> {
    pub m: R,
    pub r: R,
}

/// Adam's per-step parameters (the push constants of `optim_adam.comp`). `t` counts from 1;
/// `lr` is the scheduled rate of step t.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamParams<R> {
    /// The first moment's weight of step t, [`ema_weight`]`(β1, t)`.
    pub k1: R,
    /// The RMS's weights of step t (β2).
    pub r: Ema<R>,
    pub lr: R,
    pub eps: R,
    pub lo: R,
    pub hi: R,
}

impl<R: Real> AdamParams<R> {
    pub fn new(h: &AdamHyper, t: u32, lr: f64, range: Range) -> Self {
        AdamParams {
            k1: ema_weight(R::of(h.beta1), t),
            r: Ema::of(R::of(h.beta2), t),
            lr: R::of(lr * h.schedule.factor(t)),
            eps: R::of(h.eps),
            lo: R::of(range.lo),
            hi: R::of(range.hi),
        }
    }
}

/// One Adam step of one element: returns (θ', state', diagnostics) or `None` for a
/// non-finite gradient, in which case θ and the state stay as they are.
pub fn adam_update<R: Real>(p: &AdamParams<R>, theta: R, g: R, s: AdamElem<R>) -> Option<(R, AdamElem<R>, ElemDiag<R>)> {
    if !g.is_finite() {
        return None;
    }
    let m = (R::ONE - p.k1) * s.m + p.k1 * g;
    let r = hypot(p.r.keep * s.r, p.r.take * g);
    let step = sat(-p.lr * (m / (r + p.eps)));
    let next = sat(theta + step).max(p.lo).min(p.hi);
    let diag = ElemDiag { f: g, step: next - theta, mean: m, sd_f: r, ..Default::default() };
    Some((next, AdamElem { m, r }, diag))
}

/// The meta-estimator's per-element state, all zero initially.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MetaElem<R> {
    /// The meta-estimate ⟨F_i⟩_M.
    pub mean: R,
    /// √Var[⟨F_i⟩_M].
    pub sd: R,
    /// √(Moment2 of ⟨F⟩, or of its centred samples), bias-corrected with the global count t.
    pub rms_f: R,
    /// √(Moment2 of ⟨ΔF⟩/‖Δπ‖ (of ⟨ΔF⟩ with `fd_raw`), or of its centred samples),
    /// bias-corrected with `wsum_d`.
    pub rms_d: R,
    /// 1 − decay_d^count: the bias-correction sum of the ΔF Moment2's own samples.
    pub wsum_d: R,
    /// 1/(1 − α_prev): the effective number of samples averaged so far. The seed's clip
    /// α ≤ 1/(2 − α_prev) reads 1 − α ≥ 1/(1 + n_eff); n_eff = 0 is α_prev = −∞.
    pub n_eff: R,
    /// The bias-corrected √v̂ of ⟨F⟩ ([`META_BETA2`]), the normaliser of the Wiener step.
    pub v: R,
    /// The secant curvature of `step = newton`: √(Σ w·(ΔF/Δθ)²/Σ w) over the element's
    /// steps, w = Δθ², each earlier weight forgotten by `decay_h` per new secant.
    pub curv: R,
    /// √Σ w of that fit.
    pub curv_w: R,
    /// The element's last step θ_i − θ_{i−1}, the Δθ of the next ⟨ΔF⟩ (0 after a skip).
    pub last: R,
}

/// Meta's per-step parameters (the push constants of `optim_meta.comp`). `t` counts from 1;
/// `lr` is the scheduled rate of step t.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetaParams<R> {
    /// The weights of step t of ⟨F⟩'s Moment2 (decay_f).
    pub f: Ema<R>,
    /// The weights of step t of the Wiener step's normaliser √v̂ ([`META_BETA2`]).
    pub v: Ema<R>,
    pub lr: R,
    pub decay_d: R,
    pub eps: R,
    pub lo: R,
    pub hi: R,
    pub step: StepRule,
    pub centred: bool,
    /// Moment2 of ⟨ΔF⟩ itself rather than of ⟨ΔF⟩/‖Δπ‖ ([`super::FdVariance::Raw`]).
    pub fd_raw: bool,
    /// `step = newton`: the square root of the curvature fit's forgetting, the significance
    /// and the settle fraction.
    pub keep_h: R,
    pub sig: R,
    pub settle: R,
}

impl<R: Real> MetaParams<R> {
    /// The parameters of step `t` of a group of `k` elements (its size sets the
    /// significance, [`MetaHyper::sig_for`]).
    pub fn new(h: &MetaHyper, k: usize, t: u32, lr: f64, range: Range) -> Self {
        MetaParams {
            f: Ema::of(R::of(h.decay_f), t),
            v: Ema::of(R::of(META_BETA2), t),
            lr: R::of(lr * h.schedule.factor(t)),
            decay_d: R::of(h.decay_d),
            eps: R::of(h.eps),
            lo: R::of(range.lo),
            hi: R::of(range.hi),
            step: h.step,
            centred: h.variance == VarianceEstimate::Centred,
            fd_raw: h.fdvar == super::FdVariance::Raw,
            keep_h: R::of(h.decay_h).sqrt(),
            sig: R::of(h.sig_for(k)),
            settle: R::of(h.settle),
        }
    }
}

/// One element's inputs to a meta step: the proportional gradient ⟨F⟩, the finite-difference
/// sample ⟨ΔF⟩ and, for the centred variance estimate, the sums of half of their samples.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MetaInput<R> {
    pub f: R,
    pub df: R,
    pub f_half: R,
    pub df_half: R,
}

/// One meta-estimator step of one element (supplementary B, Moment2 + Meta, with the step
/// rule, variance estimate and ⟨ΔF⟩ variance model of `p`), given the buffer's ‖Δπ‖² `dpi2` of the
/// previous step. Returns (θ', state', diagnostics) or `None` for a non-finite input, in
/// which case θ and the state stay as they are.
///
/// Not split: it mirrors glsl/optim_meta.comp statement by statement, so that the two can
/// be read side by side; the GPU pass is checked against it element by element.
pub fn meta_update<R: Real>(p: &MetaParams<R>, theta: R, x: MetaInput<R>, dpi2: R, s: MetaElem<R>) -> Option<(R, MetaElem<R>, ElemDiag<R>)> {
    let (f, df) = (x.f, x.df);
    if !f.is_finite() || !df.is_finite() || (p.centred && !(x.f_half.is_finite() && x.df_half.is_finite())) {
        return None;
    }
    let one = R::ONE;
    // What the two Moment2 EMAs average the squares of.
    let (sample_f, sample_d) = if p.centred { (centred_sample(f, x.f_half), centred_sample(df, x.df_half)) } else { (f, df) };
    let rms_f = hypot(p.f.keep * s.rms_f, p.f.take * sample_f);
    let v = hypot(p.v.keep * s.v, p.v.take * f);

    // ΔF terms: VD = Moment2(ΔF/‖Δπ‖)·‖Δπ‖² (or Moment2(ΔF) with fd_raw), kept as the
    // standard deviation sd_d.
    let (df, sd_d, rms_d, wsum_d) = if dpi2 > R::ZERO && dpi2.is_finite() {
        let step_len = if p.fd_raw { one } else { dpi2.sqrt() };
        let q = one - p.decay_d;
        let wsum_d = q + p.decay_d * s.wsum_d;
        let kd = q / wsum_d;
        let sd_d = hypot((one - kd).sqrt() * sat(s.rms_d * step_len), kd.sqrt() * sample_d);
        (df, sd_d, sat(sd_d / step_len), wsum_d)
    } else {
        (R::ZERO, R::ZERO, s.rms_d, s.wsum_d)
    };

    // mean += ΔF; var += VD; α by inverse-variance weighting, clipped to perfect averaging.
    // Written with the gain g = 1 − α (the weight of the fresh sample), which f32 keeps
    // accurate as α → 1, and the update h + g·(F − h) on halves, which cannot overflow.
    let sd_pred = hypot(s.sd, sd_d);
    let reg = hypot(sd_pred, R::of(ALPHA_REG.sqrt()));
    let bound = one / (one + s.n_eff);
    let weighted = inverse_variance_weight(reg, rms_f);
    let gain = weighted.max(bound);
    let pred = sat(s.mean + df);
    let half_diff = R::of(0.5) * f - R::of(0.5) * pred;
    let mean = sat(pred + gain * half_diff + gain * half_diff);
    let sd = hypot((one - gain) * sd_pred, gain * rms_f);

    // The secant curvature along the element's own last step (where ΔF spans it): the RMS
    // of ΔF/Δθ weighted by Δθ², each earlier weight forgotten by decay_h.
    let (mut curv, mut curv_w) = (s.curv, s.curv_w);
    if dpi2 > R::ZERO && dpi2.is_finite() && s.last != R::ZERO {
        curv_w = hypot(p.keep_h * s.curv_w, s.last);
        let kw = s.last.abs() / curv_w;
        let k = kw * kw;
        let secant = sat(df / s.last);
        curv = hypot((one - k).sqrt() * curv, k.sqrt() * secant);
    }
    let h = curv;

    let ratio = match p.step {
        StepRule::Snr => mean / (sd + p.eps),
        StepRule::Newton if mean == R::ZERO => R::ZERO,
        // The Wiener step: the estimate over √v̂, shrunk by its own significance.
        StepRule::Newton => (mean / (v + p.eps)) * inverse_variance_weight(mean.abs(), sd),
    };
    let mut step = sat(-p.lr * ratio);
    let mut newton = false;
    let n_eff = one / gain;
    if p.step == StepRule::Newton && h > R::ZERO {
        // Newton's step −mean/h shrunk by the positive-part James–Stein factor
        // 1 − (sig·sd/mean)², or the Wiener step times settle, whichever is longer, within
        // lr.
        let z2 = if mean == R::ZERO {
            R::MAX
        } else {
            let z = p.sig * (sd / mean.abs());
            if z >= one {
                one
            } else {
                z * z
            }
        };
        let shrink = if z2 >= one { R::ZERO } else { one - z2 };
        let newton_step = sat(-mean / h) * shrink;
        let newton_step = newton_step.max(-p.lr).min(p.lr);
        let settle_step = p.settle * step;
        newton = newton_step.abs() > settle_step.abs();
        step = if newton { newton_step } else { settle_step }.max(-p.lr).min(p.lr);
    }
    let next = sat(theta + step).max(p.lo).min(p.hi);
    let taken = next - theta;
    let diag = ElemDiag { n_eff, clipped: weighted < bound, newton, f, df, sd_d, step: taken, mean, sd, sd_f: rms_f, curv: h };
    Some((next, MetaElem { mean, sd, rms_f, rms_d, wsum_d, n_eff, v, curv, curv_w, last: taken }, diag))
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
    record: DiagRecord<R>,
    diagnostics: Diagnostics,
}

/// One step's inputs for a whole buffer: the gradient, and for Meta the finite-difference
/// sample and (centred variance) the half-sample sums of both.
#[derive(Clone, Copy, Debug, Default)]
pub struct StepInput<'a, R> {
    pub grad: &'a [R],
    pub fd: Option<&'a [R]>,
    pub grad_half: Option<&'a [R]>,
    pub fd_half: Option<&'a [R]>,
}

impl<R: Real> BufferOptimiser<R> {
    pub fn new(optimiser: &Optimiser, n: usize, lr: f64, range: Range) -> Result<Self, OptimError> {
        optimiser.validate()?;
        if !(lr >= 0.0 && lr.is_finite()) {
            return Err(OptimError::BadHyper(format!("lr = {lr} must be non-negative and finite")));
        }
        let elems = match *optimiser {
            Optimiser::Adam(h) => Elems::Adam(h, vec![AdamElem::default(); n]),
            Optimiser::Meta(h) => Elems::Meta(h, vec![MetaElem::default(); n]),
        };
        Ok(BufferOptimiser { elems, lr, range, t: 0, dpi2: R::ZERO, nonfinite: 0, record: DiagRecord::default(), diagnostics: Diagnostics::default() })
    }

    /// One step over the buffer, in place. `fd` is required by Meta and ignored by Adam.
    /// Returns the number of elements skipped for non-finite inputs.
    pub fn step(&mut self, theta: &mut [R], grad: &[R], fd: Option<&[R]>) -> Result<u64, OptimError> {
        self.step_with(theta, StepInput { grad, fd, ..Default::default() })
    }

    /// [`Self::step`] with every input, the half-sample sums included.
    pub fn step_with(&mut self, theta: &mut [R], input: StepInput<R>) -> Result<u64, OptimError> {
        let dpi2_prev = self.dpi2;
        let n = self.len();
        check_len("theta", n, theta.len())?;
        check_len("gradient", n, input.grad.len())?;
        let t = self.t + 1;
        let mut skipped = 0;
        let mut record = DiagRecord::default();
        let lr_t;
        match &mut self.elems {
            Elems::Adam(h, state) => {
                let p = AdamParams::<R>::new(h, t, self.lr, self.range);
                lr_t = p.lr.to_f64();
                for ((th, &g), s) in theta.iter_mut().zip(input.grad).zip(state.iter_mut()) {
                    match adam_update(&p, *th, g, *s) {
                        Some((t2, s2, d)) => {
                            (*th, *s) = (t2, s2);
                            record = record.merge(DiagRecord::of(&d));
                        }
                        None => skipped += 1,
                    }
                }
            }
            Elems::Meta(h, state) => {
                let fd = input.fd.ok_or(OptimError::MissingFd)?;
                check_len("finite-difference gradient", n, fd.len())?;
                let p = MetaParams::<R>::new(h, n, t, self.lr, self.range);
                lr_t = p.lr.to_f64();
                let halves = if p.centred {
                    let (gh, fh) = input.grad_half.zip(input.fd_half).ok_or(OptimError::MissingHalves)?;
                    check_len("half-sample gradient", n, gh.len())?;
                    check_len("half-sample finite-difference gradient", n, fh.len())?;
                    Some((gh, fh))
                } else {
                    None
                };
                for (i, (th, s)) in theta.iter_mut().zip(state.iter_mut()).enumerate() {
                    let (f_half, df_half) = halves.map_or((R::ZERO, R::ZERO), |(gh, fh)| (gh[i], fh[i]));
                    let x = MetaInput { f: input.grad[i], df: fd[i], f_half, df_half };
                    match meta_update(&p, *th, x, dpi2_prev, *s) {
                        Some((t2, s2, d)) => {
                            (*th, *s) = (t2, s2);
                            record = record.merge(DiagRecord::of(&d));
                        }
                        None => {
                            // The element did not move: the next ⟨ΔF⟩ spans no step of it.
                            s.last = R::ZERO;
                            skipped += 1;
                        }
                    }
                }
                self.dpi2 = record.step.total();
            }
        }
        self.t = t;
        self.nonfinite += skipped;
        self.record = record;
        self.diagnostics = Diagnostics::from_record(&record, lr_t);
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

    /// The last step's diagnostics record, as the GPU reduces it.
    pub fn record(&self) -> &DiagRecord<R> {
        &self.record
    }

    /// The last step's diagnostics.
    pub fn diagnostics(&self) -> &Diagnostics {
        &self.diagnostics
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

/// The parameter groups of one θ buffer as the GPU passes run them: each group (a range of
/// the buffer) has its own state, rate and range, and its ΔF terms scale with its own
/// previous step.
#[derive(Clone, Debug)]
pub struct GroupedOptimiser<R> {
    groups: Vec<(usize, BufferOptimiser<R>)>,
}

impl<R: Real> GroupedOptimiser<R> {
    /// `groups`: (offset, length, learning rate, range) of each group.
    pub fn new(optimiser: &Optimiser, groups: &[(usize, usize, f64, Range)]) -> Result<Self, OptimError> {
        let groups =
            groups.iter().map(|&(offset, len, lr, range)| Ok((offset, BufferOptimiser::new(optimiser, len, lr, range)?))).collect::<Result<_, OptimError>>()?;
        Ok(GroupedOptimiser { groups })
    }

    /// One step of every group over the whole buffer; returns the elements skipped.
    pub fn step_with(&mut self, theta: &mut [R], input: StepInput<R>) -> Result<u64, OptimError> {
        let mut skipped = 0;
        for (offset, o) in &mut self.groups {
            let r = *offset..*offset + o.len();
            let input = StepInput {
                grad: &input.grad[r.clone()],
                fd: input.fd.map(|s| &s[r.clone()]),
                grad_half: input.grad_half.map(|s| &s[r.clone()]),
                fd_half: input.fd_half.map(|s| &s[r.clone()]),
            };
            skipped += o.step_with(&mut theta[r.clone()], input)?;
        }
        Ok(skipped)
    }

    /// The last step's diagnostics, per group.
    pub fn diagnostics(&self) -> Vec<Diagnostics> {
        self.groups.iter().map(|(_, o)| *o.diagnostics()).collect()
    }
}

fn check_len(what: &'static str, expected: usize, found: usize) -> Result<(), OptimError> {
    if expected == found {
        Ok(())
    } else {
        Err(OptimError::Length { what, expected, found })
    }
}
