//! Wavefront OBJ loading: a line-by-line check that reports the offending line (tobj's
//! errors name none, and it can overflow on absurd relative indices), then tobj with
//! triangulation and one index buffer shared by positions, normals and UVs.

use std::path::Path;

use super::SceneError;

/// Triangles of one OBJ file, all objects and groups merged. `normals` and `uvs` are either
/// empty or one per position; every index is below `positions.len()`.
#[derive(Debug, Default)]
pub struct ObjData {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<[u32; 3]>,
}

pub fn load(path: &Path, bytes: &[u8]) -> Result<ObjData, SceneError> {
    let err = |line, message: String| SceneError::Obj { path: path.to_path_buf(), line, message };
    let text = std::str::from_utf8(bytes).map_err(|e| err(0, format!("not UTF-8 text: {e}")))?;
    check_lines(text).map_err(|(line, message)| err(line, message))?;
    // tobj reads a comment after a vertex's numbers as more numbers: without them.
    let text: String = text.lines().map(|l| l.split('#').next().unwrap_or("")).collect::<Vec<_>>().join("\n");

    // The update covers fields that exist only with tobj's optional features.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions { single_index: true, triangulate: true, ignore_points: true, ignore_lines: true, ..Default::default() };
    // Materials come from the scene file, so `mtllib` lines are not followed.
    let (models, _) = tobj::load_obj_buf(&mut text.as_bytes(), &options, |_| Ok(Default::default()))
        .map_err(|source| SceneError::ObjParse { path: path.to_path_buf(), source })?;

    let mut out = ObjData::default();
    for mesh in models.iter().map(|m| &m.mesh) {
        let base = out.positions.len() as u32;
        out.positions.extend(mesh.positions.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
        out.normals.extend(mesh.normals.chunks_exact(3).map(|n| [n[0], n[1], n[2]]));
        out.uvs.extend(mesh.texcoords.chunks_exact(2).map(|t| [t[0], t[1]]));
        out.indices.extend(mesh.indices.chunks_exact(3).map(|t| [base + t[0], base + t[1], base + t[2]]));
    }
    let n = out.positions.len();
    // With a single index buffer a vertex without a normal gets none, so a file that gives
    // normals (or UVs) to some faces only leaves the arrays shorter than the positions.
    if !out.normals.is_empty() && out.normals.len() != n {
        return Err(err(0, "normals are given for some faces but not all".into()));
    }
    if !out.uvs.is_empty() && out.uvs.len() != n {
        return Err(err(0, "texture coordinates are given for some faces but not all".into()));
    }
    if out.indices.is_empty() {
        return Err(err(0, "no triangles".into()));
    }
    if out.indices.iter().flatten().any(|&i| i as usize >= n) {
        return Err(err(0, "face index out of bounds".into()));
    }
    Ok(out)
}

/// Checks vertex values and face indices line by line; `Err((line, message))`.
fn check_lines(text: &str) -> Result<(), (usize, String)> {
    let (mut positions, mut uvs, mut normals, mut faces) = (0usize, 0usize, 0usize, 0usize);
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("");
        let mut words = content.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let (count, min_values) = match keyword {
            "v" => (&mut positions, 3),
            "vt" => (&mut uvs, 2),
            "vn" => (&mut normals, 3),
            "f" => {
                let corners: Vec<&str> = words.collect();
                if corners.len() < 3 {
                    return Err((line, format!("face with {} vertices (at least 3 needed)", corners.len())));
                }
                for corner in corners {
                    check_corner(corner, [positions, uvs, normals]).map_err(|m| (line, m))?;
                }
                faces += 1;
                continue;
            }
            _ => continue,
        };
        let mut values = 0;
        for word in words {
            match word.parse::<f32>() {
                Ok(v) if v.is_finite() => values += 1,
                Ok(_) => return Err((line, format!("non-finite value `{word}`"))),
                Err(_) => return Err((line, format!("`{word}` is not a number"))),
            }
        }
        if values < min_values {
            return Err((line, format!("`{keyword}` needs {min_values} numbers, got {values}")));
        }
        *count += 1;
    }
    if faces == 0 {
        return Err((0, "no faces".into()));
    }
    Ok(())
}

/// One `v`, `v/vt`, `v//vn` or `v/vt/vn` corner against the counts defined so far.
fn check_corner(corner: &str, counts: [usize; 3]) -> Result<(), String> {
    const KINDS: [&str; 3] = ["vertex", "texture coordinate", "normal"];
    let parts: Vec<&str> = corner.split('/').collect();
    if parts.len() > 3 || parts[0].is_empty() {
        return Err(format!("malformed face corner `{corner}`"));
    }
    for ((part, count), kind) in parts.iter().zip(counts).zip(KINDS) {
        if part.is_empty() {
            continue;
        }
        let index: i64 = part.parse().map_err(|_| format!("malformed face corner `{corner}`"))?;
        // OBJ indices are 1-based; negative ones count back from the latest definition.
        if index == 0 || index.unsigned_abs() > count as u64 {
            return Err(format!("{kind} index {index} out of bounds ({count} defined so far)"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn load_str(text: &str) -> Result<ObjData, SceneError> {
        load(Path::new("t.obj"), text.as_bytes())
    }

    fn err_line(text: &str) -> usize {
        match load_str(text) {
            Err(SceneError::Obj { line, .. }) => line,
            other => panic!("expected an OBJ error, got {other:?}"),
        }
    }

    #[test]
    fn quads_are_triangulated_and_objects_merged() {
        let text = "o a\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf -3 -2 -1\n";
        let obj = load_str(text).unwrap();
        assert_eq!(obj.positions.len(), 7);
        assert_eq!(obj.indices.len(), 3);
        assert_eq!(obj.indices[2].map(|i| obj.positions[i as usize]), [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]);
        assert!(obj.normals.is_empty() && obj.uvs.is_empty());
    }

    #[test]
    fn normals_and_uvs_share_the_position_index() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvn 0 0 1\nf 1/1/1 2/2/1 3/1/1\n";
        let obj = load_str(text).unwrap();
        assert_eq!(obj.positions.len(), obj.normals.len());
        assert_eq!(obj.positions.len(), obj.uvs.len());
        let [a, b, _] = obj.indices[0];
        assert_eq!((obj.uvs[a as usize], obj.uvs[b as usize]), ([0.0, 0.0], [1.0, 0.0]));
    }

    #[test]
    fn bad_lines_are_reported_with_their_number() {
        assert_eq!(err_line("v 0 0 0\nv 1 0 0\nv 0 1 0\n# c\nf 1 2 4\n"), 5);
        assert_eq!(err_line("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"), 4);
        assert_eq!(err_line("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 1 2\n"), 4);
        assert_eq!(err_line("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/2 2/2 3/2\n"), 4);
        assert_eq!(err_line("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n"), 4);
        assert_eq!(err_line("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n"), 4);
        assert_eq!(err_line("v 0 0 0\nv 1e40 0 0\n"), 2);
        assert_eq!(err_line("v 0 NaN 0\n"), 1);
        assert_eq!(err_line("v 0 x 0\n"), 1);
        assert_eq!(err_line("v 0 0 0\nv 1 0 0\nv 0 1 0\n"), 0);
    }

    #[test]
    fn partial_normals_are_rejected() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 2 4 3\n";
        assert!(matches!(load_str(text), Err(SceneError::Obj { .. })));
    }
}
