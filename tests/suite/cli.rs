//! The command line end to end: the built binary on tiny scenes, with the validation layer on
//! (`VKINVERSE_VALIDATION=1`), its outputs read back and checked against DESIGN.md's formats,
//! and bad input checked to give one `vkinverse: error:` line, a non-zero exit and no output.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

use common::binary::{json, s, vkinverse, vkinverse_during, vkinverse_env, vkinverse_err, vkinverse_err_env, vkinverse_ok, Output};
use common::pictures::assert_run_pictures;
use common::scenes::{temp_dir, write_delta_lit};
use vkinverse::npy::{self, Array};
use vkinverse::optim::{self, Range};

const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

fn bundled_cornell() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell/scene.toml")
}

/// `scenes/cornell` with the film cut to 16×16 and direct light only, in a directory of its
/// own holding copies of the meshes.
fn cornell_copy(name: &str) -> PathBuf {
    let src = bundled_cornell();
    let dir = temp_dir(name);
    let meshes = dir.join("meshes");
    std::fs::create_dir_all(&meshes).unwrap();
    for entry in std::fs::read_dir(src.parent().unwrap().join("meshes")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), meshes.join(entry.file_name())).unwrap();
    }
    let mut text = std::fs::read_to_string(&src).unwrap();
    for (from, to) in [("width = 64", "width = 16"), ("height = 64", "height = 16"), ("max_depth = 4", "max_depth = 2")] {
        assert!(text.contains(from), "scenes/cornell/scene.toml no longer has `{from}`");
        text = text.replacen(from, to, 1);
    }
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// One tiny Cornell box per test process, so that its rendered target (cached beside the
/// scene) is rendered once, not by every test.
fn tiny_cornell() -> &'static Path {
    static SCENE: OnceLock<PathBuf> = OnceLock::new();
    SCENE.get_or_init(|| cornell_copy("cornell16"))
}

/// A tiny Cornell box whose scene text is edited by `edit`, in its own directory.
fn edited_cornell(name: &str, edit: impl FnOnce(&str) -> String) -> PathBuf {
    let path = cornell_copy(name);
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, edit(&text)).unwrap();
    path
}

fn replace_once(text: &str, from: &str, to: &str) -> String {
    assert!(text.contains(from), "scene text lacks {from:?}");
    text.replacen(from, to, 1)
}

fn dir_names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

/// The committed checkpoint's directory: the one `checkpoint/current` names.
fn committed(dir: &Path) -> PathBuf {
    let name = std::fs::read_to_string(dir.join("checkpoint/current")).expect("checkpoint/current");
    dir.join("checkpoint").join(name.trim())
}

/// log.csv as a header and rows of fields.
fn read_log(dir: &Path) -> (String, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(dir.join("log.csv")).unwrap();
    let mut lines = text.lines();
    let header = lines.next().expect("log.csv is empty").to_string();
    let rows = lines.map(|l| l.split(',').map(str::to_string).collect()).collect();
    (header, rows)
}

fn field(row: &[String], i: usize) -> f64 {
    row[i].parse().unwrap_or_else(|_| panic!("log.csv field {i} of {row:?} is not a number"))
}

/// Checks the bytes are a decodable PNG and returns its size.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap();
    assert!(bytes.starts_with(PNG_SIGNATURE), "{} lacks the PNG signature", path.display());
    let info = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (info.info().width, info.info().height)
}

const LOG_HEADER: &str = "iteration,time_s,gpu_time_s,loss,param_error,param_error.materials.red.base_color";

/// A machine whose Vulkan loader finds no driver (here: the driver variables name a manifest
/// that does not exist; on a bare GPU machine, a driver whose own libraries do not load)
/// gets one line that says so and what to check, not the loader's bare result.
#[test]
fn no_vulkan_driver_is_one_line_saying_what_to_check() {
    let missing = "/nonexistent/vkinverse-test-icd.json";
    let image = temp_dir("no-driver").join("x.exr");
    let scene = bundled_cornell();
    let render = ["render".as_ref(), scene.as_os_str(), "-o".as_ref(), image.as_os_str()];
    for args in [&["info".as_ref()][..], &render[..]] {
        vkinverse_err_env::<&std::ffi::OsStr>(
            args,
            &[("VK_DRIVER_FILES", missing), ("VK_ICD_FILENAMES", missing)],
            &["no Vulkan driver could be loaded", "mesa-vulkan-drivers", "VK_DRIVER_FILES"],
        );
    }
}

#[test]
fn info_lists_the_test_device_and_features() {
    let text = vkinverse_ok(&["info"]).stdout;
    // The device the tests run on: lavapipe, unless VKINVERSE_TEST_DEVICE names another.
    let expected = std::env::var("VKINVERSE_TEST_DEVICE").unwrap_or_else(|_| "llvmpipe".into());
    assert!(text.contains(&expected), "{expected} missing from:\n{text}");
    // Without this line the absence of validation messages would prove nothing.
    assert!(text.contains("validation layer: on"), "VKINVERSE_VALIDATION=1 did not turn the layer on:\n{text}");

    let info = json(&{
        let dir = temp_dir("info");
        let path = dir.join("info.json");
        std::fs::write(&path, vkinverse_ok(&["info", "--json"]).stdout).unwrap();
        path
    });
    let chosen = info["chosen"].as_u64().expect("chosen device index") as usize;
    let device = &info["devices"][chosen];
    let features = device["features"].as_object().expect("features map");
    assert!(features.len() >= 7, "{features:?}");
    for (name, has) in features {
        assert_eq!(has, &serde_json::Value::Bool(true), "{name}: vkinverse runs only on devices that have it");
        let line = text.lines().find(|l| l.trim_start().starts_with(name.as_str()));
        assert!(line.is_some_and(|l| l.trim_end().ends_with("yes")), "no `{name} ... yes` line in:\n{text}");
    }
    assert!(text.contains(device["name"].as_str().unwrap()));

    // A reader that stops early closes the pipe: that is not an error and not a panic.
    let mut child = Command::new(env!("CARGO_BIN_EXE_vkinverse")).args(["info", "--json"]).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && stderr.is_empty(), "closed stdout: {:?}\n{stderr}", out.status);
}

#[test]
fn render_writes_exr_and_png() {
    let dir = temp_dir("render");
    let scene = bundled_cornell();
    let film = vkinverse::scene::Scene::load(&scene).unwrap().film;
    let exr = dir.join("cornell.exr");
    let png = dir.join("cornell.png");
    vkinverse_ok(&["render", &s(&scene), "--spp", "2", "-o", &s(&exr)]);
    vkinverse_ok(&["render", &s(&scene), "--spp", "1", "--seed", "3", "-o", &s(&png)]);

    let image = vkinverse::image::read_exr(&exr).unwrap();
    assert_eq!((image.width, image.height), (film.width, film.height));
    assert!(image.data.iter().flatten().all(|c| c.is_finite() && *c >= 0.0), "negative or non-finite radiance");
    // The area light faces the camera's side of the box: some pixels must be lit.
    assert!(image.data.iter().flatten().any(|c| *c > 0.1), "the render is black");
    assert_eq!(png_size(&png), (film.width, film.height));
    assert_eq!(dir_names(&dir), ["cornell.exr", "cornell.png"]);

    // Each bad argument is one error line, and nothing new appears in the directory.
    let bad = dir.join("bad.exr");
    vkinverse_err(&["render", &s(&scene), "--spp", "1", "-o", &s(&dir.join("bad.jpg"))], &["bad.jpg", ".exr, .npy or .png"]);
    vkinverse_err(&["render", &s(&scene), "--spp", "0", "-o", &s(&bad)], &["--spp"]);
    vkinverse_err(&["render", &s(&scene), "--spp", "1", "--sensor", "5", "-o", &s(&bad)], &["--sensor 5", "1 sensor"]);
    vkinverse_err(&["render", &s(&scene), "--spp", "abc", "-o", &s(&bad)], &["--spp", "abc"]);
    // An output directory that cannot be made fails before rendering.
    vkinverse_err(&["render", &s(&scene), "--spp", "1", "-o", &s(&dir.join("cornell.exr/x.exr"))], &["cornell.exr"]);
    assert_eq!(dir_names(&dir), ["cornell.exr", "cornell.png"]);
    // A missing one is made first.
    vkinverse_ok(&["render", &s(&scene), "--spp", "1", "-o", &s(&dir.join("new/dir/x.exr"))]);
    assert!(dir.join("new/dir/x.exr").exists());
}

/// Runs `optimise` on the tiny Cornell box and checks every output against DESIGN.md;
/// returns log.csv's param_error column.
fn optimise_and_check(optimiser: &str, iterations: usize) -> Vec<f64> {
    let out_dir = temp_dir(&format!("optimise-{optimiser}"));
    let out =
        vkinverse_ok(&["optimise", &s(tiny_cornell()), "--optimiser", optimiser, "--iterations", &iterations.to_string(), "--lr", "0.05", "-o", &s(&out_dir)]);
    assert!(out.stdout.contains(&format!("{iterations} iterations of {optimiser}")), "{}", out.stdout);
    // Meta's defaults carry the primal image and log its weights.
    let mut expected = vec![
        ".lock",
        "checkpoint",
        "error_vs_time.png",
        "final",
        "final.exr",
        "log.csv",
        "optimiser.csv",
        "optimiser.png",
        "params",
        "preview.png",
        "start.exr",
        "summary.json",
        "target.exr",
    ];
    if optimiser == "meta" {
        expected.splice(1..1, ["carry.csv", "carry.png"]);
    }
    assert_eq!(dir_names(&out_dir), expected);
    // The optimiser's diagnostics: one row per iteration and parameter group, the step's
    // learning rate and size consistent with θ's movement, n_eff (meta) counting up.
    let diag = vkinverse::optim::csv::DiagLog::parse(&std::fs::read_to_string(out_dir.join("optimiser.csv")).unwrap()).unwrap();
    assert_eq!(diag.rows.len(), iterations);
    for (k, (it, group, d)) in diag.rows.iter().enumerate() {
        assert_eq!((*it as usize, group.as_str(), d.elements), (k + 1, "materials.red.base_color", 3));
        assert!((d.lr - 0.05).abs() < 1e-6, "lr {}", d.lr);
        assert!((d.step_norm - d.rms_step * 3f64.sqrt()).abs() <= 1e-5 * d.step_norm.max(1e-30), "{d:?}");
        assert!(d.rms_f > 0.0 && d.rms_step > 0.0 && d.rms_step <= 0.05 * 8.0, "{d:?}");
        match optimiser {
            "meta" => {
                assert!(d.n_eff_min >= 1.0 && d.n_eff_max <= (k + 1) as f64 + 1e-3 && d.n_eff_min <= d.n_eff_mean && d.n_eff_mean <= d.n_eff_max, "{d:?}")
            }
            _ => assert_eq!((d.n_eff_mean, d.sd_fd), (0.0, 0.0)),
        }
    }
    png_size(&out_dir.join("optimiser.png"));
    if optimiser == "meta" {
        // The carried image's log: one row per iteration, the first carry the fresh render's
        // alone, later weights within (0, 1], and its plot.
        let carry = std::fs::read_to_string(out_dir.join("carry.csv")).unwrap();
        let weights: Vec<f64> = carry.lines().skip(1).map(|l| l.split(',').nth(2).unwrap().parse().unwrap()).collect();
        assert_eq!(weights.len(), iterations);
        assert_eq!(weights[0], 1.0);
        assert!(weights.iter().all(|w| *w > 0.0 && *w <= 1.0), "{weights:?}");
        assert_eq!(png_size(&out_dir.join("carry.png")), (800, 750));
    }

    let (header, rows) = read_log(&out_dir);
    assert_eq!(header, LOG_HEADER);
    assert_eq!(rows.len(), iterations + 1, "row 0 plus one per iteration");
    let mut last_time = (0.0, 0.0);
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row.len(), 6, "{row:?}");
        assert_eq!(row[0], i.to_string());
        let time = (field(row, 1), field(row, 2));
        assert!(time.0 >= last_time.0 && time.1 >= last_time.1, "time went backwards at row {i}");
        last_time = time;
        // Row 0 is the start: no image has been rendered, so no loss.
        if i == 0 {
            assert_eq!(row[3], "");
        } else {
            let loss = field(row, 3);
            assert!(loss.is_finite() && loss >= 0.0, "loss {loss}");
        }
        // One parameter: its error is the total error.
        assert!((field(row, 4) - field(row, 5)).abs() < 1e-12);
    }
    let errors: Vec<f64> = rows.iter().map(|r| field(r, 4)).collect();
    // init 0.5 grey against the reference red (0.63, 0.065, 0.05).
    let expected0 = ((0.13f64.powi(2) + 0.435f64.powi(2) + 0.45f64.powi(2)) / 3.0).sqrt();
    assert!((errors[0] - expected0).abs() < 1e-6, "initial error {} (expected {expected0})", errors[0]);

    let summary = json(&out_dir.join("summary.json"));
    assert_eq!(summary["iterations"], iterations);
    assert_eq!(summary["optimiser"], optimiser);
    assert!((summary["final_param_error"].as_f64().unwrap() - errors[iterations]).abs() < 1e-9);
    assert!((summary["initial_param_error"].as_f64().unwrap() - errors[0]).abs() < 1e-9);
    assert!((summary["settings"]["lr"].as_f64().unwrap() - 0.05).abs() < 1e-6);
    // The result's image error, and the reference's from the same random numbers (most
    // of both is the low-spp target's noise): the red wall a few steps from grey is
    // further from the target than the reference.
    let image_error = summary["final_image_error"].as_f64().expect("final_image_error");
    let floor = summary["reference_image_error"].as_f64().expect("reference_image_error");
    assert!(image_error > floor && floor > 0.0, "the result's {image_error:e} against the reference's {floor:e}");
    assert_eq!(summary["image_error_spp"], 64);
    // The meta-estimator reports how many samples it averages (n_eff = 1/(1 - α), at least
    // 1 after its first step, at most one more per iteration); Adam has no such state.
    match optimiser {
        "meta" => {
            let n_eff = summary["meta_n_eff"]["materials.red.base_color"].as_f64().expect("meta_n_eff of the red wall");
            assert!((1.0..=iterations as f64 + 1e-3).contains(&n_eff), "n_eff {n_eff} after {iterations} iterations");
        }
        _ => assert!(summary.get("meta_n_eff").is_none(), "{summary}"),
    }

    let params = json(&out_dir.join("params/params.json"));
    let red = params["materials.red.base_color"].as_array().expect("red wall colour in params.json");
    assert_eq!(red.len(), 3);
    let red: Vec<f64> = red.iter().map(|v| v.as_f64().unwrap()).collect();
    assert!(red.iter().all(|v| (0.0..=1.0).contains(v)), "{red:?} outside the range [0, 1]");
    // The saved colour is the last logged θ.
    let rmse = (red.iter().zip([0.63, 0.065, 0.05]).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / 3.0).sqrt();
    assert!((rmse - errors[iterations]).abs() < 1e-4, "params.json error {rmse}, log {}", errors[iterations]);

    // The pictures: target, start and final EXRs and the preview of the three and their
    // difference; the result is nearer the target than the start (the renders share their
    // random numbers, so most of what differs is the red wall).
    let pictures = assert_run_pictures(&out_dir, 1, (16, 16));
    let (target, start, fin) = &pictures[0];
    let distance = |a: &vkinverse::Image| a.data.iter().flatten().zip(target.data.iter().flatten()).map(|(x, t)| f64::from((x - t).abs())).sum::<f64>();
    assert!(distance(fin) < distance(start), "the result is no nearer the target than the start: {} against {}", distance(fin), distance(start));
    png_size(&out_dir.join("error_vs_time.png"));
    let state = json(&committed(&out_dir).join("state.json"));
    assert_eq!(state["iteration"], iterations);
    assert_eq!(state["settings"]["optimiser"], optimiser);
    // The checkpoint holds the log as it was at its iteration: here, all of it.
    assert_eq!(std::fs::read(committed(&out_dir).join("log.csv")).unwrap(), std::fs::read(out_dir.join("log.csv")).unwrap());
    errors
}

#[test]
fn optimise_adam_outputs_and_progress() {
    let errors = optimise_and_check("adam", 8);
    assert!(errors[8] < 0.8 * errors[0], "adam did not approach the reference: {errors:?}");
}

#[test]
fn optimise_meta_outputs_and_progress() {
    let errors = optimise_and_check("meta", 8);
    assert!(errors[8] < 0.8 * errors[0], "meta did not approach the reference: {errors:?}");
}

/// A scene of two sensors gets its pictures per sensor (`preview-K.png`, `target-K.exr`,
/// `start-K.exr`, `final-K.exr`, and `final.exr` as sensor 0's); `--overwrite` with a scene
/// of one sensor removes them all.
#[test]
fn a_scene_of_two_sensors_gets_pictures_per_sensor() {
    let second = "fov_y = 39.3\n\n[[sensors]]\norigin = [-0.6, 1.4, 3.2]\ntarget = [0.2, 0.8, 0]\nup = [0, 1, 0]\nfov_y = 45\n";
    let scene = edited_cornell("two-sensors", |t| replace_once(t, "fov_y = 39.3\n", second));
    let out_dir = temp_dir("two-sensors-out");
    let out = vkinverse_ok(&["optimise", &s(&scene), "--optimiser", "adam", "--iterations", "2", "--target-spp", "16", "-o", &s(&out_dir)]);
    assert!(out.stdout.contains("preview-K.png (K = 0..1)"), "{}", out.stdout);
    let names = dir_names(&out_dir);
    for k in 0..2 {
        for stem in ["final", "start", "target"] {
            assert!(names.contains(&format!("{stem}-{k}.exr")), "{stem}-{k}.exr missing from {names:?}");
        }
    }
    assert!(!names.iter().any(|n| ["preview.png", "start.exr", "target.exr"].contains(&n.as_str())), "{names:?}");
    let pictures = assert_run_pictures(&out_dir, 2, (16, 16));
    assert_ne!(pictures[0].0, pictures[1].0, "the two sensors' targets are one image");

    vkinverse_ok(&["optimise", &s(tiny_cornell()), "--iterations", "1", "--quiet", "--overwrite", "-o", &s(&out_dir)]);
    let names = dir_names(&out_dir);
    assert!(!names.iter().any(|n| n.contains('-')), "the first run's per-sensor pictures are left: {names:?}");
    assert_run_pictures(&out_dir, 1, (16, 16));
}

/// A run directory holding the scene's target image as `target.exr` is refused before
/// the run writes its own `target.exr` over it.
#[test]
fn a_run_does_not_write_over_the_scenes_target_image() {
    let scene = edited_cornell("target-in-outdir", |t| replace_once(t, "fov_y = 39.3", "fov_y = 39.3\ntarget_image = \"target.exr\""));
    let dir = scene.parent().unwrap();
    let target = dir.join("target.exr");
    vkinverse::image::write_exr(&target, &vkinverse::Image::filled(16, 16, [0.25; 3])).unwrap();
    let before = std::fs::read(&target).unwrap();
    vkinverse_err(&["optimise", &s(&scene), "--iterations", "1", "-o", &s(dir)], &["target.exr", "another directory"]);
    assert_eq!(std::fs::read(&target).unwrap(), before);
}

#[test]
fn fd_stride_runs_the_finite_difference_on_part_of_the_pixels() {
    let out_dir = temp_dir("fd-stride");
    let args = |stride: &str| {
        ["optimise", &s(tiny_cornell()), "--optimiser", "meta", "--iterations", "8", "--lr", "0.05", "--fd-stride", stride, "--quiet", "-o", &s(&out_dir)]
            .map(String::from)
    };
    vkinverse_err(&args("0"), &["--fd-stride", "at least 1"]);
    vkinverse_ok(&args("2"));
    let summary = json(&out_dir.join("summary.json"));
    assert_eq!(summary["settings"]["fd_stride"], 2);
    assert!(summary["pass_ms"]["trace_fd_adjoint"].as_f64().unwrap() > 0.0);
    let (_, rows) = read_log(&out_dir);
    let e = |i: usize| field(&rows[i], 4);
    assert!(e(8) < 0.8 * e(0), "meta with fd_stride 2 did not approach the reference: {} -> {}", e(0), e(8));
}

#[test]
fn a_texture_parameter_starts_from_an_earlier_runs_recovered_texture() {
    // A first run recovers a floor's colour as a 4×4 texture; a second names the first's
    // `params/` EXR as its `init` and so starts where the first ended.
    let textured = |name: &str, init: &str| {
        write_delta_lit(name, (16, 16), &format!("[[optimise.params]]\ntarget = \"materials.floor.base_color\"\n{init}\nrange = [0, 1]\ntexture = [4, 4]\n"))
    };
    let first = textured("init-first", "init = [0.2, 0.2, 0.2]");
    let first_out = temp_dir("init-first-out");
    vkinverse_ok(&["optimise", &s(&first), "--optimiser", "adam", "--iterations", "3", "--lr", "0.1", "--quiet", "-o", &s(&first_out)]);
    let recovered = first_out.join("params/materials.floor.base_color.exr");
    assert!(recovered.is_file(), "{} was not written", recovered.display());
    let second = textured("init-second", &format!("init = {{ texture = {:?} }}", s(&recovered)));
    let second_out = temp_dir("init-second-out");
    vkinverse_ok(&["optimise", &s(&second), "--optimiser", "adam", "--iterations", "1", "--quiet", "-o", &s(&second_out)]);
    let first_summary = json(&first_out.join("summary.json"));
    let (uniform, ended) = (first_summary["initial_param_error"].as_f64().unwrap(), first_summary["final_param_error"].as_f64().unwrap());
    let started = json(&second_out.join("summary.json"))["initial_param_error"].as_f64().unwrap();
    assert!(ended < 0.8 * uniform, "the first run did not move: {uniform} -> {ended}");
    assert!((started - ended).abs() <= 1e-6 * ended, "the second run started at error {started}, the first ended at {ended}");
}

#[test]
fn init_from_starts_every_parameter_where_an_earlier_run_ended() {
    // A first run recovers a floor colour texture (4×4) and a light's intensity; runs given
    // `--init-from` its directory start from both, a texture at another size resampled.
    let scene = |name: &str, size: u32, intensity_range: &str| {
        write_delta_lit(
            name,
            (16, 16),
            &format!(
                "[[optimise.params]]\ntarget = \"materials.floor.base_color\"\ninit = [0.2, 0.2, 0.2]\nrange = [0, 1]\ntexture = [{size}, {size}]\n\
             [[optimise.params]]\ntarget = \"lights.bulb.intensity\"\ninit = 1.0\nrange = {intensity_range}\n"
            ),
        )
    };
    let first_out = temp_dir("init-from-first-out");
    vkinverse_ok(&[
        "optimise",
        &s(&scene("init-from-first", 4, "[0, 10]")),
        "--optimiser",
        "adam",
        "--iterations",
        "3",
        "--lr",
        "0.1",
        "--quiet",
        "-o",
        &s(&first_out),
    ]);
    let recovered = json(&first_out.join("params/params.json"));
    let intensity = recovered["lights.bulb.intensity"].as_f64().unwrap();
    assert!(intensity > 1.1, "the intensity did not move towards 2: {intensity}");
    // Row 0 of log.csv is the start; columns 4.. the overall and per-parameter errors.
    let (header, rows) = read_log(&first_out);
    assert!(header.ends_with("param_error,param_error.materials.floor.base_color,param_error.lights.bulb.intensity"), "{header}");
    let (start, end) = (&rows[0], rows.last().unwrap());
    assert!(field(end, 4) < 0.8 * field(start, 4), "the first run did not move: {} -> {}", field(start, 4), field(end, 4));

    // The same scene, from the run's directory: every parameter starts where it ended.
    let same_out = temp_dir("init-from-same-out");
    vkinverse_ok(&[
        "optimise",
        &s(&scene("init-from-same", 4, "[0, 10]")),
        "--optimiser",
        "meta",
        "--iterations",
        "1",
        "--init-from",
        &s(&first_out),
        "--quiet",
        "-o",
        &s(&same_out),
    ]);
    let (_, same) = read_log(&same_out);
    for i in 4..7 {
        assert!(
            (field(&same[0], i) - field(end, i)).abs() <= 1e-6 * field(end, i),
            "column {i}: started at {}, the first run ended at {}",
            field(&same[0], i),
            field(end, i)
        );
    }
    let summary = json(&same_out.join("summary.json"));
    assert!((summary["initial_param_error"].as_f64().unwrap() - field(end, 4)).abs() <= 1e-6 * field(end, 4));
    assert_eq!(summary["started_from"].as_str(), Some(s(&first_out.join("params/params.json")).as_str()));
    assert!(json(&first_out.join("summary.json")).get("started_from").is_none(), "a run from the scene's init names a start");

    // An 8×8 texture from the 4×4 one, named by the params/ directory: nearest-texel
    // upsampling repeats each texel four times, so the floor's error is the same (its
    // reference is one colour).
    let resized_out = temp_dir("init-from-resized-out");
    vkinverse_ok(&[
        "optimise",
        &s(&scene("init-from-resized", 8, "[0, 10]")),
        "--optimiser",
        "adam",
        "--iterations",
        "1",
        "--init-from",
        &s(&first_out.join("params")),
        "--quiet",
        "-o",
        &s(&resized_out),
    ]);
    let (_, resized) = read_log(&resized_out);
    for i in [5, 6] {
        assert!(
            (field(&resized[0], i) - field(end, i)).abs() <= 1e-6 * field(end, i),
            "column {i}: started at {}, the first run ended at {}",
            field(&resized[0], i),
            field(end, i)
        );
    }

    // Refused, one line each: a value outside this scene's range, a parameter the run did
    // not optimise, a file that is not one of parameter values, a missing directory, and
    // --resume (which continues from its own checkpoint).
    let out = temp_dir("init-from-refused-out");
    let refused = |scene: &Path, from: &Path, needles: &[&str]| {
        vkinverse_err(&["optimise", &s(scene), "--iterations", "1", "--init-from", &s(from), "--quiet", "-o", &s(&out)], needles);
    };
    refused(&scene("init-from-range", 4, "[0, 1.05]"), &first_out, &["params.json", "lights.bulb.intensity", "outside the range [0, 1.05]"]);
    let other = write_delta_lit("init-from-other", (16, 16), "[[optimise.params]]\ntarget = \"lights.spot.intensity\"\ninit = 1.0\nrange = [0, 10]\n");
    refused(&other, &first_out, &["lights.spot.intensity", "no value for this parameter", "materials.floor.base_color"]);
    let bad = temp_dir("init-from-bad");
    std::fs::write(bad.join("params.json"), "[1, 2]").unwrap();
    refused(&other, &bad, &["params.json", "expected an object of parameter values"]);
    std::fs::write(bad.join("params.json"), "{\"lights.spot.intensity\": \"bright\"}").unwrap();
    refused(&other, &bad, &["lights.spot.intensity", "expected a number"]);
    refused(&other, &bad.join("nothing"), &["nothing", "cannot read an earlier run's parameters"]);
    vkinverse_err(&["optimise", &s(&other), "--resume", "--init-from", &s(&first_out), "-o", &s(&out)], &["--init-from", "--resume"]);
    // compare and gradcheck take the same start.
    vkinverse_err(
        &["compare", &s(&other), "--optimisers", "adam,meta", "--iterations", "1", "--init-from", &s(&first_out), "-o", &s(&out)],
        &["lights.spot.intensity", "no value for this parameter"],
    );
    vkinverse_err(&["gradcheck", &s(&other), "--init-from", &s(&bad.join("nothing"))], &["nothing", "cannot read an earlier run's parameters"]);
}

#[test]
fn command_line_lr_overrides_the_scene() {
    // Adam's first step moves every element by lr (|m̂/√v̂| = 1), whatever the gradient's
    // size, so one step from 0.5 lands on 0.5 ± lr, not 0.5 ± the scene's 0.02.
    let out_dir = temp_dir("lr");
    vkinverse_ok(&["optimise", &s(tiny_cornell()), "--optimiser", "adam", "--iterations", "1", "--lr", "0.1", "--quiet", "-o", &s(&out_dir)]);
    let params = json(&out_dir.join("params/params.json"));
    for v in params["materials.red.base_color"].as_array().unwrap() {
        let step = (v.as_f64().unwrap() - 0.5).abs();
        assert!((step - 0.1).abs() < 1e-3, "first step {step}, expected the --lr of 0.1");
    }
}

#[test]
fn resume_continues_from_the_checkpoint() {
    let out_dir = temp_dir("resume");
    let base = ["optimise", &s(tiny_cornell()), "--optimiser", "meta", "--quiet", "-o", &s(&out_dir)].map(String::from);
    let with = |extra: &[&str]| base.iter().cloned().chain(extra.iter().map(|a| a.to_string())).collect::<Vec<_>>();
    vkinverse_ok(&with(&["--iterations", "6", "--checkpoint-every", "3"]));
    let state = json(&committed(&out_dir).join("state.json"));
    assert_eq!(state["iteration"], 6);
    let (_, first) = read_log(&out_dir);
    assert_eq!(first.len(), 7);
    // The clock resumes where the last row left it: writing the log and checkpoints is not
    // optimisation time (generous slack for a preempted process).
    let saved = state["time_s"].as_f64().unwrap() - field(&first[6], 1);
    assert!((-1e-6..0.05).contains(&saved), "checkpoint time {saved} s after the last row");
    // A commit removes the checkpoints before it: the pointer and one directory are left.
    assert_eq!(dir_names(&out_dir.join("checkpoint")), ["0000000006", "current"]);

    // Meta's carried image is checkpointed with its count of carries.
    let count = vkinverse::npy::read(&committed(&out_dir).join("carry_count.npy")).unwrap();
    assert_eq!(count.data, [6.0], "carries in six iterations");
    let image = vkinverse::npy::read(&committed(&out_dir).join("carried_image_0.npy")).unwrap();
    assert!(image.data.iter().any(|&v| v > 0.0), "the checkpointed carried image is black");
    // With its weights' state (w, the carried image's variance, the fresh render's, the
    // difference's, the adjoint render's weight), and the log of the weights.
    let state0 = vkinverse::npy::read(&committed(&out_dir).join("carry_state_0.npy")).unwrap();
    assert_eq!(state0.data.len(), 5);
    assert!(state0.data[0] > 0.0 && state0.data[0] < 1.0 && state0.data[1] > 0.0 && state0.data[1] < state0.data[2], "carry state {:?}", state0.data);
    assert!(state0.data[4] > 0.0 && state0.data[4] < 1.0, "the adjoint render's weight {}", state0.data[4]);

    // θ and the previous θ are saved as θ's three floats in one texel, without the material
    // data that follow them in θ's buffer (the format of earlier checkpoints), and the
    // previous θ is the iterate before the last.
    let theta = vkinverse::npy::read(&committed(&out_dir).join("theta.npy")).unwrap();
    let prev = vkinverse::npy::read(&committed(&out_dir).join("theta_prev.npy")).unwrap();
    assert_eq!((theta.data.len(), prev.data.len()), (4, 4));
    assert!(theta.data[..3] != prev.data[..3] && prev.data[..3].iter().all(|v| (0.0..=1.0).contains(v)), "θ {:?}, previous θ {:?}", theta.data, prev.data);

    // A checkpoint that holds state the optimiser no longer keeps (the variance
    // calibration's and the sign run's of earlier versions) resumes: those files are not read.
    for name in ["meta_nis.npy", "meta_run.npy"] {
        vkinverse::npy::write(&committed(&out_dir).join(name), &vkinverse::npy::Array { shape: vec![4], data: vec![0.0; 4] }).unwrap();
    }
    // Nor the adjoint render's weight in its carry state and log.
    let state_path = committed(&out_dir).join("carry_state_0.npy");
    vkinverse::npy::write(&state_path, &vkinverse::npy::Array { shape: vec![4], data: state0.data[..4].to_vec() }).unwrap();
    let carry_csv = committed(&out_dir).join("carry.csv");
    let earlier: String = std::fs::read_to_string(&carry_csv).unwrap().lines().map(|l| l.rsplit_once(',').unwrap().0.to_string() + "\n").collect();
    assert!(earlier.starts_with("iteration,sensor,weight,var_carried,var_fresh,var_diff\n"), "{earlier}");
    std::fs::write(&carry_csv, earlier).unwrap();
    vkinverse_ok(&with(&["--iterations", "10", "--resume"]));
    let (header, rows) = read_log(&out_dir);
    assert_eq!(header, LOG_HEADER);
    let iterations: Vec<String> = rows.iter().map(|r| r[0].clone()).collect();
    assert_eq!(iterations, (0..=10).map(|i| i.to_string()).collect::<Vec<_>>(), "iterations 0..=10, each once");
    // The first six rows are kept as they were.
    assert_eq!(rows[..7], first[..]);
    // So are the first six steps' diagnostics, and the resumed steps follow them.
    let diag = |dir: &Path| std::fs::read_to_string(dir.join("optimiser.csv")).unwrap();
    let (before, after) = (diag(&committed(&out_dir)), diag(&out_dir));
    assert_eq!(after.lines().count(), 11, "header and ten steps");
    assert_eq!(after, before, "the last checkpoint holds the whole diagnostics log");
    let iters: Vec<&str> = after.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(iters, (1..=10).map(|i| i.to_string()).collect::<Vec<_>>());
    // Likewise the carried image's log: one row per step, the first carry's weight 1, the
    // last step's row the checkpoint's state.
    let carry = std::fs::read_to_string(out_dir.join("carry.csv")).unwrap();
    assert_eq!(carry, std::fs::read_to_string(committed(&out_dir).join("carry.csv")).unwrap());
    let carry_rows: Vec<Vec<String>> = carry.lines().skip(1).map(|l| l.split(',').map(String::from).collect()).collect();
    // (The log resumed from the earlier format is written in the current one.)
    assert_eq!(carry.lines().next().unwrap(), "iteration,sensor,weight,var_carried,var_fresh,var_diff,weight_adjoint");
    assert_eq!(carry_rows.iter().map(|r| r[0].clone()).collect::<Vec<_>>(), (1..=10).map(|i| i.to_string()).collect::<Vec<_>>());
    assert_eq!(field(&carry_rows[0], 2), 1.0, "the first carry takes the fresh render");
    let last_state = vkinverse::npy::read(&committed(&out_dir).join("carry_state_0.npy")).unwrap();
    assert!((field(&carry_rows[9], 2) - last_state.data[0] as f64).abs() < 1e-6, "{:?} against {:?}", carry_rows[9], last_state.data);
    let times: Vec<f64> = rows.iter().map(|r| field(r, 1)).collect();
    assert!(times.windows(2).all(|w| w[0] <= w[1]), "time_s restarted on resume: {times:?}");
    // θ continues: the step after the checkpoint starts near the checkpoint's error, far
    // from the initial one.
    let e = |i: usize| field(&rows[i], 4);
    assert!((e(7) - e(6)).abs() < 0.05 && (e(7) - e(6)).abs() < 0.5 * (e(7) - e(0)).abs(), "errors {:?}", (e(0), e(6), e(7)));
    assert!(e(10) < e(6), "no progress after resuming: {:?}", (e(6), e(10)));

    let summary = json(&out_dir.join("summary.json"));
    assert_eq!(summary["iterations"], 10);
    assert!((summary["initial_param_error"].as_f64().unwrap() - e(0)).abs() < 1e-9, "the initial error is the run's, not the checkpoint's");
    assert!((summary["final_param_error"].as_f64().unwrap() - e(10)).abs() < 1e-9);
    assert_eq!(json(&committed(&out_dir).join("state.json"))["iteration"], 10);

    // Resuming with the other optimiser cannot use this state.
    let mut adam = with(&["--iterations", "12", "--resume"]);
    adam[3] = "adam".into();
    vkinverse_err(&adam, &["checkpoint", "meta"]);
}

#[test]
fn time_budget_stops_the_run() {
    let out_dir = temp_dir("budget");
    let out = vkinverse_ok(&["optimise", &s(tiny_cornell()), "--optimiser", "adam", "--time-budget", "2", "--quiet", "-o", &s(&out_dir)]);
    let summary = json(&out_dir.join("summary.json"));
    let total = summary["total_time_s"].as_f64().unwrap();
    // The loop stops where another iteration of the mean length would pass the budget: it
    // ends near the budget, past it by less than one iteration (tiny ones here) at most.
    assert!((1.0..4.0).contains(&total), "optimised for {total} s on a 2 s budget");
    let (_, rows) = read_log(&out_dir);
    assert!(rows.len() > 2, "only {} rows", rows.len());
    // log.csv rounds to microseconds.
    assert!(field(rows.last().unwrap(), 1) <= total + 1e-6, "{:?} after {total} s", rows.last());
    // Set-up (target, pipelines, final render) comes on top and is slow on a busy CPU.
    assert!(out.wall < Duration::from_secs(60), "the run took {:?}", out.wall);
}

#[test]
fn bad_scenes_are_one_line_errors_and_write_nothing() {
    let check = |name: &str, scene: &Path, needles: &[&str]| {
        let out_dir = scene.parent().unwrap().join("out");
        let line = vkinverse_err(&["optimise", &s(scene), "--iterations", "2", "-o", &s(&out_dir)], needles);
        assert!(!out_dir.exists(), "{name}: output directory created");
        line
    };

    let toml = edited_cornell("bad-toml", |t| replace_once(t, "height = 16", "height = = 16"));
    let line = check("toml", &toml, &["scene.toml:7:"]);
    // toml's own multi-line snippet (`7 | height = = 16` and a caret) is not squeezed in.
    assert!(!line.contains('^') && !line.contains(" | "), "{line}");

    let missing = edited_cornell("missing-obj", |t| replace_once(t, "meshes/floor.obj", "meshes/no_floor.obj"));
    check("missing obj", &missing, &["scene.toml", "no_floor.obj"]);

    let broken = cornell_copy("broken-obj");
    std::fs::write(broken.parent().unwrap().join("meshes/floor.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n").unwrap();
    check("broken obj", &broken, &["floor.obj:4", "7"]);

    let target = edited_cornell("bad-target", |t| replace_once(t, "fov_y = 39.3", "fov_y = 39.3\ntarget_image = \"target.exr\""));
    std::fs::write(target.parent().unwrap().join("target.exr"), "P6 16 16 255\n").unwrap();
    check("target", &target, &["target_image", "target.exr"]);

    let nothing = temp_dir("no-scene").join("scene.toml");
    check("no scene", &nothing, &["scene.toml"]);
}

#[test]
fn bad_optimise_flags_are_one_line_errors() {
    let scene = s(tiny_cornell());
    let out_dir = temp_dir("bad-flags").join("out");
    let run = |extra: &[&str], needles: &[&str]| {
        let args: Vec<&str> = ["optimise", scene.as_str(), "-o", out_dir.to_str().unwrap()].iter().chain(extra).copied().collect();
        vkinverse_err(&args, needles);
        assert!(!out_dir.exists(), "{extra:?}: output directory created");
    };
    run(&["--lr", "-1"], &["--lr", "-1"]);
    run(&["--lr", "0"], &["--lr"]);
    run(&["--optimiser", "foo"], &["--optimiser", "foo"]);
    run(&["--time-budget", "-1"], &["--time-budget"]);
    run(&["--time-budget", "nan"], &["--time-budget"]);
    run(&["--spp", "0"], &["--spp"]);
    run(&["--fd-spp", "0"], &["--fd-spp"]);
    run(&["--iterations", "0"], &["--iterations", "at least 1"]);
    run(&["--checkpoint-every", "0"], &["--checkpoint-every", "at least 1"]);
    run(&["--target-spp", "0"], &["--target-spp", "at least 1"]);
    run(&["--resume", "--overwrite"], &["--resume", "--overwrite"]);
    run(&["--unknown-flag"], &["--unknown-flag"]);
    let resume_dir = temp_dir("resume-nothing");
    vkinverse_err(&["optimise", &scene, "--iterations", "2", "--resume", "-o", &s(&resume_dir)], &["no committed checkpoint"]);
    // A missing required argument is named.
    vkinverse_err(&["optimise", &scene], &["--output"]);
    vkinverse_err(&["gradcheck", &scene, "--spp", "0"], &["--spp"]);
    vkinverse_err(&["gradcheck", &scene, "--primal-spp", "0"], &["--primal-spp", "at least 1"]);
    vkinverse_err(&["bench", "--elements", "0"], &["--elements"]);
}

/// Gradient streams with magnitudes from 1e-3 to 1e2 and both signs.
fn streams(iterations: usize, n: usize) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let value = |i: usize, j: usize, salt: f32| ((i * 7 + j * 13) as f32 * 0.37 + salt).sin() * 10f32.powi((j % 6) as i32 - 3);
    let g = (0..iterations).map(|i| (0..n).map(|j| value(i, j, 0.0)).collect()).collect();
    let fd = (0..iterations).map(|i| (0..n).map(|j| 0.1 * value(i, j, 1.3)).collect()).collect();
    (g, fd)
}

#[test]
fn replay_matches_the_cpu_reference() {
    let dir = temp_dir("replay");
    let (iterations, n) = (12, 5);
    let (g, fd) = streams(iterations, n);
    let grads = dir.join("grads.npy");
    let fd_grads = dir.join("fd_grads.npy");
    npy::write_rows(&grads, &g).unwrap();
    npy::write_rows(&fd_grads, &fd).unwrap();
    let init: Vec<f32> = (0..n).map(|j| 0.2 + 0.1 * j as f32).collect();
    let init_path = dir.join("init.npy");
    npy::write(&init_path, &Array { shape: vec![n], data: init.clone() }).unwrap();

    // Half-pixel sums of both streams, for the centred variance estimate of meta's defaults.
    let half = |rows: &[Vec<f32>]| rows.iter().map(|r| r.iter().enumerate().map(|(j, x)| x * (0.3 + 0.1 * j as f32)).collect()).collect::<Vec<Vec<f32>>>();
    let (gh, fh) = (half(&g), half(&fd));
    let (gh_path, fh_path) = (dir.join("gh.npy"), dir.join("fh.npy"));
    npy::write_rows(&gh_path, &gh).unwrap();
    npy::write_rows(&fh_path, &fh).unwrap();
    let halves = format!("{},{}", s(&gh_path), s(&fh_path));

    let seed_meta = "meta@step=snr@var=zero@fdvar=scaled@decay_d=0.9";
    let cases: [(&str, Option<&[f32]>, Option<&str>); 8] = [
        ("adam", None, None),
        ("meta", None, None),
        ("meta-seed@step=newton", Some(&init), Some("0.1,0.7")),
        (seed_meta, None, None),
        ("meta@step=newton@sig=1@settle=0.5@decay_h=0.8", Some(&init), Some("0.1,0.7")),
        ("adam@schedule=cosine@horizon=12", Some(&init), Some("0,1")),
        ("meta@step=snr@fdvar=raw@carry=0", Some(&init), Some("0.1,0.7")),
        (seed_meta, Some(&init), Some("0.1,0.7")),
    ];
    for (k, (name, start, range)) in cases.into_iter().enumerate() {
        let traj = dir.join(format!("traj-{k}.npy"));
        let diag = dir.join(format!("diag-{k}.csv"));
        let mut args = vec!["replay".to_string(), "--optimiser".into(), name.into(), "--lr".into(), "0.05".into()];
        if start.is_some() {
            args.extend(["--init".into(), s(&init_path)]);
        }
        if let Some(r) = range {
            args.extend(["--range".into(), r.into()]);
        }
        let optimiser = name.parse::<vkinverse::optim::spec::Spec>().unwrap().optimiser;
        if optimiser.needs_halves() {
            args.extend(["--halves".into(), halves.clone()]);
        }
        args.extend(["--diagnostics".into(), s(&diag)]);
        args.extend([s(&grads), s(&fd_grads), "-o".into(), s(&traj)]);
        vkinverse_ok(&args);

        let got = npy::read(&traj).unwrap();
        assert_eq!(got.shape, [iterations + 1, n]);
        let zeros = vec![0.0; n];
        let start = start.unwrap_or(&zeros);
        let rows = got.rows();
        assert_eq!(rows[0], start, "{name}: row 0 is the start");
        let range: Range = range.map_or(Range::UNBOUNDED, |r| r.parse().unwrap());
        let streams = optim::Streams {
            grads: &g,
            fd_grads: Some(&fd),
            grad_halves: optimiser.needs_halves().then_some(gh.as_slice()),
            fd_halves: optimiser.needs_halves().then_some(fh.as_slice()),
        };
        // Newton's rule is held to the f32 reference: on streams whose ⟨ΔF⟩ ignore the steps
        // its curvature rests on steps that f32 resolves coarsely (src/optim/tests.rs).
        let newton = matches!(optimiser, optim::Optimiser::Meta(h) if h.step == optim::StepRule::Newton);
        let cpu = if newton {
            optim::replay::replay_streams::<f32>(&optimiser, &streams, start, range, 0.05)
        } else {
            optim::replay::replay_streams::<f64>(&optimiser, &streams, start, range, 0.05)
        }
        .unwrap();
        for (i, (gpu_row, cpu_row)) in rows.iter().zip(&cpu.theta).enumerate() {
            for (j, (a, b)) in gpu_row.iter().zip(cpu_row).enumerate() {
                assert!((*a as f64 - b).abs() < 1e-5, "{name} {range:?}: θ[{i}][{j}] GPU {a} CPU {b}");
                assert!(range.lo <= *a as f64 && *a as f64 <= range.hi);
            }
        }
        // The diagnostics file: one row per step, its step sizes those of the reference.
        let log = vkinverse::optim::csv::DiagLog::parse(&std::fs::read_to_string(&diag).unwrap()).unwrap();
        assert_eq!(log.rows.len(), iterations, "{name}");
        for ((_, _, d), c) in log.rows.iter().zip(&cpu.diagnostics) {
            assert!((d.rms_step - c.rms_step).abs() <= 1e-4 * c.rms_step.max(1e-6), "{name}: rms_step {} vs {}", d.rms_step, c.rms_step);
        }
        // The trajectory moved: a replay that ignored the gradients would also start right.
        assert!(rows[iterations] != rows[0], "{name}: θ never moved");
    }
}

#[test]
fn bad_replay_inputs_are_one_line_errors() {
    let dir = temp_dir("replay-bad");
    let (g, fd) = streams(4, 3);
    let grads = dir.join("grads.npy");
    npy::write_rows(&grads, &g).unwrap();
    let fd_grads = dir.join("fd_grads.npy");
    npy::write_rows(&fd_grads, &fd).unwrap();

    let bytes = std::fs::read(&grads).unwrap();
    let truncated = dir.join("truncated.npy");
    std::fs::write(&truncated, &bytes[..bytes.len() - 6]).unwrap();
    // Same header length, so only the dtype is wrong.
    let f8 = dir.join("float64.npy");
    let mut f8_bytes = bytes.clone();
    let descr = f8_bytes.windows(5).position(|w| w == b"'<f4'").expect("dtype in the header");
    f8_bytes[descr + 3] = b'8';
    std::fs::write(&f8, f8_bytes).unwrap();
    let narrow = dir.join("narrow.npy");
    npy::write_rows(&narrow, &fd.iter().map(|r| r[..2].to_vec()).collect::<Vec<_>>()).unwrap();
    let one_d = dir.join("one_d.npy");
    npy::write(&one_d, &Array { shape: vec![3], data: vec![0.0; 3] }).unwrap();
    let bad_init = dir.join("init4.npy");
    npy::write(&bad_init, &Array { shape: vec![4], data: vec![0.0; 4] }).unwrap();

    let before = dir_names(&dir);
    let traj = s(&dir.join("traj.npy"));
    let run = |args: &[&str], needles: &[&str]| {
        let mut all = vec!["replay"];
        all.extend_from_slice(args);
        all.extend_from_slice(&["-o", &traj]);
        vkinverse_err(&all, needles);
    };
    let (grads, fd_grads) = (s(&grads), s(&fd_grads));
    run(&["--optimiser", "adam", &s(&dir.join("missing.npy"))], &["missing.npy", "not found"]);
    run(&["--optimiser", "adam", &s(&truncated)], &["truncated.npy", "truncated"]);
    run(&["--optimiser", "adam", &s(&f8)], &["float64.npy", "<f8"]);
    run(&["--optimiser", "adam", &s(&one_d)], &["one_d.npy", "[iterations, n]"]);
    run(&["--optimiser", "meta", &grads, &s(&narrow)], &["narrow.npy", "[4, 2]", "[4, 3]"]);
    run(&["--optimiser", "meta", &grads], &["meta", "FD_GRADS"]);
    run(&["--optimiser", "adam", "--range", "1,0", &grads], &["--range", "1,0"]);
    run(&["--optimiser", "adam", "--range", "0", &grads], &["--range"]);
    run(&["--optimiser", "adam", "--lr", "-1", &grads], &["--lr"]);
    run(&["--optimiser", "foo", &grads, &fd_grads], &["--optimiser", "foo"]);
    run(&["--optimiser", "adam", "--init", &s(&bad_init), &grads], &["init4.npy", "4 values"]);
    assert_eq!(dir_names(&dir), before, "a failed replay left files behind");
}

/// The tiny Cornell box (16², depth 2) is resolved by the automatic rounds in a few
/// seconds: every element "pass", exit 0; the JSON report carries each element's z and the
/// standard error the 10 % bias needs, and the combined statistic.
#[test]
fn gradcheck_passes_on_the_cornell_box() {
    let out = vkinverse_ok(&["gradcheck", &s(tiny_cornell())]);
    let rows: Vec<&str> = out.stdout.lines().filter(|l| l.starts_with("materials.red.base_color")).collect();
    assert_eq!(rows.len(), 3, "one row per colour channel:\n{}", out.stdout);
    assert!(rows.iter().all(|r| r.trim_end().ends_with("pass")), "{}", out.stdout);
    assert!(out.stdout.lines().any(|l| l == "verdict: pass"), "{}", out.stdout);
    let out = vkinverse_ok(&["gradcheck", &s(tiny_cornell()), "--json", "--primal-spp", "32"]);
    let report: serde_json::Value = serde_json::from_str(&out.stdout).unwrap();
    assert_eq!(report["verdict"], "pass");
    assert_eq!((report["spp"].as_u64(), report["primal_spp"].as_u64()), (Some(16), Some(32)));
    assert!(report["rounds"].as_u64().unwrap() >= 8, "at least the pilot's rounds");
    let p = report["combined"]["p_value"].as_f64().unwrap();
    assert!((1e-3..=1.0).contains(&p), "combined p {p}");
    for row in report["rows"].as_array().unwrap() {
        let (z, se, needed) = (row["z"].as_f64().unwrap(), row["se"].as_f64().unwrap(), row["se_needed"].as_f64().unwrap());
        assert!(z.abs() <= 4.0 && se > 0.0 && se <= needed, "{row}");
        assert_eq!(row["verdict"], "pass");
        // The median of the rounds lies on the side of 0 where most of them are.
        let (median, negative) = (row["adjoint_median"].as_f64().unwrap(), row["adjoint_share_negative"].as_f64().unwrap());
        assert!((0.0..=1.0).contains(&negative), "{row}");
        assert!(
            if negative > 0.5 {
                median < 0.0
            } else if negative < 0.5 {
                median >= 0.0
            } else {
                true
            },
            "{row}"
        );
    }
}

/// Four rounds cannot resolve the gap scene (light through a 2 cm gap): the verdict is
/// "inconclusive", no element says "pass", and the exit status is non-zero.
#[test]
fn gradcheck_too_noisy_to_decide_is_inconclusive_and_fails_the_command() {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/gap");
    let dir = temp_dir("gradcheck-gap");
    std::fs::create_dir_all(dir.join("meshes")).unwrap();
    for entry in std::fs::read_dir(src.join("meshes")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), dir.join("meshes").join(entry.file_name())).unwrap();
    }
    let text = std::fs::read_to_string(src.join("scene.toml")).unwrap().replacen("width = 64", "width = 16", 1).replacen("height = 64", "height = 16", 1);
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    let scene = s(&dir.join("scene.toml"));
    let out = vkinverse(&["gradcheck", &scene, "--rounds", "4", "--spp", "4"]);
    assert!(!out.ok(), "an inconclusive check must not exit 0:\n{}", out.stdout);
    assert!(out.stderr.contains("gradcheck inconclusive") && out.stderr.contains("rounds"), "{}", out.stderr);
    assert!(out.stdout.lines().any(|l| l.starts_with("verdict: inconclusive")), "{}", out.stdout);
    let rows: Vec<&str> = out.stdout.lines().filter(|l| l.starts_with("materials.")).collect();
    assert_eq!(rows.len(), 6, "{}", out.stdout);
    assert!(rows.iter().all(|r| !r.trim_end().ends_with("pass")), "{}", out.stdout);
}

// ---------------------------------------------------------------------------------------
// The run directory (src/rundir.rs): lock, used directories, crash-safe checkpoints, resume.

/// `optimise` of the tiny Cornell box with the meta-estimator into `dir`, with `extra`.
fn optimise_args(dir: &Path, extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> = ["optimise", &s(tiny_cornell()), "--optimiser", "meta", "-o", &s(dir)].map(String::from).to_vec();
    args.extend(extra.iter().map(|a| a.to_string()));
    args
}

/// Every file under `dir` (but the lock) with its bytes, to show that nothing changed.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let p = entry.unwrap().path();
        if p.is_dir() {
            out.extend(snapshot(&p));
        } else if p.file_name().is_some_and(|n| n != ".lock") {
            out.push((p.clone(), std::fs::read(&p).unwrap()));
        }
    }
    out.sort();
    out
}

/// Runs with the debug build's `VKINVERSE_DEBUG_ABORT_AT=step` and checks that it stopped
/// there.
fn killed_at(args: &[String], step: &str) {
    let out = vkinverse_env(args, &[("VKINVERSE_DEBUG_ABORT_AT", step)]);
    let name = step.split(':').next().unwrap();
    assert!(!out.ok() && out.stderr.contains(&format!("aborting at {name}")), "{args:?} did not stop at {step}: {:?}\n{}", out.code, out.stderr);
}

/// Sends `signal` to process `pid`.
fn send(pid: u32, signal: libc::c_int) {
    // SAFETY: kill(2) with a child's id and a signal number reads and writes no memory.
    let sent = unsafe { libc::kill(pid as libc::pid_t, signal) };
    assert_eq!(sent, 0, "kill -{signal} {pid}: {}", std::io::Error::last_os_error());
}

/// Runs the binary (as [`vkinverse_during`]) and sends it `signal` once, as soon as
/// `ready(its stderr so far)`; fails the test if it ended before that.
fn signalled_when<S: AsRef<std::ffi::OsStr>>(args: &[S], envs: &[(&str, &str)], signal: libc::c_int, mut ready: impl FnMut(&str) -> bool) -> Output {
    let mut sent = false;
    let out = vkinverse_during(args, envs, |pid, err| {
        if !sent && ready(err) {
            send(pid, signal);
            sent = true;
        }
    });
    assert!(sent, "{:?} ended before it was ready for signal {signal}:\n{}", args.iter().map(|a| a.as_ref().to_string_lossy()).collect::<Vec<_>>(), out.stderr);
    out
}

/// The iteration of the committed checkpoint of run directory `dir`, if any (its pointer
/// names it, zero-padded).
fn committed_iteration(dir: &Path) -> Option<u64> {
    std::fs::read_to_string(dir.join("checkpoint/current")).ok()?.trim().parse().ok()
}

/// Ctrl-C while `optimise` iterates (src/interrupt.rs): the run stops after its current
/// iteration, writes every output as at any end (its summary says it was interrupted),
/// exits with 130 and says how to continue; `--resume` continues it (SIGTERM stops it
/// likewise), to the iterations asked for, each iteration logged once.
#[test]
fn a_ctrl_c_stops_the_run_with_its_outputs_and_resume_finishes_it() {
    let dir = temp_dir("interrupt");
    // Once the first checkpoint is committed the loop is iterating.
    let args = optimise_args(&dir, &["--iterations", "100000", "--checkpoint-every", "1", "--quiet"]);
    let out = signalled_when(&args, &[], libc::SIGINT, |_| dir.join("checkpoint/current").exists());
    assert_eq!(out.code, Some(130), "{}", out.stderr);
    let summary = json(&dir.join("summary.json"));
    let n = summary["iterations"].as_u64().unwrap();
    assert!((1..100000).contains(&n), "stopped at iteration {n}");
    assert_eq!(summary["interrupted"], true);
    let lines: Vec<&str> = out.stderr.lines().collect();
    assert_eq!(
        lines,
        [format!("vkinverse: interrupted: stopped at iteration {n} of 100000; the same command with --resume continues the run in {}", dir.display())]
    );
    assert_eq!(read_log(&dir).1.len() as u64, n + 1, "log.csv holds iterations 0..={n}");
    assert_eq!(json(&committed(&dir).join("state.json"))["iteration"], n);
    for file in ["final.exr", "error_vs_time.png", "optimiser.csv", "optimiser.png", "params/params.json", "final/scene.toml"] {
        assert!(dir.join(file).exists(), "{file} not written");
    }
    // Resumed, and stopped again by SIGTERM (a batch scheduler's notice) once it has moved
    // on: the same, with the status 143 that SIGTERM's end has.
    let args = optimise_args(&dir, &["--iterations", "100000", "--checkpoint-every", "1", "--quiet", "--resume"]);
    let out = signalled_when(&args, &[], libc::SIGTERM, |_| committed_iteration(&dir).is_some_and(|i| i > n));
    assert_eq!(out.code, Some(143), "{}", out.stderr);
    let summary = json(&dir.join("summary.json"));
    let m = summary["iterations"].as_u64().unwrap();
    assert!(m > n && summary["interrupted"] == true, "{summary}");
    let more = (m + 2).to_string();
    let out = vkinverse_ok(&optimise_args(&dir, &["--iterations", &more, "--checkpoint-every", "1", "--resume"]));
    assert!(out.stderr.contains(&format!("resuming from the checkpoint at iteration {m}")), "{}", out.stderr);
    let summary = json(&dir.join("summary.json"));
    assert_eq!((summary["iterations"].as_u64(), summary["interrupted"].as_bool()), (Some(m + 2), Some(false)));
    let iterations: Vec<String> = read_log(&dir).1.iter().map(|r| r[0].clone()).collect();
    assert_eq!(iterations, (0..=m + 2).map(|i| i.to_string()).collect::<Vec<_>>());
}

/// Ctrl-C during a batch: the job it stops keeps its outputs and is recorded as
/// interrupted, with its values there; no further job starts; the table is written and the exit status is 130.
#[test]
fn a_ctrl_c_stops_a_batch_after_the_job_it_interrupts_and_resume_continues_it() {
    let dir = temp_dir("interrupt-batch");
    let jobs = dir.join("jobs.toml");
    let scene = s(tiny_cornell());
    std::fs::write(&jobs, format!("iterations = 100000\ncheckpoint_every = 1\n[[jobs]]\nscene = \"{scene}\"\n[[jobs]]\nscene = \"{scene}\"\nseed = 1\n"))
        .unwrap();
    let out_dir = dir.join("out");
    let iterating = || std::fs::read_dir(&out_dir).into_iter().flatten().any(|e| e.unwrap().path().join("checkpoint/current").exists());
    let out = signalled_when(&["--quiet", "batch", &s(&jobs), "-o", &s(&out_dir)], &[], libc::SIGINT, |_| iterating());
    assert_eq!(out.code, Some(130), "{}", out.stderr);
    let said =
        format!("vkinverse: interrupted: 1 of 2 jobs ran (see {}); the same command with --resume continues the batch", out_dir.join("results.csv").display());
    assert!(out.stderr.trim_end().ends_with(&said), "{}", out.stderr);
    let results = json(&out_dir.join("results.json"));
    let rows = results["results"].as_array().unwrap();
    assert_eq!(rows.len(), 1, "{results}");
    assert_eq!(rows[0]["status"], "interrupted");
    assert!(rows[0]["message"].as_str().unwrap().starts_with("stopped at iteration"), "{}", rows[0]["message"]);
    let run = out_dir.join(rows[0]["dir"].as_str().unwrap());
    let summary = json(&run.join("summary.json"));
    assert_eq!(summary["interrupted"], true);
    // The row holds the run's values where it stopped.
    assert_eq!(rows[0]["iterations"], summary["iterations"], "{results}");
    assert_eq!(rows[0]["final_loss"], summary["final_loss"], "{results}");
    assert!(std::fs::read_to_string(out_dir.join("results.csv")).unwrap().contains(",interrupted,stopped at iteration"));
    assert_eq!(dir_names(&out_dir).iter().filter(|n| n.starts_with("job-")).count(), 1, "the second job started");
    // The scene's plot has the interrupted job's curve up to where it stopped.
    let curves = |out_dir: &Path| -> String {
        let names: Vec<String> = dir_names(out_dir).into_iter().filter(|n| n.starts_with("curves-") && n.ends_with(".csv")).collect();
        assert_eq!(names.len(), 1, "{names:?}");
        std::fs::read_to_string(out_dir.join(&names[0])).unwrap()
    };
    let label = rows[0]["label"].as_str().unwrap();
    let stopped = format!("{label} (interrupted),");
    let points = curves(&out_dir).lines().filter(|l| l.starts_with(&stopped)).count() as u64;
    assert_eq!(points, summary["iterations"].as_u64().unwrap() + 1, "{}", curves(&out_dir));
    // So has a merge of the table, which reads the logs back.
    let merged = dir.join("merged");
    vkinverse_ok(&["--quiet", "batch", "--merge", &s(&out_dir), "-o", &s(&merged)]);
    assert_eq!(curves(&merged), curves(&out_dir));

    // --resume continues the batch (the flags' iterations replacing the jobs'): the first
    // job from its checkpoint, the second afresh.
    let n = json(&run.join("summary.json"))["iterations"].as_u64().unwrap();
    let total = (n + 2).to_string();
    let again = ["--quiet", "batch", &s(&jobs), "--resume", "--iterations", &total, "-o", &s(&out_dir)];
    vkinverse_ok(&again);
    let results = json(&out_dir.join("results.json"));
    let rows = results["results"].as_array().unwrap();
    assert_eq!(rows.len(), 2, "{results}");
    for row in rows {
        assert_eq!((row["status"].as_str(), row["iterations"].as_u64()), (Some("ok"), Some(n + 2)), "{row}");
    }
    let iterations: Vec<String> = read_log(&run).1.iter().map(|r| r[0].clone()).collect();
    assert_eq!(iterations, (0..=n + 2).map(|i| i.to_string()).collect::<Vec<_>>(), "the first job continued where it stopped");
    // Finished, its curve is the whole run's, under its own label.
    let text = curves(&out_dir);
    assert!(!text.contains("(interrupted)") && text.lines().filter(|l| l.starts_with(&format!("{label},"))).count() as u64 == n + 3, "{text}");
    // Once more: both runs are finished and read back as they are, not run again.
    let before = snapshot(&out_dir);
    vkinverse_ok(&again);
    assert_eq!(json(&out_dir.join("results.json")), results);
    let runs = |snap: Vec<(PathBuf, Vec<u8>)>| snap.into_iter().filter(|(p, _)| p.strip_prefix(&out_dir).unwrap().starts_with("job-")).collect::<Vec<_>>();
    assert!(runs(snapshot(&out_dir)) == runs(before), "a finished job's directory changed");
}

/// Ctrl-C during `render`: the image written holds the samples rendered until then, as a
/// render of that many samples with the same seed does (up to rounding), and the exit
/// status is 130.
#[test]
fn a_ctrl_c_ends_a_render_with_the_samples_so_far() {
    let dir = temp_dir("interrupt-render");
    let partial = dir.join("partial.exr");
    let args = ["render", &s(tiny_cornell()), "--spp", "100000000", "--seed", "7", "-o", &s(&partial)];
    // Every submission prints a progress line: the render is under way once one is there.
    let out = signalled_when(&args, &[("VKINVERSE_PROGRESS_SECS", "0")], libc::SIGINT, |err| err.contains("render: "));
    assert_eq!(out.code, Some(130), "{}", out.stderr);
    let last = out.stderr.lines().last().unwrap_or_default();
    let k: u32 = last
        .strip_prefix("vkinverse: interrupted: stopped at ")
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{}", out.stderr));
    assert_eq!(last, format!("vkinverse: interrupted: stopped at {k} of 100000000 samples per pixel; {} holds their mean", partial.display()));
    assert!((1..100000000).contains(&k));
    let whole = dir.join("whole.exr");
    vkinverse_ok(&["render", &s(tiny_cornell()), "--spp", &k.to_string(), "--seed", "7", "--quiet", "-o", &s(&whole)]);
    let (a, b) = (vkinverse::image::read_exr(&partial).unwrap(), vkinverse::image::read_exr(&whole).unwrap());
    assert_eq!((a.width, a.height), (b.width, b.height));
    for (p, q) in a.data.iter().flatten().zip(b.data.iter().flatten()) {
        assert!((p - q).abs() <= 1e-4 * (q.abs() + 1e-3), "{p} against {q} from a render of {k} spp");
    }
}

/// `render --time-budget`: a render that its --spp would keep going for hours stops soon
/// after the budget runs out, with the samples rendered by then, and says how many; a
/// budget that is not a positive number is refused.
#[test]
fn a_render_stops_at_its_time_budget() {
    let dir = temp_dir("render-budget");
    let exr = dir.join("budget.exr");
    let out = vkinverse_ok(&["render", &s(tiny_cornell()), "--spp", "100000000", "--time-budget", "1", "-o", &s(&exr)]);
    assert!(out.wall < Duration::from_secs(60), "the render took {:?}", out.wall);
    let last = out.stderr.lines().last().unwrap_or_default();
    let k: u32 =
        last.strip_prefix("rendered 16x16 at ").and_then(|r| r.split(' ').next()).and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("{}", out.stderr));
    assert!((1..100000000).contains(&k) && last.contains(" spp (the time budget's) in "), "{last}");
    let image = vkinverse::image::read_exr(&exr).unwrap();
    let mean = image.data.iter().flatten().map(|&v| v as f64).sum::<f64>() / (3 * image.data.len()) as f64;
    assert!(image.data.iter().flatten().all(|v| v.is_finite() && *v >= 0.0) && mean > 0.0, "mean {mean}");
    for bad in ["0", "-1", "nan"] {
        vkinverse_err(&["render", &s(tiny_cornell()), "--time-budget", bad, "-o", &s(&exr)], &["--time-budget", "not positive and finite"]);
    }
}

/// Ctrl-C while `optimise` renders its targets: no run is written (nor a partial target
/// cached), the exit status is 130, and the directory takes a run afterwards.
#[test]
fn a_ctrl_c_while_the_targets_render_writes_no_run() {
    let scene = cornell_copy("interrupt-target");
    let dir = temp_dir("interrupt-target-run");
    let args = ["optimise", &s(&scene), "--target-spp", "100000000", "--iterations", "2", "-o", &s(&dir)];
    let out = signalled_when(&args, &[("VKINVERSE_PROGRESS_SECS", "0")], libc::SIGINT, |err| err.contains("target: "));
    assert_eq!(out.code, Some(130), "{}", out.stderr);
    let last = out.stderr.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("vkinverse: interrupted: while rendering the target of sensor 0 (")
            && last.ends_with(" of 100000000 samples per pixel); no iteration ran"),
        "{}",
        out.stderr
    );
    for file in vkinverse::rundir::RUN_FILES {
        assert!(!dir.join(file).exists(), "{file} written");
    }
    let cache = scene.parent().unwrap().join(".vkinverse-cache");
    assert!(!cache.exists() || dir_names(&cache).is_empty(), "a partial target cached: {:?}", dir_names(&cache));
    vkinverse_ok(&["optimise", &s(&scene), "--target-spp", "16", "--iterations", "2", "--quiet", "-o", &s(&dir)]);
}

/// Ctrl-C during a comparison: the run it stops keeps its outputs, the next optimiser
/// does not start, no comparison is written, and the exit status is 130.
#[test]
fn a_ctrl_c_stops_a_comparison_without_a_table_and_resume_continues_it() {
    let out_dir = temp_dir("interrupt-compare").join("out");
    let args = ["--quiet", "compare", &s(tiny_cornell()), "--optimisers", "meta,adam", "--iterations", "100000", "--checkpoint-every", "1", "-o", &s(&out_dir)];
    let out = signalled_when(&args, &[], libc::SIGINT, |_| out_dir.join("meta/checkpoint/current").exists());
    assert_eq!(out.code, Some(130), "{}", out.stderr);
    let meta = out_dir.join("meta");
    let n = json(&meta.join("summary.json"))["iterations"].as_u64().unwrap();
    assert_eq!(
        out.stderr.lines().collect::<Vec<_>>(),
        [format!(
            "vkinverse: interrupted: meta stopped at iteration {n} (its outputs are in {}); no comparison written; the same command with --resume continues it",
            meta.display()
        )]
    );
    for name in ["adam", "compare.csv", "compare.json", "error_vs_time.png"] {
        assert!(!out_dir.join(name).exists(), "{name} written");
    }
    // --resume continues meta's run and starts adam's; the comparison is written.
    let total = (n + 2).to_string();
    vkinverse_ok(&["--quiet", "compare", &s(tiny_cornell()), "--optimisers", "meta,adam", "--iterations", &total, "--resume", "-o", &s(&out_dir)]);
    let runs = json(&out_dir.join("compare.json"))["runs"].as_array().unwrap().clone();
    assert_eq!(runs.len(), 2);
    for run in &runs {
        assert_eq!(run["iterations"].as_u64(), Some(n + 2), "{run}");
    }
    assert_eq!(read_log(&meta).1.len() as u64, n + 3, "meta's log holds iterations 0..={}", n + 2);
}

#[test]
#[cfg_attr(not(debug_assertions), ignore = "pauses or kills the run at a named step: only debug builds have those points (src/rundir.rs)")]
fn a_busy_directory_is_refused_at_once() {
    let dir = temp_dir("busy");
    let mut first = Command::new(env!("CARGO_BIN_EXE_vkinverse"))
        .args(optimise_args(&dir, &["--iterations", "2", "--quiet"]))
        .env("VKINVERSE_DEBUG_PAUSE_AT", "run.locked")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufRead::read_line(&mut std::io::BufReader::new(first.stderr.take().unwrap()), &mut line).unwrap();
    assert!(line.contains("paused at run.locked"), "{line}");
    let second = vkinverse_err(&optimise_args(&dir, &["--iterations", "2", "--overwrite"]), &[&s(&dir), "another run"]);
    let _ = first.kill();
    let _ = first.wait();
    assert!(second.contains(".lock"), "{second}");
    // The lock goes with its process, however it ends: the directory holds no run.
    vkinverse_ok(&optimise_args(&dir, &["--iterations", "1", "--quiet"]));
}

#[test]
fn a_used_directory_needs_resume_or_overwrite() {
    let dir = temp_dir("used");
    vkinverse_ok(&optimise_args(&dir, &["--iterations", "2", "--quiet"]));
    let before = snapshot(&dir);
    vkinverse_err(&optimise_args(&dir, &["--iterations", "2"]), &[&s(&dir), "holds a run", "--resume", "--overwrite"]);
    assert_eq!(snapshot(&dir), before, "a refusal deletes or changes nothing");
    vkinverse_ok(&optimise_args(&dir, &["--iterations", "3", "--seed", "5", "--overwrite", "--quiet"]));
    let summary = json(&dir.join("summary.json"));
    assert_eq!((summary["iterations"].as_u64(), summary["settings"]["seed"].as_u64()), (Some(3), Some(5)));
    assert_eq!(read_log(&dir).1.len(), 4);
}

#[test]
#[cfg_attr(not(debug_assertions), ignore = "pauses or kills the run at a named step: only debug builds have those points (src/rundir.rs)")]
fn a_killed_overwrite_never_mixes_two_runs() {
    let dir = temp_dir("overwrite-kill");
    vkinverse_ok(&optimise_args(&dir, &["--iterations", "3", "--quiet"]));
    // Killed after the old run's pointer went: nothing of it is resumable any more.
    killed_at(&optimise_args(&dir, &["--iterations", "3", "--overwrite", "--quiet"]), "overwrite.cleared");
    vkinverse_err(&optimise_args(&dir, &["--iterations", "3", "--resume"]), &["no committed checkpoint"]);
    // Killed before its first checkpoint is committed: none of the old run's files remain
    // beside the new run's, and there is no checkpoint to resume.
    killed_at(&optimise_args(&dir, &["--iterations", "3", "--checkpoint-every", "1", "--overwrite", "--quiet"]), "checkpoint.written:1");
    for old in ["summary.json", "params", "final.exr", "error_vs_time.png", "log.csv", "optimiser.csv", "optimiser.png"] {
        assert!(!dir.join(old).exists(), "{old} left beside the new run");
    }
    assert!(!dir.join("checkpoint/current").exists());
}

/// A run killed after its last checkpoint, while it writes its outputs, gets them from
/// `--resume`, which after that changes nothing; and a run whose last iteration fell on a
/// checkpoint commits that iteration once (a second commit of it would remove the
/// committed checkpoint before writing its replacement, leaving nothing to resume meanwhile).
#[test]
#[cfg_attr(not(debug_assertions), ignore = "pauses or kills the run at a named step: only debug builds have those points (src/rundir.rs)")]
fn resume_writes_the_outputs_a_kill_left_out() {
    // Commits at iterations 2, 4 and 6, and no fourth.
    let dir = temp_dir("final-commit");
    let out = vkinverse_env(
        &optimise_args(&dir, &["--iterations", "6", "--checkpoint-every", "2", "--quiet"]),
        &[("VKINVERSE_DEBUG_ABORT_AT", "checkpoint.written:4")],
    );
    assert!(out.ok(), "a fourth checkpoint was written ({:?}):\n{}", out.code, out.stderr);
    assert_eq!(json(&dir.join("summary.json"))["iterations"], 6);

    let dir = temp_dir("outputs-kill");
    let args = optimise_args(&dir, &["--iterations", "3", "--checkpoint-every", "2", "--quiet", "--resume"]);
    killed_at(&optimise_args(&dir, &["--iterations", "3", "--checkpoint-every", "2", "--quiet"]), "run.checkpointed");
    assert_eq!(json(&committed(&dir).join("state.json"))["iteration"], 3);
    assert!(!dir.join("summary.json").exists());
    vkinverse_ok(&args);
    assert_eq!(json(&dir.join("summary.json"))["iterations"], 3);
    for file in ["final.exr", "error_vs_time.png", "optimiser.png", "params/params.json"] {
        assert!(dir.join(file).exists(), "{file} not written");
    }
    let iterations: Vec<String> = read_log(&dir).1.iter().map(|r| r[0].clone()).collect();
    assert_eq!(iterations, ["0", "1", "2", "3"]);
    // Every table has a row per iteration, not only those up to the previous checkpoint.
    for table in ["optimiser.csv", "carry.csv"] {
        let text = std::fs::read_to_string(dir.join(table)).unwrap();
        let last = text.lines().last().unwrap_or_default();
        assert!(last.starts_with("3,"), "{table} lost its last rows:\n{text}");
    }
    let before = snapshot(&dir);
    let out = vkinverse_ok(&args);
    assert!(out.stdout.contains("nothing to do"), "{}", out.stdout);
    assert!(snapshot(&dir) == before, "a finished run changed");
}

#[test]
#[cfg_attr(not(debug_assertions), ignore = "pauses or kills the run at a named step: only debug builds have those points (src/rundir.rs)")]
fn the_checkpoint_swap_survives_a_kill_at_each_step() {
    // (step of the second commit, iteration of the checkpoint a resume finds)
    for (step, resumed_from) in [("checkpoint.written:2", 2), ("checkpoint.committed:2", 4)] {
        let dir = temp_dir(&format!("swap-{}", step.replace([':', '.'], "-")));
        killed_at(&optimise_args(&dir, &["--iterations", "6", "--checkpoint-every", "2", "--quiet"]), step);
        assert_eq!(json(&committed(&dir).join("state.json"))["iteration"], resumed_from, "{step}");
        let out = vkinverse_ok(&optimise_args(&dir, &["--iterations", "6", "--checkpoint-every", "2", "--resume"]));
        assert!(out.stderr.contains(&format!("resuming from the checkpoint at iteration {resumed_from}")), "{}", out.stderr);
        let (_, rows) = read_log(&dir);
        let iterations: Vec<String> = rows.iter().map(|r| r[0].clone()).collect();
        assert_eq!(iterations, (0..=6).map(|i| i.to_string()).collect::<Vec<_>>(), "{step}: iterations 0..=6, each once");
        assert_eq!(json(&dir.join("summary.json"))["iterations"], 6);
        assert_eq!(dir_names(&dir.join("checkpoint")), ["0000000006", "current"], "{step}");
    }
}

#[test]
fn resume_checks_the_scene_and_reports_changed_settings() {
    let dir = temp_dir("resume-checks");
    vkinverse_ok(&optimise_args(&dir, &["--iterations", "2", "--quiet"]));
    let before = snapshot(&dir);
    // Another parameter set: named, refused, nothing changed.
    let other = edited_cornell("resume-other-param", |t| replace_once(t, "target = \"materials.red.base_color\"", "target = \"materials.green.base_color\""));
    let args = |scene: &Path, extra: &[&str]| {
        let mut a = vec!["optimise".to_string(), s(scene), "--optimiser".into(), "meta".into(), "-o".into(), s(&dir), "--resume".into()];
        a.extend(extra.iter().map(|x| x.to_string()));
        a
    };
    vkinverse_err(&args(&other, &["--iterations", "4"]), &["cannot resume", "materials.red.base_color", "materials.green.base_color"]);
    // Another scene: its content hash differs.
    let moved = edited_cornell("resume-other-scene", |t| replace_once(t, "fov_y = 39.3", "fov_y = 45"));
    vkinverse_err(&args(&moved, &["--iterations", "4"]), &["cannot resume", "content differs"]);
    assert_eq!(snapshot(&dir), before);
    // A finished run with nothing left to do: said so, nothing changed.
    let out = vkinverse_ok(&args(tiny_cornell(), &["--iterations", "2"]));
    assert!(out.stdout.contains("nothing to do"), "{}", out.stdout);
    assert_eq!(snapshot(&dir), before, "resuming a finished run changed its files");
    // Changed settings are allowed and listed.
    let out = vkinverse_ok(&args(tiny_cornell(), &["--iterations", "3", "--spp", "3"]));
    assert!(out.stderr.contains("iterations: 2 -> 3") && out.stderr.contains("spp: 2 -> 3"), "{}", out.stderr);
    assert_eq!(json(&dir.join("summary.json"))["iterations"], 3);
}

#[test]
fn progress_lines_and_light_warnings_on_a_pipe() {
    let dir = temp_dir("progress");
    // stderr is a pipe here: periodic lines instead of a bar (every update at 0 s).
    let out = vkinverse_env(&["render", &s(tiny_cornell()), "--spp", "8", "-o", &s(&dir.join("x.exr"))], &[("VKINVERSE_PROGRESS_SECS", "0")]);
    assert!(out.ok(), "{}", out.stderr);
    assert!(out.stderr.contains("render: 4/8 (50 %) samples") && out.stderr.contains("render: 8/8 (100 %) samples"), "{}", out.stderr);
    // A scene without light says so.
    let dark = edited_cornell("dark", |t| {
        let lit = t.lines().find(|l| l.trim_start().starts_with("emission")).expect("the light's emission").to_string();
        replace_once(t, &lit, "emission = [0, 0, 0]")
    });
    let out = vkinverse_ok(&["render", &s(&dark), "--spp", "1", "-o", &s(&dir.join("dark.exr"))]);
    assert!(out.stderr.contains("warning") && out.stderr.contains("no light"), "{}", out.stderr);
    // So does a normal map on meshes without texture coordinates (the Cornell box's).
    let bumpy = edited_cornell("bumpy", |t| replace_once(t, "name = \"red\"", "name = \"red\"\nnormal_map = { texture = \"n.exr\" }"));
    vkinverse::image::write_exr(&bumpy.with_file_name("n.exr"), &vkinverse::image::Image::filled(2, 2, [0.6, 0.5, 0.9])).unwrap();
    let out = vkinverse_ok(&["render", &s(&bumpy), "--spp", "1", "-o", &s(&dir.join("bumpy.exr"))]);
    assert!(out.stderr.contains("warning") && out.stderr.contains("has no texture coordinates") && out.stderr.contains("\"red\""), "{}", out.stderr);
    // And an alpha texture there, which then cuts nothing out.
    let masked = edited_cornell("masked", |t| replace_once(t, "name = \"red\"", "name = \"red\"\nalpha = { texture = \"a.exr\" }"));
    vkinverse::image::write_exr(&masked.with_file_name("a.exr"), &vkinverse::image::Image::filled(2, 2, [0.0; 3])).unwrap();
    let out = vkinverse_ok(&["render", &s(&masked), "--spp", "1", "-o", &s(&dir.join("masked.exr"))]);
    assert!(out.stderr.contains("warning") && out.stderr.contains("the alpha texture of its material \"red\" is not applied"), "{}", out.stderr);
}

#[test]
fn replay_refuses_non_finite_start_values() {
    let dir = temp_dir("replay-nan");
    let (g, _) = streams(3, 2);
    let grads = dir.join("grads.npy");
    npy::write_rows(&grads, &g).unwrap();
    let init = dir.join("init.npy");
    npy::write(&init, &Array { shape: vec![2], data: vec![0.5, f32::NAN] }).unwrap();
    vkinverse_err(&["replay", "--optimiser", "adam", "--init", &s(&init), &s(&grads), "-o", &s(&dir.join("t.npy"))], &["init.npy", "value 1 is NaN"]);
}

/// A scene bench times its synthetic θ at 1M parameters unless `--elements` says otherwise
/// (at the buffer bench's 16M it was most of a scene bench's run time on lavapipe).
#[test]
fn scene_bench_sizes_its_synthetic_theta_by_default_and_by_flag() {
    let scene = s(tiny_cornell());
    let bench = |extra: &[&str]| -> serde_json::Value {
        let args: Vec<&str> = ["bench", scene.as_str(), "--iterations", "1", "--json"].iter().chain(extra).copied().collect();
        let out = vkinverse_ok(&args);
        serde_json::from_str(&out.stdout).unwrap_or_else(|e| panic!("{e}:\n{}", out.stdout))
    };
    let elements = |v: &serde_json::Value| v["optimisers"]["elements"].as_u64().expect("optimisers.elements");
    let warm_up = |v: &serde_json::Value| (v["warm_up"]["rounds"].as_u64().expect("warm_up.rounds"), v["warm_up"]["seconds"].as_f64().unwrap());
    let default = bench(&[]);
    assert_eq!(elements(&default), 1 << 20);
    // On a CPU device the only untimed round is the one that compiles the pipelines; with a
    // warm-up time, rounds repeat until it has passed.
    if std::env::var("VKINVERSE_TEST_DEVICE").is_err() {
        assert_eq!(warm_up(&default).0, 1, "{}", default["warm_up"]);
    }
    let warmed = bench(&["--elements", "4096", "--warm-up", "0.3"]);
    assert_eq!(elements(&warmed), 4096);
    let (rounds, seconds) = warm_up(&warmed);
    assert!(rounds >= 2 && seconds >= 0.3, "{}", warmed["warm_up"]);
    for bad in ["-1", "nan", "1e9"] {
        vkinverse_err(&["bench", scene.as_str(), &format!("--warm-up={bad}")], &["--warm-up", "between 0 and 3600 seconds"]);
    }
}

/// `compare` into a directory holding an `optimise` run refuses, under the same lock and
/// used-directory rule, and leaves the run's files as they were.
#[test]
fn compare_refuses_a_directory_holding_an_optimise_run() {
    let dir = temp_dir("compare-into-run");
    vkinverse_ok(&optimise_args(&dir, &["--iterations", "1", "--quiet"]));
    let before = snapshot(&dir);
    let err = vkinverse_err(
        &["--quiet", "compare", &s(tiny_cornell()), "--optimisers", "meta,adam", "--iterations", "1", "-o", &s(&dir)],
        &["holds an optimisation's run", "--overwrite"],
    );
    assert!(!err.contains("panicked"), "{err}");
    assert!(snapshot(&dir) == before, "compare changed the run's files");
    let file = dir.join("summary.json");
    vkinverse_err(&["--quiet", "compare", &s(tiny_cornell()), "--optimisers", "meta", "--iterations", "1", "-o", &s(&file)], &["is a file, not a directory"]);
}
