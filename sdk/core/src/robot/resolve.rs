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

// ---------------------------------------------------------------------------------------------
// 2. Embodiment and plugin constraint terms
// ---------------------------------------------------------------------------------------------

/// The `[embodiment]` section: a built-in kind or a plugin; `steering_joints` are refused with
/// anything but `ackermann`.
pub(super) fn embodiment(
    e: &RawEmbodiment,
    ck: &Checker<'_>,
    dir: &Path,
) -> Result<EmbodimentSpec, ProfileError> {
    let embodiment = if e.kind == "plugin" {
        plugin_embodiment(e, ck, dir)?
    } else {
        builtin_embodiment(e, ck)?
    };
    if !e.steering_joints.is_empty() && builtin_kind(&embodiment) != Some(EmbodimentKind::Ackermann)
    {
        return Err(ck.invalid(
            "embodiment.steering_joints",
            format!("only used with kind = \"ackermann\", not \"{}\"", e.kind),
        ));
    }
    Ok(embodiment)
}

/// `kind = "plugin"`: `library` and `plugin` are required and non-empty, the library is
/// resolved against `dir`, `config` defaults to empty.
fn plugin_embodiment(
    e: &RawEmbodiment,
    ck: &Checker<'_>,
    dir: &Path,
) -> Result<EmbodimentSpec, ProfileError> {
    let library = e
        .library
        .as_deref()
        .ok_or_else(|| ck.invalid("embodiment.library", "required with kind = \"plugin\""))?;
    ck.non_empty("embodiment.library", library)?;
    let plugin = e
        .plugin
        .as_deref()
        .ok_or_else(|| ck.invalid("embodiment.plugin", "required with kind = \"plugin\""))?;
    ck.non_empty("embodiment.plugin", plugin)?;
    if let Some(ms) = e.deadline_ms {
        plugin_deadline(ck, "embodiment.deadline_ms", ms)?;
    }
    Ok(EmbodimentSpec::Plugin(PluginRef {
        library: resolve_path(dir, library),
        plugin: plugin.to_string(),
        config: e.config.clone().unwrap_or_default(),
        weight: 1.0,
        deadline_ms: e.deadline_ms,
        isolation: e.isolation,
        declared_in: ck.file.to_path_buf(),
    }))
}

/// A plugin's `deadline_ms`: in `[0, MAX_PLUGIN_DEADLINE_MS]` (0: none).
fn plugin_deadline(ck: &Checker<'_>, field: &str, ms: f64) -> Result<(), ProfileError> {
    let ms = ck.non_negative(field, ms)?;
    if ms > MAX_PLUGIN_DEADLINE_MS {
        return Err(ck.invalid(
            field,
            format!("at most {MAX_PLUGIN_DEADLINE_MS} ms (0: no deadline), got {ms}"),
        ));
    }
    Ok(())
}

/// A built-in `kind`, which allows none of the plugin fields (`library`, `plugin`, `config`).
fn builtin_embodiment(e: &RawEmbodiment, ck: &Checker<'_>) -> Result<EmbodimentSpec, ProfileError> {
    let kind = EmbodimentKind::from_name(&e.kind).ok_or_else(|| {
        ck.invalid(
            "embodiment.kind",
            format!(
                "unknown embodiment `{}`; expected one of differential_drive, ackermann, \
                 omnidirectional, plugin",
                e.kind
            ),
        )
    })?;
    for (field, present) in [
        ("embodiment.library", e.library.is_some()),
        ("embodiment.plugin", e.plugin.is_some()),
        ("embodiment.config", e.config.is_some()),
        ("embodiment.deadline_ms", e.deadline_ms.is_some()),
        ("embodiment.isolation", e.isolation.is_some()),
    ] {
        if present {
            return Err(ck.invalid(field, "only allowed with kind = \"plugin\""));
        }
    }
    Ok(EmbodimentSpec::Builtin(kind))
}

/// The built-in kind of an embodiment, `None` for a plugin.
pub(super) fn builtin_kind(embodiment: &EmbodimentSpec) -> Option<EmbodimentKind> {
    match embodiment {
        EmbodimentSpec::Builtin(k) => Some(*k),
        EmbodimentSpec::Plugin(_) => None,
    }
}

/// The `[[constraint]]` plugin terms in declaration order: `library` and `plugin` non-empty,
/// `weight >= 0`, `deadline_ms` in `[0, MAX_PLUGIN_DEADLINE_MS]`, the library resolved
/// against `dir`.
pub(super) fn constraints(
    raw: &[RawConstraint],
    ck: &Checker<'_>,
    dir: &Path,
) -> Result<Vec<PluginRef>, ProfileError> {
    let mut constraints = Vec::with_capacity(raw.len());
    for (i, c) in raw.iter().enumerate() {
        ck.non_empty(&format!("constraint[{i}].library"), &c.library)?;
        ck.non_empty(&format!("constraint[{i}].plugin"), &c.plugin)?;
        let weight = ck
            .within(
                &format!("constraint[{i}].weight"),
                c.weight,
                WEIGHT_RANGE,
                true,
            )
            .map_err(|e| match e {
                // Which term it is about: the plugin's name in the message.
                ProfileError::Invalid {
                    file,
                    field,
                    message,
                } => ProfileError::Invalid {
                    file,
                    field,
                    message: format!("{message} (plugin `{}`)", c.plugin),
                },
                other => other,
            })?;
        if let Some(ms) = c.deadline_ms {
            plugin_deadline(ck, &format!("constraint[{i}].deadline_ms"), ms)?;
        }
        constraints.push(PluginRef {
            library: resolve_path(dir, &c.library),
            plugin: c.plugin.clone(),
            config: c.config.clone(),
            weight,
            deadline_ms: c.deadline_ms,
            isolation: c.isolation,
            declared_in: ck.file.to_path_buf(),
        });
    }
    Ok(constraints)
}

// ---------------------------------------------------------------------------------------------
// 3. The URDF
// ---------------------------------------------------------------------------------------------

/// What the profile takes from its URDF (lengths in m, positions in the base-link frame).
pub(super) struct UrdfFacts {
    /// The URDF, resolved against the profile's directory.
    pub(super) path: PathBuf,
    /// `base_link` as written, or the URDF's root link.
    pub(super) base_link: String,
    /// Radius of the disc about the base-link origin covering the footprint (m).
    pub(super) footprint_radius: f64,
    /// Where `footprint_radius` came from.
    pub(super) footprint_source: Provenance,
    /// The footprint's xy shapes (the override disc when `[footprint] radius` is given).
    pub(super) footprint_shapes: Vec<FootprintShape>,
    /// The measured `embodiment.wheel_joints`, in the order listed.
    pub(super) wheel_joints: Vec<WheelJoint>,
    /// The measured `embodiment.steering_joints`, in the order listed.
    pub(super) steering_joints: Vec<SteeringJoint>,
    /// Spread of the wheel centres along the base link's y axis (m), with two or more wheels
    /// that are not all on one line along x.
    pub(super) track_width: Option<f64>,
}

/// Loads the URDF named by `raw.urdf` (or parses `text`, its contents given in memory), picks
/// the base link and measures the footprint, then the wheel joints and the steering joints
/// (each checked to exist, in the order listed).
pub(super) fn urdf(
    raw: &RawProfile,
    ck: &Checker<'_>,
    dir: &Path,
    footprint_override: Option<f64>,
    text: Option<&str>,
) -> Result<UrdfFacts, ProfileError> {
    let path = resolve_path(dir, &raw.urdf);
    let model = match text {
        Some(text) => UrdfModel::parse(text, &path, ck.file)?,
        None => UrdfModel::load(&path, ck.file)?,
    };
    let urdf_name = raw.urdf.as_str();
    let base_link = match &raw.base_link {
        Some(b) => {
            if !model.has_link(b) {
                return Err(ck.invalid("base_link", format!("no link `{b}` in {urdf_name}")));
            }
            b.clone()
        }
        None => model.root_link()?,
    };
    let (footprint_radius, footprint_source, footprint_shapes) =
        footprint(&model, &base_link, footprint_override)?;

    let e = &raw.embodiment;
    distinct_joints(e, ck)?;
    let mut wheel_joints: Vec<WheelJoint> = Vec::with_capacity(e.wheel_joints.len());
    for (i, name) in e.wheel_joints.iter().enumerate() {
        if !model.robot.joints.iter().any(|j| &j.name == name) {
            return Err(ck.invalid(
                format!("embodiment.wheel_joints[{i}]"),
                format!("no joint `{name}` in {urdf_name}"),
            ));
        }
        let wheel = model.wheel_joint(&base_link, name)?;
        // Two wheels in one place: a copied joint, whose track or wheelbase would be 0.
        if let Some(k) = wheel_joints.iter().position(|w| {
            let d = (0..3).map(|a| w.position[a] - wheel.position[a]);
            d.map(|x| x * x).sum::<f64>().sqrt() < SAME_PLACE
        }) {
            return Err(ck.invalid(
                format!("embodiment.wheel_joints[{i}]"),
                format!(
                    "joint `{name}` sits where wheel_joints[{k}] (`{}`) does, at {:?} m in the \
                     base-link frame of {urdf_name}",
                    wheel_joints[k].name, wheel.position
                ),
            ));
        }
        wheel_joints.push(wheel);
    }
    let mut steering_joints = Vec::with_capacity(e.steering_joints.len());
    for (i, name) in e.steering_joints.iter().enumerate() {
        if !model.robot.joints.iter().any(|j| &j.name == name) {
            return Err(ck.invalid(
                format!("embodiment.steering_joints[{i}]"),
                format!("no joint `{name}` in {urdf_name}"),
            ));
        }
        steering_joints.push(model.steering_joint(&base_link, name)?);
    }
    let track_width = if wheel_joints.len() >= 2 {
        let ys = wheel_joints.iter().map(|w| w.position[1]);
        let lo = ys.clone().fold(f64::INFINITY, f64::min);
        let hi = ys.fold(f64::NEG_INFINITY, f64::max);
        (hi - lo > 0.0).then_some(hi - lo)
    } else {
        None
    };
    Ok(UrdfFacts {
        path,
        base_link,
        footprint_radius,
        footprint_source,
        footprint_shapes,
        wheel_joints,
        steering_joints,
        track_width,
    })
}

/// Closer than this (m), two wheel joints are in one place.
const SAME_PLACE: f64 = 1e-6;

/// Each joint listed once in `wheel_joints` and `steering_joints` together: a joint listed
/// twice would count its wheel twice in the track, the wheelbase and the caps.
fn distinct_joints(e: &RawEmbodiment, ck: &Checker<'_>) -> Result<(), ProfileError> {
    let listed: Vec<(String, &String)> = e
        .wheel_joints
        .iter()
        .enumerate()
        .map(|(i, n)| (format!("embodiment.wheel_joints[{i}]"), n))
        .chain(
            e.steering_joints
                .iter()
                .enumerate()
                .map(|(i, n)| (format!("embodiment.steering_joints[{i}]"), n)),
        )
        .collect();
    for (k, (field, name)) in listed.iter().enumerate() {
        if let Some((first, _)) = listed[..k].iter().find(|(_, n)| n == name) {
            return Err(ck.invalid(
                field,
                format!("joint `{name}` is already {first}; list each joint once"),
            ));
        }
    }
    Ok(())
}

/// The footprint radius (m) with its provenance, and the footprint shapes: measured from the
/// base link's collision geometry, or the override disc about the origin when `[footprint]
/// radius` is given (the URDF's value, if it has one, is then only quoted in the provenance).
fn footprint(
    model: &UrdfModel,
    base_link: &str,
    footprint_override: Option<f64>,
) -> Result<(f64, Provenance, Vec<FootprintShape>), ProfileError> {
    let (radius, source) = match footprint_override {
        Some(r) => {
            let urdf_says = match model.footprint_radius(base_link) {
                Ok((u, _)) => format!("URDF base collision would give {} m", num(u)),
                Err(_) => "URDF base collision has no analytic extent".to_string(),
            };
            (
                r,
                Provenance::profile(format!(
                    "robot.toml [footprint] radius (overrides; {urdf_says})"
                )),
            )
        }
        None => {
            let (r, account) = model.footprint_radius(base_link)?;
            (r, Provenance::urdf(format!("URDF {account}")))
        }
    };
    let shapes = match footprint_override {
        Some(radius) => vec![FootprintShape::Disc {
            center: [0.0, 0.0],
            radius,
        }],
        None => model.footprint_shapes(base_link)?,
    };
    Ok((radius, source, shapes))
}

// ---------------------------------------------------------------------------------------------
// 4. Effective limits and their provenance
// ---------------------------------------------------------------------------------------------

/// The limits the robot actually has, after the URDF caps.
pub(super) struct Effective {
    /// The effective limits (SI units).
    pub(super) limits: Limits,
    /// Where each of `limits` came from.
    pub(super) sources: LimitProvenance,
    /// Effective minimum turning radius (m, 0 = turns in place); `kappa_max = 1 / r`.
    pub(super) min_turning_radius: f64,
    /// Distance along x between the steering and the wheel axles (m), for an Ackermann robot
    /// with steering joints.
    pub(super) wheelbase: Option<f64>,
}

/// The effective limits: `v_max` and `v_reverse_max` capped by the slowest wheel's rim speed,
/// `omega_max` by the wheels of a differential drive, the turning radius raised to what the
/// steering joints of an Ackermann robot allow; `a_max` and `lateral_speed_max` as given.
pub(super) fn limits(
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
