//! With libtorch (the `torch` feature): bakes its library directory into the extension module
//! as an rpath, so that `import human2nav` finds libtorch without LD_LIBRARY_PATH: the
//! libtorch of the torch 2.13 installation the module was built against, the same files
//! `import torch` loads. `human2nav-flow` passes the directory on to the packages that depend
//! on it. Without the feature the module links no libtorch.

fn main() {
    println!("cargo::rerun-if-env-changed=DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_HUMAN2NAV_FLOW_LIBTORCH_LIB") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
