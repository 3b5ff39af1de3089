//! Bakes libtorch's library directory into this package's tests as an rpath, so they run
//! without LD_LIBRARY_PATH. `human2nav-flow` (with its `torch` feature) passes the directory on
//! to the packages that depend on it.

fn main() {
    println!("cargo::rerun-if-env-changed=DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
