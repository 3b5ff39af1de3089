//! Out-of-process plugin instances: a planner, constraint term or embodiment that runs in a
//! helper process of its own, so that a plugin that aborts, segfaults or hangs costs its own
//! use, not the host.
//!
//! Setting: `isolation` in a bench `[[methods]]` plugin entry, a [`crate::PluginSpec`], a robot
//! profile's `[[constraint]]` or its `[embodiment]` (`kind = "plugin"`): `"process"`, the
//! default when nothing is written, or `"in_process"`, an explicit opt-in for speed (the cost
//! per call: `cargo bench -p human2nav-plugin --bench process`). The C API and the Python
//! package run a profile's plugins in process unless the profile writes `"process"`
//! ([`human2nav_core::robot::RobotProfile::default_plugin_isolation`]).
//!
//! **The helper.** `human2nav-plugin-host` (a binary of this crate) loads one library with every
//! check of the in-process host, creates one instance (without a deadline of its own) and serves
//! calls on its stdin/stdout; whatever the plugin prints on stdout goes to stderr. It is found,
//! in order: the path set with [`crate::PluginHost::with_process_helper`]; the environment
//! variable [`HELPER_ENV`]; `human2nav-plugin-host` next to the current executable, then in that
//! directory's parent (a test or benchmark binary lives in `target/<profile>/deps`).
//!
//! **Protocol.** Each message is a little-endian `u32` length and that many bytes; the first
//! byte is the operation (request) or the status (answer: 0 OK, 1 error). Numbers are `u64`
//! or the IEEE bits of `f64` (so plans, gradients and robot states are bit-identical to
//! in-process calls); strings are a length and UTF-8. The first request creates the instance
//! (kind, library, factory, TOML config, optional robot); then a planner's `reset` and `plan`
//! (the observation; the answer is the plan or the planner's error), a constraint's `evaluate`
//! (batch, context, and the cost and gradient to add to; the answer is both, or the term's
//! error), an embodiment's `holonomic`, `saturate`, `step`, `track` and `coupled_limit` (the
//! answer is the value and the failure, if any, that the helper's own checks found). Messages
//! are capped at [`MAX_MESSAGE_BYTES`].
//!
//! **Failures and restarts.** Every call waits at most the instance's deadline (none with
//! `deadline_ms = 0`: then only a dead process is noticed). When the process closes its end
//! (it died) or the deadline passes (it is killed), the call fails with an error naming the
//! instance and the cause (`plugin process for planner `straight` died during `plan`: signal
//! SIGSEGV`, `... exited with status 3`, `... did not answer `plan` within 1000 ms (killed)`):
//! a planner returns the stop-in-place plan flagged `fallback` with [`PlanInfo::error`] set (as
//! after an in-process missed deadline), a constraint term returns the error. The next call
//! starts a fresh process and instance (a planner loses its state: as after `reset`). At most
//! [`MAX_RESTARTS`] restarts per instance (proxy); after that the instance is marked dead like
//! an in-process one ([`crate::PluginHost::failures`]) and calls fail at once, so a plugin that
//! crashes on every call does not spawn processes for ever. An embodiment is not restarted: as
//! after any other failure of an embodiment, the first one marks it dead and the robot halts
//! where it is (an embodiment that cannot step is not safe to keep driving).

use crate::abi::H2nCoupledLimit;
use crate::error::{PluginError, PluginKind};
use crate::init::RobotContext;
use human2nav_core::constraint::{ConstraintContext, ConstraintError, TrajBatch};
use human2nav_core::embodiment::RobotState;
use human2nav_core::obstacle::{Obstacle, OccupancyGrid};
use human2nav_core::{
    AgentState, ControllerGains, CoupledLimit, Limits, Observation, Plan, PlanError, PlanInfo,
    Pose2, Twist2,
};
use std::borrow::Cow;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// Environment variable naming the helper executable.
pub const HELPER_ENV: &str = "HUMAN2NAV_PLUGIN_HOST";
/// The helper's file name (without the OS's executable suffix).
pub const HELPER_NAME: &str = "human2nav-plugin-host";
/// Restarts one instance may use; the next failure marks it dead.
pub const MAX_RESTARTS: u32 = 3;
/// Largest message either side accepts (64 MiB: a 64 × 32-pose batch is 49 KiB).
pub const MAX_MESSAGE_BYTES: usize = 64 << 20;
/// Shortest time the helper gets to load the library and create the instance.
pub const MIN_START_TIME: Duration = Duration::from_secs(30);

pub(crate) const OP_INIT: u8 = 1;
pub(crate) const OP_RESET: u8 = 2;
pub(crate) const OP_PLAN: u8 = 3;
pub(crate) const OP_EVALUATE: u8 = 4;
pub(crate) const OP_HOLONOMIC: u8 = 5;
pub(crate) const OP_SATURATE: u8 = 6;
pub(crate) const OP_STEP: u8 = 7;
pub(crate) const OP_TRACK: u8 = 8;
pub(crate) const OP_COUPLED_LIMIT: u8 = 9;
pub(crate) const OP_PROPERTIES: u8 = 10;
pub(crate) const ANSWER_OK: u8 = 0;
pub(crate) const ANSWER_ERR: u8 = 1;

mod client;
mod messages;
mod serve;
#[cfg(test)]
mod tests;
mod wire;

pub(crate) use client::{ProcessClient, start_instance};
pub use client::{find_helper, signal_name};
pub(crate) use messages::*;
pub use serve::serve_stdio;
pub(crate) use wire::*;
