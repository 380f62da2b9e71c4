//! The staging path between host and device-local memory.
//!
//! A buffer whose memory the host cannot map (device-local memory on a discrete GPU, or
//! any device buffer when [`ContextOptions::unmappable_device_memory`] is set) is written
//! and read through two persistent host-visible buffers of [`STAGING_BYTES`] each, one for
//! uploads (CPU-to-GPU memory) and one for readbacks (GPU-to-CPU memory), with one
//! command buffer and fence reused for every copy. A transfer larger than the staging
//! buffer goes in chunks. The staging buffers are made on the first staged transfer and
//! live as long as the [`Context`], so steady-state work (an optimisation iteration's loss
//! and θ readbacks, the frame counter) allocates nothing. They hold raw handles rather
//! than [`Buffer`](super::Buffer)s: a `Buffer` holds an `Arc<Context>`, and the context
//! owning one would never be dropped.
//!
//! [`ContextOptions::unmappable_device_memory`]: super::ContextOptions::unmappable_device_memory

use super::buffer::allocate_bound;
use super::commands::create_pool_and_fence;
use super::{vk_err, Context, GpuError, Result};
use ash::vk;
use gpu_allocator::vulkan::Allocation;
use gpu_allocator::MemoryLocation;
use super::transfers::Counters;

/// Bytes of each staging buffer: large enough that a scene's uploads take few chunks,
/// small next to any device's memory.
pub const STAGING_BYTES: u64 = 4 << 20;

/// Name prefix of the staging allocations (left out of [`Context::live_allocations`]).
pub(crate) const STAGING_NAME: &str = "staging ";

struct HostBuffer {
    raw: vk::Buffer,
    allocation: Allocation,
}

/// The staging buffers, command buffer and fence; made on first use.
struct Parts {
    upload: HostBuffer,
    readback: HostBuffer,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
}

/// Held by the [`Context`] behind a mutex: one staged transfer at a time.
#[derive(Default)]
pub(crate) struct Staging {
    parts: Option<Parts>,
}

/// Direction of a staged copy.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Direction {
    Upload,
    Readback,
}

fn host_buffer(ctx: &Context, name: &str, location: MemoryLocation, usage: vk::BufferUsageFlags) -> Result<HostBuffer> {
    let info = vk::BufferCreateInfo::default().size(STAGING_BYTES).usage(usage);
    let (raw, allocation) = allocate_bound(ctx, name, &info, location)?;
    let b = HostBuffer { raw, allocation };
    if b.allocation.mapped_ptr().is_none() {
        free_host_buffer(ctx, b);
        return Err(GpuError::BufferAccess { name: name.into(), what: "host-visible memory could not be mapped".into() });
    }
    Counters::add(&ctx.counters.staging_allocations, 1);
    Ok(b)
}

fn free_host_buffer(ctx: &Context, b: HostBuffer) {
    // SAFETY: the staging copies are waited for before any transfer returns.
    unsafe { ctx.device.destroy_buffer(b.raw, None) };
    let _ = ctx.allocator.lock().unwrap_or_else(|p| p.into_inner()).free(b.allocation);
}

impl Parts {
    fn new(ctx: &Context) -> Result<Parts> {
        let upload = host_buffer(ctx, "staging upload", MemoryLocation::CpuToGpu, vk::BufferUsageFlags::TRANSFER_SRC)?;
        let readback = match host_buffer(ctx, "staging readback", MemoryLocation::GpuToCpu, vk::BufferUsageFlags::TRANSFER_DST) {
            Ok(b) => b,
            Err(e) => {
                free_host_buffer(ctx, upload);
                return Err(e);
            }
        };
        let made = create_pool_and_fence(ctx);
        match made {
            Ok((pool, cmd, fence)) => Ok(Parts { upload, readback, pool, cmd, fence }),
            Err(e) => {
                free_host_buffer(ctx, upload);
                free_host_buffer(ctx, readback);
                Err(e)
            }
        }
    }

    /// Records and runs one copy of `bytes` between `target` at `offset` and the start of
    /// the staging buffer of `dir`, and waits for it.
    fn copy(&self, ctx: &Context, dir: Direction, target: vk::Buffer, offset: u64, bytes: u64) -> Result<()> {
        let dev = &ctx.device;
        let (src, dst, region) = match dir {
            Direction::Upload => (self.upload.raw, target, vk::BufferCopy { src_offset: 0, dst_offset: offset, size: bytes }),
            Direction::Readback => (target, self.readback.raw, vk::BufferCopy { src_offset: offset, dst_offset: 0, size: bytes }),
        };
        let barrier = |cmd, src: (vk::PipelineStageFlags2, vk::AccessFlags2), dst: (vk::PipelineStageFlags2, vk::AccessFlags2)| {
            let mb = [vk::MemoryBarrier2::default().src_stage_mask(src.0).src_access_mask(src.1).dst_stage_mask(dst.0).dst_access_mask(dst.1)];
            // SAFETY: recording into a command buffer in the recording state.
            unsafe { dev.cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&mb)) };
        };
        // SAFETY: the command buffer is not pending (every copy is waited for), both
        // buffers are alive and the region lies inside both (checked by the callers).
        unsafe {
            dev.reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty()).map_err(vk_err("vkResetCommandBuffer"))?;
            dev.begin_command_buffer(self.cmd, &vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT))
                .map_err(vk_err("vkBeginCommandBuffer"))?;
        }
        // Earlier submissions' writes and the host's writes to the staging buffer → the copy.
        barrier(
            self.cmd,
            (vk::PipelineStageFlags2::ALL_COMMANDS | vk::PipelineStageFlags2::HOST, vk::AccessFlags2::MEMORY_WRITE | vk::AccessFlags2::HOST_WRITE),
            (vk::PipelineStageFlags2::COPY, vk::AccessFlags2::TRANSFER_READ | vk::AccessFlags2::TRANSFER_WRITE),
        );
        // SAFETY: as above.
        unsafe { dev.cmd_copy_buffer(self.cmd, src, dst, &[region]) };
        // The copy → later submissions, and the host's read of the staging buffer.
        barrier(
            self.cmd,
            (vk::PipelineStageFlags2::COPY, vk::AccessFlags2::TRANSFER_WRITE),
            (
                vk::PipelineStageFlags2::ALL_COMMANDS | vk::PipelineStageFlags2::HOST,
                vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE | vk::AccessFlags2::HOST_READ,
            ),
        );
        let cmds = [vk::CommandBufferSubmitInfo::default().command_buffer(self.cmd)];
        let submit = [vk::SubmitInfo2::default().command_buffer_infos(&cmds)];
        // SAFETY: recording ends; the fence is unsignalled (reset after every wait); the
        // queue is externally synchronised by its mutex.
        unsafe {
            dev.end_command_buffer(self.cmd).map_err(vk_err("vkEndCommandBuffer"))?;
            let queue = ctx.queue.lock().unwrap_or_else(|p| p.into_inner());
            dev.queue_submit2(*queue, &submit, self.fence).map_err(vk_err("vkQueueSubmit2"))?;
        }
        Counters::add(&ctx.counters.submissions, 1);
        let waited = unsafe { dev.wait_for_fences(&[self.fence], true, ctx.timeout.as_nanos() as u64) };
        match waited {
            Ok(()) => {}
            Err(vk::Result::TIMEOUT) => {
                // Leave nothing pending behind the reused fence and command buffer.
                let _ = ctx.wait_idle();
                let _ = unsafe { dev.reset_fences(&[self.fence]) };
                return Err(GpuError::Timeout(ctx.timeout.as_millis() as u64));
            }
            Err(e) => return Err(vk_err("vkWaitForFences")(e)),
        }
        // SAFETY: the fence is signalled and nothing waits on it.
        unsafe { dev.reset_fences(&[self.fence]) }.map_err(vk_err("vkResetFences"))
    }
}

impl Staging {
    /// Copies `data` into `target` from byte `offset` on, in chunks of [`STAGING_BYTES`].
    pub(crate) fn upload(&mut self, ctx: &Context, target: vk::Buffer, data: &[u8]) -> Result<()> {
        let parts = self.parts(ctx)?;
        for (k, chunk) in data.chunks(STAGING_BYTES as usize).enumerate() {
            // No copy from the staging buffer is pending: every copy is waited for.
            let dst = parts
                .upload
                .allocation
                .mapped_slice_mut()
                .ok_or_else(|| GpuError::BufferAccess { name: "staging upload".into(), what: "not mapped".into() })?;
            dst[..chunk.len()].copy_from_slice(chunk);
            parts.copy(ctx, Direction::Upload, target, (k as u64) * STAGING_BYTES, chunk.len() as u64)?;
        }
        Counters::add(&ctx.counters.staged_upload, data.len() as u64);
        Ok(())
    }

    /// Fills `out` from `target`'s bytes from 0 on, in chunks of [`STAGING_BYTES`].
    pub(crate) fn readback(&mut self, ctx: &Context, target: vk::Buffer, out: &mut [u8]) -> Result<()> {
        let parts = self.parts(ctx)?;
        for (k, chunk) in out.chunks_mut(STAGING_BYTES as usize).enumerate() {
            parts.copy(ctx, Direction::Readback, target, (k as u64) * STAGING_BYTES, chunk.len() as u64)?;
            let src = parts
                .readback
                .allocation
                .mapped_slice()
                .ok_or_else(|| GpuError::BufferAccess { name: "staging readback".into(), what: "not mapped".into() })?;
            chunk.copy_from_slice(&src[..chunk.len()]);
        }
        Counters::add(&ctx.counters.staged_readback, out.len() as u64);
        Ok(())
    }

    fn parts(&mut self, ctx: &Context) -> Result<&mut Parts> {
        if self.parts.is_none() {
            self.parts = Some(Parts::new(ctx)?);
        }
        Ok(self.parts.as_mut().expect("made above"))
    }

    /// Frees everything; called by the context before its allocator and device go.
    pub(crate) fn destroy(&mut self, ctx: &Context) {
        if let Some(p) = self.parts.take() {
            // SAFETY: every copy was waited for; the pool's command buffer goes with it.
            unsafe {
                ctx.device.destroy_fence(p.fence, None);
                ctx.device.destroy_command_pool(p.pool, None);
            }
            free_host_buffer(ctx, p.upload);
            free_host_buffer(ctx, p.readback);
        }
    }
}
