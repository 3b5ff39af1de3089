//! [`PluginLibrary`]: a library loaded once per canonical path, its entry and factory tables
//! checked before use.

use super::*;

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
    pub(super) path: PathBuf,
    pub(super) abi_version: u32,
    pub(super) name: String,
    pub(super) version: String,
    pub(super) factories: Vec<FactoryInfo>,
    /// `create` of each factory, in the order of `factories` (checked non-null).
    pub(super) creates: Vec<CreateFn>,
    /// What was checked when the library was loaded, in order.
    pub(super) checks: Vec<Check>,
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
pub(super) fn table_size(
    path: &Path,
    table: &str,
    size: u32,
    min: usize,
) -> Result<(), PluginError> {
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
    /// [`crate::locate`]. Checks the file before the OS loader maps it and the ABI version
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

/// How the checks and `plugin inspect` describe a library's ABI version.
pub(crate) fn abi_version_text(found: u32) -> String {
    if found < OBSTACLES_SINCE {
        format!(
            "{found} (this host: {ABI_VERSION}; a version-{found} planner is given pedestrians, not \
             static obstacles or the occupancy grid)"
        )
    } else {
        format!("{found} (this host: {ABI_VERSION})")
    }
}
