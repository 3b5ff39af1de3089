//! The plugin side of the ABI: generic `extern "C"` shims around the core traits, used by the
//! expansion of [`export_plugin!`](crate::export_plugin). Authors never call these directly.
//!
//! Every shim checks its pointers and lengths, runs the author's code inside `catch_unwind`,
//! turns errors into status codes plus a per-instance last-error message, and marks the
//! instance unusable (`H2N_POISONED` from then on) when the code panicked.

use crate::abi::*;
use crate::init::{InitError, PluginInit, RobotContext};
use crate::validate::EvaluateBuffers;
use human2nav_core::constraint::{ConstraintContext, ConstraintTerm, TrajBatch};
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::obstacle::{Obstacle, OccupancyGrid};
use human2nav_core::{AgentState, Observation, Plan, PlanError, PlanInfo, Planner, Pose2};
use std::ffi::c_void;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::ptr::NonNull;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

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

// ---------------------------------------------------------------------------------------------
// Constraint terms

unsafe extern "C" fn constraint_evaluate<T: ConstraintTerm + 'static>(
    instance: *mut c_void,
    batch: *const H2nTrajBatch,
    ctx: *const H2nConstraintContext,
    cost: H2nF64Out,
    grad: H2nF64Out,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |term| {
            let batch = reference(batch, "batch")?;
            let ctx = reference(ctx, "context")?;
            if (ctx.struct_size as usize) < std::mem::size_of::<H2nConstraintContext>() {
                return Err(Fail::invalid("constraint context is from an older host"));
            }
            if batch.dim != 3 {
                return Err(Fail::invalid(format!(
                    "pose dimension is {}, expected 3",
                    batch.dim
                )));
            }
            EvaluateBuffers {
                batch: batch.batch,
                horizon: batch.horizon,
                values: batch.len,
                cost: cost.len,
                grad: grad.len,
            }
            .check()
            .map_err(Fail::invalid)?;
            let data = slice(batch.data, batch.len, "batch data")?;
            let cost = slice_mut(cost.data, cost.len, "cost")?;
            let grad = slice_mut(grad.data, grad.len, "gradient")?;
            let agents = agents_from_abi(ctx.agents, ctx.agent_count)?;
            let limits = (&ctx.limits).into();
            let core_ctx = ConstraintContext {
                dt: ctx.dt,
                limits: &limits,
                initial_velocity: ctx.initial_velocity.into(),
                agents: &agents,
                scene: Default::default(),
            };
            let view = TrajBatch::new(data, batch.batch, batch.horizon)
                .map_err(|e| Fail::invalid(e.to_string()))?;
            term.evaluate(view, &core_ctx, cost, grad)
                .map_err(|e| Fail::error(e.to_string()))
        })
    }
}

/// Creates a constraint term through `ctor` (used by `export_plugin!`).
///
/// # Safety
/// The arguments of [`H2nFactory::create`], as passed by a host honouring the ABI.
pub unsafe fn create_constraint<T, E>(
    args: *const H2nCreateArgs,
    out: *mut H2nObject,
    error: *mut H2nBuffer,
    ctor: fn(&PluginInit<'_>) -> Result<T, E>,
) -> H2nStatus
where
    T: ConstraintTerm + 'static,
    E: Into<InitError>,
{
    let vtable: &'static H2nConstraintVTable = const {
        &H2nConstraintVTable {
            struct_size: std::mem::size_of::<H2nConstraintVTable>() as u32,
            reserved: 0,
            destroy: Some(destroy::<T>),
            last_error: Some(last_error::<T>),
            name: Some(name::<T>),
            evaluate: Some(constraint_evaluate::<T>),
        }
    };
    // SAFETY: forwarded contract.
    unsafe {
        create::<T>(
            H2N_KIND_CONSTRAINT,
            args,
            out,
            error,
            (vtable as *const H2nConstraintVTable).cast(),
            |init| {
                let term = ctor(init).map_err(Into::into)?;
                let name = term.name().to_owned();
                Ok((term, name))
            },
        )
    }
}

// ---------------------------------------------------------------------------------------------
// Embodiments

unsafe extern "C" fn embodiment_holonomic<T: Embodiment + 'static>(
    instance: *mut c_void,
    out: *mut u32,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let out = output(out, "output")?;
            out.write(u32::from(e.holonomic()));
            Ok(())
        })
    }
}

unsafe extern "C" fn embodiment_saturate<T: Embodiment + 'static>(
    instance: *mut c_void,
    state: *const H2nRobotState,
    cmd: *const H2nTwist,
    dt: f64,
    out: *mut H2nTwist,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let state: RobotState = reference(state, "state")?.into();
            let cmd = *reference(cmd, "command")?;
            let out = output(out, "output")?;
            out.write(e.saturate(&state, cmd.into(), dt).into());
            Ok(())
        })
    }
}

unsafe extern "C" fn embodiment_step<T: Embodiment + 'static>(
    instance: *mut c_void,
    state: *const H2nRobotState,
    cmd: *const H2nTwist,
    dt: f64,
    out: *mut H2nRobotState,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let state: RobotState = reference(state, "state")?.into();
            let cmd = *reference(cmd, "command")?;
            let out = output(out, "output")?;
            out.write((&e.step(&state, cmd.into(), dt)).into());
            Ok(())
        })
    }
}

unsafe extern "C" fn embodiment_track<T: Embodiment + 'static>(
    instance: *mut c_void,
    state: *const H2nRobotState,
    plan: *const H2nPlanView,
    t: f64,
    out: *mut H2nTwist,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let state: RobotState = reference(state, "state")?.into();
            let view = reference(plan, "plan")?;
            let poses = slice(view.poses, view.pose_count, "plan poses")?;
            let plan = Plan {
                t0: view.t0,
                dt: view.dt,
                poses: poses.iter().map(|&p| Pose2::from(p)).collect(),
                info: PlanInfo::default(),
            };
            let out = output(out, "output")?;
            out.write(e.track(&state, &plan, t).into());
            Ok(())
        })
    }
}

unsafe extern "C" fn embodiment_coupled_limit<T: Embodiment + 'static>(
    instance: *mut c_void,
    out: *mut H2nCoupledLimit,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let out = output(out, "output")?;
            out.write(
                e.coupled_limit()
                    .as_ref()
                    .map(Into::into)
                    .unwrap_or_default(),
            );
            Ok(())
        })
    }
}

/// Creates an embodiment through `ctor` (used by `export_plugin!`).
///
/// # Safety
/// The arguments of [`H2nFactory::create`], as passed by a host honouring the ABI.
pub unsafe fn create_embodiment<T, E>(
    args: *const H2nCreateArgs,
    out: *mut H2nObject,
    error: *mut H2nBuffer,
    ctor: fn(&PluginInit<'_>) -> Result<T, E>,
) -> H2nStatus
where
    T: Embodiment + 'static,
    E: Into<InitError>,
{
    let vtable: &'static H2nEmbodimentVTable = const {
        &H2nEmbodimentVTable {
            struct_size: std::mem::size_of::<H2nEmbodimentVTable>() as u32,
            reserved: 0,
            destroy: Some(destroy::<T>),
            last_error: Some(last_error::<T>),
            name: Some(name::<T>),
            holonomic: Some(embodiment_holonomic::<T>),
            saturate: Some(embodiment_saturate::<T>),
            step: Some(embodiment_step::<T>),
            track: Some(embodiment_track::<T>),
            coupled_limit: Some(embodiment_coupled_limit::<T>),
        }
    };
    // SAFETY: forwarded contract.
    unsafe {
        create::<T>(
            H2N_KIND_EMBODIMENT,
            args,
            out,
            error,
            (vtable as *const H2nEmbodimentVTable).cast(),
            |init| {
                let e = ctor(init).map_err(Into::into)?;
                let name = e.name().to_owned();
                Ok((e, name))
            },
        )
    }
}

// ---------------------------------------------------------------------------------------------
// Planners

/// A planner and the plan it produced last (kept for `last_plan`). The host calls a planner
/// from one thread at a time; the mutex makes that a checked invariant instead of an assumption.
struct PlannerState<T> {
    planner: T,
    last_plan: Option<Plan>,
}

/// Writes `plan` into the host's buffer, or only its length when the buffer is too small.
///
/// # Safety
/// `out.poses` has `out.capacity` writable poses; `out.note` as [`write_buffer`].
unsafe fn write_plan(plan: &Plan, out: &mut H2nPlanOut) -> Result<(), Fail> {
    out.t0 = plan.t0;
    out.dt = plan.dt;
    out.len = plan.poses.len();
    out.fallback = u32::from(plan.info.fallback);
    // SAFETY: forwarded contract (the note buffer is host-owned).
    unsafe { write_buffer(&mut out.note, &plan.info.notes.join("; ")) };
    if plan.poses.len() > out.capacity {
        return Err(Fail {
            status: H2N_BUFFER_TOO_SMALL,
            message: format!(
                "plan has {} poses, buffer holds {}",
                plan.poses.len(),
                out.capacity
            ),
        });
    }
    // SAFETY: forwarded contract.
    let dst = unsafe { slice_mut(out.poses, plan.poses.len(), "plan poses") }?;
    for (d, p) in dst.iter_mut().zip(&plan.poses) {
        *d = (*p).into();
    }
    Ok(())
}

fn plan_fail(e: PlanError) -> Fail {
    match e {
        PlanError::InvalidObservation(m) => Fail::invalid(m),
        PlanError::Failed { message, .. } | PlanError::Unusable { message, .. } => {
            Fail::error(message)
        }
        // PlanError may grow variants; they all cross as ordinary errors.
        #[allow(unreachable_patterns)]
        other => Fail::error(other.to_string()),
    }
}

unsafe extern "C" fn planner_reset<T: Planner + 'static>(instance: *mut c_void) -> H2nStatus {
    // SAFETY: `call` checks `instance`; the host upholds the rest of the contract.
    unsafe {
        call::<Mutex<PlannerState<T>>>(instance, |state| {
            let mut state = state
                .lock()
                .map_err(|_| Fail::error("planner state is poisoned"))?;
            state.planner.reset();
            state.last_plan = None;
            Ok(())
        })
    }
}

unsafe extern "C" fn planner_plan<T: Planner + 'static>(
    instance: *mut c_void,
    obs: *const H2nObservation,
    out: *mut H2nPlanOut,
) -> H2nStatus {
    // SAFETY: `call` checks `instance`; the host upholds the rest of the contract.
    unsafe {
        call::<Mutex<PlannerState<T>>>(instance, |state| {
            let raw = reference(obs, "observation")?;
            if (raw.struct_size as usize) < std::mem::size_of::<H2nObservation>() {
                return Err(Fail::invalid("observation is from an older host"));
            }
            let mut out = output(out, "plan output")?;
            let out = out.as_mut();
            let obs = Observation {
                time: raw.time,
                ego: raw.ego.into(),
                ego_velocity: raw.ego_velocity.into(),
                goal: raw.goal,
                agents: agents_from_abi(raw.agents, raw.agent_count)?,
                obstacles: obstacles_from_abi(raw.obstacles, raw.obstacle_count)?,
                occupancy: occupancy_from_abi(raw.occupancy)?,
                ..Default::default()
            };
            let mut state = state
                .lock()
                .map_err(|_| Fail::error("planner state is poisoned"))?;
            let plan = state.planner.plan(&obs).map_err(plan_fail)?;
            let written = write_plan(&plan, out);
            state.last_plan = Some(plan);
            written
        })
    }
}

unsafe extern "C" fn planner_last_plan<T: Planner + 'static>(
    instance: *mut c_void,
    out: *mut H2nPlanOut,
) -> H2nStatus {
    // SAFETY: `call` checks `instance`; the host upholds the rest of the contract.
    unsafe {
        call::<Mutex<PlannerState<T>>>(instance, |state| {
            let mut out = output(out, "plan output")?;
            let state = state
                .lock()
                .map_err(|_| Fail::error("planner state is poisoned"))?;
            let plan = state
                .last_plan
                .as_ref()
                .ok_or_else(|| Fail::error("no plan yet"))?;
            write_plan(plan, out.as_mut())
        })
    }
}

/// Creates a planner through `ctor` (used by `export_plugin!`).
///
/// # Safety
/// The arguments of [`H2nFactory::create`], as passed by a host honouring the ABI.
pub unsafe fn create_planner<T, E>(
    args: *const H2nCreateArgs,
    out: *mut H2nObject,
    error: *mut H2nBuffer,
    ctor: fn(&PluginInit<'_>) -> Result<T, E>,
) -> H2nStatus
where
    T: Planner + 'static,
    E: Into<InitError>,
{
    type S<T> = Mutex<PlannerState<T>>;
    let vtable: &'static H2nPlannerVTable = const {
        &H2nPlannerVTable {
            struct_size: std::mem::size_of::<H2nPlannerVTable>() as u32,
            reserved: 0,
            destroy: Some(destroy::<S<T>>),
            last_error: Some(last_error::<S<T>>),
            name: Some(name::<S<T>>),
            reset: Some(planner_reset::<T>),
            plan: Some(planner_plan::<T>),
            last_plan: Some(planner_last_plan::<T>),
        }
    };
    // SAFETY: forwarded contract.
    unsafe {
        create::<S<T>>(
            H2N_KIND_PLANNER,
            args,
            out,
            error,
            (vtable as *const H2nPlannerVTable).cast(),
            |init| {
                let planner = ctor(init).map_err(Into::into)?;
                let name = planner.name().to_owned();
                Ok((
                    Mutex::new(PlannerState {
                        planner,
                        last_plan: None,
                    }),
                    name,
                ))
            },
        )
    }
}

#[cfg(test)]
mod tests {
    //! The shims called directly with the pointers a faulty host could pass: every bad pointer
    //! or length must come back as a status and a message, never as undefined behaviour.

    use super::*;
    use human2nav_core::constraint::{ConstraintContext, ConstraintError, TrajBatch};

    /// Cost `Σ x` per trajectory, gradient 1 on every `x`.
    struct SumX;

    impl ConstraintTerm for SumX {
        fn name(&self) -> &str {
            "sum_x"
        }

        fn evaluate(
            &self,
            batch: TrajBatch<'_>,
            _ctx: &ConstraintContext<'_>,
            cost: &mut [f64],
            grad: &mut [f64],
        ) -> Result<(), ConstraintError> {
            for b in 0..batch.batch {
                for (k, p) in batch.trajectory(b).chunks_exact(3).enumerate() {
                    cost[b] += p[0];
                    grad[(b * batch.horizon + k) * 3] += 1.0;
                }
            }
            Ok(())
        }
    }

    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct SumXConfig {
        #[serde(default)]
        panic: bool,
    }

    fn ctor(init: &PluginInit<'_>) -> Result<SumX, InitError> {
        let c: SumXConfig = init.config()?;
        if c.panic {
            panic!("constructor panicked on request");
        }
        Ok(SumX)
    }

    fn args(config: &str) -> H2nCreateArgs {
        H2nCreateArgs {
            struct_size: std::mem::size_of::<H2nCreateArgs>() as u32,
            kind: H2N_KIND_CONSTRAINT,
            config: H2nStr::new(config),
            has_robot: 0,
            reserved: 0,
            limits: H2nLimits::default(),
            gains: H2nGains::default(),
            footprint_radius: 0.0,
        }
    }

    fn create(args: *const H2nCreateArgs) -> (H2nStatus, H2nObject, String) {
        let mut out = H2nObject {
            instance: std::ptr::null_mut(),
            vtable: std::ptr::null(),
        };
        let mut buf = [0u8; 256];
        let mut err = H2nBuffer {
            data: buf.as_mut_ptr(),
            capacity: buf.len(),
            len: 0,
        };
        // SAFETY: valid (or deliberately null) pointers for the duration of the call.
        let status = unsafe { create_constraint(args, &mut out, &mut err, ctor) };
        let msg = String::from_utf8_lossy(&buf[..err.len.min(buf.len())]).into_owned();
        (status, out, msg)
    }

    fn vtable(obj: &H2nObject) -> &'static H2nConstraintVTable {
        // SAFETY: `create_constraint` returns a constraint vtable in static memory.
        unsafe { &*obj.vtable.cast::<H2nConstraintVTable>() }
    }

    fn last_error_of(obj: &H2nObject) -> String {
        let mut buf = [0u8; 256];
        let mut out = H2nBuffer {
            data: buf.as_mut_ptr(),
            capacity: buf.len(),
            len: 0,
        };
        // SAFETY: live instance, host-owned buffer.
        unsafe { (vtable(obj).last_error.expect("last_error"))(obj.instance, &mut out) };
        String::from_utf8_lossy(&buf[..out.len.min(buf.len())]).into_owned()
    }

    fn context() -> H2nConstraintContext {
        H2nConstraintContext {
            struct_size: std::mem::size_of::<H2nConstraintContext>() as u32,
            reserved: 0,
            dt: 0.1,
            limits: H2nLimits::default(),
            initial_velocity: H2nTwist::default(),
            agents: std::ptr::null(),
            agent_count: 0,
        }
    }

    #[test]
    fn create_checks_its_arguments() {
        let (status, _, msg) = create(std::ptr::null());
        assert_eq!(status, H2N_INVALID_ARGUMENT);
        assert!(msg.contains("null"), "{msg}");
        let mut small = args("");
        small.struct_size = 8;
        assert_eq!(create(&small).0, H2N_INVALID_ARGUMENT);
        let mut wrong_kind = args("");
        wrong_kind.kind = H2N_KIND_PLANNER;
        assert_eq!(create(&wrong_kind).0, H2N_INVALID_ARGUMENT);
        let bad_utf8 = [0xff_u8, 0xfe];
        let mut not_text = args("");
        not_text.config = H2nStr {
            ptr: bad_utf8.as_ptr(),
            len: 2,
        };
        assert_eq!(create(&not_text).0, H2N_INVALID_ARGUMENT);
        let (status, _, msg) = create(&args("speed = 1"));
        assert_eq!(status, H2N_CONFIG);
        assert!(msg.contains("speed"), "{msg}");
        let (status, _, msg) = create(&args("panic = true"));
        assert_eq!(status, H2N_PANIC);
        assert!(msg.contains("constructor panicked on request"), "{msg}");
    }

    #[test]
    fn error_messages_are_truncated_to_the_host_buffer_with_the_full_length_reported() {
        let mut out = H2nObject {
            instance: std::ptr::null_mut(),
            vtable: std::ptr::null(),
        };
        let mut buf = [0u8; 5];
        let mut err = H2nBuffer {
            data: buf.as_mut_ptr(),
            capacity: buf.len(),
            len: 0,
        };
        let a = args("speed = 1");
        // SAFETY: valid pointers for the call.
        let status = unsafe { create_constraint(&a, &mut out, &mut err, ctor) };
        assert_eq!(status, H2N_CONFIG);
        assert!(err.len > 5);
        assert_eq!(&buf, b"confi");
        // A null buffer is simply not written.
        // SAFETY: as above, with a null error buffer (allowed).
        let status = unsafe { create_constraint(&a, &mut out, std::ptr::null_mut(), ctor) };
        assert_eq!(status, H2N_CONFIG);
    }

    /// A `sum_x` instance created through the shim and called through its vtable; destroyed
    /// (and a null instance destroyed, a no-op) when dropped.
    struct SumXInstance {
        obj: H2nObject,
        vt: &'static H2nConstraintVTable,
        data: [f64; 6],
    }

    impl SumXInstance {
        fn new() -> Self {
            let (status, obj, _) = create(&args(""));
            assert_eq!(status, H2N_OK);
            let vt = vtable(&obj);
            Self {
                obj,
                vt,
                data: [1.0, 0.0, 0.0, 2.0, 0.0, 0.0],
            }
        }

        /// One trajectory of two poses over `self.data`.
        fn good(&self) -> H2nTrajBatch {
            H2nTrajBatch {
                data: self.data.as_ptr(),
                len: 6,
                batch: 1,
                horizon: 2,
                dim: 3,
            }
        }

        fn eval(
            &self,
            batch: *const H2nTrajBatch,
            ctx: *const H2nConstraintContext,
            cost: &mut [f64],
            cost_len: usize,
            grad: &mut [f64],
        ) -> H2nStatus {
            let c = H2nF64Out {
                data: cost.as_mut_ptr(),
                len: cost_len,
            };
            let g = H2nF64Out {
                data: grad.as_mut_ptr(),
                len: grad.len(),
            };
            // SAFETY: live instance; pointers valid or deliberately null.
            unsafe { (self.vt.evaluate.expect("evaluate"))(self.obj.instance, batch, ctx, c, g) }
        }

        /// A good call still succeeds: the refused calls before did not poison the instance.
        fn assert_still_usable(&self) {
            let (mut cost, mut grad) = ([0.0], [0.0; 6]);
            assert_eq!(
                self.eval(&self.good(), &context(), &mut cost, 1, &mut grad),
                H2N_OK
            );
            assert_eq!((cost, grad), ([3.0], [1.0, 0.0, 0.0, 1.0, 0.0, 0.0]));
        }
    }

    impl Drop for SumXInstance {
        fn drop(&mut self) {
            // SAFETY: destroyed exactly once; null is a no-op.
            unsafe {
                (self.vt.destroy.expect("destroy"))(self.obj.instance);
                (self.vt.destroy.expect("destroy"))(std::ptr::null_mut());
            }
        }
    }

    #[test]
    fn evaluate_computes_through_the_shim() {
        let sum = SumXInstance::new();
        // SAFETY: live instance; the returned view lives as long as it.
        assert_eq!(
            unsafe { (sum.vt.name.expect("name"))(sum.obj.instance).as_str() },
            Ok("sum_x")
        );
        sum.assert_still_usable();
    }

    #[test]
    fn evaluate_checks_the_batch() {
        let sum = SumXInstance::new();
        let good = sum.good();
        let ctx = context();
        let (mut cost, mut grad) = ([0.0], [0.0; 6]);
        let mut eval = |batch: *const H2nTrajBatch| sum.eval(batch, &ctx, &mut cost, 1, &mut grad);
        assert_eq!(eval(std::ptr::null()), H2N_INVALID_ARGUMENT);
        assert!(last_error_of(&sum.obj).contains("batch is null"));
        assert_eq!(eval(&H2nTrajBatch { dim: 2, ..good }), H2N_INVALID_ARGUMENT);
        assert_eq!(eval(&H2nTrajBatch { len: 5, ..good }), H2N_INVALID_ARGUMENT);
        assert_eq!(
            last_error_of(&sum.obj),
            "5 values cannot be 1 trajectories × 2 poses × 3"
        );
        let overflow = H2nTrajBatch {
            batch: usize::MAX,
            horizon: 2,
            ..good
        };
        assert_eq!(eval(&overflow), H2N_INVALID_ARGUMENT);
        let null_data = H2nTrajBatch {
            data: std::ptr::null(),
            ..good
        };
        assert_eq!(eval(&null_data), H2N_INVALID_ARGUMENT);
        assert!(
            last_error_of(&sum.obj).contains("batch data is null"),
            "{}",
            last_error_of(&sum.obj)
        );
        sum.assert_still_usable();
    }

    #[test]
    fn evaluate_checks_the_outputs_the_context_and_the_instance() {
        let sum = SumXInstance::new();
        let good = sum.good();
        let ctx = context();
        let (mut cost, mut grad) = ([0.0], [0.0; 6]);
        assert_eq!(
            sum.eval(&good, std::ptr::null(), &mut cost, 1, &mut grad),
            H2N_INVALID_ARGUMENT
        );
        let mut cost2 = [0.0; 2];
        assert_eq!(
            sum.eval(&good, &ctx, &mut cost2, 2, &mut grad),
            H2N_INVALID_ARGUMENT
        );
        assert_eq!(
            last_error_of(&sum.obj),
            "cost has 2 entries for 1 trajectories"
        );
        let mut grad5 = [0.0; 5];
        assert_eq!(
            sum.eval(&good, &ctx, &mut cost, 1, &mut grad5),
            H2N_INVALID_ARGUMENT
        );
        assert_eq!(
            last_error_of(&sum.obj),
            "gradient has 5 entries, the batch 6"
        );
        let old_ctx = H2nConstraintContext {
            struct_size: 16,
            ..context()
        };
        assert_eq!(
            sum.eval(&good, &old_ctx, &mut cost, 1, &mut grad),
            H2N_INVALID_ARGUMENT
        );
        let null_agents = H2nConstraintContext {
            agent_count: 3,
            ..context()
        };
        assert_eq!(
            sum.eval(&good, &null_agents, &mut cost, 1, &mut grad),
            H2N_INVALID_ARGUMENT
        );
        sum.assert_still_usable();
        // A null instance is refused too.
        let c = H2nF64Out {
            data: cost.as_mut_ptr(),
            len: 1,
        };
        let g = H2nF64Out {
            data: grad.as_mut_ptr(),
            len: 6,
        };
        // SAFETY: a null instance is part of what the shim must survive.
        let status = unsafe {
            (sum.vt.evaluate.expect("evaluate"))(std::ptr::null_mut(), &good, &ctx, c, g)
        };
        assert_eq!(status, H2N_INVALID_ARGUMENT);
    }

    /// An embodiment and a planner whose methods must not run: a call panics.
    struct Untouchable;

    impl Embodiment for Untouchable {
        fn name(&self) -> &str {
            "untouchable"
        }

        fn holonomic(&self) -> bool {
            panic!("holonomic ran")
        }

        fn saturate(
            &self,
            _: &RobotState,
            _: human2nav_core::Twist2,
            _: f64,
        ) -> human2nav_core::Twist2 {
            panic!("saturate ran")
        }

        fn step(&self, _: &RobotState, _: human2nav_core::Twist2, _: f64) -> RobotState {
            panic!("step ran")
        }

        fn track(&self, _: &RobotState, _: &Plan, _: f64) -> human2nav_core::Twist2 {
            panic!("track ran")
        }
    }

    impl Planner for Untouchable {
        fn name(&self) -> &str {
            "untouchable"
        }

        fn plan(&mut self, _: &Observation) -> Result<Plan, PlanError> {
            panic!("plan ran")
        }
    }

    fn untouchable(_: &PluginInit<'_>) -> Result<Untouchable, InitError> {
        Ok(Untouchable)
    }

    fn message(last_error: Option<LastErrorFn>, instance: *mut c_void) -> String {
        let mut buf = [0u8; 256];
        let mut out = H2nBuffer {
            data: buf.as_mut_ptr(),
            capacity: buf.len(),
            len: 0,
        };
        // SAFETY: live instance, host-owned buffer.
        unsafe { (last_error.expect("last_error"))(instance, &mut out) };
        String::from_utf8_lossy(&buf[..out.len.min(buf.len())]).into_owned()
    }

    #[test]
    fn null_outputs_are_refused_before_the_author_code_runs() {
        let create_as = |kind: u32| {
            let mut obj = H2nObject {
                instance: std::ptr::null_mut(),
                vtable: std::ptr::null(),
            };
            let a = H2nCreateArgs { kind, ..args("") };
            // SAFETY: valid pointers for the duration of the call; a null error buffer is allowed.
            let status = unsafe {
                if kind == H2N_KIND_EMBODIMENT {
                    create_embodiment(&a, &mut obj, std::ptr::null_mut(), untouchable)
                } else {
                    create_planner(&a, &mut obj, std::ptr::null_mut(), untouchable)
                }
            };
            assert_eq!(status, H2N_OK);
            obj
        };

        let obj = create_as(H2N_KIND_EMBODIMENT);
        // SAFETY: `create_embodiment` returns an embodiment vtable in static memory.
        let vt = unsafe { &*obj.vtable.cast::<H2nEmbodimentVTable>() };
        let state = H2nRobotState::default();
        let cmd = H2nTwist::default();
        let plan = H2nPlanView {
            t0: 0.0,
            dt: 0.1,
            poses: std::ptr::null(),
            pose_count: 0,
        };
        // SAFETY: live instance; every input valid, every output deliberately null.
        let statuses = unsafe {
            [
                (vt.holonomic.expect("holonomic"))(obj.instance, std::ptr::null_mut()),
                (vt.saturate.expect("saturate"))(
                    obj.instance,
                    &state,
                    &cmd,
                    0.1,
                    std::ptr::null_mut(),
                ),
                (vt.step.expect("step"))(obj.instance, &state, &cmd, 0.1, std::ptr::null_mut()),
                (vt.track.expect("track"))(obj.instance, &state, &plan, 0.0, std::ptr::null_mut()),
                (vt.coupled_limit.expect("coupled_limit"))(obj.instance, std::ptr::null_mut()),
            ]
        };
        assert_eq!(statuses, [H2N_INVALID_ARGUMENT; 5]);
        assert_eq!(message(vt.last_error, obj.instance), "output is null");
        // SAFETY: destroyed exactly once.
        unsafe { (vt.destroy.expect("destroy"))(obj.instance) };

        let obj = create_as(H2N_KIND_PLANNER);
        // SAFETY: `create_planner` returns a planner vtable in static memory.
        let vt = unsafe { &*obj.vtable.cast::<H2nPlannerVTable>() };
        let obs = H2nObservation {
            struct_size: std::mem::size_of::<H2nObservation>() as u32,
            reserved: 0,
            time: 0.0,
            ego: H2nPose::default(),
            ego_velocity: H2nTwist::default(),
            goal: [1.0, 0.0],
            agents: std::ptr::null(),
            agent_count: 0,
            obstacles: std::ptr::null(),
            obstacle_count: 0,
            occupancy: std::ptr::null(),
        };
        // SAFETY: live instance; the observation is valid, the output deliberately null.
        let status = unsafe { (vt.plan.expect("plan"))(obj.instance, &obs, std::ptr::null_mut()) };
        assert_eq!(status, H2N_INVALID_ARGUMENT);
        assert_eq!(message(vt.last_error, obj.instance), "plan output is null");
        // SAFETY: as above.
        let status =
            unsafe { (vt.last_plan.expect("last_plan"))(obj.instance, std::ptr::null_mut()) };
        assert_eq!(status, H2N_INVALID_ARGUMENT);
        assert_eq!(message(vt.last_error, obj.instance), "plan output is null");
        // SAFETY: destroyed exactly once.
        unsafe { (vt.destroy.expect("destroy"))(obj.instance) };
    }

    #[test]
    fn agents_cross_with_their_histories() {
        let history = [[1.0, 2.0], [3.0, 4.0]];
        let agent = H2nAgent {
            id: 5,
            position: [0.5, 0.25],
            velocity: [0.0, 1.0],
            radius: 0.3,
            history: history.as_ptr().cast(),
            history_len: 2,
        };
        // SAFETY: one valid agent with two history points.
        let agents = unsafe { agents_from_abi(&agent, 1) }
            .ok()
            .unwrap_or_default();
        assert_eq!(agents.len(), 1);
        assert_eq!(agents[0].history, vec![[1.0, 2.0], [3.0, 4.0]]);
        assert_eq!((agents[0].id, agents[0].radius), (5, 0.3));
        let broken = H2nAgent {
            history: std::ptr::null(),
            ..agent
        };
        // SAFETY: the null history with a non-zero length must be refused, not read.
        assert!(unsafe { agents_from_abi(&broken, 1) }.is_err());
    }
}
