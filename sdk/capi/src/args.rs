//! Argument helpers: the checks every function makes of its pointers, strings and numbers
//! before it uses them.

use crate::failure::Failure;
use crate::{h2n_planner, h2n_status};
use std::ffi::{CStr, c_char};

/// A required string argument.
///
/// # Safety
/// `p` is NULL or a NUL-terminated string valid for the call.
pub(crate) unsafe fn required_str<'a>(p: *const c_char, name: &str) -> Result<&'a str, Failure> {
    // SAFETY: forwarded from the caller.
    unsafe { optional_str(p, name) }?.ok_or_else(|| Failure::invalid(format!("{name} is NULL")))
}

/// An optional string argument (NULL: `None`).
///
/// # Safety
/// `p` is NULL or a NUL-terminated string valid for the call.
pub(crate) unsafe fn optional_str<'a>(
    p: *const c_char,
    name: &str,
) -> Result<Option<&'a str>, Failure> {
    if p.is_null() {
        return Ok(None);
    }
    // SAFETY: the caller passes a NUL-terminated string (function contract).
    let s = unsafe { CStr::from_ptr(p) };
    s.to_str()
        .map(Some)
        .map_err(|e| Failure::invalid(format!("{name} is not UTF-8: {e}")))
}

/// The object behind a required pointer.
///
/// # Safety
/// `p` is NULL or points to a live `T`.
pub(crate) unsafe fn required_ref<'a, T>(p: *const T, name: &str) -> Result<&'a T, Failure> {
    // SAFETY: forwarded from the caller.
    unsafe { p.as_ref() }.ok_or_else(|| Failure::invalid(format!("{name} is NULL")))
}

/// The writable object behind a required output pointer.
///
/// # Safety
/// `p` is NULL or points to writable memory for a `T`.
pub(crate) unsafe fn required_out<'a, T>(p: *mut T, name: &str) -> Result<&'a mut T, Failure> {
    // SAFETY: forwarded from the caller.
    unsafe { p.as_mut() }.ok_or_else(|| Failure::invalid(format!("{name} is NULL")))
}

/// The planner behind a handle, refused when an earlier call panicked in it.
///
/// # Safety
/// `p` is NULL or a planner from `h2n_planner_create*` not yet freed.
pub(crate) unsafe fn planner_mut<'a>(p: *mut h2n_planner) -> Result<&'a mut h2n_planner, Failure> {
    // SAFETY: forwarded from the caller.
    let planner = unsafe { required_out(p, "planner") }?;
    if planner.busy {
        return Err(Failure::new(
            h2n_status::Poisoned,
            "the planner panicked in an earlier call; free it and create a new one",
        ));
    }
    Ok(planner)
}

pub(crate) fn finite(name: &str, values: &[f64]) -> Result<(), Failure> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Failure::invalid(format!("{name} is not finite")))
    }
}
