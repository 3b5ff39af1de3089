//! `human2nav-plugin-host`: runs one plugin planner or constraint term in a process of its own
//! and serves its calls on stdin/stdout. Started by the plugin host for instances declared with
//! `isolation = "process"`; not meant to be run by hand (see `human2nav_plugin::process`).

fn main() {
    std::process::exit(human2nav_plugin::process::serve_stdio());
}
