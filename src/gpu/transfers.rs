//! The transfer counters: every `Buffer::write` and `Buffer::read` is counted, mapped or
//! staged, so that benchmarks can report the host↔device bytes of an iteration.

use std::sync::atomic::{AtomicU64, Ordering};

/// Host↔device traffic through `Buffer::write` / `Buffer::read` since the context was
/// made (counters only grow).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TransferStats {
    /// Bytes written by the host into buffers (mapped or staged).
    pub upload_bytes: u64,
    /// Bytes read by the host from buffers (mapped or staged).
    pub readback_bytes: u64,
    /// Of those, the bytes that went through the staging buffers.
    pub staged_upload_bytes: u64,
    pub staged_readback_bytes: u64,
    /// Copy submissions made for staged transfers.
    pub staged_submissions: u64,
    /// GPU buffers created (`Buffer::new`) and staging buffers created.
    pub buffers_created: u64,
    pub staging_allocations: u64,
}

impl TransferStats {
    /// The counts from `earlier` to `self`.
    pub fn since(&self, earlier: &TransferStats) -> TransferStats {
        TransferStats {
            upload_bytes: self.upload_bytes - earlier.upload_bytes,
            readback_bytes: self.readback_bytes - earlier.readback_bytes,
            staged_upload_bytes: self.staged_upload_bytes - earlier.staged_upload_bytes,
            staged_readback_bytes: self.staged_readback_bytes - earlier.staged_readback_bytes,
            staged_submissions: self.staged_submissions - earlier.staged_submissions,
            buffers_created: self.buffers_created - earlier.buffers_created,
            staging_allocations: self.staging_allocations - earlier.staging_allocations,
        }
    }
}

#[derive(Default)]
pub(crate) struct Counters {
    pub upload: AtomicU64,
    pub readback: AtomicU64,
    pub staged_upload: AtomicU64,
    pub staged_readback: AtomicU64,
    pub submissions: AtomicU64,
    pub buffers: AtomicU64,
    pub staging_allocations: AtomicU64,
}

impl Counters {
    pub fn snapshot(&self) -> TransferStats {
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        TransferStats {
            upload_bytes: g(&self.upload),
            readback_bytes: g(&self.readback),
            staged_upload_bytes: g(&self.staged_upload),
            staged_readback_bytes: g(&self.staged_readback),
            staged_submissions: g(&self.submissions),
            buffers_created: g(&self.buffers),
            staging_allocations: g(&self.staging_allocations),
        }
    }

    pub fn add(a: &AtomicU64, n: u64) {
        a.fetch_add(n, Ordering::Relaxed);
    }
}
