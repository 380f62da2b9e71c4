//! The forward path tracer on analytic scenes.

use crate::common;

use common::scenes::{sphere_obj, write_scene};
use common::with_gpu;
use vkinverse::render::{GpuScene, PrimalRenderer};
use vkinverse::scene::{ColorValue, Scene};

const ENV: [f32; 3] = [0.8, 0.6, 0.4];
const RHO: f32 = 0.5;

/// A closed object (`obj`, in the scene's `sphere.obj`) of material `material` (the body of
/// its table after its name) in the constant environment ENV, seen from (0, 0, 4) on a
/// 24 × 20 film with a field of view of `fov_y`.
fn object_in_environment(name: &str, material: &str, obj: &str, fov_y: f32, max_depth: u32, rr_depth: u32) -> Scene {
    let toml = format!(
        r#"
[film]
width = 24
height = 20
[integrator]
max_depth = {max_depth}
rr_depth = {rr_depth}
[[sensors]]
origin = [0, 0, 4]
target = [0, 0, 0]
up = [0, 1, 0]
fov_y = {fov_y}
[[materials]]
name = "object"
{material}
[[meshes]]
file = "sphere.obj"
material = "object"
[environment]
constant = [{}, {}, {}]
"#,
        ENV[0], ENV[1], ENV[2]
    );
    Scene::load(write_scene(name, &toml, obj)).unwrap()
}

fn convex_scene(max_depth: u32) -> Scene {
    let grey = format!("type = \"diffuse\"\nbase_color = [{RHO}, {RHO}, {RHO}]");
    object_in_environment(&format!("convex{max_depth}"), &grey, &sphere_obj(1.0, 3, false), 40.0, max_depth, 10)
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
            let r = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
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
            let r = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
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
                assert!((mean - expected).abs() <= 5.0 * se + 1e-4 * expected, "depth {max_depth} channel {c}: mean {mean} expected {expected} (se {se})");
            }
        }
    });
}

#[test]
fn same_seed_same_image() {
    with_gpu(|ctx| {
        let scene = Scene::load("scenes/cornell/scene.toml").unwrap();
        let r = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
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

#[test]
fn bvh_layouts_render_the_same() {
    // Every layout traces the same paths as the binary one: the images agree up to rays
    // that tie or graze an edge, where the traversal order may pick another of two
    // equally good hits (the triangle test's arithmetic is the same in every layout).
    for name in ["cornell", "spiral"] {
        let scene = Scene::load(format!("scenes/{name}/scene.toml")).unwrap();
        let images = with_gpu(|ctx| {
            vkinverse::bvh::BvhLayout::ALL.map(|layout| {
                let r = PrimalRenderer::new(GpuScene::with_bvh_layout(ctx, &scene, layout).unwrap()).unwrap();
                r.render(0, 2, 7, |_, _| {}).unwrap()
            })
        });
        for (layout, other) in vkinverse::bvh::BvhLayout::ALL.iter().zip(&images).skip(1) {
            let (mut diff, mut total) = (0.0f64, 0.0f64);
            for (a, b) in images[0].data.iter().zip(&other.data) {
                for c in 0..3 {
                    diff += (a[c] as f64 - b[c] as f64).abs();
                    total += a[c] as f64;
                }
            }
            assert!(total > 0.0, "{name}: a lit image");
            assert!(diff <= 1e-4 * total, "{name} {layout:?}: the image differs from the binary layout's by {:.2e} (relative L1)", diff / total);
        }
    }
}

// ---------------------------------------------------------------------------------------
// Environment-map light sampling
// ---------------------------------------------------------------------------------------

use std::f64::consts::PI;
use vkinverse::image::{write_exr, Image};
use vkinverse::render::envmap::{environment_uv, EnvDistribution};

/// A 2 × 2 quad in the y = 0 plane facing +y.
const QUAD_OBJ: &str = "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvt 0 1\nvt 1 1\nvt 1 0\nvt 0 0\nf 1/1 4/4 3/3 2/2\n";

/// A 32 × 16 lat-long map: a dim sky of 0.02 and one bright texel (row 4, column 10:
/// about 50° from the zenith) of (400, 320, 240).
fn spot_map() -> Image {
    let mut img = Image::filled(32, 16, [0.02, 0.02, 0.02]);
    img.data[4 * 32 + 10] = [400.0, 320.0, 240.0];
    img
}

/// The environment's bilinear lookup (glsl/lib/scene_access.glsl `footprint`, repeat
/// wrapping) at texture coordinates uv.
fn bilinear(img: &Image, uv: [f64; 2]) -> [f64; 3] {
    let (w, h) = (img.width as i64, img.height as i64);
    let p = [uv[0] * w as f64 - 0.5, (1.0 - uv[1]) * h as f64 - 0.5];
    let f = [p[0].floor(), p[1].floor()];
    let t = [p[0] - f[0], p[1] - f[1]];
    let a = [(f[0] as i64).rem_euclid(w), (f[1] as i64).rem_euclid(h)];
    let b = [(a[0] + 1) % w, (a[1] + 1) % h];
    let mut v = [0.0; 3];
    for (x, y, wt) in
        [(a[0], a[1], (1.0 - t[0]) * (1.0 - t[1])), (b[0], a[1], t[0] * (1.0 - t[1])), (a[0], b[1], (1.0 - t[0]) * t[1]), (b[0], b[1], t[0] * t[1])]
    {
        let px = img.get(x as u32, y as u32);
        for c in 0..3 {
            v[c] += wt * px[c] as f64;
        }
    }
    v
}

/// Radiance leaving a Lambertian plane of albedo ρ facing +y under `map`, unoccluded:
/// ρ/π ∫ L(ω) cos θ dω over the upper hemisphere, by the midpoint rule on a 4096 × 2048
/// grid of (u, θ) (dω = sin θ dθ dφ). The integrand is piecewise bilinear in (u, θ/π)
/// times a smooth factor, so the rule is accurate to ~1e-6.
fn plane_radiance(map: &Image, rho: f64) -> [f64; 3] {
    let (nu, nt) = (4096usize, 2048usize);
    let (du, dt) = (1.0 / nu as f64, 0.5 / nt as f64);
    let mut sum = [0.0; 3];
    for j in 0..nt {
        let theta = PI * (j as f64 + 0.5) * dt;
        let jac = theta.cos() * theta.sin() * 2.0 * PI * PI * du * dt;
        for i in 0..nu {
            let l = bilinear(map, [(i as f64 + 0.5) * du, 1.0 - theta / PI]);
            for c in 0..3 {
                sum[c] += l[c] * jac;
            }
        }
    }
    sum.map(|s| s * rho / PI)
}

/// A diffuse quad (ρ = 0.5) seen from straight above so that every pixel sees it, lit by
/// the lat-long map `map` only (max depth 2: direct light; the quad cannot see itself).
/// Every pixel estimates the same radiance.
fn env_lit_quad(name: &str, map: &Image) -> Scene {
    Scene::load(quad_under_map(name, map, QUAD_OBJ, "")).unwrap()
}

/// Writes the scene of [`env_lit_quad`] into a fresh temp dir `name`, its quad from OBJ text
/// `obj` and `material` added to the quad's material table, and returns its path.
fn quad_under_map(name: &str, map: &Image, obj: &str, material: &str) -> std::path::PathBuf {
    let dir = common::scenes::temp_dir(name);
    std::fs::write(dir.join("quad.obj"), obj).unwrap();
    write_exr(&dir.join("sky.exr"), map).unwrap();
    let toml = format!(
        r#"
[film]
width = 32
height = 32
[integrator]
max_depth = 2
rr_depth = 5
[[sensors]]
origin = [0, 3, 0]
target = [0, 0, 0]
up = [0, 0, -1]
fov_y = 30
[[materials]]
name = "grey"
type = "diffuse"
base_color = [{RHO}, {RHO}, {RHO}]
{material}
[[meshes]]
file = "quad.obj"
material = "grey"
[environment]
file = "sky.exr"
"#
    );
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    dir.join("scene.toml")
}

/// How the quad of [`normal_quad`] is shaded: a constant normal map (the tangent-space
/// normal it encodes) or vertex normals (world space), or neither.
#[derive(Clone, Copy)]
enum Shading {
    Geometric,
    Map([f32; 3]),
    Vertex([f32; 3]),
}

/// The diffuse quad of [`env_lit_quad`] under [`spot_map`], shaded as `shading` says;
/// `mirrored`: its texture coordinates' u runs along −x instead of +x.
fn normal_quad(name: &str, shading: Shading, mirrored: bool) -> Scene {
    let u = |x: f32| if mirrored { 1.0 - x } else { x };
    let mut obj = format!("v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvt {} 1\nvt {} 1\nvt {} 0\nvt {} 0\n", u(0.0), u(1.0), u(1.0), u(0.0));
    let (mut map, mut normals) = ("", None);
    match shading {
        Shading::Geometric => obj.push_str("f 1/1 4/4 3/3 2/2\n"),
        Shading::Vertex(n) => obj.push_str(&format!("vn {} {} {}\nf 1/1/1 4/4/1 3/3/1 2/2/1\n", n[0], n[1], n[2])),
        Shading::Map(n) => {
            obj.push_str("f 1/1 4/4 3/3 2/2\n");
            // Encoded as (n + 1) / 2, in a 2 × 2 image so that the lookup is bilinear.
            normals = Some(Image::filled(2, 2, n.map(|v| (v + 1.0) / 2.0)));
            map = "normal_map = { texture = \"normals.exr\" }";
        }
    }
    let path = quad_under_map(name, &spot_map(), &obj, map);
    if let Some(img) = normals {
        write_exr(&path.with_file_name("normals.exr"), &img).unwrap();
    }
    Scene::load(path).unwrap()
}

/// A constant normal map shades as the vertex normals it encodes, turned into the frame
/// of the texture coordinates: x along dp/du, y along dp/dv (the bitangent
/// cross(n, tangent), turned where u is mirrored) and z along the surface normal. The quad
/// faces +y with u along +x and v along −z, so the tangent-space (sin a, 0, cos a) is the
/// world's (sin a, cos a, 0) and (0, sin a, cos a) is (0, cos a, −sin a); mirroring u turns
/// the first to (−sin a, cos a, 0) and leaves the second. With the same random numbers the
/// images agree but for float rounding in the normal (a sample whose direction the
/// rounding carries across the map's bright texel's edge could change one pixel), while the
/// spot of light to one side makes each tilt change the image by a tenth or more. The map
/// of the untilted normal (0, 0, 1) renders as the geometric normal.
#[test]
fn a_constant_normal_map_shades_as_the_vertex_normals_it_encodes() {
    let a = 35f32.to_radians();
    let (s, c) = (a.sin(), a.cos());
    let cases = [
        ("flat", [0.0, 0.0, 1.0], [0.0, 1.0, 0.0], false),
        ("tilt-u", [s, 0.0, c], [s, c, 0.0], false),
        ("tilt-v", [0.0, s, c], [0.0, c, -s], false),
        ("mirrored-tilt-u", [s, 0.0, c], [-s, c, 0.0], true),
        ("mirrored-tilt-v", [0.0, s, c], [0.0, c, -s], true),
    ];
    let render = |ctx: &std::sync::Arc<vkinverse::gpu::Context>, scene: &Scene| {
        let gs = GpuScene::new(ctx, scene).unwrap();
        let mapped = gs.has("HAS_NORMAL_MAPS");
        (PrimalRenderer::new(gs).unwrap().render(0, 16, 5, |_, _| {}).unwrap(), mapped)
    };
    let mean = |img: &Image| img.data.iter().map(|p| p[0] as f64).sum::<f64>() / img.data.len() as f64;
    with_gpu(|ctx| {
        let (flat, _) = render(ctx, &normal_quad("nmap-geometric", Shading::Geometric, false));
        for (name, map, world, mirrored) in cases {
            let (mapped, has_maps) = render(ctx, &normal_quad(&format!("nmap-{name}"), Shading::Map(map), mirrored));
            assert!(has_maps, "{name}: the kernels are built with normal maps");
            let (vertex, _) = render(ctx, &normal_quad(&format!("nmap-{name}-vn"), Shading::Vertex(world), mirrored));
            let off = mapped.data.iter().zip(&vertex.data).filter(|(p, q)| (0..3).any(|k| (p[k] - q[k]).abs() > 1e-4 * q[k].abs().max(1e-3))).count();
            eprintln!("{name}: mean {:.5} (vertex normals {:.5}, geometric {:.5}); {off} pixels differ", mean(&mapped), mean(&vertex), mean(&flat));
            assert!(off <= 2, "{name}: {off} pixels differ from the vertex normals' image");
            let change = (mean(&vertex) / mean(&flat) - 1.0).abs();
            if name == "flat" {
                assert!(change < 1e-5, "the untilted map changes the image by {change}");
            } else {
                assert!(change > 0.1, "{name}: the tilt changes the image by only {change}");
            }
        }
    });
}

/// The diffuse quad of [`normal_quad`] (facing +y, x from −1 to 1 and z from −1 to 1),
/// its texture coordinates spanning [0.25, 0.75] (u along +x, or −x where `mirrored`; v
/// along −z) so that a 2 × 2 texture is bilinear across it, with vertex normal `normal`
/// (if any) and the material line `material`; `heights` (if any) written as height.exr.
fn bump_quad(name: &str, normal: Option<[f64; 3]>, mirrored: bool, heights: Option<&Image>, material: &str) -> Scene {
    let u = |x: f32| if mirrored { 1.0 - x } else { x };
    let mut obj = format!("v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvt {} 0.75\nvt {} 0.75\nvt {} 0.25\nvt {} 0.25\n", u(0.25), u(0.75), u(0.75), u(0.25));
    match normal {
        None => obj.push_str("f 1/1 4/4 3/3 2/2\n"),
        Some(n) => obj.push_str(&format!("vn {} {} {}\nf 1/1/1 4/4/1 3/3/1 2/2/1\n", n[0], n[1], n[2])),
    }
    let path = quad_under_map(name, &spot_map(), &obj, material);
    if let Some(img) = heights {
        write_exr(&path.with_file_name("height.exr"), img).unwrap();
    }
    Scene::load(path).unwrap()
}

/// A bump map bends the shading normal as Mitsuba's `bumpmap` does: n' is the normalised
/// cross product of dp/du and dp/dv, each less its part along the unshaded normal n and
/// plus n times the height's derivative in u or v. On the quad of [`bump_quad`]
/// (dp/du = (±4, 0, 0), dp/dv = (0, 0, −4)) a 2 × 2 height texture is a plane, so n' is
/// one vector, computed here in f64 from that definition; the bump-mapped quad renders as
/// the quad whose vertex normals are n' (all pixels within 1e-4 but for two, as for the
/// normal maps), with and without vertex normals of its own (whose tilt the definition
/// mixes with the slope's), for a slope in u, in v, both, mirrored u, and the luminance of
/// a red ramp. Each tilt changes the image by more than a tenth. A nearest-filtered
/// ramp (no slope between texel edges, as Mitsuba's) and a constant height (only slopes
/// count) render as the quad without a map.
#[test]
fn a_bump_map_shades_as_the_normal_of_its_slope() {
    use glam::DVec3;
    let scale = 1.4; // a slope of 2.8 across dp/du = 4: a tilt of 35 degrees
    let ramp = |h: [f32; 4], k: [f32; 3]| Image { width: 2, height: 2, data: h.iter().map(|&v| k.map(|c| v * c)).collect() };
    let grey = [1.0f32; 3];
    let tilted = DVec3::new(0.3, 0.9, 0.3).normalize();
    // (name, the height texels (top row first: v = 0.75), their colour, the vertex
    // normal, mirrored u, the map's extra keys, whether the surface stays flat)
    let cases: [(&str, [f32; 4], [f32; 3], Option<DVec3>, bool, &str, bool); 8] = [
        ("u", [0.0, 1.0, 0.0, 1.0], grey, None, false, "", false),
        ("v", [1.0, 1.0, 0.0, 0.0], grey, None, false, "", false),
        ("uv-smooth", [1.0, 2.0, 0.0, 1.0], grey, Some(tilted), false, "", false),
        ("u-smooth", [0.0, 1.0, 0.0, 1.0], grey, Some(DVec3::new(20f64.to_radians().sin(), 20f64.to_radians().cos(), 0.0)), false, "", false),
        ("u-mirrored", [0.0, 1.0, 0.0, 1.0], grey, None, true, "", false),
        ("u-red", [0.0, 1.0, 0.0, 1.0], [1.0 / 0.212671, 0.0, 0.0], None, false, "", false),
        ("nearest", [0.0, 1.0, 0.0, 1.0], grey, None, false, ", filter = \"nearest\"", true),
        ("offset", [5.0; 4], grey, None, false, "", true),
    ];
    let render = |ctx: &std::sync::Arc<vkinverse::gpu::Context>, scene: &Scene| {
        let gs = GpuScene::new(ctx, scene).unwrap();
        let mapped = gs.has("HAS_NORMAL_MAPS");
        (PrimalRenderer::new(gs).unwrap().render(0, 16, 5, |_, _| {}).unwrap(), mapped)
    };
    let mean = |img: &Image| img.data.iter().map(|p| p[0] as f64).sum::<f64>() / img.data.len() as f64;
    let differing =
        |a: &Image, b: &Image| a.data.iter().zip(&b.data).filter(|(p, q)| (0..3).any(|k| (p[k] - q[k]).abs() > 1e-4 * q[k].abs().max(1e-3))).count();
    with_gpu(|ctx| {
        for (name, h, colour, normal, mirrored, extra, flat) in cases {
            let material = format!("bump_map = {{ texture = \"height.exr\", scale = {scale}{extra} }}");
            let (bumped, has_maps) =
                render(ctx, &bump_quad(&format!("bump-{name}"), normal.map(|n| n.to_array()), mirrored, Some(&ramp(h, colour)), &material));
            assert!(has_maps, "{name}: the kernels are built with normal maps");
            // The height's derivatives (the luminance of the texels, times scale): across
            // half a unit of u or v between texel centres.
            let lum = |i: usize| (0.212671 * colour[0] + 0.715160 * colour[1] + 0.072169 * colour[2]) as f64 * h[i] as f64 * scale;
            let (hu, hv) = ((lum(1) - lum(0)) / 0.5, (lum(0) - lum(2)) / 0.5);
            let n = normal.unwrap_or(DVec3::Y);
            let (dp_du, dp_dv) = (DVec3::new(if mirrored { -4.0 } else { 4.0 }, 0.0, 0.0), DVec3::new(0.0, 0.0, -4.0));
            let along = |d: DVec3, slope: f64| d - n * n.dot(d) + n * slope;
            let c = along(dp_du, hu).cross(along(dp_dv, hv)).normalize();
            let expected = if flat {
                n
            } else if c.y < 0.0 {
                -c
            } else {
                c
            };
            let (reference, _) = render(ctx, &bump_quad(&format!("bump-{name}-vn"), Some(expected.to_array()), false, None, ""));
            let off = differing(&bumped, &reference);
            eprintln!("{name}: normal {expected:.4}, mean {:.5} (vertex normals {:.5}); {off} pixels differ", mean(&bumped), mean(&reference));
            assert!(off <= 2, "{name}: {off} pixels differ from the image of the normal {expected}");
            if !flat {
                let (unbumped, _) = render(ctx, &bump_quad(&format!("bump-{name}-plain"), normal.map(|n| n.to_array()), mirrored, None, ""));
                let change = (mean(&bumped) / mean(&unbumped) - 1.0).abs();
                assert!(change > 0.1, "{name}: the slope changes the image by only {change}");
            }
        }
    });
}

/// Per channel: the mean over pixels, its standard error and the variance over pixels
/// (pixels are independent estimates of one value).
fn pixel_stats(img: &Image) -> [(f64, f64, f64); 3] {
    std::array::from_fn(|c| {
        let v: Vec<f64> = img.data.iter().map(|p| p[c] as f64).collect();
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        (mean, (var / n).sqrt(), var)
    })
}

/// A small bright spot in a lat-long map lighting a diffuse quad: with the map light-
/// sampled (next-event estimation, MIS with cosine sampling) and with cosine sampling
/// alone, the image mean agrees with the CPU integral of the map within 5 standard errors
/// (+1e-4 relative for float32 accumulation), and light sampling divides the per-pixel
/// variance by a large factor: measured 65 in every channel at 16 spp (the variance of the
/// cosine-sampled image rests on ~150 spot hits, so its estimate is good to ~10 %); the
/// test asserts at least 16, a quarter of that. A 1 × 1 map (a constant sky through the
/// map machinery: uniform sampling of the sphere) must give ρ·L; its pixel variance
/// (measured 6.4e-4 in red, 0.4 % of ρ·L squared) is what light-sampling a constant
/// environment would cost here, where cosine sampling alone is exact (variance 0), which
/// is why a constant environment is left to BSDF sampling.
#[test]
fn environment_map_sampling_is_unbiased_and_reduces_variance() {
    with_gpu(|ctx| {
        let map = spot_map();
        let scene = env_lit_quad("env-spot", &map);
        let expected = plane_radiance(&map, RHO as f64);
        let mut gs = GpuScene::new(ctx, &scene).unwrap();
        assert!(gs.environment_sampling(), "a lat-long map is light-sampled");
        let spp = 16;
        let mut stats = Vec::new();
        for sampled in [true, false] {
            gs.set_environment_sampling(sampled).unwrap();
            let r = PrimalRenderer::new(gs).unwrap();
            let img = r.render(0, spp, 5, |_, _| {}).unwrap();
            gs = r.scene;
            let s = pixel_stats(&img);
            for c in 0..3 {
                let (mean, se, var) = s[c];
                eprintln!("light sampling {sampled}, channel {c}: mean {mean:.5} ± {se:.1e} (expected {:.5}), pixel variance {var:.3e}", expected[c]);
                assert!(
                    (mean - expected[c]).abs() <= 5.0 * se + 1e-4 * expected[c],
                    "light sampling {sampled}, channel {c}: mean {mean} expected {} (se {se})",
                    expected[c]
                );
            }
            stats.push(s);
        }
        for (c, (without, with)) in stats[1].iter().zip(&stats[0]).enumerate() {
            let ratio = without.2 / with.2;
            eprintln!("channel {c}: variance without / with light sampling = {ratio:.1}");
            assert!(ratio >= 16.0, "channel {c}: light sampling reduces the variance by only {ratio:.2}×");
        }

        let uniform = Image::filled(1, 1, [0.8, 0.6, 0.4]);
        let r = PrimalRenderer::new(GpuScene::new(ctx, &env_lit_quad("env-uniform", &uniform)).unwrap()).unwrap();
        let img = r.render(0, spp, 5, |_, _| {}).unwrap();
        let s = pixel_stats(&img);
        for (c, l) in [0.8f64, 0.6, 0.4].into_iter().enumerate() {
            let (mean, se, var) = s[c];
            let expected = RHO as f64 * l;
            eprintln!("1 × 1 map, channel {c}: mean {mean:.5} ± {se:.1e} (expected {expected:.5}), pixel variance {var:.3e}");
            assert!((mean - expected).abs() <= 5.0 * se + 1e-4 * expected, "1 × 1 map channel {c}: mean {mean} expected {expected}");
        }
    });
}

/// xorshift64*: uniform numbers in [0, 1) for the CPU distribution tests.
struct Xorshift(u64);
impl Xorshift {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545F4914F6CDD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The environment map's 2D distribution on the CPU (src/render/envmap.rs): cell
/// probabilities sum to 1, the densities integrate to 1 over the sphere (exactly per cell,
/// and by Monte Carlo over uniform directions), every cell is possible (the uniform
/// share), a sample lands in the cell the kernel would look its density up in with that
/// density, and sample frequencies match the probabilities. Each cell is split in 2 × 2
/// sub-cells of equal solid angle (halves in φ and in cos θ), each expected with
/// probability pmf/4 (the density is constant in a cell); Pearson's χ² over the
/// sub-cells must stay below its mean + 6 standard deviations (k + 6√(2k)).
#[test]
fn environment_distribution_matches_its_pdf() {
    let (w, h) = (16u32, 8u32);
    let mut texels = vec![0.05f32; (3 * w * h) as usize];
    for (i, v) in [(2 * 16 + 3, 50.0), (0, 8.0), (7 * 16 + 15, 20.0), (4 * 16 + 8, 3.0)] {
        texels[3 * i..3 * i + 3].copy_from_slice(&[v, 0.5 * v, 0.1 * v]);
    }
    let d = EnvDistribution::new(&texels, w, h);
    let total: f64 = d.pmf.iter().sum();
    assert!((total - 1.0).abs() < 1e-12, "Σ pmf = {total}");
    let integral: f64 = (0..h as usize)
        .flat_map(|r| (0..w as usize).map(move |c| (r, c)))
        .map(|(r, c)| d.density[r * w as usize + c] as f64 * EnvDistribution::cell_solid_angle(w, h, r as u32))
        .sum();
    assert!((integral - 1.0).abs() < 1e-5, "∫ pdf dω = {integral}");
    assert!(d.pmf.iter().all(|&p| p > 0.0), "every cell has a positive probability");
    let bright = d.pmf[2 * 16 + 3];
    assert!(bright > 0.3, "the brightest texel's cell is the likeliest: {bright}");

    let mut rng = Xorshift(0x9E3779B97F4A7C15);
    // ∫ pdf dω by uniform directions on the sphere: 4π E[pdf].
    let n = 400_000;
    let (mut s, mut s2) = (0.0, 0.0);
    for _ in 0..n {
        let z = 1.0 - 2.0 * rng.next();
        let phi = 2.0 * PI * rng.next();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let v = 4.0 * PI * d.pdf([r * phi.cos(), z, r * phi.sin()]);
        s += v;
        s2 += v * v;
    }
    let (mean, se) = (s / n as f64, ((s2 / n as f64 - (s / n as f64).powi(2)) / n as f64).sqrt());
    assert!((mean - 1.0).abs() <= 5.0 * se, "4π E[pdf] over uniform directions = {mean} ± {se}");

    let cells = (w * h) as usize;
    let mut counts = vec![0u64; 4 * cells];
    let samples = 1_000_000;
    for _ in 0..samples {
        let (dir, pdf) = d.sample([rng.next(), rng.next()]);
        let len = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-9, "unit direction: {dir:?}");
        let (r, c) = d.cell(dir);
        let k = r * w as usize + c;
        assert_eq!(pdf, d.density[k] as f64, "the sampled density is the looked-up one");
        // Sub-cell: which half of the cell's azimuth range and of its cos θ range.
        let [u, _] = environment_uv(dir);
        let half_u = ((u * w as f64 - c as f64) >= 0.5) as usize;
        let (ct0, ct1) = ((PI * r as f64 / h as f64).cos(), (PI * (r + 1) as f64 / h as f64).cos());
        let half_t = (dir[1] < 0.5 * (ct0 + ct1)) as usize;
        counts[4 * k + 2 * half_t + half_u] += 1;
    }
    let mut chi2 = 0.0;
    for k in 0..cells {
        for j in 0..4 {
            let e = d.pmf[k] / 4.0 * samples as f64;
            chi2 += (counts[4 * k + j] as f64 - e).powi(2) / e;
        }
    }
    let dof = (4 * cells - 1) as f64;
    eprintln!("χ² = {chi2:.1} over {dof} degrees of freedom");
    assert!(chi2 < dof + 6.0 * (2.0 * dof).sqrt(), "χ² = {chi2} over {dof} degrees of freedom");
}

/// Every record the kernels read from texel buffers, read through the GLSL accessors by
/// records_test and written back as storage-buffer structs, equals the buffer's bytes
/// read through the Rust mirror: materials, shading, meshes, emitters (and the cdf the
/// light-sampling search reads), BVH nodes of both layouts and triangles, material data,
/// θ and the environment map's distribution. Scenes: spiral (principled materials, vertex
/// normals, emitters, three optimised parameters), ajar (an optimised albedo texture), a
/// quad under a lat-long map (the distribution) and one with a normal map (its material
/// data and the tangents, mirrored).
#[test]
fn kernels_read_the_records_the_host_wrote() {
    use vkinverse::bvh::{BvhCwNode, BvhLayout, BvhNode, BvhTriangle, BvhWideNode};
    use vkinverse::gpu::{Buffer, CommandBuffer, ComputePipeline, MemoryKind};
    use vkinverse::shared::{EmitterTri, Globals, LightRecord, MaterialRecord, SensorRecord, TriShading, TriUv1, ValueRef};
    fn read<T: bytemuck::Pod>(b: &Buffer) -> Vec<T> {
        let bytes: Vec<u8> = b.read().unwrap();
        bytes.chunks_exact(std::mem::size_of::<T>()).map(bytemuck::pod_read_unaligned).collect()
    }
    fn out<T: bytemuck::Pod>(ctx: &std::sync::Arc<vkinverse::gpu::Context>, name: &str, n: usize) -> Buffer {
        Buffer::zeroed::<T>(ctx, name, n.max(1), MemoryKind::Device).unwrap()
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scenes = [
        ("spiral", Scene::load(root.join("scenes/spiral/scene.toml")).unwrap()),
        ("ajar", Scene::load(root.join("scenes/ajar/scene.toml")).unwrap()),
        ("env quad", env_lit_quad("records-env", &spot_map())),
        ("normal map", normal_quad("records-nmap", Shading::Map([0.3, -0.2, 0.93]), true)),
        ("emission texture", lamp_scene("records-emission", true, LAMP_RED, LAMP_BLUE)),
        ("alpha test", cutout_scene("records-alpha", Cutout::Masked, false, 0.5)),
        (
            "second uv set",
            common::scenes::two_uv_sets(
                "records-uv1",
                common::scenes::UvCase::Second,
                "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.5, 0.5, 0.5]\nrange = [0, 1]\ntexture = [4, 4]\n",
            ),
        ),
        (
            "lights",
            delta_lit_scene(
                "records-lights",
                "[[optimise.params]]\ntarget = \"lights.spot.color\"\ninit = [0.5, 0.5, 0.5]\nrange = [0, 1]\n\
                 [[optimise.params]]\ntarget = \"lights.bulb.intensity\"\ninit = 1.0\nrange = [0, 4]\n",
            ),
        ),
    ];
    with_gpu(|ctx| {
        for (name, scene) in &scenes {
            for layout in BvhLayout::ALL {
                let gs = GpuScene::with_bvh_layout(ctx, scene, layout).unwrap();
                let bound: Vec<(&str, &Buffer)> = gs.bindings();
                let buffer = |n: &str| bound.iter().find(|(b, _)| *b == n).unwrap_or_else(|| panic!("{n} not bound")).1;
                let materials: Vec<MaterialRecord> = read(buffer("Materials"));
                let shading: Vec<TriShading> = read(buffer("Shading"));
                let emitters: Vec<EmitterTri> = read(buffer("Emitters"));
                let triangles: Vec<BvhTriangle> = read(buffer("BvhTriangles"));
                let sensors: Vec<SensorRecord> = read(buffer("Sensors"));
                let globals: Vec<Globals> = read(buffer("SceneGlobals"));
                let lights: Vec<LightRecord> = read(buffer("Lights"));
                let lights = &lights[..globals[0].num_lights as usize];
                let uv1: Vec<TriUv1> = read(buffer("ShadingUv1"));
                let uv1 = if gs.has("HAS_UV1") { &uv1[..] } else { &[][..] };
                let floats = |n: &str| -> Vec<f32> { read(buffer(n)) };
                // θ's buffer: θ padded to CONST_BASE floats, then the material data.
                let theta_buffer = floats("Theta");
                let base = gs.const_base as usize;
                assert!(base >= gs.layout.len && base.is_multiple_of(4), "{name}: CONST_BASE {base} after θ, on a texel");
                // (The material data end on a whole texel: up to 3 floats of padding.)
                let (data, theta, env) = (theta_buffer[base..].to_vec(), theta_buffer[..base].to_vec(), floats("EnvDistribution"));
                let (n_nodes, node_bytes) = match layout {
                    BvhLayout::Binary => (read::<BvhNode>(buffer("BvhNodes")).len(), std::mem::size_of::<BvhNode>()),
                    BvhLayout::Wide => (read::<BvhWideNode>(buffer("BvhNodes")).len(), std::mem::size_of::<BvhWideNode>()),
                    BvhLayout::Cw8 => (read::<BvhCwNode>(buffer("BvhNodes")).len(), std::mem::size_of::<BvhCwNode>()),
                };
                assert_eq!(shading.len(), triangles.len(), "{name}: one shading record per triangle");
                if *name == "normal map" {
                    // The quad's u runs along −x: tangent −x, dp/dv (−z) against cross(ng, tangent) (+z).
                    assert!(
                        shading.iter().all(|s| s.tangent == [-1.0, 0.0, 0.0, -1.0]),
                        "{name}: tangents {:?}",
                        shading.iter().map(|s| s.tangent).collect::<Vec<_>>()
                    );
                    assert!(materials[0].normal_map.width == 2 && materials[0].normal_map.flags & ValueRef::IN_THETA == 0, "{name}: {:?}", materials[0]);
                }
                assert!(!emitters.is_empty() || matches!(*name, "env quad" | "lights" | "normal map"), "{name} has emitters");

                let pipeline = ComputePipeline::new(ctx, &gs.kernel("records_test"), &[gs.const_base_spec()]).unwrap();
                let o_materials = out::<MaterialRecord>(ctx, "out materials", materials.len());
                let o_shading = out::<TriShading>(ctx, "out shading", shading.len());
                let o_emitters = out::<EmitterTri>(ctx, "out emitters", emitters.len());
                let o_cdfs = out::<f32>(ctx, "out cdfs", emitters.len());
                let o_nodes = Buffer::zeroed::<u8>(ctx, "out nodes", n_nodes.max(1) * node_bytes, MemoryKind::Device).unwrap();
                let o_triangles = out::<BvhTriangle>(ctx, "out triangles", triangles.len());
                let o_floats = out::<f32>(ctx, "out floats", data.len() + theta.len() + env.len());
                let o_sensors = out::<SensorRecord>(ctx, "out sensors", sensors.len());
                let o_globals = out::<Globals>(ctx, "out globals", 1);
                let o_lights = out::<LightRecord>(ctx, "out lights", lights.len());
                let o_triples = out::<[f32; 3]>(ctx, "out triples", data.len() + theta.len());
                let o_uv1 = out::<TriUv1>(ctx, "out uv1", uv1.len());
                let mut b = bound.clone();
                b.extend([
                    ("OutMaterials", &o_materials),
                    ("OutShading", &o_shading),
                    ("OutEmitters", &o_emitters),
                    ("OutCdfs", &o_cdfs),
                    ("OutNodes", &o_nodes),
                    ("OutTriangles", &o_triangles),
                    ("OutFloats", &o_floats),
                    ("OutSensors", &o_sensors),
                    ("OutGlobals", &o_globals),
                    ("OutLights", &o_lights),
                    ("OutTriples", &o_triples),
                    ("OutUv1", &o_uv1),
                ]);
                // The frame counter is the scene's but not read here.
                b.retain(|(n, _)| pipeline.reflection().binding(n).is_some());
                let group = pipeline.bind(&b).unwrap();
                let counts =
                    [materials.len(), shading.len(), emitters.len(), n_nodes, data.len(), theta.len(), env.len(), sensors.len(), lights.len(), uv1.len()];
                let c = counts.map(|c| c as u32);
                let push = vkinverse::kernels::RecordsPush {
                    materials: c[0],
                    triangles: c[1],
                    emitters: c[2],
                    nodes: c[3],
                    material_data: c[4],
                    theta: c[5],
                    env_dist: c[6],
                    sensors: c[7],
                    lights: c[8],
                    uv1s: c[9],
                };
                let threads = *counts.iter().max().unwrap() as u64;
                let mut cmd = CommandBuffer::new(ctx, "records").unwrap();
                cmd.record(|rec| rec.dispatch_linear(&pipeline, &group, &push, threads)).unwrap();
                cmd.submit_and_wait().unwrap();

                let tag = format!("{name} {layout:?}");
                assert_eq!(read::<MaterialRecord>(&o_materials)[..materials.len()], materials[..], "{tag}: materials");
                assert_eq!(read::<TriShading>(&o_shading)[..shading.len()], shading[..], "{tag}: shading");
                assert_eq!(read::<EmitterTri>(&o_emitters)[..emitters.len()], emitters[..], "{tag}: emitters");
                assert_eq!(read::<SensorRecord>(&o_sensors)[..sensors.len()], sensors[..], "{tag}: sensors");
                assert_eq!(read::<Globals>(&o_globals), globals, "{tag}: globals");
                assert_eq!(read::<LightRecord>(&o_lights)[..lights.len()], lights[..], "{tag}: lights");
                assert_eq!(read::<TriUv1>(&o_uv1)[..uv1.len()], uv1[..], "{tag}: second uv sets");
                if *name == "second uv set" {
                    // The second set, per triangle, is the mesh's own (not its first set).
                    assert_eq!(uv1.len(), shading.len(), "{tag}: one second-set record per triangle");
                    assert!(uv1.iter().zip(&shading).any(|(a, s)| [a.uv0, a.uv1, a.uv2] != [s.uv0, s.uv1, s.uv2]), "{tag}: the second set differs");
                    assert!(materials.iter().any(|m| m.base_color.flags & ValueRef::UV1 != 0), "{tag}: a texture reads the second set");
                }
                // A triangle's shading record repeats its material's one_sided and its mesh's
                // emission (one per mesh, the scene's emission value); an emitter's record what
                // light sampling needs of its triangle's shading record.
                let mut mesh_emission = std::collections::HashMap::new();
                for (t, sh) in shading.iter().enumerate() {
                    assert_eq!(sh.one_sided, materials[sh.material as usize].one_sided, "{tag}: triangle {t}'s one_sided");
                    let first = *mesh_emission.entry(sh.mesh).or_insert(sh.emission);
                    assert_eq!(sh.emission, first, "{tag}: triangle {t}'s emission against its mesh's other triangles'");
                }
                for (m, e) in &mesh_emission {
                    // A constant emission reads the scene's value; an optimised one reads θ.
                    let o = e.offset as usize;
                    if e.flags & ValueRef::IN_THETA == 0 {
                        let (want, size): (Vec<f32>, _) = match &scene.meshes[*m as usize].emission {
                            ColorValue::Constant(c) => (c.to_vec(), [0, 0]),
                            ColorValue::Texture(t) => (t.image.data.as_flattened().to_vec(), [t.image.width, t.image.height]),
                        };
                        assert_eq!(([e.width, e.height], &data[o..o + want.len()]), (size, &want[..]), "{tag}: mesh {m}'s emission");
                    } else {
                        assert!(o + 3 <= gs.layout.len, "{tag}: mesh {m}'s emission at θ[{o}..] of {}", gs.layout.len);
                    }
                }
                for e in &emitters {
                    let sh = &shading[e.prim as usize];
                    assert_eq!(
                        (e.ng, e.two_sided, e.pdf, e.emission),
                        (sh.ng, sh.emitter_flags & TriShading::TWO_SIDED, sh.emitter_pdf, sh.emission),
                        "{tag}: emitter {}",
                        e.prim
                    );
                }
                let cdfs: Vec<f32> = emitters.iter().map(|e| e.cdf).collect();
                assert_eq!(read::<f32>(&o_cdfs)[..cdfs.len()], cdfs[..], "{tag}: emitter cdfs");
                assert_eq!(read::<BvhTriangle>(&o_triangles)[..triangles.len()], triangles[..], "{tag}: triangles");
                // A triangle's BVH record names the alpha test its shading record names.
                for tri in &triangles {
                    assert_eq!(tri.alpha_material, shading[tri.prim as usize].alpha_material, "{tag}: triangle {}'s alpha test", tri.prim);
                }
                if *name == "alpha test" {
                    let (grey, tests) = (&materials[1], shading.iter().filter(|s| s.alpha_material == 2).count());
                    assert_eq!((grey.alpha_cutoff, grey.alpha.width, grey.alpha.height, tests), (0.5, 4, 1, 2), "{tag}: the occluder's alpha test");
                    assert_eq!(&data[grey.alpha.offset as usize..][..4], [0.0, 0.0, 1.0, 1.0], "{tag}: the alpha texels");
                }
                let nodes_in: Vec<u8> = buffer("BvhNodes").read().unwrap();
                let nodes_out: Vec<u8> = o_nodes.read().unwrap();
                assert_eq!(nodes_out[..nodes_in.len()], nodes_in[..], "{tag}: nodes");
                let all: Vec<f32> = [data.clone(), theta.clone(), env.clone()].concat();
                let got: Vec<u32> = read::<f32>(&o_floats)[..all.len()].iter().map(|v| v.to_bits()).collect();
                assert_eq!(got, all.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "{tag}: material data, θ, environment");
                // Every vec3 fetch3 can read, at each of the four alignments within a texel.
                let triples = read::<[f32; 3]>(&o_triples);
                for (base, floats) in [(0, &data), (data.len(), &theta)] {
                    for i in 0..floats.len().saturating_sub(2) {
                        let want = [floats[i], floats[i + 1], floats[i + 2]].map(f32::to_bits);
                        assert_eq!(
                            triples[base + i].map(f32::to_bits),
                            want,
                            "{tag}: the vec3 at float {i} of {}",
                            if base == 0 { "material data" } else { "θ" }
                        );
                    }
                }
                if *name == "env quad" {
                    assert!(!env.is_empty(), "the lat-long map has a distribution");
                }
                if !matches!(*name, "env quad" | "normal map" | "emission texture" | "alpha test") {
                    assert!(theta.iter().any(|&v| v != 0.0), "{tag}: θ holds the start values");
                }
            }
        }
    });
}

/// The records kernels read from texel buffers have the layouts of their Rust mirrors
/// (offsets reflected from records_test's output structs) and are whole texels.
#[test]
fn texel_record_layouts_match_reflection() {
    use std::mem::offset_of;
    use vkinverse::shared::{EmitterTri, Globals, LightRecord, MaterialRecord, SensorRecord, TriShading, TEXEL_RECORDS};
    let spirv = vkinverse::gpu::shaders::get("records_test").unwrap();
    let r = vkinverse::gpu::reflect::Reflection::new("records_test", spirv).unwrap();
    let size = |name: &str| TEXEL_RECORDS.iter().find(|(n, _)| *n == name).unwrap_or_else(|| panic!("{name} not a texel record")).1;
    let check = |name: &str, rust: &[(&str, usize)]| common::check_layout("records_test", name, rust, size(name));
    check(
        "MaterialRecord",
        &[
            ("base_color", offset_of!(MaterialRecord, base_color)),
            ("roughness", offset_of!(MaterialRecord, roughness)),
            ("metallic", offset_of!(MaterialRecord, metallic)),
            ("kind", offset_of!(MaterialRecord, kind)),
            ("one_sided", offset_of!(MaterialRecord, one_sided)),
            ("alpha_cutoff", offset_of!(MaterialRecord, alpha_cutoff)),
            ("ior", offset_of!(MaterialRecord, ior)),
            ("normal_map", offset_of!(MaterialRecord, normal_map)),
            ("alpha", offset_of!(MaterialRecord, alpha)),
            ("absorption", offset_of!(MaterialRecord, absorption)),
            ("internal", offset_of!(MaterialRecord, internal)),
            ("eta", offset_of!(MaterialRecord, eta)),
            ("table", offset_of!(MaterialRecord, table)),
            ("k", offset_of!(MaterialRecord, k)),
            ("coating", offset_of!(MaterialRecord, coating)),
            ("specular", offset_of!(MaterialRecord, specular)),
            ("pad", offset_of!(MaterialRecord, pad)),
        ],
    );
    check(
        "TriShading",
        &[
            ("ng", offset_of!(TriShading, ng)),
            ("material", offset_of!(TriShading, material)),
            ("emitter_pdf", offset_of!(TriShading, emitter_pdf)),
            ("emitter_flags", offset_of!(TriShading, emitter_flags)),
            ("one_sided", offset_of!(TriShading, one_sided)),
            ("mesh", offset_of!(TriShading, mesh)),
            ("emission", offset_of!(TriShading, emission)),
            ("n0", offset_of!(TriShading, n0)),
            ("n1", offset_of!(TriShading, n1)),
            ("n2", offset_of!(TriShading, n2)),
            ("uv0", offset_of!(TriShading, uv0)),
            ("uv1", offset_of!(TriShading, uv1)),
            ("uv2", offset_of!(TriShading, uv2)),
            ("alpha_material", offset_of!(TriShading, alpha_material)),
            ("tangent", offset_of!(TriShading, tangent)),
        ],
    );
    check(
        "EmitterTri",
        &[
            ("p0", offset_of!(EmitterTri, p0)),
            ("e1", offset_of!(EmitterTri, e1)),
            ("e2", offset_of!(EmitterTri, e2)),
            ("ng", offset_of!(EmitterTri, ng)),
            ("prim", offset_of!(EmitterTri, prim)),
            ("cdf", offset_of!(EmitterTri, cdf)),
            ("pdf", offset_of!(EmitterTri, pdf)),
            ("two_sided", offset_of!(EmitterTri, two_sided)),
            ("emission", offset_of!(EmitterTri, emission)),
        ],
    );
    check(
        "SensorRecord",
        &[
            ("origin", offset_of!(SensorRecord, origin)),
            ("right", offset_of!(SensorRecord, right)),
            ("up", offset_of!(SensorRecord, up)),
            ("forward", offset_of!(SensorRecord, forward)),
            ("tan_half_fov_y", offset_of!(SensorRecord, tan_half_fov_y)),
            ("aspect", offset_of!(SensorRecord, aspect)),
            ("ortho_half_height", offset_of!(SensorRecord, ortho_half_height)),
            ("lens_radius", offset_of!(SensorRecord, lens_radius)),
            ("focus_distance", offset_of!(SensorRecord, focus_distance)),
            ("pad1", offset_of!(SensorRecord, pad)),
            ("pad2", offset_of!(SensorRecord, pad) + 4),
            ("pad3", offset_of!(SensorRecord, pad) + 8),
        ],
    );
    check(
        "Globals",
        &[
            ("environment", offset_of!(Globals, environment)),
            ("environment_scale", offset_of!(Globals, environment_scale)),
            ("environment_sample_prob", offset_of!(Globals, environment_sample_prob)),
            ("num_lights", offset_of!(Globals, num_lights)),
            ("filter_table", offset_of!(Globals, filter_table)),
        ],
    );
    check(
        "LightRecord",
        &[
            ("position", offset_of!(LightRecord, position)),
            ("kind", offset_of!(LightRecord, kind)),
            ("direction", offset_of!(LightRecord, direction)),
            ("falloff", offset_of!(LightRecord, falloff)),
            ("color", offset_of!(LightRecord, color)),
            ("intensity", offset_of!(LightRecord, intensity)),
            ("cos_inner", offset_of!(LightRecord, cos_inner)),
            ("cos_outer", offset_of!(LightRecord, cos_outer)),
            ("inner", offset_of!(LightRecord, inner)),
            ("outer", offset_of!(LightRecord, outer)),
        ],
    );
    for (name, size) in TEXEL_RECORDS {
        assert_eq!(size % vkinverse::gpu::TEXEL_BYTES as usize, 0, "{name} is whole texels");
    }
    // The scene's bindings sit where lib/scene_access.glsl puts them, as texel buffers.
    use vkinverse::gpu::reflect::{BindingKind, TexelType};
    let bindings = [
        ("Materials", 20),
        ("Shading", 21),
        ("Emitters", 23),
        ("Sensors", 24),
        ("SceneGlobals", 25),
        ("EnvDistribution", 27),
        ("Lights", 28),
        ("Theta", 30),
        ("BvhNodes", 10),
        ("BvhTriangles", 11),
    ];
    for (name, binding) in bindings {
        let b = r.binding(name).unwrap_or_else(|| panic!("{name} not bound"));
        // Read-only storage texel buffers, read by image loads (glsl/lib/texels.glsl).
        assert_eq!((b.binding, b.kind), (binding, BindingKind::ImageBuffer(TexelType::Uint)), "{name}");
    }
}

/// lavapipe's compiler caps the loop iterations of one shader invocation (a SIMD batch)
/// at 65535, counted over every loop of the kernel and never reset: past it, every loop
/// exits after its current iteration, so a thread that loops over too many samples
/// returns truncated paths. The passes therefore split their samples into short
/// dispatches. A primal pass of 1024 samples per pixel (the loss image of a gradient
/// estimate) must render the same image as `render`, which submits 4 spp at a time:
/// channel means within 1 % (their standard errors are ~0.1 %; a truncated pass loses
/// tens of percent).
#[test]
fn many_samples_per_pixel_in_one_pass_render_the_same_image() {
    use vkinverse::gpu::{Buffer, CommandBuffer, MemoryKind};
    use vkinverse::image::Image;
    use vkinverse::ops::BufferOps;
    use vkinverse::render::gradient::{GradientInputs, GradientPass};
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = Scene::load(root.join("scenes/cornell/scene.toml")).unwrap();
    with_gpu(|ctx| {
        let renderer = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
        let gs = &renderer.scene;
        let spp = 1024;
        let split = renderer.render(0, spp, 5, |_, _| {}).unwrap();
        let ops = BufferOps::new(ctx).unwrap();
        let zero = Image { width: gs.width, height: gs.height, data: vec![[0.0; 3]; gs.pixels()] };
        let grad = Buffer::zeroed::<f32>(ctx, "grad", gs.layout.len.max(1), MemoryKind::Device).unwrap();
        let pass = GradientPass::new(
            gs,
            &ops,
            &GradientInputs {
                targets: &[zero],
                loss: vkinverse::settings::RunSettings::of_scene(&scene).loss,
                spp: 1,
                primal_spp: spp,
                seed: 9,
                theta: &gs.theta,
                theta_prev: None,
                grad: &grad,
                grad_half: None,
            },
        )
        .unwrap();
        let mut cmd = CommandBuffer::new(ctx, "primal").unwrap();
        cmd.record(|rec| pass.record_loss(rec, gs, &ops)).unwrap();
        cmd.submit_and_wait().unwrap();
        let one = pass.rendered(0, gs).unwrap();
        let mean = |img: &Image, c: usize| img.data.iter().map(|p| p[c] as f64).sum::<f64>() / img.data.len() as f64;
        for c in 0..3 {
            let (a, b) = (mean(&one, c), mean(&split, c));
            assert!((a / b - 1.0).abs() < 0.01, "channel {c}: {spp} spp in one pass {a}, in submissions of 4 {b}");
        }
    });
}

/// The adjoint pass renders θ as it replays its samples for their radiance
/// (`GradientPass::adjoint_radiance`, which meta's carried image takes in): its image is the
/// primal kernel's with the adjoint pass's seed and samples, over a pass split into several
/// dispatches, and on every pixel, those without gradient (an adjoint weight of 0, which skip
/// the gradient replay) included.
#[test]
fn the_adjoint_pass_renders_theta_with_its_own_samples() {
    use vkinverse::gpu::{Buffer, CommandBuffer, MemoryKind};
    use vkinverse::image::Image;
    use vkinverse::ops::BufferOps;
    use vkinverse::render::gradient::{GradientInputs, GradientPass, SEED_ADJOINT, SEED_PRIMAL};
    use vkinverse::render::spp_per_dispatch;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = Scene::load(root.join("scenes/cornell/scene.toml")).unwrap();
    with_gpu(|ctx| {
        let renderer = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
        let gs = &renderer.scene;
        let ops = BufferOps::new(ctx).unwrap();
        let loss = vkinverse::settings::RunSettings::of_scene(&scene).loss;
        let grad = Buffer::zeroed::<f32>(ctx, "grad", gs.layout.len.max(1), MemoryKind::Device).unwrap();
        let (spp, seed) = (9u32, 11u32);
        assert!(spp > spp_per_dispatch(gs.max_depth), "one dispatch would not test the split");
        let zero = Image { width: gs.width, height: gs.height, data: vec![[0.0; 3]; gs.pixels()] };
        let run = |pass: &GradientPass, adjoint: bool| {
            let mut cmd = CommandBuffer::new(ctx, "pass").unwrap();
            cmd.record(|rec| {
                rec.transition(&[(&grad, vkinverse::gpu::Access::TransferWrite)])?;
                rec.zero(&grad)?;
                pass.record_passes(rec, gs, &ops, adjoint)
            })
            .unwrap();
            cmd.submit_and_wait().unwrap();
        };
        // The primal kernel with the adjoint pass's seed and samples.
        let primal = GradientPass::new(
            gs,
            &ops,
            &GradientInputs {
                targets: std::slice::from_ref(&zero),
                loss,
                spp: 1,
                primal_spp: spp,
                seed: seed.wrapping_add(SEED_ADJOINT).wrapping_sub(SEED_PRIMAL),
                theta: &gs.theta,
                theta_prev: None,
                grad: &grad,
                grad_half: None,
            },
        )
        .unwrap();
        run(&primal, false);
        let want = primal.rendered(0, gs).unwrap();
        // A pass's own primal image as its target makes every pixel's adjoint weight 0.
        let first = GradientPass::new(
            gs,
            &ops,
            &GradientInputs {
                targets: std::slice::from_ref(&zero),
                loss,
                spp,
                primal_spp: 1,
                seed,
                theta: &gs.theta,
                theta_prev: None,
                grad: &grad,
                grad_half: None,
            },
        )
        .unwrap();
        run(&first, false);
        let own = first.rendered(0, gs).unwrap();
        for (what, target) in [("a black target", zero), ("its own primal image as the target", own)] {
            let pass = GradientPass::new(
                gs,
                &ops,
                &GradientInputs { targets: &[target], loss, spp, primal_spp: 1, seed, theta: &gs.theta, theta_prev: None, grad: &grad, grad_half: None },
            )
            .unwrap();
            run(&pass, true);
            let g: Vec<f32> = grad.read().unwrap();
            let no_gradient = g.iter().all(|&x| x == 0.0);
            assert_eq!(no_gradient, what.contains("own"), "{what}: gradient {g:?}");
            let got: Vec<[f32; 3]> = pass.adjoint_radiance(0).expect("a gradient estimate's adjoint pass renders").read().unwrap();
            let mut total = 0.0;
            for (i, (a, b)) in got.iter().zip(&want.data).enumerate() {
                for c in 0..3 {
                    total += b[c] as f64;
                    assert!(
                        (a[c] - b[c]).abs() <= 1e-5 * (1.0 + b[c].abs()),
                        "{what}: pixel {i} channel {c}: adjoint pass {} against the primal kernel {}",
                        a[c],
                        b[c]
                    );
                }
            }
            assert!(total > 0.0, "{what}: a black image tests nothing");
        }
    });
}

fn delta_lit_scene(name: &str, optimise: &str) -> Scene {
    Scene::load(common::scenes::write_delta_lit(name, (24, 20), optimise)).unwrap()
}

/// Point, spot (both falloffs) and directional lights over a diffuse plane, direct light
/// only: every pixel agrees with the closed form averaged over the pixel (8 × 8 points),
/// within 5 standard errors of the pixel's own jitter noise (the only randomness left:
/// delta lights are sampled exactly) plus 1e-4 relative for the ray offset and float
/// rounding. A light with a wrong falloff, distance law or cosine moves many pixels by
/// many standard errors.
#[test]
fn delta_lights_over_a_diffuse_plane_match_the_closed_form() {
    let scene = delta_lit_scene("delta-analytic", "");
    assert_eq!(scene.lights.len(), 4);
    let spp = 64;
    let image = with_gpu(|ctx| {
        let renderer = PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap();
        assert_eq!(renderer.scene.features.lights.count(), 4);
        renderer.render(0, spp, 3, |_, _| {}).unwrap()
    });
    let (w, h) = (scene.film.width, scene.film.height);
    let sensor = &scene.sensors[0];
    let aspect = w as f32 / h as f32;
    let mut worst: f64 = 0.0;
    for y in 0..h {
        for x in 0..w {
            let mut samples = Vec::new();
            for k in 0..64 {
                let jitter = glam::Vec2::new((k % 8) as f32 + 0.5, (k / 8) as f32 + 0.5) / 8.0;
                let ndc = (glam::Vec2::new(x as f32, y as f32) + jitter) / glam::Vec2::new(w as f32, h as f32) * 2.0 - 1.0;
                let d = sensor.ray_direction(glam::Vec2::new(ndc.x, -ndc.y), aspect);
                let t = -sensor.origin.y / d.y;
                let p = sensor.origin + t * d;
                samples.push(common::scenes::delta_lit_radiance(&scene, p.to_array().map(f64::from)));
            }
            let got = image.get(x, y);
            for c in 0..3 {
                let v: Vec<f64> = samples.iter().map(|s| s[c]).collect();
                let mean = v.iter().sum::<f64>() / v.len() as f64;
                let sd = (v.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
                let tol = 5.0 * sd / (spp as f64).sqrt() + 1e-4 * mean + 1e-6;
                let err = (got[c] as f64 - mean).abs();
                worst = worst.max(err / tol);
                assert!(err <= tol, "pixel ({x}, {y}) channel {c}: rendered {} vs closed form {mean} (tolerance {tol})", got[c]);
            }
        }
    }
    eprintln!("delta lights: worst pixel at {worst:.2} of its tolerance");
    assert!(image.data.iter().any(|p| p[2] > 0.0), "the scene is lit");
}

/// Every kernel's bindings fit the test device's per-stage descriptor limits, and a device
/// with Vulkan's least guaranteed limits is refused with an error naming the limit, not
/// handed an invalid pipeline layout.
#[test]
fn kernels_fit_the_per_stage_descriptor_limits_or_are_refused() {
    use vkinverse::gpu::reflect::Reflection;
    use vkinverse::gpu::{check_descriptor_limits, shaders, ComputePipeline, DescriptorLimits, GpuError};
    with_gpu(|ctx| {
        let limits = ctx.info().descriptor_limits;
        for (name, spirv) in shaders::KERNELS {
            let r = Reflection::new(name, spirv).unwrap();
            check_descriptor_limits(name, &r.bindings, "test", limits).unwrap_or_else(|e| panic!("{e}"));
        }
        let minimum = DescriptorLimits { storage_buffers: 4, storage_images: 4, sampled_images: 16, resources: 128 };
        let r = Reflection::new("trace_primal_cw8", shaders::get("trace_primal_cw8").unwrap()).unwrap();
        let err = check_descriptor_limits("trace_primal_cw8", &r.bindings, "small", minimum).unwrap_err();
        assert!(matches!(err, GpuError::TooManyDescriptors { what: "storage texel buffers", max: 4, .. }), "{err}");
        let msg = err.to_string();
        assert!(msg.contains("maxPerStageDescriptorStorageImages") && msg.contains("device 'small'") && !msg.contains('\n'), "{msg}");
        // The texel-fetch build counts its texel buffers as sampled images instead.
        let r = Reflection::new("trace_primal_sampled_cw8", shaders::get("trace_primal_sampled_cw8").unwrap()).unwrap();
        check_descriptor_limits("trace_primal_sampled_cw8", &r.bindings, "small", minimum).unwrap();
        let fewer = DescriptorLimits { sampled_images: 2, ..minimum };
        let err = check_descriptor_limits("trace_primal_sampled_cw8", &r.bindings, "small", fewer).unwrap_err();
        assert!(matches!(err, GpuError::TooManyDescriptors { what: "uniform texel buffers", .. }), "{err}");
        // The pipeline is built through the check.
        ComputePipeline::new(ctx, "trace_primal_cw8", &[]).unwrap();
    });
}

/// Radiances of [`lamp_scene`]'s two halves.
const LAMP_RED: [f32; 3] = [4.0, 0.5, 0.5];
const LAMP_BLUE: [f32; 3] = [0.5, 0.5, 4.0];

/// A white diffuse floor (the 2 × 2 quad) under a 1 × 0.5 lamp at y = 1 facing down, seen
/// from below the lamp's height so that both its underside and the lit floor are in view.
/// `textured`: one mesh whose emission is a 16 × 1 texture (8 texels `left`, 8 `right`)
/// and whose left and right halves read the middle of either run only (u in
/// [0.125, 0.375] and [0.625, 0.875]: the bilinear lookup there never mixes them);
/// otherwise the same two halves as two meshes of constant emission `left` and `right`.
fn lamp_scene(name: &str, textured: bool, left_emission: [f32; 3], right_emission: [f32; 3]) -> Scene {
    let dir = common::scenes::temp_dir(name);
    std::fs::write(dir.join("floor.obj"), common::scenes::QUAD_OBJ).unwrap();
    let half = |x0: f32, u0: f32| {
        let (x1, u1) = (x0 + 0.5, u0 + 0.25);
        format!("v {x0} 1 -0.25\nv {x1} 1 -0.25\nv {x1} 1 0.25\nv {x0} 1 0.25\nvt {u0} 0.5\nvt {u1} 0.5\nvt {u1} 0.5\nvt {u0} 0.5\n")
    };
    let (left, right) = (half(-0.5, 0.125), half(0.0, 0.625));
    let color = |c: [f32; 3]| format!("[{}, {}, {}]", c[0], c[1], c[2]);
    let lamps = if textured {
        let texels = Image { width: 16, height: 1, data: [[left_emission; 8], [right_emission; 8]].concat() };
        write_exr(&dir.join("lamp.exr"), &texels).unwrap();
        std::fs::write(dir.join("lamp.obj"), format!("{left}{right}f 1/1 2/2 3/3 4/4\nf 5/5 6/6 7/7 8/8\n")).unwrap();
        "[[meshes]]\nfile = \"lamp.obj\"\nmaterial = \"black\"\nemission = { texture = \"lamp.exr\" }\n".to_string()
    } else {
        std::fs::write(dir.join("left.obj"), format!("{left}f 1/1 2/2 3/3 4/4\n")).unwrap();
        std::fs::write(dir.join("right.obj"), format!("{right}f 1/1 2/2 3/3 4/4\n")).unwrap();
        format!(
            "[[meshes]]\nfile = \"left.obj\"\nmaterial = \"black\"\nemission = {}\n[[meshes]]\nfile = \"right.obj\"\nmaterial = \"black\"\nemission = {}\n",
            color(left_emission),
            color(right_emission)
        )
    };
    let toml = format!(
        "[film]\nwidth = 32\nheight = 32\n[integrator]\nmax_depth = 3\n[[sensors]]\norigin = [0, 0.3, 2.5]\ntarget = [0, 0.45, 0]\nfov_y = 50\n\
         [[materials]]\nname = \"white\"\ntype = \"diffuse\"\nbase_color = [0.8, 0.8, 0.8]\n\
         [[materials]]\nname = \"black\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n\
         [[meshes]]\nfile = \"floor.obj\"\nmaterial = \"white\"\n{lamps}"
    );
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    Scene::load(dir.join("scene.toml")).unwrap()
}

/// A textured emitter lights and shows as the constant emitters of its texels do: the
/// lamp of [`lamp_scene`] as one textured mesh and as two constant meshes. Seen directly
/// (the emission at a ray's hit), pixels inside either half show that half's radiance
/// exactly; on the floor, lit by next-event estimation (the emission at a sampled point
/// of the light) and by BSDF samples that hit the lamp, each quadrant's mean agrees
/// within Monte Carlo noise. A light sample that
/// read the texture at the wrong point would light the floor's right side red: its blue
/// would fall by more than half.
#[test]
fn textured_emission_lights_as_the_constant_emitters_of_its_texels() {
    let exact = |img: &Image, want: [f32; 3]| img.data.iter().filter(|p| (0..3).all(|c| (p[c] - want[c]).abs() <= 1e-5 * want[c])).count();
    with_gpu(|ctx| {
        let render = |scene: &Scene, seed: u32| {
            let gs = GpuScene::new(ctx, scene).unwrap();
            PrimalRenderer::new(gs).unwrap().render(0, 512, seed, |_, _| {}).unwrap()
        };
        let textured = lamp_scene("emission-texture", true, LAMP_RED, LAMP_BLUE);
        assert!(GpuScene::new(ctx, &textured).unwrap().has("HAS_EMISSION_TEXTURES"));
        let split = lamp_scene("emission-split", false, LAMP_RED, LAMP_BLUE);
        // The same seed: camera rays (and so the lamp seen directly) alike; another seed of
        // the constant scene shows the noise.
        let (a, b, again) = (render(&textured, 1), render(&split, 1), render(&split, 2));
        for img in [&a, &b] {
            assert!(
                exact(img, LAMP_RED) >= 4 && exact(img, LAMP_BLUE) >= 4,
                "the lamp's halves in view: {} red, {} blue pixels",
                exact(img, LAMP_RED),
                exact(img, LAMP_BLUE)
            );
        }
        let (qa, qb, qc) = (quadrant_sums(&a), quadrant_sums(&b), quadrant_sums(&again));
        for q in 0..4 {
            for c in 0..3 {
                let (x, y, noise) = (qa[q][c], qb[q][c], (qc[q][c] / qb[q][c] - 1.0).abs());
                eprintln!("quadrant {q}, channel {c}: textured {x:.3}, constant {y:.3} (ratio {:.4}; two seeds of the constant scene: {noise:.4})", x / y);
                assert!((x / y - 1.0).abs() < 0.03, "quadrant {q}, channel {c}: {x} vs {y}");
            }
        }
    });
}

/// Light sampling picks a textured emitter's triangles by the texels their lookups can
/// reach: the lamp of [`lamp_scene`] black on its left half and white on its right has
/// the emitter table of the same lamp as a black and a white mesh (the left half's
/// triangles, which can only read black texels, are not sampled at all), and renders as
/// it does within noise.
#[test]
fn textured_emitters_are_sampled_by_the_texels_they_reach() {
    use vkinverse::shared::EmitterTri;
    let white = [3.0, 3.0, 3.0];
    let (textured, split) = (lamp_scene("emission-half-black", true, [0.0; 3], white), lamp_scene("emission-half-black-split", false, [0.0; 3], white));
    with_gpu(|ctx| {
        let table = |scene: &Scene| {
            let gs = GpuScene::new(ctx, scene).unwrap();
            let bound = gs.bindings();
            let bytes: Vec<u8> = bound.iter().find(|(n, _)| *n == "Emitters").unwrap().1.read().unwrap();
            let records: Vec<EmitterTri> = bytes.chunks_exact(std::mem::size_of::<EmitterTri>()).map(bytemuck::pod_read_unaligned).collect();
            records[..gs.emitters() as usize].iter().map(|e| (e.p0, e.pdf, e.cdf)).collect::<Vec<_>>()
        };
        let (a, b) = (table(&textured), table(&split));
        assert_eq!(a.len(), 2, "the white half's two triangles: {a:?}");
        assert_eq!(a, b, "the textured lamp's emitter table against the two meshes'");
        let render = |scene: &Scene| PrimalRenderer::new(GpuScene::new(ctx, scene).unwrap()).unwrap().render(0, 256, 1, |_, _| {}).unwrap();
        let mean = |img: &Image| img.data.iter().map(|p| p[0] as f64).sum::<f64>() / img.data.len() as f64;
        let (x, y) = (mean(&render(&textured)), mean(&render(&split)));
        assert!((x / y - 1.0).abs() < 0.01, "mean {x} against {y}");
    });
}

/// Textures read at a mesh's second set of texture coordinates (a colour texture, a
/// normal map, whose tangent frame is that of its set, and an emission texture, whose
/// light-sampling table is too) render bit for bit as the same textures read at a first
/// set that holds those coordinates, and reading the decoy set instead changes the
/// image: [`common::scenes::two_uv_sets`]. The same seed gives the same paths, and the
/// second set is interpolated with the same arithmetic as the first.
#[test]
fn a_second_set_of_texture_coordinates_renders_as_the_first() {
    use common::scenes::{two_uv_sets, UvCase};
    let (first, second, decoy) =
        (two_uv_sets("uv-first", UvCase::First, ""), two_uv_sets("uv-second", UvCase::Second, ""), two_uv_sets("uv-decoy", UvCase::Decoy, ""));
    with_gpu(|ctx| {
        let render = |scene: &Scene| {
            let gs = GpuScene::new(ctx, scene).unwrap();
            PrimalRenderer::new(gs).unwrap().render(0, 64, 3, |_, _| {}).unwrap()
        };
        assert!(GpuScene::new(ctx, &second).unwrap().has("HAS_UV1"), "the kernels read the second set");
        assert!(!GpuScene::new(ctx, &first).unwrap().has("HAS_UV1"), "nor where no mesh has one");
        let (a, b, c) = (render(&first), render(&second), render(&decoy));
        let peak = a.data.iter().flatten().fold(0.0f32, |m, &v| m.max(v));
        let worst = a.data.iter().flatten().zip(b.data.iter().flatten()).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(peak > 0.1 && worst <= 1e-5 * peak, "set 1 against set 0: largest difference {worst} (peak {peak})");
        let diff: f64 = a.data.iter().flatten().zip(c.data.iter().flatten()).map(|(x, y)| (x - y).abs() as f64).sum();
        let total: f64 = a.data.iter().flatten().map(|&v| v as f64).sum();
        assert!(diff > 0.1 * total, "the decoy changes the image by only {:.4} (relative L1)", diff / total);
    });
}

/// What the cut-out scenes' masked object is replaced by, or whether it keeps its alpha test.
#[derive(Clone, Copy, PartialEq)]
enum Cutout {
    /// The whole quad with a 4 × 1 alpha texture (0, 0, 1, 1) tested at 0.5: the bilinear
    /// lookup is below 0.5 exactly where u < 0.5, so the test cuts out the quad's left half.
    Masked,
    /// The whole quad, there with probability `alpha` (alpha_mode "blend").
    Blend(f32),
    /// The quad's right half alone, without an alpha test.
    Half,
    /// The whole quad, without an alpha test.
    Whole,
    /// No quad.
    Absent,
}

/// A white floor lit from y = 1.2 by a 1 × 1 lamp facing down (emission 3), seen from below
/// the lamp's height as in [`lamp_scene`], 32² pixels, depth 3. `lamp_cut`: the lamp is
/// the object `cutout` shapes; otherwise the lamp is whole and the object is a 0.8 × 0.8
/// occluder of colour `grey` at y = 0.6 between it and the floor.
fn cutout_scene(name: &str, cutout: Cutout, lamp_cut: bool, grey: f32) -> Scene {
    let dir = common::scenes::temp_dir(name);
    std::fs::write(dir.join("floor.obj"), common::scenes::QUAD_OBJ).unwrap();
    // A quad facing down at height y over [x0, x1] × [-h, h], u from 0 at x = -h to 1 at x = h.
    let quad = |y: f32, h: f32, x0: f32| {
        let u0 = (x0 + h) / (2.0 * h);
        format!("v {x0} {y} {}\nv {h} {y} {}\nv {h} {y} {h}\nv {x0} {y} {h}\nvt {u0} 0\nvt 1 0\nvt 1 1\nvt {u0} 1\nf 1/1 2/2 3/3 4/4\n", -h, -h)
    };
    let (y, h) = if lamp_cut { (1.2, 0.5) } else { (0.6, 0.4) };
    let object = quad(y, h, if cutout == Cutout::Half { 0.0 } else { -h });
    write_exr(&dir.join("mask.exr"), &Image { width: 4, height: 1, data: vec![[0.0; 3], [0.0; 3], [1.0; 3], [1.0; 3]] }).unwrap();
    let alpha = match cutout {
        Cutout::Masked => "alpha = { texture = \"mask.exr\" }\nalpha_cutoff = 0.5\n".to_string(),
        Cutout::Blend(a) => format!("alpha = {a}\nalpha_mode = \"blend\"\n"),
        _ => String::new(),
    };
    std::fs::write(dir.join("object.obj"), object).unwrap();
    let object = |material: &str, emission: &str| {
        if cutout == Cutout::Absent {
            String::new()
        } else {
            format!("[[meshes]]\nfile = \"object.obj\"\nmaterial = \"{material}\"\n{emission}")
        }
    };
    let meshes = if lamp_cut {
        format!("[[materials]]\nname = \"lamp\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n{alpha}{}", object("lamp", "emission = [3, 3, 3]\n"))
    } else {
        std::fs::write(dir.join("lamp.obj"), quad(1.2, 0.5, -0.5)).unwrap();
        format!(
            "[[materials]]\nname = \"grey\"\ntype = \"diffuse\"\nbase_color = [{grey}, {grey}, {grey}]\n{alpha}{}\
             [[materials]]\nname = \"lamp\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n[[meshes]]\nfile = \"lamp.obj\"\nmaterial = \"lamp\"\nemission = [3, 3, 3]\n",
            object("grey", "")
        )
    };
    let toml = format!(
        "[film]\nwidth = 32\nheight = 32\n[integrator]\nmax_depth = 3\n[[sensors]]\norigin = [0, 0.3, 2.5]\ntarget = [0, 0.45, 0]\nfov_y = 50\n\
         [[materials]]\nname = \"white\"\ntype = \"diffuse\"\nbase_color = [0.8, 0.8, 0.8]\n[[meshes]]\nfile = \"floor.obj\"\nmaterial = \"white\"\n{meshes}"
    );
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    Scene::load(dir.join("scene.toml")).unwrap()
}

/// The sums of each channel over the image's four quadrants (top left, top right, bottom
/// left, bottom right).
fn quadrant_sums(img: &Image) -> [[f64; 3]; 4] {
    let mut sums = [[0.0f64; 3]; 4];
    for y in 0..img.height {
        for x in 0..img.width {
            let q = (2 * y / img.height * 2 + 2 * x / img.width) as usize;
            for (sum, v) in sums[q].iter_mut().zip(img.get(x, y)) {
                *sum += v as f64;
            }
        }
    }
    sums
}

/// An alpha test removes the surface where it fails, for every ray: an occluder whose
/// left half is cut out renders as its right half alone (seen directly by camera rays,
/// casting shadows on the floor through shadow rays, reflecting light through BSDF-sampled
/// rays), not as the whole occluder; and a lamp whose left half is cut out lights the
/// floor as its right half alone (light samples that land on the cut-out half bring no
/// light). Same seeds: the cut-out occluder's paths are the half occluder's, so quadrant
/// by quadrant the two agree to rounding; the lamp's light samples land on all of it, so
/// there the two agree within Monte Carlo noise.
#[test]
fn alpha_tests_cut_surfaces_out_for_every_ray() {
    with_gpu(|ctx| {
        let render = |scene: &Scene, spp: u32, seed: u32| {
            let gs = GpuScene::new(ctx, scene).unwrap();
            PrimalRenderer::new(gs).unwrap().render(0, spp, seed, |_, _| {}).unwrap()
        };
        let masked = cutout_scene("alpha-occluder", Cutout::Masked, false, 0.5);
        assert!(GpuScene::new(ctx, &masked).unwrap().has("HAS_ALPHA_MASKS"));
        let half = cutout_scene("alpha-occluder-half", Cutout::Half, false, 0.5);
        assert!(!GpuScene::new(ctx, &half).unwrap().has("HAS_ALPHA_MASKS"));
        let whole = cutout_scene("alpha-occluder-whole", Cutout::Whole, false, 0.5);
        let (a, b, w) = (quadrant_sums(&render(&masked, 128, 1)), quadrant_sums(&render(&half, 128, 1)), quadrant_sums(&render(&whole, 128, 1)));
        for q in 0..4 {
            for c in 0..3 {
                eprintln!("occluder, quadrant {q}, channel {c}: cut out {:.4}, half {:.4}, whole {:.4}", a[q][c], b[q][c], w[q][c]);
                assert!((a[q][c] / b[q][c] - 1.0).abs() < 1e-3, "quadrant {q}, channel {c}: the cut-out occluder {} against its half {}", a[q][c], b[q][c]);
            }
        }
        // The left half of the occluder shades the floor's left side and hides what is
        // behind it: without the cut the bottom-left quadrant would be far darker.
        assert!(w[2][0] < 0.8 * b[2][0], "the whole occluder {} should darken the bottom-left quadrant against the half {}", w[2][0], b[2][0]);

        let lamp = cutout_scene("alpha-lamp", Cutout::Masked, true, 0.0);
        let (half_lamp, whole_lamp) = (cutout_scene("alpha-lamp-half", Cutout::Half, true, 0.0), cutout_scene("alpha-lamp-whole", Cutout::Whole, true, 0.0));
        let (a, b, again, w) = (
            quadrant_sums(&render(&lamp, 512, 1)),
            quadrant_sums(&render(&half_lamp, 512, 2)),
            quadrant_sums(&render(&half_lamp, 512, 3)),
            quadrant_sums(&render(&whole_lamp, 512, 1)),
        );
        for q in 0..4 {
            for c in 0..3 {
                let noise = (again[q][c] / b[q][c] - 1.0).abs();
                eprintln!(
                    "lamp, quadrant {q}, channel {c}: cut out {:.4}, half {:.4} (two seeds of the half differ by {noise:.4}), whole {:.4}",
                    a[q][c], b[q][c], w[q][c]
                );
                // (The top-left quadrant sees the lamp's cut-out half against the black
                // sky: nothing there but for the whole lamp.)
                let agree = if b[q][c] == 0.0 { a[q][c] == 0.0 } else { (a[q][c] / b[q][c] - 1.0).abs() < 0.02 };
                assert!(agree, "quadrant {q}, channel {c}: the cut-out lamp {} against its half {}", a[q][c], b[q][c]);
            }
        }
        assert!(w[2][0] > 1.3 * b[2][0], "the whole lamp {} should light the bottom-left quadrant more than the half {}", w[2][0], b[2][0]);
    });
}

/// A blend (alpha_mode "blend") is a coverage: each ray that reaches the surface finds it
/// there with probability alpha. With a black occluder or a lamp of black material, every
/// path that carries light crosses the blended quad at most once, so the image is linear in
/// the coverage: a black occluder at alpha 0.3 renders as 0.3 × the opaque occluder's
/// image + 0.7 × the image without it, and a lamp at alpha 0.3 as 0.3 × the opaque lamp's
/// (its light samples included). Each quadrant agrees within Monte Carlo noise. An alpha of
/// 1 never cuts: no test is built, and the image is the opaque occluder's, bit for bit.
#[test]
fn blended_surfaces_are_there_with_probability_alpha() {
    with_gpu(|ctx| {
        let image = |scene: &Scene| PrimalRenderer::new(GpuScene::new(ctx, scene).unwrap()).unwrap().render(0, 16, 1, |_, _| {}).unwrap();
        let (solid, whole) = (cutout_scene("blend-solid", Cutout::Blend(1.0), false, 0.5), cutout_scene("blend-solid-whole", Cutout::Whole, false, 0.5));
        assert!(solid.materials[1].alpha.is_some() && !GpuScene::new(ctx, &solid).unwrap().has("HAS_ALPHA_MASKS"), "an alpha of 1 is no test");
        let bits = |i: &Image| i.data.iter().flat_map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
        assert_eq!(bits(&image(&solid)), bits(&image(&whole)), "an alpha of 1 renders as the opaque occluder");
        let render = |scene: &Scene, seed: u32| {
            quadrant_sums(&PrimalRenderer::new(GpuScene::new(ctx, scene).unwrap()).unwrap().render(0, 512, seed, |_, _| {}).unwrap())
        };
        let alpha = 0.3;
        for lamp in [false, true] {
            let tag = if lamp { "lamp" } else { "occluder" };
            let blend = render(&cutout_scene(&format!("blend-{tag}"), Cutout::Blend(alpha as f32), lamp, 0.0), 1);
            let whole = render(&cutout_scene(&format!("blend-{tag}-whole"), Cutout::Whole, lamp, 0.0), 2);
            let absent = render(&cutout_scene(&format!("blend-{tag}-absent"), Cutout::Absent, lamp, 0.0), 3);
            for q in 0..4 {
                for c in 0..3 {
                    let want = alpha * whole[q][c] + (1.0 - alpha) * absent[q][c];
                    eprintln!(
                        "{tag}, quadrant {q}, channel {c}: blend {:.4}, expected {want:.4} (opaque {:.4}, absent {:.4})",
                        blend[q][c], whole[q][c], absent[q][c]
                    );
                    let agree = if want == 0.0 { blend[q][c] == 0.0 } else { (blend[q][c] / want - 1.0).abs() < 0.03 };
                    assert!(agree, "{tag}, quadrant {q}, channel {c}: the blend {} against {want}", blend[q][c]);
                }
            }
        }
    });
}

/// A closed box of side 2 centred at the origin, faces outward (counter-clockwise seen from
/// outside), as OBJ text.
const CUBE_OBJ: &str = "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n\
f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 4 8 7 3\nf 1 5 8 4\nf 2 3 7 6\n";

/// An object of glass (`kind`: "dielectric" or "thin_dielectric"; `obj` its mesh) in the
/// constant environment, seen with a field of view of `fov_y`, without Russian roulette.
fn glass_scene(name: &str, kind: &str, obj: &str, fov_y: f32, tint: [f32; 3], ior: f32, max_depth: u32) -> Scene {
    glass_scene_with(name, kind, obj, fov_y, tint, ior, "", max_depth)
}

/// [`glass_scene`] with `extra` added to the material's table.
#[allow(clippy::too_many_arguments)]
fn glass_scene_with(name: &str, kind: &str, obj: &str, fov_y: f32, tint: [f32; 3], ior: f32, extra: &str, max_depth: u32) -> Scene {
    let glass = format!("type = \"{kind}\"\nbase_color = [{}, {}, {}]\nior = {ior}\n{extra}", tint[0], tint[1], tint[2]);
    object_in_environment(name, &glass, obj, fov_y, max_depth, max_depth)
}

/// White furnace through glass: a clear dielectric (no tint) in a constant environment
/// loses nothing. A path's weight is 1 at every mirror and, through the surface, 1/η² in
/// and η² out, so every path that escapes carries exactly L, and the image is L to float
/// rounding. Only a path cut at the depth limit would carry 0: light that enters a faceted
/// sphere near its rim can circle inside by total internal reflection for tens of bounces
/// (at depth 48, 22 pixels of 480 lost a sample or two), hence depth 512. Both indices,
/// glass in air and a bubble (η < 1: total internal reflection from outside).
#[test]
fn clear_glass_in_a_furnace_passes_all_light() {
    with_gpu(|ctx| {
        for ior in [1.5f32, 0.75] {
            let scene = glass_scene(&format!("glass-furnace-{ior}"), "dielectric", &sphere_obj(1.0, 3, false), 40.0, [1.0; 3], ior, 512);
            let gs = GpuScene::new(ctx, &scene).unwrap();
            assert!(gs.has("HAS_DIELECTRICS"));
            let img = PrimalRenderer::new(gs).unwrap().render(0, 16, 3, |_, _| {}).unwrap();
            let mut lowest = f32::INFINITY;
            for px in &img.data {
                for c in 0..3 {
                    assert!(px[c] <= ENV[c] * (1.0 + 1e-5), "ior {ior}: {px:?} brighter than the environment");
                    lowest = lowest.min(px[c] / ENV[c]);
                }
            }
            // Every sample carries L: the pixels are L to float rounding.
            assert!(lowest > 1.0 - 1e-5, "ior {ior}: a pixel at {lowest} of the environment");
        }
    });
}

/// A tinted glass box seen face-on in a constant environment: a camera sample is mirrored
/// with the Fresnel reflectance F ≈ ((η − 1)/(η + 1))² (incidence within 7° of the normal:
/// F within 2e-4 of it) and sees L, or enters, and every path that enters leaves through
/// the surface once more (the box is convex): two transmissions, t² L. So the image's mean
/// is (F + (1 − F) t²) L per channel; checked within 5 standard errors of its samples. A
/// thin sheet of the same glass in its place: (R + (1 − R) t) L with R = 2F/(1 + F).
/// Then the box clear but absorbing (coefficient σ, seen through a 4° field, where a ray
/// inside is within 0.05 % of the box's width 2): each crossing of the interior keeps
/// e^{−2σ}, and a path that enters leaves on either face after k internal mirrors with
/// (1 − F) (F e^{−2σ})^k, so the mean is F + (1 − F)² e^{−2σ} / (1 − F e^{−2σ}).
#[test]
fn tinted_glass_transmits_through_each_crossing() {
    with_gpu(|ctx| {
        let tint = [1.0f32, 0.5, 0.2];
        let ior = 1.5f64;
        let f = ((ior - 1.0) / (ior + 1.0)).powi(2);
        let check = |what: &str, scene: &Scene, expected: [f64; 3]| check_glass_mean(ctx, what, scene, expected);
        // The box, then a thin sheet (one face at z = 1): mirrored with its reflectance
        // 2F/(1 + F), or let through once, tinted by t.
        for (kind, obj, expected) in [
            ("dielectric", CUBE_OBJ, [0, 1, 2].map(|c| f + (1.0 - f) * (tint[c] as f64).powi(2))),
            (
                "thin_dielectric",
                "v -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\nf 1 2 3 4\n",
                [0, 1, 2].map(|c| 2.0 * f / (1.0 + f) + (1.0 - 2.0 * f / (1.0 + f)) * tint[c] as f64),
            ),
        ] {
            let scene = glass_scene(&format!("glass-box-{kind}"), kind, obj, 10.0, tint, ior as f32, 16);
            check(kind, &scene, expected);
        }
        let sigma = [0.0f64, 0.25, 1.0];
        let absorbed = sigma.map(|s| f + (1.0 - f).powi(2) * (-2.0 * s).exp() / (1.0 - f * (-2.0 * s).exp()));
        let absorbing = glass_scene_with("glass-box-absorbing", "dielectric", CUBE_OBJ, 4.0, [1.0; 3], ior as f32, "absorption = [0, 0.25, 1]", 32);
        check("absorbing", &absorbing, absorbed);
        // Rough glass at roughness 0 (GGX alpha 1e-3: microfacets within a milliradian of
        // the surface's normal, whose Fresnel terms and masking differ from the smooth
        // interface's by under 1e-5) follows the same closed forms, through its own
        // sampling, weights and interior.
        let rough = glass_scene_with("rough-box", "rough_dielectric", CUBE_OBJ, 10.0, tint, ior as f32, "roughness = 0", 16);
        assert!(GpuScene::new(ctx, &rough).unwrap().has("HAS_ROUGH_DIELECTRICS"));
        check("rough box", &rough, [0, 1, 2].map(|c| f + (1.0 - f) * (tint[c] as f64).powi(2)));
        let rough =
            glass_scene_with("rough-box-absorbing", "rough_dielectric", CUBE_OBJ, 4.0, [1.0; 3], ior as f32, "roughness = 0\nabsorption = [0, 0.25, 1]", 32);
        check("rough absorbing", &rough, absorbed);
    });
}

/// Light samples through rough glass: a camera looks down at 45° through a narrow field of
/// view at a rough glass floor (the plane y = 0, glass below it) under which a square light
/// (3 × 3, one unit down, shining up) is the only emitter. Every pixel is light that one
/// transmission brings from the light: taken by the light samples, which leave from below
/// the surface, and by the continuations that reach the light, MIS-weighted against them.
/// The expected image mean is computed by the f64 mirror independently: camera rays as
/// the kernels draw them, the floor's transmission sampled by `bsdf::sample` alone, its
/// weight counted where the refracted ray reaches the light. A shadow ray started on the
/// wrong side or a wrong light-sampling weight shows as a difference: light samples whose
/// shadow rays left from the camera's side (so the floor blocked them all) lost their
/// share, 6 % of the image, and failed this test at 25 standard errors. Both distributions
/// of microfacets.
#[test]
fn light_samples_pass_through_rough_glass() {
    for distribution in ["ggx", "beckmann"] {
        light_through_rough_glass(distribution);
    }
}

fn light_through_rough_glass(distribution: &str) {
    use glam::DVec3;
    let dir = common::scenes::temp_dir(&format!("rough-glass-light-{distribution}"));
    std::fs::write(dir.join("floor.obj"), "v -100 0 -100\nv -100 0 100\nv 100 0 100\nv 100 0 -100\nf 1 2 3 4\n").unwrap();
    std::fs::write(dir.join("light.obj"), "v -1.5 -1 -1.5\nv -1.5 -1 1.5\nv 1.5 -1 1.5\nv 1.5 -1 -1.5\nf 1 2 3 4\n").unwrap();
    let (tint, roughness, ior, le, fov) = ([1.0, 0.6, 0.3], 0.5, 1.5, 2.0, 1.0f64);
    let toml = format!(
        "[film]\nwidth = 16\nheight = 16\n[integrator]\nmax_depth = 2\nrr_depth = 5\n\
         [[sensors]]\norigin = [0, 2, 2]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\nfov_y = {fov}\n\
         [[materials]]\nname = \"glass\"\ntype = \"rough_dielectric\"\ndistribution = \"{distribution}\"\nbase_color = [{}, {}, {}]\nroughness = {roughness}\nior = {ior}\n\
         [[materials]]\nname = \"black\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n\
         [[meshes]]\nfile = \"floor.obj\"\nmaterial = \"glass\"\n[[meshes]]\nfile = \"light.obj\"\nmaterial = \"black\"\nemission = [{le}, {le}, {le}]\n",
        tint[0], tint[1], tint[2]
    );
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    let scene = Scene::load(dir.join("scene.toml")).unwrap();
    let img = with_gpu(|ctx| PrimalRenderer::new(GpuScene::new(ctx, &scene).unwrap()).unwrap().render(0, 64, 9, |_, _| {}).unwrap());

    // The reference: E[weight · (the refracted ray reaches the light)] · le over uniform
    // points of the film (the camera of `camera_ray`: square film, so aspect 1).
    let m = vkinverse::bsdf::MaterialF64 {
        base_color: DVec3::from_array(tint),
        roughness,
        metallic: 0.0,
        kind: if distribution == "ggx" { vkinverse::shared::MATERIAL_ROUGH_DIELECTRIC } else { vkinverse::shared::MATERIAL_ROUGH_DIELECTRIC_BECKMANN },
        ior,
        ..Default::default()
    };
    let reference = floor_reference(fov, |p, d, u| match vkinverse::bsdf::sample(&m, DVec3::Y, -d, u) {
        Some(s) if s.wi.y < 0.0 => {
            let q = p + (-1.0 / s.wi.y) * s.wi;
            if q.x.abs() < 1.5 && q.z.abs() < 1.5 {
                s.weight * le
            } else {
                DVec3::ZERO
            }
        }
        _ => DVec3::ZERO,
    });
    check_image_mean(distribution, &img, reference, 0.05);
}

/// The expected image mean of the camera of the floor tests (at (0, 2, 2), looking at the
/// origin through a square film `fov` degrees wide) from the f64 mirror: the mean of
/// `value(p, d, u)` over 400 000 uniform points of the film as the kernels draw camera
/// rays, d the ray's direction, p where it meets the plane y = 0 and u three uniform
/// numbers; and its standard error, per channel.
fn floor_reference(fov: f64, value: impl Fn(glam::DVec3, glam::DVec3, glam::DVec3) -> glam::DVec3) -> (glam::DVec3, glam::DVec3) {
    use glam::DVec3;
    let origin = DVec3::new(0.0, 2.0, 2.0);
    let forward = (-origin).normalize();
    let right = forward.cross(DVec3::Y).normalize();
    let up = right.cross(forward);
    let tan_half = (0.5 * fov).to_radians().tan();
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    const SAMPLES: usize = 400_000;
    let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
    for _ in 0..SAMPLES {
        let (x, y) = (2.0 * uniform() - 1.0, 2.0 * uniform() - 1.0);
        let d = (forward + x * tan_half * right + y * tan_half * up).normalize();
        let p = origin + (-origin.y / d.y) * d;
        let v = value(p, d, DVec3::new(uniform(), uniform(), uniform()));
        sum += v;
        sum2 += v * v;
    }
    let n = SAMPLES as f64;
    let mean = sum / n;
    (mean, ((sum2 / n - mean * mean) / (n - 1.0)).max(DVec3::ZERO).sqrt())
}

/// Asserts that each channel's mean over `img` is the `reference` (mean, standard error)
/// within 5 standard errors of their difference, and the reference at least `least`.
fn check_image_mean(what: &str, img: &Image, (mean_cpu, se_cpu): (glam::DVec3, glam::DVec3), least: f64) {
    for c in 0..3 {
        let v: Vec<f64> = img.data.iter().map(|p| p[c] as f64).collect();
        let k = v.len() as f64;
        let mean = v.iter().sum::<f64>() / k;
        let se = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (k - 1.0) / k).sqrt();
        let tol = 5.0 * (se * se + se_cpu[c] * se_cpu[c]).sqrt();
        eprintln!("{what}, channel {c}: image mean {mean:.5} ± {se:.1e}, reference {:.5} ± {:.1e}", mean_cpu[c], se_cpu[c]);
        assert!(mean_cpu[c] > least, "{what}, channel {c}: the light must reach the camera");
        assert!((mean - mean_cpu[c]).abs() <= tol, "{what}, channel {c}: image mean {mean} against the reference {} (tolerance {tol:e})", mean_cpu[c]);
    }
}

/// A conductor's reflection through the whole renderer: a camera looks down at 45° through
/// a narrow field of view at a rough conductor floor (the plane y = 0) whose mirror
/// direction meets a square light (2 × 3, one unit up, shining down), the only emitter.
/// Every pixel is light that one reflection brings from the light, by light samples and
/// by continuations, MIS-weighted. The expected image mean comes from the f64 mirror alone,
/// as in `light_samples_pass_through_rough_glass`: camera rays as the kernels draw them,
/// the floor's reflection sampled by `bsdf::sample`, its weight counted where the reflected
/// ray reaches the light. Each channel has its own complex index (a dielectric's 1.5 + 0i,
/// a metal's 0.2 + 3i, 3 + 1i) and tint, so an index that did not reach the kernels (the
/// scene records' eta and k) or reached them in the wrong channel would show. The scene
/// has no principled material, so the kernels keep the conductor alone. Both
/// distributions of microfacets.
#[test]
fn light_reflects_off_conductors() {
    use glam::DVec3;
    for distribution in ["ggx", "beckmann"] {
        let dir = common::scenes::temp_dir(&format!("conductor-light-{distribution}"));
        std::fs::write(dir.join("floor.obj"), "v -100 0 -100\nv -100 0 100\nv 100 0 100\nv 100 0 -100\nf 1 2 3 4\n").unwrap();
        std::fs::write(dir.join("light.obj"), "v -1 1 -2.5\nv 1 1 -2.5\nv 1 1 -0.5\nv -1 1 -0.5\nf 1 2 3 4\n").unwrap();
        let (tint, roughness, eta, k, le, fov) = ([0.9, 0.7, 1.0], 0.3, [1.5, 0.2, 3.0], [0.0, 3.0, 1.0], 2.0, 1.0f64);
        let v3 = |v: [f64; 3]| format!("[{}, {}, {}]", v[0], v[1], v[2]);
        let toml = format!(
            "[film]\nwidth = 16\nheight = 16\n[integrator]\nmax_depth = 2\nrr_depth = 5\n\
             [[sensors]]\norigin = [0, 2, 2]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\nfov_y = {fov}\n\
             [[materials]]\nname = \"metal\"\ntype = \"conductor\"\ndistribution = \"{distribution}\"\nbase_color = {}\nroughness = {roughness}\neta = {}\nk = {}\n\
             [[materials]]\nname = \"black\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n\
             [[meshes]]\nfile = \"floor.obj\"\nmaterial = \"metal\"\n[[meshes]]\nfile = \"light.obj\"\nmaterial = \"black\"\nemission = [{le}, {le}, {le}]\n",
            v3(tint), v3(eta), v3(k)
        );
        std::fs::write(dir.join("scene.toml"), toml).unwrap();
        let scene = Scene::load(dir.join("scene.toml")).unwrap();
        let img = with_gpu(|ctx| {
            let gs = GpuScene::new(ctx, &scene).unwrap();
            assert!(gs.has("HAS_CONDUCTORS") && !gs.has("HAS_PRINCIPLED") && !gs.has("HAS_DIELECTRICS"));
            PrimalRenderer::new(gs).unwrap().render(0, 64, 9, |_, _| {}).unwrap()
        });

        let m = vkinverse::bsdf::MaterialF64 {
            base_color: DVec3::from_array(tint),
            roughness,
            kind: if distribution == "ggx" { vkinverse::shared::MATERIAL_CONDUCTOR } else { vkinverse::shared::MATERIAL_CONDUCTOR_BECKMANN },
            eta: DVec3::from_array(eta),
            k: DVec3::from_array(k),
            ..Default::default()
        };
        let reference = floor_reference(fov, |p, d, u| match vkinverse::bsdf::sample(&m, DVec3::Y, -d, u) {
            Some(s) => {
                let q = p + ((1.0 - p.y) / s.wi.y) * s.wi;
                if q.x.abs() < 1.0 && (-2.5..-0.5).contains(&q.z) {
                    s.weight * le
                } else {
                    DVec3::ZERO
                }
            }
            None => DVec3::ZERO,
        });
        check_image_mean(distribution, &img, reference, 0.02);
    }
}

/// A plastic's light through the whole renderer: the scene of
/// `light_reflects_off_conductors` with a plastic floor (GGX and linear, then Beckmann
/// and nonlinear), which reflects the light glossily off its coating and diffusely from
/// its base, by light samples and continuations, MIS-weighted. The expected image mean
/// comes from the f64 mirror with the coating that `bsdf::coating` tabulates, so a table
/// that did not reach the kernels (its place in the material data), an internal
/// reflectance or an index that did not, would show. The scene has no principled material.
#[test]
fn light_reflects_off_plastics() {
    use glam::DVec3;
    for (distribution, nonlinear) in [("ggx", false), ("beckmann", true)] {
        let dir = common::scenes::temp_dir(&format!("plastic-light-{distribution}"));
        std::fs::write(dir.join("floor.obj"), "v -100 0 -100\nv -100 0 100\nv 100 0 100\nv 100 0 -100\nf 1 2 3 4\n").unwrap();
        std::fs::write(dir.join("light.obj"), "v -1 1 -2.5\nv 1 1 -2.5\nv 1 1 -0.5\nv -1 1 -0.5\nf 1 2 3 4\n").unwrap();
        let (base, roughness, ior, le, fov) = ([0.8, 0.4, 0.1], 0.3f32, 1.6f32, 2.0, 1.0f64);
        let toml = format!(
            "[film]\nwidth = 16\nheight = 16\n[integrator]\nmax_depth = 2\nrr_depth = 5\n\
             [[sensors]]\norigin = [0, 2, 2]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\nfov_y = {fov}\n\
             [[materials]]\nname = \"plastic\"\ntype = \"plastic\"\ndistribution = \"{distribution}\"\nbase_color = [{}, {}, {}]\nroughness = {roughness}\nior = {ior}\nnonlinear = {nonlinear}\n\
             [[materials]]\nname = \"black\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n\
             [[meshes]]\nfile = \"floor.obj\"\nmaterial = \"plastic\"\n[[meshes]]\nfile = \"light.obj\"\nmaterial = \"black\"\nemission = [{le}, {le}, {le}]\n",
            base[0], base[1], base[2]
        );
        std::fs::write(dir.join("scene.toml"), toml).unwrap();
        let scene = Scene::load(dir.join("scene.toml")).unwrap();
        let img = with_gpu(|ctx| {
            let gs = GpuScene::new(ctx, &scene).unwrap();
            assert!(gs.has("HAS_PLASTICS") && !gs.has("HAS_PRINCIPLED") && !gs.has("HAS_CONDUCTORS") && !gs.has("HAS_DIELECTRICS"));
            PrimalRenderer::new(gs).unwrap().render(0, 64, 9, |_, _| {}).unwrap()
        });

        let beckmann = distribution == "beckmann";
        let (transmittance, internal) = vkinverse::bsdf::coating(beckmann, f64::from(roughness), f64::from(ior));
        let m = vkinverse::bsdf::MaterialF64 {
            base_color: DVec3::from_array(base),
            roughness: f64::from(roughness),
            kind: if beckmann { vkinverse::shared::MATERIAL_PLASTIC_BECKMANN } else { vkinverse::shared::MATERIAL_PLASTIC },
            ior: f64::from(ior),
            transmittance: vkinverse::bsdf::Table(transmittance),
            internal,
            nonlinear,
            specular: DVec3::ONE,
            ..Default::default()
        };
        let reference = floor_reference(fov, |p, d, u| match vkinverse::bsdf::sample(&m, DVec3::Y, -d, u) {
            Some(s) if s.wi.y > 0.0 => {
                let q = p + ((1.0 - p.y) / s.wi.y) * s.wi;
                if q.x.abs() < 1.0 && (-2.5..-0.5).contains(&q.z) {
                    s.weight * le
                } else {
                    DVec3::ZERO
                }
            }
            _ => DVec3::ZERO,
        });
        check_image_mean(distribution, &img, reference, 0.005);
    }
}

/// Checks that the mean of `scene`'s image over the environment's radiance is `expected`
/// per channel, within 5 standard errors of its pixels (64 spp each).
fn check_glass_mean(ctx: &std::sync::Arc<vkinverse::gpu::Context>, what: &str, scene: &Scene, expected: [f64; 3]) {
    let img = PrimalRenderer::new(GpuScene::new(ctx, scene).unwrap()).unwrap().render(0, 64, 5, |_, _| {}).unwrap();
    for c in 0..3 {
        let v: Vec<f64> = img.data.iter().map(|p| p[c] as f64 / ENV[c] as f64).collect();
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let se = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt();
        let expected = expected[c];
        assert!((mean - expected).abs() <= 5.0 * se + 2e-4, "{what}, channel {c}: mean {mean} expected {expected} (se {se})");
    }
}
