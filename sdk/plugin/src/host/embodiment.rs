//! [`PluginEmbodiment`]: a plugin's embodiment behind core's [`Embodiment`], every answer
//! checked, every call under a deadline (a worker thread in this process, or the helper
//! process's client).

use super::*;
use crate::process::{EmbodimentCall, EmbodimentValue};
use std::borrow::Cow;

impl PluginHost {
    /// Creates an embodiment for a robot with these limits and gains, in this process, whose
    /// calls run under [`deadline::DEFAULT_DEADLINE`].
    pub fn embodiment(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: &RobotContext,
    ) -> Result<PluginEmbodiment, PluginError> {
        self.embodiment_with_deadline(
            library,
            plugin,
            config,
            robot,
            Some(deadline::DEFAULT_DEADLINE),
        )
    }

    /// [`PluginHost::embodiment`] with a deadline per call (`None`: none, calls run on the
    /// caller's thread; see [`crate::deadline`]).
    pub fn embodiment_with_deadline(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: &RobotContext,
        deadline: Option<Duration>,
    ) -> Result<PluginEmbodiment, PluginError> {
        self.embodiment_with_options(
            library,
            plugin,
            config,
            robot,
            deadline,
            PluginIsolation::InProcess,
        )
    }

    /// [`PluginHost::embodiment_with_deadline`], in the host process or in a helper process of
    /// its own ([`PluginIsolation::Process`], see [`crate::process`]). The plugin's coupled
    /// limit is asked for once here, under the deadline.
    pub fn embodiment_with_options(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: &RobotContext,
        deadline: Option<Duration>,
        isolation: PluginIsolation,
    ) -> Result<PluginEmbodiment, PluginError> {
        if isolation == PluginIsolation::Process {
            return self.embodiment_in_helper(library, plugin, config, robot, deadline);
        }
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
            coupled_limit: c.vtable.coupled_limit,
        };
        let health = Arc::clone(&c.handle.health);
        let core = EmbodimentCore {
            handle: c.handle,
            fns,
        };
        let exec = match deadline {
            None => EmbodimentExec::Direct(core),
            Some(_) => EmbodimentExec::Worker(Slot::spawn(
                &c.name,
                &c.label,
                move |job: &mut Box<EmbodimentJob>| core.run(job),
            )?),
        };
        let mut e = PluginEmbodiment {
            name: c.name,
            health,
            deadline,
            coupled: None,
            exec,
        };
        let mut job = EmbodimentJob::new(&EmbodimentCall::CoupledLimit);
        match e.run_in_process(&mut job, "coupled_limit") {
            Some(()) if job.status == H2N_OK => {}
            Some(()) => {
                return Err(PluginError::Malformed {
                    path: library.to_path_buf(),
                    message: format!("embodiment `{plugin}`: {}", job.message),
                });
            }
            None => {
                return Err(PluginError::Probe {
                    path: library.to_path_buf(),
                    kind: PluginKind::Embodiment,
                    name: plugin.to_owned(),
                    message: e.health.message(),
                });
            }
        }
        e.coupled = job.coupled;
        Ok(e)
    }

    /// An embodiment in a helper process: started, then asked for its coupled limit.
    fn embodiment_in_helper(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: &RobotContext,
        deadline: Option<Duration>,
    ) -> Result<PluginEmbodiment, PluginError> {
        let (mut client, name, health) = self.process_instance(
            PluginKind::Embodiment,
            library,
            plugin,
            config,
            Some(robot),
            deadline,
        )?;
        let process = |message: String| PluginError::Process {
            instance: format!("embodiment `{plugin}` from {}", library.display()),
            message,
        };
        let coupled = match client.embodiment(&EmbodimentCall::CoupledLimit) {
            Ok((EmbodimentValue::CoupledLimit(c), None)) => c,
            Ok((_, Some(failure))) => return Err(process(failure)),
            Ok((other, None)) => {
                return Err(process(format!(
                    "it answered `coupled_limit` with {other:?}"
                )));
            }
            Err(message) => return Err(process(message)),
        };
        Ok(PluginEmbodiment {
            name,
            health,
            deadline,
            coupled,
            exec: EmbodimentExec::Process(Mutex::new(client)),
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
    coupled_limit: Option<CoupledLimitFn>,
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

/// The functions of an embodiment instance, with the instance.
struct EmbodimentCore {
    handle: Handle,
    fns: EmbodimentFns,
}

/// Which embodiment call a job makes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Op {
    Holonomic,
    Saturate,
    Step,
    Track,
    CoupledLimit,
}

/// One embodiment call with every buffer the plugin may touch (so a call that outlives its
/// deadline writes only into memory it owns), and its answer.
struct EmbodimentJob {
    op: Op,
    state: H2nRobotState,
    cmd: H2nTwist,
    dt: f64,
    t: f64,
    plan_t0: f64,
    plan_dt: f64,
    poses: Vec<H2nPose>,
    /// The call's status; when it is not OK, `message` says why (the instance's last error,
    /// read on the thread that called, or what was wrong with a coupled limit).
    status: H2nStatus,
    message: String,
    holonomic: u32,
    twist: H2nTwist,
    next: H2nRobotState,
    coupled: Option<CoupledLimit>,
}

impl EmbodimentJob {
    fn new(call: &EmbodimentCall<'_>) -> Self {
        let mut job = Self {
            op: Op::Holonomic,
            state: H2nRobotState::default(),
            cmd: H2nTwist::default(),
            dt: 0.0,
            t: 0.0,
            plan_t0: 0.0,
            plan_dt: 0.0,
            poses: Vec::new(),
            status: H2N_OK,
            message: String::new(),
            holonomic: 0,
            twist: H2nTwist::default(),
            next: H2nRobotState::default(),
            coupled: None,
        };
        job.load(call);
        job
    }

    /// Copies a call's inputs into the job.
    fn load(&mut self, call: &EmbodimentCall<'_>) {
        match call {
            EmbodimentCall::Holonomic => self.op = Op::Holonomic,
            EmbodimentCall::CoupledLimit => self.op = Op::CoupledLimit,
            EmbodimentCall::Saturate { state, cmd, dt }
            | EmbodimentCall::Step { state, cmd, dt } => {
                self.op = if matches!(call, EmbodimentCall::Saturate { .. }) {
                    Op::Saturate
                } else {
                    Op::Step
                };
                self.state = H2nRobotState::from(state);
                self.cmd = H2nTwist::from(*cmd);
                self.dt = *dt;
            }
            EmbodimentCall::Track { state, plan, t } => {
                self.op = Op::Track;
                self.state = H2nRobotState::from(state);
                self.plan_t0 = plan.t0;
                self.plan_dt = plan.dt;
                self.poses.clear();
                self.poses
                    .extend(plan.poses.iter().map(|&p| H2nPose::from(p)));
                self.t = *t;
            }
        }
    }

    /// The answer of an OK call.
    fn value(&self) -> EmbodimentValue {
        match self.op {
            Op::Holonomic => EmbodimentValue::Holonomic(self.holonomic != 0),
            Op::Step => EmbodimentValue::State(RobotState {
                pose: self.next.pose.into(),
                velocity: self.next.velocity.into(),
            }),
            Op::CoupledLimit => EmbodimentValue::CoupledLimit(self.coupled),
            Op::Saturate | Op::Track => EmbodimentValue::Twist(self.twist.into()),
        }
    }
}

impl EmbodimentCore {
    /// Runs a job on its own buffers (on the worker thread, or the caller's without deadline).
    fn run(&self, job: &mut EmbodimentJob) {
        job.message.clear();
        let ptr = self.handle.ptr();
        // SAFETY (every call): live instance (the ABI lets embodiment instances take concurrent
        // calls), checked function, pointers into the job, which this thread owns for the call.
        job.status = match job.op {
            Op::Holonomic => unsafe { (self.fns.holonomic)(ptr, &mut job.holonomic) },
            Op::Saturate => unsafe {
                (self.fns.saturate)(ptr, &job.state, &job.cmd, job.dt, &mut job.twist)
            },
            Op::Step => unsafe {
                (self.fns.step)(ptr, &job.state, &job.cmd, job.dt, &mut job.next)
            },
            Op::Track => {
                let view = H2nPlanView {
                    t0: job.plan_t0,
                    dt: job.plan_dt,
                    poses: job.poses.as_ptr(),
                    pose_count: job.poses.len(),
                };
                unsafe { (self.fns.track)(ptr, &job.state, &view, job.t, &mut job.twist) }
            }
            Op::CoupledLimit => match self.fns.coupled_limit {
                None => {
                    job.coupled = None;
                    H2N_OK
                }
                Some(f) => match unsafe { call_coupled_limit(f, ptr) } {
                    Ok(c) => {
                        job.coupled = c;
                        H2N_OK
                    }
                    Err(Ok(message)) => {
                        job.message = message;
                        H2N_ERROR
                    }
                    Err(Err(status)) => {
                        job.message = format!("coupled_limit: {}", self.last_error(status));
                        status
                    }
                },
            },
        };
        if job.status != H2N_OK && job.message.is_empty() {
            job.message = self.last_error(job.status);
        }
    }

    /// The instance's last error, or the status's name when it has none.
    fn last_error(&self, status: H2nStatus) -> String {
        let message = self.handle.last_error();
        if message.is_empty() {
            status_name(status).to_owned()
        } else {
            message
        }
    }
}

enum EmbodimentExec {
    /// No deadline: calls run on the caller's thread, concurrently when the caller's are.
    Direct(EmbodimentCore),
    /// With a deadline: calls run on the instance's worker, one at a time.
    Worker(Mutex<Slot<EmbodimentJob>>),
    /// In a helper process of its own, one call at a time.
    Process(Mutex<ProcessClient>),
}

/// Largest yaw rate an embodiment plugin may answer (rad/s): 16 turns a second, far past any
/// robot, so that only a broken value is refused.
pub const MAX_EMBODIMENT_YAW_RATE: f64 = 100.0;

/// An embodiment living in a plugin library.
///
/// The [`Embodiment`] methods cannot return errors; when the plugin fails, panics, misses its
/// deadline, answers a value out of range or (in a helper process) dies, the proxy returns the
/// safe value (zero command; robot halted where it is) and records the failure, naming the
/// call (see [`PluginEmbodiment::failure`] and [`PluginHost::failures`]). After that every call
/// returns the safe value at once.
pub struct PluginEmbodiment {
    name: String,
    health: Arc<Health>,
    deadline: Option<Duration>,
    coupled: Option<CoupledLimit>,
    exec: EmbodimentExec,
}

impl fmt::Debug for PluginEmbodiment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PluginEmbodiment")
            .field("name", &self.name)
            .field("health", &self.health)
            .field("deadline", &self.deadline)
            .finish()
    }
}

impl PluginEmbodiment {
    /// The failure that made this embodiment unusable, if any.
    pub fn failure(&self) -> Option<String> {
        self.health.poisoned().then(|| self.health.message())
    }

    /// The deadline of each call (`None`: calls run on the caller's thread, or wait for the
    /// helper process without a limit).
    pub fn deadline(&self) -> Option<Duration> {
        self.deadline
    }

    /// True when the instance runs in a helper process of its own.
    pub fn in_own_process(&self) -> bool {
        matches!(self.exec, EmbodimentExec::Process(_))
    }

    /// Runs a job in this process, on this thread or on the worker under the deadline;
    /// `None` when no answer came (the deadline passed or the worker is gone: the instance is
    /// then marked dead).
    fn run_in_process(&self, job: &mut EmbodimentJob, call: &str) -> Option<()> {
        match &self.exec {
            EmbodimentExec::Direct(core) => {
                core.run(job);
                Some(())
            }
            EmbodimentExec::Worker(slot) => {
                let mut guard = slot.lock().unwrap_or_else(|e| e.into_inner());
                let slot = &mut *guard;
                // Another thread may have timed out while this one waited for the lock.
                if self.health.poisoned() {
                    return None;
                }
                let worker = slot.worker.as_ref()?;
                let mut boxed = slot
                    .spare
                    .take()
                    .unwrap_or_else(|| Box::new(EmbodimentJob::new(&EmbodimentCall::Holonomic)));
                std::mem::swap(&mut *boxed, job);
                let deadline = self.deadline.unwrap_or(deadline::DEFAULT_DEADLINE);
                match worker.call(boxed, deadline) {
                    Ok(mut boxed) => {
                        std::mem::swap(&mut *boxed, job);
                        slot.spare = Some(boxed);
                        Some(())
                    }
                    Err(NoAnswer::TimedOut) => {
                        slot.worker = None;
                        self.health.timed_out(call, deadline);
                        None
                    }
                    Err(NoAnswer::Gone) => {
                        slot.worker = None;
                        self.health.worker_gone();
                        None
                    }
                }
            }
            EmbodimentExec::Process(_) => None,
        }
    }

    /// Makes a call; `None` when it failed (the failure is recorded and the instance is dead).
    fn call(&self, call: EmbodimentCall<'_>) -> Option<EmbodimentValue> {
        if self.health.poisoned() {
            return None;
        }
        if let EmbodimentExec::Process(client) = &self.exec {
            let mut client = client.lock().unwrap_or_else(|e| e.into_inner());
            return match client.embodiment(&call) {
                Ok((value, None)) => Some(value),
                Ok((_, Some(failure))) | Err(failure) => {
                    self.health.poison(&failure);
                    None
                }
            };
        }
        let mut job = EmbodimentJob::new(&call);
        self.run_in_process(&mut job, call.name())?;
        if job.status != H2N_OK {
            self.health.poison(&format!(
                "embodiment `{}`: `{}` failed: {}; the robot is halted",
                self.name,
                call.name(),
                job.message
            ));
            return None;
        }
        Some(job.value())
    }

    /// Checks what a `saturate`, `step` or `track` call answered, every call: a pose within
    /// [`MAX_COORDINATE`](human2nav_core::planner::MAX_COORDINATE) m of the origin with a finite
    /// heading, speeds within [`MAX_SPEED`](human2nav_core::planner::MAX_SPEED) m/s and a yaw
    /// rate within [`MAX_EMBODIMENT_YAW_RATE`]. A value outside poisons the embodiment with a
    /// message naming the call and the field (the caller then halts the robot); `None`.
    fn checked(&self, call: &str, pose: Option<Pose2>, twist: Twist2) -> Option<()> {
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
            self.health.poison(&message);
            return None;
        }
        Some(())
    }

    /// A twist answer, checked; the zero twist after a failure.
    fn twist(&self, call: EmbodimentCall<'_>) -> Twist2 {
        let name = call.name();
        match self.call(call) {
            Some(EmbodimentValue::Twist(t)) if self.checked(name, None, t).is_some() => t,
            _ => Twist2::ZERO,
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
        matches!(
            self.call(EmbodimentCall::Holonomic),
            Some(EmbodimentValue::Holonomic(true))
        )
    }

    fn saturate(&self, state: &RobotState, cmd: Twist2, dt: f64) -> Twist2 {
        self.twist(EmbodimentCall::Saturate {
            state: *state,
            cmd,
            dt,
        })
    }

    fn step(&self, state: &RobotState, cmd: Twist2, dt: f64) -> RobotState {
        let halted = RobotState {
            pose: state.pose,
            velocity: Twist2::ZERO,
        };
        match self.call(EmbodimentCall::Step {
            state: *state,
            cmd,
            dt,
        }) {
            Some(EmbodimentValue::State(next))
                if self
                    .checked("step", Some(next.pose), next.velocity)
                    .is_some() =>
            {
                next
            }
            _ => halted,
        }
    }

    fn track(&self, state: &RobotState, plan: &Plan, t: f64) -> Twist2 {
        self.twist(EmbodimentCall::Track {
            state: *state,
            plan: Cow::Borrowed(plan),
            t,
        })
    }
}
