//! Hostile inputs: each problem once found by trying the tool as a hostile user would, kept
//! as a regression. Every case ends in a clear one-line refusal naming the file and the
//! place, quickly, without a panic, an abort or memory spent before the check.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use vkinverse::image::{read_exr, write_exr, Image, ImageError};
use vkinverse::scene::Scene;

use crate::common::binary::{s, vkinverse, vkinverse_err};

/// Longest a refusal may take: the node graph and the nesting checks are linear.
const QUICK: Duration = Duration::from_secs(10);

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vkinverse-hostile-{}-{name}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    dir
}

/// Loads `path`, which must fail quickly with a one-line message holding every needle.
fn refused(path: &Path, needles: &[&str]) -> String {
    let start = Instant::now();
    let err = match Scene::load(path) {
        Ok(_) => panic!("{} loaded but should not have", path.display()),
        Err(e) => e.to_string(),
    };
    assert!(start.elapsed() < QUICK, "{}: took {:?} to refuse", path.display(), start.elapsed());
    assert!(!err.contains('\n'), "multi-line message: {err}");
    for needle in needles {
        assert!(err.contains(needle), "{err:?} lacks {needle:?}");
    }
    err
}

/// The bundled box glTF changed by `edit`, written as `NAME.gltf` in a fresh directory.
fn box_variant(name: &str, edit: impl FnOnce(&mut Value)) -> PathBuf {
    let mut doc: Value = serde_json::from_str(&fs::read_to_string(data("box/box.gltf")).unwrap()).unwrap();
    edit(&mut doc);
    let path = temp(name).join(format!("{name}.gltf"));
    fs::write(&path, serde_json::to_string(&doc).unwrap()).unwrap();
    path
}

fn index_accessor(doc: &Value) -> usize {
    doc["meshes"][0]["primitives"][0]["indices"].as_u64().expect("box has indexed meshes") as usize
}

fn position_accessor(doc: &Value) -> usize {
    doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"].as_u64().unwrap() as usize
}

#[test]
fn gltf_files_that_once_panicked_are_refused() {
    let cases: Vec<(&str, Box<dyn FnOnce(&mut Value)>, &[&str])> = vec![
        ("stride", Box::new(|d| d["bufferViews"][0]["byteStride"] = json!(4)), &["accessors[0]", "stride of 4"]),
        (
            "float-indices",
            Box::new(|d| {
                let i = index_accessor(d);
                d["accessors"][i]["componentType"] = json!(5126);
            }),
            &["accessors["],
        ),
        (
            "missing-accessor",
            Box::new(|d| d["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = json!(999)),
            &["attributes.NORMAL", "accessor 999 does not exist"],
        ),
        (
            "image-without-source",
            Box::new(|d| {
                d["images"] = json!([{}]);
                d["textures"] = json!([{ "source": 0 }]);
                d["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = json!({ "index": 0 });
            }),
            &["images[0]", "neither a uri nor a bufferView"],
        ),
        (
            "indices-past-view",
            Box::new(|d| {
                let i = index_accessor(d);
                d["accessors"][i]["count"] = json!(600);
            }),
            &["run past buffer view"],
        ),
        (
            "positions-past-view",
            Box::new(|d| {
                let i = position_accessor(d);
                d["accessors"][i]["count"] = json!(400);
            }),
            &["400 elements", "run past buffer view"],
        ),
        ("device-file", Box::new(|d| d["buffers"][0]["uri"] = json!("/dev/zero")), &["buffers[0]", "/dev/zero", "not a regular file"]),
        (
            "negative-colour",
            Box::new(|d| d["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = json!([-1.0, 0.5, 0.5, 1.0])),
            &["base_color", "negative"],
        ),
        ("huge-scale", Box::new(|d| d["nodes"][0]["scale"] = json!([1e20, 1e20, 1e20])), &["vertex coordinate", "the BVH is built for"]),
        (
            "light-overflow",
            Box::new(|d| {
                let light = &mut d["extensions"]["KHR_lights_punctual"]["lights"][0];
                light["color"] = json!([4.0, 4.0, 4.0]);
                light["intensity"] = json!(3e38);
            }),
            &["overflows single precision"],
        ),
    ];
    for (name, edit, needles) in cases {
        let path = box_variant(name, edit);
        let msg = refused(&path, needles);
        assert!(msg.contains(&format!("{name}.gltf")), "{name}: {msg:?} does not name the file");
    }
}

#[test]
fn gltf_node_graphs_are_walked_with_cycle_and_depth_checks() {
    let grow = |doc: &mut Value, nodes: Vec<Value>| {
        let first = doc["nodes"].as_array().unwrap().len();
        doc["nodes"].as_array_mut().unwrap().extend(nodes);
        doc["scenes"][0]["nodes"].as_array_mut().unwrap().push(json!(first));
        first
    };
    let cycle = box_variant("cycle", |d| {
        let n = d["nodes"].as_array().unwrap().len();
        grow(d, vec![json!({ "children": [n + 1] }), json!({ "children": [n] })]);
    });
    refused(&cycle, &["its own ancestor"]);
    let chain = box_variant("chain", |d| {
        let n = d["nodes"].as_array().unwrap().len();
        grow(d, (0..10_000).map(|i| if i < 9_999 { json!({ "children": [n + i + 1] }) } else { json!({}) }).collect());
    });
    refused(&chain, &["deeper than 256 levels"]);
    // Forty levels, each node listing the next twice: 2^40 paths if walked naively.
    let doubled = box_variant("doubled", |d| {
        let n = d["nodes"].as_array().unwrap().len();
        grow(d, (0..40).map(|i| if i < 39 { json!({ "children": [n + i + 1, n + i + 1] }) } else { json!({ "mesh": 0 }) }).collect());
    });
    refused(&doubled, &["is a child of node", "already"]);
}

#[test]
fn mitsuba_xml_nesting_and_twosided_refusals_say_what_and_where() {
    let dir = temp("xml");
    let deep = dir.join("deep.xml");
    fs::write(&deep, format!("<scene version=\"3.0.0\">{}{}</scene>", "<ref>".repeat(20_000), "</ref>".repeat(20_000))).unwrap();
    refused(&deep, &["deep.xml", "nested 65 deep"]);
    let twice = dir.join("twice.xml");
    fs::write(&twice, "<scene version=\"3.0.0\">\n<bsdf type=\"twosided\" id=\"a\"><bsdf type=\"twosided\"><bsdf type=\"diffuse\"/></bsdf></bsdf>\n</scene>\n")
        .unwrap();
    refused(&twice, &["twice.xml", "line 2", "twosided inside a twosided"]);
}

#[test]
fn truncated_toml_and_commented_obj_messages_say_what_and_where() {
    let dir = temp("text");
    let toml = dir.join("trunc.toml");
    fs::write(&toml, "x = ").unwrap();
    refused(&toml, &["trunc.toml:1:5", "the file ends where a value should be"]);
    // A trailing comment on a vertex colour line once read as "color parse error".
    let scene = dir.join("scene.toml");
    fs::write(
        &scene,
        "[film]\nwidth = 4\nheight = 4\n[[sensors]]\norigin = [0, 0, 3]\ntarget = [0, 0, 0]\nfov_y = 40\n\
         [[materials]]\nname = \"m\"\ntype = \"diffuse\"\nbase_color = [0.5, 0.5, 0.5]\n\
         [[meshes]]\nfile = \"c.obj\"\nmaterial = \"m\"\n",
    )
    .unwrap();
    fs::write(dir.join("c.obj"), "v 0 0 0 # a\nv 1 0 0\nv 0 1 0 # b\nf 1 2 3 # the face\n").unwrap();
    let loaded = Scene::load(&scene).expect("comments in an OBJ are comments");
    assert_eq!(loaded.triangle_count(), 1);
}

/// An EXR of `w` × `h` whose header is then edited to claim `claim` × `claim` pixels.
fn lying_exr(path: &Path, claim: i32) {
    write_exr(path, &Image::filled(4, 4, [0.5, 0.5, 0.5])).unwrap();
    let mut bytes = fs::read(path).unwrap();
    for name in [&b"dataWindow\0box2i\0"[..], &b"displayWindow\0box2i\0"[..]] {
        let at = bytes.windows(name.len()).position(|w| w == name).expect("EXR header attribute") + name.len() + 4;
        bytes[at + 8..at + 12].copy_from_slice(&(claim - 1).to_le_bytes());
        bytes[at + 12..at + 16].copy_from_slice(&(claim - 1).to_le_bytes());
    }
    fs::write(path, bytes).unwrap();
}

#[test]
fn an_exr_claiming_a_huge_size_is_refused_before_allocation() {
    let dir = temp("exr");
    let path = dir.join("huge.exr");
    lying_exr(&path, 100_000);
    match read_exr(&path) {
        Err(ImageError::TooLarge { .. }) => {}
        other => panic!("expected TooLarge, got {:?}", other.map(|i| (i.width, i.height))),
    }
    // As a scene's environment, through the binary.
    let scene = dir.join("scene.toml");
    fs::write(
        &scene,
        "[film]\nwidth = 4\nheight = 4\n[[sensors]]\norigin = [0, 0, 3]\ntarget = [0, 0, 0]\nfov_y = 40\n\
         [environment]\nfile = \"huge.exr\"\n",
    )
    .unwrap();
    let err = vkinverse_err(&["render", &s(&scene), "-o", &s(&dir.join("out.exr"))], &["huge.exr", "100000"]);
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn an_imported_environment_obeys_the_toml_value_policy() {
    let dir = temp("env");
    write_exr(&dir.join("env.exr"), &Image::filled(8, 4, [-1.0, 0.5, 0.5])).unwrap();
    let xml = dir.join("env.xml");
    fs::write(
        &xml,
        "<scene version=\"3.0.0\">\n<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>\
         <film type=\"hdrfilm\"><integer name=\"width\" value=\"4\"/><integer name=\"height\" value=\"4\"/></film></sensor>\n\
         <emitter type=\"envmap\"><string name=\"filename\" value=\"env.exr\"/></emitter>\n\
         <shape type=\"rectangle\"><bsdf type=\"diffuse\"/></shape>\n</scene>\n",
    )
    .unwrap();
    refused(&xml, &["environment", "-1"]);
}

/// A `.vol` header of `size` voxels and `channels` (version 3, float32), then `data`.
fn vol_bytes(size: [i32; 3], channels: i32, data: &[f32]) -> Vec<u8> {
    let mut b = b"VOL\x03".to_vec();
    for v in [1].iter().chain(&size).chain([&channels]) {
        b.extend_from_slice(&v.to_le_bytes());
    }
    for v in [0.0f32, 0.0, 0.0, 1.0, 1.0, 1.0].iter().chain(data) {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

/// Hostile Mitsuba `.vol` grids as a medium's density: each is refused in one line naming
/// the key and the file, before anything of the claimed size is allocated.
#[test]
fn hostile_vol_grids_are_refused_in_one_line() {
    let dir = temp("vol");
    let scene = dir.join("scene.toml");
    fs::write(
        &scene,
        "[film]\nwidth = 4\nheight = 4\n[[sensors]]\norigin = [0, 0, 3]\ntarget = [0, 0, 0]\nfov_y = 40\n\
         [[media]]\nname = \"fog\"\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\ndensity = \"bad.vol\"\n",
    )
    .unwrap();
    let good = vol_bytes([2, 2, 2], 1, &[0.5; 8]);
    let edit = |at: usize, bytes: &[u8]| {
        let mut b = good.clone();
        b[at..at + bytes.len()].copy_from_slice(bytes);
        b
    };
    let mut nan = good.clone();
    nan.truncate(good.len() - 4);
    nan.extend_from_slice(&f32::NAN.to_le_bytes());
    let cases: Vec<(Vec<u8>, &[&str])> = vec![
        (Vec::new(), &["bad magic"]),
        (b"VOL".to_vec(), &["ends inside the 48-byte header (3 bytes)"]),
        (good[..30].to_vec(), &["ends inside the 48-byte header (30 bytes)"]),
        (edit(0, b"\x93NUMPY"), &["bad magic"]),
        (edit(3, &[2]), &["unsupported .vol version 2"]),
        (edit(4, &3i32.to_le_bytes()), &["unsupported .vol encoding 3"]),
        (edit(8, &(-1i32).to_le_bytes()), &["x has -1 voxels"]),
        (edit(16, &i32::MAX.to_le_bytes()), &["z has 2147483647 voxels"]),
        (vol_bytes([1024, 1024, 1024], 1, &[]), &["1073741824 voxels; at most"]),
        (vol_bytes([100, 100, 100], 1, &[0.5; 8]), &["truncated data: 32 of 4000000 bytes"]),
        (edit(20, &i32::MIN.to_le_bytes()), &["-2147483648 channels"]),
        ([good.clone(), vec![0; 7]].concat(), &["7 bytes after the grid data"]),
        (nan, &["voxel (1, 1, 1) channel 0 is NaN"]),
        (vol_bytes([2, 2, 2], 1, &[-0.5; 8]), &["-0.5 is negative"]),
        (vol_bytes([1, 1, 1], 3, &[0.5; 3]), &["has 3 channels; a density has 1"]),
    ];
    for (bytes, needles) in cases {
        fs::write(dir.join("bad.vol"), &bytes).unwrap();
        let err = refused(&scene, needles);
        assert!(err.contains("media.fog.density") && (err.contains("bad.vol") || err.contains("negative")), "{err}");
    }
}

#[test]
fn the_binary_turns_a_refusal_into_one_line_and_a_non_zero_exit() {
    let path = box_variant("cli-stride", |d| d["bufferViews"][0]["byteStride"] = json!(4));
    let out = vkinverse(&["render", &s(&path), "-o", &s(&path.with_extension("exr"))]);
    assert_eq!(out.code, Some(1), "{}", out.stderr);
    assert_eq!(out.stderr.trim().lines().count(), 1, "{}", out.stderr);
    assert!(out.stderr.contains("cli-stride.gltf") && !out.stderr.contains("panicked"), "{}", out.stderr);
    assert!(!path.with_extension("exr").exists(), "a refused render left an image");
}

/// An emitter of 1e30 or 1e-30 once ran to the end with a loss of inf or 0 and parameters
/// that never moved, exiting 0. Now the run stops with an error naming the likely cause.
#[test]
fn an_emitter_too_bright_or_too_faint_stops_the_run_with_its_cause() {
    let cornell = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell");
    for (name, emission, needles) in
        [("bright", "1e30", &["the loss is inf", "too bright"][..]), ("faint", "1e-30", &["the gradient has been zero", "20 iterations"][..])]
    {
        let dir = temp(&format!("emitter-{name}"));
        let copied = std::process::Command::new("cp").arg("-r").arg(cornell.join(".")).arg(&dir).status().unwrap();
        assert!(copied.success(), "cp -r {}", cornell.display());
        let text = fs::read_to_string(dir.join("scene.toml")).unwrap();
        assert!(text.contains("emission = [17.0, 12.0, 4.0]") && text.contains("width = 64"), "the Cornell scene changed");
        let text = text
            .replacen("emission = [17.0, 12.0, 4.0]", &format!("emission = [{emission}, {emission}, {emission}]"), 1)
            .replacen("width = 64", "width = 16", 1)
            .replacen("height = 64", "height = 16", 1);
        fs::write(dir.join("scene.toml"), text).unwrap();
        let err = vkinverse_err(&["optimise", &s(&dir.join("scene.toml")), "--iterations", "30", "--quiet", "-o", &s(&dir.join("run"))], needles);
        assert!(!err.contains("panicked"), "{err}");
    }
}
