//! The steps of [`RobotProfile::load`](super::RobotProfile::load) after parsing, in the order
//! `from_raw` runs them, which is the order errors are reported in:
//!
//! 1. [`check_values`]: `name`, `urdf`, `[limits]`, `[footprint]`, `[controller]` and
//!    `[cost]`, before the URDF is opened, so a bad scalar is reported even when the URDF
//!    is broken too;
//! 2. [`embodiment`] and [`constraints`]: the `[embodiment]` section and the `[[constraint]]`
//!    plugin terms, with their paths resolved against the profile's directory;
//! 3. [`urdf`]: the URDF, its base link, the footprint and the wheel and steering joints;
//! 4. [`limits`]: the effective limits after the URDF caps, each with its provenance.

use super::footprint::FootprintShape;
use super::urdf::UrdfModel;
use super::{
    EmbodimentKind, EmbodimentSpec, LimitProvenance, MAX_PLUGIN_DEADLINE_MS, Origin, PluginRef,
    ProfileError, Provenance, RawConstraint, RawEmbodiment, RawLimits, RawProfile, SteeringJoint,
    WheelJoint,
};
use crate::limits::{ControllerGains, GuidanceWeights, Limits};
use std::path::{Path, PathBuf};

mod effective;
mod plugins;
mod urdf_facts;

pub(super) use effective::limits;
pub(super) use plugins::{builtin_kind, constraints, embodiment};
use urdf_facts::UrdfFacts;
pub(super) use urdf_facts::urdf;

// The range of every number of a profile. A limit is a positive SI value a robot among people
// can have (speeds up to the planner's `MAX_SPEED`); a gain or weight is 0 (off) or within six
// orders of magnitude either side of the shipped values. Outside, `1/limit`, `gain·error` or
// Φ's softplus overflow: 1e-300 and 1e300 both gave infinite costs.

/// `v_max`, `v_reverse_max`, `lateral_speed_max` (m/s).
pub const SPEED_RANGE: (f64, f64) = (1e-3, crate::planner::MAX_SPEED);
/// `a_max` (m/s²).
pub const ACCEL_RANGE: (f64, f64) = (1e-3, 100.0);
/// `omega_max` (rad/s).
pub const YAW_RATE_RANGE: (f64, f64) = (1e-3, 100.0);
/// `min_turning_radius` (or 0), `[footprint] radius`, a URDF wheel's radius and track (m).
pub const LENGTH_RANGE: (f64, f64) = (1e-3, 1000.0);
/// `[controller]` `k_x`, `k_y`, `k_theta`, `k_d` (or 0).
pub const GAIN_RANGE: (f64, f64) = (1e-6, 1e3);
/// `[controller] lookahead` (s).
pub const LOOKAHEAD_RANGE: (f64, f64) = (1e-3, 10.0);
/// `[cost]` `lambda_*` and a `[[constraint]]` `weight` (or 0).
pub const WEIGHT_RANGE: (f64, f64) = (1e-6, 1e6);
/// `[cost] gamma`.
pub const GAMMA_RANGE: (f64, f64) = (1e-3, 1e3);

/// Builds errors naming one profile file.
pub(super) struct Checker<'a> {
    /// The robot.toml being loaded.
    pub(super) file: &'a Path,
}

impl Checker<'_> {
    fn invalid(&self, field: impl Into<String>, message: impl Into<String>) -> ProfileError {
        ProfileError::Invalid {
            file: self.file.to_path_buf(),
            field: field.into(),
            message: message.into(),
        }
    }

    /// Finite and `> 0`.
    fn positive(&self, field: &str, v: f64) -> Result<f64, ProfileError> {
        if !v.is_finite() {
            Err(self.invalid(field, format!("must be a finite number, got {v}")))
        } else if v <= 0.0 {
            Err(self.invalid(field, format!("must be > 0, got {v}")))
        } else {
            Ok(v)
        }
    }

    /// Finite, in `[lo, hi]` (or exactly 0 where `zero` allows it; `lo > 0`).
    fn within(
        &self,
        field: &str,
        v: f64,
        (lo, hi): (f64, f64),
        zero: bool,
    ) -> Result<f64, ProfileError> {
        let v = if zero {
            self.non_negative(field, v)?
        } else {
            self.positive(field, v)?
        };
        if zero && v == 0.0 {
            return Ok(v);
        }
        if v < lo || v > hi {
            let zero = if zero { "0 or " } else { "" };
            return Err(self.invalid(
                field,
                format!("must be {zero}in [{lo:e}, {hi:e}], got {v:e}"),
            ));
        }
        Ok(v)
    }

    /// Finite and `>= 0`.
    fn non_negative(&self, field: &str, v: f64) -> Result<f64, ProfileError> {
        if !v.is_finite() {
            Err(self.invalid(field, format!("must be a finite number, got {v}")))
        } else if v < 0.0 {
            Err(self.invalid(field, format!("must be >= 0, got {v}")))
        } else {
            Ok(v)
        }
    }

    fn non_empty(&self, field: &str, s: &str) -> Result<(), ProfileError> {
        if s.trim().is_empty() {
            Err(self.invalid(field, "must not be empty"))
        } else {
            Ok(())
        }
    }

    fn controller(&self, g: &ControllerGains) -> Result<(), ProfileError> {
        for (field, v) in [
            ("controller.k_x", g.k_x),
            ("controller.k_y", g.k_y),
            ("controller.k_theta", g.k_theta),
            ("controller.k_d", g.k_d),
        ] {
            self.within(field, v, GAIN_RANGE, true)?;
        }
        self.within("controller.lookahead", g.lookahead, LOOKAHEAD_RANGE, false)?;
        Ok(())
    }

    fn guidance(&self, w: &GuidanceWeights) -> Result<(), ProfileError> {
        for (field, v) in [
            ("cost.lambda_v", w.lambda_v),
            ("cost.lambda_a", w.lambda_a),
            ("cost.lambda_omega", w.lambda_omega),
            ("cost.lambda_kappa", w.lambda_kappa),
            ("cost.lambda_lateral", w.lambda_lateral),
            ("cost.lambda_reverse", w.lambda_reverse),
            ("cost.lambda_coupled", w.lambda_coupled),
        ] {
            self.within(field, v, WEIGHT_RANGE, true)?;
        }
        self.within("cost.gamma", w.gamma, GAMMA_RANGE, false)?;
        self.non_negative("cost.delta", w.delta)?;
        if w.delta >= 1.0 {
            return Err(self.invalid("cost.delta", format!("must be < 1, got {}", w.delta)));
        }
        Ok(())
    }
}

/// `path` relative to `dir` unless absolute.
fn resolve_path(dir: &Path, path: &str) -> PathBuf {
    let p = PathBuf::from(path);
    if p.is_absolute() { p } else { dir.join(p) }
}

/// A number formatted for provenance strings (no trailing zeros).
fn num(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".to_string()
    } else {
        s.to_string()
    }
}

// ---------------------------------------------------------------------------------------------
// 1. The profile's own values
// ---------------------------------------------------------------------------------------------

/// The values robot.toml gives directly, checked.
pub(super) struct Checked {
    /// `[limits]` as written (SI units, before any URDF cap): finite and `> 0`,
    /// `min_turning_radius >= 0`.
    pub(super) limits: RawLimits,
    /// `[footprint] radius` (m, finite and `> 0`), overriding the URDF when given.
    pub(super) footprint_override: Option<f64>,
    /// `[controller]`, or the defaults when the section is absent.
    pub(super) controller: ControllerGains,
    /// Whether `controller` was written or defaulted.
    pub(super) controller_source: Origin,
    /// `[cost]`, or the defaults when the section is absent.
    pub(super) guidance: GuidanceWeights,
    /// Whether `guidance` was written or defaulted.
    pub(super) guidance_source: Origin,
}

/// Checks the scalars of robot.toml (`name`, `urdf`, `[limits]`, `[footprint] radius`,
/// `[controller]`, `[cost]`), in that order, before anything else is looked at.
pub(super) fn check_values(raw: &RawProfile, ck: &Checker<'_>) -> Result<Checked, ProfileError> {
    crate::input::check_name(&raw.name).map_err(|why| ck.invalid("name", why))?;
    ck.non_empty("urdf", &raw.urdf)?;
    let l = &raw.limits;
    let limits = RawLimits {
        v_max: ck.within("limits.v_max", l.v_max, SPEED_RANGE, false)?,
        v_reverse_max: ck.within("limits.v_reverse_max", l.v_reverse_max, SPEED_RANGE, false)?,
        a_max: ck.within("limits.a_max", l.a_max, ACCEL_RANGE, false)?,
        omega_max: ck.within("limits.omega_max", l.omega_max, YAW_RATE_RANGE, false)?,
        min_turning_radius: ck.within(
            "limits.min_turning_radius",
            l.min_turning_radius,
            LENGTH_RANGE,
            true,
        )?,
        lateral_speed_max: ck.within(
            "limits.lateral_speed_max",
            l.lateral_speed_max,
            SPEED_RANGE,
            false,
        )?,
    };
    let footprint_override = raw
        .footprint
        .radius
        .map(|r| ck.within("footprint.radius", r, LENGTH_RANGE, false))
        .transpose()?;
    let controller_source = if raw.controller.is_some() {
        Origin::Profile
    } else {
        Origin::Default
    };
    let controller = raw.controller.unwrap_or_default();
    ck.controller(&controller)?;
    let guidance_source = if raw.guidance.is_some() {
        Origin::Profile
    } else {
        Origin::Default
    };
    let guidance = raw.guidance.unwrap_or_default();
    ck.guidance(&guidance)?;
    Ok(Checked {
        limits,
        footprint_override,
        controller,
        controller_source,
        guidance,
        guidance_source,
    })
}
