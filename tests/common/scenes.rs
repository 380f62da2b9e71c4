//! Small analytic test scenes written to a temporary directory.
#![allow(dead_code)]

use std::fmt::Write as _;
use std::path::PathBuf;

/// A fresh, empty temporary directory for one test.
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vkinverse-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A sphere of `radius` tessellated from an octahedron subdivided `levels` times, as OBJ
/// text without normals (flat shading). `inward`: triangles face the centre.
pub fn sphere_obj(radius: f32, levels: u32, inward: bool) -> String {
    let mut tris: Vec<[[f32; 3]; 3]> = Vec::new();
    let p = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
    for (a, b, c) in [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)] {
        tris.push([p[a], p[b], p[c]]);
    }
    let norm = |v: [f32; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / l, v[1] / l, v[2] / l]
    };
    let mid = |a: [f32; 3], b: [f32; 3]| norm([(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0, (a[2] + b[2]) / 2.0]);
    for _ in 0..levels {
        tris = tris
            .iter()
            .flat_map(|[a, b, c]| {
                let (ab, bc, ca) = (mid(*a, *b), mid(*b, *c), mid(*c, *a));
                [[*a, ab, ca], [ab, *b, bc], [ca, bc, *c], [ab, bc, ca]]
            })
            .collect();
    }
    let mut s = String::new();
    for t in &tris {
        for v in t {
            writeln!(s, "v {} {} {}", v[0] * radius, v[1] * radius, v[2] * radius).unwrap();
        }
    }
    for i in 0..tris.len() {
        let b = 3 * i + 1;
        if inward {
            writeln!(s, "f {} {} {}", b, b + 2, b + 1).unwrap();
        } else {
            writeln!(s, "f {} {} {}", b, b + 1, b + 2).unwrap();
        }
    }
    s
}

/// Writes `scene.toml` and `sphere.obj` into a temp dir and returns the scene path.
pub fn write_scene(name: &str, toml: &str, obj: &str) -> PathBuf {
    let dir = temp_dir(name);
    std::fs::write(dir.join("sphere.obj"), obj).unwrap();
    let path = dir.join("scene.toml");
    std::fs::write(&path, toml).unwrap();
    path
}
