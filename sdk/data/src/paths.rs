//! Where datasets and generated files live.
//!
//! The datasets are found at, in order: a path given in the config, `$HUMAN2NAV_DATA`, and
//! `<workspace root>/../shared/data`. Generated files default to `<workspace root>/out/`.

use std::path::{Path, PathBuf};

/// Environment variable naming the dataset directory.
pub const DATA_ENV: &str = "HUMAN2NAV_DATA";

/// The nearest ancestor of `start` (inclusive) holding a `Cargo.toml` with a `[workspace]`
/// table.
pub fn find_workspace_root(start: &Path) -> Option<PathBuf> {
    let start = if start.is_absolute() {
        start.to_path_buf()
    } else {
        std::env::current_dir().ok()?.join(start)
    };
    start.ancestors().find_map(|dir| {
        let manifest = dir.join("Cargo.toml");
        let body = human2nav_core::input::read_user_file(
            &manifest,
            "Cargo manifest",
            human2nav_core::input::MAX_CONFIG_BYTES,
        )
        .ok()?;
        body.lines()
            .any(|l| l.trim() == "[workspace]")
            .then(|| dir.to_path_buf())
    })
}

/// Where the dataset directory was named.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataRootFrom {
    /// `paths.data_root` in the data config.
    Config,
    /// The environment variable [`DATA_ENV`].
    Env,
    /// Nowhere: the default `<workspace>/../shared/data`.
    Default,
}

/// The dataset directory: `configured` (relative paths against `workspace`) if given and
/// non-empty, else `$HUMAN2NAV_DATA`, else `<workspace>/../shared/data`.
pub fn data_root(configured: Option<&Path>, workspace: &Path) -> PathBuf {
    data_root_from(configured, workspace).0
}

/// [`data_root`] with where it was named.
pub fn data_root_from(configured: Option<&Path>, workspace: &Path) -> (PathBuf, DataRootFrom) {
    if let Some(p) = configured.filter(|p| !p.as_os_str().is_empty()) {
        let p = if p.is_absolute() {
            p.to_path_buf()
        } else {
            workspace.join(p)
        };
        return (p, DataRootFrom::Config);
    }
    if let Some(env) = std::env::var_os(DATA_ENV).filter(|v| !v.is_empty()) {
        return (PathBuf::from(env), DataRootFrom::Env);
    }
    (
        workspace.join("..").join("shared").join("data"),
        DataRootFrom::Default,
    )
}

/// Resolves a configured output path against the workspace root.
pub fn output_path(p: &Path, workspace: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        workspace.join(p)
    }
}
