//! The robot's footprint as the simulator checks collisions with it: the xy projection of the
//! base link's `<collision>` geometry, one convex shape per element, in the base-link frame.
//!
//! Planners plan with a coarser, simpler body: the disc about the base-link origin that covers
//! every shape ([`super::RobotProfile::footprint_radius`]). A car whose base link is its rear
//! axle is the case where the two differ most: its body box lies ahead of the origin.

use crate::se2::Pose2;
use serde::{Deserialize, Serialize};

/// One convex piece of the footprint, in the base-link frame (m, rad).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "snake_case")]
pub enum FootprintShape {
    /// A disc (an upright cylinder or a sphere; the covering disc of a tilted element).
    Disc {
        /// Centre `[x, y]` in the base-link frame (m).
        center: [f64; 2],
        /// Radius (m).
        radius: f64,
    },
    /// A rectangle (an upright box): half extents along its own axes, rotated by `yaw`.
    Rect {
        /// Centre `[x, y]` in the base-link frame (m).
        center: [f64; 2],
        /// Half extents along the rectangle's own x and y axes (m).
        half: [f64; 2],
        /// Rotation of the rectangle's axes from the base link's x axis (rad, counter-clockwise).
        yaw: f64,
    },
}

impl FootprintShape {
    /// Signed distance from the point `p` (base-link frame) to the shape: positive outside,
    /// negative inside (minus the depth).
    pub fn signed_distance(&self, p: [f64; 2]) -> f64 {
        match *self {
            FootprintShape::Disc { center, radius } => {
                (p[0] - center[0]).hypot(p[1] - center[1]) - radius
            }
            FootprintShape::Rect { center, half, yaw } => {
                let (s, c) = yaw.sin_cos();
                let (dx, dy) = (p[0] - center[0], p[1] - center[1]);
                // The point in the rectangle's own axes, folded into the first quadrant.
                let qx = (c * dx + s * dy).abs() - half[0];
                let qy = (-s * dx + c * dy).abs() - half[1];
                let outside = qx.max(0.0).hypot(qy.max(0.0));
                outside + qx.max(qy).min(0.0)
            }
        }
    }

    /// The farthest distance of the shape from the base-link origin (the radius of the
    /// smallest disc about the origin that covers it).
    pub fn reach(&self) -> f64 {
        match *self {
            FootprintShape::Disc { center, radius } => center[0].hypot(center[1]) + radius,
            FootprintShape::Rect { .. } => self
                .corners()
                .iter()
                .map(|p| p[0].hypot(p[1]))
                .fold(0.0, f64::max),
        }
    }

    /// The rectangle's corners, counter-clockwise (empty for a disc).
    pub fn corners(&self) -> Vec<[f64; 2]> {
        match *self {
            FootprintShape::Disc { .. } => Vec::new(),
            FootprintShape::Rect { center, half, yaw } => rect_corners(center, half, yaw).into(),
        }
    }
}

impl std::fmt::Display for FootprintShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let n = |v: f64| (v * 1e3).round() / 1e3;
        match *self {
            FootprintShape::Disc { center, radius } => write!(
                f,
                "disc r {} m at ({}, {})",
                n(radius),
                n(center[0]),
                n(center[1])
            ),
            FootprintShape::Rect { center, half, yaw } => {
                write!(
                    f,
                    "box {} × {} m at ({}, {})",
                    n(2.0 * half[0]),
                    n(2.0 * half[1]),
                    n(center[0]),
                    n(center[1])
                )?;
                if yaw != 0.0 {
                    write!(f, ", yaw {} rad", n(yaw))?;
                }
                Ok(())
            }
        }
    }
}

/// The corners of the rectangle [`FootprintShape::Rect`] `{ center, half, yaw }`,
/// counter-clockwise.
pub(crate) fn rect_corners(center: [f64; 2], half: [f64; 2], yaw: f64) -> [[f64; 2]; 4] {
    let (s, c) = yaw.sin_cos();
    [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)].map(|(a, b)| {
        let (x, y) = (a * half[0], b * half[1]);
        [center[0] + c * x - s * y, center[1] + s * x + c * y]
    })
}

/// The farthest any of `shapes` reaches from the base-link origin (0 for an empty footprint):
/// no point of the footprint is farther from the robot's pose than this.
pub fn reach(shapes: &[FootprintShape]) -> f64 {
    shapes.iter().map(FootprintShape::reach).fold(0.0, f64::max)
}

/// The clearance between a footprint at the origin of its frame and a disc of `radius` at `p`
/// (base-link frame): the smallest signed distance to any shape minus the radius, `+∞` for an
/// empty footprint.
pub fn clearance(shapes: &[FootprintShape], p: [f64; 2], radius: f64) -> f64 {
    shapes
        .iter()
        .map(|s| s.signed_distance(p))
        .fold(f64::INFINITY, f64::min)
        - radius
}

/// [`clearance`] with the footprint placed at `pose` and the disc's centre `p` in the same
/// frame as `pose`.
pub fn clearance_at(shapes: &[FootprintShape], pose: Pose2, p: [f64; 2], radius: f64) -> f64 {
    clearance_at_turned(shapes, pose, pose.theta.sin_cos(), p, radius)
}

/// [`clearance_at`] with the sine and cosine of the pose's heading given, for a caller that
/// checks many discs against one pose.
pub fn clearance_at_turned(
    shapes: &[FootprintShape],
    pose: Pose2,
    turn: (f64, f64),
    p: [f64; 2],
    radius: f64,
) -> f64 {
    clearance(shapes, pose.inverse_act_turned(turn, p), radius)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn rectangle_distance_outside_inside_and_rotated() {
        let r = FootprintShape::Rect {
            center: [0.325, 0.0],
            half: [0.49, 0.3725],
            yaw: 0.0,
        };
        // Beside the long side, past the front, past a corner, inside.
        assert_relative_eq!(r.signed_distance([0.325, 1.0]), 0.6275, epsilon = 1e-12);
        assert_relative_eq!(r.signed_distance([1.815, 0.0]), 1.0, epsilon = 1e-12);
        assert_relative_eq!(
            r.signed_distance([0.815 + 0.3, 0.3725 + 0.4]),
            0.5,
            epsilon = 1e-12
        );
        assert_relative_eq!(r.signed_distance([0.325, 0.3]), -0.0725, epsilon = 1e-12);
        // A quarter turn swaps the extents.
        let q = FootprintShape::Rect {
            center: [0.0, 0.0],
            half: [0.35, 0.155],
            yaw: std::f64::consts::FRAC_PI_2,
        };
        assert_relative_eq!(q.signed_distance([0.0, 1.0]), 0.65, epsilon = 1e-12);
        assert_relative_eq!(q.signed_distance([1.0, 0.0]), 0.845, epsilon = 1e-12);
        // Reach: the farthest corner from the origin.
        assert_relative_eq!(r.reach(), 0.815f64.hypot(0.3725), epsilon = 1e-12);
    }

    #[test]
    fn disc_distance_and_clearance_take_the_nearest_shape() {
        let d = FootprintShape::Disc {
            center: [0.1, 0.0],
            radius: 0.3,
        };
        assert_relative_eq!(d.signed_distance([1.1, 0.0]), 0.7, epsilon = 1e-12);
        assert_relative_eq!(d.reach(), 0.4, epsilon = 1e-12);
        let far = FootprintShape::Disc {
            center: [5.0, 0.0],
            radius: 0.3,
        };
        assert_relative_eq!(clearance(&[far, d], [1.1, 0.0], 0.3), 0.4, epsilon = 1e-12);
        assert_eq!(clearance(&[], [0.0, 0.0], 0.3), f64::INFINITY);
    }
}
