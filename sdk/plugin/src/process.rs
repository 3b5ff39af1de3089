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
const ANSWER_OK: u8 = 0;
const ANSWER_ERR: u8 = 1;

// ---------------------------------------------------------------------------------------------
// Encoding
// ---------------------------------------------------------------------------------------------

/// A message being written (the four length bytes first, filled in by [`Enc::finish`]).
#[derive(Debug, Default)]
pub(crate) struct Enc(pub(crate) Vec<u8>);

impl Enc {
    pub(crate) fn start(&mut self, tag: u8) {
        self.0.clear();
        self.0.extend_from_slice(&[0, 0, 0, 0, tag]);
    }
    pub(crate) fn finish(&mut self) -> &[u8] {
        let n = (self.0.len() - 4) as u32;
        self.0[..4].copy_from_slice(&n.to_le_bytes());
        &self.0
    }
    pub(crate) fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    pub(crate) fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_bits().to_le_bytes());
    }
    pub(crate) fn f64s(&mut self, v: &[f64]) {
        self.u64(v.len() as u64);
        for &x in v {
            self.f64(x);
        }
    }
    pub(crate) fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.0.extend_from_slice(s.as_bytes());
    }
    pub(crate) fn pose(&mut self, p: Pose2) {
        self.f64(p.x);
        self.f64(p.y);
        self.f64(p.theta);
    }
    pub(crate) fn twist(&mut self, t: Twist2) {
        self.f64(t.vx);
        self.f64(t.vy);
        self.f64(t.omega);
    }
    pub(crate) fn opt_str(&mut self, s: Option<&str>) {
        match s {
            Some(s) => {
                self.u8(1);
                self.str(s);
            }
            None => self.u8(0),
        }
    }
    pub(crate) fn limits(&mut self, l: &Limits) {
        for v in [l.v_max, l.v_reverse_max, l.a_max, l.omega_max] {
            self.f64(v);
        }
        match l.kappa_max {
            Some(k) => {
                self.u8(1);
                self.f64(k);
            }
            None => self.u8(0),
        }
        self.f64(l.lateral_speed_max);
    }
    pub(crate) fn agents(&mut self, agents: &[AgentState]) {
        self.u64(agents.len() as u64);
        for a in agents {
            self.u64(a.id);
            for v in [a.position[0], a.position[1], a.velocity[0], a.velocity[1]] {
                self.f64(v);
            }
            self.f64(a.radius);
            self.u64(a.history.len() as u64);
            for h in &a.history {
                self.f64(h[0]);
                self.f64(h[1]);
            }
        }
    }
    pub(crate) fn obstacles(&mut self, obstacles: &[Obstacle]) {
        self.u64(obstacles.len() as u64);
        for o in obstacles {
            match o {
                Obstacle::Circle { center, radius } => {
                    self.u8(0);
                    self.f64s(&[center[0], center[1], *radius]);
                }
                Obstacle::Segment { a, b } => {
                    self.u8(1);
                    self.f64s(&[a[0], a[1], b[0], b[1]]);
                }
                Obstacle::Polygon { vertices } => {
                    self.u8(2);
                    let flat: Vec<f64> = vertices.iter().flatten().copied().collect();
                    self.f64s(&flat);
                }
            }
        }
    }
    pub(crate) fn occupancy(&mut self, grid: Option<&OccupancyGrid>) {
        let Some(g) = grid else {
            self.u8(0);
            return;
        };
        self.u8(1);
        self.pose(g.origin);
        self.f64(g.resolution);
        self.u64(g.width as u64);
        self.u64(g.height as u64);
        self.u8(g.occupied_threshold.to_le_bytes()[0]);
        self.u64(g.data.len() as u64);
        self.0.extend(g.data.iter().map(|c| c.to_le_bytes()[0]));
    }
}

/// A message being read; every read checks the length (a short message is an error).
#[derive(Debug)]
pub(crate) struct Dec<'a> {
    buf: &'a [u8],
    at: usize,
}

impl<'a> Dec<'a> {
    pub(crate) fn new(buf: &'a [u8]) -> Self {
        Self { buf, at: 0 }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.buf.len());
        let Some(end) = end else {
            return Err(format!(
                "message of {} bytes cut short at byte {}",
                self.buf.len(),
                self.at
            ));
        };
        let s = &self.buf[self.at..end];
        self.at = end;
        Ok(s)
    }
    pub(crate) fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    pub(crate) fn u64(&mut self) -> Result<u64, String> {
        let mut b = [0u8; 8];
        b.copy_from_slice(self.take(8)?);
        Ok(u64::from_le_bytes(b))
    }
    /// A count of items of at least `item_bytes` each (checked against what is left).
    pub(crate) fn count(&mut self, item_bytes: usize) -> Result<usize, String> {
        let n = self.u64()?;
        let left = (self.buf.len() - self.at) as u64;
        if n.saturating_mul(item_bytes.max(1) as u64) > left {
            return Err(format!("a count of {n} exceeds the message"));
        }
        Ok(n as usize)
    }
    pub(crate) fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_bits(self.u64()?))
    }
    pub(crate) fn f64s_into(&mut self, out: &mut Vec<f64>) -> Result<(), String> {
        let n = self.count(8)?;
        out.clear();
        out.reserve(n);
        for _ in 0..n {
            out.push(self.f64()?);
        }
        Ok(())
    }
    pub(crate) fn str(&mut self) -> Result<String, String> {
        let n = self.count(1)?;
        String::from_utf8(self.take(n)?.to_vec()).map_err(|e| format!("a string: {e}"))
    }
    pub(crate) fn pose(&mut self) -> Result<Pose2, String> {
        Ok(Pose2::new(self.f64()?, self.f64()?, self.f64()?))
    }
    pub(crate) fn twist(&mut self) -> Result<Twist2, String> {
        Ok(Twist2::new(self.f64()?, self.f64()?, self.f64()?))
    }
    pub(crate) fn opt_str(&mut self) -> Result<Option<String>, String> {
        Ok(match self.u8()? {
            0 => None,
            _ => Some(self.str()?),
        })
    }
    pub(crate) fn limits(&mut self) -> Result<Limits, String> {
        let (v_max, v_reverse_max, a_max, omega_max) =
            (self.f64()?, self.f64()?, self.f64()?, self.f64()?);
        let kappa_max = match self.u8()? {
            0 => None,
            _ => Some(self.f64()?),
        };
        Ok(Limits {
            v_max,
            v_reverse_max,
            a_max,
            omega_max,
            kappa_max,
            lateral_speed_max: self.f64()?,
            coupled: None,
        })
    }
    pub(crate) fn agents(&mut self) -> Result<Vec<AgentState>, String> {
        let n = self.count(56)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let id = self.u64()?;
            let position = [self.f64()?, self.f64()?];
            let velocity = [self.f64()?, self.f64()?];
            let radius = self.f64()?;
            let h = self.count(16)?;
            let mut history = Vec::with_capacity(h);
            for _ in 0..h {
                history.push([self.f64()?, self.f64()?]);
            }
            out.push(AgentState {
                id,
                position,
                velocity,
                radius,
                history,
            });
        }
        Ok(out)
    }
    pub(crate) fn obstacles(&mut self) -> Result<Vec<Obstacle>, String> {
        let n = self.count(9)?;
        let mut out = Vec::with_capacity(n);
        let mut v = Vec::new();
        for i in 0..n {
            let kind = self.u8()?;
            self.f64s_into(&mut v)?;
            out.push(match (kind, v.as_slice()) {
                (0, &[x, y, radius]) => Obstacle::Circle {
                    center: [x, y],
                    radius,
                },
                (1, &[x0, y0, x1, y1]) => Obstacle::Segment {
                    a: [x0, y0],
                    b: [x1, y1],
                },
                (2, flat) if flat.len() % 2 == 0 => Obstacle::Polygon {
                    vertices: flat.chunks_exact(2).map(|p| [p[0], p[1]]).collect(),
                },
                _ => {
                    return Err(format!(
                        "obstacle {i}: kind {kind} with {} numbers",
                        v.len()
                    ));
                }
            });
        }
        Ok(out)
    }
    pub(crate) fn occupancy(&mut self) -> Result<Option<OccupancyGrid>, String> {
        if self.u8()? == 0 {
            return Ok(None);
        }
        let origin = self.pose()?;
        let resolution = self.f64()?;
        let width = usize::try_from(self.u64()?).map_err(|e| format!("grid width: {e}"))?;
        let height = usize::try_from(self.u64()?).map_err(|e| format!("grid height: {e}"))?;
        let occupied_threshold = i8::from_le_bytes([self.u8()?]);
        let n = self.count(1)?;
        let data = self
            .take(n)?
            .iter()
            .map(|&b| i8::from_le_bytes([b]))
            .collect();
        Ok(Some(OccupancyGrid {
            origin,
            resolution,
            width,
            height,
            data,
            occupied_threshold,
        }))
    }
}

/// Reads one message (without its length) into `buf`; `Ok(false)` at a clean end of input.
pub(crate) fn read_message(
    r: &mut (impl Read + ?Sized),
    buf: &mut Vec<u8>,
) -> std::io::Result<bool> {
    let mut len = [0u8; 4];
    match r.read_exact(&mut len) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(false),
        Err(e) => return Err(e),
    }
    let n = u32::from_le_bytes(len) as usize;
    if n == 0 || n > MAX_MESSAGE_BYTES {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("a message of {n} bytes (limit {MAX_MESSAGE_BYTES})"),
        ));
    }
    buf.clear();
    buf.resize(n, 0);
    r.read_exact(buf)?;
    Ok(true)
}

// ---------------------------------------------------------------------------------------------
// Messages shared by both sides
// ---------------------------------------------------------------------------------------------

/// What the helper creates.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct InitRequest {
    pub kind: PluginKind,
    pub library: PathBuf,
    pub factory: String,
    pub config: String,
    pub robot: Option<RobotContext>,
}

impl InitRequest {
    pub(crate) fn encode(&self, e: &mut Enc) {
        e.start(OP_INIT);
        e.u64(u64::from(self.kind.code()));
        e.str(&self.library.to_string_lossy());
        e.str(&self.factory);
        e.str(&self.config);
        match &self.robot {
            Some(r) => {
                e.u8(1);
                e.limits(&r.limits);
                let g = &r.gains;
                for v in [g.k_x, g.k_y, g.k_theta, g.k_d, g.lookahead] {
                    e.f64(v);
                }
                e.f64(r.footprint_radius);
            }
            None => e.u8(0),
        }
    }

    pub(crate) fn decode(d: &mut Dec<'_>) -> Result<Self, String> {
        let kind = PluginKind::from_code(d.u64()? as u32);
        let library = PathBuf::from(d.str()?);
        let factory = d.str()?;
        let config = d.str()?;
        let robot = match d.u8()? {
            0 => None,
            _ => {
                let limits = d.limits()?;
                let gains = ControllerGains {
                    k_x: d.f64()?,
                    k_y: d.f64()?,
                    k_theta: d.f64()?,
                    k_d: d.f64()?,
                    lookahead: d.f64()?,
                };
                Some(RobotContext {
                    limits,
                    gains,
                    footprint_radius: d.f64()?,
                })
            }
        };
        Ok(Self {
            kind,
            library,
            factory,
            config,
            robot,
        })
    }
}

pub(crate) fn encode_observation(e: &mut Enc, obs: &Observation) {
    e.start(OP_PLAN);
    e.f64(obs.time);
    e.pose(obs.ego);
    e.twist(obs.ego_velocity);
    e.f64(obs.goal[0]);
    e.f64(obs.goal[1]);
    e.agents(&obs.agents);
    e.obstacles(&obs.obstacles);
    e.occupancy(obs.occupancy.as_ref());
}

pub(crate) fn decode_observation(d: &mut Dec<'_>) -> Result<Observation, String> {
    Ok(Observation {
        time: d.f64()?,
        ego: d.pose()?,
        ego_velocity: d.twist()?,
        goal: [d.f64()?, d.f64()?],
        agents: d.agents()?,
        obstacles: d.obstacles()?,
        occupancy: d.occupancy()?,
        ..Default::default()
    })
}

pub(crate) fn encode_plan_answer(e: &mut Enc, r: &Result<Plan, PlanError>) {
    match r {
        Ok(plan) => {
            e.start(ANSWER_OK);
            e.f64(plan.t0);
            e.f64(plan.dt);
            e.u64(plan.poses.len() as u64);
            for &p in &plan.poses {
                e.pose(p);
            }
            e.u8(u8::from(plan.info.fallback));
            e.u64(plan.info.notes.len() as u64);
            for n in &plan.info.notes {
                e.str(n);
            }
            e.opt_str(plan.info.error.as_deref());
        }
        Err(err) => {
            e.start(ANSWER_ERR);
            let (tag, a, b) = match err {
                PlanError::InvalidObservation(m) => (0, m.as_str(), ""),
                PlanError::InvalidSettings(m) => (1, m.as_str(), ""),
                PlanError::Failed { planner, message } => (2, planner.as_str(), message.as_str()),
                PlanError::Unusable { planner, message } => (3, planner.as_str(), message.as_str()),
            };
            e.u8(tag);
            e.str(a);
            e.str(b);
        }
    }
}

pub(crate) fn decode_plan_answer(d: &mut Dec<'_>) -> Result<Result<Plan, PlanError>, String> {
    if d.u8()? != ANSWER_OK {
        let (tag, a, b) = (d.u8()?, d.str()?, d.str()?);
        return Ok(Err(match tag {
            0 => PlanError::InvalidObservation(a),
            1 => PlanError::InvalidSettings(a),
            2 => PlanError::Failed {
                planner: a,
                message: b,
            },
            _ => PlanError::Unusable {
                planner: a,
                message: b,
            },
        }));
    }
    let (t0, dt) = (d.f64()?, d.f64()?);
    let n = d.count(24)?;
    let mut poses = Vec::with_capacity(n);
    for _ in 0..n {
        poses.push(d.pose()?);
    }
    let fallback = d.u8()? != 0;
    let k = d.count(8)?;
    let mut notes = Vec::with_capacity(k);
    for _ in 0..k {
        notes.push(d.str()?);
    }
    let error = d.opt_str()?;
    Ok(Ok(Plan {
        t0,
        dt,
        poses,
        info: PlanInfo {
            fallback,
            notes,
            error,
            ..PlanInfo::default()
        },
    }))
}

pub(crate) fn encode_evaluate(
    e: &mut Enc,
    batch: TrajBatch<'_>,
    ctx: &ConstraintContext<'_>,
    cost: &[f64],
    grad: &[f64],
) {
    e.start(OP_EVALUATE);
    e.u64(batch.batch as u64);
    e.u64(batch.horizon as u64);
    e.f64s(batch.data);
    e.f64(ctx.dt);
    e.limits(ctx.limits);
    e.twist(ctx.initial_velocity);
    e.agents(ctx.agents);
    e.f64s(cost);
    e.f64s(grad);
}

/// An `evaluate` request as the helper reads it.
#[derive(Debug, Default)]
pub(crate) struct EvaluateRequest {
    pub batch: usize,
    pub horizon: usize,
    pub data: Vec<f64>,
    pub dt: f64,
    pub limits: Option<Limits>,
    pub initial_velocity: Twist2,
    pub agents: Vec<AgentState>,
    pub cost: Vec<f64>,
    pub grad: Vec<f64>,
}

impl EvaluateRequest {
    pub(crate) fn decode(&mut self, d: &mut Dec<'_>) -> Result<(), String> {
        self.batch = d.u64()? as usize;
        self.horizon = d.u64()? as usize;
        d.f64s_into(&mut self.data)?;
        self.dt = d.f64()?;
        self.limits = Some(d.limits()?);
        self.initial_velocity = d.twist()?;
        self.agents = d.agents()?;
        d.f64s_into(&mut self.cost)?;
        d.f64s_into(&mut self.grad)?;
        Ok(())
    }
}

pub(crate) fn encode_evaluate_answer(
    e: &mut Enc,
    r: &Result<(), ConstraintError>,
    cost: &[f64],
    grad: &[f64],
) {
    match r {
        Ok(()) => {
            e.start(ANSWER_OK);
            e.f64s(cost);
            e.f64s(grad);
        }
        Err(ConstraintError::Shape(m)) => {
            e.start(ANSWER_ERR);
            e.u8(0);
            e.str("");
            e.str(m);
        }
        Err(ConstraintError::Failed { term, message }) => {
            e.start(ANSWER_ERR);
            e.u8(1);
            e.str(term);
            e.str(message);
        }
    }
}

/// Decodes an `evaluate` answer into the caller's buffers (same lengths as sent).
pub(crate) fn decode_evaluate_answer(
    d: &mut Dec<'_>,
    cost: &mut [f64],
    grad: &mut [f64],
) -> Result<Result<(), ConstraintError>, String> {
    if d.u8()? != ANSWER_OK {
        let (tag, term, message) = (d.u8()?, d.str()?, d.str()?);
        return Ok(Err(match tag {
            0 => ConstraintError::Shape(message),
            _ => ConstraintError::Failed { term, message },
        }));
    }
    for out in [cost, grad] {
        let n = d.count(8)?;
        if n != out.len() {
            return Err(format!("an answer of {n} values for {}", out.len()));
        }
        for v in out.iter_mut() {
            *v = d.f64()?;
        }
    }
    Ok(Ok(()))
}

pub(crate) fn encode_unit_answer(e: &mut Enc, r: Result<(), &str>) {
    match r {
        Ok(()) => e.start(ANSWER_OK),
        Err(m) => {
            e.start(ANSWER_ERR);
            e.str(m);
        }
    }
}

/// `Ok(())` or the helper's error message.
pub(crate) fn decode_unit_answer(d: &mut Dec<'_>) -> Result<Result<(), String>, String> {
    if d.u8()? == ANSWER_OK {
        Ok(Ok(()))
    } else {
        Ok(Err(d.str()?))
    }
}

// ---------------------------------------------------------------------------------------------
// The host side
// ---------------------------------------------------------------------------------------------

/// Where the helper executable is (see the module docs); `configured` is the host's setting.
pub fn find_helper(configured: Option<&Path>) -> Result<PathBuf, String> {
    if let Some(p) = configured {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os(HELPER_ENV).filter(|p| !p.is_empty()) {
        return Ok(PathBuf::from(p));
    }
    let file = format!("{HELPER_NAME}{}", std::env::consts::EXE_SUFFIX);
    let mut tried = Vec::new();
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    {
        for d in [Some(dir.as_path()), dir.parent()].into_iter().flatten() {
            let p = d.join(&file);
            if p.is_file() {
                return Ok(p);
            }
            tried.push(p.display().to_string());
        }
    }
    Err(format!(
        "cannot find the plugin host executable `{file}` (tried {}; build it with `cargo build \
         -p human2nav-plugin` or set {HELPER_ENV})",
        if tried.is_empty() {
            "nothing: the current executable's directory is unknown".to_owned()
        } else {
            tried.join(", ")
        }
    ))
}

/// A running helper.
struct Running {
    child: Child,
    stdin: ChildStdin,
    /// Messages read by the reader thread; it ends (dropping its sender) at end of input.
    answers: mpsc::Receiver<Vec<u8>>,
}

/// Why a call got no answer.
enum Lost {
    Closed,
    TimedOut,
}

/// One out-of-process instance: its helper (started again after a failure) and its settings.
pub(crate) struct ProcessClient {
    helper: PathBuf,
    init: Vec<u8>,
    /// `planner `straight``: how messages name the instance.
    what: String,
    deadline: Option<Duration>,
    running: Option<Running>,
    restarts: u32,
    /// Set once the restarts are used up: every call fails with it.
    dead: Option<String>,
    enc: Enc,
}

impl std::fmt::Debug for ProcessClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProcessClient")
            .field("what", &self.what)
            .field("restarts", &self.restarts)
            .field("dead", &self.dead)
            .finish()
    }
}

/// The name of a signal a process died of.
pub fn signal_name(sig: i32) -> String {
    let name = match sig {
        1 => "SIGHUP",
        2 => "SIGINT",
        3 => "SIGQUIT",
        4 => "SIGILL",
        5 => "SIGTRAP",
        6 => "SIGABRT",
        7 if cfg!(target_os = "linux") => "SIGBUS",
        8 => "SIGFPE",
        9 => "SIGKILL",
        10 if !cfg!(target_os = "linux") => "SIGBUS",
        11 => "SIGSEGV",
        13 => "SIGPIPE",
        15 => "SIGTERM",
        _ => return format!("signal {sig}"),
    };
    format!("signal {name}")
}

fn describe_exit(status: std::process::ExitStatus) -> String {
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        if let Some(sig) = status.signal() {
            return signal_name(sig);
        }
    }
    match status.code() {
        Some(c) => format!("exited with status {c}"),
        None => format!("ended ({status})"),
    }
}

impl ProcessClient {
    /// Starts the helper and creates the instance; returns the client and the instance name.
    pub(crate) fn start(
        helper: PathBuf,
        init: &InitRequest,
        deadline: Option<Duration>,
    ) -> Result<(Self, String), String> {
        let mut enc = Enc::default();
        init.encode(&mut enc);
        enc.finish();
        let mut client = Self {
            helper,
            init: enc.0.clone(),
            what: format!("{} `{}`", init.kind, init.factory),
            deadline,
            running: None,
            restarts: 0,
            dead: None,
            enc,
        };
        let name = client.spawn()?;
        Ok((client, name))
    }

    /// Restarts used so far.
    pub(crate) fn restarts(&self) -> u32 {
        self.restarts
    }

    fn spawn(&mut self) -> Result<String, String> {
        let prefix = format!("plugin process for {}", self.what);
        let mut child = Command::new(&self.helper)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| format!("{prefix}: cannot start {}: {e}", self.helper.display()))?;
        let (Some(mut stdin), Some(mut stdout)) = (child.stdin.take(), child.stdout.take()) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("{prefix}: its pipes were not set up"));
        };
        let (tx, answers) = mpsc::channel();
        let spawned = std::thread::Builder::new()
            .name("h2n-proc-reader".into())
            .spawn(move || {
                let mut buf = Vec::new();
                while let Ok(true) = read_message(&mut stdout, &mut buf) {
                    if tx.send(std::mem::take(&mut buf)).is_err() {
                        break;
                    }
                }
            });
        if let Err(e) = spawned {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("{prefix}: cannot start its reader thread: {e}"));
        }
        let start = self
            .deadline
            .map_or(MIN_START_TIME, |d| d.max(MIN_START_TIME));
        let sent = stdin.write_all(&self.init).and_then(|()| stdin.flush());
        let answer = match sent {
            Ok(()) => match answers.recv_timeout(start) {
                Ok(a) => Ok(a),
                Err(mpsc::RecvTimeoutError::Timeout) => Err(Lost::TimedOut),
                Err(mpsc::RecvTimeoutError::Disconnected) => Err(Lost::Closed),
            },
            Err(_) => Err(Lost::Closed),
        };
        let answer = match answer {
            Ok(a) => a,
            Err(lost) => {
                let _ = child.kill();
                let status = child.wait();
                return Err(match (lost, status) {
                    (Lost::TimedOut, _) => format!(
                        "{prefix} did not create the instance within {} (killed)",
                        crate::deadline::describe(start)
                    ),
                    (Lost::Closed, Ok(s)) => {
                        format!(
                            "{prefix} died while creating the instance: {}",
                            describe_exit(s)
                        )
                    }
                    (Lost::Closed, Err(e)) => format!("{prefix} died while creating it: {e}"),
                });
            }
        };
        let mut d = Dec::new(&answer);
        let name = match d.u8() {
            Ok(ANSWER_OK) => d.str(),
            Ok(_) => Err(d.str().unwrap_or_else(|e| e)),
            Err(e) => Err(e),
        };
        match name {
            Ok(name) => {
                self.running = Some(Running {
                    child,
                    stdin,
                    answers,
                });
                Ok(name)
            }
            Err(message) => {
                let _ = child.kill();
                let _ = child.wait();
                Err(message)
            }
        }
    }

    /// Kills the helper (if running) and reports how it ended.
    fn stop(&mut self) -> Option<String> {
        let mut r = self.running.take()?;
        let _ = r.child.kill();
        Some(match r.child.wait() {
            Ok(s) => describe_exit(s),
            Err(e) => format!("could not be waited for: {e}"),
        })
    }

    /// Sends the request in `self.enc` (finished) and waits for the answer. The error is the
    /// message of a failed call (a dead or hung process, or one that could not be restarted).
    fn round_trip(&mut self, call: &str) -> Result<Vec<u8>, String> {
        if let Some(dead) = &self.dead {
            return Err(dead.clone());
        }
        if self.running.is_none() {
            // Restart after a failure.
            self.restarts += 1;
            if let Err(e) = self.spawn() {
                return Err(self.give_up(format!("{e} (restart {})", self.restarts)));
            }
        }
        let deadline = self.deadline;
        let Some(r) = self.running.as_mut() else {
            return Err(format!("plugin process for {} is not running", self.what));
        };
        let sent = r
            .stdin
            .write_all(&self.enc.0)
            .and_then(|()| r.stdin.flush());
        let answer = match (sent, deadline) {
            (Err(_), _) => Err(Lost::Closed),
            (Ok(()), Some(d)) => r.answers.recv_timeout(d).map_err(|e| match e {
                mpsc::RecvTimeoutError::Timeout => Lost::TimedOut,
                mpsc::RecvTimeoutError::Disconnected => Lost::Closed,
            }),
            (Ok(()), None) => r.answers.recv().map_err(|_| Lost::Closed),
        };
        match answer {
            Ok(a) => Ok(a),
            Err(lost) => {
                let how = self.stop().unwrap_or_default();
                let what = &self.what;
                let message = match lost {
                    Lost::Closed => {
                        format!("plugin process for {what} died during `{call}`: {how}")
                    }
                    Lost::TimedOut => format!(
                        "plugin process for {what} did not answer `{call}` within {} (killed)",
                        crate::deadline::describe(deadline.unwrap_or_default())
                    ),
                };
                Err(self.after_failure(message))
            }
        }
    }

    /// Adds the restart policy to a failure's message; past the last restart the client is
    /// dead.
    fn after_failure(&mut self, message: String) -> String {
        if self.restarts >= MAX_RESTARTS {
            return self.give_up(message);
        }
        let left = MAX_RESTARTS - self.restarts;
        let message = format!(
            "{message}; a new process is started for the next call ({left} restart{} left)",
            if left == 1 { "" } else { "s" }
        );
        eprintln!("warning: {message}");
        message
    }

    fn give_up(&mut self, message: String) -> String {
        self.stop();
        let message = format!(
            "{message}; no restarts left (at most {MAX_RESTARTS}): the instance is marked dead"
        );
        eprintln!("warning: {message}");
        self.dead = Some(message.clone());
        message
    }

    /// True once the restarts are used up.
    pub(crate) fn dead(&self) -> Option<&str> {
        self.dead.as_deref()
    }

    /// `reset` of a planner. A failure is recorded (the next call restarts the process).
    pub(crate) fn reset(&mut self) -> Result<(), String> {
        self.enc.start(OP_RESET);
        self.enc.finish();
        let answer = self.round_trip("reset")?;
        let mut d = Dec::new(&answer);
        self.decoded(decode_unit_answer(&mut d))?
    }

    /// `plan`: `Err` for a failed call (dead or hung process), else the planner's answer.
    pub(crate) fn plan(&mut self, obs: &Observation) -> Result<Result<Plan, PlanError>, String> {
        encode_observation(&mut self.enc, obs);
        self.enc.finish();
        let answer = self.round_trip("plan")?;
        let mut d = Dec::new(&answer);
        self.decoded(decode_plan_answer(&mut d))
    }

    /// `evaluate`, adding into `cost` and `grad` on success.
    pub(crate) fn evaluate(
        &mut self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<Result<(), ConstraintError>, String> {
        encode_evaluate(&mut self.enc, batch, ctx, cost, grad);
        self.enc.finish();
        let answer = self.round_trip("evaluate")?;
        let mut d = Dec::new(&answer);
        self.decoded(decode_evaluate_answer(&mut d, cost, grad))
    }

    /// A malformed answer is a failed call; the process is restarted for the next one.
    fn decoded<T>(&mut self, r: Result<T, String>) -> Result<T, String> {
        r.map_err(|e| {
            self.stop();
            let message = format!(
                "plugin process for {} sent a malformed answer: {e} (killed)",
                self.what
            );
            self.after_failure(message)
        })
    }
}

impl Drop for ProcessClient {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Creates an instance in a helper process: `Ok((client, instance name))`.
pub(crate) fn start_instance(
    helper: Option<&Path>,
    kind: PluginKind,
    library: &Path,
    factory: &str,
    config: &str,
    robot: Option<&RobotContext>,
    deadline: Option<Duration>,
) -> Result<(ProcessClient, String), PluginError> {
    let instance = format!("{kind} `{factory}` from {}", library.display());
    let process = |message: String| PluginError::Process {
        instance: instance.clone(),
        message,
    };
    let file = crate::resolve::resolve_library_path(library)?;
    let file = std::fs::canonicalize(&file).unwrap_or(file);
    let helper = find_helper(helper).map_err(process)?;
    let init = InitRequest {
        kind,
        library: file,
        factory: factory.to_owned(),
        config: config.to_owned(),
        robot: robot.copied(),
    };
    ProcessClient::start(helper, &init, deadline).map_err(process)
}

// ---------------------------------------------------------------------------------------------
// The helper side
// ---------------------------------------------------------------------------------------------

/// The instance a helper serves.
enum Served {
    Planner(crate::host::PluginPlanner),
    Constraint(crate::host::PluginConstraint),
}

/// The protocol's output: the original stdout, after fd 1 was pointed at stderr (so a plugin
/// that prints cannot corrupt the protocol).
#[cfg(unix)]
fn protocol_output() -> std::io::Result<Box<dyn Write>> {
    use std::os::fd::AsFd;
    let fd = std::io::stdout().as_fd().try_clone_to_owned()?;
    unsafe extern "C" {
        fn dup2(old: std::ffi::c_int, new: std::ffi::c_int) -> std::ffi::c_int;
    }
    // SAFETY: `dup2` on descriptors 2 and 1 of this process; the protocol keeps its own
    // duplicate of the original descriptor 1.
    if unsafe { dup2(2, 1) } < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(Box::new(std::fs::File::from(fd)))
}

#[cfg(not(unix))]
fn protocol_output() -> std::io::Result<Box<dyn Write>> {
    Ok(Box::new(std::io::stdout()))
}

/// The helper's main loop (`human2nav-plugin-host`): serves one instance on stdin/stdout until
/// stdin closes. Returns the process exit code.
#[doc(hidden)]
pub fn serve_stdio() -> i32 {
    let mut out = match protocol_output() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{HELPER_NAME}: cannot set up its output: {e}");
            return 2;
        }
    };
    let stdin = std::io::stdin();
    let mut input = stdin.lock();
    match serve(&mut input, &mut out) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("{HELPER_NAME}: {e}");
            2
        }
    }
}

fn send(out: &mut dyn Write, e: &mut Enc) -> std::io::Result<()> {
    out.write_all(e.finish())?;
    out.flush()
}

fn invalid(m: String) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, m)
}

/// Serves one instance: the first message creates it, then calls until the end of `input`.
pub(crate) fn serve(input: &mut dyn Read, out: &mut dyn Write) -> std::io::Result<()> {
    let mut buf = Vec::new();
    let mut e = Enc::default();
    if !read_message(input, &mut buf)? {
        return Ok(());
    }
    let mut d = Dec::new(&buf);
    if d.u8().map_err(invalid)? != OP_INIT {
        return Err(invalid(
            "the first message does not create an instance".into(),
        ));
    }
    let init = InitRequest::decode(&mut d).map_err(invalid)?;
    let host = crate::PluginHost::new();
    let created = match init.kind {
        PluginKind::Planner => host
            .planner_with_deadline(
                &init.library,
                &init.factory,
                &init.config,
                init.robot.as_ref(),
                None,
            )
            .map(Served::Planner),
        PluginKind::Constraint => host
            .constraint_with_deadline(
                &init.library,
                &init.factory,
                &init.config,
                init.robot.as_ref(),
                None,
            )
            .map(Served::Constraint),
        other => Err(PluginError::Process {
            instance: format!("{other} `{}`", init.factory),
            message: "only planners and constraint terms run in their own process".into(),
        }),
    };
    let mut served = match created {
        Ok(s) => {
            let name = match &s {
                Served::Planner(p) => human2nav_core::Planner::name(p).to_owned(),
                Served::Constraint(c) => {
                    human2nav_core::constraint::ConstraintTerm::name(c).to_owned()
                }
            };
            e.start(ANSWER_OK);
            e.str(&name);
            send(out, &mut e)?;
            s
        }
        Err(err) => {
            encode_unit_answer(&mut e, Err(&err.to_string()));
            return send(out, &mut e);
        }
    };
    let mut eval = EvaluateRequest::default();
    while read_message(input, &mut buf)? {
        let mut d = Dec::new(&buf);
        let op = d.u8().map_err(invalid)?;
        match (op, &mut served) {
            (OP_RESET, Served::Planner(p)) => {
                human2nav_core::Planner::reset(p);
                encode_unit_answer(&mut e, Ok(()));
            }
            (OP_PLAN, Served::Planner(p)) => {
                let obs = decode_observation(&mut d).map_err(invalid)?;
                let r = human2nav_core::Planner::plan(p, &obs);
                encode_plan_answer(&mut e, &r);
            }
            (OP_EVALUATE, Served::Constraint(c)) => {
                eval.decode(&mut d).map_err(invalid)?;
                let limits = eval.limits.unwrap_or(Limits {
                    v_max: 0.0,
                    v_reverse_max: 0.0,
                    a_max: 0.0,
                    omega_max: 0.0,
                    kappa_max: None,
                    lateral_speed_max: 0.0,
                    coupled: None,
                });
                let ctx = ConstraintContext {
                    dt: eval.dt,
                    limits: &limits,
                    initial_velocity: eval.initial_velocity,
                    agents: &eval.agents,
                    scene: Default::default(),
                };
                let batch = TrajBatch {
                    data: &eval.data,
                    batch: eval.batch,
                    horizon: eval.horizon,
                };
                let r = human2nav_core::constraint::ConstraintTerm::evaluate(
                    c,
                    batch,
                    &ctx,
                    &mut eval.cost,
                    &mut eval.grad,
                );
                encode_evaluate_answer(&mut e, &r, &eval.cost, &eval.grad);
            }
            (op, _) => {
                return Err(invalid(format!(
                    "operation {op} does not apply to this instance"
                )));
            }
        }
        send(out, &mut e)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn observations_and_plans_round_trip_bit_for_bit() {
        let obs = Observation {
            time: 0.1 + 0.2,
            ego: Pose2::new(1.0 / 3.0, -0.0, f64::MIN_POSITIVE),
            ego_velocity: Twist2::new(0.5, 1e-300, -2.0),
            goal: [5.0, 1.0],
            agents: vec![AgentState {
                id: 7,
                position: [1.0, 2.0],
                velocity: [0.1, -0.2],
                radius: 0.3,
                history: vec![[0.5, 0.25]; 3],
            }],
            obstacles: vec![
                Obstacle::Circle {
                    center: [1.0, -2.0],
                    radius: 0.4,
                },
                Obstacle::Segment {
                    a: [0.0, 1.5],
                    b: [9.0, 1.5],
                },
                Obstacle::Polygon {
                    vertices: vec![[3.0, 0.0], [4.0, 0.0], [4.0, 1.0]],
                },
            ],
            occupancy: Some(OccupancyGrid {
                origin: Pose2::new(-5.0, -5.0, 0.0),
                resolution: 0.05,
                width: 2,
                height: 2,
                data: vec![-1, 0, 100, 64],
                occupied_threshold: 65,
            }),
            ..Default::default()
        };
        let mut e = Enc::default();
        encode_observation(&mut e, &obs);
        let msg = e.finish().to_vec();
        let mut d = Dec::new(&msg[5..]);
        let back = decode_observation(&mut d).expect("decode");
        assert_eq!(back, obs);
        assert_eq!(back.ego.y.to_bits(), (-0.0f64).to_bits());

        let plan = Plan {
            t0: 0.3,
            dt: 0.1,
            poses: vec![Pose2::new(0.1, 0.2, 0.3); 4],
            info: PlanInfo {
                fallback: true,
                notes: vec!["a".into(), "b c".into()],
                error: Some("why".into()),
                ..PlanInfo::default()
            },
        };
        encode_plan_answer(&mut e, &Ok(plan.clone()));
        let msg = e.finish().to_vec();
        let back = decode_plan_answer(&mut Dec::new(&msg[4..])).expect("decode");
        assert_eq!(back.expect("ok"), plan);
        let err = PlanError::Failed {
            planner: "p".into(),
            message: "m".into(),
        };
        encode_plan_answer(&mut e, &Err(err));
        let msg = e.finish().to_vec();
        let back = decode_plan_answer(&mut Dec::new(&msg[4..])).expect("decode");
        assert_eq!(back.expect_err("err").to_string(), "planner `p` failed: m");
    }

    #[test]
    fn short_or_lying_messages_are_errors() {
        let mut e = Enc::default();
        e.start(ANSWER_OK);
        e.u64(1 << 60);
        let msg = e.finish().to_vec();
        let mut d = Dec::new(&msg[5..]);
        assert!(d.count(8).is_err());
        let mut d = Dec::new(&msg[5..7]);
        assert!(d.u64().is_err());
    }

    #[test]
    fn signals_are_named() {
        assert_eq!(signal_name(11), "signal SIGSEGV");
        assert_eq!(signal_name(6), "signal SIGABRT");
        assert_eq!(signal_name(64), "signal 64");
    }
}
