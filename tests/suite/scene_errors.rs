//! Scene loading end to end: the bundled scenes load, and every kind of bad input gives its
//! typed `SceneError` with a one-line message naming the file and the key or line.

use std::fs;
use std::path::{Path, PathBuf};

use vkinverse::image::{write_exr, Image};
use vkinverse::scene::{AlphaMode, ColorValue, Distribution, ParamTarget, Reference, ScalarValue, Scene, SceneError, TextureValue as _};

const TRIANGLE: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n";
const BARE_TRIANGLE: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

const BASE: &str = r#"[film]
width = 8
height = 8

[[sensors]]
origin = [0, 0, 3]
target = [0, 0, 0]
fov_y = 40

[[materials]]
name = "m"
type = "principled"
base_color = [0.5, 0.5, 0.5]

[[meshes]]
file = "tri.obj"
material = "m"
"#;

/// The error of loading `scene` (fixture `name`) with `file` beside it: a `w` × `h` image of
/// `fill` but for channel `c` of pixel `i` (in row order), which holds `value`.
fn bad_texel(name: &str, scene: &str, file: &str, (w, h): (u32, u32), fill: [f32; 3], (i, c): (usize, usize), value: f32) -> SceneError {
    let path = fixture(name, scene);
    let mut img = Image::filled(w, h, fill);
    img.data[i][c] = value;
    write_exr(&path.with_file_name(file), &img).unwrap();
    Scene::load(&path).unwrap_err()
}

/// A fresh directory holding `tri.obj`, `bare.obj`, `tex.exr` (4x4) and `scene.toml`.
fn fixture(name: &str, scene: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vkinverse-scene-tests-{}-{name}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    fs::write(dir.join("tri.obj"), TRIANGLE).unwrap();
    fs::write(dir.join("bare.obj"), BARE_TRIANGLE).unwrap();
    write_exr(&dir.join("tex.exr"), &Image::filled(4, 4, [0.25, 0.5, 0.75])).unwrap();
    fs::write(dir.join("scene.toml"), scene).unwrap();
    dir.join("scene.toml")
}

fn load_err(name: &str, scene: &str) -> SceneError {
    match Scene::load(fixture(name, scene)) {
        Ok(_) => panic!("{name}: scene loaded but should not have"),
        Err(e) => e,
    }
}

/// The message is one line and contains every needle.
fn assert_message(err: &SceneError, needles: &[&str]) {
    let msg = err.to_string();
    assert!(!msg.contains('\n'), "multi-line message: {msg}");
    for needle in needles {
        assert!(msg.contains(needle), "{msg:?} lacks {needle:?}");
    }
}

fn with_optimise(params: &str) -> String {
    format!("{BASE}\n[optimise]\n[[optimise.params]]\n{params}\n")
}

#[test]
fn bundled_scenes_load() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let cornell = Scene::load(root.join("cornell/scene.toml")).unwrap();
    assert_eq!((cornell.film.width, cornell.film.height, cornell.integrator.max_depth), (64, 64, 4));
    assert_eq!(cornell.meshes.len(), 8);
    assert_eq!(cornell.triangle_count(), 6 * 2 + 2 * 5 * 2);
    let red = cornell.material_index("red").unwrap();
    assert_eq!(cornell.meshes[cornell.mesh_index("left").unwrap()].material, red);
    let p = &cornell.optimise.params[0];
    assert_eq!((p.target, p.shape.channels(), p.init.as_slice()), (ParamTarget::BaseColor { material: red }, 3, &[0.5; 3][..]));
    assert!(matches!(&p.reference, Reference::Constant(c) if c == &[0.63, 0.065, 0.05]));
    let light = &cornell.meshes[cornell.mesh_index("light").unwrap()];
    assert!(matches!(light.emission, ColorValue::Constant(c) if c[0] > 0.0) && light.positions.iter().all(|p| p[1] > 1.9));

    let spiral = Scene::load(root.join("spiral/scene.toml")).unwrap();
    let channels: Vec<u32> = spiral.optimise.params.iter().map(|p| p.shape.channels()).collect();
    assert_eq!(channels, [3, 1, 1]);
    let lrs: Vec<Option<f32>> = spiral.optimise.params.iter().map(|p| p.lr).collect();
    assert_eq!(lrs, [None, Some(0.01), Some(0.01)]);
    assert!(matches!(spiral.environment.value, ColorValue::Constant(c) if c[2] > 0.0));
    assert!(spiral.meshes.iter().any(|m| !m.normals.is_empty() && !m.uvs.is_empty()));

    // The paper's texture scenes: each optimises one texture.
    let ajar = Scene::load(root.join("ajar/scene.toml")).unwrap();
    let glossy = Scene::load(root.join("glossy/scene.toml")).unwrap();
    let textures: Vec<_> =
        [&ajar, &glossy].iter().map(|s| (s.optimise.params.len(), s.optimise.params[0].shape.channels(), s.optimise.params[0].shape.texture_size())).collect();
    assert_eq!(textures, [(1, 3, Some([32, 32])), (1, 1, Some([8, 8]))]);

    for scene in [&cornell, &spiral, &ajar, &glossy] {
        let g = scene.flatten();
        let n = g.positions.len();
        assert_eq!((g.normals.len(), g.uvs.len()), (n, n));
        assert_eq!(g.indices.len(), scene.triangle_count());
        assert_eq!(g.triangle_material.len(), g.indices.len());
        assert_eq!(g.triangle_mesh.len(), g.indices.len());
        assert!(g.indices.iter().flatten().all(|&i| (i as usize) < n));
        assert!(g.triangle_material.iter().all(|&m| (m as usize) < scene.materials.len()));
        // The material follows the mesh a triangle came from.
        for (t, &mesh) in g.triangle_mesh.iter().enumerate() {
            assert_eq!(g.triangle_material[t] as usize, scene.meshes[mesh as usize].material);
        }
    }
    assert_ne!(cornell.content_hash(), spiral.content_hash());
}

#[test]
fn defaults_and_resolved_parameters() {
    let text = format!(
        "{BASE}\n[[materials]]\nname = \"glow\"\ntype = \"diffuse\"\nbase_color = [0, 0, 0]\n\
         [[meshes]]\nname = \"lamp\"\nfile = \"bare.obj\"\nmaterial = \"glow\"\nemission = [2, 2, 2]\n\
         [environment]\nfile = \"tex.exr\"\nscale = 2\n\n[optimise]\noptimiser = \"adam\"\n\
         [[optimise.params]]\ntarget = \"materials.m.roughness\"\ninit = 0.25\nrange = [0, 1]\ntexture = [16, 8]\n\
         [[optimise.params]]\ntarget = \"meshes.lamp.emission\"\ninit = 1\nrange = [0, 10]\nlr = 0.5\n\
         [[optimise.params]]\ntarget = \"environment\"\ninit = [1, 2, 3]\nrange = [0, 4]\ntexture = [8, 4]\n"
    );
    let scene = Scene::load(fixture("defaults", &text)).unwrap();
    assert_eq!((scene.integrator.max_depth, scene.integrator.rr_depth), (6, 5));
    let o = &scene.optimise;
    // The scene's settings layer holds what it sets; the rest are the defaults.
    let run = vkinverse::settings::RunSettings::of_scene(&scene);
    assert_eq!((run.iterations, run.spp, run.fd_spp, run.primal_spp, run.lr, run.seed), (Some(500), 2, 1, 4, 0.02, 0));
    assert_eq!(o.settings.optimiser.as_ref().map(|s| s.label.as_str()), Some("adam"));
    assert_eq!(o.settings.loss, None);
    assert_eq!(run.loss.as_str(), "l2");
    let [rough, emission, env] = &o.params[..] else { panic!("three params expected") };
    assert_eq!((rough.target, rough.shape.channels(), rough.shape.texture_size()), (ParamTarget::Roughness { material: 0 }, 1, Some([16, 8])));
    assert!(matches!(&rough.reference, Reference::Constant(v) if v == &[0.5]));
    assert_eq!((emission.target, emission.init.as_slice(), emission.lr), (ParamTarget::Emission { mesh: 1 }, &[1.0; 3][..], Some(0.5)));
    assert!(matches!(&emission.reference, Reference::Constant(v) if v == &[2.0; 3]));
    assert_eq!(env.target, ParamTarget::Environment);
    assert!(matches!(&env.reference, Reference::Texture(t) if t.image.get(3, 3) == [0.25, 0.5, 0.75]));
    assert_eq!(scene.environment.scale, 2.0);
}

#[test]
fn content_hash_follows_the_reference_scene_only() {
    let base = Scene::load(fixture("hash-a", BASE)).unwrap().content_hash();
    assert_eq!(base, Scene::load(fixture("hash-a", BASE)).unwrap().content_hash());
    let optimise = format!("# comment\n{BASE}\n[optimise]\nlr = 0.5\n");
    assert_eq!(base, Scene::load(fixture("hash-b", &optimise)).unwrap().content_hash());
    let film = BASE.replace("height = 8", "height = 9");
    assert_ne!(base, Scene::load(fixture("hash-c", &film)).unwrap().content_hash());
    let path = fixture("hash-d", BASE);
    fs::write(path.with_file_name("tri.obj"), TRIANGLE.replace("v 0 1 0", "v 0 2 0")).unwrap();
    assert_ne!(base, Scene::load(&path).unwrap().content_hash());
    // A normal map, its scale and its convention are part of the reference scene.
    let mapped = |name: &str, map: &str| {
        Scene::load(fixture(name, &BASE.replace("base_color = [0.5, 0.5, 0.5]", &format!("base_color = [0.5, 0.5, 0.5]\nnormal_map = {map}"))))
            .unwrap()
            .content_hash()
    };
    let plain = mapped("hash-e", "{ texture = \"tex.exr\" }");
    assert_ne!(base, plain);
    assert_ne!(plain, mapped("hash-f", "{ texture = \"tex.exr\", scale = 0.5 }"));
    assert_ne!(plain, mapped("hash-g", "{ texture = \"tex.exr\", bitangent = \"cross\" }"));
    assert_eq!(plain, mapped("hash-h", "{ texture = \"tex.exr\", bitangent = \"uv\", scale = 1 }"));
    // An emission texture is too; a constant emission hashes as its values.
    let emitting = |name: &str, emission: &str| Scene::load(fixture(name, &format!("{BASE}emission = {emission}\n"))).unwrap().content_hash();
    let textured = emitting("hash-i", "{ texture = \"tex.exr\" }");
    assert_ne!(textured, base);
    assert_ne!(textured, emitting("hash-j", "[0.25, 0.5, 0.75]"));
    assert_eq!(emitting("hash-k", "[0, 0, 0]"), base, "no emission and black emission hash alike");
    // An alpha test and its cutoff are too.
    let cut = |name: &str, alpha: &str| {
        Scene::load(fixture(name, &BASE.replace("base_color = [0.5, 0.5, 0.5]", &format!("base_color = [0.5, 0.5, 0.5]\n{alpha}")))).unwrap().content_hash()
    };
    let masked = cut("hash-l", "alpha = { texture = \"tex.exr\" }");
    assert_ne!(masked, base);
    assert_ne!(masked, cut("hash-m", "alpha = { texture = \"tex.exr\" }\nalpha_cutoff = 0.3"));
    assert_eq!(masked, cut("hash-n", "alpha = { texture = \"tex.exr\" }\nalpha_cutoff = 0.5"), "0.5 is the default cutoff");
    assert_ne!(masked, cut("hash-o", "alpha = 0.25"));
    assert_ne!(masked, cut("hash-p", "alpha = { texture = \"tex.exr\" }\nalpha_mode = \"blend\""));
    assert_eq!(masked, cut("hash-q", "alpha = { texture = \"tex.exr\" }\nalpha_mode = \"mask\""), "mask is the default mode");
    // A dielectric's index of refraction is too; rough glass is another kind, and its
    // roughness and distribution count.
    let hash = |name: &str, material: &str| Scene::load(fixture(name, &BASE.replace("type = \"principled\"", material))).unwrap().content_hash();
    let glass = |name: &str, keys: &str| hash(name, &format!("type = \"dielectric\"{keys}"));
    let bk7 = glass("hash-r", "");
    assert_ne!(bk7, base);
    assert_eq!(bk7, glass("hash-s", "\nior = 1.5"), "1.5 is the default index");
    assert_ne!(bk7, glass("hash-t", "\nior = 1.33"));
    assert_ne!(bk7, glass("hash-u", "\nabsorption = [0, 0, 0.5]"));
    assert_eq!(bk7, glass("hash-v", "\nabsorption = [0, 0, 0]"), "no absorption hashes as none");
    let rough = |name: &str, keys: &str| hash(name, &format!("type = \"rough_dielectric\"{keys}"));
    let frosted = rough("hash-w", "");
    assert_ne!(frosted, bk7);
    assert_eq!(frosted, rough("hash-x", "\nroughness = 0.3"), "0.3 is the default roughness");
    assert_ne!(frosted, rough("hash-y", "\nroughness = 0.5"));
    assert_eq!(frosted, rough("hash-z", "\ndistribution = \"ggx\""), "GGX is the default distribution");
    assert_ne!(frosted, rough("hash-za", "\ndistribution = \"beckmann\""));
    // A conductor's complex index counts, and a named metal hashes as its index.
    let metal = |name: &str, keys: &str| hash(name, &format!("type = \"conductor\"{keys}"));
    let gold = metal("hash-zb", "\nmetal = \"Au\"");
    assert_ne!(gold, metal("hash-zc", "\nmetal = \"Cu\""));
    assert_ne!(gold, metal("hash-zd", "\nmetal = \"Au\"\ndistribution = \"beckmann\""));
    let [eta, k] = vkinverse::scene::metal("Au").unwrap();
    assert_eq!(gold, metal("hash-ze", &format!("\neta = {eta:?}\nk = {k:?}")), "a named metal is its index");
    assert_ne!(gold, metal("hash-zf", &format!("\neta = {eta:?}\nk = [1, 1, 1]")));
    assert_eq!(metal("hash-zg", ""), metal("hash-zh", "\nmetal = \"none\""), "\"none\" is the default metal");
}

/// Emission is a colour or an EXR texture of texels that are not negative, on a mesh with
/// texture coordinates; an optimised emission texture needs them too.
#[test]
fn emission_textures_are_checked() {
    let emitting = |mesh: &str, emission: &str| BASE.replace("file = \"tri.obj\"", &format!("file = \"{mesh}\"\nemission = {emission}"));
    let s = Scene::load(fixture("emission-texture", &emitting("tri.obj", "{ texture = \"tex.exr\" }"))).unwrap();
    let ColorValue::Texture(t) = &s.meshes[0].emission else { panic!("a textured emission: {:?}", s.meshes[0].emission) };
    assert_eq!((t.image.width, t.image.height), (4, 4));
    let err = bad_texel("emission-negative", &emitting("tri.obj", "{ texture = \"glow.exr\" }"), "glow.exr", (2, 2), [1.0; 3], (2, 1), -0.5);
    assert!(matches!(err, SceneError::OutOfRange { .. }), "{err:?}");
    assert_message(&err, &["meshes.tri.emission.texture", "glow.exr", "-0.5", "(0, 1)"]);
    assert_message(&load_err("emission-missing", &emitting("tri.obj", "{ texture = \"none.exr\" }")), &["meshes.tri.emission.texture", "none.exr"]);
    assert_message(&load_err("emission-negative-constant", &emitting("tri.obj", "[1, -1, 1]")), &["meshes.tri.emission", "negative"]);
    assert_message(&load_err("emission-malformed", &emitting("tri.obj", "\"glow.exr\"")), &["expected [r, g, b] or { texture"]);
    let err = load_err("emission-no-uvs", &emitting("bare.obj", "{ texture = \"tex.exr\" }"));
    assert!(matches!(err, SceneError::Invalid { .. }), "{err:?}");
    assert_message(&err, &["meshes.bare", "its emission is textured", "texture coordinates"]);
    let optimised = format!(
        "{}\n[optimise]\n[[optimise.params]]\ntarget = \"meshes.bare.emission\"\ninit = 1\nrange = [0, 4]\ntexture = [2, 2]\n",
        emitting("bare.obj", "[1, 1, 1]")
    );
    assert_message(&load_err("emission-param-no-uvs", &optimised), &["meshes.bare", "its emission is textured", "texture coordinates"]);
    // With texture coordinates the same parameter loads, its reference the scene's texture.
    let optimised = format!(
        "{}\n[optimise]\n[[optimise.params]]\ntarget = \"meshes.tri.emission\"\ninit = 1\nrange = [0, 4]\ntexture = [2, 2]\n",
        emitting("tri.obj", "{ texture = \"tex.exr\" }")
    );
    let s = Scene::load(fixture("emission-param", &optimised)).unwrap();
    assert!(matches!(s.optimise.params[0].reference, Reference::Texture(_)));
    assert_eq!(vkinverse::render::ParamLayout::new(&s).initial().len(), 12, "2 × 2 texels of 3 channels");
}

/// A second set of texture coordinates: `uv1` per triangle corner, read by textures with
/// `uv_set = 1`. A vertex whose corners differ in it is split; a set other than 0 or 1, a
/// texture reading set 1 on a mesh without one, and a `uv1` array of the wrong shape or
/// with a non-finite value are one-line errors naming the key (and the file).
#[test]
fn second_texture_coordinates_are_checked() {
    let quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n";
    let scene = |set: &str, uv1: &str| {
        BASE.replace("base_color = [0.5, 0.5, 0.5]", &format!("base_color = {{ texture = \"tex.exr\"{set} }}"))
            .replace("file = \"tri.obj\"", &format!("file = \"quad.obj\"{uv1}"))
    };
    let write = |name: &str, text: &str, corners: Option<(Vec<usize>, Vec<f32>)>| {
        let path = fixture(name, text);
        fs::write(path.with_file_name("quad.obj"), quad).unwrap();
        if let Some((shape, data)) = corners {
            vkinverse::npy::write(&path.with_file_name("uv1.npy"), &vkinverse::npy::Array { shape, data }).unwrap();
        }
        path
    };
    // Vertex 1 (a corner of both triangles) has (0.5, 0.5) in one and (0.9, 0.1) in the other.
    let corners: Vec<f32> = [[0.5, 0.5], [0.1, 0.2], [0.3, 0.4], [0.9, 0.1], [0.3, 0.4], [0.7, 0.8]].concat();
    let s = Scene::load(write("uv1", &scene(", uv_set = 1", "\nuv1 = \"uv1.npy\""), Some((vec![2, 3, 2], corners.clone())))).unwrap();
    let m = &s.meshes[0];
    assert_eq!((m.positions.len(), m.uvs.len(), m.uvs1.len()), (5, 5, 5), "vertex 1 split in two");
    assert_eq!(m.corner_uvs1().as_flattened().as_flattened(), &corners[..], "the corners read back");
    assert_eq!(m.indices[1][0], 4, "the second triangle's first corner is the copy");
    assert_eq!(m.positions[4], m.positions[0]);
    let ColorValue::Texture(t) = &s.materials[0].base_color else { panic!("a texture") };
    assert_eq!(t.uv_set, 1);
    for (name, set, uv1, array, needles) in [
        ("uv-set-2", ", uv_set = 2", "", None, &["materials.m.base_color.uv_set", "2 is not 0 or 1"][..]),
        ("uv1-missing", ", uv_set = 1", "", None, &["meshes.quad", "tex.exr", "texture coordinate set 1", "quad.obj"][..]),
        ("uv1-shape", "", "\nuv1 = \"uv1.npy\"", Some((vec![2, 2, 3], corners.clone())), &["meshes.quad.uv1", "uv1.npy", "[2, 3, 2]"][..]),
        ("uv1-nan", "", "\nuv1 = \"uv1.npy\"", Some((vec![2, 3, 2], [&corners[..11], &[f32::NAN]].concat())), &["meshes.quad.uv1", "NaN"][..]),
        ("uv1-absent", "", "\nuv1 = \"none.npy\"", None, &["meshes.quad.uv1", "none.npy"][..]),
    ] {
        let err = Scene::load(write(name, &scene(set, uv1), array)).map(|_| ()).unwrap_err();
        assert_message(&err, needles);
    }
}

/// A medium's fixed `majorant` bounds its density: below a voxel's value or below the
/// range top of its density parameter, it is refused naming the key; at or above, the
/// scene loads with it.
#[test]
fn a_fixed_majorant_bounds_the_density() {
    let medium = |majorant: &str, optimise: &str| {
        format!("{BASE}\n[[media]]\nname = \"fog\"\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\ndensity = 2.0\nalbedo = 0.5\n{majorant}\n{optimise}")
    };
    let param = "[optimise]\n[[optimise.params]]\ntarget = \"media.fog.density\"\ninit = 1\nrange = [0, 8]\n";
    let s = Scene::load(fixture("majorant", &medium("majorant = 8", param))).unwrap();
    assert_eq!(s.media[0].majorant, Some(8.0));
    assert_message(&load_err("majorant-density", &medium("majorant = 1.5", "")), &["media.fog.majorant", "1.5 is below the density's 2"]);
    assert_message(&load_err("majorant-range", &medium("majorant = 4", param)), &["media.fog.majorant", "below the range top 8", "media.fog.density"]);
    assert_message(&load_err("majorant-zero", &medium("majorant = 0", "")), &["media.fog.majorant"]);
}

#[test]
fn toml_syntax_error_names_the_line() {
    let err = load_err("syntax", &BASE.replace("height = 8", "height = = 8"));
    assert!(matches!(err, SceneError::Toml { line: 3, .. }), "{err:?}");
    assert_message(&err, &["scene.toml:3:"]);
}

#[test]
fn unknown_key_is_named() {
    let err = load_err("unknown", &BASE.replace("fov_y = 40", "fov_y = 40\nfocus = 2"));
    assert!(matches!(err, SceneError::Toml { line: 9, .. }), "{err:?}");
    assert_message(&err, &["scene.toml:9:", "unknown field `focus`"]);
    let err = load_err("bad-type", &BASE.replace("base_color = [0.5, 0.5, 0.5]", "base_color = \"red\""));
    assert_message(&err, &["scene.toml:13:", "texture"]);
}

#[test]
fn missing_files_name_key_and_path() {
    let err = load_err("missing-obj", &BASE.replace("tri.obj", "nope.obj"));
    assert!(matches!(err, SceneError::MissingFile { .. }), "{err:?}");
    assert_message(&err, &["scene.toml", "meshes.nope.file", "nope.obj"]);

    let tex = BASE.replace("[0.5, 0.5, 0.5]", "{ texture = \"absent.exr\" }");
    let err = load_err("missing-tex", &tex);
    assert!(matches!(err, SceneError::MissingFile { .. }), "{err:?}");
    assert_message(&err, &["scene.toml", "materials.m.base_color.texture", "absent.exr"]);

    let err = load_err("missing-target", &BASE.replace("fov_y = 40", "fov_y = 40\ntarget_image = \"t.exr\""));
    assert_message(&err, &["sensors[0].target_image", "t.exr"]);
    assert!(matches!(Scene::load("/nonexistent/scene.toml"), Err(SceneError::ReadScene { .. })));
}

#[test]
fn malformed_obj_names_file_and_line() {
    for (name, obj, line, needle) in [
        ("obj-index", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4, "vertex index 4"),
        ("obj-nan", "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", 2, "non-finite"),
        ("obj-nofaces", "v 0 0 0\nv 1 0 0\nv 0 1 0\n", 0, "no faces"),
    ] {
        let path = fixture(name, BASE);
        fs::write(path.with_file_name("tri.obj"), obj).unwrap();
        let err = Scene::load(&path).unwrap_err();
        assert!(matches!(err, SceneError::Obj { line: l, .. } if l == line), "{err:?}");
        let located = if line > 0 { format!("tri.obj:{line}:") } else { "tri.obj:".into() };
        assert_message(&err, &[&located, needle]);
    }
}

#[test]
fn exr_without_rgb_is_named() {
    use exr::prelude::{SpecificChannels, WritableImage};
    let path = fixture("exr-y", &BASE.replace("[0.5, 0.5, 0.5]", "{ texture = \"y.exr\" }"));
    let channels = SpecificChannels::build().with_channel("Y").with_pixel_fn(|_| (0.5f32,));
    exr::prelude::Image::from_channels((2, 2), channels).write().to_file(path.with_file_name("y.exr")).unwrap();
    let err = Scene::load(&path).unwrap_err();
    assert!(matches!(err, SceneError::Image { source: vkinverse::image::ImageError::MissingRgb { .. }, .. }), "{err:?}");
    assert_message(&err, &["scene.toml", "materials.m.base_color.texture", "y.exr", "Y"]);
}

#[test]
fn non_finite_values_are_rejected() {
    let err = bad_texel("nan-pixel", &BASE.replace("[0.5, 0.5, 0.5]", "{ texture = \"nan.exr\" }"), "nan.exr", (3, 2), [0.1; 3], (4, 1), f32::INFINITY);
    assert!(matches!(err, SceneError::NonFinitePixel { x: 1, y: 1, .. }), "{err:?}");
    assert_message(&err, &["materials.m.base_color.texture", "nan.exr", "(1, 1)"]);

    let err = load_err("nan-color", &BASE.replace("[0.5, 0.5, 0.5]", "[0.5, nan, 0.5]"));
    assert!(matches!(err, SceneError::NonFinite { .. }), "{err:?}");
    assert_message(&err, &["scene.toml", "materials.m.base_color"]);

    let err = load_err("nan-init", &with_optimise("target = \"materials.m.base_color\"\ninit = nan\nrange = [0, 1]"));
    assert!(matches!(err, SceneError::NonFinite { .. }), "{err:?}");
    assert_message(&err, &["optimise.params[0].init"]);
}

#[test]
fn film_size_and_fov_are_bounded() {
    for (name, from, to, key) in [
        ("film-zero", "width = 8", "width = 0", "film.width"),
        ("film-huge", "height = 8", "height = 20000", "film.height"),
        ("fov-zero", "fov_y = 40", "fov_y = 0", "sensors[0].fov_y"),
        ("fov-180", "fov_y = 40", "fov_y = 180", "sensors[0].fov_y"),
        ("roughness", "type = \"principled\"", "type = \"principled\"\nroughness = 1.5", "materials.m.roughness"),
    ] {
        let err = load_err(name, &BASE.replace(from, to));
        assert!(matches!(err, SceneError::OutOfRange { .. }), "{name}: {err:?}");
        assert_message(&err, &["scene.toml", key]);
    }
    // A sensor is a pinhole camera (fov_y) or an orthographic one (ortho_height), one of
    // the two.
    for (name, to, key) in [
        ("fov-missing", "", "sensors[0].fov_y"),
        ("fov-and-ortho", "fov_y = 40\northo_height = 2", "sensors[0]"),
        ("ortho-zero", "ortho_height = 0", "sensors[0].ortho_height"),
        ("ortho-nan", "ortho_height = nan", "sensors[0].ortho_height"),
    ] {
        assert_message(&load_err(name, &BASE.replace("fov_y = 40", to)), &["scene.toml", key]);
    }
    assert_eq!(Scene::load(fixture("ortho", &BASE.replace("fov_y = 40", "ortho_height = 2.5"))).unwrap().sensors[0].ortho_height, Some(2.5));
    // The pixel filter: a known name, its own size key only, in range; the box's hash is
    // the scene's without the key, the others' differ and `hide_emitters` changes it too.
    use vkinverse::scene::PixelFilter;
    for (name, to, key) in [
        ("filter-name", "filter = \"lanczos\"", "film.filter"),
        ("filter-stddev-zero", "filter = \"gaussian\"\nfilter_stddev = 0", "film.filter_stddev"),
        ("filter-stddev-wide", "filter = \"gaussian\"\nfilter_stddev = 5", "film.filter_stddev"),
        ("filter-radius-nan", "filter = \"tent\"\nfilter_radius = nan", "film.filter_radius"),
        ("filter-wrong-size", "filter = \"tent\"\nfilter_stddev = 1", "film.filter_stddev"),
        ("filter-size-alone", "filter_radius = 1", "film.filter_radius"),
    ] {
        assert_message(&load_err(name, &BASE.replace("height = 8", &format!("height = 8\n{to}"))), &["scene.toml", key]);
    }
    let load = |name: &str, to: &str| Scene::load(fixture(name, &BASE.replace("height = 8", &format!("height = 8\n{to}")))).unwrap();
    let plain = Scene::load(fixture("filter-none", BASE)).unwrap();
    assert_eq!(plain.pixel_filter, PixelFilter::Box);
    assert_eq!(load("filter-box", "filter = \"box\"").content_hash(), plain.content_hash());
    let gaussian = load("filter-gaussian", "filter = \"gaussian\"");
    assert_eq!(gaussian.pixel_filter, PixelFilter::Gaussian { stddev: 0.5 });
    let tent = load("filter-tent", "filter = \"tent\"\nfilter_radius = 2");
    assert_eq!(tent.pixel_filter, PixelFilter::Tent { radius: 2.0 });
    assert!(gaussian.content_hash() != plain.content_hash() && tent.content_hash() != plain.content_hash() && tent.content_hash() != gaussian.content_hash());
    let hidden = Scene::load(fixture("hide-emitters", &BASE.replace("[film]", "[integrator]\nhide_emitters = true\n[film]"))).unwrap();
    assert!(hidden.integrator.hide_emitters && hidden.content_hash() != plain.content_hash());
    // A thin lens takes an aperture and a distance of focus, both positive, on a pinhole.
    for (name, to, key) in [
        ("lens-no-focus", "fov_y = 40\naperture_radius = 0.1", "sensors[0].focus_distance"),
        ("lens-no-aperture", "fov_y = 40\nfocus_distance = 2", "sensors[0].aperture_radius"),
        ("lens-zero", "fov_y = 40\naperture_radius = 0\nfocus_distance = 2", "sensors[0].aperture_radius"),
        ("lens-ortho", "ortho_height = 2\naperture_radius = 0.1\nfocus_distance = 2", "orthographic"),
    ] {
        assert_message(&load_err(name, &BASE.replace("fov_y = 40", to)), &["scene.toml", key]);
    }
}

#[test]
fn names_must_be_defined_and_unique() {
    let err = load_err("undefined-material", &BASE.replace("material = \"m\"", "material = \"wall\""));
    assert!(matches!(err, SceneError::Undefined { kind: "material", .. }), "{err:?}");
    assert_message(&err, &["scene.toml", "meshes.tri.material", "\"wall\"", "the scene has \"m\""]);

    let dup = BASE.replace("[[meshes]]", "[[materials]]\nname = \"m\"\ntype = \"diffuse\"\nbase_color = [1, 1, 1]\n\n[[meshes]]");
    let err = load_err("duplicate-material", &dup);
    assert!(matches!(err, SceneError::Duplicate { .. }), "{err:?}");
    assert_message(&err, &["materials[1].name", "\"m\""]);

    let err = load_err("duplicate-mesh", &format!("{BASE}\n[[meshes]]\nfile = \"tri.obj\"\nmaterial = \"m\"\n"));
    assert!(matches!(err, SceneError::Duplicate { .. }), "{err:?}");
    assert_message(&err, &["meshes[1]", "\"tri\""]);
}

#[test]
fn optimise_targets_must_exist() {
    let err = load_err("target-material", &with_optimise("target = \"materials.wall.base_color\"\ninit = 0.5\nrange = [0, 1]"));
    assert!(matches!(err, SceneError::Undefined { kind: "material", .. }), "{err:?}");
    assert_message(&err, &["optimise.params[0].target", "\"wall\"", "the scene has \"m\""]);

    let err = load_err("target-mesh", &with_optimise("target = \"meshes.lamp.emission\"\ninit = 0.5\nrange = [0, 1]"));
    assert!(matches!(err, SceneError::Undefined { kind: "mesh", .. }), "{err:?}");
    assert_message(&err, &["optimise.params[0].target", "\"lamp\"", "the scene has \"tri\""]);

    let err = load_err("target-property", &with_optimise("target = \"materials.m.colour\"\ninit = 0.5\nrange = [0, 1]"));
    assert!(matches!(err, SceneError::Invalid { .. }), "{err:?}");
    assert_message(&err, &["optimise.params[0].target", "materials.m.colour"]);

    let twice = "target = \"materials.m.metallic\"\ninit = 0.5\nrange = [0, 1]\n[[optimise.params]]\n\
                 target = \"materials.m.metallic\"\ninit = 0.5\nrange = [0, 1]";
    let err = load_err("target-twice", &with_optimise(twice));
    assert!(matches!(err, SceneError::Duplicate { .. }), "{err:?}");
    assert_message(&err, &["optimise.params[1].target"]);
}

#[test]
fn init_and_range_are_checked() {
    let err = load_err("init-outside", &with_optimise("target = \"materials.m.base_color\"\ninit = [0.5, 1.5, 0.5]\nrange = [0, 1]"));
    assert!(matches!(err, SceneError::OutOfRange { .. }), "{err:?}");
    assert_message(&err, &["optimise.params[0].init", "1.5"]);

    let err = load_err("range-empty", &with_optimise("target = \"materials.m.base_color\"\ninit = 0.5\nrange = [1, 1]"));
    assert!(matches!(err, SceneError::OutOfRange { .. }), "{err:?}");
    assert_message(&err, &["optimise.params[0].range"]);

    let err = load_err("init-channels", &with_optimise("target = \"materials.m.roughness\"\ninit = [0.5, 0.5, 0.5]\nrange = [0, 1]"));
    assert!(matches!(err, SceneError::Invalid { .. }), "{err:?}");
    assert_message(&err, &["optimise.params[0].init"]);
}

#[test]
fn inconsistent_scenes_are_rejected() {
    let no_uvs = BASE.replace("tri.obj", "bare.obj").replace("[0.5, 0.5, 0.5]", "{ texture = \"tex.exr\" }");
    let err = load_err("no-uvs", &no_uvs);
    assert!(matches!(err, SceneError::Invalid { .. }), "{err:?}");
    assert_message(&err, &["meshes.bare", "texture coordinates"]);

    let textured = BASE.replace("[0.5, 0.5, 0.5]", "{ texture = \"tex.exr\" }");
    let needs_texture = format!("{textured}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.base_color\"\ninit = 0.5\nrange = [0, 1]\n");
    let err = load_err("param-texture", &needs_texture);
    assert_message(&err, &["optimise.params[0]", "texture = [w, h]"]);

    let err = load_err("env-both", &format!("{BASE}\n[environment]\nconstant = [1, 1, 1]\nfile = \"tex.exr\"\n"));
    assert_message(&err, &["scene.toml", "environment", "exactly one"]);

    let err = load_err("diffuse-roughness", &BASE.replace("\"principled\"", "\"diffuse\"\nroughness = 0.3"));
    assert_message(&err, &["materials.m", "diffuse"]);

    let sized = BASE.replace("fov_y = 40", "fov_y = 40\ntarget_image = \"tex.exr\"");
    let err = load_err("target-size", &sized);
    assert_message(&err, &["sensors[0].target_image", "4x4", "8x8"]);
    assert!(Scene::load(fixture("target-ok", &sized.replace("width = 8\nheight = 8", "width = 4\nheight = 4"))).is_ok());
}

#[test]
fn lights_and_imports_are_checked() {
    let light = |body: &str| format!("{BASE}\n[[lights]]\nname = \"key\"\n{body}\n");
    let cases: [(&str, String, &[&str]); 6] = [
        ("spot-direction", light("type = \"spot\"\nposition = [0, 1, 0]"), &["lights.key", "needs `direction`"]),
        ("point-position", light("type = \"point\""), &["lights.key", "needs `position`"]),
        ("cone", light("type = \"spot\"\nposition = [0, 1, 0]\ndirection = [0, -1, 0]\ninner_angle = 40\nouter_angle = 30"), &["lights.key", "cone angles"]),
        ("point-cone", light("type = \"point\"\nposition = [0, 1, 0]\nouter_angle = 30"), &["lights.key", "only spot lights"]),
        ("negative", light("type = \"directional\"\ndirection = [0, -1, 0]\nintensity = -1"), &["lights.key.intensity", "negative"]),
        ("zero-direction", light("type = \"directional\"\ndirection = [0, 0, 0]"), &["lights.key.direction", "zero"]),
    ];
    for (name, text, needles) in &cases {
        assert_message(&load_err(name, text), needles);
    }
    let twice = format!("{}[[lights]]\nname = \"key\"\ntype = \"point\"\nposition = [0, 2, 0]\n", light("type = \"point\"\nposition = [0, 1, 0]"));
    assert_message(&load_err("light-twice", &twice), &["lights[1].name", "\"key\" is defined more than once"]);
    let target =
        |t: &str| format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"{t}\"\ninit = 1\nrange = [0, 2]\n", light("type = \"point\"\nposition = [0, 1, 0]"));
    assert_message(&load_err("light-property", &target("lights.key.radius")), &["optimise.params[0].target", "lights.NAME.color|intensity"]);
    assert_message(&load_err("light-undefined", &target("lights.fill.intensity")), &["no light named \"fill\""]);
    let ok = Scene::load(fixture("light-ok", &target("lights.key.intensity"))).unwrap();
    assert_eq!(ok.optimise.params[0].target, ParamTarget::LightIntensity { light: 0 });
    // An imported file must be glTF or Mitsuba XML, and readable.
    assert_message(&load_err("import-ext", &format!("import = \"tri.obj\"\n{BASE}")), &["scene.toml", "import", "tri.obj", ".gltf, .glb or .xml"]);
    assert_message(&load_err("import-missing", &format!("import = \"none.gltf\"\n{BASE}")), &["none.gltf", "cannot read scene"]);
}

#[test]
fn texture_values_obey_the_rules_of_constants() {
    // A roughness texture is held to [0, 1] as a roughness constant is.
    let rough = BASE.replace("base_color = [0.5, 0.5, 0.5]", "base_color = [0.5, 0.5, 0.5]\nroughness = { texture = \"rough.exr\" }");
    let err = bad_texel("rough-range", &rough, "rough.exr", (3, 2), [0.5; 3], (5, 0), 1.5);
    assert!(matches!(err, SceneError::OutOfRange { .. }), "{err:?}");
    assert_message(&err, &["materials.m.roughness.texture", "rough.exr", "1.5", "(2, 1)", "[0, 1]"]);
    // A colour texture, like a colour, is non-negative.
    let err = bad_texel("color-range", &BASE.replace("[0.5, 0.5, 0.5]", "{ texture = \"neg.exr\" }"), "neg.exr", (2, 2), [0.5; 3], (1, 2), -0.25);
    assert_message(&err, &["materials.m.base_color.texture", "-0.25", "(1, 0)"]);
    // A texture's filter is "bilinear" (the default) or "nearest".
    use vkinverse::scene::Filter;
    let with = |value: &str| BASE.replace("base_color = [0.5, 0.5, 0.5]", &format!("base_color = {value}"));
    let nearest = Scene::load(fixture("filter-nearest", &with("{ texture = \"tex.exr\", filter = \"nearest\" }"))).unwrap();
    assert_eq!(nearest.materials[0].base_color.filter(), Filter::Nearest);
    let s = Scene::load(fixture("filter-default", &with("{ texture = \"tex.exr\" }"))).unwrap();
    assert_eq!(s.materials[0].base_color.filter(), Filter::Bilinear);
    assert_ne!(nearest.content_hash(), s.content_hash(), "the filter changes the render");
    let named = Scene::load(fixture("filter-bilinear", &with("{ texture = \"tex.exr\", filter = \"bilinear\" }"))).unwrap();
    assert_eq!(named.content_hash(), s.content_hash(), "bilinear is the default");
    assert_message(
        &load_err("filter-unknown", &with("{ texture = \"tex.exr\", filter = \"cubic\" }")),
        &["materials.m.base_color.filter", "\"cubic\"", "\"bilinear\" or \"nearest\""],
    );
    let nmap = BASE.replace("base_color = [0.5, 0.5, 0.5]", "base_color = [0.5, 0.5, 0.5]\nnormal_map = { texture = \"tex.exr\", filter = \"nearest\" }");
    assert_eq!(Scene::load(fixture("filter-nmap", &nmap)).unwrap().materials[0].normal_map().unwrap().texture.filter, Filter::Nearest);
    assert_message(&load_err("filter-nmap-unknown", &nmap.replace("nearest", "box")), &["materials.m.normal_map.filter", "\"box\""]);
    // Its wrap modes: one for both axes or [u, v], each "repeat" (the default), "clamp" or "mirror".
    use vkinverse::scene::Wrap;
    let s = Scene::load(fixture("wrap-one", &with("{ texture = \"tex.exr\", wrap = \"clamp\" }"))).unwrap();
    assert_eq!(s.materials[0].base_color.wrap(), [Wrap::Clamp; 2]);
    let pair = Scene::load(fixture("wrap-pair", &with("{ texture = \"tex.exr\", wrap = [\"mirror\", \"repeat\"] }"))).unwrap();
    assert_eq!(pair.materials[0].base_color.wrap(), [Wrap::Mirror, Wrap::Repeat]);
    assert_ne!(pair.content_hash(), named.content_hash(), "the wrap modes change the render");
    assert_message(
        &load_err("wrap-unknown", &with("{ texture = \"tex.exr\", wrap = \"border\" }")),
        &["materials.m.base_color.wrap", "\"border\"", "\"clamp\""],
    );
    assert_message(&load_err("wrap-three", &with("{ texture = \"tex.exr\", wrap = [\"clamp\", \"clamp\", \"clamp\"] }")), &["scene.toml:13", "texture"]);
    let nmap_wrap = nmap.replace("filter = \"nearest\"", "wrap = [\"repeat\", \"clamp\"]");
    assert_eq!(Scene::load(fixture("wrap-nmap", &nmap_wrap)).unwrap().materials[0].normal_map().unwrap().texture.wrap, [Wrap::Repeat, Wrap::Clamp]);
}

/// A normal map's texels encode unit vectors in [0, 1], its scale is finite and its
/// bitangent one of two conventions; a missing file is named with its key.
#[test]
fn normal_maps_are_checked() {
    let with = |map: &str| BASE.replace("base_color = [0.5, 0.5, 0.5]", &format!("base_color = [0.5, 0.5, 0.5]\nnormal_map = {map}"));
    let s = Scene::load(fixture("nmap-ok", &with("{ texture = \"tex.exr\", scale = 0.5, bitangent = \"cross\" }"))).unwrap();
    let n = s.materials[0].normal_map().unwrap();
    assert_eq!((n.scale, n.bitangent), (0.5, vkinverse::scene::Bitangent::Cross));
    assert_eq!(n.vectors()[0], [(0.5 - 1.0) * 0.5, 0.0, 0.5]);
    let err = bad_texel("nmap-range", &with("{ texture = \"bumps.exr\" }"), "bumps.exr", (2, 2), [0.5, 0.5, 1.0], (3, 2), 1.25);
    assert!(matches!(err, SceneError::OutOfRange { .. }), "{err:?}");
    assert_message(&err, &["materials.m.normal_map.texture", "bumps.exr", "1.25", "(1, 1)", "[0, 1]", "(n + 1) / 2"]);
    assert_message(&load_err("nmap-scale", &with("{ texture = \"tex.exr\", scale = nan }")), &["materials.m.normal_map.scale"]);
    assert_message(&load_err("nmap-bitangent", &with("{ texture = \"tex.exr\", bitangent = \"left\" }")), &["materials.m.normal_map.bitangent", "\"left\""]);
    assert_message(&load_err("nmap-missing", &with("{ texture = \"none.exr\" }")), &["materials.m.normal_map.texture", "none.exr"]);
    assert_message(&load_err("nmap-key", &with("{ texture = \"tex.exr\", strength = 2 }")), &["strength"]);
}

/// A bump map's heights are any finite numbers, its scale finite (1 by default); it takes
/// the texture keys `filter` and `wrap`, and cannot be combined with a normal map or put on
/// a dielectric; a missing file is named with its key. The map and its scale are part of
/// the hash; written back (`final/`), it loads as it was.
#[test]
fn bump_maps_are_checked() {
    use vkinverse::scene::{Filter, Wrap};
    let with = |map: &str| BASE.replace("base_color = [0.5, 0.5, 0.5]", &format!("base_color = [0.5, 0.5, 0.5]\nbump_map = {map}"));
    let s = Scene::load(fixture("bump-ok", &with("{ texture = \"tex.exr\", scale = 0.25, filter = \"nearest\", wrap = \"clamp\" }"))).unwrap();
    let b = s.materials[0].bump_map().unwrap();
    assert_eq!((b.scale, b.texture.filter, b.texture.wrap), (0.25, Filter::Nearest, [Wrap::Clamp; 2]));
    // tex.exr's texels are (0.25, 0.5, 0.75): the height is scale times their luminance.
    let luminance = 0.212671 * 0.25 + 0.715160 * 0.5 + 0.072169 * 0.75;
    assert!((b.heights()[0] - 0.25 * luminance).abs() < 1e-7, "{}", b.heights()[0]);
    assert_eq!(Scene::load(fixture("bump-default", &with("{ texture = \"tex.exr\" }"))).unwrap().materials[0].bump_map().unwrap().scale, 1.0);
    // Heights may be negative or large, not NaN (the image reader refuses it).
    let path = fixture("bump-negative", &with("{ texture = \"h.exr\" }"));
    write_exr(&path.with_file_name("h.exr"), &Image::filled(2, 2, [-3.0, 7.0, 0.5])).unwrap();
    assert!(Scene::load(&path).is_ok());
    let err = bad_texel("bump-nan", &with("{ texture = \"h.exr\" }"), "h.exr", (2, 2), [-3.0, 7.0, 0.5], (3, 1), f32::NAN);
    assert_message(&err, &["materials.m.bump_map.texture", "h.exr", "non-finite", "(1, 1)"]);
    assert_message(&load_err("bump-scale", &with("{ texture = \"tex.exr\", scale = inf }")), &["materials.m.bump_map.scale"]);
    assert_message(&load_err("bump-missing", &with("{ texture = \"none.exr\" }")), &["materials.m.bump_map.texture", "none.exr"]);
    assert_message(&load_err("bump-key", &with("{ texture = \"tex.exr\", bitangent = \"uv\" }")), &["bitangent"]);
    assert_message(&load_err("bump-filter", &with("{ texture = \"tex.exr\", filter = \"cubic\" }")), &["materials.m.bump_map.filter", "\"cubic\""]);
    let both = with("{ texture = \"tex.exr\" }\nnormal_map = { texture = \"tex.exr\" }");
    assert_message(&load_err("bump-and-normal", &both), &["materials.m.bump_map", "normal_map"]);
    let glass = with("{ texture = \"tex.exr\" }").replace("type = \"principled\"\nbase_color = [0.5, 0.5, 0.5]", "type = \"dielectric\"");
    assert_message(&load_err("bump-glass", &glass), &["materials.m.bump_map", "dielectric"]);
    // The hash: a map, its scale; written back, the same scene.
    let base = Scene::load(fixture("bump-hash-a", BASE)).unwrap().content_hash();
    let one = Scene::load(fixture("bump-hash-b", &with("{ texture = \"tex.exr\" }"))).unwrap();
    assert_ne!(base, one.content_hash());
    assert_ne!(one.content_hash(), Scene::load(fixture("bump-hash-c", &with("{ texture = \"tex.exr\", scale = 2 }"))).unwrap().content_hash());
    assert_eq!(one.content_hash(), Scene::load(fixture("bump-hash-d", &with("{ texture = \"tex.exr\", scale = 1 }"))).unwrap().content_hash());
    let out = std::env::temp_dir().join(format!("vkinverse-scene-tests-{}-bump-written", std::process::id()));
    vkinverse::scene::write::write_final(&out, &one, &[]).unwrap();
    let again = Scene::load(out.join("final/scene.toml")).unwrap();
    let b = again.materials[0].bump_map().expect("the written bump map");
    assert_eq!((b.scale, b.heights()), (1.0, one.materials[0].bump_map().unwrap().heights()));
}

/// An alpha is a number or an EXR texture in [0, 1], its mode "mask" (the default) or
/// "blend", and a mask's cutoff a number in [0, 1] (0.5 by default); mode and cutoff come
/// only with an alpha, and the alpha cannot be optimised.
#[test]
fn alpha_tests_are_checked() {
    let with = |alpha: &str| BASE.replace("base_color = [0.5, 0.5, 0.5]", &format!("base_color = [0.5, 0.5, 0.5]\n{alpha}"));
    let s = Scene::load(fixture("alpha-ok", &with("alpha = { texture = \"tex.exr\" }"))).unwrap();
    let a = s.materials[0].alpha.as_ref().unwrap();
    assert!(matches!(a.value, ScalarValue::Texture(_)) && a.mode == AlphaMode::Mask { cutoff: 0.5 }, "{a:?}");
    let s = Scene::load(fixture("alpha-constant", &with("alpha = 0.2\nalpha_cutoff = 0.1"))).unwrap();
    let a = s.materials[0].alpha.as_ref().unwrap();
    assert!(matches!(a.value, ScalarValue::Constant(v) if v == 0.2) && a.mode == AlphaMode::Mask { cutoff: 0.1 }, "{a:?}");
    let s = Scene::load(fixture("alpha-blend", &with("alpha = 0.2\nalpha_mode = \"blend\""))).unwrap();
    assert_eq!(s.materials[0].alpha.as_ref().unwrap().mode, AlphaMode::Blend);
    assert!(Scene::load(fixture("alpha-none", BASE)).unwrap().materials[0].alpha.is_none());
    let err = bad_texel("alpha-range", &with("alpha = { texture = \"mask.exr\" }"), "mask.exr", (2, 2), [1.0; 3], (1, 0), 1.5);
    assert!(matches!(err, SceneError::OutOfRange { .. }), "{err:?}");
    assert_message(&err, &["materials.m.alpha.texture", "mask.exr", "1.5", "(1, 0)", "[0, 1]"]);
    assert_message(&load_err("alpha-constant-range", &with("alpha = -0.5")), &["materials.m.alpha", "-0.5"]);
    assert_message(&load_err("alpha-missing", &with("alpha = { texture = \"none.exr\" }")), &["materials.m.alpha.texture", "none.exr"]);
    assert_message(&load_err("alpha-cutoff-range", &with("alpha = 0.5\nalpha_cutoff = 2")), &["materials.m.alpha_cutoff", "2"]);
    assert_message(&load_err("alpha-cutoff-nan", &with("alpha = 0.5\nalpha_cutoff = nan")), &["materials.m.alpha_cutoff"]);
    assert_message(&load_err("alpha-cutoff-alone", &with("alpha_cutoff = 0.5")), &["materials.m.alpha_cutoff", "needs an alpha"]);
    assert_message(&load_err("alpha-mode-alone", &with("alpha_mode = \"blend\"")), &["materials.m.alpha_mode", "needs an alpha"]);
    assert_message(
        &load_err("alpha-mode-unknown", &with("alpha = 0.5\nalpha_mode = \"add\"")),
        &["materials.m.alpha_mode", "\"add\"", "\"mask\" or \"blend\""],
    );
    assert_message(&load_err("alpha-blend-cutoff", &with("alpha = 0.5\nalpha_mode = \"blend\"\nalpha_cutoff = 0.5")), &["materials.m.alpha_cutoff", "blend"]);
    assert_message(&load_err("alpha-malformed", &with("alpha = \"mask.exr\"")), &["expected a number or { texture"]);
    let optimised = format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.alpha\"\ninit = 1\nrange = [0, 1]\n", with("alpha = 1"));
    assert_message(&load_err("alpha-param", &optimised), &["materials.m.alpha"]);
}

#[test]
fn optimise_settings_are_checked_by_the_one_validate() {
    let err = load_err("checkpoint-zero", &format!("{BASE}\n[optimise]\ncheckpoint_every = 0\n"));
    assert_message(&err, &["optimise.checkpoint_every", "at least 1"]);
    let err = load_err("seed-type", &format!("{BASE}\n[optimise]\nseed = 'x'\n"));
    assert_message(&err, &["scene.toml:20:8", "expected u64"]);
    let err = load_err("unknown-setting", &format!("{BASE}\n[optimise]\nsppp = 2\n"));
    assert_message(&err, &["scene.toml:20:1", "unknown field `sppp`"]);
    // A seed beyond 32 bits is kept whole.
    let scene = Scene::load(fixture("seed-u64", &format!("{BASE}\n[optimise]\nseed = 4294967296\noptimiser = 'adam@beta1=0.5'\n"))).unwrap();
    let run = vkinverse::settings::RunSettings::of_scene(&scene);
    assert_eq!(run.seed, 1 << 32);
    assert_eq!(run.optimiser.label, "adam@beta1=0.5");
}

#[test]
fn an_image_as_init_is_resampled_to_the_texture_and_checked() {
    // A 2×1 image (0.2 | 0.8) as the start of a 4×2 roughness texture: nearest texels.
    let dir =
        fixture("init-image", &with_optimise("target = \"materials.m.roughness\"\ninit = { texture = \"halves.exr\" }\nrange = [0, 1]\ntexture = [4, 2]"));
    let halves = Image { width: 2, height: 1, data: vec![[0.2, 0.9, 0.9], [0.8, 0.9, 0.9]] };
    write_exr(&dir.parent().unwrap().join("halves.exr"), &halves).unwrap();
    let scene = Scene::load(dir.clone()).unwrap();
    assert_eq!(scene.optimise.params[0].init, [0.2, 0.2, 0.8, 0.8, 0.2, 0.2, 0.8, 0.8]);
    // A start image has no filter of its own.
    let filtered = std::fs::read_to_string(&dir).unwrap().replace("{ texture = \"halves.exr\" }", "{ texture = \"halves.exr\", filter = \"nearest\" }");
    std::fs::write(&dir, filtered).unwrap();
    assert_message(&Scene::load(dir.clone()).unwrap_err(), &["init.filter", "start image"]);
    std::fs::write(&dir, std::fs::read_to_string(&dir).unwrap().replace(", filter = \"nearest\"", "")).unwrap();
    let layout = vkinverse::render::ParamLayout::new(&scene);
    assert_eq!(layout.initial(), scene.optimise.params[0].init);

    // Not a texture parameter.
    let err = load_err("init-image-constant", &with_optimise("target = \"materials.m.roughness\"\ninit = { texture = \"tex.exr\" }\nrange = [0, 1]"));
    assert_message(&err, &["init", "texture = [w, h]"]);
    // A missing image names its key and file.
    let err = load_err(
        "init-image-missing",
        &with_optimise("target = \"materials.m.roughness\"\ninit = { texture = \"nope.exr\" }\nrange = [0, 1]\ntexture = [2, 2]"),
    );
    assert!(matches!(err, SceneError::MissingFile { .. }), "{err:?}");
    assert_message(&err, &["init.texture", "nope.exr"]);
    // Texels outside the parameter's range (tex.exr holds 0.25, 0.5, 0.75).
    let err = load_err(
        "init-image-range",
        &with_optimise("target = \"materials.m.base_color\"\ninit = { texture = \"tex.exr\" }\nrange = [0, 0.6]\ntexture = [2, 2]"),
    );
    assert!(matches!(err, SceneError::OutOfRange { .. }), "{err:?}");
    assert_message(&err, &["init.texture", "0.75", "[0, 0.6]"]);
    // A malformed `init` says what it takes.
    let err = load_err("init-image-malformed", &with_optimise("target = \"materials.m.roughness\"\ninit = \"tex.exr\"\nrange = [0, 1]"));
    assert_message(&err, &["expected a number, [r, g, b] or", "file.exr"]);
}

/// A conductor: a white tint, roughness 0.3, GGX and the perfect mirror ("none") by
/// default; a named metal or `eta` and `k` together, finite and not negative; no metallic
/// (its reflectance comes from the index), optimisable tint and roughness; the index keys
/// only on a conductor.
#[test]
fn conductors_are_checked() {
    let metal = |extra: &str| BASE.replace("type = \"principled\"\nbase_color = [0.5, 0.5, 0.5]", &format!("type = \"conductor\"{extra}"));
    let s = Scene::load(fixture("metal-default", &metal(""))).unwrap();
    let m = &s.materials[0];
    assert_eq!((m.kind.as_str(), m.distribution, m.eta, m.k), ("conductor", Distribution::Ggx, [0.0; 3], [1.0; 3]));
    assert!(matches!(m.roughness, ScalarValue::Constant(r) if r == 0.3) && matches!(m.base_color, ColorValue::Constant(c) if c == [1.0; 3]), "{m:?}");
    let s = Scene::load(fixture(
        "metal-gold",
        &metal("\nmetal = \"Au\"\nroughness = 0.1\ndistribution = \"beckmann\"\nbase_color = [0.9, 0.9, 0.8]\none_sided = true"),
    ))
    .unwrap();
    let m = &s.materials[0];
    assert_eq!([m.eta, m.k], vkinverse::scene::metal("Au").unwrap());
    assert!(m.distribution == Distribution::Beckmann && m.one_sided && matches!(m.roughness, ScalarValue::Constant(r) if r == 0.1));
    let s = Scene::load(fixture("metal-index", &metal("\neta = [0.2, 0.9, 1.1]\nk = [3.9, 2.4, 0]"))).unwrap();
    assert_eq!([s.materials[0].eta, s.materials[0].k], [[0.2, 0.9, 1.1], [3.9, 2.4, 0.0]]);
    assert_message(&load_err("metal-unknown", &metal("\nmetal = \"unobtainium\"")), &["materials.m.metal", "unobtainium", "Au", "Cu"]);
    assert_message(&load_err("metal-both", &metal("\nmetal = \"Au\"\neta = [1, 1, 1]\nk = [1, 1, 1]")), &["materials.m.metal", "either"]);
    assert_message(&load_err("metal-eta-alone", &metal("\neta = [1, 1, 1]")), &["materials.m.k", "missing"]);
    assert_message(&load_err("metal-k-alone", &metal("\nk = [1, 1, 1]")), &["materials.m.eta", "missing"]);
    assert_message(&load_err("metal-negative", &metal("\neta = [1, -1, 1]\nk = [1, 1, 1]")), &["materials.m.eta", "-1", "negative"]);
    assert_message(&load_err("metal-nan", &metal("\neta = [1, 1, 1]\nk = [1, nan, 1]")), &["materials.m.k"]);
    assert_message(&load_err("metal-metallic", &metal("\nmetallic = 1")), &["materials.m.metallic", "conductor"]);
    assert_message(&load_err("metal-ior", &metal("\nior = 1.5")), &["materials.m.ior", "dielectric"]);
    assert_message(&load_err("metal-distribution", &metal("\ndistribution = \"phong\"")), &["materials.m.distribution", "phong"]);
    assert_message(&load_err("metal-roughness-range", &metal("\nroughness = 1.5")), &["materials.m.roughness", "1.5"]);
    for (key, line) in [("metal", "metal = \"Au\""), ("eta", "eta = [1, 1, 1]"), ("k", "k = [1, 1, 1]")] {
        let principled = BASE.replace("type = \"principled\"", &format!("type = \"principled\"\n{line}"));
        assert_message(&load_err(&format!("principled-{key}"), &principled), &[&format!("materials.m.{key}"), "conductor"]);
    }
    let principled = BASE.replace("type = \"principled\"", "type = \"principled\"\ndistribution = \"beckmann\"");
    assert_message(&load_err("principled-distribution", &principled), &["materials.m.distribution", "conductor"]);
    for (target, init) in [("roughness", "0.5"), ("base_color", "[0.5, 0.5, 0.5]")] {
        let optimised =
            format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.{target}\"\ninit = {init}\nrange = [0, 1]\n", metal("\nmetal = \"Cu\""));
        Scene::load(fixture(&format!("metal-param-{target}"), &optimised)).unwrap();
    }
    let optimised = format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.metallic\"\ninit = 0.5\nrange = [0, 1]\n", metal(""));
    assert_message(&load_err("metal-metallic-param", &optimised), &["optimise.params[0].target", "conductor", "metallic"]);
}

/// A plastic: roughness 0.3, GGX, index 1.5 and linear by default; its diffuse
/// reflectance (`base_color`) required and optimisable; its roughness a number (its
/// coating's table is computed for it), not optimisable; no metallic; an index other than 1
/// in [0.25, 4]; `nonlinear`, `layered` and `specular` (each channel in [0, 1]) only on a
/// plastic, and `nonlinear` only with a layered coating.
#[test]
fn plastics_are_checked() {
    let plastic = |extra: &str| BASE.replace("type = \"principled\"", &format!("type = \"plastic\"{extra}"));
    let s = Scene::load(fixture("plastic-default", &plastic(""))).unwrap();
    let m = &s.materials[0];
    assert_eq!((m.kind.as_str(), m.distribution, m.ior, m.nonlinear), ("plastic", Distribution::Ggx, 1.5, false));
    assert!(matches!(m.roughness, ScalarValue::Constant(r) if r == 0.3) && matches!(m.base_color, ColorValue::Constant(c) if c == [0.5; 3]), "{m:?}");
    let s = Scene::load(fixture("plastic-set", &plastic("\nroughness = 0.1\ndistribution = \"beckmann\"\nior = 1.33\nnonlinear = true\none_sided = true")))
        .unwrap();
    let m = &s.materials[0];
    assert!(
        m.distribution == Distribution::Beckmann && m.ior == 1.33 && m.nonlinear && m.one_sided && matches!(m.roughness, ScalarValue::Constant(r) if r == 0.1),
        "{m:?}"
    );
    let no_base = BASE.replace("type = \"principled\"\nbase_color = [0.5, 0.5, 0.5]", "type = \"plastic\"");
    assert_message(&load_err("plastic-no-base", &no_base), &["materials.m.base_color", "missing"]);
    assert_message(&load_err("plastic-rough-texture", &plastic("\nroughness = { texture = \"tex.exr\" }")), &["materials.m.roughness", "number", "plastic"]);
    assert_message(&load_err("plastic-metallic", &plastic("\nmetallic = 0.5")), &["materials.m.metallic", "plastic"]);
    assert_message(&load_err("plastic-ior-one", &plastic("\nior = 1")), &["materials.m.ior", "is 1", "plastic"]);
    assert_message(&load_err("plastic-ior-range", &plastic("\nior = 5")), &["materials.m.ior", "[0.25, 4]"]);
    assert_message(&load_err("plastic-distribution", &plastic("\ndistribution = \"phong\"")), &["materials.m.distribution", "phong"]);
    assert_message(&load_err("plastic-eta", &plastic("\neta = [1, 1, 1]\nk = [1, 1, 1]")), &["materials.m.eta", "conductor"]);
    let principled = BASE.replace("type = \"principled\"", "type = \"principled\"\nnonlinear = true");
    assert_message(&load_err("principled-nonlinear", &principled), &["materials.m.nonlinear", "plastic"]);
    let s = Scene::load(fixture("plastic-unlayered", &plastic("\nlayered = false\nspecular = [0.2, 0.5, 1]"))).unwrap();
    assert_eq!((s.materials[0].layered, s.materials[0].specular), (false, [0.2, 0.5, 1.0]));
    assert_message(&load_err("plastic-specular", &plastic("\nspecular = [0.2, 1.5, 1]")), &["materials.m.specular", "1.5 is outside [0, 1]"]);
    assert_message(&load_err("plastic-unlayered-nonlinear", &plastic("\nlayered = false\nnonlinear = true")), &["materials.m.nonlinear", "layered"]);
    for key in ["layered = false", "specular = [1, 1, 1]"] {
        let principled = BASE.replace("type = \"principled\"", &format!("type = \"principled\"\n{key}"));
        assert_message(&load_err("principled-coating", &principled), &["materials.m.", "plastic"]);
    }
    let optimised = format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.base_color\"\ninit = [0.5, 0.5, 0.5]\nrange = [0, 1]\n", plastic(""));
    Scene::load(fixture("plastic-param-base", &optimised)).unwrap();
    for target in ["roughness", "metallic"] {
        let optimised = format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.{target}\"\ninit = 0.5\nrange = [0, 1]\n", plastic(""));
        assert_message(&load_err(&format!("plastic-param-{target}"), &optimised), &["optimise.params[0].target", "plastic", target]);
    }
}

/// A dielectric: white transmittance and index 1.5 by default, its index within
/// [0.25, 4], its absorption finite and not negative (a thin one has none), no roughness, metallic, one-sidedness, normal map or alpha, no optimised
/// roughness or metallic; an index only on a dielectric, a base colour required elsewhere.
#[test]
fn dielectrics_are_checked() {
    let glass = |extra: &str| BASE.replace("type = \"principled\"\nbase_color = [0.5, 0.5, 0.5]", &format!("type = \"dielectric\"{extra}"));
    let s = Scene::load(fixture("glass-default", &glass(""))).unwrap();
    let m = &s.materials[0];
    assert_eq!((m.kind.as_str(), m.ior), ("dielectric", 1.5));
    assert!(matches!(m.base_color, ColorValue::Constant(c) if c == [1.0; 3]), "{:?}", m.base_color);
    let s = Scene::load(fixture("glass-set", &glass("\nbase_color = [0.9, 0.8, 0.7]\nior = 0.75"))).unwrap();
    assert_eq!(s.materials[0].ior, 0.75);
    assert_message(&load_err("glass-ior-range", &glass("\nior = 5")), &["materials.m.ior", "5", "[0.25, 4]"]);
    assert_message(&load_err("glass-ior-zero", &glass("\nior = 0")), &["materials.m.ior", "[0.25, 4]"]);
    assert_message(&load_err("glass-ior-nan", &glass("\nior = nan")), &["materials.m.ior"]);
    assert_message(&load_err("glass-rough", &glass("\nroughness = 0.1")), &["materials.m", "smooth", "roughness"]);
    for (key, line) in [
        ("one_sided", "one_sided = true"),
        ("normal_map", "normal_map = { texture = \"tex.exr\" }"),
        ("bump_map", "bump_map = { texture = \"tex.exr\" }"),
        ("alpha", "alpha = 0.5"),
    ] {
        assert_message(&load_err(&format!("glass-{key}"), &glass(&format!("\n{line}"))), &[&format!("materials.m.{key}"), "dielectric"]);
    }
    let s = Scene::load(fixture("glass-absorbing", &glass("\nabsorption = [0.5, 0, 2]"))).unwrap();
    assert_eq!(s.materials[0].absorption, [0.5, 0.0, 2.0]);
    assert_message(&load_err("glass-absorption-negative", &glass("\nabsorption = [0.5, -1, 2]")), &["materials.m.absorption", "-1", "negative"]);
    assert_message(&load_err("glass-absorption-nan", &glass("\nabsorption = [0.5, nan, 2]")), &["materials.m.absorption"]);
    let thin = BASE.replace("type = \"principled\"\nbase_color = [0.5, 0.5, 0.5]", "type = \"thin_dielectric\"\nabsorption = [1, 1, 1]");
    assert_message(&load_err("thin-absorption", &thin), &["materials.m.absorption", "refracting dielectric"]);
    assert_message(
        &load_err("principled-absorption", &BASE.replace("type = \"principled\"", "type = \"principled\"\nabsorption = [1, 1, 1]")),
        &["materials.m.absorption"],
    );
    // A principled material's index sets its dielectric reflectance; a diffuse one has none.
    let principled = |extra: &str| BASE.replace("type = \"principled\"", &format!("type = \"principled\"{extra}"));
    assert_eq!(Scene::load(fixture("ior-principled", &principled("\nior = 2"))).unwrap().materials[0].ior, 2.0);
    assert_eq!(Scene::load(fixture("ior-principled-default", &principled(""))).unwrap().materials[0].ior, 1.5);
    assert_message(&load_err("ior-principled-range", &principled("\nior = 9")), &["materials.m.ior", "9", "[0.25, 4]"]);
    assert_message(&load_err("ior-diffuse", &BASE.replace("type = \"principled\"", "type = \"diffuse\"\nior = 1.5")), &["materials.m.ior", "principled"]);
    assert_message(&load_err("no-base-color", &BASE.replace("base_color = [0.5, 0.5, 0.5]", "")), &["materials.m.base_color", "missing"]);
    let optimised = format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.roughness\"\ninit = 0.5\nrange = [0, 1]\n", glass(""));
    assert_message(&load_err("glass-param", &optimised), &["optimise.params[0].target", "dielectric", "roughness"]);
    let tinted = format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.base_color\"\ninit = [0.5, 0.5, 0.5]\nrange = [0, 1]\n", glass(""));
    Scene::load(fixture("glass-tint-param", &tinted)).unwrap();
    // Rough glass: a roughness (0.3 by default, optimisable), an absorption, no metallic,
    // no index of 1.
    let rough = |extra: &str| BASE.replace("type = \"principled\"\nbase_color = [0.5, 0.5, 0.5]", &format!("type = \"rough_dielectric\"{extra}"));
    let s = Scene::load(fixture("rough-default", &rough(""))).unwrap();
    let m = &s.materials[0];
    assert_eq!((m.kind.as_str(), m.ior), ("rough_dielectric", 1.5));
    assert!(matches!(m.roughness, ScalarValue::Constant(r) if r == 0.3) && matches!(m.base_color, ColorValue::Constant(c) if c == [1.0; 3]), "{m:?}");
    let s = Scene::load(fixture("rough-set", &rough("\nroughness = 0.6\nabsorption = [1, 0, 0]\nior = 1.33"))).unwrap();
    assert!(matches!(s.materials[0].roughness, ScalarValue::Constant(r) if r == 0.6) && s.materials[0].absorption == [1.0, 0.0, 0.0]);
    assert_message(&load_err("rough-metallic", &rough("\nmetallic = 0.5")), &["materials.m", "rough dielectric", "metallic"]);
    assert_message(&load_err("rough-roughness-range", &rough("\nroughness = 1.5")), &["materials.m.roughness", "1.5"]);
    assert_message(&load_err("rough-matched", &rough("\nior = 1")), &["materials.m.ior", "is 1"]);
    assert_message(&load_err("rough-one-sided", &rough("\none_sided = true")), &["materials.m.one_sided", "dielectric"]);
    let s = Scene::load(fixture("rough-beckmann", &rough("\ndistribution = \"beckmann\""))).unwrap();
    assert_eq!(s.materials[0].distribution, Distribution::Beckmann);
    assert_message(&load_err("rough-distribution", &rough("\ndistribution = \"phong\"")), &["materials.m.distribution", "phong", "beckmann"]);
    assert_message(&load_err("glass-distribution", &glass("\ndistribution = \"ggx\"")), &["materials.m.distribution", "rough_dielectric"]);
    let optimised = format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.roughness\"\ninit = 0.5\nrange = [0, 1]\n", rough(""));
    Scene::load(fixture("rough-param", &optimised)).unwrap();
    let optimised = format!("{}\n[optimise]\n[[optimise.params]]\ntarget = \"materials.m.metallic\"\ninit = 0.5\nrange = [0, 1]\n", rough(""));
    assert_message(&load_err("rough-metallic-param", &optimised), &["optimise.params[0].target", "rough_dielectric", "metallic"]);
}

/// Every bad `[[media]]` entry or medium parameter is one line naming the key and what is
/// wrong with it.
#[test]
fn bad_media_are_named() {
    let medium = |keys: &str| format!("{BASE}\n[[media]]\nname = \"fog\"\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n{keys}\n");
    let cases: &[(&str, String, &[&str])] = &[
        (
            "inverted",
            format!("{BASE}\n[[media]]\nname = \"fog\"\nmin = [0, 0, 0]\nmax = [1, -1, 1]\ndensity = 1\n"),
            &["media.fog.max", "y -1 is not above min's 0"],
        ),
        ("negative", medium("density = -1"), &["media.fog.density", "-1 is negative"]),
        ("colour density", medium("density = [1, 2, 3]"), &["media.fog.density", "one channel"]),
        ("missing grid", medium("density = \"none.npy\""), &["media.fog.density", "none.npy"]),
        ("albedo", medium("density = 1\nalbedo = 1.5"), &["media.fog.albedo", "outside [0, 1]"]),
        ("g", medium("density = 1\nalbedo = 0.5\ng = 1"), &["media.fog.g", "outside"]),
        ("emitting scatterer", medium("density = 1\nalbedo = 0.5\nemission = 2"), &["media.fog.emission", "emits nothing"]),
        ("zero scale", medium("density = 1\nscale = 0"), &["media.fog.scale", "not positive"]),
        (
            "two",
            format!("{}[[media]]\nname = \"mist\"\nmin = [0, 0, 0]\nmax = [1, 1, 1]\ndensity = 1\n", medium("density = 1")),
            &["media", "2 media: a scene holds at most one"],
        ),
        (
            "negative range",
            format!("{}{}", medium("density = 1"), "[[optimise.params]]\ntarget = \"media.fog.density\"\ninit = 1\nrange = [-1, 2]\n"),
            &["optimise.params[0].range", "not negative"],
        ),
        (
            "grid on a colour",
            format!("{}{}", medium("density = 1"), "[[optimise.params]]\ntarget = \"materials.m.base_color\"\ninit = 0.5\nrange = [0, 1]\ngrid = [2, 2, 2]\n"),
            &["optimise.params[0].grid", "only a medium's density, emission and albedo are grids"],
        ),
        (
            "unknown medium",
            format!("{}{}", medium("density = 1"), "[[optimise.params]]\ntarget = \"media.smoke.density\"\ninit = 1\nrange = [0, 2]\n"),
            &["no medium named \"smoke\"", "\"fog\""],
        ),
        (
            "scatterer's emission",
            format!("{}{}", medium("density = 1\nalbedo = 0.5"), "[[optimise.params]]\ntarget = \"media.fog.emission\"\ninit = 1\nrange = [0, 2]\n"),
            &["optimise.params[0].target", "scatters"],
        ),
        (
            "absorber's albedo",
            format!("{}{}", medium("density = 1"), "[[optimise.params]]\ntarget = \"media.fog.albedo\"\ninit = 0.5\nrange = [0, 1]\n"),
            &["optimise.params[0].target", "does not scatter"],
        ),
        (
            "albedo range",
            format!("{}{}", medium("density = 1\nalbedo = 0.5"), "[[optimise.params]]\ntarget = \"media.fog.albedo\"\ninit = 0.5\nrange = [0, 2]\n"),
            &["optimise.params[0].range", "an albedo lies in [0, 1]"],
        ),
        ("albedo grid file", medium("density = 1\nalbedo = \"none.npy\""), &["media.fog.albedo", "none.npy"]),
    ];
    for (name, scene, needles) in cases {
        let err = load_err(&format!("media-{name}"), scene);
        assert_message(&err, needles);
    }
    // A grid of the wrong shape names the file and the shapes a grid may have.
    let path = fixture("media-shape", &medium("density = \"flat.npy\""));
    vkinverse::npy::write(&path.with_file_name("flat.npy"), &vkinverse::npy::Array { shape: vec![4, 4], data: vec![1.0; 16] }).unwrap();
    assert_message(&Scene::load(&path).unwrap_err(), &["media.fog.density", "flat.npy", "[z, y, x]"]);
}
