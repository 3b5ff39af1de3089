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

/// The dataset directory: `configured` (relative paths against `workspace`) if given and
/// non-empty, else `$HUMAN2NAV_DATA`, else `<workspace>/../shared/data`.
pub fn data_root(configured: Option<&Path>, workspace: &Path) -> PathBuf {
    if let Some(p) = configured.filter(|p| !p.as_os_str().is_empty()) {
        return if p.is_absolute() {
            p.to_path_buf()
        } else {
            workspace.join(p)
        };
    }
    if let Some(env) = std::env::var_os(DATA_ENV).filter(|v| !v.is_empty()) {
        return PathBuf::from(env);
    }
    workspace.join("..").join("shared").join("data")
}

/// Resolves a configured output path against the workspace root.
pub fn output_path(p: &Path, workspace: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        workspace.join(p)
    }
}
