//! The forward path tracer on analytic scenes.

mod common;

use common::scenes::{sphere_obj, write_scene};
use common::with_gpu;
use vkinverse::render::{GpuScene, Renderer};
use vkinverse::scene::Scene;

const ENV: [f32; 3] = [0.8, 0.6, 0.4];
const RHO: f32 = 0.5;

fn convex_scene(max_depth: u32) -> Scene {
    let toml = format!(
        r#"
[film]
width = 24
height = 20
[integrator]
max_depth = {max_depth}
rr_depth = 10
[[sensors]]
origin = [0, 0, 4]
target = [0, 0, 0]
up = [0, 1, 0]
fov_y = 40
[[materials]]
name = "grey"
type = "diffuse"
base_color = [{RHO}, {RHO}, {RHO}]
[[meshes]]
file = "sphere.obj"
material = "grey"
[environment]
constant = [{}, {}, {}]
"#,
        ENV[0], ENV[1], ENV[2]
    );
    Scene::load(write_scene(&format!("convex{max_depth}"), &toml, &sphere_obj(1.0, 3, false))).unwrap()
}

/// White furnace, outside: a convex diffuse object in a constant environment. Every
/// camera sample either misses (exactly L) or hits, and a cosine-sampled Lambertian
/// bounce weighs exactly ρ and escapes (the object is convex), so a pixel is exactly
/// L (depth 1 sees no light on the object: 0) mixed by coverage: no Monte Carlo noise
/// (Russian roulette, the only other random choice, starts deeper than these paths).
#[test]
fn white_furnace_convex_object_is_exact() {
    with_gpu(|ctx| {
        for max_depth in [1u32, 2, 5] {
            let scene = convex_scene(max_depth);
            let r = Renderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
            let img = r.render(0, 8, 1, |_, _| {}).unwrap();
            let hit_value = if max_depth == 1 { 0.0 } else { RHO };
            let (w, h) = (img.width, img.height);
            // The centre pixel sees only the sphere, the corner only the environment.
            let centre = img.get(w / 2, h / 2);
            let corner = img.get(0, 0);
            for c in 0..3 {
                assert!((centre[c] - hit_value * ENV[c]).abs() <= 1e-5, "depth {max_depth} centre {centre:?}");
                assert!((corner[c] - ENV[c]).abs() <= 1e-6, "depth {max_depth} corner {corner:?}");
            }
            // Every pixel is a coverage mix: the same ratio to L in every channel, within [hit, 1].
            for px in &img.data {
                let r0 = px[0] / ENV[0];
                for c in 0..3 {
                    assert!((px[c] / ENV[c] - r0).abs() <= 1e-5, "{px:?}");
                }
                assert!(r0 >= hit_value - 1e-5 && r0 <= 1.0 + 1e-5, "{px:?}");
            }
        }
    });
}

/// White furnace, inside: the camera inside a closed sphere that emits Le towards its
/// inside and reflects with albedo ρ. Every point sees the same radiance, the geometric
/// series Le Σ_{k<D} ρ^k for max depth D. Light sampling, BSDF sampling and Russian
/// roulette all take part, so the check is statistical: the image mean within 5 standard
/// errors (the pixels are independent estimates).
#[test]
fn white_furnace_inside_emitting_sphere_is_geometric_series() {
    with_gpu(|ctx| {
        for (max_depth, rr_depth) in [(1u32, 5u32), (2, 5), (4, 5), (6, 3)] {
            let toml = format!(
                r#"
[film]
width = 32
height = 32
[integrator]
max_depth = {max_depth}
rr_depth = {rr_depth}
[[sensors]]
origin = [0.1, -0.2, 0.3]
target = [0, 0, -1]
up = [0, 1, 0]
fov_y = 70
[[materials]]
name = "grey"
type = "diffuse"
base_color = [{RHO}, {RHO}, {RHO}]
[[meshes]]
file = "sphere.obj"
material = "grey"
emission = [1.0, 2.0, 0.5]
"#
            );
            let scene = Scene::load(write_scene(&format!("inside{max_depth}"), &toml, &sphere_obj(2.0, 3, true))).unwrap();
            let r = Renderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
            let img = r.render(0, 16, 7, |_, _| {}).unwrap();
            let series: f32 = (0..max_depth).map(|k| RHO.powi(k as i32)).sum();
            let le = [1.0f32, 2.0, 0.5];
            for c in 0..3 {
                let v: Vec<f64> = img.data.iter().map(|p| p[c] as f64).collect();
                let n = v.len() as f64;
                let mean = v.iter().sum::<f64>() / n;
                let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
                let se = (var / n).sqrt();
                let expected = (le[c] * series) as f64;
                assert!(
                    (mean - expected).abs() <= 5.0 * se + 1e-4 * expected,
                    "depth {max_depth} channel {c}: mean {mean} expected {expected} (se {se})"
                );
            }
        }
    });
}

#[test]
fn same_seed_same_image() {
    with_gpu(|ctx| {
        let scene = Scene::load("scenes/cornell/scene.toml").unwrap();
        let r = Renderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
        let a = r.render(0, 2, 3, |_, _| {}).unwrap();
        let b = r.render(0, 2, 3, |_, _| {}).unwrap();
        let c = r.render(0, 2, 4, |_, _| {}).unwrap();
        let bits = |i: &vkinverse::image::Image| i.data.iter().flat_map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
        assert_eq!(bits(&a), bits(&b), "same seed must give a bit-identical image");
        assert_ne!(bits(&a), bits(&c), "another seed must give another image");
        assert!(a.data.iter().all(|p| p.iter().all(|v| v.is_finite() && *v >= 0.0)));
        let mean: f32 = a.data.iter().map(|p| p[0] + p[1] + p[2]).sum::<f32>() / a.data.len() as f32;
        assert!(mean > 0.01, "the Cornell box is lit: mean {mean}");
    });
}
