//! [`PluginEmbodiment`]: a plugin's embodiment behind core's [`Embodiment`], every answer
//! checked.

use super::*;

impl PluginHost {
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
pub(super) unsafe fn call_coupled_limit(
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
