//! Dataset locator for the real-data tests.

#![allow(dead_code, clippy::unwrap_used)]

use std::path::{Path, PathBuf};

/// `$HUMAN2NAV_DATA`, else `<workspace>/../shared/data`; `None` (with a note) when absent.
pub fn data(test: &str) -> Option<PathBuf> {
    let ws = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let dir = human2nav_data::paths::data_root(None, &ws);
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

/// A fresh scratch file path under the system temp directory.
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("human2nav-data-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}
