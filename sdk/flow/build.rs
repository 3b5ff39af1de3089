//! With the `torch` feature: bakes libtorch's library directory into this package's tests,
//! benches and examples as an rpath (so they run without LD_LIBRARY_PATH), and passes the
//! directory on to the packages that depend on this one as `DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB`
//! (`links = "human2nav-flow"`), so that a binary or library that plans through this crate
//! finds libtorch too when feature unification built it with libtorch. `torch-sys`
//! (`links = "tch"`) exports the directory to its direct dependents. Without the feature there
//! is no libtorch and nothing to pass on.

fn main() {
    println!("cargo::rerun-if-env-changed=DEP_TCH_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_TCH_LIBTORCH_LIB") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
        println!("cargo::metadata=LIBTORCH_LIB={dir}");
    }
}
