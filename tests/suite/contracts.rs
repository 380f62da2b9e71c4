//! Host/GPU contracts that need no device: every kernel's push block against its Rust
//! mirror, by reflection of the embedded SPIR-V; the constants header generated from
//! src/constants.rs.

use vkinverse::gpu::reflect::Reflection;
use vkinverse::gpu::shaders::KERNELS;

/// Every kernel with a push block has a mirror (`vkinverse::kernels::mirror`) whose members
/// (names and byte offsets, in order) and size are the reflected ones; a kernel without one
/// has the empty mirror.
#[test]
fn every_push_block_matches_its_mirror() {
    assert!(KERNELS.len() > 20, "{} kernels", KERNELS.len());
    for (kernel, spirv) in KERNELS {
        let r = Reflection::new(kernel, spirv).unwrap();
        let (members, size) = vkinverse::kernels::mirror(kernel).unwrap_or_else(|| panic!("{kernel}: no Rust mirror of its push block"));
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
