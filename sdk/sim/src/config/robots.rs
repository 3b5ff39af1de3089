//! The robots of the configuration: built-in or plugin embodiments, each name once.

use super::BenchConfig;
use crate::error::SimError;
use crate::runner::RobotSetup;
use human2nav_plugin::PluginHost;

/// The robots of the configuration, in order; plugin embodiments are created through a fresh
/// plugin host (see [`load_robots_with`]).
pub fn load_robots(cfg: &BenchConfig) -> Result<Vec<RobotSetup>, SimError> {
    load_robots_with(cfg, &PluginHost::new())
}

/// The robots of the configuration, in order, built-in or plugin embodiments (created through
/// `host`, which then lists a plugin embodiment that fails during the runs); every plugin a
/// profile declares is resolved first ([`RobotSetup::load_with`]).
/// Two profiles of one name are refused: the results are keyed by the robot's name, so every
/// run would count twice (the same profile listed twice) or two robots would mix.
pub fn load_robots_with(cfg: &BenchConfig, host: &PluginHost) -> Result<Vec<RobotSetup>, SimError> {
    let robots: Vec<RobotSetup> = cfg
        .robots
        .iter()
        .map(|p| RobotSetup::load_with(&cfg.resolve(p), host))
        .collect::<Result<_, _>>()?;
    for (i, r) in robots.iter().enumerate() {
        if let Some(j) = robots[..i].iter().position(|o| o.name == r.name) {
            return Err(SimError::setting(
                "bench",
                format!("robots[{i}]"),
                format!(
                    "robot `{}` is already robots[{j}] ({} and {}); each robot once, by a \
                     name of its own",
                    r.name,
                    cfg.robots[j].display(),
                    cfg.robots[i].display()
                ),
            ));
        }
    }
    Ok(robots)
}
