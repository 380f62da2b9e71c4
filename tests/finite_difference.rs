//! The fused finite-difference sample (one trace, both parameter states) against the
//! straightforward one (one gradient estimate per state with the same seeds).

mod common;

use common::with_gpu;
use vkinverse::gpu::{Buffer, CommandBuffer, MemoryKind};
use vkinverse::ops::BufferOps;
use vkinverse::render::gradient::GradientPass;
use vkinverse::render::targets::targets;
use vkinverse::render::{GpuScene, Renderer};
use vkinverse::scene::Scene;

/// What a finite-difference sample of a scene needs: the scene, its renderer (θ at the
/// scene's init), cheap targets, the buffer operations and θ_{i-1} with every element moved
/// by `shift` inside its range.
fn fd_setup(ctx: &std::sync::Arc<vkinverse::gpu::Context>, scene_path: &str, shift: f32) -> (Scene, Renderer, Vec<vkinverse::image::Image>, BufferOps, Buffer) {
    let scene = Scene::load(scene_path).unwrap();
    let renderer = Renderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
    let gs = &renderer.scene;
    // Target quality is irrelevant to these comparisons: few samples keep the tests short.
    let imgs = targets(&renderer, &scene, 16, |_, _, _| {}).unwrap();
    let ops = BufferOps::new(ctx).unwrap();
    let theta = gs.layout.initial();
    let mut prev_vals = theta.clone();
    for slot in &gs.layout.slots {
        for v in &mut prev_vals[slot.offset..slot.offset + slot.len] {
            *v = if *v + shift <= slot.range[1] { *v + shift } else { *v - shift };
        }
    }
    gs.set_theta(theta).unwrap();
    // Read as texels by the trace kernels, like the scene's θ.
    let theta_prev = vkinverse::render::texel_buffer(ctx, "theta prev", &prev_vals).unwrap();
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
        let fused = GradientPass::new(gs, &ops, &imgs, loss, spp, spp, seed, &gs.theta, Some(&theta_prev), &fused_grad, None).unwrap();
        let cur = GradientPass::new(gs, &ops, &imgs, loss, spp, spp, seed, &gs.theta, None, &g_cur, None).unwrap();
        let prv = GradientPass::new(gs, &ops, &imgs, loss, spp, spp, seed, &theta_prev, None, &g_prev, None).unwrap();
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
    let (fused, two) = fd_samples("scenes/cornell/scene.toml", 0.05, 2, 2);
    for (a, b) in fused.iter().zip(&two) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-4 * y.abs() + 1e-8, "fused {x} vs two-trace {y}");
        }
        assert!(a.iter().any(|v| v.abs() > 1e-7), "a 0.05 step changes the gradient: {a:?}");
    }
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
            let mut pass = GradientPass::new(gs, &ops, &imgs, loss, 1, 1, 5, &gs.theta, Some(&theta_prev), &grad, None).unwrap();
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
    let quad = "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nf 1 4 3 2\n";
    let light = "v -0.3 1.2 -0.8\nv 0.3 1.2 -0.8\nv 0.3 1.2 -0.2\nv -0.3 1.2 -0.2\nf 1 2 3 4\n";
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
        let dir = common::scenes::temp_dir(&format!("fd-env-{i}"));
        let mut sky = vkinverse::image::Image::filled(16, 8, [0.05, 0.06, 0.08]);
        sky.data[2 * 16 + 8] = [60.0, 50.0, 30.0];
        vkinverse::image::write_exr(&dir.join("sky.exr"), &sky).unwrap();
        std::fs::write(dir.join("quad.obj"), quad).unwrap();
        std::fs::write(dir.join("light.obj"), light).unwrap();
        let toml = format!(
            r#"
[film]
width = 16
height = 16
[integrator]
max_depth = 3
rr_depth = 5
[[sensors]]
origin = [0, 1.2, 1.8]
target = [0, 0, -0.1]
up = [0, 1, 0]
fov_y = 50
[[materials]]
name = "floor"
type = "diffuse"
base_color = [0.7, 0.4, 0.2]
[[materials]]
name = "black"
type = "diffuse"
base_color = [0, 0, 0]
[[meshes]]
file = "quad.obj"
material = "floor"
[[meshes]]
file = "light.obj"
material = "black"
emission = [6, 6, 6]
[environment]
file = "sky.exr"
[optimise]
{optimise}
"#
        );
        std::fs::write(dir.join("scene.toml"), toml).unwrap();
        let (fused, two) = fd_samples(dir.join("scene.toml").to_str().unwrap(), 0.05, 2, 2);
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

/// The carry pass (glsl/carry_image.comp) against its formula, on two sensors' images of a
/// pixel count that is no multiple of the workgroup: the first carry takes the fresh image,
/// later ones the running mean and then the EMA of weight `w_min` of the fresh image and the
/// carried one moved by cur − prev; the losses' images are replaced by the result.
#[test]
fn carry_pass_follows_its_formula() {
    use vkinverse::engine::Carry;
    with_gpu(|ctx| {
        let (pixels, w_min, rounds) = (1000usize, 0.3f64, 5u32);
        let ops = BufferOps::new(ctx).unwrap();
        let mk = |name: &str| Buffer::zeroed::<[f32; 3]>(ctx, name, pixels, MemoryKind::Device).unwrap();
        let bufs: Vec<[Buffer; 3]> = (0..2).map(|s| [mk(&format!("fresh {s}")), mk(&format!("cur {s}")), mk(&format!("prev {s}"))]).collect();
        let triples: Vec<(&Buffer, &Buffer, &Buffer)> = bufs.iter().map(|[f, c, p]| (f, c, p)).collect();
        let carry = Carry::new(ctx, pixels, &triples, w_min).unwrap();
        let mut cmd = CommandBuffer::new(ctx, "carry").unwrap();
        cmd.record(|rec| carry.record(rec, &ops, None)).unwrap();
        let value = |s: usize, r: u32, i: usize, kind: u32| -> [f32; 3] {
            let x = (s * 7919 + r as usize * 104729 + i * 31 + kind as usize * 17) as f32;
            [(x * 0.37).sin(), (x * 0.11).cos() * 2.0, (x * 0.05).sin() + 1.0]
        };
        let mut expected: Vec<Vec<[f64; 3]>> = vec![vec![[0.0; 3]; pixels]; 2];
        for r in 0..rounds {
            for (s, [f, c, p]) in bufs.iter().enumerate() {
                f.write(&(0..pixels).map(|i| value(s, r, i, 0)).collect::<Vec<_>>()).unwrap();
                c.write(&(0..pixels).map(|i| value(s, r, i, 1)).collect::<Vec<_>>()).unwrap();
                p.write(&(0..pixels).map(|i| value(s, r, i, 2)).collect::<Vec<_>>()).unwrap();
            }
            cmd.submit_and_wait().unwrap();
            let w = (1.0 / (r as f64 + 1.0)).max(w_min);
            for (s, [f, c, p]) in bufs.iter().enumerate() {
                let (fresh, cur, prev): (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 3]>) = (f.read().unwrap(), c.read().unwrap(), p.read().unwrap());
                let carried: Vec<[f32; 3]> = carry.image(s).read().unwrap();
                for i in 0..pixels {
                    let (vf, vc, vp) = (value(s, r, i, 0), value(s, r, i, 1), value(s, r, i, 2));
                    for k in 0..3 {
                        let diff = vc[k] as f64 - vp[k] as f64;
                        let e = if r == 0 { vf[k] as f64 } else { w * vf[k] as f64 + (1.0 - w) * (expected[s][i][k] + diff) };
                        expected[s][i][k] = e;
                        let close = |got: f32, want: f64| (got as f64 - want).abs() <= 1e-5 * (1.0 + want.abs());
                        assert!(close(carried[i][k], e), "round {r} sensor {s} pixel {i}: carried {} against {e}", carried[i][k]);
                        assert!(close(fresh[i][k], e) && close(cur[i][k], e), "round {r} sensor {s} pixel {i}: the losses' image of θ is not the carried one");
                        assert!(close(prev[i][k], e - diff), "round {r} sensor {s} pixel {i}: prev {} against {}", prev[i][k], e - diff);
                    }
                }
            }
        }
    });
}

/// A meta-estimator run with the carried image (`carry`): after 30 iterations in which θ
/// moves, the carried image agrees with a 512-spp render of the θ it belongs to (the carry
/// follows θ through the finite differences instead of lagging behind: without them the
/// green channel's mean is 5 % off here, with them 0.2 %), and is closer to it than a
/// fresh render at the run's primal_spp (an RMS error of about a fifth).
#[test]
fn carried_image_follows_the_parameters_with_less_noise_than_a_fresh_render() {
    use vkinverse::engine::Engine;
    use vkinverse::optim::spec::Spec;
    use vkinverse::settings::RunSettings;
    let scene = Scene::load("scenes/cornell/scene.toml").unwrap();
    let mut settings = RunSettings::of_scene(&scene);
    settings.optimiser = "meta@carry=0.05".parse::<Spec>().unwrap();
    with_gpu(|ctx| {
        let engine = Engine::new(ctx, &scene, &settings, |_, _, _| {}).unwrap();
        let mut iteration = engine.iteration().unwrap();
        let iterations = 30;
        let mut theta_of_last = engine.theta().unwrap();
        for i in 0..iterations {
            if i + 1 == iterations {
                theta_of_last = engine.theta().unwrap();
            }
            engine.step(&mut iteration, i).unwrap();
        }
        let start = engine.scene().layout.initial();
        let moved = theta_of_last.iter().zip(&start).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(moved > 0.05, "θ moved by {moved} only: the test needs a moving θ");
        let carried: Vec<[f32; 3]> = engine.carry.as_ref().expect("meta@carry builds a carry").image(0).read().unwrap();
        engine.scene().set_theta(theta_of_last).unwrap();
        let reference = engine.renderer.render(0, 512, 77, |_, _| {}).unwrap();
        let fresh = engine.renderer.render(0, settings.primal_spp, 78, |_, _| {}).unwrap();
        let stats = |img: &[[f32; 3]]| -> ([f64; 3], f64) {
            let mut mean = [0f64; 3];
            let mut sq = 0f64;
            for (a, b) in img.iter().zip(&reference.data) {
                for k in 0..3 {
                    let d = a[k] as f64 - b[k] as f64;
                    mean[k] += d / img.len() as f64;
                    sq += d * d / (3 * img.len()) as f64;
                }
            }
            (mean, sq.sqrt())
        };
        let ref_mean: Vec<f64> = (0..3).map(|k| reference.data.iter().map(|p| p[k] as f64).sum::<f64>() / reference.data.len() as f64).collect();
        let (bias, rms_carried) = stats(&carried);
        let (_, rms_fresh) = stats(&fresh.data);
        for k in 0..3 {
            assert!(bias[k].abs() < 0.01 * ref_mean[k], "channel {k}: the carried image's mean is off by {} (image mean {})", bias[k], ref_mean[k]);
        }
        assert!(rms_carried < 0.5 * rms_fresh, "carried image RMS error {rms_carried} against a fresh render's {rms_fresh}");
    });
}
