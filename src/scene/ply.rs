//! PLY (Stanford polygon file, ASCII or binary) meshes through `ply-rs-bw`: vertex
//! positions `x y z`, optional normals `nx ny nz` and texture coordinates (`u v`, `s t` or
//! `texture_u texture_v`), and faces as index lists (`vertex_indices` or `vertex_index`),
//! polygons split into triangle fans.

use std::path::Path;

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

use super::obj::ObjData;
use super::SceneError;

/// Triangles of one PLY file (as an OBJ's: `normals` and `uvs` empty or one per
/// position), `uvs` as stored: v pointing down the image, Mitsuba's convention for PLY.
pub fn load(path: &Path, bytes: &[u8]) -> Result<ObjData, SceneError> {
    let err = |message: String| SceneError::Obj { path: path.to_path_buf(), line: 0, message };
    let ply = Parser::<DefaultElement>::new().read_ply(&mut std::io::Cursor::new(bytes)).map_err(|e| err(format!("malformed PLY: {e}")))?;
    let vertices = ply.payload.get("vertex").ok_or_else(|| err("no `vertex` element".into()))?;
    let faces = ply.payload.get("face").ok_or_else(|| err("no `face` element".into()))?;
    let scalar = |e: &DefaultElement, names: &[&str]| -> Option<f32> { names.iter().find_map(|n| e.get(*n)).and_then(Property::to_f32_lossy) };
    let mut out = ObjData::default();
    let has = |names: &[&str]| vertices.first().is_some_and(|v| names.iter().any(|n| v.get(*n).is_some()));
    let with_normals = has(&["nx"]);
    let uv_names: [(&[&str], &[&str]); 1] = [(&["u", "s", "texture_u", "texture_s"], &["v", "t", "texture_v", "texture_t"])];
    let with_uvs = has(uv_names[0].0);
    for (i, v) in vertices.iter().enumerate() {
        let get = |names: &[&str]| scalar(v, names).ok_or_else(|| err(format!("vertex {i} lacks {}", names[0])));
        out.positions.push([get(&["x"])?, get(&["y"])?, get(&["z"])?]);
        if with_normals {
            out.normals.push([get(&["nx"])?, get(&["ny"])?, get(&["nz"])?]);
        }
        if with_uvs {
            out.uvs.push([get(uv_names[0].0)?, get(uv_names[0].1)?]);
        }
    }
    let n = out.positions.len() as u64;
    for (i, f) in faces.iter().enumerate() {
        let list: Vec<i64> = match f.get("vertex_indices").or_else(|| f.get("vertex_index")) {
            Some(Property::ListChar(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListUChar(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListShort(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListUShort(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListInt(v)) => v.iter().map(|&x| x as i64).collect(),
            Some(Property::ListUInt(v)) => v.iter().map(|&x| x as i64).collect(),
            _ => return Err(err(format!("face {i} has no integer `vertex_indices` list"))),
        };
        if list.len() < 3 {
            return Err(err(format!("face {i} has {} vertices (at least 3 needed)", list.len())));
        }
        if let Some(bad) = list.iter().find(|&&x| x < 0 || x as u64 >= n) {
            return Err(err(format!("face {i}: vertex index {bad} out of bounds ({n} vertices)")));
        }
        for k in 1..list.len() - 1 {
            out.indices.push([list[0] as u32, list[k] as u32, list[k + 1] as u32]);
        }
    }
    if out.indices.is_empty() {
        return Err(err("no faces".into()));
    }
    Ok(out)
}
