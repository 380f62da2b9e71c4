//! Command buffers recorded once and submitted many times, with derived barriers.
//!
//! A pass is declared once: its kernel's bindings carry their access, reflected from the
//! SPIR-V ([`super::BindGroup`]). The [`Recorder`] remembers, per buffer, the last access it
//! recorded, the last write, and what the barriers since made that write visible to; before
//! each dispatch, copy or fill it records the barrier that the buffer's previous use
//! requires (a read after a write waits for the write, a write after anything waits for the
//! last access), and none where none is needed (reads after reads).
//!
//! Hand-written barriers stay possible ([`Recorder::barrier`]); in debug builds their
//! declared previous access is checked against the recorded one. Passes batched on purpose
//! — dispatches that write disjoint parts of one buffer, or add into it with atomics — go in
//! [`Recorder::unordered`], where no barrier is derived between them; a read of what
//! another dispatch of the batch wrote (or a write over what it read) is then a
//! [`GpuError::Hazard`] at record time, since nothing orders them.
//!
//! With a profiler attached ([`CommandBuffer::record_profiled`], [`Recorder::with_profiler`])
//! every dispatch outside a named scope is timed in a scope named after its kernel
//! (consecutive dispatches of one kernel share one), and [`Recorder::scope`] names a pass of
//! several dispatches.
//!
//! Each recording starts with a global barrier (everything earlier submitted → this
//! submission) and ends with one (this submission → host reads), so state never has to
//! be tracked across submissions.

use super::{vk_err, Access, BindGroup, Buffer, ComputePipeline, Context, GpuError, Profiler, PushBlock, Result};
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
    /// The unordered batch of the last access, if it was in one.
    batch: Option<u32>,
    /// The recording's access count at the last write ([`Recorder::last_write`]).
    written_at: Option<u64>,
}

impl Track {
    /// Whether `access` next needs a barrier: a write after anything, a read after a write,
    /// unless a barrier since the last write made the buffer visible to it.
    fn needs_barrier(&self, access: Access) -> bool {
        (self.written.is_some() || access.writes()) && !self.visible_to.iter().any(|v| v.covers(access))
    }
}

/// What a recording tracks across the recorders that add to it.
#[derive(Default)]
struct State {
    tracked: HashMap<u64, Track>,
    /// Unordered batches opened so far (their numbers).
    batches: u32,
    /// Barriers recorded (derived or hand-written), for tests and benchmarks.
    barriers: u32,
    /// Buffer accesses tracked so far.
    accesses: u64,
    /// This recording's number, unique in the process ([`Recorder::recording`]).
    recording: u64,
}

/// The next recording's number.
static NEXT_RECORDING: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// Records commands into a [`CommandBuffer`]; see the module doc for the derived barriers.
pub struct Recorder<'a> {
    ctx: &'a Arc<Context>,
    cmd: vk::CommandBuffer,
    state: &'a mut State,
    keep: &'a mut Kept,
    profiler: Option<&'a mut Profiler>,
    /// Named scopes open on the attached profiler.
    named: usize,
    /// The kernel whose automatic scope is open on the attached profiler.
    auto: Option<String>,
    /// The unordered batch open, if any.
    batch: Option<u32>,
}

/// What a recording uses, kept alive for as long as it may execute.
#[derive(Default)]
struct Kept {
    buffers: Vec<Buffer>,
    pipelines: Vec<ComputePipeline>,
    groups: Vec<BindGroup>,
}

impl Recorder<'_> {
    /// Records the barriers that `list`'s accesses need after what this recording did with
    /// each buffer, then tracks the accesses. Inside an unordered batch no barrier is
    /// derived between its own accesses.
    fn access(&mut self, pass: &str, list: &[(&Buffer, Access)]) -> Result<()> {
        let mut pending = Vec::new();
        for (buf, access) in list {
            if let Some(t) = self.state.tracked.get(&buf.0.id) {
                let same_batch = self.batch.is_some() && t.batch == self.batch;
                if same_batch {
                    // Nothing orders the batch's dispatches: only writes (to disjoint parts,
                    // or atomic) may follow writes.
                    if t.written.is_some() && !access.writes() || !t.last.writes() && access.writes() {
                        return Err(GpuError::Hazard { pass: pass.to_string(), buffer: buf.name().to_string(), previous: t.last, now: *access });
                    }
                } else if t.needs_barrier(*access) {
                    // A read waits for the last write; a write for the last access, which
                    // follows every earlier one.
                    let from = match t.written {
                        Some(w) if !access.writes() => w,
                        _ => t.last,
                    };
                    pending.push((*buf, from, *access));
                }
            }
        }
        if !pending.is_empty() {
            self.barriers(&pending)?;
        }
        for (buf, access) in list {
            self.track(buf, *access);
        }
        Ok(())
    }

    fn track(&mut self, buf: &Buffer, access: Access) {
        let batch = self.batch;
        self.state.accesses += 1;
        let at = access.writes().then_some(self.state.accesses);
        match self.state.tracked.get_mut(&buf.0.id) {
            Some(t) => {
                // Reads after a barrier leave it in force for further reads; a write
                // starts a new epoch that needs its own barrier.
                if access.writes() {
                    t.visible_to.clear();
                    t.written = Some(access);
                    t.written_at = at;
                }
                t.last = access;
                t.batch = batch;
            }
            None => {
                let written = access.writes().then_some(access);
                self.state.tracked.insert(buf.0.id, Track { last: access, written, visible_to: Vec::new(), batch, written_at: at });
                self.keep.buffers.push(buf.clone());
            }
        }
    }

    /// This recording's number, unique in the process: with [`Self::last_write`], what a
    /// pass needs to tell whether its inputs changed since it last ran in the recording.
    pub fn recording(&self) -> u64 {
        self.state.recording
    }

    /// When this recording last wrote `buf`, as a count of the accesses it had tracked then
    /// (later writes count higher); None where it has not written it.
    pub fn last_write(&self, buf: &Buffer) -> Option<u64> {
        self.state.tracked.get(&buf.0.id).and_then(|t| t.written_at)
    }

    /// Records one barrier per `(buffer, previous access, next access)`. In debug builds
    /// the declared previous access must cover what was actually recorded last.
    pub fn barriers(&mut self, list: &[(&Buffer, Access, Access)]) -> Result<()> {
        let mut raw = Vec::with_capacity(list.len());
        for (buf, from, to) in list {
            match self.state.tracked.get_mut(&buf.0.id) {
                Some(t) => {
                    // The declared previous access covers the last one, or is the last write
                    // (made visible to another kind of read after reads of one kind).
                    let declared_ok = from.covers(t.last) || (!to.writes() && t.written.is_some_and(|w| from.covers(w)));
                    if cfg!(debug_assertions) && !declared_ok {
                        return Err(GpuError::BarrierMismatch { buffer: buf.name().to_string(), declared: *from, actual: t.last });
                    }
                    t.visible_to.push(*to);
                    // A barrier orders what follows after the batch's accesses.
                    t.batch = None;
                }
                None => {
                    // A write declared here counts as made now (its time is not known).
                    let written = from.writes().then_some(*from);
                    self.state.accesses += 1;
                    let written_at = from.writes().then_some(self.state.accesses);
                    self.state.tracked.insert(buf.0.id, Track { last: *from, written, visible_to: vec![*to], batch: None, written_at });
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
        self.state.barriers += raw.len() as u32;
        // SAFETY: recording into a command buffer in the recording state.
        unsafe { self.ctx.device.cmd_pipeline_barrier2(self.cmd, &vk::DependencyInfo::default().buffer_memory_barriers(&raw)) };
        Ok(())
    }

    /// Makes `buf` ready for `to` ahead of time, taking the previous access from what this
    /// recording last did with it (nothing is needed for a buffer this recording has not
    /// touched: the recording's opening barrier covers earlier submissions). Dispatches,
    /// copies and fills do this themselves.
    pub fn transition(&mut self, list: &[(&Buffer, Access)]) -> Result<()> {
        let mut pending = Vec::new();
        for (buf, to) in list {
            if let Some(t) = self.state.tracked.get(&buf.0.id) {
                if t.needs_barrier(*to) {
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

    /// Barriers recorded so far in this recording, derived or hand-written.
    pub fn barrier_count(&self) -> u32 {
        self.state.barriers
    }

    /// Records `f`'s commands as one unordered batch: no barrier is derived between them
    /// (they write disjoint parts of their buffers, or add with atomics); barriers from
    /// what came before, and to what comes after, are derived as usual.
    pub fn unordered<R>(&mut self, f: impl FnOnce(&mut Self) -> Result<R>) -> Result<R> {
        let outer = self.batch;
        self.state.batches += 1;
        self.batch = Some(self.state.batches);
        let r = f(self);
        self.batch = outer;
        r
    }

    fn global_barrier(&self, src: (vk::PipelineStageFlags2, vk::AccessFlags2), dst: (vk::PipelineStageFlags2, vk::AccessFlags2)) {
        let mb = [vk::MemoryBarrier2::default().src_stage_mask(src.0).src_access_mask(src.1).dst_stage_mask(dst.0).dst_access_mask(dst.1)];
        // SAFETY: recording into a command buffer in the recording state.
        unsafe { self.ctx.device.cmd_pipeline_barrier2(self.cmd, &vk::DependencyInfo::default().memory_barriers(&mb)) };
    }

    /// Records `f` with `profiler` attached instead of any other: its dispatches are timed
    /// there ([`Self::scope`] and the kernels' own scopes). The profiler must have been
    /// reset in this recording ([`Profiler::reset`]).
    pub fn with_profiler<R>(&mut self, profiler: &mut Profiler, f: impl FnOnce(&mut Recorder) -> Result<R>) -> Result<R> {
        self.close_auto()?;
        let mut inner = Recorder {
            ctx: self.ctx,
            cmd: self.cmd,
            state: &mut *self.state,
            keep: &mut *self.keep,
            profiler: Some(profiler),
            named: 0,
            auto: None,
            batch: self.batch,
        };
        let r = f(&mut inner)?;
        inner.finish_scopes()?;
        Ok(r)
    }

    /// Opens scope `name` on the attached profiler (nothing without one): the dispatches
    /// until [`Self::end_scope`] are timed together under that name.
    pub fn begin_scope(&mut self, name: &str) -> Result<()> {
        self.close_auto()?;
        self.named += 1;
        let (dev, cmd) = (&self.ctx.device, self.cmd);
        match self.profiler.as_deref_mut() {
            Some(p) => p.begin_raw(dev, cmd, name),
            None => Ok(()),
        }
    }

    /// Closes the scope [`Self::begin_scope`] opened.
    pub fn end_scope(&mut self) -> Result<()> {
        self.close_auto()?;
        if self.named == 0 {
            return Err(GpuError::Profiler("end_scope() without begin_scope()".into()));
        }
        self.named -= 1;
        let (dev, cmd) = (&self.ctx.device, self.cmd);
        match self.profiler.as_deref_mut() {
            Some(p) => p.end_raw(dev, cmd),
            None => Ok(()),
        }
    }

    /// Records `f` inside scope `name`.
    pub fn scope<R>(&mut self, name: &str, f: impl FnOnce(&mut Self) -> Result<R>) -> Result<R> {
        self.begin_scope(name)?;
        let r = f(self)?;
        self.end_scope()?;
        Ok(r)
    }

    /// Opens kernel `kernel`'s automatic scope, unless it is open already or a named
    /// scope is.
    fn auto_scope(&mut self, kernel: &str) -> Result<()> {
        if self.profiler.is_none() || self.named > 0 || self.auto.as_deref() == Some(kernel) {
            return Ok(());
        }
        self.close_auto()?;
        let (dev, cmd) = (&self.ctx.device, self.cmd);
        if let Some(p) = self.profiler.as_deref_mut() {
            p.begin_raw(dev, cmd, kernel)?;
        }
        self.auto = Some(kernel.to_string());
        Ok(())
    }

    fn close_auto(&mut self) -> Result<()> {
        if self.auto.take().is_some() {
            let (dev, cmd) = (&self.ctx.device, self.cmd);
            if let Some(p) = self.profiler.as_deref_mut() {
                p.end_raw(dev, cmd)?;
            }
        }
        Ok(())
    }

    /// Closes the automatic scope and checks that every named one was closed.
    fn finish_scopes(&mut self) -> Result<()> {
        self.close_auto()?;
        if self.named > 0 {
            return Err(GpuError::Profiler(format!("{} scope(s) never ended", self.named)));
        }
        Ok(())
    }

    /// Dispatches `groups` workgroups of `pipeline` with `group` bound and `push` as push
    /// constants (which must have exactly the reflected size), after the barriers its
    /// bindings' accesses need.
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
        // Merge the accesses of a buffer bound twice.
        let mut accesses: Vec<(&Buffer, Access)> = Vec::new();
        for (_, buf, access) in &group.0.buffers {
            match accesses.iter_mut().find(|(b, _)| b.0.id == buf.0.id) {
                Some((_, a)) if *a != *access => *a = Access::ComputeReadWrite,
                Some(_) => {}
                None => accesses.push((buf, *access)),
            }
        }
        self.access(kernel, &accesses)?;
        if groups.contains(&0) {
            return Ok(());
        }
        self.auto_scope(kernel)?;
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
        self.close_auto()?;
        self.access("copy", &[(src, Access::TransferRead), (dst, Access::TransferWrite)])?;
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
        self.close_auto()?;
        self.access("zero", &[(buf, Access::TransferWrite)])?;
        // SAFETY: fill of a whole live buffer with transfer-dst usage.
        unsafe { self.ctx.device.cmd_fill_buffer(self.cmd, buf.0.raw, 0, vk::WHOLE_SIZE, 0) };
        Ok(())
    }

    /// The device and the command buffer being recorded, for the profiler's commands.
    pub(crate) fn raw(&self) -> (&ash::Device, vk::CommandBuffer) {
        (&self.ctx.device, self.cmd)
    }
}

/// Writes timestamp `index` of `pool` into `cmd` once all earlier commands completed
/// (ALL_COMMANDS), so a scope measures the work recorded inside it.
pub(crate) fn write_timestamp(device: &ash::Device, cmd: vk::CommandBuffer, pool: vk::QueryPool, index: u32) {
    // SAFETY: the query was reset earlier in this command buffer.
    unsafe { device.cmd_write_timestamp2(cmd, vk::PipelineStageFlags2::ALL_COMMANDS, pool, index) };
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
        self.record_with(None, f)
    }

    /// [`Self::record`] with `profiler` attached (and reset): every pass is timed in it, in
    /// a scope named after its kernel or the scope the pass opened.
    pub fn record_profiled(&mut self, profiler: &mut Profiler, f: impl FnOnce(&mut Recorder) -> Result<()>) -> Result<()> {
        self.record_with(Some(profiler), f)
    }

    fn record_with(&mut self, mut profiler: Option<&mut Profiler>, f: impl FnOnce(&mut Recorder) -> Result<()>) -> Result<()> {
        self.wait()?;
        let dev = &self.ctx.device;
        // SAFETY: the buffer is not pending (waited above).
        unsafe {
            dev.reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty()).map_err(vk_err("vkResetCommandBuffer"))?;
            dev.begin_command_buffer(self.cmd, &vk::CommandBufferBeginInfo::default()).map_err(vk_err("vkBeginCommandBuffer"))?;
        }
        self.keep = Kept::default();
        let mut state = State { recording: NEXT_RECORDING.fetch_add(1, std::sync::atomic::Ordering::Relaxed), ..State::default() };
        if let Some(p) = profiler.as_deref_mut() {
            p.reset_raw(dev, self.cmd);
        }
        let mut rec = Recorder { ctx: &self.ctx, cmd: self.cmd, state: &mut state, keep: &mut self.keep, profiler, named: 0, auto: None, batch: None };
        // Everything submitted before (and host writes) → this submission.
        rec.global_barrier(
            (vk::PipelineStageFlags2::ALL_COMMANDS, vk::AccessFlags2::MEMORY_WRITE),
            (vk::PipelineStageFlags2::ALL_COMMANDS, vk::AccessFlags2::MEMORY_READ | vk::AccessFlags2::MEMORY_WRITE),
        );
        let result = f(&mut rec).and_then(|()| rec.finish_scopes());
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
