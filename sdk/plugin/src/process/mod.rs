//! Out-of-process plugin instances: a planner or constraint term that runs in a helper process
//! of its own, so that a plugin that aborts, segfaults or hangs costs one call, not the host.
//!
//! Setting: `isolation = "process"` (default `"in_process"`) in a bench `[[methods]]` plugin
//! entry, a [`crate::PluginSpec`] or a robot profile's `[[constraint]]`. Embodiments always run
//! in the host process (microseconds per simulator step; their trait cannot report a failure).
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
//! or the IEEE bits of `f64` (so plans and gradients are bit-identical to in-process calls);
//! strings are a length and UTF-8. The first request creates the instance (kind, library,
//! factory, TOML config, optional robot as TOML); then `reset`, `plan` (the observation; the
//! answer is the plan or the planner's error) and `evaluate` (batch, context, and the cost and
//! gradient to add to; the answer is both, or the term's error). Messages are capped at
//! [`MAX_MESSAGE_BYTES`].
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
//! crashes on every call does not spawn processes for ever.

use crate::error::{PluginError, PluginKind};
use crate::init::RobotContext;
use human2nav_core::constraint::{ConstraintContext, ConstraintError, TrajBatch};
use human2nav_core::obstacle::{Obstacle, OccupancyGrid};
use human2nav_core::{
    AgentState, ControllerGains, Limits, Observation, Plan, PlanError, PlanInfo, Pose2, Twist2,
};
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
