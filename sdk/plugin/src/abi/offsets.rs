//! The size and field offsets of every ABI struct as this compiler lays them out ([`layout`]),
//! for comparison with what the C compiler of a plugin sees.

use super::*;

/// Size and field offsets of one ABI struct.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StructLayout {
    /// The struct's name as in the C header.
    pub name: &'static str,
    /// `sizeof` the struct (bytes).
    pub size: usize,
    /// `(field, offset)` in declaration order.
    pub fields: Vec<(&'static str, usize)>,
}

/// The layout of every ABI struct as this compiler lays them out; the C plugin reports the same
/// table from its compiler and the tests compare the two.
// One line per struct: a table, kept unformatted so that it reads as one.
#[rustfmt::skip]
pub fn layout() -> Vec<StructLayout> {
    use std::mem::{offset_of, size_of};
    macro_rules! entry {
        ($t:ident { $($f:ident),* $(,)? }) => {
            StructLayout {
                name: stringify!($t),
                size: size_of::<$t>(),
                fields: vec![$((stringify!($f), offset_of!($t, $f))),*],
            }
        };
    }
    vec![
        entry!(H2nStr { ptr, len }),
        entry!(H2nBuffer { data, capacity, len }),
        entry!(H2nPluginEntry { abi_version, struct_size, name, version, factories, factory_count,
            find_factory }),
        entry!(H2nFactory { struct_size, kind, name, description, create }),
        entry!(H2nLimits { v_max, v_reverse_max, a_max, omega_max, kappa_max, lateral_speed_max,
            has_kappa_max, reserved }),
        entry!(H2nGains { k_x, k_y, k_theta, k_d, lookahead }),
        entry!(H2nCreateArgs { struct_size, kind, config, has_robot, reserved, limits, gains,
            footprint_radius }),
        entry!(H2nObject { instance, vtable }),
        entry!(H2nPose { x, y, theta }),
        entry!(H2nTwist { vx, vy, omega }),
        entry!(H2nAgent { id, position, velocity, radius, history, history_len }),
        entry!(H2nTrajBatch { data, len, batch, horizon, dim }),
        entry!(H2nF64Out { data, len }),
        entry!(H2nConstraintContext { struct_size, reserved, dt, limits, initial_velocity, agents,
            agent_count }),
        entry!(H2nConstraintVTable { struct_size, reserved, destroy, last_error, name, evaluate,
            properties }),
        entry!(H2nRobotState { pose, velocity }),
        entry!(H2nPlanView { t0, dt, poses, pose_count }),
        entry!(H2nCoupledLimit { v, lateral, omega, max }),
        entry!(H2nEmbodimentVTable { struct_size, reserved, destroy, last_error, name, holonomic,
            saturate, step, track, coupled_limit }),
        entry!(H2nObstacle { kind, reserved, x0, y0, x1, y1, radius, vertices, vertex_count }),
        entry!(H2nOccupancyGrid { origin, resolution, width, height, data, occupied_threshold,
            reserved }),
        entry!(H2nObservation { struct_size, reserved, time, ego, ego_velocity, goal, agents,
            agent_count, obstacles, obstacle_count, occupancy }),
        entry!(H2nPlanOut { t0, dt, poses, capacity, len, fallback, reserved, note }),
        entry!(H2nPlannerVTable { struct_size, reserved, destroy, last_error, name, reset, plan,
            last_plan }),
    ]
}
