//! Bakes libtorch's library directory into the extension module as an rpath, so that
//! `import human2nav` finds libtorch without LD_LIBRARY_PATH: the libtorch of the torch 2.13
//! installation the module was built against, the same files `import torch` loads. `torch-sys`
//! (links = "tch") exports the directory to packages that depend on it directly.

fn main() {
    println!("cargo:rerun-if-env-changed=DEP_TCH_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_TCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
