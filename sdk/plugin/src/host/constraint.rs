//! [`PluginConstraint`]: a plugin's constraint term behind core's [`ConstraintTerm`].

use super::*;

impl PluginHost {
    /// Creates a constraint term from `library` (path resolved per [`crate::locate`]), whose
    /// calls run under [`deadline::DEFAULT_DEADLINE`].
    pub fn constraint(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<PluginConstraint, PluginError> {
        self.constraint_with_deadline(
            library,
            plugin,
            config,
            robot,
            Some(deadline::DEFAULT_DEADLINE),
        )
    }

    /// [`PluginHost::constraint`] with a deadline per `evaluate` call (`None`: none, calls run
    /// on the caller's thread; see [`crate::deadline`]).
    pub fn constraint_with_deadline(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
    ) -> Result<PluginConstraint, PluginError> {
        self.constraint_with_options(
            library,
            plugin,
            config,
            robot,
            deadline,
            PluginIsolation::InProcess,
        )
    }

    /// [`PluginHost::constraint_with_deadline`], in the host process or in a helper process of
    /// its own ([`PluginIsolation::Process`], see [`crate::process`]).
    pub fn constraint_with_options(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
        isolation: PluginIsolation,
    ) -> Result<PluginConstraint, PluginError> {
        if isolation == PluginIsolation::Process {
            let (mut client, name, health) = self.process_instance(
                PluginKind::Constraint,
                library,
                plugin,
                config,
                robot,
                deadline,
            )?;
            let separable_nonnegative =
                client
                    .separable_nonnegative()
                    .map_err(|message| PluginError::Process {
                        instance: format!("constraint `{plugin}` from {}", library.display()),
                        message,
                    })?;
            return Ok(PluginConstraint {
                name,
                health,
                deadline,
                separable_nonnegative,
                exec: ConstraintExec::Process(Mutex::new(client)),
            });
        }
        let c = self.instance::<H2nConstraintVTable>(library, plugin, config, robot)?;
        let evaluate = c.vtable.evaluate.ok_or_else(|| PluginError::NullSlot {
            path: library.to_path_buf(),
            table: format!("constraint vtable of `{plugin}`"),
            slot: "evaluate",
        })?;
        // Asked once, on this thread, as the factory was.
        // SAFETY: a live instance of the table the slot came from.
        let separable_nonnegative = unsafe { call_properties(c.vtable.properties, c.handle.ptr()) }
            .map_err(|status| PluginError::Malformed {
                path: library.to_path_buf(),
                message: format!(
                    "constraint `{plugin}`: properties returned {}: {}",
                    status_name(status),
                    c.handle.failure(status)
                ),
            })?;
        let health = Arc::clone(&c.handle.health);
        let core = ConstraintCore {
            handle: c.handle,
            evaluate,
        };
        let exec = match deadline {
            None => ConstraintExec::Direct(core),
            Some(_) => ConstraintExec::Worker(Slot::spawn(
                &c.name,
                &c.label,
                move |job: &mut Box<ConstraintJob>| core.run(job),
            )?),
        };
        Ok(PluginConstraint {
            name: c.name,
            health,
            deadline,
            separable_nonnegative,
            exec,
        })
    }
}

/// Calls a constraint's `properties` slot: whether it declares
/// [`H2N_CONSTRAINT_SEPARABLE_NONNEGATIVE`] (false without the slot), or the failed status.
///
/// # Safety
/// `instance` is a live instance of the vtable `f` came from.
pub(super) unsafe fn call_properties(
    f: Option<PropertiesFn>,
    instance: *mut c_void,
) -> Result<bool, H2nStatus> {
    let Some(f) = f else {
        return Ok(false);
    };
    let mut bits = 0u32;
    // SAFETY: live instance (the caller's contract), a valid output.
    let status = unsafe { f(instance, &mut bits) };
    if status != H2N_OK {
        return Err(status);
    }
    Ok(bits & H2N_CONSTRAINT_SEPARABLE_NONNEGATIVE != 0)
}

/// The functions of a constraint instance, with the instance.
struct ConstraintCore {
    handle: Handle,
    evaluate: EvaluateFn,
}

/// One `evaluate` call with every buffer the plugin may touch (so a call that outlives its
/// deadline writes only into memory it owns).
struct ConstraintJob {
    data: Vec<f64>,
    batch: usize,
    horizon: usize,
    dt: f64,
    limits: H2nLimits,
    initial_velocity: H2nTwist,
    agents: Vec<H2nAgent>,
    history: Vec<f64>,
    cost: Vec<f64>,
    grad: Vec<f64>,
    result: Result<(), (H2nStatus, String)>,
}

// SAFETY: the raw pointers in `agents` are null or point into the job's own `history` (set by
// `link_histories` on the thread that makes the call); the job moves between threads as a
// whole and is used by one thread at a time.
unsafe impl Send for ConstraintJob {}

impl ConstraintJob {
    fn new() -> Self {
        Self {
            data: Vec::new(),
            batch: 0,
            horizon: 0,
            dt: 0.0,
            limits: H2nLimits::default(),
            initial_velocity: H2nTwist::default(),
            agents: Vec::new(),
            history: Vec::new(),
            cost: Vec::new(),
            grad: Vec::new(),
            result: Ok(()),
        }
    }
}

impl ConstraintCore {
    /// Calls `evaluate`; on failure the status and the instance's message (read on this
    /// thread, right after the call).
    ///
    /// # Safety
    /// Every pointer in `batch`, `ctx`, `cost` and `grad` is valid for the call, the outputs
    /// of their stated lengths and distinct.
    unsafe fn call(
        &self,
        batch: &H2nTrajBatch,
        ctx: &H2nConstraintContext,
        cost: H2nF64Out,
        grad: H2nF64Out,
    ) -> Result<(), (H2nStatus, String)> {
        // SAFETY: live instance, checked function; forwarded contract for the pointers.
        let status = unsafe { (self.evaluate)(self.handle.ptr(), batch, ctx, cost, grad) };
        if status == H2N_OK {
            Ok(())
        } else {
            Err((status, self.handle.failure(status)))
        }
    }

    /// Runs a job on its own buffers (on the worker thread).
    fn run(&self, job: &mut ConstraintJob) {
        link_histories(&mut job.agents, &job.history);
        let batch = H2nTrajBatch {
            data: job.data.as_ptr(),
            len: job.data.len(),
            batch: job.batch,
            horizon: job.horizon,
            dim: 3,
        };
        let ctx = H2nConstraintContext {
            struct_size: std::mem::size_of::<H2nConstraintContext>() as u32,
            reserved: 0,
            dt: job.dt,
            limits: job.limits,
            initial_velocity: job.initial_velocity,
            agents: job.agents.as_ptr(),
            agent_count: job.agents.len(),
        };
        let cost = H2nF64Out {
            data: job.cost.as_mut_ptr(),
            len: job.cost.len(),
        };
        let grad = H2nF64Out {
            data: job.grad.as_mut_ptr(),
            len: job.grad.len(),
        };
        // SAFETY: every pointer points into the job, which this thread owns for the call.
        job.result = unsafe { self.call(&batch, &ctx, cost, grad) };
    }
}

enum ConstraintExec {
    /// No deadline: calls run on the caller's thread, on the caller's buffers.
    Direct(ConstraintCore),
    /// With a deadline: calls run on the instance's worker, one at a time.
    Worker(Mutex<Slot<ConstraintJob>>),
    /// In a helper process of its own, one call at a time.
    Process(Mutex<ProcessClient>),
}

/// A constraint term living in a plugin library.
pub struct PluginConstraint {
    name: String,
    health: Arc<Health>,
    deadline: Option<Duration>,
    /// What the instance declared through its `properties` slot.
    separable_nonnegative: bool,
    exec: ConstraintExec,
}

impl fmt::Debug for PluginConstraint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PluginConstraint")
            .field("name", &self.name)
            .field("health", &self.health)
            .field("deadline", &self.deadline)
            .finish()
    }
}

impl PluginConstraint {
    /// True once the plugin panicked or missed its deadline; the term then refuses to evaluate.
    pub fn is_poisoned(&self) -> bool {
        self.health.poisoned()
    }

    /// The deadline of each `evaluate` call (`None`: calls run on the caller's thread).
    pub fn deadline(&self) -> Option<Duration> {
        self.deadline
    }

    /// True when the term runs in a helper process of its own.
    pub fn in_own_process(&self) -> bool {
        matches!(self.exec, ConstraintExec::Process(_))
    }

    fn unusable(&self) -> ConstraintError {
        ConstraintError::Failed {
            term: self.name.clone(),
            message: format!(
                "unusable after an earlier failure: {}",
                self.health.message()
            ),
        }
    }

    /// Runs the call on the worker with copies of the caller's buffers.
    fn evaluate_on_worker(
        &self,
        slot: &Mutex<Slot<ConstraintJob>>,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<Result<(), (H2nStatus, String)>, ConstraintError> {
        let mut guard = slot.lock().unwrap_or_else(|e| e.into_inner());
        let slot = &mut *guard;
        // Another thread may have timed out while this one waited for the lock.
        if self.health.poisoned() {
            return Err(self.unusable());
        }
        let Some(worker) = slot.worker.as_ref() else {
            return Err(self.unusable());
        };
        let mut job = slot
            .spare
            .take()
            .unwrap_or_else(|| Box::new(ConstraintJob::new()));
        job.data.clear();
        job.data.extend_from_slice(batch.data);
        (job.batch, job.horizon) = (batch.batch, batch.horizon);
        job.dt = ctx.dt;
        job.limits = ctx.limits.into();
        job.initial_velocity = ctx.initial_velocity.into();
        load_agents(ctx.agents, &mut job.agents, &mut job.history);
        job.cost.clear();
        job.cost.extend_from_slice(cost);
        job.grad.clear();
        job.grad.extend_from_slice(grad);
        let deadline = self.deadline.unwrap_or(deadline::DEFAULT_DEADLINE);
        match worker.call(job, deadline) {
            Ok(mut job) => {
                cost.copy_from_slice(&job.cost);
                grad.copy_from_slice(&job.grad);
                let result = std::mem::replace(&mut job.result, Ok(()));
                slot.spare = Some(job);
                Ok(result)
            }
            Err(NoAnswer::TimedOut) => {
                slot.worker = None;
                let message = self.health.timed_out("evaluate", deadline);
                Err(ConstraintError::Failed {
                    term: self.name.clone(),
                    message,
                })
            }
            Err(NoAnswer::Gone) => {
                slot.worker = None;
                Err(ConstraintError::Failed {
                    term: self.name.clone(),
                    message: self.health.worker_gone(),
                })
            }
        }
    }
}

impl ConstraintTerm for PluginConstraint {
    fn name(&self) -> &str {
        &self.name
    }

    /// What the plugin declared ([`H2N_CONSTRAINT_SEPARABLE_NONNEGATIVE`]); false without a
    /// `properties` slot.
    fn separable_nonnegative(&self) -> bool {
        self.separable_nonnegative
    }

    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        let fail = |message: String| ConstraintError::Failed {
            term: self.name.clone(),
            message,
        };
        if self.health.poisoned() {
            return Err(self.unusable());
        }
        EvaluateBuffers {
            batch: batch.batch,
            horizon: batch.horizon,
            values: batch.data.len(),
            cost: cost.len(),
            grad: grad.len(),
        }
        .check()
        .map_err(ConstraintError::Shape)?;
        let result = match &self.exec {
            ConstraintExec::Direct(core) => {
                let agents: Vec<H2nAgent> = ctx.agents.iter().map(H2nAgent::borrow).collect();
                let abi_batch = H2nTrajBatch {
                    data: batch.data.as_ptr(),
                    len: batch.data.len(),
                    batch: batch.batch,
                    horizon: batch.horizon,
                    dim: 3,
                };
                let abi_ctx = H2nConstraintContext {
                    struct_size: std::mem::size_of::<H2nConstraintContext>() as u32,
                    reserved: 0,
                    dt: ctx.dt,
                    limits: ctx.limits.into(),
                    initial_velocity: ctx.initial_velocity.into(),
                    agents: agents.as_ptr(),
                    agent_count: agents.len(),
                };
                let c = H2nF64Out {
                    data: cost.as_mut_ptr(),
                    len: cost.len(),
                };
                let g = H2nF64Out {
                    data: grad.as_mut_ptr(),
                    len: grad.len(),
                };
                // SAFETY: every pointer is valid for the call; the outputs are distinct
                // host-owned slices of the stated lengths.
                unsafe { core.call(&abi_batch, &abi_ctx, c, g) }
            }
            ConstraintExec::Worker(slot) => {
                self.evaluate_on_worker(slot, batch, ctx, cost, grad)?
            }
            ConstraintExec::Process(client) => {
                let mut client = client.lock().unwrap_or_else(|e| e.into_inner());
                return match client.evaluate(batch, ctx, cost, grad) {
                    Ok(answer) => answer,
                    Err(message) => {
                        if client.dead().is_some() {
                            self.health.poison(&message);
                        }
                        Err(fail(message))
                    }
                };
            }
        };
        result.map_err(|(status, message)| match status {
            H2N_INVALID_ARGUMENT => ConstraintError::Shape(message),
            H2N_PANIC => fail(format!("panicked (the term is now unusable): {message}")),
            H2N_POISONED => fail(format!("unusable after an earlier panic: {message}")),
            _ => fail(message),
        })
    }
}
