//! Bakes libtorch's library directory into this package's binaries and tests as an rpath, so
//! they run without LD_LIBRARY_PATH. `torch-sys` (links = "tch") exports the directory to
//! packages that depend on it directly.

fn main() {
    println!("cargo:rerun-if-env-changed=DEP_TCH_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_TCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
