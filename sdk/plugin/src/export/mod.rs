//! The plugin side of the ABI: generic `extern "C"` shims around the core traits, used by the
//! expansion of [`export_plugin!`](crate::export_plugin). Authors never call these directly.
//!
//! Every shim checks its pointers and lengths, runs the author's code inside `catch_unwind`,
//! turns errors into status codes plus a per-instance last-error message, and marks the
//! instance unusable (`H2N_POISONED` from then on) when the code panicked.

use crate::abi::*;
use crate::init::{InitError, PluginInit, RobotContext};
use human2nav_core::AgentState;
use human2nav_core::obstacle::{Obstacle, OccupancyGrid};
use std::ffi::c_void;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::ptr::NonNull;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

mod constraint;
mod embodiment;
mod planner;
#[cfg(test)]
mod tests;

pub use constraint::create_constraint;
pub use embodiment::create_embodiment;
pub use planner::create_planner;

/// A failure inside a shim: the status to return and the message for `last_error`.
pub(crate) struct Fail {
    status: H2nStatus,
    message: String,
}

impl Fail {
    fn invalid(message: impl Into<String>) -> Self {
        Self {
            status: H2N_INVALID_ARGUMENT,
            message: message.into(),
        }
    }

    fn error(message: impl Into<String>) -> Self {
        Self {
            status: H2N_ERROR,
            message: message.into(),
        }
    }
}

/// The message of a caught panic.
pub(crate) fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_owned()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "(non-string panic payload)".to_owned()
    }
}

/// Copies `message` into a host-owned buffer (truncating) and records its full length.
///
/// # Safety
/// `out` is null or points to a valid `H2nBuffer` whose `data` has `capacity` writable bytes.
unsafe fn write_buffer(out: *mut H2nBuffer, message: &str) {
    // SAFETY: the caller guarantees `out` is null or valid for writes.
    let Some(out) = (unsafe { out.as_mut() }) else {
        return;
    };
    let n = message.len().min(out.capacity);
    if n > 0 && !out.data.is_null() {
        // SAFETY: `data` has `capacity >= n` writable bytes per the caller's contract and cannot
        // overlap a message owned by this plugin.
        unsafe { std::ptr::copy_nonoverlapping(message.as_ptr(), out.data, n) };
    }
    out.len = message.len();
}

/// A shared slice from an ABI pointer + length; null is allowed only for length 0.
///
/// # Safety
/// When non-null, `ptr` must point to `len` initialised `T` valid for `'a`.
unsafe fn slice<'a, T>(ptr: *const T, len: usize, what: &str) -> Result<&'a [T], Fail> {
    if len == 0 {
        return Ok(&[]);
    }
    if ptr.is_null() {
        return Err(Fail::invalid(format!(
            "{what} is null but its length is {len}"
        )));
    }
    if !ptr.is_aligned() {
        return Err(Fail::invalid(format!("{what} is not aligned")));
    }
    // SAFETY: non-null, aligned, and `len` valid elements per the caller's contract.
    Ok(unsafe { std::slice::from_raw_parts(ptr, len) })
}

/// A mutable slice from an ABI pointer + length; null is allowed only for length 0.
///
/// # Safety
/// When non-null, `ptr` must point to `len` initialised `T` valid for writes for `'a` and not
/// aliased by any other slice in use.
unsafe fn slice_mut<'a, T>(ptr: *mut T, len: usize, what: &str) -> Result<&'a mut [T], Fail> {
    if len == 0 {
        return Ok(&mut []);
    }
    if ptr.is_null() {
        return Err(Fail::invalid(format!(
            "{what} is null but its length is {len}"
        )));
    }
    if !ptr.is_aligned() {
        return Err(Fail::invalid(format!("{what} is not aligned")));
    }
    // SAFETY: non-null, aligned, valid and unaliased per the caller's contract.
    Ok(unsafe { std::slice::from_raw_parts_mut(ptr, len) })
}

/// A reference from a non-null, aligned ABI pointer.
///
/// # Safety
/// When non-null, `ptr` must point to a valid `T` for `'a`.
unsafe fn reference<'a, T>(ptr: *const T, what: &str) -> Result<&'a T, Fail> {
    if ptr.is_null() {
        return Err(Fail::invalid(format!("{what} is null")));
    }
    if !ptr.is_aligned() {
        return Err(Fail::invalid(format!("{what} is not aligned")));
    }
    // SAFETY: non-null, aligned and valid per the caller's contract.
    Ok(unsafe { &*ptr })
}

/// A non-null output pointer. Like every output, it must be valid and aligned for writes for
/// the duration of the call (the host's side of the contract); only null is checked.
fn output<T>(ptr: *mut T, what: &str) -> Result<NonNull<T>, Fail> {
    NonNull::new(ptr).ok_or_else(|| Fail::invalid(format!("{what} is null")))
}

/// Rebuilds the host's agents (copying their histories).
///
/// # Safety
/// `ptr` must point to `count` valid `H2nAgent`s whose `history` pointers are valid.
unsafe fn agents_from_abi(ptr: *const H2nAgent, count: usize) -> Result<Vec<AgentState>, Fail> {
    // SAFETY: forwarded contract.
    let raw = unsafe { slice(ptr, count, "agents") }?;
    let mut out = Vec::with_capacity(raw.len());
    for a in raw {
        let n = a
            .history_len
            .checked_mul(2)
            .ok_or_else(|| Fail::invalid("history too long"))?;
        // SAFETY: forwarded contract: `history` holds `2·history_len` doubles.
        let flat = unsafe { slice(a.history, n, "agent history") }?;
        out.push(AgentState {
            id: a.id,
            position: a.position,
            velocity: a.velocity,
            radius: a.radius,
            history: flat.chunks_exact(2).map(|p| [p[0], p[1]]).collect(),
        });
    }
    Ok(out)
}

/// Rebuilds the host's static obstacles (ABI version 2).
///
/// # Safety
/// `ptr` must point to `count` valid `H2nObstacle`s whose polygon `vertices` are valid.
pub(crate) unsafe fn obstacles_from_abi(
    ptr: *const H2nObstacle,
    count: usize,
) -> Result<Vec<Obstacle>, Fail> {
    // SAFETY: forwarded contract.
    let raw = unsafe { slice(ptr, count, "obstacles") }?;
    let mut out = Vec::with_capacity(raw.len());
    for (i, o) in raw.iter().enumerate() {
        out.push(match o.kind {
            H2N_OBSTACLE_CIRCLE => Obstacle::Circle {
                center: [o.x0, o.y0],
                radius: o.radius,
            },
            H2N_OBSTACLE_SEGMENT => Obstacle::Segment {
                a: [o.x0, o.y0],
                b: [o.x1, o.y1],
            },
            H2N_OBSTACLE_POLYGON => {
                let n = o
                    .vertex_count
                    .checked_mul(2)
                    .ok_or_else(|| Fail::invalid(format!("obstacles[{i}]: too many vertices")))?;
                // SAFETY: forwarded contract: `vertices` holds `2·vertex_count` doubles.
                let flat = unsafe { slice(o.vertices, n, "polygon vertices") }?;
                Obstacle::Polygon {
                    vertices: flat.chunks_exact(2).map(|p| [p[0], p[1]]).collect(),
                }
            }
            k => return Err(Fail::invalid(format!("obstacles[{i}]: unknown kind {k}"))),
        });
    }
    Ok(out)
}

/// Rebuilds the host's occupancy grid (ABI version 2), `None` for a null pointer.
///
/// # Safety
/// When non-null, `ptr` must point to a valid grid whose `data` holds `width·height` cells.
pub(crate) unsafe fn occupancy_from_abi(
    ptr: *const H2nOccupancyGrid,
) -> Result<Option<OccupancyGrid>, Fail> {
    if ptr.is_null() {
        return Ok(None);
    }
    // SAFETY: non-null: forwarded contract.
    let g = unsafe { reference(ptr, "occupancy grid") }?;
    let n = g
        .width
        .checked_mul(g.height)
        .ok_or_else(|| Fail::invalid("occupancy grid: width·height overflows"))?;
    // SAFETY: forwarded contract.
    let cells = unsafe { slice(g.data, n, "occupancy grid cells") }?;
    let occupied_threshold = i8::try_from(g.occupied_threshold).map_err(|_| {
        Fail::invalid(format!(
            "occupancy grid: occupied_threshold {} is not a cell value",
            g.occupied_threshold
        ))
    })?;
    Ok(Some(OccupancyGrid {
        origin: g.origin.into(),
        resolution: g.resolution,
        width: g.width,
        height: g.height,
        data: cells.to_vec(),
        occupied_threshold,
    }))
}

/// What a plugin instance is on the plugin's side of the boundary.
struct Instance<S> {
    state: S,
    name: Box<str>,
    poisoned: AtomicBool,
    last_error: Mutex<String>,
}

impl<S> Instance<S> {
    fn new(state: S, name: &str) -> Self {
        Self {
            state,
            name: name.into(),
            poisoned: AtomicBool::new(false),
            last_error: Mutex::new(String::new()),
        }
    }

    fn set_error(&self, message: String) {
        *self.last_error.lock().unwrap_or_else(|e| e.into_inner()) = message;
    }
}

/// Runs `body` on the instance behind `instance` with every guard of the ABI.
///
/// # Safety
/// `instance` is null or was returned by a `create` shim for `Instance<S>` and not destroyed.
unsafe fn call<S>(instance: *mut c_void, body: impl FnOnce(&S) -> Result<(), Fail>) -> H2nStatus {
    if instance.is_null() {
        return H2N_INVALID_ARGUMENT;
    }
    // SAFETY: per the caller's contract `instance` is a live `Instance<S>` (boxed by `create`);
    // shims only ever take shared references to it.
    let inst = unsafe { &*(instance as *const Instance<S>) };
    if inst.poisoned.load(Ordering::Acquire) {
        // last_error still holds the panic that poisoned the instance.
        return H2N_POISONED;
    }
    match catch_unwind(AssertUnwindSafe(|| body(&inst.state))) {
        Ok(Ok(())) => H2N_OK,
        Ok(Err(fail)) => {
            inst.set_error(fail.message);
            fail.status
        }
        Err(payload) => {
            inst.poisoned.store(true, Ordering::Release);
            inst.set_error(format!("panicked: {}", panic_message(payload.as_ref())));
            H2N_PANIC
        }
    }
}

/// `destroy` of every vtable.
///
/// # Safety
/// `instance` is null or a live `Instance<S>` from `create`; it is not used afterwards.
unsafe extern "C" fn destroy<S>(instance: *mut c_void) {
    if instance.is_null() {
        return;
    }
    // SAFETY: `instance` came from `Box::into_raw` in `create` and is destroyed exactly once.
    let boxed = unsafe { Box::from_raw(instance as *mut Instance<S>) };
    // A panicking destructor must not unwind into the host; its memory is then leaked.
    let _ = catch_unwind(AssertUnwindSafe(move || drop(boxed)));
}

/// `last_error` of every vtable.
///
/// # Safety
/// As [`call`], and `out` as [`write_buffer`].
unsafe extern "C" fn last_error<S>(instance: *mut c_void, out: *mut H2nBuffer) {
    if instance.is_null() {
        // SAFETY: forwarded contract.
        unsafe { write_buffer(out, "instance is null") };
        return;
    }
    // SAFETY: a live `Instance<S>`; only shared access.
    let inst = unsafe { &*(instance as *const Instance<S>) };
    let message = inst.last_error.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: forwarded contract.
    unsafe { write_buffer(out, &message) };
}

/// `name` of every vtable.
///
/// # Safety
/// As [`call`]. The returned view lives as long as the instance.
unsafe extern "C" fn name<S>(instance: *mut c_void) -> H2nStr {
    if instance.is_null() {
        return H2nStr::EMPTY;
    }
    // SAFETY: a live `Instance<S>`; its boxed name is never modified.
    let inst = unsafe { &*(instance as *const Instance<S>) };
    H2nStr::new(&inst.name)
}

/// Common part of every `create` shim: checks the arguments, runs the constructor under
/// `catch_unwind` and boxes the instance.
///
/// # Safety
/// `args` is null or a valid `H2nCreateArgs` (with `config` readable); `out` is null or valid
/// for writes; `error` as [`write_buffer`].
unsafe fn create<S: 'static>(
    kind: u32,
    args: *const H2nCreateArgs,
    out: *mut H2nObject,
    error: *mut H2nBuffer,
    vtable: *const c_void,
    build: impl FnOnce(&PluginInit<'_>) -> Result<(S, String), InitError>,
) -> H2nStatus {
    let result = catch_unwind(AssertUnwindSafe(|| -> Result<*mut c_void, Fail> {
        // SAFETY: forwarded contract.
        let args = unsafe { reference(args, "create args") }?;
        if (args.struct_size as usize) < std::mem::size_of::<H2nCreateArgs>() {
            return Err(Fail::invalid(format!(
                "create args are {} bytes, this plugin needs {}",
                args.struct_size,
                std::mem::size_of::<H2nCreateArgs>()
            )));
        }
        if args.kind != kind {
            return Err(Fail::invalid(format!(
                "factory of kind {kind} called for kind {}",
                args.kind
            )));
        }
        if out.is_null() {
            return Err(Fail::invalid("output object is null"));
        }
        // SAFETY: forwarded contract: `config` is readable for the duration of the call.
        let config = unsafe { args.config.as_str() }
            .map_err(|e| Fail::invalid(format!("config is not UTF-8: {e}")))?;
        let robot = (args.has_robot != 0).then(|| RobotContext {
            limits: (&args.limits).into(),
            gains: (&args.gains).into(),
            footprint_radius: args.footprint_radius,
        });
        let init = PluginInit::new(config, robot);
        let (state, name) = build(&init).map_err(|e| Fail {
            status: if e.is_config() { H2N_CONFIG } else { H2N_ERROR },
            message: e.to_string(),
        })?;
        Ok(Box::into_raw(Box::new(Instance::new(state, &name))).cast())
    }));
    let fail = match result {
        Ok(Ok(instance)) => {
            // SAFETY: `out` was checked non-null above and is valid for writes per the contract.
            unsafe { out.write(H2nObject { instance, vtable }) };
            return H2N_OK;
        }
        Ok(Err(fail)) => fail,
        Err(payload) => Fail {
            status: H2N_PANIC,
            message: format!("factory panicked: {}", panic_message(payload.as_ref())),
        },
    };
    // SAFETY: forwarded contract.
    unsafe { write_buffer(error, &fail.message) };
    fail.status
}

/// Lookup by kind and name in a factory table (the entry's `find_factory`).
///
/// # Safety
/// `name` must be readable.
pub unsafe fn find_factory(
    factories: &'static [H2nFactory],
    kind: u32,
    name: H2nStr,
) -> *const H2nFactory {
    // SAFETY: forwarded contract.
    let Ok(name) = (unsafe { name.as_str() }) else {
        return std::ptr::null();
    };
    factories
        .iter()
        .find(|f| {
            // SAFETY: factory names are static string literals.
            f.kind == kind && unsafe { f.name.as_str() }.is_ok_and(|n| n == name)
        })
        .map_or(std::ptr::null(), |f| f as *const H2nFactory)
}
