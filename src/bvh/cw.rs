//! The compressed 8-wide layout ([`BvhLayout::Cw8`]): the nodes of Ylitie, Karras &
//! Laine 2017, "Efficient incoherent ray traversal on GPUs through compressed wide BVHs",
//! as obvhs builds them (`CwBvhNode`, 80 bytes = 5 texels for eight children, against
//! 8 texels for the four children of [`BvhWideNode`](super::BvhWideNode)).
//!
//! A node stores its box origin `p`, a power-of-two scale per axis and each child's box
//! as 8-bit grid coordinates (`p + q * scale`); inner children are stored contiguously
//! from `child_base`, and the leaf children's triangles (at most 3 per leaf, 24 per node)
//! contiguously from `triangle_base`. Children sit in slots ordered by direction
//! (obvhs's octant ordering), so that a ray visits them roughly front to back without
//! sorting.
//!
//! The tree is obvhs's conversion (`bvh2_to_cwbvh`, a SAH cost over the collapses of a
//! binary tree) of the same binary tree the other layouts are made from, [`Bvh`], each of
//! its leaves first split into one-triangle leaves. Invariants of a [`CwBvh`] from
//! [`CwBvh::from_binary`]:
//! - at least one node; node 0 is the root;
//! - every child's grid box, in exact arithmetic, contains every triangle below it: the
//!   grid coordinates are widened after obvhs's quantisation until they do (its float
//!   quantisation can round a plane inwards by an ulp);
//! - inner nodes are at depth `<= CW_STACK_SIZE` (root at depth 0), which bounds the
//!   traversal stack (one entry per level): a tree that would be deeper is made from a
//!   binary tree built with a smaller depth limit;
//! - `triangles` holds every input triangle exactly once.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use obvhs::aabb::Aabb;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh;
use obvhs::cwbvh::node::CwBvhNode;

use super::{Bvh, BvhBuffers, BvhLayout, BvhTriangle, INNER};
use crate::gpu::{self, Buffer, Context, MemoryKind};

/// Entries of the compressed layout's traversal stack (`BVH_CW_STACK_SIZE` in
/// glsl/shared/bvh.glsl, compared by a test): one per level of inner nodes.
pub const CW_STACK_SIZE: u32 = 32;

/// Entries of the compressed layout's register stack (`BVH_CW_STACK_REGISTERS`): a tree of
/// at most this inner depth is traced with its stack in registers (`BVH_STACK_REGISTERS`,
/// [`crate::render::GpuScene::spec`]).
pub const CW_STACK_REGISTERS: u32 = 4;

/// Mirror of `BvhCwNode` (glsl/shared/bvh.glsl): 80 bytes, byte for byte obvhs's
/// `CwBvhNode`. `e_imask` packs the three scale exponents (bytes 0-2, the scale of axis k
/// is the float with exponent bits `e[k]`) and the mask of inner children (byte 3);
/// `meta` has one byte per child (0: empty; `001sssss`, s = 24 + slot: inner; else a leaf,
/// its triangle offset in the low 5 bits and its count in unary in the high 3);
/// `quant_x` holds the children's 8-bit min x (bytes 0-7) then max x (bytes 8-15), and so
/// on for y and z.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BvhCwNode {
    pub p: [f32; 3],
    pub e_imask: u32,
    pub child_base: u32,
    pub triangle_base: u32,
    pub meta: [u32; 2],
    pub quant_x: [u32; 4],
    pub quant_y: [u32; 4],
    pub quant_z: [u32; 4],
}

impl BvhCwNode {
    fn from_obvhs(n: &CwBvhNode) -> Self {
        bytemuck::cast(*n)
    }

    fn to_obvhs(self) -> CwBvhNode {
        bytemuck::cast(self)
    }

    /// Byte `b` of a little-endian word array.
    fn byte(words: &[u32], b: usize) -> u32 {
        (words[b / 4] >> (8 * (b % 4))) & 0xff
    }

    fn set_byte(words: &mut [u32], b: usize, v: u32) {
        let shift = 8 * (b % 4);
        words[b / 4] = (words[b / 4] & !(0xff << shift)) | ((v & 0xff) << shift);
    }

    /// The grid scale of each axis (a power of two, or 0 for exponent 0).
    pub fn scale(&self) -> [f32; 3] {
        std::array::from_fn(|k| f32::from_bits(((self.e_imask >> (8 * k)) & 0xff) << 23))
    }

    pub fn imask(&self) -> u32 {
        self.e_imask >> 24
    }

    /// The meta byte of child `c`.
    pub fn meta(&self, c: usize) -> u32 {
        Self::byte(&self.meta, c)
    }

    /// Child `c`'s grid box: (min, max) grid coordinates per axis.
    pub fn quantised(&self, c: usize) -> ([u32; 3], [u32; 3]) {
        let q = [&self.quant_x, &self.quant_y, &self.quant_z];
        (std::array::from_fn(|k| Self::byte(q[k], c)), std::array::from_fn(|k| Self::byte(q[k], 8 + c)))
    }

    fn set_quantised(&mut self, c: usize, lo: [u32; 3], hi: [u32; 3]) {
        let q = [&mut self.quant_x, &mut self.quant_y, &mut self.quant_z];
        for (k, words) in q.into_iter().enumerate() {
            Self::set_byte(words, c, lo[k]);
            Self::set_byte(words, 8 + c, hi[k]);
        }
    }

    /// Child `c`'s box in exact arithmetic (f64), (min, max).
    pub fn child_box(&self, c: usize) -> ([f64; 3], [f64; 3]) {
        let (lo, hi) = self.quantised(c);
        let s = self.scale();
        let at = |k: usize, q: u32| f64::from(self.p[k]) + f64::from(q) * f64::from(s[k]);
        (std::array::from_fn(|k| at(k, lo[k])), std::array::from_fn(|k| at(k, hi[k])))
    }

    /// What child `c` is: `None` if empty, else `Some((index, count))` with count
    /// [`INNER`] for the inner node at `index`, or a leaf of `count` triangles from `index`.
    pub fn child(&self, c: usize) -> Option<(u32, u32)> {
        let m = self.meta(c);
        if m == 0 {
            return None;
        }
        if m & 0x18 == 0x18 {
            let below = self.imask() & ((1u32 << c) - 1);
            Some((self.child_base + below.count_ones(), INNER))
        } else {
            Some((self.triangle_base + (m & 31), (m >> 5).count_ones()))
        }
    }
}

/// A BVH in the compressed 8-wide layout; see the module documentation.
#[derive(Clone, Debug, Default)]
pub struct CwBvh {
    pub nodes: Vec<BvhCwNode>,
    pub triangles: Vec<BvhTriangle>,
}

/// A box containing a triangle stored as v0 and two rounded edges (`e = v - v0` rounded
/// to f32, so off by at most half an ulp of e): v0 + e in f64, widened by that error and
/// rounded outwards to f32.
fn triangle_box(t: &BvhTriangle) -> ([f32; 3], [f32; 3]) {
    let mut lo = t.v0;
    let mut hi = t.v0;
    for e in [t.e1, t.e2] {
        for k in 0..3 {
            let v = f64::from(t.v0[k]) + f64::from(e[k]);
            let err = f64::from(e[k]).abs() * f64::from(f32::EPSILON);
            lo[k] = lo[k].min(((v - err) as f32).next_down());
            hi[k] = hi[k].max(((v + err) as f32).next_up());
        }
    }
    (lo, hi)
}

/// Exact-arithmetic box of the input triangle, from its input vertices.
fn input_box(positions: &[[f32; 3]], tri: &[u32; 3]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &i in tri {
        for k in 0..3 {
            lo[k] = lo[k].min(positions[i as usize][k]);
            hi[k] = hi[k].max(positions[i as usize][k]);
        }
    }
    (lo, hi)
}

/// Balanced binary subtree of one-triangle leaves over `range` (triangle indices of the
/// flattened tree) appended to `nodes` at `at`.
fn push_leaves(nodes: &mut Vec<Bvh2Node>, at: usize, range: std::ops::Range<u32>, boxes: &[Aabb]) {
    let mut tasks = vec![(at, range)];
    while let Some((at, range)) = tasks.pop() {
        if range.len() == 1 {
            nodes[at] = Bvh2Node::new(boxes[range.start as usize], 1, range.start);
            continue;
        }
        let mid = range.start + range.len() as u32 / 2;
        let first = nodes.len();
        nodes.push(Bvh2Node::default());
        nodes.push(Bvh2Node::default());
        nodes[at] = Bvh2Node::new(Aabb::INVALID, 0, first as u32);
        tasks.push((first, range.start..mid));
        tasks.push((first + 1, mid..range.end));
    }
}

/// The flattened binary tree as an obvhs tree of one-triangle leaves (what its
/// conversion expects); primitive i is `bvh.triangles[i]`.
fn to_bvh2(bvh: &Bvh, boxes: &[Aabb]) -> Bvh2 {
    let mut nodes = vec![Bvh2Node::default()];
    // (binary node, obvhs node to fill); obvhs siblings are adjacent.
    let mut tasks = vec![(0u32, 0usize)];
    let mut root_leaf = None;
    while let Some((b, at)) = tasks.pop() {
        let children: Vec<_> = bvh.nodes[b as usize].children().into_iter().filter(|c| c.count != 0).collect();
        if children.len() == 1 {
            // Only the root has an empty child; its one child becomes the root.
            let c = children[0];
            if c.is_inner() {
                tasks.push((c.index, at));
            } else {
                root_leaf = Some(c.index..c.index + c.count);
            }
            continue;
        }
        let first = nodes.len();
        nodes.push(Bvh2Node::default());
        nodes.push(Bvh2Node::default());
        nodes[at] = Bvh2Node::new(Aabb::INVALID, 0, first as u32);
        for (k, c) in children.iter().enumerate() {
            if c.is_inner() {
                tasks.push((c.index, first + k));
            } else {
                push_leaves(&mut nodes, first + k, c.index..c.index + c.count, boxes);
            }
        }
    }
    if let Some(range) = root_leaf {
        push_leaves(&mut nodes, 0, range, boxes);
    }
    // Inner boxes bottom-up from the leaves' (children come after their parents), so
    // that every box contains the triangle boxes below it exactly.
    for n in (0..nodes.len()).rev() {
        if nodes[n].prim_count == 0 {
            let first = nodes[n].first_index as usize;
            let b = nodes[first].aabb().union(nodes[first + 1].aabb());
            nodes[n] = Bvh2Node::new(b, 0, first as u32);
        }
    }
    Bvh2 { nodes, primitive_indices: (0..bvh.triangles.len() as u32).collect(), ..Default::default() }
}

/// Depth of the deepest inner node (root at 0).
fn inner_depth(nodes: &[BvhCwNode]) -> u32 {
    let mut deepest = 0;
    let mut stack = vec![(0u32, 0u32)];
    while let Some((n, d)) = stack.pop() {
        deepest = deepest.max(d);
        for c in 0..8 {
            if let Some((index, INNER)) = nodes[n as usize].child(c) {
                stack.push((index, d + 1));
            }
        }
    }
    deepest
}

impl CwBvh {
    /// Converts a flattened binary tree (see the module documentation). `bounds` gives
    /// each of `bvh.triangles`' exact box; without it (`None`) boxes are taken from the
    /// stored vertex and edges, widened by an ulp.
    fn convert(bvh: &Bvh, bounds: Option<&[([f32; 3], [f32; 3])]>) -> CwBvh {
        let tri_boxes: Vec<([f32; 3], [f32; 3])> = match bounds {
            Some(b) => b.to_vec(),
            None => bvh.triangles.iter().map(triangle_box).collect(),
        };
        if bvh.triangles.is_empty() {
            return CwBvh { nodes: vec![BvhCwNode::default()], triangles: Vec::new() };
        }
        let boxes: Vec<Aabb> = tri_boxes.iter().map(|(lo, hi)| Aabb::new((*lo).into(), (*hi).into())).collect();
        let bvh2 = to_bvh2(bvh, &boxes);
        let cw = bvh2_to_cwbvh(&bvh2, 3, true, false);
        let triangles: Vec<BvhTriangle> = cw.primitive_indices.iter().map(|&i| bvh.triangles[i as usize]).collect();
        let leaf_boxes: Vec<([f32; 3], [f32; 3])> = cw.primitive_indices.iter().map(|&i| tri_boxes[i as usize]).collect();
        let mut nodes: Vec<BvhCwNode> = cw.nodes.iter().map(BvhCwNode::from_obvhs).collect();
        widen(&mut nodes, &leaf_boxes);
        CwBvh { nodes, triangles }
    }

    /// Converts `bvh` (a tree from [`super::build_with_depth_limit`] or [`super::build`]);
    /// see the module documentation. A result deeper than [`CW_STACK_SIZE`] is returned
    /// as is: [`CwBvh::build`] is what guarantees the depth.
    pub fn from_binary(bvh: &Bvh) -> CwBvh {
        Self::convert(bvh, None)
    }

    /// Builds the compressed tree of the triangles `indices` over `positions`, from the
    /// binary tree of [`super::build`], or of a smaller depth limit if that is too deep
    /// for the traversal stack.
    pub fn build(positions: &[[f32; 3]], indices: &[[u32; 3]]) -> CwBvh {
        let mut limit = super::STACK_SIZE;
        loop {
            let bvh = super::build_with_depth_limit(positions, indices, limit);
            let bounds: Vec<_> = bvh.triangles.iter().map(|t| input_box(positions, &indices[t.prim as usize])).collect();
            let cw = Self::convert(&bvh, Some(&bounds));
            // A binary tree of depth limit 0 holds at most two leaves, which the
            // conversion splits into subtrees of at most log2(triangles) levels.
            if inner_depth(&cw.nodes) <= CW_STACK_SIZE || limit == 0 {
                return cw;
            }
            limit /= 2;
        }
    }

    /// Depth of the deepest inner node (root at 0).
    pub fn depth(&self) -> u32 {
        inner_depth(&self.nodes)
    }

    /// Copies the nodes and triangles to device-local buffers.
    pub fn upload(&self, ctx: &Arc<Context>) -> gpu::Result<BvhBuffers> {
        Ok(BvhBuffers {
            layout: BvhLayout::Cw8,
            nodes: Buffer::from_slice(ctx, "bvh cw8 nodes", &self.nodes, MemoryKind::Device)?,
            triangles: Buffer::from_slice(ctx, "bvh triangles", &self.triangles, MemoryKind::Device)?,
            stack_entries: self.depth(),
        })
    }
}

/// Widens every child's grid box until, in exact arithmetic, it contains the boxes of
/// everything below it (bottom-up: children come after their parents). `leaf_boxes` are
/// the triangles' boxes in the tree's triangle order.
fn widen(nodes: &mut [BvhCwNode], leaf_boxes: &[([f32; 3], [f32; 3])]) {
    // The exact box of each node's content, filled bottom-up.
    let mut content = vec![([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]); nodes.len()];
    let grow = |acc: &mut ([f64; 3], [f64; 3]), lo: [f64; 3], hi: [f64; 3]| {
        for k in 0..3 {
            acc.0[k] = acc.0[k].min(lo[k]);
            acc.1[k] = acc.1[k].max(hi[k]);
        }
    };
    for n in (0..nodes.len()).rev() {
        let mut node = nodes[n];
        let mut all = content[n];
        for c in 0..8 {
            let need = match node.child(c) {
                None => continue,
                Some((index, INNER)) => content[index as usize],
                Some((first, count)) => {
                    let mut b = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
                    for (lo, hi) in &leaf_boxes[first as usize..(first + count) as usize] {
                        grow(&mut b, lo.map(f64::from), hi.map(f64::from));
                    }
                    b
                }
            };
            grow(&mut all, need.0, need.1);
            let (mut lo, mut hi) = node.quantised(c);
            let s = node.scale();
            for k in 0..3 {
                let at = |q: u32| f64::from(node.p[k]) + f64::from(q) * f64::from(s[k]);
                while lo[k] > 0 && at(lo[k]) > need.0[k] {
                    lo[k] -= 1;
                }
                while hi[k] < 255 && at(hi[k]) < need.1[k] {
                    hi[k] += 1;
                }
            }
            node.set_quantised(c, lo, hi);
        }
        content[n] = all;
        nodes[n] = node;
    }
    // The root's grid (and so every node's) starts at its content's min: obvhs takes p
    // from the exact box it was given, so q = 0 is exact.
    debug_assert!(nodes.iter().all(|n| n.to_obvhs().p.is_finite()));
}
