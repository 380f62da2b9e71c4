//! The target cache: keyed on the scene's content and the renderer's SPIR-V (another
//! renderer, here the other BVH layout's build of trace_primal, renders anew), and kept in
//! the user's cache directory when the scene's cannot be written.

mod common;

use common::scenes::{sphere_obj, temp_dir, write_scene};
use vkinverse::bvh::BvhLayout;
use vkinverse::render::targets::{cache_dirs, targets};
use vkinverse::render::{GpuScene, Renderer};
use vkinverse::scene::Scene;
use vkinverse::settings::{RunSettings, Settings};

const SCENE: &str = r#"[film]
width = 8
height = 8
[integrator]
max_depth = 2
[[sensors]]
origin = [0, 0, 3]
target = [0, 0, 0]
fov_y = 40
[[materials]]
name = "m"
type = "diffuse"
base_color = [0.5, 0.5, 0.5]
[[meshes]]
file = "sphere.obj"
material = "m"
[environment]
constant = [1, 1, 1]
[optimise]
[[optimise.params]]
target = "materials.m.base_color"
init = 0.2
range = [0, 1]
"#;

/// Renders (or loads) the targets with `layout`; true if anything was rendered.
fn rendered(ctx: &std::sync::Arc<vkinverse::gpu::Context>, scene: &Scene, layout: BvhLayout) -> bool {
    let renderer = Renderer::new(GpuScene::with_bvh_layout(ctx, scene, layout).unwrap()).unwrap();
    let mut any = false;
    targets(&renderer, scene, 4, |_, _, _| any = true).unwrap();
    any
}

#[test]
fn a_renderer_change_invalidates_the_cache_and_a_read_only_scene_uses_the_user_cache() {
    let user_cache = temp_dir("user-cache");
    // Only this test binary's process reads the variable.
    std::env::set_var("VKINVERSE_CACHE_DIR", &user_cache);
    let path = write_scene("target-cache", SCENE, &sphere_obj(1.0, 1, false));
    let scene = Scene::load(&path).unwrap();
    let beside = scene.dir().join(".vkinverse-cache");
    common::with_gpu(|ctx| {
        assert!(rendered(ctx, &scene, BvhLayout::Wide), "nothing cached yet");
        assert!(!rendered(ctx, &scene, BvhLayout::Wide), "the same renderer reads its cached target");
        assert!(rendered(ctx, &scene, BvhLayout::Binary), "another renderer's SPIR-V is another key");
        assert!(!rendered(ctx, &scene, BvhLayout::Binary));
        assert_eq!(std::fs::read_dir(&beside).unwrap().count(), 2);

        // A scene directory that cannot take the cache (here a file stands where the cache
        // directory would be, which stops root too): the user cache takes it.
        let ro = write_scene("target-cache-ro", SCENE, &sphere_obj(1.0, 1, false));
        std::fs::write(ro.with_file_name(".vkinverse-cache"), "not a directory").unwrap();
        let scene = Scene::load(&ro).unwrap();
        assert_eq!(cache_dirs(&scene)[1], user_cache);
        let before = std::fs::read_dir(&user_cache).unwrap().count();
        assert!(rendered(ctx, &scene, BvhLayout::Wide));
        assert_eq!(std::fs::read_dir(&user_cache).unwrap().count(), before + 1);
        assert!(!rendered(ctx, &scene, BvhLayout::Wide), "read back from the user cache");
    });
}

/// The run's `target_spp` (scene `[optimise]`, command line, job file) is the sample count
/// the engine renders its targets with, and a key of the cache.
#[test]
fn the_run_renders_its_targets_at_target_spp() {
    let scene_text = SCENE.replace("[optimise]\n", "[optimise]\ntarget_spp = 8\n");
    let path = write_scene("target-spp", &scene_text, &sphere_obj(1.0, 1, false));
    let scene = Scene::load(&path).unwrap();
    let beside = scene.dir().join(".vkinverse-cache");
    let cached = || -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(&beside).map(|d| d.map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect()).unwrap_or_default();
        names.sort();
        names
    };
    common::with_gpu(|ctx| {
        let from_scene = RunSettings::of_scene(&scene);
        assert_eq!(from_scene.target_spp, 8);
        let mut rendered = Vec::new();
        vkinverse::engine::Engine::new(ctx, &scene, &from_scene, |_, done, total| rendered.push((done, total))).unwrap();
        assert_eq!(rendered.last(), Some(&(8, 8)), "progress reports the target's samples");
        assert!(matches!(cached().as_slice(), [one] if one.ends_with("-s0-8spp.exr")), "{:?}", cached());
        // Given outside the scene it wins, and is cached under its own key.
        let over = Settings { target_spp: Some(16), ..Default::default() };
        let run = Settings::resolve(&scene.optimise.settings, &over);
        vkinverse::engine::Engine::new(ctx, &scene, &run, |_, _, _| {}).unwrap();
        let names = cached();
        assert_eq!(names.len(), 2, "{names:?}");
        assert!(names.iter().any(|n| n.ends_with("-s0-16spp.exr")), "{names:?}");
    });
}
