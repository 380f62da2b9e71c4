//! What a kernel declares, read from its SPIR-V with spirq: descriptor bindings by name,
//! push-constant size, workgroup size, specialization constants, struct layouts.
//!
//! spirq is used rather than spirv-reflect 0.2.3, which aborts on SPIR-V 1.4+ and on
//! SPIR-V 1.3 returns no storage-buffer bindings; the kernels here are SPIR-V 1.6.

use super::{GpuError, Result};
use spirq::prelude::*;
use spirq::ty::{AccessType, DescriptorType, ImageFormat, ScalarType, Type};

/// One descriptor binding.
#[derive(Clone, Debug)]
pub struct BindingInfo {
    pub set: u32,
    pub binding: u32,
    /// Instance name and block name, both usable to bind it.
    pub names: Vec<String>,
    pub access: BindingAccess,
    pub kind: BindingKind,
}

/// What a binding is: a storage buffer (`buffer` block), or a buffer read through 4-component
/// 32-bit texels (`samplerBuffer`, `usamplerBuffer`, `isamplerBuffer`: a uniform texel buffer).
/// Texel fetches take the sampler path: on lavapipe that is a vector gather where a
/// storage-buffer load is a loop over the SIMD lanes, and on GPUs it goes through the texture
/// cache.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindingKind {
    StorageBuffer,
    TexelBuffer(TexelType),
    /// A read-only storage texel buffer (`readonly uimageBuffer` and the like, format
    /// rgba32ui/rgba32f/rgba32i): the same texels read by image loads.
    ImageBuffer(TexelType),
}

impl BindingKind {
    /// The component type of a binding read as 16-byte texels (either kind of texel buffer).
    pub fn texel(self) -> Option<TexelType> {
        match self {
            BindingKind::StorageBuffer => None,
            BindingKind::TexelBuffer(t) | BindingKind::ImageBuffer(t) => Some(t),
        }
    }
}

/// Component type of a texel buffer; the host views the buffer as R32G32B32A32 of this type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TexelType {
    Float,
    Uint,
    Int,
}

/// How a kernel accesses a storage buffer, from its `readonly`/`writeonly` qualifiers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindingAccess {
    Read,
    Write,
    ReadWrite,
}

/// Scalar type of a specialization constant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpecKind {
    Bool,
    U32,
    I32,
    F32,
}

/// A specialization constant by name (local-size constants are named `local_size_x` etc).
#[derive(Clone, Debug)]
pub struct SpecInfo {
    pub name: String,
    pub id: u32,
    pub kind: SpecKind,
}

/// One dimension of the workgroup size: a literal, or a specialization constant.
#[derive(Clone, Copy, Debug)]
pub enum LocalSize {
    Fixed(u32),
    Spec { id: u32, default: u32 },
}

/// Everything the host needs to know about one compute kernel.
#[derive(Clone, Debug)]
pub struct Reflection {
    pub kernel: String,
    pub bindings: Vec<BindingInfo>,
    pub push_constant_size: u32,
    /// Names and byte offsets of the push block's top-level members, in order.
    pub push_members: Vec<(String, usize)>,
    pub local_size: [LocalSize; 3],
    pub spec_constants: Vec<SpecInfo>,
    structs: Vec<spirq::ty::StructType>,
}

fn err(kernel: &str, msg: impl Into<String>) -> GpuError {
    GpuError::Reflect { kernel: kernel.to_string(), msg: msg.into() }
}

fn collect_structs(ty: &Type, out: &mut Vec<spirq::ty::StructType>) {
    match ty {
        Type::Struct(s) => {
            out.push(s.clone());
            for m in &s.members {
                collect_structs(&m.ty, out);
            }
        }
        Type::Array(a) => collect_structs(&a.element_ty, out),
        _ => {}
    }
}

impl Reflection {
    /// Reflects the single compute entry point `main` of `spirv`.
    /// Not split: one walk over the entry point's variables and types, each collected where
    /// the walk meets it.
    pub fn new(kernel: &str, spirv: &[u8]) -> Result<Self> {
        if !spirv.len().is_multiple_of(4) {
            return Err(err(kernel, "SPIR-V length is not a multiple of 4"));
        }
        let words: Vec<u32> = spirv.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        let entries = ReflectConfig::new().spv(words).ref_all_rscs(true).reflect().map_err(|e| err(kernel, e.to_string()))?;
        let entry = entries.into_iter().find(|e| e.name == "main").ok_or_else(|| err(kernel, "no entry point named main"))?;

        let mut bindings: Vec<BindingInfo> = Vec::new();
        let mut push_constant_size = 0;
        let mut push_members = Vec::new();
        let mut spec_constants = Vec::new();
        let mut structs = Vec::new();
        for var in &entry.vars {
            match var {
                Variable::Descriptor { name, desc_bind, desc_ty, ty, .. } => {
                    let (access, kind) = match desc_ty {
                        DescriptorType::StorageBuffer(a) => (
                            match a {
                                AccessType::ReadOnly => BindingAccess::Read,
                                AccessType::WriteOnly => BindingAccess::Write,
                                AccessType::ReadWrite => BindingAccess::ReadWrite,
                            },
                            BindingKind::StorageBuffer,
                        ),
                        DescriptorType::UniformTexelBuffer() => {
                            let scalar = match ty {
                                Type::CombinedImageSampler(t) => &t.sampled_image_ty.scalar_ty,
                                Type::SampledImage(t) => &t.scalar_ty,
                                other => return Err(err(kernel, format!("texel buffer of unexpected type {other:?}"))),
                            };
                            let texel = match scalar {
                                ScalarType::Float { bits: 32 } => TexelType::Float,
                                ScalarType::Integer { bits: 32, is_signed: false } => TexelType::Uint,
                                ScalarType::Integer { bits: 32, is_signed: true } => TexelType::Int,
                                other => return Err(err(kernel, format!("texel buffer of unsupported component type {other:?}"))),
                            };
                            (BindingAccess::Read, BindingKind::TexelBuffer(texel))
                        }
                        DescriptorType::StorageTexelBuffer(AccessType::ReadOnly) => {
                            let texel = match ty {
                                Type::StorageImage(t) => match t.fmt {
                                    ImageFormat::Rgba32ui => TexelType::Uint,
                                    ImageFormat::Rgba32f => TexelType::Float,
                                    ImageFormat::Rgba32i => TexelType::Int,
                                    other => return Err(err(kernel, format!("image buffer of unsupported format {other:?}"))),
                                },
                                other => return Err(err(kernel, format!("image buffer of unexpected type {other:?}"))),
                            };
                            (BindingAccess::Read, BindingKind::ImageBuffer(texel))
                        }
                        other => return Err(err(kernel, format!("unsupported descriptor type {other:?}"))),
                    };
                    let mut names = Vec::new();
                    if let Some(n) = name.as_ref().filter(|n| !n.is_empty()) {
                        names.push(n.clone());
                    }
                    if let Type::Struct(s) = ty {
                        if let Some(n) = s.name.as_ref().filter(|n| !n.is_empty()) {
                            names.push(n.clone());
                        }
                    }
                    if names.is_empty() {
                        return Err(err(kernel, format!("binding {} has no name", desc_bind.bind())));
                    }
                    collect_structs(ty, &mut structs);
                    bindings.push(BindingInfo { set: desc_bind.set(), binding: desc_bind.bind(), names, access, kind });
                }
                Variable::PushConstant { ty, .. } => {
                    push_constant_size = ty.nbyte().ok_or_else(|| err(kernel, "unsized push-constant block"))? as u32;
                    if let Type::Struct(s) = ty {
                        push_members = s.members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset.unwrap_or(usize::MAX))).collect();
                    }
                    collect_structs(ty, &mut structs);
                }
                Variable::SpecConstant { name, spec_id, ty } => {
                    let kind = match ty {
                        Type::Scalar(ScalarType::Boolean) => SpecKind::Bool,
                        Type::Scalar(ScalarType::Integer { bits: 32, is_signed: false }) => SpecKind::U32,
                        Type::Scalar(ScalarType::Integer { bits: 32, is_signed: true }) => SpecKind::I32,
                        Type::Scalar(ScalarType::Float { bits: 32 }) => SpecKind::F32,
                        other => return Err(err(kernel, format!("unsupported specialization constant type {other:?}"))),
                    };
                    if let Some(name) = name {
                        spec_constants.push(SpecInfo { name: name.clone(), id: *spec_id, kind });
                    }
                }
                _ => {}
            }
        }
        if bindings.iter().any(|b| b.set != 0) {
            return Err(err(kernel, "every binding must be in set 0"));
        }
        bindings.sort_by_key(|b| b.binding);

        let mut local_size = None;
        for mode in &entry.exec_modes {
            let dims = |i: usize| -> Result<LocalSize> {
                let c = mode.operands.get(i).ok_or_else(|| err(kernel, "short LocalSize"))?;
                let value = match &c.value {
                    spirq::constant::ConstantValue::U32(v) => *v,
                    spirq::constant::ConstantValue::S32(v) => *v as u32,
                    other => return Err(err(kernel, format!("local size constant {other:?}"))),
                };
                Ok(match c.spec_id {
                    Some(id) => LocalSize::Spec { id, default: value },
                    None => LocalSize::Fixed(value),
                })
            };
            if matches!(mode.exec_mode, spirq::spirv::ExecutionMode::LocalSize | spirq::spirv::ExecutionMode::LocalSizeId) {
                local_size = Some([dims(0)?, dims(1)?, dims(2)?]);
            }
        }
        let local_size = local_size.ok_or_else(|| err(kernel, "no LocalSize execution mode"))?;
        for (axis, dim) in ["local_size_x", "local_size_y", "local_size_z"].iter().zip(local_size) {
            if let LocalSize::Spec { id, .. } = dim {
                spec_constants.retain(|s| s.id != id);
                spec_constants.push(SpecInfo { name: axis.to_string(), id, kind: SpecKind::U32 });
            }
        }
        Ok(Self { kernel: kernel.to_string(), bindings, push_constant_size, push_members, local_size, spec_constants, structs })
    }

    /// The binding called `name` (instance or block name).
    pub fn binding(&self, name: &str) -> Option<&BindingInfo> {
        self.bindings.iter().find(|b| b.names.iter().any(|n| n == name))
    }

    /// Member names and byte offsets of the struct type called `name`, if the kernel uses it.
    pub fn struct_layout(&self, name: &str) -> Option<Vec<(String, usize)>> {
        let s = self.structs.iter().find(|s| s.name.as_deref() == Some(name))?;
        Some(s.members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset.unwrap_or(usize::MAX))).collect())
    }

    /// Byte size of the struct type called `name` (offset of its last member plus its size).
    pub fn struct_size(&self, name: &str) -> Option<usize> {
        let s = self.structs.iter().find(|s| s.name.as_deref() == Some(name))?;
        let last = s.members.last()?;
        Some(last.offset? + last.ty.nbyte()?)
    }
}
