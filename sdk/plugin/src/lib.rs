//! Dynamic plugins for human2nav: a small, versioned C ABI, the [`export_plugin!`] macro for
//! plugin authors, and a [`libloading`]-based host whose proxies implement the core traits.
//! No libtorch.
//!
//! * [`abi`]: the `#[repr(C)]` tables and status codes (mirrored in `include/human2nav_plugin.h`
//!   for plugins written in C).
//! * [`export_plugin!`] and [`init`]: what an author writes. Implement
//!   [`ConstraintTerm`](human2nav_core::constraint::ConstraintTerm),
//!   [`Embodiment`](human2nav_core::embodiment::Embodiment) or
//!   [`Planner`](human2nav_core::Planner) as usual, give each type a constructor from
//!   [`PluginInit`] (TOML config + optional robot context), and export them. The macro writes
//!   every `unsafe` shim, catches panics and checks pointers and lengths.
//! * [`host`]: [`PluginHost`] loads libraries explicitly (checking the ABI version first) and
//!   returns proxies ([`PluginConstraint`], [`PluginEmbodiment`], [`PluginPlanner`]) that the
//!   rest of the SDK uses like built-ins. Libraries are never unloaded.
//! * [`robot`]: [`PluginHost::load_robot`] turns a robot profile into a [`LoadedRobot`]
//!   (embodiment + plugin constraint terms); [`PluginSpec`] names a plugin in other configs.
//! * [`locate`]: how library paths in profiles are resolved (relative to the declaring file,
//!   optional extension and `lib` prefix, the `{profile}` placeholder).
//! * [`libfile`]: the library file is checked before the OS loader maps it (a truncated
//!   library would fault inside `dlopen`); [`validate`]: every table, function slot, count and
//!   string a plugin hands over is checked before use, against documented caps;
//!   [`inspect`]: what `human2nav plugin inspect` reports; [`deadline`]: plugin calls that do
//!   not return in time do not hang the host; [`process`]: planners, constraint terms and
//!   embodiments run in a helper process unless declared `isolation = "in_process"`, so a
//!   plugin that aborts, segfaults or hangs does not take the host down.
//!
//! Why not export Rust trait objects: their layout is not stable across compiler versions, so
//! a plugin built with another rustc would be undefined behaviour. Only C types cross.

#![warn(missing_docs)]

pub mod abi;
pub mod deadline;
mod error;
#[doc(hidden)]
pub mod export;
pub mod host;
pub mod init;
pub mod inspect;
pub mod libfile;
pub mod locate;
mod macros;
pub mod process;
/// The former name of [`locate`].
pub use locate as resolve;
pub mod robot;
pub mod validate;

pub use abi::ABI_VERSION;
pub use error::{PluginError, PluginKind};
pub use host::{
    FactoryInfo, PluginConstraint, PluginEmbodiment, PluginFailure, PluginHost, PluginLibrary,
    PluginPlanner,
};
pub use human2nav_core::robot::PluginIsolation;
pub use init::{InitError, PluginInit, RobotContext, parse_config};
pub use inspect::{InspectReport, inspect_library};
pub use robot::{LoadedRobot, PluginSpec, RobotResolution, ref_isolation, robot_context};
pub use validate::{Check, CheckStatus};
