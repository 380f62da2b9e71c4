//! Mitsuba XML as Mitsuba reads it: the small files in `tests/data/mitsuba/`, one for each
//! thing that Mitsuba's own scenes use (includes and search paths, spectra, emitters
//! referenced by id, default field of view and depth, rotations about non-unit axes, the
//! `moment` wrapper and the `direct` integrator's weighting). Expected values are Mitsuba
//! 3.6's (scalar_rgb), quoted in each file.

use std::path::{Path, PathBuf};
use vkinverse::scene::{ColorValue, Scene};

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(rel)
}

fn constant(c: &ColorValue) -> [f32; 3] {
    match c {
        ColorValue::Constant(c) => *c,
        ColorValue::Texture(_) => panic!("a constant colour"),
    }
}

fn close(a: [f32; 3], b: [f32; 3], rel: f32) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() <= rel * y.abs().max(1e-3))
}

fn load_err(rel: &str) -> String {
    let msg = Scene::load(data(rel)).map(|_| ()).expect_err(rel).to_string();
    assert!(!msg.contains('\n'), "{rel}: {msg}");
    msg
}

/// `<include>` splices the included scene's children in; `<path>` adds a directory where
/// file names are looked for. box.xml in pieces loads to box.xml's scene.
#[test]
fn includes_and_paths_load_the_scene_in_pieces() {
    let whole = Scene::load(data("box/box.xml")).unwrap();
    let pieces = Scene::load(data("mitsuba/include.xml")).unwrap();
    assert_eq!(pieces.meshes.len(), whole.meshes.len());
    for (a, b) in whole.meshes.iter().zip(&pieces.meshes) {
        assert_eq!((&a.name, &a.positions, &a.indices, &a.emission, a.material), (&b.name, &b.positions, &b.indices, &b.emission, b.material));
    }
    assert_eq!(whole.materials.len(), pieces.materials.len());
    assert_eq!((whole.film.width, whole.sensors[0].origin, whole.sensors[0].fov_y), (pieces.film.width, pieces.sensors[0].origin, pieces.sensors[0].fov_y));
    assert_eq!((whole.lights.len(), whole.integrator.max_depth), (pieces.lights.len(), pieces.integrator.max_depth));
    assert_eq!(whole.warnings.len(), pieces.warnings.len(), "{:?}", pieces.warnings);

    let msg = load_err("mitsuba/include-loop.xml");
    assert!(msg.contains("include loop") && msg.contains("loop.xml"), "{msg}");
    // An error inside an included file names that file and its own line.
    let msg = load_err("mitsuba/include-broken.xml");
    assert!(msg.contains("parts/broken.xml line 3") && msg.contains("no_such_parameter"), "{msg}");
}

/// Spectra become RGB as in Mitsuba's RGB variants: reflectances under D65, radiances as
/// they are, a blackbody by Planck's law.
#[test]
fn spectra_are_converted_as_mitsubas_rgb_variants_do() {
    let s = Scene::load(data("mitsuba/spectra.xml")).unwrap();
    let material = |name: &str| constant(&s.materials[s.materials.iter().position(|m| m.name == name).unwrap()].base_color);
    assert!(close(material("white"), [0.735013, 0.735625, 0.736264], 0.01), "{:?}", material("white"));
    assert_eq!(material("grey"), [0.25; 3]);
    let lamp = constant(&s.meshes[0].emission);
    assert!(close(lamp, [1.19969, 0.949521, 0.903443], 0.01), "{lamp:?}");
    let env = &s.environment;
    let sky = constant(&env.value).map(|v| v * env.scale);
    assert!(close(sky, [0.440534, 0.414483, 0.439763], 0.02), "{sky:?}");
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    // The same list from a file of `wavelength value` lines, with a comment.
    let dir = std::env::temp_dir().join(format!("vkinverse-spectrum-file-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("flat.spd"), "# a flat radiance\n400 1\n700 1\n").unwrap();
    let xml = std::fs::read_to_string(data("mitsuba/spectra.xml")).unwrap().replace(r#"value="400:1, 700:1""#, r#"filename="flat.spd""#);
    std::fs::write(dir.join("s.xml"), xml).unwrap();
    let from_file = Scene::load(dir.join("s.xml")).unwrap();
    assert_eq!(constant(&from_file.meshes[0].emission), lamp);
    std::fs::write(dir.join("flat.spd"), "400 1 2\n700 1\n").unwrap();
    let msg = Scene::load(dir.join("s.xml")).map(|_| ()).unwrap_err().to_string();
    assert!(msg.contains("flat.spd") && msg.contains("`400 1 2` is not wavelength:value"), "{msg}");
    std::fs::remove_dir_all(&dir).unwrap();
    // A spectrum that is not one is named as such.
    let dir = std::env::temp_dir().join(format!("vkinverse-spectrum-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(data("mitsuba/spectra.xml")).unwrap().replace("400:1, 700:1", "700:1, 400:1");
    std::fs::write(dir.join("s.xml"), text).unwrap();
    let msg = Scene::load(dir.join("s.xml")).map(|_| ()).unwrap_err().to_string();
    assert!(msg.contains("wavelengths must increase") && msg.contains("<spectrum name=\"radiance\">"), "{msg}");
}

/// A shape refers to an area emitter declared at the top level by its id.
#[test]
fn area_emitters_are_referenced_by_id() {
    let s = Scene::load(data("mitsuba/emitter-by-id.xml")).unwrap();
    assert_eq!(constant(&s.meshes[0].emission), [3.0, 2.0, 1.0]);
    assert_eq!(s.materials[s.meshes[0].material].name, "grey");
}

/// No fov: Mitsuba's 50 mm default; no integrator, or a path integrator without
/// max_depth: Mitsuba's unlimited depth, as −1 gives, with a warning that names the depth.
#[test]
fn defaults_are_mitsubas_and_a_changed_depth_is_announced() {
    let s = Scene::load(data("mitsuba/default-fov.xml")).unwrap();
    let expected = 2.0 * ((38.1848f32.to_radians() / 2.0).tan() * 48.0 / 64.0).atan().to_degrees();
    assert!((s.sensors[0].fov_y - expected).abs() < 1e-3, "{} vs {expected}", s.sensors[0].fov_y);
    assert!(s.sensors[0].lens.is_none(), "focus_distance makes no lens on a perspective sensor");
    assert_eq!(s.integrator.max_depth, 64);
    assert!(s.warnings.iter().any(|w| w.contains("no <integrator>") && w.contains("64")), "{:?}", s.warnings);
    let default = Scene::load(data("mitsuba/depth-default.xml")).unwrap();
    let unlimited = Scene::load(data("mitsuba/depth-unlimited.xml")).unwrap();
    assert_eq!(default.integrator.max_depth, unlimited.integrator.max_depth);
    assert_eq!(default.integrator.max_depth, 64);
    for s in [&default, &unlimited] {
        assert!(s.warnings.len() == 1 && s.warnings[0].contains("unlimited") && s.warnings[0].contains("64"), "{:?}", s.warnings);
    }
}

/// `<rotate>` about a non-unit axis is Mitsuba's matrix (which scales and shears), with a
/// warning naming the element.
#[test]
fn rotations_use_mitsubas_arithmetic() {
    let s = Scene::load(data("mitsuba/rotate-shear.xml")).unwrap();
    // The rectangle's corner (1, 1, 0) under Mitsuba's rotate([0, 2, 0], 90):
    // [[0, 0, 2], [0, 4, 0], [-2, 0, 0]] · (1, 1, 0) = (0, 4, -2).
    let p = s.meshes[0].positions.iter().find(|p| p[1] > 0.0 && p[2] < 0.0).copied().expect("a corner");
    assert!(close(p, [0.0, 4.0, -2.0], 1e-4), "{p:?}");
    assert!(s.warnings.len() == 1 && s.warnings[0].contains("<rotate>") && s.warnings[0].contains("shears"), "{:?}", s.warnings);
}

/// The `moment` wrapper renders its inner integrator, and the `direct` integrator's weight
/// of delta lights by emitter_samples is named.
#[test]
fn wrappers_unwrap_and_directs_weighting_is_named() {
    let s = Scene::load(data("mitsuba/moment-direct.xml")).unwrap();
    assert_eq!(s.integrator.max_depth, 2, "the direct integrator inside");
    assert_eq!(s.warnings.len(), 2, "{:?}", s.warnings);
    assert!(s.warnings[0].contains("moment"), "{}", s.warnings[0]);
    assert!(s.warnings[1].contains("emitter_samples (4)") && s.warnings[1].contains("bulb"), "{}", s.warnings[1]);
    // stokes around path, as Mitsuba's polarisation scenes have it: the radiance is the
    // Stokes vector's first component.
    let text = std::fs::read_to_string(data("mitsuba/moment-direct.xml")).unwrap();
    let (start, end) = (text.find("<integrator").unwrap(), text.rfind("</integrator>").unwrap() + "</integrator>".len());
    let stokes = format!(
        "{}<integrator type=\"stokes\"><integrator type=\"path\"><integer name=\"max_depth\" value=\"5\"/></integrator></integrator>{}",
        &text[..start],
        &text[end..]
    );
    let dir = crate::common::scenes::temp_dir("mitsuba-stokes");
    std::fs::write(dir.join("s.xml"), stokes).unwrap();
    let s = Scene::load(dir.join("s.xml")).unwrap();
    assert_eq!(s.integrator.max_depth, 5, "the path integrator inside");
    assert!(s.warnings.iter().any(|w| w.contains("Stokes")), "{:?}", s.warnings);
}

/// References resolve wherever their target is declared; a top-level sampler may be
/// referred to; plugin types are read case-insensitively; anisotropic roughness is
/// rendered isotropic at the geometric mean, with a warning.
#[test]
fn references_resolve_in_any_order() {
    let s = Scene::load(data("mitsuba/forward-refs.xml")).unwrap();
    assert_eq!(constant(&s.meshes[0].emission), [2.0, 3.0, 4.0]);
    let m = &s.materials[s.meshes[0].material];
    assert_eq!(m.name, "metal");
    let vkinverse::scene::ScalarValue::Constant(r) = m.roughness else { panic!("a constant roughness") };
    assert!((r * r - (0.05f32 * 0.2).sqrt()).abs() < 1e-5, "alpha {}", r * r);
    assert!(s.warnings.len() == 1 && s.warnings[0].contains("anisotropic"), "{:?}", s.warnings);
}

/// The recovered scene of a Mitsuba file is written back as Mitsuba XML: the source with
/// the new values (a texture as an EXR bitmap), loading again to them; what has no place in
/// the file is left as it was, and a comment says so.
#[test]
fn recovered_values_are_written_back_into_the_xml() {
    use vkinverse::scene::write::write_final;
    use vkinverse::scene::{ParamTarget, ScalarValue};
    use vkinverse::{ParamValue, Shape};
    let scene = Scene::load(data("box/box.xml")).unwrap();
    let material = |name: &str| scene.materials.iter().position(|m| m.name == name).unwrap();
    let texture: Vec<f32> = (0..12).map(|i| i as f32 / 12.0).collect();
    let values = vec![
        (ParamTarget::BaseColor { material: material("red") }, ParamValue::new(Shape::constant(3), vec![0.2, 0.3, 0.4]).unwrap()),
        (ParamTarget::Roughness { material: material("red") }, ParamValue::new(Shape::constant(1), vec![0.35]).unwrap()),
        (ParamTarget::BaseColor { material: material("white") }, ParamValue::new(Shape::texture(2, 2, 3), texture.clone()).unwrap()),
        (ParamTarget::Emission { mesh: scene.mesh_index("light").unwrap() }, ParamValue::new(Shape::constant(3), vec![5.0, 4.0, 3.0]).unwrap()),
        (ParamTarget::LightIntensity { light: 0 }, ParamValue::new(Shape::constant(1), vec![3.0]).unwrap()),
        (ParamTarget::Environment, ParamValue::new(Shape::constant(3), vec![0.1, 0.2, 0.3]).unwrap()),
    ];
    let out = std::env::temp_dir().join(format!("vkinverse-xml-write-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    write_final(&out, &scene, &values).unwrap();
    let xml = out.join("final/scene.xml");
    let back = Scene::load(&xml).unwrap_or_else(|e| panic!("{e}\n{}", std::fs::read_to_string(&xml).unwrap()));
    let m = |name: &str| back.materials.iter().find(|m| m.name == name).unwrap().clone();
    assert_eq!(constant(&m("red").base_color), [0.2, 0.3, 0.4]);
    assert!(matches!(m("red").roughness, ScalarValue::Constant(r) if (r - 0.35).abs() < 1e-6), "{:?}", m("red").roughness);
    let ColorValue::Texture(t) = &m("white").base_color else { panic!("a texture") };
    let texels: Vec<f32> = t.image.data.iter().flatten().copied().collect();
    assert!(texels.iter().zip(&texture).all(|(a, b)| (a - b).abs() < 1e-6), "{texels:?}");
    assert_eq!(constant(&back.meshes[back.mesh_index("light").unwrap()].emission), [5.0, 4.0, 3.0]);
    let (a, b) = (&scene.lights[0], &back.lights[0]);
    assert!(a.color.iter().zip(b.color).all(|(x, y)| (3.0 * x * a.intensity - y * b.intensity).abs() < 1e-5), "{b:?}");
    // Everything else as it was: the meshes, the camera; the environment (box.xml has none)
    // was not written, and the file says so.
    assert_eq!(back.meshes.len(), scene.meshes.len());
    assert_eq!(back.sensors[0].origin, scene.sensors[0].origin);
    let text = std::fs::read_to_string(&xml).unwrap();
    assert!(text.contains("Not written back") && text.contains("environment"), "{text}");
    std::fs::remove_dir_all(&out).unwrap();
}

/// An `<include>` inside an included file names its file relative to the scene's directory
/// when it is not beside the including file, as Mitsuba's own test scenes do
/// (`include/base.xml` includes `include/preamble.xml`).
#[test]
fn nested_includes_resolve_against_the_scene_directory_too() {
    let dir = crate::common::scenes::temp_dir("mitsuba-nested-include");
    std::fs::create_dir_all(dir.join("include")).unwrap();
    std::fs::write(dir.join("scene.xml"), "<scene version=\"3.0.0\"><include filename=\"include/base.xml\"/></scene>").unwrap();
    std::fs::write(
        dir.join("include/base.xml"),
        "<scene version=\"3.0.0\"><include filename=\"include/preamble.xml\"/>\
         <sensor type=\"perspective\"><film type=\"hdrfilm\"><integer name=\"width\" value=\"4\"/><integer name=\"height\" value=\"4\"/></film></sensor></scene>",
    )
    .unwrap();
    std::fs::write(
        dir.join("include/preamble.xml"),
        "<scene version=\"3.0.0\"><emitter type=\"constant\"><rgb name=\"radiance\" value=\"0.25\"/></emitter></scene>",
    )
    .unwrap();
    let scene = Scene::load(dir.join("scene.xml")).unwrap();
    assert_eq!(constant(&scene.environment.value), [0.25; 3], "the preamble's emitter was read");
    assert_eq!(scene.film.width, 4);
}
