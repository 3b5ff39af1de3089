//! When the planner was built with libtorch (this package's `torch` feature, or a workspace
//! build in which another package asked for it), bakes libtorch's library directory into the C
//! library and this package's tests as an rpath, so that a program linked against
//! libhuman2nav_c runs without LD_LIBRARY_PATH. `human2nav-flow` passes the directory on to the
//! packages that depend on it. A build of this package alone links no libtorch.

fn main() {
    println!("cargo::rerun-if-env-changed=DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
