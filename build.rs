//! Compiles every `glsl/*.comp` kernel to SPIR-V with shaderc (glslang) and generates
//! `$OUT_DIR/shaders.rs`, a table of the embedded SPIR-V by kernel name.
//!
//! A kernel may declare structural variants in its header comment (the comment lines
//! before and after `#version`):
//! `// variant: NAME DEFINE[=VALUE] [DEFINE...]` compiles the file once more as kernel
//! `NAME` with those macros defined (e.g. the adjoint pass from the primal source).
//! A compile error fails the build with the compiler's `file:line` message.
//!
//! The constants shared with the host are defined once, in `src/constants.rs`; this script
//! writes them as `$OUT_DIR/vkinverse_constants.glsl`, which kernels `#include`.
//!
//! The SPIR-V is not optimised unless `VKINVERSE_SPIRV_OPT=1` is set at build time
//! ([`spirv_opt`]). Compiling is done once per source, not once per profile: the kernels
//! compile in parallel, and each one's SPIR-V is kept in
//! `target/spirv-cache/`, named by a hash of everything its compilation reads (its own
//! file, every file under `glsl/` that is not a kernel, the constants, its macros and the
//! compiler's options). A release build after a test build, or clippy after either, finds
//! every kernel there; a change to one kernel recompiles that kernel only. Entries that no
//! kernel of the current sources names are removed.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// Part of every cache key: changing how kernels are compiled (the options below, the
/// include rules) must change this.
const COMPILE_SETTINGS: &str = "vulkan1.3 spirv1.6 debug-info include:requester,glsl,out_dir v2";

/// One SPIR-V module to build: a kernel file, or one of its variants.
struct Job {
    name: String,
    path: PathBuf,
    source: String,
    defines: Vec<(String, Option<String>)>,
}

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let root = manifest.join("glsl");
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    println!("cargo:rerun-if-changed=build.rs");

    // Every file and folder under glsl/ is tracked (a folder, so that a new file counts).
    let mut files = Vec::new();
    list_files(&root, &mut files);
    files.sort();

    let constants = manifest.join("src/constants.rs");
    println!("cargo:rerun-if-changed={}", constants.display());
    // Rewritten only when it changes: a tracked file written by the script itself would
    // look changed to cargo on every build (it is not tracked; its source is).
    let generated = out.join("vkinverse_constants.glsl");
    let constants_glsl = glsl_constants(&constants);
    if std::fs::read_to_string(&generated).ok().as_deref() != Some(constants_glsl.as_str()) {
        std::fs::write(&generated, &constants_glsl).unwrap();
    }

    // What every kernel may include: the library files and the constants.
    let mut shared = xxhash_rust::xxh3::Xxh3::new();
    shared.update(COMPILE_SETTINGS.as_bytes());
    println!("cargo:rerun-if-env-changed=VKINVERSE_SPIRV_OPT");
    shared.update(if spirv_opt() { b"spirv-opt performance" } else { b"unoptimised" });
    shared.update(constants_glsl.as_bytes());
    for file in files.iter().filter(|f| !is_kernel(f)) {
        shared.update(file.strip_prefix(&root).unwrap().display().to_string().as_bytes());
        shared.update(&[0]);
        shared.update(&std::fs::read(file).unwrap());
        shared.update(&[0]);
    }

    let jobs: Vec<Job> = files.iter().filter(|f| is_kernel(f)).flat_map(|path| kernel_jobs(path)).collect();
    let cache = cache_dir(&out);
    let keys: Vec<String> = jobs
        .iter()
        .map(|job| {
            let mut h = shared.clone();
            h.update(job.path.file_name().unwrap().to_string_lossy().as_bytes());
            h.update(&[0]);
            h.update(job.source.as_bytes());
            for (k, v) in &job.defines {
                h.update(format!("\0-D{k}={}", v.as_deref().unwrap_or("")).as_bytes());
            }
            format!("{}-{:032x}.spv", job.name, h.digest128())
        })
        .collect();

    // The kernels not in the cache, compiled by one worker per core.
    let missing: Vec<usize> = (0..jobs.len()).filter(|&i| cache.as_ref().is_none_or(|c| !c.join(&keys[i]).is_file())).collect();
    let results: Mutex<Vec<Option<Result<Vec<u8>, String>>>> = Mutex::new((0..jobs.len()).map(|_| None).collect());
    let next = AtomicUsize::new(0);
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get()).min(missing.len().max(1));
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| {
                let compiler = shaderc::Compiler::new().expect("shaderc compiler");
                while let Some(&i) = missing.get(next.fetch_add(1, Ordering::Relaxed)) {
                    let result = compile(&compiler, &jobs[i], &root, &out);
                    results.lock().unwrap()[i] = Some(result);
                }
            });
        }
    });

    let mut table = String::from("/// Embedded SPIR-V of every kernel, by name.\npub static KERNELS: &[(&str, &[u8])] = &[\n");
    let mut failures = Vec::new();
    for (i, result) in results.into_inner().unwrap().into_iter().enumerate() {
        let job = &jobs[i];
        let cached = result.is_none();
        // Found in the cache; compiled here after all if another build (of other sources)
        // pruned it since.
        let result = result.unwrap_or_else(|| {
            std::fs::read(cache.as_ref().unwrap().join(&keys[i])).or_else(|_| compile(&shaderc::Compiler::new().expect("shaderc compiler"), job, &root, &out))
        });
        let spirv = match result {
            Ok(spirv) => spirv,
            Err(e) => {
                failures.push(format!("{}: {e}", job.name));
                continue;
            }
        };
        if let (Some(cache), false) = (&cache, cached) {
            // Written whole under another name first: a build running beside this one never
            // reads half a module.
            let tmp = cache.join(format!("{}.{}.tmp", keys[i], std::process::id()));
            if std::fs::write(&tmp, &spirv).is_ok() {
                let _ = std::fs::rename(&tmp, cache.join(&keys[i]));
            }
        }
        let spv = out.join(format!("{}.spv", job.name));
        if std::fs::read(&spv).ok().as_deref() != Some(spirv.as_slice()) {
            std::fs::write(&spv, &spirv).unwrap();
        }
        writeln!(table, "    ({:?}, include_bytes!({:?})),", job.name, spv.display().to_string()).unwrap();
    }
    if !failures.is_empty() {
        // The build must fail with the compiler's own file:line messages.
        eprintln!("{}", failures.join("\n"));
        panic!("GLSL compilation failed:\n{}", failures.join("\n"));
    }
    if let Some(cache) = &cache {
        prune(cache, &keys);
    }
    table.push_str("];\n");
    let shaders = out.join("shaders.rs");
    if std::fs::read_to_string(&shaders).ok().as_deref() != Some(table.as_str()) {
        std::fs::write(&shaders, table).unwrap();
    }
}

/// Whether the kernels go through spirv-opt's performance passes (`VKINVERSE_SPIRV_OPT=1`).
/// They do not by default: the drivers optimise the SPIR-V they are given, and on lavapipe
/// the unoptimised kernels run as fast (docs/performance.md) while a clean build compiles
/// them in seconds instead of many minutes.
fn spirv_opt() -> bool {
    std::env::var("VKINVERSE_SPIRV_OPT").is_ok_and(|v| v == "1")
}

fn is_kernel(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "comp")
}

/// Every file under `dir`, each tracked with `rerun-if-changed`, as is every folder.
fn list_files(dir: &Path, files: &mut Vec<PathBuf>) {
    println!("cargo:rerun-if-changed={}", dir.display());
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.unwrap().path();
        if path.is_dir() {
            list_files(&path, files);
        } else {
            println!("cargo:rerun-if-changed={}", path.display());
            files.push(path);
        }
    }
}

/// The kernel itself and the variants its header declares.
fn kernel_jobs(path: &Path) -> Vec<Job> {
    let source = std::fs::read_to_string(path).unwrap();
    let stem = path.file_stem().unwrap().to_str().unwrap().to_string();
    let mut variants = vec![(stem, Vec::<(String, Option<String>)>::new())];
    // The header: `#version` and the comment lines around it, up to the first other line.
    let header = source.lines().take_while(|l| l.starts_with("//") || l.starts_with("#version") || l.trim().is_empty());
    for line in header {
        if let Some(rest) = line.strip_prefix("// variant:") {
            let mut words = rest.split_whitespace();
            let name = words.next().expect("variant needs a name").to_string();
            let defines = words
                .map(|d| match d.split_once('=') {
                    Some((k, v)) => (k.to_string(), Some(v.to_string())),
                    None => (d.to_string(), None),
                })
                .collect();
            variants.push((name, defines));
        }
    }
    variants.into_iter().map(|(name, defines)| Job { name, path: path.to_path_buf(), source: source.clone(), defines }).collect()
}

/// `target/spirv-cache`, beside the profiles' folders (`OUT_DIR` is
/// `target/<profile>/build/<package>-<hash>/out`); none where `OUT_DIR` is laid out
/// otherwise or the folder cannot be made.
fn cache_dir(out: &Path) -> Option<PathBuf> {
    let build = out.ancestors().nth(2)?;
    if build.file_name()? != "build" {
        return None;
    }
    let dir = build.parent()?.parent()?.join("spirv-cache");
    std::fs::create_dir_all(&dir).ok()?;
    Some(dir)
}

/// Removes the cache's modules that no kernel of the current sources names (and stale
/// temporary files).
fn prune(cache: &Path, keys: &[String]) {
    let Ok(entries) = std::fs::read_dir(cache) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let stale_tmp = name.ends_with(".tmp") && entry.metadata().and_then(|m| m.modified()).is_ok_and(|t| t.elapsed().is_ok_and(|age| age.as_secs() > 3600));
        if stale_tmp || (name.ends_with(".spv") && !keys.contains(&name)) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

fn compile(compiler: &shaderc::Compiler, job: &Job, root: &Path, out: &Path) -> Result<Vec<u8>, String> {
    let mut options = shaderc::CompileOptions::new().unwrap();
    options.set_target_env(shaderc::TargetEnv::Vulkan, shaderc::EnvVersion::Vulkan1_3 as u32);
    options.set_target_spirv(shaderc::SpirvVersion::V1_6);
    if spirv_opt() {
        options.set_optimization_level(shaderc::OptimizationLevel::Performance);
    } else {
        options.set_optimization_level(shaderc::OptimizationLevel::Zero);
    }
    options.set_generate_debug_info();
    for (k, v) in &job.defines {
        options.add_macro_definition(k, v.as_deref());
    }
    options.set_include_callback(|requested, _ty, requester, _depth| {
        let base = Path::new(requester).parent().unwrap_or(Path::new(""));
        let candidates = [base.join(requested), root.join(requested), out.join(requested)];
        let found = candidates.iter().find(|p| p.is_file()).ok_or_else(|| format!("{requester}: cannot find included file \"{requested}\""))?;
        let content = std::fs::read_to_string(found).map_err(|e| e.to_string())?;
        Ok(shaderc::ResolvedInclude { resolved_name: found.display().to_string(), content })
    });
    compiler
        .compile_into_spirv(&job.source, shaderc::ShaderKind::Compute, &job.path.display().to_string(), "main", Some(&options))
        .map(|artifact| artifact.as_binary_u8().to_vec())
        .map_err(|e| e.to_string())
}

/// The GLSL header of the `pub const NAME: u32 = VALUE;` lines of `path` (doc comments
/// are carried over as comments); any other item fails the build.
fn glsl_constants(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    let mut glsl =
        String::from("// Generated by build.rs from src/constants.rs: edit that file.\n#ifndef VKINVERSE_CONSTANTS_GLSL\n#define VKINVERSE_CONSTANTS_GLSL\n");
    for line in text.lines().map(str::trim) {
        if let Some(doc) = line.strip_prefix("///") {
            writeln!(glsl, "//{doc}").unwrap();
        } else if let Some(item) = line.strip_prefix("pub const ") {
            let (name, rest) = item.split_once(": u32 = ").unwrap_or_else(|| panic!("src/constants.rs: `{line}` is not `pub const NAME: u32 = VALUE;`"));
            let value: u32 = rest.trim_end_matches(';').parse().unwrap_or_else(|_| panic!("src/constants.rs: `{line}`: value is not a u32 literal"));
            writeln!(glsl, "const uint {name} = {value}u;").unwrap();
        } else if !(line.is_empty() || line.starts_with("//!")) {
            panic!("src/constants.rs: unexpected line `{line}`");
        }
    }
    glsl.push_str("#endif\n");
    glsl
}
