//! docs/scene-format.md against the loader, both ways: every key its tables document is
//! accepted by the loader in that section (and, for a material key, by every type the
//! table names), and every key the loader accepts is documented. The loader's keys come
//! from `vkinverse::scene::scene_keys` (its serde types) and `MaterialKind::accepts`. Also
//! docs/optimisers.md's spec key table against the parser, the README's scene, and the job
//! files and scenes that are read as they are.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use vkinverse::optim::spec::{ADAM_KEYS, META_KEYS};
use vkinverse::optim::Schedule;
use vkinverse::scene::{scene_keys, MaterialKind, Scene, TEXTURE_SECTION};

use crate::common::scenes::{sphere_obj, temp_dir};

const DOC_PATH: &str = "docs/scene-format.md";
const DOC: &str = include_str!("../../docs/scene-format.md");

/// The section each heading opens. A `###` heading that is not listed stays in the
/// section of the `##` heading above it (the material types under "Materials").
const SECTIONS: &[(&str, &str)] = &[
    ("Top level", ""),
    ("Film", "film"),
    ("Integrator", "integrator"),
    ("Sensors", "sensors"),
    ("Materials", "materials"),
    ("Normal maps", "materials.normal_map"),
    ("Bump maps", "materials.bump_map"),
    ("Textures", TEXTURE_SECTION),
    ("Meshes", "meshes"),
    ("Lights", "lights"),
    ("Environment", "environment"),
    ("Media", "media"),
    ("Optimisation", "optimise"),
    ("Parameters", "optimise.params"),
];

/// One documented key: its section, the material types its table names (`Types:` line;
/// material tables only) and its line in the page.
#[derive(Debug)]
struct Row {
    section: String,
    key: String,
    types: Option<Vec<MaterialKind>>,
    line: usize,
}

fn path(section: &str, key: &str) -> String {
    if section.is_empty() {
        key.to_string()
    } else {
        format!("{section}.{key}")
    }
}

/// The backticked words of `text`.
fn code_spans(text: &str) -> Vec<&str> {
    text.split('`').skip(1).step_by(2).collect()
}

/// Every row of every key table of `doc` (a table whose first column is headed `Key`),
/// or what is malformed.
fn documented(doc: &str) -> Result<Vec<Row>, Vec<String>> {
    let (mut rows, mut errors) = (Vec::new(), Vec::new());
    let (mut parent, mut section, mut types): (Option<&str>, Option<&str>, Option<Vec<MaterialKind>>) = (None, None, None);
    let mut in_keys = false;
    for (i, line) in doc.lines().enumerate() {
        let n = i + 1;
        if line.starts_with('#') {
            let level = line.chars().take_while(|c| *c == '#').count();
            let title = line.trim_start_matches('#').trim();
            let opened = SECTIONS.iter().find(|(h, _)| *h == title).map(|(_, s)| *s);
            section = opened.or(if level > 2 { parent } else { None });
            if level <= 2 {
                parent = opened;
            }
            types = None;
            continue;
        }
        if let Some(list) = line.strip_prefix("Types:") {
            let mut kinds = Vec::new();
            for name in code_spans(list) {
                match MaterialKind::ALL.into_iter().find(|k| k.as_str() == name) {
                    Some(k) => kinds.push(k),
                    None => errors.push(format!("{DOC_PATH}:{n}: `{name}` is no material type")),
                }
            }
            types = Some(kinds);
            continue;
        }
        let Some(cells) = line.trim().strip_prefix('|') else {
            in_keys = false;
            continue;
        };
        let first = cells.split('|').next().unwrap_or("").trim();
        if first.starts_with("---") {
            continue;
        }
        if !in_keys {
            in_keys = first == "Key";
            continue;
        }
        let Some(section) = section else {
            errors.push(format!("{DOC_PATH}:{n}: a key table under a heading that opens no section (add it to SECTIONS)"));
            continue;
        };
        match code_spans(first).as_slice() {
            [key] if first == format!("`{key}`") => rows.push(Row { section: section.to_string(), key: key.to_string(), types: types.clone(), line: n }),
            _ => errors.push(format!("{DOC_PATH}:{n}: the first cell `{first}` is not one key in backticks")),
        }
    }
    if errors.is_empty() {
        Ok(rows)
    } else {
        Err(errors)
    }
}

/// What is documented but not accepted (a), then what is accepted but not documented (b).
fn disagreements(rows: &[Row], accepted: &BTreeSet<(String, &'static str)>) -> Vec<String> {
    let mut errors = Vec::new();
    for r in rows {
        if !accepted.contains(&(r.section.clone(), r.key.as_str())) {
            errors.push(format!("{DOC_PATH}:{}: `{}` is documented but the loader does not accept it", r.line, path(&r.section, &r.key)));
            continue;
        }
        if r.section != "materials" {
            continue;
        }
        match &r.types {
            None => errors.push(format!("{DOC_PATH}:{}: `materials.{}` is in a table without a `Types:` line", r.line, r.key)),
            Some(types) => {
                for t in types.iter().filter(|t| !t.accepts(&r.key)) {
                    errors.push(format!("{DOC_PATH}:{}: `materials.{}` is documented for type {}, which does not take it", r.line, r.key, t.as_str()));
                }
            }
        }
    }
    for (section, key) in accepted {
        let rows_of_key = || rows.iter().filter(|r| r.section == *section && r.key == *key);
        if section != "materials" {
            if rows_of_key().next().is_none() {
                errors.push(format!("`{}` is accepted by the loader but not documented in {DOC_PATH}", path(section, key)));
            }
            continue;
        }
        let takers: Vec<MaterialKind> = MaterialKind::ALL.into_iter().filter(|t| t.accepts(key)).collect();
        if takers.is_empty() {
            errors.push(format!("`materials.{key}` is read by the loader but no material type takes it (MaterialKind::accepts)"));
        }
        for t in takers {
            if !rows_of_key().any(|r| r.types.as_ref().is_some_and(|ts| ts.contains(&t))) {
                errors.push(format!("`materials.{key}` (type {}) is accepted by the loader but not documented in {DOC_PATH}", t.as_str()));
            }
        }
    }
    errors
}

#[test]
fn scene_format_page_and_loader_agree_on_every_key() {
    let rows = documented(DOC).unwrap_or_else(|e| panic!("{}", e.join("\n")));
    let accepted = scene_keys();
    let errors = disagreements(&rows, &accepted);
    assert!(errors.is_empty(), "{} disagreement(s) between the loader and {DOC_PATH}:\n{}", errors.len(), errors.join("\n"));
    assert!(rows.len() >= accepted.len(), "{} rows for {} keys", rows.len(), accepted.len());
}

/// The check can fail: a page without one row, or with a key the loader does not know,
/// is reported by the key's name.
#[test]
fn a_missing_or_unknown_row_is_named() {
    let accepted = scene_keys();
    let without = DOC.replace("| `focus_distance` |", "| ~~removed~~ |");
    assert!(documented(&without).is_err_and(|e| e.iter().any(|m| m.contains("~~removed~~"))));
    let without = DOC.lines().filter(|l| !l.starts_with("| `focus_distance` |")).collect::<Vec<_>>().join("\n");
    let errors = disagreements(&documented(&without).unwrap(), &accepted);
    assert_eq!(errors, ["`sensors.focus_distance` is accepted by the loader but not documented in docs/scene-format.md"]);
    let without = DOC.lines().filter(|l| !l.starts_with("| `nonlinear` |")).collect::<Vec<_>>().join("\n");
    let errors = disagreements(&documented(&without).unwrap(), &accepted);
    assert_eq!(errors, ["`materials.nonlinear` (type plastic) is accepted by the loader but not documented in docs/scene-format.md"]);
    let extra = DOC.replace("| `nonlinear` |", "| `nonlinearity` |");
    let errors = disagreements(&documented(&extra).unwrap(), &accepted);
    assert!(errors.iter().any(|e| e.contains("`materials.nonlinearity` is documented but the loader does not accept it")), "{errors:?}");
    let wrong_type = DOC.replacen("Types: `plastic`.", "Types: `plastic`, `diffuse`.", 1);
    let errors = disagreements(&documented(&wrong_type).unwrap(), &accepted);
    assert!(errors.iter().any(|e| e.contains("`materials.roughness` is documented for type diffuse")), "{errors:?}");
}

/// The page's first example, the minimal scene, loads as it is beside its mesh.
#[test]
fn the_minimal_scene_loads() {
    let start = DOC.find("```toml\n").expect("a TOML example") + "```toml\n".len();
    let text = &DOC[start..start + DOC[start..].find("```").unwrap()];
    let dir = temp_dir("minimal");
    std::fs::write(dir.join("ball.obj"), sphere_obj(1.0, 2, false)).unwrap();
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    let scene = Scene::load(dir.join("scene.toml")).unwrap_or_else(|e| panic!("the minimal scene of {DOC_PATH}: {e}"));
    assert_eq!((scene.sensors.len(), scene.materials.len(), scene.meshes.len(), scene.lights.len()), (1, 1, 1, 1));
    assert_eq!(scene.optimise.params.len(), 1);
}

/// Every TOML example of the page is TOML, and every key in it is one the loader accepts
/// where the example puts it. An example is a scene (`[film]`, `[[sensors]]`, `import`)
/// where its keys are top-level keys; else its keys belong to its heading's section, or
/// else to a section that has them all (`alpha = …` to `materials`).
#[test]
fn every_example_uses_accepted_keys() {
    let accepted = scene_keys();
    let sections: BTreeSet<&str> = accepted.iter().map(|(s, _)| s.as_str()).collect();
    let (mut heading, mut parent, mut errors, mut examples) = ("", "", Vec::new(), 0);
    let mut lines = DOC.lines().enumerate();
    while let Some((i, line)) = lines.next() {
        if line.starts_with('#') {
            let title = line.trim_start_matches('#').trim();
            let opened = SECTIONS.iter().find(|(h, _)| *h == title).map(|(_, s)| *s);
            heading = opened.unwrap_or(if line.starts_with("###") { parent } else { "" });
            if !line.starts_with("###") {
                parent = heading;
            }
        }
        if line != "```toml" {
            continue;
        }
        let text: Vec<&str> = lines.by_ref().map(|(_, l)| l).take_while(|l| *l != "```").collect();
        let table: toml::Table = toml::from_str(&text.join("\n")).unwrap_or_else(|e| panic!("{DOC_PATH}:{}: the example is not TOML: {e}", i + 1));
        let holds = |section: &str| table.keys().all(|k| accepted.contains(&(section.to_string(), k.as_str())));
        let section = ["", heading].into_iter().chain(sections.iter().copied()).find(|s| holds(s)).unwrap_or(heading);
        check_keys(section, &table, &accepted, &sections, &mut |key| errors.push(format!("{DOC_PATH}:{}: the example's `{key}` is not accepted", i + 1)));
        examples += 1;
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
    assert!(examples > 10, "{examples} examples");
}

/// Calls `bad` with every key of `table` (at `section`) that the loader does not accept
/// there, and follows nested tables into their sections: a key's own section where there
/// is one, else the texture reference's.
fn check_keys(section: &str, table: &toml::Table, accepted: &BTreeSet<(String, &str)>, sections: &BTreeSet<&str>, bad: &mut dyn FnMut(String)) {
    for (key, value) in table {
        if !accepted.contains(&(section.to_string(), key.as_str())) {
            bad(path(section, key));
            continue;
        }
        let inner = path(section, key);
        let own = if sections.contains(inner.as_str()) { inner.as_str() } else { TEXTURE_SECTION };
        let tables: Vec<&toml::Table> = match value {
            toml::Value::Table(t) => vec![t],
            toml::Value::Array(items) => items.iter().filter_map(toml::Value::as_table).collect(),
            _ => Vec::new(),
        };
        for t in tables {
            check_keys(own, t, accepted, sections, bad);
        }
    }
}

/// The README's scene, written beside the Cornell box's meshes, loads with what it says:
/// two materials, three meshes, one parameter to recover.
#[test]
fn the_readme_scene_loads() {
    let readme = include_str!("../../README.md");
    let start = readme.find("```toml\n").expect("a TOML example in the README") + "```toml\n".len();
    let text = &readme[start..start + readme[start..].find("```").unwrap()];
    let dir = temp_dir("readme");
    let meshes = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cornell/meshes");
    std::fs::create_dir_all(dir.join("meshes")).unwrap();
    for name in ["left.obj", "back.obj", "light.obj"] {
        std::fs::copy(format!("{meshes}/{name}"), dir.join("meshes").join(name)).unwrap();
    }
    std::fs::write(dir.join("scene.toml"), text).unwrap();
    let scene = Scene::load(dir.join("scene.toml")).unwrap_or_else(|e| panic!("the README's scene: {e}"));
    assert_eq!((scene.materials.len(), scene.meshes.len(), scene.optimise.params.len()), (2, 3, 1));
    assert_eq!(scene.optimise.params[0].name, "materials.red.base_color");
}

// What the documentation and the bundled files promise, against the code: the spec key
// table of docs/optimisers.md, and the job files and scenes that are read as they are.

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

/// Files under `dir` (recursively) whose name ends with `suffix`.
fn files_ending(dir: &Path, suffix: &str, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            files_ending(&path, suffix, out);
        } else if path.file_name().is_some_and(|n| n.to_string_lossy().ends_with(suffix)) {
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
    // Every scene file under scenes/: each scene.toml and its variants (atref.toml,
    // smoke/heldout.toml, …).
    let mut scenes = Vec::new();
    files_ending(&root().join("scenes"), ".toml", &mut scenes);
    scenes.sort();
    assert!(scenes.len() >= 9, "{scenes:?}");
    for path in &scenes {
        vkinverse::Scene::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}

/// The smoke and cloud scenes (experiments/volume.md): their held-out views show the
/// training scene's medium from cameras that are not among its training cameras.
#[test]
fn the_volume_scenes_held_out_views_are_new_views_of_the_same_medium() {
    held_out_views("smoke", 8, true, &["media.smoke.density", "media.smoke.emission"]);
    held_out_views("cloud", 5, false, &["media.cloud.density"]);
    let cloud = Scene::load(root().join("scenes/cloud/scene.toml")).unwrap();
    assert!(cloud.media[0].scatters(), "the cloud scatters");
}

fn held_out_views(name: &str, views: usize, emission_grid: bool, params: &[&str]) {
    let train = Scene::load(root().join(format!("scenes/{name}/scene.toml"))).unwrap();
    let held = Scene::load(root().join(format!("scenes/{name}/heldout.toml"))).unwrap();
    assert_eq!((train.media.len(), train.meshes.len(), train.sensors.len(), held.sensors.len()), (1, 0, views, 2));
    assert_eq!(train.media[0].density.shape.array(), vec![64, 64, 64, 1]);
    let emission = train.media[0].emission.shape.array();
    assert_eq!(emission[emission.len() - 1], 3, "{name}: {emission:?}");
    assert_eq!(emission.len() == 4, emission_grid, "{name}: {emission:?}");
    let (a, b) = (&train.media[0], &held.media[0]);
    assert_eq!((&a.name, a.min, a.max, a.scale, a.step, &a.albedo, a.g), (&b.name, b.min, b.max, b.scale, b.step, &b.albedo, b.g));
    assert!(a.density == b.density && a.emission == b.emission, "heldout.toml's grids are not scene.toml's");
    assert_eq!((train.film.width, train.film.height), (held.film.width, held.film.height));
    for h in &held.sensors {
        assert!(train.sensors.iter().all(|t| t.origin != h.origin), "a held-out view at {:?} is a training view", h.origin);
    }
    let targets: Vec<&str> = train.optimise.params.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(targets, params);
    assert!(held.optimise.params.is_empty());
}
