//! What the validation layers say: the debug-utils messenger callback and the log it records
//! into, which tests and tools read to fail on any warning or error; and the test hook
//! [`INVALID_CALL_ENV`], which makes one deliberately invalid Vulkan call so that a test can see
//! a real validation message travel to the tool's output.

use ash::vk;
use std::ffi::c_void;
use std::sync::{Mutex, MutexGuard};

/// Severity of a recorded debug-utils message.
#[derive(Copy, Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    /// Diagnostic chatter.
    Verbose,
    /// Informational.
    Info,
    /// Possible misuse or performance problem: fails a test.
    Warning,
    /// Invalid usage: fails a test.
    Error,
}

/// One message from the debug-utils messenger (or from the leak check at shutdown).
#[derive(Clone, Debug)]
pub struct DebugMessage {
    /// How bad it is.
    pub severity: Severity,
    /// The message id name (a VUID for validation errors), empty where none was given.
    pub id_name: String,
    /// The message text.
    pub text: String,
}

/// Every message the messenger received, in order. Shared so it can be read after the context is
/// gone (messages arrive up to `vkDestroyInstance`).
#[derive(Debug, Default)]
pub struct MessageLog {
    messages: Mutex<Vec<DebugMessage>>,
}

impl MessageLog {
    fn lock(&self) -> MutexGuard<'_, Vec<DebugMessage>> {
        // A poisoned log still holds valid messages: keep recording.
        self.messages.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(super) fn push(&self, message: DebugMessage) {
        self.lock().push(message);
    }

    /// All messages so far.
    pub fn all(&self) -> Vec<DebugMessage> {
        self.lock().clone()
    }

    /// Number of messages so far, of any severity.
    pub fn len(&self) -> usize {
        self.lock().len()
    }

    /// Whether no message arrived yet.
    pub fn is_empty(&self) -> bool {
        self.lock().is_empty()
    }

    /// Number of warnings and errors so far (without copying them).
    pub fn problem_count(&self) -> usize {
        self.lock()
            .iter()
            .filter(|m| m.severity >= Severity::Warning)
            .count()
    }

    /// Warnings and errors so far: a validated test expects none.
    pub fn warnings_and_errors(&self) -> Vec<DebugMessage> {
        self.lock()
            .iter()
            .filter(|m| m.severity >= Severity::Warning)
            .cloned()
            .collect()
    }
}

/// The debug-utils messenger callback: records every message into the [`MessageLog`] its user
/// data points to, and forwards it to the `log` crate.
///
/// # Safety
/// Called by the validation layer only: `data` is a valid callback-data pointer for the call and
/// `user_data` the `Arc<MessageLog>` pointer registered with the messenger, alive until after
/// the messenger is destroyed.
pub(super) unsafe extern "system" fn record_debug_message(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user_data: *mut c_void,
) -> vk::Bool32 {
    let severity = if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        Severity::Error
    } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING) {
        Severity::Warning
    } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::INFO) {
        Severity::Info
    } else {
        Severity::Verbose
    };
    // SAFETY: the layer passes a valid callback-data pointer for the duration of the call, and
    // `user_data` is the `Arc<MessageLog>` pointer registered in `GpuContext::new`, which stays
    // alive until after the messenger and the instance are destroyed.
    let (log, id_name, text) = unsafe {
        let data = &*data;
        let id_name = data
            .message_id_name_as_c_str()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let text = data
            .message_as_c_str()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        (&*(user_data as *const MessageLog), id_name, text)
    };
    match severity {
        Severity::Error => log::error!("[vulkan] {id_name}: {text}"),
        Severity::Warning => log::warn!("[vulkan] {id_name}: {text}"),
        Severity::Info => log::debug!("[vulkan] {id_name}: {text}"),
        Severity::Verbose => log::trace!("[vulkan] {id_name}: {text}"),
    }
    log.push(DebugMessage {
        severity,
        id_name,
        text,
    });
    vk::FALSE
}

/// Test hook: when this environment variable is set (to anything) and validation is on,
/// [`crate::gpu::GpuContext::new`] makes one deliberately invalid Vulkan call right after
/// creating the device: `vkCreateBuffer` with a `usage` of 0, which
/// `VUID-VkBufferCreateInfo-usage-requiredbitmask` forbids. The validation layer reports it
/// (and does not pass the call on to the driver), so a test can check that a real layer message
/// reaches the tool's stderr and its validation summary. Without validation the variable is
/// ignored (an invalid call nobody checks is undefined behaviour). Never set it otherwise.
pub const INVALID_CALL_ENV: &str = "MIXVOL_TEST_INVALID_VULKAN_CALL";

/// Makes the deliberately invalid call of [`INVALID_CALL_ENV`] on `device` (created with the
/// validation layer on); a buffer the call nevertheless created is destroyed at once.
pub(super) fn make_deliberately_invalid_call(device: &ash::Device) {
    log::warn!(
        "{INVALID_CALL_ENV} is set: making one deliberately invalid Vulkan call for the \
         validation layer to report"
    );
    let info = vk::BufferCreateInfo::default()
        .size(16)
        .usage(vk::BufferUsageFlags::empty())
        .sharing_mode(vk::SharingMode::EXCLUSIVE);
    // SAFETY: only made with the validation layer active, which reports the zero usage and
    // skips the call (returning an error); a buffer created anyway is destroyed right away and
    // never used.
    unsafe {
        if let Ok(buffer) = device.create_buffer(&info, None) {
            device.destroy_buffer(buffer, None);
        }
    }
}
