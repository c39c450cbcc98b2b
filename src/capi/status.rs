//! Status codes, the per-thread last error, and the guard every export runs in.

use std::cell::RefCell;
use std::ffi::{CString, c_char};
use std::panic::{AssertUnwindSafe, catch_unwind};

/// What a call returns: `KPCN_OK` (0) or why it failed. [`kpcn_last_error`] has the message.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(clippy::enum_variant_names)] // the C names (KPCN_OK, …) come from these
pub enum KpcnStatus {
    /// Success.
    KpcnOk = 0,
    /// A NULL where a value is needed, an unknown name or enum value, a bad size or stride.
    KpcnErrorInvalidArgument = 1,
    /// The call does not fit the denoiser's state: a missing input or output image, sizes
    /// that disagree, a handle that was freed.
    KpcnErrorInvalidState = 2,
    /// A file could not be read or written.
    KpcnErrorIo = 3,
    /// The model could not be loaded or evaluated.
    KpcnErrorModel = 4,
    /// The progress callback asked to stop. Output images and files are untouched.
    KpcnErrorCancelled = 5,
    /// A bug in kpcn (a caught panic). The message says where; please report it.
    KpcnErrorInternal = 6,
    /// A struct's `struct_size` is not one this library knows.
    KpcnErrorUnsupportedVersion = 7,
    /// Memory ran out. Nothing was written; lower `max_memory_mb` or free memory.
    KpcnErrorOutOfMemory = 8,
}

/// An error on its way to the caller: a status and a message.
#[derive(Debug)]
pub(crate) struct Failure {
    pub status: KpcnStatus,
    pub message: String,
}

impl Failure {
    pub fn new(status: KpcnStatus, message: impl Into<String>) -> Self {
        Failure { status, message: message.into() }
    }

    pub fn invalid(message: impl Into<String>) -> Self {
        Self::new(KpcnStatus::KpcnErrorInvalidArgument, message)
    }

    pub fn state(message: impl Into<String>) -> Self {
        Self::new(KpcnStatus::KpcnErrorInvalidState, message)
    }
}

impl From<crate::io::IoError> for Failure {
    fn from(e: crate::io::IoError) -> Self {
        use crate::io::IoError;
        let status = match e {
            IoError::BadImage { .. } => KpcnStatus::KpcnErrorInvalidArgument,
            IoError::MissingImages { .. } | IoError::MissingChannels { .. } => KpcnStatus::KpcnErrorInvalidState,
            IoError::OutOfMemory { .. } => KpcnStatus::KpcnErrorOutOfMemory,
            _ => KpcnStatus::KpcnErrorIo,
        };
        Failure::new(status, e.to_string())
    }
}

impl From<crate::model::ModelError> for Failure {
    fn from(e: crate::model::ModelError) -> Self {
        let status = match e {
            crate::model::ModelError::OutOfMemory(_) => KpcnStatus::KpcnErrorOutOfMemory,
            _ => KpcnStatus::KpcnErrorModel,
        };
        Failure::new(status, e.to_string())
    }
}

impl From<crate::denoise::DenoiseError> for Failure {
    fn from(e: crate::denoise::DenoiseError) -> Self {
        use crate::denoise::DenoiseError;
        let status = match e {
            DenoiseError::Cancelled => KpcnStatus::KpcnErrorCancelled,
            DenoiseError::Model(crate::model::ModelError::OutOfMemory(_)) => KpcnStatus::KpcnErrorOutOfMemory,
            DenoiseError::Model(_) => KpcnStatus::KpcnErrorModel,
            DenoiseError::Threads(_) | DenoiseError::Empty => KpcnStatus::KpcnErrorInvalidArgument,
            DenoiseError::OutOfMemory(_) => KpcnStatus::KpcnErrorOutOfMemory,
        };
        Failure::new(status, e.to_string())
    }
}

impl From<crate::denoise::FileError> for Failure {
    fn from(e: crate::denoise::FileError) -> Self {
        use crate::denoise::FileError;
        match e {
            FileError::Io(io) => io.into(),
            FileError::Refused { .. } => Failure::invalid(e.to_string()),
            FileError::Denoise { path, cause } => {
                let inner = Failure::from(cause);
                Failure::new(inner.status, format!("{}: {}", path.display(), inner.message))
            }
        }
    }
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

/// Records `f` as this thread's last error and returns its status.
pub(crate) fn record(f: Failure) -> KpcnStatus {
    // Interior NULs cannot cross into C; they cannot come from our messages anyway.
    let text = CString::new(f.message.replace('\0', " ")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = text);
    f.status
}

/// Runs an export's body: its error, or a panic inside it, becomes a status and this
/// thread's last error. Nothing unwinds into the host.
pub(crate) fn guard(body: impl FnOnce() -> Result<(), Failure>) -> KpcnStatus {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => KpcnStatus::KpcnOk,
        Ok(Err(f)) => record(f),
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            record(Failure::new(KpcnStatus::KpcnErrorInternal, format!("internal error: {what}")))
        }
    }
}

/// The message of the last call that failed on this thread (`""` if none did). The pointer
/// stays valid until the next failing call on this thread; copy it to keep it.
#[unsafe(no_mangle)]
pub extern "C" fn kpcn_last_error() -> *const c_char {
    catch_unwind(|| LAST_ERROR.with(|e| e.borrow().as_ptr())).unwrap_or(c"".as_ptr())
}

/// A constant English description of a status code (also for codes this library does not
/// know). Never NULL.
#[unsafe(no_mangle)]
pub extern "C" fn kpcn_status_string(status: i32) -> *const c_char {
    let s = match status {
        0 => c"ok",
        1 => c"invalid argument",
        2 => c"invalid state",
        3 => c"input/output error",
        4 => c"model error",
        5 => c"cancelled",
        6 => c"internal error",
        7 => c"unsupported struct version",
        8 => c"out of memory",
        _ => c"unknown status",
    };
    s.as_ptr()
}
