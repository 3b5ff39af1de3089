//! The observation a C caller passes ([`h2n_observation`]), checked and converted into the
//! planner's [`Observation`], obstacles included.

use crate::args::finite;
use crate::failure::Failure;
use crate::{H2N_MAX_AGENTS, H2N_MAX_OBSTACLES, h2n_agent, h2n_observation, h2n_obstacle_kind};
use human2nav_core::obstacle::{MAX_POLYGON_VERTICES, Obstacle};
use human2nav_core::{AgentState, Observation, Pose2, Twist2};

/// The observation as the planner takes it, every number checked.
///
/// # Safety
/// `obs.agents` points to `obs.agent_count` agents when the count is not 0.
pub(crate) unsafe fn observation(obs: &h2n_observation) -> Result<Observation, Failure> {
    if obs.agent_count > H2N_MAX_AGENTS {
        return Err(Failure::invalid(format!(
            "observation.agent_count {} is more than {H2N_MAX_AGENTS}",
            obs.agent_count
        )));
    }
    let agents: &[h2n_agent] = if obs.agent_count == 0 {
        &[]
    } else if obs.agents.is_null() {
        return Err(Failure::invalid(format!(
            "observation.agents is NULL but agent_count is {}",
            obs.agent_count
        )));
    } else {
        // SAFETY: non-null, `agent_count` elements (the caller's contract), capped above.
        unsafe { std::slice::from_raw_parts(obs.agents, obs.agent_count) }
    };
    finite("observation.time", &[obs.time])?;
    finite("observation.ego", &[obs.ego.x, obs.ego.y, obs.ego.theta])?;
    let v = obs.ego_velocity;
    finite("observation.ego_velocity", &[v.vx, v.vy, v.omega])?;
    finite("observation.goal", &[obs.goal_x, obs.goal_y])?;
    let mut out = Vec::with_capacity(agents.len());
    for (i, a) in agents.iter().enumerate() {
        finite(
            &format!("observation.agents[{i}] (id {})", a.id),
            &[a.x, a.y, a.vx, a.vy, a.radius],
        )?;
        if a.radius < 0.0 {
            return Err(Failure::invalid(format!(
                "observation.agents[{i}] (id {}): radius {} is negative",
                a.id, a.radius
            )));
        }
        out.push(AgentState {
            id: a.id,
            position: [a.x, a.y],
            velocity: [a.vx, a.vy],
            radius: a.radius,
            history: Vec::new(),
        });
    }
    // SAFETY: the caller's contract on `obstacles` and their vertices.
    let obstacles = unsafe { obstacles(obs) }?;
    Ok(Observation {
        time: obs.time,
        ego: Pose2::new(obs.ego.x, obs.ego.y, obs.ego.theta),
        ego_velocity: Twist2::new(v.vx, v.vy, v.omega),
        goal: [obs.goal_x, obs.goal_y],
        agents: out,
        obstacles,
        ..Default::default()
    })
}

/// The observation's obstacles, checked (the planner validates their numbers).
///
/// # Safety
/// `obs.obstacles` points to `obs.obstacle_count` obstacles when the count is not 0, and each
/// polygon's `vertices` to `2·vertex_count` numbers.
unsafe fn obstacles(obs: &h2n_observation) -> Result<Vec<Obstacle>, Failure> {
    if obs.obstacle_count > H2N_MAX_OBSTACLES {
        return Err(Failure::invalid(format!(
            "observation.obstacle_count {} is more than {H2N_MAX_OBSTACLES}",
            obs.obstacle_count
        )));
    }
    if obs.obstacle_count == 0 {
        return Ok(Vec::new());
    }
    if obs.obstacles.is_null() {
        return Err(Failure::invalid(format!(
            "observation.obstacles is NULL but obstacle_count is {}",
            obs.obstacle_count
        )));
    }
    // SAFETY: non-null, `obstacle_count` elements (the caller's contract), capped above.
    let raw = unsafe { std::slice::from_raw_parts(obs.obstacles, obs.obstacle_count) };
    let mut out = Vec::with_capacity(raw.len());
    for (i, o) in raw.iter().enumerate() {
        let obstacle = match o.kind {
            k if k == h2n_obstacle_kind::Circle as i32 => Obstacle::Circle {
                center: [o.x0, o.y0],
                radius: o.radius,
            },
            k if k == h2n_obstacle_kind::Segment as i32 => Obstacle::Segment {
                a: [o.x0, o.y0],
                b: [o.x1, o.y1],
            },
            k if k == h2n_obstacle_kind::Polygon as i32 => {
                if !(3..=MAX_POLYGON_VERTICES).contains(&o.vertex_count) {
                    return Err(Failure::invalid(format!(
                        "observation.obstacles[{i}]: a polygon needs 3 to \
                         {MAX_POLYGON_VERTICES} vertices, vertex_count is {}",
                        o.vertex_count
                    )));
                }
                if o.vertices.is_null() {
                    return Err(Failure::invalid(format!(
                        "observation.obstacles[{i}].vertices is NULL"
                    )));
                }
                // SAFETY: non-null, 2·vertex_count numbers (contract), count capped above.
                let xy = unsafe { std::slice::from_raw_parts(o.vertices, 2 * o.vertex_count) };
                Obstacle::Polygon {
                    vertices: xy.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
                }
            }
            other => {
                return Err(Failure::invalid(format!(
                    "observation.obstacles[{i}].kind {other} is not an h2n_obstacle_kind \
                     (0 circle, 1 segment, 2 polygon)"
                )));
            }
        };
        out.push(obstacle);
    }
    Ok(out)
}
