//! What the plugin crate's integration tests share: the fixture library and a host that
//! starts this crate's helper executable.

use human2nav_plugin::PluginHost;
use human2nav_plugin::resolve::resolve_library_path;
use std::path::PathBuf;

/// The fixture plugin library (`plugins/fixtures/test_plugin`), built beside the test binary.
pub fn fixture() -> PathBuf {
    let deps = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(PathBuf::from))
        .expect("test binary directory");
    for dir in [deps.clone(), deps.parent().unwrap_or(&deps).to_path_buf()] {
        let p = dir.join("human2nav_fixture_test_plugin");
        if resolve_library_path(&p).is_ok() {
            return p;
        }
    }
    panic!(
        "the fixture cdylib was not built next to {}",
        deps.display()
    );
}

/// A host whose isolated plugins run in this crate's `human2nav-plugin-host`.
pub fn host() -> PluginHost {
    PluginHost::new().with_process_helper(env!("CARGO_BIN_EXE_human2nav-plugin-host"))
}
