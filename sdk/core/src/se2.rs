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
    /// Translation along the x axis of the frame the pose is expressed in (m).
    pub x: f64,
    /// Translation along that frame's y axis (m).
    pub y: f64,
    /// Heading (rad), counter-clockwise from that frame's x axis; kept as given by
    /// [`Pose2::new`], wrapped to `(-π, π]` by the group operations.
    pub theta: f64,
}

/// A body-frame velocity in se(2): longitudinal `v_x`, lateral `v_y` (m/s), yaw rate `ω` (rad/s).
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist2 {
    /// Longitudinal velocity along the body x axis, forward positive (m/s).
    pub vx: f64,
    /// Lateral velocity along the body y axis, positive to the left (m/s).
    pub vy: f64,
    /// Yaw rate, counter-clockwise positive (rad/s).
    pub omega: f64,
}

impl Twist2 {
    /// Standing still: every component 0.
    pub const ZERO: Twist2 = Twist2 {
        vx: 0.0,
        vy: 0.0,
        omega: 0.0,
    };

    /// A body-frame twist from `v_x`, `v_y` (m/s) and `ω` (rad/s).
    pub const fn new(vx: f64, vy: f64, omega: f64) -> Self {
        Self { vx, vy, omega }
    }

    /// The twist scaled by `s`.
    pub fn scale(self, s: f64) -> Self {
        Self::new(self.vx * s, self.vy * s, self.omega * s)
    }

    /// `[v_x, v_y, ω]`, the twist layout of the batched APIs.
    pub fn to_array(self) -> [f64; 3] {
        [self.vx, self.vy, self.omega]
    }

    /// The twist from the first three values `[v_x, v_y, ω]` of `s`; panics when `s` holds
    /// fewer than three.
    pub fn from_slice(s: &[f64]) -> Self {
        Self::new(s[0], s[1], s[2])
    }

    /// True when all three components are finite.
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
        // 1 − cos θ = 2·sin²(θ/2) avoids the cancellation of the direct form near 0.
        let h = (0.5 * theta).sin();
        (theta.sin() / theta, 2.0 * h * h / theta)
    }
}

impl Pose2 {
    /// The identity transform: origin, heading 0.
    pub const IDENTITY: Pose2 = Pose2 {
        x: 0.0,
        y: 0.0,
        theta: 0.0,
    };

    /// A pose from `x`, `y` (m) and `θ` (rad), `θ` taken as given (not wrapped).
    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    /// `[x, y, θ]`, the pose layout of the batched APIs.
    pub fn to_array(self) -> [f64; 3] {
        [self.x, self.y, self.theta]
    }

    /// The pose from the first three values `[x, y, θ]` of `s`; panics when `s` holds fewer
    /// than three.
    pub fn from_slice(s: &[f64]) -> Self {
        Self::new(s[0], s[1], s[2])
    }

    /// True when all three coordinates are finite.
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
        self.inverse_act_turned(self.theta.sin_cos(), p)
    }

    /// [`Self::inverse_act`] with the heading's sine and cosine `(s, c)` given, for mapping
    /// many points into one frame.
    pub fn inverse_act_turned(self, (s, c): (f64, f64), p: [f64; 2]) -> [f64; 2] {
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
    assert!(
        x0.len() == x1.len() && x0.len() == out.len(),
        "interpolate_batch: length mismatch"
    );
    assert_eq!(
        x0.len() % 3,
        0,
        "interpolate_batch: length not a multiple of 3"
    );
    for ((a, b), o) in x0
        .chunks_exact(3)
        .zip(x1.chunks_exact(3))
        .zip(out.chunks_exact_mut(3))
    {
        let p = Pose2::from_slice(a).interpolate(Pose2::from_slice(b), t);
        o.copy_from_slice(&p.to_array());
    }
}

/// Batched Lie-group Euler step (Eq. 5), in place: `poses[i] ← poses[i]·exp(dt·v[i])`.
pub fn euler_step_batch(poses: &mut [f64], v: &[f64], dt: f64) {
    assert_eq!(poses.len(), v.len(), "euler_step_batch: length mismatch");
    assert_eq!(
        poses.len() % 3,
        0,
        "euler_step_batch: length not a multiple of 3"
    );
    for (p, w) in poses.chunks_exact_mut(3).zip(v.chunks_exact(3)) {
        let next = Pose2::from_slice(p).euler_step(Twist2::from_slice(w), dt);
        p.copy_from_slice(&next.to_array());
    }
}

/// Below this |θ| the Jacobians of `exp`/`log` use Taylor series (their closed forms cancel).
const SMALL_ANGLE_JACOBIAN: f64 = 1e-3;

/// A 3×3 Jacobian in the `(x, y, θ)` / `(v_x, v_y, ω)` coordinates, row-major:
/// `j[r][c] = ∂out_r / ∂in_c`.
pub type Jacobian3 = [[f64; 3]; 3];

/// `∂ exp(ξ) / ∂ξ` in coordinates: rows are the pose's `x, y, θ`, columns the twist's
/// `v_x, v_y, ω` (the derivative of the wrap is taken as 1, its value away from ±π).
pub fn exp_jacobian(xi: Twist2) -> Jacobian3 {
    let w = xi.omega;
    let (a, b) = v_coefficients(w);
    // a' = d/dω (sin ω / ω), b' = d/dω ((1 − cos ω) / ω).
    let (da, db) = if w.abs() < SMALL_ANGLE_JACOBIAN {
        let w2 = w * w;
        (-w / 3.0 + w * w2 / 30.0, 0.5 - w2 / 8.0 + w2 * w2 / 144.0)
    } else {
        let (s, c) = w.sin_cos();
        ((w * c - s) / (w * w), (w * s - (1.0 - c)) / (w * w))
    };
    [
        [a, -b, da * xi.vx - db * xi.vy],
        [b, a, db * xi.vx + da * xi.vy],
        [0.0, 0.0, 1.0],
    ]
}

/// `∂ log(p) / ∂p` in coordinates: rows are the twist's `v_x, v_y, ω`, columns the pose's
/// `x, y, θ`. Valid away from `θ = ±π`, where `log` itself jumps.
pub fn log_jacobian(p: Pose2) -> Jacobian3 {
    let phi = wrap_angle(p.theta);
    let half = 0.5 * phi;
    // A(φ) = (φ/2)·cot(φ/2) and its derivative A'(φ).
    let (a, da) = if phi.abs() < SMALL_ANGLE_JACOBIAN {
        let p2 = phi * phi;
        (
            1.0 - p2 / 12.0 - p2 * p2 / 720.0,
            -phi / 6.0 - phi * p2 / 180.0,
        )
    } else {
        let (s, c) = half.sin_cos();
        (half * c / s, 0.5 * c / s - 0.25 * phi / (s * s))
    };
    [
        [a, half, da * p.x + 0.5 * p.y],
        [-half, a, -0.5 * p.x + da * p.y],
        [0.0, 0.0, 1.0],
    ]
}

/// `∂ p⁻¹ / ∂p` in coordinates.
pub fn inverse_jacobian(p: Pose2) -> Jacobian3 {
    let (s, c) = p.theta.sin_cos();
    [
        [-c, -s, s * p.x - c * p.y],
        [s, -c, c * p.x + s * p.y],
        [0.0, 0.0, -1.0],
    ]
}

/// The Jacobians of `a ∘ b` with respect to `a` and to `b`, in coordinates.
pub fn compose_jacobians(a: Pose2, b: Pose2) -> (Jacobian3, Jacobian3) {
    let (s, c) = a.theta.sin_cos();
    let ja = [
        [1.0, 0.0, -s * b.x - c * b.y],
        [0.0, 1.0, c * b.x - s * b.y],
        [0.0, 0.0, 1.0],
    ];
    let jb = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
    (ja, jb)
}

/// The Jacobians of the Euler step `x·exp(dt·w)` (Eq. 5) with respect to the pose `x` and
/// to the twist `w`, in coordinates. The second already contains the factor `dt`.
pub fn euler_step_jacobians(x: Pose2, w: Twist2, dt: f64) -> (Jacobian3, Jacobian3) {
    let xi = w.scale(dt);
    let (jx, jb) = compose_jacobians(x, Pose2::exp(xi));
    let je = exp_jacobian(xi);
    let mut jw = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            jw[r][c] = dt * (0..3).map(|k| jb[r][k] * je[k][c]).sum::<f64>();
        }
    }
    (jx, jw)
}

/// `jᵀ·v` for a 3×3 Jacobian: pulls a cotangent back through the map `j` linearises.
pub fn transpose_apply(j: &Jacobian3, v: [f64; 3]) -> [f64; 3] {
    [
        j[0][0] * v[0] + j[1][0] * v[1] + j[2][0] * v[2],
        j[0][1] * v[0] + j[1][1] * v[1] + j[2][1] * v[2],
        j[0][2] * v[0] + j[1][2] * v[1] + j[2][2] * v[2],
    ]
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

    // ---- group laws, Jacobians and edge cases ----

    use proptest::prelude::*;

    /// Angle difference wrapped to (-π, π], for comparing headings.
    fn dtheta(a: f64, b: f64) -> f64 {
        wrap_angle(a - b)
    }

    fn assert_pose_eq(a: Pose2, b: Pose2, tol: f64) {
        assert_relative_eq!(a.x, b.x, epsilon = tol);
        assert_relative_eq!(a.y, b.y, epsilon = tol);
        assert_relative_eq!(dtheta(a.theta, b.theta), 0.0, epsilon = tol);
    }

    fn pose() -> impl Strategy<Value = Pose2> {
        (-10.0..10.0f64, -10.0..10.0f64, -PI..PI).prop_map(|(x, y, t)| Pose2::new(x, y, t))
    }

    /// Twists whose rotation stays inside (-π, π), where `log(exp(ξ)) = ξ`.
    fn twist() -> impl Strategy<Value = Twist2> {
        (-5.0..5.0f64, -5.0..5.0f64, -3.1..3.1f64).prop_map(|(a, b, w)| Twist2::new(a, b, w))
    }

    proptest! {
        #[test]
        fn composition_is_associative(a in pose(), b in pose(), c in pose()) {
            assert_pose_eq(a.compose(b).compose(c), a.compose(b.compose(c)), 1e-9);
        }

        #[test]
        fn identity_is_neutral(a in pose()) {
            assert_pose_eq(a.compose(Pose2::IDENTITY), a, 1e-12);
            assert_pose_eq(Pose2::IDENTITY.compose(a), a, 1e-12);
        }

        #[test]
        fn inverse_is_two_sided(a in pose()) {
            assert_pose_eq(a.compose(a.inverse()), Pose2::IDENTITY, 1e-9);
            assert_pose_eq(a.inverse().compose(a), Pose2::IDENTITY, 1e-9);
            assert_pose_eq(a.inverse().inverse(), a, 1e-9);
        }

        #[test]
        fn log_of_exp_round_trips(xi in twist()) {
            let back = Pose2::exp(xi).log();
            prop_assert!((back.vx - xi.vx).abs() < 1e-9);
            prop_assert!((back.vy - xi.vy).abs() < 1e-9);
            prop_assert!((back.omega - xi.omega).abs() < 1e-12);
        }

        #[test]
        fn exp_of_log_round_trips(a in pose()) {
            assert_pose_eq(Pose2::exp(a.log()), a, 1e-9);
        }

        #[test]
        fn exp_is_a_one_parameter_subgroup(xi in twist(), s in 0.0..1.0f64) {
            // exp(sξ)·exp((1−s)ξ) = exp(ξ): the flow of a constant body velocity.
            let split = Pose2::exp(xi.scale(s)).compose(Pose2::exp(xi.scale(1.0 - s)));
            assert_pose_eq(split, Pose2::exp(xi), 1e-9);
        }

        #[test]
        fn action_matches_composition(a in pose(), b in pose(), px in -5.0..5.0f64, py in -5.0..5.0f64) {
            let lhs = a.compose(b).act([px, py]);
            let rhs = a.act(b.act([px, py]));
            prop_assert!((lhs[0] - rhs[0]).abs() < 1e-9 && (lhs[1] - rhs[1]).abs() < 1e-9);
            let back = a.inverse_act(a.act([px, py]));
            prop_assert!((back[0] - px).abs() < 1e-9 && (back[1] - py).abs() < 1e-9);
        }

        #[test]
        fn interpolation_follows_the_geodesic(a in pose(), b in pose(), t in 0.0..1.0f64) {
            // x(t) = a·exp(t·ξ) with ξ = log(a⁻¹b): the remaining way is exp((1−t)·ξ).
            let xt = a.interpolate(b, t);
            let xi = a.between(b).log();
            assert_pose_eq(xt.compose(Pose2::exp(xi.scale(1.0 - t))), b, 1e-8);
        }

        #[test]
        fn euler_step_is_right_multiplication(a in pose(), w in twist(), dt in 0.0..1.0f64) {
            assert_pose_eq(a.euler_step(w, dt), a.compose(Pose2::exp(w.scale(dt))), 1e-12);
        }

        #[test]
        fn wrap_angle_lands_in_half_open_interval(a in -100.0..100.0f64) {
            let w = wrap_angle(a);
            prop_assert!(w > -PI && w <= PI);
            prop_assert!(((a - w) / (2.0 * PI) - ((a - w) / (2.0 * PI)).round()).abs() < 1e-9);
        }

        #[test]
        fn exp_jacobian_matches_finite_differences(xi in twist()) {
            let j = exp_jacobian(xi);
            let fd = fd_jacobian(|v| Pose2::exp(Twist2::from_slice(v)).to_array(), xi.to_array());
            assert_jacobian_close(&j, &fd, 1e-6);
        }

        #[test]
        fn log_jacobian_matches_finite_differences(
            x in -5.0..5.0f64, y in -5.0..5.0f64, t in -3.0..3.0f64,
        ) {
            let j = log_jacobian(Pose2::new(x, y, t));
            let fd = fd_jacobian(|p| Pose2::from_slice(p).log().to_array(), [x, y, t]);
            assert_jacobian_close(&j, &fd, 1e-6);
        }

        #[test]
        fn inverse_and_compose_jacobians_match_finite_differences(a in pose(), b in pose()) {
            let a = Pose2::new(a.x, a.y, a.theta * 0.9);
            let b = Pose2::new(b.x, b.y, b.theta * 0.05);
            let fd = fd_jacobian(|p| Pose2::from_slice(p).inverse().to_array(), a.to_array());
            assert_jacobian_close(&inverse_jacobian(a), &fd, 1e-6);
            let (ja, jb) = compose_jacobians(a, b);
            let fa = fd_jacobian(|p| Pose2::from_slice(p).compose(b).to_array(), a.to_array());
            let fb = fd_jacobian(|p| a.compose(Pose2::from_slice(p)).to_array(), b.to_array());
            assert_jacobian_close(&ja, &fa, 1e-6);
            assert_jacobian_close(&jb, &fb, 1e-6);
        }

        #[test]
        fn euler_step_jacobians_match_finite_differences(a in pose(), w in twist(), dt in 0.01..0.5f64) {
            // Keep θ away from ±π so the wrapped output is differentiable.
            let a = Pose2::new(a.x, a.y, a.theta * 0.8);
            let w = Twist2::new(w.vx, w.vy, w.omega * 0.5);
            let (jx, jw) = euler_step_jacobians(a, w, dt);
            let fx = fd_jacobian(|p| Pose2::from_slice(p).euler_step(w, dt).to_array(), a.to_array());
            let fw = fd_jacobian(|v| a.euler_step(Twist2::from_slice(v), dt).to_array(), w.to_array());
            assert_jacobian_close(&jx, &fx, 1e-6);
            assert_jacobian_close(&jw, &fw, 1e-6);
        }
    }

    /// Central finite differences of a map R³ → R³ (step 1e-6), as a row-major Jacobian.
    fn fd_jacobian(f: impl Fn(&[f64]) -> [f64; 3], at: [f64; 3]) -> Jacobian3 {
        let h = 1e-6;
        let mut j = [[0.0; 3]; 3];
        for c in 0..3 {
            let mut p = at;
            let mut m = at;
            p[c] += h;
            m[c] -= h;
            let (fp, fm) = (f(&p), f(&m));
            for r in 0..3 {
                // Headings differ by a wrapped amount.
                let d = if r == 2 {
                    wrap_angle(fp[r] - fm[r])
                } else {
                    fp[r] - fm[r]
                };
                j[r][c] = d / (2.0 * h);
            }
        }
        j
    }

    fn assert_jacobian_close(a: &Jacobian3, b: &Jacobian3, tol: f64) {
        for r in 0..3 {
            for c in 0..3 {
                let scale = 1.0 + b[r][c].abs();
                assert!(
                    (a[r][c] - b[r][c]).abs() <= tol * scale,
                    "entry ({r},{c}): analytic {} vs finite difference {}",
                    a[r][c],
                    b[r][c]
                );
            }
        }
    }

    #[test]
    fn jacobians_at_small_angles_match_finite_differences() {
        for &w in &[0.0, 1e-9, -1e-5, 9e-4, -1.1e-3, 0.3] {
            let xi = Twist2::new(0.8, -0.3, w);
            let fd = fd_jacobian(
                |v| Pose2::exp(Twist2::from_slice(v)).to_array(),
                xi.to_array(),
            );
            assert_jacobian_close(&exp_jacobian(xi), &fd, 1e-7);
            let p = Pose2::new(0.8, -0.3, w);
            let fd = fd_jacobian(|v| Pose2::from_slice(v).log().to_array(), p.to_array());
            assert_jacobian_close(&log_jacobian(p), &fd, 1e-7);
        }
    }

    #[test]
    fn closed_form_values() {
        // Half turn on a unit circle: v = π, ω = π for one second ends at (0, 2), facing back.
        let p = Pose2::exp(Twist2::new(PI, 0.0, PI));
        assert_relative_eq!(p.x, 0.0, epsilon = 1e-12);
        assert_relative_eq!(p.y, 2.0, epsilon = 1e-12);
        assert_relative_eq!(p.theta, PI, epsilon = 1e-12);
        // log of a pure translation is that translation; of a pure rotation, that rotation.
        let xi = Pose2::new(3.0, -4.0, 0.0).log();
        assert_relative_eq!(xi.vx, 3.0);
        assert_relative_eq!(xi.vy, -4.0);
        let xi = Pose2::new(0.0, 0.0, -1.2).log();
        assert_relative_eq!(xi.omega, -1.2);
        assert_relative_eq!(xi.vx, 0.0);
        // Composition: translate then rotate, and the inverse of a rotated translation.
        let a = Pose2::new(1.0, 0.0, PI / 2.0);
        let b = Pose2::new(1.0, 0.0, 0.0);
        let ab = a.compose(b);
        assert_relative_eq!(ab.x, 1.0, epsilon = 1e-12);
        assert_relative_eq!(ab.y, 1.0, epsilon = 1e-12);
        let ai = a.inverse();
        assert_relative_eq!(ai.x, 0.0, epsilon = 1e-12);
        assert_relative_eq!(ai.y, 1.0, epsilon = 1e-12);
        assert_relative_eq!(ai.theta, -PI / 2.0, epsilon = 1e-12);
        // Geodesic midpoint between the identity and a quarter-circle end pose.
        let q = Pose2::exp(Twist2::new(PI / 2.0, 0.0, PI / 2.0));
        let m = Pose2::IDENTITY.interpolate(q, 0.5);
        let expected = Pose2::exp(Twist2::new(PI / 4.0, 0.0, PI / 4.0));
        assert_pose_eq(m, expected, 1e-12);
    }

    #[test]
    fn small_angle_branches_are_continuous() {
        // The Taylor and closed-form branches agree across the switch-over.
        for &w in &[SMALL_ANGLE * 0.999, SMALL_ANGLE * 1.001] {
            let p = Pose2::exp(Twist2::new(1.0, 0.5, w));
            assert_relative_eq!(p.x, 1.0 - 0.5 * w / 2.0, epsilon = 1e-12);
            assert_relative_eq!(p.y, 0.5 + w / 2.0, epsilon = 1e-12);
        }
        let a = exp_jacobian(Twist2::new(1.0, 0.5, SMALL_ANGLE_JACOBIAN * 0.999));
        let b = exp_jacobian(Twist2::new(1.0, 0.5, SMALL_ANGLE_JACOBIAN * 1.001));
        assert_jacobian_close(&a, &b, 1e-5);
    }

    #[test]
    fn heading_wraps_at_pi_under_composition_and_exp() {
        let a = Pose2::new(0.0, 0.0, 3.0);
        let b = Pose2::new(0.0, 0.0, 0.5);
        let ab = a.compose(b);
        assert_relative_eq!(ab.theta, 3.5 - 2.0 * PI, epsilon = 1e-12);
        // A full turn comes back to the start with θ = 0, not 2π.
        let full = Pose2::exp(Twist2::new(0.0, 0.0, 2.0 * PI));
        assert_relative_eq!(full.theta, 0.0, epsilon = 1e-12);
        // log picks the short way round.
        let back = Pose2::new(0.0, 0.0, 3.5).log();
        assert_relative_eq!(back.omega, 3.5 - 2.0 * PI, epsilon = 1e-12);
    }

    #[test]
    fn batched_forms_match_scalar_forms() {
        let poses = [0.1, 0.2, 0.3, -1.0, 2.0, -2.5];
        let twists = [1.0, 0.0, 0.5, 0.3, -0.2, -1.0];
        let mut out = [0.0; 6];
        exp_batch(&twists, &mut out);
        for k in 0..2 {
            let p = Pose2::exp(Twist2::from_slice(&twists[3 * k..]));
            assert_pose_eq(Pose2::from_slice(&out[3 * k..]), p, 1e-15);
        }
        log_batch(&poses, &mut out);
        for k in 0..2 {
            let xi = Pose2::from_slice(&poses[3 * k..]).log();
            assert_relative_eq!(out[3 * k], xi.vx);
            assert_relative_eq!(out[3 * k + 2], xi.omega);
        }
        let mut stepped = poses;
        euler_step_batch(&mut stepped, &twists, 0.1);
        for k in 0..2 {
            let p = Pose2::from_slice(&poses[3 * k..])
                .euler_step(Twist2::from_slice(&twists[3 * k..]), 0.1);
            assert_pose_eq(Pose2::from_slice(&stepped[3 * k..]), p, 1e-15);
        }
        interpolate_batch(&poses, &stepped, 1.0, &mut out);
        for k in 0..2 {
            assert_pose_eq(
                Pose2::from_slice(&out[3 * k..]),
                Pose2::from_slice(&stepped[3 * k..]),
                1e-12,
            );
        }
    }
}
