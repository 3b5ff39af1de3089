//! The targets, one per kind of input.

pub mod capi;
pub mod config;
pub mod data;
#[cfg(feature = "model")]
pub mod model;
pub mod observe;
pub mod plugin;

use crate::Target;

/// Every target, in the order the runs report them.
pub fn all() -> Vec<Target> {
    let mut t = config::targets();
    #[cfg(feature = "model")]
    t.extend(model::targets());
    t.extend(data::targets());
    t.extend(plugin::targets());
    t.extend(observe::targets());
    t.extend(capi::targets());
    t
}

/// The target called `name`.
pub fn by_name(name: &str) -> Option<Target> {
    all().into_iter().find(|t| t.name == name)
}

/// The input as text the way a reader that takes `&str` would get it from a file.
pub(crate) fn lossy(input: &[u8]) -> std::borrow::Cow<'_, str> {
    String::from_utf8_lossy(input)
}

/// Shipped files as seeds.
pub(crate) fn seeds_of(files: &[&str]) -> Vec<Vec<u8>> {
    files.iter().map(|s| s.as_bytes().to_vec()).collect()
}
