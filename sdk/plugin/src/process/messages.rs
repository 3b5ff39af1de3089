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
