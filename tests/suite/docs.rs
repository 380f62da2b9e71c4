//! What the documentation and the bundled files promise, against the code: the spec key
//! table of docs/optimisers.md, and the job files and scenes that are read as they are.

use std::path::{Path, PathBuf};
use vkinverse::optim::spec::{ADAM_KEYS, META_KEYS};
use vkinverse::optim::Schedule;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The first column of docs/optimisers.md's key table, as (optimiser, key): `adam@beta1` is
/// ("adam", "beta1"), `@warmup` ("", "warmup").
fn table_keys() -> Vec<(String, String)> {
    let text = std::fs::read_to_string(root().join("docs/optimisers.md")).unwrap();
    let mut rows = text.lines().skip_while(|l| !l.starts_with("| key |")).skip(2).take_while(|l| l.starts_with('|'));
    let mut keys = Vec::new();
    for row in rows.by_ref() {
        let cell = row.trim_start_matches('|').split('|').next().unwrap().trim().trim_matches('`');
        let (optimiser, key) = cell.split_once('@').unwrap_or_else(|| panic!("key cell '{cell}' is not OPTIMISER@KEY or @KEY"));
        keys.push((optimiser.to_string(), key.to_string()));
    }
    keys
}

#[test]
fn optimiser_key_table_and_parser_agree() {
    let table = table_keys();
    assert!(table.len() > 10, "{table:?}");
    let schedule: Vec<&str> = Schedule::KEYS.split(", ").collect();
    // Every key in the table is one the parser takes for its optimiser.
    for (optimiser, key) in &table {
        let known = match optimiser.as_str() {
            "adam" => ADAM_KEYS.iter().any(|k| k.name == key),
            "meta" => META_KEYS.iter().any(|k| k.name == key),
            "" => schedule.contains(&key.as_str()),
            other => panic!("'{other}@{key}': no optimiser {other}"),
        };
        assert!(known, "docs/optimisers.md lists {optimiser}@{key}, which the spec parser does not take");
    }
    // Every key the parser takes is in the table, once.
    let expected = ADAM_KEYS
        .iter()
        .map(|k| ("adam", k.name))
        .chain(META_KEYS.iter().map(|k| ("meta", k.name)))
        .chain(schedule.iter().map(|&k| ("", k)))
        .collect::<Vec<_>>();
    for (optimiser, key) in &expected {
        let n = table.iter().filter(|(o, k)| o == optimiser && k == key).count();
        assert_eq!(n, 1, "{optimiser}@{key} appears {n} times in docs/optimisers.md's key table");
    }
    assert_eq!(table.len(), expected.len());
    // And every spec the table could write parses: each meta key on both meta names.
    for name in ["meta", "meta-seed"] {
        for k in META_KEYS {
            let value = if k.values == "number" { "0.5".to_string() } else { k.values.split('|').next().unwrap().to_string() };
            let spec = format!("{name}@{}={value}", k.name);
            assert!(spec.parse::<vkinverse::Spec>().is_ok(), "{spec}");
        }
    }
}

/// Files under `dir` (recursively) named `name`.
fn files_named(dir: &Path, name: &str, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            files_named(&path, name, out);
        } else if path.file_name().is_some_and(|n| n == name) {
            out.push(path);
        }
    }
}

#[test]
fn job_files_and_scenes_parse() {
    // The protocol's job files (experiments/*.toml; the pilots under experiments/pilots/ are
    // records of earlier versions and are not read).
    let mut jobs: Vec<PathBuf> = std::fs::read_dir(root().join("experiments"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == "toml"))
        .collect();
    jobs.sort();
    assert!(jobs.iter().any(|p| p.ends_with("protocol.toml")) && jobs.iter().any(|p| p.ends_with("bound.toml")), "{jobs:?}");
    for path in &jobs {
        let expanded = vkinverse::batch::load_jobs(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(!expanded.is_empty(), "{}", path.display());
    }
    let mut scenes = Vec::new();
    files_named(&root().join("scenes"), "scene.toml", &mut scenes);
    scenes.sort();
    assert!(scenes.len() >= 6, "{scenes:?}");
    for path in &scenes {
        vkinverse::Scene::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}
