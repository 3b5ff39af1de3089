//! Core of the human2nav SDK (no libtorch).
//!
//! * [`se2`]: the SE(2) Lie group used for every pose and trajectory.
//! * [`trajectory`]: fixed-step pose sequences and their derived speed, acceleration, yaw rate,
//!   curvature and lateral speed.
//! * [`input`]: reading user-named files (regular files only, with a size cap); [`fileset`]:
//!   folders of files committed as one set with a manifest written last; [`lock`]: one writer
//!   per output folder.
//! * [`robot`]: robot profiles (`robot.toml` + URDF) with their [`limits`].
//! * [`embodiment`]: kinematic models, command saturation and tracking controllers.
//! * [`constraint`]: constraint terms, the soft-margin penalty of Eq. 8 and Φ of Eq. 9.
//! * [`feasibility`]: the trajectory feasibility score (TFS; also reachable by its former name
//!   `tfs`).
//! * [`bev`]: the ego-centred bird's-eye-view raster shared by training and inference.
//! * [`flow`], [`guidance`]: the flow-model interface and feasibility guidance (Algorithm 1).
//! * [`forecast`]: what the people around the robot may do, and the predictors that say so.
//! * [`planner`]: the `Planner` trait, observations and plans.
//! * [`obstacle`]: static obstacles and occupancy grids; [`frames`]: pedestrians from another
//!   frame and time.
//! * [`human2nav`]: the reference planner (sampling, guidance, selection).
//! * [`ablation`]: the four-arm guidance ablation (raw, Algorithm 1, QP, both).

#![warn(missing_docs)]

pub mod ablation;
pub mod bev;
pub mod constraint;
pub mod embodiment;
pub mod feasibility;
pub mod fileset;
pub mod flow;
pub mod forecast;
pub mod frames;
pub mod guidance;
pub mod human2nav;
pub mod input;
pub mod limits;
pub mod lock;
pub mod motions;
pub mod obstacle;
pub mod planner;
pub mod projection;
pub mod robot;
pub mod se2;
pub mod social_force;
pub mod trajectory;

/// The former name of [`feasibility`], kept so that existing paths resolve.
pub use feasibility as tfs;

pub use flow::{FlowCondition, FlowError, FlowModel};
pub use limits::{ControllerGains, CoupledLimit, GuidanceWeights, Limits};
pub use planner::{
    AgentState, Deadline, Observation, Plan, PlanError, PlanInfo, Planner, Stage, StageProgress,
    Stages,
};
pub use se2::{Pose2, Twist2};
