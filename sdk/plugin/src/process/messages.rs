//! The messages both sides exchange: creating an instance, planning, evaluating, and their
//! answers.

use super::*;

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

/// A constraint term's `properties` answer: whether it declares itself separable and
/// non-negative.
pub(crate) fn encode_properties_answer(e: &mut Enc, separable_nonnegative: bool) {
    e.start(ANSWER_OK);
    e.u8(u8::from(separable_nonnegative));
}

/// The flag of [`encode_properties_answer`].
pub(crate) fn decode_properties_answer(d: &mut Dec<'_>) -> Result<bool, String> {
    match d.u8()? {
        ANSWER_OK => match d.u8()? {
            v @ (0 | 1) => Ok(v == 1),
            v => Err(format!("a flag of {v}")),
        },
        other => Err(format!("answer code {other}")),
    }
}

/// An embodiment call: what the host sends and the helper decodes.
#[derive(Clone, Debug, PartialEq)]
#[expect(
    clippy::large_enum_variant,
    reason = "a call lives for one round trip and is matched at once; boxing the plan would add an allocation per call"
)]
pub(crate) enum EmbodimentCall<'a> {
    Holonomic,
    Saturate {
        state: RobotState,
        cmd: Twist2,
        dt: f64,
    },
    Step {
        state: RobotState,
        cmd: Twist2,
        dt: f64,
    },
    Track {
        state: RobotState,
        plan: Cow<'a, Plan>,
        t: f64,
    },
    CoupledLimit,
}

impl EmbodimentCall<'_> {
    /// The call's name, as messages show it.
    pub(crate) fn name(&self) -> &'static str {
        match self {
            Self::Holonomic => "holonomic",
            Self::Saturate { .. } => "saturate",
            Self::Step { .. } => "step",
            Self::Track { .. } => "track",
            Self::CoupledLimit => "coupled_limit",
        }
    }

    pub(crate) fn encode(&self, e: &mut Enc) {
        match self {
            Self::Holonomic => e.start(OP_HOLONOMIC),
            Self::Saturate { state, cmd, dt } | Self::Step { state, cmd, dt } => {
                e.start(if matches!(self, Self::Saturate { .. }) {
                    OP_SATURATE
                } else {
                    OP_STEP
                });
                e.state(state);
                e.twist(*cmd);
                e.f64(*dt);
            }
            Self::Track { state, plan, t } => {
                e.start(OP_TRACK);
                e.state(state);
                e.f64(plan.t0);
                e.f64(plan.dt);
                e.u64(plan.poses.len() as u64);
                for &p in &plan.poses {
                    e.pose(p);
                }
                e.f64(*t);
            }
            Self::CoupledLimit => e.start(OP_COUPLED_LIMIT),
        }
    }

    /// The call of operation `op` (read already); `None` for an operation that is not an
    /// embodiment's.
    pub(crate) fn decode(op: u8, d: &mut Dec<'_>) -> Result<Option<Self>, String> {
        Ok(Some(match op {
            OP_HOLONOMIC => Self::Holonomic,
            OP_SATURATE => Self::Saturate {
                state: d.state()?,
                cmd: d.twist()?,
                dt: d.f64()?,
            },
            OP_STEP => Self::Step {
                state: d.state()?,
                cmd: d.twist()?,
                dt: d.f64()?,
            },
            OP_TRACK => {
                let state = d.state()?;
                let (t0, dt) = (d.f64()?, d.f64()?);
                let n = d.count(24)?;
                let mut poses = Vec::with_capacity(n);
                for _ in 0..n {
                    poses.push(d.pose()?);
                }
                Self::Track {
                    state,
                    plan: Cow::Owned(Plan {
                        t0,
                        dt,
                        poses,
                        info: PlanInfo::default(),
                    }),
                    t: d.f64()?,
                }
            }
            OP_COUPLED_LIMIT => Self::CoupledLimit,
            _ => return Ok(None),
        }))
    }
}

/// What an embodiment call answered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum EmbodimentValue {
    Holonomic(bool),
    Twist(Twist2),
    State(RobotState),
    CoupledLimit(Option<CoupledLimit>),
}

/// The answer to an embodiment call: the value and the failure the helper's proxy recorded
/// (its checks of the answer, a failed or panicking call), if any.
pub(crate) fn encode_embodiment_answer(
    e: &mut Enc,
    value: &EmbodimentValue,
    failure: Option<&str>,
) {
    e.start(ANSWER_OK);
    match value {
        EmbodimentValue::Holonomic(h) => e.u8(u8::from(*h)),
        EmbodimentValue::Twist(t) => e.twist(*t),
        EmbodimentValue::State(s) => e.state(s),
        EmbodimentValue::CoupledLimit(c) => {
            let c = c.as_ref().map(H2nCoupledLimit::from).unwrap_or_default();
            for v in [c.v, c.lateral, c.omega, c.max] {
                e.f64(v);
            }
        }
    }
    e.opt_str(failure);
}

/// Decodes the answer to `call`: the value (a coupled limit checked as the in-process host
/// checks it) and the helper's failure message, if any.
pub(crate) fn decode_embodiment_answer(
    d: &mut Dec<'_>,
    call: &EmbodimentCall<'_>,
) -> Result<(EmbodimentValue, Option<String>), String> {
    if d.u8()? != ANSWER_OK {
        return Err(format!(
            "the helper refused `{}`: {}",
            call.name(),
            d.str()?
        ));
    }
    let value = match call {
        EmbodimentCall::Holonomic => EmbodimentValue::Holonomic(d.u8()? != 0),
        EmbodimentCall::Saturate { .. } | EmbodimentCall::Track { .. } => {
            EmbodimentValue::Twist(d.twist()?)
        }
        EmbodimentCall::Step { .. } => EmbodimentValue::State(d.state()?),
        EmbodimentCall::CoupledLimit => {
            let c = H2nCoupledLimit {
                v: d.f64()?,
                lateral: d.f64()?,
                omega: d.f64()?,
                max: d.f64()?,
            };
            EmbodimentValue::CoupledLimit(
                c.to_limit()
                    .map_err(|(field, m)| format!("coupled_limit: {field} = {m}"))?,
            )
        }
    };
    Ok((value, d.opt_str()?))
}
