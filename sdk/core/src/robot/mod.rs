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
//! # kind = "plugin" only: library = "...", plugin = "...", config = """...""", and
//! # deadline_ms and isolation as for a [[constraint]] (per saturate, step or track call)
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
//! [cost]                           # GuidanceWeights: Φ's built-in terms, all optional
//!                                  # (documented defaults; read as `[guidance]` too)
//!
//! [[constraint]]                   # zero or more plugin constraint terms
//! library = "..."                  # relative to this file; OS extension and `lib` optional
//! plugin = "clearance"
//! weight = 1.0                     # finite, >= 0; default 1
//! config = """..."""               # default ""
//! deadline_ms = 1000               # per evaluate call; default: the plugin host's (1000 ms);
//!                                  # 0: none; at most 3 600 000 (see human2nav_plugin::deadline)
//! isolation = "process"            # process (default): the term runs in a helper process of
//!                                  # its own (human2nav_plugin::process); "in_process": in the
//!                                  # host, faster, but a crash takes the host down
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
mod resolve;
mod urdf;

pub use crate::embodiment::EmbodimentKind;
pub use resolve::{
    ACCEL_RANGE, GAIN_RANGE, GAMMA_RANGE, LENGTH_RANGE, LOOKAHEAD_RANGE, SPEED_RANGE, WEIGHT_RANGE,
    YAW_RATE_RANGE,
};
pub use urdf::{MAX_URDF_DEPTH, SteeringJoint, WheelJoint};

use crate::embodiment::{BuiltinEmbodiment, Embodiment};
use crate::input::MAX_PROFILE_BYTES;
use crate::limits::{ControllerGains, GuidanceWeights, Limits};
use resolve::Checker;
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// Why a robot profile could not be loaded. Every variant names the file and the field.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// The profile file itself could not be read.
    #[error("{}: (file): cannot read: {source}", file.display())]
    Read {
        /// The profile.
        file: PathBuf,
        /// Why it could not be read (missing, not a regular file, over the size cap, not UTF-8).
        #[source]
        source: std::io::Error,
    },
    /// TOML syntax error, unknown field, missing field or wrong type.
    #[error("{}: {field}: line {line}, column {column}: {message}", file.display())]
    Parse {
        /// The profile.
        file: PathBuf,
        /// Best-effort dotted name of the field at the error (`limits.v_max`,
        /// `constraint[1].weight`); `(document)` when there is none.
        field: String,
        /// 1-based line of the error.
        line: usize,
        /// 1-based column of the error, in characters.
        column: usize,
        /// The TOML parser's message, on one line.
        message: String,
    },
    /// A value that parsed but is not acceptable (negative limit, unknown embodiment, ...).
    #[error("{}: {field}: {message}", file.display())]
    Invalid {
        /// The profile.
        file: PathBuf,
        /// Dotted name of the offending field (`limits.v_max`, `embodiment.wheel_joints[1]`).
        field: String,
        /// What is wrong with its value.
        message: String,
    },
    /// The URDF named by the profile's `urdf` field is missing or unparsable.
    #[error("{}: urdf: cannot load `{}`: {message}", file.display(), urdf.display())]
    UrdfLoad {
        /// The profile that names the URDF.
        file: PathBuf,
        /// The URDF, resolved against the profile's directory.
        urdf: PathBuf,
        /// Why it could not be read or parsed, on one line.
        message: String,
    },
    /// The URDF parsed but lacks something the profile needs.
    #[error("{}: {element}: {message}", urdf.display())]
    UrdfContent {
        /// The URDF.
        urdf: PathBuf,
        /// The element at fault (``link `base_link` ``, ``joint `left_wheel_joint` ``, `robot`).
        element: String,
        /// What is missing or wrong.
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

/// Longest deadline a plugin declaration may set (`deadline_ms`, one hour).
pub const MAX_PLUGIN_DEADLINE_MS: f64 = 3_600_000.0;

/// Where a plugin instance runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PluginIsolation {
    /// In the host process, opted into with `isolation = "in_process"`: no per-call process
    /// round trip, but a plugin that aborts or segfaults takes the host down with it (a hang
    /// still only costs the call's deadline).
    InProcess,
    /// In a helper process of its own (the default): a plugin that aborts, segfaults or hangs
    /// costs a call (planners and constraint terms, whose helper is restarted) or the
    /// embodiment (halted), never the host; see `human2nav_plugin::process`.
    #[default]
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
    /// Deadline of each call, in milliseconds, as written (`None`: the plugin host's default;
    /// `0`: none).
    pub deadline_ms: Option<f64>,
    /// Where the instance runs, as written (`None`: not written, which is
    /// [`PluginIsolation::default`], a helper process, unless the program embedding the SDK
    /// chose otherwise with [`RobotProfile::default_plugin_isolation`]).
    pub isolation: Option<PluginIsolation>,
    /// The robot.toml that declared this reference.
    pub declared_in: PathBuf,
}

/// How the robot moves: a built-in model or one from a plugin.
#[derive(Clone, Debug, PartialEq)]
pub enum EmbodimentSpec {
    /// One of the built-in kinematic models ([`RobotProfile::builtin_embodiment`] builds it).
    Builtin(EmbodimentKind),
    /// A model from a plugin library (`kind = "plugin"`); its weight is 1.
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
    /// Which kind of source set the value.
    pub origin: Origin,
    /// The account itself, as shown to users (also what `Display` prints).
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
    /// Of `v_max`: robot.toml, or the slowest wheel joint's rim speed when lower.
    pub v_max: Provenance,
    /// Of `v_reverse_max`: robot.toml, or the slowest wheel joint's rim speed when lower.
    pub v_reverse_max: Provenance,
    /// Of `a_max`: always robot.toml.
    pub a_max: Provenance,
    /// Of `omega_max`: robot.toml, or a differential drive's wheel cap `2·v_wheel / track`.
    pub omega_max: Provenance,
    /// Of `kappa_max`: `1 / min_turning_radius` from robot.toml or from an Ackermann robot's
    /// steering joints, or why there is none (turns in place).
    pub kappa_max: Provenance,
    /// Of `lateral_speed_max`: always robot.toml.
    pub lateral_speed_max: Provenance,
}

/// One row of [`RobotProfile::limit_table`].
#[derive(Clone, Debug, PartialEq)]
pub struct LimitEntry<'a> {
    /// Field name (`v_max`, ..., `kappa_max`).
    pub name: &'static str,
    /// The effective value; `None` for `kappa_max` of a robot that turns in place.
    pub value: Option<f64>,
    /// SI unit of `value` (`m/s`, `m/s²`, `rad/s`, `1/m`).
    pub unit: &'static str,
    /// Where the value came from.
    pub source: &'a Provenance,
}

/// A loaded and validated robot profile.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotProfile {
    /// The robot's name (`name`; by convention its folder name), non-empty.
    pub name: String,
    /// Free text from `description` (empty when not given).
    pub description: String,
    /// The robot.toml this was loaded from (as given to [`RobotProfile::load`]).
    pub source: PathBuf,
    /// The URDF, resolved against the profile's directory.
    pub urdf: PathBuf,
    /// The URDF link whose origin the robot's pose refers to.
    pub base_link: String,
    /// How the robot moves: a built-in kinematic model or a plugin.
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
    /// Where `footprint_radius` came from: the URDF geometry that set it, or the
    /// `[footprint] radius` override.
    pub footprint_source: Provenance,
    /// The footprint the simulator checks collisions with: the URDF base collision's xy
    /// projection ([`footprint`]), or the disc of `footprint_radius` when `[footprint] radius`
    /// overrides the URDF.
    pub footprint_shapes: Vec<footprint::FootprintShape>,
    /// Effective limits after the URDF caps.
    pub limits: Limits,
    /// Where each effective limit came from.
    pub limit_sources: LimitProvenance,
    /// Effective minimum turning radius (m, 0 = turns in place); `kappa_max = 1 / r`.
    pub min_turning_radius: f64,
    /// Gains of the tracking controller (`[controller]`, else the defaults), checked finite
    /// and `>= 0` (`lookahead > 0`).
    pub controller: ControllerGains,
    /// Whether `controller` was written in robot.toml ([`Origin::Profile`]) or defaulted.
    pub controller_source: Origin,
    /// Weights and shape of the feasibility penalty Φ (`[cost]`, else the defaults),
    /// checked finite, `>= 0`, `gamma > 0`, `delta < 1`.
    pub guidance: GuidanceWeights,
    /// Whether `guidance` was written in robot.toml ([`Origin::Profile`]) or defaulted.
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
    /// `[cost]`; `[guidance]`, its name until December 2026, is still read.
    #[serde(default, rename = "cost", alias = "guidance")]
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
    #[serde(default)]
    deadline_ms: Option<f64>,
    #[serde(default)]
    isolation: Option<PluginIsolation>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct RawFootprint {
    radius: Option<f64>,
}

#[derive(Clone, Copy, Debug, Deserialize)]
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
    isolation: Option<PluginIsolation>,
}

// ---------------------------------------------------------------------------------------------
// Loading
// ---------------------------------------------------------------------------------------------

impl RobotProfile {
    /// Reads, validates and resolves a `robot.toml` and its URDF.
    ///
    /// ```
    /// use human2nav_core::robot::RobotProfile;
    ///
    /// let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    /// let diablo = RobotProfile::load(&root.join("robots/diablo/robot.toml"))?;
    /// assert_eq!(diablo.name, "diablo");
    /// // Each limit is the tighter of the profile's value and what the URDF allows.
    /// assert!(diablo.limits.v_max > 0.0 && diablo.limits.omega_max > 0.0);
    /// # Ok::<(), human2nav_core::robot::ProfileError>(())
    /// ```
    pub fn load(path: &Path) -> Result<RobotProfile, ProfileError> {
        let text = crate::input::read_user_file(path, "robot profile", MAX_PROFILE_BYTES).map_err(
            |source| ProfileError::Read {
                file: path.to_path_buf(),
                source,
            },
        )?;
        Self::from_toml_str(&text, path, None)
    }

    /// Validates and resolves a profile held in memory: `text` is the `robot.toml`, `path`
    /// names it in errors and its folder is where relative paths in it are resolved (plugins,
    /// and the URDF when `urdf` is `None`), and `urdf` is the text of the URDF its `urdf` key
    /// names, for a robot description read from elsewhere (a parameter server); `None` reads
    /// that file. The same size caps apply as to files.
    pub fn from_toml_str(
        text: &str,
        path: &Path,
        urdf: Option<&str>,
    ) -> Result<RobotProfile, ProfileError> {
        if text.len() as u64 > MAX_PROFILE_BYTES {
            return Err(ProfileError::Read {
                file: path.to_path_buf(),
                source: std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!(
                        "{} bytes is more than the limit of {MAX_PROFILE_BYTES} for a robot profile",
                        text.len()
                    ),
                ),
            });
        }
        let raw: RawProfile = toml::from_str(text).map_err(|e| parse_error(path, text, &e))?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::from_raw(raw, path, &dir, urdf)
    }

    /// Checks a parsed profile and resolves it against its URDF, one [`resolve`] step after
    /// the other: the profile's own values, the embodiment, the plugin constraint terms, the
    /// URDF, then the effective limits. Errors are reported in that order.
    fn from_raw(
        raw: RawProfile,
        path: &Path,
        dir: &Path,
        urdf_text: Option<&str>,
    ) -> Result<RobotProfile, ProfileError> {
        let ck = Checker { file: path };
        let checked = resolve::check_values(&raw, &ck)?;
        let embodiment = resolve::embodiment(&raw.embodiment, &ck, dir)?;
        let constraints = resolve::constraints(&raw.constraints, &ck, dir)?;
        let urdf = resolve::urdf(&raw, &ck, dir, checked.footprint_override, urdf_text)?;
        let kind = resolve::builtin_kind(&embodiment);
        let effective = resolve::limits(&checked.limits, kind, &urdf, &ck)?;
        Ok(RobotProfile {
            name: raw.name,
            description: raw.description,
            source: path.to_path_buf(),
            urdf: urdf.path,
            base_link: urdf.base_link,
            embodiment,
            wheel_joints: urdf.wheel_joints,
            steering_joints: urdf.steering_joints,
            track_width: urdf.track_width,
            wheelbase: effective.wheelbase,
            footprint_radius: urdf.footprint_radius,
            footprint_source: urdf.footprint_source,
            footprint_shapes: urdf.footprint_shapes,
            limits: effective.limits,
            limit_sources: effective.sources,
            min_turning_radius: effective.min_turning_radius,
            controller: checked.controller,
            controller_source: checked.controller_source,
            guidance: checked.guidance,
            guidance_source: checked.guidance_source,
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

    /// Sets where each plugin this profile names runs when its declaration does not say
    /// (`isolation` not written): for a program that embeds the SDK and chooses another default
    /// than [`PluginIsolation::default`] (the C API and the Python package choose
    /// [`PluginIsolation::InProcess`]: the embedding program is the host, and no helper
    /// executable ships with them). A written `isolation` is kept.
    pub fn default_plugin_isolation(&mut self, isolation: PluginIsolation) {
        let refs = self
            .constraints
            .iter_mut()
            .chain(match &mut self.embodiment {
                EmbodimentSpec::Plugin(r) => Some(r),
                EmbodimentSpec::Builtin(_) => None,
            });
        for r in refs {
            r.isolation.get_or_insert(isolation);
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
