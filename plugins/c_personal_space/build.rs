//! Compiles the C plugin and makes its two symbols visible in the shared library.
//!
//! rustc links a `cdylib` with a version script that hides every symbol it did not export
//! itself, which would hide the C entry point. On ELF targets a second version script (GNU ld
//! merges them) re-exports the two C symbols; `--undefined` pulls their object out of the static
//! archive. macOS and Windows use their linkers' equivalents.

fn main() {
    let manifest = std::path::PathBuf::from(
        std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".to_owned()),
    );
    let include = manifest.join("../../sdk/plugin/include");
    println!("cargo:rerun-if-changed=c/personal_space.c");
    println!("cargo:rerun-if-changed=c/exports.map");
    println!(
        "cargo:rerun-if-changed={}",
        include.join("human2nav_plugin.h").display()
    );
    cc::Build::new()
        .file(manifest.join("c/personal_space.c"))
        .include(&include)
        .std("c11")
        .warnings(true)
        .extra_warnings(true)
        .warnings_into_errors(true)
        .compile("h2n_c_personal_space");

    let symbols = ["human2nav_plugin_entry", "h2n_c_layout"];
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    match os.as_str() {
        "macos" | "ios" => {
            for s in symbols {
                println!("cargo:rustc-cdylib-link-arg=-Wl,-u,_{s}");
                println!("cargo:rustc-cdylib-link-arg=-Wl,-exported_symbol,_{s}");
            }
        }
        "windows" => {
            for s in symbols {
                println!("cargo:rustc-cdylib-link-arg=/EXPORT:{s}");
            }
        }
        _ => {
            for s in symbols {
                println!("cargo:rustc-cdylib-link-arg=-Wl,--undefined={s}");
            }
            println!(
                "cargo:rustc-cdylib-link-arg=-Wl,--version-script={}",
                manifest.join("c/exports.map").display()
            );
            println!("cargo:rustc-link-lib=m");
            println!("cargo:rustc-link-lib=pthread");
        }
    }
}
