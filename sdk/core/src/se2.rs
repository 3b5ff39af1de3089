//! The special Euclidean group SE(2) and its Lie algebra se(2).
//!
//! A [`Pose2`] is a rigid transform `(x, y, θ)`; a [`Twist2`] is a body-frame velocity
//! `(v_x, v_y, ω)` in se(2). Composition is `a ∘ b` (apply `b` in the frame of `a`),
//! [`Pose2::exp`] maps a twist to the pose reached after one unit of time at that constant
//! body velocity, and [`Pose2::log`] is its inverse with `θ` wrapped to `(-π, π]`.
//!
//! Paper equations: geodesic interpolation `x0·exp(t·log(x0⁻¹x1))` (Eq. 4) is
//! [`Pose2::interpolate`]; the Lie-group Euler step `X·exp(Δt·V)` (Eq. 5) is
//! [`Pose2::euler_step`]. Batched forms work on flat `[N, 3]` arrays of `f64` laid out
//! `x, y, θ` (poses) or `v_x, v_y, ω` (twists), the layout shared by every batch API of the
//! SDK.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Below this |θ| the closed forms of `exp`/`log` switch to their Taylor series.
const SMALL_ANGLE: f64 = 1e-6;

/// Wraps an angle to `(-π, π]`.
pub fn wrap_angle(a: f64) -> f64 {
    if a > -PI && a <= PI {
        return a;
    }
    let r = (a + PI).rem_euclid(2.0 * PI) - PI;
    // rem_euclid maps the boundary to -π; the half-open interval keeps +π.
    if r <= -PI { r + 2.0 * PI } else { r }
}

/// A rigid transform in the plane: translation `(x, y)` in metres and heading `θ` in radians.
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose2 {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

/// A body-frame velocity in se(2): longitudinal `v_x`, lateral `v_y` (m/s), yaw rate `ω` (rad/s).
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist2 {
    pub vx: f64,
    pub vy: f64,
    pub omega: f64,
}

impl Twist2 {
    pub const ZERO: Twist2 = Twist2 { vx: 0.0, vy: 0.0, omega: 0.0 };

    pub const fn new(vx: f64, vy: f64, omega: f64) -> Self {
        Self { vx, vy, omega }
    }

    /// The twist scaled by `s`.
    pub fn scale(self, s: f64) -> Self {
        Self::new(self.vx * s, self.vy * s, self.omega * s)
    }

    pub fn to_array(self) -> [f64; 3] {
        [self.vx, self.vy, self.omega]
    }

    pub fn from_slice(s: &[f64]) -> Self {
        Self::new(s[0], s[1], s[2])
    }

    pub fn is_finite(self) -> bool {
        self.vx.is_finite() && self.vy.is_finite() && self.omega.is_finite()
    }
}

/// `sin θ / θ` and `(1 − cos θ) / θ`, the entries of the left Jacobian `V(θ)`.
fn v_coefficients(theta: f64) -> (f64, f64) {
    if theta.abs() < SMALL_ANGLE {
        let t2 = theta * theta;
        (1.0 - t2 / 6.0, theta / 2.0 - theta * t2 / 24.0)
    } else {
        (theta.sin() / theta, (1.0 - theta.cos()) / theta)
    }
}

impl Pose2 {
    pub const IDENTITY: Pose2 = Pose2 { x: 0.0, y: 0.0, theta: 0.0 };

    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    pub fn to_array(self) -> [f64; 3] {
        [self.x, self.y, self.theta]
    }

    pub fn from_slice(s: &[f64]) -> Self {
        Self::new(s[0], s[1], s[2])
    }

    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta.is_finite()
    }

    /// The same pose with `θ` wrapped to `(-π, π]`.
    pub fn normalized(self) -> Self {
        Self::new(self.x, self.y, wrap_angle(self.theta))
    }

    /// `self ∘ other`: `other` expressed in the frame of `self`, mapped to the outer frame.
    pub fn compose(self, other: Pose2) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2::new(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            wrap_angle(self.theta + other.theta),
        )
    }

    /// The inverse transform, so that `p.compose(p.inverse())` is the identity.
    pub fn inverse(self) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2::new(
            -c * self.x - s * self.y,
            s * self.x - c * self.y,
            wrap_angle(-self.theta),
        )
    }

    /// `self⁻¹ ∘ other`: `other` seen from the frame of `self`.
    pub fn between(self, other: Pose2) -> Pose2 {
        self.inverse().compose(other)
    }

    /// Applies the transform to a point: `R(θ)·p + t`.
    pub fn act(self, p: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.theta.sin_cos();
        [self.x + c * p[0] - s * p[1], self.y + s * p[0] + c * p[1]]
    }

    /// Rotates a free vector (a velocity, say) without translating it.
    pub fn rotate(self, v: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.theta.sin_cos();
        [c * v[0] - s * v[1], s * v[0] + c * v[1]]
    }

    /// Maps a world point into this frame: `R(θ)ᵀ·(p − t)`.
    pub fn inverse_act(self, p: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.theta.sin_cos();
        let (dx, dy) = (p[0] - self.x, p[1] - self.y);
        [c * dx + s * dy, -s * dx + c * dy]
    }

    /// Rotates a world-frame vector into this frame.
    pub fn inverse_rotate(self, v: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.theta.sin_cos();
        [c * v[0] + s * v[1], -s * v[0] + c * v[1]]
    }

    /// The exponential map se(2) → SE(2): the pose reached from the identity after one unit of
    /// time at constant body velocity `xi`. `θ` of the result is wrapped.
    pub fn exp(xi: Twist2) -> Pose2 {
        let (a, b) = v_coefficients(xi.omega);
        Pose2::new(
            a * xi.vx - b * xi.vy,
            b * xi.vx + a * xi.vy,
            wrap_angle(xi.omega),
        )
    }

    /// The logarithm SE(2) → se(2), the inverse of [`Pose2::exp`] with `ω ∈ (-π, π]`.
    pub fn log(self) -> Twist2 {
        let theta = wrap_angle(self.theta);
        let half = 0.5 * theta;
        // V(θ)⁻¹ = [[A, θ/2], [−θ/2, A]] with A = (θ/2)·cot(θ/2).
        let a = if theta.abs() < SMALL_ANGLE {
            1.0 - theta * theta / 12.0
        } else {
            half * half.cos() / half.sin()
        };
        Twist2::new(
            a * self.x + half * self.y,
            -half * self.x + a * self.y,
            theta,
        )
    }

    /// Geodesic interpolation `self·exp(t·log(self⁻¹·other))` (paper Eq. 4).
    pub fn interpolate(self, other: Pose2, t: f64) -> Pose2 {
        self.compose(Pose2::exp(self.between(other).log().scale(t)))
    }

    /// The Lie-group Euler step `self·exp(dt·v)` (paper Eq. 5).
    pub fn euler_step(self, v: Twist2, dt: f64) -> Pose2 {
        self.compose(Pose2::exp(v.scale(dt)))
    }
}

/// Batched [`Pose2::exp`] over flat `[N, 3]` arrays.
///
/// # Panics
/// If the lengths differ or are not multiples of 3 (a programming error, never user input).
pub fn exp_batch(xi: &[f64], out: &mut [f64]) {
    assert_eq!(xi.len(), out.len(), "exp_batch: length mismatch");
    assert_eq!(xi.len() % 3, 0, "exp_batch: length not a multiple of 3");
    for (x, o) in xi.chunks_exact(3).zip(out.chunks_exact_mut(3)) {
        o.copy_from_slice(&Pose2::exp(Twist2::from_slice(x)).to_array());
    }
}

/// Batched [`Pose2::log`] over flat `[N, 3]` arrays.
pub fn log_batch(poses: &[f64], out: &mut [f64]) {
    assert_eq!(poses.len(), out.len(), "log_batch: length mismatch");
    assert_eq!(poses.len() % 3, 0, "log_batch: length not a multiple of 3");
    for (p, o) in poses.chunks_exact(3).zip(out.chunks_exact_mut(3)) {
        o.copy_from_slice(&Pose2::from_slice(p).log().to_array());
    }
}

/// Batched geodesic interpolation (Eq. 4) between two `[N, 3]` pose arrays.
pub fn interpolate_batch(x0: &[f64], x1: &[f64], t: f64, out: &mut [f64]) {
    assert!(x0.len() == x1.len() && x0.len() == out.len(), "interpolate_batch: length mismatch");
    assert_eq!(x0.len() % 3, 0, "interpolate_batch: length not a multiple of 3");
    for ((a, b), o) in x0.chunks_exact(3).zip(x1.chunks_exact(3)).zip(out.chunks_exact_mut(3)) {
        let p = Pose2::from_slice(a).interpolate(Pose2::from_slice(b), t);
        o.copy_from_slice(&p.to_array());
    }
}

/// Batched Lie-group Euler step (Eq. 5), in place: `poses[i] ← poses[i]·exp(dt·v[i])`.
pub fn euler_step_batch(poses: &mut [f64], v: &[f64], dt: f64) {
    assert_eq!(poses.len(), v.len(), "euler_step_batch: length mismatch");
    assert_eq!(poses.len() % 3, 0, "euler_step_batch: length not a multiple of 3");
    for (p, w) in poses.chunks_exact_mut(3).zip(v.chunks_exact(3)) {
        let next = Pose2::from_slice(p).euler_step(Twist2::from_slice(w), dt);
        p.copy_from_slice(&next.to_array());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn wrap_angle_is_half_open_at_pi() {
        assert_relative_eq!(wrap_angle(PI), PI);
        assert_relative_eq!(wrap_angle(-PI), PI);
        assert_relative_eq!(wrap_angle(3.0 * PI), PI);
        assert_relative_eq!(wrap_angle(0.5 + 4.0 * PI), 0.5, epsilon = 1e-12);
        assert_relative_eq!(wrap_angle(-0.5 - 6.0 * PI), -0.5, epsilon = 1e-12);
    }

    #[test]
    fn exp_of_pure_rotation_and_translation() {
        let p = Pose2::exp(Twist2::new(1.0, 2.0, 0.0));
        assert_relative_eq!(p.x, 1.0);
        assert_relative_eq!(p.y, 2.0);
        // Quarter circle of radius 1: v = 1, ω = π/2 for one second ends at (2/π, 2/π).
        let q = Pose2::exp(Twist2::new(PI / 2.0, 0.0, PI / 2.0));
        assert_relative_eq!(q.x, 1.0, epsilon = 1e-12);
        assert_relative_eq!(q.y, 1.0, epsilon = 1e-12);
        assert_relative_eq!(q.theta, PI / 2.0, epsilon = 1e-12);
    }

    #[test]
    fn log_inverts_exp_at_small_angles() {
        for &w in &[0.0, 1e-9, -1e-7, 1e-5, 1e-3] {
            let xi = Twist2::new(0.7, -0.2, w);
            let back = Pose2::exp(xi).log();
            assert_relative_eq!(back.vx, xi.vx, epsilon = 1e-12);
            assert_relative_eq!(back.vy, xi.vy, epsilon = 1e-12);
            assert_relative_eq!(back.omega, xi.omega, epsilon = 1e-15);
        }
    }

    #[test]
    fn interpolation_hits_endpoints() {
        let a = Pose2::new(1.0, -2.0, 0.3);
        let b = Pose2::new(-0.5, 4.0, 2.9);
        let p0 = a.interpolate(b, 0.0);
        let p1 = a.interpolate(b, 1.0);
        assert_relative_eq!(p0.x, a.x, epsilon = 1e-12);
        assert_relative_eq!(p1.x, b.x, epsilon = 1e-12);
        assert_relative_eq!(p1.y, b.y, epsilon = 1e-12);
        assert_relative_eq!(p1.theta, b.theta, epsilon = 1e-12);
    }
}
