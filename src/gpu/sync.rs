//! Semantic access types and their synchronization2 stage/access flags.
//!
//! Barriers are declared as "this buffer was last used as X and will next be used as Y";
//! the recorder checks X against what it actually recorded last (see commands.rs).

use ash::vk;

/// How a pass uses a buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    ComputeRead,
    ComputeWrite,
    ComputeReadWrite,
    TransferRead,
    TransferWrite,
    HostRead,
    HostWrite,
}

impl Access {
    /// Whether the access writes memory (and so needs a barrier before any later access).
    pub fn writes(self) -> bool {
        matches!(self, Access::ComputeWrite | Access::ComputeReadWrite | Access::TransferWrite | Access::HostWrite)
    }

    /// Whether memory made visible to `self` is visible to `other` too (same stage, and
    /// `self` includes `other`'s kind of access).
    pub fn covers(self, other: Access) -> bool {
        self == other || (self == Access::ComputeReadWrite && matches!(other, Access::ComputeRead | Access::ComputeWrite))
    }

    pub(crate) fn stage(self) -> vk::PipelineStageFlags2 {
        match self {
            Access::ComputeRead | Access::ComputeWrite | Access::ComputeReadWrite => vk::PipelineStageFlags2::COMPUTE_SHADER,
            Access::TransferRead | Access::TransferWrite => vk::PipelineStageFlags2::TRANSFER,
            Access::HostRead | Access::HostWrite => vk::PipelineStageFlags2::HOST,
        }
    }

    pub(crate) fn access(self) -> vk::AccessFlags2 {
        match self {
            // Reads are storage-buffer loads or texel-buffer fetches (sampled reads).
            Access::ComputeRead => vk::AccessFlags2::SHADER_STORAGE_READ | vk::AccessFlags2::SHADER_SAMPLED_READ,
            Access::ComputeWrite => vk::AccessFlags2::SHADER_STORAGE_WRITE,
            Access::ComputeReadWrite => vk::AccessFlags2::SHADER_STORAGE_READ | vk::AccessFlags2::SHADER_STORAGE_WRITE,
            Access::TransferRead => vk::AccessFlags2::TRANSFER_READ,
            Access::TransferWrite => vk::AccessFlags2::TRANSFER_WRITE,
            Access::HostRead => vk::AccessFlags2::HOST_READ,
            Access::HostWrite => vk::AccessFlags2::HOST_WRITE,
        }
    }
}
