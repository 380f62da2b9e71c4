//! `compare` and `batch` end to end: the built binary on the tiny Cornell box with the
//! validation layer on, their tables read back, and bad input checked to give one
//! `vkinverse: error:` line.

use crate::common;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use vkinverse::image::read_exr;

use common::binary::{json, s, vkinverse_err, vkinverse_ok};
use common::pictures::{assert_panels, assert_run_pictures};
use common::scenes::temp_dir;

/// One directory per test process with `cornell/` (scenes/cornell at 16×16, direct light
/// only, so its target is rendered once) and `broken/` (a scene file that does not parse).
fn scenes() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = temp_dir("compare-batch-scenes");
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cornell");
        let meshes = dir.join("cornell/meshes");
        std::fs::create_dir_all(&meshes).unwrap();
        for entry in std::fs::read_dir(src.join("meshes")).unwrap() {
            let entry = entry.unwrap();
            std::fs::copy(entry.path(), meshes.join(entry.file_name())).unwrap();
        }
        let mut text = std::fs::read_to_string(src.join("scene.toml")).unwrap();
        for (from, to) in [("width = 64", "width = 16"), ("height = 64", "height = 16"), ("max_depth = 4", "max_depth = 2")] {
            assert!(text.contains(from), "scenes/cornell/scene.toml no longer has `{from}`");
            text = text.replacen(from, to, 1);
        }
        std::fs::write(dir.join("cornell/scene.toml"), text).unwrap();
        std::fs::create_dir_all(dir.join("broken")).unwrap();
        std::fs::write(dir.join("broken/scene.toml"), "[film]\nwidth = \"wide\"\n").unwrap();
        dir
    })
}

/// Splits one CSV line (RFC 4180 quoting, no line breaks inside fields).
fn csv_line(line: &str) -> Vec<String> {
    let mut fields = vec![String::new()];
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                chars.next();
                fields.last_mut().unwrap().push('"');
            }
            ('"', _) => quoted = !quoted,
            (',', false) => fields.push(String::new()),
            _ => fields.last_mut().unwrap().push(c),
        }
    }
    fields
}

/// A CSV file as its header and rows; every row has the header's number of fields.
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header = csv_line(lines.next().expect("empty CSV"));
    let rows: Vec<Vec<String>> = lines.map(csv_line).collect();
    for r in &rows {
        assert_eq!(r.len(), header.len(), "{}: row {r:?}", path.display());
    }
    (header, rows)
}

fn num(field: &str) -> f64 {
    field.parse().unwrap_or_else(|_| panic!("{field:?} is not a number"))
}

#[test]
fn compare_two_optimisers() {
    let out = temp_dir("compare");
    let cornell = scenes().join("cornell/scene.toml");
    let printed =
        vkinverse_ok(&["compare", &s(&cornell), "--optimisers", "meta,adam@beta1=0.5", "--iterations", "4", "--lr", "0.05", "--seed", "3", "-o", &s(&out)])
            .stdout;
    assert!(printed.contains("meta") && printed.contains("adam@beta1=0.5") && printed.contains("speed-up"), "{printed}");
    for name in ["meta", "adam@beta1=0.5", "compare.csv", "compare.json", "curves.csv", "error_vs_time.png", "optimiser.png", "finals.png"] {
        assert!(out.join(name).exists(), "{name} missing");
    }
    // Each run is a full optimise run with the same settings and seed.
    for (dir, optimiser) in [("meta", "meta"), ("adam@beta1=0.5", "adam")] {
        let summary = json(&out.join(dir).join("summary.json"));
        assert_eq!(summary["optimiser"], optimiser);
        assert_eq!(summary["iterations"], 4);
        assert_eq!(summary["settings"]["seed"], 3);
        assert!(out.join(dir).join("log.csv").exists());
    }
    assert_eq!(json(&out.join("adam@beta1=0.5/summary.json"))["settings"]["optimiser"], "adam@beta1=0.5");

    let (header, rows) = read_csv(&out.join("compare.csv"));
    assert_eq!(
        header,
        ["label", "optimiser", "iterations", "time_s", "final_error", "time_to_2x", "time_to_1x", "time_to_0.5x", "speedup", "image_error_over_reference"]
    );
    assert_eq!(rows.len(), 2);
    assert_eq!((rows[0][0].as_str(), rows[1][0].as_str()), ("meta", "adam@beta1=0.5"));
    for r in &rows {
        assert_eq!(r[2], "4");
        assert!(num(&r[3]) > 0.0 && num(&r[4]) > 0.0, "{r:?}");
        // Empty (never reached) or a time within the run.
        for t in &r[5..8] {
            assert!(t.is_empty() || (0.0..=num(&r[3]) + 1e-6).contains(&num(t)), "{r:?}");
        }
        // The run's own summary less its reference's.
        let summary = json(&out.join(&r[0]).join("summary.json"));
        let over = summary["final_image_error"].as_f64().unwrap() - summary["reference_image_error"].as_f64().unwrap();
        assert!((num(&r[9]) - over).abs() <= 1e-9 * over.abs().max(1e-12), "{r:?}: {over}");
    }
    // The runs share their seed, so they share the reference's renders.
    let floors: Vec<f64> =
        ["meta", "adam@beta1=0.5"].iter().map(|d| json(&out.join(d).join("summary.json"))["reference_image_error"].as_f64().unwrap()).collect();
    assert_eq!(floors[0], floors[1]);
    // The baseline reaches its own final error (at the latest at its end): speed-up 1.
    assert!((num(&rows[0][8]) - 1.0).abs() < 1e-12, "{:?}", rows[0]);

    let (header, points) = read_csv(&out.join("curves.csv"));
    assert_eq!(header, ["label", "time_s", "error"]);
    let labels: BTreeSet<&str> = points.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(labels, BTreeSet::from(["meta", "adam@beta1=0.5"]));
    for label in labels {
        let curve: Vec<(f64, f64)> = points.iter().filter(|r| r[0] == label).map(|r| (num(&r[1]), num(&r[2]))).collect();
        // The reference is known: the parameter error, from the start (row 0) on.
        assert_eq!(curve.len(), 5, "{label}: {curve:?}");
        assert!(curve.windows(2).all(|w| w[0].0 <= w[1].0), "{label}: time goes backwards");
        let final_error = rows.iter().find(|r| r[0] == label).map(|r| num(&r[4]));
        assert_eq!(final_error, Some(curve[4].1), "{label}: compare.csv's final error is the curve's last point");
    }

    let summary = json(&out.join("compare.json"));
    assert_eq!(summary["metric"], "param_error");
    assert_eq!(summary["baseline"], "meta");
    assert_eq!(summary["runs"].as_array().map(Vec::len), Some(2));

    // finals.png: the target, then each run's final image in --optimisers order.
    let meta = assert_run_pictures(&out.join("meta"), 1, (16, 16));
    let adam = read_exr(&out.join("adam@beta1=0.5/final.exr")).unwrap();
    assert_eq!(read_exr(&out.join("adam@beta1=0.5/target.exr")).unwrap(), meta[0].0, "the runs share their target");
    assert_panels(&out.join("finals.png"), &[meta[0].0.clone(), meta[0].2.clone(), adam]);
    // A finished run without its pictures (one from before runs wrote them), read back by a
    // resume: no finals.png, and a warning naming the missing file.
    std::fs::remove_file(out.join("adam@beta1=0.5/final.exr")).unwrap();
    std::fs::remove_file(out.join("finals.png")).unwrap();
    let args = ["compare", &s(&cornell), "--optimisers", "meta,adam@beta1=0.5", "--iterations", "4", "--lr", "0.05", "--seed", "3", "--resume", "-o", &s(&out)];
    let resumed = vkinverse_ok(&args).stderr;
    assert!(resumed.contains("finals.png not written") && resumed.contains("final.exr is missing"), "{resumed}");
    assert!(!out.join("finals.png").exists());

    let bytes = std::fs::read(out.join("error_vs_time.png")).unwrap();
    let info = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().expect("error_vs_time.png decodes");
    assert!(info.info().width > 0 && info.info().height > 0);

    // A bad spec is refused before anything runs.
    let bad = temp_dir("compare-bad").join("out");
    vkinverse_err(&["compare", &s(&cornell), "--optimisers", "meta,adam@beta3=0.5", "-o", &s(&bad)], &["beta3", "adam"]);
    vkinverse_err(&["compare", &s(&cornell), "--optimisers", "meta,meta", "-o", &s(&bad)], &["meta", "twice"]);
    assert!(!bad.exists());
}

/// The job file of the batch tests: the product gives jobs 1 and 2, job 3 names a scene
/// that does not parse, job 4 sets its own optimiser spec and spp.
fn jobs_file(name: &str) -> PathBuf {
    let path = scenes().join(name);
    let text = "iterations = 2\nlr = 0.05\nscenes = [\"cornell/scene.toml\"]\noptimisers = [\"meta\", \"adam\"]\n\n\
                [[jobs]]\nscene = \"broken/scene.toml\"\n\n\
                [[jobs]]\nscene = \"cornell/scene.toml\"\noptimiser = \"adam@beta1=0.5\"\nspp = 1\n";
    std::fs::write(&path, text).unwrap();
    path
}

/// results.json's rows with what does not depend on timing or location: job, label,
/// optimiser, seed, spp, status, message, iterations.
fn rows_of(dir: &Path) -> Vec<Vec<String>> {
    let results = json(&dir.join("results.json"));
    let rows = results["results"].as_array().expect("results array");
    let (header, csv_rows) = read_csv(&dir.join("results.csv"));
    assert_eq!(header.join(","), "job,label,scene,optimiser,seed,spp,status,message,iterations,time_s,final_loss,final_error,final_image_error,dir");
    assert_eq!(csv_rows.len(), rows.len(), "results.csv and results.json differ");
    rows.iter()
        .zip(&csv_rows)
        .map(|(r, c)| {
            let keys = ["job", "label", "optimiser", "seed", "spp", "status", "message", "iterations"];
            let fields: Vec<String> = keys
                .iter()
                .map(|k| {
                    if r[k].is_string() {
                        r[k].as_str().unwrap().to_string()
                    } else if r[k].is_null() {
                        String::new()
                    } else {
                        r[k].to_string()
                    }
                })
                .collect();
            // The CSV holds the same values.
            let from_csv: Vec<&String> = [0, 1, 3, 4, 5, 6, 7, 8].iter().map(|&i| &c[i]).collect();
            assert_eq!(from_csv, fields.iter().collect::<Vec<_>>());
            fields
        })
        .collect()
}

#[test]
fn batch_records_failures_and_shards_merge() {
    let jobs = jobs_file("jobs.toml");
    let all = temp_dir("batch-all");
    let line = vkinverse_err(&["--quiet", "batch", &s(&jobs), "-o", &s(&all)], &["1 of 4 jobs failed", "results.csv"]);
    assert!(line.contains(&s(&all)), "{line}");
    let rows = rows_of(&all);
    assert_eq!(rows.iter().map(|r| r[0].as_str()).collect::<Vec<_>>(), ["1", "2", "3", "4"]);
    assert_eq!(rows.iter().map(|r| r[5].as_str()).collect::<Vec<_>>(), ["ok", "ok", "failed", "ok"]);
    assert_eq!(rows.iter().map(|r| r[2].as_str()).collect::<Vec<_>>(), ["meta", "adam", "", "adam@beta1=0.5"]);
    assert!(rows[2][6].contains("broken") && rows[2][6].contains("scene.toml:2:"), "the failure names the file and line: {:?}", rows[2][6]);
    for ok in [&rows[0], &rows[1], &rows[3]] {
        assert_eq!((ok[6].as_str(), ok[7].as_str()), ("", "2"), "{ok:?}");
    }
    assert_eq!(rows[3][4], "1", "job 4's own spp");
    for (k, label) in [(1, "cornell-meta"), (2, "cornell-adam"), (4, "cornell-adam@beta1=0.5-spp1")] {
        assert_eq!(rows[k - 1][1], label);
        assert!(all.join(format!("job-{k}-{label}/summary.json")).exists(), "job {k}'s outputs");
    }
    // One plot for the scene with the three finished jobs' curves (row 0 plus 2 iterations
    // each), and the data behind it.
    let (header, points) = read_csv(&all.join("curves-cornell.csv"));
    assert_eq!(header, ["label", "time_s", "error"]);
    let labels: BTreeSet<&str> = points.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(labels, BTreeSet::from(["cornell-meta", "cornell-adam", "cornell-adam@beta1=0.5-spp1"]));
    assert_eq!(points.len(), 9);
    let bytes = std::fs::read(all.join("error_vs_time-cornell.png")).unwrap();
    png::Decoder::new(std::io::Cursor::new(bytes)).read_info().expect("error_vs_time-cornell.png decodes");

    // Shards 1/2 (jobs 1, 3) and 2/2 (jobs 2, 4), merged, give the same rows.
    let shard1 = temp_dir("batch-shard1");
    let shard2 = temp_dir("batch-shard2");
    vkinverse_err(&["--quiet", "batch", &s(&jobs), "--shard", "1/2", "-o", &s(&shard1)], &["1 of 2 jobs failed"]);
    vkinverse_ok(&["--quiet", "batch", &s(&jobs), "--shard", "2/2", "-o", &s(&shard2)]);
    assert_eq!(rows_of(&shard1).iter().map(|r| r[0].as_str()).collect::<Vec<_>>(), ["1", "3"]);
    let merged = temp_dir("batch-merged");
    // Shard 2 first: the merge sorts by job.
    vkinverse_ok(&["--quiet", "batch", "--merge", &s(&shard2), &s(&shard1), "-o", &s(&merged)]);
    assert_eq!(rows_of(&merged), rows);
    assert_eq!(json(&merged.join("results.json"))["total_jobs"], 4);
    // The merge plots the whole batch: the same curves as the unsharded run.
    let (_, merged_points) = read_csv(&merged.join("curves-cornell.csv"));
    let merged_labels: BTreeSet<&str> = merged_points.iter().map(|r| r[0].as_str()).collect();
    assert_eq!((merged_labels, merged_points.len()), (labels, points.len()));
    assert!(merged.join("error_vs_time-cornell.png").exists());

    // A job in two tables is refused.
    let twice = temp_dir("batch-twice").join("out");
    vkinverse_err(&["batch", "--merge", &s(&shard1), &s(&shard1), "-o", &s(&twice)], &["job 1", "both"]);
    assert!(!twice.exists());
}

/// Run settings given on the command line replace every job's, the job file's shared
/// ones and a job's own alike; they are checked like optimise's, and refused with --merge.
#[test]
fn batch_flags_replace_every_jobs_settings() {
    let jobs = jobs_file("jobs-flags.toml");
    let out = temp_dir("batch-flags");
    // Shard 2/2: jobs 2 (the product's adam) and 4 (spp 1 of its own).
    vkinverse_ok(&["--quiet", "batch", &s(&jobs), "--shard", "2/2", "--seed", "5", "--iterations", "3", "--spp", "2", "-o", &s(&out)]);
    let rows = rows_of(&out);
    assert_eq!(
        rows.iter().map(|r| (r[0].as_str(), r[3].as_str(), r[4].as_str(), r[7].as_str())).collect::<Vec<_>>(),
        [("2", "5", "2", "3"), ("4", "5", "2", "3")]
    );
    for dir in ["job-2-cornell-adam", "job-4-cornell-adam@beta1=0.5-spp1"] {
        let summary = json(&out.join(dir).join("summary.json"));
        assert_eq!((summary["settings"]["seed"].as_u64(), summary["iterations"].as_u64()), (Some(5), Some(3)), "{dir}");
        // The file's shared rate, which no flag replaced, still holds.
        assert!((summary["settings"]["lr"].as_f64().unwrap() - 0.05).abs() < 1e-9, "{dir}");
    }
    let bad = temp_dir("batch-flags-bad").join("out");
    vkinverse_err(&["batch", &s(&jobs), "--spp", "0", "-o", &s(&bad)], &["--spp", "at least 1"]);
    vkinverse_err(&["batch", "--merge", &s(&out), "--seed", "1", "-o", &s(&bad)], &["--merge"]);
    assert!(!bad.exists());
}

/// `--film` and `--max-depth` load every job's scene at that size and depth (a protocol at
/// another resolution), each run's summary records what it rendered, and bad values or
/// their use with --merge are refused before anything is written.
#[test]
fn batch_film_and_depth_apply_to_every_job() {
    let jobs = jobs_file("jobs-film.toml");
    let out = temp_dir("batch-film");
    // Shard 1/2: jobs 1 (the product's meta) and 3 (the broken scene, which fails).
    vkinverse_err(
        &["--quiet", "batch", &s(&jobs), "--shard", "1/2", "--film", "12x8", "--max-depth", "1", "--iterations", "1", "-o", &s(&out)],
        &["1 of 2 jobs failed"],
    );
    let rows = rows_of(&out);
    assert_eq!(rows.iter().map(|r| (r[0].as_str(), r[5].as_str())).collect::<Vec<_>>(), [("1", "ok"), ("3", "failed")]);
    let run = out.join("job-1-cornell-meta");
    let summary = json(&run.join("summary.json"));
    assert_eq!((summary["film"].to_string().as_str(), summary["max_depth"].as_u64()), ("[12,8]", Some(1)));
    let image = vkinverse::image::read_exr(&run.join("final.exr")).unwrap();
    assert_eq!((image.width, image.height), (12, 8));
    // Without the flags, the scene's own film (16 × 16 here) and depth (2).
    let plain = temp_dir("batch-film-plain");
    vkinverse_ok(&["--quiet", "batch", &s(&jobs), "--scene", "cornell", "--shard", "1/2", "--iterations", "1", "-o", &s(&plain)]);
    let summary = json(&plain.join("job-1-cornell-meta").join("summary.json"));
    assert_eq!((summary["film"].to_string().as_str(), summary["max_depth"].as_u64()), ("[16,16]", Some(2)));
    let bad = temp_dir("batch-film-bad").join("out");
    vkinverse_err(&["batch", &s(&jobs), "--film", "0x8", "-o", &s(&bad)], &["--film 0x8", "WIDTHxHEIGHT"]);
    vkinverse_err(&["batch", &s(&jobs), "--max-depth", "0", "-o", &s(&bad)], &["--max-depth 0"]);
    vkinverse_err(&["batch", "--merge", &s(&out), "--film", "8x8", "-o", &s(&bad)], &["--merge"]);
    assert!(!bad.exists());
}

#[test]
fn batch_runs_the_jobs_of_the_scenes_named() {
    let jobs = jobs_file("jobs-scene.toml");
    let out = temp_dir("batch-scene");
    // The file's jobs 1, 2 and 4 are the Cornell box's; job 3 (a broken scene) is left out,
    // so the batch succeeds, and the jobs keep their numbers.
    vkinverse_ok(&["--quiet", "batch", &s(&jobs), "--scene", "cornell", "--iterations", "1", "-o", &s(&out)]);
    let rows = rows_of(&out);
    assert_eq!(rows.iter().map(|r| (r[0].as_str(), r[5].as_str())).collect::<Vec<_>>(), [("1", "ok"), ("2", "ok"), ("4", "ok")]);
    assert!(out.join("job-4-cornell-adam@beta1=0.5-spp1").join("summary.json").exists());
    let bad = temp_dir("batch-scene-bad").join("out");
    vkinverse_err(&["batch", &s(&jobs), "--scene", "ajar", "-o", &s(&bad)], &["--scene ajar", "cornell, broken"]);
    vkinverse_err(&["batch", "--merge", &s(&out), "--scene", "cornell", "-o", &s(&bad)], &["--scene"]);
    assert!(!bad.exists());
}

#[test]
fn bad_shards_are_refused() {
    let jobs = jobs_file("jobs-bad-shard.toml");
    let out = temp_dir("batch-bad-shard").join("out");
    for (shard, needle) in [("0/2", "numbered 1 to 2"), ("3/2", "numbered 1 to 2"), ("x", "not I/N"), ("1/0", "at least 1")] {
        vkinverse_err(&["batch", &s(&jobs), "--shard", shard, "-o", &s(&out)], &["--shard", shard, needle]);
    }
    assert!(!out.exists(), "a refused batch wrote {}", out.display());
}
