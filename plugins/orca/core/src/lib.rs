//! ORCA (optimal reciprocal collision avoidance, van den Berg et al. 2011) as a human2nav
//! planner, with the semantics of the RVO2 library.
//!
//! * [`lp`]: RVO2's incremental 2-D linear programs, solved exactly.
//! * [`orca`]: neighbour selection, ORCA half-planes and the new velocity of one agent.
//! * [`obstacle`]: static obstacles as RVO2 obstacles and their ORCA lines (circles, segments
//!   and polygons; the occupancy grid is not used).
//! * [`kdtree`]: the k-d tree (and the brute-force scan) that find a crowd's neighbours.
//! * [`sim`]: [`OrcaSim`], a crowd of ORCA agents stepped together (RVO2's `doStep`).
//! * [`planner`]: [`OrcaPlanner`], the [`human2nav_core::Planner`] that turns the ORCA velocity
//!   into a plan the robot's tracking controller follows (the documented holonomic → embodiment
//!   conversion).
//!
//! This crate has no plugin entry point, so other plugins can link it (SARL simulates ORCA
//! humans and converts velocities like ORCA); `human2nav-orca` (`plugins/orca`) re-exports it
//! and is the `cdylib` the host loads.

pub mod kdtree;
pub mod lp;
pub mod obstacle;
pub mod orca;
pub mod planner;
pub mod sim;

pub use planner::{OrcaConfig, OrcaError, OrcaPlanner};
pub use sim::{NeighborSearch, OrcaSim};
