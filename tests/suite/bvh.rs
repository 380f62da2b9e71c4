//! The scene BVH: the flattened layout is well-formed, its structs match the kernels'
//! reflection, and the GPU traversal (glsl/lib/bvh_traverse.glsl, run by
//! glsl/trace_test.comp) agrees ray by ray with the brute-force CPU reference, in both
//! node layouts (binary; wide: trace_test_wide; compressed 8-wide: trace_test_cw8).
//!
//! A ray is compared exactly (hit or miss, triangle, t to 1e-4 relative) unless it is
//! *borderline*: some triangle's hit lies within rounding distance of an edge, of T_MIN or
//! of tmax, or two hits are equally far. Such a ray may go either way in f32; its GPU hit
//! must still be a real hit of the triangle it names. Borderline rays must stay rare.

use crate::common;

use common::with_gpu;
use glam::DVec3;
use std::sync::Arc;
use vkinverse::bvh::{
    self, Bvh, BvhBuffers, BvhLayout, CwBvh, TraceRay, TraceResult, WideBvh, CW_STACK_SIZE, INNER, NO_HIT, STACK_SIZE, T_MIN, WIDE_STACK_SIZE,
};
use vkinverse::gpu::Buffer;
use vkinverse::gpu::{CommandBuffer, ComputePipeline, Context, MemoryKind};

// ---------------------------------------------------------------------------------------
// Inputs
// ---------------------------------------------------------------------------------------

/// A small PCG32: deterministic random numbers for geometry and rays.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        let mut r = Rng(seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407));
        r.next_u32();
        r
    }

    fn next_u32(&mut self) -> u32 {
        let old = self.0;
        self.0 = old.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        xorshifted.rotate_right((old >> 59) as u32)
    }

    /// Uniform in [0, 1).
    fn f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 / (1u32 << 24) as f32
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }

    fn point(&mut self, lo: [f32; 3], hi: [f32; 3]) -> [f32; 3] {
        [self.range(lo[0], hi[0]), self.range(lo[1], hi[1]), self.range(lo[2], hi[2])]
    }

    /// Uniform on the unit sphere.
    fn direction(&mut self) -> [f32; 3] {
        let z = self.range(-1.0, 1.0);
        let phi = self.range(0.0, std::f32::consts::TAU);
        let r = (1.0 - z * z).max(0.0).sqrt();
        [r * phi.cos(), r * phi.sin(), z]
    }

    fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.next_u32() as usize % items.len()]
    }
}

#[derive(Clone, Default)]
struct Mesh {
    positions: Vec<[f32; 3]>,
    indices: Vec<[u32; 3]>,
}

impl Mesh {
    fn push(&mut self, tri: [[f32; 3]; 3]) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&tri);
        self.indices.push([base, base + 1, base + 2]);
    }

    /// A uniformly distributed point on triangle `prim`.
    fn point_on(&self, prim: usize, rng: &mut Rng) -> [f32; 3] {
        let [a, b, c] = self.indices[prim].map(|i| glam::Vec3::from(self.positions[i as usize]));
        let (mut u, mut v) = (rng.f32(), rng.f32());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        (a + u * (b - a) + v * (c - a)).to_array()
    }
}

/// `n` random triangles of size ~0.2 in [-1, 1]^3, every tenth one axis-aligned (its box is
/// flat along one axis, like the Cornell box's walls).
fn soup(n: usize, seed: u64) -> Mesh {
    let mut rng = Rng::new(seed);
    let mut mesh = Mesh::default();
    for i in 0..n {
        let c = rng.point([-1.0; 3], [1.0; 3]);
        let mut tri = [0usize; 3].map(|_| {
            let o = rng.point([-0.12; 3], [0.12; 3]);
            [c[0] + o[0], c[1] + o[1], c[2] + o[2]]
        });
        if i % 10 == 0 {
            let axis = i / 10 % 3;
            for v in &mut tri {
                v[axis] = c[axis];
            }
        }
        mesh.push(tri);
    }
    mesh
}

fn cornell_scene() -> vkinverse::scene::Scene {
    vkinverse::scene::Scene::load(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/cornell/scene.toml")).unwrap()
}

fn scene_mesh(name: &str) -> Mesh {
    let path = format!("{}/scenes/{name}/scene.toml", env!("CARGO_MANIFEST_DIR"));
    let g = vkinverse::scene::Scene::load(path).unwrap().flatten();
    Mesh { positions: g.positions, indices: g.indices }
}

fn ray(origin: [f32; 3], dir: [f32; 3], tmax: f32) -> TraceRay {
    TraceRay { origin, tmax, dir }
}

fn normalize(d: [f32; 3]) -> [f32; 3] {
    glam::Vec3::from(d).normalize().to_array()
}

/// The six axis directions, with -0.0 and +0.0 in the zero components.
fn axis_directions() -> Vec<[f32; 3]> {
    vec![[1.0, 0.0, 0.0], [-1.0, -0.0, 0.0], [0.0, 1.0, -0.0], [-0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-0.0, 0.0, -1.0]]
}

/// Random rays for a mesh inside [lo, hi]: from outside, from inside (so starting inside
/// boxes), along the axes, with one zero direction component, unnormalised, and leaving
/// surfaces; tmax finite or infinite.
fn random_rays(mesh: &Mesh, lo: [f32; 3], hi: [f32; 3], n: usize, seed: u64) -> Vec<TraceRay> {
    let mut rng = Rng::new(seed);
    let centre = glam::Vec3::from(lo).lerp(glam::Vec3::from(hi), 0.5);
    let radius = (glam::Vec3::from(hi) - glam::Vec3::from(lo)).length();
    let mut rays = Vec::with_capacity(n);
    for i in 0..n {
        let tmax = if rng.f32() < 0.5 { f32::INFINITY } else { rng.range(0.05, 2.0 * radius) };
        let inside = rng.point(lo, hi);
        let r = match i % 6 {
            0 => {
                let o = (centre + radius * glam::Vec3::from(rng.direction())).to_array();
                let target = glam::Vec3::from(rng.point(lo, hi));
                ray(o, (target - glam::Vec3::from(o)).normalize().to_array(), tmax)
            }
            1 => ray(inside, rng.direction(), tmax),
            2 => ray(inside, rng.pick(&axis_directions()), tmax),
            3 => {
                let mut d = rng.direction();
                d[i / 6 % 3] = if rng.f32() < 0.5 { 0.0 } else { -0.0 };
                ray(inside, normalize(d), tmax)
            }
            4 => {
                // |dir| != 1: t is in units of |dir|.
                let d = glam::Vec3::from(rng.direction()) * rng.range(0.25, 4.0);
                ray(inside, d.to_array(), tmax)
            }
            _ => {
                let prim = rng.next_u32() as usize % mesh.indices.len();
                ray(mesh.point_on(prim, &mut rng), rng.direction(), tmax)
            }
        };
        rays.push(r);
    }
    rays
}

// ---------------------------------------------------------------------------------------
// GPU
// ---------------------------------------------------------------------------------------

/// The trace_test pipeline for `layout`, both traces on.
fn pipeline(ctx: &Arc<Context>, layout: BvhLayout) -> ComputePipeline {
    ComputePipeline::new(ctx, &layout.kernel("trace_test"), &[]).unwrap()
}

/// Runs trace_test over `rays` and returns the results.
fn run_trace(ctx: &Arc<Context>, pipe: &ComputePipeline, bufs: &BvhBuffers, rays: &[TraceRay]) -> Vec<TraceResult> {
    let ray_buf = Buffer::from_slice(ctx, "rays", rays, MemoryKind::Device).unwrap();
    let out = Buffer::zeroed::<TraceResult>(ctx, "results", rays.len(), MemoryKind::Device).unwrap();
    let mut binds = vec![("Rays", &ray_buf), ("Results", &out)];
    binds.extend(bufs.bindings());
    let group = pipe.bind(&binds).unwrap();
    let push = vkinverse::kernels::CountPush::new(rays.len() as u64);
    let mut cmd = CommandBuffer::new(ctx, "trace_test").unwrap();
    cmd.record(|rec| rec.dispatch_linear(pipe, &group, &push, rays.len() as u64)).unwrap();
    cmd.submit_and_wait().unwrap();
    out.read().unwrap()
}

fn trace(ctx: &Arc<Context>, layout: BvhLayout, bvh: &Bvh, rays: &[TraceRay]) -> Vec<TraceResult> {
    let bufs = bvh.upload_as(ctx, layout).unwrap();
    run_trace(ctx, &pipeline(ctx, layout), &bufs, rays)
}

/// The results of `rays` in every layout.
fn trace_layouts(bvh: &Bvh, rays: &[TraceRay]) -> Vec<(BvhLayout, Vec<TraceResult>)> {
    with_gpu(|ctx| BvhLayout::ALL.iter().map(|&l| (l, trace(ctx, l, bvh, rays))).collect())
}

// ---------------------------------------------------------------------------------------
// Comparison with the CPU reference
// ---------------------------------------------------------------------------------------

fn dvec(p: [f32; 3]) -> DVec3 {
    DVec3::from(p.map(f64::from))
}

/// Whether the ray is borderline (see the module doc): some triangle's hit is within
/// rounding distance of the policy's boundaries, or the two nearest hits tie.
fn borderline(mesh: &Mesh, r: &TraceRay) -> bool {
    let (o, d) = (dvec(r.origin), dvec(r.dir));
    let tmax = f64::from(r.tmax);
    let t_min = f64::from(T_MIN);
    let mut hits: Vec<f64> = Vec::new();
    for tri in &mesh.indices {
        let v = tri.map(|i| dvec(mesh.positions[i as usize]));
        let (e1, e2) = (v[1] - v[0], v[2] - v[0]);
        let det = e1.dot(d.cross(e2));
        let scale = d.length() * e1.length() * e2.length();
        if scale == 0.0 {
            continue;
        }
        // How much f32 rounding (of e1, e2 and the products) can move u, v and t: about 16
        // ulps times the condition number of the 3x3 system.
        let cond = (1.0 + (o - v[0]).length() / e1.length().min(e2.length())) * scale / det.abs().max(1e-300);
        let tol = 1e-6 * cond.max(1.0);
        let Some((t, u, w)) = bvh::moller_trumbore(v, o, d) else {
            continue;
        };
        let margin = u.min(w).min(1.0 - u - w);
        let t_tol = tol * t.abs().max(1.0);
        let near_inside = margin > -tol;
        let near_range = t > t_min - t_tol && t < tmax + t_tol;
        if near_inside && near_range {
            let edge = margin < tol;
            let at_bounds = (t - t_min).abs() <= t_tol || (t - tmax).abs() <= t_tol;
            if edge || at_bounds || cond > 1e4 {
                return true;
            }
            hits.push(t);
        }
    }
    hits.sort_by(f64::total_cmp);
    hits.windows(2).any(|w| w[1] - w[0] <= 1e-5 * w[0].abs().max(1.0))
}

/// Compares GPU results with `intersect_brute_force` ray by ray; returns the number of
/// borderline rays. Panics with the ray on a disagreement.
fn check_against_cpu(label: &str, mesh: &Mesh, rays: &[TraceRay], results: &[TraceResult]) -> usize {
    assert_eq!(results.len(), rays.len());
    let mut borderline_rays = 0;
    for (i, (r, g)) in rays.iter().zip(results).enumerate() {
        let what = || format!("{label} ray {i}: {r:?}\n  gpu {g:?}");
        let gpu_hit = g.hit.prim != NO_HIT;
        // Any-hit traversal enters every box closest-hit traversal enters, and finds a hit
        // whenever closest-hit does: the two agree on every ray, borderline or not.
        assert_eq!(g.any_hit, gpu_hit as u32, "any-hit disagrees with closest-hit: {}", what());
        if !gpu_hit {
            assert_eq!(g.hit.t, r.tmax, "a miss reports t = tmax: {}", what());
        }
        let cpu = bvh::intersect_brute_force(&mesh.positions, &mesh.indices, r.origin, r.dir, r.tmax);
        if borderline(mesh, r) {
            borderline_rays += 1;
            if gpu_hit {
                // The GPU's hit must be a real one of the triangle it names.
                let prim = g.hit.prim as usize;
                assert!(prim < mesh.indices.len(), "{}", what());
                let v = mesh.indices[prim].map(|k| dvec(mesh.positions[k as usize]));
                let (t, u, w) = bvh::moller_trumbore(v, dvec(r.origin), dvec(r.dir)).unwrap_or_else(|| panic!("GPU hit on a parallel triangle: {}", what()));
                assert!((t - f64::from(g.hit.t)).abs() <= 1e-3 * t.abs().max(1.0), "{} (cpu t {t})", what());
                assert!(u > -1e-3 && w > -1e-3 && u + w < 1.0 + 1e-3, "{} (cpu u {u} v {w})", what());
            }
            continue;
        }
        match cpu {
            None => assert!(!gpu_hit, "GPU hit where the CPU misses: {}", what()),
            Some(c) => {
                assert!(gpu_hit, "GPU misses where the CPU hits {c:?}: {}", what());
                assert_eq!(g.hit.prim, c.prim, "other triangle than the CPU's {c:?}: {}", what());
                // Relative to t, or absolute below t = 1, where the origin's rounding dominates.
                assert!((g.hit.t - c.t).abs() <= 1e-4 * c.t.max(1.0), "t differs from the CPU's {c:?}: {}", what());
                assert!((g.hit.u - c.u).abs() <= 1e-3 && (g.hit.v - c.v).abs() <= 1e-3, "barycentrics differ from {c:?}: {}", what());
            }
        }
    }
    borderline_rays
}

// ---------------------------------------------------------------------------------------
// Well-formedness of the flattened BVH (CPU only)
// ---------------------------------------------------------------------------------------

struct Walk {
    node_seen: Vec<bool>,
    prim_seen: Vec<bool>,
    next_triangle: u32,
    max_depth: u32,
    max_leaf: u32,
    leaves: u32,
}

fn inside(inner_min: [f32; 3], inner_max: [f32; 3], outer_min: [f32; 3], outer_max: [f32; 3]) -> bool {
    (0..3).all(|k| inner_min[k] >= outer_min[k] && inner_max[k] <= outer_max[k])
}

fn walk(mesh: &Mesh, bvh: &Bvh, node: u32, depth: u32, w: &mut Walk) {
    assert!(!w.node_seen[node as usize], "node {node} reached twice");
    w.node_seen[node as usize] = true;
    w.max_depth = w.max_depth.max(depth);
    let children = bvh.nodes[node as usize].children();
    if children[0].is_inner() {
        assert_eq!(children[0].index, node + 1, "depth-first order: the left inner child follows its parent");
    }
    for c in children {
        if c.is_inner() {
            assert!(c.index > node && (c.index as usize) < bvh.nodes.len(), "child {} of node {node}", c.index);
            for g in bvh.nodes[c.index as usize].children() {
                if g.count != 0 {
                    assert!(inside(g.min, g.max, c.min, c.max), "a box of node {} sticks out of its parent's", c.index);
                }
            }
            walk(mesh, bvh, c.index, depth + 1, w);
        } else if c.count == 0 {
            assert_eq!(node, 0, "only the root has empty children");
            assert_eq!((c.min, c.max), ([f32::INFINITY; 3], [f32::INFINITY; 3]), "an empty child's box is never entered");
        } else {
            assert_eq!(c.index, w.next_triangle, "leaves tile the triangle array in depth-first order");
            w.next_triangle += c.count;
            w.max_leaf = w.max_leaf.max(c.count);
            w.leaves += 1;
            for tri in &bvh.triangles[c.index as usize..w.next_triangle as usize] {
                let prim = tri.prim as usize;
                assert!(!w.prim_seen[prim], "triangle {prim} in two leaves");
                w.prim_seen[prim] = true;
                let [a, b, d] = mesh.indices[prim].map(|i| glam::Vec3::from(mesh.positions[i as usize]));
                for p in [a, b, d] {
                    assert!(inside(p.to_array(), p.to_array(), c.min, c.max), "triangle {prim} outside its leaf box");
                }
                assert_eq!(tri.v0, a.to_array());
                assert_eq!(tri.e1, (b - a).to_array());
                assert_eq!(tri.e2, (d - a).to_array());
            }
        }
    }
}

/// What check_well_formed measured.
struct Shape {
    /// Largest depth of an inner node.
    depth: u32,
    /// Triangles in the largest leaf.
    max_leaf: u32,
    /// Non-empty leaves.
    leaves: u32,
}

/// Checks the invariants of the module doc of vkinverse::bvh.
fn check_well_formed(mesh: &Mesh, bvh: &Bvh, max_depth: u32) -> Shape {
    assert!(!bvh.nodes.is_empty(), "there is always a root");
    assert_eq!(bvh.triangles.len(), mesh.indices.len());
    let mut w =
        Walk { node_seen: vec![false; bvh.nodes.len()], prim_seen: vec![false; mesh.indices.len()], next_triangle: 0, max_depth: 0, max_leaf: 0, leaves: 0 };
    walk(mesh, bvh, 0, 0, &mut w);
    assert!(w.node_seen.iter().all(|&s| s), "unreachable nodes");
    assert!(w.prim_seen.iter().all(|&s| s), "triangles in no leaf");
    assert_eq!(w.next_triangle as usize, bvh.triangles.len());
    assert!(w.max_depth <= max_depth, "inner node at depth {} > {max_depth}", w.max_depth);
    Shape { depth: w.max_depth, max_leaf: w.max_leaf, leaves: w.leaves }
}

#[test]
fn flattened_bvh_is_well_formed() {
    let mut one = Mesh::default();
    one.push([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let mut two = one.clone();
    two.push([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]);
    let cases = [
        ("empty", Mesh::default()),
        ("one triangle", one),
        ("two triangles", two),
        ("soup", soup(3000, 1)),
        ("cornell", scene_mesh("cornell")),
        ("spiral", scene_mesh("spiral")),
    ];
    for (name, mesh) in &cases {
        let bvh = bvh::build(&mesh.positions, &mesh.indices);
        let shape = check_well_formed(mesh, &bvh, STACK_SIZE);
        // Unless the depth limit forces it, leaves are obvhs's (at most 8 triangles).
        assert!(shape.max_leaf <= 8, "{name}: leaf of {} triangles", shape.max_leaf);
        if mesh.indices.len() <= 1 {
            assert_eq!(bvh.nodes.len(), 1, "{name}");
            assert_eq!(bvh.nodes[0].right_count, 0, "{name}: the root's right child is empty");
        }
        if *name == "soup" {
            assert!(shape.depth >= 6, "soup: a tree over 3000 triangles has some depth, got {}", shape.depth);
        }
    }
    // Depth limits below the obvhs tree's depth: rebalanced subtrees, then merged leaves.
    let mesh = soup(3000, 2);
    let full = check_well_formed(&mesh, &bvh::build(&mesh.positions, &mesh.indices), STACK_SIZE);
    for limit in [0, 1, 3, 6, 9, full.depth - 1] {
        assert!(limit < full.depth, "the limit {limit} must cut the tree (depth {})", full.depth);
        let bvh = bvh::build_with_depth_limit(&mesh.positions, &mesh.indices, limit);
        let shape = check_well_formed(&mesh, &bvh, limit);
        assert_eq!(shape.depth, limit, "limit {limit}: the tree is cut at the limit, not above it");
        // Leaves hang at depth <= limit + 1: 2^(limit + 1) slots. Obvhs's leaves are kept
        // when they fit, and merged when they do not.
        if u64::from(full.leaves) <= 1 << (limit + 1) {
            assert_eq!(shape.leaves, full.leaves, "limit {limit}: no leaves merged");
            assert!(shape.max_leaf <= 8, "limit {limit}: no leaves merged");
        } else {
            assert!(u64::from(shape.leaves) <= 1 << (limit + 1), "limit {limit}: {} leaves", shape.leaves);
        }
    }
}

/// Walks a wide tree from `node` at `depth`: every node reached once, inner children after
/// their parent, boxes nested, empty slots never entered. Returns the largest depth of an
/// inner node.
fn walk_wide(tree: &WideBvh, node: u32, depth: u32, seen: &mut Vec<bool>) -> u32 {
    assert!(!seen[node as usize], "wide node {node} reached twice");
    seen[node as usize] = true;
    let mut max_depth = depth;
    for c in tree.nodes[node as usize].slots() {
        if c.is_inner() {
            assert!(c.index > node && (c.index as usize) < tree.nodes.len(), "child {} of wide node {node}", c.index);
            for g in tree.nodes[c.index as usize].slots() {
                if g.count != 0 {
                    assert!(inside(g.min, g.max, c.min, c.max), "a box of wide node {} sticks out of its parent's", c.index);
                }
            }
            max_depth = max_depth.max(walk_wide(tree, c.index, depth + 1, seen));
        } else if c.count == 0 {
            assert_eq!((c.min, c.max), ([f32::INFINITY; 3], [f32::INFINITY; 3]), "an empty slot is never entered");
        }
    }
    max_depth
}

/// The non-empty leaf children of a binary tree, as (index, count, box).
fn binary_leaves(bvh: &Bvh) -> Vec<(u32, u32, [f32; 3], [f32; 3])> {
    let mut out = Vec::new();
    let mut stack = vec![0u32];
    while let Some(n) = stack.pop() {
        let children = bvh.nodes[n as usize].children();
        for c in children.iter().rev() {
            if c.is_inner() {
                stack.push(c.index);
            }
        }
        for c in children {
            if !c.is_inner() && c.count != 0 {
                out.push((c.index, c.count, c.min, c.max));
            }
        }
    }
    out
}

/// Checks the wide layout of `bvh` (see vkinverse::bvh::WideBvh): well-formed with inner
/// nodes at depth <= max_depth, and the binary tree's leaves, boxes and triangles. Returns
/// the largest depth of an inner node.
fn check_wide_well_formed(mesh: &Mesh, bvh: &Bvh, max_depth: u32) -> u32 {
    let wide = WideBvh::from_binary(bvh);
    assert!(!wide.nodes.is_empty(), "there is always a root");
    assert_eq!(wide.triangles, bvh.triangles, "the binary tree's triangles");
    assert_eq!(wide.triangles.len(), mesh.indices.len());
    let mut seen = vec![false; wide.nodes.len()];
    let depth = walk_wide(&wide, 0, 0, &mut seen);
    assert!(seen.iter().all(|&s| s), "unreachable wide nodes");
    assert!(depth <= max_depth, "wide inner node at depth {depth} > {max_depth}");
    let mut wide_leaves: Vec<_> =
        wide.nodes.iter().flat_map(|n| n.slots()).filter(|c| !c.is_inner() && c.count != 0).map(|c| (c.index, c.count, c.min, c.max)).collect();
    let mut leaves = binary_leaves(bvh);
    let key = |l: &(u32, u32, [f32; 3], [f32; 3])| l.0;
    wide_leaves.sort_by_key(key);
    leaves.sort_by_key(key);
    assert_eq!(wide_leaves, leaves, "the wide tree's leaves are the binary tree's");
    // Every inner slot's box is the union of its node's slots (the binary boxes are tight).
    for n in &wide.nodes {
        for c in n.slots().iter().filter(|c| c.is_inner()) {
            let slots = wide.nodes[c.index as usize].slots();
            let used: Vec<_> = slots.iter().filter(|g| g.count != 0).collect();
            for k in 0..3 {
                assert_eq!(c.min[k], used.iter().map(|g| g.min[k]).fold(f32::INFINITY, f32::min));
                assert_eq!(c.max[k], used.iter().map(|g| g.max[k]).fold(f32::NEG_INFINITY, f32::max));
            }
        }
    }
    depth
}

#[test]
fn wide_bvh_is_well_formed() {
    let mut one = Mesh::default();
    one.push([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let mut two = one.clone();
    two.push([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]);
    for (name, mesh) in [
        ("empty", Mesh::default()),
        ("one triangle", one),
        ("two triangles", two),
        ("soup", soup(3000, 1)),
        ("cornell", scene_mesh("cornell")),
        ("spiral", scene_mesh("spiral")),
    ] {
        let bvh = bvh::build(&mesh.positions, &mesh.indices);
        let depth = check_wide_well_formed(&mesh, &bvh, STACK_SIZE / 2);
        let binary = check_well_formed(&mesh, &bvh, STACK_SIZE).depth;
        assert!(depth <= binary / 2, "{name}: wide depth {depth}, binary {binary}");
        let wide = WideBvh::from_binary(&bvh);
        let slots = wide.nodes.iter().flat_map(|n| n.count).filter(|&c| c != 0).count();
        if name == "soup" {
            // Nodes are filled where the tree allows: at least 3 slots of 4 on average
            // (nodes near the leaves may have fewer than 4 leaves below them).
            assert!(slots >= 3 * wide.nodes.len(), "soup: {slots} slots used in {} wide nodes", wide.nodes.len());
        }
    }
    let mesh = soup(3000, 2);
    for limit in [0, 1, 2, 3, 6, 9] {
        let bvh = bvh::build_with_depth_limit(&mesh.positions, &mesh.indices, limit);
        assert_eq!(check_wide_well_formed(&mesh, &bvh, limit / 2), limit / 2, "limit {limit}");
    }
}

// ---------------------------------------------------------------------------------------
// Layouts and constants
// ---------------------------------------------------------------------------------------

/// The value of `#define NAME value` in glsl/shared/bvh.glsl.
fn glsl_define(name: &str) -> String {
    let src = include_str!("../../glsl/shared/bvh.glsl");
    src.lines()
        .find_map(|l| l.strip_prefix("#define ")?.strip_prefix(name)?.strip_prefix(' ').map(|v| v.trim().to_string()))
        .unwrap_or_else(|| panic!("no #define {name}"))
}

#[test]
fn glsl_constants_match_rust() {
    assert_eq!(glsl_define("BVH_STACK_SIZE").parse::<u32>().unwrap(), STACK_SIZE);
    assert_eq!(glsl_define("BVH_WIDE_STACK_SIZE").parse::<u32>().unwrap(), WIDE_STACK_SIZE);
    assert_eq!(glsl_define("BVH_CW_STACK_SIZE").parse::<u32>().unwrap(), CW_STACK_SIZE);
    assert_eq!(glsl_define("BVH_CW_STACK_REGISTERS").parse::<u32>().unwrap(), vkinverse::bvh::CW_STACK_REGISTERS);
    assert_eq!(glsl_define("BVH_T_MIN").parse::<f32>().unwrap(), T_MIN);
    let hex = |s: String| u32::from_str_radix(s.trim_start_matches("0x").trim_end_matches('u'), 16).unwrap();
    assert_eq!(hex(glsl_define("BVH_INNER")), INNER);
    assert_eq!(hex(glsl_define("BVH_NO_HIT")), NO_HIT);
}

#[test]
fn struct_layouts_match_reflection() {
    use std::mem::{offset_of, size_of};
    use vkinverse::bvh::{BvhNode, BvhTriangle, Hit};
    let reflect = |kernel: &str| {
        let spirv = vkinverse::gpu::shaders::get(kernel).unwrap();
        vkinverse::gpu::reflect::Reflection::new(kernel, spirv).unwrap()
    };
    let r = reflect("trace_test");
    // Nodes and triangles are read from texel buffers; records_test writes them out as
    // structs (and tests/suite/render.rs checks that it reads back what the host wrote).
    let check = |name: &str, rust: &[(&str, usize)], size: usize| {
        let kernel = if matches!(name, "BvhNode" | "BvhTriangle") { "records_test" } else { "trace_test" };
        common::check_layout(kernel, name, rust, size)
    };
    check(
        "BvhNode",
        &[
            ("left_min", offset_of!(BvhNode, left_min)),
            ("left_index", offset_of!(BvhNode, left_index)),
            ("left_max", offset_of!(BvhNode, left_max)),
            ("left_count", offset_of!(BvhNode, left_count)),
            ("right_min", offset_of!(BvhNode, right_min)),
            ("right_index", offset_of!(BvhNode, right_index)),
            ("right_max", offset_of!(BvhNode, right_max)),
            ("right_count", offset_of!(BvhNode, right_count)),
        ],
        size_of::<BvhNode>(),
    );
    check(
        "BvhTriangle",
        &[
            ("v0", offset_of!(BvhTriangle, v0)),
            ("e1", offset_of!(BvhTriangle, e1)),
            ("e2", offset_of!(BvhTriangle, e2)),
            ("prim", offset_of!(BvhTriangle, prim)),
            ("alpha_material", offset_of!(BvhTriangle, alpha_material)),
            ("pad", offset_of!(BvhTriangle, pad)),
        ],
        size_of::<BvhTriangle>(),
    );
    check("Hit", &[("t", offset_of!(Hit, t)), ("prim", offset_of!(Hit, prim)), ("u", offset_of!(Hit, u)), ("v", offset_of!(Hit, v))], size_of::<Hit>());
    check(
        "TraceRay",
        &[("origin", offset_of!(TraceRay, origin)), ("tmax", offset_of!(TraceRay, tmax)), ("dir", offset_of!(TraceRay, dir))],
        size_of::<TraceRay>(),
    );
    check("TraceResult", &[("hit", offset_of!(TraceResult, hit)), ("any_hit", offset_of!(TraceResult, any_hit))], size_of::<TraceResult>());
    // The byte sizes stated in glsl/shared/bvh.glsl.
    assert_eq!([size_of::<BvhNode>(), size_of::<BvhTriangle>(), size_of::<Hit>(), size_of::<TraceRay>(), size_of::<TraceResult>()], [64, 48, 16, 28, 20]);
    // The geometry bindings sit where bvh_traverse.glsl's convention puts them.
    for (name, binding) in [("BvhNodes", 10), ("BvhTriangles", 11)] {
        let b = r.binding(name).unwrap_or_else(|| panic!("{name} not bound"));
        assert_eq!(b.binding, binding, "{name}");
        assert_eq!(b.access, vkinverse::gpu::reflect::BindingAccess::Read, "{name} is read-only");
    }

    // The wide build: its node struct, and the same bindings.
    use vkinverse::bvh::BvhWideNode;
    let r = reflect("trace_test_wide");
    common::check_layout(
        "records_test_wide",
        "BvhWideNode",
        &[
            ("min_x", offset_of!(BvhWideNode, min_x)),
            ("min_y", offset_of!(BvhWideNode, min_y)),
            ("min_z", offset_of!(BvhWideNode, min_z)),
            ("max_x", offset_of!(BvhWideNode, max_x)),
            ("max_y", offset_of!(BvhWideNode, max_y)),
            ("max_z", offset_of!(BvhWideNode, max_z)),
            ("index", offset_of!(BvhWideNode, index)),
            ("count", offset_of!(BvhWideNode, count)),
        ],
        size_of::<BvhWideNode>(),
    );
    assert_eq!(size_of::<BvhWideNode>(), 128);
    use vkinverse::bvh::BvhCwNode;
    common::check_layout(
        "records_test_cw8",
        "BvhCwNode",
        &[
            ("p", offset_of!(BvhCwNode, p)),
            ("e_imask", offset_of!(BvhCwNode, e_imask)),
            ("child_base", offset_of!(BvhCwNode, child_base)),
            ("triangle_base", offset_of!(BvhCwNode, triangle_base)),
            ("meta", offset_of!(BvhCwNode, meta)),
            ("quant_x", offset_of!(BvhCwNode, quant_x)),
            ("quant_y", offset_of!(BvhCwNode, quant_y)),
            ("quant_z", offset_of!(BvhCwNode, quant_z)),
        ],
        size_of::<BvhCwNode>(),
    );
    assert_eq!(size_of::<BvhCwNode>(), 80);
    assert_eq!(reflect("records_test_wide").struct_size("BvhTriangle"), Some(size_of::<BvhTriangle>()));
    for (name, binding) in [("BvhNodes", 10), ("BvhTriangles", 11)] {
        let b = r.binding(name).unwrap_or_else(|| panic!("{name} not bound in trace_test_wide"));
        assert_eq!(b.binding, binding, "{name}");
        assert_eq!(b.access, vkinverse::gpu::reflect::BindingAccess::Read, "{name} is read-only");
    }
}

// ---------------------------------------------------------------------------------------
// GPU traversal against the CPU reference
// ---------------------------------------------------------------------------------------

#[test]
fn random_rays_into_a_triangle_soup() {
    let mesh = soup(3000, 3);
    let rays = random_rays(&mesh, [-1.2; 3], [1.2; 3], 6001, 4);
    let bvh = bvh::build(&mesh.positions, &mesh.indices);
    for (layout, results) in trace_layouts(&bvh, &rays) {
        let borderline = check_against_cpu(&format!("soup {layout:?}"), &mesh, &rays, &results);
        let hits = results.iter().filter(|r| r.hit.prim != NO_HIT).count();
        assert!(hits > rays.len() / 4 && hits < rays.len() * 3 / 4, "a mix of hits and misses: {hits} of {}", rays.len());
        assert!(borderline * 50 < rays.len(), "{borderline} borderline rays of {}", rays.len());
    }
}

#[test]
fn cornell_box_rays() {
    let scene = cornell_scene();
    let g = scene.flatten();
    let mesh = Mesh { positions: g.positions, indices: g.indices };
    let mut rng = Rng::new(5);
    // Camera rays through jittered points of every pixel of a 37 x 29 film with the
    // scene's aspect ratio.
    let sensor = &scene.sensors[0];
    let aspect = scene.film.width as f32 / scene.film.height as f32;
    let (w, h) = (37, 29);
    let mut rays = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let ndc = glam::Vec2::new((x as f32 + rng.f32()) / w as f32 * 2.0 - 1.0, 1.0 - (y as f32 + rng.f32()) / h as f32 * 2.0);
            rays.push(ray(sensor.origin.to_array(), sensor.ray_direction(ndc, aspect).to_array(), f32::INFINITY));
        }
    }
    // Rays inside the room, along axes (walls are axis-aligned: their boxes are flat along
    // the ray's only non-zero component), and leaving surfaces.
    rays.extend(random_rays(&mesh, [-0.999, 0.001, -0.999], [0.999, 1.999, 0.999], 3000, 6));
    let bvh = bvh::build(&mesh.positions, &mesh.indices);
    // Rays lying in the planes of the floor and the left wall, which those triangles are
    // parallel to: the slab test sees 0 * (1 / 0) there. Most of them graze the edges of
    // other walls, so they are borderline by design.
    let mut in_plane = Vec::new();
    for i in 0..50 {
        let t = i as f32 / 50.0 * 1.8 - 0.9;
        in_plane.push(ray([t, 0.0, 0.3], [0.0, 0.0, -1.0], f32::INFINITY));
        in_plane.push(ray([-1.0, 1.0 + t, 0.0], [0.0, -0.0, 1.0], f32::INFINITY));
        in_plane.push(ray([t, 0.0, t], normalize([1.0, 0.0, -1.0]), f32::INFINITY));
    }
    let in_plane_results = trace_layouts(&bvh, &in_plane);
    for ((layout, results), (_, in_plane_results)) in trace_layouts(&bvh, &rays).into_iter().zip(in_plane_results) {
        let borderline = check_against_cpu(&format!("cornell {layout:?}"), &mesh, &rays, &results);
        assert!(borderline * 50 < rays.len(), "{borderline} borderline rays of {}", rays.len());
        check_against_cpu(&format!("cornell in-plane {layout:?}"), &mesh, &in_plane, &in_plane_results);
        // The camera looks into the open front of the room and sees it fill the film: only
        // rays through the top and bottom rows pass above the ceiling or below the floor.
        let camera_hits = results.iter().take(w * h).filter(|g| g.hit.prim != NO_HIT).count();
        assert!(camera_hits * 10 > w * h * 9, "{camera_hits} of {} camera rays hit the room", w * h);
    }
}

#[test]
fn empty_scene_always_misses() {
    let mesh = Mesh::default();
    let bvh = bvh::build(&[], &[]);
    assert!(bvh.triangles.is_empty());
    let rays = random_rays(&soup(10, 1), [-1.0; 3], [1.0; 3], 131, 7);
    for (layout, results) in trace_layouts(&bvh, &rays) {
        for (r, g) in rays.iter().zip(&results) {
            assert_eq!(g.hit.prim, NO_HIT, "{layout:?} {r:?}");
            assert_eq!(g.any_hit, 0, "{layout:?} {r:?}");
            assert_eq!(g.hit.t, r.tmax, "{layout:?} {r:?}");
        }
        check_against_cpu(&format!("empty {layout:?}"), &mesh, &rays, &results);
    }
}

#[test]
fn single_triangle_policy() {
    let mut mesh = Mesh::default();
    mesh.push([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let down = [0.0, 0.0, -1.0];
    /// A ray and its expected hit as (t, u, v).
    type Case = (TraceRay, Option<(f32, f32, f32)>);
    let cases: Vec<Case> = vec![
        (ray([0.2, 0.3, 1.0], down, f32::INFINITY), Some((1.0, 0.2, 0.3))),
        // Back faces count.
        (ray([0.2, 0.3, -1.0], [0.0, 0.0, 1.0], f32::INFINITY), Some((1.0, 0.2, 0.3))),
        // t is in units of |dir|.
        (ray([0.2, 0.3, 1.0], [0.0, 0.0, -2.0], f32::INFINITY), Some((0.5, 0.2, 0.3))),
        // The open interval (T_MIN, tmax).
        (ray([0.2, 0.3, 1.0], down, 1.0), None),
        (ray([0.2, 0.3, 1.0], down, 0.999), None),
        (ray([0.2, 0.3, 1.0], down, 1.001), Some((1.0, 0.2, 0.3))),
        (ray([0.2, 0.3, 0.5 * T_MIN], down, f32::INFINITY), None),
        (ray([0.2, 0.3, 2.0 * T_MIN], down, f32::INFINITY), Some((2.0 * T_MIN, 0.2, 0.3))),
        (ray([0.2, 0.3, -1.0], down, f32::INFINITY), None),
        // Vertices and edges belong to the triangle.
        (ray([0.0, 0.0, 1.0], down, f32::INFINITY), Some((1.0, 0.0, 0.0))),
        (ray([0.5, 0.5, 1.0], down, f32::INFINITY), Some((1.0, 0.5, 0.5))),
        (ray([0.5, 0.0, 1.0], down, f32::INFINITY), Some((1.0, 0.5, 0.0))),
        (ray([0.5, 0.5001, 1.0], down, f32::INFINITY), None),
        (ray([-0.0001, 0.5, 1.0], down, f32::INFINITY), None),
        // Parallel rays: in the plane, and above it.
        (ray([0.2, 0.3, 0.0], [1.0, 0.0, 0.0], f32::INFINITY), None),
        (ray([-1.0, 0.3, 0.0], [1.0, 0.0, 0.0], f32::INFINITY), None),
        (ray([-1.0, 0.3, 0.5], [1.0, -0.0, 0.0], f32::INFINITY), None),
        // Oblique, from outside the triangle's box.
        (ray([-1.0, -1.0, 1.0], normalize([1.25, 1.25, -1.0]), f32::INFINITY), Some((4.125f32.sqrt(), 0.25, 0.25))),
    ];
    let rays: Vec<TraceRay> = cases.iter().map(|c| c.0).collect();
    let bvh = bvh::build(&mesh.positions, &mesh.indices);
    for (layout, results) in trace_layouts(&bvh, &rays) {
        for ((r, expected), g) in cases.iter().zip(&results) {
            let cpu = bvh::intersect_brute_force(&mesh.positions, &mesh.indices, r.origin, r.dir, r.tmax);
            assert_eq!(cpu.map(|h| h.prim), expected.map(|_| 0), "CPU reference on {layout:?} {r:?}");
            match expected {
                None => {
                    assert_eq!(g.hit.prim, NO_HIT, "{layout:?} {r:?}: {g:?}");
                    assert_eq!(g.any_hit, 0, "{layout:?} {r:?}");
                }
                Some((t, u, v)) => {
                    assert_eq!(g.hit.prim, 0, "{layout:?} {r:?}: {g:?}");
                    assert_eq!(g.any_hit, 1, "{layout:?} {r:?}");
                    for (got, want) in [(g.hit.t, *t), (g.hit.u, *u), (g.hit.v, *v)] {
                        assert!((got - want).abs() <= 1e-5 * want.max(1.0), "{layout:?} {r:?}: {g:?}, want {expected:?}");
                    }
                    let c = cpu.unwrap();
                    assert!((c.t - t).abs() <= 1e-5 * t.max(1.0) && (c.u - u).abs() <= 1e-5 && (c.v - v).abs() <= 1e-5, "CPU {c:?}");
                }
            }
        }
    }
}

#[test]
fn depth_limited_trees_trace_the_same() {
    let mesh = soup(2000, 8);
    let rays = random_rays(&mesh, [-1.2; 3], [1.2; 3], 1500, 9);
    with_gpu(|ctx| {
        for layout in BvhLayout::ALL {
            let pipe = pipeline(ctx, layout);
            // Odd limits too: the wide tree's depth is half the binary one's, rounded down.
            for limit in [0, 1, 2, 3, 5] {
                let bvh = bvh::build_with_depth_limit(&mesh.positions, &mesh.indices, limit);
                let bufs = bvh.upload_as(ctx, layout).unwrap();
                let results = run_trace(ctx, &pipe, &bufs, &rays);
                let borderline = check_against_cpu(&format!("{layout:?} depth limit {limit}"), &mesh, &rays, &results);
                assert!(borderline * 50 < rays.len(), "{borderline} borderline rays");
            }
        }
    });
}

/// A tree that fills the traversal stack: a left spine from the root down to depth
/// STACK_SIZE, every spine node's right child an inner node of two one-triangle leaves,
/// all boxes equal (ties go left, so the spine is always "near" and each right child is
/// pushed): the stack holds STACK_SIZE entries at the bottom of the spine.
#[test]
fn deepest_tree_fills_the_stack() {
    let depth = STACK_SIZE as usize;
    // Triangle i lies in the plane z = 1 + (n - 1 - i) / 100, covering the square
    // [-1, 1]^2 and more.
    let n = 2 * (depth + 1);
    let mut mesh = Mesh::default();
    for i in 0..n {
        let z = 1.0 + (n - 1 - i) as f32 / 100.0;
        mesh.push([[-1.0, -1.0, z], [3.0, -1.0, z], [-1.0, 3.0, z]]);
    }
    let (lo, hi) = ([-1.0, -1.0, 1.0], [3.0, 3.0, 1.0 + (n - 1) as f32 / 100.0]);
    let leaf = |first: usize| (first as u32, 1);
    let node = |left: (u32, u32), right: (u32, u32)| bvh::BvhNode {
        left_min: lo,
        left_index: left.0,
        left_max: hi,
        left_count: left.1,
        right_min: lo,
        right_index: right.0,
        right_max: hi,
        right_count: right.1,
    };
    // Depth-first: the spine 0..=depth, then the right children bottom-up (the deepest
    // one's triangles first).
    let mut nodes = Vec::new();
    for d in 0..depth {
        nodes.push(node((d as u32 + 1, INNER), ((2 * depth - d) as u32, INNER)));
    }
    nodes.push(node(leaf(0), leaf(1)));
    for d in (0..depth).rev() {
        let first = 2 * (depth - d);
        nodes.push(node(leaf(first), leaf(first + 1)));
    }
    let triangles = (0..n)
        .map(|i| {
            let [a, b, c] = mesh.indices[i].map(|k| mesh.positions[k as usize]);
            bvh::BvhTriangle::new(a, b, c, i as u32)
        })
        .collect();
    let tree = Bvh { nodes, triangles };
    assert_eq!(check_well_formed(&mesh, &tree, STACK_SIZE).depth, STACK_SIZE);

    // For every triangle, rays starting just below and just above its plane: each one's
    // closest hit is that triangle, so a lost stack entry shows as a wrong hit.
    let mut rng = Rng::new(12);
    let mut rays = Vec::new();
    for i in 0..n {
        let z = 1.0 + (n - 1 - i) as f32 / 100.0;
        let [x, y, _] = rng.point([-0.9; 3], [0.9; 3]);
        rays.push(ray([x, y, z - 0.005], [0.0, 0.0, 1.0], f32::INFINITY));
        rays.push(ray([x, y, z + 0.005], normalize([rng.range(-0.2, 0.2), rng.range(-0.2, 0.2), -1.0]), f32::INFINITY));
    }
    // The wide layout of the same tree is a spine of depth STACK_SIZE / 2.
    assert_eq!(check_wide_well_formed(&mesh, &tree, STACK_SIZE / 2), STACK_SIZE / 2);
    for (layout, results) in trace_layouts(&tree, &rays) {
        check_against_cpu(&format!("deepest tree {layout:?}"), &mesh, &rays, &results);
        for (k, g) in results.iter().enumerate() {
            assert_eq!(g.hit.prim, k as u32 / 2, "{layout:?} ray {k}: {:?}", rays[k]);
        }
    }
}

/// The wide counterpart: a spine of wide nodes from the root down to depth
/// STACK_SIZE / 2, every spine node's slot 0 the next spine node and slots 1 to 3 inner
/// nodes of one one-triangle leaf each, the bottom spine node one leaf; all boxes equal
/// (ties keep slot order, so the spine is always nearest and slots 1 to 3 are pushed): the
/// stack holds 3 * STACK_SIZE / 2 = WIDE_STACK_SIZE entries at the bottom of the spine.
#[test]
fn deepest_wide_tree_fills_the_stack() {
    let depth = (STACK_SIZE / 2) as usize;
    assert_eq!(3 * depth, WIDE_STACK_SIZE as usize);
    let n = 3 * depth + 1;
    let mut mesh = Mesh::default();
    for i in 0..n {
        let z = 1.0 + (n - 1 - i) as f32 / 100.0;
        mesh.push([[-1.0, -1.0, z], [3.0, -1.0, z], [-1.0, 3.0, z]]);
    }
    let (lo, hi) = ([-1.0, -1.0, 1.0], [3.0, 3.0, 1.0 + (n - 1) as f32 / 100.0]);
    let slot = |index: u32, count: u32| bvh::BvhChild { min: lo, max: hi, index, count };
    // Depth-first: spine node d at 4d, followed by its three side nodes; triangles in the
    // order the leaves are met: the bottom leaf first (triangle 0), then the side leaves
    // from the bottom up.
    let mut nodes = vec![bvh::BvhWideNode::default(); 4 * depth + 1];
    for d in 0..depth {
        let at = 4 * d;
        nodes[at].set_slot(0, &slot((at + 4) as u32, INNER));
        for k in 1..4 {
            nodes[at].set_slot(k, &slot((at + k) as u32, INNER));
            let first = 3 * (depth - 1 - d) + k;
            nodes[at + k].set_slot(0, &slot(first as u32, 1));
        }
    }
    nodes[4 * depth].set_slot(0, &slot(0, 1));
    let triangles = (0..n)
        .map(|i| {
            let [a, b, c] = mesh.indices[i].map(|k| mesh.positions[k as usize]);
            bvh::BvhTriangle::new(a, b, c, i as u32)
        })
        .collect();
    let tree = WideBvh { nodes, triangles };
    // Well-formed except for the depth-first order of the triangles, which the traversal
    // does not rely on.
    assert_eq!(walk_wide(&tree, 0, 0, &mut vec![false; tree.nodes.len()]), depth as u32);

    let mut rng = Rng::new(13);
    let mut rays = Vec::new();
    for i in 0..n {
        let z = 1.0 + (n - 1 - i) as f32 / 100.0;
        let [x, y, _] = rng.point([-0.9; 3], [0.9; 3]);
        rays.push(ray([x, y, z - 0.005], [0.0, 0.0, 1.0], f32::INFINITY));
        rays.push(ray([x, y, z + 0.005], normalize([rng.range(-0.2, 0.2), rng.range(-0.2, 0.2), -1.0]), f32::INFINITY));
    }
    let results = with_gpu(|ctx| {
        let bufs = tree.upload(ctx).unwrap();
        run_trace(ctx, &pipeline(ctx, BvhLayout::Wide), &bufs, &rays)
    });
    check_against_cpu("deepest wide tree", &mesh, &rays, &results);
    for (k, g) in results.iter().enumerate() {
        assert_eq!(g.hit.prim, k as u32 / 2, "ray {k}: {:?}", rays[k]);
    }
}

/// Walks a compressed tree: every node reached once; every child's box (in exact
/// arithmetic) contains every triangle below it, taken from the input vertices; leaves
/// of 1 to 3 triangles; every triangle in exactly one leaf. Returns the depth of the
/// deepest inner node.
fn check_cw_well_formed(name: &str, mesh: &Mesh, tree: &CwBvh) -> u32 {
    assert_eq!(tree.triangles.len(), mesh.indices.len(), "{name}: every triangle once");
    let mut seen_nodes = vec![false; tree.nodes.len()];
    let mut seen_tris = vec![false; tree.triangles.len()];
    let mut deepest = 0;
    let mut stack = vec![(0u32, 0u32)];
    let inside = |p: [f32; 3], b: &([f64; 3], [f64; 3])| (0..3).all(|k| b.0[k] <= f64::from(p[k]) && f64::from(p[k]) <= b.1[k]);
    while let Some((n, depth)) = stack.pop() {
        assert!(!seen_nodes[n as usize], "{name}: node {n} reached twice");
        seen_nodes[n as usize] = true;
        deepest = deepest.max(depth);
        let node = &tree.nodes[n as usize];
        for c in 0..8 {
            let Some((index, count)) = node.child(c) else { continue };
            let b = node.child_box(c);
            if count == INNER {
                assert!(index > n, "{name}: inner child {index} after its parent {n}");
                stack.push((index, depth + 1));
                // The child's box contains every triangle below it.
                let mut below = vec![index];
                while let Some(m) = below.pop() {
                    let mn = &tree.nodes[m as usize];
                    for cc in 0..8 {
                        match mn.child(cc) {
                            Some((i, INNER)) => below.push(i),
                            Some((first, count)) => {
                                for t in &tree.triangles[first as usize..(first + count) as usize] {
                                    for v in mesh.indices[t.prim as usize] {
                                        assert!(
                                            inside(mesh.positions[v as usize], &b),
                                            "{name}: node {n} child {c} misses a vertex below it: {:?} not in {b:?}, node {node:?} sub {m}",
                                            mesh.positions[v as usize]
                                        );
                                    }
                                }
                            }
                            None => {}
                        }
                    }
                }
            } else {
                assert!((1..=3).contains(&count), "{name}: leaf of {count} triangles");
                for i in index..index + count {
                    assert!(!seen_tris[i as usize], "{name}: triangle {i} in two leaves");
                    seen_tris[i as usize] = true;
                    let t = &tree.triangles[i as usize];
                    for v in mesh.indices[t.prim as usize] {
                        assert!(inside(mesh.positions[v as usize], &b), "{name}: leaf box misses a vertex of triangle {}", t.prim);
                    }
                }
            }
        }
    }
    assert!(seen_tris.iter().all(|&s| s), "{name}: every triangle in a leaf");
    let mut prims: Vec<u32> = tree.triangles.iter().map(|t| t.prim).collect();
    prims.sort_unstable();
    assert!(prims.iter().enumerate().all(|(i, &p)| p == i as u32), "{name}: the input triangles, each once");
    deepest
}

#[test]
fn compressed_bvh_is_well_formed_and_traces_like_the_reference() {
    let mut one = Mesh::default();
    one.push([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let cases = [("one triangle", one), ("soup", soup(3000, 21)), ("cornell", scene_mesh("cornell")), ("spiral", scene_mesh("spiral"))];
    let mut trees = Vec::new();
    for (name, mesh) in &cases {
        let tree = CwBvh::build(&mesh.positions, &mesh.indices);
        let depth = check_cw_well_formed(name, mesh, &tree);
        assert!(depth <= CW_STACK_SIZE, "{name}: depth {depth}");
        assert_eq!(depth, tree.depth(), "{name}");
        // Converted from the flattened binary tree (vertex boxes from the stored edges).
        check_cw_well_formed(name, mesh, &CwBvh::from_binary(&bvh::build(&mesh.positions, &mesh.indices)));
        if *name == "soup" {
            assert!(tree.nodes.len() * 8 < mesh.indices.len() * 2, "soup: {} nodes for {} triangles: wide nodes", tree.nodes.len(), mesh.indices.len());
        }
        trees.push(tree);
    }
    // A tree whose obvhs build is far deeper than the stack: triangles shrinking
    // geometrically towards a point. The build retries with smaller binary depth limits.
    let mut deep = Mesh::default();
    for i in 0..400 {
        let s = 0.9f32.powi(i);
        deep.push([[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s]]);
    }
    let tree = CwBvh::build(&deep.positions, &deep.indices);
    assert!(check_cw_well_formed("nested", &deep, &tree) <= CW_STACK_SIZE);

    // Built from the input vertices (as the renderer builds it), traced against the
    // reference.
    let soup_rays = random_rays(&cases[1].1, [-1.2; 3], [1.2; 3], 3001, 22);
    let deep_rays = random_rays(&deep, [-0.2; 3], [1.2; 3], 2001, 23);
    let (soup_results, deep_results) = with_gpu(|ctx| {
        let pipe = pipeline(ctx, BvhLayout::Cw8);
        (run_trace(ctx, &pipe, &trees[1].upload(ctx).unwrap(), &soup_rays), run_trace(ctx, &pipe, &tree.upload(ctx).unwrap(), &deep_rays))
    });
    let borderline = check_against_cpu("soup cw8 build", &cases[1].1, &soup_rays, &soup_results);
    assert!(borderline * 50 < soup_rays.len(), "{borderline} borderline rays");
    check_against_cpu("nested cw8 build", &deep, &deep_rays, &deep_results);
    let hits = deep_results.iter().filter(|r| r.hit.prim != NO_HIT).count();
    assert!(hits > deep_rays.len() / 10, "nested: {hits} hits");
}

/// The compressed layout's register stack (`BVH_STACK_REGISTERS`, for trees of inner depth
/// at most `CW_STACK_REGISTERS`): on a tree of exactly that depth, where the stack fills
/// every register, it traces every ray as the array stack does (the same nodes in the same
/// order: identical results) and as the reference; and the renderer picks it exactly for
/// such trees.
#[test]
fn register_stack_traces_shallow_trees_like_the_array_stack() {
    use vkinverse::bvh::CW_STACK_REGISTERS;
    use vkinverse::gpu::SpecValue;
    // The smallest soup whose tree reaches the registers' depth.
    let (mesh, tree) = [300, 600, 1200, 2400, 4800, 9600]
        .into_iter()
        .map(|n| {
            let mesh = soup(n, 31);
            let tree = CwBvh::build(&mesh.positions, &mesh.indices);
            (mesh, tree)
        })
        .find(|(_, t)| t.depth() == CW_STACK_REGISTERS)
        .expect("a soup whose compressed tree has the registers' depth");
    let rays = random_rays(&mesh, [-1.2; 3], [1.2; 3], 3001, 32);
    let (array, registers) = with_gpu(|ctx| {
        let bufs = tree.upload(ctx).unwrap();
        assert_eq!(bufs.stack_entries, CW_STACK_REGISTERS);
        let regs = ComputePipeline::new(ctx, &BvhLayout::Cw8.kernel("trace_test"), &[("BVH_STACK_REGISTERS", SpecValue::Bool(true))]).unwrap();
        (run_trace(ctx, &pipeline(ctx, BvhLayout::Cw8), &bufs, &rays), run_trace(ctx, &regs, &bufs, &rays))
    });
    let borderline = check_against_cpu("register stack", &mesh, &rays, &registers);
    assert!(borderline * 50 < rays.len(), "{borderline} borderline rays");
    for (i, (a, r)) in array.iter().zip(&registers).enumerate() {
        assert_eq!(
            (a.hit.prim, a.hit.t.to_bits(), a.any_hit),
            (r.hit.prim, r.hit.t.to_bits(), r.any_hit),
            "ray {i}: array stack {:?}, registers {:?}",
            a.hit,
            r.hit
        );
    }
    // The renderer's choice, on the Cornell box's shallow tree.
    let (entries, on) = with_gpu(|ctx| {
        let gs = vkinverse::render::GpuScene::with_bvh_layout(ctx, &cornell_scene(), BvhLayout::Cw8).unwrap();
        let on = gs.spec().iter().find(|(n, _)| *n == "BVH_STACK_REGISTERS").map(|(_, v)| matches!(v, SpecValue::Bool(true)));
        (gs.bvh().stack_entries, on)
    });
    assert!(entries <= CW_STACK_REGISTERS && on == Some(true), "cornell: {entries} entries, registers {on:?}");
}
