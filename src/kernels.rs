//! `#[repr(C)]` mirrors of every kernel's push-constant block (scalar layout), each a
//! [`PushBlock`](crate::gpu::PushBlock) whose members every dispatch checks against the reflected SPIR-V. A test
//! (tests/suite/contracts.rs) names the block of each kernel and checks every kernel
//! against it, so a new kernel without a mirror, or a drift on either side, fails.


use crate::gpu::push_block;
use crate::shared::Material;
use bytemuck::{Pod, Zeroable};

/// `Push { uint n; }` of copy, sub, reduce and trace_test: the element (or ray) count.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct CountPush {
    pub n: u32,
}
push_block!(CountPush { n });

impl CountPush {
    /// A count of elements; the kernels index with 32 bits.
    pub fn new(n: u64) -> Self {
        CountPush { n: n as u32 }
    }
}

/// `Push { uint n4; }` of copy_vec4 and copy_wide: the count of float4s.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Count4Push {
    pub n4: u32,
}
push_block!(Count4Push { n4 });

/// fill.comp's block.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct FillPush {
    pub n: u32,
    pub value: f32,
}
push_block!(FillPush { n, value });

/// scale_add.comp's block: `x = a x + b`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ScaleAddPush {
    pub n: u32,
    pub a: f32,
    pub b: f32,
}
push_block!(ScaleAddPush { n, a, b });

/// carry_weight.comp's block.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct CarryWeightPush {
    /// carry_stats' workgroups.
    pub groups: u32,
    /// 1 / (3 pixels).
    pub scale: f32,
    /// s_fd / (s_fd + s_primal).
    pub fresh_share: f32,
    pub w_min: f32,
    /// 1: inverse-variance weights; 0: fixed.
    pub variance: u32,
    /// s_primal / s_adjoint, the adjoint render's variance over the fresh render's; 0: the
    /// adjoint render is not taken in.
    pub adjoint_ratio: f32,
    /// The adjoint render's least weight.
    pub u_min: f32,
}
push_block!(CarryWeightPush { groups, scale, fresh_share, w_min, variance, adjoint_ratio, u_min });

/// gather.comp's block.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GatherPush {
    pub threads: u32,
    /// A power of two.
    pub table_len: u32,
    pub rounds: u32,
}
push_block!(GatherPush { threads, table_len, rounds });

/// loss.comp's block.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct LossPush {
    /// Pixels.
    pub n: u32,
    /// 1 / (3 n): the mean over pixels and channels.
    pub scale: f32,
}
push_block!(LossPush { n, scale });

/// The block of trace_primal.comp and all its variants (trace_adjoint, trace_fd_*, ...).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct TracePush {
    pub width: u32,
    pub height: u32,
    pub sensor: u32,
    /// Samples per pixel in this dispatch.
    pub spp: u32,
    /// Index of the first of them (for the random numbers).
    pub first_sample: u32,
    /// Combined with the iteration counter.
    pub seed: u32,
    /// Primal: added value = weight × sum of samples; adjoint: the adjoint's scale.
    pub weight: f32,
    /// Trace every `stride`-th pixel of each row (0 or 1: every pixel), from column
    /// (row + iteration + `phase`) mod `stride`: a checkerboard (for 2) that moves every
    /// iteration. The dispatch has ceil(width / stride) × height invocations.
    pub stride: u32,
    pub phase: u32,
}

impl TracePush {
    /// The invocations of a dispatch with this block.
    pub fn invocations(&self) -> u64 {
        self.width.div_ceil(self.stride.max(1)) as u64 * self.height as u64
    }
}
push_block!(TracePush { width, height, sensor, spp, first_sample, seed, weight, stride, phase });

/// records_test.comp's block: the element count of every record array.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RecordsPush {
    pub materials: u32,
    pub triangles: u32,
    pub emitters: u32,
    pub nodes: u32,
    pub material_data: u32,
    pub theta: u32,
    pub env_dist: u32,
    pub sensors: u32,
    pub lights: u32,
    /// Triangles with a second-set record (0 where no mesh has a second set).
    pub uv1s: u32,
}
push_block!(RecordsPush { materials, triangles, emitters, nodes, material_data, theta, env_dist, sensors, lights, uv1s });

/// majorant's block: the medium's density slot in θ (its first element and its voxels per
/// axis), the majorant grid's cells per axis, the grid's first word and the record's
/// majorant word (`majorant_cells` follows it) in the medium's buffer, the factor (the
/// margin times the medium's scale), the cost of walking the grid per unit length (in
/// tentative collisions: `walks_grid`), the stage (0 writes the cells, 1 their largest
/// and whether the kernels walk them) and the parameter states read (2 where the previous θ
/// is another buffer than θ) (glsl/majorant.comp).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MajorantPush {
    pub offset: u32,
    pub dims: [u32; 3],
    pub cells: [u32; 3],
    pub grid_word: u32,
    pub record_word: u32,
    pub factor: f32,
    pub walk_cost: f32,
    pub stage: u32,
    pub states: u32,
}
push_block!(MajorantPush { offset, dims, cells, grid_word, record_word, factor, walk_cost, stage, states });

/// The bsdf_sample_test variant's block: one material and direction per dispatch.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct BsdfSamplePush {
    pub material: Material,
    pub n: [f32; 3],
    pub wo: [f32; 3],
    pub count: u32,
    pub seed: u32,
}
push_block!(BsdfSamplePush { material, n, wo, count, seed });

/// rng_test.comp's block: the keys of the numbers drawn.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RngTestPush {
    /// Threads (pixels).
    pub n: u32,
    pub sample_index: u32,
    /// The pass's seed.
    pub seed: u32,
    /// The iteration counter.
    pub frame: u32,
    /// Numbers per thread.
    pub dims: u32,
}
push_block!(RngTestPush { n, sample_index, seed, frame, dims });


