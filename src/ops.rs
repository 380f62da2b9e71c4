//! Buffer kernels every later pass reuses: fill, copy, scale-add and reductions (sum and
//! sum of squares), recorded into a [`Recorder`].

use crate::gpu::{BindGroup, Buffer, CommandBuffer, ComputePipeline, Context, MemoryKind, Recorder, Result, SpecValue};
use crate::kernels::{CountPush, FillPush, ScaleAddPush};
use std::sync::Arc;

/// Elements summed by one reduce workgroup: local size × ITEMS (glsl/reduce.comp).
fn reduce_chunk(p: &ComputePipeline) -> u64 {
    // ITEMS is left at its default of 4 by `BufferOps::new`.
    p.local_size()[0] as u64 * 4
}

/// The pipelines of the buffer kernels.
pub struct BufferOps {
    ctx: Arc<Context>,
    fill: ComputePipeline,
    copy: ComputePipeline,
    scale_add: ComputePipeline,
    sub: ComputePipeline,
    merge_half: ComputePipeline,
    reduce_sum: ComputePipeline,
    reduce_sq: ComputePipeline,
}

/// A reduction prepared for one input buffer: the partial-sum buffers and the bind groups
/// of every level, so that it can be recorded into a resubmitted command buffer.
pub struct Reduction {
    /// (bind group, input elements, squares?, partial-sum output) per level
    levels: Vec<(BindGroup, u64, bool, Buffer)>,
    result: Buffer,
}

impl Reduction {
    /// The 1-element buffer that holds the result after the recorded work ran.
    pub fn result(&self) -> &Buffer {
        &self.result
    }
}

impl BufferOps {
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        Ok(Self {
            ctx: ctx.clone(),
            fill: ComputePipeline::new(ctx, "fill", &[])?,
            copy: ComputePipeline::new(ctx, "copy", &[])?,
            scale_add: ComputePipeline::new(ctx, "scale_add", &[])?,
            sub: ComputePipeline::new(ctx, "sub", &[])?,
            merge_half: ComputePipeline::new(ctx, "merge_half", &[])?,
            reduce_sum: ComputePipeline::new(ctx, "reduce", &[("SQUARE", SpecValue::Bool(false))])?,
            reduce_sq: ComputePipeline::new(ctx, "reduce", &[("SQUARE", SpecValue::Bool(true))])?,
        })
    }

    fn elements(buf: &Buffer) -> u64 {
        buf.len() / 4
    }

    /// Records `dst[i] = value` over the whole buffer.
    pub fn fill(&self, rec: &mut Recorder, dst: &Buffer, value: f32) -> Result<()> {
        let group = self.fill.bind(&[("Dst", dst)])?;
        let n = Self::elements(dst);
        rec.dispatch_linear(&self.fill, &group, &FillPush { n: n as u32, value }, n)
    }

    /// Records `dst[i] = src[i]` for the first `min(len)` elements.
    pub fn copy(&self, rec: &mut Recorder, src: &Buffer, dst: &Buffer) -> Result<()> {
        let group = self.copy.bind(&[("Src", src), ("Dst", dst)])?;
        let n = Self::elements(src).min(Self::elements(dst));
        rec.dispatch_linear(&self.copy, &group, &CountPush::new(n), n)
    }

    /// Records `x[i] = a * x[i] + b`.
    pub fn scale_add(&self, rec: &mut Recorder, x: &Buffer, a: f32, b: f32) -> Result<()> {
        let group = self.scale_add.bind(&[("X", x)])?;
        let n = Self::elements(x);
        rec.dispatch_linear(&self.scale_add, &group, &ScaleAddPush { n: n as u32, a, b }, n)
    }

    /// Records `dst[i] = a[i] - b[i]`.
    pub fn sub(&self, rec: &mut Recorder, a: &Buffer, b: &Buffer, dst: &Buffer) -> Result<()> {
        let group = self.sub.bind(&[("A", a), ("B", b), ("Dst", dst)])?;
        let n = Self::elements(dst);
        rec.dispatch_linear(&self.sub, &group, &CountPush::new(n), n)
    }

    /// Records `grad[i] += fresh[2i] + fresh[2i + 1]; half[i] += fresh[2i + 1]; fresh[2i] =
    /// fresh[2i + 1] = 0` over `grad`'s elements (glsl/merge_half.comp).
    pub fn merge_half(&self, rec: &mut Recorder, grad: &Buffer, half: &Buffer, fresh: &Buffer) -> Result<()> {
        let group = self.merge_half.bind(&[("Grad", grad), ("GradHalf", half), ("Fresh", fresh)])?;
        let n = (Self::elements(fresh) / 2).min(Self::elements(grad)).min(Self::elements(half));
        rec.dispatch_linear(&self.merge_half, &group, &CountPush::new(n), n)
    }

    /// Prepares the sum (or, with `square`, the sum of squares) of `src`'s f32 elements.
    pub fn reduction(&self, src: &Buffer, square: bool) -> Result<Reduction> {
        let mut levels = Vec::new();
        let mut n = Self::elements(src);
        let mut input = src.clone();
        let mut first = true;
        loop {
            let pipe = if first && square { &self.reduce_sq } else { &self.reduce_sum };
            let groups = n.div_ceil(reduce_chunk(pipe)).max(1);
            // Zeroed: a result read before the first reduction ran reads 0.
            let out = Buffer::zeroed::<f32>(&self.ctx, &format!("{} partials {}", src.name(), levels.len()), groups as usize, MemoryKind::Device)?;
            levels.push((pipe.bind(&[("Src", &input), ("Partials", &out)])?, n, first && square, out.clone()));
            input = out;
            n = groups;
            first = false;
            if groups == 1 {
                break;
            }
        }
        Ok(Reduction { levels, result: input })
    }

    /// Records a prepared reduction; afterwards `reduction.result()` holds the value. The
    /// recorder orders each level after whatever last touched its input and output (the
    /// previous level's partial sums, or earlier passes in the same recording).
    pub fn record_reduction(&self, rec: &mut Recorder, reduction: &Reduction) -> Result<()> {
        for (group, n, square, _) in &reduction.levels {
            let pipe = if *square { &self.reduce_sq } else { &self.reduce_sum };
            let groups = n.div_ceil(reduce_chunk(pipe)).max(1);
            rec.dispatch_linear(pipe, group, &CountPush::new(*n), groups * pipe.local_size()[0] as u64)?;
        }
        Ok(())
    }

    /// Sums (or sums the squares of) `src` now and returns the value.
    pub fn sum(&self, src: &Buffer, square: bool) -> Result<f32> {
        let red = self.reduction(src, square)?;
        let mut cmd = CommandBuffer::new(&self.ctx, "sum")?;
        cmd.record(|rec| self.record_reduction(rec, &red))?;
        cmd.submit_and_wait()?;
        Ok(red.result().read::<f32>()?[0])
    }
}
