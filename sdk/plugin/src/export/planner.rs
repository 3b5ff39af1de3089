//! Planners across the ABI: the `reset`, `plan` and `last_plan` shims around a planner and its
//! last plan, and [`create_planner`].

use super::{
    Fail, agents_from_abi, call, create, destroy, last_error, name, obstacles_from_abi,
    occupancy_from_abi, output, reference, slice_mut, write_buffer,
};
use crate::abi::*;
use crate::init::{InitError, PluginInit};
use human2nav_core::{Observation, Plan, PlanError, Planner};
use std::ffi::c_void;
use std::sync::Mutex;

/// A planner and the plan it produced last (kept for `last_plan`). The host calls a planner
/// from one thread at a time; the mutex makes that a checked invariant instead of an assumption.
struct PlannerState<T> {
    planner: T,
    last_plan: Option<Plan>,
}

/// Writes `plan` into the host's buffer, or only its length when the buffer is too small.
///
/// # Safety
/// `out.poses` has `out.capacity` writable poses; `out.note` as [`write_buffer`].
unsafe fn write_plan(plan: &Plan, out: &mut H2nPlanOut) -> Result<(), Fail> {
    out.t0 = plan.t0;
    out.dt = plan.dt;
    out.len = plan.poses.len();
    out.fallback = u32::from(plan.info.fallback);
    // SAFETY: forwarded contract (the note buffer is host-owned).
    unsafe { write_buffer(&mut out.note, &plan.info.notes.join("; ")) };
    if plan.poses.len() > out.capacity {
        return Err(Fail {
            status: H2N_BUFFER_TOO_SMALL,
            message: format!(
                "plan has {} poses, buffer holds {}",
                plan.poses.len(),
                out.capacity
            ),
        });
    }
    // SAFETY: forwarded contract.
    let dst = unsafe { slice_mut(out.poses, plan.poses.len(), "plan poses") }?;
    for (d, p) in dst.iter_mut().zip(&plan.poses) {
        *d = (*p).into();
    }
    Ok(())
}

fn plan_fail(e: PlanError) -> Fail {
    match e {
        PlanError::InvalidObservation(m) => Fail::invalid(m),
        PlanError::Failed { message, .. } | PlanError::Unusable { message, .. } => {
            Fail::error(message)
        }
        // PlanError may grow variants; they all cross as ordinary errors.
        #[allow(unreachable_patterns)]
        other => Fail::error(other.to_string()),
    }
}

unsafe extern "C" fn planner_reset<T: Planner + 'static>(instance: *mut c_void) -> H2nStatus {
    // SAFETY: `call` checks `instance`; the host upholds the rest of the contract.
    unsafe {
        call::<Mutex<PlannerState<T>>>(instance, |state| {
            let mut state = state
                .lock()
                .map_err(|_| Fail::error("planner state is poisoned"))?;
            state.planner.reset();
            state.last_plan = None;
            Ok(())
        })
    }
}

unsafe extern "C" fn planner_plan<T: Planner + 'static>(
    instance: *mut c_void,
    obs: *const H2nObservation,
    out: *mut H2nPlanOut,
) -> H2nStatus {
    // SAFETY: `call` checks `instance`; the host upholds the rest of the contract.
    unsafe {
        call::<Mutex<PlannerState<T>>>(instance, |state| {
            let raw = reference(obs, "observation")?;
            if (raw.struct_size as usize) < std::mem::size_of::<H2nObservation>() {
                return Err(Fail::invalid("observation is from an older host"));
            }
            let mut out = output(out, "plan output")?;
            let out = out.as_mut();
            let obs = Observation {
                time: raw.time,
                ego: raw.ego.into(),
                ego_velocity: raw.ego_velocity.into(),
                goal: raw.goal,
                agents: agents_from_abi(raw.agents, raw.agent_count)?,
                obstacles: obstacles_from_abi(raw.obstacles, raw.obstacle_count)?,
                occupancy: occupancy_from_abi(raw.occupancy)?,
                ..Default::default()
            };
            let mut state = state
                .lock()
                .map_err(|_| Fail::error("planner state is poisoned"))?;
            let plan = state.planner.plan(&obs).map_err(plan_fail)?;
            let written = write_plan(&plan, out);
            state.last_plan = Some(plan);
            written
        })
    }
}

unsafe extern "C" fn planner_last_plan<T: Planner + 'static>(
    instance: *mut c_void,
    out: *mut H2nPlanOut,
) -> H2nStatus {
    // SAFETY: `call` checks `instance`; the host upholds the rest of the contract.
    unsafe {
        call::<Mutex<PlannerState<T>>>(instance, |state| {
            let mut out = output(out, "plan output")?;
            let state = state
                .lock()
                .map_err(|_| Fail::error("planner state is poisoned"))?;
            let plan = state
                .last_plan
                .as_ref()
                .ok_or_else(|| Fail::error("no plan yet"))?;
            write_plan(plan, out.as_mut())
        })
    }
}

/// Creates a planner through `ctor` (used by `export_plugin!`).
///
/// # Safety
/// The arguments of [`H2nFactory::create`], as passed by a host honouring the ABI.
pub unsafe fn create_planner<T, E>(
    args: *const H2nCreateArgs,
    out: *mut H2nObject,
    error: *mut H2nBuffer,
    ctor: fn(&PluginInit<'_>) -> Result<T, E>,
) -> H2nStatus
where
    T: Planner + 'static,
    E: Into<InitError>,
{
    type S<T> = Mutex<PlannerState<T>>;
    let vtable: &'static H2nPlannerVTable = const {
        &H2nPlannerVTable {
            struct_size: std::mem::size_of::<H2nPlannerVTable>() as u32,
            reserved: 0,
            destroy: Some(destroy::<S<T>>),
            last_error: Some(last_error::<S<T>>),
            name: Some(name::<S<T>>),
            reset: Some(planner_reset::<T>),
            plan: Some(planner_plan::<T>),
            last_plan: Some(planner_last_plan::<T>),
        }
    };
    // SAFETY: forwarded contract.
    unsafe {
        create::<S<T>>(
            H2N_KIND_PLANNER,
            args,
            out,
            error,
            (vtable as *const H2nPlannerVTable).cast(),
            |init| {
                let planner = ctor(init).map_err(Into::into)?;
                let name = planner.name().to_owned();
                Ok((
                    Mutex::new(PlannerState {
                        planner,
                        last_plan: None,
                    }),
                    name,
                ))
            },
        )
    }
}
