//! The vtable of each plugin kind: its slots, checked before any instance of it is used.

use super::*;

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
    const MIN_SIZE: usize = std::mem::offset_of!(H2nConstraintVTable, properties);
    fn own_slots(&self) -> Vec<(&'static str, bool, bool)> {
        vec![
            ("evaluate", self.evaluate.is_some(), true),
            ("properties", self.properties.is_some(), false),
        ]
    }
    unsafe fn probe_instance(&self, instance: *mut c_void) -> Result<String, String> {
        if self.properties.is_none() {
            return Ok(String::new());
        }
        // SAFETY: a live instance of this table (the caller's contract).
        match unsafe { super::constraint::call_properties(self.properties, instance) } {
            Ok(true) => Ok("; separable and non-negative".to_owned()),
            Ok(false) => Ok("; no properties".to_owned()),
            Err(status) => Err(format!("properties returned {}", status_name(status))),
        }
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
pub(super) unsafe fn instance_name(
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
