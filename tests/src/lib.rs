//! Helpers shared by the integration tests in `tests/tests/`.

use std::path::{Path, PathBuf};

/// The workspace root (the directory holding the top-level `Cargo.toml`).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from(".."))
}

/// Where the real pedestrian datasets are: `$HUMAN2NAV_DATA`, else `../shared/data` beside the
/// workspace. `None` (and a note on stderr naming the test) when they are absent.
pub fn dataset_root(test: &str) -> Option<PathBuf> {
    let dir = std::env::var_os("HUMAN2NAV_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("../shared/data"));
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!(
            "skipping {test}: real datasets not found at {} (set HUMAN2NAV_DATA)",
            dir.display()
        );
        None
    }
}

/// The directory cargo writes this profile's artefacts to (`target/debug` for tests), where the
/// plugin `cdylib`s end up.
pub fn target_profile_dir() -> PathBuf {
    // Test binaries live in target/<profile>/deps/.
    std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().and_then(Path::parent).map(Path::to_path_buf))
        .unwrap_or_else(|| workspace_root().join("target/debug"))
}
