//! Named GPU timestamp scopes. A profiler attached to a recording
//! ([`super::CommandBuffer::record_profiled`]) times every pass in a scope named after its
//! kernel, or after the scope the pass opened ([`Recorder::scope`]); a profiler used on its
//! own opens scopes explicitly (`profiler.begin(rec, "trace_primal")` … `end(rec)`).
//!
//! Scopes nest; each result carries its depth. Scope names are the kernel/pass names, so
//! a table of results reads like the pass list.

use super::commands::write_timestamp;
use super::{vk_err, Context, GpuError, Recorder, Result};
use ash::vk;
use std::sync::Arc;

/// The measured GPU time of one scope instance.
#[derive(Clone, Debug, PartialEq)]
pub struct ScopeTime {
    pub name: String,
    pub depth: usize,
    pub ms: f64,
}

struct Scope {
    name: String,
    depth: usize,
    begin: u32,
    end: Option<u32>,
}

/// A pool of timestamp queries handed out to named scopes within one recording.
pub struct Profiler {
    ctx: Arc<Context>,
    pool: vk::QueryPool,
    capacity: u32,
    scopes: Vec<Scope>,
    open: Vec<usize>,
    used: u32,
}

impl Profiler {
    /// Scopes a profiler takes per recording when nothing says otherwise: far more than an
    /// iteration opens (a few per sensor and pass), at 16 bytes of query pool each.
    pub const SCOPES: u32 = 1024;

    /// A profiler for up to `max_scopes` scopes per recording.
    pub fn new(ctx: &Arc<Context>, max_scopes: u32) -> Result<Self> {
        let capacity = max_scopes * 2;
        let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(capacity.max(1));
        // SAFETY: valid create info.
        let pool = unsafe { ctx.device.create_query_pool(&info, None) }.map_err(vk_err("vkCreateQueryPool"))?;
        Ok(Self { ctx: ctx.clone(), pool, capacity, scopes: Vec::new(), open: Vec::new(), used: 0 })
    }

    /// Starts a new recording: forgets earlier scopes and resets the queries on the GPU.
    /// Call first inside every `CommandBuffer::record` that uses this profiler.
    pub fn reset(&mut self, rec: &mut Recorder) {
        let (device, cmd) = rec.raw();
        self.reset_raw(device, cmd);
    }

    fn forget(&mut self) {
        self.scopes.clear();
        self.open.clear();
        self.used = 0;
    }

    /// [`Self::reset`] into command buffer `cmd` being recorded.
    pub(crate) fn reset_raw(&mut self, device: &ash::Device, cmd: ash::vk::CommandBuffer) {
        self.forget();
        // SAFETY: outside any render pass; the pool has `capacity` queries.
        unsafe { device.cmd_reset_query_pool(cmd, self.pool, 0, self.capacity.max(1)) };
    }

    /// Opens scope `name` in command buffer `cmd` being recorded.
    pub(crate) fn begin_raw(&mut self, device: &ash::Device, cmd: ash::vk::CommandBuffer, name: &str) -> Result<()> {
        let q = self.next_query()?;
        write_timestamp(device, cmd, self.pool, q);
        self.scopes.push(Scope { name: name.into(), depth: self.open.len(), begin: q, end: None });
        self.open.push(self.scopes.len() - 1);
        Ok(())
    }

    /// Closes the innermost open scope in command buffer `cmd` being recorded.
    pub(crate) fn end_raw(&mut self, device: &ash::Device, cmd: ash::vk::CommandBuffer) -> Result<()> {
        let idx = self.open.pop().ok_or_else(|| GpuError::Profiler("end() without begin()".into()))?;
        let q = self.next_query()?;
        write_timestamp(device, cmd, self.pool, q);
        self.scopes[idx].end = Some(q);
        Ok(())
    }

    fn next_query(&mut self) -> Result<u32> {
        if self.used >= self.capacity {
            return Err(GpuError::Profiler(format!("more than {} scopes in one recording", self.capacity / 2)));
        }
        self.used += 1;
        Ok(self.used - 1)
    }

    /// Opens scope `name` (nested inside any open scope).
    pub fn begin(&mut self, rec: &mut Recorder, name: &str) -> Result<()> {
        let (device, cmd) = rec.raw();
        self.begin_raw(device, cmd, name)
    }

    /// Closes the innermost open scope.
    pub fn end(&mut self, rec: &mut Recorder) -> Result<()> {
        let (device, cmd) = rec.raw();
        self.end_raw(device, cmd)
    }

    /// Runs `f` inside scope `name`.
    pub fn scope<R>(&mut self, rec: &mut Recorder, name: &str, f: impl FnOnce(&mut Recorder, &mut Self) -> Result<R>) -> Result<R> {
        self.begin(rec, name)?;
        let r = f(rec, self)?;
        self.end(rec)?;
        Ok(r)
    }

    /// Reads the scope times of the last completed submission, in recording order.
    pub fn results(&self) -> Result<Vec<ScopeTime>> {
        if !self.open.is_empty() {
            return Err(GpuError::Profiler(format!("scope '{}' never ended", self.scopes[self.open[0]].name)));
        }
        if self.used == 0 {
            return Ok(Vec::new());
        }
        let mut ticks = vec![0u64; self.used as usize];
        // SAFETY: all `used` queries were written by the submitted recording; WAIT blocks
        // until they are available.
        unsafe { self.ctx.device.get_query_pool_results(self.pool, 0, &mut ticks, vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT) }
            .map_err(vk_err("vkGetQueryPoolResults"))?;
        let mask = self.ctx.timestamp_mask;
        let period = self.ctx.info().timestamp_period_ns as f64;
        Ok(self
            .scopes
            .iter()
            .map(|s| {
                let b = ticks[s.begin as usize] & mask;
                let e = ticks[s.end.unwrap_or(s.begin) as usize] & mask;
                // Timestamps wrap at the valid-bit width.
                let dt = e.wrapping_sub(b) & mask;
                ScopeTime { name: s.name.clone(), depth: s.depth, ms: dt as f64 * period * 1e-6 }
            })
            .collect())
    }

    /// Sum of the times of every scope called `name`.
    pub fn total_ms(times: &[ScopeTime], name: &str) -> f64 {
        times.iter().filter(|t| t.name == name).map(|t| t.ms).sum()
    }
}

impl Drop for Profiler {
    fn drop(&mut self) {
        // SAFETY: the owner waits for submissions that write these queries before dropping.
        unsafe { self.ctx.device.destroy_query_pool(self.pool, None) };
    }
}
