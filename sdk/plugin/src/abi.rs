//! The C ABI between a host and a plugin library, version [`ABI_VERSION`].
//!
//! Everything here is `#[repr(C)]` and mirrored by hand in `include/human2nav_plugin.h`; the C
//! plugin in `plugins/c_personal_space` exports the sizes and field offsets its compiler sees so
//! the integration tests can compare them with [`layout`].
//!
//! # Contract
//!
//! * A plugin library exports one symbol, [`ENTRY_SYMBOL`], of type [`EntryFn`]. It returns a
//!   pointer to a [`H2nPluginEntry`] that lives as long as the library. The first field of that
//!   table, `abi_version`, is the only thing frozen forever: the host reads it before anything
//!   else and refuses the library when it is not between [`MIN_ABI_VERSION`] and
//!   [`ABI_VERSION`].
//! * Versions: 1 passed planners the pedestrians (with their recent history); 2 appends the
//!   static obstacles and the occupancy grid to [`H2nObservation`]. A version-1 library loads
//!   unchanged: the tables it reads are prefixes of version 2's, and it never sees the
//!   appended fields (the host notes on each plan that it did not see obstacles).
//! * Every table starts with a `struct_size` (or is versioned by the entry's): tables are
//!   append-only, so a newer plugin may add fields at the end and an older host ignores them.
//!   The host refuses a `struct_size` below the table's first version (its own size, except
//!   for a table that has grown since: [`H2nEmbodimentVTable::coupled_limit`] and
//!   [`H2nConstraintVTable::properties`] were appended, and a table that ends before its slot
//!   has none) or above
//!   [`crate::validate::MAX_TABLE_BYTES`]. The factories of the entry's array are
//!   `struct_size` bytes apart, and all have the same `struct_size`.
//! * Function slots are nullable (`Option<extern "C" fn>`, the layout of a C function pointer).
//!   Each table says which slots are **required** (the host refuses an instance or library
//!   with a null one, naming the file, the table and the slot, and calls nothing of it) and
//!   which are **optional** (`find_factory`, `last_error`, `name`, `reset`, `coupled_limit`,
//!   `properties`).
//! * Counts and lengths a plugin hands over are capped ([`crate::validate`]): factories,
//!   names, descriptions, plan lengths, messages.
//! * Strings are [`H2nStr`] (UTF-8, pointer and length, no terminator required); arrays are
//!   pointer and length (and shape). The host owns every output buffer; the plugin writes into
//!   it and reports how much it needed ([`H2nBuffer`]).
//! * Every function returns a status ([`H2N_OK`] or one of the `H2N_*` errors). After a failure
//!   the instance's `last_error` explains it. A status of [`H2N_PANIC`] means the plugin caught a
//!   panic: the instance is then unusable and every later call returns [`H2N_POISONED`].
//! * Configuration reaches a factory as a TOML string; the plugin parses it and rejects unknown
//!   fields ([`H2N_CONFIG`]).
//! * Constraint and embodiment instances must tolerate concurrent calls from several threads
//!   (the Rust traits are `Send + Sync`); a planner instance is only ever called by one thread
//!   at a time. `destroy` is called exactly once, after the last call, on any thread. With a
//!   deadline ([`crate::deadline`]) a planner's or constraint's calls come from one worker
//!   thread of the host; an instance that missed its deadline gets no further call but `destroy`,
//!   once (and if) its late call returns.
//! * Libraries are never unloaded, so static data may be referenced by the host for ever.

use human2nav_core::CoupledLimit;
use std::ffi::c_void;

mod convert;
mod offsets;

pub use offsets::{StructLayout, layout};

/// The version of this ABI, which plugins built with this crate declare. Bumped when what a
/// plugin may rely on changes: appending fields to a table (guarded by its `struct_size`)
/// keeps older plugins loading, but a plugin that reads the new fields needs a host that
/// writes them, so it declares the new version.
pub const ABI_VERSION: u32 = 2;

/// The oldest ABI version this host loads: version-1 plugins (pedestrians only) still work.
pub const MIN_ABI_VERSION: u32 = 1;

/// The first ABI version whose planners read the observation's obstacles and occupancy grid.
pub const OBSTACLES_SINCE: u32 = 2;

/// Name of the symbol every plugin library exports.
pub const ENTRY_SYMBOL: &str = "human2nav_plugin_entry";

/// Signature of [`ENTRY_SYMBOL`]: returns the plugin's entry table (never null for a plugin).
pub type EntryFn = unsafe extern "C" fn() -> *const H2nPluginEntry;

// Function-pointer slots. Every slot of a table is an `Option` of one of these: a C function
// pointer may be null, and `Option<extern "C" fn>` has exactly the layout of a nullable C
// function pointer, so the host can read a table whatever the plugin put in it and check each
// slot before calling it. Which slots may be null is documented on each table.

/// `H2nPluginEntry::find_factory`.
pub type FindFactoryFn = unsafe extern "C" fn(kind: u32, name: H2nStr) -> *const H2nFactory;
/// `H2nFactory::create`.
pub type CreateFn = unsafe extern "C" fn(
    args: *const H2nCreateArgs,
    out: *mut H2nObject,
    error: *mut H2nBuffer,
) -> H2nStatus;
/// `destroy` of every vtable.
pub type DestroyFn = unsafe extern "C" fn(instance: *mut c_void);
/// `last_error` of every vtable.
pub type LastErrorFn = unsafe extern "C" fn(instance: *mut c_void, out: *mut H2nBuffer);
/// `name` of every vtable.
pub type NameFn = unsafe extern "C" fn(instance: *mut c_void) -> H2nStr;
/// `H2nConstraintVTable::evaluate`.
pub type EvaluateFn = unsafe extern "C" fn(
    instance: *mut c_void,
    batch: *const H2nTrajBatch,
    ctx: *const H2nConstraintContext,
    cost: H2nF64Out,
    grad: H2nF64Out,
) -> H2nStatus;
/// `H2nConstraintVTable::properties`.
pub type PropertiesFn = unsafe extern "C" fn(instance: *mut c_void, out: *mut u32) -> H2nStatus;
/// `H2nEmbodimentVTable::holonomic`.
pub type HolonomicFn = unsafe extern "C" fn(instance: *mut c_void, out: *mut u32) -> H2nStatus;
/// `H2nEmbodimentVTable::saturate`.
pub type SaturateFn = unsafe extern "C" fn(
    instance: *mut c_void,
    state: *const H2nRobotState,
    cmd: *const H2nTwist,
    dt: f64,
    out: *mut H2nTwist,
) -> H2nStatus;
/// `H2nEmbodimentVTable::step`.
pub type StepFn = unsafe extern "C" fn(
    instance: *mut c_void,
    state: *const H2nRobotState,
    cmd: *const H2nTwist,
    dt: f64,
    out: *mut H2nRobotState,
) -> H2nStatus;
/// `H2nEmbodimentVTable::track`.
pub type TrackFn = unsafe extern "C" fn(
    instance: *mut c_void,
    state: *const H2nRobotState,
    plan: *const H2nPlanView,
    t: f64,
    out: *mut H2nTwist,
) -> H2nStatus;
/// `H2nEmbodimentVTable::coupled_limit`.
pub type CoupledLimitFn =
    unsafe extern "C" fn(instance: *mut c_void, out: *mut H2nCoupledLimit) -> H2nStatus;
/// `H2nPlannerVTable::reset`.
pub type ResetFn = unsafe extern "C" fn(instance: *mut c_void) -> H2nStatus;
/// `H2nPlannerVTable::plan`.
pub type PlanFn = unsafe extern "C" fn(
    instance: *mut c_void,
    obs: *const H2nObservation,
    out: *mut H2nPlanOut,
) -> H2nStatus;
/// `H2nPlannerVTable::last_plan`.
pub type LastPlanFn =
    unsafe extern "C" fn(instance: *mut c_void, out: *mut H2nPlanOut) -> H2nStatus;

/// Status code returned by every ABI function.
pub type H2nStatus = i32;
/// Success.
pub const H2N_OK: H2nStatus = 0;
/// The call failed; `last_error` (or the create error buffer) says why.
pub const H2N_ERROR: H2nStatus = 1;
/// A null pointer, a length that does not match its shape, or text that is not UTF-8.
pub const H2N_INVALID_ARGUMENT: H2nStatus = 2;
/// The TOML configuration was rejected (syntax, unknown field, bad value).
pub const H2N_CONFIG: H2nStatus = 3;
/// The call panicked; the plugin caught the panic and the instance is now unusable.
pub const H2N_PANIC: H2nStatus = 4;
/// An earlier call on this instance panicked; the instance refuses further work.
pub const H2N_POISONED: H2nStatus = 5;
/// A host-owned output array was too small; the needed length was written back.
pub const H2N_BUFFER_TOO_SMALL: H2nStatus = 6;
/// No factory of that kind and name (create only).
pub const H2N_UNKNOWN_FACTORY: H2nStatus = 7;

/// A short description of a status code, for error messages.
pub fn status_name(status: H2nStatus) -> &'static str {
    match status {
        H2N_OK => "ok",
        H2N_ERROR => "error",
        H2N_INVALID_ARGUMENT => "invalid argument",
        H2N_CONFIG => "invalid configuration",
        H2N_PANIC => "panic",
        H2N_POISONED => "unusable after an earlier panic",
        H2N_BUFFER_TOO_SMALL => "buffer too small",
        H2N_UNKNOWN_FACTORY => "unknown factory",
        _ => "unknown status",
    }
}

/// Factory kind: a constraint term ([`H2nConstraintVTable`]).
pub const H2N_KIND_CONSTRAINT: u32 = 1;
/// Factory kind: an embodiment ([`H2nEmbodimentVTable`]).
pub const H2N_KIND_EMBODIMENT: u32 = 2;
/// Factory kind: a planner ([`H2nPlannerVTable`]).
pub const H2N_KIND_PLANNER: u32 = 3;

/// Borrowed UTF-8 text: `len` bytes at `ptr` (no terminator required; `ptr` may be null when
/// `len == 0`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct H2nStr {
    /// First byte of the text (may be null when `len == 0`).
    pub ptr: *const u8,
    /// Length in bytes.
    pub len: usize,
}

impl H2nStr {
    /// The empty string.
    pub const EMPTY: H2nStr = H2nStr {
        ptr: std::ptr::null(),
        len: 0,
    };

    /// Borrows a Rust string (the view must not outlive `s`).
    pub const fn new(s: &str) -> Self {
        Self {
            ptr: s.as_ptr(),
            len: s.len(),
        }
    }

    /// The text as a Rust string.
    ///
    /// # Safety
    /// `ptr` must point to `len` readable bytes that stay valid and unchanged for `'a`.
    pub unsafe fn as_str<'a>(self) -> Result<&'a str, std::str::Utf8Error> {
        if self.len == 0 || self.ptr.is_null() {
            return Ok("");
        }
        // SAFETY: the caller guarantees `len` readable bytes at `ptr` for 'a.
        let bytes = unsafe { std::slice::from_raw_parts(self.ptr, self.len) };
        std::str::from_utf8(bytes)
    }
}

/// A host-owned byte buffer the plugin writes text into: it copies `min(len, capacity)` bytes of
/// its UTF-8 message to `data` and sets `len` to the message's full length (so the host can tell
/// that it was truncated). `data` may be null when `capacity == 0`.
#[repr(C)]
#[derive(Debug)]
pub struct H2nBuffer {
    /// Where the plugin writes (host-owned; may be null when `capacity == 0`).
    pub data: *mut u8,
    /// Bytes the host allocated at `data`.
    pub capacity: usize,
    /// Set by the plugin: the full length of its message, which may exceed `capacity`.
    pub len: usize,
}

/// The exported entry table.
#[repr(C)]
#[derive(Debug)]
pub struct H2nPluginEntry {
    /// Must equal the host's [`ABI_VERSION`]; read before anything else.
    pub abi_version: u32,
    /// `sizeof(H2nPluginEntry)` as the plugin was compiled.
    pub struct_size: u32,
    /// The plugin's name (e.g. `personal_space`).
    pub name: H2nStr,
    /// The plugin's own version (e.g. `0.1.0`).
    pub version: H2nStr,
    /// What the plugin provides: `factory_count` entries, each `struct_size` bytes apart (the
    /// `struct_size` of the first; every factory must have the same one).
    pub factories: *const H2nFactory,
    /// Number of entries at `factories`.
    pub factory_count: usize,
    /// Factory lookup by kind and name (returns null when there is none). **Optional** (may be
    /// null): this host looks factories up in the validated `factories` array and does not call
    /// it; it stays in the table for hosts that do.
    pub find_factory: Option<FindFactoryFn>,
}

// SAFETY: an entry table is immutable static data (string literals, static factory arrays and
// function pointers); sharing references to it between threads cannot race.
unsafe impl Sync for H2nPluginEntry {}

/// One factory: creates instances of one kind under one name.
#[repr(C)]
#[derive(Debug)]
pub struct H2nFactory {
    /// `sizeof(H2nFactory)` as the plugin was compiled.
    pub struct_size: u32,
    /// One of the `H2N_KIND_*` constants.
    pub kind: u32,
    /// The factory name robot profiles refer to (`plugin = "..."`).
    pub name: H2nStr,
    /// One line for `human2nav plugin inspect`.
    pub description: H2nStr,
    /// Creates an instance. On success writes `out` and returns [`H2N_OK`]; on failure writes a
    /// message into `error` (host-owned) and returns a status. **Required.**
    pub create: Option<CreateFn>,
}

// SAFETY: as for `H2nPluginEntry`: factories are immutable static data.
unsafe impl Sync for H2nFactory {}

/// The robot's hard limits ([`human2nav_core::Limits`]); `has_kappa_max == 0` means no curvature
/// limit (the robot turns in place) and `kappa_max` is then ignored.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct H2nLimits {
    /// Largest forward speed (m/s).
    pub v_max: f64,
    /// Largest reverse speed (m/s, a positive number).
    pub v_reverse_max: f64,
    /// Largest longitudinal acceleration (m/s², braking too).
    pub a_max: f64,
    /// Largest yaw rate (rad/s).
    pub omega_max: f64,
    /// Largest curvature (1/m); read only when `has_kappa_max == 1`.
    pub kappa_max: f64,
    /// Largest body-frame lateral speed (m/s): a small slip tolerance for non-holonomic robots,
    /// the real sideways limit for omnidirectional ones.
    pub lateral_speed_max: f64,
    /// 1 when `kappa_max` applies, 0 when the robot has no curvature limit.
    pub has_kappa_max: u32,
    /// Padding, always 0.
    pub reserved: u32,
}

/// Tracking-controller gains ([`human2nav_core::ControllerGains`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct H2nGains {
    /// Proportional gain on the along-track position error (1/s).
    pub k_x: f64,
    /// Proportional gain on the cross-track position error (see [`human2nav_core::ControllerGains::k_y`]).
    pub k_y: f64,
    /// Proportional gain on the heading error (1/s).
    pub k_theta: f64,
    /// Derivative (velocity feed-forward error) gain, dimensionless.
    pub k_d: f64,
    /// Look-ahead time along the plan (s).
    pub lookahead: f64,
}

/// What a factory receives.
#[repr(C)]
#[derive(Debug)]
pub struct H2nCreateArgs {
    /// `sizeof(H2nCreateArgs)` as the host was compiled.
    pub struct_size: u32,
    /// The kind being created (the factory's own kind).
    pub kind: u32,
    /// The TOML configuration from the robot profile or benchmark config (may be empty).
    pub config: H2nStr,
    /// 1 when `limits`, `gains` and `footprint_radius` describe the robot the instance serves,
    /// 0 when there is no robot context (e.g. `plugin inspect`, a stand-alone constraint).
    pub has_robot: u32,
    /// Padding, always 0.
    pub reserved: u32,
    /// The robot's hard limits (meaningful when `has_robot == 1`).
    pub limits: H2nLimits,
    /// The robot's tracking-controller gains (meaningful when `has_robot == 1`).
    pub gains: H2nGains,
    /// Footprint radius of the robot (m).
    pub footprint_radius: f64,
}

/// A created instance: an opaque pointer and the vtable of its kind
/// ([`H2nConstraintVTable`], [`H2nEmbodimentVTable`] or [`H2nPlannerVTable`]).
#[repr(C)]
#[derive(Debug)]
pub struct H2nObject {
    /// The plugin's instance, passed back to every vtable function.
    pub instance: *mut c_void,
    /// The kind's vtable (`H2nConstraintVTable`, `H2nEmbodimentVTable` or `H2nPlannerVTable`).
    pub vtable: *const c_void,
}

/// A pose `(x, y, θ)` (m, m, rad).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct H2nPose {
    /// Position x (m).
    pub x: f64,
    /// Position y (m).
    pub y: f64,
    /// Heading (rad).
    pub theta: f64,
}

/// A body-frame twist `(v_x, v_y, ω)` (m/s, m/s, rad/s).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct H2nTwist {
    /// Forward speed (m/s).
    pub vx: f64,
    /// Lateral speed, to the left (m/s).
    pub vy: f64,
    /// Yaw rate, counter-clockwise (rad/s).
    pub omega: f64,
}

/// Another agent. `history` points to `history_len` positions `[x, y]` (`2·history_len`
/// doubles, oldest first) and may be null when `history_len == 0`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct H2nAgent {
    /// The agent's identity, stable across calls.
    pub id: u64,
    /// Current position `[x, y]` (m).
    pub position: [f64; 2],
    /// Current velocity `[v_x, v_y]` (m/s).
    pub velocity: [f64; 2],
    /// Body radius (m).
    pub radius: f64,
    /// Past positions, `2·history_len` doubles, oldest first (may be null when `history_len == 0`).
    pub history: *const f64,
    /// Number of past positions at `history`.
    pub history_len: usize,
}

/// A read-only batch of trajectories: `data` holds `len == batch·horizon·dim` doubles laid out
/// `[batch, horizon, dim]` with `dim == 3` (`x, y, θ`).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct H2nTrajBatch {
    /// The poses, `[batch, horizon, dim]` doubles.
    pub data: *const f64,
    /// Doubles at `data`: `batch·horizon·dim`.
    pub len: usize,
    /// Number of trajectories.
    pub batch: usize,
    /// Poses per trajectory.
    pub horizon: usize,
    /// Values per pose, always 3 (`x, y, θ`).
    pub dim: usize,
}

/// A host-owned output array of `len` doubles.
#[repr(C)]
#[derive(Debug)]
pub struct H2nF64Out {
    /// Where the callee writes (host-owned).
    pub data: *mut f64,
    /// Doubles at `data`.
    pub len: usize,
}

/// What a constraint term sees besides the trajectories ([`human2nav_core::constraint::ConstraintContext`]).
#[repr(C)]
#[derive(Debug)]
pub struct H2nConstraintContext {
    /// `sizeof(H2nConstraintContext)` as the host was compiled.
    pub struct_size: u32,
    /// Padding, always 0.
    pub reserved: u32,
    /// Time between poses (s).
    pub dt: f64,
    /// The robot's hard limits.
    pub limits: H2nLimits,
    /// The robot's body-frame velocity at the first pose.
    pub initial_velocity: H2nTwist,
    /// The other agents, `agent_count` of them (may be null when `agent_count == 0`).
    pub agents: *const H2nAgent,
    /// Number of agents at `agents`.
    pub agent_count: usize,
}

/// Vtable of a constraint term ([`human2nav_core::constraint::ConstraintTerm`]).
#[repr(C)]
#[derive(Debug)]
pub struct H2nConstraintVTable {
    /// `sizeof(H2nConstraintVTable)` as the plugin was compiled.
    pub struct_size: u32,
    /// Padding, always 0.
    pub reserved: u32,
    /// Frees the instance. Called exactly once. **Required.**
    pub destroy: Option<DestroyFn>,
    /// Copies the instance's last error message into `out` (`len = 0` when there is none).
    /// **Optional**: without it the host reports failures by their status alone.
    pub last_error: Option<LastErrorFn>,
    /// The term's name, valid as long as the instance. **Optional**: without it the host uses
    /// the factory's name.
    pub name: Option<NameFn>,
    /// Adds the cost of trajectory `b` into `cost.data[b]` (`cost.len == batch`) and its
    /// gradient into `grad` (`grad.len == batch.len`). **Required.**
    pub evaluate: Option<EvaluateFn>,
    /// Writes the term's property bits (`H2N_CONSTRAINT_*`) into `out`; asked once, when the
    /// instance is created. Bits this host does not know are ignored. **Optional** (no
    /// properties), and appended after the first version of this table: a table whose
    /// `struct_size` ends before it has none.
    pub properties: Option<PropertiesFn>,
}

/// [`H2nConstraintVTable::properties`] bit: the term's cost of a trajectory is never negative,
/// is finite for finite poses, and is the same to the bit whatever other trajectories share its
/// batch (core's `ConstraintTerm::separable_nonnegative`). A planner may then leave the term
/// out for candidates whose score already loses without it. A term that sets this bit must
/// hold to all three; a negative cost turns that pruning off for the planning call.
pub const H2N_CONSTRAINT_SEPARABLE_NONNEGATIVE: u32 = 1;

/// A robot state: pose and the body-frame velocity executed during the last step.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct H2nRobotState {
    /// The robot's pose (world frame).
    pub pose: H2nPose,
    /// The body-frame velocity executed during the last step.
    pub velocity: H2nTwist,
}

/// A read-only plan: `pose_count` poses, `poses[k]` at `t0 + k·dt` (diagnostics are not passed).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct H2nPlanView {
    /// Time of the first pose (s).
    pub t0: f64,
    /// Time between poses (s).
    pub dt: f64,
    /// The poses, `pose_count` of them.
    pub poses: *const H2nPose,
    /// Number of poses at `poses`.
    pub pose_count: usize,
}

/// A coupled twist limit `v·|v_x| + lateral·|v_y| + omega·|ω| ≤ max`
/// ([`human2nav_core::CoupledLimit`]). All zeros means "none".
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct H2nCoupledLimit {
    /// Coefficient of `|v_x|` (`>= 0`).
    pub v: f64,
    /// Coefficient of `|v_y|` (`>= 0`).
    pub lateral: f64,
    /// Coefficient of `|ω|` (m/rad, `>= 0`).
    pub omega: f64,
    /// The bound (m/s, `> 0` unless every field is 0).
    pub max: f64,
}

impl From<&CoupledLimit> for H2nCoupledLimit {
    fn from(c: &CoupledLimit) -> Self {
        Self {
            v: c.v,
            lateral: c.lateral,
            omega: c.omega,
            max: c.max,
        }
    }
}

impl H2nCoupledLimit {
    /// `None` for all zeros, else the limit, checked ([`CoupledLimit::validate`]: the error
    /// names the field).
    pub fn to_limit(&self) -> Result<Option<CoupledLimit>, (&'static str, String)> {
        if *self == Self::default() {
            return Ok(None);
        }
        let c = CoupledLimit {
            v: self.v,
            lateral: self.lateral,
            omega: self.omega,
            max: self.max,
        };
        c.validate().map(|()| Some(c))
    }
}

/// Vtable of an embodiment ([`human2nav_core::embodiment::Embodiment`]).
#[repr(C)]
#[derive(Debug)]
pub struct H2nEmbodimentVTable {
    /// `sizeof(H2nEmbodimentVTable)` as the plugin was compiled.
    pub struct_size: u32,
    /// Padding, always 0.
    pub reserved: u32,
    /// **Required** (as in [`H2nConstraintVTable`]).
    pub destroy: Option<DestroyFn>,
    /// **Optional** (as in [`H2nConstraintVTable`]).
    pub last_error: Option<LastErrorFn>,
    /// **Optional** (as in [`H2nConstraintVTable`]).
    pub name: Option<NameFn>,
    /// Writes 1 to `out` when the robot can move sideways, else 0. **Required.**
    pub holonomic: Option<HolonomicFn>,
    /// Clips `cmd` to what the robot can do from `state` within `dt`. **Required.**
    pub saturate: Option<SaturateFn>,
    /// Advances the kinematic model by `dt` under an already saturated command. **Required.**
    pub step: Option<StepFn>,
    /// The tracking controller's (unsaturated) command that follows `plan` at time `t`.
    /// **Required.**
    pub track: Option<TrackFn>,
    /// Writes the embodiment's coupled twist limit into `out` (which the host zeroes first;
    /// left all zeros: none). Called once, when the instance is created; the host checks the
    /// values and adds the limit to the robot's limits, which TFS, Φ and the last-step
    /// correction use. **Optional**, and appended after the first version of this table: a
    /// table whose `struct_size` ends before it has none.
    pub coupled_limit: Option<CoupledLimitFn>,
}

/// [`H2nObstacle::kind`]: a disc, centre `(x0, y0)`, `radius`.
pub const H2N_OBSTACLE_CIRCLE: u32 = 0;
/// [`H2nObstacle::kind`]: a line segment (a wall) from `(x0, y0)` to `(x1, y1)`.
pub const H2N_OBSTACLE_SEGMENT: u32 = 1;
/// [`H2nObstacle::kind`]: a simple polygon of `vertex_count ≥ 3` vertices.
pub const H2N_OBSTACLE_POLYGON: u32 = 2;

/// A static obstacle in the world frame ([`human2nav_core::obstacle::Obstacle`]); the fields its kind
/// does not use are zero (ABI version 2).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct H2nObstacle {
    /// [`H2N_OBSTACLE_CIRCLE`], [`H2N_OBSTACLE_SEGMENT`] or [`H2N_OBSTACLE_POLYGON`].
    pub kind: u32,
    /// Padding, always 0.
    pub reserved: u32,
    /// Circle centre or segment start x (m).
    pub x0: f64,
    /// Circle centre or segment start y (m).
    pub y0: f64,
    /// Segment end x (m).
    pub x1: f64,
    /// Segment end y (m).
    pub y1: f64,
    /// Circle radius (m).
    pub radius: f64,
    /// Polygon vertices, `2·vertex_count` doubles `x, y, x, y, …` (null for other kinds).
    pub vertices: *const f64,
    /// Number of polygon vertices.
    pub vertex_count: usize,
}

/// An occupancy grid in the layout of `nav_msgs/OccupancyGrid`
/// ([`human2nav_core::obstacle::OccupancyGrid`]; ABI version 2).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct H2nOccupancyGrid {
    /// Pose of the corner of cell `(0, 0)` in the world frame.
    pub origin: H2nPose,
    /// Cell edge (m).
    pub resolution: f64,
    /// Cells per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major values, `width·height` of them: −1 unknown, 0 (free) to 100 (occupied).
    pub data: *const i8,
    /// Cells at or above this value are obstacles.
    pub occupied_threshold: i32,
    /// Padding, always 0.
    pub reserved: u32,
}

/// What a planner sees at one planning instant ([`human2nav_core::Observation`]). The fields
/// from `obstacles` on are version 2's: a version-1 plugin reads the prefix before them.
#[repr(C)]
#[derive(Debug)]
pub struct H2nObservation {
    /// `sizeof(H2nObservation)` as the host was compiled.
    pub struct_size: u32,
    /// Padding, always 0.
    pub reserved: u32,
    /// Time of the observation (s).
    pub time: f64,
    /// The robot's pose (world frame).
    pub ego: H2nPose,
    /// The robot's body-frame velocity.
    pub ego_velocity: H2nTwist,
    /// The goal position `[x, y]` (world frame, m).
    pub goal: [f64; 2],
    /// The other agents, `agent_count` of them (may be null when `agent_count == 0`).
    pub agents: *const H2nAgent,
    /// Number of agents at `agents`.
    pub agent_count: usize,
    /// Static obstacles, `obstacle_count` of them (may be null when `obstacle_count == 0`).
    /// Version 2.
    pub obstacles: *const H2nObstacle,
    /// Number of obstacles at `obstacles`. Version 2.
    pub obstacle_count: usize,
    /// The occupancy grid, or null when the observation has none. Version 2.
    pub occupancy: *const H2nOccupancyGrid,
}

/// Size of a version-1 [`H2nObservation`]: everything before `obstacles`.
pub const OBSERVATION_V1_SIZE: usize = std::mem::offset_of!(H2nObservation, obstacles);

/// A host-owned plan buffer. The plugin writes `t0`, `dt`, `fallback`, up to `capacity` poses
/// and sets `len` to the plan's length. When `len > capacity` the call returns
/// [`H2N_BUFFER_TOO_SMALL`] and the plugin keeps the plan so that `last_plan` can copy it into
/// a larger buffer. `note` receives an optional one-line diagnostic (e.g. why it fell back).
#[repr(C)]
#[derive(Debug)]
pub struct H2nPlanOut {
    /// Written by the plugin: time of the first pose (s).
    pub t0: f64,
    /// Written by the plugin: time between poses (s).
    pub dt: f64,
    /// Host-owned room for `capacity` poses.
    pub poses: *mut H2nPose,
    /// Poses the host allocated at `poses`.
    pub capacity: usize,
    /// Written by the plugin: the plan's length (may exceed `capacity`).
    pub len: usize,
    /// 1 when the planner fell back to its safe behaviour (stop in place).
    pub fallback: u32,
    /// Padding, always 0.
    pub reserved: u32,
    /// Host-owned buffer for an optional one-line diagnostic.
    pub note: H2nBuffer,
}

/// Vtable of a planner ([`human2nav_core::Planner`]).
#[repr(C)]
#[derive(Debug)]
pub struct H2nPlannerVTable {
    /// `sizeof(H2nPlannerVTable)` as the plugin was compiled.
    pub struct_size: u32,
    /// Padding, always 0.
    pub reserved: u32,
    /// **Required** (as in [`H2nConstraintVTable`]).
    pub destroy: Option<DestroyFn>,
    /// **Optional** (as in [`H2nConstraintVTable`]).
    pub last_error: Option<LastErrorFn>,
    /// **Optional** (as in [`H2nConstraintVTable`]).
    pub name: Option<NameFn>,
    /// Forgets state carried between calls. **Optional**: a planner without state between
    /// calls may leave it null.
    pub reset: Option<ResetFn>,
    /// Plans from one observation into `out`. **Required.**
    pub plan: Option<PlanFn>,
    /// Copies the plan of the last successful `plan` call into `out` (after
    /// [`H2N_BUFFER_TOO_SMALL`]). **Required.**
    pub last_plan: Option<LastPlanFn>,
}
