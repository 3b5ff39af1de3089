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
//! hands over is checked before use ([`crate::validate`]); planner and constraint calls run under
//! a deadline ([`crate::deadline`]).
//!
//! A plugin call that panicked (or missed its deadline) marks its instance unusable: later
//! calls fail with an error naming the original failure (constraints, planners) or return the
//! documented safe value (embodiments, whose trait methods cannot fail: zero twist, robot halted
//! in place). The [`PluginHost`] that created an instance lists such failures in
//! [`PluginHost::failures`].

use crate::abi::*;
use crate::deadline::{self, NoAnswer, Worker};
use crate::error::{PluginError, PluginKind};
use crate::init::RobotContext;
use crate::libfile::{self, MAX_LIBRARY_BYTES};
use crate::process::{self as proc_host, ProcessClient};
use crate::resolve::resolve_library_path;
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

/// One factory a library provides.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FactoryInfo {
    /// What the factory creates: a constraint term, an embodiment or a planner.
    pub kind: PluginKind,
    /// The name robot profiles and benchmark configs refer to (`plugin = "..."`).
    pub name: String,
    /// The factory's one-line description, for `human2nav plugin inspect`.
    pub description: String,
}

/// A loaded, validated plugin library.
pub struct PluginLibrary {
    path: PathBuf,
    abi_version: u32,
    name: String,
    version: String,
    factories: Vec<FactoryInfo>,
    /// `create` of each factory, in the order of `factories` (checked non-null).
    creates: Vec<CreateFn>,
    /// What was checked when the library was loaded, in order.
    checks: Vec<Check>,
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

/// Records a failed check and returns its error.
fn failed(checks: &mut Vec<Check>, item: &str, e: PluginError) -> PluginError {
    checks.push(Check::fail(item, e.to_string()));
    e
}

/// `Ok` when a table's declared size is between what this ABI needs and [`MAX_TABLE_BYTES`].
fn table_size(path: &Path, table: &str, size: u32, min: usize) -> Result<(), PluginError> {
    let s = size as usize;
    if s < min || s > MAX_TABLE_BYTES {
        return Err(PluginError::TableSize {
            path: path.to_path_buf(),
            table: table.to_owned(),
            size,
            min,
            max: MAX_TABLE_BYTES,
        });
    }
    Ok(())
}

impl PluginLibrary {
    /// Loads (or returns the already loaded) library at `path`, resolved as described in
    /// [`crate::resolve`]. Checks the file before the OS loader maps it and the ABI version
    /// before reading anything else of the entry table, then every table it hands over.
    pub fn load(path: &Path) -> Result<Arc<PluginLibrary>, PluginError> {
        Self::load_checked(path).0
    }

    /// [`PluginLibrary::load`], also returning what was checked (up to and including a failed
    /// check). A library loaded before returns the checks of its first load.
    pub fn load_checked(path: &Path) -> (Result<Arc<PluginLibrary>, PluginError>, Vec<Check>) {
        let mut checks = Vec::new();
        let file = match resolve_library_path(path) {
            Ok(f) => f,
            Err(e) => return (Err(failed(&mut checks, "library path", e.clone())), checks),
        };
        let canonical = std::fs::canonicalize(&file).unwrap_or(file);
        let mut libs = registry().lock().unwrap_or_else(|e| e.into_inner());
        if let Some(lib) = libs.get(&canonical) {
            return (Ok(Arc::clone(lib)), lib.checks.clone());
        }
        checks.push(Check::pass(
            "library path",
            format!("{} resolves to {}", path.display(), canonical.display()),
        ));
        match Self::open(&canonical, &mut checks) {
            Ok(mut lib) => {
                lib.checks = checks.clone();
                let lib = Arc::new(lib);
                libs.insert(canonical, Arc::clone(&lib));
                (Ok(lib), checks)
            }
            Err(e) => (Err(e), checks),
        }
    }

    fn open(path: &Path, checks: &mut Vec<Check>) -> Result<PluginLibrary, PluginError> {
        match libfile::check_library_file(path) {
            Ok(f) => checks.push(Check::pass(
                "file",
                format!(
                    "regular file of {} bytes (limit {MAX_LIBRARY_BYTES}); {}",
                    f.size, f.format
                ),
            )),
            Err(problem) => {
                let e = PluginError::Open {
                    path: path.to_path_buf(),
                    message: format!("{problem} (refused before loading)"),
                };
                return Err(failed(checks, "file", e));
            }
        }
        // SAFETY: loading a library runs its initialisers. The user named this library
        // explicitly as a plugin; running its code is the purpose of loading it. The file
        // passed the checks above, so the loader maps no page past its end.
        let lib = unsafe { libloading::Library::new(path) }.map_err(|e| {
            let e = PluginError::Open {
                path: path.to_path_buf(),
                message: one_line(&e.to_string()),
            };
            failed(checks, "loader", e)
        })?;
        // Never unloaded: every pointer the plugin hands out stays valid for the process.
        let lib: &'static libloading::Library = Box::leak(Box::new(lib));
        // SAFETY: the symbol, if present, has the `EntryFn` signature by the ABI contract.
        let entry_fn = unsafe { lib.get::<EntryFn>(ENTRY_SYMBOL.as_bytes()) }.map_err(|_| {
            let e = PluginError::MissingEntry {
                path: path.to_path_buf(),
                symbol: ENTRY_SYMBOL,
            };
            failed(checks, "entry symbol", e)
        })?;
        // SAFETY: calling the entry function of a plugin is the ABI's first step; it takes no
        // arguments and returns a pointer to static data.
        let raw = unsafe { entry_fn() };
        checks.push(Check::pass(
            "entry symbol",
            format!("`{ENTRY_SYMBOL}` exported and called"),
        ));
        // SAFETY: `raw` is what the library's entry function returned; the library is never
        // unloaded.
        unsafe { Self::from_entry(path, raw, checks) }
    }

    /// Validates an entry table and everything it points to (see [`crate::validate`]).
    ///
    /// # Safety
    /// `raw` is null or points to readable static memory that starts with the ABI version; when
    /// the version matches, to a v1 entry table whose `struct_size` first bytes are readable,
    /// whose strings are readable for their (capped) lengths and whose factory array holds
    /// `factory_count` (capped) factories of the declared stride, all for the life of the
    /// process.
    pub(crate) unsafe fn from_entry(
        path: &Path,
        raw: *const H2nPluginEntry,
        checks: &mut Vec<Check>,
    ) -> Result<PluginLibrary, PluginError> {
        // SAFETY: the caller's contract on `raw`.
        let (entry, found) = unsafe { Self::entry_table(path, raw, checks) }?;
        // SAFETY: `entry` is a checked v1 table; its strings are readable for their length.
        let (name, version) = unsafe { Self::entry_strings(path, entry, checks) }?;
        // SAFETY: the caller's contract on the factory array.
        let (factories, creates) = unsafe { Self::factory_array(path, entry, checks) }?;
        Ok(PluginLibrary {
            path: path.to_path_buf(),
            abi_version: found,
            name,
            version,
            factories,
            creates,
            checks: Vec::new(),
        })
    }

    /// The entry table behind `raw` once its pointer, ABI version and size are checked, and
    /// the ABI version found.
    ///
    /// # Safety
    /// As [`Self::from_entry`].
    unsafe fn entry_table(
        path: &Path,
        raw: *const H2nPluginEntry,
        checks: &mut Vec<Check>,
    ) -> Result<(&'static H2nPluginEntry, u32), PluginError> {
        if raw.is_null() || !raw.is_aligned() {
            let e = PluginError::Malformed {
                path: path.to_path_buf(),
                message: "the entry function returned a null or misaligned table".into(),
            };
            return Err(failed(checks, "entry table", e));
        }
        // SAFETY: every ABI version starts the entry table with a `u32` ABI version, so this
        // read is valid whatever version the plugin speaks. Nothing else is read before the
        // version is known to match.
        let found = unsafe { raw.cast::<u32>().read() };
        if !(MIN_ABI_VERSION..=ABI_VERSION).contains(&found) {
            let e = PluginError::AbiMismatch {
                path: path.to_path_buf(),
                found,
                expected: ABI_VERSION,
            };
            return Err(failed(checks, "ABI version", e));
        }
        checks.push(Check::pass("ABI version", abi_version_text(found)));
        // SAFETY: a v1 entry table starts with two `u32`s (version, size).
        let size = unsafe { raw.cast::<u32>().add(1).read() };
        let min = std::mem::size_of::<H2nPluginEntry>();
        table_size(path, "entry table", size, min).map_err(|e| failed(checks, "entry table", e))?;
        // SAFETY: the version matches and the table is at least as large as a v1 table, so
        // `raw` points to a v1 entry table in static memory; every function slot is an
        // `Option`, valid for any pointer value, null included.
        Ok((unsafe { &*raw }, found))
    }

    /// The plugin's name (not empty) and version from a checked entry table.
    ///
    /// # Safety
    /// The table's strings are readable for their (capped) lengths.
    unsafe fn entry_strings(
        path: &Path,
        entry: &H2nPluginEntry,
        checks: &mut Vec<Check>,
    ) -> Result<(String, String), PluginError> {
        let malformed = |message: String| PluginError::Malformed {
            path: path.to_path_buf(),
            message,
        };
        // SAFETY: strings of the table, readable for their length (capped by `plugin_str`).
        let name = unsafe { plugin_str(entry.name, MAX_NAME_BYTES) }
            .map_err(|m| malformed(format!("the plugin name {m}")))
            .and_then(|n| {
                if n.is_empty() {
                    Err(malformed("the plugin name is empty".into()))
                } else {
                    Ok(n.to_owned())
                }
            })
            .map_err(|e| failed(checks, "entry table", e))?;
        // SAFETY: as above.
        let version = unsafe { plugin_str(entry.version, MAX_NAME_BYTES) }
            .map(str::to_owned)
            .map_err(|m| failed(checks, "entry table", malformed(format!("the version {m}"))))?;
        checks.push(Check::pass(
            "entry table",
            format!(
                "{} bytes (this ABI needs {}, limit {MAX_TABLE_BYTES}); name and version \
                 UTF-8 within {MAX_NAME_BYTES} bytes; find_factory {} (optional, not called: \
                 factories are looked up in the checked array)",
                entry.struct_size,
                std::mem::size_of::<H2nPluginEntry>(),
                if entry.find_factory.is_some() {
                    "set"
                } else {
                    "null"
                }
            ),
        ));
        Ok((name, version))
    }

    /// Every factory of a checked entry table: its count (capped), the array's pointer and
    /// stride, then each factory ([`Self::factory`]).
    ///
    /// # Safety
    /// The factory array holds `factory_count` (capped) factories of the declared stride, in
    /// static memory.
    unsafe fn factory_array(
        path: &Path,
        entry: &H2nPluginEntry,
        checks: &mut Vec<Check>,
    ) -> Result<(Vec<FactoryInfo>, Vec<CreateFn>), PluginError> {
        let count = entry.factory_count;
        if count > MAX_FACTORIES {
            let e = PluginError::Cap {
                path: path.to_path_buf(),
                what: "the factory count".into(),
                value: count as u64,
                cap: MAX_FACTORIES as u64,
            };
            return Err(failed(checks, "factory table", e));
        }
        let mut factories = Vec::with_capacity(count);
        let mut creates = Vec::with_capacity(count);
        if count == 0 {
            checks.push(Check::pass("factory table", "no factories"));
            return Ok((factories, creates));
        }
        let malformed = |message: String| PluginError::Malformed {
            path: path.to_path_buf(),
            message,
        };
        if entry.factories.is_null() || !entry.factories.is_aligned() {
            let e = malformed("the factory table is null or misaligned".into());
            return Err(failed(checks, "factory table", e));
        }
        // SAFETY: non-null and aligned; every factory starts with its `u32` size.
        let stride = unsafe { entry.factories.cast::<u32>().read() };
        let fmin = std::mem::size_of::<H2nFactory>();
        table_size(path, "factory table entry 0", stride, fmin)
            .map_err(|e| failed(checks, "factory table", e))?;
        let stride = stride as usize;
        if stride % std::mem::align_of::<H2nFactory>() != 0 {
            let e = malformed(format!(
                "factories are {stride} bytes apart, not a multiple of their alignment {}",
                std::mem::align_of::<H2nFactory>()
            ));
            return Err(failed(checks, "factory table", e));
        }
        checks.push(Check::pass(
            "factory table",
            format!(
                "{count} factories (limit {MAX_FACTORIES}), {stride} bytes apart (this ABI \
                 needs {fmin})"
            ),
        ));
        for i in 0..count {
            // SAFETY: within the `count · stride` bytes of the factory array (both capped);
            // the stride is a multiple of the alignment, so each factory is aligned.
            let fp = unsafe {
                entry
                    .factories
                    .cast::<u8>()
                    .add(i * stride)
                    .cast::<H2nFactory>()
            };
            // SAFETY: as above.
            let (info, create) = unsafe { Self::factory(path, fp, i, stride, &factories, checks) }?;
            factories.push(info);
            creates.push(create);
        }
        Ok((factories, creates))
    }

    /// Factory `i` of the array: its size (the array's stride), name (not empty, not a repeat
    /// of an earlier factory's of the same kind), description and `create` slot (required).
    ///
    /// # Safety
    /// `fp` is aligned and points to `stride` readable bytes of static memory whose strings are
    /// readable for their (capped) lengths.
    unsafe fn factory(
        path: &Path,
        fp: *const H2nFactory,
        i: usize,
        stride: usize,
        earlier: &[FactoryInfo],
        checks: &mut Vec<Check>,
    ) -> Result<(FactoryInfo, CreateFn), PluginError> {
        let malformed = |message: String| PluginError::Malformed {
            path: path.to_path_buf(),
            message,
        };
        let item = format!("factory {i}");
        // SAFETY: the caller's contract; a factory starts with its `u32` size.
        let fsize = unsafe { fp.cast::<u32>().read() };
        if fsize as usize != stride {
            let e = malformed(format!(
                "factory {i} is {fsize} bytes, factory 0 is {stride} (the entries of \
                 one array have one size)"
            ));
            return Err(failed(checks, &item, e));
        }
        // SAFETY: aligned, at least a v1 factory, static; slots are `Option`s.
        let f: &'static H2nFactory = unsafe { &*fp };
        let kind = PluginKind::from_code(f.kind);
        // SAFETY: strings of the factory, readable for their (capped) length.
        let fname = unsafe { plugin_str(f.name, MAX_NAME_BYTES) }
            .map_err(|m| malformed(format!("factory {i}: the name {m}")))
            .and_then(|n| {
                if n.is_empty() {
                    Err(malformed(format!("factory {i}: the name is empty")))
                } else {
                    Ok(n.to_owned())
                }
            })
            .map_err(|e| failed(checks, &item, e))?;
        let item = format!("factory {i} ({kind} `{fname}`)");
        // SAFETY: as above.
        let description = unsafe { plugin_str(f.description, MAX_DESCRIPTION_BYTES) }
            .map(str::to_owned)
            .map_err(|m| {
                let e = malformed(format!("factory {i}: the description {m}"));
                failed(checks, &item, e)
            })?;
        let Some(create) = f.create else {
            let e = PluginError::NullSlot {
                path: path.to_path_buf(),
                table: format!("factory table entry {i} ({kind} `{fname}`)"),
                slot: "create",
            };
            return Err(failed(checks, &item, e));
        };
        if earlier.iter().any(|o| o.kind == kind && o.name == fname) {
            let e = malformed(format!("factory {i} repeats {kind} `{fname}`"));
            return Err(failed(checks, &item, e));
        }
        checks.push(Check::pass(
            item,
            format!(
                "create set; name and description UTF-8 within {MAX_NAME_BYTES} and \
                 {MAX_DESCRIPTION_BYTES} bytes"
            ),
        ));
        let info = FactoryInfo {
            kind,
            name: fname,
            description,
        };
        Ok((info, create))
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

    /// The ABI version the library speaks (between [`MIN_ABI_VERSION`] and [`ABI_VERSION`]
    /// once loaded).
    pub fn abi_version(&self) -> u32 {
        self.abi_version
    }

    /// What the library provides.
    pub fn factories(&self) -> &[FactoryInfo] {
        &self.factories
    }

    /// What was checked when the library was loaded.
    pub fn checks(&self) -> &[Check] {
        &self.checks
    }

    /// Creates an instance through the factory `kind`/`name` (looked up in the checked table).
    pub(crate) fn create(
        &self,
        kind: PluginKind,
        name: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<H2nObject, PluginError> {
        let Some(index) = self
            .factories
            .iter()
            .position(|f| f.kind == kind && f.name == name)
        else {
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
        };
        let create = self.creates[index];
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
        // SAFETY: `create` is the factory's checked, non-null function; every pointer is valid
        // for the duration of the call and the buffers are host-owned with the stated
        // capacities.
        let status = unsafe { create(&args, &mut out, &mut error) };
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
        if out.instance.is_null() {
            return Err(PluginError::Malformed {
                path: self.path.clone(),
                message: format!("factory `{name}` reported success but returned a null instance"),
            });
        }
        Ok(out)
    }
}

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

/// A vtable kind: its slots, for validation.
pub(crate) trait VTable: Sized + 'static {
    const KIND: PluginKind;
    /// The size of the table's first version: the smallest `struct_size` accepted. Slots
    /// appended since are absent (null) from a table that ends before them.
    const MIN_SIZE: usize = std::mem::size_of::<Self>();
    /// `(slot, set, required)` of the slots after the common three, in table order.
    fn own_slots(&self) -> Vec<(&'static str, bool, bool)>;
    fn destroy_fn(&self) -> Option<DestroyFn>;
    fn last_error_fn(&self) -> Option<LastErrorFn>;
    fn name_fn(&self) -> Option<NameFn>;

    /// What a probe of a fresh instance reports beyond the table (`plugin inspect`); an error
    /// makes the probe fail. Default: nothing.
    ///
    /// # Safety
    /// `instance` is a live instance of this table.
    unsafe fn probe_instance(&self, _instance: *mut c_void) -> Result<String, String> {
        Ok(String::new())
    }

    /// `(slot, set, required)` in table order: `destroy` (required), `last_error` and `name`
    /// (optional), then the kind's own.
    fn slots(&self) -> Vec<(&'static str, bool, bool)> {
        let mut slots = vec![
            ("destroy", self.destroy_fn().is_some(), true),
            ("last_error", self.last_error_fn().is_some(), false),
            ("name", self.name_fn().is_some(), false),
        ];
        slots.extend(self.own_slots());
        slots
    }
}

/// The slots every vtable kind starts with (`destroy`, `last_error`, `name`), read the same
/// way for each.
macro_rules! common_slots {
    () => {
        fn destroy_fn(&self) -> Option<DestroyFn> {
            self.destroy
        }
        fn last_error_fn(&self) -> Option<LastErrorFn> {
            self.last_error
        }
        fn name_fn(&self) -> Option<NameFn> {
            self.name
        }
    };
}

impl VTable for H2nConstraintVTable {
    const KIND: PluginKind = PluginKind::Constraint;
    fn own_slots(&self) -> Vec<(&'static str, bool, bool)> {
        vec![("evaluate", self.evaluate.is_some(), true)]
    }
    common_slots!();
}

impl VTable for H2nEmbodimentVTable {
    const KIND: PluginKind = PluginKind::Embodiment;
    const MIN_SIZE: usize = std::mem::offset_of!(H2nEmbodimentVTable, coupled_limit);
    fn own_slots(&self) -> Vec<(&'static str, bool, bool)> {
        vec![
            ("holonomic", self.holonomic.is_some(), true),
            ("saturate", self.saturate.is_some(), true),
            ("step", self.step.is_some(), true),
            ("track", self.track.is_some(), true),
            ("coupled_limit", self.coupled_limit.is_some(), false),
        ]
    }
    unsafe fn probe_instance(&self, instance: *mut c_void) -> Result<String, String> {
        let Some(f) = self.coupled_limit else {
            return Ok(String::new());
        };
        // SAFETY: a live instance of this table (the caller's contract).
        match unsafe { call_coupled_limit(f, instance) } {
            Ok(Some(c)) => Ok(format!(
                "; coupled limit {:.4}·|v_x| + {:.4}·|v_y| + {:.4}·|ω| ≤ {:.4}",
                c.v, c.lateral, c.omega, c.max
            )),
            Ok(None) => Ok("; no coupled limit".to_owned()),
            Err(Ok(message)) => Err(message),
            Err(Err(status)) => Err(format!("coupled_limit returned {}", status_name(status))),
        }
    }
    common_slots!();
}

impl VTable for H2nPlannerVTable {
    const KIND: PluginKind = PluginKind::Planner;
    fn own_slots(&self) -> Vec<(&'static str, bool, bool)> {
        vec![
            ("reset", self.reset.is_some(), false),
            ("plan", self.plan.is_some(), true),
            ("last_plan", self.last_plan.is_some(), true),
        ]
    }
    common_slots!();
}

/// Checks the vtable an instance of factory `factory` came with (see [`crate::validate`]) and
/// returns a copy of it with a description of what was checked: the table's declared bytes,
/// and null slots for those appended after its version. On failure nothing of the table is
/// called (the instance is leaked: destroying it would call into the broken table).
///
/// # Safety
/// `ptr` is null or points to readable memory of the library, starting with a `u32` size, and
/// at least that many bytes when the size is accepted.
pub(crate) unsafe fn checked_vtable<T: VTable>(
    lib: &PluginLibrary,
    factory: &str,
    ptr: *const c_void,
) -> Result<(T, String), PluginError> {
    let table = format!("{} vtable of `{factory}`", T::KIND);
    if ptr.is_null() || !ptr.cast::<T>().is_aligned() {
        return Err(PluginError::Malformed {
            path: lib.path.clone(),
            message: format!("the {table} is null or misaligned"),
        });
    }
    // SAFETY: non-null and aligned; every vtable starts with its `u32` size.
    let size = unsafe { ptr.cast::<u32>().read() };
    let min = T::MIN_SIZE;
    table_size(&lib.path, &table, size, min)?;
    // SAFETY: aligned (checked), a table of this kind (the factory's) of `size >= MIN_SIZE`
    // readable bytes.
    let vt = unsafe { read_table::<T>(ptr, size as usize) };
    let slots = vt.slots();
    if let Some((slot, _, _)) = slots.iter().find(|(_, set, required)| *required && !*set) {
        return Err(PluginError::NullSlot {
            path: lib.path.clone(),
            table,
            slot,
        });
    }
    let list = |required: bool, set: bool| {
        slots
            .iter()
            .filter(|s| s.2 == required && s.1 == set)
            .map(|s| s.0)
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (opt_set, opt_null) = (list(false, true), list(false, false));
    Ok((
        vt,
        format!(
            "{size} bytes (this ABI needs {min}, limit {MAX_TABLE_BYTES}); required {} set; \
             optional: {}{}",
            list(true, true),
            if opt_set.is_empty() {
                "none set".to_owned()
            } else {
                format!("{opt_set} set")
            },
            if opt_null.is_empty() {
                String::new()
            } else {
                format!(", {opt_null} null")
            }
        ),
    ))
}

/// A copy of the first `size` bytes of a table of kind `T` (at most the whole `T`), the rest
/// zero: slots the plugin's version of the table does not have read as null.
///
/// # Safety
/// `ptr` is aligned for `T` and points to at least `min(size, size_of::<T>())` readable bytes
/// of a table of this kind, whose size is at least `T::MIN_SIZE`.
unsafe fn read_table<T: VTable>(ptr: *const c_void, size: usize) -> T {
    let mut out = std::mem::MaybeUninit::<T>::zeroed();
    let n = size.min(std::mem::size_of::<T>());
    // SAFETY: `n` bytes are readable at `ptr` and fit in `out`; the two do not overlap.
    unsafe { std::ptr::copy_nonoverlapping(ptr.cast::<u8>(), out.as_mut_ptr().cast::<u8>(), n) };
    // SAFETY: every field of a vtable is an integer or an `Option` of a function pointer, for
    // which both the plugin's bytes and zero (`None`) are valid values.
    unsafe { out.assume_init() }
}

/// The name an instance reports through its (optional) `name` slot, else `fallback`.
///
/// # Safety
/// `instance` is a live instance of a vtable whose `name` slot is `name`.
unsafe fn instance_name(
    name: Option<NameFn>,
    instance: *mut c_void,
    fallback: &str,
) -> Result<String, String> {
    let Some(name) = name else {
        return Ok(fallback.to_owned());
    };
    // SAFETY: live instance; the returned view lives as long as the instance (capped, copied
    // immediately).
    let s = unsafe { name(instance) };
    // SAFETY: as above.
    match unsafe { plugin_str(s, MAX_NAME_BYTES) } {
        Ok("") => Ok(fallback.to_owned()),
        Ok(n) => Ok(n.to_owned()),
        Err(m) => Err(format!("the instance name {m}")),
    }
}

/// Creates an instance with an empty configuration and no robot, checks its vtable and its
/// name and destroys it (for `plugin inspect`). `Ok(Ok(what was checked))`, or `Ok(Err(why))`
/// when the factory declined (it needs a config or a robot; its vtable is then checked when a
/// profile creates an instance); `Err` when the instance or its vtable is malformed.
pub(crate) fn probe_factory(
    lib: &PluginLibrary,
    info: &FactoryInfo,
) -> Result<Result<String, String>, PluginError> {
    fn probe<T: VTable>(
        lib: &PluginLibrary,
        info: &FactoryInfo,
    ) -> Result<Result<String, String>, PluginError> {
        let obj = match lib.create(T::KIND, &info.name, "", None) {
            Ok(obj) => obj,
            Err(e @ PluginError::Malformed { .. }) => return Err(e),
            Err(e) => return Ok(Err(e.to_string())),
        };
        // SAFETY: the factory of this kind returned this vtable; a library is never unloaded.
        let (vt, detail) = unsafe { checked_vtable::<T>(lib, &info.name, obj.vtable) }?;
        // SAFETY: a live instance of this vtable.
        let name = unsafe { instance_name(vt.name_fn(), obj.instance, &info.name) };
        // SAFETY: as above.
        let extra = unsafe { vt.probe_instance(obj.instance) };
        if let Some(destroy) = vt.destroy_fn() {
            // SAFETY: the instance is live and destroyed exactly once, here.
            unsafe { destroy(obj.instance) };
        }
        match name.and_then(|n| extra.map(|e| (n, e))) {
            Ok((n, e)) => Ok(Ok(format!("{detail}; instance name `{n}`{e}"))),
            Err(m) => Err(PluginError::Malformed {
                path: lib.path.clone(),
                message: format!("{} `{}`: {m}", T::KIND, info.name),
            }),
        }
    }
    match info.kind {
        PluginKind::Constraint => probe::<H2nConstraintVTable>(lib, info),
        PluginKind::Embodiment => probe::<H2nEmbodimentVTable>(lib, info),
        PluginKind::Planner => probe::<H2nPlannerVTable>(lib, info),
        PluginKind::Unknown(c) => Ok(Err(format!(
            "kind {c} is unknown to this host; not created"
        ))),
    }
}

/// Health of one plugin instance, shared by its proxy and the host that created it.
#[derive(Debug)]
struct Health {
    kind: PluginKind,
    label: String,
    poisoned: AtomicBool,
    message: Mutex<Option<String>>,
}

impl Health {
    fn new(kind: PluginKind, label: String) -> Arc<Self> {
        Arc::new(Self {
            kind,
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

    /// Marks the instance dead after a missed deadline, logs it and returns the message.
    fn timed_out(&self, call: &str, deadline: Duration) -> String {
        let message = format!(
            "{} did not return from `{call}` within its deadline of {}; the instance is marked \
             dead and every later call fails at once",
            self.label,
            deadline::describe(deadline)
        );
        self.poison(&message);
        eprintln!("warning: {message}");
        message
    }

    /// Marks the instance dead after its worker thread ended (a bug in the host's code).
    fn worker_gone(&self) -> String {
        let message = format!("{}: its worker thread ended unexpectedly", self.label);
        self.poison(&message);
        message
    }
}

/// A plugin instance that became unusable.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PluginFailure {
    /// What the instance was.
    pub kind: PluginKind,
    /// `<kind> <name> from <library>`.
    pub instance: String,
    /// The panic, last error or missed deadline that made it unusable.
    pub message: String,
}

/// The instance part shared by the three proxies: it destroys the instance when dropped.
struct Handle {
    instance: NonNull<c_void>,
    destroy: DestroyFn,
    last_error: Option<LastErrorFn>,
    health: Arc<Health>,
    library: Arc<PluginLibrary>,
}

// SAFETY: the ABI requires constraint and embodiment instances to accept concurrent calls from
// any thread; a planner's handle is only used through `&mut` (or by its one worker thread), so
// never concurrently.
unsafe impl Send for Handle {}
// SAFETY: as above.
unsafe impl Sync for Handle {}

impl Handle {
    fn ptr(&self) -> *mut c_void {
        self.instance.as_ptr()
    }

    /// The instance's last error message (empty without a `last_error` slot).
    fn last_error(&self) -> String {
        let Some(last_error) = self.last_error else {
            return String::new();
        };
        let mut buf = vec![0u8; 512];
        for _ in 0..2 {
            let mut out = H2nBuffer {
                data: buf.as_mut_ptr(),
                capacity: buf.len(),
                len: 0,
            };
            // SAFETY: live instance; host-owned buffer of the stated capacity.
            unsafe { last_error(self.ptr(), &mut out) };
            if out.len <= buf.len() {
                return buffer_text(&buf, out.len);
            }
            buf.resize(out.len.min(MAX_MESSAGE_BYTES), 0);
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
        // SAFETY: the instance is live, no call on it is in progress (the handle is dropped
        // by its only user), and this is the only place it is destroyed.
        unsafe { (self.destroy)(self.ptr()) };
    }
}

impl fmt::Debug for Handle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Handle")
            .field("health", &self.health)
            .finish()
    }
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

    /// Creates a constraint term from `library` (path resolved per [`crate::resolve`]), whose
    /// calls run under [`deadline::DEFAULT_DEADLINE`].
    pub fn constraint(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<PluginConstraint, PluginError> {
        self.constraint_with_deadline(
            library,
            plugin,
            config,
            robot,
            Some(deadline::DEFAULT_DEADLINE),
        )
    }

    /// [`PluginHost::constraint`] with a deadline per `evaluate` call (`None`: none, calls run
    /// on the caller's thread; see [`crate::deadline`]).
    pub fn constraint_with_deadline(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
    ) -> Result<PluginConstraint, PluginError> {
        self.constraint_with_options(
            library,
            plugin,
            config,
            robot,
            deadline,
            PluginIsolation::InProcess,
        )
    }

    /// [`PluginHost::constraint_with_deadline`], in the host process or in a helper process of
    /// its own ([`PluginIsolation::Process`], see [`crate::process`]).
    pub fn constraint_with_options(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
        isolation: PluginIsolation,
    ) -> Result<PluginConstraint, PluginError> {
        if isolation == PluginIsolation::Process {
            let (client, name, health) = self.process_instance(
                PluginKind::Constraint,
                library,
                plugin,
                config,
                robot,
                deadline,
            )?;
            return Ok(PluginConstraint {
                name,
                health,
                deadline,
                exec: ConstraintExec::Process(Mutex::new(client)),
            });
        }
        let c = self.instance::<H2nConstraintVTable>(library, plugin, config, robot)?;
        let evaluate = c.vtable.evaluate.ok_or_else(|| PluginError::NullSlot {
            path: library.to_path_buf(),
            table: format!("constraint vtable of `{plugin}`"),
            slot: "evaluate",
        })?;
        let health = Arc::clone(&c.handle.health);
        let core = ConstraintCore {
            handle: c.handle,
            evaluate,
        };
        let exec = match deadline {
            None => ConstraintExec::Direct(core),
            Some(_) => {
                let worker =
                    Worker::spawn(thread_name(&c.name), move |job: &mut Box<ConstraintJob>| {
                        core.run(job)
                    })
                    .map_err(|e| worker_error(&c.label, e))?;
                ConstraintExec::Worker(Mutex::new(Slot {
                    worker: Some(worker),
                    spare: None,
                }))
            }
        };
        Ok(PluginConstraint {
            name: c.name,
            health,
            deadline,
            exec,
        })
    }

    /// Creates an embodiment for a robot with these limits and gains. Embodiment calls have no
    /// deadline (see [`crate::deadline`]).
    pub fn embodiment(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: &RobotContext,
    ) -> Result<PluginEmbodiment, PluginError> {
        let c = self.instance::<H2nEmbodimentVTable>(library, plugin, config, Some(robot))?;
        let null = |slot: &'static str| PluginError::NullSlot {
            path: library.to_path_buf(),
            table: format!("embodiment vtable of `{plugin}`"),
            slot,
        };
        let fns = EmbodimentFns {
            holonomic: c.vtable.holonomic.ok_or_else(|| null("holonomic"))?,
            saturate: c.vtable.saturate.ok_or_else(|| null("saturate"))?,
            step: c.vtable.step.ok_or_else(|| null("step"))?,
            track: c.vtable.track.ok_or_else(|| null("track"))?,
        };
        let coupled = match c.vtable.coupled_limit {
            // SAFETY: a live instance of this vtable.
            Some(f) => unsafe { call_coupled_limit(f, c.handle.ptr()) }.map_err(|e| {
                let message = e.unwrap_or_else(|status| {
                    format!("coupled_limit: {}", c.handle.failure(status))
                });
                PluginError::Malformed {
                    path: library.to_path_buf(),
                    message: format!("embodiment `{plugin}`: {message}"),
                }
            })?,
            None => None,
        };
        Ok(PluginEmbodiment {
            handle: c.handle,
            name: c.name,
            fns,
            coupled,
        })
    }

    /// Creates a planner, optionally for a given robot, whose calls run under
    /// [`deadline::DEFAULT_DEADLINE`].
    pub fn planner(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<PluginPlanner, PluginError> {
        self.planner_with_deadline(
            library,
            plugin,
            config,
            robot,
            Some(deadline::DEFAULT_DEADLINE),
        )
    }

    /// [`PluginHost::planner`] with a deadline per `plan`/`reset` call (`None`: none, calls run
    /// on the caller's thread; see [`crate::deadline`]).
    pub fn planner_with_deadline(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
    ) -> Result<PluginPlanner, PluginError> {
        self.planner_with_options(
            library,
            plugin,
            config,
            robot,
            deadline,
            PluginIsolation::InProcess,
        )
    }

    /// [`PluginHost::planner_with_deadline`], in the host process or in a helper process of its
    /// own ([`PluginIsolation::Process`], see [`crate::process`]).
    pub fn planner_with_options(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
        isolation: PluginIsolation,
    ) -> Result<PluginPlanner, PluginError> {
        if isolation == PluginIsolation::Process {
            let (client, name, health) = self.process_instance(
                PluginKind::Planner,
                library,
                plugin,
                config,
                robot,
                deadline,
            )?;
            return Ok(PluginPlanner {
                name,
                health,
                deadline,
                exec: PlannerExec::Process(client),
                spare: None,
                horizon: human2nav_core::trajectory::DEFAULT_HORIZON,
            });
        }
        let c = self.instance::<H2nPlannerVTable>(library, plugin, config, robot)?;
        let null = |slot: &'static str| PluginError::NullSlot {
            path: library.to_path_buf(),
            table: format!("planner vtable of `{plugin}`"),
            slot,
        };
        let mut core = PlannerCore {
            abi_version: c.handle.library.abi_version,
            reset: c.vtable.reset,
            plan: c.vtable.plan.ok_or_else(|| null("plan"))?,
            last_plan: c.vtable.last_plan.ok_or_else(|| null("last_plan"))?,
            handle: c.handle,
        };
        let health = Arc::clone(&core.handle.health);
        let exec = match deadline {
            None => PlannerExec::Direct(core),
            Some(_) => PlannerExec::Worker(Some(
                Worker::spawn(thread_name(&c.name), move |job: &mut Box<PlanJob>| {
                    core.run(job)
                })
                .map_err(|e| worker_error(&c.label, e))?,
            )),
        };
        Ok(PluginPlanner {
            name: c.name,
            health,
            deadline,
            exec,
            spare: None,
            horizon: human2nav_core::trajectory::DEFAULT_HORIZON,
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

/// Copies an observation's obstacles and occupancy grid into a job's ABI records (vertex and
/// cell pointers left null; [`PlannerCore::plan`] links them on the thread that calls).
fn load_obstacles(obs: &Observation, job: &mut PlanJob) {
    job.obstacles.clear();
    job.vertices.clear();
    for o in &obs.obstacles {
        let mut r = H2nObstacle {
            kind: H2N_OBSTACLE_CIRCLE,
            reserved: 0,
            x0: 0.0,
            y0: 0.0,
            x1: 0.0,
            y1: 0.0,
            radius: 0.0,
            vertices: std::ptr::null(),
            vertex_count: 0,
        };
        match o {
            Obstacle::Circle { center, radius } => {
                [r.x0, r.y0] = *center;
                r.radius = *radius;
            }
            Obstacle::Segment { a, b } => {
                r.kind = H2N_OBSTACLE_SEGMENT;
                [r.x0, r.y0] = *a;
                [r.x1, r.y1] = *b;
            }
            Obstacle::Polygon { vertices } => {
                r.kind = H2N_OBSTACLE_POLYGON;
                r.vertex_count = vertices.len();
                job.vertices.extend(vertices.iter().flatten());
            }
        }
        job.obstacles.push(r);
    }
    job.cells.clear();
    job.occupancy = obs.occupancy.as_ref().map(|g| {
        job.cells.extend_from_slice(&g.data);
        H2nOccupancyGrid {
            origin: g.origin.into(),
            resolution: g.resolution,
            width: g.width,
            height: g.height,
            data: std::ptr::null(),
            occupied_threshold: i32::from(g.occupied_threshold),
            reserved: 0,
        }
    });
}

/// Points each polygon's `vertices` into `vertices` (filled by [`load_obstacles`]).
fn link_vertices(obstacles: &mut [H2nObstacle], vertices: &[f64]) {
    let mut at = 0;
    for o in obstacles
        .iter_mut()
        .filter(|o| o.kind == H2N_OBSTACLE_POLYGON)
    {
        let n = 2 * o.vertex_count;
        o.vertices = vertices
            .get(at..at + n)
            .map_or(std::ptr::null(), <[f64]>::as_ptr);
        at += n;
    }
}

/// The note on a version-1 plugin's plan when the observation had what it cannot see.
fn unseen_by_v1(obstacles: usize, grid: bool) -> Option<String> {
    let what = match (obstacles, grid) {
        (0, false) => return None,
        (0, true) => "the occupancy grid".to_string(),
        (n, false) => format!("{n} static obstacle(s)"),
        (n, true) => format!("{n} static obstacle(s) and the occupancy grid"),
    };
    Some(format!(
        "plugin ABI version 1: {what} not passed to the planner (version 2 carries them)"
    ))
}

/// How the checks and `plugin inspect` describe a library's ABI version.
pub(crate) fn abi_version_text(found: u32) -> String {
    if found < 2 {
        format!(
            "{found} (this host: {ABI_VERSION}; a version-{found} planner is given pedestrians, not \
             static obstacles or the occupancy grid)"
        )
    } else {
        format!("{found} (this host: {ABI_VERSION})")
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

/// A proxy's worker and the buffers of the call not in flight.
struct Slot<J> {
    /// `None` once the instance missed a deadline (the worker was let go).
    worker: Option<Worker<Box<J>>>,
    spare: Option<Box<J>>,
}

/// The functions of a constraint instance, with the instance.
struct ConstraintCore {
    handle: Handle,
    evaluate: EvaluateFn,
}

/// One `evaluate` call with every buffer the plugin may touch (so a call that outlives its
/// deadline writes only into memory it owns).
struct ConstraintJob {
    data: Vec<f64>,
    batch: usize,
    horizon: usize,
    dt: f64,
    limits: H2nLimits,
    initial_velocity: H2nTwist,
    agents: Vec<H2nAgent>,
    history: Vec<f64>,
    cost: Vec<f64>,
    grad: Vec<f64>,
    result: Result<(), (H2nStatus, String)>,
}

// SAFETY: the raw pointers in `agents` are null or point into the job's own `history` (set by
// `link_histories` on the thread that makes the call); the job moves between threads as a
// whole and is used by one thread at a time.
unsafe impl Send for ConstraintJob {}

impl ConstraintJob {
    fn new() -> Self {
        Self {
            data: Vec::new(),
            batch: 0,
            horizon: 0,
            dt: 0.0,
            limits: H2nLimits::default(),
            initial_velocity: H2nTwist::default(),
            agents: Vec::new(),
            history: Vec::new(),
            cost: Vec::new(),
            grad: Vec::new(),
            result: Ok(()),
        }
    }
}

impl ConstraintCore {
    /// Calls `evaluate`; on failure the status and the instance's message (read on this
    /// thread, right after the call).
    ///
    /// # Safety
    /// Every pointer in `batch`, `ctx`, `cost` and `grad` is valid for the call, the outputs
    /// of their stated lengths and distinct.
    unsafe fn call(
        &self,
        batch: &H2nTrajBatch,
        ctx: &H2nConstraintContext,
        cost: H2nF64Out,
        grad: H2nF64Out,
    ) -> Result<(), (H2nStatus, String)> {
        // SAFETY: live instance, checked function; forwarded contract for the pointers.
        let status = unsafe { (self.evaluate)(self.handle.ptr(), batch, ctx, cost, grad) };
        if status == H2N_OK {
            Ok(())
        } else {
            Err((status, self.handle.failure(status)))
        }
    }

    /// Runs a job on its own buffers (on the worker thread).
    fn run(&self, job: &mut ConstraintJob) {
        link_histories(&mut job.agents, &job.history);
        let batch = H2nTrajBatch {
            data: job.data.as_ptr(),
            len: job.data.len(),
            batch: job.batch,
            horizon: job.horizon,
            dim: 3,
        };
        let ctx = H2nConstraintContext {
            struct_size: std::mem::size_of::<H2nConstraintContext>() as u32,
            reserved: 0,
            dt: job.dt,
            limits: job.limits,
            initial_velocity: job.initial_velocity,
            agents: job.agents.as_ptr(),
            agent_count: job.agents.len(),
        };
        let cost = H2nF64Out {
            data: job.cost.as_mut_ptr(),
            len: job.cost.len(),
        };
        let grad = H2nF64Out {
            data: job.grad.as_mut_ptr(),
            len: job.grad.len(),
        };
        // SAFETY: every pointer points into the job, which this thread owns for the call.
        job.result = unsafe { self.call(&batch, &ctx, cost, grad) };
    }
}

enum ConstraintExec {
    /// No deadline: calls run on the caller's thread, on the caller's buffers.
    Direct(ConstraintCore),
    /// With a deadline: calls run on the instance's worker, one at a time.
    Worker(Mutex<Slot<ConstraintJob>>),
    /// In a helper process of its own, one call at a time.
    Process(Mutex<ProcessClient>),
}

/// A constraint term living in a plugin library.
pub struct PluginConstraint {
    name: String,
    health: Arc<Health>,
    deadline: Option<Duration>,
    exec: ConstraintExec,
}

impl fmt::Debug for PluginConstraint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PluginConstraint")
            .field("name", &self.name)
            .field("health", &self.health)
            .field("deadline", &self.deadline)
            .finish()
    }
}

impl PluginConstraint {
    /// True once the plugin panicked or missed its deadline; the term then refuses to evaluate.
    pub fn is_poisoned(&self) -> bool {
        self.health.poisoned()
    }

    /// The deadline of each `evaluate` call (`None`: calls run on the caller's thread).
    pub fn deadline(&self) -> Option<Duration> {
        self.deadline
    }

    fn unusable(&self) -> ConstraintError {
        ConstraintError::Failed {
            term: self.name.clone(),
            message: format!(
                "unusable after an earlier failure: {}",
                self.health.message()
            ),
        }
    }

    /// Runs the call on the worker with copies of the caller's buffers.
    fn evaluate_on_worker(
        &self,
        slot: &Mutex<Slot<ConstraintJob>>,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<Result<(), (H2nStatus, String)>, ConstraintError> {
        let mut guard = slot.lock().unwrap_or_else(|e| e.into_inner());
        let slot = &mut *guard;
        // Another thread may have timed out while this one waited for the lock.
        if self.health.poisoned() {
            return Err(self.unusable());
        }
        let Some(worker) = slot.worker.as_ref() else {
            return Err(self.unusable());
        };
        let mut job = slot
            .spare
            .take()
            .unwrap_or_else(|| Box::new(ConstraintJob::new()));
        job.data.clear();
        job.data.extend_from_slice(batch.data);
        (job.batch, job.horizon) = (batch.batch, batch.horizon);
        job.dt = ctx.dt;
        job.limits = ctx.limits.into();
        job.initial_velocity = ctx.initial_velocity.into();
        load_agents(ctx.agents, &mut job.agents, &mut job.history);
        job.cost.clear();
        job.cost.extend_from_slice(cost);
        job.grad.clear();
        job.grad.extend_from_slice(grad);
        let deadline = self.deadline.unwrap_or(deadline::DEFAULT_DEADLINE);
        match worker.call(job, deadline) {
            Ok(mut job) => {
                cost.copy_from_slice(&job.cost);
                grad.copy_from_slice(&job.grad);
                let result = std::mem::replace(&mut job.result, Ok(()));
                slot.spare = Some(job);
                Ok(result)
            }
            Err(NoAnswer::TimedOut) => {
                slot.worker = None;
                let message = self.health.timed_out("evaluate", deadline);
                Err(ConstraintError::Failed {
                    term: self.name.clone(),
                    message,
                })
            }
            Err(NoAnswer::Gone) => {
                slot.worker = None;
                Err(ConstraintError::Failed {
                    term: self.name.clone(),
                    message: self.health.worker_gone(),
                })
            }
        }
    }
}

impl ConstraintTerm for PluginConstraint {
    fn name(&self) -> &str {
        &self.name
    }

    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        let fail = |message: String| ConstraintError::Failed {
            term: self.name.clone(),
            message,
        };
        if self.health.poisoned() {
            return Err(self.unusable());
        }
        EvaluateBuffers {
            batch: batch.batch,
            horizon: batch.horizon,
            values: batch.data.len(),
            cost: cost.len(),
            grad: grad.len(),
        }
        .check()
        .map_err(ConstraintError::Shape)?;
        let result = match &self.exec {
            ConstraintExec::Direct(core) => {
                let agents: Vec<H2nAgent> = ctx.agents.iter().map(H2nAgent::borrow).collect();
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
                let c = H2nF64Out {
                    data: cost.as_mut_ptr(),
                    len: cost.len(),
                };
                let g = H2nF64Out {
                    data: grad.as_mut_ptr(),
                    len: grad.len(),
                };
                // SAFETY: every pointer is valid for the call; the outputs are distinct
                // host-owned slices of the stated lengths.
                unsafe { core.call(&abi_batch, &abi_ctx, c, g) }
            }
            ConstraintExec::Worker(slot) => {
                self.evaluate_on_worker(slot, batch, ctx, cost, grad)?
            }
            ConstraintExec::Process(client) => {
                let mut client = client.lock().unwrap_or_else(|e| e.into_inner());
                return match client.evaluate(batch, ctx, cost, grad) {
                    Ok(answer) => answer,
                    Err(message) => {
                        if client.dead().is_some() {
                            self.health.poison(&message);
                        }
                        Err(fail(message))
                    }
                };
            }
        };
        result.map_err(|(status, message)| match status {
            H2N_INVALID_ARGUMENT => ConstraintError::Shape(message),
            H2N_PANIC => fail(format!("panicked (the term is now unusable): {message}")),
            H2N_POISONED => fail(format!("unusable after an earlier panic: {message}")),
            _ => fail(message),
        })
    }
}

/// The checked functions of an embodiment.
#[derive(Clone, Copy)]
struct EmbodimentFns {
    holonomic: HolonomicFn,
    saturate: SaturateFn,
    step: StepFn,
    track: TrackFn,
}

/// Calls an embodiment's `coupled_limit` slot and checks what it wrote: `Ok(None)` when it left
/// the output zeroed; `Err(Err(status))` for a failed call, `Err(Ok(message))` naming the field
/// of a bad value.
///
/// # Safety
/// `instance` is a live instance of the vtable `f` came from.
unsafe fn call_coupled_limit(
    f: CoupledLimitFn,
    instance: *mut c_void,
) -> Result<Option<CoupledLimit>, Result<String, H2nStatus>> {
    let mut out = H2nCoupledLimit::default();
    // SAFETY: live instance (the caller's contract), valid output pointer.
    let status = unsafe { f(instance, &mut out) };
    if status != H2N_OK {
        return Err(Err(status));
    }
    out.to_limit()
        .map_err(|(field, message)| Ok(format!("coupled_limit: {field} = {message}")))
}

/// Largest yaw rate an embodiment plugin may answer (rad/s): 16 turns a second, far past any
/// robot, so that only a broken value is refused.
pub const MAX_EMBODIMENT_YAW_RATE: f64 = 100.0;

/// An embodiment living in a plugin library.
///
/// The [`Embodiment`] methods cannot return errors; when the plugin fails or panics the proxy
/// returns the safe value (zero command; robot halted where it is) and records the failure
/// (see [`PluginEmbodiment::failure`] and [`PluginHost::failures`]). After a panic every call
/// returns the safe value.
pub struct PluginEmbodiment {
    handle: Handle,
    name: String,
    fns: EmbodimentFns,
    coupled: Option<CoupledLimit>,
}

impl fmt::Debug for PluginEmbodiment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PluginEmbodiment")
            .field("name", &self.name)
            .field("handle", &self.handle)
            .finish()
    }
}

impl PluginEmbodiment {
    /// The failure that made this embodiment unusable, if any.
    pub fn failure(&self) -> Option<String> {
        self.handle
            .health
            .poisoned()
            .then(|| self.handle.health.message())
    }

    /// Checks what a `saturate`, `step` or `track` call answered, every call: a pose within
    /// [`MAX_COORDINATE`](human2nav_core::planner::MAX_COORDINATE) m of the origin with a finite
    /// heading, speeds within [`MAX_SPEED`](human2nav_core::planner::MAX_SPEED) m/s and a yaw
    /// rate within [`MAX_EMBODIMENT_YAW_RATE`]. A value outside poisons the embodiment with a
    /// message naming the call and the field (the caller then halts the robot); `None`.
    fn checked(
        &self,
        call: &str,
        pose: Option<H2nPose>,
        twist: H2nTwist,
    ) -> Option<(Option<H2nPose>, Twist2)> {
        use human2nav_core::planner::{MAX_COORDINATE, MAX_SPEED};
        let within = |v: f64, bound: f64| v.is_finite() && v.abs() <= bound;
        // Arrays, not a Vec: this runs at every simulator step.
        let twist_fields = [
            ("vx", twist.vx, MAX_SPEED, "m/s"),
            ("vy", twist.vy, MAX_SPEED, "m/s"),
            ("omega", twist.omega, MAX_EMBODIMENT_YAW_RATE, "rad/s"),
        ];
        let pose_fields = pose.map(|p| {
            [
                ("x", p.x, MAX_COORDINATE, "m"),
                ("y", p.y, MAX_COORDINATE, "m"),
                ("theta", p.theta, f64::MAX, "rad"),
            ]
        });
        if let Some((field, value, bound, unit)) = twist_fields
            .into_iter()
            .chain(pose_fields.into_iter().flatten())
            .find(|(_, v, b, _)| !within(*v, *b))
        {
            let message = format!(
                "embodiment `{}`: {call} answered {field} = {value}, outside ±{bound:e} {unit} \
                 (or not finite); the robot is halted",
                self.name
            );
            self.handle.health.poison(&message);
            return None;
        }
        Some((pose, twist.into()))
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
        &self.name
    }

    /// What the plugin's `coupled_limit` slot reported when the instance was created.
    fn coupled_limit(&self) -> Option<CoupledLimit> {
        self.coupled
    }

    fn holonomic(&self) -> bool {
        if self.handle.health.poisoned() {
            return false;
        }
        let mut out = 0u32;
        // SAFETY: live instance, checked function, valid output pointer.
        let status = unsafe { (self.fns.holonomic)(self.handle.ptr(), &mut out) };
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
        // SAFETY: live instance, checked function, valid pointers for the call.
        let status = unsafe { (self.fns.saturate)(self.handle.ptr(), &s, &c, dt, &mut out) };
        if status != H2N_OK {
            self.failed(status);
            return Twist2::ZERO;
        }
        self.checked("saturate", None, out)
            .map_or(Twist2::ZERO, |(_, t)| t)
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
        // SAFETY: live instance, checked function, valid pointers for the call.
        let status = unsafe { (self.fns.step)(self.handle.ptr(), &s, &c, dt, &mut out) };
        if status != H2N_OK {
            self.failed(status);
            return halted;
        }
        match self.checked("step", Some(out.pose), out.velocity) {
            Some((Some(pose), velocity)) => RobotState {
                pose: pose.into(),
                velocity,
            },
            _ => halted,
        }
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
        // SAFETY: live instance, checked function, valid pointers for the call.
        let status = unsafe { (self.fns.track)(self.handle.ptr(), &s, &view, t, &mut out) };
        if status != H2N_OK {
            self.failed(status);
            return Twist2::ZERO;
        }
        self.checked("track", None, out)
            .map_or(Twist2::ZERO, |(_, t)| t)
    }
}

/// The functions of a planner instance, with the instance.
struct PlannerCore {
    handle: Handle,
    /// The library's ABI version: from 2 on the observation carries obstacles.
    abi_version: u32,
    reset: Option<ResetFn>,
    plan: PlanFn,
    last_plan: LastPlanFn,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PlanOp {
    Plan,
    Reset,
}

/// One `plan` or `reset` call with every buffer the plugin may touch.
struct PlanJob {
    op: PlanOp,
    time: f64,
    ego: H2nPose,
    ego_velocity: H2nTwist,
    goal: [f64; 2],
    agents: Vec<H2nAgent>,
    history: Vec<f64>,
    /// Static obstacles (polygon vertex pointers left null, see [`link_vertices`]) and the
    /// polygons' vertices.
    obstacles: Vec<H2nObstacle>,
    vertices: Vec<f64>,
    /// The occupancy grid (its `data` pointer left null) and its cells.
    occupancy: Option<H2nOccupancyGrid>,
    cells: Vec<i8>,
    /// Obstacles and grid a version-1 plugin was not given (a note on its plan).
    unseen: Option<String>,
    /// Plan buffer (grows to the longest plan seen, at most [`MAX_PLAN_POSES`]).
    poses: Vec<H2nPose>,
    note: Vec<u8>,
    /// The call's status, with the instance's message when it is not OK.
    status: H2nStatus,
    message: String,
    /// A problem the host found with an OK answer (a plan longer than its buffer or the cap).
    problem: Option<String>,
    t0: f64,
    dt: f64,
    len: usize,
    fallback: bool,
    note_len: usize,
}

// SAFETY: as for `ConstraintJob`: the pointers in `agents` point into the job's own `history`,
// those in `obstacles` into its own `vertices` (the grid's `data`, into `cells`, is set only in
// the local observation of the call).
unsafe impl Send for PlanJob {}

impl PlanJob {
    fn new() -> Self {
        Self {
            op: PlanOp::Plan,
            time: 0.0,
            ego: H2nPose::default(),
            ego_velocity: H2nTwist::default(),
            goal: [0.0; 2],
            agents: Vec::new(),
            history: Vec::new(),
            obstacles: Vec::new(),
            vertices: Vec::new(),
            occupancy: None,
            cells: Vec::new(),
            unseen: None,
            poses: Vec::new(),
            note: Vec::new(),
            status: H2N_OK,
            message: String::new(),
            problem: None,
            t0: 0.0,
            dt: 0.0,
            len: 0,
            fallback: false,
            note_len: 0,
        }
    }
}

impl PlannerCore {
    /// Runs a job on its own buffers (on the worker thread, or the caller's without deadline).
    fn run(&mut self, job: &mut PlanJob) {
        job.message.clear();
        job.problem = None;
        match job.op {
            PlanOp::Reset => {
                job.status = match self.reset {
                    // SAFETY: live instance (exclusive: one thread at a time), checked function.
                    Some(reset) => unsafe { reset(self.handle.ptr()) },
                    None => H2N_OK,
                };
                if job.status != H2N_OK {
                    job.message = self.handle.failure(job.status);
                }
            }
            PlanOp::Plan => self.plan(job),
        }
    }

    fn plan(&mut self, job: &mut PlanJob) {
        link_histories(&mut job.agents, &job.history);
        link_vertices(&mut job.obstacles, &job.vertices);
        let occupancy = job.occupancy.map(|mut g| {
            g.data = job.cells.as_ptr();
            g
        });
        // A version-1 plugin reads the prefix before `obstacles`; it is told nothing more.
        job.unseen = (self.abi_version < 2)
            .then(|| unseen_by_v1(job.obstacles.len(), occupancy.is_some()))
            .flatten();
        let obs = H2nObservation {
            struct_size: std::mem::size_of::<H2nObservation>() as u32,
            reserved: 0,
            time: job.time,
            ego: job.ego,
            ego_velocity: job.ego_velocity,
            goal: job.goal,
            agents: job.agents.as_ptr(),
            agent_count: job.agents.len(),
            obstacles: if job.obstacles.is_empty() {
                std::ptr::null()
            } else {
                job.obstacles.as_ptr()
            },
            obstacle_count: job.obstacles.len(),
            occupancy: occupancy
                .as_ref()
                .map_or(std::ptr::null(), std::ptr::from_ref),
        };
        if job.poses.len() < 64 {
            job.poses.resize(64, H2nPose::default());
        }
        if job.note.len() < 256 {
            job.note.resize(256, 0);
        }
        let mut out = plan_out(&mut job.poses, &mut job.note);
        // SAFETY: live instance (one call at a time), checked function; the observation and the
        // host-owned buffers live in the job for the whole call.
        let mut status = unsafe { (self.plan)(self.handle.ptr(), &obs, &mut out) };
        if status == H2N_BUFFER_TOO_SMALL && out.len > job.poses.len() {
            if out.len > MAX_PLAN_POSES {
                job.status = H2N_ERROR;
                job.problem = Some(format!(
                    "it returned a plan of {} poses, more than the {MAX_PLAN_POSES} this host \
                     accepts",
                    out.len
                ));
                return;
            }
            job.poses.resize(out.len, H2nPose::default());
            out = plan_out(&mut job.poses, &mut job.note);
            // SAFETY: as above.
            status = unsafe { (self.last_plan)(self.handle.ptr(), &mut out) };
        }
        job.status = status;
        if status != H2N_OK {
            job.message = self.handle.failure(status);
            return;
        }
        if out.len > out.capacity {
            job.status = H2N_ERROR;
            job.problem = Some(format!(
                "it reported a plan of {} poses in a buffer of {}",
                out.len, out.capacity
            ));
            return;
        }
        job.t0 = out.t0;
        job.dt = out.dt;
        job.len = out.len;
        job.fallback = out.fallback != 0;
        job.note_len = out.note.len;
    }
}

fn plan_out(poses: &mut [H2nPose], note: &mut [u8]) -> H2nPlanOut {
    H2nPlanOut {
        t0: 0.0,
        dt: 0.0,
        poses: poses.as_mut_ptr(),
        capacity: poses.len(),
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

enum PlannerExec {
    /// No deadline: calls run on the caller's thread.
    Direct(PlannerCore),
    /// With a deadline: calls run on the instance's worker; `None` once it missed one.
    Worker(Option<Worker<Box<PlanJob>>>),
    /// In a helper process of its own.
    Process(ProcessClient),
}

/// A planner living in a plugin library.
///
/// With a deadline ([`PluginHost::planner`] sets [`deadline::DEFAULT_DEADLINE`]) a `plan` call
/// that does not return in time gives the safe plan (stop in place, flagged as a fallback, with
/// [`PlanInfo::error`] saying why), logs a line on stderr and marks the planner dead: every
/// later call fails at once with [`PlanError::Unusable`].
pub struct PluginPlanner {
    name: String,
    health: Arc<Health>,
    deadline: Option<Duration>,
    exec: PlannerExec,
    /// The buffers of the call not in flight.
    spare: Option<Box<PlanJob>>,
    /// Length of the last plan (of the safe plan after a missed deadline).
    horizon: usize,
}

impl fmt::Debug for PluginPlanner {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PluginPlanner")
            .field("name", &self.name)
            .field("health", &self.health)
            .field("deadline", &self.deadline)
            .finish()
    }
}

impl PluginPlanner {
    /// The deadline of each call (`None`: calls run on the caller's thread).
    pub fn deadline(&self) -> Option<Duration> {
        self.deadline
    }

    /// True once the planner panicked or missed its deadline.
    pub fn is_poisoned(&self) -> bool {
        self.health.poisoned()
    }

    /// Runs a job; `Err` when the deadline passed (the planner is then dead) or the worker is
    /// gone.
    fn execute(&mut self, fill: impl FnOnce(&mut PlanJob)) -> Result<Box<PlanJob>, NoAnswer> {
        let mut job = self
            .spare
            .take()
            .unwrap_or_else(|| Box::new(PlanJob::new()));
        fill(&mut job);
        match &mut self.exec {
            PlannerExec::Direct(core) => {
                core.run(&mut job);
                Ok(job)
            }
            PlannerExec::Worker(worker) => {
                let Some(w) = worker.as_ref() else {
                    return Err(NoAnswer::Gone);
                };
                let answer = w.call(job, self.deadline.unwrap_or(deadline::DEFAULT_DEADLINE));
                if answer.is_err() {
                    // Let go of the worker: it ends (and destroys the instance) if the call
                    // ever returns.
                    *worker = None;
                }
                answer
            }
            // Process calls never come here (see `plan` and `reset`).
            PlannerExec::Process(_) => Err(NoAnswer::Gone),
        }
    }

    /// Restarts of the helper process so far (`None` for an instance in the host process).
    pub fn process_restarts(&self) -> Option<u32> {
        match &self.exec {
            PlannerExec::Process(c) => Some(c.restarts()),
            _ => None,
        }
    }

    /// `plan` in the helper process: a dead or hung process gives the stop-in-place plan with
    /// [`PlanInfo::error`] set; after the last restart the planner is unusable.
    fn plan_in_process(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        let PlannerExec::Process(client) = &mut self.exec else {
            return Err(PlanError::Unusable {
                planner: self.name.clone(),
                message: "not an out-of-process planner".into(),
            });
        };
        match client.plan(obs) {
            Ok(Ok(plan)) => {
                self.horizon = plan.poses.len().max(1);
                Ok(plan)
            }
            Ok(Err(e)) => Err(e),
            Err(why) => {
                if client.dead().is_some() {
                    self.health.poison(&why);
                }
                let mut plan = Plan::stop_in_place(
                    obs,
                    human2nav_core::trajectory::DEFAULT_DT,
                    self.horizon,
                    why.clone(),
                );
                plan.info.error = Some(why);
                Ok(plan)
            }
        }
    }

    /// What a missed deadline or a lost worker means for the instance.
    fn no_answer(&self, e: NoAnswer, call: &str) -> String {
        match e {
            NoAnswer::TimedOut => self
                .health
                .timed_out(call, self.deadline.unwrap_or(deadline::DEFAULT_DEADLINE)),
            NoAnswer::Gone if self.health.poisoned() => self.health.message(),
            NoAnswer::Gone => self.health.worker_gone(),
        }
    }

    fn error(&self, job: &PlanJob) -> PlanError {
        let planner = self.name.clone();
        if let Some(problem) = &job.problem {
            return PlanError::Failed {
                planner,
                message: problem.clone(),
            };
        }
        let message = job.message.clone();
        match job.status {
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
        &self.name
    }

    fn reset(&mut self) {
        if self.health.poisoned() {
            return;
        }
        if let PlannerExec::Process(client) = &mut self.exec {
            // The trait's reset cannot fail: a failure is recorded and the next call restarts
            // the process (or reports the dead instance).
            if let Err(why) = client.reset() {
                if client.dead().is_some() {
                    self.health.poison(&why);
                }
            }
            return;
        }
        match self.execute(|job| job.op = PlanOp::Reset) {
            Ok(job) => {
                if job.status != H2N_OK {
                    // The trait's reset cannot fail; the next `plan` reports the unusable
                    // planner.
                    self.health.poison(&job.message);
                }
                self.spare = Some(job);
            }
            Err(e) => {
                self.no_answer(e, "reset");
            }
        }
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        if self.health.poisoned() {
            return Err(PlanError::Unusable {
                planner: self.name.clone(),
                message: self.health.message(),
            });
        }
        obs.validate()?;
        if matches!(self.exec, PlannerExec::Process(_)) {
            return self.plan_in_process(obs);
        }
        let job = match self.execute(|job| {
            job.op = PlanOp::Plan;
            job.time = obs.time;
            job.ego = obs.ego.into();
            job.ego_velocity = obs.ego_velocity.into();
            job.goal = obs.goal;
            load_agents(&obs.agents, &mut job.agents, &mut job.history);
            load_obstacles(obs, job);
        }) {
            Ok(job) => job,
            Err(NoAnswer::TimedOut) => {
                let why = self.no_answer(NoAnswer::TimedOut, "plan");
                let mut plan = Plan::stop_in_place(
                    obs,
                    human2nav_core::trajectory::DEFAULT_DT,
                    self.horizon,
                    why.clone(),
                );
                plan.info.error = Some(why);
                return Ok(plan);
            }
            Err(e) => {
                return Err(PlanError::Unusable {
                    planner: self.name.clone(),
                    message: self.no_answer(e, "plan"),
                });
            }
        };
        let result = if job.status != H2N_OK {
            Err(self.error(&job))
        } else {
            let n = job.len.min(job.poses.len());
            let note = buffer_text(&job.note, job.note_len);
            let notes = [Some(note).filter(|n| !n.is_empty()), job.unseen.clone()]
                .into_iter()
                .flatten()
                .collect();
            let plan = Plan {
                t0: job.t0,
                dt: job.dt,
                poses: job.poses[..n].iter().map(|&p| Pose2::from(p)).collect(),
                info: PlanInfo {
                    fallback: job.fallback,
                    notes,
                    ..PlanInfo::default()
                },
            };
            if !plan.is_finite() || plan.poses.is_empty() {
                Err(PlanError::Failed {
                    planner: self.name.clone(),
                    message: "the plugin returned an empty or non-finite plan".into(),
                })
            } else {
                self.horizon = plan.poses.len();
                Ok(plan)
            }
        };
        self.spare = Some(job);
        result
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

#[cfg(test)]
mod tests {
    //! Entry tables a broken plugin could return, validated in-process exactly as after
    //! `dlopen` (the tables are statics of this test binary instead of a library's).

    use super::*;

    /// A plugin that claims a longer message than it wrote shows what it wrote, not the NUL
    /// bytes after it; control characters become spaces.
    #[test]
    fn a_claimed_error_length_is_not_trusted_past_the_text() {
        let mut buf = vec![0u8; 1009];
        buf[..4].copy_from_slice(b"oops");
        assert_eq!(buffer_text(&buf, 1009), "oops");
        let bell = b"bad\x07value\x1b[2J";
        assert_eq!(buffer_text(bell, bell.len()), "bad value [2J");
        assert_eq!(buffer_text(b"longer", 4096), "longer \u{2026}");
    }

    unsafe extern "C" fn create_nothing(
        _: *const H2nCreateArgs,
        _: *mut H2nObject,
        _: *mut H2nBuffer,
    ) -> H2nStatus {
        H2N_ERROR
    }

    fn factory(name: &'static str, create: Option<CreateFn>) -> H2nFactory {
        H2nFactory {
            struct_size: std::mem::size_of::<H2nFactory>() as u32,
            kind: H2N_KIND_CONSTRAINT,
            name: H2nStr::new(name),
            description: H2nStr::new("test"),
            create,
        }
    }

    fn entry(factories: &'static [H2nFactory]) -> H2nPluginEntry {
        H2nPluginEntry {
            abi_version: ABI_VERSION,
            struct_size: std::mem::size_of::<H2nPluginEntry>() as u32,
            name: H2nStr::new("broken"),
            version: H2nStr::new("0"),
            factories: factories.as_ptr(),
            factory_count: factories.len(),
            find_factory: None,
        }
    }

    fn load(e: H2nPluginEntry) -> (Result<PluginLibrary, PluginError>, Vec<Check>) {
        let e: &'static H2nPluginEntry = Box::leak(Box::new(e));
        let mut checks = Vec::new();
        // SAFETY: a leaked (static) table whose fields are as declared or deliberately wrong
        // in ways the validation must catch before reading out of bounds.
        let r =
            unsafe { PluginLibrary::from_entry(Path::new("/lib/libbroken.so"), e, &mut checks) };
        (r, checks)
    }

    fn leak(f: Vec<H2nFactory>) -> &'static [H2nFactory] {
        Box::leak(f.into_boxed_slice())
    }

    #[test]
    fn a_valid_table_loads_and_lists_its_checks() {
        let (r, checks) = load(entry(leak(vec![
            factory("a", Some(create_nothing)),
            factory("b", Some(create_nothing)),
        ])));
        let lib = r.expect("valid");
        assert_eq!(lib.factories().len(), 2);
        assert!(checks.iter().all(Check::passed), "{checks:?}");
        assert!(
            checks
                .iter()
                .any(|c| c.item == "factory 1 (constraint `b`)")
        );
    }

    #[test]
    fn a_null_create_slot_names_the_file_the_table_and_the_slot() {
        let (r, checks) = load(entry(leak(vec![
            factory("a", Some(create_nothing)),
            factory("b", None),
        ])));
        let err = r.expect_err("null create");
        assert_eq!(
            err.to_string(),
            "/lib/libbroken.so: the factory table entry 1 (constraint `b`) has a null `create` \
             (a required function)"
        );
        assert!(checks.last().is_some_and(|c| !c.passed()));
    }

    #[test]
    fn an_absurd_factory_count_is_refused_without_allocating() {
        let mut e = entry(leak(vec![factory("a", Some(create_nothing))]));
        e.factory_count = 1 << 40;
        let err = load(e).0.expect_err("count");
        assert_eq!(
            err.to_string(),
            "/lib/libbroken.so: the factory count is 1099511627776, more than this host \
             accepts (256)"
        );
    }

    #[test]
    fn wrong_table_sizes_are_refused() {
        let mut e = entry(leak(vec![factory("a", Some(create_nothing))]));
        e.struct_size = 8;
        let err = load(e).0.expect_err("entry size");
        assert!(
            err.to_string()
                .contains("the entry table declares 8 bytes (struct_size); this host needs"),
            "{err}"
        );
        let mut f = factory("a", Some(create_nothing));
        f.struct_size = 1 << 30;
        let err = load(entry(leak(vec![f]))).0.expect_err("factory size");
        assert!(
            err.to_string()
                .contains("factory table entry 0 declares 1073741824"),
            "{err}"
        );
        // Two factories of different sizes cannot be one array.
        let mut g = factory("b", Some(create_nothing));
        g.struct_size += 8;
        let err = load(entry(leak(vec![factory("a", Some(create_nothing)), g])))
            .0
            .expect_err("stride");
        assert!(err.to_string().contains("factory 1 is"), "{err}");
    }

    #[test]
    fn bad_strings_and_duplicates_are_refused() {
        let mut e = entry(leak(vec![factory("a", Some(create_nothing))]));
        e.name = H2nStr {
            ptr: std::ptr::null(),
            len: 5,
        };
        assert!(
            load(e)
                .0
                .expect_err("null name")
                .to_string()
                .contains("is null with length 5")
        );
        let mut e = entry(leak(vec![factory("a", Some(create_nothing))]));
        e.version = H2nStr {
            ptr: "x".as_ptr(),
            len: 1 << 40,
        };
        let err = load(e).0.expect_err("long version");
        assert!(err.to_string().contains("the limit is 256"), "{err}");
        let err = load(entry(leak(vec![
            factory("a", Some(create_nothing)),
            factory("a", Some(create_nothing)),
        ])))
        .0
        .expect_err("duplicate");
        assert!(err.to_string().contains("repeats constraint `a`"), "{err}");
    }

    #[test]
    fn worker_thread_names_keep_only_safe_characters() {
        assert_eq!(thread_name("personal_space"), "h2n-personal_sp");
        assert_eq!(thread_name("a\0b c/é"), "h2n-abc");
    }

    /// What the host writes for a version-2 planner is what the plugin side reads back: every
    /// obstacle kind and the occupancy grid; a version-1 planner is told what it missed.
    #[test]
    fn obstacles_and_the_grid_cross_the_boundary() {
        use human2nav_core::obstacle::OccupancyGrid;
        let obs = Observation {
            obstacles: vec![
                Obstacle::Circle {
                    center: [1.0, 2.0],
                    radius: 0.5,
                },
                Obstacle::Polygon {
                    vertices: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
                },
                Obstacle::Segment {
                    a: [-1.0, 3.0],
                    b: [4.0, 3.0],
                },
                Obstacle::Polygon {
                    vertices: vec![[5.0, 5.0], [6.0, 5.0], [6.0, 6.0], [5.0, 6.0]],
                },
            ],
            occupancy: Some(OccupancyGrid {
                origin: Pose2::new(-2.0, -1.0, 0.25),
                resolution: 0.1,
                width: 3,
                height: 2,
                data: vec![0, 100, -1, 50, 65, 0],
                occupied_threshold: 60,
            }),
            ..Observation::default()
        };
        let mut job = PlanJob::new();
        load_obstacles(&obs, &mut job);
        link_vertices(&mut job.obstacles, &job.vertices);
        let grid = job.occupancy.map(|mut g| {
            g.data = job.cells.as_ptr();
            g
        });
        // SAFETY: the records point into the job's buffers, alive for these calls.
        let (obstacles, occupancy) = unsafe {
            (
                crate::export::obstacles_from_abi(job.obstacles.as_ptr(), job.obstacles.len()),
                crate::export::occupancy_from_abi(grid.as_ref().map_or(std::ptr::null(), |g| g)),
            )
        };
        assert_eq!(obstacles.ok(), Some(obs.obstacles.clone()));
        assert_eq!(occupancy.ok().flatten(), obs.occupancy);
        assert_eq!(
            unseen_by_v1(4, true).as_deref(),
            Some(
                "plugin ABI version 1: 4 static obstacle(s) and the occupancy grid not passed to \
                 the planner (version 2 carries them)"
            )
        );
        assert_eq!(unseen_by_v1(0, false), None);
    }

    #[test]
    fn agent_histories_are_linked_into_the_flat_buffer() {
        let agents = vec![
            AgentState {
                id: 1,
                position: [0.0, 0.0],
                velocity: [0.0, 0.0],
                radius: 0.3,
                history: vec![[1.0, 2.0], [3.0, 4.0]],
            },
            AgentState {
                id: 2,
                position: [0.0, 0.0],
                velocity: [0.0, 0.0],
                radius: 0.3,
                history: vec![],
            },
            AgentState {
                id: 3,
                position: [0.0, 0.0],
                velocity: [0.0, 0.0],
                radius: 0.3,
                history: vec![[5.0, 6.0]],
            },
        ];
        let (mut abi, mut flat) = (Vec::new(), Vec::new());
        load_agents(&agents, &mut abi, &mut flat);
        link_histories(&mut abi, &flat);
        assert_eq!(flat, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        assert!(abi[1].history.is_null());
        // SAFETY: the pointers point into `flat`, which is alive.
        unsafe {
            assert_eq!(*abi[0].history, 1.0);
            assert_eq!(*abi[2].history.add(1), 6.0);
        }
    }
}
