//! Step 4 of resolving a profile: the effective limits after the URDF caps (wheel rim speeds,
//! a differential drive's yaw rate, an Ackermann robot's turning radius), with provenance.

use super::*;

/// The limits the robot actually has, after the URDF caps.
pub(in crate::robot) struct Effective {
    /// The effective limits (SI units).
    pub(in crate::robot) limits: Limits,
    /// Where each of `limits` came from.
    pub(in crate::robot) sources: LimitProvenance,
    /// Effective minimum turning radius (m, 0 = turns in place); `kappa_max = 1 / r`.
    pub(in crate::robot) min_turning_radius: f64,
    /// Distance along x between the steering and the wheel axles (m), for an Ackermann robot
    /// with steering joints.
    pub(in crate::robot) wheelbase: Option<f64>,
}

/// The effective limits: `v_max` and `v_reverse_max` capped by the slowest wheel's rim speed,
/// `omega_max` by the wheels of a differential drive, the turning radius raised to what the
/// steering joints of an Ackermann robot allow; `a_max` and `lateral_speed_max` as given.
pub(in crate::robot) fn limits(
    given: &RawLimits,
    kind: Option<EmbodimentKind>,
    urdf: &UrdfFacts,
    ck: &Checker<'_>,
) -> Result<Effective, ProfileError> {
    let wheel_cap = urdf
        .wheel_joints
        .iter()
        .filter_map(|w| w.velocity_limit.map(|v| (v * w.radius, w)))
        .min_by(|a, b| a.0.total_cmp(&b.0));
    let (v_max, v_max_src) = cap_speed("v_max", given.v_max, wheel_cap);
    let (v_reverse_max, v_reverse_src) = cap_speed("v_reverse_max", given.v_reverse_max, wheel_cap);
    let (omega_max, omega_src) = cap_omega(given.omega_max, kind, wheel_cap, urdf.track_width);
    for (field, v, src) in [
        ("limits.v_max", v_max, &v_max_src),
        ("limits.v_reverse_max", v_reverse_max, &v_reverse_src),
        ("limits.omega_max", omega_max, &omega_src),
    ] {
        if !(v.is_finite() && v >= SPEED_RANGE.0) {
            return Err(ck.invalid(
                field,
                format!(
                    "the URDF caps it at {v:e}, below {:e}: {src}",
                    SPEED_RANGE.0
                ),
            ));
        }
    }
    let (r_min, kappa_src, wheelbase) = turning_radius(
        given.min_turning_radius,
        kind,
        &urdf.wheel_joints,
        &urdf.steering_joints,
        ck,
    )?;
    Ok(Effective {
        limits: Limits {
            v_max,
            v_reverse_max,
            a_max: given.a_max,
            omega_max,
            kappa_max: (r_min > 0.0).then(|| 1.0 / r_min),
            lateral_speed_max: given.lateral_speed_max,
            coupled: None,
        },
        sources: LimitProvenance {
            v_max: v_max_src,
            v_reverse_max: v_reverse_src,
            a_max: Provenance::profile("robot.toml [limits] a_max"),
            omega_max: omega_src,
            kappa_max: kappa_src,
            lateral_speed_max: Provenance::profile("robot.toml [limits] lateral_speed_max"),
        },
        min_turning_radius: r_min,
        wheelbase,
    })
}

/// A speed limit (m/s) `given` under `[limits] field`, lowered to the slowest wheel's rim speed
/// `wheel_cap` (m/s, with its wheel) when that is smaller.
fn cap_speed(field: &str, given: f64, wheel_cap: Option<(f64, &WheelJoint)>) -> (f64, Provenance) {
    let toml = format!("robot.toml [limits] {field}");
    match wheel_cap {
        Some((cap, w)) if cap < given => (
            cap,
            Provenance::urdf(format!(
                "URDF joint `{}` velocity {} rad/s × wheel radius {} m (robot.toml said {})",
                w.name,
                num(w.velocity_limit.unwrap_or(0.0)),
                num(w.radius),
                num(given)
            )),
        ),
        Some((cap, w)) => (
            given,
            Provenance::profile(format!(
                "{toml} (URDF joint `{}` allows {} m/s)",
                w.name,
                num(cap)
            )),
        ),
        None => (given, Provenance::profile(toml)),
    }
}

/// The yaw-rate limit (rad/s): for a differential drive with a wheel cap and a track, the
/// smaller of `omega_max` and `2 · wheel_cap / track`; otherwise `omega_max` as given.
fn cap_omega(
    omega_max: f64,
    kind: Option<EmbodimentKind>,
    wheel_cap: Option<(f64, &WheelJoint)>,
    track_width: Option<f64>,
) -> (f64, Provenance) {
    match (kind, wheel_cap, track_width) {
        (Some(EmbodimentKind::DifferentialDrive), Some((cap, _)), Some(track)) => {
            let w_cap = 2.0 * cap / track;
            if w_cap < omega_max {
                (
                    w_cap,
                    Provenance::urdf(format!(
                        "URDF wheels: 2 × {} m/s / track {} m (robot.toml said {})",
                        num(cap),
                        num(track),
                        num(omega_max)
                    )),
                )
            } else {
                (
                    omega_max,
                    Provenance::profile(format!(
                        "robot.toml [limits] omega_max (URDF wheels allow {} rad/s)",
                        num(w_cap)
                    )),
                )
            }
        }
        _ => (
            omega_max,
            Provenance::profile("robot.toml [limits] omega_max"),
        ),
    }
}

/// The effective minimum turning radius (m, 0 = turns in place) with the provenance of
/// `kappa_max`, and the wheelbase (m) when the steering joints set one. An Ackermann robot
/// takes the larger of `min_turning_radius` and the steering joints' `L / tan δ_max`, and must
/// have one of the two; any other robot takes `min_turning_radius` as given.
fn turning_radius(
    min_turning_radius: f64,
    kind: Option<EmbodimentKind>,
    wheel_joints: &[WheelJoint],
    steering_joints: &[SteeringJoint],
    ck: &Checker<'_>,
) -> Result<(f64, Provenance, Option<f64>), ProfileError> {
    if kind != Some(EmbodimentKind::Ackermann) {
        return Ok(if min_turning_radius > 0.0 {
            (
                min_turning_radius,
                Provenance::profile("1 / robot.toml [limits] min_turning_radius"),
                None,
            )
        } else {
            (
                0.0,
                Provenance::profile(
                    "none: robot.toml [limits] min_turning_radius = 0 (turns in place)",
                ),
                None,
            )
        });
    }
    let from_urdf = steering_geometry(wheel_joints, steering_joints, ck)?;
    let wheelbase = from_urdf.as_ref().map(|s| s.wheelbase);
    let (r_min, source) = match from_urdf {
        Some(s) if s.r_min > min_turning_radius => (
            s.r_min,
            Provenance::urdf(format!(
                "URDF joint `{}` steering limit {} rad, wheelbase {} m: r_min = L / tan δ = {} m (robot.toml said {})",
                s.joint,
                num(s.delta),
                num(s.wheelbase),
                num(s.r_min),
                num(min_turning_radius)
            )),
        ),
        Some(s) => (
            min_turning_radius,
            Provenance::profile(format!(
                "1 / robot.toml [limits] min_turning_radius (URDF steering allows r_min {} m)",
                num(s.r_min)
            )),
        ),
        None if min_turning_radius > 0.0 => (
            min_turning_radius,
            Provenance::profile("1 / robot.toml [limits] min_turning_radius"),
        ),
        None => {
            return Err(ck.invalid(
                "limits.min_turning_radius",
                "an ackermann robot cannot turn in place: give min_turning_radius > 0 or \
                 embodiment.steering_joints",
            ));
        }
    };
    Ok((r_min, source, wheelbase))
}

/// The turning geometry an Ackermann robot's steering joints give.
struct SteeringGeometry<'a> {
    /// `r_min = L / tan δ_max` (m).
    r_min: f64,
    /// The wheelbase `L` (m, > 0).
    wheelbase: f64,
    /// The smallest steering limit `δ_max` over the steering joints (rad).
    delta: f64,
    /// The steering joint with that limit.
    joint: &'a str,
}

/// The wheelbase (distance along x between the mean steering-joint and the mean wheel-joint
/// origin) and the minimum turning radius it gives with the tightest steering limit; `None`
/// without steering joints. Needs the wheel joints and a wheelbase that is not 0.
fn steering_geometry<'a>(
    wheel_joints: &[WheelJoint],
    steering_joints: &'a [SteeringJoint],
    ck: &Checker<'_>,
) -> Result<Option<SteeringGeometry<'a>>, ProfileError> {
    if steering_joints.is_empty() {
        return Ok(None);
    }
    if wheel_joints.is_empty() {
        return Err(ck.invalid(
            "embodiment.wheel_joints",
            "an ackermann robot with steering_joints needs its rear wheel joints too \
             (the wheelbase is measured between the two)",
        ));
    }
    let mean_x = |xs: &mut dyn Iterator<Item = f64>, n: usize| xs.sum::<f64>() / n as f64;
    let front = mean_x(
        &mut steering_joints.iter().map(|s| s.position[0]),
        steering_joints.len(),
    );
    let rear = mean_x(
        &mut wheel_joints.iter().map(|w| w.position[0]),
        wheel_joints.len(),
    );
    let l = (front - rear).abs();
    if !(l.is_finite() && l > 1e-6) {
        return Err(ck.invalid(
            "embodiment.steering_joints",
            "the steering joints sit on the wheel joints' axle (wheelbase 0)",
        ));
    }
    let (delta, joint) = steering_joints
        .iter()
        .map(|s| (s.max_angle, s.name.as_str()))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .unwrap_or((0.0, ""));
    Ok(Some(SteeringGeometry {
        r_min: l / delta.tan(),
        wheelbase: l,
        delta,
        joint,
    }))
}
