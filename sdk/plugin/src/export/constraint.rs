//! Constraint terms across the ABI: the `evaluate` and `properties` shims and
//! [`create_constraint`], the factory that `export_plugin!` expands to for a constraint.

use super::{
    Fail, agents_from_abi, call, create, destroy, last_error, name, output, reference, slice,
    slice_mut,
};
use crate::abi::*;
use crate::init::{InitError, PluginInit};
use crate::validate::EvaluateBuffers;
use human2nav_core::constraint::{ConstraintContext, ConstraintTerm, TrajBatch};
use std::ffi::c_void;

unsafe extern "C" fn constraint_evaluate<T: ConstraintTerm + 'static>(
    instance: *mut c_void,
    batch: *const H2nTrajBatch,
    ctx: *const H2nConstraintContext,
    cost: H2nF64Out,
    grad: H2nF64Out,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |term| {
            let batch = reference(batch, "batch")?;
            let ctx = reference(ctx, "context")?;
            if (ctx.struct_size as usize) < std::mem::size_of::<H2nConstraintContext>() {
                return Err(Fail::invalid("constraint context is from an older host"));
            }
            if batch.dim != 3 {
                return Err(Fail::invalid(format!(
                    "pose dimension is {}, expected 3",
                    batch.dim
                )));
            }
            EvaluateBuffers {
                batch: batch.batch,
                horizon: batch.horizon,
                values: batch.len,
                cost: cost.len,
                grad: grad.len,
            }
            .check()
            .map_err(Fail::invalid)?;
            let data = slice(batch.data, batch.len, "batch data")?;
            let cost = slice_mut(cost.data, cost.len, "cost")?;
            let grad = slice_mut(grad.data, grad.len, "gradient")?;
            let agents = agents_from_abi(ctx.agents, ctx.agent_count)?;
            let limits = (&ctx.limits).into();
            let core_ctx = ConstraintContext {
                dt: ctx.dt,
                limits: &limits,
                initial_velocity: ctx.initial_velocity.into(),
                agents: &agents,
                scene: Default::default(),
            };
            let view = TrajBatch::new(data, batch.batch, batch.horizon)
                .map_err(|e| Fail::invalid(e.to_string()))?;
            term.evaluate(view, &core_ctx, cost, grad)
                .map_err(|e| Fail::error(e.to_string()))
        })
    }
}

unsafe extern "C" fn constraint_properties<T: ConstraintTerm + 'static>(
    instance: *mut c_void,
    out: *mut u32,
) -> H2nStatus {
    // SAFETY: the host upholds the ABI contract for every pointer; `call` checks `instance`.
    unsafe {
        call::<T>(instance, |term| {
            let out = output(out, "output")?;
            out.write(if term.separable_nonnegative() {
                H2N_CONSTRAINT_SEPARABLE_NONNEGATIVE
            } else {
                0
            });
            Ok(())
        })
    }
}

/// Creates a constraint term through `ctor` (used by `export_plugin!`).
///
/// # Safety
/// The arguments of [`H2nFactory::create`], as passed by a host honouring the ABI.
pub unsafe fn create_constraint<T, E>(
    args: *const H2nCreateArgs,
    out: *mut H2nObject,
    error: *mut H2nBuffer,
    ctor: fn(&PluginInit<'_>) -> Result<T, E>,
) -> H2nStatus
where
    T: ConstraintTerm + 'static,
    E: Into<InitError>,
{
    let vtable: &'static H2nConstraintVTable = const {
        &H2nConstraintVTable {
            struct_size: std::mem::size_of::<H2nConstraintVTable>() as u32,
            reserved: 0,
            destroy: Some(destroy::<T>),
            last_error: Some(last_error::<T>),
            name: Some(name::<T>),
            evaluate: Some(constraint_evaluate::<T>),
            properties: Some(constraint_properties::<T>),
        }
    };
    // SAFETY: forwarded contract.
    unsafe {
        create::<T>(
            H2N_KIND_CONSTRAINT,
            args,
            out,
            error,
            (vtable as *const H2nConstraintVTable).cast(),
            |init| {
                let term = ctor(init).map_err(Into::into)?;
                let name = term.name().to_owned();
                Ok((term, name))
            },
        )
    }
}
