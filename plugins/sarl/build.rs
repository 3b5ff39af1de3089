//! Bakes libtorch's library directory into this package's binaries, tests and the plugin
//! `cdylib` as an rpath, so the host can load the plugin without LD_LIBRARY_PATH. `torch-sys`
//! (links = "tch") exports the directory to packages that depend on it directly.
//!
//! The crate also links `human2nav-orca` as an rlib (ORCA humans in training, ORCA's plan
//! conversion), whose own `export_plugin!` defines the same entry symbol as ours. Every target
//! of this package is linked with `--allow-multiple-definition`: the linker keeps the first
//! definition, and a crate's own objects always precede its dependencies' on rustc's link line,
//! so the cdylib exports SARL's entry table (the plugin tests check it lists the `sarl`
//! factory).

fn main() {
    println!("cargo:rerun-if-env-changed=DEP_TCH_LIBTORCH_LIB");
    if let Ok(dir) = std::env::var("DEP_TCH_LIBTORCH_LIB") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
    }
    println!("cargo:rustc-link-arg=-Wl,--allow-multiple-definition");
}
