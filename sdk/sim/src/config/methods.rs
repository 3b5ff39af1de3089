//! The methods the simulator builds without libtorch: `straight`, `oracle` and plugins.

use super::{BenchConfig, MethodConfig};
use crate::bench::MethodSpec;
use crate::error::SimError;
use human2nav_core::Planner;
use human2nav_plugin::deadline::deadline_from_ms;
use human2nav_plugin::{PluginHost, RobotContext};
use std::sync::Arc;

/// Builds the methods whose kind the simulator knows without libtorch:
///
/// * `straight`: [`MethodSpec::straight`] with the method's `config`;
/// * `oracle`: [`MethodSpec::oracle`] (the clairvoyant yardstick) with the method's `config`;
/// * `plugin`: a planner from the plugin library `library` (factory `plugin`, default the
///   method's name), created per episode through `host` with the robot's limits, gains and
///   footprint and the method's `config` as its TOML, its calls under the method's
///   `deadline_ms`, in the host process or (`isolation = "process"`) in a helper process. The
///   library is loaded once here, so a missing build fails before any
///   episode runs.
///
/// Either replans at the method's `replan_hz` when it sets one. Returns `Ok(None)` for any
/// other kind (the caller resolves those, e.g. `human2nav`).
pub fn builtin_method(
    m: &MethodConfig,
    cfg: &BenchConfig,
    host: &Arc<PluginHost>,
) -> Result<Option<MethodSpec>, SimError> {
    let spec = builtin_planner(m, cfg, host)?;
    Ok(spec.map(|s| s.with_replan_hz(m.replan_hz)))
}

fn builtin_planner(
    m: &MethodConfig,
    cfg: &BenchConfig,
    host: &Arc<PluginHost>,
) -> Result<Option<MethodSpec>, SimError> {
    let section = || format!("methods[{}]", m.name);
    match m.kind.as_str() {
        "straight" => MethodSpec::straight(&m.name, &m.config)
            .map(Some)
            .map_err(|e| SimError::setting(section(), "config", e.to_string())),
        "oracle" => MethodSpec::oracle(&m.name, &m.config)
            .map(Some)
            .map_err(|e| SimError::setting(section(), "config", e.to_string())),
        "plugin" => {
            let Some(library) = &m.library else {
                return Err(SimError::setting(
                    section(),
                    "library",
                    "a plugin method names its library",
                ));
            };
            let library = cfg.resolve(library);
            let factory = m.plugin.clone().unwrap_or_else(|| m.name.clone());
            let config = toml::to_string(&m.config)
                .map_err(|e| SimError::setting(section(), "config", e.to_string()))?;
            let lib = host.load_library(&library).map_err(|e| {
                SimError::setting(
                    section(),
                    "library",
                    format!("{e} (build the plugin with `cargo build --workspace`, or `--release` for a release binary)"),
                )
            })?;
            if !lib.factories().iter().any(|f| f.name == factory) {
                let known: Vec<&str> = lib.factories().iter().map(|f| f.name.as_str()).collect();
                return Err(SimError::setting(
                    section(),
                    "plugin",
                    format!(
                        "{} has no factory `{factory}` (it has: {})",
                        lib.path().display(),
                        known.join(", ")
                    ),
                ));
            }
            let deadline = deadline_from_ms(m.deadline_ms)
                .map_err(|e| SimError::setting(section(), "deadline_ms", e))?;
            let isolation = m.isolation.unwrap_or_default();
            let host = Arc::clone(host);
            Ok(Some(MethodSpec::new(m.name.clone(), move |ctx| {
                let robot = RobotContext {
                    limits: ctx.robot.limits,
                    gains: ctx.robot.gains,
                    footprint_radius: ctx.robot.footprint_radius,
                };
                let planner = host.planner_with_options(
                    &library,
                    &factory,
                    &config,
                    Some(&robot),
                    deadline,
                    isolation,
                )?;
                Ok(Box::new(planner) as Box<dyn Planner>)
            })))
        }
        _ => Ok(None),
    }
}
