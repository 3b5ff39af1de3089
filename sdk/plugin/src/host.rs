//! The host side: loading libraries (libloading) and proxies that implement the core traits.
//!
//! A [`PluginLibrary`] is loaded once per canonical path and never unloaded: the `Library`
//! handle is leaked on purpose, so the vtables and static strings it hands out stay valid for
//! the life of the process. Proxies ([`PluginConstraint`], [`PluginEmbodiment`],
//! [`PluginPlanner`]) implement [`ConstraintTerm`], [`Embodiment`] and [`Planner`]; a planner,
//! simulator or CLI holding a `Box<dyn ...>` cannot tell them from built-ins.
//!
//! A plugin call that panicked marks its instance unusable: later calls fail with an error
//! naming the original panic (constraints, planners) or return the documented safe value
//! (embodiments, whose trait methods cannot fail: zero twist, robot halted in place). The
//! [`PluginHost`] that created an instance lists such failures in [`PluginHost::failures`].

use crate::abi::*;
use crate::error::{PluginError, PluginKind};
use crate::init::RobotContext;
use crate::resolve::resolve_library_path;
use human2nav_core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::{Observation, Plan, PlanError, PlanInfo, Planner, Pose2, Twist2};
use std::collections::HashMap;
use std::ffi::c_void;
use std::fmt;
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

/// One factory a library provides.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FactoryInfo {
    pub kind: PluginKind,
    pub name: String,
    pub description: String,
}

/// A loaded, validated plugin library.
pub struct PluginLibrary {
    path: PathBuf,
    entry: &'static H2nPluginEntry,
    name: String,
    version: String,
    factories: Vec<FactoryInfo>,
}

impl fmt::Debug for PluginLibrary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PluginLibrary")
            .field("path", &self.path)
            .field("name", &self.name)
            .field("version", &self.version)
            .field("factories", &self.factories)
            .finish()
    }
}

/// Libraries loaded by this process, by canonical path (never removed: never unloaded).
fn registry() -> &'static Mutex<HashMap<PathBuf, Arc<PluginLibrary>>> {
    static REGISTRY: OnceLock<Mutex<HashMap<PathBuf, Arc<PluginLibrary>>>> = OnceLock::new();
    REGISTRY.get_or_init(|| Mutex::new(HashMap::new()))
}

/// Reads a static string of the entry table.
///
/// # Safety
/// `s` must be readable for the life of the process (the library is never unloaded).
unsafe fn static_str(s: H2nStr, path: &Path, what: &str) -> Result<String, PluginError> {
    // SAFETY: forwarded contract.
    unsafe { s.as_str() }
        .map(str::to_owned)
        .map_err(|e| PluginError::Malformed {
            path: path.to_path_buf(),
            message: format!("{what} is not UTF-8: {e}"),
        })
}

impl PluginLibrary {
    /// Loads (or returns the already loaded) library at `path`, resolved as described in
    /// [`crate::resolve`]. Checks the ABI version before reading anything else.
    pub fn load(path: &Path) -> Result<Arc<PluginLibrary>, PluginError> {
        let file = resolve_library_path(path)?;
        let canonical = std::fs::canonicalize(&file).unwrap_or(file);
        let mut libs = registry().lock().unwrap_or_else(|e| e.into_inner());
        if let Some(lib) = libs.get(&canonical) {
            return Ok(Arc::clone(lib));
        }
        let lib = Arc::new(Self::open(&canonical)?);
        libs.insert(canonical, Arc::clone(&lib));
        Ok(lib)
    }

    fn open(path: &Path) -> Result<PluginLibrary, PluginError> {
        let err = |message: String| PluginError::Malformed {
            path: path.to_path_buf(),
            message,
        };
        // SAFETY: loading a library runs its initialisers. The user named this library
        // explicitly as a plugin; running its code is the purpose of loading it.
        let lib = unsafe { libloading::Library::new(path) }.map_err(|e| PluginError::Open {
            path: path.to_path_buf(),
            message: one_line(&e.to_string()),
        })?;
        // Never unloaded: every pointer the plugin hands out stays valid for the process.
        let lib: &'static libloading::Library = Box::leak(Box::new(lib));
        // SAFETY: the symbol, if present, has the `EntryFn` signature by the ABI contract.
        let entry_fn = unsafe { lib.get::<EntryFn>(ENTRY_SYMBOL.as_bytes()) }.map_err(|_| {
            PluginError::MissingEntry {
                path: path.to_path_buf(),
                symbol: ENTRY_SYMBOL,
            }
        })?;
        // SAFETY: calling the entry function of a plugin is the ABI's first step; it takes no
        // arguments and returns a pointer to static data.
        let raw = unsafe { entry_fn() };
        if raw.is_null() || !raw.is_aligned() {
            return Err(err(
                "the entry function returned a null or misaligned table".into(),
            ));
        }
        // SAFETY: every ABI version starts the entry table with a `u32` ABI version, so this
        // read is valid whatever version the plugin speaks. Nothing else is read before the
        // version is known to match.
        let found = unsafe { raw.cast::<u32>().read() };
        if found != ABI_VERSION {
            return Err(PluginError::AbiMismatch {
                path: path.to_path_buf(),
                found,
                expected: ABI_VERSION,
            });
        }
        // SAFETY: the versions match, so `raw` points to a v1 entry table in static memory
        // of a library that is never unloaded.
        let entry: &'static H2nPluginEntry = unsafe { &*raw };
        if (entry.struct_size as usize) < std::mem::size_of::<H2nPluginEntry>() {
            return Err(err(format!(
                "entry table is {} bytes, ABI {ABI_VERSION} needs {}",
                entry.struct_size,
                std::mem::size_of::<H2nPluginEntry>()
            )));
        }
        // SAFETY: static strings of a never-unloaded library.
        let name = unsafe { static_str(entry.name, path, "plugin name") }?;
        // SAFETY: as above.
        let version = unsafe { static_str(entry.version, path, "plugin version") }?;
        if entry.factory_count > 0 && (entry.factories.is_null() || !entry.factories.is_aligned()) {
            return Err(err("factory table is null or misaligned".into()));
        }
        let factories: &'static [H2nFactory] = if entry.factory_count == 0 {
            &[]
        } else {
            // SAFETY: checked non-null and aligned; `factory_count` entries in static memory.
            unsafe { std::slice::from_raw_parts(entry.factories, entry.factory_count) }
        };
        let mut infos = Vec::with_capacity(factories.len());
        for (i, f) in factories.iter().enumerate() {
            if (f.struct_size as usize) < std::mem::size_of::<H2nFactory>() {
                return Err(err(format!("factory {i} is {} bytes", f.struct_size)));
            }
            infos.push(FactoryInfo {
                kind: PluginKind::from_code(f.kind),
                // SAFETY: static strings of a never-unloaded library.
                name: unsafe { static_str(f.name, path, "factory name") }?,
                // SAFETY: as above.
                description: unsafe { static_str(f.description, path, "factory description") }?,
            });
        }
        Ok(PluginLibrary {
            path: path.to_path_buf(),
            entry,
            name,
            version,
            factories: infos,
        })
    }

    /// The library file (canonical path).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The plugin's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The plugin's own version.
    pub fn version(&self) -> &str {
        &self.version
    }

    /// The ABI version the library speaks (always [`ABI_VERSION`] once loaded).
    pub fn abi_version(&self) -> u32 {
        self.entry.abi_version
    }

    /// What the library provides.
    pub fn factories(&self) -> &[FactoryInfo] {
        &self.factories
    }

    /// Creates an instance through the factory `kind`/`name`.
    fn create(
        &self,
        kind: PluginKind,
        name: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<H2nObject, PluginError> {
        // SAFETY: `find_factory` is a function of the validated entry table; `name` is readable
        // for the duration of the call.
        let factory = unsafe { (self.entry.find_factory)(kind.code(), H2nStr::new(name)) };
        if factory.is_null() || !factory.is_aligned() {
            return Err(PluginError::UnknownFactory {
                path: self.path.clone(),
                plugin: self.name.clone(),
                kind,
                name: name.to_owned(),
                available: self
                    .factories
                    .iter()
                    .filter(|f| f.kind == kind)
                    .map(|f| f.name.clone())
                    .collect(),
            });
        }
        // SAFETY: non-null, aligned, points into the library's static factory table.
        let factory: &'static H2nFactory = unsafe { &*factory };
        if (factory.struct_size as usize) < std::mem::size_of::<H2nFactory>() {
            return Err(PluginError::Malformed {
                path: self.path.clone(),
                message: format!("factory `{name}` is {} bytes", factory.struct_size),
            });
        }
        let args = H2nCreateArgs {
            struct_size: std::mem::size_of::<H2nCreateArgs>() as u32,
            kind: kind.code(),
            config: H2nStr::new(config),
            has_robot: u32::from(robot.is_some()),
            reserved: 0,
            limits: robot.map(|r| (&r.limits).into()).unwrap_or_default(),
            gains: robot.map(|r| (&r.gains).into()).unwrap_or_default(),
            footprint_radius: robot.map_or(0.0, |r| r.footprint_radius),
        };
        let mut out = H2nObject {
            instance: std::ptr::null_mut(),
            vtable: std::ptr::null(),
        };
        let mut message = vec![0u8; 1024];
        let mut error = H2nBuffer {
            data: message.as_mut_ptr(),
            capacity: message.len(),
            len: 0,
        };
        // SAFETY: every pointer is valid for the duration of the call and the buffers are
        // host-owned with the stated capacities.
        let status = unsafe { (factory.create)(&args, &mut out, &mut error) };
        if status != H2N_OK {
            let message = buffer_text(&message, error.len);
            return Err(if status == H2N_CONFIG {
                PluginError::Config {
                    path: self.path.clone(),
                    kind,
                    name: name.to_owned(),
                    message,
                }
            } else {
                PluginError::Create {
                    path: self.path.clone(),
                    kind,
                    name: name.to_owned(),
                    status: status_name(status),
                    message,
                }
            });
        }
        if out.instance.is_null() || out.vtable.is_null() {
            return Err(PluginError::Malformed {
                path: self.path.clone(),
                message: format!("factory `{name}` reported success but returned a null object"),
            });
        }
        Ok(out)
    }
}

/// The text of a host buffer the plugin wrote `len` bytes (full length) into.
fn buffer_text(buf: &[u8], len: usize) -> String {
    let shown = &buf[..len.min(buf.len())];
    let mut s = one_line(&String::from_utf8_lossy(shown));
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

/// Health of one plugin instance, shared by its proxy and the host that created it.
#[derive(Debug)]
struct Health {
    label: String,
    poisoned: AtomicBool,
    message: Mutex<Option<String>>,
}

impl Health {
    fn new(label: String) -> Arc<Self> {
        Arc::new(Self {
            label,
            poisoned: AtomicBool::new(false),
            message: Mutex::new(None),
        })
    }

    fn poisoned(&self) -> bool {
        self.poisoned.load(Ordering::Acquire)
    }

    fn poison(&self, message: &str) {
        let mut m = self.message.lock().unwrap_or_else(|e| e.into_inner());
        if m.is_none() {
            *m = Some(message.to_owned());
        }
        self.poisoned.store(true, Ordering::Release);
    }

    fn message(&self) -> String {
        self.message
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
            .unwrap_or_default()
    }
}

/// A plugin instance that became unusable.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PluginFailure {
    /// `<kind> <name> from <library>`.
    pub instance: String,
    /// The panic (or last error) that made it unusable.
    pub message: String,
}

/// The instance part shared by the three proxies.
struct Handle {
    instance: NonNull<c_void>,
    destroy: unsafe extern "C" fn(*mut c_void),
    last_error: unsafe extern "C" fn(*mut c_void, *mut H2nBuffer),
    name: String,
    health: Arc<Health>,
    _library: Arc<PluginLibrary>,
}

// SAFETY: the ABI requires constraint and embodiment instances to accept concurrent calls from
// any thread; planner proxies only call through `&mut self`, so never concurrently.
unsafe impl Send for Handle {}
// SAFETY: as above.
unsafe impl Sync for Handle {}

impl Handle {
    fn ptr(&self) -> *mut c_void {
        self.instance.as_ptr()
    }

    /// The instance's last error message.
    fn last_error(&self) -> String {
        let mut buf = vec![0u8; 512];
        for _ in 0..2 {
            let mut out = H2nBuffer {
                data: buf.as_mut_ptr(),
                capacity: buf.len(),
                len: 0,
            };
            // SAFETY: live instance; host-owned buffer of the stated capacity.
            unsafe { (self.last_error)(self.ptr(), &mut out) };
            if out.len <= buf.len() {
                return buffer_text(&buf, out.len);
            }
            buf.resize(out.len.min(1 << 16), 0);
        }
        buffer_text(&buf, buf.len())
    }

    /// Turns a non-OK status into a message, poisoning the instance on a panic.
    fn failure(&self, status: H2nStatus) -> String {
        let message = self.last_error();
        let message = if message.is_empty() {
            status_name(status).to_owned()
        } else {
            message
        };
        if status == H2N_PANIC || status == H2N_POISONED {
            self.health.poison(&message);
        }
        message
    }
}

impl Drop for Handle {
    fn drop(&mut self) {
        // SAFETY: the instance is live and this is the only place it is destroyed.
        unsafe { (self.destroy)(self.ptr()) };
    }
}

impl fmt::Debug for Handle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Handle")
            .field("name", &self.name)
            .field("health", &self.health)
            .finish()
    }
}

/// Loads plugin libraries and creates instances whose proxies implement the core traits.
/// Loading is explicit: only the libraries named in calls are loaded.
#[derive(Debug, Default)]
pub struct PluginHost {
    instances: Mutex<Vec<Arc<Health>>>,
}

impl PluginHost {
    /// A host with no instances yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Loads a library (see [`PluginLibrary::load`]).
    pub fn load_library(&self, path: &Path) -> Result<Arc<PluginLibrary>, PluginError> {
        PluginLibrary::load(path)
    }

    fn handle(
        &self,
        lib: &Arc<PluginLibrary>,
        kind: PluginKind,
        name: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<(Handle, *const c_void), PluginError> {
        let obj = lib.create(kind, name, config, robot)?;
        let label = format!("{kind} `{name}` from {}", lib.path.display());
        let health = Health::new(label);
        {
            let mut instances = self.instances.lock().unwrap_or_else(|e| e.into_inner());
            // Forget healthy instances that were dropped (a benchmark creates one planner per
            // episode); failed ones stay listed for `failures`.
            instances.retain(|h| Arc::strong_count(h) > 1 || h.poisoned());
            instances.push(Arc::clone(&health));
        }
        // The callers replace `destroy` and `last_error` with the kind's vtable entries before
        // anything can drop the handle.
        Ok((
            Handle {
                // SAFETY: `create` checked it is non-null.
                instance: unsafe { NonNull::new_unchecked(obj.instance) },
                destroy: noop_destroy,
                last_error: noop_last_error,
                name: name.to_owned(),
                health,
                _library: Arc::clone(lib),
            },
            obj.vtable,
        ))
    }

    /// Reads the instance's name through the vtable's `name`.
    fn instance_name(handle: &Handle, name: unsafe extern "C" fn(*mut c_void) -> H2nStr) -> String {
        // SAFETY: live instance; the returned view lives as long as the instance, and is
        // copied immediately.
        let s = unsafe { name(handle.ptr()) };
        // SAFETY: as above.
        unsafe { s.as_str() }
            .map(str::to_owned)
            .unwrap_or_else(|_| handle.name.clone())
    }

    /// Creates a constraint term from `library` (path resolved per [`crate::resolve`]).
    pub fn constraint(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<PluginConstraint, PluginError> {
        let lib = self.load_library(library)?;
        let (mut handle, vtable) =
            self.handle(&lib, PluginKind::Constraint, plugin, config, robot)?;
        // SAFETY: the factory was of kind constraint, so its vtable is a constraint vtable
        // in the library's static memory.
        let vt: &'static H2nConstraintVTable = unsafe { &*vtable.cast::<H2nConstraintVTable>() };
        handle.destroy = vt.destroy;
        handle.last_error = vt.last_error;
        if (vt.struct_size as usize) < std::mem::size_of::<H2nConstraintVTable>() {
            return Err(malformed_vtable(&lib, plugin, vt.struct_size));
        }
        handle.name = Self::instance_name(&handle, vt.name);
        Ok(PluginConstraint { handle, vtable: vt })
    }

    /// Creates an embodiment for a robot with these limits and gains.
    pub fn embodiment(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: &RobotContext,
    ) -> Result<PluginEmbodiment, PluginError> {
        let lib = self.load_library(library)?;
        let (mut handle, vtable) =
            self.handle(&lib, PluginKind::Embodiment, plugin, config, Some(robot))?;
        // SAFETY: the factory was of kind embodiment, so its vtable is an embodiment vtable.
        let vt: &'static H2nEmbodimentVTable = unsafe { &*vtable.cast::<H2nEmbodimentVTable>() };
        handle.destroy = vt.destroy;
        handle.last_error = vt.last_error;
        if (vt.struct_size as usize) < std::mem::size_of::<H2nEmbodimentVTable>() {
            return Err(malformed_vtable(&lib, plugin, vt.struct_size));
        }
        handle.name = Self::instance_name(&handle, vt.name);
        Ok(PluginEmbodiment { handle, vtable: vt })
    }

    /// Creates a planner, optionally for a given robot.
    pub fn planner(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<PluginPlanner, PluginError> {
        let lib = self.load_library(library)?;
        let (mut handle, vtable) = self.handle(&lib, PluginKind::Planner, plugin, config, robot)?;
        // SAFETY: the factory was of kind planner, so its vtable is a planner vtable.
        let vt: &'static H2nPlannerVTable = unsafe { &*vtable.cast::<H2nPlannerVTable>() };
        handle.destroy = vt.destroy;
        handle.last_error = vt.last_error;
        if (vt.struct_size as usize) < std::mem::size_of::<H2nPlannerVTable>() {
            return Err(malformed_vtable(&lib, plugin, vt.struct_size));
        }
        handle.name = Self::instance_name(&handle, vt.name);
        Ok(PluginPlanner {
            handle,
            vtable: vt,
            poses: Vec::new(),
        })
    }

    /// Instances created by this host that became unusable (a plugin panicked).
    pub fn failures(&self) -> Vec<PluginFailure> {
        self.instances
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .filter(|h| h.poisoned())
            .map(|h| PluginFailure {
                instance: h.label.clone(),
                message: h.message(),
            })
            .collect()
    }
}

/// Placeholder `destroy` until the vtable is known (never called on a live instance: the
/// handle's functions are replaced before any early return can drop it).
unsafe extern "C" fn noop_destroy(_: *mut c_void) {}

unsafe extern "C" fn noop_last_error(_: *mut c_void, out: *mut H2nBuffer) {
    // SAFETY: the host only passes its own valid buffers.
    if let Some(out) = unsafe { out.as_mut() } {
        out.len = 0;
    }
}

fn malformed_vtable(lib: &PluginLibrary, plugin: &str, size: u32) -> PluginError {
    PluginError::Malformed {
        path: lib.path.clone(),
        message: format!("vtable of `{plugin}` is {size} bytes, too small for ABI {ABI_VERSION}"),
    }
}

/// Converts agents into ABI views borrowing their histories.
fn agent_views(agents: &[human2nav_core::AgentState]) -> Vec<H2nAgent> {
    agents.iter().map(H2nAgent::borrow).collect()
}

/// A constraint term living in a plugin library.
#[derive(Debug)]
pub struct PluginConstraint {
    handle: Handle,
    vtable: &'static H2nConstraintVTable,
}

impl PluginConstraint {
    /// True once the plugin panicked; the term then refuses to evaluate.
    pub fn is_poisoned(&self) -> bool {
        self.handle.health.poisoned()
    }
}

impl ConstraintTerm for PluginConstraint {
    fn name(&self) -> &str {
        &self.handle.name
    }

    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        let fail = |message: String| ConstraintError::Failed {
            term: self.handle.name.clone(),
            message,
        };
        if self.handle.health.poisoned() {
            return Err(fail(format!(
                "unusable after an earlier panic: {}",
                self.handle.health.message()
            )));
        }
        if batch.data.len() != batch.batch * batch.horizon * 3 {
            return Err(ConstraintError::Shape(format!(
                "{} values cannot be {} trajectories × {} poses × 3",
                batch.data.len(),
                batch.batch,
                batch.horizon
            )));
        }
        if cost.len() != batch.batch || grad.len() != batch.data.len() {
            return Err(ConstraintError::Shape(format!(
                "cost has {} entries and gradient {} for a batch of {} × {} poses",
                cost.len(),
                grad.len(),
                batch.batch,
                batch.horizon
            )));
        }
        let agents = agent_views(ctx.agents);
        let abi_batch = H2nTrajBatch {
            data: batch.data.as_ptr(),
            len: batch.data.len(),
            batch: batch.batch,
            horizon: batch.horizon,
            dim: 3,
        };
        let abi_ctx = H2nConstraintContext {
            struct_size: std::mem::size_of::<H2nConstraintContext>() as u32,
            reserved: 0,
            dt: ctx.dt,
            limits: ctx.limits.into(),
            initial_velocity: ctx.initial_velocity.into(),
            agents: agents.as_ptr(),
            agent_count: agents.len(),
        };
        // SAFETY: live instance; every pointer is valid for the call, output buffers are
        // distinct host-owned slices of the stated lengths.
        let status = unsafe {
            (self.vtable.evaluate)(
                self.handle.ptr(),
                &abi_batch,
                &abi_ctx,
                H2nF64Out {
                    data: cost.as_mut_ptr(),
                    len: cost.len(),
                },
                H2nF64Out {
                    data: grad.as_mut_ptr(),
                    len: grad.len(),
                },
            )
        };
        if status == H2N_OK {
            return Ok(());
        }
        let message = self.handle.failure(status);
        Err(match status {
            H2N_INVALID_ARGUMENT => ConstraintError::Shape(message),
            H2N_PANIC => fail(format!("panicked (the term is now unusable): {message}")),
            H2N_POISONED => fail(format!("unusable after an earlier panic: {message}")),
            _ => fail(message),
        })
    }
}

/// An embodiment living in a plugin library.
///
/// The [`Embodiment`] methods cannot return errors; when the plugin fails or panics the proxy
/// returns the safe value (zero command; robot halted where it is) and records the failure
/// (see [`PluginEmbodiment::failure`] and [`PluginHost::failures`]). After a panic every call
/// returns the safe value.
#[derive(Debug)]
pub struct PluginEmbodiment {
    handle: Handle,
    vtable: &'static H2nEmbodimentVTable,
}

impl PluginEmbodiment {
    /// The failure that made this embodiment unusable, if any.
    pub fn failure(&self) -> Option<String> {
        self.handle
            .health
            .poisoned()
            .then(|| self.handle.health.message())
    }

    /// Records a failed call. Any failure makes the embodiment unusable: one that cannot
    /// saturate, step or track is not safe to keep driving.
    fn failed(&self, status: H2nStatus) {
        let message = self.handle.failure(status);
        if status != H2N_PANIC && status != H2N_POISONED {
            self.handle.health.poison(&message);
        }
    }
}

impl Embodiment for PluginEmbodiment {
    fn name(&self) -> &str {
        &self.handle.name
    }

    fn holonomic(&self) -> bool {
        if self.handle.health.poisoned() {
            return false;
        }
        let mut out = 0u32;
        // SAFETY: live instance, valid output pointer.
        let status = unsafe { (self.vtable.holonomic)(self.handle.ptr(), &mut out) };
        if status != H2N_OK {
            self.failed(status);
            return false;
        }
        out != 0
    }

    fn saturate(&self, state: &RobotState, cmd: Twist2, dt: f64) -> Twist2 {
        if self.handle.health.poisoned() {
            return Twist2::ZERO;
        }
        let s = H2nRobotState::from(state);
        let c = H2nTwist::from(cmd);
        let mut out = H2nTwist::default();
        // SAFETY: live instance, valid pointers for the call.
        let status = unsafe { (self.vtable.saturate)(self.handle.ptr(), &s, &c, dt, &mut out) };
        if status != H2N_OK {
            self.failed(status);
            return Twist2::ZERO;
        }
        out.into()
    }

    fn step(&self, state: &RobotState, cmd: Twist2, dt: f64) -> RobotState {
        let halted = RobotState {
            pose: state.pose,
            velocity: Twist2::ZERO,
        };
        if self.handle.health.poisoned() {
            return halted;
        }
        let s = H2nRobotState::from(state);
        let c = H2nTwist::from(cmd);
        let mut out = H2nRobotState::default();
        // SAFETY: live instance, valid pointers for the call.
        let status = unsafe { (self.vtable.step)(self.handle.ptr(), &s, &c, dt, &mut out) };
        if status != H2N_OK {
            self.failed(status);
            return halted;
        }
        (&out).into()
    }

    fn track(&self, state: &RobotState, plan: &Plan, t: f64) -> Twist2 {
        if self.handle.health.poisoned() {
            return Twist2::ZERO;
        }
        let poses: Vec<H2nPose> = plan.poses.iter().map(|&p| p.into()).collect();
        let view = H2nPlanView {
            t0: plan.t0,
            dt: plan.dt,
            poses: poses.as_ptr(),
            pose_count: poses.len(),
        };
        let s = H2nRobotState::from(state);
        let mut out = H2nTwist::default();
        // SAFETY: live instance, valid pointers for the call.
        let status = unsafe { (self.vtable.track)(self.handle.ptr(), &s, &view, t, &mut out) };
        if status != H2N_OK {
            self.failed(status);
            return Twist2::ZERO;
        }
        out.into()
    }
}

/// A planner living in a plugin library.
#[derive(Debug)]
pub struct PluginPlanner {
    handle: Handle,
    vtable: &'static H2nPlannerVTable,
    /// Reused plan buffer (grows to the longest plan seen).
    poses: Vec<H2nPose>,
}

impl PluginPlanner {
    fn error(&self, status: H2nStatus) -> PlanError {
        let message = self.handle.failure(status);
        let planner = self.handle.name.clone();
        match status {
            H2N_INVALID_ARGUMENT => PlanError::InvalidObservation(message),
            H2N_PANIC => PlanError::Failed {
                planner,
                message: format!("panicked (the planner is now unusable): {message}"),
            },
            H2N_POISONED => PlanError::Unusable { planner, message },
            _ => PlanError::Failed { planner, message },
        }
    }
}

impl Planner for PluginPlanner {
    fn name(&self) -> &str {
        &self.handle.name
    }

    fn reset(&mut self) {
        if self.handle.health.poisoned() {
            return;
        }
        // SAFETY: live instance, called through `&mut self` (never concurrently).
        let status = unsafe { (self.vtable.reset)(self.handle.ptr()) };
        if status != H2N_OK {
            // The trait's reset cannot fail; the next `plan` reports the unusable planner.
            let message = self.handle.failure(status);
            self.handle.health.poison(&message);
        }
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        if self.handle.health.poisoned() {
            return Err(PlanError::Unusable {
                planner: self.handle.name.clone(),
                message: self.handle.health.message(),
            });
        }
        obs.validate()?;
        let agents = agent_views(&obs.agents);
        let abi_obs = H2nObservation {
            struct_size: std::mem::size_of::<H2nObservation>() as u32,
            reserved: 0,
            time: obs.time,
            ego: obs.ego.into(),
            ego_velocity: obs.ego_velocity.into(),
            goal: obs.goal,
            agents: agents.as_ptr(),
            agent_count: agents.len(),
        };
        if self.poses.len() < 64 {
            self.poses.resize(64, H2nPose::default());
        }
        let mut note = vec![0u8; 256];
        let mut out = self.plan_out(&mut note);
        // SAFETY: live instance (exclusive through `&mut self`); host-owned buffers of the
        // stated capacities.
        let mut status = unsafe { (self.vtable.plan)(self.handle.ptr(), &abi_obs, &mut out) };
        if status == H2N_BUFFER_TOO_SMALL && out.len > self.poses.len() {
            self.poses.resize(out.len, H2nPose::default());
            out = self.plan_out(&mut note);
            // SAFETY: as above.
            status = unsafe { (self.vtable.last_plan)(self.handle.ptr(), &mut out) };
        }
        if status != H2N_OK {
            return Err(self.error(status));
        }
        let n = out.len.min(self.poses.len());
        let notes = {
            let text = buffer_text(&note, out.note.len);
            if text.is_empty() {
                Vec::new()
            } else {
                vec![text]
            }
        };
        let plan = Plan {
            t0: out.t0,
            dt: out.dt,
            poses: self.poses[..n].iter().map(|&p| Pose2::from(p)).collect(),
            info: PlanInfo {
                fallback: out.fallback != 0,
                notes,
                ..PlanInfo::default()
            },
        };
        if !plan.is_finite() || plan.poses.is_empty() {
            return Err(PlanError::Failed {
                planner: self.handle.name.clone(),
                message: "the plugin returned an empty or non-finite plan".into(),
            });
        }
        Ok(plan)
    }
}

impl PluginPlanner {
    fn plan_out(&mut self, note: &mut [u8]) -> H2nPlanOut {
        H2nPlanOut {
            t0: 0.0,
            dt: 0.0,
            poses: self.poses.as_mut_ptr(),
            capacity: self.poses.len(),
            len: 0,
            fallback: 0,
            reserved: 0,
            note: H2nBuffer {
                data: note.as_mut_ptr(),
                capacity: note.len(),
                len: 0,
            },
        }
    }
}
