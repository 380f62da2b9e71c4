//! Compute pipelines built from reflected SPIR-V, and bind groups filled by GLSL name.

use super::reflect::{BindingAccess, BindingInfo, BindingKind, LocalSize, Reflection, SpecKind, TexelType};
use super::{shaders, vk_err, Access, Buffer, Context, DescriptorLimits, GpuError, PushBlock, Result};
use ash::vk;
use std::sync::Arc;

/// A specialization-constant value.
#[derive(Clone, Copy, Debug)]
pub enum SpecValue {
    Bool(bool),
    U32(u32),
    I32(i32),
    F32(f32),
}

impl SpecValue {
    fn kind_name(self) -> &'static str {
        match self {
            SpecValue::Bool(_) => "bool",
            SpecValue::U32(_) => "uint",
            SpecValue::I32(_) => "int",
            SpecValue::F32(_) => "float",
        }
    }

    fn bytes(self) -> [u8; 4] {
        match self {
            // VkBool32 is 4 bytes.
            SpecValue::Bool(b) => (b as u32).to_le_bytes(),
            SpecValue::U32(v) => v.to_le_bytes(),
            SpecValue::I32(v) => v.to_le_bytes(),
            SpecValue::F32(v) => v.to_le_bytes(),
        }
    }
}

/// A compute pipeline and the layouts it created; destroyed when the last handle goes
/// (recordings that use it hold one).
#[derive(Clone)]
pub struct ComputePipeline(Arc<PipelineInner>);

pub(crate) struct PipelineInner {
    ctx: Arc<Context>,
    reflection: Reflection,
    local_size: [u32; 3],
    set_layout: vk::DescriptorSetLayout,
    layout: vk::PipelineLayout,
    pipeline: vk::Pipeline,
}

impl ComputePipeline {
    /// Builds kernel `kernel` (a `glsl/*.comp` file stem or declared variant) with the
    /// given specialization constants, by name.
    pub fn new(ctx: &Arc<Context>, kernel: &str, spec: &[(&str, SpecValue)]) -> Result<Self> {
        let spirv = shaders::get(kernel).ok_or_else(|| GpuError::UnknownKernel(kernel.into()))?;
        Self::from_spirv(ctx, kernel, spirv, spec)
    }

    /// Builds a pipeline from SPIR-V bytes.
    pub fn from_spirv(ctx: &Arc<Context>, kernel: &str, spirv: &[u8], spec: &[(&str, SpecValue)]) -> Result<Self> {
        let reflection = Reflection::new(kernel, spirv)?;
        let mut entries = Vec::new();
        let mut data = Vec::new();
        for (name, value) in spec {
            let info = reflection
                .spec_constants
                .iter()
                .find(|s| s.name == *name)
                .ok_or_else(|| GpuError::UnknownSpecConstant { kernel: kernel.into(), name: name.to_string() })?;
            let ok = matches!(
                (info.kind, value),
                (SpecKind::Bool, SpecValue::Bool(_))
                    | (SpecKind::U32, SpecValue::U32(_))
                    | (SpecKind::I32, SpecValue::I32(_))
                    | (SpecKind::F32, SpecValue::F32(_))
            );
            if !ok {
                return Err(GpuError::SpecConstantType {
                    kernel: kernel.into(),
                    name: name.to_string(),
                    expected: format!("{:?}", info.kind),
                    got: value.kind_name(),
                });
            }
            entries.push(vk::SpecializationMapEntry { constant_id: info.id, offset: data.len() as u32, size: 4 });
            data.extend_from_slice(&value.bytes());
        }
        let local_size = reflection.local_size.map(|d| match d {
            LocalSize::Fixed(v) => v,
            LocalSize::Spec { id, default } => reflection
                .spec_constants
                .iter()
                .find(|s| s.id == id)
                .and_then(|s| spec.iter().find(|(n, _)| *n == s.name))
                .map(|(_, v)| match v {
                    SpecValue::U32(v) => *v,
                    _ => default,
                })
                .unwrap_or(default),
        });

        check_descriptor_limits(kernel, &reflection.bindings, &ctx.info().name, ctx.info().descriptor_limits)?;
        let layout_bindings: Vec<_> = reflection
            .bindings
            .iter()
            .map(|b| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b.binding)
                    .descriptor_type(descriptor_type(b.kind))
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let dev = &ctx.device;
        // Declared before `partial`, so that an error path's destruction holds it too.
        let _made = super::context::pipelines_made();
        // SAFETY: create infos reference locals alive for each call; on failure every
        // object made so far is destroyed by `Partial`'s drop.
        let mut partial = Partial { dev, set_layout: None, layout: None, module: None };
        let set_layout = unsafe { dev.create_descriptor_set_layout(&vk::DescriptorSetLayoutCreateInfo::default().bindings(&layout_bindings), None) }
            .map_err(vk_err("vkCreateDescriptorSetLayout"))?;
        partial.set_layout = Some(set_layout);
        let ranges = [vk::PushConstantRange::default().stage_flags(vk::ShaderStageFlags::COMPUTE).size(reflection.push_constant_size)];
        let set_layouts = [set_layout];
        let mut layout_info = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts);
        if reflection.push_constant_size > 0 {
            layout_info = layout_info.push_constant_ranges(&ranges);
        }
        let layout = unsafe { dev.create_pipeline_layout(&layout_info, None) }.map_err(vk_err("vkCreatePipelineLayout"))?;
        partial.layout = Some(layout);
        let words: Vec<u32> = spirv.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        let module = unsafe { dev.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&words), None) }.map_err(vk_err("vkCreateShaderModule"))?;
        partial.module = Some(module);
        let spec_info = vk::SpecializationInfo::default().map_entries(&entries).data(&data);
        let stage =
            vk::PipelineShaderStageCreateInfo::default().stage(vk::ShaderStageFlags::COMPUTE).module(module).name(c"main").specialization_info(&spec_info);
        let info = [vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout)];
        let pipeline =
            unsafe { dev.create_compute_pipelines(vk::PipelineCache::null(), &info, None) }.map_err(|(_, e)| vk_err("vkCreateComputePipelines")(e))?[0];
        // The module is no longer needed once the pipeline exists.
        unsafe { dev.destroy_shader_module(module, None) };
        std::mem::forget(partial);
        Ok(Self(Arc::new(PipelineInner { ctx: ctx.clone(), reflection, local_size, set_layout, layout, pipeline })))
    }

    pub fn name(&self) -> &str {
        &self.0.reflection.kernel
    }

    pub fn reflection(&self) -> &Reflection {
        &self.0.reflection
    }

    /// Checks that `P` mirrors this kernel's push block: its size and every member's name
    /// and byte offset, in order.
    pub fn check_push<P: PushBlock>(&self) -> Result<()> {
        let r = &self.0.reflection;
        let size = std::mem::size_of::<P>();
        if size != r.push_constant_size as usize {
            return Err(GpuError::PushConstantSize { kernel: r.kernel.clone(), expected: r.push_constant_size, got: size });
        }
        let same = r.push_members.len() == P::MEMBERS.len() && r.push_members.iter().zip(P::MEMBERS).all(|((a, x), (b, y))| a == b && x == y);
        if !same {
            let show = |m: &mut dyn Iterator<Item = (&str, usize)>| m.map(|(n, o)| format!("{n}@{o}")).collect::<Vec<_>>().join(" ");
            return Err(GpuError::PushLayout {
                kernel: r.kernel.clone(),
                reflected: show(&mut r.push_members.iter().map(|(n, o)| (n.as_str(), *o))),
                host: show(&mut P::MEMBERS.iter().copied()),
            });
        }
        Ok(())
    }

    /// Workgroup size after specialization.
    pub fn local_size(&self) -> [u32; 3] {
        self.0.local_size
    }

    pub(crate) fn raw(&self) -> (vk::Pipeline, vk::PipelineLayout) {
        (self.0.pipeline, self.0.layout)
    }

    /// Binds buffers to this kernel's bindings by GLSL name (block instance or block
    /// name). Every binding must be given exactly once.
    pub fn bind(&self, resources: &[(&str, &Buffer)]) -> Result<BindGroup> {
        let me = &self.0;
        let kernel = &me.reflection.kernel;
        let mut slots: Vec<Option<Buffer>> = vec![None; me.reflection.bindings.len()];
        for (name, buf) in resources {
            let idx = me.reflection.bindings.iter().position(|b| b.names.iter().any(|n| n == name)).ok_or_else(|| GpuError::UnknownBinding {
                kernel: kernel.clone(),
                name: name.to_string(),
                known: me.reflection.bindings.iter().map(|b| b.names.join("/")).collect::<Vec<_>>().join(", "),
            })?;
            slots[idx] = Some((*buf).clone());
        }
        let mut bound = Vec::new();
        for (info, slot) in me.reflection.bindings.iter().zip(slots) {
            let buf = slot.ok_or_else(|| GpuError::UnboundBinding { kernel: kernel.clone(), name: info.names[0].clone() })?;
            let access = match info.access {
                BindingAccess::Read => Access::ComputeRead,
                BindingAccess::Write => Access::ComputeWrite,
                BindingAccess::ReadWrite => Access::ComputeReadWrite,
            };
            bound.push(Bound { binding: info.binding, buffer: buf, access, kind: info.kind, name: info.names[0].clone() });
        }
        BindGroup::new(&me.ctx, me.set_layout, kernel, bound)
    }
}

/// Fails with [`GpuError::TooManyDescriptors`] where a kernel's bindings exceed one of the
/// device's per-stage limits, instead of an invalid pipeline layout.
pub fn check_descriptor_limits(kernel: &str, bindings: &[BindingInfo], device: &str, limits: DescriptorLimits) -> Result<()> {
    let count = |f: fn(BindingKind) -> bool| bindings.iter().filter(|b| f(b.kind)).count() as u32;
    let checks = [
        ("storage buffers", "maxPerStageDescriptorStorageBuffers", count(|k| k == BindingKind::StorageBuffer), limits.storage_buffers),
        ("storage texel buffers", "maxPerStageDescriptorStorageImages", count(|k| matches!(k, BindingKind::ImageBuffer(_))), limits.storage_images),
        ("uniform texel buffers", "maxPerStageDescriptorSampledImages", count(|k| matches!(k, BindingKind::TexelBuffer(_))), limits.sampled_images),
        ("descriptors", "maxPerStageResources", bindings.len() as u32, limits.resources),
    ];
    match checks.into_iter().find(|c| c.2 > c.3) {
        Some((what, limit, count, max)) => Err(GpuError::TooManyDescriptors { kernel: kernel.into(), device: device.into(), what, count, max, limit }),
        None => Ok(()),
    }
}

fn descriptor_type(kind: BindingKind) -> vk::DescriptorType {
    match kind {
        BindingKind::StorageBuffer => vk::DescriptorType::STORAGE_BUFFER,
        BindingKind::TexelBuffer(_) => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
        BindingKind::ImageBuffer(_) => vk::DescriptorType::STORAGE_TEXEL_BUFFER,
    }
}

/// Bytes of one texel of a texel-buffer view: four 32-bit components.
pub const TEXEL_BYTES: u64 = 16;

/// `n` 32-bit values rounded up to whole texels, at least one texel: the length of a texel
/// buffer that holds them.
pub fn texel_padded(n: usize) -> usize {
    let per_texel = TEXEL_BYTES as usize / 4;
    n.div_ceil(per_texel).max(1) * per_texel
}

fn texel_format(t: TexelType) -> vk::Format {
    match t {
        TexelType::Float => vk::Format::R32G32B32A32_SFLOAT,
        TexelType::Uint => vk::Format::R32G32B32A32_UINT,
        TexelType::Int => vk::Format::R32G32B32A32_SINT,
    }
}

/// One buffer of a bind group.
pub(crate) struct Bound {
    binding: u32,
    buffer: Buffer,
    access: Access,
    kind: BindingKind,
    /// The kernel's name for the binding (for errors).
    name: String,
}

/// Destroys what a half-built pipeline made.
struct Partial<'a> {
    dev: &'a ash::Device,
    set_layout: Option<vk::DescriptorSetLayout>,
    layout: Option<vk::PipelineLayout>,
    module: Option<vk::ShaderModule>,
}

impl Drop for Partial<'_> {
    fn drop(&mut self) {
        // SAFETY: reached only on an error path; none of these objects is in use.
        unsafe {
            if let Some(m) = self.module {
                self.dev.destroy_shader_module(m, None);
            }
            if let Some(l) = self.layout {
                self.dev.destroy_pipeline_layout(l, None);
            }
            if let Some(s) = self.set_layout {
                self.dev.destroy_descriptor_set_layout(s, None);
            }
        }
    }
}

impl Drop for PipelineInner {
    fn drop(&mut self) {
        // SAFETY: recordings that use this pipeline hold a handle, so the last handle goes
        // only once no pending work uses it.
        let _made = super::context::pipelines_made();
        unsafe {
            self.ctx.device.destroy_pipeline(self.pipeline, None);
            self.ctx.device.destroy_pipeline_layout(self.layout, None);
            self.ctx.device.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

/// A descriptor set with its buffers, owned together: the buffers live as long as the
/// set, and recordings that use the set hold a handle to it.
#[derive(Clone)]
pub struct BindGroup(pub(crate) Arc<BindGroupInner>);

pub(crate) struct BindGroupInner {
    ctx: Arc<Context>,
    kernel: String,
    pool: vk::DescriptorPool,
    pub(crate) set: vk::DescriptorSet,
    /// (binding, buffer, how the kernel accesses it)
    pub(crate) buffers: Vec<(u32, Buffer, Access)>,
    /// Views of the buffers bound as texel buffers.
    views: Vec<vk::BufferView>,
}

impl BindGroup {
    /// The buffer bound at `binding`, if any.
    pub fn bound(&self, binding: u32) -> Option<&Buffer> {
        self.0.buffers.iter().find(|(b, _, _)| *b == binding).map(|(_, buf, _)| buf)
    }

    fn new(ctx: &Arc<Context>, layout: vk::DescriptorSetLayout, kernel: &str, bound: Vec<Bound>) -> Result<Self> {
        let dev = &ctx.device;
        // Texel buffers are viewed whole, as 16-byte texels; the view must fit the
        // device's limit and cannot end in a partial texel.
        let max_texels = ctx.info().max_texel_buffer_elements;
        let max_storage = ctx.info().max_storage_buffer_range;
        for b in &bound {
            if b.kind == BindingKind::StorageBuffer && b.buffer.storage_extent() > max_storage {
                return Err(GpuError::BufferTooLarge {
                    name: format!("{}, bound to storage buffer '{}' of kernel '{kernel}'", b.buffer.name(), b.name),
                    size: b.buffer.storage_extent(),
                    max: max_storage,
                    limit: "storage-buffer range",
                });
            }
            if b.kind.texel().is_some() {
                let len = b.buffer.len();
                if len % TEXEL_BYTES != 0 || len / TEXEL_BYTES > max_texels {
                    return Err(GpuError::BufferAccess {
                        name: b.buffer.name().to_string(),
                        what: format!(
                            "bound to texel buffer '{}' of kernel '{kernel}': {len} bytes is not a whole number of \
                             {TEXEL_BYTES}-byte texels within the device's {max_texels}",
                            b.name
                        ),
                    });
                }
            }
        }
        let mut sizes: Vec<vk::DescriptorPoolSize> = Vec::new();
        for b in &bound {
            let ty = descriptor_type(b.kind);
            match sizes.iter_mut().find(|s| s.ty == ty) {
                Some(s) => s.descriptor_count += 1,
                None => sizes.push(vk::DescriptorPoolSize { ty, descriptor_count: 1 }),
            }
        }
        if sizes.is_empty() {
            sizes.push(vk::DescriptorPoolSize { ty: vk::DescriptorType::STORAGE_BUFFER, descriptor_count: 1 });
        }
        // SAFETY: valid create/allocate infos; the pool is destroyed if allocation fails.
        let pool = unsafe { dev.create_descriptor_pool(&vk::DescriptorPoolCreateInfo::default().max_sets(1).pool_sizes(&sizes), None) }
            .map_err(vk_err("vkCreateDescriptorPool"))?;
        // From here on, the group owns the pool and the views made so far: its drop frees
        // them on any error below.
        let mut group = BindGroupInner {
            ctx: ctx.clone(),
            kernel: kernel.to_string(),
            pool,
            set: vk::DescriptorSet::null(),
            buffers: bound.iter().map(|b| (b.binding, b.buffer.clone(), b.access)).collect(),
            views: Vec::new(),
        };
        let layouts = [layout];
        group.set = unsafe { dev.allocate_descriptor_sets(&vk::DescriptorSetAllocateInfo::default().descriptor_pool(pool).set_layouts(&layouts)) }
            .map_err(vk_err("vkAllocateDescriptorSets"))?[0];
        // One view slot per binding (null for storage buffers), for the descriptor writes.
        let mut views: Vec<[vk::BufferView; 1]> = Vec::with_capacity(bound.len());
        for b in &bound {
            views.push([match b.kind.texel() {
                None => vk::BufferView::null(),
                Some(t) => {
                    let info = vk::BufferViewCreateInfo::default().buffer(b.buffer.0.raw).format(texel_format(t)).offset(0).range(vk::WHOLE_SIZE);
                    // SAFETY: the buffer has both texel-buffer usages and a whole number of
                    // texels (checked above); the group destroys the view.
                    let view = unsafe { dev.create_buffer_view(&info, None) }.map_err(vk_err("vkCreateBufferView"))?;
                    group.views.push(view);
                    view
                }
            }]);
        }
        // A storage binding sees the buffer's storage extent (all of it unless the buffer
        // says less).
        let range = |b: &Bound| if b.buffer.storage_extent() < b.buffer.len() { b.buffer.storage_extent() } else { vk::WHOLE_SIZE };
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> =
            bound.iter().map(|b| [vk::DescriptorBufferInfo { buffer: b.buffer.0.raw, offset: 0, range: range(b) }]).collect();
        let writes: Vec<_> = bound
            .iter()
            .zip(infos.iter().zip(&views))
            .map(|(b, (info, view))| {
                let w = vk::WriteDescriptorSet::default().dst_set(group.set).dst_binding(b.binding).descriptor_type(descriptor_type(b.kind));
                match b.kind {
                    BindingKind::StorageBuffer => w.buffer_info(info),
                    BindingKind::TexelBuffer(_) | BindingKind::ImageBuffer(_) => w.texel_buffer_view(view),
                }
            })
            .collect();
        // SAFETY: the set is not in use by any command buffer yet; the views live as long
        // as the group.
        unsafe { dev.update_descriptor_sets(&writes, &[]) };
        Ok(Self(Arc::new(group)))
    }

    /// The buffers bound, in binding order.
    pub fn buffers(&self) -> impl Iterator<Item = &Buffer> {
        self.0.buffers.iter().map(|(_, b, _)| b)
    }

    /// The kernel this group was made for.
    pub fn kernel(&self) -> &str {
        &self.0.kernel
    }
}

impl Drop for BindGroupInner {
    fn drop(&mut self) {
        // SAFETY: destroying the pool frees its set; recordings hold a handle, so no
        // pending work uses it or the views.
        unsafe {
            for v in &self.views {
                self.ctx.device.destroy_buffer_view(*v, None);
            }
            self.ctx.device.destroy_descriptor_pool(self.pool, None);
        }
    }
}
