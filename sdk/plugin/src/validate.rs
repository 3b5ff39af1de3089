//! What the host checks in the tables a plugin hands it, and the caps on every count and size
//! that comes from a plugin.
//!
//! A plugin is code the user chose to run, so it can always crash the process on purpose; what
//! the host guards against is a *broken* plugin (a hand-written C table with a missing function,
//! a plugin built against other headers, a bad length) taking the host down with a segfault or
//! a multi-gigabyte allocation. Every table is checked when it is first seen, before any of its
//! functions is called:
//!
//! * tables: non-null and aligned; `struct_size` at least what this ABI needs and at most
//!   [`MAX_TABLE_BYTES`]; the factory array's stride is the first factory's `struct_size`, and
//!   every factory must have the same one;
//! * function slots: every required slot non-null (a null one is an error naming the file, the
//!   table and the slot); the optional ones are listed in [`crate::abi`] (`find_factory`,
//!   `last_error`, `name`, `reset`);
//! * counts and lengths, against the caps below: factories, strings, plan lengths, messages.
//!   A string with a null pointer and a non-zero length is refused, as is text that is not
//!   UTF-8.

use std::fmt;

/// Most factories one library may declare.
pub const MAX_FACTORIES: usize = 256;
/// Largest `struct_size` of any table (entry, factory, vtable). Tables are append-only, so a
/// newer plugin may declare more than this host knows; four kilobytes is far beyond any
/// plausible extension and catches a garbage size.
pub const MAX_TABLE_BYTES: usize = 4096;
/// Longest plugin name, version, factory name or instance name (bytes).
pub const MAX_NAME_BYTES: usize = 256;
/// Longest factory description (bytes).
pub const MAX_DESCRIPTION_BYTES: usize = 4096;
/// Longest plan a planner may return (poses): 1000 s at 0.1 s.
pub const MAX_PLAN_POSES: usize = 10_000;
/// Longest error message or plan note the host reads (bytes); longer ones are cut.
pub const MAX_MESSAGE_BYTES: usize = 1 << 16;

/// How a check came out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CheckStatus {
    /// The check was made and passed.
    Passed,
    /// The check was made and failed; the [`Check::detail`] says why.
    Failed,
    /// Not checked now (e.g. a factory that needs a configuration to create an instance: its
    /// vtable is checked when an instance is created).
    Deferred,
}

/// One thing the host checked about a library, a factory or an instance.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Check {
    /// What was checked (`file`, `entry table`, `factory 0 (constraint `x`)`, ...).
    pub item: String,
    /// Whether the check passed, failed or was not run.
    pub status: CheckStatus,
    /// What was found (on failure, the error).
    pub detail: String,
}

impl Check {
    pub(crate) fn pass(item: impl Into<String>, detail: impl Into<String>) -> Self {
        Self {
            item: item.into(),
            status: CheckStatus::Passed,
            detail: detail.into(),
        }
    }

    pub(crate) fn fail(item: impl Into<String>, detail: impl Into<String>) -> Self {
        Self {
            item: item.into(),
            status: CheckStatus::Failed,
            detail: detail.into(),
        }
    }

    pub(crate) fn defer(item: impl Into<String>, detail: impl Into<String>) -> Self {
        Self {
            item: item.into(),
            status: CheckStatus::Deferred,
            detail: detail.into(),
        }
    }

    /// True unless the check failed.
    pub fn passed(&self) -> bool {
        self.status != CheckStatus::Failed
    }
}

impl fmt::Display for Check {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mark = match self.status {
            CheckStatus::Passed => "ok   ",
            CheckStatus::Failed => "FAIL ",
            CheckStatus::Deferred => "later",
        };
        write!(f, "{mark} {}: {}", self.item, self.detail)
    }
}

/// The buffer lengths of one constraint `evaluate` call, as the host passes them and the
/// plugin receives them: `values` poses values for `batch` trajectories of `horizon` poses
/// (`x, y, θ`), one `cost` entry per trajectory and one `grad` entry per pose value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct EvaluateBuffers {
    pub batch: usize,
    pub horizon: usize,
    pub values: usize,
    pub cost: usize,
    pub grad: usize,
}

impl EvaluateBuffers {
    /// Checks `values == batch·horizon·3` (without overflow), then `cost == batch`, then
    /// `grad == values`; the error describes the first mismatch.
    pub(crate) fn check(&self) -> Result<(), String> {
        let expected = self
            .batch
            .checked_mul(self.horizon)
            .and_then(|n| n.checked_mul(3));
        if expected != Some(self.values) {
            return Err(format!(
                "{} values cannot be {} trajectories × {} poses × 3",
                self.values, self.batch, self.horizon
            ));
        }
        if self.cost != self.batch {
            return Err(format!(
                "cost has {} entries for {} trajectories",
                self.cost, self.batch
            ));
        }
        if self.grad != self.values {
            return Err(format!(
                "gradient has {} entries, the batch {}",
                self.grad, self.values
            ));
        }
        Ok(())
    }
}

/// Reads a string a plugin handed over: at most `cap` bytes, UTF-8, and a null pointer only
/// with length 0. The error is a phrase for "<what> <error>".
///
/// # Safety
/// When `s.ptr` is non-null and `s.len <= cap`, it must point to `s.len` readable bytes that
/// stay valid for `'a`.
pub(crate) unsafe fn plugin_str<'a>(s: crate::abi::H2nStr, cap: usize) -> Result<&'a str, String> {
    if s.len == 0 {
        return Ok("");
    }
    if s.ptr.is_null() {
        return Err(format!("is null with length {}", s.len));
    }
    if s.len > cap {
        return Err(format!("is {} bytes long, the limit is {cap}", s.len));
    }
    // SAFETY: non-null, within the cap, readable per the caller's contract.
    let bytes = unsafe { std::slice::from_raw_parts(s.ptr, s.len) };
    std::str::from_utf8(bytes).map_err(|e| format!("is not UTF-8: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn buffers(batch: usize, horizon: usize, values: usize, cost: usize, grad: usize) -> String {
        EvaluateBuffers {
            batch,
            horizon,
            values,
            cost,
            grad,
        }
        .check()
        .err()
        .unwrap_or_default()
    }

    #[test]
    fn evaluate_buffers_name_the_first_mismatch() {
        assert_eq!(buffers(2, 4, 24, 2, 24), "");
        assert_eq!(buffers(0, 0, 0, 0, 0), "");
        assert_eq!(
            buffers(2, 4, 23, 2, 24),
            "23 values cannot be 2 trajectories × 4 poses × 3"
        );
        assert_eq!(
            buffers(2, 4, 24, 3, 25),
            "cost has 3 entries for 2 trajectories"
        );
        assert_eq!(
            buffers(2, 4, 24, 2, 25),
            "gradient has 25 entries, the batch 24"
        );
        // B·T·3 overflowing usize is a mismatch, not a wrapped product.
        let huge = usize::MAX / 2 + 1;
        assert_eq!(
            buffers(huge, 2, 0, huge, 0),
            format!("0 values cannot be {huge} trajectories × 2 poses × 3")
        );
    }
}
