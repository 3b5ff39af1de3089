//! Hands libtorch's library directory on to the programs that depend on this crate.
//!
//! `human2nav-flow` (with its `torch` feature, `links = "human2nav-flow"`) tells its direct
//! dependents where libtorch lives (`DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB`). This crate re-exports it as its own link metadata, which cargo
//! passes to the build scripts of direct dependents as `DEP_HUMAN2NAV_LIBTORCH_LIB`, so a
//! program that depends on `human2nav` alone can bake it in as an rpath:
//!
//! ```no_run
//! // build.rs of a program
//! if let Ok(dir) = std::env::var("DEP_HUMAN2NAV_LIBTORCH_LIB") {
//!     println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
//! }
//! ```
//!
//! This crate's own tests get the rpath too. Without the `flow` feature there is no libtorch
//! and nothing to pass on.

fn main() {
    println!("cargo::rerun-if-env-changed=DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
        println!("cargo::metadata=LIBTORCH_LIB={dir}");
    }
}
