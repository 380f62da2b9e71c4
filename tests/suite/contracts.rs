//! Host/GPU contracts that need no device: every kernel's push block against its Rust
//! mirror, by reflection of the embedded SPIR-V; the constants header generated from
//! src/constants.rs.

use vkinverse::gpu::reflect::Reflection;
use vkinverse::gpu::shaders::KERNELS;
use vkinverse::gpu::PushBlock;
use vkinverse::kernels::*;
use vkinverse::optim::push::{AdamPush, DiagPush, MetaPush};

/// A push block's members (name, byte offset) and size.
type Layout = (&'static [(&'static str, usize)], usize);

fn layout<P: PushBlock>() -> Layout {
    (P::MEMBERS, std::mem::size_of::<P>())
}

/// The host mirror of kernel `kernel`'s push block (`()` for none); None for a kernel
/// that has no mirror.
fn mirror(kernel: &str) -> Option<Layout> {
    // A kernel's BVH-layout builds (`_wide`, `_cw8`) share its block; copy_wide is a kernel
    // of its own.
    let base = if kernel == "copy_wide" { kernel } else { kernel.strip_suffix("_wide").or_else(|| kernel.strip_suffix("_cw8")).unwrap_or(kernel) };
    Some(match base {
        "copy" | "sub" | "merge_half" | "reduce" | "trace_test" | "bsdf_test" | "carry_image" | "carry_stats" | "carry_adjoint" => layout::<CountPush>(),
        "copy_vec4" | "copy_wide" => layout::<Count4Push>(),
        "fill" => layout::<FillPush>(),
        "scale_add" => layout::<ScaleAddPush>(),
        "gather" | "gather_texel" => layout::<GatherPush>(),
        "loss" => layout::<LossPush>(),
        "carry_weight" => layout::<CarryWeightPush>(),
        "records_test" => layout::<RecordsPush>(),
        "majorant" => layout::<MajorantPush>(),
        "bsdf_sample_test" => layout::<BsdfSamplePush>(),
        "rng_test" => layout::<RngTestPush>(),
        "optim_adam" => layout::<AdamPush>(),
        "optim_meta" => layout::<MetaPush>(),
        "optim_diag" => layout::<DiagPush>(),
        "layout_probe" => layout::<()>(),
        k if k.starts_with("trace_") => layout::<TracePush>(),
        _ => return None,
    })
}

/// Every kernel with a push block has a mirror ([`mirror`]) whose members
/// (names and byte offsets, in order) and size are the reflected ones; a kernel without one
/// has the empty mirror.
#[test]
fn every_push_block_matches_its_mirror() {
    assert!(KERNELS.len() > 20, "{} kernels", KERNELS.len());
    for (kernel, spirv) in KERNELS {
        let r = Reflection::new(kernel, spirv).unwrap();
        let (members, size) = mirror(kernel).unwrap_or_else(|| panic!("{kernel}: no Rust mirror of its push block"));
        let reflected: Vec<(&str, usize)> = r.push_members.iter().map(|(n, o)| (n.as_str(), *o)).collect();
        assert_eq!(reflected, members, "{kernel}: push block members and offsets");
        assert_eq!(r.push_constant_size as usize, size, "{kernel}: push block size");
    }
}

/// The constants the kernels compile with are the Rust ones: build.rs generated the header
/// from src/constants.rs, and no kernel source defines one of them itself.
#[test]
fn shared_constants_are_generated_from_one_definition() {
    let header = std::fs::read_to_string(concat!(env!("OUT_DIR"), "/vkinverse_constants.glsl")).unwrap();
    for (name, value) in [
        ("MATERIAL_DIFFUSE", vkinverse::constants::MATERIAL_DIFFUSE),
        ("MATERIAL_PRINCIPLED", vkinverse::constants::MATERIAL_PRINCIPLED),
        ("MATERIAL_DIELECTRIC", vkinverse::constants::MATERIAL_DIELECTRIC),
        ("MATERIAL_THIN_DIELECTRIC", vkinverse::constants::MATERIAL_THIN_DIELECTRIC),
        ("MATERIAL_ROUGH_DIELECTRIC", vkinverse::constants::MATERIAL_ROUGH_DIELECTRIC),
        ("MATERIAL_ROUGH_DIELECTRIC_BECKMANN", vkinverse::constants::MATERIAL_ROUGH_DIELECTRIC_BECKMANN),
        ("LOCAL_GRADS_CAPACITY", vkinverse::constants::LOCAL_GRADS_CAPACITY),
        ("LOSS_L2", vkinverse::constants::LOSS_L2),
        ("LOSS_L1", vkinverse::constants::LOSS_L1),
        ("LOSS_RELATIVE_L2", vkinverse::constants::LOSS_RELATIVE_L2),
    ] {
        assert!(header.contains(&format!("const uint {name} = {value}u;")), "{name} in:\n{header}");
        for dir in ["glsl", "glsl/lib", "glsl/shared"] {
            for entry in std::fs::read_dir(format!("{}/{dir}", env!("CARGO_MANIFEST_DIR"))).unwrap() {
                let path = entry.unwrap().path();
                if path.is_file() {
                    let text = std::fs::read_to_string(&path).unwrap();
                    assert!(!text.contains(&format!("const uint {name} =")), "{} defines {name} itself", path.display());
                }
            }
        }
    }
}

/// The modules of `src/` (the command line's `main.rs` and `cli/` aside) import each other
/// without a loop: top-level modules through `crate::NAME`, and the files of each module
/// directory through `super::NAME`. A loop would mean two layers that cannot be read, built
/// or changed one without the other.
#[test]
fn modules_import_each_other_without_loops() {
    use std::collections::{BTreeMap, BTreeSet};
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    // The identifiers that follow `prefix` in `text`, comments stripped.
    let refs = |text: &str, prefix: &str| -> BTreeSet<String> {
        let code: String = text.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n");
        code.match_indices(prefix)
            .filter(|(at, _)| !code[..*at].ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':'))
            .map(|(at, _)| code[at + prefix.len()..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect())
            .collect()
    };
    let stem = |p: &std::path::Path| p.file_stem().unwrap().to_string_lossy().into_owned();
    let rs_files = |dir: &std::path::Path| -> Vec<std::path::PathBuf> {
        let mut v: Vec<_> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|e| e == "rs")).collect();
        v.sort();
        v
    };
    // Every graph: (what, node -> nodes it imports).
    let mut graphs: Vec<(String, BTreeMap<String, BTreeSet<String>>)> = Vec::new();
    let mut top: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut dirs = Vec::new();
    for entry in std::fs::read_dir(&src).unwrap() {
        let path = entry.unwrap().path();
        let name = stem(&path);
        if ["main", "lib", "cli"].contains(&name.as_str()) {
            continue;
        }
        let files = if path.is_dir() {
            let mut all = Vec::new();
            let mut stack = vec![path.clone()];
            while let Some(d) = stack.pop() {
                dirs.push(d.clone());
                for e in std::fs::read_dir(&d).unwrap() {
                    let p = e.unwrap().path();
                    if p.is_dir() {
                        stack.push(p);
                    } else if p.extension().is_some_and(|e| e == "rs") {
                        all.push(p);
                    }
                }
            }
            all
        } else {
            vec![path.clone()]
        };
        let uses = top.entry(name.clone()).or_default();
        for f in files {
            uses.extend(refs(&std::fs::read_to_string(&f).unwrap(), "crate::").into_iter().filter(|m| *m != name));
        }
    }
    let known: BTreeSet<String> = top.keys().cloned().collect();
    for uses in top.values_mut() {
        uses.retain(|m| known.contains(m));
    }
    graphs.push(("src/".into(), top));
    for dir in dirs {
        let files: Vec<String> = rs_files(&dir).iter().map(|p| stem(p)).filter(|s| s != "mod").collect();
        let module = stem(&dir);
        let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for f in &files {
            let text = std::fs::read_to_string(dir.join(format!("{f}.rs"))).unwrap();
            let uses: BTreeSet<String> =
                refs(&text, "super::").into_iter().chain(refs(&text, &format!("crate::{module}::"))).filter(|m| m != f && files.contains(m)).collect();
            g.insert(f.clone(), uses);
        }
        graphs.push((format!("src/{module}/"), g));
    }
    for (what, g) in &graphs {
        // A node is on a loop when it reaches itself.
        for start in g.keys() {
            let mut seen = BTreeSet::new();
            let mut stack: Vec<(String, Vec<String>)> = g[start].iter().map(|n| (n.clone(), vec![start.clone(), n.clone()])).collect();
            while let Some((node, path)) = stack.pop() {
                assert!(node != *start, "{what}: modules import each other in a loop: {}", path.join(" -> "));
                if seen.insert(node.clone()) {
                    for next in g.get(&node).into_iter().flatten() {
                        let mut p = path.clone();
                        p.push(next.clone());
                        stack.push((next.clone(), p));
                    }
                }
            }
        }
    }
    assert!(graphs[0].1.len() > 20, "the top-level modules were found: {:?}", graphs[0].1.keys());
}

/// A function of `src/` (tests aside) longer than 100 lines says why it is not split: a
/// `Not split:` line in the comment above it.
#[test]
fn long_functions_say_why_they_are_not_split() {
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut stack = vec![src];
    let mut unexplained = Vec::new();
    let mut seen = 0;
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") || path.file_name().is_some_and(|f| f == "tests.rs") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let lines: Vec<&str> = text.lines().collect();
            let mut i = 0;
            while i < lines.len() {
                let line = lines[i];
                if line.trim_start().starts_with("#[cfg(test)]") {
                    // The tests below a module's code.
                    break;
                }
                let trimmed = line.trim_start();
                let is_fn = ["fn ", "pub fn ", "pub(crate) fn ", "pub(super) fn ", "const fn ", "pub const fn ", "unsafe fn ", "pub unsafe fn "]
                    .iter()
                    .any(|p| trimmed.starts_with(p));
                if !is_fn {
                    i += 1;
                    continue;
                }
                let indent = line.len() - trimmed.len();
                // Its body ends at the closing brace at its own indentation.
                let mut end = i;
                while end < lines.len() && !lines[end].trim_end().ends_with('{') && !lines[end].trim_end().ends_with(';') {
                    end += 1;
                }
                if end >= lines.len() || lines[end].trim_end().ends_with(';') {
                    i += 1;
                    continue;
                }
                let close = (end + 1..lines.len())
                    .find(|&k| lines[k].len() > indent && lines[k].starts_with(&" ".repeat(indent)) && lines[k][indent..].starts_with('}'));
                let Some(close) = close.or_else(|| (end + 1..lines.len()).find(|&k| lines[k] == "}")) else { break };
                seen += 1;
                if close - i + 1 > 100 {
                    let above = lines[i.saturating_sub(12)..i].join("\n");
                    if !above.contains("Not split:") {
                        unexplained.push(format!("{}:{} ({} lines)", path.display(), i + 1, close - i + 1));
                    }
                }
                i = close + 1;
            }
        }
    }
    assert!(seen > 500, "the functions were found: {seen}");
    assert!(unexplained.is_empty(), "functions over 100 lines without a `Not split:` comment:\n{}", unexplained.join("\n"));
}
