//! Named storage buffers allocated through gpu-allocator and freed on drop.
//!
//! A [`Buffer`] is a cheap handle (`Arc` inside): bind groups keep the buffers they bind
//! alive. Zero-length buffers are legal at this level (a kernel over 0 elements); they
//! are backed by a 16-byte allocation because Vulkan forbids empty buffers.

use super::transfers::Counters;
use super::{vk_err, Context, GpuError, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Where a buffer lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MemoryKind {
    /// Device-local; filled and read through the context's staging buffers unless it
    /// happens to be mapped (and the context allows mapping it).
    Device,
    /// Host-visible, written by the host, read by the device.
    Upload,
    /// Host-visible, written by the device, read by the host.
    Readback,
}

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

pub(crate) struct BufferInner {
    pub(crate) ctx: Arc<Context>,
    pub(crate) raw: vk::Buffer,
    pub(crate) id: u64,
    allocation: Mutex<Option<Allocation>>,
    name: String,
    len: u64,
    /// What a storage-buffer binding sees ([`Buffer::set_storage_extent`]).
    storage_extent: AtomicU64,
    kind: MemoryKind,
}

/// A named GPU buffer. Cloning clones the handle, not the memory.
#[derive(Clone)]
pub struct Buffer(pub(crate) Arc<BufferInner>);

impl Buffer {
    /// The buffer's number, unique in the process (its clones share it).
    pub fn id(&self) -> u64 {
        self.0.id
    }

    /// Allocates `len` bytes (contents undefined): up to the larger of the device's
    /// storage-buffer range and its texel-buffer range, since a buffer may be bound as
    /// either. A storage-buffer binding sees at most the storage range
    /// ([`Buffer::set_storage_extent`]); binding more is an error then.
    pub fn new(ctx: &Arc<Context>, name: &str, len: u64, kind: MemoryKind) -> Result<Self> {
        let max = bindable_bytes(ctx);
        if len > max {
            return Err(GpuError::BufferTooLarge { name: name.into(), size: len, max, limit: "storage- and texel-buffer ranges" });
        }
        let physical = len.max(16);
        // Any buffer may also be bound as a texel buffer (read through texel fetches or
        // image loads).
        let info = vk::BufferCreateInfo::default().size(physical).usage(
            vk::BufferUsageFlags::STORAGE_BUFFER
                | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER
                | vk::BufferUsageFlags::STORAGE_TEXEL_BUFFER
                | vk::BufferUsageFlags::TRANSFER_SRC
                | vk::BufferUsageFlags::TRANSFER_DST,
        );
        let location = match kind {
            MemoryKind::Device => MemoryLocation::GpuOnly,
            MemoryKind::Upload => MemoryLocation::CpuToGpu,
            MemoryKind::Readback => MemoryLocation::GpuToCpu,
        };
        let (raw, allocation) = allocate_bound(ctx, name, &info, location)?;
        Counters::add(&ctx.counters.buffers, 1);
        Ok(Self(Arc::new(BufferInner {
            ctx: ctx.clone(),
            raw,
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            allocation: Mutex::new(Some(allocation)),
            name: name.into(),
            len,
            storage_extent: AtomicU64::new(len),
            kind,
        })))
    }

    /// Storage-buffer bindings of this buffer see its first `bytes` only (a whole number of
    /// 16-byte texels, at least one): the rest is read through texel-buffer views alone,
    /// which reach further on most devices. Set before the buffer is bound.
    pub fn set_storage_extent(&self, bytes: u64) {
        let bytes = bytes.next_multiple_of(16).clamp(16, self.0.len.max(16));
        self.0.storage_extent.store(bytes, Ordering::Relaxed);
    }

    /// The bytes a storage-buffer binding of this buffer sees: its length unless
    /// [`Buffer::set_storage_extent`] said less.
    pub fn storage_extent(&self) -> u64 {
        self.0.storage_extent.load(Ordering::Relaxed).min(self.0.len)
    }

    /// Allocates a buffer holding `data`.
    pub fn from_slice<T: bytemuck::Pod>(ctx: &Arc<Context>, name: &str, data: &[T], kind: MemoryKind) -> Result<Self> {
        let buf = Self::new(ctx, name, std::mem::size_of_val(data) as u64, kind)?;
        buf.write(data)?;
        Ok(buf)
    }

    /// A new device buffer named `name` holding a copy of this one (copied on the device,
    /// in one submission that is waited for), with the same storage extent.
    pub fn duplicate(&self, name: &str) -> Result<Self> {
        let copy = Self::new(&self.0.ctx, name, self.0.len, MemoryKind::Device)?;
        copy.set_storage_extent(self.storage_extent());
        let mut cmd = super::CommandBuffer::new(&self.0.ctx, name)?;
        cmd.record(|rec| rec.copy(self, &copy, self.0.len))?;
        cmd.submit_and_wait()?;
        Ok(copy)
    }

    /// Allocates a zero-filled buffer of `n` elements of `T`.
    pub fn zeroed<T: bytemuck::Pod>(ctx: &Arc<Context>, name: &str, n: usize, kind: MemoryKind) -> Result<Self> {
        Self::from_slice(ctx, name, &vec![T::zeroed(); n], kind)
    }

    pub fn name(&self) -> &str {
        &self.0.name
    }

    /// Whether both handles refer to the same buffer.
    pub fn same(&self, other: &Buffer) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }

    /// Length in bytes as requested.
    pub fn len(&self) -> u64 {
        self.0.len
    }

    pub fn is_empty(&self) -> bool {
        self.0.len == 0
    }

    pub fn kind(&self) -> MemoryKind {
        self.0.kind
    }

    fn check_len(&self, bytes: usize) -> Result<()> {
        if bytes as u64 > self.0.len {
            return Err(GpuError::BufferAccess { name: self.0.name.clone(), what: format!("{bytes} bytes do not fit in {} bytes", self.0.len) });
        }
        Ok(())
    }

    /// Runs `f` on the mapped bytes, if the memory is host-visible (and, for a device
    /// buffer, the context allows mapping it).
    fn with_mapped<R>(&self, f: impl FnOnce(&mut [u8]) -> R) -> Option<R> {
        if self.0.kind == MemoryKind::Device && !self.0.ctx.device_mappable {
            return None;
        }
        let mut guard = self.0.allocation.lock().unwrap_or_else(|p| p.into_inner());
        let slice = guard.as_mut()?.mapped_slice_mut()?;
        Some(f(&mut slice[..self.0.len as usize]))
    }

    /// Copies `data` to the start of the buffer. The caller must ensure that no submitted
    /// work uses the buffer (all submissions here are waited for before returning).
    pub fn write<T: bytemuck::Pod>(&self, data: &[T]) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        self.check_len(bytes.len())?;
        if bytes.is_empty() {
            return Ok(());
        }
        let ctx = &self.0.ctx;
        Counters::add(&ctx.counters.upload, bytes.len() as u64);
        if self.with_mapped(|m| m[..bytes.len()].copy_from_slice(bytes)).is_some() {
            return Ok(());
        }
        ctx.staging.lock().unwrap_or_else(|p| p.into_inner()).upload(ctx, self.0.raw, bytes)
    }

    /// Reads the first `len() / size_of::<T>()` elements.
    pub fn read<T: bytemuck::Pod>(&self) -> Result<Vec<T>> {
        self.read_prefix(self.0.len as usize / std::mem::size_of::<T>())
    }

    /// Reads the first `n` elements (at most `len() / size_of::<T>()`).
    pub fn read_prefix<T: bytemuck::Pod>(&self, n: usize) -> Result<Vec<T>> {
        let n = n.min(self.0.len as usize / std::mem::size_of::<T>());
        let mut out = vec![T::zeroed(); n];
        let nbytes = n * std::mem::size_of::<T>();
        if nbytes == 0 {
            return Ok(out);
        }
        let dst: &mut [u8] = bytemuck::cast_slice_mut(&mut out);
        let ctx = &self.0.ctx;
        Counters::add(&ctx.counters.readback, nbytes as u64);
        if self.with_mapped(|m| dst.copy_from_slice(&m[..nbytes])).is_some() {
            return Ok(out);
        }
        ctx.staging.lock().unwrap_or_else(|p| p.into_inner()).readback(ctx, self.0.raw, dst)?;
        Ok(out)
    }
}

/// The largest buffer the device can bind whole one way or another: the larger of its
/// storage-buffer range and its texel-buffer range (in 16-byte texels).
pub(crate) fn bindable_bytes(ctx: &Context) -> u64 {
    let info = ctx.info();
    info.max_storage_buffer_range.max(info.max_texel_buffer_bytes())
}

/// Creates a buffer and binds a new allocation of `location` memory to it; on failure
/// nothing is left behind.
pub(crate) fn allocate_bound(ctx: &Context, name: &str, info: &vk::BufferCreateInfo, location: MemoryLocation) -> Result<(vk::Buffer, Allocation)> {
    // SAFETY: valid create info on a live device.
    let raw = unsafe { ctx.device.create_buffer(info, None) }.map_err(vk_err("vkCreateBuffer"))?;
    let requirements = unsafe { ctx.device.get_buffer_memory_requirements(raw) };
    let allocation = ctx.allocator.lock().unwrap_or_else(|p| p.into_inner()).allocate(&AllocationCreateDesc {
        name,
        requirements,
        location,
        linear: true,
        allocation_scheme: AllocationScheme::GpuAllocatorManaged,
    });
    let allocation = match allocation {
        Ok(a) => a,
        Err(source) => {
            // SAFETY: the buffer was never bound or used.
            unsafe { ctx.device.destroy_buffer(raw, None) };
            return Err(GpuError::Alloc { name: name.into(), source });
        }
    };
    // SAFETY: the allocation satisfies `requirements` and is not bound elsewhere.
    if let Err(e) = unsafe { ctx.device.bind_buffer_memory(raw, allocation.memory(), allocation.offset()) } {
        unsafe { ctx.device.destroy_buffer(raw, None) };
        let _ = ctx.allocator.lock().unwrap_or_else(|p| p.into_inner()).free(allocation);
        return Err(vk_err("vkBindBufferMemory")(e));
    }
    Ok((raw, allocation))
}

impl Drop for BufferInner {
    fn drop(&mut self) {
        // SAFETY: the last handle is gone; command buffers that used this buffer hold a
        // handle through their bind groups, so no pending work references it.
        unsafe { self.ctx.device.destroy_buffer(self.raw, None) };
        if let Some(a) = self.allocation.lock().unwrap_or_else(|p| p.into_inner()).take() {
            let _ = self.ctx.allocator.lock().unwrap_or_else(|p| p.into_inner()).free(a);
        }
    }
}
