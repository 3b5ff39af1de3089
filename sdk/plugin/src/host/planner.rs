//! [`PluginPlanner`]: a plugin's planner behind core's [`Planner`], and what the host writes
//! into its observation (ABI version 2: obstacles and the occupancy grid).

use super::*;

impl PluginHost {
    /// Creates a planner, optionally for a given robot, whose calls run under
    /// [`deadline::DEFAULT_DEADLINE`].
    pub fn planner(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
    ) -> Result<PluginPlanner, PluginError> {
        self.planner_with_deadline(
            library,
            plugin,
            config,
            robot,
            Some(deadline::DEFAULT_DEADLINE),
        )
    }

    /// [`PluginHost::planner`] with a deadline per `plan`/`reset` call (`None`: none, calls run
    /// on the caller's thread; see [`crate::deadline`]).
    pub fn planner_with_deadline(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
    ) -> Result<PluginPlanner, PluginError> {
        self.planner_with_options(
            library,
            plugin,
            config,
            robot,
            deadline,
            PluginIsolation::InProcess,
        )
    }

    /// [`PluginHost::planner_with_deadline`], in the host process or in a helper process of its
    /// own ([`PluginIsolation::Process`], see [`crate::process`]).
    pub fn planner_with_options(
        &self,
        library: &Path,
        plugin: &str,
        config: &str,
        robot: Option<&RobotContext>,
        deadline: Option<Duration>,
        isolation: PluginIsolation,
    ) -> Result<PluginPlanner, PluginError> {
        if isolation == PluginIsolation::Process {
            let (client, name, health) = self.process_instance(
                PluginKind::Planner,
                library,
                plugin,
                config,
                robot,
                deadline,
            )?;
            return Ok(PluginPlanner {
                name,
                health,
                deadline,
                exec: PlannerExec::Process(client),
                spare: None,
                horizon: human2nav_core::trajectory::DEFAULT_HORIZON,
            });
        }
        let c = self.instance::<H2nPlannerVTable>(library, plugin, config, robot)?;
        let null = |slot: &'static str| PluginError::NullSlot {
            path: library.to_path_buf(),
            table: format!("planner vtable of `{plugin}`"),
            slot,
        };
        let mut core = PlannerCore {
            abi_version: c.handle.library.abi_version,
            reset: c.vtable.reset,
            plan: c.vtable.plan.ok_or_else(|| null("plan"))?,
            last_plan: c.vtable.last_plan.ok_or_else(|| null("last_plan"))?,
            handle: c.handle,
        };
        let health = Arc::clone(&core.handle.health);
        let exec = match deadline {
            None => PlannerExec::Direct(core),
            Some(_) => PlannerExec::Worker(Some(
                Worker::spawn(thread_name(&c.name), move |job: &mut Box<PlanJob>| {
                    core.run(job)
                })
                .map_err(|e| worker_error(&c.label, e))?,
            )),
        };
        Ok(PluginPlanner {
            name: c.name,
            health,
            deadline,
            exec,
            spare: None,
            horizon: human2nav_core::trajectory::DEFAULT_HORIZON,
        })
    }
}

/// Copies an observation's obstacles and occupancy grid into a job's ABI records (vertex and
/// cell pointers left null; [`PlannerCore::plan`] links them on the thread that calls).
fn load_obstacles(obs: &Observation, job: &mut PlanJob) {
    job.obstacles.clear();
    job.vertices.clear();
    for o in &obs.obstacles {
        let mut r = H2nObstacle {
            kind: H2N_OBSTACLE_CIRCLE,
            reserved: 0,
            x0: 0.0,
            y0: 0.0,
            x1: 0.0,
            y1: 0.0,
            radius: 0.0,
            vertices: std::ptr::null(),
            vertex_count: 0,
        };
        match o {
            Obstacle::Circle { center, radius } => {
                [r.x0, r.y0] = *center;
                r.radius = *radius;
            }
            Obstacle::Segment { a, b } => {
                r.kind = H2N_OBSTACLE_SEGMENT;
                [r.x0, r.y0] = *a;
                [r.x1, r.y1] = *b;
            }
            Obstacle::Polygon { vertices } => {
                r.kind = H2N_OBSTACLE_POLYGON;
                r.vertex_count = vertices.len();
                job.vertices.extend(vertices.iter().flatten());
            }
        }
        job.obstacles.push(r);
    }
    job.cells.clear();
    job.occupancy = obs.occupancy.as_ref().map(|g| {
        job.cells.extend_from_slice(&g.data);
        H2nOccupancyGrid {
            origin: g.origin.into(),
            resolution: g.resolution,
            width: g.width,
            height: g.height,
            data: std::ptr::null(),
            occupied_threshold: i32::from(g.occupied_threshold),
            reserved: 0,
        }
    });
}

/// Points each polygon's `vertices` into `vertices` (filled by [`load_obstacles`]).
fn link_vertices(obstacles: &mut [H2nObstacle], vertices: &[f64]) {
    let mut at = 0;
    for o in obstacles
        .iter_mut()
        .filter(|o| o.kind == H2N_OBSTACLE_POLYGON)
    {
        let n = 2 * o.vertex_count;
        o.vertices = vertices
            .get(at..at + n)
            .map_or(std::ptr::null(), <[f64]>::as_ptr);
        at += n;
    }
}

/// The note on a version-1 plugin's plan when the observation had what it cannot see.
fn unseen_by_v1(obstacles: usize, grid: bool) -> Option<String> {
    let what = match (obstacles, grid) {
        (0, false) => return None,
        (0, true) => "the occupancy grid".to_string(),
        (n, false) => format!("{n} static obstacle(s)"),
        (n, true) => format!("{n} static obstacle(s) and the occupancy grid"),
    };
    Some(format!(
        "plugin ABI version 1: {what} not passed to the planner (version 2 carries them)"
    ))
}

/// The functions of a planner instance, with the instance.
struct PlannerCore {
    handle: Handle,
    /// The library's ABI version: from 2 on the observation carries obstacles.
    abi_version: u32,
    reset: Option<ResetFn>,
    plan: PlanFn,
    last_plan: LastPlanFn,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PlanOp {
    Plan,
    Reset,
}

/// One `plan` or `reset` call with every buffer the plugin may touch.
struct PlanJob {
    op: PlanOp,
    time: f64,
    ego: H2nPose,
    ego_velocity: H2nTwist,
    goal: [f64; 2],
    agents: Vec<H2nAgent>,
    history: Vec<f64>,
    /// Static obstacles (polygon vertex pointers left null, see [`link_vertices`]) and the
    /// polygons' vertices.
    obstacles: Vec<H2nObstacle>,
    vertices: Vec<f64>,
    /// The occupancy grid (its `data` pointer left null) and its cells.
    occupancy: Option<H2nOccupancyGrid>,
    cells: Vec<i8>,
    /// Obstacles and grid a version-1 plugin was not given (a note on its plan).
    unseen: Option<String>,
    /// Plan buffer (grows to the longest plan seen, at most [`MAX_PLAN_POSES`]).
    poses: Vec<H2nPose>,
    note: Vec<u8>,
    /// The call's status, with the instance's message when it is not OK.
    status: H2nStatus,
    message: String,
    /// A problem the host found with an OK answer (a plan longer than its buffer or the cap).
    problem: Option<String>,
    t0: f64,
    dt: f64,
    len: usize,
    fallback: bool,
    note_len: usize,
}

// SAFETY: as for `ConstraintJob`: the pointers in `agents` point into the job's own `history`,
// those in `obstacles` into its own `vertices` (the grid's `data`, into `cells`, is set only in
// the local observation of the call).
unsafe impl Send for PlanJob {}

impl PlanJob {
    fn new() -> Self {
        Self {
            op: PlanOp::Plan,
            time: 0.0,
            ego: H2nPose::default(),
            ego_velocity: H2nTwist::default(),
            goal: [0.0; 2],
            agents: Vec::new(),
            history: Vec::new(),
            obstacles: Vec::new(),
            vertices: Vec::new(),
            occupancy: None,
            cells: Vec::new(),
            unseen: None,
            poses: Vec::new(),
            note: Vec::new(),
            status: H2N_OK,
            message: String::new(),
            problem: None,
            t0: 0.0,
            dt: 0.0,
            len: 0,
            fallback: false,
            note_len: 0,
        }
    }
}

impl PlannerCore {
    /// Runs a job on its own buffers (on the worker thread, or the caller's without deadline).
    fn run(&mut self, job: &mut PlanJob) {
        job.message.clear();
        job.problem = None;
        match job.op {
            PlanOp::Reset => {
                job.status = match self.reset {
                    // SAFETY: live instance (exclusive: one thread at a time), checked function.
                    Some(reset) => unsafe { reset(self.handle.ptr()) },
                    None => H2N_OK,
                };
                if job.status != H2N_OK {
                    job.message = self.handle.failure(job.status);
                }
            }
            PlanOp::Plan => self.plan(job),
        }
    }

    fn plan(&mut self, job: &mut PlanJob) {
        link_histories(&mut job.agents, &job.history);
        link_vertices(&mut job.obstacles, &job.vertices);
        let occupancy = job.occupancy.map(|mut g| {
            g.data = job.cells.as_ptr();
            g
        });
        // A version-1 plugin reads the prefix before `obstacles`; it is told nothing more.
        job.unseen = (self.abi_version < OBSTACLES_SINCE)
            .then(|| unseen_by_v1(job.obstacles.len(), occupancy.is_some()))
            .flatten();
        let obs = H2nObservation {
            struct_size: std::mem::size_of::<H2nObservation>() as u32,
            reserved: 0,
            time: job.time,
            ego: job.ego,
            ego_velocity: job.ego_velocity,
            goal: job.goal,
            agents: job.agents.as_ptr(),
            agent_count: job.agents.len(),
            obstacles: if job.obstacles.is_empty() {
                std::ptr::null()
            } else {
                job.obstacles.as_ptr()
            },
            obstacle_count: job.obstacles.len(),
            occupancy: occupancy
                .as_ref()
                .map_or(std::ptr::null(), std::ptr::from_ref),
        };
        if job.poses.len() < 64 {
            job.poses.resize(64, H2nPose::default());
        }
        if job.note.len() < 256 {
            job.note.resize(256, 0);
        }
        let mut out = plan_out(&mut job.poses, &mut job.note);
        // SAFETY: live instance (one call at a time), checked function; the observation and the
        // host-owned buffers live in the job for the whole call.
        let mut status = unsafe { (self.plan)(self.handle.ptr(), &obs, &mut out) };
        if status == H2N_BUFFER_TOO_SMALL && out.len > job.poses.len() {
            if out.len > MAX_PLAN_POSES {
                job.status = H2N_ERROR;
                job.problem = Some(format!(
                    "it returned a plan of {} poses, more than the {MAX_PLAN_POSES} this host \
                     accepts",
                    out.len
                ));
                return;
            }
            job.poses.resize(out.len, H2nPose::default());
            out = plan_out(&mut job.poses, &mut job.note);
            // SAFETY: as above.
            status = unsafe { (self.last_plan)(self.handle.ptr(), &mut out) };
        }
        job.status = status;
        if status != H2N_OK {
            job.message = self.handle.failure(status);
            return;
        }
        if out.len > out.capacity {
            job.status = H2N_ERROR;
            job.problem = Some(format!(
                "it reported a plan of {} poses in a buffer of {}",
                out.len, out.capacity
            ));
            return;
        }
        job.t0 = out.t0;
        job.dt = out.dt;
        job.len = out.len;
        job.fallback = out.fallback != 0;
        job.note_len = out.note.len;
    }
}

fn plan_out(poses: &mut [H2nPose], note: &mut [u8]) -> H2nPlanOut {
    H2nPlanOut {
        t0: 0.0,
        dt: 0.0,
        poses: poses.as_mut_ptr(),
        capacity: poses.len(),
        len: 0,
        fallback: 0,
        reserved: 0,
        note: H2nBuffer {
            data: note.as_mut_ptr(),
            capacity: note.len(),
            len: 0,
        },
    }
}

enum PlannerExec {
    /// No deadline: calls run on the caller's thread.
    Direct(PlannerCore),
    /// With a deadline: calls run on the instance's worker; `None` once it missed one.
    Worker(Option<Worker<Box<PlanJob>>>),
    /// In a helper process of its own.
    Process(ProcessClient),
}

/// A planner living in a plugin library.
///
/// With a deadline ([`PluginHost::planner`] sets [`deadline::DEFAULT_DEADLINE`]) a `plan` call
/// that does not return in time gives the safe plan (stop in place, flagged as a fallback, with
/// [`PlanInfo::error`] saying why), logs a line on stderr and marks the planner dead: every
/// later call fails at once with [`PlanError::Unusable`].
pub struct PluginPlanner {
    name: String,
    health: Arc<Health>,
    deadline: Option<Duration>,
    exec: PlannerExec,
    /// The buffers of the call not in flight.
    spare: Option<Box<PlanJob>>,
    /// Length of the last plan (of the safe plan after a missed deadline).
    horizon: usize,
}

impl fmt::Debug for PluginPlanner {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PluginPlanner")
            .field("name", &self.name)
            .field("health", &self.health)
            .field("deadline", &self.deadline)
            .finish()
    }
}

impl PluginPlanner {
    /// The deadline of each call (`None`: calls run on the caller's thread).
    pub fn deadline(&self) -> Option<Duration> {
        self.deadline
    }

    /// True once the planner panicked or missed its deadline.
    pub fn is_poisoned(&self) -> bool {
        self.health.poisoned()
    }

    /// Runs a job; `Err` when the deadline passed (the planner is then dead) or the worker is
    /// gone.
    fn execute(&mut self, fill: impl FnOnce(&mut PlanJob)) -> Result<Box<PlanJob>, NoAnswer> {
        let mut job = self
            .spare
            .take()
            .unwrap_or_else(|| Box::new(PlanJob::new()));
        fill(&mut job);
        match &mut self.exec {
            PlannerExec::Direct(core) => {
                core.run(&mut job);
                Ok(job)
            }
            PlannerExec::Worker(worker) => {
                let Some(w) = worker.as_ref() else {
                    return Err(NoAnswer::Gone);
                };
                let answer = w.call(job, self.deadline.unwrap_or(deadline::DEFAULT_DEADLINE));
                if answer.is_err() {
                    // Let go of the worker: it ends (and destroys the instance) if the call
                    // ever returns.
                    *worker = None;
                }
                answer
            }
            // Process calls never come here (see `plan` and `reset`).
            PlannerExec::Process(_) => Err(NoAnswer::Gone),
        }
    }

    /// Restarts of the helper process so far (`None` for an instance in the host process).
    pub fn process_restarts(&self) -> Option<u32> {
        match &self.exec {
            PlannerExec::Process(c) => Some(c.restarts()),
            _ => None,
        }
    }

    /// `plan` in the helper process: a dead or hung process gives the stop-in-place plan with
    /// [`PlanInfo::error`] set; after the last restart the planner is unusable.
    fn plan_in_process(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        let PlannerExec::Process(client) = &mut self.exec else {
            return Err(PlanError::Unusable {
                planner: self.name.clone(),
                message: "not an out-of-process planner".into(),
            });
        };
        match client.plan(obs) {
            Ok(Ok(plan)) => {
                self.horizon = plan.poses.len().max(1);
                Ok(plan)
            }
            Ok(Err(e)) => Err(e),
            Err(why) => {
                if client.dead().is_some() {
                    self.health.poison(&why);
                }
                let mut plan = Plan::stop_in_place(
                    obs,
                    human2nav_core::trajectory::DEFAULT_DT,
                    self.horizon,
                    why.clone(),
                );
                plan.info.error = Some(why);
                Ok(plan)
            }
        }
    }

    /// What a missed deadline or a lost worker means for the instance.
    fn no_answer(&self, e: NoAnswer, call: &str) -> String {
        match e {
            NoAnswer::TimedOut => self
                .health
                .timed_out(call, self.deadline.unwrap_or(deadline::DEFAULT_DEADLINE)),
            NoAnswer::Gone if self.health.poisoned() => self.health.message(),
            NoAnswer::Gone => self.health.worker_gone(),
        }
    }

    fn error(&self, job: &PlanJob) -> PlanError {
        let planner = self.name.clone();
        if let Some(problem) = &job.problem {
            return PlanError::Failed {
                planner,
                message: problem.clone(),
            };
        }
        let message = job.message.clone();
        match job.status {
            H2N_INVALID_ARGUMENT => PlanError::InvalidObservation(message),
            H2N_PANIC => PlanError::Failed {
                planner,
                message: format!("panicked (the planner is now unusable): {message}"),
            },
            H2N_POISONED => PlanError::Unusable { planner, message },
            _ => PlanError::Failed { planner, message },
        }
    }
}

impl Planner for PluginPlanner {
    fn name(&self) -> &str {
        &self.name
    }

    fn reset(&mut self) {
        if self.health.poisoned() {
            return;
        }
        if let PlannerExec::Process(client) = &mut self.exec {
            // The trait's reset cannot fail: a failure is recorded and the next call restarts
            // the process (or reports the dead instance).
            if let Err(why) = client.reset() {
                if client.dead().is_some() {
                    self.health.poison(&why);
                }
            }
            return;
        }
        match self.execute(|job| job.op = PlanOp::Reset) {
            Ok(job) => {
                if job.status != H2N_OK {
                    // The trait's reset cannot fail; the next `plan` reports the unusable
                    // planner.
                    self.health.poison(&job.message);
                }
                self.spare = Some(job);
            }
            Err(e) => {
                self.no_answer(e, "reset");
            }
        }
    }

    fn plan(&mut self, obs: &Observation) -> Result<Plan, PlanError> {
        if self.health.poisoned() {
            return Err(PlanError::Unusable {
                planner: self.name.clone(),
                message: self.health.message(),
            });
        }
        obs.validate()?;
        if matches!(self.exec, PlannerExec::Process(_)) {
            return self.plan_in_process(obs);
        }
        let job = match self.execute(|job| {
            job.op = PlanOp::Plan;
            job.time = obs.time;
            job.ego = obs.ego.into();
            job.ego_velocity = obs.ego_velocity.into();
            job.goal = obs.goal;
            load_agents(&obs.agents, &mut job.agents, &mut job.history);
            load_obstacles(obs, job);
        }) {
            Ok(job) => job,
            Err(NoAnswer::TimedOut) => {
                let why = self.no_answer(NoAnswer::TimedOut, "plan");
                let mut plan = Plan::stop_in_place(
                    obs,
                    human2nav_core::trajectory::DEFAULT_DT,
                    self.horizon,
                    why.clone(),
                );
                plan.info.error = Some(why);
                return Ok(plan);
            }
            Err(e) => {
                return Err(PlanError::Unusable {
                    planner: self.name.clone(),
                    message: self.no_answer(e, "plan"),
                });
            }
        };
        let result = if job.status != H2N_OK {
            Err(self.error(&job))
        } else {
            let n = job.len.min(job.poses.len());
            let note = buffer_text(&job.note, job.note_len);
            let notes = [Some(note).filter(|n| !n.is_empty()), job.unseen.clone()]
                .into_iter()
                .flatten()
                .collect();
            let plan = Plan {
                t0: job.t0,
                dt: job.dt,
                poses: job.poses[..n].iter().map(|&p| Pose2::from(p)).collect(),
                info: PlanInfo {
                    fallback: job.fallback,
                    notes,
                    ..PlanInfo::default()
                },
            };
            if !plan.is_finite() || plan.poses.is_empty() {
                Err(PlanError::Failed {
                    planner: self.name.clone(),
                    message: "the plugin returned an empty or non-finite plan".into(),
                })
            } else {
                self.horizon = plan.poses.len();
                Ok(plan)
            }
        };
        self.spare = Some(job);
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the host writes for a version-2 planner is what the plugin side reads back: every
    /// obstacle kind and the occupancy grid; a version-1 planner is told what it missed.
    #[test]
    fn obstacles_and_the_grid_cross_the_boundary() {
        use human2nav_core::obstacle::OccupancyGrid;
        let obs = Observation {
            obstacles: vec![
                Obstacle::Circle {
                    center: [1.0, 2.0],
                    radius: 0.5,
                },
                Obstacle::Polygon {
                    vertices: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
                },
                Obstacle::Segment {
                    a: [-1.0, 3.0],
                    b: [4.0, 3.0],
                },
                Obstacle::Polygon {
                    vertices: vec![[5.0, 5.0], [6.0, 5.0], [6.0, 6.0], [5.0, 6.0]],
                },
            ],
            occupancy: Some(OccupancyGrid {
                origin: Pose2::new(-2.0, -1.0, 0.25),
                resolution: 0.1,
                width: 3,
                height: 2,
                data: vec![0, 100, -1, 50, 65, 0],
                occupied_threshold: 60,
            }),
            ..Observation::default()
        };
        let mut job = PlanJob::new();
        load_obstacles(&obs, &mut job);
        link_vertices(&mut job.obstacles, &job.vertices);
        let grid = job.occupancy.map(|mut g| {
            g.data = job.cells.as_ptr();
            g
        });
        // SAFETY: the records point into the job's buffers, alive for these calls.
        let (obstacles, occupancy) = unsafe {
            (
                crate::export::obstacles_from_abi(job.obstacles.as_ptr(), job.obstacles.len()),
                crate::export::occupancy_from_abi(grid.as_ref().map_or(std::ptr::null(), |g| g)),
            )
        };
        assert_eq!(obstacles.ok(), Some(obs.obstacles.clone()));
        assert_eq!(occupancy.ok().flatten(), obs.occupancy);
        assert_eq!(
            unseen_by_v1(4, true).as_deref(),
            Some(
                "plugin ABI version 1: 4 static obstacle(s) and the occupancy grid not passed to \
                 the planner (version 2 carries them)"
            )
        );
        assert_eq!(unseen_by_v1(0, false), None);
    }
}
