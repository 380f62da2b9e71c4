//! A glTF document checked before the `gltf` crate reads it: every index in range, every
//! buffer view inside its buffer, every accessor inside its view with a component type its
//! use allows, images with a source, and nodes that form trees no deeper than
//! [`MAX_NODE_DEPTH`]. The crate trusts what it reads (a short stride or float indices
//! panic inside it, an accessor past its view reads short without a word, a node cycle
//! recurses without end); a document that passes here reads as it says.

use serde_json::Value;

/// Deepest node hierarchy accepted (a chain of nodes each the only child of the previous):
/// far beyond any real model's, and shallow enough to walk by recursion.
pub const MAX_NODE_DEPTH: usize = 256;

/// What is wrong and where (a JSON path such as `accessors[3].count`).
pub type Problem = (String, String);

fn array<'a>(root: &'a Value, key: &str) -> &'a [Value] {
    root.get(key).and_then(Value::as_array).map(Vec::as_slice).unwrap_or(&[])
}

/// A non-negative integer property, if present.
fn uint(v: &Value, key: &str) -> Option<u64> {
    v.get(key).and_then(Value::as_u64)
}

/// Bytes of one component of glTF component type `t`.
fn component_bytes(t: u64) -> Option<u64> {
    match t {
        5120 | 5121 => Some(1),
        5122 | 5123 => Some(2),
        5125 | 5126 => Some(4),
        _ => None,
    }
}

/// Components of accessor type `t`.
fn components(t: &str) -> Option<u64> {
    match t {
        "SCALAR" => Some(1),
        "VEC2" => Some(2),
        "VEC3" => Some(3),
        "VEC4" | "MAT2" => Some(4),
        "MAT3" => Some(9),
        "MAT4" => Some(16),
        _ => None,
    }
}

/// Checks the document `root` whose buffers hold `buffer_lengths` bytes each (what was
/// loaded: a GLB's binary chunk, a data URI's, a file's first `byteLength`).
pub fn check(root: &Value, buffer_lengths: &[u64]) -> Result<(), Problem> {
    let bad = |at: String, what: String| Err((at, what));
    let views = array(root, "bufferViews");
    for (i, v) in views.iter().enumerate() {
        let at = format!("bufferViews[{i}]");
        let buffer = uint(v, "buffer").unwrap_or(u64::MAX);
        let Some(&len) = buffer_lengths.get(buffer as usize) else { return bad(format!("{at}.buffer"), format!("buffer {buffer} does not exist")) };
        let (offset, length) = (uint(v, "byteOffset").unwrap_or(0), uint(v, "byteLength").unwrap_or(0));
        if offset.checked_add(length).is_none_or(|end| end > len) {
            return bad(at, format!("bytes {offset}..{} run past buffer {buffer}'s {len}", offset.saturating_add(length)));
        }
        if let Some(stride) = uint(v, "byteStride") {
            if !(4..=252).contains(&stride) || stride % 4 != 0 {
                return bad(format!("{at}.byteStride"), format!("{stride} is not a multiple of 4 in 4..=252"));
            }
        }
    }
    let accessors = array(root, "accessors");
    for (i, a) in accessors.iter().enumerate() {
        check_accessor(a, &format!("accessors[{i}]"), views)?;
    }
    for (m, mesh) in array(root, "meshes").iter().enumerate() {
        for (p, prim) in array(mesh, "primitives").iter().enumerate() {
            check_primitive(prim, &format!("meshes[{m}].primitives[{p}]"), accessors)?;
        }
    }
    for (i, image) in array(root, "images").iter().enumerate() {
        let at = format!("images[{i}]");
        match (image.get("uri").and_then(Value::as_str), uint(image, "bufferView")) {
            (None, None) => return bad(at, "has neither a uri nor a bufferView".into()),
            (_, Some(v)) if v as usize >= views.len() => return bad(format!("{at}.bufferView"), format!("buffer view {v} does not exist")),
            (_, Some(_)) if image.get("mimeType").and_then(Value::as_str).is_none() => {
                return bad(at, "has a bufferView but no mimeType (the glTF specification requires one)".into())
            }
            _ => {}
        }
    }
    let images = array(root, "images").len();
    for (i, t) in array(root, "textures").iter().enumerate() {
        if let Some(s) = uint(t, "source").filter(|s| *s as usize >= images) {
            return bad(format!("textures[{i}].source"), format!("image {s} does not exist"));
        }
    }
    check_nodes(root)
}

fn check_accessor(a: &Value, at: &str, views: &[Value]) -> Result<(), Problem> {
    let bad = |field: &str, what: String| Err((format!("{at}{field}"), what));
    let ty = a.get("type").and_then(Value::as_str).unwrap_or("");
    let Some(comps) = components(ty) else { return bad(".type", format!("\"{ty}\" is not an accessor type")) };
    let ctype = uint(a, "componentType").unwrap_or(0);
    let Some(size) = component_bytes(ctype) else { return bad(".componentType", format!("{ctype} is not a component type")) };
    let count = uint(a, "count").unwrap_or(0);
    if count == 0 {
        return bad(".count", "is 0".into());
    }
    if let Some(sparse) = a.get("sparse") {
        check_sparse(sparse, &format!("{at}.sparse"), count, comps * size, views)?;
    }
    let Some(view) = uint(a, "bufferView") else { return Ok(()) };
    let Some(v) = views.get(view as usize) else { return bad(".bufferView", format!("buffer view {view} does not exist")) };
    let element = comps * size;
    let stride = uint(v, "byteStride").unwrap_or(element);
    if stride < element {
        return bad("", format!("elements of {element} bytes do not fit buffer view {view}'s stride of {stride}"));
    }
    let offset = uint(a, "byteOffset").unwrap_or(0);
    let end = (count - 1).checked_mul(stride).and_then(|x| x.checked_add(offset)).and_then(|x| x.checked_add(element));
    let length = uint(v, "byteLength").unwrap_or(0);
    if end.is_none_or(|end| end > length) {
        return bad("", format!("{count} elements of {element} bytes from byte {offset} run past buffer view {view}'s {length} bytes"));
    }
    Ok(())
}

/// A sparse accessor's substitutions (of an accessor of `count` elements of `element`
/// bytes): between 1 and `count` of them; their indices unsigned integers and their values
/// elements, each in a buffer view without a stride that holds all of them.
fn check_sparse(sparse: &Value, at: &str, count: u64, element: u64, views: &[Value]) -> Result<(), Problem> {
    let bad = |field: &str, what: String| Err((format!("{at}{field}"), what));
    let n = uint(sparse, "count").unwrap_or(0);
    if n == 0 || n > count {
        return bad(".count", format!("{n} is not between 1 and the accessor's {count} elements"));
    }
    for part in ["indices", "values"] {
        let Some(p) = sparse.get(part) else { return bad(&format!(".{part}"), "is missing".into()) };
        let bytes = if part == "indices" {
            match uint(p, "componentType") {
                Some(t @ (5121 | 5123 | 5125)) => component_bytes(t).unwrap_or(4),
                t => return bad(&format!(".{part}.componentType"), format!("{} is not an unsigned integer type", t.unwrap_or(0))),
            }
        } else {
            element
        };
        let view = uint(p, "bufferView").unwrap_or(u64::MAX);
        let Some(v) = views.get(view as usize) else { return bad(&format!(".{part}.bufferView"), format!("buffer view {view} does not exist")) };
        if v.get("byteStride").is_some() {
            return bad(&format!(".{part}.bufferView"), format!("buffer view {view} has a byteStride (a sparse accessor's views have none)"));
        }
        let offset = uint(p, "byteOffset").unwrap_or(0);
        let length = uint(v, "byteLength").unwrap_or(0);
        if n.checked_mul(bytes).and_then(|x| x.checked_add(offset)).is_none_or(|end| end > length) {
            return bad(&format!(".{part}"), format!("{n} elements of {bytes} bytes from byte {offset} run past buffer view {view}'s {length} bytes"));
        }
    }
    Ok(())
}

/// The attributes the importer reads take these component types: indices unsigned
/// integers, positions and normals floats, texture coordinates floats or normalised
/// unsigned integers.
fn check_primitive(prim: &Value, at: &str, accessors: &[Value]) -> Result<(), Problem> {
    let accessor = |field: String, index: Option<u64>| -> Result<Option<(&Value, String)>, Problem> {
        match index {
            None => Ok(None),
            Some(i) => accessors.get(i as usize).map(|a| Some((a, field.clone()))).ok_or((field, format!("accessor {i} does not exist"))),
        }
    };
    let kind = |a: &Value| (a.get("type").and_then(Value::as_str).unwrap_or("").to_string(), uint(a, "componentType").unwrap_or(0));
    if let Some((a, field)) = accessor(format!("{at}.indices"), uint(prim, "indices"))? {
        let (ty, ct) = kind(a);
        if ty != "SCALAR" || !matches!(ct, 5121 | 5123 | 5125) {
            return Err((field, format!("indices must be unsigned integer scalars, not {ty} of component type {ct}")));
        }
    }
    let attributes = prim.get("attributes").and_then(Value::as_object);
    for (name, index) in attributes.into_iter().flatten() {
        let Some((a, field)) = accessor(format!("{at}.attributes.{name}"), index.as_u64())? else { continue };
        let (ty, ct) = kind(a);
        let fits = match name.as_str() {
            "POSITION" | "NORMAL" => ty == "VEC3" && ct == 5126,
            n if n.starts_with("TEXCOORD_") => ty == "VEC2" && matches!(ct, 5126 | 5121 | 5123),
            _ => true,
        };
        if !fits {
            return Err((field, format!("{ty} of component type {ct} is not what glTF allows for {name}")));
        }
    }
    Ok(())
}

/// Nodes form trees: every child index exists, no node has two parents (or is its own
/// ancestor), and no tree is deeper than [`MAX_NODE_DEPTH`].
fn check_nodes(root: &Value) -> Result<(), Problem> {
    let nodes = array(root, "nodes");
    let mut parent: Vec<Option<usize>> = vec![None; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        for (k, c) in array(n, "children").iter().enumerate() {
            let at = format!("nodes[{i}].children[{k}]");
            let c = c.as_u64().unwrap_or(u64::MAX) as usize;
            if c >= nodes.len() {
                return Err((at, format!("node {c} does not exist")));
            }
            if let Some(p) = parent[c] {
                return Err((at, format!("node {c} is a child of node {p} already (glTF's nodes form trees)")));
            }
            parent[c] = Some(i);
        }
    }
    for (s, scene) in array(root, "scenes").iter().enumerate() {
        for (k, n) in array(scene, "nodes").iter().enumerate() {
            if n.as_u64().is_none_or(|n| n as usize >= nodes.len()) {
                return Err((format!("scenes[{s}].nodes[{k}]"), format!("node {n} does not exist")));
            }
        }
    }
    // Depth of each node by its chain of parents; a chain that returns to its start is a
    // cycle (its nodes all have a parent, so no root reaches them).
    for start in 0..nodes.len() {
        let mut depth = 0;
        let mut at = start;
        while let Some(p) = parent[at] {
            depth += 1;
            if p == start {
                return Err((format!("nodes[{start}]"), "is its own ancestor (a cycle of children)".into()));
            }
            if depth > MAX_NODE_DEPTH {
                return Err((format!("nodes[{start}]"), format!("lies deeper than {MAX_NODE_DEPTH} levels of nodes")));
            }
            at = p;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn doc(extra: Value) -> Value {
        let mut d = json!({
            "buffers": [{ "byteLength": 48 }],
            "bufferViews": [{ "buffer": 0, "byteLength": 36 }, { "buffer": 0, "byteOffset": 36, "byteLength": 12 }],
            "accessors": [
                { "bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3" },
                { "bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR" }
            ],
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1 }] }],
            "nodes": [{ "mesh": 0 }],
            "scenes": [{ "nodes": [0] }]
        });
        for (k, v) in extra.as_object().unwrap() {
            d[k] = v.clone();
        }
        d
    }

    fn problem(d: Value) -> String {
        let (at, what) = check(&d, &[48]).unwrap_err();
        format!("{at}: {what}")
    }

    #[test]
    fn a_document_that_reads_as_it_says_passes() {
        check(&doc(json!({})), &[48]).unwrap();
    }

    #[test]
    fn what_the_gltf_crate_would_panic_on_or_misread_is_refused() {
        let mut d = doc(json!({}));
        d["bufferViews"][0]["byteStride"] = json!(4);
        assert!(problem(d).contains("do not fit buffer view 0's stride of 4"));
        let mut d = doc(json!({}));
        d["accessors"][1]["componentType"] = json!(5126);
        assert!(problem(d).contains("indices must be unsigned integer scalars"));
        let mut d = doc(json!({}));
        d["accessors"][1]["count"] = json!(300);
        assert!(problem(d).contains("run past buffer view 1's 12 bytes"));
        let mut d = doc(json!({}));
        d["accessors"][0]["count"] = json!(4);
        assert!(problem(d).starts_with("accessors[0]"));
        let mut d = doc(json!({}));
        d["bufferViews"][1]["byteLength"] = json!(1000);
        assert!(problem(d).contains("run past buffer 0's 48"));
        let mut d = doc(json!({}));
        d["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = json!(7);
        assert!(problem(d).contains("accessor 7 does not exist"));
        assert!(problem(doc(json!({ "images": [{}] }))).contains("neither a uri nor a bufferView"));
        assert!(problem(doc(json!({ "images": [{ "bufferView": 9 }] }))).contains("buffer view 9"));
        assert!(problem(doc(json!({ "images": [{ "bufferView": 0 }] }))).contains("no mimeType"));
        assert!(problem(doc(json!({ "textures": [{ "source": 0 }] }))).contains("image 0 does not exist"));
    }

    /// A sparse accessor passes with substitutions that fit their views; too many, none, a
    /// float index, a strided view or a view too short for them are refused.
    #[test]
    fn sparse_accessors_are_checked_as_their_views_hold_them() {
        let sparse =
            |count: u64| json!({ "count": count, "indices": { "bufferView": 1, "componentType": 5125 }, "values": { "bufferView": 0, "byteOffset": 12 } });
        let with = |s: Value| {
            let mut d = doc(json!({}));
            d["accessors"][0]["sparse"] = s;
            d
        };
        check(&with(sparse(2)), &[48]).unwrap();
        // Without a base view: zeros with the substitutions.
        let mut d = with(sparse(1));
        d["accessors"][0].as_object_mut().unwrap().remove("bufferView");
        check(&d, &[48]).unwrap();
        assert!(problem(with(sparse(0))).contains("0 is not between 1 and the accessor's 3 elements"));
        assert!(problem(with(sparse(4))).contains("4 is not between 1"));
        let mut s = sparse(2);
        s["indices"]["componentType"] = json!(5126);
        assert!(problem(with(s)).contains("indices.componentType: 5126 is not an unsigned integer type"));
        let mut d = with(sparse(3));
        d["accessors"][0]["sparse"]["values"]["byteOffset"] = json!(0);
        check(&d, &[48]).unwrap();
        assert!(problem(with(sparse(3))).contains("3 elements of 12 bytes from byte 12 run past buffer view 0's 36 bytes"));
        let mut d = with(sparse(2));
        d["bufferViews"][1]["byteStride"] = json!(4);
        assert!(problem(d).contains("has a byteStride"));
        let mut s = sparse(2);
        s["values"]["bufferView"] = json!(5);
        assert!(problem(with(s)).contains("buffer view 5 does not exist"));
    }

    #[test]
    fn nodes_must_form_shallow_trees() {
        let cycle = doc(json!({ "nodes": [{ "mesh": 0, "children": [1] }, { "children": [0] }] }));
        assert!(problem(cycle).contains("own ancestor"));
        let twice = doc(json!({ "nodes": [{ "children": [1, 1] }, { "mesh": 0 }] }));
        assert!(problem(twice).contains("a child of node 0 already"));
        let chain: Vec<Value> =
            (0..MAX_NODE_DEPTH + 2).map(|i| if i + 1 < MAX_NODE_DEPTH + 2 { json!({ "children": [i + 1] }) } else { json!({ "mesh": 0 }) }).collect();
        assert!(problem(doc(json!({ "nodes": chain }))).contains("deeper than"));
        let ok: Vec<Value> = (0..MAX_NODE_DEPTH).map(|i| if i + 1 < MAX_NODE_DEPTH { json!({ "children": [i + 1] }) } else { json!({ "mesh": 0 }) }).collect();
        check(&doc(json!({ "nodes": ok })), &[48]).unwrap();
        assert!(problem(doc(json!({ "scenes": [{ "nodes": [5] }] }))).contains("node 5 does not exist"));
    }
}
