//! A plugin written in C: `c/personal_space.c` is compiled by `build.rs` (with the `cc` crate)
//! against `sdk/plugin/include/human2nav_plugin.h` and linked into this `cdylib`. The C file
//! defines the entry symbol `human2nav_plugin_entry` itself; this Rust crate contributes no code,
//! it only lets cargo build and place the library next to the other plugins.
//!
//! It provides the constraint `personal_space_c`, the same cost and gradient as the Rust plugin
//! `personal_space` (see `plugins/personal_space`), and exports `h2n_c_layout`, the sizes and
//! field offsets of every ABI struct as the C compiler sees them, which the integration tests
//! compare with the Rust definitions.
