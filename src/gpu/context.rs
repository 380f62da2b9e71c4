//! Instance, device selection, the compute queue and the allocator.
//!
//! Invariant: every GPU object holds an `Arc<Context>`, so the device (and the allocator,
//! which must go before it) is destroyed only after the last object using it.

use super::staging::{Staging, STAGING_NAME};
use super::transfers::{Counters, TransferStats};
use super::{vk_err, GpuError, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{c_void, CStr, CString};
use std::mem::ManuallyDrop;
use std::sync::{Arc, Mutex, OnceLock, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::Duration;

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// The Vulkan loader, loaded once per process and kept: every context shares it, so that
/// no context's end unloads the loader (and the drivers it loaded) under another.
static LOADER: OnceLock<std::result::Result<ash::Entry, String>> = OnceLock::new();

/// Held for writing while an instance and its device are made or destroyed, for reading
/// while a pipeline is (`pipelines_made`). Concurrent `vkCreateInstance`/`vkDestroyInstance`
/// and `vkCreateDevice`/`vkDestroyDevice` from different threads are legal Vulkan, but the
/// loader keeps process-global lists of instances and devices that some releases do not
/// lock everywhere, and NVIDIA's driver crashed when one thread destroyed an instance while
/// others created theirs (the test suite at 16 threads, `experiments/gpu-runs.md`). The validation
/// layer of Debian 12 (1.3.239) crashed in `vkCreateComputePipelines` on one device while
/// another thread was in `vkCreateDevice` (`gpu_layer` on lavapipe, about 1 run in 30), so
/// pipelines are made and destroyed only while no device is. Contexts are made rarely (one
/// per process in the command-line tool) and pipelines at start-up, so the lock seldom
/// makes a thread wait; pipelines of different contexts are still made at once.
static LIFECYCLE: RwLock<()> = RwLock::new(());

fn lifecycle() -> RwLockWriteGuard<'static, ()> {
    LIFECYCLE.write().unwrap_or_else(|p| p.into_inner())
}

/// Held while a pipeline and its layouts are made or destroyed: never while an instance or
/// device is ([`LIFECYCLE`]).
pub(crate) fn pipelines_made() -> RwLockReadGuard<'static, ()> {
    LIFECYCLE.read().unwrap_or_else(|p| p.into_inner())
}

fn loader() -> Result<ash::Entry> {
    // SAFETY: loading the system Vulkan loader; failure is reported, not assumed.
    let entry = LOADER.get_or_init(|| unsafe { ash::Entry::load() }.map_err(|e| e.to_string()));
    entry.clone().map_err(GpuError::Loader)
}

/// How to create a [`Context`].
#[derive(Clone, Debug, Default)]
pub struct ContextOptions {
    /// Device index or a case-insensitive part of its name; `None` picks the best device.
    pub device: Option<String>,
    /// Enable the Khronos validation layer with synchronization validation.
    pub validation: bool,
    /// Longest wait for one submission; `None` means 120 s (lavapipe is slow).
    pub timeout: Option<Duration>,
    /// Never map device-local buffers, even where the driver makes them host-visible (as
    /// lavapipe does): every write and read of a [`MemoryKind::Device`] buffer then goes
    /// through the staging buffers, as on a discrete GPU (CI runs the tests once so).
    ///
    /// [`MemoryKind::Device`]: super::MemoryKind::Device
    pub unmappable_device_memory: bool,
    /// Treat the device's storage-buffer range as at most this many bytes (tests: the split
    /// of a buffer into the part that storage-buffer bindings see and the part read only
    /// through texel-buffer views, on a device whose range is larger).
    pub storage_buffer_range_cap: Option<u64>,
}

/// The features vkinverse needs, as read from a device.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeviceFeatures {
    pub vulkan_1_3: bool,
    pub scalar_block_layout: bool,
    pub synchronization2: bool,
    pub maintenance4: bool,
    pub float32_atomic_add: bool,
    pub subgroup_arithmetic: bool,
    pub timestamps: bool,
}

impl DeviceFeatures {
    /// Each feature with its Vulkan name, in the order they are checked.
    pub fn list(&self) -> [(&'static str, bool); 7] {
        [
            ("Vulkan 1.3", self.vulkan_1_3),
            ("scalarBlockLayout", self.scalar_block_layout),
            ("synchronization2", self.synchronization2),
            ("maintenance4 (workgroup sizes from specialization constants)", self.maintenance4),
            ("shaderBufferFloat32AtomicAdd (VK_EXT_shader_atomic_float)", self.float32_atomic_add),
            ("subgroup arithmetic in compute shaders", self.subgroup_arithmetic),
            ("timestamps on the compute queue", self.timestamps),
        ]
    }
}

/// Fails with [`GpuError::MissingFeature`] naming the first feature the device lacks.
pub fn check_features(device: &str, features: &DeviceFeatures) -> Result<()> {
    match features.list().into_iter().find(|(_, has)| !has) {
        Some((feature, _)) => Err(GpuError::MissingFeature { device: device.to_string(), feature }),
        None => Ok(()),
    }
}

/// What `vkinverse info` prints about a device.
#[derive(Clone, Debug)]
pub struct DeviceInfo {
    pub index: usize,
    pub name: String,
    pub device_type: String,
    pub api_version: String,
    pub driver: String,
    pub max_storage_buffer_range: u64,
    /// Texels a texel-buffer view may span.
    pub max_texel_buffer_elements: u64,
    pub max_workgroup_invocations: u32,
    pub max_workgroup_count: [u32; 3],
    pub subgroup_size: u32,
    pub timestamp_period_ns: f32,
    pub device_local_heap_bytes: u64,
    pub features: DeviceFeatures,
    /// Descriptors one compute kernel may use, per kind.
    pub descriptor_limits: DescriptorLimits,
}

impl DeviceInfo {
    /// The bytes one texel-buffer view may span: `max_texel_buffer_elements` 16-byte texels.
    pub fn max_texel_buffer_bytes(&self) -> u64 {
        self.max_texel_buffer_elements.saturating_mul(super::TEXEL_BYTES)
    }
}

/// The device's per-stage descriptor limits that vkinverse's kernels run into (Vulkan
/// guarantees only 4 storage buffers and 4 storage images per stage; desktop drivers allow
/// thousands). Storage texel buffers count as storage images, uniform texel buffers as
/// sampled images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DescriptorLimits {
    pub storage_buffers: u32,
    pub storage_images: u32,
    pub sampled_images: u32,
    pub resources: u32,
}

/// The Vulkan instance, the chosen device and its compute queue.
pub struct Context {
    // The loader library must outlive every handle made from it.
    _entry: ash::Entry,
    pub(crate) instance: ash::Instance,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    pub(crate) device: ash::Device,
    pub(crate) queue: Mutex<vk::Queue>,
    pub(crate) queue_family: u32,
    pub(crate) allocator: ManuallyDrop<Mutex<Allocator>>,
    pub(crate) timeout: Duration,
    pub(crate) timestamp_mask: u64,
    /// Whether device-local buffers may be read and written through a mapping.
    pub(crate) device_mappable: bool,
    pub(crate) staging: Mutex<Staging>,
    pub(crate) counters: Counters,
    info: DeviceInfo,
    devices: Vec<DeviceInfo>,
    // Boxed so that its address, handed to the debug callback, stays fixed.
    messages: Box<Mutex<Vec<String>>>,
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the layer passes a valid callback-data pointer for the duration of the call,
    // and `user` is the boxed message list owned by the Context that owns the messenger.
    let (text, list) = unsafe {
        let msg = (*data).p_message;
        let text = if msg.is_null() { String::new() } else { CStr::from_ptr(msg).to_string_lossy().into_owned() };
        (text, &*(user as *const Mutex<Vec<String>>))
    };
    let line = format!("[{severity:?}] {text}");
    eprintln!("vulkan validation: {line}");
    if let Ok(mut list) = list.lock() {
        list.push(line);
    }
    // An error refuses the call: the Khronos layer then returns
    // VK_ERROR_VALIDATION_FAILED_EXT instead of passing an invalid call on, which a real
    // driver may crash on (NVIDIA's does on an invalid SPIR-V module).
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        vk::TRUE
    } else {
        vk::FALSE
    }
}

fn version_string(v: u32) -> String {
    format!("{}.{}.{}", vk::api_version_major(v), vk::api_version_minor(v), vk::api_version_patch(v))
}

fn has_extension(available: &[vk::ExtensionProperties], name: &CStr) -> bool {
    available.iter().any(|e| e.extension_name_as_c_str() == Ok(name))
}

impl Context {
    /// Creates the instance (with validation when asked), picks a device (discrete >
    /// integrated > virtual > CPU, or the one named in `options.device`), checks the
    /// features vkinverse needs and creates the device, queue and allocator.
    /// Not split: instance, messenger, device and allocator are made in order under one
    /// lock and one guard that destroys what an error leaves behind; split, each part would
    /// carry the guard's state.
    pub fn new(options: &ContextOptions) -> Result<Arc<Self>> {
        let validation = options.validation;
        // Released when `new` returns, after an error path's guard has destroyed what it made.
        let _lifecycle = lifecycle();
        let entry = loader()?;
        let messages: Box<Mutex<Vec<String>>> = Box::default();

        // SAFETY: plain queries on a loaded entry.
        let layers = unsafe { entry.enumerate_instance_layer_properties() }.map_err(vk_err("vkEnumerateInstanceLayerProperties"))?;
        let inst_exts = unsafe { entry.enumerate_instance_extension_properties(None) }.map_err(vk_err("vkEnumerateInstanceExtensionProperties"))?;
        let mut layer_names = Vec::new();
        let mut ext_names: Vec<*const i8> = Vec::new();
        let mut flags = vk::InstanceCreateFlags::empty();
        if has_extension(&inst_exts, ash::khr::portability_enumeration::NAME) {
            // MoltenVK exposes its devices only to instances that opt in.
            ext_names.push(ash::khr::portability_enumeration::NAME.as_ptr());
            flags |= vk::InstanceCreateFlags::ENUMERATE_PORTABILITY_KHR;
        }
        let mut want_validation_features = false;
        if validation {
            if !layers.iter().any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER)) {
                return Err(GpuError::NoValidationLayer);
            }
            layer_names.push(VALIDATION_LAYER.as_ptr());
            ext_names.push(ash::ext::debug_utils::NAME.as_ptr());
            // SAFETY: query of the layer's own extensions.
            let layer_exts =
                unsafe { entry.enumerate_instance_extension_properties(Some(VALIDATION_LAYER)) }.map_err(vk_err("vkEnumerateInstanceExtensionProperties"))?;
            if has_extension(&layer_exts, ash::ext::validation_features::NAME) {
                ext_names.push(ash::ext::validation_features::NAME.as_ptr());
                want_validation_features = true;
            }
        }
        let app_name = CString::new("vkinverse").unwrap_or_default();
        let app = vk::ApplicationInfo::default().application_name(&app_name).engine_name(&app_name).api_version(vk::API_VERSION_1_3);
        let enabled = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
        let mut vfeatures = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enabled);
        let mut create =
            vk::InstanceCreateInfo::default().application_info(&app).enabled_layer_names(&layer_names).enabled_extension_names(&ext_names).flags(flags);
        if want_validation_features {
            create = create.push_next(&mut vfeatures);
        }
        // SAFETY: all pointers in `create` reference locals that outlive the call.
        let instance = unsafe { entry.create_instance(&create, None) }.map_err(|e| match e {
            // The loader found no driver manifest, or none whose library loads.
            vk::Result::ERROR_INCOMPATIBLE_DRIVER => GpuError::NoDriver(e),
            e => vk_err("vkCreateInstance")(e),
        })?;

        let debug = if validation {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR)
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(debug_callback))
                .user_data(&*messages as *const Mutex<Vec<String>> as *mut c_void);
            // SAFETY: the user-data box lives in the Context, which destroys the messenger first.
            let messenger = unsafe { loader.create_debug_utils_messenger(&info, None) }.map_err(vk_err("vkCreateDebugUtilsMessengerEXT"));
            match messenger {
                Ok(m) => Some((loader, m)),
                Err(e) => {
                    // SAFETY: the instance has no children yet.
                    unsafe { instance.destroy_instance(None) };
                    return Err(e);
                }
            }
        } else {
            None
        };

        // From here on, a failure must destroy what was made: build a partial guard.
        let guard = InstanceGuard { instance: &instance, debug: debug.as_ref() };
        let (devices, physicals) = Self::survey(&instance)?;
        if devices.is_empty() {
            return Err(GpuError::NoDevice);
        }
        let chosen = Self::choose(&devices, options.device.as_deref())?;
        let mut info = devices[chosen].clone();
        check_features(&info.name, &info.features)?;
        if let Some(cap) = options.storage_buffer_range_cap {
            info.max_storage_buffer_range = info.max_storage_buffer_range.min(cap);
        }
        let physical = physicals[chosen];

        // SAFETY: queries on a valid physical device.
        let families = unsafe { instance.get_physical_device_queue_family_properties(physical) };
        let queue_family = families
            .iter()
            .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.timestamp_valid_bits > 0)
            .ok_or(GpuError::MissingFeature { device: info.name.clone(), feature: "a compute queue with timestamps" })? as u32;
        let valid_bits = families[queue_family as usize].timestamp_valid_bits;
        let timestamp_mask = if valid_bits >= 64 { u64::MAX } else { (1u64 << valid_bits) - 1 };

        let dev_exts = unsafe { instance.enumerate_device_extension_properties(physical) }.map_err(vk_err("vkEnumerateDeviceExtensionProperties"))?;
        let mut dev_ext_names = vec![ash::ext::shader_atomic_float::NAME.as_ptr()];
        let portability = c"VK_KHR_portability_subset";
        if has_extension(&dev_exts, portability) {
            // Required on MoltenVK whenever the device exposes it.
            dev_ext_names.push(portability.as_ptr());
        }
        let priorities = [1.0f32];
        let queue_info = [vk::DeviceQueueCreateInfo::default().queue_family_index(queue_family).queue_priorities(&priorities)];
        let mut f12 = vk::PhysicalDeviceVulkan12Features::default().scalar_block_layout(true);
        let mut f13 = vk::PhysicalDeviceVulkan13Features::default().synchronization2(true).maintenance4(true);
        let mut fatomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default().shader_buffer_float32_atomics(true).shader_buffer_float32_atomic_add(true);
        let mut features = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12).push_next(&mut f13).push_next(&mut fatomic);
        let dev_create = vk::DeviceCreateInfo::default().queue_create_infos(&queue_info).enabled_extension_names(&dev_ext_names).push_next(&mut features);
        // SAFETY: the create info references locals alive for the call; features were checked.
        let device = unsafe { instance.create_device(physical, &dev_create, None) }.map_err(vk_err("vkCreateDevice"))?;
        // SAFETY: family and index 0 were requested in `queue_info`.
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: the device has no children yet.
                unsafe { device.destroy_device(None) };
                return Err(GpuError::Alloc { name: "allocator".into(), source });
            }
        };
        std::mem::forget(guard);
        Ok(Arc::new(Self {
            _entry: entry,
            instance,
            debug,
            device,
            queue: Mutex::new(queue),
            queue_family,
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            timeout: options.timeout.unwrap_or(Duration::from_secs(120)),
            timestamp_mask,
            device_mappable: !options.unmappable_device_memory,
            staging: Mutex::new(Staging::default()),
            counters: Counters::default(),
            info,
            devices,
            messages,
        }))
    }

    /// Reads name, limits and features of every physical device.
    fn survey(instance: &ash::Instance) -> Result<(Vec<DeviceInfo>, Vec<vk::PhysicalDevice>)> {
        // SAFETY: enumeration and property queries on a valid instance.
        let physicals = unsafe { instance.enumerate_physical_devices() }.map_err(vk_err("vkEnumeratePhysicalDevices"))?;
        let mut infos = Vec::new();
        for (index, &pd) in physicals.iter().enumerate() {
            let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
            let mut driver = vk::PhysicalDeviceDriverProperties::default();
            let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut subgroup).push_next(&mut driver);
            let mut f12 = vk::PhysicalDeviceVulkan12Features::default();
            let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
            let mut fatomic = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
            let exts = unsafe { instance.enumerate_device_extension_properties(pd) }.map_err(vk_err("vkEnumerateDeviceExtensionProperties"))?;
            let has_atomic_ext = has_extension(&exts, ash::ext::shader_atomic_float::NAME);
            let mut feats2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f12).push_next(&mut f13);
            if has_atomic_ext {
                feats2 = feats2.push_next(&mut fatomic);
            }
            unsafe {
                instance.get_physical_device_properties2(pd, &mut props2);
                instance.get_physical_device_features2(pd, &mut feats2);
            }
            let props = props2.properties;
            let memory = unsafe { instance.get_physical_device_memory_properties(pd) };
            let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
            let device_local_heap_bytes = memory.memory_heaps[..memory.memory_heap_count as usize]
                .iter()
                .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
                .map(|h| h.size)
                .max()
                .unwrap_or(0);
            let features = DeviceFeatures {
                vulkan_1_3: props.api_version >= vk::API_VERSION_1_3,
                scalar_block_layout: f12.scalar_block_layout == vk::TRUE,
                synchronization2: f13.synchronization2 == vk::TRUE,
                maintenance4: f13.maintenance4 == vk::TRUE,
                float32_atomic_add: has_atomic_ext && fatomic.shader_buffer_float32_atomic_add == vk::TRUE,
                subgroup_arithmetic: subgroup.supported_stages.contains(vk::ShaderStageFlags::COMPUTE)
                    && subgroup.supported_operations.contains(vk::SubgroupFeatureFlags::ARITHMETIC),
                timestamps: families.iter().any(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE) && f.timestamp_valid_bits > 0),
            };
            let cstr = |s: std::result::Result<&CStr, std::ffi::FromBytesUntilNulError>| s.map(|c: &CStr| c.to_string_lossy().into_owned()).unwrap_or_default();
            infos.push(DeviceInfo {
                index,
                name: cstr(props.device_name_as_c_str()),
                device_type: format!("{:?}", props.device_type),
                api_version: version_string(props.api_version),
                driver: format!("{} {}", cstr(driver.driver_name_as_c_str()), cstr(driver.driver_info_as_c_str())),
                max_storage_buffer_range: props.limits.max_storage_buffer_range as u64,
                max_texel_buffer_elements: props.limits.max_texel_buffer_elements as u64,
                max_workgroup_invocations: props.limits.max_compute_work_group_invocations,
                max_workgroup_count: props.limits.max_compute_work_group_count,
                subgroup_size: subgroup.subgroup_size,
                timestamp_period_ns: props.limits.timestamp_period,
                device_local_heap_bytes,
                features,
                descriptor_limits: DescriptorLimits {
                    storage_buffers: props.limits.max_per_stage_descriptor_storage_buffers,
                    storage_images: props.limits.max_per_stage_descriptor_storage_images,
                    sampled_images: props.limits.max_per_stage_descriptor_sampled_images,
                    resources: props.limits.max_per_stage_resources,
                },
            });
        }
        Ok((infos, physicals))
    }

    fn choose(devices: &[DeviceInfo], wanted: Option<&str>) -> Result<usize> {
        if let Some(w) = wanted {
            if let Ok(i) = w.parse::<usize>() {
                return devices.get(i).map(|d| d.index).ok_or_else(|| GpuError::DeviceNotFound(w.to_string()));
            }
            let lw = w.to_lowercase();
            return devices.iter().find(|d| d.name.to_lowercase().contains(&lw)).map(|d| d.index).ok_or_else(|| GpuError::DeviceNotFound(w.to_string()));
        }
        let rank = |t: &str| match t {
            "DISCRETE_GPU" => 4,
            "INTEGRATED_GPU" => 3,
            "VIRTUAL_GPU" => 2,
            "CPU" => 1,
            _ => 0,
        };
        // Among devices of the best type, prefer one that has every needed feature.
        let best = devices.iter().max_by_key(|d| (check_features(&d.name, &d.features).is_ok(), rank(&d.device_type), usize::MAX - d.index)).map(|d| d.index);
        best.ok_or(GpuError::NoDevice)
    }

    /// The chosen device.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Every device the loader reported, chosen or not.
    pub fn devices(&self) -> &[DeviceInfo] {
        &self.devices
    }

    /// Whether validation is on (messages are then collected).
    pub fn validation_enabled(&self) -> bool {
        self.debug.is_some()
    }

    /// Takes the validation messages collected so far.
    pub fn take_validation_messages(&self) -> Vec<String> {
        self.messages.lock().map(|mut m| std::mem::take(&mut *m)).unwrap_or_default()
    }

    /// Names and sizes of the allocations still alive (the leak report), less the
    /// context's own staging buffers.
    pub fn live_allocations(&self) -> Vec<(String, u64)> {
        let alloc = self.allocator.lock().unwrap_or_else(|p| p.into_inner());
        alloc.generate_report().allocations.into_iter().filter(|a| !a.name.starts_with(STAGING_NAME)).map(|a| (a.name, a.size)).collect()
    }

    /// Whether device-local buffers are read and written through a mapping where the
    /// memory allows it (false: always through the staging buffers; see
    /// [`ContextOptions::unmappable_device_memory`]).
    pub fn device_memory_mappable(&self) -> bool {
        self.device_mappable
    }

    /// Host↔device transfers so far.
    pub fn transfer_stats(&self) -> TransferStats {
        self.counters.snapshot()
    }

    /// Waits until the device is idle.
    pub fn wait_idle(&self) -> Result<()> {
        // SAFETY: the queue is externally synchronised by its mutex.
        let _q = self.queue.lock().unwrap_or_else(|p| p.into_inner());
        unsafe { self.device.device_wait_idle() }.map_err(vk_err("vkDeviceWaitIdle"))
    }
}

/// Destroys the instance (and messenger) if device creation fails half-way.
struct InstanceGuard<'a> {
    instance: &'a ash::Instance,
    debug: Option<&'a (ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
}

impl Drop for InstanceGuard<'_> {
    fn drop(&mut self) {
        // SAFETY: reached only on an error path, before any device object exists.
        unsafe {
            if let Some((loader, m)) = self.debug {
                loader.destroy_debug_utils_messenger(*m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        // SAFETY: the last Arc is gone, so no object uses the device any more; the
        // allocator frees its memory blocks before the device is destroyed.
        unsafe {
            let _ = self.device.device_wait_idle();
            let mut staging = std::mem::take(self.staging.get_mut().unwrap_or_else(|p| p.into_inner()));
            staging.destroy(self);
            ManuallyDrop::drop(&mut self.allocator);
            let _lifecycle = lifecycle();
            self.device.destroy_device(None);
            if let Some((loader, m)) = &self.debug {
                loader.destroy_debug_utils_messenger(*m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}
