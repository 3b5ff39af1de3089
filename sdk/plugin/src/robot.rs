//! Robot profiles and configuration files that name plugins.
//!
//! A `robot.toml` names plugins by path (see [`human2nav_core::robot`]): a plugin embodiment
//! (`[embodiment] kind = "plugin"`) and any number of plugin constraint terms
//! (`[[constraint]]`). [`PluginHost::load_robot`] turns the loaded profile into a runtime robot;
//! nothing is loaded that the profile does not name. Other configuration files (a benchmark's
//! list of planners, for instance) embed a [`PluginSpec`] and resolve it against their own path.

use crate::error::PluginError;
use crate::host::{PluginConstraint, PluginEmbodiment, PluginHost, PluginPlanner};
use crate::init::RobotContext;
use crate::resolve::resolve_relative;
use human2nav_core::constraint::{ConstraintError, ConstraintTerm, Phi};
use human2nav_core::embodiment::Embodiment;
use human2nav_core::robot::{EmbodimentSpec, PluginRef, RobotProfile};
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// A plugin reference as written in a TOML file other than a robot profile:
///
/// ```toml
/// library = "../../target/{profile}/human2nav_orca"   # relative to this file
/// plugin = "orca"                                     # factory name
/// weight = 1.0                                        # constraint terms only; default 1
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

impl PluginHost {
    /// A constraint term from a profile's or config's reference.
    pub fn constraint_ref(
        &self,
        r: &PluginRef,
        robot: Option<&RobotContext>,
    ) -> Result<PluginConstraint, PluginError> {
        self.constraint(&r.library, &r.plugin, &r.config, robot)
    }

    /// An embodiment from a reference, for the robot described by `robot`.
    pub fn embodiment_ref(
        &self,
        r: &PluginRef,
        robot: &RobotContext,
    ) -> Result<PluginEmbodiment, PluginError> {
        self.embodiment(&r.library, &r.plugin, &r.config, robot)
    }

    /// A planner from a reference, optionally for a robot.
    pub fn planner_ref(
        &self,
        r: &PluginRef,
        robot: Option<&RobotContext>,
    ) -> Result<PluginPlanner, PluginError> {
        self.planner(&r.library, &r.plugin, &r.config, robot)
    }

    /// The embodiment a profile describes: built-in, or created from its plugin.
    pub fn robot_embodiment(
        &self,
        profile: &RobotProfile,
    ) -> Result<Box<dyn Embodiment>, PluginError> {
        match &profile.embodiment {
            EmbodimentSpec::Plugin(r) => {
                Ok(Box::new(self.embodiment_ref(r, &robot_context(profile))?))
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
    pub fn load_robot(&self, profile: RobotProfile) -> Result<LoadedRobot, PluginError> {
        let embodiment = self.robot_embodiment(&profile)?;
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
