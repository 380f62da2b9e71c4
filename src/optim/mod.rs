//! Optimisers: Adam and the gradient meta-estimator of Bálint et al., "Joint Sampling and
//! Optimisation for Inverse Rendering" (SIGGRAPH Asia 2023), as CPU references of the GPU
//! passes `glsl/optim_adam.comp` and `glsl/optim_meta.comp`.
//!
//! An optimiser step is a pure function of (parameters, gradients, state), element by element,
//! in the style of Dr.Jit's `opt.py`. One parameter buffer is one group: Meta's ‖Δπ‖² (`dpi2`)
//! is the squared L2 norm of the buffer's previous step.
//!
//! - [`reference`]: the float32-safe formulation, generic over [`Real`] (f64 as the reference,
//!   f32 to reproduce the GPU's arithmetic). `glsl/lib/optim.glsl` is the same code in GLSL.
//! - [`literal`]: the seed pseudocode (Moment2 + Meta) and textbook Adam transcribed in plain
//!   f64; tests show that [`reference`] equals it on ordinary gradient streams.
//! - [`host`]: the reference behind a spec over float32 buffers, for callers that produce
//!   the gradient streams themselves (the Python package's loop over a Python loss).
//! - [`replay`]: batch driver over recorded gradient streams (`vkinverse replay`).
//! - [`push`]: the kernels' push-constant blocks.
//!
//! # Float32 safety
//! Where the pseudocode would overflow, underflow or divide by zero in f32, the formulation
//! (identical in [`reference`] and GLSL) does instead:
//! 1. Second moments and variances are stored as their square roots (RMS, standard deviation)
//!    and combined by a scaled `hypot`: the squares of gradients in 1e-30..1e30 leave f32.
//! 2. EMAs are stored bias-corrected and updated as convex combinations with weight
//!    k = (1−β)/(1−β^t), the seed's `w / w_sum`; 1−β^t is evaluated without cancellation
//!    ([`reference::one_minus_pow`]), since `1 - pow(0.999, t)` in f32 loses 4 digits.
//! 3. α = VF/(VF + var + 1e-30) is evaluated on standard deviations divided by the largest of
//!    them, so neither a square nor the denominator can overflow or vanish.
//! 4. α is carried as the gain g = 1 − α, accurate as α → 1; the clip α ≤ 1/(2 − α_prev)
//!    becomes g ≥ 1/(1 + n_eff) with n_eff = 1/(1 − α_prev), the effective number of averaged
//!    samples. n_eff = 0 (zero-initialised state) is α_prev = −∞, so the first α is 0.
//! 5. The mean update α·(M + ΔF) + (1−α)·F is computed as h + g·(F/2 − h/2) + g·(F/2 − h/2)
//!    with h = M + ΔF: a convex combination at every stage, so it cannot overflow.
//! 6. The ΔF Moment2 (of ΔF/‖Δπ‖) is updated through the current step's standard deviation
//!    sd_D = hypot(√(1−k)·rms_D·‖Δπ‖, √k·|ΔF|), never through ΔF/‖Δπ‖ itself (which overflows
//!    for tiny steps); the stored rms_D = sd_D/‖Δπ‖ saturates. With [`FdVariance::Raw`] the
//!    same update runs with ‖Δπ‖ taken as 1.
//! 7. ‖Δπ‖² = 0 (the first iteration, or a buffer that did not move, e.g. pinned at its range)
//!    or non-finite: the ΔF terms are skipped — ΔF is taken as 0 with variance 0 and the ΔF
//!    Moment2 is not stepped. A common-random-number finite difference over a zero step is
//!    exactly zero, so this is the limit, not an approximation.
//! 8. The ΔF Moment2 counts its own samples per element (`wsum_d` = 1 − β^count), because its
//!    samples are missing at the first iteration and whenever (7) applies.
//! 9. A non-finite F or ΔF skips the element: θ and its state are unchanged (but for its last
//!    step, which becomes 0: the next ΔF spans no step of it), its step is 0, and it is
//!    counted (Adam reads no ΔF). The F Moment2 keeps the global count t, so after
//!    a skip its bias correction is slightly low until the EMA forgets (the step bounds below
//!    still hold).
//! 10. Results that can leave the f32 range (M + ΔF, rms_D·‖Δπ‖, lr·ratio, θ + step, the
//!     secant ΔF/Δθ, M/h) saturate at ±MAX; the ratio M/(sd + ε) is taken before multiplying
//!     by lr.
//! 11. `step = newton`'s curvature, the Δθ²-weighted RMS of the secants ΔF/Δθ, is kept as its
//!     root h and the root of its weight sum and updated by `hypot` with weights that sum to
//!     one, so that neither a tiny step nor a huge ΔF overflows it.
//!
//! The seed's constants are absolute: ε = 1e-8 makes steps shrink in proportion for
//! gradients below ~1e-8 (as in Adam), and the 1e-30 in the α denominator makes Meta stop
//! averaging gradients below ~1e-15 (α → 0). Both are kept for fidelity to the seed.
//!
//! # Step bounds
//! With these choices the step is bounded for any finite input (Cauchy–Schwarz on the EMA
//! weights): Adam |Δθ| ≤ lr·[`ADAM_STEP_BOUND`] for the default betas; Meta with
//! `step = newton` |Δθ| ≤ lr; Meta with the seed's rule
//! |Δθ_t| ≤ lr·√(1 + (t−1)(1/(1−β_F) + 1/(1−β_D))), which grows like √t because a confident
//! meta-estimate takes larger steps by design: with Var[M] ≈ VF/n_eff the step is about
//! lr·√n_eff·M/√VF.

pub mod csv;
pub mod gpu;
pub mod host;
pub mod literal;
pub mod push;
pub mod reference;
pub mod replay;
pub mod schedule;
pub mod spec;
#[cfg(test)]
mod tests;

pub use host::{HostGroup, HostOptimiser, HostStep};
pub use reference::{AdamElem, BufferOptimiser, Diagnostics, GroupedOptimiser, MetaElem, Real};
pub use replay::{replay_cpu, Replay, Streams};
pub use schedule::{Decay, Schedule};

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Adam's |Δθ|/lr bound for β1 = 0.9, β2 = 0.999: the sup over t of
/// √((1−β1)²(1−β2^t)/((1−β1^t)²(1−β2)) · Σ_{j<t} (β1²/β2)^j), which tends to 7.27.
pub const ADAM_STEP_BOUND: f64 = 7.3;

/// The seed's regulariser in the α denominator, VF/(VF + var + 1e-30) (supplementary B).
pub const ALPHA_REG: f64 = 1e-30;

/// The decay of the second moment √v̂ of ⟨F⟩ that normalises the Wiener step of
/// `step = newton` (Adam's default β2).
pub const META_BETA2: f64 = 0.999;

/// Errors of the optimiser layer.
#[derive(Debug, thiserror::Error)]
pub enum OptimError {
    #[error("unknown optimiser '{0}' (expected meta, meta-seed or adam)")]
    UnknownOptimiser(String),
    #[error("invalid range '{0}' (expected LO,HI with LO <= HI)")]
    BadRange(String),
    #[error("invalid hyperparameter: {0}")]
    BadHyper(String),
    #[error("optimiser spec {0}")]
    BadSpec(String),
    #[error("{what} has length {found}, expected {expected}")]
    Length { what: &'static str, expected: usize, found: usize },
    #[error("the meta optimiser needs finite-difference gradients")]
    MissingFd,
    #[error("the centred variance estimate (var=centred) needs the half-sample sums of both gradient streams")]
    MissingHalves,
}

/// Closed parameter range; ±infinity for an open side.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Range {
    pub lo: f64,
    pub hi: f64,
}

impl Range {
    pub const UNBOUNDED: Range = Range { lo: f64::NEG_INFINITY, hi: f64::INFINITY };

    pub fn new(lo: f64, hi: f64) -> Result<Self, OptimError> {
        if lo <= hi {
            Ok(Range { lo, hi })
        } else {
            Err(OptimError::BadRange(format!("{lo},{hi}")))
        }
    }
}

impl Default for Range {
    fn default() -> Self {
        Range::UNBOUNDED
    }
}

/// Parses `LO,HI` as given to `--range`.
impl FromStr for Range {
    type Err = OptimError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || OptimError::BadRange(s.to_string());
        let (lo, hi) = s.split_once(',').ok_or_else(bad)?;
        let lo = lo.trim().parse().map_err(|_| bad())?;
        let hi = hi.trim().parse().map_err(|_| bad())?;
        Range::new(lo, hi).map_err(|_| bad())
    }
}

/// Adam (Kingma & Ba 2015) hyperparameters; the learning rate is given per run and scaled
/// by the schedule.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AdamHyper {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    pub schedule: Schedule,
}

impl Default for AdamHyper {
    fn default() -> Self {
        AdamHyper { beta1: 0.9, beta2: 0.999, eps: 1e-8, schedule: Schedule::default() }
    }
}

/// How the meta-estimator turns its estimate ⟨F⟩_M (variance V_M) into a step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StepRule {
    /// The seed's −lr·⟨F⟩_M/(√V_M + ε): lr per unit signal-to-noise ratio of the estimate,
    /// so the step grows like √n_eff as the estimate averages.
    #[default]
    Snr,
    /// Newton's step −⟨F⟩_M/h where the estimate is significant, the Wiener step scaled
    /// down elsewhere, never longer than lr. h is the element's secant curvature: the RMS
    /// of ⟨ΔF⟩/Δθ over its own recent steps, weighted by Δθ² (the finite-difference samples
    /// measure how the gradient changed over a known step, which is what Newton needs), an
    /// upper estimate where the secants are noisy. Newton's step is shrunk by the
    /// positive-part James–Stein factor 1 − (sig·√V_M/⟨F⟩_M)², zero unless the estimate
    /// lies `sig` standard deviations from 0 (`sig` for a group of one element, Bonferroni's
    /// level for larger groups, [`MetaHyper::sig_for`]). The Wiener step is Adam's
    /// normalisation of the estimate shrunk by its own significance,
    /// −lr·⟨F⟩_M/(√v̂ + ε)·⟨F⟩_M²/(⟨F⟩_M² + V_M), v̂ the EMA ([`META_BETA2`]) of ⟨F⟩²; the
    /// step is the longer of Newton's and `settle` times the Wiener step. So far from the
    /// optimum, where the estimate is significant, the iterate moves by the estimated
    /// distance to the optimum (at most lr) instead of a step that shrinks with the
    /// gradient; near it, where the estimate is noise, it moves by a fraction of the Wiener
    /// step, which keeps the finite differences small so that the estimate keeps averaging;
    /// as the averaged estimate becomes significant again, Newton's step corrects the
    /// iterate by the remaining distance.
    Newton,
}

impl StepRule {
    /// The kernels' number for it (`STEP_*`, src/constants.rs).
    pub fn code(self) -> u32 {
        use crate::constants::*;
        match self {
            StepRule::Snr => STEP_SNR,
            StepRule::Newton => STEP_NEWTON,
        }
    }
}

/// What the meta-estimator's variance EMAs of ⟨F⟩ and ⟨ΔF⟩ are taken of.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VarianceEstimate {
    /// The seed's zero-centred second moments: E[⟨F⟩²] counts the squared mean as variance,
    /// E[⟨ΔF⟩²] the squared expected change H·Δπ.
    #[default]
    Zero,
    /// Centred: each gradient pass also sums a random half of its pixels into a second
    /// buffer, and the two independent halves A, B of an estimate give (A − B)²/4, a sample
    /// of its variance that counts the per-pixel squared means (which vanish at the
    /// optimum) instead of the squared total mean. No extra samples.
    Centred,
}

impl VarianceEstimate {
    pub fn code(self) -> u32 {
        match self {
            VarianceEstimate::Zero => 0,
            VarianceEstimate::Centred => 1,
        }
    }
}

/// How the meta-estimator models the variance of its finite-difference samples ⟨ΔF⟩.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FdVariance {
    /// Supplementary B: Var[⟨ΔF⟩] ≈ Moment2(⟨ΔF⟩/‖Δπ‖)·‖Δπ‖², for a difference whose noise
    /// is proportional to the step. Where the steps' lengths vary by orders of magnitude from
    /// one iteration to the next and the difference has a noise floor (a few-sample primal
    /// image, paths reweighted for sampling parameters), the ratio learnt from a tiny step
    /// predicts a huge variance for the next large one, and the history gets no weight.
    #[default]
    Scaled,
    /// Moment2(⟨ΔF⟩) itself, not rescaled by the step.
    Raw,
}

/// How the carried primal image (`carry` > 0) weighs each iteration's fresh render.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CarryWeight {
    /// 1/k at the k-th iteration down to `carry`: a running mean, then an EMA.
    #[default]
    Fixed,
    /// The fresh render's inverse-variance weight against the carried image's, no lower
    /// than `carry`: the variances are estimated every iteration from the renders (the
    /// fresh one against the finite-difference sample's image of the same θ, and that
    /// sample's two images), and the carried image's is tracked (glsl/carry_weight.comp).
    /// Large steps weigh the fresh render, small ones let the image average more iterations.
    Variance,
}

/// The two-sided normal quantile z with P(|Z| > z) = P(|Z| > `sig`)/k: the significance
/// that keeps a family of k tests at the level of one test at `sig`. `sig` itself for
/// k ≤ 1 or `sig` = 0 (no test).
pub fn bonferroni_sig(sig: f64, k: usize) -> f64 {
    if k <= 1 || sig <= 0.0 {
        return sig;
    }
    let target = ln_two_sided_tail(sig) - (k as f64).ln();
    // The normal tail's hazard rate is at least z, so tail(sig + d) ≤ tail(sig)·e^(−d²/2):
    // the root lies below sig + √(2 ln k) (2 more for the fit's error); bisection to the
    // f64 resolution of the bracket.
    let (mut lo, mut hi) = (sig, sig + (2.0 * (k as f64).ln()).sqrt() + 2.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if ln_two_sided_tail(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// ln P(|Z| > z) = ln erfc(z/√2) for z ≥ 0, without underflow at large z: the Chebyshev
/// fit of erfc(x) = t·exp(−x² + P(t)), t = 1/(1 + x/2), relative error below 1.2e-7 for
/// every x ≥ 0 (Press et al., Numerical Recipes, §6.2), taken in logarithms.
fn ln_two_sided_tail(z: f64) -> f64 {
    const C: [f64; 10] = [-1.26551223, 1.00002368, 0.37409196, 0.09678418, -0.18628806, 0.27886807, -1.13520398, 1.48851587, -0.82215223, 0.17087277];
    let x = z.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * x);
    let poly = C.iter().rev().fold(0.0, |acc, c| c + t * acc);
    t.ln() - x * x + poly
}

/// Meta-estimator hyperparameters. `decay_f`, `decay_d` are the decays of the two Moment2
/// EMAs (0.9 in the seed's Moment2), `eps` the ε of the step (1e-8, supplementary B).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct MetaHyper {
    pub decay_f: f64,
    pub decay_d: f64,
    pub eps: f64,
    pub step: StepRule,
    pub variance: VarianceEstimate,
    /// The ⟨ΔF⟩ variance model.
    pub fdvar: FdVariance,
    /// `step = newton`: the decay of each earlier secant's weight per new one.
    pub decay_h: f64,
    /// `step = newton`: the significance, in standard deviations of the estimate, that
    /// Newton's step needs in a group of one element; an element of a group of k needs the
    /// two-sided level of `sig` divided by k (Bonferroni), so that the chance of a false
    /// Newton step anywhere in the group, when its estimate is noise alone, is that of one
    /// element at `sig`. With `sig` = 1.5: 1.5 for a scalar, 2.01 for a colour, 3.08 for an
    /// 8×8 grey texture, 4.09 for a 32×32 colour texture ([`MetaHyper::sig_for`]).
    pub sig: f64,
    /// `step = newton`: the fraction of the Wiener step taken where Newton's is shorter.
    pub settle: f64,
    /// The primal image the losses read (0: each iteration's own render). Above 0, the image
    /// is carried from one iteration to the next by the finite-difference sample's two
    /// images (an unbiased estimate of how the expected image changed between θ_{i-1} and
    /// θ_i, with common random numbers) and mixed with the fresh render, whose weight falls
    /// as 1/k at the k-th iteration down to `carry`: the adjoint images of ⟨F⟩ and ⟨ΔF⟩ then
    /// hold the noise of many iterations' primal samples instead of one's
    /// (glsl/carry_image.comp). The carry needs the fused finite-difference sample on every
    /// pixel: with `fd_stride` > 1 or `fd_two_trace` the losses read each iteration's own
    /// render.
    pub carry: f64,
    /// How the fresh render is weighed in the carried image (`carry_weight` = fixed|variance).
    pub carry_weight: CarryWeight,
    /// With the carried image (`carry_weight = variance`): the adjoint pass of ⟨F⟩, whose
    /// primal replays render θ_i at `spp` with random numbers of their own, mixes that
    /// render into the carried image after the losses read it, by its inverse-variance
    /// weight (`carry_adjoint` = on|off; glsl/carry_adjoint.comp). The next iterations' images
    /// then hold those samples too, at no extra tracing.
    pub carry_adjoint: bool,
    pub schedule: Schedule,
}

impl MetaHyper {
    /// The significance `step = newton` asks of each element of a group of `k` elements:
    /// [`bonferroni_sig`]`(sig, k)`.
    pub fn sig_for(&self, k: usize) -> f64 {
        bonferroni_sig(self.sig, k)
    }

    /// The seed's configuration (supplementary B, spec `meta-seed`): the step
    /// −lr·⟨F⟩_M/(√V_M + ε), zero-centred Moment2 EMAs of decay 0.9, the ⟨ΔF⟩ variance
    /// scaled by the step, constant β_F and learning rate, each iteration's own primal
    /// render.
    pub fn seed() -> Self {
        MetaHyper {
            decay_f: 0.9,
            decay_d: 0.9,
            eps: 1e-8,
            step: StepRule::Snr,
            variance: VarianceEstimate::Zero,
            fdvar: FdVariance::Scaled,
            decay_h: 0.9,
            sig: 3.0,
            settle: 0.3,
            carry: 0.0,
            carry_weight: CarryWeight::Fixed,
            carry_adjoint: false,
            schedule: Schedule::default(),
        }
    }
}

/// The defaults (spec `meta`): Newton's step rule on the finite differences' secant
/// curvature (`lr` is the longest step, the typical step far from the optimum as for Adam;
/// significance 1.5 for a group of one element and Bonferroni's for larger groups, a tenth
/// of the secants' weight forgotten per step, 0.3 of the Wiener step near the optimum, each
/// element's own James–Stein factor), the centred variance estimate and the raw ⟨ΔF⟩
/// variance of decay 0.3, with the seed's other decay and ε, each parameter group's own
/// step norm, constant β_F and rate, and the carried primal image with inverse-variance
/// weights down to 0.01 and the adjoint pass's render mixed in. Chosen by the pilot runs of
/// experiments/history.md: the centred estimate (experiments/pilots/pilot.toml,
/// experiments/pilots/pilot2.toml), `fdvar=raw` (experiments/pilots/pilot3.toml), which lets
/// the estimate average for parameters that change how paths are sampled, then Newton's
/// rule (experiments/pilots/pilot6.toml), whose settled error relative to the best Adam has
/// the smaller geometric mean over the six bundled scenes, and its sig and settle
/// (experiments/pilots/pilot7.toml: no other setting tried was better on every scene), then
/// the carried primal image (experiments/pilots/pilot14.toml,
/// experiments/pilots/pilot15.toml) with its inverse-variance weights down to 0.01
/// (experiments/pilots/pilot17.toml), then a shorter memory of the ⟨ΔF⟩ variance,
/// `decay_d` = 0.3 (experiments/pilots/pilot28.toml, experiments/pilots/pilot29.toml: the
/// smaller geometric mean at two seeds), then the adjoint pass's render taken into the
/// carried image, `carry_adjoint` (experiments/pilots/pilot35.toml,
/// experiments/pilots/pilot36.toml: a smaller geometric mean at two seeds for less
/// tracing), then Bonferroni's significance by the group's size at `sig` = 1.5
/// (experiments/pilots/pilot62.toml). docs/optimisers.md lists every key with its evidence.
impl Default for MetaHyper {
    fn default() -> Self {
        MetaHyper {
            sig: 1.5,
            decay_d: 0.3,
            step: StepRule::Newton,
            variance: VarianceEstimate::Centred,
            fdvar: FdVariance::Raw,
            carry: 0.01,
            carry_weight: CarryWeight::Variance,
            carry_adjoint: true,
            ..MetaHyper::seed()
        }
    }
}

/// An optimiser and its hyperparameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Optimiser {
    Adam(AdamHyper),
    Meta(MetaHyper),
}

impl Optimiser {
    pub fn name(&self) -> &'static str {
        match self {
            Optimiser::Adam(_) => "adam",
            Optimiser::Meta(_) => "meta",
        }
    }

    /// Whether each iteration needs a finite-difference sample ⟨ΔF_i⟩.
    pub fn needs_fd(&self) -> bool {
        matches!(self, Optimiser::Meta(_))
    }

    /// Whether the gradient passes must also sum half of their samples separately (the
    /// centred variance estimate).
    pub fn needs_halves(&self) -> bool {
        matches!(self, Optimiser::Meta(h) if h.variance == VarianceEstimate::Centred)
    }

    /// The learning-rate schedule.
    pub fn schedule(&self) -> &Schedule {
        match self {
            Optimiser::Adam(h) => &h.schedule,
            Optimiser::Meta(h) => &h.schedule,
        }
    }

    /// The learning-rate schedule, to change.
    pub fn schedule_mut(&mut self) -> &mut Schedule {
        match self {
            Optimiser::Adam(h) => &mut h.schedule,
            Optimiser::Meta(h) => &mut h.schedule,
        }
    }

    /// The optimiser for a run of `iterations` steps: a cosine horizon of 0 becomes it.
    pub fn resolve(mut self, iterations: u32) -> Self {
        let s = self.schedule().resolve(iterations);
        *self.schedule_mut() = s;
        self
    }

    /// Checks that decays lie in [0, 1), ε is positive and finite, and the schedule is valid.
    pub fn validate(&self) -> Result<(), OptimError> {
        let decay = |name: &str, b: f64| {
            if (0.0..1.0).contains(&b) {
                Ok(())
            } else {
                Err(OptimError::BadHyper(format!("{name} = {b} is outside [0, 1)")))
            }
        };
        let eps = match *self {
            Optimiser::Adam(h) => {
                decay("beta1", h.beta1)?;
                decay("beta2", h.beta2)?;
                h.eps
            }
            Optimiser::Meta(h) => {
                decay("decay_f", h.decay_f)?;
                decay("decay_d", h.decay_d)?;
                decay("decay_h", h.decay_h)?;
                if !(0.0..=1.0).contains(&h.settle) {
                    return Err(OptimError::BadHyper(format!("settle = {} is outside [0, 1]", h.settle)));
                }
                if !(h.sig >= 0.0 && h.sig <= 1e6) {
                    return Err(OptimError::BadHyper(format!("sig = {} is outside [0, 1e6]", h.sig)));
                }
                if !(0.0..=1.0).contains(&h.carry) {
                    return Err(OptimError::BadHyper(format!("carry = {} is outside [0, 1]", h.carry)));
                }
                h.eps
            }
        };
        self.schedule().validate()?;
        if eps > 0.0 && eps.is_finite() {
            Ok(())
        } else {
            Err(OptimError::BadHyper(format!("eps = {eps} must be positive and finite")))
        }
    }
}

impl fmt::Display for Optimiser {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Parses `meta` or `adam` with default hyperparameters, or `meta-seed`: the meta-estimator
/// in the seed's configuration ([`MetaHyper::seed`]).
impl FromStr for Optimiser {
    type Err = OptimError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "adam" => Ok(Optimiser::Adam(AdamHyper::default())),
            "meta" => Ok(Optimiser::Meta(MetaHyper::default())),
            "meta-seed" => Ok(Optimiser::Meta(MetaHyper::seed())),
            _ => Err(OptimError::UnknownOptimiser(s.to_string())),
        }
    }
}
