//! The fused finite-difference sample (one trace, both parameter states) against the
//! straightforward one (one gradient estimate per state with the same seeds).

use crate::common;

use common::with_gpu;
use vkinverse::gpu::{Buffer, CommandBuffer, MemoryKind};
use vkinverse::ops::BufferOps;
use vkinverse::render::gradient::{GradientInputs, GradientPass};
use vkinverse::render::targets::{padded, targets};
use vkinverse::render::{GpuScene, PrimalRenderer};
use vkinverse::scene::Scene;

/// What a finite-difference sample of a scene needs: the scene, its renderer (θ at the
/// scene's init), cheap targets, the buffer operations and θ_{i-1} with every element moved
/// by `shift` inside its range.
fn fd_setup(
    ctx: &std::sync::Arc<vkinverse::gpu::Context>,
    scene_path: &str,
    shift: f32,
) -> (Scene, PrimalRenderer, Vec<vkinverse::image::Image>, BufferOps, Buffer) {
    let scene = Scene::load(scene_path).unwrap();
    let renderer = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
    let gs = &renderer.scene;
    // Target quality is irrelevant to these comparisons: few samples keep the tests short.
    let source = vkinverse::render::targets::TargetSource { spp: 16, cache_dir: None, cancel: &vkinverse::Cancel::new() };
    let imgs = targets(&renderer, &scene, source, &mut ()).unwrap();
    let ops = BufferOps::new(ctx).unwrap();
    let theta = gs.layout.initial();
    let mut prev_vals = theta.clone();
    for slot in &gs.layout.slots {
        for v in &mut prev_vals[slot.offset..slot.offset + slot.len] {
            *v = if *v + shift <= slot.range[1] { *v + shift } else { *v - shift };
        }
    }
    gs.set_theta(theta).unwrap();
    // Read as texels by the trace kernels, shaped like the scene's θ (the material data
    // after it).
    let theta_prev = gs.theta.duplicate("theta prev").unwrap();
    theta_prev.write(&padded(gs, prev_vals)).unwrap();
    (scene, renderer, imgs, ops, theta_prev)
}

/// ⟨ΔF⟩ for θ_prev → θ = scene init, fused and two-trace, over `rounds` seeds.
fn fd_samples(scene_path: &str, shift: f32, spp: u32, rounds: u32) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    with_gpu(|ctx| {
        let (scene, renderer, imgs, ops, theta_prev) = fd_setup(ctx, scene_path, shift);
        let gs = &renderer.scene;
        let n = gs.layout.len;
        let fused_grad = Buffer::zeroed::<f32>(ctx, "fused", n, MemoryKind::Device).unwrap();
        let g_cur = Buffer::zeroed::<f32>(ctx, "cur", n, MemoryKind::Device).unwrap();
        let g_prev = Buffer::zeroed::<f32>(ctx, "prev", n, MemoryKind::Device).unwrap();
        let loss = vkinverse::settings::RunSettings::of_scene(&scene).loss;
        let seed = 77;
        let fused = GradientPass::new(
            gs,
            &ops,
            &GradientInputs {
                targets: &imgs,
                loss,
                spp,
                primal_spp: spp,
                seed,
                theta: &gs.theta,
                theta_prev: Some(&theta_prev),
                grad: &fused_grad,
                grad_half: None,
            },
        )
        .unwrap();
        let cur = GradientPass::new(
            gs,
            &ops,
            &GradientInputs { targets: &imgs, loss, spp, primal_spp: spp, seed, theta: &gs.theta, theta_prev: None, grad: &g_cur, grad_half: None },
        )
        .unwrap();
        let prv = GradientPass::new(
            gs,
            &ops,
            &GradientInputs { targets: &imgs, loss, spp, primal_spp: spp, seed, theta: &theta_prev, theta_prev: None, grad: &g_prev, grad_half: None },
        )
        .unwrap();
        let mut cmd_fused = CommandBuffer::new(ctx, "fused").unwrap();
        cmd_fused.record(|rec| fused.record(rec, gs, &ops)).unwrap();
        let mut cmd_two = CommandBuffer::new(ctx, "two").unwrap();
        cmd_two
            .record(|rec| {
                cur.record(rec, gs, &ops)?;
                prv.record(rec, gs, &ops)
            })
            .unwrap();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for r in 0..rounds {
            gs.set_frame(r).unwrap();
            for buf in [&fused_grad, &g_cur, &g_prev] {
                buf.write(&vec![0f32; n]).unwrap();
            }
            cmd_fused.submit_and_wait().unwrap();
            cmd_two.submit_and_wait().unwrap();
            a.push(fused_grad.read::<f32>().unwrap());
            let (c, p): (Vec<f32>, Vec<f32>) = (g_cur.read().unwrap(), g_prev.read().unwrap());
            b.push(c.iter().zip(&p).map(|(x, y)| x - y).collect());
        }
        (a, b)
    })
}

/// Diffuse materials: BSDF sampling does not depend on the base colour and the Cornell
/// box's paths end before Russian roulette starts, so both versions trace the very same
/// paths and must agree up to float summation order (atomics in another order).
#[test]
fn fused_equals_two_trace_when_sampling_does_not_depend_on_parameters() {
    assert_fused_equals_two_trace("scenes/cornell/scene.toml");
}

/// The fused and two-trace samples of `scene_path` (θ_prev 0.05 off, 2 spp, 2 rounds) agree
/// up to float summation order, and the step changes the gradient.
fn assert_fused_equals_two_trace(scene_path: &str) {
    let (fused, two) = fd_samples(scene_path, 0.05, 2, 2);
    for (a, b) in fused.iter().zip(&two) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-4 * y.abs() + 1e-8, "fused {x} vs two-trace {y}");
        }
        assert!(a.iter().any(|v| v.abs() > 1e-7), "a 0.05 step changes the gradient: {a:?}");
    }
}

/// The same with a normal map on a diffuse quad lit by an area light and a sky: the map
/// bends the shading normal of every vertex on the quad in both parameter states alike
/// (it is no parameter), so the fused sample still traces the two-trace version's paths.
#[test]
fn fused_equals_two_trace_on_a_normal_mapped_surface() {
    let floor = "type = \"diffuse\"\nbase_color = [0.7, 0.4, 0.2]\nnormal_map = { texture = \"normals.exr\" }";
    let optimise = "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.5, 0.5, 0.5]\nrange = [0, 1]";
    let path = common::scenes::lit_quad("fd-normal-map", 16, floor, "constant = [0.3, 0.35, 0.4]", optimise);
    assert_fused_equals_two_trace(path.to_str().unwrap());
}

/// The same with the area light's emission optimised as a texture: both parameter states
/// read it where a light sample lands and where a BSDF sample hits the light.
#[test]
fn fused_equals_two_trace_with_an_emission_texture() {
    let floor = "type = \"diffuse\"\nbase_color = [0.7, 0.4, 0.2]";
    let optimise = "[[optimise.params]]\ntarget = \"meshes.light.emission\"\ninit = [3, 9, 5]\nrange = [0, 50]\ntexture = [2, 2]";
    let path = common::scenes::lit_quad("fd-emission-texture", 16, floor, "constant = [0.3, 0.35, 0.4]", optimise);
    assert_fused_equals_two_trace(path.to_str().unwrap());
}

/// The sample on every stride-th pixel (`fd_stride`): the checkerboards of all phases
/// cover each pixel once, with the random numbers of the full sample and each pixel
/// weighted `stride` times, so their mean is the full sample up to summation order. Stride
/// 3 does not divide the 64-pixel rows: the last column of a row may be past its end.
#[test]
fn strided_samples_of_all_phases_average_to_the_full_sample() {
    with_gpu(|ctx| {
        let (scene, renderer, imgs, ops, theta_prev) = fd_setup(ctx, "scenes/cornell/scene.toml", 0.05);
        let gs = &renderer.scene;
        assert_eq!(gs.width, 64);
        let n = gs.layout.len;
        let loss = vkinverse::settings::RunSettings::of_scene(&scene).loss;
        let sample = |stride: u32, phase: u32, frame: u32| -> Vec<f32> {
            let grad = Buffer::zeroed::<f32>(ctx, "fd", n, MemoryKind::Device).unwrap();
            let mut pass = GradientPass::new(
                gs,
                &ops,
                &GradientInputs {
                    targets: &imgs,
                    loss,
                    spp: 1,
                    primal_spp: 1,
                    seed: 5,
                    theta: &gs.theta,
                    theta_prev: Some(&theta_prev),
                    grad: &grad,
                    grad_half: None,
                },
            )
            .unwrap();
            (pass.stride, pass.phase) = (stride, phase);
            let mut cmd = CommandBuffer::new(ctx, "strided").unwrap();
            cmd.record(|rec| pass.record(rec, gs, &ops)).unwrap();
            gs.set_frame(frame).unwrap();
            cmd.submit_and_wait().unwrap();
            grad.read().unwrap()
        };
        for frame in [0, 3] {
            let full = sample(1, 0, frame);
            assert!(full.iter().any(|v| v.abs() > 1e-7), "a 0.05 step changes the gradient: {full:?}");
            for stride in [2u32, 3] {
                let parts: Vec<Vec<f32>> = (0..stride).map(|phase| sample(stride, phase, frame)).collect();
                for (k, want) in full.iter().enumerate() {
                    let mean = parts.iter().map(|p| p[k]).sum::<f32>() / stride as f32;
                    assert!((mean - want).abs() <= 1e-4 * want.abs() + 1e-8, "stride {stride}, frame {frame}, element {k}: {mean} vs {want}");
                }
                // Each phase alone is a different, noisier estimate.
                assert!(parts.iter().all(|p| p != &full), "stride {stride}: a phase equals the full sample");
            }
        }
    })
}

/// Principled materials: roughness and metallic change BSDF sampling, so the two versions
/// trace different paths for θ_{i-1}; both are unbiased for the same ΔF, so their means
/// over independent seeds agree within the standard error of the difference.
#[test]
fn fused_and_two_trace_agree_in_expectation_when_sampling_depends_on_parameters() {
    let rounds = 8;
    let (fused, two) = fd_samples("scenes/spiral/scene.toml", 0.1, 2, rounds);
    let n = fused[0].len();
    for k in 0..n {
        let d: Vec<f64> = (0..rounds as usize).map(|r| (fused[r][k] - two[r][k]) as f64).collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (d.len() as f64 - 1.0);
        let se = (var / d.len() as f64).sqrt();
        let scale = two.iter().map(|t| t[k].abs() as f64).sum::<f64>() / rounds as f64;
        // 4.5 standard errors: a false alarm about once in 10^5 per element.
        assert!(mean.abs() <= 4.5 * se + 1e-3 * scale + 1e-9, "element {k}: mean difference {mean} (se {se}, scale {scale})");
    }
}

/// A diffuse quad under an area light and a lat-long map with one bright texel, both
/// light-sampled (next-event estimation picks either with probability ½). With the map
/// fixed and the quad's colour and the light's emission optimised, then with the map itself
/// optimised (a 4 × 2 texture): no sampling decision depends on θ (the map's distribution
/// is built once), so the fused and two-trace samples trace the same paths and agree up to
/// float summation order, as in the Cornell box.
#[test]
fn fused_equals_two_trace_with_a_light_sampled_environment_map() {
    let params = [
        r#"
[[optimise.params]]
target = "materials.floor.base_color"
init = [0.4, 0.6, 0.5]
range = [0.0, 1.0]
[[optimise.params]]
target = "meshes.light.emission"
init = [3.0, 9.0, 5.0]
range = [0.0, 50.0]
"#,
        r#"
[[optimise.params]]
target = "environment"
init = [0.6, 0.2, 0.8]
range = [0.0, 2.0]
texture = [4, 2]
"#,
    ];
    for (i, optimise) in params.iter().enumerate() {
        let path = common::scenes::sky_lit_quad(&format!("fd-env-{i}"), 16, optimise);
        let (fused, two) = fd_samples(path.to_str().unwrap(), 0.05, 2, 2);
        for (a, b) in fused.iter().zip(&two) {
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() <= 1e-4 * y.abs() + 1e-8, "scene {i}: fused {x} vs two-trace {y}");
            }
            assert!(a.iter().all(|v| v.abs() > 1e-7), "scene {i}: a 0.05 step changes every gradient: {a:?}");
        }
    }
}

/// Delta lights' colour and intensity and the lit plane's colour: light sampling of delta
/// lights is deterministic and does not depend on θ, so the fused sample (both states
/// along one path) equals the two-trace one up to float summation order.
#[test]
fn fused_equals_two_trace_with_delta_lights() {
    let optimise = "[[optimise.params]]\ntarget = \"lights.spot.color\"\ninit = [0.5, 0.5, 0.5]\nrange = [0, 1]\n\
                    [[optimise.params]]\ntarget = \"lights.bulb.intensity\"\ninit = 1.0\nrange = [0, 4]\n\
                    [[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.3, 0.3, 0.3]\nrange = [0, 1]\n";
    let path = common::scenes::write_delta_lit("fd-delta", (16, 12), optimise);
    let (fused, two) = fd_samples(path.to_str().unwrap(), 0.05, 2, 2);
    for (a, b) in fused.iter().zip(&two) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-4 * y.abs() + 1e-8, "fused {x} vs two-trace {y}");
        }
        assert!(a.iter().all(|v| v.abs() > 1e-7), "every element's gradient moves with a 0.05 step: {a:?}");
    }
}

/// The carry passes (glsl/carry_stats.comp, carry_weight.comp, carry_image.comp) against
/// their formulas in f64, on two sensors' images of a pixel count that is no multiple of the
/// workgroup, with both weights: the first carry takes the fresh image; later ones mix it
/// with the carried one moved by cur − prev, with the running mean's weight down to `w_min`
/// (fixed) or the inverse-variance weight from the renders' squared differences and the
/// tracked variance (variance); the losses' images are replaced by the result, and the
/// state holds the weight and the variances. With the adjoint pass's render taken in
/// (carry_adjoint.comp), it is mixed into the carried image after the losses' images were
/// written, by its inverse-variance weight against the carried image's tracked variance.
#[test]
fn carry_pass_follows_its_formula() {
    use vkinverse::engine::{Carry, CarryInputs};
    use vkinverse::optim::CarryWeight;
    with_gpu(|ctx| {
        let (pixels, rounds, spp) = (1000usize, 6u32, (4u32, 1u32));
        let ops = BufferOps::new(ctx).unwrap();
        let mk = |name: &str| Buffer::zeroed::<[f32; 3]>(ctx, name, pixels, MemoryKind::Device).unwrap();
        let bufs: Vec<[Buffer; 3]> = (0..2).map(|s| [mk(&format!("fresh {s}")), mk(&format!("cur {s}")), mk(&format!("prev {s}"))]).collect();
        let triples: Vec<(&Buffer, &Buffer, &Buffer)> = bufs.iter().map(|[f, c, p]| (f, c, p)).collect();
        // The adjoint pass's renders of θ_i, at 2 spp (kind 3 below).
        let (adjoint_renders, s_a) = ([mk("adjoint 0"), mk("adjoint 1")], 2u32);
        // Whether the fresh and the adjoint render's floors were each reached.
        let mut floors_met = [false; 2];
        for (mode, w_min, with_adjoint) in [(CarryWeight::Fixed, 0.3f64, false), (CarryWeight::Variance, 0.02, false), (CarryWeight::Variance, 0.9, true)] {
            let adjoint = with_adjoint.then(|| (adjoint_renders.iter().collect::<Vec<_>>(), s_a));
            let carry = Carry::new(ctx, CarryInputs { pixels, images: &triples, w_min, weight: mode, spp, adjoint }).unwrap();
            let mut cmd = CommandBuffer::new(ctx, "carry").unwrap();
            cmd.record(|rec| {
                carry.record(rec, &ops)?;
                carry.record_adjoint(rec)
            })
            .unwrap();
            // cur and prev differ by a small step, fresh by noise of the size of cur's.
            let value = |s: usize, r: u32, i: usize, kind: u32| -> [f32; 3] {
                let x = (s * 7919 + r as usize * 104729 + i * 31) as f32;
                let base = [(x * 0.37).sin(), (x * 0.11).cos() * 2.0, (x * 0.05).sin() + 1.0];
                let y = (s * 31 + r as usize * 17 + i * 7 + kind as usize * 1013) as f32;
                let noise = (y * 0.731).sin() * [0.3, 0.01, 0.1, 0.2][kind as usize];
                base.map(|b| b + noise)
            };
            let mut expected: Vec<Vec<[f64; 3]>> = vec![vec![[0.0; 3]; pixels]; 2];
            let mut var = [0f64; 2];
            for r in 0..rounds {
                for (s, [f, c, p]) in bufs.iter().enumerate() {
                    f.write(&(0..pixels).map(|i| value(s, r, i, 0)).collect::<Vec<_>>()).unwrap();
                    c.write(&(0..pixels).map(|i| value(s, r, i, 1)).collect::<Vec<_>>()).unwrap();
                    p.write(&(0..pixels).map(|i| value(s, r, i, 2)).collect::<Vec<_>>()).unwrap();
                    adjoint_renders[s].write(&(0..pixels).map(|i| value(s, r, i, 3)).collect::<Vec<_>>()).unwrap();
                }
                cmd.submit_and_wait().unwrap();
                for (s, [f, c, p]) in bufs.iter().enumerate() {
                    let sq = |a: usize, b: usize| -> f64 {
                        (0..pixels)
                            .map(|i| (0..3).map(|k| (value(s, r, i, a as u32)[k] as f64 - value(s, r, i, b as u32)[k] as f64).powi(2)).sum::<f64>())
                            .sum::<f64>()
                            / (3 * pixels) as f64
                    };
                    let v_fresh = sq(0, 1) * spp.1 as f64 / (spp.0 + spp.1) as f64;
                    // With the adjoint render the floor is shared by the two renders' samples.
                    let s_new = if with_adjoint { (spp.0 + s_a) as f64 } else { spp.0 as f64 };
                    let (w_floor, u_floor) = (w_min * spp.0 as f64 / s_new, w_min * (s_new - spp.0 as f64) / s_new);
                    let v_diff = sq(1, 2);
                    let w = match (r, mode) {
                        (0, _) => 1.0,
                        (_, CarryWeight::Fixed) => (1.0 / (r as f64 + 1.0)).max(w_floor),
                        (_, CarryWeight::Variance) => ((var[s] + v_diff) / (var[s] + v_diff + v_fresh)).max(w_floor),
                    };
                    var[s] = w * w * v_fresh + (1.0 - w) * (1.0 - w) * (var[s] + v_diff);
                    // The adjoint render's weight, against the carried image after the carry.
                    let v_adjoint = v_fresh * spp.0 as f64 / s_a as f64;
                    let u = if with_adjoint { (var[s] / (var[s] + v_adjoint)).max(u_floor) } else { 0.0 };
                    floors_met[0] |= with_adjoint && w == w_floor;
                    floors_met[1] |= with_adjoint && u == u_floor;
                    var[s] = (1.0 - u) * (1.0 - u) * var[s] + u * u * v_adjoint;
                    let state = carry.sensor_state(s).unwrap();
                    let near = |got: f32, want: f64, what: &str| {
                        assert!((got as f64 - want).abs() <= 1e-4 * want.abs() + 1e-9, "{mode:?} round {r} sensor {s}: {what} {got} against {want}")
                    };
                    near(state.weight, w, "weight");
                    near(state.var_carried, var[s], "carried variance");
                    near(state.var_fresh, v_fresh, "fresh variance");
                    near(state.var_diff, v_diff, "difference variance");
                    near(state.weight_adjoint, u, "adjoint render's weight");

                    let (fresh, cur, prev): (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 3]>) = (f.read().unwrap(), c.read().unwrap(), p.read().unwrap());
                    let carried: Vec<[f32; 3]> = carry.image(s).read().unwrap();
                    for i in 0..pixels {
                        let (vf, vc, vp) = (value(s, r, i, 0), value(s, r, i, 1), value(s, r, i, 2));
                        for k in 0..3 {
                            let diff = vc[k] as f64 - vp[k] as f64;
                            let e = if r == 0 { vf[k] as f64 } else { w * vf[k] as f64 + (1.0 - w) * (expected[s][i][k] + diff) };
                            // The losses read the carry's image; the adjoint render is mixed in after.
                            let mixed = (1.0 - u) * e + u * value(s, r, i, 3)[k] as f64;
                            expected[s][i][k] = mixed;
                            let close = |got: f32, want: f64| (got as f64 - want).abs() <= 1e-4 * (1.0 + want.abs());
                            assert!(close(carried[i][k], mixed), "{mode:?} round {r} sensor {s} pixel {i}: carried {} against {mixed}", carried[i][k]);
                            assert!(
                                close(fresh[i][k], e) && close(cur[i][k], e),
                                "round {r} sensor {s} pixel {i}: the losses' image of θ is not the carried one"
                            );
                            assert!(close(prev[i][k], e - diff), "round {r} sensor {s} pixel {i}: prev {} against {}", prev[i][k], e - diff);
                        }
                    }
                }
            }
        }
        assert_eq!(floors_met, [true, true], "the rounds never reached the fresh and the adjoint render's floors");
    });
}

/// A non-finite pixel in the fresh render (a NaN from a broken texture, an overflow) makes
/// its statistics non-finite: the carry then takes the fresh image alone, restarts the
/// tracked variance, and the next iteration weighs finite renders again.
#[test]
fn carry_weight_survives_a_non_finite_render() {
    use vkinverse::engine::{Carry, CarryInputs};
    use vkinverse::optim::CarryWeight;
    with_gpu(|ctx| {
        let pixels = 300usize;
        let ops = BufferOps::new(ctx).unwrap();
        let mk = |name: &str| Buffer::zeroed::<[f32; 3]>(ctx, name, pixels, MemoryKind::Device).unwrap();
        let (f, c, p) = (mk("fresh"), mk("cur"), mk("prev"));
        let carry =
            Carry::new(ctx, CarryInputs { pixels, images: &[(&f, &c, &p)], w_min: 0.01, weight: CarryWeight::Variance, spp: (4, 1), adjoint: None }).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "carry").unwrap();
        cmd.record(|rec| carry.record(rec, &ops)).unwrap();
        let image = |r: u32, kind: u32| -> Vec<[f32; 3]> { (0..pixels).map(|i| [((i as u32 * 7 + r * 13 + kind * 5) % 11) as f32 * 0.1; 3]).collect() };
        for r in 0..4u32 {
            let mut fresh = image(r, 0);
            if r == 1 {
                fresh[0] = [f32::NAN; 3];
                fresh[1] = [f32::INFINITY; 3];
            }
            f.write(&fresh).unwrap();
            c.write(&image(r, 1)).unwrap();
            p.write(&image(r, 2)).unwrap();
            cmd.submit_and_wait().unwrap();
            let state = carry.sensor_state(0).unwrap();
            match r {
                1 => {
                    assert_eq!(state.weight, 1.0, "round 1: {state:?}");
                    assert!(state.var_carried.is_finite(), "round 1: {state:?}");
                    let carried: Vec<[f32; 3]> = carry.image(0).read().unwrap();
                    assert_eq!(carried[2..], fresh[2..], "round 1 takes the fresh image");
                }
                _ => assert!(state.values().iter().all(|v| v.is_finite()) && (0.0..=1.0).contains(&state.weight), "round {r}: {state:?}"),
            }
        }
        let carried: Vec<[f32; 3]> = carry.image(0).read().unwrap();
        assert!(carried.iter().flatten().all(|v| v.is_finite()), "the carried image stays non-finite after finite renders took over");
    });
}

/// 30 meta iterations of the Cornell box with `spec`, in which θ moves; then the carried
/// image, a 512-spp render of the θ it belongs to, a fresh render at the run's primal_spp,
/// and the carry's state.
fn carried_run(spec: &str) -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 3]>, vkinverse::engine::CarryState) {
    use vkinverse::engine::Engine;
    use vkinverse::optim::spec::Spec;
    use vkinverse::settings::RunSettings;
    let scene = Scene::load("scenes/cornell/scene.toml").unwrap();
    let mut settings = RunSettings::of_scene(&scene);
    settings.optimiser = spec.parse::<Spec>().unwrap();
    with_gpu(|ctx| {
        let engine = Engine::new(&crate::common::device(ctx), &scene, &settings, &mut (), &Default::default()).unwrap();
        let mut iteration = engine.iteration().unwrap();
        let iterations = 30;
        let mut theta_of_last = engine.theta().unwrap();
        let mut last = None;
        for i in 0..iterations {
            if i + 1 == iterations {
                theta_of_last = engine.theta().unwrap();
            }
            last = Some(engine.step(&mut iteration, i).unwrap());
        }
        let start = engine.scene().layout.initial();
        let moved = theta_of_last.iter().zip(&start).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(moved > 0.05, "θ moved by {moved} only: the test needs a moving θ");
        let carry = engine.carry.as_ref().expect("meta@carry builds a carry");
        let carried: Vec<[f32; 3]> = carry.image(0).read().unwrap();
        let state = carry.sensor_state(0).unwrap();
        assert_eq!(last.unwrap().carry, vec![state], "the iteration's report holds the carry's state");
        engine.scene().set_theta(theta_of_last).unwrap();
        let reference = engine.renderer.render(0, 512, 77, |_, _| {}).unwrap();
        let fresh = engine.renderer.render(0, settings.primal_spp, 78, |_, _| {}).unwrap();
        (carried, reference.data, fresh.data, state)
    })
}

/// Per channel, the mean of `img` − `reference`; and the mean squared difference over pixels
/// and channels.
fn error_stats(img: &[[f32; 3]], reference: &[[f32; 3]]) -> ([f64; 3], f64) {
    let mut mean = [0f64; 3];
    let mut sq = 0f64;
    for (a, b) in img.iter().zip(reference) {
        for k in 0..3 {
            let d = a[k] as f64 - b[k] as f64;
            mean[k] += d / img.len() as f64;
            sq += d * d / (3 * img.len()) as f64;
        }
    }
    (mean, sq)
}

/// A meta-estimator run with the carried image (`carry`, fixed weights): after 30
/// iterations in which θ moves, the carried image agrees with a 512-spp render of the θ it
/// belongs to (the carry follows θ through the finite differences instead of lagging
/// behind: without them the green channel's mean is 5 % off here, with them 0.2 %), and is
/// closer to it than a fresh render at the run's primal_spp (an RMS error of about a fifth).
#[test]
fn carried_image_follows_the_parameters_with_less_noise_than_a_fresh_render() {
    let (carried, reference, fresh, _) = carried_run("meta@carry=0.05@carry_weight=fixed");
    let ref_mean: Vec<f64> = (0..3).map(|k| reference.iter().map(|p| p[k] as f64).sum::<f64>() / reference.len() as f64).collect();
    let (bias, ms_carried) = error_stats(&carried, &reference);
    let (_, ms_fresh) = error_stats(&fresh, &reference);
    for k in 0..3 {
        assert!(bias[k].abs() < 0.01 * ref_mean[k], "channel {k}: the carried image's mean is off by {} (image mean {})", bias[k], ref_mean[k]);
    }
    let (rms_carried, rms_fresh) = (ms_carried.sqrt(), ms_fresh.sqrt());
    assert!(rms_carried < 0.5 * rms_fresh, "carried image RMS error {rms_carried} against a fresh render's {rms_fresh}");
}

/// The inverse-variance weights (`carry_weight=variance`): the variances the carry estimates
/// and tracks are those measured against a 512-spp render of the same θ (the fresh render's
/// from its difference with the finite-difference image of θ, the carried image's through
/// the iterations, the adjoint pass's render mixed in), and the carried image is unbiased
/// with less noise than a fresh render.
#[test]
fn carried_image_variance_weights_estimate_the_variances_they_weigh() {
    // With the defaults' adjoint render mixed into the carried image after each carry.
    let (carried, reference, fresh, state) = carried_run("meta@carry=0.001@carry_weight=variance");
    assert!(state.weight_adjoint > 0.0, "the adjoint render was not taken in");
    // The reference's own variance, at 512 spp against the fresh render's primal_spp.
    let primal_spp = vkinverse::settings::RunSettings::of_scene(&Scene::load("scenes/cornell/scene.toml").unwrap()).primal_spp;
    let ref_var = state.var_fresh as f64 * primal_spp as f64 / 512.0;
    let (bias, ms_carried) = error_stats(&carried, &reference);
    let (_, ms_fresh) = error_stats(&fresh, &reference);
    let ref_mean: Vec<f64> = (0..3).map(|k| reference.iter().map(|p| p[k] as f64).sum::<f64>() / reference.len() as f64).collect();
    for k in 0..3 {
        assert!(bias[k].abs() < 0.01 * ref_mean[k], "channel {k}: the carried image's mean is off by {} (image mean {})", bias[k], ref_mean[k]);
    }
    let fresh_ratio = state.var_fresh as f64 / (ms_fresh - ref_var);
    assert!(
        (0.8..1.25).contains(&fresh_ratio),
        "the fresh render's estimated variance {} against its measured {} (ratio {fresh_ratio})",
        state.var_fresh,
        ms_fresh - ref_var
    );
    // Tracked through 30 carries (measured: 0.9 of the carried image's squared error, the
    // fresh render's estimate 1.0 of its own).
    let carried_ratio = state.var_carried as f64 / (ms_carried - ref_var).max(1e-12);
    assert!(
        (0.6..1.7).contains(&carried_ratio),
        "the carried image's tracked variance {} against its measured {} (ratio {carried_ratio})",
        state.var_carried,
        ms_carried - ref_var
    );
    assert!(state.weight > 0.0 && state.weight < 0.5, "weight {} of the fresh render after 30 iterations", state.weight);
    assert!(ms_carried < 0.25 * ms_fresh, "carried image's mean squared error {ms_carried} against a fresh render's {ms_fresh}");
}

/// A buffer bound as θ or θ_{i-1} is shaped like the scene's θ buffer, material data
/// included: one holding θ alone is refused with the sizes named, not read past its end.
#[test]
fn a_theta_buffer_without_the_material_data_is_refused() {
    with_gpu(|ctx| {
        let (_, renderer, imgs, ops, theta_prev) = fd_setup(ctx, "scenes/cornell/scene.toml", 0.05);
        let gs = &renderer.scene;
        let grad = Buffer::zeroed::<f32>(ctx, "fd", gs.layout.len, MemoryKind::Device).unwrap();
        let bare = vkinverse::render::texel_buffer(ctx, "bare theta", &gs.layout.initial()).unwrap();
        assert!(bare.len() < gs.theta.len(), "the Cornell box has material data after θ");
        for (theta, prev) in [(&bare, None), (&gs.theta, Some(&bare))] {
            let e = GradientPass::new(
                gs,
                &ops,
                &GradientInputs {
                    targets: &imgs,
                    loss: vkinverse::settings::Loss::L2,
                    spp: 1,
                    primal_spp: 1,
                    seed: 5,
                    theta,
                    theta_prev: prev,
                    grad: &grad,
                    grad_half: None,
                },
            )
            .err()
            .expect("refused");
            assert!(e.to_string().contains("bare theta") && e.to_string().contains(&gs.theta.len().to_string()), "{e}");
        }
        GradientPass::new(
            gs,
            &ops,
            &GradientInputs {
                targets: &imgs,
                loss: vkinverse::settings::Loss::L2,
                spp: 1,
                primal_spp: 1,
                seed: 5,
                theta: &gs.theta,
                theta_prev: Some(&theta_prev),
                grad: &grad,
                grad_half: None,
            },
        )
        .unwrap();
    });
}

/// A medium's density and emission grids (4³, random) over a floor lit by a point light
/// and the sky: the fused sample marches both states along the same steps (one jitter per
/// ray), and its shadow rays' transmittance per state, so it equals the two-trace sample up
/// to float summation order.
#[test]
fn fused_equals_two_trace_through_a_medium() {
    let dir = common::scenes::temp_dir("fd-medium");
    let n = 4usize;
    let value = |i: usize, k: u32| ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(k) >> 8) as f32 / (1u32 << 24) as f32;
    let density = vkinverse::npy::Array { shape: vec![n, n, n], data: (0..n * n * n).map(|i| 0.3 + 1.5 * value(i, 1)).collect() };
    let emission = vkinverse::npy::Array { shape: vec![n, n, n, 3], data: (0..n * n * n * 3).map(|i| 0.05 + 0.4 * value(i, 7)).collect() };
    vkinverse::npy::write(&dir.join("density.npy"), &density).unwrap();
    vkinverse::npy::write(&dir.join("emission.npy"), &emission).unwrap();
    std::fs::write(dir.join("floor.obj"), "v -3 -1 -3\nv 3 -1 -3\nv 3 -1 3\nv -3 -1 3\nf 1 3 2\nf 1 4 3\n").unwrap();
    let toml = "[film]\nwidth = 10\nheight = 10\n[integrator]\nmax_depth = 3\n\
                [[sensors]]\norigin = [0.6, 1.4, 4]\ntarget = [0, -0.2, 0]\nfov_y = 40\n\
                [environment]\nconstant = [0.1, 0.2, 0.3]\n\
                [[materials]]\nname = \"floor\"\ntype = \"diffuse\"\nbase_color = [0.6, 0.5, 0.4]\n\
                [[meshes]]\nname = \"floor\"\nfile = \"floor.obj\"\nmaterial = \"floor\"\n\
                [[lights]]\nname = \"bulb\"\ntype = \"point\"\nposition = [1.5, 2, 1]\nintensity = 6\n\
                [[media]]\nname = \"cloud\"\nmin = [-1, -0.8, -1]\nmax = [1, 0.8, 1]\ndensity = \"density.npy\"\nemission = \"emission.npy\"\n\
                [[optimise.params]]\ntarget = \"media.cloud.density\"\ninit = 1.0\nrange = [0, 10]\n\
                [[optimise.params]]\ntarget = \"media.cloud.emission\"\ninit = 0.2\nrange = [0, 10]\n";
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    let (fused, two) = fd_samples(dir.join("scene.toml").to_str().unwrap(), 0.05, 2, 2);
    let mut worst = 0f32;
    for (a, b) in fused.iter().zip(&two) {
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
        for (x, y) in a.iter().zip(b) {
            worst = worst.max((x - y).abs() / scale);
            assert!((x - y).abs() <= 1e-5 * scale, "fused {x} vs two-trace {y} (largest element {scale})");
        }
        assert!(a.iter().filter(|v| v.abs() > 1e-7).count() > a.len() / 2, "a 0.05 step changes most elements' gradient");
    }
    eprintln!("fused against two-trace through a medium: largest difference {worst:.1e} of the largest element");
}

/// The meta optimiser's θ_{i−1} is shaped like θ's buffer, the scene's material data after
/// θ included, which the two-trace finite difference renders from: past θ it equals θ's
/// buffer (the door-ajar scene's texture among the data), and an iteration that moves
/// θ_{i−1} leaves them as they are.
#[test]
fn the_previous_theta_holds_the_material_data() {
    use vkinverse::engine::Engine;
    use vkinverse::settings::RunSettings;
    let scene = Scene::load("scenes/ajar/scene.toml").unwrap();
    let mut settings = RunSettings::of_scene(&scene);
    settings.optimiser = "meta".parse().unwrap();
    with_gpu(|ctx| {
        let engine = Engine::new(&crate::common::device(ctx), &scene, &settings, &mut (), &Default::default()).unwrap();
        let gs = engine.scene();
        let base = gs.const_base as usize;
        let prev = engine.optimiser().unwrap().theta_prev.as_ref().expect("meta keeps θ_{i−1}");
        let data: Vec<f32> = gs.theta.read().unwrap();
        assert!(data[base..].iter().filter(|&&v| v != 0.0).count() > 16, "the scene has material data");
        assert_eq!(prev.read::<f32>().unwrap()[base..], data[base..]);
        let mut iteration = engine.iteration().unwrap();
        engine.step(&mut iteration, 0).unwrap();
        assert_eq!(prev.read::<f32>().unwrap()[base..], data[base..], "an iteration moves θ's part alone");
    });
}
