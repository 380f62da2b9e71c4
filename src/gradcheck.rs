//! `vkinverse gradcheck`: the adjoint (path replay) gradient of the loss against central
//! finite differences of the loss with common random numbers, per optimised parameter
//! element (a few texels of a texture).
//!
//! Both sides are Monte Carlo estimates, so each is averaged over `rounds` independent
//! seeds and compared within their combined standard error: an element passes when
//! |adjoint − fd| ≤ 4·√(se_adj² + se_fd²) + rel_tol·|fd| + abs_tol. For l2 and relative_l2
//! the finite difference is of the unbiased loss (I1 − T)(I2 − T) over two independent
//! renders; for l1 it is of the plain loss, whose finite difference also carries the
//! derivative of the image noise (shrinking with `primal_spp`); `rel_tol` covers that.

use crate::engine::Engine;
use crate::error::Result;
use crate::gpu::{CommandBuffer, Context};
use crate::render::gradient::GradientPass;
use crate::scene::Scene;
use crate::settings::RunSettings;
use serde::Serialize;
use std::sync::Arc;

/// How to check.
#[derive(Clone, Debug)]
pub struct Options {
    pub spp: u32,
    pub primal_spp: u32,
    pub rounds: u32,
    pub step: f32,
    pub rel_tol: f64,
    pub abs_tol: f64,
    /// At most this many elements per parameter (texels are spread over the texture).
    pub max_elements: usize,
    pub seed: u32,
}

impl Default for Options {
    fn default() -> Self {
        Options { spp: 16, primal_spp: 16, rounds: 4, step: 0.01, rel_tol: 0.1, abs_tol: 1e-6, max_elements: 4, seed: 1 }
    }
}

/// One checked element.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub param: String,
    pub element: usize,
    pub adjoint: f64,
    pub adjoint_se: f64,
    pub finite_difference: f64,
    pub finite_difference_se: f64,
    pub relative_error: f64,
    pub pass: bool,
}

fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    if v.len() < 2 {
        return (m, 0.0);
    }
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// Checks every optimised parameter of `scene` at its initial values.
pub fn gradcheck(ctx: &Arc<Context>, scene: &Scene, opts: &Options) -> Result<Vec<Row>> {
    // The gradient estimate of an optimisation iteration at the options' sample counts.
    let mut settings = RunSettings::of_scene(scene);
    (settings.spp, settings.primal_spp, settings.seed) = (opts.spp, opts.primal_spp, opts.seed as u64);
    let engine = Engine::gradient_only(ctx, scene, &settings)?;
    let (gs, ops, grad, pass, target_images) = (engine.scene(), &engine.ops, &engine.grad, &engine.gradient, &engine.targets);
    let n = gs.layout.len.max(1);
    let mut grad_cmd = CommandBuffer::new(ctx, "gradient")?;
    grad_cmd.record(|rec| engine.record_gradient(rec, None))?;
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
        if loss_kind == crate::settings::Loss::L1 {
            return Ok(a.total_loss()?);
        }
        let mut total = 0.0;
        for (s, t) in target_images.iter().enumerate() {
            let (i1, i2) = (a.rendered(s, gs)?, b.rendered(s, gs)?);
            let mut sum = 0.0f64;
            for ((p1, p2), pt) in i1.data.iter().zip(&i2.data).zip(&t.data) {
                for c in 0..3 {
                    let tc = pt[c] as f64;
                    let w = if loss_kind == crate::settings::Loss::RelativeL2 { 1.0 / (tc * tc + 0.01) } else { 1.0 };
                    sum += (p1[c] as f64 - tc) * (p2[c] as f64 - tc) * w;
                }
            }
            total += sum / (3.0 * i1.data.len() as f64);
        }
        Ok(total)
    };
    let theta0 = gs.layout.initial();

    // Adjoint: `rounds` independent estimates.
    let mut adj: Vec<Vec<f64>> = vec![Vec::new(); gs.layout.len];
    for r in 0..opts.rounds {
        gs.set_theta(theta0.clone())?;
        grad.write(&vec![0f32; n])?;
        gs.set_frame(r)?;
        grad_cmd.submit_and_wait()?;
        let g: Vec<f32> = grad.read()?;
        for (k, v) in adj.iter_mut().enumerate() {
            v.push(g[k] as f64);
        }
    }

    let mut rows = Vec::new();
    for slot in &gs.layout.slots {
        let count = slot.len.min(opts.max_elements);
        let stride = (slot.len / count.max(1)).max(1);
        for e in (0..slot.len).step_by(stride).take(count) {
            let k = slot.offset + e;
            // Central differences, clamped inside the parameter's range.
            let lo = (theta0[k] - opts.step).max(slot.range[0]);
            let hi = (theta0[k] + opts.step).min(slot.range[1]);
            let mut fd = Vec::new();
            for r in 0..opts.rounds {
                // The same frame (seed) for both sides: common random numbers.
                gs.set_frame(1000 + r)?;
                let mut at = |x: f32| -> Result<f64> {
                    let mut t = theta0.clone();
                    t[k] = x;
                    gs.set_theta(t)?;
                    loss_cmd.submit_and_wait()?;
                    unbiased_loss(&pass, &second)
                };
                let (lp, lm) = (at(hi)?, at(lo)?);
                fd.push((lp - lm) / (hi - lo) as f64);
            }
            let (a, a_se) = mean_se(&adj[k]);
            let (f, f_se) = mean_se(&fd);
            let bound = 4.0 * (a_se * a_se + f_se * f_se).sqrt() + opts.rel_tol * f.abs() + opts.abs_tol;
            rows.push(Row {
                param: slot.name.clone(),
                element: e,
                adjoint: a,
                adjoint_se: a_se,
                finite_difference: f,
                finite_difference_se: f_se,
                relative_error: (a - f).abs() / f.abs().max(1e-12),
                pass: (a - f).abs() <= bound,
            });
        }
    }
    gs.set_theta(theta0)?;
    Ok(rows)
}
