//! The target cache: keyed on the scene's content and the renderer's SPIR-V (another
//! renderer, here the other BVH layout's build of trace_primal, renders anew); the run's
//! target sample count; the image error.

use crate::common;

use common::scenes::{renders_targets, sphere_obj, temp_dir, write_scene, TARGET_SCENE};
use common::with_gpu;
use vkinverse::bvh::BvhLayout;
use vkinverse::scene::Scene;
use vkinverse::settings::{RunSettings, Settings};

/// A change of renderer (here the other BVH layout's build of trace_primal) renders its
/// targets anew, under its own key beside the scene; the same renderer reads them back.
#[test]
fn a_renderer_change_invalidates_the_cache() {
    let path = write_scene("target-cache", TARGET_SCENE, &sphere_obj(1.0, 1, false));
    let scene = Scene::load(&path).unwrap();
    let beside = scene.dir().join(".vkinverse-cache");
    common::with_gpu(|ctx| {
        assert!(renders_targets(ctx, &scene, BvhLayout::Wide), "nothing cached yet");
        assert!(!renders_targets(ctx, &scene, BvhLayout::Wide), "the same renderer reads its cached target");
        assert!(renders_targets(ctx, &scene, BvhLayout::Binary), "another renderer's SPIR-V is another key");
        assert!(!renders_targets(ctx, &scene, BvhLayout::Binary));
        assert_eq!(std::fs::read_dir(&beside).unwrap().count(), 2);
    });
}

/// The run's `target_spp` (scene `[optimise]`, command line, job file) is the sample count
/// the engine renders its targets with, and a key of the cache.
#[test]
fn the_run_renders_its_targets_at_target_spp() {
    let scene_text = TARGET_SCENE.replace("[optimise]\n", "[optimise]\ntarget_spp = 8\n");
    let path = write_scene("target-spp", &scene_text, &sphere_obj(1.0, 1, false));
    let scene = Scene::load(&path).unwrap();
    let beside = scene.dir().join(".vkinverse-cache");
    let cached = || -> Vec<String> {
        let mut names: Vec<String> =
            std::fs::read_dir(&beside).map(|d| d.map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect()).unwrap_or_default();
        names.sort();
        names
    };
    common::with_gpu(|ctx| {
        let from_scene = RunSettings::of_scene(&scene);
        assert_eq!(from_scene.target_spp, 8);
        struct Rendered(Vec<(u32, u32)>);
        impl vkinverse::Observer for Rendered {
            fn target_progress(&mut self, _: usize, done: u32, total: u32) {
                self.0.push((done, total));
            }
        }
        let mut progress = Rendered(Vec::new());
        let device = common::device(ctx);
        vkinverse::engine::Engine::new(&device, &scene, &from_scene, &mut progress, &Default::default()).unwrap();
        let rendered = progress.0;
        assert_eq!(rendered.last(), Some(&(8, 8)), "progress reports the target's samples");
        assert!(matches!(cached().as_slice(), [one] if one.ends_with("-s0-8spp.exr")), "{:?}", cached());
        // Given outside the scene it wins, and is cached under its own key.
        let over = Settings { target_spp: Some(16), ..Default::default() };
        let run = Settings::resolve(&scene.optimise.settings, &over);
        vkinverse::engine::Engine::new(&device, &scene, &run, &mut (), &Default::default()).unwrap();
        let names = cached();
        assert_eq!(names.len(), 2, "{names:?}");
        assert!(names.iter().any(|n| n.ends_with("-s0-16spp.exr")), "{names:?}");
    });
}

/// [`TARGET_SCENE`] seen from above over a plane, at depth 3: the plane's shadow and the sphere's
/// reflection of it make every render noisy.
fn noisy_scene() -> String {
    let floor = "[[materials]]\nname = \"floor\"\ntype = \"diffuse\"\nbase_color = [0.6, 0.6, 0.6]\n[[meshes]]\nfile = \"plane.obj\"\nmaterial = \"floor\"\n";
    let scene = TARGET_SCENE
        .replace("width = 8\nheight = 8", "width = 16\nheight = 16")
        .replace("max_depth = 2", "max_depth = 3")
        .replace("origin = [0, 0, 3]", "origin = [0, 2.5, 3]");
    scene.replace("[optimise]\n", "[optimise]\ntarget_spp = 64\n") + floor
}

fn mse(a: &vkinverse::image::Image, b: &vkinverse::image::Image) -> f64 {
    let sum: f64 = a.data.iter().zip(&b.data).flat_map(|(p, q)| (0..3).map(move |c| (f64::from(p[c]) - f64::from(q[c])).powi(2))).sum();
    sum / (3 * a.data.len()) as f64
}

/// The image error (`summary.json`'s `final_image_error`) estimates the squared distance
/// of θ's expected image from the target without the renders' noise: averaged over eight
/// pairs of renders of 4 spp it agrees with the same from two renders of 1024 (one pair's
/// estimate is as noisy as the renders' variance is large), where the squared difference
/// of each pair's mean from the target carries their variance too; at the reference it is
/// the target's own noise only. θ is restored after rendering another θ.
#[test]
fn image_error_leaves_out_the_renders_noise() {
    let path = write_scene("image-error", &noisy_scene(), &sphere_obj(1.0, 2, false));
    std::fs::write(path.with_file_name("plane.obj"), common::scenes::PLANE_OBJ).unwrap();
    let scene = Scene::load(&path).unwrap();
    common::with_gpu(|ctx| {
        let engine = vkinverse::engine::Engine::new(&common::device(ctx), &scene, &RunSettings::of_scene(&scene), &mut (), &Default::default()).unwrap();
        let theta = engine.theta().unwrap();
        let reference = engine.scene().layout.reference();
        assert_ne!(theta, reference);
        let (clean, _) = engine.image_error(None, 1024, [11, 12]).unwrap();
        // Eight estimates from renders of 4 spp, and the squared difference of each pair's
        // mean from the target.
        let (mut estimate, mut naive) = (0.0, 0.0);
        for k in 0..8 {
            let (e, means) = engine.image_error(None, 4, [100 + 2 * k, 101 + 2 * k]).unwrap();
            estimate += e / 8.0;
            naive += mse(&means[0], &engine.targets[0]) / 8.0;
        }
        let (at_ref, ref_means) = engine.image_error(Some(&reference), 4, [13, 14]).unwrap();
        let naive_ref = mse(&ref_means[0], &engine.targets[0]);
        assert_eq!(engine.theta().unwrap(), theta, "θ is the optimised θ again");
        let miss = (estimate - clean).abs();
        assert!(miss < 0.03 * clean, "4 spp: {estimate:.4e}, 1024 spp: {clean:.4e}");
        assert!(naive - clean > 4.0 * miss, "the mean's squared difference adds the renders' variance: {naive:.4e} against {clean:.4e}");
        assert!(at_ref.abs() < 0.3 * (naive_ref - at_ref), "at the reference only the target's noise: {at_ref:.4e}, the 8-spp mean's {naive_ref:.4e}");
        assert!(clean > 10.0 * at_ref.abs());
    });
}

/// A scene directory that cannot take the target cache (a file stands where the cache
/// directory would be, which stops root too) has its targets cached in the configured cache
/// directory (the user's, on the command line), and read back from there.
#[test]
fn a_read_only_scene_uses_the_configured_cache() {
    let user_cache = temp_dir("user-cache");
    let path = write_scene("target-cache-ro", TARGET_SCENE, &sphere_obj(1.0, 1, false));
    std::fs::write(path.with_file_name(".vkinverse-cache"), "not a directory").unwrap();
    let scene = Scene::load(&path).unwrap();
    assert_eq!(vkinverse::render::targets::cache_dirs(&scene, Some(&user_cache))[1], user_cache);
    with_gpu(|ctx| {
        let before = std::fs::read_dir(&user_cache).unwrap().count();
        assert!(common::scenes::renders_targets_cached(ctx, &scene, BvhLayout::Wide, Some(&user_cache)));
        assert_eq!(std::fs::read_dir(&user_cache).unwrap().count(), before + 1);
        assert!(!common::scenes::renders_targets_cached(ctx, &scene, BvhLayout::Wide, Some(&user_cache)), "read back from the user cache");
    });
}
