//! Differentiable rendering: the image losses and the path-replay adjoint gradients of
//! glsl/lib/integrator.glsl against finite differences, the gradient's linearity over
//! sensors, exact zeros for parameters the image does not depend on, and constant memory
//! over a long resubmitted gradient loop.
//!
//! # How the adjoint is checked (`measure`)
//! Each round r:
//! 1. the recorded [`GradientPass`] runs at θ₀ with iteration counter r: primal image
//!    I_r → loss → adjoint pass, whose gradient is a_r;
//! 2. the loss and δ_r = dLoss/dI_r are recomputed on the CPU from I_r with the formulas
//!    of glsl/loss.comp, and the loss value must equal the kernel's;
//! 3. per probed element k, the scene is rendered at θ₀ ± h·e_k with the adjoint pass's
//!    own seed, sample count and counter, i.e. along the very sample paths the adjoint
//!    replayed (common random numbers), and f_r = Σ_p δ_r(p)·(I₊(p) − I₋(p)) / 2h.
//!
//! δ_r comes from the primal stream, independent of the adjoint stream, so
//! E[f_r] = Σ_p E[δ(p)]·(E[I](θ₀ + h)(p) − E[I](θ₀ − h)(p)) / 2h, and the adjoint is
//! unbiased exactly when E[a_r − f_r] = 0 up to the central difference's truncation error.
//! Finite differences of the loss value itself (`vkinverse::gradcheck`) also pick up
//! d Var(I)/dθ of the noisy primal image (on the Cornell red wall under relative_l2 the
//! red channel's difference was off by 24 % at 16 primal spp and 9 % at 64, 3 σ each), so
//! they cannot be held to a tight threshold; the chain-rule split has no such term.
//!
//! Sharing the paths cancels most of the Monte Carlo noise in d_r = a_r − f_r. Where the
//! sampling does not depend on θ (diffuse colours without Russian roulette, emission, the
//! environment) the adjoint must be the exact derivative of each sample and d_r is float
//! rounding only. Where it does (the principled lobe choice, GGX visible-normal
//! directions, Russian roulette), I± follow paths that move with θ and d_r is a zero-mean
//! random variable; its standard error over rounds sets the threshold. An element passes
//! when |mean d| ≤ 4·se(d) + ε·mean(Σ_p |term_p|), the terms being those f_r sums: ε
//! bounds the difference's truncation and float rounding, which scale with the terms
//! (they can cancel in f_r), and is stated per test. Every test also asserts that the same
//! criterion rejects the adjoint with its sign flipped or scaled by 1 ± R (R per test).

use crate::common;

use common::scenes::{lit_quad, temp_dir};
use common::with_gpu;
use std::sync::Arc;
use vkinverse::gpu::{Buffer, CommandBuffer, Context, MemoryKind};
use vkinverse::image::Image;
use vkinverse::ops::BufferOps;
use vkinverse::render::gradient::{GradientInputs, GradientPass, SEED_ADJOINT};
use vkinverse::render::{GpuScene, PrimalRenderer};
use vkinverse::scene::{Loss, Scene, TextureValue as _};

// ---------------------------------------------------------------------------------------
// Scenes
// ---------------------------------------------------------------------------------------

const CORNELL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cornell/meshes");
const SPIRAL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/spiral/meshes");

/// Writes `files` and `scene.toml` into a fresh temp dir and loads the scene.
fn load(name: &str, toml: &str, files: &[(&str, &str)]) -> Scene {
    let dir = temp_dir(&format!("gradients-{name}"));
    for (f, text) in files {
        std::fs::write(dir.join(f), text).unwrap();
    }
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    Scene::load(dir.join("scene.toml")).unwrap()
}

/// scenes/cornell at `film`² pixels with `extra` tables (sensors, materials, meshes; their
/// `files` are written beside the scene) and `[optimise]` body `optimise`. Mesh names are
/// the OBJ stems (floor, ceiling, back, left, right, short_box, tall_box, light).
fn cornell(name: &str, film: u32, max_depth: u32, extra: &str, files: &[(&str, &str)], optimise: &str) -> Scene {
    let m = CORNELL;
    let toml = format!(
        r#"
[film]
width = {film}
height = {film}
[integrator]
max_depth = {max_depth}
rr_depth = 5
[[sensors]]
origin = [0, 1, 3.9]
target = [0, 1, 0]
up = [0, 1, 0]
fov_y = 39.3
[[materials]]
name = "white"
type = "diffuse"
base_color = [0.725, 0.71, 0.68]
[[materials]]
name = "red"
type = "diffuse"
base_color = [0.63, 0.065, 0.05]
[[materials]]
name = "green"
type = "diffuse"
base_color = [0.14, 0.45, 0.091]
[[materials]]
name = "light"
type = "diffuse"
base_color = [0.78, 0.78, 0.78]
[[meshes]]
file = "{m}/floor.obj"
material = "white"
[[meshes]]
file = "{m}/ceiling.obj"
material = "white"
[[meshes]]
file = "{m}/back.obj"
material = "white"
[[meshes]]
file = "{m}/left.obj"
material = "red"
[[meshes]]
file = "{m}/right.obj"
material = "green"
[[meshes]]
file = "{m}/short_box.obj"
material = "white"
[[meshes]]
file = "{m}/tall_box.obj"
material = "white"
[[meshes]]
file = "{m}/light.obj"
material = "light"
emission = [17.0, 12.0, 4.0]
{extra}
[optimise]
{optimise}
"#
    );
    load(name, &toml, files)
}

/// scenes/spiral at `film`² pixels: a metallic ribbon with smooth normals and a glossy
/// ball on a floor, under an area light and a constant sky.
fn spiral(name: &str, film: u32, optimise: &str) -> Scene {
    let m = SPIRAL;
    let toml = format!(
        r#"
[film]
width = {film}
height = {film}
[integrator]
max_depth = 4
rr_depth = 5
[[sensors]]
origin = [0, 1.4, 3.2]
target = [0, 0.55, 0]
up = [0, 1, 0]
fov_y = 40
[[materials]]
name = "ribbon"
type = "principled"
base_color = [0.9, 0.55, 0.2]
roughness = 0.3
metallic = 0.8
[[materials]]
name = "ball"
type = "principled"
base_color = [0.1, 0.3, 0.8]
roughness = 0.15
metallic = 0.0
[[materials]]
name = "floor"
type = "diffuse"
base_color = [0.5, 0.5, 0.5]
[[materials]]
name = "light"
type = "diffuse"
base_color = [0.0, 0.0, 0.0]
[[meshes]]
file = "{m}/floor.obj"
material = "floor"
[[meshes]]
file = "{m}/ribbon.obj"
material = "ribbon"
[[meshes]]
file = "{m}/ball.obj"
material = "ball"
[[meshes]]
file = "{m}/light.obj"
material = "light"
emission = [6.0, 6.0, 6.0]
[environment]
constant = [0.35, 0.4, 0.5]
[optimise]
{optimise}
"#
    );
    load(name, &toml, &[])
}

/// A principled textured quad seen at 40°, lit by an area light whose glossy reflection is
/// in view and by a constant sky ([`lit_quad`]). The quad cannot see itself, so the image is
/// linear in its base colour and metallic (not in roughness).
fn glossy(name: &str, film: u32, optimise: &str) -> Scene {
    glossy_with(name, film, "", optimise)
}

/// [`glossy`] with `floor` added to the floor's material (`normals.exr` lies beside it).
fn glossy_with(name: &str, film: u32, floor: &str, optimise: &str) -> Scene {
    let floor = format!("type = \"principled\"\nbase_color = [0.7, 0.4, 0.2]\nroughness = 0.35\nmetallic = 0.4\n{floor}");
    Scene::load(lit_quad(&format!("gradients-{name}"), film, &floor, "constant = [0.3, 0.35, 0.4]", optimise)).unwrap()
}

/// A diffuse quad lit by the area light of [`glossy`] and by a 16 × 8 lat-long map with one
/// bright texel (over the quad, about 34° from the zenith) on a dim sky: next-event
/// estimation picks the light or the map with probability ½ each, and the map by its
/// (non-uniform) distribution.
fn env_lit(name: &str, film: u32, optimise: &str) -> Scene {
    Scene::load(common::scenes::sky_lit_quad(&format!("gradients-{name}"), film, optimise)).unwrap()
}

// ---------------------------------------------------------------------------------------
// Adjoint against finite differences
// ---------------------------------------------------------------------------------------

/// The loss of `rendered` against `target` and its gradient with respect to every pixel
/// channel, as glsl/loss.comp defines them: the mean over pixels and channels of
/// l2 (I − T)², l1 |I − T|, relative_l2 (I − T)² / (T² + 0.01).
fn cpu_loss(loss: Loss, rendered: &Image, target: &Image) -> (f64, Vec<[f64; 3]>) {
    let scale = 1.0 / (3.0 * rendered.data.len() as f64);
    let mut value = 0.0;
    let grad = rendered
        .data
        .iter()
        .zip(&target.data)
        .map(|(i, t)| {
            let mut g = [0.0; 3];
            for c in 0..3 {
                let t = t[c] as f64;
                let d = i[c] as f64 - t;
                let (v, dv) = match loss {
                    Loss::L2 => (d * d, 2.0 * d),
                    Loss::L1 => (
                        d.abs(),
                        if d > 0.0 {
                            1.0
                        } else if d < 0.0 {
                            -1.0
                        } else {
                            0.0
                        },
                    ),
                    Loss::RelativeL2 => {
                        let w = 1.0 / (t * t + 0.01);
                        (d * d * w, 2.0 * d * w)
                    }
                };
                value += v * scale;
                g[c] = dv * scale;
            }
            g
        })
        .collect();
    (value, grad)
}

/// Seed of rendered targets, apart from the gradient pass's streams.
const TARGET_SEED: u32 = 0x7A46_E701;

/// A scene on the device and one recorded gradient estimate of it.
struct Bench {
    renderer: PrimalRenderer,
    grad: Buffer,
    pass: GradientPass,
    cmd: CommandBuffer,
    targets: Vec<Image>,
    loss: Loss,
    _ops: BufferOps,
}

impl Bench {
    /// Targets are the reference scene rendered at `target_spp` (any fixed image defines
    /// a loss; its noise does not matter).
    fn new(ctx: &Arc<Context>, scene: &Scene, loss: Loss, spp: u32, primal_spp: u32, target_spp: u32) -> Self {
        let renderer = PrimalRenderer::new(GpuScene::new(ctx, scene).unwrap()).unwrap();
        let gs = &renderer.scene;
        gs.set_theta(gs.layout.reference()).unwrap();
        gs.set_frame(0).unwrap();
        let targets: Vec<Image> = (0..gs.sensors).map(|s| renderer.render(s as u32, target_spp, TARGET_SEED, |_, _| {}).unwrap()).collect();
        Self::with_targets(renderer, targets, loss, spp, primal_spp)
    }

    fn with_targets(renderer: PrimalRenderer, targets: Vec<Image>, loss: Loss, spp: u32, primal_spp: u32) -> Self {
        let gs = &renderer.scene;
        let ctx = &gs.ctx;
        gs.set_theta(gs.layout.initial()).unwrap();
        let ops = BufferOps::new(ctx).unwrap();
        let grad = Buffer::zeroed::<f32>(ctx, "grad", gs.layout.len.max(1), MemoryKind::Device).unwrap();
        let pass = GradientPass::new(
            gs,
            &ops,
            &GradientInputs { targets: &targets, loss, spp, primal_spp, seed: 1, theta: &gs.theta, theta_prev: None, grad: &grad, grad_half: None },
        )
        .unwrap();
        let mut cmd = CommandBuffer::new(ctx, "gradient").unwrap();
        cmd.record(|rec| pass.record(rec, gs, &ops)).unwrap();
        Bench { renderer, grad, pass, cmd, targets, loss, _ops: ops }
    }

    fn scene(&self) -> &GpuScene {
        &self.renderer.scene
    }

    /// One gradient estimate at `theta` with iteration counter `frame`: the gradient and,
    /// per sensor, dLoss/dI of the primal image it used (after checking the kernel's loss
    /// value against [`cpu_loss`]).
    fn estimate(&mut self, theta: &[f32], frame: u32) -> (Vec<f32>, Vec<Vec<[f64; 3]>>) {
        let gs = &self.renderer.scene;
        gs.set_theta(theta.to_vec()).unwrap();
        self.grad.write(&vec![0f32; gs.layout.len.max(1)]).unwrap();
        gs.set_frame(frame).unwrap();
        self.cmd.submit_and_wait().unwrap();
        let g: Vec<f32> = self.grad.read().unwrap();
        let mut deltas = Vec::new();
        for s in 0..gs.sensors {
            let img = self.pass.rendered(s, gs).unwrap();
            let (value, delta) = cpu_loss(self.loss, &img, &self.targets[s]);
            let gpu = self.pass.loss_value(s).unwrap() as f64;
            // A float32 tree sum of a few hundred non-negative terms is good to ~1e-6.
            assert!((gpu - value).abs() <= 1e-5 * value.abs(), "{:?} loss kernel {gpu} vs CPU {value}", self.loss);
            deltas.push(delta);
        }
        (g, deltas)
    }

    /// Every sensor rendered at `theta` along the adjoint pass's sample paths of
    /// iteration `frame` (same seed, sample indices and count).
    fn render_adjoint_paths(&self, theta: &[f32], frame: u32) -> Vec<Image> {
        let gs = &self.renderer.scene;
        gs.set_theta(theta.to_vec()).unwrap();
        gs.set_frame(frame).unwrap();
        let seed = self.pass.seed.wrapping_add(SEED_ADJOINT);
        (0..gs.sensors).map(|s| self.renderer.render(s as u32, self.pass.spp, seed, |_, _| {}).unwrap()).collect()
    }
}

/// θ elements perturbed together by ±h (or +h against θ₀ when `forward`). Elements of one
/// probe must be distinct colour channels of one parameter or texel, or a single scalar:
/// every colour parameter here is separable by channel (image channel c depends on
/// channel c only, in expectation), so each element reads its own image channel.
struct Probe {
    elements: Vec<usize>,
    h: f32,
    forward: bool,
}

fn probe(elements: impl IntoIterator<Item = usize>, h: f32) -> Probe {
    Probe { elements: elements.into_iter().collect(), h, forward: false }
}

/// Per-round adjoint and finite-difference samples of one θ element.
#[derive(Debug, Clone)]
struct Samples {
    name: String,
    element: usize,
    adjoint: Vec<f64>,
    fd: Vec<f64>,
    /// Σ_p |δ_r(p)·(I₊(p) − I₋(p))| / 2h: the size of the terms the difference sums, the
    /// scale of its rounding and truncation errors (terms of both signs can cancel in fd).
    magnitude: Vec<f64>,
}

fn mean_se(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

/// See the module documentation; θ₀ is the parameters' `init`.
fn measure(b: &mut Bench, probes: &[Probe], rounds: u32) -> Vec<Samples> {
    let theta0 = b.scene().layout.initial();
    measure_at(b, &theta0, probes, rounds)
}

fn measure_at(b: &mut Bench, theta0: &[f32], probes: &[Probe], rounds: u32) -> Vec<Samples> {
    let layout = b.scene().layout.clone();
    let mut out = Vec::new();
    for p in probes {
        for &k in &p.elements {
            let slot = layout.slots.iter().find(|s| k >= s.offset && k < s.offset + s.len).unwrap();
            let (name, element) = (slot.name.clone(), k - slot.offset);
            out.push(Samples { name, element, adjoint: Vec::new(), fd: Vec::new(), magnitude: Vec::new() });
        }
    }
    for r in 0..rounds {
        let (g, deltas) = b.estimate(theta0, r);
        let mut o = 0;
        for p in probes {
            let mut plus = theta0.to_vec();
            let mut minus = theta0.to_vec();
            for &k in &p.elements {
                plus[k] += p.h;
                if !p.forward {
                    minus[k] -= p.h;
                }
            }
            let ip = b.render_adjoint_paths(&plus, r);
            let im = b.render_adjoint_paths(&minus, r);
            let width = if p.forward { p.h } else { 2.0 * p.h } as f64;
            for &k in &p.elements {
                let slot = layout.slots.iter().find(|s| k >= s.offset && k < s.offset + s.len).unwrap();
                let channels = if slot.shape.channels() == 3 { (k - slot.offset) % 3..(k - slot.offset) % 3 + 1 } else { 0..3 };
                let (mut fd, mut magnitude) = (0.0, 0.0);
                for (s, delta) in deltas.iter().enumerate() {
                    for (px, d) in delta.iter().enumerate() {
                        for c in channels.clone() {
                            let term = d[c] * (ip[s].data[px][c] as f64 - im[s].data[px][c] as f64) / width;
                            fd += term;
                            magnitude += term.abs();
                        }
                    }
                }
                out[o].adjoint.push(g[k] as f64);
                out[o].fd.push(fd);
                out[o].magnitude.push(magnitude);
                o += 1;
            }
        }
    }
    out
}

/// Standard errors of the paired difference allowed before a disagreement counts.
const Z: f64 = 4.0;

/// Whether `scale` × the adjoint agrees with the finite differences:
/// |mean(scale·a − f)| ≤ Z·se(scale·a − f) + eps·mean(magnitude).
fn agrees(s: &Samples, scale: f64, eps: f64) -> bool {
    let d: Vec<f64> = s.adjoint.iter().zip(&s.fd).map(|(a, f)| scale * a - f).collect();
    let (dm, dse) = mean_se(&d);
    let (magnitude, _) = mean_se(&s.magnitude);
    dm.abs() <= Z * dse + eps * magnitude
}

/// Asserts that every element agrees within `eps` and that the same criterion rejects
/// the adjoint negated or scaled by 1 ± `resolution`. Prints one line per element.
fn check(what: &str, samples: &[Samples], eps: f64, resolution: f64) {
    for s in samples {
        let (a, a_se) = mean_se(&s.adjoint);
        let (f, f_se) = mean_se(&s.fd);
        let d: Vec<f64> = s.adjoint.iter().zip(&s.fd).map(|(a, f)| a - f).collect();
        let (dm, dse) = mean_se(&d);
        let (magnitude, _) = mean_se(&s.magnitude);
        let line = format!(
            "{what}: {}[{}] adjoint {a:.5e} ± {a_se:.1e}, fd {f:.5e} ± {f_se:.1e}, \
             difference {:+.2e} ± {:.1e} of fd (z {:+.2}; Σ|terms| = {:.1} |fd|)",
            s.name,
            s.element,
            dm / f.abs(),
            dse / f.abs(),
            dm / dse.max(f64::MIN_POSITIVE),
            magnitude / f.abs()
        );
        eprintln!("{line}");
        assert!(f.abs() > 0.0 && f.is_finite(), "{line}: the image must depend on the element");
        assert!(agrees(s, 1.0, eps), "{line}: the adjoint disagrees with finite differences");
        for wrong in [-1.0, 1.0 - resolution, 1.0 + resolution] {
            assert!(!agrees(s, wrong, eps), "{line}: the check cannot tell the adjoint from {wrong} × itself");
        }
    }
}

// ---------------------------------------------------------------------------------------
// Tests: adjoint against finite differences
// ---------------------------------------------------------------------------------------

/// ε where the adjoint is the exact derivative of each sample: the images are float32 and
/// their difference is divided by 2h. The largest mean residue measured is 1.8e-5 of the
/// terms' size (the furnace below, 1.1e-5 of it truncation); 1e-4 leaves margin while a
/// 1 % error is 100 times larger.
const EPS_EXACT: f64 = 1e-4;

/// Diffuse base colour (the Cornell red wall) and mesh emission (its light), under each
/// loss. Cosine sampling, emitter choice (by area when emission is optimised) and the
/// camera do not depend on either, and max depth 4 < rr_depth 5 keeps roulette out, so
/// every replayed sample's adjoint must be the derivative of that sample: 8 rounds of
/// 4 spp at 16² suffice, and a 1 % scale error is rejected (measured: means within
/// 5e-5 of fd, mostly within 3e-6). The red wall cannot see itself, so the image is at
/// most quadratic in its colour at depth 4 and the central difference has no truncation
/// error; it is linear in emission. The emission is set far from the reference in every
/// channel (dark red and green light, bright blue) so that each channel's gradient is
/// significant under every loss.
#[test]
fn diffuse_colour_and_emission_gradients_are_exact_for_every_loss() {
    with_gpu(|ctx| {
        let optimise = r#"
[[optimise.params]]
target = "materials.red.base_color"
init = [0.5, 0.5, 0.5]
range = [0.0, 1.0]
[[optimise.params]]
target = "meshes.light.emission"
init = [6.0, 20.0, 8.0]
range = [0.0, 50.0]
"#;
        let scene = cornell("losses", 16, 4, "", &[], optimise);
        for loss in [Loss::L2, Loss::L1, Loss::RelativeL2] {
            let mut b = Bench::new(ctx, &scene, loss, 4, 4, 16);
            let samples = measure(&mut b, &[probe(0..3, 0.01), probe(3..6, 0.5)], 8);
            check(loss.as_str(), &samples, EPS_EXACT, 0.01);
            if loss == Loss::L2 {
                // An optimised emission at exactly 0 (a range bound, where optimisers park
                // it) still has a derivative. Forward difference: the central one would
                // leave the range; the image is linear in emission, so it is exact too.
                let mut theta0 = b.scene().layout.initial();
                theta0[3..6].fill(0.0);
                let forward = Probe { elements: vec![3, 4, 5], h: 0.5, forward: true };
                check("l2, emission 0", &measure_at(&mut b, &theta0, &[forward], 4), EPS_EXACT, 0.01);
            }
        }
    });
}

/// Russian roulette on every bounce from depth 2, up to depth 8, inside a closed emitting
/// sphere (a white furnace) whose diffuse red channel is 1: the path throughput's largest
/// channel stays ≥ 1, so the survival probability is the constant 0.95 and does not move
/// with the green and blue channels probed here or with the emission. The adjoint's
/// bookkeeping of roulette (throughput divided by the survival probability, the radiance
/// still to come along the path) must then give the exact per-sample derivative again.
/// The image is a degree-7 polynomial in the colour, whose central difference at h = 0.01
/// is off by 2.5e-4; h = 0.002 cuts that to 1e-5, under [`EPS_EXACT`]. (Where survival
/// depends on θ, as in the Cornell box with rr_depth 2, the red wall's colour gradient
/// agreed with finite differences to −0.4 % ± 2 % over 400 rounds, too slow for here.)
#[test]
fn gradients_are_exact_under_russian_roulette() {
    with_gpu(|ctx| {
        let toml = r#"
[film]
width = 16
height = 16
[integrator]
max_depth = 8
rr_depth = 2
[[sensors]]
origin = [0.1, -0.2, 0.3]
target = [0, 0, -1]
up = [0, 1, 0]
fov_y = 70
[[materials]]
name = "inside"
type = "diffuse"
base_color = [1.0, 0.6, 0.3]
[[meshes]]
file = "sphere.obj"
material = "inside"
emission = [1.0, 1.0, 1.0]
[optimise]
[[optimise.params]]
target = "materials.inside.base_color"
init = [1.0, 0.45, 0.2]
range = [0.0, 1.0]
[[optimise.params]]
target = "meshes.sphere.emission"
init = [0.8, 0.8, 0.8]
range = [0.0, 10.0]
"#;
        let scene = load("roulette", toml, &[("sphere.obj", &common::scenes::sphere_obj(2.0, 2, true))]);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        let samples = measure(&mut b, &[probe(1..3, 0.002), probe(3..6, 0.1)], 8);
        check("l2", &samples, EPS_EXACT, 0.01);
    });
}

/// Principled material on a textured quad: metallic, roughness and a 4 × 4 base-colour
/// texture. The lobe choice depends on base colour and metallic, the GGX visible-normal
/// directions on roughness, so the replayed paths move with θ and the comparison is
/// statistical: 48 rounds of 8 spp at 16². Steps: the image is linear in metallic and
/// base colour here (the quad cannot see itself), so h = 0.2 / 0.1 costs no truncation
/// and keeps the lobe-switch jumps of the difference frequent enough to average (at
/// h = 0.01 the rare large jumps gave |z| up to 6.6 over 16 rounds). In roughness the
/// difference at h = 0.1 is off by −3.1 % (14 σ over 1024 rounds), so h = 0.03 leaves
/// ≈ 0.3 %, covered by ε = 1 % of the terms' size (2.7 |fd| here). Texels probed: two
/// corners and two inside, all three channels each; the initial texture is off the
/// reference in every channel. Measured standard errors of the difference: 1.5 % of fd
/// for metallic and roughness, 0.1–0.5 % for texels; a 20 % scale error is rejected.
#[test]
fn principled_and_texture_gradients_match_finite_differences() {
    with_gpu(|ctx| check_principled(ctx, &glossy("principled", 16, &principled_optimise(0.3)), &[0, 5, 10, 15]));
}

/// The `[optimise]` body of the principled tests: metallic from `metallic`, roughness from
/// 0.6 and a 4 × 4 base-colour texture off the reference in every channel.
fn principled_optimise(metallic: f32) -> String {
    format!(
        r#"
[[optimise.params]]
target = "materials.floor.metallic"
init = {metallic}
range = [0.0, 1.0]
[[optimise.params]]
target = "materials.floor.roughness"
init = 0.6
range = [0.05, 1.0]
[[optimise.params]]
target = "materials.floor.base_color"
init = [0.4, 0.6, 0.4]
range = [0.0, 1.0]
texture = [4, 4]
"#
    )
}

/// The checks of [`principled_and_texture_gradients_match_finite_differences`] on `scene`
/// (a quad of [`principled_optimise`]): metallic and the base-colour texels `texels`, then
/// roughness, 48 rounds of 8 spp each.
fn check_principled(ctx: &Arc<Context>, scene: &Scene, texels: &[usize]) {
    let mut b = Bench::new(ctx, scene, Loss::L2, 8, 8, 16);
    let mut probes = vec![probe([0], 0.2)];
    probes.extend(texels.iter().map(|t| probe(2 + 3 * t..5 + 3 * t, 0.1)));
    let metallic = measure(&mut b, &probes, 48);
    check("l2", &metallic, EPS_EXACT, 0.2);
    let roughness = measure(&mut b, &[probe([1], 0.03)], 48);
    check("l2", &roughness, 0.01, 0.2);
}

/// The same with a normal map on the quad (4 × 4 texels, tilts up to 30°, bilinear): the
/// map perturbs the shading normal of every path vertex on the quad, in the primal, the
/// replay and the finite differences alike, and is no parameter. Metallic starts at 0.9:
/// from 0.3 its gradient here is too small for the check to tell the adjoint from its
/// negative in 48 rounds.
#[test]
fn normal_mapped_principled_gradients_match_finite_differences() {
    with_gpu(|ctx| {
        let scene = glossy_with("normal-mapped", 16, "normal_map = { texture = \"normals.exr\", scale = 0.8 }", &principled_optimise(0.9));
        assert!(GpuScene::new(ctx, &scene).unwrap().has("HAS_NORMAL_MAPS"), "the kernels are built with normal maps");
        check_principled(ctx, &scene, &[5, 10]);
    });
}

/// The environment: a constant sky (spiral scene) and a 4 × 2 lat-long map (the glossy
/// quad; the map is light-sampled, from a distribution built from θ's start value and
/// fixed after, half of the next-event samples besides the area light's). Environment
/// lookups are continuous in the parameter and nothing samples by it, so the adjoint is
/// exact per sample (4 rounds). Then a fixed, non-uniform map (a bright texel, [`env_lit`])
/// sampled beside an area light: the diffuse colour it lights through next-event
/// estimation, MIS-weighted escapes and emitter hits, and the light's emission, are exact
/// per sample too (cosine sampling, the light choice and both light distributions do not
/// depend on them; max depth 3 < rr_depth 5). The spiral's ribbon colour adds a
/// principled material with smooth shading normals that sees itself; its lobe choice
/// moves with the colour, so it is statistical (32 rounds of 8 spp, standard error of the
/// difference 0.3–0.5 % of fd; the image is a polynomial in the colour dominated by its
/// linear part, and h = 0.05 leaves ≲ 1e-4 of truncation, under ε = 1e-3).
#[test]
fn environment_gradients_match_finite_differences() {
    with_gpu(|ctx| {
        let optimise = r#"
[[optimise.params]]
target = "environment"
init = [0.6, 0.2, 0.8]
range = [0.0, 2.0]
[[optimise.params]]
target = "materials.ribbon.base_color"
init = [0.5, 0.8, 0.5]
range = [0.0, 1.0]
"#;
        let scene = spiral("environment", 16, optimise);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 8, 8, 16);
        check("l2", &measure(&mut b, &[probe(0..3, 0.05)], 4), EPS_EXACT, 0.01);
        check("l2", &measure(&mut b, &[probe(3..6, 0.05)], 32), 1e-3, 0.2);

        let optimise = r#"
[[optimise.params]]
target = "environment"
init = [0.6, 0.2, 0.8]
range = [0.0, 2.0]
texture = [4, 2]
"#;
        let scene = glossy("environment-map", 16, optimise);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        let texels: Vec<Probe> = (0..8).map(|t| probe(3 * t..3 * t + 3, 0.05)).collect();
        check("l2", &measure(&mut b, &texels, 4), EPS_EXACT, 0.01);

        let optimise = r#"
[[optimise.params]]
target = "materials.floor.base_color"
init = [0.4, 0.6, 0.5]
range = [0.0, 1.0]
[[optimise.params]]
target = "meshes.light.emission"
init = [3.0, 9.0, 5.0]
range = [0.0, 50.0]
"#;
        let scene = env_lit("environment-nee", 16, optimise);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        assert!(b.scene().environment_sampling(), "the map is light-sampled");
        check("l2", &measure(&mut b, &[probe(0..3, 0.01), probe(3..6, 0.5)], 4), EPS_EXACT, 0.01);
    });
}

/// An emission texture: the area light of [`lit_quad`](common::scenes::lit_quad) optimised
/// as 2 × 2 texels, which light the diffuse floor through next-event estimation (the
/// texture read at the sampled point of the light) and through BSDF samples that hit the
/// light (read where they hit). The image is linear in every texel and neither strategy
/// depends on them (emitters are picked by area when emission is optimised), so the
/// adjoint must be exact per sample, texel by texel.
#[test]
fn emission_texture_gradients_are_exact() {
    with_gpu(|ctx| {
        let optimise = "[[optimise.params]]\ntarget = \"meshes.light.emission\"\ninit = [3.0, 9.0, 5.0]\nrange = [0.0, 50.0]\ntexture = [2, 2]\n";
        let floor = "type = \"diffuse\"\nbase_color = [0.7, 0.4, 0.2]";
        let scene = Scene::load(common::scenes::lit_quad("gradients-emission-texture", 16, floor, "constant = [0.1, 0.1, 0.1]", optimise)).unwrap();
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        assert!(b.scene().has("HAS_EMISSION_TEXTURES"));
        let texels: Vec<Probe> = (0..4).map(|t| probe(3 * t..3 * t + 3, 0.5)).collect();
        check("l2", &measure(&mut b, &texels, 4), EPS_EXACT, 0.01);
    });
}

/// Hidden emitters (`hide_emitters = true`): the lit quad of
/// [`lit_quad`](common::scenes::lit_quad) seen from below its light, so that the camera
/// sees the light's emitting face, the floor and the sky, and the camera rays pass through
/// the light and find no sky. The sky and the light still light the floor, through
/// next-event estimation and BSDF samples: the gradients of both must leave out what the
/// camera no longer sees, exactly (the image is linear in each, and nothing samples by
/// them), also for the floor's colour.
#[test]
fn hidden_emitter_gradients_are_exact() {
    with_gpu(|ctx| {
        let optimise = "[[optimise.params]]\ntarget = \"environment\"\ninit = [0.6, 0.2, 0.8]\nrange = [0.0, 2.0]\n\
                        [[optimise.params]]\ntarget = \"meshes.light.emission\"\ninit = [3.0, 9.0, 5.0]\nrange = [0.0, 50.0]\n\
                        [[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.4, 0.6, 0.5]\nrange = [0.0, 1.0]\n";
        let floor = "type = \"diffuse\"\nbase_color = [0.7, 0.4, 0.2]";
        let path = common::scenes::lit_quad("gradients-hidden-emitters", 16, floor, "constant = [0.2, 0.2, 0.2]", optimise);
        let toml = std::fs::read_to_string(&path).unwrap();
        let toml = toml
            .replace("rr_depth = 5", "rr_depth = 5\nhide_emitters = true")
            .replace("origin = [0, 1.2, 1.8]\ntarget = [0, 0, -0.1]", "origin = [0, 0.6, 1.8]\ntarget = [0, 1.0, -0.5]");
        std::fs::write(&path, toml).unwrap();
        let scene = Scene::load(path).unwrap();
        assert!(scene.integrator.hide_emitters && scene.sensors[0].origin.y == 0.6);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        check("hidden", &measure(&mut b, &[probe(0..3, 0.05), probe(3..6, 0.5), probe(6..9, 0.05)], 4), EPS_EXACT, 0.01);
    });
}

/// A floor whose diffuse colour is a texture looked up at its nearest texel
/// (`filter = "nearest"`), optimised as 2 × 2 texels that keep the filter: each point of
/// the floor reads one texel, in the primal, the replay and the finite differences alike,
/// so the adjoint is exact per sample, texel by texel.
#[test]
fn nearest_texture_gradients_are_exact() {
    with_gpu(|ctx| {
        let optimise = "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.3, 0.6, 0.9]\nrange = [0.0, 1.0]\ntexture = [2, 2]\n";
        let floor = "type = \"diffuse\"\nbase_color = { texture = \"albedo.exr\", filter = \"nearest\" }";
        let path = common::scenes::lit_quad("gradients-nearest", 16, floor, "constant = [0.2, 0.2, 0.2]", optimise);
        let albedo = vkinverse::image::Image { width: 2, height: 2, data: vec![[0.7, 0.4, 0.2], [0.2, 0.4, 0.7], [0.5; 3], [0.9, 0.1, 0.5]] };
        vkinverse::image::write_exr(&path.parent().unwrap().join("albedo.exr"), &albedo).unwrap();
        let scene = Scene::load(path).unwrap();
        assert_eq!(scene.materials[0].base_color.filter(), vkinverse::scene::Filter::Nearest);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        let texels: Vec<Probe> = (0..4).map(|t| probe(3 * t..3 * t + 3, 0.1)).collect();
        check("nearest", &measure(&mut b, &texels, 4), EPS_EXACT, 0.01);
    });
}

/// A floor whose left half an alpha test cuts out (a 4 × 1 alpha texture 0, 0, 1, 1 at 0.5),
/// its diffuse colour a 2 × 2 texture: camera rays, shadow rays and bounces pass through the
/// cut-out half to the sky and the light, in the primal, the replay and the finite
/// differences alike. Then the same floor as a blend at alpha 0.5, whose choices are drawn
/// per ray: the replays, which cast the same rays, make the same ones. The alpha is no
/// parameter and nothing samples by the colour, so the adjoint is exact per sample.
#[test]
fn alpha_tested_gradients_are_exact() {
    with_gpu(|ctx| {
        let optimise = "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.3, 0.6, 0.9]\nrange = [0.0, 1.0]\ntexture = [2, 2]\n";
        for (name, alpha) in [("gradients-alpha", "alpha = { texture = \"mask.exr\" }"), ("gradients-blend", "alpha = 0.5\nalpha_mode = \"blend\"")] {
            let floor = format!("type = \"diffuse\"\nbase_color = [0.7, 0.4, 0.2]\n{alpha}");
            let path = common::scenes::lit_quad(name, 16, &floor, "constant = [0.2, 0.2, 0.2]", optimise);
            let mask = vkinverse::image::Image { width: 4, height: 1, data: vec![[0.0; 3], [0.0; 3], [1.0; 3], [1.0; 3]] };
            vkinverse::image::write_exr(&path.parent().unwrap().join("mask.exr"), &mask).unwrap();
            let scene = Scene::load(path).unwrap();
            let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
            assert!(b.scene().has("HAS_ALPHA_MASKS"));
            let texels: Vec<Probe> = (0..4).map(|t| probe(3 * t..3 * t + 3, 0.1)).collect();
            check(name, &measure(&mut b, &texels, 4), EPS_EXACT, 0.01);
        }
    });
}

/// The lit quad of [`lit_quad`] under a glass slab of `kind` (its type and any keys of its
/// own) over the floor's left half: two faces 2 cm apart, tint 0.8, index 1.5, absorption
/// (1, 2, 3), under a grey sky; deep enough (6) for the floor under the slab to see the
/// light through it.
fn slab_scene(name: &str, kind: &str, optimise: &str) -> Scene {
    let glass = format!(
        "constant = [0.2, 0.2, 0.2]\n[[materials]]\nname = \"glass\"\n{kind}\nbase_color = [0.8, 0.8, 0.8]\nior = 1.5\nabsorption = [1, 2, 3]\n\
         [[meshes]]\nfile = \"slab.obj\"\nmaterial = \"glass\"\n"
    );
    let path = lit_quad(name, 16, "type = \"diffuse\"\nbase_color = [0.7, 0.4, 0.2]", &glass, optimise);
    let dir = path.parent().unwrap();
    std::fs::write(
        dir.join("slab.obj"),
        "v -1 0.3 -1\nv 0 0.3 -1\nv 0 0.3 1\nv -1 0.3 1\nv -1 0.28 -1\nv 0 0.28 -1\nv 0 0.28 1\nv -1 0.28 1\nf 1 4 3 2\nf 5 6 7 8\n",
    )
    .unwrap();
    let toml = std::fs::read_to_string(&path).unwrap().replace("max_depth = 3", "max_depth = 6").replace("rr_depth = 5", "rr_depth = 6");
    std::fs::write(&path, toml).unwrap();
    Scene::load(path).unwrap()
}

/// Glass: a diffuse floor's 2 × 2 colour texture seen through a tinted, absorbing glass
/// slab (two faces 2 cm apart over the floor's left half), and the slab's tint, against finite
/// differences. The slab refracts or mirrors each ray with the Fresnel reflectance, which
/// no parameter changes, and blocks light samples through it (its lobes are deltas), so
/// what reaches the floor under it comes through by the paths' own bounces; every choice
/// is the same at θ ± h and the adjoint is exact per sample. The tint's derivative is that
/// of a mass that scales each crossing (twice for a path through the slab and back).
#[test]
fn gradients_through_glass_are_exact() {
    with_gpu(|ctx| {
        let optimise = "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.3, 0.6, 0.9]\nrange = [0.0, 1.0]\ntexture = [2, 2]\n\
                        [[optimise.params]]\ntarget = \"materials.glass.base_color\"\ninit = [0.95, 0.5, 0.2]\nrange = [0.0, 1.0]\n";
        let scene = slab_scene("gradients-glass", "type = \"dielectric\"", optimise);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 16, 16, 64);
        assert!(b.scene().has("HAS_DIELECTRICS"));
        // The tint's step is short: a path that crosses the slab k times is a polynomial of
        // degree k in it, whose central difference is exact only for k ≤ 2.
        let probes: Vec<Probe> = (0..5).map(|t| probe(3 * t..3 * t + 3, if t < 4 { 0.05 } else { 0.005 })).collect();
        check("glass", &measure(&mut b, &probes, 32), EPS_EXACT, 0.01);
    });
}

/// Rough glass: the slab of [`gradients_through_glass_are_exact`] made rough (GGX, then
/// Beckmann; roughness 0.4, from 0.3), against finite differences. Its lobes are no deltas:
/// light samples pass through its faces (the shadow ray leaves from the far side), the
/// emission a continuation finds is MIS-weighted, and the floor under it is lit through
/// both faces. The floor's texels and the slab's tint change no choice (the lobe is picked
/// by the Fresnel reflectance at the sampled microfacet, which neither moves), so they are
/// exact per sample. The roughness moves the sampled microfacets, and with them every later
/// vertex: its finite differences follow other paths than the adjoint's, so it agrees in
/// the mean only, and its samples switch lobes where the moved microfacet's Fresnel
/// reflectance crosses their random number: 256 rounds of 64 spp, ε = 0.01 as the
/// principled roughness (measured: −3.2 % ± 3.2 % of fd with GGX, −0.3 % ± 5.9 % with
/// Beckmann). The tint starts on the side of its reference where the floor's texels start
/// (too dark in red, too bright in green and blue), so that the two residuals do not
/// cancel in its gradient.
#[test]
fn gradients_through_rough_glass_match_finite_differences() {
    with_gpu(|ctx| {
        let optimise = "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.3, 0.6, 0.9]\nrange = [0.0, 1.0]\ntexture = [2, 2]\n\
                        [[optimise.params]]\ntarget = \"materials.glass.base_color\"\ninit = [0.5, 0.95, 0.95]\nrange = [0.0, 1.0]\n\
                        [[optimise.params]]\ntarget = \"materials.glass.roughness\"\ninit = 0.3\nrange = [0.0, 1.0]\n";
        for distribution in ["ggx", "beckmann"] {
            let kind = format!("type = \"rough_dielectric\"\ndistribution = \"{distribution}\"\nroughness = 0.4");
            let scene = slab_scene(&format!("gradients-rough-glass-{distribution}"), &kind, optimise);
            let mut b = Bench::new(ctx, &scene, Loss::L2, 16, 16, 64);
            assert!(b.scene().has("HAS_DIELECTRICS") && b.scene().has("HAS_ROUGH_DIELECTRICS"));
            let probes: Vec<Probe> = (0..5).map(|t| probe(3 * t..3 * t + 3, if t < 4 { 0.05 } else { 0.005 })).collect();
            check(distribution, &measure(&mut b, &probes, 32), EPS_EXACT, 0.01);
            let mut b = Bench::new(ctx, &scene, Loss::L2, 64, 64, 64);
            // Beckmann's adjoint is about twice as noisy here (5.9 % of fd against GGX's
            // 2.6 %): 0.35 resolved.
            let resolution = if distribution == "ggx" { 0.2 } else { 0.35 };
            check(distribution, &measure(&mut b, &[probe([15], 0.05)], 256), 0.01, resolution);
        }
    });
}

/// A conductor: the floor of [`lit_quad`] made of gold (GGX, then Beckmann; roughness 0.4,
/// from 0.3), its tint a 2 × 2 texture, against finite differences. The tint scales the
/// reflection and changes no choice, so it is exact per sample. The roughness moves the
/// sampled microfacets and every later vertex with them: it agrees in the mean only, over
/// 256 rounds of 64 spp, as the rough glass's. Its step is short (h = 0.025): at h = 0.05
/// the central difference's h² term alone put fd 1.3 % (GGX) and 3.6 % (Beckmann) below
/// the adjoint, 0.35 % and 0.85–1.0 % at h = 0.025 (a quarter, as truncation must). The tint
/// starts too dark in red and too bright in green and blue.
#[test]
fn conductor_gradients_match_finite_differences() {
    with_gpu(|ctx| {
        let optimise = "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.5, 0.95, 0.95]\nrange = [0.0, 1.0]\ntexture = [2, 2]\n\
                        [[optimise.params]]\ntarget = \"materials.floor.roughness\"\ninit = 0.3\nrange = [0.0, 1.0]\n";
        for distribution in ["ggx", "beckmann"] {
            let floor = format!("type = \"conductor\"\nmetal = \"Au\"\ndistribution = \"{distribution}\"\nbase_color = [0.9, 0.8, 0.7]\nroughness = 0.4");
            let scene = Scene::load(lit_quad(&format!("gradients-conductor-{distribution}"), 16, &floor, "constant = [0.2, 0.2, 0.2]", optimise)).unwrap();
            let mut b = Bench::new(ctx, &scene, Loss::L2, 16, 16, 64);
            assert!(b.scene().has("HAS_CONDUCTORS") && !b.scene().has("HAS_PRINCIPLED"));
            let probes: Vec<Probe> = (0..4).map(|t| probe(3 * t..3 * t + 3, 0.05)).collect();
            check(distribution, &measure(&mut b, &probes, 32), EPS_EXACT, 0.01);
            let mut b = Bench::new(ctx, &scene, Loss::L2, 64, 64, 64);
            check(distribution, &measure(&mut b, &[probe([12], 0.025)], 256), 0.01, 0.2);
        }
    });
}

/// A plastic: the floor of [`lit_quad`] (GGX at roughness 0.3 and linear, then Beckmann at
/// 0.5 and nonlinear), its diffuse reflectance a 2 × 2 texture, against finite
/// differences. The reflectance scales the base's light (through 1 / (1 − R_int), or
/// 1 / (1 − ρ R_int) with `nonlinear`, whose derivative is then not linear in ρ) and moves
/// the choice between the coating's and the base's lobe, so the difference of a round is
/// zero-mean noise, as for the principled lobe choice: 48 rounds. The texture starts too
/// dark in red and too bright in green and blue.
#[test]
fn plastic_gradients_match_finite_differences() {
    with_gpu(|ctx| {
        let optimise = "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.3, 0.9, 0.9]\nrange = [0.0, 1.0]\ntexture = [2, 2]\n";
        for (distribution, roughness, nonlinear) in [("ggx", 0.3, false), ("beckmann", 0.5, true)] {
            let floor = format!("type = \"plastic\"\ndistribution = \"{distribution}\"\nbase_color = [0.7, 0.5, 0.3]\nroughness = {roughness}\nior = 1.49\nnonlinear = {nonlinear}");
            let scene = Scene::load(lit_quad(&format!("gradients-plastic-{distribution}"), 16, &floor, "constant = [0.2, 0.2, 0.2]", optimise)).unwrap();
            let mut b = Bench::new(ctx, &scene, Loss::L2, 16, 16, 16);
            assert!(b.scene().has("HAS_PLASTICS") && !b.scene().has("HAS_PRINCIPLED"));
            let probes: Vec<Probe> = (0..4).map(|t| probe(3 * t..3 * t + 3, 0.05)).collect();
            check(distribution, &measure(&mut b, &probes, 48), EPS_EXACT, 0.2);
        }
    });
}

/// scenes/gap (a closed box lit only through a 2 cm gap between a one-sided light and the
/// ceiling) at 32² pixels, its left wall's colour checked by `vkinverse::gradcheck`: the
/// adjoint against finite differences of the unbiased loss over independent renders, so
/// that a dependence between the primal image that makes the residual and the adjoint's
/// paths shows (the per-sample checks above share one residual between both sides and
/// cannot see it). The image is carried by rare bright paths, so the product of residual
/// and path derivative is noisy: 40 rounds of 16 spp leave a standard error of the
/// difference (3e-5) about the size of the red channel's gradient itself. That detects
/// adjoint paths that repeat the primal ones (the adjoint pass given the primal pass's
/// seed, a mutation that fails here at z = +13.7, +12.9, +12.5) but not the weaker
/// dependence of pcg4d's streams before their seeds were hashed: that put the adjoint
/// 5.6e-6 ± 4.4e-6 (40 % ± 30 % of the red gradient) above finite differences along the
/// same paths with an independent residual at this size, over 2000 rounds; tests/suite/rng.rs
/// catches it at z = +16 in a second.
#[test]
fn gap_scene_gradient_agrees_with_finite_differences_of_independent_renders() {
    with_gpu(|ctx| {
        let mut scene = Scene::load(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/gap/scene.toml")).unwrap();
        scene.film.width = 32;
        scene.film.height = 32;
        scene.optimise.params.retain(|p| p.name.starts_with("materials.left."));
        assert_eq!(scene.optimise.params.len(), 1, "the gap scene optimises its left wall's colour");
        let opts = vkinverse::gradcheck::Options { spp: 16, primal_spp: 16, rounds: Some(40), ..Default::default() };
        let report = vkinverse::gradcheck::gradcheck(&common::device(ctx), &scene, &opts).unwrap();
        eprintln!("{}", report.table());
        assert_eq!(report.rows.len(), 3);
        assert!(report.typical_gradient > 0.0 && report.rows.iter().all(|r| r.se > 0.0), "the wall's colour must matter");
        for r in &report.rows {
            assert!(
                r.z.abs() <= vkinverse::gradcheck::Z_FAIL,
                "{}[{}]: adjoint {:.4e} ± {:.1e} against {:.4e} ± {:.1e} (z {:+.2})",
                r.param,
                r.element,
                r.adjoint,
                r.adjoint_se,
                r.finite_difference,
                r.finite_difference_se,
                r.z
            );
        }
        let h = report.combined.expect("40 rounds of 3 elements give the combined statistic");
        assert!(h.p_value >= vkinverse::gradcheck::P_FAIL, "combined: T² {:.2}, p = {:.2e}", h.t2, h.p_value);
        assert_ne!(report.verdict, vkinverse::gradcheck::Verdict::Fail);
    });
}

// ---------------------------------------------------------------------------------------
// Tests: structure of the gradient
// ---------------------------------------------------------------------------------------

/// Two sensors: the gradient equals the sum of the gradients of each sensor alone. Seeds
/// do not depend on the sensor index, so each sensor replays the same paths alone as in
/// the pair: the primal images and losses must be bit-identical, and the gradients differ
/// only by the order of their float32 atomic additions. Against a black target with l2,
/// every added term (δ = 2I/3n ≥ 0 times non-negative path derivatives) is ≥ 0, so any
/// order of summing n terms is within (n − 1)·u·sum of the exact sum (u = 2⁻²⁴); with
/// n_s ≤ pixels·spp·(2·max_depth − 1) additions per element and sensor, the three sums
/// compared are within 2·(n_a + n_b)·u·sum of each other (the path radiance still to come
/// can be negative by rounding, which adds terms of order u): 8.5e-4 of the sum here,
/// while dropping or doubling either sensor's share would move it by that share: each
/// sensor's share of the three frames' total must be at least 10 times the bound (a
/// single 2-spp frame's share varies widely: 1 % of the sum has been seen).
/// Measured: 1.8e-6.
#[test]
fn gradient_of_two_sensors_is_the_sum_over_sensors() {
    with_gpu(|ctx| {
        let second = r#"
[[sensors]]
origin = [-0.6, 1.4, 3.2]
target = [0.2, 0.8, 0]
up = [0, 1, 0]
fov_y = 45
"#;
        let optimise = r#"
[[optimise.params]]
target = "materials.white.base_color"
init = [0.5, 0.5, 0.5]
range = [0.0, 1.0]
[[optimise.params]]
target = "meshes.light.emission"
init = [10.0, 10.0, 10.0]
range = [0.0, 50.0]
"#;
        let (film, spp, max_depth) = (16u32, 2u32, 4u32);
        let both = cornell("linearity", film, max_depth, second, &[], optimise);
        assert_eq!(both.sensors.len(), 2);
        let bench = |sensors: &[usize]| {
            let mut scene = both.clone();
            scene.sensors = sensors.iter().map(|&s| both.sensors[s].clone()).collect();
            let renderer = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
            let black = vec![Image::filled(film, film, [0.0; 3]); sensors.len()];
            Bench::with_targets(renderer, black, Loss::L2, spp, spp)
        };
        let (mut pair, mut first, mut second) = (bench(&[0, 1]), bench(&[0]), bench(&[1]));
        let per_sensor = (film * film * spp * (2 * max_depth - 1)) as f64;
        let unit_roundoff = f32::EPSILON as f64 / 2.0;
        let bound = 2.0 * (2.0 * per_sensor) * unit_roundoff;
        let theta = pair.scene().layout.initial();
        let mut worst = 0.0f64;
        let mut totals = vec![[0.0f64; 2]; theta.len()];
        for frame in 0..3 {
            let (g_pair, _) = pair.estimate(&theta, frame);
            let (g_first, _) = first.estimate(&theta, frame);
            let (g_second, _) = second.estimate(&theta, frame);
            for (s, alone) in [(0, &first), (1, &second)] {
                let bits = |i: Image| i.data.iter().flat_map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
                assert_eq!(
                    bits(pair.pass.rendered(s, pair.scene()).unwrap()),
                    bits(alone.pass.rendered(0, alone.scene()).unwrap()),
                    "sensor {s}: the primal image must not depend on the other sensor"
                );
                assert_eq!(pair.pass.loss_value(s).unwrap().to_bits(), alone.pass.loss_value(0).unwrap().to_bits());
            }
            for k in 0..theta.len() {
                let (a, b) = (g_first[k] as f64, g_second[k] as f64);
                let sum = a + b;
                let err = (g_pair[k] as f64 - sum).abs() / sum;
                worst = worst.max(err);
                assert!(err <= bound, "frame {frame} element {k}: pair {} vs {a} + {b}: {err:.2e} of the sum > {bound:.2e}", g_pair[k]);
                totals[k][0] += a;
                totals[k][1] += b;
            }
        }
        for (k, [a, b]) in totals.iter().enumerate() {
            assert!(a.min(*b) > 10.0 * bound * (a + b), "element {k}: both sensors must contribute ({a}, {b} over three frames)");
        }
        eprintln!("two sensors: largest difference from the sum {worst:.2e} of it (bound {bound:.2e})");
    });
}

/// Exactly zero gradients: (1) the emission of a light behind the camera that faces away
/// from everything (emitters are one-sided, and nothing lies behind it), while paths do
/// reach its back (its material's colour has a gradient) and the box light has one;
/// (2) a wall colour at max depth 1, where the image is emitters seen directly.
/// Gradients of textures read at a second set of texture coordinates are those of the
/// same textures read at a first set that holds the coordinates: the floor's colour
/// texture and the lamp's emission texture of [`common::scenes::two_uv_sets`], optimised
/// as 4 × 4 and 16 × 1 textures, against the same scene reading its coordinates as set 0
/// (same targets, same seed). Read at the decoy set instead, the gradient moves.
#[test]
fn gradients_at_a_second_set_of_texture_coordinates_are_those_at_the_first() {
    use common::scenes::{two_uv_sets, UvCase};
    let optimise = "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.5, 0.5, 0.5]\nrange = [0, 1]\ntexture = [4, 4]\n\
                    [[optimise.params]]\ntarget = \"meshes.lamp.emission\"\ninit = [2, 2, 2]\nrange = [0, 8]\ntexture = [16, 1]\n";
    with_gpu(|ctx| {
        let grad = |case: UvCase| {
            let scene = two_uv_sets(&format!("grad-uv-{case:?}"), case, optimise);
            let mut b = Bench::new(ctx, &scene, Loss::L2, 16, 16, 64);
            let theta = b.scene().layout.initial();
            b.estimate(&theta, 0).0
        };
        let (a, b, c) = (grad(UvCase::First), grad(UvCase::Second), grad(UvCase::Decoy));
        assert_eq!(a.len(), 4 * 4 * 3 + 16 * 3);
        let peak = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        eprintln!("gradient peak {peak}, largest difference {worst}");
        assert!(peak > 0.0 && worst <= 1e-4 * peak, "set 1 against set 0: largest difference {worst} (peak {peak})");
        let moved = a.iter().zip(&c).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(moved > 0.1 * peak, "the decoy moves the gradient by only {moved} (peak {peak})");
    });
}

#[test]
fn gradient_is_zero_where_the_image_does_not_depend_on_the_parameter() {
    with_gpu(|ctx| {
        // 4 × 4, at z = 5 (the camera is at z = 3.9 looking down −z), facing +z.
        let backlight = "v -2 -1 5\nv 2 -1 5\nv 2 3 5\nv -2 3 5\nf 1 2 3 4\n";
        let extra = r#"
[[materials]]
name = "grey"
type = "diffuse"
base_color = [0.5, 0.5, 0.5]
[[meshes]]
file = "backlight.obj"
material = "grey"
emission = [5.0, 5.0, 5.0]
"#;
        let optimise = r#"
[[optimise.params]]
target = "meshes.backlight.emission"
init = [5.0, 5.0, 5.0]
range = [0.0, 50.0]
[[optimise.params]]
target = "materials.grey.base_color"
init = [0.3, 0.3, 0.3]
range = [0.0, 1.0]
[[optimise.params]]
target = "meshes.light.emission"
init = [10.0, 10.0, 10.0]
range = [0.0, 50.0]
"#;
        let scene = cornell("zero-backlight", 16, 4, extra, &[("backlight.obj", backlight)], optimise);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        let theta = b.scene().layout.initial();
        let mut reached = [0.0f64; 6];
        for frame in 0..4 {
            let (g, _) = b.estimate(&theta, frame);
            assert_eq!(&g[0..3], &[0.0; 3], "frame {frame}: the backward-facing light cannot reach the image");
            for (r, v) in reached.iter_mut().zip(&g[3..9]) {
                *r += v.abs() as f64;
            }
        }
        assert!(reached.iter().all(|&v| v > 0.0), "paths must reach the grey quad and the box light: {reached:?}");

        let optimise = r#"
[[optimise.params]]
target = "materials.red.base_color"
init = [0.5, 0.5, 0.5]
range = [0.0, 1.0]
[[optimise.params]]
target = "meshes.light.emission"
init = [10.0, 10.0, 10.0]
range = [0.0, 50.0]
"#;
        let scene = cornell("zero-depth1", 16, 1, "", &[], optimise);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        let theta = b.scene().layout.initial();
        for frame in 0..2 {
            let (g, _) = b.estimate(&theta, frame);
            assert_eq!(&g[0..3], &[0.0; 3], "frame {frame}: at max depth 1 no surface colour matters");
            assert!(g[3..6].iter().all(|&v| v != 0.0), "frame {frame}: the light seen directly has a gradient: {:?}", &g[3..6]);
        }
    });
}

/// Delta lights' colour and intensity (a point light and a spot light in the Cornell box,
/// with its area light on) and the red wall's colour, now also lit by them: light
/// sampling of delta lights draws nothing random and does not depend on θ, nor does
/// anything else at depth 4 < rr_depth 5, so each replayed sample's adjoint must be the
/// exact derivative of that sample (as in the test above). The image is linear in each
/// light's colour and intensity and at most quadratic in the wall's colour. The colour
/// starts far below the reference in every channel, and both lights below their
/// intensities, so that the residual has one sign where they shine and each gradient is
/// significant.
#[test]
fn delta_light_gradients_are_exact() {
    with_gpu(|ctx| {
        let lights = r#"
[[lights]]
name = "bulb"
type = "point"
position = [0.3, 1.2, 0.4]
color = [1.0, 0.9, 0.7]
intensity = 1.5
[[lights]]
name = "spot"
type = "spot"
position = [-0.5, 1.7, 0.5]
direction = [-0.4, -1, -0.3]
color = [0.6, 0.8, 1.0]
intensity = 2.0
inner_angle = 10
outer_angle = 40
"#;
        let optimise = r#"
[[optimise.params]]
target = "lights.bulb.color"
init = [0.3, 0.3, 0.1]
range = [0.0, 2.0]
[[optimise.params]]
target = "lights.bulb.intensity"
init = 1.0
range = [0.0, 5.0]
[[optimise.params]]
target = "lights.spot.intensity"
init = 0.5
range = [0.0, 5.0]
[[optimise.params]]
target = "materials.red.base_color"
init = [0.1, 0.01, 0.01]
range = [0.0, 1.0]
"#;
        let scene = cornell("delta-lights", 16, 4, lights, &[], optimise);
        let mut b = Bench::new(ctx, &scene, Loss::L2, 4, 4, 16);
        let samples = measure(&mut b, &[probe(0..3, 0.05), probe([3], 0.1), probe([4], 0.1), probe(5..8, 0.01)], 8);
        check("l2", &samples, EPS_EXACT, 0.01);
    });
}

/// The integrator kernels are specialised for the scene's features (`GpuScene::spec`): a
/// scene without textures (of materials or of emission), principled materials, alpha
/// tests or dielectrics has their code compiled out. The kernels
/// with every feature compiled in must compute the same thing: the Cornell box (neither
/// feature) and the spiral (principled, untextured) render the same images and the same
/// gradient either way. The same image up to rounding: lavapipe renders both bit for bit
/// alike, while a GPU's compiler fuses multiplies and adds differently in the two builds
/// (an NVIDIA H200 differed in 22 % of the Cornell box's values, by at most 2 units in the
/// last place); a feature's code taken where it should not be, or left out, changes
/// pixels by far more than the bound below. Likewise the adjoint kernels with `CACHE_ALL` (the gradient
/// replay takes every cast from the cache, its traversal compiled out) and without (it
/// tests each cast for the cache at run time), and with the per-thread gradient sums
/// added in an unrolled loop (`LOCAL_GRADS_UNROLLED`) and indexed per lane.
#[test]
fn feature_specialisation_changes_no_result() {
    for (name, principled) in [("cornell", false), ("spiral", true)] {
        let scene = Scene::load(format!("{}/scenes/{name}/scene.toml", env!("CARGO_MANIFEST_DIR"))).unwrap();
        let (images, grads) = with_gpu(|ctx| {
            let mut images = Vec::new();
            let mut grads = Vec::new();
            for every_feature in [false, true] {
                let mut gs = GpuScene::new(ctx, &scene).unwrap();
                assert!(!gs.has("HAS_TEXTURES"), "{name} has no texture");
                assert!(!gs.has("HAS_NORMAL_MAPS"), "{name} has no normal map");
                assert!(!gs.has("HAS_EMISSION_TEXTURES"), "{name} has no emission texture");
                assert!(!gs.has("HAS_ALPHA_MASKS"), "{name} has no alpha test");
                assert!(!gs.has("HAS_DIELECTRICS"), "{name} has no dielectric");
                assert!(!gs.has("HAS_ROUGH_DIELECTRICS"), "{name} has no rough dielectric");
                assert!(!gs.has("HAS_CONDUCTORS"), "{name} has no conductor");
                assert!(!gs.has("HAS_PLASTICS"), "{name} has no plastic");
                assert_eq!(gs.has("HAS_PRINCIPLED"), principled, "{name}: principled materials");
                // The spiral's meshes have vertex normals, the Cornell box's none.
                assert_eq!(gs.has("HAS_NORMALS"), principled, "{name}: vertex normals");
                assert!(gs.replay_cached, "{name}: every cast of a path fits the replay cache");
                assert!(gs.local_grads_unrolled, "{name}: few parameters, summed in an unrolled loop");
                if every_feature {
                    gs.every_feature = true;
                    // The gradient replay tests each cast for the cache at run time.
                    gs.replay_cached = false;
                    // The per-thread gradient sums indexed per lane.
                    gs.local_grads_unrolled = false;
                }
                let renderer = PrimalRenderer::new(gs).unwrap();
                renderer.scene.set_theta(renderer.scene.layout.reference()).unwrap();
                renderer.scene.set_frame(0).unwrap();
                let target = renderer.render(0, 4, TARGET_SEED, |_, _| {}).unwrap();
                let mut bench = Bench::with_targets(renderer, vec![target.clone()], Loss::L2, 4, 4);
                let theta = bench.scene().layout.initial();
                let (g, _) = bench.estimate(&theta, 3);
                images.push(target);
                grads.push(g);
            }
            (images, grads)
        });
        // At most 2e-6 of each value: 17 to 34 units in the last place of an f32.
        let values = |i: &Image| i.data.iter().flat_map(|p| *p).collect::<Vec<f32>>();
        let (a, b) = (values(&images[0]), values(&images[1]));
        let (mut differing, mut beyond) = (0, 0);
        let mut worst = 0.0f64;
        for (x, y) in a.iter().zip(&b) {
            if x.to_bits() != y.to_bits() {
                differing += 1;
                let (x, y) = (*x as f64, *y as f64);
                // NaN where either is NaN (or infinite): counted beyond the bound.
                let relative = if x == y { 0.0 } else { (x - y).abs() / x.abs().max(y.abs()) };
                if relative.is_nan() || relative > 2e-6 {
                    beyond += 1;
                }
                worst = worst.max(relative);
            }
        }
        assert_eq!(
            beyond,
            0,
            "{name}: the specialised kernel renders another image: {differing} of {} values differ, by up to {worst:.2e} of their value",
            a.len()
        );
        let norm = grads[1].iter().map(|v| (*v as f64).abs()).sum::<f64>();
        let diff = grads[0].iter().zip(&grads[1]).map(|(a, b)| (*a as f64 - *b as f64).abs()).sum::<f64>();
        assert!(norm > 0.0, "{name}: a non-zero gradient");
        // Float atomics add the subgroups' sums in any order: equal up to rounding.
        assert!(diff <= 1e-5 * norm, "{name}: gradients differ by {:.2e} (relative L1): {:?} vs {:?}", diff / norm, grads[0], grads[1]);
    }
}

/// Scenes with textures, principled materials and vertex normals keep their code.
#[test]
fn scene_features_are_detected() {
    let scene = Scene::load(format!("{}/scenes/glossy/scene.toml", env!("CARGO_MANIFEST_DIR"))).unwrap();
    let (textures, principled, normals) = with_gpu(|ctx| {
        let gs = GpuScene::new(ctx, &scene).unwrap();
        (gs.has("HAS_TEXTURES"), gs.has("HAS_PRINCIPLED"), gs.has("HAS_NORMALS"))
    });
    assert!(textures && principled && normals);
}
