//! Failures: [`Failure`], the status and message of a failed call, the thread's last error and
//! [`guard`], which turns a failure or a panic into a status.

use crate::h2n_status;
use human2nav_core::PlanError;
use human2nav_flow::planner::PlannerError;
use std::cell::RefCell;
use std::ffi::CString;
use std::panic::{AssertUnwindSafe, catch_unwind};

thread_local! {
    pub(crate) static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

/// A failed call: its status and message.
pub(crate) struct Failure {
    status: h2n_status,
    message: String,
}

impl Failure {
    pub(crate) fn new(status: h2n_status, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }

    pub(crate) fn invalid(message: impl Into<String>) -> Self {
        Self::new(h2n_status::InvalidArgument, message)
    }
}

impl From<PlannerError> for Failure {
    fn from(e: PlannerError) -> Self {
        let status = match &e {
            PlannerError::Config { .. }
            | PlannerError::Setting { .. }
            | PlannerError::Profile { .. } => h2n_status::Config,
            PlannerError::Model { .. } => h2n_status::Model,
            PlannerError::Plugin { .. } => h2n_status::Plugin,
            PlannerError::Plan(PlanError::InvalidObservation(_)) => h2n_status::InvalidArgument,
            PlannerError::Plan(PlanError::InvalidSettings(_)) => h2n_status::Config,
            PlannerError::Plan(_) => h2n_status::Plan,
        };
        Self::new(status, e.to_string())
    }
}

fn set_last_error(message: &str) {
    // A message with an interior NUL is cut there rather than lost.
    let text = message.split('\0').next().unwrap_or_default();
    let c = CString::new(text).unwrap_or_default();
    LAST_ERROR.with(|slot| *slot.borrow_mut() = c);
}

/// Runs `f`, turning its failure or panic into a status and the thread's last error.
pub(crate) fn guard(f: impl FnOnce() -> Result<(), Failure>) -> h2n_status {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => h2n_status::Ok,
        Ok(Err(failure)) => {
            set_last_error(&failure.message);
            failure.status
        }
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_owned());
            set_last_error(&format!("internal error (panic): {what}"));
            h2n_status::Panic
        }
    }
}
