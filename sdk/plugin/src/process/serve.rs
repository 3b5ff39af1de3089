//! The helper side: serving one instance on stdin/stdout.

use super::*;

/// The instance a helper serves.
enum Served {
    Planner(crate::host::PluginPlanner),
    Constraint(crate::host::PluginConstraint),
    Embodiment(crate::host::PluginEmbodiment),
}

/// Runs an embodiment call on the helper's proxy (which checks every answer).
fn embodiment_value(
    emb: &crate::host::PluginEmbodiment,
    call: &EmbodimentCall<'_>,
) -> EmbodimentValue {
    use human2nav_core::embodiment::Embodiment;
    match call {
        EmbodimentCall::Holonomic => EmbodimentValue::Holonomic(emb.holonomic()),
        EmbodimentCall::Saturate { state, cmd, dt } => {
            EmbodimentValue::Twist(emb.saturate(state, *cmd, *dt))
        }
        EmbodimentCall::Step { state, cmd, dt } => {
            EmbodimentValue::State(emb.step(state, *cmd, *dt))
        }
        EmbodimentCall::Track { state, plan, t } => {
            EmbodimentValue::Twist(emb.track(state, plan, *t))
        }
        EmbodimentCall::CoupledLimit => EmbodimentValue::CoupledLimit(emb.coupled_limit()),
    }
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
fn serve(input: &mut dyn Read, out: &mut dyn Write) -> std::io::Result<()> {
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
        PluginKind::Embodiment => match init.robot.as_ref() {
            Some(robot) => host
                .embodiment_with_deadline(&init.library, &init.factory, &init.config, robot, None)
                .map(Served::Embodiment),
            None => Err(PluginError::Process {
                instance: format!("embodiment `{}`", init.factory),
                message: "an embodiment is created for a robot, and none was sent".into(),
            }),
        },
        other => Err(PluginError::Process {
            instance: format!("{other} `{}`", init.factory),
            message: "only planners, constraint terms and embodiments run in their own process"
                .into(),
        }),
    };
    let mut served = match created {
        Ok(s) => {
            let name = match &s {
                Served::Planner(p) => human2nav_core::Planner::name(p).to_owned(),
                Served::Constraint(c) => {
                    human2nav_core::constraint::ConstraintTerm::name(c).to_owned()
                }
                Served::Embodiment(b) => human2nav_core::embodiment::Embodiment::name(b).to_owned(),
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
        if let Served::Embodiment(emb) = &served {
            let Some(call) = EmbodimentCall::decode(op, &mut d).map_err(invalid)? else {
                return Err(invalid(format!(
                    "operation {op} does not apply to an embodiment"
                )));
            };
            let value = embodiment_value(emb, &call);
            encode_embodiment_answer(&mut e, &value, emb.failure().as_deref());
            send(out, &mut e)?;
            continue;
        }
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
            (OP_PROPERTIES, Served::Constraint(c)) => {
                let flag = human2nav_core::constraint::ConstraintTerm::separable_nonnegative(c);
                encode_properties_answer(&mut e, flag);
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
