//! What the validation layers say: the debug-utils messenger callback and the log it records
//! into, which tests and tools read to fail on any warning or error.

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
