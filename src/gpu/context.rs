//! The Vulkan context: instance, optional validation with a recording messenger, one device and
//! queue, and the gpu-allocator allocator. Everything the backend creates holds an
//! `Arc<DeviceShared>`, so the device outlives every object made from it.

use super::validation::{
    make_deliberately_invalid_call, record_debug_message, DebugMessage, MessageLog, Severity,
    INVALID_CALL_ENV,
};
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{c_void, CStr};
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";
const VALIDATION_FEATURES_EXT: &CStr = c"VK_EXT_validation_features";

/// How to create a [`GpuContext`].
#[derive(Clone, Debug, Default)]
pub struct ContextDesc {
    /// Enable `VK_LAYER_KHRONOS_validation` (with synchronization validation where the layer
    /// offers `VK_EXT_validation_features`). Missing layer with this set is an error. (With
    /// validation on, the test hook [`crate::gpu::INVALID_CALL_ENV`] makes one deliberately
    /// invalid call for the layer to report.)
    pub validation: bool,
    /// Pick the first physical device whose name contains this (case-insensitive); `None` prefers
    /// discrete, then integrated, then virtual, then CPU devices. The `MIXVOL_DEVICE` environment
    /// variable sets it when this is `None`.
    pub device_name: Option<String>,
}

/// What the chosen device can do, queried once at start.
#[derive(Clone, Debug)]
pub struct DeviceInfo {
    /// The device name as reported by the driver.
    pub name: String,
    /// The device type (CPU for lavapipe).
    pub device_type: vk::PhysicalDeviceType,
    /// Device limits.
    pub limits: vk::PhysicalDeviceLimits,
    /// Nanoseconds per timestamp tick.
    pub timestamp_period_ns: f32,
    /// Whether the queue writes timestamps.
    pub timestamps_supported: bool,
    /// Whether `VK_LAYER_KHRONOS_validation` is active.
    pub validation: bool,
    /// Whether synchronization validation is active.
    pub synchronization_validation: bool,
    /// Whether R8/R16 storage images are supported (and enabled): the fixup pass needs them for
    /// u8/u16 brick caches.
    pub storage_image_extended_formats: bool,
    /// The memory limits requests are checked against before allocating.
    pub memory: MemoryLimits,
}

/// The device's memory limits, queried once at start: every buffer and image request is checked
/// against them before it is allocated (`gpu::memory::check_request`).
#[derive(Clone, Debug, Default)]
pub struct MemoryLimits {
    /// `VkPhysicalDeviceMaintenance3Properties::maxMemoryAllocationSize`: the largest single
    /// allocation the driver promises; lower when [`ALLOCATION_CAP_ENV`] caps it.
    pub max_allocation_bytes: u64,
    /// Whether [`ALLOCATION_CAP_ENV`] lowered `max_allocation_bytes` below the driver's limit.
    pub allocation_capped: bool,
    /// Each memory heap's size in bytes and whether it is device-local.
    pub heaps: Vec<(u64, bool)>,
    /// Each memory type's property flags and heap index.
    pub types: Vec<(vk::MemoryPropertyFlags, u32)>,
    /// Whether `VK_EXT_memory_budget` is enabled: then the heaps' current budgets are queried
    /// before each allocation too.
    pub budget_extension: bool,
}

/// Environment variable that caps the largest single GPU allocation mixvol makes, in MiB: it can
/// only lower the device's `maxMemoryAllocationSize`, never raise it (for sharing a GPU with a
/// host engine, and for tests that must refuse the same request on every device).
pub const ALLOCATION_CAP_ENV: &str = "MIXVOL_GPU_MAX_ALLOCATION_MB";

/// The allocation limit under the cap `env` (the value of [`ALLOCATION_CAP_ENV`], MiB) given the
/// driver's `device_limit`: the limit and whether the cap lowered it.
fn capped_allocation_limit(device_limit: u64, env: Option<&str>) -> Result<(u64, bool)> {
    let Some(text) = env else {
        return Ok((device_limit, false));
    };
    let mib: u64 = text.trim().parse().ok().filter(|&m| m > 0).ok_or_else(|| {
        Error::InvalidInput(format!(
            "{ALLOCATION_CAP_ENV}={text:?}: expected a whole number of MiB above 0"
        ))
    })?;
    let cap = mib.saturating_mul(1 << 20);
    if device_limit == 0 || cap < device_limit {
        Ok((cap, true))
    } else {
        Ok((device_limit, false))
    }
}

/// Queries `pd`'s memory limits (`budget_extension`: whether VK_EXT_memory_budget is enabled),
/// under [`ALLOCATION_CAP_ENV`].
fn memory_limits(
    instance: &ash::Instance,
    pd: vk::PhysicalDevice,
    budget_extension: bool,
) -> Result<MemoryLimits> {
    let mut maintenance3 = vk::PhysicalDeviceMaintenance3Properties::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut maintenance3);
    // SAFETY: `pd` belongs to `instance` (a 1.3 instance: properties2 is core); the chain is
    // well formed and outlives the call.
    unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
    // SAFETY: as above.
    let mem = unsafe { instance.get_physical_device_memory_properties(pd) };
    let heaps = mem.memory_heaps[..mem.memory_heap_count as usize]
        .iter()
        .map(|h| (h.size, h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL)))
        .collect();
    let types = mem.memory_types[..mem.memory_type_count as usize]
        .iter()
        .map(|t| (t.property_flags, t.heap_index))
        .collect();
    let (max_allocation_bytes, allocation_capped) = capped_allocation_limit(
        maintenance3.max_memory_allocation_size,
        std::env::var(ALLOCATION_CAP_ENV).ok().as_deref(),
    )?;
    Ok(MemoryLimits {
        max_allocation_bytes,
        allocation_capped,
        heaps,
        types,
        budget_extension,
    })
}

/// Whether `pd` offers the device extension `name`.
fn has_device_extension(instance: &ash::Instance, pd: vk::PhysicalDevice, name: &CStr) -> bool {
    // SAFETY: plain query on a physical device of `instance`.
    unsafe { instance.enumerate_device_extension_properties(pd) }
        .map(|exts| exts.iter().any(|e| e.extension_name_as_c_str() == Ok(name)))
        .unwrap_or(false)
}

impl DeviceShared {
    /// The bytes still available under VK_EXT_memory_budget in each heap (budget minus usage),
    /// or `None` without the extension.
    pub(crate) fn heap_budgets(&self) -> Option<Vec<u64>> {
        if !self.info.memory.budget_extension {
            return None;
        }
        let mut budget = vk::PhysicalDeviceMemoryBudgetPropertiesEXT::default();
        let mut props = vk::PhysicalDeviceMemoryProperties2::default().push_next(&mut budget);
        // SAFETY: the extension is enabled on this device; the chain outlives the call.
        unsafe {
            self.instance
                .get_physical_device_memory_properties2(self.physical_device, &mut props)
        };
        let count = props.memory_properties.memory_heap_count as usize;
        Some(
            (0..count)
                .map(|h| budget.heap_budget[h].saturating_sub(budget.heap_usage[h]))
                .collect(),
        )
    }
}

/// State shared by every object of the backend. Dropped last: waits idle, drops the allocator
/// (which reports leaks), destroys the device, the messenger and the instance, in that order.
pub(crate) struct DeviceShared {
    allocator: AllocatorSlot,
    /// Allocations made by this crate and not yet freed (works with a host allocator too).
    pub(crate) live_allocations: AtomicUsize,
    /// False when the instance and device belong to a host engine: they are then never
    /// destroyed here.
    owns_device: bool,
    pub(crate) device: ash::Device,
    pub(crate) physical_device: vk::PhysicalDevice,
    pub(crate) queue: vk::Queue,
    /// Serialises vkQueueSubmit (the queue requires external synchronisation).
    pub(crate) queue_lock: Mutex<()>,
    pub(crate) queue_family: u32,
    pub(crate) info: DeviceInfo,
    instance: ash::Instance,
    debug_utils: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    log: Arc<MessageLog>,
    log_user_data: *const MessageLog,
    _entry: ash::Entry,
}

impl DeviceShared {
    /// The instance the device was created from.
    pub(crate) fn instance(&self) -> &ash::Instance {
        &self.instance
    }
}

// SAFETY: the raw pointer `log_user_data` is an `Arc<MessageLog>` reference count owned by this
// struct (MessageLog is Sync); every other field is Send + Sync.
unsafe impl Send for DeviceShared {}
// SAFETY: see the Send impl; shared access never mutates the pointer.
unsafe impl Sync for DeviceShared {}

impl DeviceShared {
    /// Waits until the device is idle, holding the queue lock (idle waits need external
    /// synchronisation of every queue): afterwards no GPU work uses the crate's objects.
    pub(crate) fn wait_idle(&self) -> Result<()> {
        let _queue = self.queue_lock.lock().unwrap_or_else(|e| e.into_inner());
        // SAFETY: the device is live; `_queue` serialises this with our own submissions.
        unsafe { self.device.device_wait_idle() }.vk("vkDeviceWaitIdle")
    }

    /// Locks the allocator (recovering from a poisoned lock: the allocator state stays valid).
    pub(crate) fn allocator(&self) -> MutexGuard<'_, Allocator> {
        let mutex = match &self.allocator {
            AllocatorSlot::Owned(a) => &**a,
            AllocatorSlot::Host(a) => &**a,
        };
        mutex.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Format features of `format` with optimal tiling.
    pub(crate) fn optimal_format_features(&self, format: vk::Format) -> vk::FormatFeatureFlags {
        // SAFETY: the physical device handle belongs to `self.instance`, which is alive.
        unsafe {
            self.instance
                .get_physical_device_format_properties(self.physical_device, format)
                .optimal_tiling_features
        }
    }

    /// Errors with `Unsupported` unless `format` has all `required` optimal-tiling features.
    pub(crate) fn require_format(
        &self,
        format: vk::Format,
        required: vk::FormatFeatureFlags,
        purpose: &str,
    ) -> Result<()> {
        let have = self.optimal_format_features(format);
        if have.contains(required) {
            Ok(())
        } else {
            Err(Error::Unsupported(format!(
                "{purpose}: format {format:?} lacks {:?} (has {have:?})",
                required & !have
            )))
        }
    }
}

/// The allocator: created here, or lent by a host engine.
#[allow(clippy::large_enum_variant)] // reason: one per context; boxing buys nothing.
enum AllocatorSlot {
    Owned(ManuallyDrop<Mutex<Allocator>>),
    Host(Arc<Mutex<Allocator>>),
}

impl Drop for DeviceShared {
    fn drop(&mut self) {
        let live = self.live_allocations.load(Ordering::SeqCst);
        if live != 0 {
            self.log.push(DebugMessage {
                severity: Severity::Error,
                id_name: "mixvol-leaked-allocation".into(),
                text: format!("{live} allocation(s) made by mixvol still live at shutdown"),
            });
        }
        if !self.owns_device {
            // The host's instance and device stay alive; an allocator we made for them is
            // dropped (the host waited for its GPU work, per `from_host`'s contract).
            if let AllocatorSlot::Owned(allocator) = &mut self.allocator {
                // SAFETY: dropped exactly once, here; no allocation of ours is live.
                unsafe { ManuallyDrop::drop(allocator) };
            }
            // SAFETY: the pointer came from Arc::into_raw in `from_host` and is reclaimed once.
            unsafe { drop(Arc::from_raw(self.log_user_data)) };
            return;
        }
        let AllocatorSlot::Owned(allocator) = &mut self.allocator else {
            unreachable!("an owned device always has an owned allocator");
        };
        // SAFETY: every object created from the device holds an Arc to this struct, so none is
        // alive now; waiting idle makes sure the GPU no longer uses freed memory. Destruction
        // runs in reverse creation order: allocator, device, messenger, instance.
        unsafe {
            if let Err(e) = self.device.device_wait_idle() {
                log::error!("vkDeviceWaitIdle at shutdown: {e}");
            }
            let report = allocator
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .generate_report();
            for leak in &report.allocations {
                self.log.push(DebugMessage {
                    severity: Severity::Error,
                    id_name: "mixvol-leaked-allocation".into(),
                    text: format!("allocation '{}' ({} bytes) leaked", leak.name, leak.size),
                });
            }
            ManuallyDrop::drop(allocator);
            self.device.destroy_device(None);
            if let Some((loader, messenger)) = self.debug_utils.take() {
                loader.destroy_debug_utils_messenger(messenger, None);
            }
            self.instance.destroy_instance(None);
            drop(Arc::from_raw(self.log_user_data));
        }
    }
}

/// A host engine's Vulkan objects, lent to [`GpuContext::from_host`].
pub struct HostDevice {
    /// The loader entry the host uses.
    pub entry: ash::Entry,
    /// The host's instance.
    pub instance: ash::Instance,
    /// The physical device of `device`.
    pub physical_device: vk::PhysicalDevice,
    /// The host's device.
    pub device: ash::Device,
    /// A graphics + compute queue family of `device`.
    pub queue_family: u32,
    /// A queue of `queue_family`; only the offscreen `renderer::Renderer` submits to it,
    /// the embedding path (`embed::VolumePass`) never does.
    pub queue: vk::Queue,
    /// The host's gpu-allocator allocator, if it wants ours to share it; otherwise the context
    /// creates its own for `device`.
    pub allocator: Option<Arc<Mutex<Allocator>>>,
}

/// A headless Vulkan instance + device + allocator. Cheap to clone (reference counted).
#[derive(Clone)]
pub struct GpuContext {
    pub(crate) shared: Arc<DeviceShared>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("device", &self.shared.info.name)
            .finish()
    }
}

fn device_type_rank(t: vk::PhysicalDeviceType) -> u32 {
    match t {
        vk::PhysicalDeviceType::DISCRETE_GPU => 0,
        vk::PhysicalDeviceType::INTEGRATED_GPU => 1,
        vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
        vk::PhysicalDeviceType::CPU => 3,
        _ => 4,
    }
}

impl GpuContext {
    /// Creates the instance, picks a device (see [`ContextDesc`]) and creates device and allocator.
    pub fn new(desc: &ContextDesc) -> Result<Self> {
        // SAFETY: loading the system Vulkan loader; we only call it through ash's typed wrappers.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| Error::Loader(e.to_string()))?;
        let log = Arc::new(MessageLog::default());
        let log_user_data = Arc::into_raw(log.clone());
        // From here on `log_user_data` holds a reference count; `Guard` returns it on early errors.
        struct UserDataGuard(*const MessageLog, bool);
        impl Drop for UserDataGuard {
            fn drop(&mut self) {
                if !self.1 {
                    // SAFETY: the pointer came from Arc::into_raw and was not handed to a
                    // DeviceShared (flag false), so it is reclaimed exactly once here.
                    unsafe { drop(Arc::from_raw(self.0)) };
                }
            }
        }
        let mut guard = UserDataGuard(log_user_data, false);
        let shared = Self::create(entry, desc, log, log_user_data)?;
        guard.1 = true;
        Ok(Self {
            shared: Arc::new(shared),
        })
    }

    fn create(
        entry: ash::Entry,
        desc: &ContextDesc,
        log: Arc<MessageLog>,
        log_user_data: *const MessageLog,
    ) -> Result<DeviceShared> {
        // SAFETY: plain queries on a loaded entry.
        let instance_version = unsafe { entry.try_enumerate_instance_version() }
            .vk("vkEnumerateInstanceVersion")?
            .unwrap_or(vk::API_VERSION_1_0);
        if instance_version < vk::API_VERSION_1_3 {
            return Err(Error::Unsupported(format!(
                "Vulkan 1.3 instance required, loader offers {}.{}",
                vk::api_version_major(instance_version),
                vk::api_version_minor(instance_version)
            )));
        }
        let mut layers = Vec::new();
        let mut extensions = Vec::new();
        let mut sync_validation = false;
        if desc.validation {
            // SAFETY: plain queries on a loaded entry.
            let available = unsafe { entry.enumerate_instance_layer_properties() }
                .vk("vkEnumerateInstanceLayerProperties")?;
            let found = available
                .iter()
                .any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER));
            if !found {
                return Err(Error::Unsupported(
                    "validation requested but VK_LAYER_KHRONOS_validation is not installed \
                     (Debian: vulkan-validationlayers)"
                        .into(),
                ));
            }
            layers.push(VALIDATION_LAYER.as_ptr());
            // SAFETY: plain query of the layer's instance extensions.
            let layer_exts =
                unsafe { entry.enumerate_instance_extension_properties(Some(VALIDATION_LAYER)) }
                    .vk("vkEnumerateInstanceExtensionProperties")?;
            sync_validation = layer_exts
                .iter()
                .any(|e| e.extension_name_as_c_str() == Ok(VALIDATION_FEATURES_EXT));
            if sync_validation {
                extensions.push(VALIDATION_FEATURES_EXT.as_ptr());
            }
            extensions.push(ash::ext::debug_utils::NAME.as_ptr());
        }

        let app_info = vk::ApplicationInfo::default()
            .application_name(c"mixvol")
            .engine_name(c"mixvol")
            .api_version(vk::API_VERSION_1_3);
        let enabled_validation = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
        let mut validation_features =
            vk::ValidationFeaturesEXT::default().enabled_validation_features(&enabled_validation);
        let mut messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
            .message_severity(
                vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
                    | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                    | vk::DebugUtilsMessageSeverityFlagsEXT::INFO
                    | vk::DebugUtilsMessageSeverityFlagsEXT::VERBOSE,
            )
            .message_type(
                vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                    | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                    | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
            )
            .pfn_user_callback(Some(record_debug_message))
            .user_data(log_user_data as *mut c_void);
        let mut instance_info = vk::InstanceCreateInfo::default()
            .application_info(&app_info)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&extensions);
        if desc.validation {
            // Chained so that messages from vkCreateInstance/vkDestroyInstance are recorded too.
            instance_info = instance_info.push_next(&mut messenger_info);
            if sync_validation {
                instance_info = instance_info.push_next(&mut validation_features);
            }
        }
        // SAFETY: all pointers in the create info refer to locals that outlive the call.
        let instance =
            unsafe { entry.create_instance(&instance_info, None) }.vk("vkCreateInstance")?;

        // From here on, clean up the instance on error.
        let result = (|| {
            let debug_utils = if desc.validation {
                let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
                // SAFETY: the create info is valid and its user data outlives the messenger.
                let messenger =
                    unsafe { loader.create_debug_utils_messenger(&messenger_info, None) }
                        .vk("vkCreateDebugUtilsMessengerEXT")?;
                Some((loader, messenger))
            } else {
                None
            };
            let picked = Self::pick_device(&instance, desc);
            let (physical_device, queue_family) = match picked {
                Ok(p) => p,
                Err(e) => {
                    if let Some((loader, messenger)) = &debug_utils {
                        // SAFETY: the messenger was created above from this loader.
                        unsafe { loader.destroy_debug_utils_messenger(*messenger, None) };
                    }
                    return Err(e);
                }
            };
            Ok((debug_utils, physical_device, queue_family))
        })();
        let (debug_utils, physical_device, queue_family) = match result {
            Ok(v) => v,
            Err(e) => {
                // SAFETY: nothing else was created from the instance.
                unsafe { instance.destroy_instance(None) };
                return Err(e);
            }
        };

        // SAFETY: the physical device was enumerated from this instance.
        let properties = unsafe { instance.get_physical_device_properties(physical_device) };
        // SAFETY: as above.
        let families =
            unsafe { instance.get_physical_device_queue_family_properties(physical_device) };
        let name = properties
            .device_name_as_c_str()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();

        let mut features13 = vk::PhysicalDeviceVulkan13Features::default()
            .dynamic_rendering(true)
            .synchronization2(true)
            .maintenance4(true);
        // SAFETY: the physical device was enumerated from this instance.
        let supported10 = unsafe { instance.get_physical_device_features(physical_device) };
        let features10 = vk::PhysicalDeviceFeatures::default()
            .shader_storage_image_extended_formats(
                supported10.shader_storage_image_extended_formats == vk::TRUE,
            );
        let priorities = [1.0f32];
        let queue_infos = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(queue_family)
            .queue_priorities(&priorities)];
        let budget_extension =
            has_device_extension(&instance, physical_device, ash::ext::memory_budget::NAME);
        let device_extensions: Vec<*const std::ffi::c_char> = if budget_extension {
            vec![ash::ext::memory_budget::NAME.as_ptr()]
        } else {
            Vec::new()
        };
        let device_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_infos)
            .enabled_extension_names(&device_extensions)
            .enabled_features(&features10)
            .push_next(&mut features13);
        // SAFETY: required features were checked in pick_device; pointers outlive the call.
        let device = match unsafe { instance.create_device(physical_device, &device_info, None) } {
            Ok(d) => d,
            Err(result) => {
                // SAFETY: tear down what exists, in reverse order.
                unsafe {
                    if let Some((loader, messenger)) = &debug_utils {
                        loader.destroy_debug_utils_messenger(*messenger, None);
                    }
                    instance.destroy_instance(None);
                }
                return Err(Error::Vulkan {
                    call: "vkCreateDevice",
                    result,
                });
            }
        };
        // SAFETY: queue 0 of the family we created.
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        if desc.validation && std::env::var_os(INVALID_CALL_ENV).is_some() {
            make_deliberately_invalid_call(&device);
        }
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: tear down what exists, in reverse order.
                unsafe {
                    device.destroy_device(None);
                    if let Some((loader, messenger)) = &debug_utils {
                        loader.destroy_debug_utils_messenger(*messenger, None);
                    }
                    instance.destroy_instance(None);
                }
                return Err(Error::Allocation {
                    name: "allocator".into(),
                    source,
                });
            }
        };
        let info = DeviceInfo {
            name,
            device_type: properties.device_type,
            limits: properties.limits,
            timestamp_period_ns: properties.limits.timestamp_period,
            timestamps_supported: families[queue_family as usize].timestamp_valid_bits > 0,
            validation: desc.validation,
            synchronization_validation: desc.validation && sync_validation,
            storage_image_extended_formats: features10.shader_storage_image_extended_formats
                == vk::TRUE,
            memory: memory_limits(&instance, physical_device, budget_extension)?,
        };
        log::info!(
            "device: {} ({:?}), validation {}, sync validation {}",
            info.name,
            info.device_type,
            info.validation,
            info.synchronization_validation
        );
        Ok(DeviceShared {
            allocator: AllocatorSlot::Owned(ManuallyDrop::new(Mutex::new(allocator))),
            live_allocations: AtomicUsize::new(0),
            owns_device: true,
            device,
            physical_device,
            queue,
            queue_lock: Mutex::new(()),
            queue_family,
            info,
            instance,
            debug_utils,
            log,
            log_user_data,
            _entry: entry,
        })
    }

    /// Chooses the physical device and a graphics+compute queue family; checks 1.3 features.
    fn pick_device(
        instance: &ash::Instance,
        desc: &ContextDesc,
    ) -> Result<(vk::PhysicalDevice, u32)> {
        let wanted = desc
            .device_name
            .clone()
            .or_else(|| std::env::var("MIXVOL_DEVICE").ok())
            .map(|s| s.to_lowercase());
        // SAFETY: plain enumeration on a live instance.
        let devices =
            unsafe { instance.enumerate_physical_devices() }.vk("vkEnumeratePhysicalDevices")?;
        let mut candidates = Vec::new();
        let mut rejected = Vec::new();
        let mut present = Vec::new();
        for pd in devices {
            // SAFETY: `pd` was enumerated from `instance`.
            let props = unsafe { instance.get_physical_device_properties(pd) };
            let name = props
                .device_name_as_c_str()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            present.push(name.clone());
            if let Some(w) = &wanted {
                if !name.to_lowercase().contains(w) {
                    continue;
                }
            }
            if props.api_version < vk::API_VERSION_1_3 {
                rejected.push(format!("{name}: Vulkan 1.3 not supported"));
                continue;
            }
            let mut f13 = vk::PhysicalDeviceVulkan13Features::default();
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut f13);
            // SAFETY: `pd` is valid and the chain is well formed.
            unsafe { instance.get_physical_device_features2(pd, &mut f2) };
            let missing: Vec<&str> = [
                (f13.dynamic_rendering, "dynamicRendering"),
                (f13.synchronization2, "synchronization2"),
                (f13.maintenance4, "maintenance4"),
            ]
            .iter()
            .filter(|(have, _)| *have == vk::FALSE)
            .map(|(_, n)| *n)
            .collect();
            if !missing.is_empty() {
                rejected.push(format!("{name}: missing features {missing:?}"));
                continue;
            }
            // SAFETY: `pd` is valid.
            let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
            let family = families.iter().position(|f| {
                f.queue_flags
                    .contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE)
            });
            match family {
                Some(family) => {
                    candidates.push((device_type_rank(props.device_type), pd, family as u32))
                }
                None => rejected.push(format!("{name}: no graphics+compute queue")),
            }
        }
        candidates.sort_by_key(|c| c.0);
        candidates.first().map(|c| (c.1, c.2)).ok_or_else(|| {
            let found = if present.is_empty() {
                "the Vulkan loader reports no devices (is a driver installed?)".to_string()
            } else {
                format!("devices present: {}", present.join(", "))
            };
            let why = if rejected.is_empty() {
                String::new()
            } else {
                format!("; rejected: {}", rejected.join("; "))
            };
            let hint = if wanted.is_some() && candidates.is_empty() && rejected.is_empty() {
                " (matched case-insensitively as a substring of the device name)"
            } else {
                ""
            };
            Error::Unsupported(format!(
                "no usable Vulkan device{}{hint}; {found}{why}",
                wanted
                    .map(|w| format!(" matching '{w}'"))
                    .unwrap_or_default(),
            ))
        })
    }

    /// Wraps a host engine's Vulkan objects instead of creating our own. Nothing the host owns
    /// is ever destroyed by this crate; the context records no message of the host's layers
    /// (the host's own messenger receives them).
    ///
    /// # Safety
    /// - `host.device` was created from `host.instance` and `host.physical_device` with Vulkan
    ///   1.3 and the features `dynamicRendering`, `synchronization2` and `maintenance4` enabled
    ///   (and `shaderStorageImageExtendedFormats` for u8/u16 brick caches); `host.queue` is a
    ///   queue of `host.queue_family`, which supports graphics and compute.
    /// - `host.allocator`, when given, allocates from `host.device`.
    /// - All of them outlive the context and every object created from it, and the host waits
    ///   for GPU work that uses those objects before dropping them.
    pub unsafe fn from_host(host: HostDevice) -> Result<Self> {
        // SAFETY: the caller guarantees the handles are valid and related.
        let properties = unsafe {
            host.instance
                .get_physical_device_properties(host.physical_device)
        };
        if properties.api_version < vk::API_VERSION_1_3 {
            return Err(Error::Unsupported(
                "the host device must support Vulkan 1.3".into(),
            ));
        }
        // SAFETY: as above.
        let families = unsafe {
            host.instance
                .get_physical_device_queue_family_properties(host.physical_device)
        };
        let family = families
            .get(host.queue_family as usize)
            .ok_or_else(|| Error::InvalidInput(format!("no queue family {}", host.queue_family)))?;
        if !family
            .queue_flags
            .contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE)
        {
            return Err(Error::Unsupported(format!(
                "queue family {} lacks graphics + compute",
                host.queue_family
            )));
        }
        // SAFETY: as above.
        let features = unsafe {
            host.instance
                .get_physical_device_features(host.physical_device)
        };
        let allocator = match host.allocator {
            Some(a) => AllocatorSlot::Host(a),
            None => {
                let allocator = Allocator::new(&AllocatorCreateDesc {
                    instance: host.instance.clone(),
                    device: host.device.clone(),
                    physical_device: host.physical_device,
                    debug_settings: Default::default(),
                    buffer_device_address: false,
                    allocation_sizes: Default::default(),
                })
                .map_err(|source| Error::Allocation {
                    name: "allocator".into(),
                    source,
                })?;
                AllocatorSlot::Owned(ManuallyDrop::new(Mutex::new(allocator)))
            }
        };
        let name = properties
            .device_name_as_c_str()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let log = Arc::new(MessageLog::default());
        let log_user_data = Arc::into_raw(log.clone());
        let info = DeviceInfo {
            name,
            device_type: properties.device_type,
            limits: properties.limits,
            timestamp_period_ns: properties.limits.timestamp_period,
            timestamps_supported: family.timestamp_valid_bits > 0,
            validation: false,
            synchronization_validation: false,
            storage_image_extended_formats: features.shader_storage_image_extended_formats
                == vk::TRUE,
            // The host's device: whether it enabled VK_EXT_memory_budget is not known here.
            memory: memory_limits(&host.instance, host.physical_device, false)?,
        };
        let shared = DeviceShared {
            allocator,
            live_allocations: AtomicUsize::new(0),
            owns_device: false,
            device: host.device,
            physical_device: host.physical_device,
            queue: host.queue,
            queue_lock: Mutex::new(()),
            queue_family: host.queue_family,
            info,
            instance: host.instance,
            debug_utils: None,
            log,
            log_user_data,
            _entry: host.entry,
        };
        Ok(Self {
            shared: Arc::new(shared),
        })
    }

    /// What the device is and what it can do.
    pub fn info(&self) -> &DeviceInfo {
        &self.shared.info
    }

    /// The shared message log; keep a clone to inspect messages after the context is dropped.
    pub fn message_log(&self) -> Arc<MessageLog> {
        self.shared.log.clone()
    }

    /// Number of live allocations this crate made (0 once every resource is dropped).
    pub fn live_allocation_count(&self) -> usize {
        self.shared.live_allocations.load(Ordering::SeqCst)
    }

    /// Bytes of device memory this crate's live allocations use (sub-allocations through
    /// gpu-allocator, not counting the unused rest of its memory blocks).
    pub fn allocated_bytes(&self) -> u64 {
        self.shared
            .allocator()
            .generate_report()
            .total_allocated_bytes
    }

    /// The ash device, for hosts that record into their own command buffers.
    pub fn device(&self) -> &ash::Device {
        &self.shared.device
    }

    /// The instance the device was created from (for hosts that create their own objects on a
    /// context made with [`GpuContext::new`], e.g. to query memory types).
    pub fn instance(&self) -> &ash::Instance {
        self.shared.instance()
    }

    /// The physical device of [`GpuContext::device`].
    pub fn physical_device(&self) -> vk::PhysicalDevice {
        self.shared.physical_device
    }

    /// The graphics + compute queue family the context uses (for the host's command pools).
    pub fn queue_family(&self) -> u32 {
        self.shared.queue_family
    }

    /// The queue the context uses. A host that submits to it itself must not do so while a
    /// `renderer::Renderer` on the same context submits from another thread (the
    /// queue needs external synchronisation).
    pub fn queue(&self) -> vk::Queue {
        self.shared.queue
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cap only lowers the driver's limit, and a bad value is an error naming the variable.
    #[test]
    fn the_allocation_cap_only_lowers_the_limit() {
        let gib = 1u64 << 30;
        assert_eq!(
            capped_allocation_limit(2 * gib, None).unwrap(),
            (2 * gib, false)
        );
        assert_eq!(
            capped_allocation_limit(2 * gib, Some("64")).unwrap(),
            (64 << 20, true)
        );
        assert_eq!(
            capped_allocation_limit(2 * gib, Some("4096")).unwrap(),
            (2 * gib, false)
        );
        assert_eq!(
            capped_allocation_limit(0, Some(" 8 ")).unwrap(),
            (8 << 20, true)
        );
        for bad in ["0", "-1", "1.5", "lots", ""] {
            let e = capped_allocation_limit(gib, Some(bad))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(ALLOCATION_CAP_ENV) && e.contains("MiB"),
                "{bad}: {e}"
            );
        }
    }
    use gpu_allocator::MemoryLocation;

    #[test]
    fn a_leaked_allocation_is_reported_at_shutdown() {
        let ctx = GpuContext::new(&ContextDesc {
            validation: true,
            device_name: None,
        })
        .unwrap();
        let log = ctx.message_log();
        // Allocate straight from the allocator and never free it (an Allocation holds no
        // reference to the context, so the context still shuts down).
        let requirements = vk::MemoryRequirements {
            size: 256,
            alignment: 16,
            memory_type_bits: u32::MAX,
        };
        let leaked = ctx
            .shared
            .allocator()
            .allocate(&gpu_allocator::vulkan::AllocationCreateDesc {
                name: "deliberately leaked",
                requirements,
                location: MemoryLocation::CpuToGpu,
                linear: true,
                allocation_scheme: gpu_allocator::vulkan::AllocationScheme::GpuAllocatorManaged,
            })
            .unwrap();
        assert_eq!(
            ctx.shared.allocator().generate_report().allocations.len(),
            1
        );
        std::mem::forget(leaked);
        drop(ctx);
        let leaks: Vec<_> = log
            .all()
            .into_iter()
            .filter(|m| m.id_name == "mixvol-leaked-allocation")
            .collect();
        assert_eq!(leaks.len(), 1, "{leaks:?}");
        assert!(leaks[0].text.contains("deliberately leaked"));
    }
}
