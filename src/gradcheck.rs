//! `vkinverse gradcheck`: the adjoint (path replay) gradient of the loss against central
//! finite differences of the loss with common random numbers, per optimised parameter
//! element (a few texels of a texture).
//!
//! # The estimates
//! Each round r gives one adjoint estimate a_r (iteration counter r) and, per element, one
//! finite difference f_r (its own counter, so the two sides are independent). For l2 and
//! relative_l2 the finite difference is of the unbiased loss (I1 − T)(I2 − T) over two
//! independent renders; for l1 it is of the plain loss, whose finite difference also
//! carries the derivative of the image noise (shrinking with `primal_spp`), which the
//! verdict allows for with [`L1_ALLOWANCE`].
//!
//! # The verdict
//! - Per element, z = (ā − f̄) / √(se_a² + se_f²). An element fails when |z| > [`Z_FAIL`].
//! - Over all elements, Hotelling's T² of the per-round differences d_r = a_r − f_r
//!   (rounds pair up arbitrarily: both sides are i.i.d. over rounds and independent of each
//!   other), which accounts for the correlation between elements that a sum of z² would
//!   ignore. The check fails when its p-value is below [`P_FAIL`].
//! - Power: the check is meant to catch a bias of [`DETECT`] (10 %) of a gradient of the
//!   scene's typical size, G = the root mean square of the elements' gradients. An element
//!   whose combined standard error exceeds (DETECT · max(|g|, G)) / ([`Z_FAIL`] +
//!   [`Z_POWER`]) could not have failed on such a bias (with 90 % probability), so it is
//!   "inconclusive", never "pass", and the standard error it would need is reported.
//!
//! # Default rounds
//! The standard errors of a scene are unknown until measured: by default a pilot of
//! [`PILOT_ROUNDS`] rounds measures each element's per-round spread, and the run is
//! extended to the rounds that the needed standard error implies (the spread falls as
//! 1/√rounds), at most `max_rounds`. Where a scene's variance needs more than that, the
//! verdict says "inconclusive" with the rounds it would need. The default 16 samples per
//! pixel keep the adjoint's product of two noisy images, (I − T) ∂I, away from the heavy
//! tails it has at 1–4 spp in scenes carried by rare paths (in scenes/gap one round in
//! 640 at 1 spp held most of the mean), where a standard error over a few hundred rounds
//! does not describe the spread.

use crate::engine::Engine;
use crate::error::Result;
use crate::gpu::CommandBuffer;
use crate::render::gradient::GradientPass;
use crate::scene::Scene;
use crate::settings::{Loss, RunSettings};
use crate::stats::{hotelling, mean_se, median, Hotelling};
use serde::Serialize;

/// |z| above which an element fails: 4 standard errors, a false alarm rate of 6e-5 per
/// element for normal estimates.
pub const Z_FAIL: f64 = 4.0;
/// p-value of the combined statistic below which the check fails.
pub const P_FAIL: f64 = 1e-3;
/// The relative bias the check must be able to see, of a gradient of the scene's typical
/// size.
pub const DETECT: f64 = 0.1;
/// One-sided normal quantile of the power wanted against that bias (90 %).
pub const Z_POWER: f64 = 1.2816;
/// Rounds of the pilot that sizes a run with automatic rounds.
pub const PILOT_ROUNDS: u32 = 8;
/// For l1 the finite difference of the plain loss is not the adjoint's expectation (see
/// the module documentation): differences up to this fraction of |fd| are allowed.
pub const L1_ALLOWANCE: f64 = 0.1;
/// Iteration counters of the finite differences start here, far from the adjoint's 0, 1, …
const FD_FRAMES: u32 = 1 << 24;

/// How to check.
#[derive(Clone, Debug)]
pub struct Options {
    pub spp: u32,
    pub primal_spp: u32,
    /// Rounds; `None` sizes the run from a pilot (module documentation).
    pub rounds: Option<u32>,
    /// The most rounds an automatic run takes.
    pub max_rounds: u32,
    pub step: f32,
    /// At most this many elements per parameter (texels are spread over the texture).
    pub max_elements: usize,
    pub seed: u32,
}

impl Default for Options {
    fn default() -> Self {
        Options { spp: 16, primal_spp: 16, rounds: None, max_rounds: 200, step: 0.01, max_elements: 4, seed: 1 }
    }
}

/// The outcome of a check, of one element or of all.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    Pass,
    Fail,
    /// Could not have failed on the bias it is meant to detect.
    Inconclusive,
}

impl Verdict {
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Pass => "pass",
            Verdict::Fail => "FAIL",
            Verdict::Inconclusive => "inconclusive",
        }
    }
}

/// One checked element.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub param: String,
    pub element: usize,
    pub adjoint: f64,
    pub adjoint_se: f64,
    /// The median of the rounds' adjoint estimates and the share of them below 0: far from
    /// the mean and from one half, they show a skewed, heavy-tailed gradient, whose typical
    /// sample points away from its expectation (a step rule that damps rare large samples
    /// then drifts that way).
    pub adjoint_median: f64,
    pub adjoint_share_negative: f64,
    pub finite_difference: f64,
    pub finite_difference_se: f64,
    /// Standard error of adjoint − finite difference.
    pub se: f64,
    pub z: f64,
    /// The standard error at which a bias of [`DETECT`] × max(|gradient|, typical) would
    /// be detected with 90 % probability.
    pub se_needed: f64,
    pub verdict: Verdict,
}

/// Every element's row and the verdict over all of them.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub loss: &'static str,
    pub spp: u32,
    pub primal_spp: u32,
    pub rounds: u32,
    /// Root mean square of the elements' gradients (mean of both estimates).
    pub typical_gradient: f64,
    /// Hotelling's T² over all elements; `None` with fewer rounds than elements + 2, for
    /// l1, or when an element never varies.
    pub combined: Option<Hotelling>,
    pub verdict: Verdict,
    /// Rounds at this spp that the least resolved element needs (the estimate of its
    /// spread over the rounds run); equal to `rounds` when none is short.
    pub rounds_needed: u32,
    pub rows: Vec<Row>,
}

impl Report {
    /// The report as a table with a summary and the verdict.
    pub fn table(&self) -> String {
        let mut s = format!(
            "{:<32} {:>3} {:>13} {:>9} {:>13} {:>9} {:>7} {:>10}  verdict\n",
            "parameter", "el", "adjoint", "± se", "finite diff", "± se", "z", "se needed"
        );
        for r in &self.rows {
            s += &format!(
                "{:<32} {:>3} {:>13.5e} {:>9.2e} {:>13.5e} {:>9.2e} {:>+7.2} {:>10.2e}  {}\n",
                r.param,
                r.element,
                r.adjoint,
                r.adjoint_se,
                r.finite_difference,
                r.finite_difference_se,
                r.z,
                r.se_needed,
                r.verdict.as_str()
            );
        }
        s += &format!(
            "{} rounds of {} spp (primal {}), {} loss; typical gradient {:.3e}: a {:.0} % bias of it needs se ≤ {:.2e}\n",
            self.rounds,
            self.spp,
            self.primal_spp,
            self.loss,
            self.typical_gradient,
            DETECT * 100.0,
            DETECT * self.typical_gradient / (Z_FAIL + Z_POWER)
        );
        s += &match &self.combined {
            Some(h) => format!("combined: Hotelling T² {:.2} (F {:.2} on {}, {}), p = {:.2e}\n", h.t2, h.f, h.dof1, h.dof2, h.p_value),
            None => "combined: not available (needs rounds ≥ elements + 2, varying elements, and not l1)\n".to_string(),
        };
        s += &format!("verdict: {}", self.verdict.as_str());
        if self.verdict == Verdict::Inconclusive {
            s += &format!(" (about {} rounds at {} spp would resolve every element)", self.rounds_needed, self.spp);
        }
        s.push('\n');
        s
    }
}

/// Per-element samples: (slot name, element, θ index).
struct Element {
    param: String,
    element: usize,
    k: usize,
    adjoint: Vec<f64>,
    fd: Vec<f64>,
}

/// Checks every optimised parameter of `scene` at its initial values.
///
/// ```
/// # fn main() -> vkinverse::Result<()> {
/// use vkinverse::scene::{Film, LoadOptions};
/// use vkinverse::{Config, Device, Scene};
/// let small = LoadOptions { film: Some(Film { width: 16, height: 16 }), max_depth: Some(2) };
/// let scene = Scene::load_with("scenes/cornell/scene.toml", &small)?;
/// let options = vkinverse::gradcheck::Options { spp: 8, primal_spp: 8, rounds: Some(4), ..Default::default() };
/// let report = vkinverse::gradcheck::gradcheck(&Device::new(&Config::from_env().0)?, &scene, &options)?;
/// assert_eq!(report.rows.len(), 3, "the red wall's three channels");
/// # Ok(())
/// # }
/// ```
pub fn gradcheck(device: &crate::device::Device, scene: &Scene, opts: &Options) -> Result<Report> {
    let ctx = device.ctx();
    // The gradient estimate of an optimisation iteration at the options' sample counts.
    let mut settings = RunSettings::of_scene(scene);
    (settings.spp, settings.primal_spp, settings.seed) = (opts.spp, opts.primal_spp, opts.seed as u64);
    let engine = Engine::gradient_only(device, scene, &settings)?;
    let (gs, ops, grad, pass, target_images) = (engine.scene(), &engine.ops, &engine.grad, &engine.gradient, &engine.targets);
    let n = gs.layout.len.max(1);
    let mut grad_cmd = CommandBuffer::new(ctx, "gradient")?;
    grad_cmd.record(|rec| engine.record_gradient(rec))?;
    // Two independent primal renders per evaluation: for l2 and relative_l2 the product
    // (I1 − T)(I2 − T) has expectation (E[I] − T)², so the finite difference does not also
    // pick up the derivative of the image variance, which the plain loss (I − T)² carries.
    let second = engine.extra_gradient(opts.spp, opts.primal_spp, opts.seed ^ 0x5A5A_5A5A, grad)?;
    let mut loss_cmd = CommandBuffer::new(ctx, "loss")?;
    loss_cmd.record(|rec| {
        pass.record_loss(rec, gs, ops)?;
        second.record_loss(rec, gs, ops)
    })?;
    let loss_kind = engine.loss();
    let unbiased_loss = |a: &GradientPass, b: &GradientPass| -> Result<f64> {
        if loss_kind == Loss::L1 {
            return Ok(a.total_loss()?);
        }
        let mut total = 0.0;
        for (s, t) in target_images.iter().enumerate() {
            let (i1, i2) = (a.rendered(s, gs)?, b.rendered(s, gs)?);
            let mut sum = 0.0f64;
            for ((p1, p2), pt) in i1.data.iter().zip(&i2.data).zip(&t.data) {
                for c in 0..3 {
                    let tc = pt[c] as f64;
                    let w = if loss_kind == Loss::RelativeL2 { 1.0 / (tc * tc + 0.01) } else { 1.0 };
                    sum += (p1[c] as f64 - tc) * (p2[c] as f64 - tc) * w;
                }
            }
            total += sum / (3.0 * i1.data.len() as f64);
        }
        Ok(total)
    };
    let theta0 = gs.layout.initial();

    let mut elements = Vec::new();
    for slot in &gs.layout.slots {
        let count = slot.len.min(opts.max_elements);
        let stride = (slot.len / count.max(1)).max(1);
        for e in (0..slot.len).step_by(stride).take(count) {
            elements.push(Element { param: slot.name.clone(), element: e, k: slot.offset + e, adjoint: Vec::new(), fd: Vec::new() });
        }
    }

    // One round: an adjoint estimate and a central difference per element.
    let mut round = |r: u32, elements: &mut [Element]| -> Result<()> {
        gs.set_theta(theta0.clone())?;
        grad.write(&vec![0f32; n])?;
        gs.set_frame(r)?;
        grad_cmd.submit_and_wait()?;
        let g: Vec<f32> = grad.read()?;
        for el in elements.iter_mut() {
            el.adjoint.push(g[el.k] as f64);
            let slot = gs.layout.slots.iter().find(|s| el.k >= s.offset && el.k < s.offset + s.len).expect("element of a slot");
            // Central differences, clamped inside the parameter's range.
            let lo = (theta0[el.k] - opts.step).max(slot.range[0]);
            let hi = (theta0[el.k] + opts.step).min(slot.range[1]);
            // The same counter (seed) for both sides: common random numbers.
            gs.set_frame(FD_FRAMES + r)?;
            let mut at = |x: f32| -> Result<f64> {
                let mut t = theta0.clone();
                t[el.k] = x;
                gs.set_theta(t)?;
                loss_cmd.submit_and_wait()?;
                unbiased_loss(pass, &second)
            };
            let (lp, lm) = (at(hi)?, at(lo)?);
            el.fd.push((lp - lm) / (hi - lo) as f64);
        }
        Ok(())
    };

    let first = opts.rounds.unwrap_or(PILOT_ROUNDS).max(2);
    for r in 0..first {
        round(r, &mut elements)?;
    }
    if opts.rounds.is_none() {
        let want = assess(&elements, loss_kind, first).rounds_needed.min(opts.max_rounds);
        for r in first..want {
            round(r, &mut elements)?;
        }
    }
    gs.set_theta(theta0)?;
    let rounds = elements.first().map_or(0, |e| e.adjoint.len() as u32);
    let mut report = assess(&elements, loss_kind, rounds);
    report.spp = opts.spp;
    report.primal_spp = opts.primal_spp;
    Ok(report)
}

/// The statistics and verdicts of the samples so far (`rounds` of them).
fn assess(elements: &[Element], loss: Loss, rounds: u32) -> Report {
    let stats: Vec<((f64, f64), (f64, f64))> = elements.iter().map(|e| (mean_se(&e.adjoint), mean_se(&e.fd))).collect();
    let typical = if stats.is_empty() { 0.0 } else { (stats.iter().map(|((a, _), (f, _))| (0.5 * (a + f)).powi(2)).sum::<f64>() / stats.len() as f64).sqrt() };
    let mut rows = Vec::new();
    let mut rounds_needed = rounds;
    let mut any_fail = false;
    let mut all_conclusive = true;
    for (e, &((a, a_se), (f, f_se))) in elements.iter().zip(&stats) {
        let se = (a_se * a_se + f_se * f_se).sqrt();
        let d = a - f;
        let allowance = if loss == Loss::L1 { L1_ALLOWANCE * f.abs() } else { 0.0 };
        let z = if se > 0.0 {
            d / se
        } else if d == 0.0 {
            0.0
        } else {
            d.signum() * f64::INFINITY
        };
        let fails = (d.abs() - allowance) > Z_FAIL * se;
        let se_needed = DETECT * (0.5 * (a + f)).abs().max(typical) / (Z_FAIL + Z_POWER);
        let conclusive = se <= se_needed;
        if !conclusive && se_needed > 0.0 {
            // se falls as 1/√rounds.
            let need = (rounds as f64 * (se / se_needed).powi(2)).ceil();
            rounds_needed = rounds_needed.max(need.min(u32::MAX as f64) as u32);
        }
        let verdict = if fails {
            Verdict::Fail
        } else if conclusive {
            Verdict::Pass
        } else {
            Verdict::Inconclusive
        };
        any_fail |= fails;
        all_conclusive &= conclusive;
        rows.push(Row {
            param: e.param.clone(),
            element: e.element,
            adjoint: a,
            adjoint_se: a_se,
            adjoint_median: median(&mut e.adjoint.clone()),
            adjoint_share_negative: e.adjoint.iter().filter(|&&x| x < 0.0).count() as f64 / e.adjoint.len().max(1) as f64,
            finite_difference: f,
            finite_difference_se: f_se,
            se,
            z,
            se_needed,
            verdict,
        });
    }
    let combined = if loss == Loss::L1 {
        None
    } else {
        let diffs: Vec<Vec<f64>> = (0..rounds as usize).map(|r| elements.iter().map(|e| e.adjoint[r] - e.fd[r]).collect()).collect();
        hotelling(&diffs)
    };
    let combined_fails = combined.is_some_and(|h| h.p_value < P_FAIL);
    let verdict = if any_fail || combined_fails {
        Verdict::Fail
    } else if all_conclusive {
        Verdict::Pass
    } else {
        Verdict::Inconclusive
    };
    Report { loss: loss.as_str(), spp: 0, primal_spp: 0, rounds, typical_gradient: typical, combined, verdict, rounds_needed, rows }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples `mean + spread · u_r` with a fixed zero-mean sequence u (|u| ≤ 1, sd ≈ 0.58).
    fn samples(mean: f64, spread: f64, rounds: usize, phase: usize) -> Vec<f64> {
        (0..rounds).map(|r| mean + spread * (((r * 7 + phase * 3) % 11) as f64 / 5.0 - 1.0)).collect()
    }

    fn element(k: usize, adjoint: Vec<f64>, fd: Vec<f64>) -> Element {
        Element { param: "p".into(), element: k, k, adjoint, fd }
    }

    #[test]
    fn verdicts_follow_z_power_and_the_combined_statistic() {
        let r = 44;
        // Agreement with standard errors well under 1/53 of the gradient: pass.
        let tight = [element(0, samples(1.0, 0.01, r, 0), samples(1.0, 0.01, r, 5)), element(1, samples(0.5, 0.01, r, 1), samples(0.5, 0.01, r, 7))];
        let rep = assess(&tight, Loss::L2, r as u32);
        assert_eq!(rep.verdict, Verdict::Pass, "{}", rep.table());
        assert!(rep.rows.iter().all(|row| row.verdict == Verdict::Pass && row.z.abs() < 4.0));
        assert!(rep.combined.is_some_and(|h| h.p_value > P_FAIL));
        // The same with a 5 % bias of the first element: its z is far beyond 4.
        let biased = [element(0, samples(1.05, 0.01, r, 0), samples(1.0, 0.01, r, 5)), element(1, samples(0.5, 0.01, r, 1), samples(0.5, 0.01, r, 7))];
        let rep = assess(&biased, Loss::L2, r as u32);
        assert_eq!(rep.verdict, Verdict::Fail);
        assert_eq!(rep.rows[0].verdict, Verdict::Fail);
        assert!(rep.rows[0].z > 4.0);
        // Agreement but spread too wide to see a 10 % bias: inconclusive, never pass, with
        // the standard error needed and more rounds asked for.
        let loose = [element(0, samples(1.0, 0.5, r, 0), samples(1.0, 0.5, r, 5)), element(1, samples(0.5, 0.01, r, 1), samples(0.5, 0.01, r, 7))];
        let rep = assess(&loose, Loss::L2, r as u32);
        assert_eq!(rep.verdict, Verdict::Inconclusive, "{}", rep.table());
        assert_eq!(rep.rows[0].verdict, Verdict::Inconclusive);
        assert!(rep.rows[0].se > rep.rows[0].se_needed && rep.rounds_needed > r as u32);
        assert!(rep.table().contains("verdict: inconclusive"));
        // A zero gradient on both sides, exactly: z 0, and resolved against the typical size.
        let zero = [element(0, vec![0.0; r], vec![0.0; r]), element(1, samples(0.5, 0.01, r, 1), samples(0.5, 0.01, r, 7))];
        let rep = assess(&zero, Loss::L2, r as u32);
        assert_eq!(rep.rows[0].z, 0.0);
        assert_eq!(rep.rows[0].verdict, Verdict::Pass);
        // Exact values that differ: infinite z, fail.
        let exact = [element(0, vec![1.0; r], vec![1.1; r])];
        assert_eq!(assess(&exact, Loss::L2, r as u32).rows[0].verdict, Verdict::Fail);
    }

    /// Three elements each 2.8 standard errors off in the same direction pass one by one
    /// but not together, when their noise is independent.
    #[test]
    fn a_common_bias_below_the_element_threshold_fails_the_combined_test() {
        let r = 60;
        let noise = |phase: u64| -> Vec<f64> {
            // A deterministic pseudo-random sequence per element (splitmix64), roughly uniform on [−1, 1).
            let mut s = phase.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            (0..r)
                .map(|_| {
                    s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
                    let mut z = s;
                    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
                    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
                    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 52) as f64 - 1.0
                })
                .collect()
        };
        let elements: Vec<Element> = (0..3)
            .map(|k| {
                let a: Vec<f64> = noise(10 + k as u64).iter().map(|u| 1.0 + u).collect();
                let f: Vec<f64> = noise(20 + k as u64).iter().map(|u| 1.0 + u).collect();
                element(k, a, f)
            })
            .collect();
        let shifted: Vec<Element> = elements
            .iter()
            .map(|e| {
                let (_, sa) = mean_se(&e.adjoint);
                let (_, sf) = mean_se(&e.fd);
                let (ma, _) = mean_se(&e.adjoint);
                let (mf, _) = mean_se(&e.fd);
                // Move the adjoint's mean to exactly 2.8 combined standard errors above fd.
                let shift = mf + 2.8 * (sa * sa + sf * sf).sqrt() - ma;
                element(e.k, e.adjoint.iter().map(|a| a + shift).collect(), e.fd.clone())
            })
            .collect();
        let rep = assess(&shifted, Loss::L2, r as u32);
        assert!(rep.rows.iter().all(|row| (row.z - 2.8).abs() < 1e-9 && row.verdict != Verdict::Fail), "{}", rep.table());
        let h = rep.combined.unwrap();
        assert!(h.p_value < P_FAIL, "combined p {}", h.p_value);
        assert_eq!(rep.verdict, Verdict::Fail);
    }
}
