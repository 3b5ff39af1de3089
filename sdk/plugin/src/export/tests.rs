//! The shims called directly with the pointers a faulty host could pass: every bad pointer
//! or length must come back as a status and a message, never as undefined behaviour.

use super::*;
use human2nav_core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::{Observation, Plan, PlanError, Planner};

/// Cost `Σ x` per trajectory, gradient 1 on every `x`.
struct SumX;

impl ConstraintTerm for SumX {
    fn name(&self) -> &str {
        "sum_x"
    }

    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        _ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        for b in 0..batch.batch {
            for (k, p) in batch.trajectory(b).chunks_exact(3).enumerate() {
                cost[b] += p[0];
                grad[(b * batch.horizon + k) * 3] += 1.0;
            }
        }
        Ok(())
    }
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct SumXConfig {
    #[serde(default)]
    panic: bool,
}

fn ctor(init: &PluginInit<'_>) -> Result<SumX, InitError> {
    let c: SumXConfig = init.config()?;
    if c.panic {
        panic!("constructor panicked on request");
    }
    Ok(SumX)
}

fn args(config: &str) -> H2nCreateArgs {
    H2nCreateArgs {
        struct_size: std::mem::size_of::<H2nCreateArgs>() as u32,
        kind: H2N_KIND_CONSTRAINT,
        config: H2nStr::new(config),
        has_robot: 0,
        reserved: 0,
        limits: H2nLimits::default(),
        gains: H2nGains::default(),
        footprint_radius: 0.0,
    }
}

fn create(args: *const H2nCreateArgs) -> (H2nStatus, H2nObject, String) {
    let mut out = H2nObject {
        instance: std::ptr::null_mut(),
        vtable: std::ptr::null(),
    };
    let mut buf = [0u8; 256];
    let mut err = H2nBuffer {
        data: buf.as_mut_ptr(),
        capacity: buf.len(),
        len: 0,
    };
    // SAFETY: valid (or deliberately null) pointers for the duration of the call.
    let status = unsafe { create_constraint(args, &mut out, &mut err, ctor) };
    let msg = String::from_utf8_lossy(&buf[..err.len.min(buf.len())]).into_owned();
    (status, out, msg)
}

fn vtable(obj: &H2nObject) -> &'static H2nConstraintVTable {
    // SAFETY: `create_constraint` returns a constraint vtable in static memory.
    unsafe { &*obj.vtable.cast::<H2nConstraintVTable>() }
}

fn last_error_of(obj: &H2nObject) -> String {
    let mut buf = [0u8; 256];
    let mut out = H2nBuffer {
        data: buf.as_mut_ptr(),
        capacity: buf.len(),
        len: 0,
    };
    // SAFETY: live instance, host-owned buffer.
    unsafe { (vtable(obj).last_error.expect("last_error"))(obj.instance, &mut out) };
    String::from_utf8_lossy(&buf[..out.len.min(buf.len())]).into_owned()
}

fn context() -> H2nConstraintContext {
    H2nConstraintContext {
        struct_size: std::mem::size_of::<H2nConstraintContext>() as u32,
        reserved: 0,
        dt: 0.1,
        limits: H2nLimits::default(),
        initial_velocity: H2nTwist::default(),
        agents: std::ptr::null(),
        agent_count: 0,
    }
}

#[test]
fn create_checks_its_arguments() {
    let (status, _, msg) = create(std::ptr::null());
    assert_eq!(status, H2N_INVALID_ARGUMENT);
    assert!(msg.contains("null"), "{msg}");
    let mut small = args("");
    small.struct_size = 8;
    assert_eq!(create(&small).0, H2N_INVALID_ARGUMENT);
    let mut wrong_kind = args("");
    wrong_kind.kind = H2N_KIND_PLANNER;
    assert_eq!(create(&wrong_kind).0, H2N_INVALID_ARGUMENT);
    let bad_utf8 = [0xff_u8, 0xfe];
    let mut not_text = args("");
    not_text.config = H2nStr {
        ptr: bad_utf8.as_ptr(),
        len: 2,
    };
    assert_eq!(create(&not_text).0, H2N_INVALID_ARGUMENT);
    let (status, _, msg) = create(&args("speed = 1"));
    assert_eq!(status, H2N_CONFIG);
    assert!(msg.contains("speed"), "{msg}");
    let (status, _, msg) = create(&args("panic = true"));
    assert_eq!(status, H2N_PANIC);
    assert!(msg.contains("constructor panicked on request"), "{msg}");
}

#[test]
fn error_messages_are_truncated_to_the_host_buffer_with_the_full_length_reported() {
    let mut out = H2nObject {
        instance: std::ptr::null_mut(),
        vtable: std::ptr::null(),
    };
    let mut buf = [0u8; 5];
    let mut err = H2nBuffer {
        data: buf.as_mut_ptr(),
        capacity: buf.len(),
        len: 0,
    };
    let a = args("speed = 1");
    // SAFETY: valid pointers for the call.
    let status = unsafe { create_constraint(&a, &mut out, &mut err, ctor) };
    assert_eq!(status, H2N_CONFIG);
    assert!(err.len > 5);
    assert_eq!(&buf, b"confi");
    // A null buffer is simply not written.
    // SAFETY: as above, with a null error buffer (allowed).
    let status = unsafe { create_constraint(&a, &mut out, std::ptr::null_mut(), ctor) };
    assert_eq!(status, H2N_CONFIG);
}

/// A `sum_x` instance created through the shim and called through its vtable; destroyed
/// (and a null instance destroyed, a no-op) when dropped.
struct SumXInstance {
    obj: H2nObject,
    vt: &'static H2nConstraintVTable,
    data: [f64; 6],
}

impl SumXInstance {
    fn new() -> Self {
        let (status, obj, _) = create(&args(""));
        assert_eq!(status, H2N_OK);
        let vt = vtable(&obj);
        Self {
            obj,
            vt,
            data: [1.0, 0.0, 0.0, 2.0, 0.0, 0.0],
        }
    }

    /// One trajectory of two poses over `self.data`.
    fn good(&self) -> H2nTrajBatch {
        H2nTrajBatch {
            data: self.data.as_ptr(),
            len: 6,
            batch: 1,
            horizon: 2,
            dim: 3,
        }
    }

    fn eval(
        &self,
        batch: *const H2nTrajBatch,
        ctx: *const H2nConstraintContext,
        cost: &mut [f64],
        cost_len: usize,
        grad: &mut [f64],
    ) -> H2nStatus {
        let c = H2nF64Out {
            data: cost.as_mut_ptr(),
            len: cost_len,
        };
        let g = H2nF64Out {
            data: grad.as_mut_ptr(),
            len: grad.len(),
        };
        // SAFETY: live instance; pointers valid or deliberately null.
        unsafe { (self.vt.evaluate.expect("evaluate"))(self.obj.instance, batch, ctx, c, g) }
    }

    /// A good call still succeeds: the refused calls before did not poison the instance.
    fn assert_still_usable(&self) {
        let (mut cost, mut grad) = ([0.0], [0.0; 6]);
        assert_eq!(
            self.eval(&self.good(), &context(), &mut cost, 1, &mut grad),
            H2N_OK
        );
        assert_eq!((cost, grad), ([3.0], [1.0, 0.0, 0.0, 1.0, 0.0, 0.0]));
    }
}

impl Drop for SumXInstance {
    fn drop(&mut self) {
        // SAFETY: destroyed exactly once; null is a no-op.
        unsafe {
            (self.vt.destroy.expect("destroy"))(self.obj.instance);
            (self.vt.destroy.expect("destroy"))(std::ptr::null_mut());
        }
    }
}

#[test]
fn evaluate_computes_through_the_shim() {
    let sum = SumXInstance::new();
    // SAFETY: live instance; the returned view lives as long as it.
    assert_eq!(
        unsafe { (sum.vt.name.expect("name"))(sum.obj.instance).as_str() },
        Ok("sum_x")
    );
    sum.assert_still_usable();
}

#[test]
fn evaluate_checks_the_batch() {
    let sum = SumXInstance::new();
    let good = sum.good();
    let ctx = context();
    let (mut cost, mut grad) = ([0.0], [0.0; 6]);
    let mut eval = |batch: *const H2nTrajBatch| sum.eval(batch, &ctx, &mut cost, 1, &mut grad);
    assert_eq!(eval(std::ptr::null()), H2N_INVALID_ARGUMENT);
    assert!(last_error_of(&sum.obj).contains("batch is null"));
    assert_eq!(eval(&H2nTrajBatch { dim: 2, ..good }), H2N_INVALID_ARGUMENT);
    assert_eq!(eval(&H2nTrajBatch { len: 5, ..good }), H2N_INVALID_ARGUMENT);
    assert_eq!(
        last_error_of(&sum.obj),
        "5 values cannot be 1 trajectories × 2 poses × 3"
    );
    let overflow = H2nTrajBatch {
        batch: usize::MAX,
        horizon: 2,
        ..good
    };
    assert_eq!(eval(&overflow), H2N_INVALID_ARGUMENT);
    let null_data = H2nTrajBatch {
        data: std::ptr::null(),
        ..good
    };
    assert_eq!(eval(&null_data), H2N_INVALID_ARGUMENT);
    assert!(
        last_error_of(&sum.obj).contains("batch data is null"),
        "{}",
        last_error_of(&sum.obj)
    );
    sum.assert_still_usable();
}

#[test]
fn evaluate_checks_the_outputs_the_context_and_the_instance() {
    let sum = SumXInstance::new();
    let good = sum.good();
    let ctx = context();
    let (mut cost, mut grad) = ([0.0], [0.0; 6]);
    assert_eq!(
        sum.eval(&good, std::ptr::null(), &mut cost, 1, &mut grad),
        H2N_INVALID_ARGUMENT
    );
    let mut cost2 = [0.0; 2];
    assert_eq!(
        sum.eval(&good, &ctx, &mut cost2, 2, &mut grad),
        H2N_INVALID_ARGUMENT
    );
    assert_eq!(
        last_error_of(&sum.obj),
        "cost has 2 entries for 1 trajectories"
    );
    let mut grad5 = [0.0; 5];
    assert_eq!(
        sum.eval(&good, &ctx, &mut cost, 1, &mut grad5),
        H2N_INVALID_ARGUMENT
    );
    assert_eq!(
        last_error_of(&sum.obj),
        "gradient has 5 entries, the batch 6"
    );
    let old_ctx = H2nConstraintContext {
        struct_size: 16,
        ..context()
    };
    assert_eq!(
        sum.eval(&good, &old_ctx, &mut cost, 1, &mut grad),
        H2N_INVALID_ARGUMENT
    );
    let null_agents = H2nConstraintContext {
        agent_count: 3,
        ..context()
    };
    assert_eq!(
        sum.eval(&good, &null_agents, &mut cost, 1, &mut grad),
        H2N_INVALID_ARGUMENT
    );
    sum.assert_still_usable();
    // A null instance is refused too.
    let c = H2nF64Out {
        data: cost.as_mut_ptr(),
        len: 1,
    };
    let g = H2nF64Out {
        data: grad.as_mut_ptr(),
        len: 6,
    };
    // SAFETY: a null instance is part of what the shim must survive.
    let status =
        unsafe { (sum.vt.evaluate.expect("evaluate"))(std::ptr::null_mut(), &good, &ctx, c, g) };
    assert_eq!(status, H2N_INVALID_ARGUMENT);
}

/// An embodiment and a planner whose methods must not run: a call panics.
struct Untouchable;

impl Embodiment for Untouchable {
    fn name(&self) -> &str {
        "untouchable"
    }

    fn holonomic(&self) -> bool {
        panic!("holonomic ran")
    }

    fn saturate(
        &self,
        _: &RobotState,
        _: human2nav_core::Twist2,
        _: f64,
    ) -> human2nav_core::Twist2 {
        panic!("saturate ran")
    }

    fn step(&self, _: &RobotState, _: human2nav_core::Twist2, _: f64) -> RobotState {
        panic!("step ran")
    }

    fn track(&self, _: &RobotState, _: &Plan, _: f64) -> human2nav_core::Twist2 {
        panic!("track ran")
    }
}

impl Planner for Untouchable {
    fn name(&self) -> &str {
        "untouchable"
    }

    fn plan(&mut self, _: &Observation) -> Result<Plan, PlanError> {
        panic!("plan ran")
    }
}

fn untouchable(_: &PluginInit<'_>) -> Result<Untouchable, InitError> {
    Ok(Untouchable)
}

fn message(last_error: Option<LastErrorFn>, instance: *mut c_void) -> String {
    let mut buf = [0u8; 256];
    let mut out = H2nBuffer {
        data: buf.as_mut_ptr(),
        capacity: buf.len(),
        len: 0,
    };
    // SAFETY: live instance, host-owned buffer.
    unsafe { (last_error.expect("last_error"))(instance, &mut out) };
    String::from_utf8_lossy(&buf[..out.len.min(buf.len())]).into_owned()
}

#[test]
fn null_outputs_are_refused_before_the_author_code_runs() {
    let create_as = |kind: u32| {
        let mut obj = H2nObject {
            instance: std::ptr::null_mut(),
            vtable: std::ptr::null(),
        };
        let a = H2nCreateArgs { kind, ..args("") };
        // SAFETY: valid pointers for the duration of the call; a null error buffer is allowed.
        let status = unsafe {
            if kind == H2N_KIND_EMBODIMENT {
                create_embodiment(&a, &mut obj, std::ptr::null_mut(), untouchable)
            } else {
                create_planner(&a, &mut obj, std::ptr::null_mut(), untouchable)
            }
        };
        assert_eq!(status, H2N_OK);
        obj
    };

    let obj = create_as(H2N_KIND_EMBODIMENT);
    // SAFETY: `create_embodiment` returns an embodiment vtable in static memory.
    let vt = unsafe { &*obj.vtable.cast::<H2nEmbodimentVTable>() };
    let state = H2nRobotState::default();
    let cmd = H2nTwist::default();
    let plan = H2nPlanView {
        t0: 0.0,
        dt: 0.1,
        poses: std::ptr::null(),
        pose_count: 0,
    };
    // SAFETY: live instance; every input valid, every output deliberately null.
    let statuses = unsafe {
        [
            (vt.holonomic.expect("holonomic"))(obj.instance, std::ptr::null_mut()),
            (vt.saturate.expect("saturate"))(obj.instance, &state, &cmd, 0.1, std::ptr::null_mut()),
            (vt.step.expect("step"))(obj.instance, &state, &cmd, 0.1, std::ptr::null_mut()),
            (vt.track.expect("track"))(obj.instance, &state, &plan, 0.0, std::ptr::null_mut()),
            (vt.coupled_limit.expect("coupled_limit"))(obj.instance, std::ptr::null_mut()),
        ]
    };
    assert_eq!(statuses, [H2N_INVALID_ARGUMENT; 5]);
    assert_eq!(message(vt.last_error, obj.instance), "output is null");
    // SAFETY: destroyed exactly once.
    unsafe { (vt.destroy.expect("destroy"))(obj.instance) };

    let obj = create_as(H2N_KIND_PLANNER);
    // SAFETY: `create_planner` returns a planner vtable in static memory.
    let vt = unsafe { &*obj.vtable.cast::<H2nPlannerVTable>() };
    let obs = H2nObservation {
        struct_size: std::mem::size_of::<H2nObservation>() as u32,
        reserved: 0,
        time: 0.0,
        ego: H2nPose::default(),
        ego_velocity: H2nTwist::default(),
        goal: [1.0, 0.0],
        agents: std::ptr::null(),
        agent_count: 0,
        obstacles: std::ptr::null(),
        obstacle_count: 0,
        occupancy: std::ptr::null(),
    };
    // SAFETY: live instance; the observation is valid, the output deliberately null.
    let status = unsafe { (vt.plan.expect("plan"))(obj.instance, &obs, std::ptr::null_mut()) };
    assert_eq!(status, H2N_INVALID_ARGUMENT);
    assert_eq!(message(vt.last_error, obj.instance), "plan output is null");
    // SAFETY: as above.
    let status = unsafe { (vt.last_plan.expect("last_plan"))(obj.instance, std::ptr::null_mut()) };
    assert_eq!(status, H2N_INVALID_ARGUMENT);
    assert_eq!(message(vt.last_error, obj.instance), "plan output is null");
    // SAFETY: destroyed exactly once.
    unsafe { (vt.destroy.expect("destroy"))(obj.instance) };
}

#[test]
fn agents_cross_with_their_histories() {
    let history = [[1.0, 2.0], [3.0, 4.0]];
    let agent = H2nAgent {
        id: 5,
        position: [0.5, 0.25],
        velocity: [0.0, 1.0],
        radius: 0.3,
        history: history.as_ptr().cast(),
        history_len: 2,
    };
    // SAFETY: one valid agent with two history points.
    let agents = unsafe { agents_from_abi(&agent, 1) }
        .ok()
        .unwrap_or_default();
    assert_eq!(agents.len(), 1);
    assert_eq!(agents[0].history, vec![[1.0, 2.0], [3.0, 4.0]]);
    assert_eq!((agents[0].id, agents[0].radius), (5, 0.3));
    let broken = H2nAgent {
        history: std::ptr::null(),
        ..agent
    };
    // SAFETY: the null history with a non-zero length must be refused, not read.
    assert!(unsafe { agents_from_abi(&broken, 1) }.is_err());
}
