//! What a plugin factory receives: the TOML configuration and, when there is one, the robot the
//! instance serves. Plugin authors write constructors `fn(&PluginInit<'_>) -> Result<T, E>` with
//! `E: Into<InitError>` and never see the ABI.

use human2nav_core::{ControllerGains, Limits};
use serde::de::DeserializeOwned;

/// The robot an instance is created for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotContext {
    /// The robot's effective hard limits.
    pub limits: Limits,
    /// Its tracking-controller gains.
    pub gains: ControllerGains,
    /// Its footprint radius (m).
    pub footprint_radius: f64,
}

/// The arguments of a plugin factory.
#[derive(Clone, Copy, Debug)]
pub struct PluginInit<'a> {
    config: &'a str,
    robot: Option<RobotContext>,
}

/// Why a factory could not create an instance.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InitError {
    /// The configuration is not valid TOML or does not fit the expected types.
    #[error("config: {message}")]
    Parse {
        /// The TOML parser's message.
        message: String,
    },
    /// The configuration names fields the plugin does not know.
    #[error("config: unknown field(s) {fields}")]
    UnknownField {
        /// The unknown fields, comma-separated.
        fields: String,
    },
    /// A configuration value is out of range.
    #[error("config: {field}: {message}")]
    Invalid {
        /// The offending field.
        field: String,
        /// What is wrong with its value.
        message: String,
    },
    /// The factory needs the robot's limits but was called without a robot.
    #[error("this plugin needs a robot context (limits, gains, footprint) and none was given")]
    NeedsRobot,
    /// Any other failure.
    #[error("{0}")]
    Failed(String),
}

impl InitError {
    /// An out-of-range configuration value.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// True for errors in the configuration (reported as `H2N_CONFIG` across the ABI).
    pub fn is_config(&self) -> bool {
        matches!(
            self,
            Self::Parse { .. } | Self::UnknownField { .. } | Self::Invalid { .. }
        )
    }
}

impl From<String> for InitError {
    fn from(message: String) -> Self {
        Self::Failed(message)
    }
}

impl From<&str> for InitError {
    fn from(message: &str) -> Self {
        Self::Failed(message.to_owned())
    }
}

impl<'a> PluginInit<'a> {
    /// Arguments for a factory (the macro builds these from the ABI; tests and built-in uses of
    /// a plugin type may call constructors directly with them).
    pub fn new(config: &'a str, robot: Option<RobotContext>) -> Self {
        Self { config, robot }
    }

    /// The configuration exactly as written in the profile.
    pub fn config_str(&self) -> &'a str {
        self.config
    }

    /// Parses the configuration into `T`. Every field the TOML names must be consumed by `T`:
    /// unknown fields are rejected even when `T` forgot `#[serde(deny_unknown_fields)]`.
    /// An empty string parses as an empty table (so `#[serde(default)]` structs get defaults).
    pub fn config<T: DeserializeOwned>(&self) -> Result<T, InitError> {
        parse_config(self.config)
    }

    /// The robot the instance serves, when the host passed one.
    pub fn robot(&self) -> Option<&RobotContext> {
        self.robot.as_ref()
    }

    /// True when the configuration as written sets the top-level key `key` (false for an
    /// unparsable configuration, which [`PluginInit::config`] reports). For robot-dependent
    /// defaults: take the robot's value unless the configuration names the key.
    pub fn sets(&self, key: &str) -> bool {
        toml::from_str::<toml::Table>(self.config).is_ok_and(|t| t.contains_key(key))
    }

    /// The robot the instance serves, or [`InitError::NeedsRobot`].
    pub fn require_robot(&self) -> Result<&RobotContext, InitError> {
        self.robot.as_ref().ok_or(InitError::NeedsRobot)
    }
}

/// Parses a TOML configuration string into `T`, rejecting unknown fields (see
/// [`PluginInit::config`]). Errors name the line and column.
pub fn parse_config<T: DeserializeOwned>(text: &str) -> Result<T, InitError> {
    let located = |e: toml::de::Error| {
        let at = e.span().map(|s| line_column(text, s.start));
        let message = match at {
            Some((line, col)) => format!("line {line} column {col}: {}", e.message()),
            None => e.message().to_owned(),
        };
        InitError::Parse { message }
    };
    let de = toml::Deserializer::parse(text).map_err(located)?;
    let mut unknown = Vec::new();
    let value: T = serde_ignored::deserialize(de, |path| unknown.push(format!("`{path}`")))
        .map_err(located)?;
    if unknown.is_empty() {
        Ok(value)
    } else {
        Err(InitError::UnknownField {
            fields: unknown.join(", "),
        })
    }
}

/// 1-based line and column of byte offset `at` in `text`.
fn line_column(text: &str, at: usize) -> (usize, usize) {
    let before = &text[..at.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, Deserialize, PartialEq)]
    #[serde(default)]
    struct Lenient {
        a: f64,
        b: Vec<u32>,
    }

    impl Default for Lenient {
        fn default() -> Self {
            Self { a: 1.5, b: vec![] }
        }
    }

    #[test]
    fn empty_config_gives_defaults() {
        let v: Lenient = parse_config("").unwrap();
        assert_eq!(v, Lenient::default());
    }

    #[test]
    fn known_fields_parse() {
        let v: Lenient = parse_config("a = 2.0\nb = [1, 2]").unwrap();
        assert_eq!(
            v,
            Lenient {
                a: 2.0,
                b: vec![1, 2]
            }
        );
    }

    #[test]
    fn unknown_fields_are_rejected_without_deny_attribute() {
        let err = parse_config::<Lenient>("a = 2.0\nc = 3\n[d]\ne = 1").unwrap_err();
        assert_eq!(
            err,
            InitError::UnknownField {
                fields: "`c`, `d`".into()
            }
        );
        assert!(err.is_config());
    }

    #[test]
    fn syntax_errors_name_line_and_column() {
        let err = parse_config::<Lenient>("a = 2.0\nb = [1,").unwrap_err();
        let InitError::Parse { message } = err else {
            panic!("expected a parse error")
        };
        assert!(message.starts_with("line 2 column"), "{message}");
    }

    #[test]
    fn type_errors_are_parse_errors() {
        let err = parse_config::<Lenient>("a = \"fast\"").unwrap_err();
        assert!(matches!(err, InitError::Parse { .. }), "{err}");
    }

    #[test]
    fn robot_context_is_optional() {
        let init = PluginInit::new("", None);
        assert!(init.robot().is_none());
        assert_eq!(init.require_robot().unwrap_err(), InitError::NeedsRobot);
    }
}
