//! Fixed-step pose sequences and the motion quantities derived from them.
//!
//! A [`Trajectory`] is `T` SE(2) poses `p_0 … p_{T−1}` at a fixed step `dt` (default
//! [`DEFAULT_HORIZON`] = 32 poses at [`DEFAULT_DT`] = 0.1 s, the paper's 3.2 s). Everything the
//! feasibility terms and the TFS look at is derived per **segment** `i = 0 … T−2`, the motion
//! from `p_i` to `p_{i+1}`, with this finite-difference convention:
//!
//! * heading change `Δθ_i = wrap(θ_{i+1} − θ_i)` and **midpoint heading**
//!   `θ_m = θ_i + Δθ_i / 2`;
//! * chord `d = (x_{i+1} − x_i, y_{i+1} − y_i)` expressed in the frame of `θ_m`:
//!   `v_i = (cos θ_m·d_x + sin θ_m·d_y) / dt` (signed longitudinal speed, negative when
//!   reversing) and `vy_i = (−sin θ_m·d_x + cos θ_m·d_y) / dt` (body-frame lateral speed).
//!   For a constant-twist arc `exp(dt·(v, 0, ω))` the chord points exactly along `θ_m`, so a
//!   unicycle (differential-drive, Ackermann) motion has `vy = 0` exactly and `v` equals the
//!   chord length over `dt` (`v·sinc(ω·dt/2)` for the arc speed `v`);
//! * yaw rate `ω_i = Δθ_i / dt`;
//! * curvature `κ_i = ω_i / sqrt(v_i² + ε_κ²)` with [`KAPPA_EPS`] `ε_κ = 0.05 m/s`: turning in
//!   place gets a large but finite curvature (`ω/ε_κ`), exactly what an Ackermann robot cannot
//!   do, and the value stays differentiable at `v = 0`;
//! * longitudinal acceleration between consecutive segments `a_i = (v_{i+1} − v_i) / dt`,
//!   `i = 0 … T−3`, optionally preceded by the **initial acceleration**
//!   `a_init = (v_0 − v_init) / dt` from the robot's current longitudinal speed `v_init` (the
//!   plan must be reachable from the current velocity). `v_init` is the velocity executed over
//!   the previous control step, which like `v_0` is a step average, so the two are `dt` apart.
//!
//! With the initial acceleration, the list `accelerations()[j]` (`j = 0 … T−2`) is the
//! acceleration *ending* at segment `j`, i.e. arriving at waypoint `j + 1`; the TFS
//! ([`crate::feasibility`]) uses exactly this alignment.
//!
//! The same quantities are available as allocation-free kernels on flat `[T, 3]` slices
//! (`x, y, θ` per pose): [`segment_values`] for values and [`segment_jet`] for values plus their
//! analytic gradients with respect to the six coordinates of the two poses, which the
//! constraint terms of [`crate::constraint`] use.

use crate::se2::{Pose2, wrap_angle};
use serde::{Deserialize, Serialize};

/// Default number of poses per trajectory (the paper's 3.2 s at 0.1 s).
pub const DEFAULT_HORIZON: usize = 32;

/// Default time step between poses (s).
pub const DEFAULT_DT: f64 = 0.1;

/// `ε_κ` of the curvature `κ = ω / sqrt(v² + ε_κ²)` (m/s).
pub const KAPPA_EPS: f64 = 0.05;

/// Why a trajectory could not be built.
#[derive(Debug, thiserror::Error)]
pub enum TrajectoryError {
    /// The time step is zero, negative or not finite.
    #[error("time step dt = {dt} s must be finite and positive")]
    InvalidDt {
        /// The time step given (s).
        dt: f64,
    },
    /// A pose has a non-finite coordinate.
    #[error("pose {index} is not finite")]
    NonFinite {
        /// Index of the first non-finite pose.
        index: usize,
    },
    /// A flat pose array whose length is not a multiple of 3.
    #[error("{len} values are not a whole number of (x, y, θ) poses")]
    Shape {
        /// Number of values given.
        len: usize,
    },
}

/// `T` poses at a fixed time step: `poses[k]` is the pose at `k·dt`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Trajectory {
    /// Time between consecutive poses (s).
    pub dt: f64,
    /// The poses, oldest first.
    pub poses: Vec<Pose2>,
}

/// All derived quantities of one trajectory (see the module docs for the convention).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Kinematics {
    /// Signed longitudinal speed per segment (m/s), `T − 1` values.
    pub v: Vec<f64>,
    /// Body-frame lateral speed per segment (m/s), `T − 1` values.
    pub vy: Vec<f64>,
    /// Yaw rate per segment (rad/s), `T − 1` values.
    pub omega: Vec<f64>,
    /// Curvature per segment (1/m), `T − 1` values.
    pub kappa: Vec<f64>,
    /// Longitudinal acceleration (m/s²): `T − 1` values (the first from the initial speed) when
    /// an initial speed was given, else the `T − 2` values between consecutive segments.
    pub accel: Vec<f64>,
}

impl Trajectory {
    /// Checks that `dt` is finite and positive and every pose is finite.
    pub fn new(dt: f64, poses: Vec<Pose2>) -> Result<Self, TrajectoryError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(TrajectoryError::InvalidDt { dt });
        }
        if let Some(index) = poses.iter().position(|p| !p.is_finite()) {
            return Err(TrajectoryError::NonFinite { index });
        }
        Ok(Self { dt, poses })
    }

    /// Builds a trajectory from a flat `[T, 3]` slice (`x, y, θ` per pose).
    pub fn from_flat(dt: f64, data: &[f64]) -> Result<Self, TrajectoryError> {
        if data.len() % 3 != 0 {
            return Err(TrajectoryError::Shape { len: data.len() });
        }
        Self::new(dt, data.chunks_exact(3).map(Pose2::from_slice).collect())
    }

    /// The poses as a flat `[T, 3]` vector.
    pub fn to_flat(&self) -> Vec<f64> {
        self.poses.iter().flat_map(|p| p.to_array()).collect()
    }

    /// Number of poses `T`.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when there are no poses.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Time covered, `(T − 1)·dt`.
    pub fn duration(&self) -> f64 {
        self.dt * self.poses.len().saturating_sub(1) as f64
    }

    fn segments(&self) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
        self.poses
            .windows(2)
            .map(|w| segment_values(&w[0].to_array(), &w[1].to_array(), self.dt))
    }

    /// Signed longitudinal speed `v_i` per segment (m/s), `T − 1` values.
    pub fn speeds(&self) -> Vec<f64> {
        self.segments().map(|s| s.0).collect()
    }

    /// Body-frame lateral speed `vy_i` per segment (m/s), `T − 1` values.
    pub fn lateral_speeds(&self) -> Vec<f64> {
        self.segments().map(|s| s.1).collect()
    }

    /// Yaw rate `ω_i` per segment (rad/s), `T − 1` values.
    pub fn yaw_rates(&self) -> Vec<f64> {
        self.segments().map(|s| s.2).collect()
    }

    /// Curvature `κ_i = ω_i / sqrt(v_i² + ε_κ²)` per segment (1/m), `T − 1` values.
    pub fn curvatures(&self) -> Vec<f64> {
        self.segments().map(|(v, _, w)| curvature(v, w)).collect()
    }

    /// Longitudinal accelerations (m/s²). With `Some(v_init)` the first value is the initial
    /// acceleration `(v_0 − v_init)/dt` and there are `T − 1` values; with `None`, `T − 2`.
    pub fn accelerations(&self, initial_speed: Option<f64>) -> Vec<f64> {
        let v = self.speeds();
        let mut out = Vec::with_capacity(v.len());
        accelerations_into(&v, self.dt, initial_speed, &mut out);
        out
    }

    /// Every derived quantity at once.
    pub fn kinematics(&self, initial_speed: Option<f64>) -> Kinematics {
        let mut k = Kinematics::default();
        kinematics_into(&self.to_flat(), self.dt, initial_speed, &mut k);
        k
    }
}

impl Default for Trajectory {
    /// [`DEFAULT_HORIZON`] identity poses at [`DEFAULT_DT`] (standing still).
    fn default() -> Self {
        Self {
            dt: DEFAULT_DT,
            poses: vec![Pose2::IDENTITY; DEFAULT_HORIZON],
        }
    }
}

/// `(v, vy, ω)` of the segment from pose `p0` to pose `p1` (each `[x, y, θ]`).
#[inline]
pub fn segment_values(p0: &[f64], p1: &[f64], dt: f64) -> (f64, f64, f64) {
    let dtheta = wrap_angle(p1[2] - p0[2]);
    let (s, c) = (p0[2] + 0.5 * dtheta).sin_cos();
    let (dx, dy) = (p1[0] - p0[0], p1[1] - p0[1]);
    ((c * dx + s * dy) / dt, (-s * dx + c * dy) / dt, dtheta / dt)
}

/// The curvature `κ = ω / sqrt(v² + ε_κ²)`.
#[inline]
pub fn curvature(v: f64, omega: f64) -> f64 {
    omega / (v * v + KAPPA_EPS * KAPPA_EPS).sqrt()
}

/// One segment's `v`, `vy`, `ω` together with their gradients with respect to the six
/// coordinates `[x_i, y_i, θ_i, x_{i+1}, y_{i+1}, θ_{i+1}]` of its two poses.
///
/// The derivative of the angle wrap is taken as 1 (its value everywhere except at the jump).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SegmentJet {
    /// Signed longitudinal speed along the midpoint heading (m/s), negative when reversing.
    pub v: f64,
    /// Lateral speed in the frame of the midpoint heading (m/s), positive to the left.
    pub vy: f64,
    /// Yaw rate, the wrapped heading change over `dt` (rad/s).
    pub omega: f64,
    /// Gradient of `v` with respect to `[x_i, y_i, θ_i, x_{i+1}, y_{i+1}, θ_{i+1}]`.
    pub dv: [f64; 6],
    /// Gradient of `vy` with respect to the six coordinates.
    pub dvy: [f64; 6],
    /// Gradient of `omega` with respect to the six coordinates (only the two headings count).
    pub domega: [f64; 6],
}

impl SegmentJet {
    /// The curvature `κ = ω / sqrt(v² + ε_κ²)` and its gradient over the six coordinates.
    pub fn curvature(&self) -> (f64, [f64; 6]) {
        let r2 = self.v * self.v + KAPPA_EPS * KAPPA_EPS;
        let r = r2.sqrt();
        let kappa = self.omega / r;
        // ∂κ/∂ω = 1/r, ∂κ/∂v = −ω·v / r³.
        let dk_dv = -kappa * self.v / r2;
        let mut d = [0.0; 6];
        for j in 0..6 {
            d[j] = self.domega[j] / r + dk_dv * self.dv[j];
        }
        (kappa, d)
    }
}

/// Values and gradients of the segment from `p0` to `p1` (each `[x, y, θ]`).
///
/// With `c = cos θ_m`, `s = sin θ_m` and `∂θ_m/∂θ_i = ∂θ_m/∂θ_{i+1} = 1/2`:
/// `∇v = [−c, −s, vy·dt/2, c, s, vy·dt/2]/dt`, `∇vy = [s, −c, −v·dt/2, −s, c, −v·dt/2]/dt`,
/// `∇ω = [0, 0, −1, 0, 0, 1]/dt`.
#[inline]
pub fn segment_jet(p0: &[f64], p1: &[f64], dt: f64) -> SegmentJet {
    let dtheta = wrap_angle(p1[2] - p0[2]);
    let (s, c) = (p0[2] + 0.5 * dtheta).sin_cos();
    let (dx, dy) = (p1[0] - p0[0], p1[1] - p0[1]);
    let inv = 1.0 / dt;
    let v = (c * dx + s * dy) * inv;
    let vy = (-s * dx + c * dy) * inv;
    let (cs, ss) = (c * inv, s * inv);
    SegmentJet {
        v,
        vy,
        omega: dtheta * inv,
        dv: [-cs, -ss, 0.5 * vy, cs, ss, 0.5 * vy],
        dvy: [ss, -cs, -0.5 * v, -ss, cs, -0.5 * v],
        domega: [0.0, 0.0, -inv, 0.0, 0.0, inv],
    }
}

/// Writes the accelerations of the speed list `v` into `out` (cleared first): with
/// `Some(v_init)` first `(v_0 − v_init)/dt`, then `(v_{i+1} − v_i)/dt`.
pub fn accelerations_into(v: &[f64], dt: f64, initial_speed: Option<f64>, out: &mut Vec<f64>) {
    out.clear();
    if let (Some(v0), Some(first)) = (initial_speed, v.first()) {
        out.push((first - v0) / dt);
    }
    out.extend(v.windows(2).map(|w| (w[1] - w[0]) / dt));
}

/// Fills `out` with every derived quantity of the flat `[T, 3]` trajectory `poses`, reusing the
/// vectors' capacity (no allocation once they are large enough).
///
/// # Panics
/// If `poses.len()` is not a multiple of 3 (a programming error).
pub fn kinematics_into(poses: &[f64], dt: f64, initial_speed: Option<f64>, out: &mut Kinematics) {
    assert_eq!(
        poses.len() % 3,
        0,
        "kinematics_into: length not a multiple of 3"
    );
    out.v.clear();
    out.vy.clear();
    out.omega.clear();
    out.kappa.clear();
    let t = poses.len() / 3;
    for i in 0..t.saturating_sub(1) {
        let (v, vy, w) = segment_values(&poses[3 * i..3 * i + 3], &poses[3 * i + 3..3 * i + 6], dt);
        out.v.push(v);
        out.vy.push(vy);
        out.omega.push(w);
        out.kappa.push(curvature(v, w));
    }
    accelerations_into(&out.v, dt, initial_speed, &mut out.accel);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se2::Twist2;
    use approx::assert_relative_eq;
    use proptest::prelude::*;

    /// Integrates a constant body twist from `start` for `t` poses.
    fn constant_twist(start: Pose2, w: Twist2, dt: f64, t: usize) -> Trajectory {
        let mut poses = vec![start];
        for _ in 1..t {
            let last = poses[poses.len() - 1];
            poses.push(last.euler_step(w, dt));
        }
        Trajectory::new(dt, poses).unwrap()
    }

    #[test]
    fn straight_line_closed_form() {
        let tr = constant_twist(
            Pose2::new(1.0, 2.0, 0.7),
            Twist2::new(1.5, 0.0, 0.0),
            0.1,
            32,
        );
        assert_eq!(tr.speeds().len(), 31);
        for v in tr.speeds() {
            assert_relative_eq!(v, 1.5, epsilon = 1e-12);
        }
        for vy in tr.lateral_speeds() {
            assert_relative_eq!(vy, 0.0, epsilon = 1e-12);
        }
        for k in tr.curvatures() {
            assert_relative_eq!(k, 0.0, epsilon = 1e-12);
        }
        let a = tr.accelerations(Some(0.5));
        assert_eq!(a.len(), 31);
        assert_relative_eq!(a[0], 10.0, epsilon = 1e-10);
        for &ai in &a[1..] {
            assert_relative_eq!(ai, 0.0, epsilon = 1e-10);
        }
        assert_eq!(tr.accelerations(None).len(), 30);
        assert_relative_eq!(tr.duration(), 3.1, epsilon = 1e-12);
    }

    #[test]
    fn arc_has_zero_lateral_speed_and_chord_speed() {
        // Unicycle arc: v = 1 m/s, ω = 0.8 rad/s. The chord speed is v·sinc(ω·dt/2).
        let (v, w, dt) = (1.0, 0.8, 0.1);
        let tr = constant_twist(Pose2::new(0.0, 0.0, 3.0), Twist2::new(v, 0.0, w), dt, 40);
        let half = 0.5 * w * dt;
        let chord = v * half.sin() / half;
        for (s, l) in tr.speeds().iter().zip(tr.lateral_speeds()) {
            assert_relative_eq!(*s, chord, epsilon = 1e-12);
            assert_relative_eq!(l, 0.0, epsilon = 1e-12);
        }
        for yr in tr.yaw_rates() {
            // The heading crosses ±π along the way; the wrap keeps ω constant.
            assert_relative_eq!(yr, w, epsilon = 1e-12);
        }
        for k in tr.curvatures() {
            assert_relative_eq!(
                k,
                w / (chord * chord + KAPPA_EPS * KAPPA_EPS).sqrt(),
                epsilon = 1e-12
            );
        }
    }

    #[test]
    fn sideways_and_reverse_motion() {
        let tr = constant_twist(
            Pose2::new(0.0, 0.0, -1.0),
            Twist2::new(-0.4, 0.3, 0.0),
            0.1,
            5,
        );
        for (v, vy) in tr.speeds().iter().zip(tr.lateral_speeds()) {
            assert_relative_eq!(*v, -0.4, epsilon = 1e-12);
            assert_relative_eq!(vy, 0.3, epsilon = 1e-12);
        }
    }

    #[test]
    fn turning_in_place_has_large_curvature() {
        let tr = constant_twist(Pose2::IDENTITY, Twist2::new(0.0, 0.0, 0.5), 0.1, 3);
        for k in tr.curvatures() {
            assert_relative_eq!(k, 0.5 / KAPPA_EPS, epsilon = 1e-12);
        }
    }

    #[test]
    fn constructors_reject_bad_input() {
        assert!(matches!(
            Trajectory::new(0.0, vec![]),
            Err(TrajectoryError::InvalidDt { .. })
        ));
        assert!(matches!(
            Trajectory::new(0.1, vec![Pose2::IDENTITY, Pose2::new(f64::NAN, 0.0, 0.0)]),
            Err(TrajectoryError::NonFinite { index: 1 })
        ));
        assert!(matches!(
            Trajectory::from_flat(0.1, &[0.0; 4]),
            Err(TrajectoryError::Shape { len: 4 })
        ));
        let tr = Trajectory::from_flat(0.1, &[0.0, 0.0, 0.0, 1.0, 2.0, 0.5]).unwrap();
        assert_eq!(tr.to_flat(), vec![0.0, 0.0, 0.0, 1.0, 2.0, 0.5]);
        let d = Trajectory::default();
        assert_eq!(d.len(), DEFAULT_HORIZON);
        assert!(d.speeds().iter().all(|&v| v == 0.0));
    }

    #[test]
    fn kinematics_into_matches_the_plain_functions() {
        let tr = constant_twist(
            Pose2::new(0.3, -0.2, 0.1),
            Twist2::new(0.9, 0.1, -0.6),
            0.1,
            12,
        );
        let k = tr.kinematics(Some(0.2));
        assert_eq!(k.v, tr.speeds());
        assert_eq!(k.vy, tr.lateral_speeds());
        assert_eq!(k.omega, tr.yaw_rates());
        assert_eq!(k.kappa, tr.curvatures());
        assert_eq!(k.accel, tr.accelerations(Some(0.2)));
    }

    /// Central finite differences of a scalar function of the two poses' six coordinates.
    fn fd6(f: impl Fn(&[f64; 6]) -> f64, at: [f64; 6]) -> [f64; 6] {
        let h = 1e-6;
        let mut g = [0.0; 6];
        for j in 0..6 {
            let (mut p, mut m) = (at, at);
            p[j] += h;
            m[j] -= h;
            g[j] = (f(&p) - f(&m)) / (2.0 * h);
        }
        g
    }

    fn seg(p: &[f64; 6], dt: f64) -> SegmentJet {
        segment_jet(&p[..3], &p[3..], dt)
    }

    proptest! {
        #[test]
        fn segment_jet_gradients_match_finite_differences(
            x0 in -3.0..3.0f64, y0 in -3.0..3.0f64, t0 in -3.0..3.0f64,
            dx in -0.3..0.3f64, dy in -0.3..0.3f64, dth in -1.0..1.0f64,
            dt in 0.05..0.2f64,
        ) {
            let at = [x0, y0, t0, x0 + dx, y0 + dy, t0 + dth];
            let jet = seg(&at, dt);
            let (kappa, dk) = jet.curvature();
            let (v, vy, w) = segment_values(&at[..3], &at[3..], dt);
            prop_assert!((jet.v - v).abs() < 1e-12 && (jet.vy - vy).abs() < 1e-12);
            prop_assert!((jet.omega - w).abs() < 1e-12 && (kappa - curvature(v, w)).abs() < 1e-9);
            let checks: [([f64; 6], [f64; 6]); 4] = [
                (jet.dv, fd6(|p| seg(p, dt).v, at)),
                (jet.dvy, fd6(|p| seg(p, dt).vy, at)),
                (jet.domega, fd6(|p| seg(p, dt).omega, at)),
                (dk, fd6(|p| seg(p, dt).curvature().0, at)),
            ];
            for (analytic, numeric) in checks {
                for j in 0..6 {
                    let tol = 1e-5 * (1.0 + numeric[j].abs());
                    prop_assert!((analytic[j] - numeric[j]).abs() < tol,
                        "coordinate {}: analytic {} vs finite difference {}", j, analytic[j], numeric[j]);
                }
            }
        }

        #[test]
        fn unicycle_segments_have_no_lateral_speed(
            t0 in -3.2..3.2f64, v in -2.0..2.0f64, w in -3.0..3.0f64,
        ) {
            let p0 = Pose2::new(0.5, -0.5, t0);
            let p1 = p0.euler_step(Twist2::new(v, 0.0, w), 0.1);
            let (_, vy, om) = segment_values(&p0.to_array(), &p1.to_array(), 0.1);
            prop_assert!(vy.abs() < 1e-12);
            prop_assert!((om - w).abs() < 1e-9);
        }
    }
}
