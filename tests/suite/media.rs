//! Media: a box of emitting and absorbing medium (glsl/lib/media.glsl) against closed forms,
//! its gradients against closed forms and central differences, stiff values, grids as
//! `.npy` or Mitsuba `.vol` files, and grids written back with the recovered scene.

use crate::common;

use std::path::Path;

use common::scenes::temp_dir;
use common::{device, with_gpu};
use vkinverse::npy::{self, Array};
use vkinverse::scene::GridFormat;
use vkinverse::vol::{self, Grid};
use vkinverse::{Image, RenderOptions, Renderer, Scene};

const BG: [f32; 3] = [0.2, 0.4, 0.6];

/// A scene of one medium box [-1, 1]² × [-d/2, d/2] seen along −z by an orthographic camera
/// whose view lies inside the box's x, y extent, in front of a constant environment BG:
/// every ray crosses depth d. `medium` holds the medium's keys after its box; `files` are
/// written beside the scene.
fn slab(name: &str, d: f32, film: u32, medium: &str, files: &[(&str, Array)], optimise: &str) -> Scene {
    slab_with(name, d, film, medium, optimise, |dir| {
        for (file, array) in files {
            npy::write(&dir.join(file), array).unwrap();
        }
    })
}

/// [`slab`] with the files that `write` puts in the scene's directory.
fn slab_with(name: &str, d: f32, film: u32, medium: &str, optimise: &str, write: impl FnOnce(&Path)) -> Scene {
    let dir = temp_dir(name);
    write(&dir);
    let toml = format!(
        "[film]\nwidth = {film}\nheight = {film}\n[integrator]\nmax_depth = 2\n\
         [[sensors]]\norigin = [0, 0, 5]\ntarget = [0, 0, 0]\northo_height = 1.0\n\
         [environment]\nconstant = [{}, {}, {}]\n\
         [[media]]\nname = \"slab\"\nmin = [-1, -1, {}]\nmax = [1, 1, {}]\n{medium}\n{optimise}",
        BG[0],
        BG[1],
        BG[2],
        -d / 2.0,
        d / 2.0
    );
    let path = dir.join("scene.toml");
    std::fs::write(&path, toml).unwrap();
    Scene::load(&path).unwrap()
}

fn render(scene: &Scene, spp: u32) -> Image {
    with_gpu(|ctx| Renderer::new(&device(ctx), scene).unwrap().render(&RenderOptions { spp, seed: 5, ..Default::default() }).unwrap())
}

fn mean(image: &Image) -> [f64; 3] {
    let n = image.data.len() as f64;
    [0, 1, 2].map(|c| image.data.iter().map(|p| p[c] as f64).sum::<f64>() / n)
}

fn assert_close(what: &str, got: f64, want: f64, rel: f64) {
    assert!((got - want).abs() <= rel * want.abs(), "{what}: {got} against {want} (relative {:.2e}, allowed {rel:.0e})", (got - want).abs() / want.abs());
}

/// A slab of constant σ keeps e^(−σd) of the background, to 1e-5 in every pixel; with
/// emission it adds L_e (1 − e^(−σd)). The march has several steps of unequal jitter per
/// pixel: the product of their factors is the closed form whatever the jitter.
#[test]
fn a_constant_slab_transmits_and_emits_in_closed_form() {
    let (sigma, d) = (1.5f64, 1.0f64);
    let t = (-sigma * d).exp();
    for (name, le) in [("transmittance", [0.0f32; 3]), ("emission", [2.0, 1.0, 0.5])] {
        let medium = format!("density = 0.75\nscale = 2.0\nstep = 0.3\nemission = [{}, {}, {}]", le[0], le[1], le[2]);
        let image = render(&slab(name, d as f32, 8, &medium, &[], ""), 2);
        for p in &image.data {
            for c in 0..3 {
                let want = le[c] as f64 * (1.0 - t) + t * BG[c] as f64;
                assert_close(&format!("{name} channel {c}"), p[c] as f64, want, 1e-5);
            }
        }
    }
}

/// A density that rises linearly along the rays (16 voxels in z): the optical depth is the
/// integral of the trilinear lookup, linear between the first and last voxel centres and
/// constant for the half voxel beyond each. The stratified march estimates it without
/// bias; the mean transmittance over 8×8 pixels × 4 samples is within 1e-3 of e^(−τ).
#[test]
fn a_density_ramp_matches_its_closed_form() {
    let n = 16;
    let v: Vec<f32> = (0..n).map(|i| 0.1 + 0.2 * i as f32).collect();
    let h = 1.0 / n as f64;
    let ends = h / 2.0 * (v[0] as f64 + v[n - 1] as f64);
    let inner: f64 = (0..n - 1).map(|i| h * (v[i] as f64 + v[i + 1] as f64) / 2.0).sum();
    let tau = ends + inner;
    let grid = Array { shape: vec![n, 1, 1], data: v };
    let image = render(&slab("ramp", 1.0, 8, "density = \"ramp.npy\"\nstep = 0.1", &[("ramp.npy", grid)], ""), 4);
    let m = mean(&image);
    for c in 0..3 {
        assert_close(&format!("channel {c}"), m[c], (-tau).exp() * BG[c] as f64, 1e-3);
    }
}

/// The gradient of a density grid whose voxels are all σ, summed over the voxels, is the
/// closed form d·e^(−σd)(L_e − L_bg) per unit adjoint (times the scale), and the emission
/// grid's is 1 − e^(−σd); both to 1e-4.
#[test]
fn the_gradients_of_constant_grids_are_closed_form() {
    let (density, scale, d) = (0.6f64, 2.0f64, 0.8f64);
    let sigma = density * scale;
    let le = [1.5f64, 0.5, 0.1];
    let optimise = format!(
        "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = {density}\nrange = [0, 10]\ngrid = [2, 3, 2]\n\
         [[optimise.params]]\ntarget = \"media.slab.emission\"\ninit = [{}, {}, {}]\nrange = [0, 10]\ngrid = [3, 2, 2]\n",
        le[0], le[1], le[2]
    );
    // (A renderer starts at the scene's own values: the same as the parameters' start.)
    let medium = format!("density = {density}\nemission = [{}, {}, {}]\nscale = 2.0\nstep = 0.25", le[0], le[1], le[2]);
    let scene = slab("constant-grad", d as f32, 6, &medium, &[], &optimise);
    let grads = with_gpu(|ctx| {
        let r = Renderer::new(&device(ctx), &scene).unwrap();
        let adjoint = Image { width: 6, height: 6, data: vec![[1.0; 3]; 36] };
        r.gradient(&adjoint, &RenderOptions { spp: 2, seed: 1, ..Default::default() }).unwrap()
    });
    let pixels = 36.0;
    let t = (-sigma * d).exp();
    let want_density: f64 = (0..3).map(|c| pixels * scale * d * t * (le[c] - BG[c] as f64)).sum();
    let density_grad: f64 = grads[0].1.data.iter().map(|&g| g as f64).sum();
    assert_eq!(grads[0].1.data.len(), 12);
    assert_close("density", density_grad, want_density, 1e-4);
    for c in 0..3 {
        let g: f64 = grads[1].1.data.iter().skip(c).step_by(3).map(|&g| g as f64).sum();
        assert_close(&format!("emission channel {c}"), g, pixels * (1.0 - t), 1e-4);
    }
}

/// A random number in [0, 1) from a counter (xorshift-multiply), for test data.
fn hashed(i: u64) -> f32 {
    let mut x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x5851_F42D_4C95_7F2D;
    x ^= x >> 29;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 32;
    (x >> 40) as f32 / (1u64 << 24) as f32
}

/// A perspective view of a random 8³ medium (density and emission) over a lit diffuse
/// floor, with a point light and an area light whose shadow rays cross it: the
/// adjoint's directional derivative along a random direction against the central
/// difference of the same estimator (same seed and paths: diffuse sampling and no
/// Russian roulette), to 1e-3.
#[test]
fn the_adjoint_matches_central_differences_on_a_random_grid() {
    random_grid_case("volume", false, false, false);
    random_grid_case("lit", true, true, true);
}

fn random_grid_case(name: &str, floor: bool, bulb: bool, lamp: bool) {
    let dir = temp_dir(&format!("random-grid-{name}"));
    let n = 8usize;
    let density = Array { shape: vec![n, n, n], data: (0..n * n * n).map(|i| 0.2 + 1.8 * hashed(i as u64)).collect() };
    let emission = Array { shape: vec![n, n, n, 3], data: (0..n * n * n * 3).map(|i| 0.05 + 0.5 * hashed(1000 + i as u64)).collect() };
    npy::write(&dir.join("density.npy"), &density).unwrap();
    npy::write(&dir.join("emission.npy"), &emission).unwrap();
    std::fs::write(dir.join("floor.obj"), "v -3 -1 -3\nv 3 -1 -3\nv 3 -1 3\nv -3 -1 3\nf 1 3 2\nf 1 4 3\n").unwrap();
    std::fs::write(dir.join("lamp.obj"), "v -0.5 3 -0.5\nv 0.5 3 -0.5\nv 0.5 3 0.5\nv -0.5 3 0.5\nf 1 2 3\nf 1 3 4\n").unwrap();
    let mut toml = "[film]\nwidth = 12\nheight = 12\n[integrator]\nmax_depth = 3\n\
                [[sensors]]\norigin = [0.6, 1.4, 4]\ntarget = [0, -0.2, 0]\nfov_y = 40\n\
                [environment]\nconstant = [0.1, 0.2, 0.3]\n\
                [[media]]\nname = \"cloud\"\nmin = [-1, -0.8, -1]\nmax = [1, 0.8, 1]\ndensity = \"density.npy\"\nemission = \"emission.npy\"\nstep = 0.7\n\
                [[optimise.params]]\ntarget = \"media.cloud.density\"\ninit = 1.0\nrange = [0, 10]\n\
                [[optimise.params]]\ntarget = \"media.cloud.emission\"\ninit = 0.2\nrange = [0, 10]\n"
        .to_string();
    toml += "[[materials]]\nname = \"floor\"\ntype = \"diffuse\"\nbase_color = [0.6, 0.5, 0.4]\n[[materials]]\nname = \"lamp\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n";
    if floor {
        toml += "[[meshes]]\nname = \"floor\"\nfile = \"floor.obj\"\nmaterial = \"floor\"\n";
    }
    if lamp {
        toml += "[[meshes]]\nname = \"lamp\"\nfile = \"lamp.obj\"\nmaterial = \"lamp\"\nemission = [4, 4, 4]\n";
    }
    if bulb {
        toml += "[[lights]]\nname = \"bulb\"\ntype = \"point\"\nposition = [1.5, 2, 1]\ncolor = [1, 1, 1]\nintensity = 6\n";
    }
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    let scene = Scene::load(dir.join("scene.toml")).unwrap();
    with_gpu(|ctx| {
        let mut r = Renderer::new(&device(ctx), &scene).unwrap();
        let names = ["media.cloud.density", "media.cloud.emission"];
        // The scene's own grids as the point, a random direction of every element.
        let base: Vec<Vec<f32>> = vec![density.data.clone(), emission.data.clone()];
        let dirs: Vec<Vec<f32>> =
            base.iter().enumerate().map(|(k, b)| (0..b.len()).map(|i| hashed(50_000 * (k as u64 + 1) + i as u64) - 0.5).collect()).collect();
        let adjoint = Image { width: 12, height: 12, data: (0..144).map(|i| [0, 1, 2].map(|c| hashed(90_000 + 3 * i + c) - 0.3)).collect() };
        let options = RenderOptions { spp: 2, seed: 11, ..Default::default() };
        let dot_adjoint =
            |img: &Image| -> f64 { img.data.iter().zip(&adjoint.data).map(|(p, a)| (0..3).map(|c| p[c] as f64 * a[c] as f64).sum::<f64>()).sum() };
        let set = |r: &mut Renderer, h: f32| {
            for (k, name) in names.iter().enumerate() {
                let v: Vec<f32> = base[k].iter().zip(&dirs[k]).map(|(b, d)| b + h * d).collect();
                r.set_param(name, &v).unwrap();
            }
        };
        set(&mut r, 0.0);
        let grads = r.gradient(&adjoint, &options).unwrap();
        let along: f64 = grads.iter().zip(&dirs).map(|((_, g), d)| g.data.iter().zip(d).map(|(&g, &d)| g as f64 * d as f64).sum::<f64>()).sum();
        let h = 2e-3;
        set(&mut r, h);
        // The adjoint pass's own paths: its seed is the options' plus SEED_ADJOINT.
        let paths = RenderOptions { seed: options.seed + vkinverse::render::gradient::SEED_ADJOINT as u64, ..options };
        let plus = dot_adjoint(&r.render(&paths).unwrap());
        set(&mut r, -h);
        let minus = dot_adjoint(&r.render(&paths).unwrap());
        let fd = (plus - minus) / (2.0 * h as f64);
        assert!(along.abs() > 1e-3, "the direction moves the loss: {along}");
        assert_close(&format!("{name}: adjoint along a random direction"), along, fd, 1e-3);
    });
}

/// σ·Δ of 1e4 per step, voxels of σ = 0 beside it, and a density at the top of its range:
/// the image and the gradients stay finite, and an opaque slab shows its emission alone.
#[test]
fn stiff_media_stay_finite() {
    let n = 4usize;
    // Alternate slices of z: 0 and 1e5 (σ·Δ = 1e5 × 0.125 × 1 voxel ≈ 1e4).
    let density = Array { shape: vec![n, 2, 2], data: (0..n * 4).map(|i| if (i / 4) % 2 == 0 { 0.0 } else { 1e5 }).collect() };
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 1e5\nrange = [0, 1e5]\ngrid = [2, 2, 4]\n\
                    [[optimise.params]]\ntarget = \"media.slab.emission\"\ninit = 0.5\nrange = [0, 1]\n";
    let scene = slab("stiff", 0.5, 4, "density = \"stiff.npy\"\nemission = 0.5\nstep = 1.0", &[("stiff.npy", density.clone())], optimise);
    with_gpu(|ctx| {
        let mut r = Renderer::new(&device(ctx), &scene).unwrap();
        let options = RenderOptions { spp: 2, seed: 3, ..Default::default() };
        let adjoint = Image { width: 4, height: 4, data: vec![[1.0; 3]; 16] };
        for values in [density.data.clone(), vec![1e5; 16], vec![0.0; 16]] {
            r.set_param("media.slab.density", &values).unwrap();
            let image = r.render(&options).unwrap();
            assert!(image.data.iter().flatten().all(|v| v.is_finite()), "{values:?}: {:?}", image.data);
            let grads = r.gradient(&adjoint, &options).unwrap();
            assert!(grads.iter().all(|(_, g)| g.data.iter().all(|v| v.is_finite())), "{values:?}: {grads:?}");
            if values[0] == 1e5 {
                // Opaque from the first step on: the emission alone.
                for v in image.data.iter().flatten() {
                    assert_close("opaque slab", *v as f64, 0.5, 1e-6);
                }
            }
        }
    });
}

/// A recovered medium goes out with the recovered scene: its grids as `.npy` files that the
/// written `scene.toml` names, which load back to the same values.
#[test]
fn media_grids_round_trip_through_the_recovered_scene() {
    let n = 3usize;
    let density = Array { shape: vec![n, n, n], data: (0..27).map(|i| hashed(i) * 2.0).collect() };
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.emission\"\ninit = [0.1, 0.2, 0.3]\nrange = [0, 1]\ngrid = [2, 1, 2]\n";
    let scene = slab("round-trip", 1.0, 4, "density = \"d.npy\"\nscale = 3.0\nstep = 0.25", &[("d.npy", density.clone())], optimise);
    let out = temp_dir("round-trip-out");
    let emission = vkinverse::ParamValue::new(vkinverse::Shape::grid(2, 1, 2, 3), (0..12).map(|i| i as f32 / 12.0).collect()).unwrap();
    let target = scene.optimise.params[0].target;
    vkinverse::scene::write::write_final(&out, &scene, &[(target, emission.clone())]).unwrap();
    let back = Scene::load(out.join("final/scene.toml")).unwrap();
    let m = &back.media[0];
    assert_eq!(m.density.data, density.data);
    assert_eq!(m.density.shape.array(), vec![3, 3, 3, 1]);
    assert_eq!(m.emission, emission);
    assert_eq!((m.scale, m.step, m.min, m.max), (3.0, 0.25, [-1.0, -1.0, -0.5], [1.0, 1.0, 0.5]));
}

/// `array` (shape [z, y, x] or [z, y, x, c]) as a `.vol` grid over the unit box.
fn as_vol(array: &Array) -> Grid {
    let channels = if array.shape.len() == 4 { array.shape[3] } else { 1 } as u32;
    let size = [array.shape[2], array.shape[1], array.shape[0]].map(|s| s as u32);
    Grid { size, channels, bbox: [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], data: array.data.clone() }
}

/// A random 5 × 4 × 3 density and 3 × 2 × 4 emission, the same values in either format.
fn random_grids() -> (Array, Array) {
    let density = Array { shape: vec![3, 4, 5], data: (0..60).map(|i| 0.1 + 2.0 * hashed(7000 + i)).collect() };
    let emission = Array { shape: vec![4, 2, 3, 3], data: (0..72).map(|i| 0.05 + hashed(8000 + i)).collect() };
    (density, emission)
}

/// The same grids as Mitsuba `.vol` files and as `.npy` arrays load to the same medium
/// (x fastest in both) and render the same image, bit for bit.
#[test]
fn vol_grids_load_and_render_as_their_npy_twins() {
    let (density, emission) = random_grids();
    let keys = |ext: &str| format!("density = \"d.{ext}\"\nemission = \"e.{ext}\"\nscale = 1.5\nstep = 0.4");
    let from_npy = slab("twin-npy", 1.0, 8, &keys("npy"), &[("d.npy", density.clone()), ("e.npy", emission.clone())], "");
    let from_vol = slab_with("twin-vol", 1.0, 8, &keys("VOL"), "", |dir| {
        vol::write(&dir.join("d.VOL"), &as_vol(&density)).unwrap();
        vol::write(&dir.join("e.VOL"), &as_vol(&emission)).unwrap();
    });
    let (a, b) = (&from_npy.media[0], &from_vol.media[0]);
    assert_eq!((&a.density, &a.emission), (&b.density, &b.emission));
    assert_eq!(a.density.shape, vkinverse::Shape::grid(5, 4, 3, 1));
    assert_eq!((a.formats, b.formats), ([GridFormat::Npy; 3], [GridFormat::Vol, GridFormat::Vol, GridFormat::Npy]));
    assert_eq!(from_npy.content_hash(), from_vol.content_hash(), "the format is not the content");
    assert!(render(&from_npy, 2) == render(&from_vol, 2), "the images differ");
}

/// A grid's channels must be the value's: one for a density, three for an emission.
#[test]
fn vol_grids_of_the_wrong_channels_are_refused() {
    let (density, emission) = random_grids();
    for (key, file, grid, needle) in [
        ("density", "e.vol", as_vol(&emission), "has 3 channels; a density has 1"),
        ("emission", "d.vol", as_vol(&density), "has 1 channel; an emission or an albedo has 3"),
    ] {
        let dir = temp_dir(&format!("channels-{key}"));
        vol::write(&dir.join(file), &grid).unwrap();
        let density = if key == "emission" { "density = 1.0\n" } else { "" };
        let toml = format!(
            "[film]\nwidth = 4\nheight = 4\n[[sensors]]\norigin = [0, 0, 5]\ntarget = [0, 0, 0]\nfov_y = 40\n\
             [[media]]\nname = \"fog\"\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n{density}{key} = \"{file}\"\n"
        );
        std::fs::write(dir.join("scene.toml"), toml).unwrap();
        let err = Scene::load(dir.join("scene.toml")).unwrap_err().to_string();
        assert!(err.contains(&format!("media.fog.{key}")) && err.contains(file) && err.contains(needle) && !err.contains('\n'), "{err}");
    }
}

/// Grids that came as `.vol` files go back as `.vol` files (their bounding box the
/// medium's), and the recovered scene loads back to the same medium.
#[test]
fn vol_grids_round_trip_through_the_recovered_scene() {
    let (density, emission) = random_grids();
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 1.0\nrange = [0, 10]\n";
    let medium = "density = \"d.vol\"\nemission = \"e.vol\"\nscale = 2.0\nstep = 0.3";
    let scene = slab_with("vol-round-trip", 1.0, 4, medium, optimise, |dir| {
        vol::write(&dir.join("d.vol"), &as_vol(&density)).unwrap();
        vol::write(&dir.join("e.vol"), &as_vol(&emission)).unwrap();
    });
    let out = temp_dir("vol-round-trip-out");
    // The recovered density at the grid's own resolution, every voxel changed.
    let recovered = vkinverse::ParamValue::new(vkinverse::Shape::grid(5, 4, 3, 1), density.data.iter().map(|v| v * 0.5 + 0.125).collect()).unwrap();
    let target = scene.optimise.params[0].target;
    vkinverse::scene::write::write_final(&out, &scene, &[(target, recovered.clone())]).unwrap();
    let grids = out.join("final/grids");
    let mut names: Vec<String> = std::fs::read_dir(&grids).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["slab.density.vol", "slab.emission.vol"]);
    let written = vol::read(&grids.join("slab.density.vol")).unwrap();
    assert_eq!((written.size, written.channels, written.bbox), ([5, 4, 3], 1, [-1.0, -1.0, -0.5, 1.0, 1.0, 0.5]));
    let back = Scene::load(out.join("final/scene.toml")).unwrap();
    let m = &back.media[0];
    assert_eq!(m.density, recovered);
    assert_eq!(m.emission, scene.media[0].emission);
    assert_eq!(m.formats, [GridFormat::Vol, GridFormat::Vol, GridFormat::Npy]);
    assert_eq!((m.scale, m.step, m.min, m.max), (2.0, 0.3, [-1.0, -1.0, -0.5], [1.0, 1.0, 0.5]));
    // Written again, it stays .vol and equal.
    let again = temp_dir("vol-round-trip-again");
    vkinverse::scene::write::write_final(&again, &back, &[]).unwrap();
    assert_eq!(Scene::load(again.join("final/scene.toml")).unwrap().media, back.media);
}

/// `rounds` gradients of the image sum (a unit adjoint) with respect to every element of
/// the first parameter, summed, one seed each: their mean and standard error.
fn gradient_rounds(scene: &Scene, spp: u32, rounds: u64) -> (f64, f64) {
    with_gpu(|ctx| renderer_gradient_rounds(&Renderer::new(&device(ctx), scene).unwrap(), spp, rounds))
}

/// [`gradient_rounds`] of a renderer at its parameters.
fn renderer_gradient_rounds(r: &Renderer, spp: u32, rounds: u64) -> (f64, f64) {
    let (w, h) = (r.scene().film.width, r.scene().film.height);
    let adjoint = Image { width: w, height: h, data: vec![[1.0; 3]; (w * h) as usize] };
    let sums: Vec<f64> = (0..rounds)
        .map(|seed| r.gradient(&adjoint, &RenderOptions { spp, seed, ..Default::default() }).unwrap()[0].1.data.iter().map(|&g| g as f64).sum())
        .collect();
    let n = sums.len() as f64;
    let mean = sums.iter().sum::<f64>() / n;
    let var = sums.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// The uniform sky of the scattering slabs below.
const SKY: f64 = 0.5;

/// A slab of scattering medium (density 2 across a thickness of 1, g 0.4, albedo `albedo`
/// as TOML) under a uniform sky of `SKY`, seen by an orthographic 8 × 8 camera, depth 64,
/// with `optimise` appended.
fn scattering_slab_under_sky(name: &str, albedo: &str, optimise: &str) -> Scene {
    let dir = temp_dir(name);
    let toml = format!(
        "[film]\nwidth = 8\nheight = 8\n[integrator]\nmax_depth = 64\n\
         [[sensors]]\norigin = [0, 0, 5]\ntarget = [0, 0, 0]\northo_height = 1.0\n\
         [environment]\nconstant = [{SKY}, {SKY}, {SKY}]\n\
         [[media]]\nname = \"slab\"\nmin = [-1, -1, -0.5]\nmax = [1, 1, 0.5]\ndensity = 2.0\nalbedo = {albedo}\ng = 0.4\n{optimise}"
    );
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    Scene::load(dir.join("scene.toml")).unwrap()
}

/// Channel `c`'s mean over the pixels and its standard error from their spread.
fn channel_mean_and_se(image: &Image, c: usize) -> (f64, f64) {
    let values: Vec<f64> = image.data.iter().map(|p| p[c] as f64).collect();
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    (mean, (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt())
}

/// A scattering medium of albedo 1 under a uniform sky (a furnace): every path ends in the
/// sky, so the image is the sky's radiance whatever the density, and the density's
/// gradient is zero. Both within 4 standard errors, over paths of up to 64 collisions
/// (Russian roulette from the fifth); the gradient's terms are not zero one by one (each
/// path's weight moves with the density where it was sampled), so a missing collision term
/// shows as a large negative mean.
#[test]
fn a_white_scattering_medium_under_a_uniform_sky_is_a_furnace() {
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 2.0\nrange = [0, 10]\n";
    let scene = scattering_slab_under_sky("furnace", "1.0", optimise);
    let image = render(&scene, 256);
    let (mean, se) = channel_mean_and_se(&image, 0);
    assert!((mean - SKY).abs() <= 4.0 * se + 1e-6, "furnace: mean {mean} against the sky's {SKY} (standard error {se:.2e})");
    assert!(se < 0.01 * SKY, "the test resolves a 4 % error: standard error {se:.2e}");
    let (g, g_se) = gradient_rounds(&scene, 16, 12);
    println!("furnace: gradient {g} ± {g_se:.2e}");
    assert!(g.abs() <= 4.0 * g_se, "furnace: the density's gradient {g} ± {g_se:.2e} is not zero");
    // Without the collisions' term, the gradient would be minus the image (96) times
    // the mean length of a path in the medium.
    assert!(g_se < 1.0, "the gradient's standard error {g_se} resolves 1 % of the image's sum");
}

/// A coloured albedo scatters each channel by its own: with albedo [1, 1, 0] under a
/// uniform sky, red and green are a furnace (the sky), and blue keeps only the light that
/// crossed without a collision, e^(−σd) of the sky; each within 4 standard errors.
#[test]
fn a_coloured_albedo_scatters_each_channel_by_its_own() {
    let scene = scattering_slab_under_sky("coloured-albedo", "[1, 1, 0]", "");
    assert_eq!(scene.media[0].albedo.data, [1.0, 1.0, 0.0]);
    let spp = 256;
    let image = render(&scene, spp);
    let t = (-2.0f64).exp();
    for (c, want) in [(0, SKY), (1, SKY), (2, t * SKY)] {
        let (mean, spread) = channel_mean_and_se(&image, c);
        // Red and green: the spread of the pixels; blue: a Bernoulli of mean e^(−σd) per sample.
        let se = match c {
            2 => SKY * (t * (1.0 - t) / (image.data.len() as f64 * spp as f64)).sqrt(),
            _ => spread + 1e-7,
        };
        assert!((mean - want).abs() <= 4.0 * se, "channel {c}: {mean} against {want} (standard error {se:.2e})");
    }
}

/// With a vanishing albedo a scattering medium only stops light: the mean image is
/// e^(−σd) times the sky, and the density's gradient −scale·d·e^(−σd) times it (per pixel
/// and channel), each within 4 standard errors of the collision sampling's.
#[test]
fn a_dark_scattering_medium_transmits_in_closed_form_in_expectation() {
    let (density, scale, d) = (0.5f64, 2.0f64, 1.0f64);
    let t = (-density * scale * d).exp();
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 0.5\nrange = [0, 10]\n";
    let scene = slab("dark-scattering", d as f32, 8, "density = 0.5\nscale = 2.0\nalbedo = 1e-6", &[], optimise);
    let image = render(&scene, 64);
    for (c, (got, bg)) in mean(&image).into_iter().zip(BG).enumerate() {
        let want = t * bg as f64;
        // Each sample is the sky or (nearly) nothing: a Bernoulli of mean e^(−σd).
        let se = bg as f64 * (t * (1.0 - t) / (64.0 * 64.0)).sqrt();
        assert!((got - want).abs() <= 4.0 * se, "channel {c}: {got} against {want} (standard error {se:.2e})");
    }
    let (g, g_se) = gradient_rounds(&scene, 16, 8);
    let want: f64 = (0..3).map(|c| 64.0 * -scale * d * t * BG[c] as f64).sum();
    assert!((g - want).abs() <= 4.0 * g_se, "gradient {g} ± {g_se:.2e} against {want}");
    assert!(g_se < 0.1 * want.abs(), "the test resolves a 40 % error: {g_se:.2e}");
}

/// A shadow ray's transmittance by ratio tracking: a white floor (albedo 0.5) under a sun
/// of irradiance 2 straight above, seen from straight above, through a dark scattering
/// slab (σ = 2 over a thickness of 0.5, albedo 1e-6) between them, with a black sky. A
/// camera ray crosses the slab with probability T = e^(−σd) (delta tracking), and the
/// sun's light reaches the floor through it weighted by the product of 1 − σ/σ̄ over
/// tentative collisions (ratio tracking), whose mean is T: the image's mean is
/// T² · 0.5 · 2 / π, and the density's gradient −2 · scale · d times it per pixel and
/// channel, each within 4 standard errors. The majorant is the parameter's range, 5 times
/// the density: many factors per shadow ray. The same again with the slab in two halves
/// 0.25 apart, the inside of a closed mesh: rays cross it in two parts.
#[test]
fn a_shadow_ray_keeps_the_slabs_transmittance_by_ratio_tracking() {
    let halves = [([-2.0, 0.1, -2.0], [2.0, 0.35, 2.0]), ([-2.0, 0.6, -2.0], [2.0, 0.85, 2.0])];
    for (name, bounds) in [("box", "min = [-2, 0.2, -2]\nmax = [2, 0.7, 2]".to_string()), ("mesh", "mesh = \"halves.obj\"".to_string())] {
        let dir = temp_dir(&format!("ratio-tracking-{name}"));
        std::fs::write(dir.join("floor.obj"), "v -2 0 -2\nv -2 0 2\nv 2 0 2\nv 2 0 -2\nf 1 2 3\nf 1 3 4\n").unwrap();
        std::fs::write(dir.join("halves.obj"), boxes_obj(&halves, false)).unwrap();
        let toml = format!(
            "[film]\nwidth = 8\nheight = 8\n[integrator]\nmax_depth = 2\n\
             [[sensors]]\norigin = [0, 5, 0]\ntarget = [0, 0, 0]\nup = [0, 0, -1]\northo_height = 1.0\n\
             [[materials]]\nname = \"white\"\ntype = \"diffuse\"\nbase_color = [0.5, 0.5, 0.5]\n\
             [[meshes]]\nfile = \"floor.obj\"\nmaterial = \"white\"\n\
             [[lights]]\nname = \"sun\"\ntype = \"directional\"\ndirection = [0, -1, 0]\ncolor = [1, 1, 1]\nintensity = 2\n\
             [[media]]\nname = \"slab\"\n{bounds}\ndensity = 1.0\nscale = 2.0\nalbedo = 1e-6\n\
             [[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 1.0\nrange = [0, 5]\n"
        );
        std::fs::write(dir.join("scene.toml"), toml).unwrap();
        let scene = Scene::load(dir.join("scene.toml")).unwrap();
        let (scale, d) = (2.0f64, 0.5f64);
        let t = (-scale * d).exp();
        let want = t * t * 0.5 * 2.0 / std::f64::consts::PI;
        let image = render(&scene, 256);
        for c in 0..3 {
            let (mean, se) = channel_mean_and_se(&image, c);
            println!("ratio tracking ({name}), channel {c}: {mean:.5} ± {se:.1e} against {want:.5}");
            assert!((mean - want).abs() <= 4.0 * se, "{name}, channel {c}: {mean} against {want} (standard error {se:.2e})");
            assert!(se < 0.02 * want, "the test resolves an 8 % error: standard error {se:.2e}");
        }
        let (g, g_se) = gradient_rounds(&scene, 16, 12);
        let want_g = 64.0 * 3.0 * -2.0 * scale * d * want;
        println!("ratio tracking ({name}): gradient {g:.4} ± {g_se:.1e} against {want_g:.4}");
        assert!((g - want_g).abs() <= 4.0 * g_se, "{name}: gradient {g} ± {g_se:.2e} against {want_g}");
        assert!(g_se < 0.05 * want_g.abs(), "the test resolves a 20 % error: {g_se:.2e}");
    }
}

/// A scattering medium's majorant follows its density whoever sets it: a dark slab
/// (albedo 1e-6, scale 0.2, depth 1) whose density parameter (range [0, 50]) is rendered
/// at 0.5, then set to 5 from the library and rendered again, keeps e^(−σd) of the
/// background in expectation at both, within 4 standard errors. A majorant left at the
/// first density's would clamp the second to an extinction of 0.14 instead of 1: a
/// transmittance of 0.87 instead of 0.37.
#[test]
fn the_majorant_follows_the_density() {
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 0.5\nrange = [0, 50]\n";
    let scene = slab("majorant-follows", 1.0, 8, "density = 0.5\nscale = 0.2\nalbedo = 1e-6", &[], optimise);
    with_gpu(|ctx| {
        let mut r = Renderer::new(&device(ctx), &scene).unwrap();
        let spp = 64;
        for density in [0.5f64, 5.0] {
            r.set_param("media.slab.density", &[density as f32]).unwrap();
            let image = r.render(&RenderOptions { spp, seed: 3, ..Default::default() }).unwrap();
            let t = (-0.2 * density).exp();
            for (c, (got, bg)) in mean(&image).into_iter().zip(BG).enumerate() {
                let want = t * bg as f64;
                let se = bg as f64 * (t * (1.0 - t) / (64.0 * spp as f64)).sqrt();
                assert!((got - want).abs() <= 4.0 * se, "density {density}, channel {c}: {got} against {want} (standard error {se:.2e})");
            }
        }
    });
}

/// The majorant pass writes, per cell of the majorant grid, the host's bound
/// (`majorant_grid`) of the larger of θ's and the previous θ's densities, bit for bit: a
/// 20 × 14 × 9 grid (cells 3 × 2 × 2, which do not divide it), sparse (nothing beyond its
/// first 6 voxels along x) and different in the two states. It writes the largest cell as
/// the record's majorant, and the cells as its `majorant_cells`: the kernels walk a grid
/// this sparse. For a constant density, whose grid saves nothing, `majorant_cells` is 0.
/// A recording that writes θ between two tracking passes runs the pass again.
#[test]
fn the_majorant_pass_writes_the_hosts_grid() {
    use vkinverse::gpu::{Buffer, CommandBuffer};
    use vkinverse::render::features::media::*;
    use vkinverse::render::GpuScene;
    use vkinverse::shared::MediumRecord;
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 0.5\nrange = [0, 10]\ngrid = [20, 14, 9]\n";
    let scene = slab("majorant-pass", 1.0, 4, "density = 0.5\nscale = 2.0\nalbedo = 0.5", &[], optimise);
    let (dims, n) = ([20u32, 14, 9], 20 * 14 * 9);
    let sparse = |salt: u64| -> Vec<f32> { (0..n).map(|i| if i % 20 < 6 && hashed(salt + i) < 0.3 { 8.0 * hashed(salt + 5000 + i) } else { 0.0 }).collect() };
    let cells = majorant_cells(dims);
    let walk_cost = CELL_STEP_COST * crossings_per_length(cells, [-1.0, -1.0, -0.5], [1.0, 1.0, 0.5]);
    with_gpu(|ctx| {
        let gs = GpuScene::new(ctx, &scene).unwrap();
        assert_eq!((gs.features.media.cells, cells), ([3, 2, 2], [3, 2, 2]));
        let theta_prev: Buffer = gs.theta.duplicate("theta prev").unwrap();
        let media = gs.bindings().into_iter().find(|(n, _)| *n == "Media").unwrap().1;
        let record = std::mem::size_of::<MediumRecord>() / 4;
        let majorant_word = std::mem::offset_of!(MediumRecord, majorant) / 4;
        for (case, now, prev) in [("sparse", sparse(7_000), sparse(8_000)), ("constant", vec![0.5; n as usize], vec![0.5; n as usize])] {
            gs.set_theta(now.clone()).unwrap();
            theta_prev.write(&vkinverse::render::targets::padded(&gs, prev.clone())).unwrap();
            let mut cb = CommandBuffer::new(ctx, "majorant").unwrap();
            cb.record(|rec| gs.features.media.record_majorant(rec, &gs.theta, &theta_prev)).unwrap();
            cb.submit_and_wait().unwrap();
            let words: Vec<u32> = media.read().unwrap();
            // One texel per cell, the majorant in its first word.
            let got: Vec<f32> = words[record..record + 48].iter().step_by(4).map(|w| f32::from_bits(*w)).collect();
            let larger: Vec<f32> = now.iter().zip(&prev).map(|(a, b)| a.max(*b)).collect();
            let want = majorant_grid(&larger, dims, MAJORANT_MARGIN * 2.0);
            assert_eq!(got, want, "{case}");
            let most = want.iter().copied().fold(0.0, f32::max);
            assert_eq!(f32::from_bits(words[majorant_word]), most, "{case}: the largest cell");
            let walk = walks_grid(&want, walk_cost);
            assert_eq!(words[majorant_word + 1], if walk { pack_cells(cells) } else { 0 }, "{case}: majorant_cells");
            assert_eq!(walk, case == "sparse", "{case}: the kernels walk the sparse grid and not the constant one");
        }
        // Within one recording the pass runs once per θ: again after θ is written.
        let (first, second) = (sparse(9_000), sparse(10_000));
        gs.set_theta(first).unwrap();
        let other: Buffer = gs.theta.duplicate("other theta").unwrap();
        other.write(&vkinverse::render::targets::padded(&gs, second.clone())).unwrap();
        let mut cb = CommandBuffer::new(ctx, "majorant twice").unwrap();
        cb.record(|rec| {
            gs.features.media.record_majorant(rec, &gs.theta, &gs.theta)?;
            rec.copy(&other, &gs.theta, 4 * n)?;
            gs.features.media.record_majorant(rec, &gs.theta, &gs.theta)
        })
        .unwrap();
        cb.submit_and_wait().unwrap();
        let words: Vec<u32> = media.read().unwrap();
        let got: Vec<f32> = words[record..record + 48].iter().step_by(4).map(|w| f32::from_bits(*w)).collect();
        assert_eq!(got, majorant_grid(&second, dims, MAJORANT_MARGIN * 2.0), "the grid of θ as written in the recording");
    });
}

/// Tracking against the majorant grid keeps a sparse medium's transmittance: a slab
/// (depth 1, 32 voxels deep, 4 × 4 across) whose density is 0 but in one layer of
/// voxels, 10 there, so that the grid's cells (4 along the depth) before and after it are
/// empty and those beside it bound the layer's lookups through their neighbour voxel
/// alone. Seen along the slab's depth, a ray keeps e^(−scale · h · 10) (h the voxel's
/// depth: the trilinear profile's integral), within 4 standard errors of the Bernoulli
/// of each sample: for the scene's own grid (the host's majorant grid), and for an
/// optimised density set from the library to the layer at voxel 16 and then at voxel 7
/// (the pass's, which must follow). A cell blind to its neighbour voxel loses an eighth
/// of the optical depth (a 13 % brighter image); a grid left at the first layer's loses
/// most of it. The density's gradient matches its closed form within 4 standard errors,
/// at the layer and at no density at all (where nothing is tracked but the derivatives
/// are not 0).
#[test]
fn tracking_against_the_majorant_grid_keeps_a_sparse_mediums_transmittance() {
    let layer = |z: usize| Array { shape: vec![32, 4, 4], data: (0..512).map(|i| if i / 16 == z { 10.0 } else { 0.0 }).collect() };
    let scale = 3.2f64;
    let t = (-scale * 10.0 / 32.0).exp();
    let check = |what: &str, image: &Image, spp: u32| {
        for (c, (got, bg)) in mean(image).into_iter().zip(BG).enumerate() {
            let want = t * bg as f64;
            let se = bg as f64 * (t * (1.0 - t) / (64.0 * spp as f64)).sqrt();
            assert!((got - want).abs() <= 4.0 * se, "{what}, channel {c}: {got} against {want} (standard error {se:.2e})");
            assert!(0.13 * want > 8.0 * se, "the test resolves a 13 % error");
        }
    };
    let fixed = slab("majorant-grid-fixed", 1.0, 8, "density = \"layer.npy\"\nscale = 3.2\nalbedo = 1e-6", &[("layer.npy", layer(16))], "");
    check("the scene's grid", &render(&fixed, 256), 256);
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 0.0\nrange = [0, 20]\ngrid = [4, 4, 32]\n";
    let scene = slab("majorant-grid-pass", 1.0, 8, "density = \"layer.npy\"\nscale = 3.2\nalbedo = 1e-6", &[("layer.npy", layer(16))], optimise);
    with_gpu(|ctx| {
        let mut r = Renderer::new(&device(ctx), &scene).unwrap();
        for z in [16, 7] {
            r.set_param("media.slab.density", &layer(z).data).unwrap();
            let image = r.render(&RenderOptions { spp: 256, seed: 11, ..Default::default() }).unwrap();
            check(&format!("the layer at voxel {z}, set from the library"), &image, 256);
        }
        // The gradient of the image's sum over every voxel: each point's trilinear weights
        // sum to 1, so it is 64 pixels × Σ sky × T × −scale × depth, empty cells included
        // (their voxels' derivatives are not 0). At no density at all, T = 1.
        let sky: f64 = BG.iter().map(|&c| c as f64).sum();
        for (what, transmittance) in [("the layer at voxel 7", t), ("no density", 1.0)] {
            if transmittance == 1.0 {
                r.set_param("media.slab.density", &[0.0; 512]).unwrap();
            }
            let (g, se) = renderer_gradient_rounds(&r, 16, 8);
            let want = 64.0 * sky * transmittance * -scale;
            println!("{what}: gradient {g:.3} ± {se:.2e} against {want:.3}");
            // (At no density every sample gives the same: the rounding of f32 sums.)
            assert!((g - want).abs() <= 4.0 * se + 1e-6 * want.abs(), "{what}: gradient {g} ± {se:.2e} against {want}");
            assert!(se < 0.05 * want.abs(), "{what}: the test resolves a 20 % error: {se:.2e}");
        }
    });
}

/// A perspective view of a random 8³ scattering medium (albedo 0.8, g 0.3) over a diffuse
/// floor, lit by the sky and a point light: the adjoint's directional derivative of the
/// density along a random direction against the central difference of independent
/// renders, paired by seed, over 32 seeds. Collision sampling makes each seed's estimator
/// jump as the density moves, so the two agree in expectation only: a z-test at 4
/// standard errors, which must resolve a tenth of the derivative.
#[test]
fn the_scattering_adjoint_agrees_with_central_differences_in_expectation() {
    let dir = temp_dir("random-grid-scattering");
    let optimise = "[[optimise.params]]\ntarget = \"media.cloud.density\"\ninit = 1.0\nrange = [0, 10]\n";
    // A fixed majorant: the renders at θ ± h then track against the same tentative
    // collisions, and their difference keeps the noise of the pairing low (a majorant that
    // follows θ moves them all).
    let scene = scattering_cloud(&dir, "0.8\nmajorant = 10", optimise);
    let density = scene.media[0].density.data.clone();
    // A direction that thickens every voxel by a random amount: a derivative well above
    // the noise.
    let dirs: Vec<f32> = (0..density.len()).map(|i| 0.25 + 0.5 * hashed(60_000 + i as u64)).collect();
    let diffs = adjoint_and_central_difference(&scene, "media.cloud.density", &density, &dirs, 0.1, 32);
    let k = diffs.len() as f64;
    let mean_of = |f: &dyn Fn(&(f64, f64)) -> f64| diffs.iter().map(f).sum::<f64>() / k;
    let (adj, fd) = (mean_of(&|d| d.0), mean_of(&|d| d.1));
    let d_mean = adj - fd;
    let se = (diffs.iter().map(|d| (d.0 - d.1 - d_mean).powi(2)).sum::<f64>() / (k - 1.0) / k).sqrt();
    let spread = |f: &dyn Fn(&(f64, f64)) -> f64, m: f64| (diffs.iter().map(|d| (f(d) - m).powi(2)).sum::<f64>() / (k - 1.0) / k).sqrt();
    println!(
        "scattering: adjoint {adj:.5} ± {:.2e}, central differences {fd:.5} ± {:.2e}, difference {d_mean:.2e} ± {se:.2e}",
        spread(&|d| d.0, adj),
        spread(&|d| d.1, fd)
    );
    assert!(d_mean.abs() <= 4.0 * se, "adjoint {adj} against central differences {fd}: {:.1} standard errors apart", d_mean.abs() / se);
    assert!(se < 0.1 * fd.abs(), "the test resolves a tenth of the derivative: standard error {se:.2e} against {fd:.2e}");
}

/// Over `seeds` seeds at 4 spp: the adjoint's derivative of ⟨A, image⟩ along `dirs` at
/// `param` = `base`, against the central difference (step `h`) of renders of the adjoint
/// pass's own paths, for a fixed random adjoint image A of the scene's 12 × 12 film.
fn adjoint_and_central_difference(scene: &Scene, param: &str, base: &[f32], dirs: &[f32], h: f32, seeds: u64) -> Vec<(f64, f64)> {
    let adjoint = Image { width: 12, height: 12, data: (0..144).map(|i| [0, 1, 2].map(|c| 0.2 + hashed(95_000 + 3 * i + c))).collect() };
    let dot_adjoint = |img: &Image| -> f64 { img.data.iter().zip(&adjoint.data).map(|(p, a)| (0..3).map(|c| p[c] as f64 * a[c] as f64).sum::<f64>()).sum() };
    with_gpu(|ctx| {
        let mut r = Renderer::new(&device(ctx), scene).unwrap();
        let set = |r: &mut Renderer, t: f32| {
            let v: Vec<f32> = base.iter().zip(dirs).map(|(b, d)| b + t * d).collect();
            r.set_param(param, &v).unwrap();
        };
        (0..seeds)
            .map(|seed| {
                let options = RenderOptions { spp: 4, seed, ..Default::default() };
                set(&mut r, 0.0);
                let g = r.gradient(&adjoint, &options).unwrap();
                let along: f64 = g[0].1.data.iter().zip(dirs).map(|(&g, &d)| g as f64 * d as f64).sum();
                let paths = RenderOptions { seed: seed + vkinverse::render::gradient::SEED_ADJOINT as u64, ..options };
                set(&mut r, h);
                let plus = dot_adjoint(&r.render(&paths).unwrap());
                set(&mut r, -h);
                let minus = dot_adjoint(&r.render(&paths).unwrap());
                (along, (plus - minus) / (2.0 * h as f64))
            })
            .collect()
    })
}

/// A perspective view of a random 8³ scattering medium (g 0.3) over a diffuse floor, lit by
/// the sky and a point light, depth 4, no Russian roulette with albedo
/// `albedo` (TOML) and `optimise` appended, in `dir`.
fn scattering_cloud(dir: &Path, albedo: &str, optimise: &str) -> Scene {
    let n = 8usize;
    let density = Array { shape: vec![n, n, n], data: (0..n * n * n).map(|i| 0.2 + 1.8 * hashed(3000 + i as u64)).collect() };
    npy::write(&dir.join("density.npy"), &density).unwrap();
    std::fs::write(dir.join("floor.obj"), "v -3 -1 -3\nv 3 -1 -3\nv 3 -1 3\nv -3 -1 3\nf 1 3 2\nf 1 4 3\n").unwrap();
    let toml = format!(
        "[film]\nwidth = 12\nheight = 12\n[integrator]\nmax_depth = 4\nrr_depth = 64\n\
         [[sensors]]\norigin = [0.6, 1.4, 4]\ntarget = [0, -0.2, 0]\nfov_y = 40\n\
         [environment]\nconstant = [0.3, 0.4, 0.5]\n\
         [[media]]\nname = \"cloud\"\nmin = [-1, -0.8, -1]\nmax = [1, 0.8, 1]\ndensity = \"density.npy\"\nalbedo = {albedo}\ng = 0.3\nstep = 0.7\n\
         [[materials]]\nname = \"floor\"\ntype = \"diffuse\"\nbase_color = [0.6, 0.5, 0.4]\n\
         [[meshes]]\nname = \"floor\"\nfile = \"floor.obj\"\nmaterial = \"floor\"\n\
         [[lights]]\nname = \"bulb\"\ntype = \"point\"\nposition = [1.5, 2, 1]\ncolor = [1, 1, 1]\nintensity = 6\n{optimise}"
    );
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    Scene::load(dir.join("scene.toml")).unwrap()
}

/// An albedo grid is looked up at each collision: a 3 × 2 × 4 grid whose voxels all hold
/// the constant's colour renders as the constant (to 1e-5 of each pixel, the rounding of
/// the trilinear weights), and a grid whose every third voxel is half as bright renders
/// differently (by more than 1 % of the image's sum).
#[test]
fn an_albedo_grid_of_equal_voxels_renders_as_its_constant() {
    let dir = temp_dir("albedo-grid-uniform");
    let colour = [0.8f32, 0.6, 0.4];
    let grid = |f: &dyn Fn(usize) -> f32| Array { shape: vec![4, 2, 3, 3], data: (0..24).flat_map(|i| colour.map(|c| c * f(i))).collect() };
    npy::write(&dir.join("albedo.npy"), &grid(&|_| 1.0)).unwrap();
    npy::write(&dir.join("halves.npy"), &grid(&|i| if i % 3 == 0 { 0.5 } else { 1.0 })).unwrap();
    let constant = scattering_cloud(&dir, "[0.8, 0.6, 0.4]", "");
    let uniform = scattering_cloud(&dir, "\"albedo.npy\"", "");
    assert_eq!(uniform.media[0].albedo.shape.array(), vec![4, 2, 3, 3]);
    let halves = scattering_cloud(&dir, "\"halves.npy\"", "");
    let (a, b, c) = (render(&constant, 8), render(&uniform, 8), render(&halves, 8));
    let difference = |x: &Image, y: &Image| -> (f64, f64) {
        let pairs = x.data.iter().zip(&y.data).flat_map(|(p, q)| (0..3).map(move |k| (p[k] as f64, q[k] as f64)));
        pairs.fold((0.0, 0.0), |(worst, sum), (p, q)| (f64::max(worst, (p - q).abs() / p.abs().max(1e-3)), sum + (p - q).abs()))
    };
    let total: f64 = a.data.iter().flat_map(|p| p.iter().map(|&v| v as f64)).sum();
    let (worst, _) = difference(&a, &b);
    assert!(worst < 1e-5, "a grid of the constant's colour renders as the constant: a pixel differs by {worst:.2e}");
    let (_, moved) = difference(&a, &c);
    assert!(moved > 0.01 * total, "a grid of other values renders otherwise: {moved} of {total}");
}

/// The albedo's adjoint against central differences. Collisions are sampled by the
/// density alone and paths end at depth 4 without Russian roulette, so each seed's image is
/// a smooth function of the albedo: per seed, the adjoint's directional derivative along a
/// random direction of a 4³ albedo grid agrees with the central difference of renders of
/// the same paths within 1e-3 of the derivative, over 8 seeds.
#[test]
fn the_albedo_adjoint_matches_central_differences_per_seed() {
    let dir = temp_dir("albedo-grid-adjoint");
    let n = 4usize;
    let albedo = Array { shape: vec![n, n, n, 3], data: (0..n * n * n * 3).map(|i| 0.3 + 0.6 * hashed(7000 + i as u64)).collect() };
    npy::write(&dir.join("albedo.npy"), &albedo).unwrap();
    let optimise = "[[optimise.params]]\ntarget = \"media.cloud.albedo\"\ninit = 0.5\nrange = [0, 1]\ngrid = [4, 4, 4]\n";
    let scene = scattering_cloud(&dir, "\"albedo.npy\"", optimise);
    let dirs: Vec<f32> = (0..albedo.data.len()).map(|i| 0.25 + 0.5 * hashed(80_000 + i as u64)).collect();
    for (seed, (along, fd)) in adjoint_and_central_difference(&scene, "media.cloud.albedo", &albedo.data, &dirs, 0.02, 8).into_iter().enumerate() {
        println!("albedo, seed {seed}: adjoint {along:.6}, central difference {fd:.6}");
        assert!(fd.abs() > 1.0, "seed {seed}: the derivative {fd} is resolved");
        assert!((along - fd).abs() <= 1e-3 * fd.abs(), "seed {seed}: adjoint {along} against central difference {fd}");
    }
}

/// Cancels its token once iteration `at` has run.
struct StopAfter(u32, vkinverse::Cancel);

impl vkinverse::Observer for StopAfter {
    fn iteration(&mut self, row: &vkinverse::LogRow, _: &[vkinverse::Diagnostics]) -> std::ops::ControlFlow<()> {
        if row.iteration == self.0 {
            self.1.cancel();
        }
        std::ops::ControlFlow::Continue(())
    }
}

/// The slab with a random 5 × 4 × 3 density, optimised as a 16³ grid that doubles to 32³
/// after iteration 3 (`upsample = [3]`).
fn coarse_to_fine_scene(name: &str, optimiser: &str) -> Scene {
    let (density, _) = random_grids();
    let optimise = format!(
        "[optimise]\noptimiser = \"{optimiser}\"\nupsample = [3]\n\
         [[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 1.0\nrange = [0, 10]\ngrid = [16, 16, 16]\n"
    );
    slab(name, 1.0, 8, "density = \"d.npy\"\nemission = 0.5\nstep = 0.5", &[("d.npy", density)], &optimise)
}

/// Runs `scene` for `iterations` into `dir` (a new run, or a resume), stopped after
/// iteration `stop` if given; its recovered parameters.
fn coarse_run(scene: &Scene, dir: &Path, iterations: u32, mode: vkinverse::Mode, stop: Option<u32>) -> vkinverse::run::Run {
    let settings = vkinverse::Settings {
        iterations: Some(iterations),
        target_spp: Some(16),
        spp: Some(1),
        primal_spp: Some(1),
        checkpoint_every: Some(1),
        ..Default::default()
    }
    .resolve_for(scene);
    let cancel = vkinverse::Cancel::new();
    let mut observer = StopAfter(stop.unwrap_or(0), cancel.clone());
    let options = vkinverse::RunOptions { out_dir: Some(dir), mode, cancel };
    with_gpu(|ctx| vkinverse::optimise(&device(ctx), scene, &settings, &options, &mut observer).unwrap().into_run())
}

/// Coarse to fine: a density optimised as a 16³ grid and upsampled to 32³ after iteration
/// 3. The recovered grid is 32³. Adam's step after the upsampling starts from the 16³ θ
/// upsampled trilinearly (each element within one step of it), and from its state carried
/// over: its root mean square gradient at iteration 4 keeps at least √(1 − k) of the
/// upsampled one in every element (a state started afresh holds √k·|g| alone). A meta run
/// stopped at the upsampling (its last checkpoint then written after it, at 32³) or just
/// after it resumes to the uninterrupted run's grid bit for bit.
#[test]
fn grids_upsample_from_16_to_32_voxels_with_the_optimisers_state() {
    let adam = coarse_to_fine_scene("coarse-adam", "adam");
    let (a, b) = (temp_dir("coarse-adam-3"), temp_dir("coarse-adam-4"));
    let coarse = coarse_run(&adam, &a, 3, vkinverse::Mode::New, None);
    let fine = coarse_run(&adam, &b, 4, vkinverse::Mode::New, None);
    let (c, f) = (&coarse.params[0].1, &fine.params[0].1);
    assert_eq!((c.shape, f.shape), (vkinverse::Shape::grid(16, 16, 16, 1), vkinverse::Shape::grid(32, 32, 32, 1)));
    let up = vkinverse::scene::media::resample(c, f.shape);
    let moved = f.data.iter().zip(&up).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    // Adam's step is at most about lr / (1 − β1) per element.
    assert!(moved > 0.0 && moved < 0.2, "after the upsampling θ moved {moved} from the upsampled 16³ θ");
    let r = |dir: &Path, it: &str| npy::read(&dir.join(format!("checkpoint/{it}/adam_r.npy"))).unwrap().data;
    let (r3, r4) = (r(&a, "0000000003"), r(&b, "0000000004"));
    let r3_up = vkinverse::scene::media::resample(&vkinverse::ParamValue::new(c.shape, r3[..c.data.len()].to_vec()).unwrap(), f.shape);
    // Adam keeps the root of the bias-corrected mean square: r_t² = (1 − k)·r_{t−1}² + k·g²
    // with k = (1 − β2) / (1 − β2^t) (glsl/lib/optim.glsl).
    let k = 0.001f64 / (1.0 - 0.999f64.powi(4));
    let keep = (1.0 - k).sqrt() as f32;
    let below = r4.iter().zip(&r3_up).filter(|(r4, r3)| **r4 < keep * **r3 * (1.0 - 1e-5)).count();
    assert_eq!(below, 0, "Adam's second moment was not carried over in {below} elements");
    assert!(r3_up.iter().sum::<f32>() > 0.0, "three steps left a second moment to carry");
    // Meta, stopped at the upsampling and just after it, then resumed.
    let meta = coarse_to_fine_scene("coarse-meta", "meta");
    let whole = coarse_run(&meta, &temp_dir("coarse-meta-whole"), 6, vkinverse::Mode::New, None);
    assert_eq!(whole.params[0].1.shape, vkinverse::Shape::grid(32, 32, 32, 1));
    for stop in [3, 4] {
        let dir = temp_dir(&format!("coarse-meta-{stop}"));
        let stopped = coarse_run(&meta, &dir, 6, vkinverse::Mode::New, Some(stop));
        assert_eq!(stopped.summary.iterations, stop);
        let resumed = coarse_run(&meta, &dir, 6, vkinverse::Mode::Resume, None);
        assert!(resumed.params == whole.params, "stopped after iteration {stop} and resumed, the run ends elsewhere");
        assert_eq!(resumed.log.rows.len(), 7);
    }
}

/// `upsample` takes increasing iterations from 1, and needs a grid to upsample.
#[test]
fn bad_upsampling_is_named() {
    let mut settings = vkinverse::Settings::default();
    for (text, needle) in [("0,3", "the first is at least 1"), ("5,3", "5 then 3: the iterations must increase"), ("3,x", "'x'")] {
        let err = settings.set("upsample", text).unwrap_err();
        assert!(err.key == "upsample" && err.message.contains(needle), "{text}: {}", err.message);
    }
    settings.set("upsample", "[2, 4]").unwrap();
    assert_eq!(settings.upsample, Some(vkinverse::settings::Upsample(vec![2, 4])));
    settings.iterations = Some(2);
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 1.0\nrange = [0, 10]\n";
    let scene = slab("upsample-constant", 1.0, 4, "density = 0.5", &[], optimise);
    let err = with_gpu(|ctx| vkinverse::optimise(&device(ctx), &scene, &settings.resolve_for(&scene), &vkinverse::RunOptions::new(None), &mut ()).unwrap_err());
    assert!(err.to_string().contains("upsample: the scene optimises no grid"), "{err}");
}

/// OBJ text of closed boxes between the corner pairs `boxes`, each of 12 triangles wound
/// out (in where `inward`).
fn boxes_obj(boxes: &[([f32; 3], [f32; 3])], inward: bool) -> String {
    let mut s = String::new();
    // The corners of a box, bit k of i picking max on axis k; faces wound out.
    let faces: [[usize; 4]; 6] = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    for (b, (lo, hi)) in boxes.iter().enumerate() {
        for i in 0..8 {
            let p = [0, 1, 2].map(|a| if i >> a & 1 == 1 { hi[a] } else { lo[a] });
            s += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        }
        for f in faces {
            let [a, b2, c, d] = f.map(|k| k + 1 + 8 * b);
            let (q, r) = if inward { ([a, c, b2], [a, d, c]) } else { ([a, b2, c], [a, c, d]) };
            s += &format!("f {} {} {}\nf {} {} {}\n", q[0], q[1], q[2], r[0], r[1], r[2]);
        }
    }
    s
}

/// Two boxes one above the other in z, each covering the slab camera's view, 0.5 deep
/// with a gap of 0.6 between them: every ray crosses 1.0 of medium, and 1.6 of their
/// bounds.
const TWO_BOXES: [([f32; 3], [f32; 3]); 2] = [([-1.0, -1.0, 0.3], [1.0, 1.0, 0.8]), ([-1.0, -1.0, -0.8], [1.0, 1.0, -0.3])];

/// A scene seen as [`slab`]'s, whose medium is the inside of the closed mesh `obj` (its
/// box the mesh's bounds), with `medium` and `optimise` appended.
fn bounded(name: &str, obj: &str, film: u32, medium: &str, optimise: &str) -> Scene {
    let dir = temp_dir(name);
    std::fs::write(dir.join("boundary.obj"), obj).unwrap();
    let toml = format!(
        "[film]\nwidth = {film}\nheight = {film}\n[integrator]\nmax_depth = 2\n\
         [[sensors]]\norigin = [0, 0, 5]\ntarget = [0, 0, 0]\northo_height = 1.0\n\
         [environment]\nconstant = [{}, {}, {}]\n\
         [[media]]\nname = \"slab\"\nmesh = \"boundary.obj\"\n{medium}\n{optimise}",
        BG[0], BG[1], BG[2]
    );
    std::fs::write(dir.join("scene.toml"), toml).unwrap();
    Scene::load(dir.join("scene.toml")).unwrap()
}

/// A medium bounded by a closed mesh fills its inside only. Two boxes 0.5 deep, 0.6 apart
/// (every ray crosses 1.0 of medium in two parts, 1.6 of the bounds): each pixel is
/// L_e (1 − e^(−σ·1)) + e^(−σ·1) L_bg to 1e-5, wound out or in (a mesh wound in is turned
/// out); filling the bounds would give e^(−σ·1.6). The density's gradient summed over its
/// voxels is the closed form d·e^(−σd)(L_e − L_bg) with d = 1, and the emission's
/// 1 − e^(−σd), both to 1e-4; the gap's voxels get none. The recovered scene writes the
/// boundary, which loads back as it was.
#[test]
fn a_medium_inside_a_closed_mesh_fills_its_inside_only() {
    let (density, scale, d) = (0.75f64, 2.0f64, 1.0f64);
    let sigma = density * scale;
    let t = (-sigma * d).exp();
    let le = [2.0f64, 1.0, 0.5];
    let medium = format!("density = {density}\nscale = {scale}\nstep = 0.3\nemission = [{}, {}, {}]", le[0], le[1], le[2]);
    for inward in [false, true] {
        let scene = bounded(&format!("bounded-inward-{inward}"), &boxes_obj(&TWO_BOXES, inward), 8, &medium, "");
        let m = &scene.media[0];
        assert_eq!((m.min, m.max), ([-1.0, -1.0, -0.8], [1.0, 1.0, 0.8]), "the box is the mesh's bounds");
        let image = render(&scene, 2);
        for p in &image.data {
            for c in 0..3 {
                let want = le[c] * (1.0 - t) + t * BG[c] as f64;
                assert_close(&format!("inward {inward}, channel {c}"), p[c] as f64, want, 1e-5);
            }
        }
    }
    // The gradients: a density grid of 8 voxels along z, of which the middle ones lie in
    // the gap.
    let optimise = format!(
        "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = {density}\nrange = [0, 10]\ngrid = [1, 1, 8]\n\
         [[optimise.params]]\ntarget = \"media.slab.emission\"\ninit = [{}, {}, {}]\nrange = [0, 10]\n",
        le[0], le[1], le[2]
    );
    let scene = bounded("bounded-grad", &boxes_obj(&TWO_BOXES, false), 6, &medium, &optimise);
    let grads = with_gpu(|ctx| {
        let r = Renderer::new(&device(ctx), &scene).unwrap();
        let adjoint = Image { width: 6, height: 6, data: vec![[1.0; 3]; 36] };
        r.gradient(&adjoint, &RenderOptions { spp: 2, seed: 1, ..Default::default() }).unwrap()
    });
    let pixels = 36.0;
    let want_density: f64 = (0..3).map(|c| pixels * scale * d * t * (le[c] - BG[c] as f64)).sum();
    let per_voxel: Vec<f64> = grads[0].1.data.iter().map(|&g| g as f64).collect();
    assert_close("density", per_voxel.iter().sum(), want_density, 1e-4);
    // Voxel centres at z = −0.7 + 0.2 k: voxels 3 and 4 (z = −0.1, 0.1) are read only by
    // lookups in the gap's middle, which no part reaches.
    assert!(per_voxel[3] == 0.0 && per_voxel[4] == 0.0, "the gap's voxels have gradients: {per_voxel:?}");
    for c in 0..3 {
        assert_close(&format!("emission channel {c}"), grads[1].1.data[c] as f64, pixels * (1.0 - t), 1e-4);
    }
    let out = temp_dir("bounded-round-trip");
    vkinverse::scene::write::write_final(&out, &scene, &[]).unwrap();
    let back = Scene::load(out.join("final/scene.toml")).unwrap();
    assert_eq!(back.media[0].boundary, scene.media[0].boundary);
    assert_eq!((back.media[0].min, back.media[0].max), (scene.media[0].min, scene.media[0].max));
}

/// A boundary that is not one closed surface wound alike is refused in one line naming
/// the key and the edge: an open box, a box with one face turned, a mesh with no volume;
/// and a medium needs its box or a mesh.
#[test]
fn boundary_meshes_that_are_not_closed_are_refused() {
    let closed = boxes_obj(&TWO_BOXES[..1], false);
    let lines: Vec<&str> = closed.lines().collect();
    let open = lines[..lines.len() - 2].join("\n");
    let turned = closed.replacen("f 1 3 4", "f 1 4 3", 1);
    let flat = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 2\n";
    for (name, obj, needles) in [
        ("open", open.as_str(), &["media.slab.mesh", "borders one triangle"][..]),
        ("turned", turned.as_str(), &["media.slab.mesh", "wound unlike"][..]),
        ("flat", flat, &["media.slab.mesh", "encloses no volume"][..]),
    ] {
        let dir = temp_dir(&format!("boundary-{name}"));
        std::fs::write(dir.join("b.obj"), obj).unwrap();
        std::fs::write(
            dir.join("scene.toml"),
            "[[sensors]]\norigin = [0, 0, 5]\ntarget = [0, 0, 0]\nfov_y = 40\n[[media]]\nname = \"slab\"\nmesh = \"b.obj\"\ndensity = 1.0\n",
        )
        .unwrap();
        let message = Scene::load(dir.join("scene.toml")).err().unwrap_or_else(|| panic!("{name}: loaded")).to_string();
        assert!(!message.contains('\n'), "{name}: {message}");
        for n in needles {
            assert!(message.contains(n), "{name}: {message:?} lacks {n:?}");
        }
    }
    let dir = temp_dir("boundary-none");
    std::fs::write(dir.join("scene.toml"), "[[sensors]]\norigin = [0, 0, 5]\ntarget = [0, 0, 0]\nfov_y = 40\n[[media]]\nname = \"slab\"\ndensity = 1.0\n")
        .unwrap();
    let message = Scene::load(dir.join("scene.toml")).err().unwrap().to_string();
    assert!(message.contains("media.slab.min") && message.contains("missing"), "{message}");
}

/// Tracking through a medium bounded by a closed mesh: the two boxes of
/// [`a_medium_inside_a_closed_mesh_fills_its_inside_only`] with a vanishing albedo keep
/// e^(−σ·1) of the background in expectation (delta tracking, part by part), and the
/// density's gradient is −scale·d·e^(−σd) times it, each within 4 standard errors. Filling
/// the bounds would keep e^(−σ·1.6): 11 standard errors off.
#[test]
fn tracking_crosses_a_bounded_medium_part_by_part() {
    let (density, scale, d) = (0.5f64, 2.0f64, 1.0f64);
    let t = (-density * scale * d).exp();
    let optimise = "[[optimise.params]]\ntarget = \"media.slab.density\"\ninit = 0.5\nrange = [0, 10]\n";
    let scene = bounded("bounded-tracking", &boxes_obj(&TWO_BOXES, false), 8, "density = 0.5\nscale = 2.0\nalbedo = 1e-6", optimise);
    let spp = 64.0;
    let image = render(&scene, spp as u32);
    for (c, (got, bg)) in mean(&image).into_iter().zip(BG).enumerate() {
        let want = t * bg as f64;
        let se = bg as f64 * (t * (1.0 - t) / (64.0 * spp)).sqrt();
        assert!((got - want).abs() <= 4.0 * se, "channel {c}: {got} against {want} (standard error {se:.2e})");
    }
    let (g, g_se) = gradient_rounds(&scene, 16, 8);
    let want: f64 = (0..3).map(|c| 64.0 * -scale * d * t * BG[c] as f64).sum();
    assert!((g - want).abs() <= 4.0 * g_se, "gradient {g} ± {g_se:.2e} against {want}");
    assert!(g_se < 0.1 * want.abs(), "the test resolves a 40 % error: {g_se:.2e}");
}
