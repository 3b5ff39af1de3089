//! Robot profiles: a `robot.toml` naming its URDF plus everything a URDF cannot say (embodiment
//! kind, limits, tracking gains, guidance weights, plugin constraint terms).
//!
//! ```toml
//! name = "diablo"                  # folder name by convention
//! description = "..."
//! urdf = "diablo.urdf"             # relative to this robot.toml
//! base_link = "base_link"          # optional; default: the URDF's root link
//!
//! [embodiment]
//! kind = "differential_drive"      # differential_drive | ackermann | omnidirectional | plugin
//! wheel_joints = ["left_wheel_joint", "right_wheel_joint"]
//! steering_joints = []             # ackermann only
//! # kind = "plugin" only: library = "...", plugin = "...", config = """..."""
//!
//! [footprint]                      # optional; required when the base collision is a mesh
//! radius = 0.35
//!
//! [limits]                         # SI units, finite, > 0 (min_turning_radius >= 0)
//! v_max = 1.2
//! v_reverse_max = 0.4
//! a_max = 1.0
//! omega_max = 1.5
//! min_turning_radius = 0.0         # 0: turns in place (kappa_max = None), else kappa_max = 1/r
//! lateral_speed_max = 0.05
//!
//! [controller]                     # ControllerGains, all optional (documented defaults)
//! [guidance]                       # GuidanceWeights, all optional (documented defaults)
//!
//! [[constraint]]                   # zero or more plugin constraint terms
//! library = "..."                  # relative to this file; OS extension and `lib` optional
//! plugin = "clearance"
//! weight = 1.0                     # finite, >= 0; default 1
//! config = """..."""               # default ""
//! deadline_ms = 1000               # per evaluate call; default: the plugin host's (1000 ms);
//!                                  # 0: none; at most 3 600 000 (see human2nav_plugin::deadline)
//! isolation = "in_process"         # in_process (default) | process: run the term in its own
//!                                  # helper process (see human2nav_plugin::process)
//! ```
//!
//! Unknown fields are rejected everywhere. Every error names the file and the field (or the
//! URDF element), and TOML syntax errors their line and column.
//!
//! What comes from the URDF:
//! * **Footprint radius**: the smallest disc about the base link's origin covering the
//!   xy-projection of every `<collision>` of the base link. A box counts by its eight corners
//!   after its collision origin (so an axis-aligned box gives its half diagonal plus nothing, an
//!   offset box its farthest corner); an upright cylinder or capsule gives `radius + |xy offset|`
//!   (tilted ones the conservative `√(r² + (L/2)²)`, resp. `r + L/2`, plus the offset); a sphere
//!   `radius + |xy offset|`. A mesh is rejected with an error naming the link, unless
//!   `[footprint] radius` is given: that value then overrides the URDF for any geometry, and the
//!   profile records which one was used. Planners keep clear with this disc.
//! * **Footprint shapes** ([`footprint`]): the same geometry one shape per element, what the
//!   simulator checks collisions against (an upright box is a rectangle, an upright cylinder,
//!   capsule or sphere a disc, a tilted element the disc about its centre covering it); with
//!   `[footprint] radius`, that disc about the origin.
//! * **Wheel joints** (`embodiment.wheel_joints`, continuous or revolute): the wheel radius `r` is
//!   the child link's cylinder or sphere (collision first, then visual). Where a joint has a
//!   positive `<limit velocity>` `ω_w`, the wheel's rim speed `ω_w·r` caps `v_max` and
//!   `v_reverse_max`; for a differential drive with two or more wheels it also caps
//!   `omega_max ≤ 2·min(ω_w·r) / track`, the track being the spread of the wheel centres along
//!   the base link's y axis. Caps only ever lower a limit.
//! * **Steering joints** (Ackermann only, revolute): the equivalent bicycle steering angle
//!   `δ_max` is the smallest `min(|lower|, |upper|)` over the joints; the wheelbase `L` is the
//!   distance along x between the mean steering-joint origin and the mean wheel-joint origin (list
//!   the rear wheels as `wheel_joints`). Then `r_min = L / tan δ_max`, and the effective minimum
//!   turning radius is the larger of this and `limits.min_turning_radius`.
//!
//! The base link's origin is the point the embodiment's kinematic model moves (for Ackermann the
//! rear-axle centre, where `v_y = 0`).

pub mod footprint;
mod urdf;

pub use crate::embodiment::EmbodimentKind;
pub use urdf::{MAX_URDF_DEPTH, SteeringJoint, WheelJoint};

use crate::embodiment::{BuiltinEmbodiment, Embodiment};
use crate::input::MAX_PROFILE_BYTES;
use crate::limits::{ControllerGains, GuidanceWeights, Limits};
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};
use urdf::UrdfModel;

/// Why a robot profile could not be loaded. Every variant names the file and the field.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// The profile file itself could not be read.
    #[error("{}: (file): cannot read: {source}", file.display())]
    Read {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// TOML syntax error, unknown field, missing field or wrong type.
    #[error("{}: {field}: line {line}, column {column}: {message}", file.display())]
    Parse {
        file: PathBuf,
        field: String,
        line: usize,
        column: usize,
        message: String,
    },
    /// A value that parsed but is not acceptable (negative limit, unknown embodiment, ...).
    #[error("{}: {field}: {message}", file.display())]
    Invalid {
        file: PathBuf,
        field: String,
        message: String,
    },
    /// The URDF named by the profile's `urdf` field is missing or unparsable.
    #[error("{}: urdf: cannot load `{}`: {message}", file.display(), urdf.display())]
    UrdfLoad {
        file: PathBuf,
        urdf: PathBuf,
        message: String,
    },
    /// The URDF parsed but lacks something the profile needs.
    #[error("{}: {element}: {message}", urdf.display())]
    UrdfContent {
        urdf: PathBuf,
        element: String,
        message: String,
    },
}

impl ProfileError {
    /// The file the error is about (the profile, or the URDF for content errors).
    pub fn file(&self) -> &Path {
        match self {
            ProfileError::Read { file, .. }
            | ProfileError::Parse { file, .. }
            | ProfileError::Invalid { file, .. }
            | ProfileError::UrdfLoad { file, .. } => file,
            ProfileError::UrdfContent { urdf, .. } => urdf,
        }
    }

    /// The field (`limits.v_max`, `embodiment.kind`, `urdf`) or URDF element the error is about.
    pub fn field(&self) -> &str {
        match self {
            ProfileError::Read { .. } => "(file)",
            ProfileError::Parse { field, .. } | ProfileError::Invalid { field, .. } => field,
            ProfileError::UrdfLoad { .. } => "urdf",
            ProfileError::UrdfContent { element, .. } => element,
        }
    }
}

/// Longest deadline a `[[constraint]]` may set (`deadline_ms`, one hour).
pub const MAX_PLUGIN_DEADLINE_MS: f64 = 3_600_000.0;

/// Where a plugin instance runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PluginIsolation {
    /// In the host process (the default): fastest, but a plugin that aborts or segfaults takes
    /// the host down with it.
    #[default]
    InProcess,
    /// In a helper process of its own, restarted when it dies or hangs (planners and constraint
    /// terms; see `human2nav_plugin::process`).
    Process,
}

/// A reference to something in a plugin library.
#[derive(Clone, Debug, PartialEq)]
pub struct PluginRef {
    /// The library, resolved against the declaring file's directory when relative (as written
    /// otherwise). The OS extension and `lib` prefix may still be missing; the loader adds them.
    pub library: PathBuf,
    /// Factory name inside the library.
    pub plugin: String,
    /// TOML handed to the plugin verbatim (empty when not given).
    pub config: String,
    /// Weight of a constraint term (1 for embodiments).
    pub weight: f64,
    /// Deadline of each call of a constraint term, in milliseconds, as written (`None`: the
    /// plugin host's default; `0`: none). Embodiments have none (always `None`).
    pub deadline_ms: Option<f64>,
    /// Where the instance runs (constraint terms and planners; embodiments always run in the
    /// host process).
    pub isolation: PluginIsolation,
    /// The robot.toml that declared this reference.
    pub declared_in: PathBuf,
}

/// How the robot moves: a built-in model or one from a plugin.
#[derive(Clone, Debug, PartialEq)]
pub enum EmbodimentSpec {
    Builtin(EmbodimentKind),
    Plugin(PluginRef),
}

impl EmbodimentSpec {
    /// `differential_drive`, `ackermann`, `omnidirectional` or `plugin`.
    pub fn kind_name(&self) -> &'static str {
        match self {
            EmbodimentSpec::Builtin(k) => k.as_str(),
            EmbodimentSpec::Plugin(_) => "plugin",
        }
    }
}

/// Where a value came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// Written in robot.toml.
    Profile,
    /// Measured in, or capped by, the URDF.
    Urdf,
    /// A documented default (the field was not given).
    Default,
}

/// Where a value came from, with a human-readable account (`robot.toml [limits] v_max`,
/// `URDF joint left_wheel_joint velocity 22 rad/s × wheel radius 0.09 m`, ...).
#[derive(Clone, Debug, PartialEq)]
pub struct Provenance {
    pub origin: Origin,
    pub detail: String,
}

impl Provenance {
    fn profile(detail: impl Into<String>) -> Self {
        Self {
            origin: Origin::Profile,
            detail: detail.into(),
        }
    }
    fn urdf(detail: impl Into<String>) -> Self {
        Self {
            origin: Origin::Urdf,
            detail: detail.into(),
        }
    }
}

impl fmt::Display for Provenance {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.detail)
    }
}

/// Provenance of each effective limit.
#[derive(Clone, Debug, PartialEq)]
pub struct LimitProvenance {
    pub v_max: Provenance,
    pub v_reverse_max: Provenance,
    pub a_max: Provenance,
    pub omega_max: Provenance,
    pub kappa_max: Provenance,
    pub lateral_speed_max: Provenance,
}

/// One row of [`RobotProfile::limit_table`].
#[derive(Clone, Debug, PartialEq)]
pub struct LimitEntry<'a> {
    /// Field name (`v_max`, ..., `kappa_max`).
    pub name: &'static str,
    /// The effective value; `None` for `kappa_max` of a robot that turns in place.
    pub value: Option<f64>,
    pub unit: &'static str,
    pub source: &'a Provenance,
}

/// A loaded and validated robot profile.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotProfile {
    pub name: String,
    pub description: String,
    /// The robot.toml this was loaded from (as given to [`RobotProfile::load`]).
    pub source: PathBuf,
    /// The URDF, resolved against the profile's directory.
    pub urdf: PathBuf,
    /// The URDF link whose origin the robot's pose refers to.
    pub base_link: String,
    pub embodiment: EmbodimentSpec,
    /// Wheel joints used for limit caps (and the wheelbase of an Ackermann robot).
    pub wheel_joints: Vec<WheelJoint>,
    /// Steering joints of an Ackermann robot.
    pub steering_joints: Vec<SteeringJoint>,
    /// Spread of the wheel centres along y (m), when there are two or more wheel joints.
    pub track_width: Option<f64>,
    /// Distance between steering and wheel axles (m), for Ackermann robots with steering joints.
    pub wheelbase: Option<f64>,
    /// Radius of the disc about the base-link origin that covers the footprint (m): the body
    /// planners avoid pedestrians with.
    pub footprint_radius: f64,
    pub footprint_source: Provenance,
    /// The footprint the simulator checks collisions with: the URDF base collision's xy
    /// projection ([`footprint`]), or the disc of `footprint_radius` when `[footprint] radius`
    /// overrides the URDF.
    pub footprint_shapes: Vec<footprint::FootprintShape>,
    /// Effective limits after the URDF caps.
    pub limits: Limits,
    pub limit_sources: LimitProvenance,
    /// Effective minimum turning radius (m, 0 = turns in place); `kappa_max = 1 / r`.
    pub min_turning_radius: f64,
    pub controller: ControllerGains,
    pub controller_source: Origin,
    pub guidance: GuidanceWeights,
    pub guidance_source: Origin,
    /// Plugin constraint terms, in the order declared.
    pub constraints: Vec<PluginRef>,
}

// ---------------------------------------------------------------------------------------------
// The file as written
// ---------------------------------------------------------------------------------------------

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawProfile {
    name: String,
    #[serde(default)]
    description: String,
    urdf: String,
    #[serde(default)]
    base_link: Option<String>,
    embodiment: RawEmbodiment,
    #[serde(default)]
    footprint: RawFootprint,
    limits: RawLimits,
    #[serde(default)]
    controller: Option<ControllerGains>,
    #[serde(default)]
    guidance: Option<GuidanceWeights>,
    #[serde(default, rename = "constraint")]
    constraints: Vec<RawConstraint>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEmbodiment {
    kind: String,
    #[serde(default)]
    wheel_joints: Vec<String>,
    #[serde(default)]
    steering_joints: Vec<String>,
    #[serde(default)]
    library: Option<String>,
    #[serde(default)]
    plugin: Option<String>,
    #[serde(default)]
    config: Option<String>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct RawFootprint {
    radius: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLimits {
    v_max: f64,
    v_reverse_max: f64,
    a_max: f64,
    omega_max: f64,
    #[serde(default)]
    min_turning_radius: f64,
    lateral_speed_max: f64,
}

fn default_weight() -> f64 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConstraint {
    library: String,
    plugin: String,
    #[serde(default = "default_weight")]
    weight: f64,
    #[serde(default)]
    config: String,
    #[serde(default)]
    deadline_ms: Option<f64>,
    #[serde(default)]
    isolation: PluginIsolation,
}

// ---------------------------------------------------------------------------------------------
// Loading
// ---------------------------------------------------------------------------------------------

/// Builds errors naming one profile file.
struct Checker<'a> {
    file: &'a Path,
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
        self.non_negative("controller.k_x", g.k_x)?;
        self.non_negative("controller.k_y", g.k_y)?;
        self.non_negative("controller.k_theta", g.k_theta)?;
        self.non_negative("controller.k_d", g.k_d)?;
        self.positive("controller.lookahead", g.lookahead)?;
        Ok(())
    }

    fn guidance(&self, w: &GuidanceWeights) -> Result<(), ProfileError> {
        self.non_negative("guidance.lambda_v", w.lambda_v)?;
        self.non_negative("guidance.lambda_a", w.lambda_a)?;
        self.non_negative("guidance.lambda_omega", w.lambda_omega)?;
        self.non_negative("guidance.lambda_kappa", w.lambda_kappa)?;
        self.non_negative("guidance.lambda_lateral", w.lambda_lateral)?;
        self.non_negative("guidance.lambda_reverse", w.lambda_reverse)?;
        self.positive("guidance.gamma", w.gamma)?;
        self.non_negative("guidance.delta", w.delta)?;
        if w.delta >= 1.0 {
            return Err(self.invalid("guidance.delta", format!("must be < 1, got {}", w.delta)));
        }
        Ok(())
    }
}

/// `path` relative to `dir` unless absolute.
fn resolve(dir: &Path, path: &str) -> PathBuf {
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

impl RobotProfile {
    /// Reads, validates and resolves a `robot.toml` and its URDF.
    pub fn load(path: &Path) -> Result<RobotProfile, ProfileError> {
        let text = crate::input::read_user_file(path, "robot profile", MAX_PROFILE_BYTES).map_err(
            |source| ProfileError::Read {
                file: path.to_path_buf(),
                source,
            },
        )?;
        let raw: RawProfile = toml::from_str(&text).map_err(|e| parse_error(path, &text, &e))?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::from_raw(raw, path, &dir)
    }

    fn from_raw(raw: RawProfile, path: &Path, dir: &Path) -> Result<RobotProfile, ProfileError> {
        let ck = Checker { file: path };

        // --- Scalars first, so a bad number is reported even when the URDF is broken too.
        ck.non_empty("name", &raw.name)?;
        ck.non_empty("urdf", &raw.urdf)?;
        let l = &raw.limits;
        let v_max = ck.positive("limits.v_max", l.v_max)?;
        let v_reverse_max = ck.positive("limits.v_reverse_max", l.v_reverse_max)?;
        let a_max = ck.positive("limits.a_max", l.a_max)?;
        let omega_max = ck.positive("limits.omega_max", l.omega_max)?;
        let min_turning_radius =
            ck.non_negative("limits.min_turning_radius", l.min_turning_radius)?;
        let lateral_speed_max = ck.positive("limits.lateral_speed_max", l.lateral_speed_max)?;
        let footprint_override = raw
            .footprint
            .radius
            .map(|r| ck.positive("footprint.radius", r))
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

        // --- Embodiment.
        let e = &raw.embodiment;
        let embodiment = if e.kind == "plugin" {
            let library = e.library.as_deref().ok_or_else(|| {
                ck.invalid("embodiment.library", "required with kind = \"plugin\"")
            })?;
            ck.non_empty("embodiment.library", library)?;
            let plugin = e.plugin.as_deref().ok_or_else(|| {
                ck.invalid("embodiment.plugin", "required with kind = \"plugin\"")
            })?;
            ck.non_empty("embodiment.plugin", plugin)?;
            EmbodimentSpec::Plugin(PluginRef {
                library: resolve(dir, library),
                plugin: plugin.to_string(),
                config: e.config.clone().unwrap_or_default(),
                weight: 1.0,
                deadline_ms: None,
                isolation: PluginIsolation::InProcess,
                declared_in: path.to_path_buf(),
            })
        } else {
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
            ] {
                if present {
                    return Err(ck.invalid(field, "only allowed with kind = \"plugin\""));
                }
            }
            EmbodimentSpec::Builtin(kind)
        };
        let kind = match &embodiment {
            EmbodimentSpec::Builtin(k) => Some(*k),
            EmbodimentSpec::Plugin(_) => None,
        };
        if !e.steering_joints.is_empty() && kind != Some(EmbodimentKind::Ackermann) {
            return Err(ck.invalid(
                "embodiment.steering_joints",
                format!("only used with kind = \"ackermann\", not \"{}\"", e.kind),
            ));
        }

        // --- Plugin constraint terms.
        let mut constraints = Vec::with_capacity(raw.constraints.len());
        for (i, c) in raw.constraints.iter().enumerate() {
            ck.non_empty(&format!("constraint[{i}].library"), &c.library)?;
            ck.non_empty(&format!("constraint[{i}].plugin"), &c.plugin)?;
            let weight = ck.non_negative(&format!("constraint[{i}].weight"), c.weight)?;
            if let Some(ms) = c.deadline_ms {
                let field = format!("constraint[{i}].deadline_ms");
                let ms = ck.non_negative(&field, ms)?;
                if ms > MAX_PLUGIN_DEADLINE_MS {
                    return Err(ck.invalid(
                        &field,
                        format!("at most {MAX_PLUGIN_DEADLINE_MS} ms (0: no deadline), got {ms}"),
                    ));
                }
            }
            constraints.push(PluginRef {
                library: resolve(dir, &c.library),
                plugin: c.plugin.clone(),
                config: c.config.clone(),
                weight,
                deadline_ms: c.deadline_ms,
                isolation: c.isolation,
                declared_in: path.to_path_buf(),
            });
        }

        // --- URDF.
        let urdf_path = resolve(dir, &raw.urdf);
        let model = UrdfModel::load(&urdf_path, path)?;
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

        let (footprint_radius, footprint_source) = match footprint_override {
            Some(r) => {
                let urdf_says = match model.footprint_radius(&base_link) {
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
                let (r, account) = model.footprint_radius(&base_link)?;
                (r, Provenance::urdf(format!("URDF {account}")))
            }
        };
        let footprint_shapes = match footprint_override {
            Some(radius) => vec![footprint::FootprintShape::Disc {
                center: [0.0, 0.0],
                radius,
            }],
            None => model.footprint_shapes(&base_link)?,
        };

        let mut wheel_joints = Vec::with_capacity(e.wheel_joints.len());
        for (i, name) in e.wheel_joints.iter().enumerate() {
            if !model.robot.joints.iter().any(|j| &j.name == name) {
                return Err(ck.invalid(
                    format!("embodiment.wheel_joints[{i}]"),
                    format!("no joint `{name}` in {urdf_name}"),
                ));
            }
            wheel_joints.push(model.wheel_joint(&base_link, name)?);
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

        // --- Effective limits.
        let wheel_cap = wheel_joints
            .iter()
            .filter_map(|w| w.velocity_limit.map(|v| (v * w.radius, w)))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let capped = |field: &str, given: f64| -> (f64, Provenance) {
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
        };
        let (v_max, v_max_src) = capped("v_max", v_max);
        let (v_reverse_max, v_reverse_src) = capped("v_reverse_max", v_reverse_max);

        let (omega_max, omega_src) = match (kind, wheel_cap, track_width) {
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
        };

        let mut wheelbase = None;
        let (r_min, kappa_src) = if kind == Some(EmbodimentKind::Ackermann) {
            let from_urdf = if steering_joints.is_empty() {
                None
            } else {
                if wheel_joints.is_empty() {
                    return Err(ck.invalid(
                        "embodiment.wheel_joints",
                        "an ackermann robot with steering_joints needs its rear wheel joints too \
                         (the wheelbase is measured between the two)",
                    ));
                }
                let mean_x =
                    |xs: &mut dyn Iterator<Item = f64>, n: usize| xs.sum::<f64>() / n as f64;
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
                wheelbase = Some(l);
                let (delta, joint) = steering_joints
                    .iter()
                    .map(|s| (s.max_angle, s.name.as_str()))
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .unwrap_or((0.0, ""));
                Some((l / delta.tan(), l, delta, joint))
            };
            match from_urdf {
                Some((r, l, delta, joint)) if r > min_turning_radius => (
                    r,
                    Provenance::urdf(format!(
                        "URDF joint `{joint}` steering limit {} rad, wheelbase {} m: r_min = L / tan δ = {} m (robot.toml said {})",
                        num(delta),
                        num(l),
                        num(r),
                        num(min_turning_radius)
                    )),
                ),
                Some((r, ..)) => (
                    min_turning_radius,
                    Provenance::profile(format!(
                        "1 / robot.toml [limits] min_turning_radius (URDF steering allows r_min {} m)",
                        num(r)
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
            }
        } else if min_turning_radius > 0.0 {
            (
                min_turning_radius,
                Provenance::profile("1 / robot.toml [limits] min_turning_radius"),
            )
        } else {
            (
                0.0,
                Provenance::profile(
                    "none: robot.toml [limits] min_turning_radius = 0 (turns in place)",
                ),
            )
        };

        let limits = Limits {
            v_max,
            v_reverse_max,
            a_max,
            omega_max,
            kappa_max: (r_min > 0.0).then(|| 1.0 / r_min),
            lateral_speed_max,
        };
        let limit_sources = LimitProvenance {
            v_max: v_max_src,
            v_reverse_max: v_reverse_src,
            a_max: Provenance::profile("robot.toml [limits] a_max"),
            omega_max: omega_src,
            kappa_max: kappa_src,
            lateral_speed_max: Provenance::profile("robot.toml [limits] lateral_speed_max"),
        };

        Ok(RobotProfile {
            name: raw.name,
            description: raw.description,
            source: path.to_path_buf(),
            urdf: urdf_path,
            base_link,
            embodiment,
            wheel_joints,
            steering_joints,
            track_width,
            wheelbase,
            footprint_radius,
            footprint_source,
            footprint_shapes,
            limits,
            limit_sources,
            min_turning_radius: r_min,
            controller,
            controller_source,
            guidance,
            guidance_source,
            constraints,
        })
    }

    /// The built-in embodiment this profile describes; `None` for `kind = "plugin"` (the plugin
    /// loader builds those).
    pub fn builtin_embodiment(&self) -> Option<Box<dyn Embodiment>> {
        match &self.embodiment {
            EmbodimentSpec::Builtin(kind) => Some(Box::new(BuiltinEmbodiment::new(
                *kind,
                self.limits,
                self.controller,
            ))),
            EmbodimentSpec::Plugin(_) => None,
        }
    }

    /// Every effective limit with its unit and provenance, in a fixed order.
    pub fn limit_table(&self) -> Vec<LimitEntry<'_>> {
        let l = &self.limits;
        let s = &self.limit_sources;
        vec![
            LimitEntry {
                name: "v_max",
                value: Some(l.v_max),
                unit: "m/s",
                source: &s.v_max,
            },
            LimitEntry {
                name: "v_reverse_max",
                value: Some(l.v_reverse_max),
                unit: "m/s",
                source: &s.v_reverse_max,
            },
            LimitEntry {
                name: "a_max",
                value: Some(l.a_max),
                unit: "m/s²",
                source: &s.a_max,
            },
            LimitEntry {
                name: "omega_max",
                value: Some(l.omega_max),
                unit: "rad/s",
                source: &s.omega_max,
            },
            LimitEntry {
                name: "kappa_max",
                value: l.kappa_max,
                unit: "1/m",
                source: &s.kappa_max,
            },
            LimitEntry {
                name: "lateral_speed_max",
                value: Some(l.lateral_speed_max),
                unit: "m/s",
                source: &s.lateral_speed_max,
            },
        ]
    }
}

// ---------------------------------------------------------------------------------------------
// TOML error location
// ---------------------------------------------------------------------------------------------

fn parse_error(file: &Path, text: &str, err: &toml::de::Error) -> ProfileError {
    let message = err
        .message()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ");
    let offset = err.span().map_or(0, |s| s.start).min(text.len());
    let (line, column) = line_col(text, offset);
    let field = field_at(text, offset, &message);
    ProfileError::Parse {
        file: file.to_path_buf(),
        field,
        line,
        column,
        message,
    }
}

/// 1-based line and column (in characters) of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, text[line_start..offset].chars().count() + 1)
}

/// Best-effort dotted name (`limits.v_max`, `constraint[1].weight`) of what sits at `offset`:
/// the nearest table header above plus the key on that line, or the key a "missing field"
/// message names. A syntax error reported at the very start of a line (an unterminated array,
/// say) belongs to the key-value line before it.
fn field_at(text: &str, offset: usize, message: &str) -> String {
    let key_of = |line: &str| -> Option<String> {
        let k = line.split('=').next()?.trim().trim_matches('"');
        (!k.is_empty() && !k.contains(char::is_whitespace) && line.contains('='))
            .then(|| k.to_string())
    };
    let data_error = [
        "unknown field",
        "duplicate key",
        "missing field",
        "invalid type",
    ]
    .iter()
    .any(|m| message.starts_with(m));
    let mut section: Option<String> = None;
    let mut arrays: Vec<(String, usize)> = Vec::new();
    let mut in_multiline = false;
    let mut previous: Option<(Option<String>, String)> = None;
    let mut found: (Option<String>, Option<String>) = (None, None);
    let mut pos = 0;
    for raw_line in text.split_inclusive('\n') {
        let line_start = pos;
        pos += raw_line.len();
        let line = raw_line.trim();
        let was_multiline = in_multiline;
        if (line.matches("\"\"\"").count() + line.matches("'''").count()) % 2 == 1 {
            in_multiline = !in_multiline;
        }
        let plain = !was_multiline && !line.starts_with('#');
        if plain {
            if let Some(inner) = line.strip_prefix("[[").and_then(|l| l.split("]]").next()) {
                let name = inner.trim().to_string();
                let n = match arrays.iter_mut().find(|(a, _)| *a == name) {
                    Some((_, n)) => {
                        *n += 1;
                        *n
                    }
                    None => {
                        arrays.push((name.clone(), 0));
                        0
                    }
                };
                section = Some(format!("{name}[{n}]"));
            } else if let Some(inner) = line.strip_prefix('[').and_then(|l| l.split(']').next()) {
                section = Some(inner.trim().to_string());
            }
        }
        if offset < pos || pos == text.len() {
            let indent = raw_line.len() - raw_line.trim_start().len();
            let at_line_start = offset <= line_start + indent;
            found = match (&previous, at_line_start && !data_error) {
                (Some((sec, key)), true) => (sec.clone(), Some(key.clone())),
                _ => {
                    let key = if plain && !line.starts_with('[') {
                        key_of(line)
                    } else {
                        None
                    };
                    (section, key)
                }
            };
            break;
        }
        if plain && !line.starts_with('[') {
            if let Some(k) = key_of(line) {
                previous = Some((section.clone(), k));
            }
        }
    }
    let (section, mut key) = found;
    if let Some(missing) = message
        .strip_prefix("missing field `")
        .and_then(|m| m.split('`').next())
    {
        key = Some(missing.to_string());
    }
    match (section, key) {
        (Some(s), Some(k)) => format!("{s}.{k}"),
        (Some(s), None) => s,
        (None, Some(k)) => k,
        (None, None) => "(document)".to_string(),
    }
}
