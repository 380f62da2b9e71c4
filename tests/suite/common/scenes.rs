//! Small analytic test scenes written to a temporary directory.
#![allow(dead_code)]

use std::fmt::Write as _;
use std::path::PathBuf;

/// A fresh, empty temporary directory for one test, named by the process, the test file
/// that asks for it (through the helpers here, which pass their caller on) and `name`:
/// the suite's modules share one process, and may pick the same names.
#[track_caller]
pub fn temp_dir(name: &str) -> PathBuf {
    let file = std::panic::Location::caller().file();
    let module = std::path::Path::new(file).file_stem().and_then(|s| s.to_str()).unwrap_or("test");
    let dir = std::env::temp_dir().join(format!("vkinverse-test-{}-{module}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A sphere of `radius` tessellated from an octahedron subdivided `levels` times, as OBJ
/// text without normals (flat shading). `inward`: triangles face the centre.
pub fn sphere_obj(radius: f32, levels: u32, inward: bool) -> String {
    let mut tris: Vec<[[f32; 3]; 3]> = Vec::new();
    let p = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
    for (a, b, c) in [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)] {
        tris.push([p[a], p[b], p[c]]);
    }
    let norm = |v: [f32; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / l, v[1] / l, v[2] / l]
    };
    let mid = |a: [f32; 3], b: [f32; 3]| norm([(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0, (a[2] + b[2]) / 2.0]);
    for _ in 0..levels {
        tris = tris
            .iter()
            .flat_map(|[a, b, c]| {
                let (ab, bc, ca) = (mid(*a, *b), mid(*b, *c), mid(*c, *a));
                [[*a, ab, ca], [ab, *b, bc], [ca, bc, *c], [ab, bc, ca]]
            })
            .collect();
    }
    let mut s = String::new();
    for t in &tris {
        for v in t {
            writeln!(s, "v {} {} {}", v[0] * radius, v[1] * radius, v[2] * radius).unwrap();
        }
    }
    for i in 0..tris.len() {
        let b = 3 * i + 1;
        if inward {
            writeln!(s, "f {} {} {}", b, b + 2, b + 1).unwrap();
        } else {
            writeln!(s, "f {} {} {}", b, b + 1, b + 2).unwrap();
        }
    }
    s
}

/// Writes `scene.toml` and `sphere.obj` into a temp dir and returns the scene path.
#[track_caller]
pub fn write_scene(name: &str, toml: &str, obj: &str) -> PathBuf {
    let dir = temp_dir(name);
    std::fs::write(dir.join("sphere.obj"), obj).unwrap();
    let path = dir.join("scene.toml");
    std::fs::write(&path, toml).unwrap();
    path
}

/// An 8 × 8 plane at y = 0 facing +y, with texture coordinates.
pub const PLANE_OBJ: &str = "v -4 0 -4\nv 4 0 -4\nv 4 0 4\nv -4 0 4\nvt 0 1\nvt 1 1\nvt 1 0\nvt 0 0\nf 1/1 4/4 3/3 2/2\n";

/// A diffuse plane seen from above, lit only by delta lights: a point light, a spot light
/// of each falloff and a directional light; depth 2 (direct light only), so the image has
/// a closed form ([`delta_lit_radiance`]). `optimise` is the `[optimise]` body.
pub fn delta_lit_toml(film: (u32, u32), optimise: &str) -> String {
    format!(
        r#"[film]
width = {}
height = {}
[integrator]
max_depth = 2
[[sensors]]
origin = [0.3, 3, 0.2]
target = [0, 0, 0]
up = [0, 0, -1]
fov_y = 60
[[materials]]
name = "floor"
type = "diffuse"
base_color = [0.5, 0.6, 0.7]
[[meshes]]
file = "plane.obj"
material = "floor"
[[lights]]
name = "bulb"
type = "point"
position = [0.4, 1.0, 0.3]
color = [1.0, 0.8, 0.6]
intensity = 2.0
[[lights]]
name = "spot"
type = "spot"
position = [-0.8, 1.5, -0.5]
direction = [0.2, -1, 0.1]
color = [0.3, 0.6, 1.0]
intensity = 4.0
inner_angle = 15
outer_angle = 35
[[lights]]
name = "stage"
type = "spot"
position = [0.9, 1.2, -0.6]
direction = [0, -1, 0.3]
color = [1.0, 0.5, 0.5]
intensity = 3.0
inner_angle = 10
outer_angle = 30
falloff = "linear"
[[lights]]
name = "sun"
type = "directional"
direction = [0.3, -1, 0.5]
color = [0.2, 0.2, 0.1]
intensity = 1.0
[optimise]
{optimise}
"#,
        film.0, film.1
    )
}

/// Writes [`delta_lit_toml`] and its plane into a temp dir and returns the scene path.
#[track_caller]
pub fn write_delta_lit(name: &str, film: (u32, u32), optimise: &str) -> PathBuf {
    let dir = temp_dir(name);
    std::fs::write(dir.join("plane.obj"), PLANE_OBJ).unwrap();
    let path = dir.join("scene.toml");
    std::fs::write(&path, delta_lit_toml(film, optimise)).unwrap();
    path
}

/// Radiance leaving the point `x` of the plane of [`delta_lit_toml`] towards the camera
/// (albedo / π × the irradiance of every light), in f64, from the scene's own values.
pub fn delta_lit_radiance(scene: &vkinverse::scene::Scene, x: [f64; 3]) -> [f64; 3] {
    use vkinverse::scene::{ColorValue, LightKind, SpotFalloff};
    let ColorValue::Constant(albedo) = scene.materials[0].base_color else { panic!("constant albedo") };
    let mut l = [0.0f64; 3];
    for light in &scene.lights {
        let p = light.position.to_array().map(f64::from);
        let axis = light.direction.to_array().map(f64::from);
        let (wi, g) = match light.kind {
            LightKind::Directional => (axis.map(|c| -c), 1.0),
            kind => {
                let d = [p[0] - x[0], p[1] - x[1], p[2] - x[2]];
                let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                let r = r2.sqrt();
                let wi = d.map(|c| c / r);
                let mut g = 1.0 / r2;
                if let LightKind::Spot { inner, outer, falloff } = kind {
                    let cos = -(wi[0] * axis[0] + wi[1] * axis[1] + wi[2] * axis[2]);
                    let (ci, co) = ((inner as f64).cos(), (outer as f64).cos());
                    g *= match falloff {
                        SpotFalloff::Smooth => ((cos - co) / (ci - co).max(0.001)).clamp(0.0, 1.0).powi(2),
                        SpotFalloff::Linear if cos <= co => 0.0,
                        SpotFalloff::Linear if cos >= ci => 1.0,
                        SpotFalloff::Linear => (outer as f64 - cos.acos()) / (outer as f64 - inner as f64),
                    };
                }
                (wi, g)
            }
        };
        let cos = wi[1].max(0.0);
        for c in 0..3 {
            l[c] += albedo[c] as f64 / std::f64::consts::PI * cos * g * light.color[c] as f64 * light.intensity as f64;
        }
    }
    l
}

/// A 2 × 2 quad in the y = 0 plane facing +y, with texture coordinates (v up, +z at v = 0).
pub const QUAD_OBJ: &str = "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvt 0 1\nvt 1 1\nvt 1 0\nvt 0 0\nf 1/1 4/4 3/3 2/2\n";
/// A 0.6 × 0.6 area light at y = 1.2 facing down, behind the quad's centre, with texture
/// coordinates (u along +x, v along +z).
pub const QUAD_LIGHT_OBJ: &str = "v -0.3 1.2 -0.8\nv 0.3 1.2 -0.8\nv 0.3 1.2 -0.2\nv -0.3 1.2 -0.2\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n";

/// Writes into a fresh temp dir `name` a scene of [`QUAD_OBJ`] seen at 40° from
/// (0, 1.2, 1.8) and lit by [`QUAD_LIGHT_OBJ`] (emission 6) and the environment `environment`
/// (the body of its table): `film`² pixels, depth 3, Russian roulette from 5. `floor` is the
/// body of the quad's material table after its name, `optimise` that of `[optimise]`;
/// `normals.exr`, a 4 × 4 normal map of tilts up to 30° in every direction, lies beside it
/// for the floor to name. Returns the scene file's path.
#[track_caller]
pub fn lit_quad(name: &str, film: u32, floor: &str, environment: &str, optimise: &str) -> PathBuf {
    let dir = temp_dir(name);
    let mut normals = vkinverse::image::Image::filled(4, 4, [0.5, 0.5, 1.0]);
    for (i, px) in normals.data.iter_mut().enumerate() {
        let a = i as f32 * 2.4;
        let t = 0.55 * ((i % 5) as f32 / 4.0);
        let n = glam::Vec3::new(t * a.cos(), t * a.sin(), 1.0).normalize();
        *px = [(n.x + 1.0) / 2.0, (n.y + 1.0) / 2.0, (n.z + 1.0) / 2.0];
    }
    vkinverse::image::write_exr(&dir.join("normals.exr"), &normals).unwrap();
    std::fs::write(dir.join("quad.obj"), QUAD_OBJ).unwrap();
    std::fs::write(dir.join("light.obj"), QUAD_LIGHT_OBJ).unwrap();
    let toml = format!(
        r#"
[film]
width = {film}
height = {film}
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
{floor}
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
{environment}
[optimise]
{optimise}
"#
    );
    let path = dir.join("scene.toml");
    std::fs::write(&path, toml).unwrap();
    path
}

/// [`lit_quad`] with a diffuse floor (0.7, 0.4, 0.2) under a 16 × 8 lat-long map with one
/// bright texel (over the quad, about 34° from the zenith) on a dim sky, light-sampled beside
/// the area light. Returns the scene file's path.
#[track_caller]
pub fn sky_lit_quad(name: &str, film: u32, optimise: &str) -> PathBuf {
    let path = lit_quad(name, film, "type = \"diffuse\"\nbase_color = [0.7, 0.4, 0.2]", "file = \"sky.exr\"", optimise);
    let mut sky = vkinverse::image::Image::filled(16, 8, [0.05, 0.06, 0.08]);
    sky.data[2 * 16 + 8] = [60.0, 50.0, 30.0];
    vkinverse::image::write_exr(&path.with_file_name("sky.exr"), &sky).unwrap();
    path
}

/// An 8 × 8 view of a white sphere under a white sky, its colour the one parameter: the
/// target cache's tests (`TARGET_SCENE` with `sphere.obj` from [`sphere_obj`]).
pub const TARGET_SCENE: &str = r#"[film]
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

/// Renders (or loads from the cache) the targets of `scene` with BVH layout `layout`; true
/// if anything was rendered.
pub fn renders_targets(ctx: &std::sync::Arc<vkinverse::gpu::Context>, scene: &vkinverse::scene::Scene, layout: vkinverse::bvh::BvhLayout) -> bool {
    renders_targets_cached(ctx, scene, layout, None)
}

/// [`renders_targets`] with `cache_dir` as the cache when the scene's own directory cannot
/// take it.
pub fn renders_targets_cached(
    ctx: &std::sync::Arc<vkinverse::gpu::Context>,
    scene: &vkinverse::scene::Scene,
    layout: vkinverse::bvh::BvhLayout,
    cache_dir: Option<&std::path::Path>,
) -> bool {
    use vkinverse::render::{GpuScene, PrimalRenderer};
    let renderer = PrimalRenderer::new(GpuScene::with_bvh_layout(ctx, scene, layout).unwrap()).unwrap();
    let mut any = false;
    struct Rendered<'a>(&'a mut bool);
    impl vkinverse::Observer for Rendered<'_> {
        fn target_progress(&mut self, _: usize, _: u32, _: u32) {
            *self.0 = true;
        }
    }
    let source = vkinverse::render::targets::TargetSource { spp: 4, cache_dir, cancel: &vkinverse::Cancel::new() };
    vkinverse::render::targets::targets(&renderer, scene, source, &mut Rendered(&mut any)).unwrap();
    any
}

/// Which texture coordinates the textures of [`two_uv_sets`] are looked up at.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UvCase {
    /// The OBJ files' own (`vt`) map them; the meshes have no second set.
    First,
    /// The OBJ files' `vt` are a decoy (turned and squeezed); the mapping is each mesh's
    /// `uv1`, which every texture reads (`uv_set = 1`).
    Second,
    /// As `Second`, but the textures read the decoy (set 0).
    Decoy,
}

/// A 2 × 2 floor at y = 0 facing up, with a 4 × 4 colour texture and a 2 × 2 normal map
/// tilted 35° along u, lit by a 1 × 0.5 lamp at y = 1 facing down whose emission is a
/// 16 × 1 texture (red on the left, blue on the right), seen from above: 32² pixels,
/// depth 3. `case` says where the textures are read ([`UvCase`]); `optimise` is appended
/// to the file (after an `[optimise]` table). Every triangle's corners are written
/// explicitly, so that the per-corner `uv1` arrays follow the OBJ's faces.
#[track_caller]
pub fn two_uv_sets(name: &str, case: UvCase, optimise: &str) -> vkinverse::scene::Scene {
    use vkinverse::image::{write_exr, Image};
    let dir = temp_dir(name);
    let decoy = |[u, v]: [f32; 2]| [0.2 + 0.5 * v, 0.9 - 0.6 * u];
    let set = if case == UvCase::Second { ", uv_set = 1" } else { "" };
    let mut meshes = String::new();
    for (mesh, positions, uvs) in [
        ("floor", [[-1.0, 0.0, -1.0], [-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, -1.0]], [[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]]),
        ("lamp", [[-0.5, 1.0, -0.25], [0.5, 1.0, -0.25], [0.5, 1.0, 0.25], [-0.5, 1.0, 0.25]], [[0.125, 0.5], [0.875, 0.5], [0.875, 0.5], [0.125, 0.5]]),
    ] {
        let mut obj = String::new();
        for p in positions {
            let _ = writeln!(obj, "v {} {} {}", p[0], p[1], p[2]);
        }
        for uv in uvs {
            let [u, v] = if case == UvCase::First { uv } else { decoy(uv) };
            let _ = writeln!(obj, "vt {u} {v}");
        }
        obj.push_str("f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n");
        std::fs::write(dir.join(format!("{mesh}.obj")), obj).unwrap();
        let uv1 = if case == UvCase::First {
            String::new()
        } else {
            let corners: Vec<f32> = [0, 1, 2, 0, 2, 3].iter().flat_map(|&i: &usize| uvs[i]).collect();
            let array = vkinverse::npy::Array { shape: vec![2, 3, 2], data: corners };
            vkinverse::npy::write(&dir.join(format!("{mesh}.uv1.npy")), &array).unwrap();
            format!("uv1 = \"{mesh}.uv1.npy\"\n")
        };
        let (material, emission) = if mesh == "floor" { ("floor", "[0, 0, 0]".to_string()) } else { ("black", format!("{{ texture = \"lamp.exr\"{set} }}")) };
        let _ = write!(meshes, "[[meshes]]\nfile = \"{mesh}.obj\"\nmaterial = \"{material}\"\nemission = {emission}\n{uv1}");
    }
    let floor = Image { width: 4, height: 4, data: (0..16).map(|k| [0.2 + 0.05 * k as f32, 0.9 - 0.04 * k as f32, 0.3 + 0.1 * (k % 4) as f32]).collect() };
    write_exr(&dir.join("floor.exr"), &floor).unwrap();
    let a = 35f32.to_radians();
    write_exr(&dir.join("normals.exr"), &Image::filled(2, 2, [(a.sin() + 1.0) / 2.0, 0.5, (a.cos() + 1.0) / 2.0])).unwrap();
    let lamp = Image { width: 16, height: 1, data: [[[4.0, 0.5, 0.5]; 8], [[0.5, 0.5, 4.0]; 8]].concat() };
    write_exr(&dir.join("lamp.exr"), &lamp).unwrap();
    let toml = format!(
        "[film]\nwidth = 32\nheight = 32\n[integrator]\nmax_depth = 3\n[[sensors]]\norigin = [0, 2.2, 2.2]\ntarget = [0, 0, 0]\nfov_y = 50\n\
         [[materials]]\nname = \"floor\"\ntype = \"diffuse\"\nbase_color = {{ texture = \"floor.exr\"{set} }}\nnormal_map = {{ texture = \"normals.exr\"{set} }}\n\
         [[materials]]\nname = \"black\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n{meshes}[optimise]\n{optimise}"
    );
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    vkinverse::scene::Scene::load(dir.join("scene.toml")).unwrap()
}
