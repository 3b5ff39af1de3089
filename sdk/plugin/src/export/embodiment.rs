//! Embodiments across the ABI: the `holonomic`, `saturate`, `step`, `track` and
//! `coupled_limit` shims and [`create_embodiment`].

use super::{call, create, destroy, last_error, name, output, reference, slice};
use crate::abi::*;
use crate::init::{InitError, PluginInit};
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::{Plan, PlanInfo, Pose2};
use std::ffi::c_void;

unsafe extern "C" fn embodiment_holonomic<T: Embodiment + 'static>(
    instance: *mut c_void,
    out: *mut u32,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let out = output(out, "output")?;
            out.write(u32::from(e.holonomic()));
            Ok(())
        })
    }
}

unsafe extern "C" fn embodiment_saturate<T: Embodiment + 'static>(
    instance: *mut c_void,
    state: *const H2nRobotState,
    cmd: *const H2nTwist,
    dt: f64,
    out: *mut H2nTwist,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let state: RobotState = reference(state, "state")?.into();
            let cmd = *reference(cmd, "command")?;
            let out = output(out, "output")?;
            out.write(e.saturate(&state, cmd.into(), dt).into());
            Ok(())
        })
    }
}

unsafe extern "C" fn embodiment_step<T: Embodiment + 'static>(
    instance: *mut c_void,
    state: *const H2nRobotState,
    cmd: *const H2nTwist,
    dt: f64,
    out: *mut H2nRobotState,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let state: RobotState = reference(state, "state")?.into();
            let cmd = *reference(cmd, "command")?;
            let out = output(out, "output")?;
            out.write((&e.step(&state, cmd.into(), dt)).into());
            Ok(())
        })
    }
}

unsafe extern "C" fn embodiment_track<T: Embodiment + 'static>(
    instance: *mut c_void,
    state: *const H2nRobotState,
    plan: *const H2nPlanView,
    t: f64,
    out: *mut H2nTwist,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let state: RobotState = reference(state, "state")?.into();
            let view = reference(plan, "plan")?;
            let poses = slice(view.poses, view.pose_count, "plan poses")?;
            let plan = Plan {
                t0: view.t0,
                dt: view.dt,
                poses: poses.iter().map(|&p| Pose2::from(p)).collect(),
                info: PlanInfo::default(),
            };
            let out = output(out, "output")?;
            out.write(e.track(&state, &plan, t).into());
            Ok(())
        })
    }
}

unsafe extern "C" fn embodiment_coupled_limit<T: Embodiment + 'static>(
    instance: *mut c_void,
    out: *mut H2nCoupledLimit,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |e| {
            let out = output(out, "output")?;
            out.write(
                e.coupled_limit()
                    .as_ref()
                    .map(Into::into)
                    .unwrap_or_default(),
            );
            Ok(())
        })
    }
}

/// Creates an embodiment through `ctor` (used by `export_plugin!`).
///
/// # Safety
/// The arguments of [`H2nFactory::create`], as passed by a host honouring the ABI.
pub unsafe fn create_embodiment<T, E>(
    args: *const H2nCreateArgs,
    out: *mut H2nObject,
    error: *mut H2nBuffer,
    ctor: fn(&PluginInit<'_>) -> Result<T, E>,
) -> H2nStatus
where
    T: Embodiment + 'static,
    E: Into<InitError>,
{
    let vtable: &'static H2nEmbodimentVTable = const {
        &H2nEmbodimentVTable {
            struct_size: std::mem::size_of::<H2nEmbodimentVTable>() as u32,
            reserved: 0,
            destroy: Some(destroy::<T>),
            last_error: Some(last_error::<T>),
            name: Some(name::<T>),
            holonomic: Some(embodiment_holonomic::<T>),
            saturate: Some(embodiment_saturate::<T>),
            step: Some(embodiment_step::<T>),
            track: Some(embodiment_track::<T>),
            coupled_limit: Some(embodiment_coupled_limit::<T>),
        }
    };
    // SAFETY: forwarded contract.
    unsafe {
        create::<T>(
            H2N_KIND_EMBODIMENT,
            args,
            out,
            error,
            (vtable as *const H2nEmbodimentVTable).cast(),
            |init| {
                let e = ctor(init).map_err(Into::into)?;
                let name = e.name().to_owned();
                Ok((e, name))
            },
        )
    }
}
