//! `human2nav plugin inspect`: what a library provides and everything the host checked.
//!
//! [`inspect_library`] loads the library as any host would (every check of
//! [`crate::libfile`] and [`crate::validate`]), then tries each factory with an empty
//! configuration and no robot: when the factory accepts, the instance's vtable and name are
//! checked and the instance destroyed; a factory that needs a configuration or a robot is
//! listed as checked later (its vtable is checked when a profile creates an instance).
//! [`InspectReport::render`] is what the CLI prints.

use crate::error::PluginError;
use crate::host::{PluginLibrary, probe_factory};
use crate::validate::{Check, CheckStatus};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What `plugin inspect` found.
#[derive(Debug)]
pub struct InspectReport {
    /// The path as given.
    pub requested: PathBuf,
    /// The library, when it loaded.
    pub library: Option<Arc<PluginLibrary>>,
    /// Every check, in order: the library's (file, entry table, factories), then one per
    /// factory instance.
    pub checks: Vec<Check>,
    /// The first failure (`None`: everything checked passed).
    pub error: Option<PluginError>,
}

impl InspectReport {
    /// True when nothing failed.
    pub fn ok(&self) -> bool {
        self.error.is_none()
    }

    /// The human-readable report: the library's description, then the checks.
    pub fn render(&self) -> String {
        let mut s = String::new();
        match &self.library {
            Some(lib) => {
                let _ = writeln!(s, "library   {}", lib.path().display());
                let _ = writeln!(s, "plugin    {} {}", lib.name(), lib.version());
                let _ = writeln!(
                    s,
                    "ABI       version {}",
                    crate::host::abi_version_text(lib.abi_version())
                );
                let factories = lib.factories();
                let plural = if factories.len() == 1 {
                    "factory"
                } else {
                    "factories"
                };
                let _ = writeln!(s, "provides  {} {plural}", factories.len());
                let width = factories.iter().map(|f| f.name.len()).max().unwrap_or(0);
                for f in factories {
                    let _ = writeln!(
                        s,
                        "  {:<11} {:<width$}  {}",
                        f.kind.to_string(),
                        f.name,
                        f.description
                    );
                }
            }
            None => {
                let _ = writeln!(s, "library   {}", self.requested.display());
            }
        }
        let failed = self
            .checks
            .iter()
            .filter(|c| c.status == CheckStatus::Failed)
            .count();
        let deferred = self
            .checks
            .iter()
            .filter(|c| c.status == CheckStatus::Deferred)
            .count();
        let _ = writeln!(
            s,
            "checked   {} checks: {} passed, {failed} failed, {deferred} left for when an instance \
             is created",
            self.checks.len(),
            self.checks.len() - failed - deferred
        );
        for c in &self.checks {
            let _ = writeln!(s, "  {c}");
        }
        s
    }
}

/// Loads the library at `path` and checks everything (see the module docs).
pub fn inspect_library(path: &Path) -> InspectReport {
    let (loaded, mut checks) = PluginLibrary::load_checked(path);
    let lib = match loaded {
        Ok(lib) => lib,
        Err(e) => {
            return InspectReport {
                requested: path.to_path_buf(),
                library: None,
                checks,
                error: Some(e),
            };
        }
    };
    let mut error = None;
    for f in lib.factories() {
        let item = format!("{} `{}` instance", f.kind, f.name);
        match probe_factory(&lib, f) {
            Ok(Ok(detail)) => checks.push(Check::pass(
                item,
                format!("created with an empty config and no robot; vtable {detail}"),
            )),
            Ok(Err(why)) => checks.push(Check::defer(
                item,
                format!(
                    "not created with an empty config and no robot ({why}); its vtable is \
                     checked when a profile creates it"
                ),
            )),
            Err(e) => {
                checks.push(Check::fail(item, e.to_string()));
                error.get_or_insert(e);
            }
        }
    }
    InspectReport {
        requested: path.to_path_buf(),
        library: Some(lib),
        checks,
        error,
    }
}
