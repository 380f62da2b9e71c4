//! The scene BVH: built on the CPU with obvhs (PLOC, Meister & Bittner 2018, plus
//! reinsertion and SAH leaf collapsing), flattened into the GPU layout of
//! `glsl/shared/bvh.glsl` and traced by `glsl/lib/bvh_traverse.glsl`.
//!
//! The layout is a binary BVH whose inner nodes hold the boxes of both children (Aila &
//! Laine 2009): one node fetch tests two boxes, and leaves live in their parent's child
//! slot instead of in nodes of their own. Invariants of a [`Bvh`] from [`build`]:
//! - there is at least one node; node 0 is the root, and every inner child has a larger
//!   index than its parent (depth-first order, left subtree first);
//! - every inner node is at depth `<= STACK_SIZE` (root at depth 0), which bounds the
//!   traversal stack; deeper subtrees of the obvhs tree are rebuilt as balanced trees over
//!   their leaves;
//! - every input triangle is in exactly one leaf; `triangles` is in leaf order, and a leaf
//!   is the range `index .. index + count` of it;
//! - a child's box contains everything below it, boxes coming straight from the input
//!   vertices (min/max are exact in f32);
//! - an empty child (count 0) has the box min = max = +inf, which no ray enters. Only the
//!   root can have one: when the scene has fewer than two leaves.
//!
//! The kernels can also trace a wide layout ([`BvhLayout::Wide`], [`WideBvh`]): 4-ary
//! nodes made from the binary tree by pulling descendants up into a node's four slots;
//! and a compressed 8-wide layout ([`BvhLayout::Cw8`], [`CwBvh`], module `cw`). Leaves and the triangle array are the binary tree's; wide inner nodes are at
//! depth `<= STACK_SIZE / 2`, which bounds the wide traversal's stack by
//! [`WIDE_STACK_SIZE`]. [`BvhLayout::default`] is the layout the renderer uses.

use std::ops::Range;
use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use obvhs::aabb::Aabb;
use obvhs::bvh2::leaf_collapser::collapse;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;
use obvhs::ploc::PlocBuilder;
use obvhs::BvhBuildParams;

use crate::gpu::{self, Buffer, Context, MemoryKind};

mod cw;
pub use cw::{BvhCwNode, CwBvh, CW_STACK_REGISTERS, CW_STACK_SIZE};

/// Entries of the GPU traversal stack (`BVH_STACK_SIZE` in glsl/shared/bvh.glsl, compared
/// by a test): [`build`] keeps every inner node at depth `<= STACK_SIZE`.
pub const STACK_SIZE: u32 = 64;

/// Entries of the wide traversal stack (`BVH_WIDE_STACK_SIZE`): a wide node pushes at most
/// 3 children, and only nodes at depth `< STACK_SIZE / 2` have inner children.
pub const WIDE_STACK_SIZE: u32 = 3 * (STACK_SIZE / 2);

/// Hits at `t <= T_MIN` are ignored (`BVH_T_MIN` in glsl/shared/bvh.glsl, compared by a
/// test); see the policy in glsl/lib/bvh_traverse.glsl.
pub const T_MIN: f32 = 1e-4;

/// Child count marking an inner node (`BVH_INNER`).
pub const INNER: u32 = u32::MAX;

/// `Hit::prim` of a miss (`BVH_NO_HIT`).
pub const NO_HIT: u32 = u32::MAX;

/// Mirror of `BvhNode` (glsl/shared/bvh.glsl): 64 bytes, an inner node holding both
/// children's boxes. A child with count [`INNER`] is the node at `index`; any other count
/// is a leaf of that many triangles from `index`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BvhNode {
    pub left_min: [f32; 3],
    pub left_index: u32,
    pub left_max: [f32; 3],
    pub left_count: u32,
    pub right_min: [f32; 3],
    pub right_index: u32,
    pub right_max: [f32; 3],
    pub right_count: u32,
}

/// One child slot of a [`BvhNode`], as read by [`BvhNode::children`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BvhChild {
    pub min: [f32; 3],
    pub max: [f32; 3],
    pub index: u32,
    pub count: u32,
}

impl BvhChild {
    pub fn is_inner(&self) -> bool {
        self.count == INNER
    }
}

impl BvhNode {
    /// The left and right child slots.
    pub fn children(&self) -> [BvhChild; 2] {
        [
            BvhChild { min: self.left_min, max: self.left_max, index: self.left_index, count: self.left_count },
            BvhChild { min: self.right_min, max: self.right_max, index: self.right_index, count: self.right_count },
        ]
    }

    fn set_child(&mut self, side: usize, index: u32, count: u32) {
        if side == 0 {
            self.left_index = index;
            self.left_count = count;
        } else {
            self.right_index = index;
            self.right_count = count;
        }
    }

    fn set_box(&mut self, side: usize, b: &Bounds) {
        if side == 0 {
            self.left_min = b.min;
            self.left_max = b.max;
        } else {
            self.right_min = b.min;
            self.right_max = b.max;
        }
    }
}

/// Mirror of `BvhWideNode` (glsl/shared/bvh.glsl): 128 bytes, the four child slots of a
/// wide node as structure of arrays (element `k` of each array is slot `k`). A slot with
/// count [`INNER`] is the wide node at `index`, count 0 is empty (box min = max = +inf),
/// any other count a leaf of that many triangles from `index`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct BvhWideNode {
    pub min_x: [f32; 4],
    pub min_y: [f32; 4],
    pub min_z: [f32; 4],
    pub max_x: [f32; 4],
    pub max_y: [f32; 4],
    pub max_z: [f32; 4],
    pub index: [u32; 4],
    pub count: [u32; 4],
}

impl Default for BvhWideNode {
    /// Four empty slots.
    fn default() -> Self {
        let inf = [f32::INFINITY; 4];
        Self { min_x: inf, min_y: inf, min_z: inf, max_x: inf, max_y: inf, max_z: inf, index: [0; 4], count: [0; 4] }
    }
}

impl BvhWideNode {
    /// Slot `k`.
    pub fn slot(&self, k: usize) -> BvhChild {
        BvhChild {
            min: [self.min_x[k], self.min_y[k], self.min_z[k]],
            max: [self.max_x[k], self.max_y[k], self.max_z[k]],
            index: self.index[k],
            count: self.count[k],
        }
    }

    /// The four slots.
    pub fn slots(&self) -> [BvhChild; 4] {
        std::array::from_fn(|k| self.slot(k))
    }

    /// Sets slot `k`.
    pub fn set_slot(&mut self, k: usize, c: &BvhChild) {
        [self.min_x[k], self.min_y[k], self.min_z[k]] = c.min;
        [self.max_x[k], self.max_y[k], self.max_z[k]] = c.max;
        self.index[k] = c.index;
        self.count[k] = c.count;
    }
}

/// Mirror of `BvhTriangle`: 48 bytes, a triangle as `v0`, `e1 = v1 - v0`, `e2 = v2 - v0`
/// (Möller & Trumbore 1997) and its index in the input triangle list.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BvhTriangle {
    pub v0: [f32; 3],
    pub e1: [f32; 3],
    pub e2: [f32; 3],
    pub prim: u32,
    /// 0, or 1 + the material whose alpha test a hit on the triangle must pass (set by
    /// [`build_as`] from its `alpha_material` list; the traversal kernels test it).
    pub alpha_material: u32,
    /// Zero: pads the record to three 16-byte texels (kernels read it from a texel buffer).
    pub pad: u32,
}

impl BvhTriangle {
    /// The triangle (a, b, c) with input index `prim`.
    pub fn new(a: [f32; 3], b: [f32; 3], c: [f32; 3], prim: u32) -> Self {
        let sub = |p: [f32; 3], q: [f32; 3]| [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
        BvhTriangle { v0: a, e1: sub(b, a), e2: sub(c, a), prim, alpha_material: 0, pad: 0 }
    }
}

/// Mirror of `Hit`: 16 bytes. `prim` is the input triangle index ([`NO_HIT`] for a miss),
/// `u` and `v` the barycentric weights of v1 and v2.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Hit {
    pub t: f32,
    pub prim: u32,
    pub u: f32,
    pub v: f32,
}

/// Mirror of `TraceRay`: 28 bytes, one ray of the `trace_test` kernel.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TraceRay {
    pub origin: [f32; 3],
    pub tmax: f32,
    pub dir: [f32; 3],
}

/// Mirror of `TraceResult`: 20 bytes, what `trace_test` writes per ray (`any_hit` is 0/1).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TraceResult {
    pub hit: Hit,
    pub any_hit: u32,
}

/// A flattened BVH; see the module documentation for its invariants.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    pub nodes: Vec<BvhNode>,
    pub triangles: Vec<BvhTriangle>,
}

/// Node layout of the BVH on the device: which nodes the buffers hold and which build of
/// the kernels traces them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BvhLayout {
    /// [`BvhNode`]: binary, both children's boxes in the parent.
    Binary,
    /// [`BvhWideNode`]: 4-ary, kernels built with `BVH_WIDE` (suffix `_wide`).
    Wide,
    /// [`BvhCwNode`]: compressed 8-ary (Ylitie et al. 2017), kernels built with `BVH_CW8`
    /// (suffix `_cw8`). The default: the fastest on lavapipe at 256x256 (experiments/lavapipe-speed.md,
    /// `vkinverse bench SCENE --bvh-layouts`).
    #[default]
    Cw8,
}

impl BvhLayout {
    pub const ALL: [BvhLayout; 3] = [BvhLayout::Binary, BvhLayout::Wide, BvhLayout::Cw8];

    /// Whether the traversal of these buffers keeps its stack in registers
    /// (`BVH_STACK_REGISTERS`): the compressed layout's, where its stack never holds more than
    /// [`CW_STACK_REGISTERS`] entries, unless `array` asks for the array (to measure one
    /// against the other, or on a device where the array measures faster:
    /// [`crate::Config::bvh_stack_array`]).
    pub fn stack_in_registers(bufs: &BvhBuffers, array: bool) -> bool {
        bufs.layout == BvhLayout::Cw8 && bufs.stack_entries <= CW_STACK_REGISTERS && !array
    }

    /// The name of the build of `kernel` (e.g. `trace_primal`) that traces this layout.
    pub fn kernel(self, kernel: &str) -> String {
        match self {
            BvhLayout::Binary => kernel.to_string(),
            BvhLayout::Wide => format!("{kernel}_wide"),
            BvhLayout::Cw8 => format!("{kernel}_cw8"),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            BvhLayout::Binary => "binary",
            BvhLayout::Wide => "wide",
            BvhLayout::Cw8 => "cw8",
        }
    }
}

impl std::str::FromStr for BvhLayout {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "binary" => Ok(BvhLayout::Binary),
            "wide" => Ok(BvhLayout::Wide),
            "cw8" => Ok(BvhLayout::Cw8),
            _ => Err(format!("unknown BVH layout '{s}' (binary, wide or cw8)")),
        }
    }
}

/// The device buffers of a [`Bvh`] or [`WideBvh`].
pub struct BvhBuffers {
    pub layout: BvhLayout,
    pub nodes: Buffer,
    pub triangles: Buffer,
    /// The most entries the traversal stack holds on this tree: the compressed layout's inner
    /// depth (each push is one level deeper than the entries below it); the stack's size in
    /// the other layouts.
    pub stack_entries: u32,
}

impl BvhBuffers {
    /// (GLSL block name, buffer) of each buffer that glsl/lib/bvh_traverse.glsl declares, to
    /// add to the bind list of any kernel that includes it.
    pub fn bindings(&self) -> [(&'static str, &Buffer); 2] {
        [("BvhNodes", &self.nodes), ("BvhTriangles", &self.triangles)]
    }
}

impl Bvh {
    /// Copies the nodes and triangles to device-local buffers.
    pub fn upload(&self, ctx: &Arc<Context>) -> gpu::Result<BvhBuffers> {
        Ok(BvhBuffers {
            layout: BvhLayout::Binary,
            nodes: Buffer::from_slice(ctx, "bvh nodes", &self.nodes, MemoryKind::Device)?,
            triangles: Buffer::from_slice(ctx, "bvh triangles", &self.triangles, MemoryKind::Device)?,
            stack_entries: STACK_SIZE,
        })
    }

    /// Uploads the tree in `layout`. The compressed layout fails if its tree is deeper than
    /// its traversal stack ([`CW_STACK_SIZE`]); [`build_as`] avoids that.
    pub fn upload_as(&self, ctx: &Arc<Context>, layout: BvhLayout) -> gpu::Result<BvhBuffers> {
        match layout {
            BvhLayout::Binary => self.upload(ctx),
            BvhLayout::Wide => WideBvh::from_binary(self).upload(ctx),
            BvhLayout::Cw8 => {
                let cw = CwBvh::from_binary(self);
                if cw.depth() > CW_STACK_SIZE {
                    return Err(gpu::GpuError::BufferAccess {
                        name: "bvh cw8 nodes".into(),
                        what: format!("tree depth {} exceeds the traversal stack ({CW_STACK_SIZE})", cw.depth()),
                    });
                }
                cw.upload(ctx)
            }
        }
    }
}

/// Builds the BVH of the triangles `indices` over `positions` (finite coordinates) in
/// `layout` and uploads it. `alpha_material[i]` (where the list is long enough) is 0 or
/// 1 + the material whose alpha test hits on triangle i must pass
/// ([`BvhTriangle::alpha_material`]); an empty list: none.
///
/// # Panics
/// If an index is out of bounds of `positions`.
pub fn build_as(ctx: &Arc<Context>, positions: &[[f32; 3]], indices: &[[u32; 3]], alpha_material: &[u32], layout: BvhLayout) -> gpu::Result<BvhBuffers> {
    let mark = |triangles: &mut [BvhTriangle]| {
        for t in triangles {
            t.alpha_material = alpha_material.get(t.prim as usize).copied().unwrap_or(0);
        }
    };
    match layout {
        BvhLayout::Cw8 => {
            let mut cw = CwBvh::build(positions, indices);
            mark(&mut cw.triangles);
            cw.upload(ctx)
        }
        _ => {
            let mut bvh = build(positions, indices);
            mark(&mut bvh.triangles);
            bvh.upload_as(ctx, layout)
        }
    }
}

/// A BVH in the wide layout. Invariants of one from [`WideBvh::from_binary`] of a [`Bvh`]
/// from [`build`] (or [`build_with_depth_limit`] with limit `L`):
/// - there is at least one node; node 0 is the root, every inner child has a larger index
///   than its parent (depth-first order);
/// - every wide node is a binary inner node `b`. Its slots start as `b`'s two children;
///   while there are fewer than 4, the shallowest inner slot (of equally deep ones, the
///   one with the largest box surface) is replaced by its two children; slots left over
///   are empty. Both of `b`'s children are inner or one is a leaf, so after at most two
///   replacements every inner slot is at least two binary levels below `b`: a wide node
///   at depth `d` is a binary inner node at depth `>= 2d`, and every wide inner node is
///   at depth `<= STACK_SIZE / 2` (`<= L / 2`);
/// - leaves, boxes and `triangles` are the binary tree's: every leaf child there is a leaf
///   slot here with the same range and box; only the binary root's empty child is dropped.
#[derive(Clone, Debug, Default)]
pub struct WideBvh {
    pub nodes: Vec<BvhWideNode>,
    pub triangles: Vec<BvhTriangle>,
}

impl WideBvh {
    /// Collapses a binary tree (see the type's invariants).
    pub fn from_binary(bvh: &Bvh) -> WideBvh {
        let mut out = WideBvh { nodes: Vec::with_capacity(bvh.nodes.len() / 2 + 1), triangles: bvh.triangles.clone() };
        let area = |c: &BvhChild| {
            let e: [f32; 3] = std::array::from_fn(|k| c.max[k] - c.min[k]);
            e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
        };
        // (binary node, wide parent and slot to point at it); the root has no parent.
        // LIFO with the first slot pushed last: depth-first order.
        let mut tasks: Vec<(u32, Option<(usize, usize)>)> = vec![(0, None)];
        while let Some((b, parent)) = tasks.pop() {
            let at = out.nodes.len();
            if let Some((p, k)) = parent {
                out.nodes[p].index[k] = at as u32;
            }
            // (child, binary levels below b).
            let mut slots: Vec<(BvhChild, u32)> = bvh.nodes[b as usize].children().into_iter().filter(|c| c.count != 0).map(|c| (c, 1)).collect();
            while slots.len() < 4 {
                let Some(open) = (0..slots.len())
                    .filter(|&i| slots[i].0.is_inner())
                    .min_by(|&i, &j| slots[i].1.cmp(&slots[j].1).then(area(&slots[j].0).total_cmp(&area(&slots[i].0))))
                else {
                    break;
                };
                let (c, level) = slots[open];
                let children = bvh.nodes[c.index as usize].children().into_iter().filter(|g| g.count != 0).map(|g| (g, level + 1));
                slots.splice(open..=open, children);
            }
            let mut node = BvhWideNode::default();
            for (k, (c, _)) in slots.iter().enumerate() {
                node.set_slot(k, c);
            }
            out.nodes.push(node);
            for (k, (c, _)) in slots.iter().enumerate().rev() {
                if c.is_inner() {
                    tasks.push((c.index, Some((at, k))));
                }
            }
        }
        out
    }

    /// Copies the nodes and triangles to device-local buffers.
    pub fn upload(&self, ctx: &Arc<Context>) -> gpu::Result<BvhBuffers> {
        Ok(BvhBuffers {
            layout: BvhLayout::Wide,
            nodes: Buffer::from_slice(ctx, "bvh wide nodes", &self.nodes, MemoryKind::Device)?,
            triangles: Buffer::from_slice(ctx, "bvh triangles", &self.triangles, MemoryKind::Device)?,
            stack_entries: WIDE_STACK_SIZE,
        })
    }
}

/// Builds the BVH of the triangles `indices` over `positions` (finite coordinates).
///
/// # Panics
/// If an index is out of bounds of `positions`.
pub fn build(positions: &[[f32; 3]], indices: &[[u32; 3]]) -> Bvh {
    build_with_depth_limit(positions, indices, STACK_SIZE)
}

/// [`build`] with inner nodes at depth `<= max_depth` instead of [`STACK_SIZE`], for
/// kernels with a smaller stack. Subtrees too deep for the limit are rebuilt as balanced
/// trees over their leaves; when even that does not fit (leaves hang at depth
/// `<= max_depth + 1`, so there is room for `2^(max_depth + 1)` of them), the lowest leaves
/// are merged.
///
/// # Panics
/// If an index is out of bounds of `positions`.
pub fn build_with_depth_limit(positions: &[[f32; 3]], indices: &[[u32; 3]], max_depth: u32) -> Bvh {
    let boxes: Vec<Aabb> = indices
        .iter()
        .map(|tri| {
            let b = triangle_bounds(positions, tri);
            Aabb::new(b.min.into(), b.max.into())
        })
        .collect();
    let bvh2 = build_bvh2(&boxes);
    Flattener::new(&bvh2, positions, indices, max_depth).run()
}

/// PLOC, reinsertion and leaf collapsing with obvhs's medium preset (its `build_bvh2`
/// without the debug-build validation, which panics on trees deeper than its own limit;
/// the depth is handled by the flattening here).
fn build_bvh2(boxes: &[Aabb]) -> Bvh2 {
    let params = BvhBuildParams::medium_build();
    let mut bvh2 = PlocBuilder::with_capacity(boxes.len()).build(
        params.ploc_search_distance,
        boxes,
        (0..boxes.len() as u32).collect(),
        params.sort_precision,
        params.search_depth_threshold,
    );
    let mut reinsertion = ReinsertionOptimizer::default();
    reinsertion.run(&mut bvh2, params.reinsertion_batch_ratio, None);
    collapse(&mut bvh2, params.max_prims_per_leaf.clamp(1, 255), params.collapse_traversal_cost);
    reinsertion.run(&mut bvh2, params.reinsertion_batch_ratio * params.post_collapse_reinsertion_batch_ratio_multiplier, None);
    bvh2
}

/// An axis-aligned box; empty when min > max.
#[derive(Clone, Copy, Debug)]
struct Bounds {
    min: [f32; 3],
    max: [f32; 3],
}

impl Bounds {
    const EMPTY: Self = Self { min: [f32::INFINITY; 3], max: [f32::NEG_INFINITY; 3] };

    fn grow(&mut self, p: [f32; 3]) {
        self.min = std::array::from_fn(|k| self.min[k].min(p[k]));
        self.max = std::array::from_fn(|k| self.max[k].max(p[k]));
    }

    fn union(&mut self, other: &Bounds) {
        self.grow(other.min);
        self.grow(other.max);
    }

    fn is_empty(&self) -> bool {
        self.min[0] > self.max[0]
    }

    /// What an empty child stores: a point at +inf, whose slab interval is empty or starts
    /// at +inf for every ray, so the traversal never enters it.
    const NEVER_HIT: Self = Self { min: [f32::INFINITY; 3], max: [f32::INFINITY; 3] };
}

fn triangle_bounds(positions: &[[f32; 3]], tri: &[u32; 3]) -> Bounds {
    let mut b = Bounds::EMPTY;
    for &i in tri {
        b.grow(positions[i as usize]);
    }
    b
}

/// What a child slot is filled from.
enum Source {
    /// The subtree of an obvhs node.
    Node(u32),
    /// A balanced tree over `Flattener::leaves[range]` (obvhs leaf node ids, in order).
    Leaves(Range<usize>),
}

/// A child slot to fill: slot `side` of output node `parent`, at depth `depth`.
struct Task {
    source: Source,
    parent: usize,
    side: usize,
    depth: u32,
}

/// Turns an obvhs tree into the output layout, depth-first.
struct Flattener<'a> {
    src: &'a [Bvh2Node],
    prim_indices: &'a [u32],
    positions: &'a [[f32; 3]],
    indices: &'a [[u32; 3]],
    max_depth: u32,
    /// Leaves below each obvhs node.
    leaf_counts: Vec<u64>,
    /// Obvhs leaf ids referenced by `Source::Leaves` ranges.
    leaves: Vec<u32>,
    out: Bvh,
}

impl<'a> Flattener<'a> {
    fn new(bvh2: &'a Bvh2, positions: &'a [[f32; 3]], indices: &'a [[u32; 3]], max_depth: u32) -> Self {
        Self {
            src: &bvh2.nodes,
            prim_indices: &bvh2.primitive_indices,
            positions,
            indices,
            max_depth,
            leaf_counts: leaf_counts(&bvh2.nodes),
            leaves: Vec::new(),
            out: Bvh::default(),
        }
    }

    fn run(mut self) -> Bvh {
        let mut tasks = Vec::new();
        match self.src.first() {
            Some(root) if !root.is_leaf() => {
                // The obvhs root becomes node 0.
                let source = self.restructure(Source::Node(0), 0);
                self.inner(source, 0, &mut tasks);
            }
            root => {
                // The root is always an inner node: a single leaf (or none) hangs below it,
                // next to an empty child. Both children start as empty leaves (count 0).
                self.out.nodes.push(BvhNode::default());
                if root.is_some() {
                    tasks.push(Task { source: Source::Node(0), parent: 0, side: 0, depth: 1 });
                }
            }
        }
        // LIFO with the left child pushed last: each subtree is emitted whole before its
        // right sibling, so nodes and leaves come out in depth-first order.
        while let Some(task) = tasks.pop() {
            self.fill(task, &mut tasks);
        }
        self.compute_boxes();
        self.out
    }

    /// Fills one child slot: a leaf, or a new inner node whose children are queued.
    fn fill(&mut self, task: Task, tasks: &mut Vec<Task>) {
        let Task { source, parent, side, depth } = task;
        let source = self.restructure(source, depth);
        let (index, count) = match source {
            Source::Node(n) if self.src[n as usize].is_leaf() => {
                let first = self.out.triangles.len() as u32;
                self.append_leaf(n);
                (first, self.out.triangles.len() as u32 - first)
            }
            // One leaf, or no room for another inner node: the leaves become one leaf.
            Source::Leaves(range) if range.len() == 1 || depth > self.max_depth => {
                let first = self.out.triangles.len() as u32;
                for i in range {
                    self.append_leaf(self.leaves[i]);
                }
                (first, self.out.triangles.len() as u32 - first)
            }
            source => (self.inner(source, depth, tasks), INNER),
        };
        self.out.nodes[parent].set_child(side, index, count);
    }

    /// Keeps an obvhs inner node if both its children fit below `depth` (a leaf always
    /// does; an inner child fits if a balanced tree over its leaves would); otherwise its
    /// subtree becomes a balanced tree over its leaves. Top-down, this keeps the obvhs
    /// structure everywhere except in subtrees that are too deep.
    fn restructure(&mut self, source: Source, depth: u32) -> Source {
        let Source::Node(n) = source else { return source };
        let src = self.src;
        let node = &src[n as usize];
        if node.is_leaf() {
            return source;
        }
        let fits = |c: u32| src[c as usize].is_leaf() || u64::from(depth) + u64::from(ceil_log2(self.leaf_counts[c as usize])) <= u64::from(self.max_depth);
        if depth <= self.max_depth && fits(node.first_index) && fits(node.first_index + 1) {
            return source;
        }
        let start = self.leaves.len();
        let mut stack = vec![n];
        while let Some(m) = stack.pop() {
            let node = &src[m as usize];
            if node.is_leaf() {
                self.leaves.push(m);
            } else {
                stack.push(node.first_index + 1);
                stack.push(node.first_index);
            }
        }
        Source::Leaves(start..self.leaves.len())
    }

    /// Adds an inner node at `depth` built from `source` (an obvhs inner node or at least
    /// two leaves) and queues its children; returns its index.
    fn inner(&mut self, source: Source, depth: u32, tasks: &mut Vec<Task>) -> u32 {
        let at = self.out.nodes.len();
        self.out.nodes.push(BvhNode::default());
        let (left, right) = match source {
            Source::Node(n) => {
                let first = self.src[n as usize].first_index;
                (Source::Node(first), Source::Node(first + 1))
            }
            Source::Leaves(range) => {
                let mid = range.start + range.len() / 2;
                (Source::Leaves(range.start..mid), Source::Leaves(mid..range.end))
            }
        };
        tasks.push(Task { source: right, parent: at, side: 1, depth: depth + 1 });
        tasks.push(Task { source: left, parent: at, side: 0, depth: depth + 1 });
        at as u32
    }

    /// Appends the triangles of obvhs leaf `n`.
    fn append_leaf(&mut self, n: u32) {
        let node = &self.src[n as usize];
        let range = node.first_index as usize..(node.first_index + node.prim_count) as usize;
        let prim_indices = self.prim_indices;
        for &prim in &prim_indices[range] {
            let [a, b, c] = self.indices[prim as usize].map(|i| self.positions[i as usize]);
            self.out.triangles.push(BvhTriangle::new(a, b, c, prim));
        }
    }

    /// Sets every child box, bottom-up: children have larger indices than their parents.
    /// Leaf boxes come from the input vertices, not from v0 + e1 (which rounds).
    fn compute_boxes(&mut self) {
        for at in (0..self.out.nodes.len()).rev() {
            for (side, child) in self.out.nodes[at].children().into_iter().enumerate() {
                let mut b = Bounds::EMPTY;
                if child.is_inner() {
                    for grandchild in self.out.nodes[child.index as usize].children() {
                        if grandchild.count != 0 {
                            b.union(&Bounds { min: grandchild.min, max: grandchild.max });
                        }
                    }
                } else {
                    for tri in &self.out.triangles[child.index as usize..(child.index + child.count) as usize] {
                        b.union(&triangle_bounds(self.positions, &self.indices[tri.prim as usize]));
                    }
                }
                let b = if b.is_empty() { Bounds::NEVER_HIT } else { b };
                self.out.nodes[at].set_box(side, &b);
            }
        }
    }
}

/// ceil(log2(n)) for n >= 1: the depth of a balanced binary tree over n leaves.
fn ceil_log2(n: u64) -> u32 {
    if n <= 1 {
        0
    } else {
        64 - (n - 1).leading_zeros()
    }
}

/// Number of leaves below every node of an obvhs tree, without recursion (a PLOC tree of a
/// pathological scene can be deeper than the thread's stack allows).
fn leaf_counts(nodes: &[Bvh2Node]) -> Vec<u64> {
    if nodes.is_empty() {
        return Vec::new();
    }
    let mut order = Vec::with_capacity(nodes.len());
    let mut stack = vec![0u32];
    while let Some(n) = stack.pop() {
        order.push(n);
        let node = &nodes[n as usize];
        if !node.is_leaf() {
            stack.push(node.first_index);
            stack.push(node.first_index + 1);
        }
    }
    let mut counts = vec![0u64; nodes.len()];
    // Children come after their parent in pre-order, so the reverse visits them first.
    for &n in order.iter().rev() {
        let node = &nodes[n as usize];
        counts[n as usize] = if node.is_leaf() { 1 } else { counts[node.first_index as usize] + counts[node.first_index as usize + 1] };
    }
    counts
}

/// Möller–Trumbore in f64 for the CPU reference: (t, u, v) of the ray's intersection with
/// the triangle's plane, or `None` when the ray is parallel to it or the triangle is
/// degenerate. Whether the point lies inside is left to the caller.
pub fn moller_trumbore(v: [DVec3; 3], origin: DVec3, dir: DVec3) -> Option<(f64, f64, f64)> {
    let e1 = v[1] - v[0];
    let e2 = v[2] - v[0];
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv_det = 1.0 / det;
    let s = origin - v[0];
    let u = s.dot(p) * inv_det;
    let q = s.cross(e1);
    let w = dir.dot(q) * inv_det;
    let t = e2.dot(q) * inv_det;
    Some((t, u, w))
}

/// The closest hit of the ray among all triangles, by testing every one of them in f64
/// (no BVH): the reference the GPU traversal is checked against. Same policy as the GPU:
/// hits with `T_MIN < t < tmax` count, edges and vertices belong to the triangle, and a
/// tie goes to the lower triangle index.
///
/// # Panics
/// If an index is out of bounds of `positions`.
pub fn intersect_brute_force(positions: &[[f32; 3]], indices: &[[u32; 3]], origin: [f32; 3], dir: [f32; 3], tmax: f32) -> Option<Hit> {
    let o = DVec3::from(origin.map(f64::from));
    let d = DVec3::from(dir.map(f64::from));
    let mut best: Option<Hit> = None;
    let mut t_best = f64::from(tmax);
    for (prim, tri) in indices.iter().enumerate() {
        let v = tri.map(|i| DVec3::from(positions[i as usize].map(f64::from)));
        if let Some((t, u, w)) = moller_trumbore(v, o, d) {
            if u >= 0.0 && w >= 0.0 && u + w <= 1.0 && t > f64::from(T_MIN) && t < t_best {
                t_best = t;
                best = Some(Hit { t: t as f32, prim: prim as u32, u: u as f32, v: w as f32 });
            }
        }
    }
    best
}
