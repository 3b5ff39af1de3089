//! Bakes libtorch's library directory into this program as an rpath, so it runs without
//! LD_LIBRARY_PATH. The `human2nav` crate passes the directory on to its direct dependents
//! (`DEP_HUMAN2NAV_LIBTORCH_LIB`).

fn main() {
    println!("cargo::rerun-if-env-changed=DEP_HUMAN2NAV_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_HUMAN2NAV_LIBTORCH_LIB") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
