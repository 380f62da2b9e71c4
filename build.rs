//! Compiles every `glsl/*.comp` kernel to SPIR-V with shaderc (glslang) and generates
//! `$OUT_DIR/shaders.rs`, a table of the embedded SPIR-V by kernel name.
//!
//! A kernel may declare structural variants in its header comment (the comment lines
//! before and after `#version`):
//! `// variant: NAME DEFINE[=VALUE] [DEFINE...]` compiles the file once more as kernel
//! `NAME` with those macros defined (e.g. the adjoint pass from the primal source).
//! Every file reached through `#include` is tracked with `rerun-if-changed`, and a
//! compile error fails the build with the compiler's `file:line` message.
//!
//! The constants shared with the host are defined once, in `src/constants.rs`; this script
//! writes them as `$OUT_DIR/vkinverse_constants.glsl`, which kernels `#include`.

use std::cell::RefCell;
use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::rc::Rc;

fn main() {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap()).join("glsl");
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    println!("cargo:rerun-if-changed=build.rs");
    // A new kernel file (not yet included anywhere) must also trigger a rebuild.
    println!("cargo:rerun-if-changed={}", root.display());

    let mut kernels: Vec<PathBuf> = std::fs::read_dir(&root)
        .expect("glsl/ directory")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "comp"))
        .collect();
    kernels.sort();

    let constants = Path::new(&std::env::var("CARGO_MANIFEST_DIR").unwrap()).join("src/constants.rs");
    println!("cargo:rerun-if-changed={}", constants.display());
    // Rewritten only when it changes, so that its time stamp moves with its content.
    let generated = out.join("vkinverse_constants.glsl");
    let text = glsl_constants(&constants);
    if std::fs::read_to_string(&generated).ok().as_deref() != Some(text.as_str()) {
        std::fs::write(&generated, text).unwrap();
    }

    let compiler = shaderc::Compiler::new().expect("shaderc compiler");
    let included: Rc<RefCell<BTreeSet<PathBuf>>> = Rc::default();
    let mut table = String::from("/// Embedded SPIR-V of every kernel, by name.\npub static KERNELS: &[(&str, &[u8])] = &[\n");
    let mut failures = Vec::new();

    for path in &kernels {
        let source = std::fs::read_to_string(path).unwrap();
        println!("cargo:rerun-if-changed={}", path.display());
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
        for (name, defines) in variants {
            let mut options = shaderc::CompileOptions::new().unwrap();
            options.set_target_env(shaderc::TargetEnv::Vulkan, shaderc::EnvVersion::Vulkan1_3 as u32);
            options.set_target_spirv(shaderc::SpirvVersion::V1_6);
            options.set_optimization_level(shaderc::OptimizationLevel::Performance);
            options.set_generate_debug_info();
            for (k, v) in &defines {
                options.add_macro_definition(k, v.as_deref());
            }
            let root_for_cb = root.clone();
            let out_for_cb = out.clone();
            let included_cb = included.clone();
            options.set_include_callback(move |requested, _ty, requester, _depth| {
                let base = Path::new(requester).parent().unwrap_or(Path::new(""));
                let candidates = [base.join(requested), root_for_cb.join(requested), out_for_cb.join(requested)];
                let found = candidates.iter().find(|p| p.is_file()).ok_or_else(|| {
                    format!("{requester}: cannot find included file \"{requested}\"")
                })?;
                let content = std::fs::read_to_string(found).map_err(|e| e.to_string())?;
                included_cb.borrow_mut().insert(found.clone());
                Ok(shaderc::ResolvedInclude {
                    resolved_name: found.display().to_string(),
                    content,
                })
            });
            match compiler.compile_into_spirv(
                &source,
                shaderc::ShaderKind::Compute,
                &path.display().to_string(),
                "main",
                Some(&options),
            ) {
                Ok(artifact) => {
                    let spv = out.join(format!("{name}.spv"));
                    std::fs::write(&spv, artifact.as_binary_u8()).unwrap();
                    writeln!(table, "    ({name:?}, include_bytes!({:?})),", spv.display().to_string()).unwrap();
                }
                Err(e) => failures.push(format!("{name}: {e}")),
            }
        }
    }
    // Not the files this script writes into OUT_DIR (the constants header): their source is
    // tracked above, and cargo counts a tracked file written during the run as changed
    // after it, which would rerun the script, and every kernel's compilation, on every build.
    for file in included.borrow().iter().filter(|f| !f.starts_with(&out)) {
        println!("cargo:rerun-if-changed={}", file.display());
    }
    if !failures.is_empty() {
        // The build must fail with the compiler's own file:line messages.
        eprintln!("{}", failures.join("\n"));
        panic!("GLSL compilation failed:\n{}", failures.join("\n"));
    }
    table.push_str("];\n");
    std::fs::write(out.join("shaders.rs"), table).unwrap();
}

/// The GLSL header of the `pub const NAME: u32 = VALUE;` lines of `path` (doc comments
/// are carried over as comments); any other item fails the build.
fn glsl_constants(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    let mut glsl = String::from("// Generated by build.rs from src/constants.rs: edit that file.\n#ifndef VKINVERSE_CONSTANTS_GLSL\n#define VKINVERSE_CONSTANTS_GLSL\n");
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
