//! Conversions between the ABI structs and the core types they carry (limits, gains, poses,
//! twists, robot states) and [`H2nAgent::borrow`].

use super::{H2nAgent, H2nGains, H2nLimits, H2nPose, H2nRobotState, H2nTwist};
use human2nav_core::{ControllerGains, Limits, Pose2, Twist2};

impl From<&Limits> for H2nLimits {
    fn from(l: &Limits) -> Self {
        Self {
            v_max: l.v_max,
            v_reverse_max: l.v_reverse_max,
            a_max: l.a_max,
            omega_max: l.omega_max,
            kappa_max: l.kappa_max.unwrap_or(0.0),
            lateral_speed_max: l.lateral_speed_max,
            has_kappa_max: u32::from(l.kappa_max.is_some()),
            reserved: 0,
        }
    }
}

impl From<&H2nLimits> for Limits {
    fn from(l: &H2nLimits) -> Self {
        Self {
            v_max: l.v_max,
            v_reverse_max: l.v_reverse_max,
            a_max: l.a_max,
            omega_max: l.omega_max,
            kappa_max: (l.has_kappa_max != 0).then_some(l.kappa_max),
            lateral_speed_max: l.lateral_speed_max,
            // Not carried by the ABI's limits: the embodiment declares it (`coupled_limit`).
            coupled: None,
        }
    }
}

impl From<&ControllerGains> for H2nGains {
    fn from(g: &ControllerGains) -> Self {
        Self {
            k_x: g.k_x,
            k_y: g.k_y,
            k_theta: g.k_theta,
            k_d: g.k_d,
            lookahead: g.lookahead,
        }
    }
}

impl From<&H2nGains> for ControllerGains {
    fn from(g: &H2nGains) -> Self {
        Self {
            k_x: g.k_x,
            k_y: g.k_y,
            k_theta: g.k_theta,
            k_d: g.k_d,
            lookahead: g.lookahead,
        }
    }
}

impl From<Pose2> for H2nPose {
    fn from(p: Pose2) -> Self {
        Self {
            x: p.x,
            y: p.y,
            theta: p.theta,
        }
    }
}

impl From<H2nPose> for Pose2 {
    fn from(p: H2nPose) -> Self {
        Pose2::new(p.x, p.y, p.theta)
    }
}

impl From<Twist2> for H2nTwist {
    fn from(t: Twist2) -> Self {
        Self {
            vx: t.vx,
            vy: t.vy,
            omega: t.omega,
        }
    }
}

impl From<H2nTwist> for Twist2 {
    fn from(t: H2nTwist) -> Self {
        Twist2::new(t.vx, t.vy, t.omega)
    }
}

impl From<&human2nav_core::embodiment::RobotState> for H2nRobotState {
    fn from(s: &human2nav_core::embodiment::RobotState) -> Self {
        Self {
            pose: s.pose.into(),
            velocity: s.velocity.into(),
        }
    }
}

impl From<&H2nRobotState> for human2nav_core::embodiment::RobotState {
    fn from(s: &H2nRobotState) -> Self {
        Self {
            pose: s.pose.into(),
            velocity: s.velocity.into(),
        }
    }
}

impl H2nAgent {
    /// A view of `a` whose `history` borrows `a.history` (valid while `a` is).
    pub fn borrow(a: &human2nav_core::AgentState) -> Self {
        Self {
            id: a.id,
            position: a.position,
            velocity: a.velocity,
            radius: a.radius,
            history: if a.history.is_empty() {
                std::ptr::null()
            } else {
                a.history.as_ptr().cast()
            },
            history_len: a.history.len(),
        }
    }
}
