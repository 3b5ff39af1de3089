//! The host side: loading libraries (libloading) and proxies that implement the core traits.
//!
//! A [`PluginLibrary`] is loaded once per canonical path and never unloaded: the `Library`
//! handle is leaked on purpose, so the vtables and static strings it hands out stay valid for
//! the life of the process. Proxies ([`PluginConstraint`], [`PluginEmbodiment`],
//! [`PluginPlanner`]) implement [`ConstraintTerm`], [`Embodiment`] and [`Planner`]; a planner,
//! simulator or CLI holding a `Box<dyn ...>` cannot tell them from built-ins.
//!
//! Before the OS loader sees a file, [`crate::libfile`] checks it (a truncated library would
//! otherwise fault inside `dlopen`); every table, function slot, count and string the plugin
//! hands over is checked before use ([`crate::validate`]); every call runs under a deadline
//! ([`crate::deadline`]), and, with [`PluginIsolation::Process`], in a helper process
//! ([`crate::process`]).
//!
//! A plugin call that panicked (or missed its deadline, or whose helper process died) marks its
//! instance unusable: later calls fail with an error naming the original failure (constraints,
//! planners) or return the documented safe value (embodiments, whose trait methods cannot fail:
//! zero twist, robot halted in place). The [`PluginHost`] that created an instance lists such
//! failures in [`PluginHost::failures`].

use crate::abi::*;
use crate::deadline::{self, NoAnswer, Worker};
use crate::error::{PluginError, PluginKind};
use crate::init::RobotContext;
use crate::libfile::{self, MAX_LIBRARY_BYTES};
use crate::locate::resolve_library_path;
use crate::process::{self as proc_host, ProcessClient};
use crate::validate::{
    Check, EvaluateBuffers, MAX_DESCRIPTION_BYTES, MAX_FACTORIES, MAX_MESSAGE_BYTES,
    MAX_NAME_BYTES, MAX_PLAN_POSES, MAX_TABLE_BYTES, plugin_str,
};
use human2nav_core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::obstacle::Obstacle;
use human2nav_core::robot::PluginIsolation;
use human2nav_core::{
    AgentState, CoupledLimit, Observation, Plan, PlanError, PlanInfo, Planner, Pose2, Twist2,
};
use std::collections::HashMap;
use std::ffi::c_void;
use std::fmt;
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

mod constraint;
mod embodiment;
mod instance;
mod library;
mod planner;
#[cfg(test)]
mod tests;
mod vtable;

pub use constraint::PluginConstraint;
use embodiment::call_coupled_limit;
pub use embodiment::{MAX_EMBODIMENT_YAW_RATE, PluginEmbodiment};
pub use instance::PluginFailure;
use instance::{Handle, Health};
pub(crate) use library::abi_version_text;
use library::table_size;
pub use library::{FactoryInfo, PluginLibrary};
pub use planner::PluginPlanner;
use vtable::instance_name;
pub(crate) use vtable::{VTable, checked_vtable, probe_factory};

/// The text of a host buffer the plugin wrote `len` bytes (full length) into.
fn buffer_text(buf: &[u8], len: usize) -> String {
    // The claimed length is not trusted past the first NUL (a C string ends there), and
    // control characters are not passed on to a terminal or a report.
    let shown = &buf[..len.min(buf.len())];
    let shown = shown.split(|&b| b == 0).next().unwrap_or_default();
    let text: String = String::from_utf8_lossy(shown)
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    let mut s = one_line(&text);
    if len > buf.len() {
        s.push_str(" …");
    }
    s
}

/// Joins the lines of a message (dlerror and panic messages may span several).
fn one_line(s: &str) -> String {
    s.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}

/// Loads plugin libraries and creates instances whose proxies implement the core traits.
/// Loading is explicit: only the libraries named in calls are loaded.
#[derive(Debug, Default)]
pub struct PluginHost {
    instances: Mutex<Vec<Arc<Health>>>,
    /// The helper executable for out-of-process instances (`None`: found as described in
    /// [`crate::process`]).
    helper: Option<PathBuf>,
}

/// A created instance with its checked vtable.
struct Created<T: 'static> {
    handle: Handle,
    vtable: T,
    name: String,
    label: String,
}

impl PluginHost {
    /// A host with no instances yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// This host, starting out-of-process instances with the helper executable at `path`
    /// instead of looking for it (see [`crate::process`]).
    pub fn with_process_helper(mut self, path: impl Into<PathBuf>) -> Self {
        self.helper = Some(path.into());
        self
    }

    /// Lists an instance's health for [`PluginHost::failures`].
    fn register(&self, health: Arc<Health>) {
        let mut instances = self.instances.lock().unwrap_or_else(|e| e.into_inner());
        // Forget healthy instances that were dropped (a benchmark creates one planner per
        // episode); failed ones stay listed for `failures`.
        instances.retain(|h| Arc::strong_count(h) > 1 || h.poisoned());
        instances.push(health);
    }

    /// Starts an out-of-process instance (see [`crate::process`]).
    fn process_instance(
        &self,
        kind: PluginKind,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
    ) -> Result<(ProcessClient, String, Arc<Health>), PluginError> {
        let (client, name) = proc_host::start_instance(
            self.helper.as_deref(),
            kind,
            library,
            plugin,
            config,
            robot,
            deadline,
        )?;
        let health = Health::new(
            kind,
            format!(
                "{kind} `{name}` from {} (in its own process)",
                library.display()
            ),
        );
        self.register(Arc::clone(&health));
        Ok((client, name, health))
    }

    /// Loads a library (see [`PluginLibrary::load`]).
    pub fn load_library(&self, path: &Path) -> Result<Arc<PluginLibrary>, PluginError> {
        PluginLibrary::load(path)
    }

    /// Creates an instance of a vtable kind and checks its vtable and name.
    fn instance<T: VTable>(
        &self,
        library: &Path,
        name: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<Created<T>, PluginError> {
        let lib = self.load_library(library)?;
        let obj = lib.create(T::KIND, name, config, robot)?;
        // SAFETY: the factory of this kind returned this vtable; the library is never
        // unloaded. On failure the instance is leaked (see `checked_vtable`).
        let (vtable, _) = unsafe { checked_vtable::<T>(&lib, name, obj.vtable) }?;
        let label = format!("{} `{name}` from {}", T::KIND, lib.path.display());
        let health = Health::new(T::KIND, label.clone());
        let handle = Handle {
            // SAFETY: `create` checked it is non-null.
            instance: unsafe { NonNull::new_unchecked(obj.instance) },
            destroy: vtable.destroy_fn().ok_or_else(|| PluginError::NullSlot {
                path: lib.path.clone(),
                table: format!("{} vtable of `{name}`", T::KIND),
                slot: "destroy",
            })?,
            last_error: vtable.last_error_fn(),
            health: Arc::clone(&health),
            library: Arc::clone(&lib),
        };
        // SAFETY: a live instance of this vtable.
        let instance_name = unsafe { instance_name(vtable.name_fn(), handle.ptr(), name) }
            .map_err(|m| PluginError::Malformed {
                path: lib.path.clone(),
                message: format!("{} `{name}`: {m}", T::KIND),
            })?;
        self.register(health);
        Ok(Created {
            handle,
            vtable,
            name: instance_name,
            label,
        })
    }

    /// Instances created by this host that became unusable (a plugin panicked or missed its
    /// deadline).
    pub fn failures(&self) -> Vec<PluginFailure> {
        self.instances
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .filter(|h| h.poisoned())
            .map(|h| PluginFailure {
                kind: h.kind,
                instance: h.label.clone(),
                message: h.message(),
            })
            .collect()
    }
}

/// A worker thread's name from an instance name the plugin chose: `h2n-` and at most 11 of its
/// ASCII letters, digits, `-` and `_` (a name with a NUL byte would make the spawn panic).
fn thread_name(instance: &str) -> String {
    let tail: String = instance
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
        .take(11)
        .collect();
    format!("h2n-{tail}")
}

fn worker_error(label: &str, e: std::io::Error) -> PluginError {
    PluginError::Worker {
        instance: label.to_owned(),
        message: e.to_string(),
    }
}

/// A proxy's worker (an instance in process under a deadline) and the buffers of the call not
/// in flight; the constraint and embodiment proxies share it.
struct Slot<J> {
    /// `None` once the instance missed a deadline (the worker was let go).
    worker: Option<Worker<Box<J>>>,
    spare: Option<Box<J>>,
}

impl<J: Send + 'static> Slot<J> {
    /// Starts the worker thread of instance `name` (`label` names it in errors), which runs
    /// `run` on each job.
    fn spawn(
        name: &str,
        label: &str,
        run: impl FnMut(&mut Box<J>) + Send + 'static,
    ) -> Result<Mutex<Self>, PluginError> {
        let worker = Worker::spawn(thread_name(name), run).map_err(|e| worker_error(label, e))?;
        Ok(Mutex::new(Slot {
            worker: Some(worker),
            spare: None,
        }))
    }
}

/// Copies agents into ABI records (history pointers left null) and their histories into one
/// flat buffer; [`link_histories`] points the records into it where the call is made.
fn load_agents(src: &[AgentState], agents: &mut Vec<H2nAgent>, history: &mut Vec<f64>) {
    agents.clear();
    history.clear();
    for a in src {
        agents.push(H2nAgent {
            history: std::ptr::null(),
            ..H2nAgent::borrow(a)
        });
        history.extend(a.history.iter().flatten());
    }
}

/// Points each agent's `history` into `history` (filled by [`load_agents`]).
fn link_histories(agents: &mut [H2nAgent], history: &[f64]) {
    let mut at = 0usize;
    for a in agents {
        let n = 2 * a.history_len;
        a.history = match history.get(at..at + n) {
            Some(h) if n > 0 => h.as_ptr(),
            _ => std::ptr::null(),
        };
        at += n;
    }
}

/// The host's table validation on tables built in memory, for the fuzz harness
/// (`human2nav-fuzz`); not part of the API.
#[doc(hidden)]
pub mod fuzzing {
    use super::*;

    /// Validates an entry table exactly as after `dlopen` (`PluginLibrary::from_entry`) and
    /// returns the factories it declares, with the checks.
    ///
    /// # Safety
    /// As for `from_entry`, except that the memory need only stay valid for this call (nothing
    /// of the table is kept: names are copied and no `create` is called).
    pub unsafe fn check_entry_table(
        raw: *const H2nPluginEntry,
    ) -> (Result<Vec<FactoryInfo>, PluginError>, Vec<Check>) {
        let mut checks = Vec::new();
        // SAFETY: the caller's contract.
        let r = unsafe { PluginLibrary::from_entry(Path::new("fuzz.so"), raw, &mut checks) };
        (r.map(|lib| lib.factories), checks)
    }

    /// Validates a vtable of `kind` (`checked_vtable`); an unknown kind is an error.
    ///
    /// # Safety
    /// As for `checked_vtable`, except that the memory need only stay valid for this call.
    pub unsafe fn check_vtable(
        kind: PluginKind,
        raw: *const c_void,
    ) -> Result<String, PluginError> {
        let lib = PluginLibrary {
            path: PathBuf::from("fuzz.so"),
            abi_version: ABI_VERSION,
            name: "fuzz".into(),
            version: String::new(),
            factories: Vec::new(),
            creates: Vec::new(),
            checks: Vec::new(),
        };
        // SAFETY (all three): the caller's contract; the returned reference is dropped here.
        match kind {
            PluginKind::Constraint => unsafe {
                checked_vtable::<H2nConstraintVTable>(&lib, "fuzz", raw).map(|r| r.1)
            },
            PluginKind::Embodiment => unsafe {
                checked_vtable::<H2nEmbodimentVTable>(&lib, "fuzz", raw).map(|r| r.1)
            },
            PluginKind::Planner => unsafe {
                checked_vtable::<H2nPlannerVTable>(&lib, "fuzz", raw).map(|r| r.1)
            },
            PluginKind::Unknown(c) => Err(PluginError::Malformed {
                path: lib.path.clone(),
                message: format!("unknown kind {c}"),
            }),
        }
    }

    /// Reads a plugin string as the host does ([`crate::validate`]'s caps), copied.
    ///
    /// # Safety
    /// As for `plugin_str`, for the duration of the call.
    pub unsafe fn read_plugin_str(s: H2nStr, cap: usize) -> Result<String, String> {
        // SAFETY: the caller's contract.
        unsafe { plugin_str(s, cap) }.map(str::to_owned)
    }
}
