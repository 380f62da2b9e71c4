//! Command buffers recorded once and submitted many times, with checked barriers.
//!
//! The [`Recorder`] remembers, per buffer, the last access it recorded, the last write, and
//! what the last barrier made that buffer visible to. Any access after a write (or a write
//! after a read) that no barrier covers is a [`GpuError::Hazard`] at record time, also a
//! read of another kind after a barrier that made the write visible to one kind of read
//! only (a transfer read after write → compute read). Lavapipe runs
//! dispatches in order, so a missing barrier never shows in its results: this check is
//! what catches one in tests.
//!
//! Each recording starts with a global barrier (everything earlier submitted → this
//! submission) and ends with one (this submission → host reads), so state never has to
//! be tracked across submissions.

use super::{vk_err, Access, BindGroup, Buffer, ComputePipeline, Context, GpuError, PushBlock, Result};
use ash::vk;
use std::collections::HashMap;
use std::sync::Arc;

/// Largest workgroup count used along x by [`Recorder::dispatch_linear`]; lavapipe's
/// limit is 65535, the minimum the Vulkan spec allows.
const MAX_GROUPS_X: u32 = 65535;

struct Track {
    last: Access,
    /// The last write this recording made (None: none yet).
    written: Option<Access>,
    /// What the barriers since the last write made it visible to.
    visible_to: Vec<Access>,
}

impl Track {
    /// Whether `access` next needs a barrier: a write after anything, a read after a write,
    /// unless a barrier since the last write made the buffer visible to it.
    fn needs_barrier(&self, access: Access) -> bool {
        (self.written.is_some() || access.writes()) && !self.visible_to.iter().any(|v| v.covers(access))
    }
}

/// Records commands into a [`CommandBuffer`]; see the module doc for the hazard check.
pub struct Recorder<'a> {
    ctx: &'a Arc<Context>,
    cmd: vk::CommandBuffer,
    tracked: HashMap<u64, Track>,
    keep: &'a mut Kept,
}

/// What a recording uses, kept alive for as long as it may execute.
#[derive(Default)]
struct Kept {
    buffers: Vec<Buffer>,
    pipelines: Vec<ComputePipeline>,
    groups: Vec<BindGroup>,
}

impl Recorder<'_> {
    fn track(&mut self, pass: &str, buf: &Buffer, access: Access) -> Result<()> {
        let id = buf.0.id;
        match self.tracked.get_mut(&id) {
            Some(t) => {
                if t.needs_barrier(access) {
                    return Err(GpuError::Hazard { pass: pass.to_string(), buffer: buf.name().to_string(), previous: t.last, now: access });
                }
                // Reads after a barrier leave it in force for further reads; a write
                // starts a new epoch that needs its own barrier.
                if access.writes() {
                    t.visible_to.clear();
                    t.written = Some(access);
                }
                t.last = access;
            }
            None => {
                let written = access.writes().then_some(access);
                self.tracked.insert(id, Track { last: access, written, visible_to: Vec::new() });
                self.keep.buffers.push(buf.clone());
            }
        }
        Ok(())
    }

    /// Records one barrier per `(buffer, previous access, next access)`. In debug builds
    /// the declared previous access must cover what was actually recorded last.
    pub fn barriers(&mut self, list: &[(&Buffer, Access, Access)]) -> Result<()> {
        let mut raw = Vec::with_capacity(list.len());
        for (buf, from, to) in list {
            match self.tracked.get_mut(&buf.0.id) {
                Some(t) => {
                    // The declared previous access covers the last one, or is the last write
                    // (made visible to another kind of read after reads of one kind).
                    let declared_ok = from.covers(t.last) || (!to.writes() && t.written.is_some_and(|w| from.covers(w)));
                    if cfg!(debug_assertions) && !declared_ok {
                        return Err(GpuError::BarrierMismatch { buffer: buf.name().to_string(), declared: *from, actual: t.last });
                    }
                    t.visible_to.push(*to);
                }
                None => {
                    let written = from.writes().then_some(*from);
                    self.tracked.insert(buf.0.id, Track { last: *from, written, visible_to: vec![*to] });
                    self.keep.buffers.push((*buf).clone());
                }
            }
            raw.push(
                vk::BufferMemoryBarrier2::default()
                    .src_stage_mask(from.stage())
                    .src_access_mask(from.access())
                    .dst_stage_mask(to.stage())
                    .dst_access_mask(to.access())
                    .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .buffer(buf.0.raw)
                    .offset(0)
                    .size(vk::WHOLE_SIZE),
            );
        }
        // SAFETY: recording into a command buffer in the recording state.
        unsafe { self.ctx.device.cmd_pipeline_barrier2(self.cmd, &vk::DependencyInfo::default().buffer_memory_barriers(&raw)) };
        Ok(())
    }

    /// Makes `buf` ready for `to`, taking the previous access from what this recording
    /// last did with it (nothing is needed for a buffer this recording has not touched:
    /// the recording's opening barrier covers earlier submissions). For passes that are
    /// composed without knowing what ran before them.
    pub fn transition(&mut self, list: &[(&Buffer, Access)]) -> Result<()> {
        let mut pending = Vec::new();
        for (buf, to) in list {
            if let Some(t) = self.tracked.get(&buf.0.id) {
                if t.needs_barrier(*to) {
                    // A read waits for the last write; a write for the last access, which
                    // follows every earlier one.
                    let from = match t.written {
                        Some(w) if !to.writes() => w,
                        _ => t.last,
                    };
                    pending.push((*buf, from, *to));
                }
            }
        }
        if pending.is_empty() {
            return Ok(());
        }
        self.barriers(&pending)
    }

    /// Records one barrier on one buffer.
    pub fn barrier(&mut self, buf: &Buffer, from: Access, to: Access) -> Result<()> {
        self.barriers(&[(buf, from, to)])
    }

    fn global_barrier(&self, src: (vk::PipelineStageFlags2, vk::AccessFlags2), dst: (vk::PipelineStageFlags2, vk::AccessFlags2)) {
        let mb = [vk::MemoryBarrier2::default().src_stage_mask(src.0).src_access_mask(src.1).dst_stage_mask(dst.0).dst_access_mask(dst.1)];
        // SAFETY: recording into a command buffer in the recording state.
        unsafe { self.ctx.device.cmd_pipeline_barrier2(self.cmd, &vk::DependencyInfo::default().memory_barriers(&mb)) };
    }

    /// Dispatches `groups` workgroups of `pipeline` with `group` bound and `push` as push
    /// constants (which must have exactly the reflected size).
    pub fn dispatch_groups<P: PushBlock>(&mut self, pipeline: &ComputePipeline, group: &BindGroup, push: &P, groups: [u32; 3]) -> Result<()> {
        let kernel = pipeline.name();
        pipeline.check_push::<P>()?;
        let push = bytemuck::bytes_of(push);
        let max = self.ctx.info().max_workgroup_count;
        for (g, m) in groups.iter().zip(max) {
            if *g > m {
                return Err(GpuError::DispatchTooLarge { kernel: kernel.into(), groups: *g as u64, max: m });
            }
        }
        // Merge the accesses of a buffer bound twice before checking hazards.
        let mut accesses: Vec<(&Buffer, Access)> = Vec::new();
        for (_, buf, access) in &group.0.buffers {
            match accesses.iter_mut().find(|(b, _)| b.0.id == buf.0.id) {
                Some((_, a)) if *a != *access => *a = Access::ComputeReadWrite,
                Some(_) => {}
                None => accesses.push((buf, *access)),
            }
        }
        for (buf, access) in accesses {
            self.track(kernel, buf, access)?;
        }
        if groups.contains(&0) {
            return Ok(());
        }
        self.keep.pipelines.push(pipeline.clone());
        self.keep.groups.push(group.clone());
        let (raw, layout) = pipeline.raw();
        // SAFETY: pipeline, layout and set are alive and compatible (the set was made from
        // this kernel's reflected layout); the push block matches the reflected one (checked
        // above), so the push range matches the reflected size.
        unsafe {
            let d = &self.ctx.device;
            d.cmd_bind_pipeline(self.cmd, vk::PipelineBindPoint::COMPUTE, raw);
            d.cmd_bind_descriptor_sets(self.cmd, vk::PipelineBindPoint::COMPUTE, layout, 0, &[group.0.set], &[]);
            if !push.is_empty() {
                d.cmd_push_constants(self.cmd, layout, vk::ShaderStageFlags::COMPUTE, 0, push);
            }
            d.cmd_dispatch(self.cmd, groups[0], groups[1], groups[2]);
        }
        Ok(())
    }

    /// Dispatches enough workgroups to cover `threads` (rounded up by the reflected
    /// workgroup size); kernels bounds-check.
    pub fn dispatch<P: PushBlock>(&mut self, pipeline: &ComputePipeline, group: &BindGroup, push: &P, threads: [u32; 3]) -> Result<()> {
        let ls = pipeline.local_size();
        let groups = [0, 1, 2].map(|i| threads[i].div_ceil(ls[i]));
        self.dispatch_groups(pipeline, group, push, groups)
    }

    /// Dispatches `n` threads of a 1-D kernel. More than 65535 workgroups are folded into
    /// a second axis; kernels index with `thread_index()` from glsl/lib/common.glsl.
    pub fn dispatch_linear<P: PushBlock>(&mut self, pipeline: &ComputePipeline, group: &BindGroup, push: &P, n: u64) -> Result<()> {
        let groups = n.div_ceil(pipeline.local_size()[0] as u64);
        let x = groups.min(MAX_GROUPS_X as u64) as u32;
        let y = if x == 0 { 0 } else { groups.div_ceil(x as u64) };
        if y > u32::MAX as u64 {
            return Err(GpuError::DispatchTooLarge { kernel: pipeline.name().into(), groups, max: MAX_GROUPS_X });
        }
        self.dispatch_groups(pipeline, group, push, [x, y as u32, 1])
    }

    /// Copies the first `bytes` bytes of `src` to `dst`.
    pub fn copy(&mut self, src: &Buffer, dst: &Buffer, bytes: u64) -> Result<()> {
        self.copy_range(src, 0, dst, 0, bytes)
    }

    /// Copies `bytes` bytes of `src` from `src_offset` to `dst` at `dst_offset`.
    pub fn copy_range(&mut self, src: &Buffer, src_offset: u64, dst: &Buffer, dst_offset: u64, bytes: u64) -> Result<()> {
        self.track("copy", src, Access::TransferRead)?;
        self.track("copy", dst, Access::TransferWrite)?;
        if bytes == 0 {
            return Ok(());
        }
        let region = [vk::BufferCopy { src_offset, dst_offset, size: bytes }];
        // SAFETY: both buffers are alive and at least `bytes` long (checked by the caller's
        // sizes; Vulkan validation reports otherwise in tests).
        unsafe { self.ctx.device.cmd_copy_buffer(self.cmd, src.0.raw, dst.0.raw, &region) };
        Ok(())
    }

    /// Sets every byte of `buf` to zero.
    pub fn zero(&mut self, buf: &Buffer) -> Result<()> {
        self.track("zero", buf, Access::TransferWrite)?;
        // SAFETY: fill of a whole live buffer with transfer-dst usage.
        unsafe { self.ctx.device.cmd_fill_buffer(self.cmd, buf.0.raw, 0, vk::WHOLE_SIZE, 0) };
        Ok(())
    }

    pub(crate) fn reset_queries(&mut self, pool: vk::QueryPool, count: u32) {
        // SAFETY: outside any render pass; the pool has at least `count` queries.
        unsafe { self.ctx.device.cmd_reset_query_pool(self.cmd, pool, 0, count) };
    }

    pub(crate) fn write_timestamp(&mut self, pool: vk::QueryPool, index: u32) {
        // ALL_COMMANDS: the timestamp is written once all earlier commands completed, so a
        // scope measures the work recorded inside it.
        // SAFETY: the query was reset earlier in this command buffer.
        unsafe { self.ctx.device.cmd_write_timestamp2(self.cmd, vk::PipelineStageFlags2::ALL_COMMANDS, pool, index) };
    }
}

/// A resettable command pool with one primary command buffer, and an unsignalled fence;
/// on failure nothing is left behind.
pub(crate) fn create_pool_and_fence(ctx: &Context) -> Result<(vk::CommandPool, vk::CommandBuffer, vk::Fence)> {
    let dev = &ctx.device;
    // SAFETY: valid create infos; partial objects are destroyed on error.
    let pool = unsafe {
        dev.create_command_pool(
            &vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family).flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
            None,
        )
    }
    .map_err(vk_err("vkCreateCommandPool"))?;
    let alloc = vk::CommandBufferAllocateInfo::default().command_pool(pool).level(vk::CommandBufferLevel::PRIMARY).command_buffer_count(1);
    let cmd = match unsafe { dev.allocate_command_buffers(&alloc) } {
        Ok(c) => c[0],
        Err(e) => {
            unsafe { dev.destroy_command_pool(pool, None) };
            return Err(vk_err("vkAllocateCommandBuffers")(e));
        }
    };
    let fence = match unsafe { dev.create_fence(&vk::FenceCreateInfo::default(), None) } {
        Ok(f) => f,
        Err(e) => {
            unsafe { dev.destroy_command_pool(pool, None) };
            return Err(vk_err("vkCreateFence")(e));
        }
    };
    Ok((pool, cmd, fence))
}

/// A primary command buffer with its own pool and fence; recorded once, submitted often.
pub struct CommandBuffer {
    ctx: Arc<Context>,
    name: String,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    pending: bool,
    keep: Kept,
}

impl CommandBuffer {
    pub fn new(ctx: &Arc<Context>, name: &str) -> Result<Self> {
        let (pool, cmd, fence) = create_pool_and_fence(ctx)?;
        Ok(Self { ctx: ctx.clone(), name: name.into(), pool, cmd, fence, pending: false, keep: Kept::default() })
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Records the commands issued by `f`, replacing any earlier recording. The recording
    /// keeps the pipelines, bind groups and buffers it uses alive.
    pub fn record(&mut self, f: impl FnOnce(&mut Recorder) -> Result<()>) -> Result<()> {
        self.wait()?;
        let dev = &self.ctx.device;
        // SAFETY: the buffer is not pending (waited above).
        unsafe {
            dev.reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty()).map_err(vk_err("vkResetCommandBuffer"))?;
            dev.begin_command_buffer(self.cmd, &vk::CommandBufferBeginInfo::default()).map_err(vk_err("vkBeginCommandBuffer"))?;
        }
        self.keep = Kept::default();
        let mut rec = Recorder { ctx: &self.ctx, cmd: self.cmd, tracked: HashMap::new(), keep: &mut self.keep };
        // Everything submitted before (and host writes) → this submission.
        rec.global_barrier(
            (vk::PipelineStageFlags2::ALL_COMMANDS, vk::AccessFlags2::MEMORY_WRITE),
            (vk::PipelineStageFlags2::ALL_COMMANDS, vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE),
        );
        let result = f(&mut rec);
        // This submission → host reads after the fence (a fence alone does not make
        // device writes visible to the host).
        rec.global_barrier(
            (vk::PipelineStageFlags2::ALL_COMMANDS, vk::AccessFlags2::MEMORY_WRITE),
            (vk::PipelineStageFlags2::HOST, vk::AccessFlags2::HOST_READ),
        );
        // SAFETY: ends the recording begun above (also after an error, so the buffer is
        // left in a defined state).
        let end = unsafe { dev.end_command_buffer(self.cmd) }.map_err(vk_err("vkEndCommandBuffer"));
        result?;
        end
    }

    /// Submits the recording without waiting.
    pub fn submit(&mut self) -> Result<()> {
        self.wait()?;
        let dev = &self.ctx.device;
        let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(self.cmd)];
        let submit = [vk::SubmitInfo2::default().command_buffer_infos(&cmds)];
        let queue = self.ctx.queue.lock().unwrap_or_else(|p| p.into_inner());
        // SAFETY: the fence is unsignalled (reset below before submit) and the command
        // buffer is executable; the queue is externally synchronised by the mutex.
        unsafe {
            dev.reset_fences(&[self.fence]).map_err(vk_err("vkResetFences"))?;
            dev.queue_submit2(*queue, &submit, self.fence).map_err(vk_err("vkQueueSubmit2"))?;
        }
        self.pending = true;
        Ok(())
    }

    /// Waits for the last submission (no-op if none is pending).
    pub fn wait(&mut self) -> Result<()> {
        if !self.pending {
            return Ok(());
        }
        let timeout = self.ctx.timeout;
        // SAFETY: waiting on our own fence.
        match unsafe { self.ctx.device.wait_for_fences(&[self.fence], true, timeout.as_nanos() as u64) } {
            Ok(()) => {
                self.pending = false;
                Ok(())
            }
            Err(vk::Result::TIMEOUT) => Err(GpuError::Timeout(timeout.as_millis() as u64)),
            Err(e) => Err(vk_err("vkWaitForFences")(e)),
        }
    }

    /// Submits and waits.
    pub fn submit_and_wait(&mut self) -> Result<()> {
        self.submit()?;
        self.wait()
    }
}

impl Drop for CommandBuffer {
    fn drop(&mut self) {
        // A pending submission must finish before its pool goes; on timeout the device is
        // idled as a last resort.
        if self.wait().is_err() {
            let _ = self.ctx.wait_idle();
        }
        // SAFETY: nothing is pending any more.
        unsafe {
            self.ctx.device.destroy_fence(self.fence, None);
            self.ctx.device.destroy_command_pool(self.pool, None);
        }
    }
}
