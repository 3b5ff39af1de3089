//! Robot profiles and configuration files that name plugins.
//!
//! A `robot.toml` names plugins by path (see [`human2nav_core::robot`]): a plugin embodiment
//! (`[embodiment] kind = "plugin"`) and any number of plugin constraint terms
//! (`[[constraint]]`). [`PluginHost::load_robot`] turns the loaded profile into a runtime robot;
//! nothing is loaded that the profile does not name. Other configuration files (a benchmark's
//! list of planners, for instance) embed a [`PluginSpec`] and resolve it against their own path.

use crate::deadline::deadline_from_ms;
use crate::error::{PluginError, PluginKind};
use crate::host::{PluginConstraint, PluginEmbodiment, PluginHost, PluginPlanner};
use crate::init::RobotContext;
use crate::locate::resolve_relative;
use human2nav_core::constraint::{
    ConstraintContext, ConstraintError, ConstraintTerm, Phi, TrajBatch,
};
use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::robot::{EmbodimentSpec, PluginIsolation, PluginRef, RobotProfile};
use human2nav_core::{Plan, PlanInfo, Pose2, Twist2};
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A plugin reference as written in a TOML file other than a robot profile:
///
/// ```toml
/// library = "../../target/{profile}/human2nav_orca"   # relative to this file
/// plugin = "orca"                                     # factory name
/// weight = 1.0                                        # constraint terms only; default 1
/// deadline_ms = 1000                                  # per call; default 1000; 0: none
/// isolation = "process"                               # default: a helper process of its own
///                                                     # (crate::process); "in_process": opt-in
///                                                     # for speed, a crash takes the host down
/// config = """
/// time_horizon = 2.0
/// """
/// ```
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PluginSpec {
    /// The library, relative to the declaring file; OS extension and `lib` prefix optional.
    pub library: PathBuf,
    /// The factory name inside the library.
    pub plugin: String,
    /// Weight (constraint terms only).
    #[serde(default = "default_weight")]
    pub weight: f64,
    /// TOML handed to the plugin verbatim.
    #[serde(default)]
    pub config: String,
    /// Deadline of each call (see [`crate::deadline`]).
    #[serde(default)]
    pub deadline_ms: Option<f64>,
    /// Where the instance runs (`None`: not written, a helper process; see [`crate::process`]).
    #[serde(default)]
    pub isolation: Option<PluginIsolation>,
}

fn default_weight() -> f64 {
    1.0
}

impl PluginSpec {
    /// The reference with `library` resolved against the directory of `declared_in`.
    pub fn resolve(&self, declared_in: &Path) -> PluginRef {
        PluginRef {
            library: resolve_relative(declared_in, &self.library),
            plugin: self.plugin.clone(),
            config: self.config.clone(),
            weight: self.weight,
            deadline_ms: self.deadline_ms,
            isolation: self.isolation,
            declared_in: declared_in.to_path_buf(),
        }
    }
}

/// The robot context a profile gives plugin factories.
pub fn robot_context(profile: &RobotProfile) -> RobotContext {
    RobotContext {
        limits: profile.limits,
        gains: profile.controller,
        footprint_radius: profile.footprint_radius,
    }
}

/// A robot profile with its embodiment and plugin constraint terms instantiated.
pub struct LoadedRobot {
    /// The parsed and validated profile the robot was built from.
    pub profile: RobotProfile,
    /// The built-in embodiment or the plugin's proxy.
    pub embodiment: Box<dyn Embodiment>,
    /// `(weight, term)` of every `[[constraint]]` of the profile, in order.
    pub plugin_terms: Vec<(f64, Box<dyn ConstraintTerm>)>,
}

impl fmt::Debug for LoadedRobot {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LoadedRobot")
            .field("profile", &self.profile.name)
            .field("embodiment", &self.embodiment.name())
            .field(
                "plugin_terms",
                &self
                    .plugin_terms
                    .iter()
                    .map(|(w, t)| (*w, t.name()))
                    .collect::<Vec<_>>(),
            )
            .finish()
    }
}

impl LoadedRobot {
    /// Φ for this robot: the built-in terms weighted by the profile's guidance weights, then the
    /// plugin terms with their weights. The plugin terms move into Φ (`plugin_terms` is left
    /// empty).
    pub fn take_phi(&mut self) -> Result<Phi, ConstraintError> {
        let mut phi = Phi::from_weights(&self.profile.guidance, &self.profile.limits);
        for (w, term) in self.plugin_terms.drain(..) {
            phi.push(w, term)?;
        }
        Ok(phi)
    }
}

/// The deadline a reference asks for (see [`deadline_from_ms`]); a bad value is a config
/// error naming the declaring file.
fn ref_deadline(r: &PluginRef, kind: PluginKind) -> Result<Option<Duration>, PluginError> {
    deadline_from_ms(r.deadline_ms).map_err(|m| PluginError::Config {
        path: r.declared_in.clone(),
        kind,
        name: r.plugin.clone(),
        message: format!("deadline_ms: {m}"),
    })
}

/// Where a reference's instance runs: as written, else [`PluginIsolation::default`] (a helper
/// process).
pub fn ref_isolation(r: &PluginRef) -> PluginIsolation {
    r.isolation.unwrap_or_default()
}

impl PluginHost {
    /// A constraint term from a profile's or config's reference, with the reference's deadline
    /// and isolation.
    pub fn constraint_ref(
        &self,
        r: &PluginRef,
        robot: Option<&RobotContext>,
    ) -> Result<PluginConstraint, PluginError> {
        let deadline = ref_deadline(r, PluginKind::Constraint)?;
        self.constraint_with_options(
            &r.library,
            &r.plugin,
            &r.config,
            robot,
            deadline,
            ref_isolation(r),
        )
    }

    /// An embodiment from a reference, for the robot described by `robot`, with the
    /// reference's deadline and isolation.
    pub fn embodiment_ref(
        &self,
        r: &PluginRef,
        robot: &RobotContext,
    ) -> Result<PluginEmbodiment, PluginError> {
        let deadline = ref_deadline(r, PluginKind::Embodiment)?;
        self.embodiment_with_options(
            &r.library,
            &r.plugin,
            &r.config,
            robot,
            deadline,
            ref_isolation(r),
        )
    }

    /// A planner from a reference, optionally for a robot, with the reference's deadline and
    /// isolation.
    pub fn planner_ref(
        &self,
        r: &PluginRef,
        robot: Option<&RobotContext>,
    ) -> Result<PluginPlanner, PluginError> {
        let deadline = ref_deadline(r, PluginKind::Planner)?;
        self.planner_with_options(
            &r.library,
            &r.plugin,
            &r.config,
            robot,
            deadline,
            ref_isolation(r),
        )
    }

    /// The embodiment a profile describes: built-in, or created from its plugin. The
    /// profile's limits are completed with what a plugin embodiment declares beyond them (its
    /// coupled limit, [`Embodiment::coupled_limit`]), so that TFS, Φ and the planner built
    /// from the profile afterwards see it.
    pub fn robot_embodiment(
        &self,
        profile: &mut RobotProfile,
    ) -> Result<Box<dyn Embodiment>, PluginError> {
        match &profile.embodiment {
            EmbodimentSpec::Plugin(r) => {
                let e = self.embodiment_ref(r, &robot_context(profile))?;
                profile.limits.coupled = e.coupled_limit();
                Ok(Box::new(e))
            }
            EmbodimentSpec::Builtin(_) => match profile.builtin_embodiment() {
                Some(e) => Ok(e),
                None => Err(PluginError::Malformed {
                    path: profile.source.clone(),
                    message: "built-in embodiment could not be constructed".into(),
                }),
            },
        }
    }

    /// Instantiates everything a loaded profile names: its embodiment and its plugin
    /// constraint terms (each created with the robot's limits, gains and footprint).
    pub fn load_robot(&self, mut profile: RobotProfile) -> Result<LoadedRobot, PluginError> {
        let embodiment = self.robot_embodiment(&mut profile)?;
        let ctx = robot_context(&profile);
        let mut plugin_terms: Vec<(f64, Box<dyn ConstraintTerm>)> =
            Vec::with_capacity(profile.constraints.len());
        for r in &profile.constraints {
            plugin_terms.push((r.weight, Box::new(self.constraint_ref(r, Some(&ctx))?)));
        }
        Ok(LoadedRobot {
            profile,
            embodiment,
            plugin_terms,
        })
    }

    /// Φ for a profile with fresh plugin term instances (built-ins + plugin terms).
    pub fn phi(&self, profile: &RobotProfile) -> Result<Phi, PluginError> {
        let ctx = robot_context(profile);
        let mut phi = Phi::from_weights(&profile.guidance, &profile.limits);
        for r in &profile.constraints {
            let term = self.constraint_ref(r, Some(&ctx))?;
            phi.push(r.weight, Box::new(term))
                .map_err(|e| PluginError::Malformed {
                    path: r.declared_in.clone(),
                    message: e.to_string(),
                })?;
        }
        Ok(phi)
    }
}

/// Where an instance runs, for the lines of `robot check`.
fn where_it_runs(own_process: bool) -> &'static str {
    if own_process {
        " in its own process"
    } else {
        " in this process"
    }
}

/// What [`PluginHost::resolve_robot`] did with each plugin of a profile, one line each.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RobotResolution {
    /// `embodiment `skid_steer` from <library>: ...` (empty for a built-in embodiment).
    pub embodiment: Option<String>,
    /// One line per `[[constraint]]`, in order.
    pub constraints: Vec<String>,
}

impl PluginHost {
    /// Fully resolves every plugin a profile declares, as a run would use it: loads each
    /// library (with every check of [`crate::libfile`] and [`crate::validate`]), finds the
    /// factory, creates the instance for this robot with the declared configuration, and makes
    /// one cheap call (an embodiment saturates, steps and tracks from rest; a constraint term
    /// evaluates one two-pose trajectory in an empty world). The error names the profile, the
    /// declaration and the plugin file. For `human2nav robot check`.
    pub fn resolve_robot(&self, profile: &RobotProfile) -> Result<RobotResolution, PluginError> {
        let in_profile = |item: String, error: PluginError| PluginError::Profile {
            profile: profile.source.clone(),
            item,
            error: Box::new(error),
        };
        let ctx = robot_context(profile);
        let mut out = RobotResolution::default();
        if let EmbodimentSpec::Plugin(r) = &profile.embodiment {
            let line = self
                .probe_embodiment(r, &ctx)
                .map_err(|e| in_profile("[embodiment]".into(), e))?;
            out.embodiment = Some(line);
        }
        for (i, r) in profile.constraints.iter().enumerate() {
            let line = self
                .probe_constraint(r, profile)
                .map_err(|e| in_profile(format!("[[constraint]] {i} (`{}`)", r.plugin), e))?;
            out.constraints.push(line);
        }
        Ok(out)
    }

    fn probe_embodiment(&self, r: &PluginRef, ctx: &RobotContext) -> Result<String, PluginError> {
        let e = self.embodiment_ref(r, ctx)?;
        let probe = |message: String| PluginError::Probe {
            path: r.library.clone(),
            kind: PluginKind::Embodiment,
            name: r.plugin.clone(),
            message,
        };
        let dt = 0.05;
        let rest = RobotState::default();
        let holonomic = e.holonomic();
        let cmd = e.saturate(&rest, Twist2::new(0.5 * ctx.limits.v_max, 0.0, 0.0), dt);
        let next = e.step(&rest, cmd, dt);
        let plan = Plan {
            t0: 0.0,
            dt: 0.1,
            poses: vec![Pose2::IDENTITY, Pose2::new(0.05, 0.0, 0.0)],
            info: PlanInfo::default(),
        };
        let track = e.track(&rest, &plan, 0.0);
        if let Some(failure) = e.failure() {
            return Err(probe(failure));
        }
        let finite = |t: Twist2| t.vx.is_finite() && t.vy.is_finite() && t.omega.is_finite();
        if !finite(cmd) || !finite(track) || !next.pose.is_finite() || !finite(next.velocity) {
            return Err(probe(format!(
                "it returned non-finite values from rest (saturate {cmd:?}, step {next:?}, \
                 track {track:?})"
            )));
        }
        Ok(format!(
            "embodiment `{}` from {}: created with its config{}; holonomic {holonomic}; \
             saturate, step and track from rest answered (deadline {})",
            e.name(),
            r.library.display(),
            where_it_runs(e.in_own_process()),
            e.deadline()
                .map_or("none".to_owned(), crate::deadline::describe)
        ))
    }

    fn probe_constraint(
        &self,
        r: &PluginRef,
        profile: &RobotProfile,
    ) -> Result<String, PluginError> {
        let term = self.constraint_ref(r, Some(&robot_context(profile)))?;
        let probe = |message: String| PluginError::Probe {
            path: r.library.clone(),
            kind: PluginKind::Constraint,
            name: r.plugin.clone(),
            message,
        };
        let data = [0.0, 0.0, 0.0, 0.05, 0.0, 0.0];
        let ctx = ConstraintContext {
            dt: 0.1,
            limits: &profile.limits,
            initial_velocity: Twist2::ZERO,
            agents: &[],
            scene: Default::default(),
        };
        let (mut cost, mut grad) = ([0.0], [0.0; 6]);
        let batch = TrajBatch::new(&data, 1, 2).map_err(|e| probe(e.to_string()))?;
        term.evaluate(batch, &ctx, &mut cost, &mut grad)
            .map_err(|e| probe(e.to_string()))?;
        if !cost[0].is_finite() || grad.iter().any(|g| !g.is_finite()) {
            return Err(probe(format!(
                "it returned a non-finite cost or gradient ({})",
                cost[0]
            )));
        }
        Ok(format!(
            "constraint `{}` from {}: created with its config{}; evaluate answered (deadline {})",
            term.name(),
            r.library.display(),
            where_it_runs(term.in_own_process()),
            term.deadline()
                .map_or("none".to_owned(), crate::deadline::describe)
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_resolve_against_their_file() {
        let spec: PluginSpec =
            toml::from_str("library = \"../x/orca\"\nplugin = \"orca\"").unwrap();
        assert_eq!(spec.weight, 1.0);
        assert_eq!(spec.config, "");
        let r = spec.resolve(Path::new("sdk/configs/bench.toml"));
        assert_eq!(r.library, PathBuf::from("sdk/configs/../x/orca"));
        assert_eq!(r.declared_in, PathBuf::from("sdk/configs/bench.toml"));
        assert!(
            toml::from_str::<PluginSpec>("library = \"a\"\nplugin = \"b\"\nextra = 1").is_err()
        );
    }
}
