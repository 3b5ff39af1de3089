//! Where a plugin library named in a profile or config actually is.
//!
//! Rules (explicit; nothing is scanned):
//! 1. A relative path is relative to the directory of the file that names it
//!    ([`resolve_relative`]; robot profiles do this when they are loaded).
//! 2. The placeholder `{profile}` is replaced by the cargo profile directory plugins are taken
//!    from: `$HUMAN2NAV_PLUGIN_PROFILE` when set, else the host's own build (`debug` for a debug
//!    build, `release` otherwise). So `../../target/{profile}/human2nav_skid_steer` names the
//!    workspace-built plugin matching the binary that loads it. Any other `{name}` is an error.
//! 3. The OS's library extension may be omitted, and on Unix the `lib` prefix too: the host
//!    tries the path as written, then with the extension appended, then with `lib` prepended to
//!    the file name and the extension appended. The first regular file wins.

use crate::error::PluginError;
use std::path::{Path, PathBuf};

/// Environment variable overriding the `{profile}` placeholder.
pub const PROFILE_ENV: &str = "HUMAN2NAV_PLUGIN_PROFILE";

/// The value of `{profile}` for this process.
pub fn profile_dir_name() -> String {
    match std::env::var(PROFILE_ENV) {
        Ok(p) if !p.is_empty() => p,
        _ if cfg!(debug_assertions) => "debug".to_owned(),
        _ => "release".to_owned(),
    }
}

/// `path` relative to the directory of `declared_in` (unchanged when absolute).
pub fn resolve_relative(declared_in: &Path, path: &Path) -> PathBuf {
    if path.is_absolute() {
        return path.to_path_buf();
    }
    match declared_in.parent() {
        Some(dir) => dir.join(path),
        None => path.to_path_buf(),
    }
}

/// Replaces `{profile}` in every component of `path` (see the module docs).
pub fn expand_placeholders(path: &Path) -> Result<PathBuf, PluginError> {
    let text = path.to_string_lossy();
    if !text.contains('{') {
        return Ok(path.to_path_buf());
    }
    let mut out = String::with_capacity(text.len());
    let mut rest: &str = &text;
    while let Some(start) = rest.find('{') {
        out.push_str(&rest[..start]);
        let after = &rest[start + 1..];
        let Some(end) = after.find('}') else {
            out.push_str(&rest[start..]);
            rest = "";
            break;
        };
        let name = &after[..end];
        if name == "profile" {
            out.push_str(&profile_dir_name());
        } else if !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(PluginError::Placeholder {
                path: path.to_path_buf(),
                placeholder: name.to_owned(),
            });
        } else {
            out.push_str(&rest[start..start + end + 2]);
        }
        rest = &after[end + 1..];
    }
    out.push_str(rest);
    Ok(PathBuf::from(out))
}

/// The paths tried for `path` (after placeholder expansion), in order.
pub fn candidates(path: &Path) -> Vec<PathBuf> {
    let mut out = vec![path.to_path_buf()];
    let suffix = std::env::consts::DLL_SUFFIX;
    let Some(file) = path.file_name().and_then(|f| f.to_str()) else {
        return out;
    };
    if !file.ends_with(suffix) {
        out.push(path.with_file_name(format!("{file}{suffix}")));
        let prefix = std::env::consts::DLL_PREFIX;
        if !prefix.is_empty() && !file.starts_with(prefix) {
            out.push(path.with_file_name(format!("{prefix}{file}{suffix}")));
        }
    }
    out
}

/// Finds the library file `path` names (see the module docs).
pub fn resolve_library_path(path: &Path) -> Result<PathBuf, PluginError> {
    let expanded = expand_placeholders(path)?;
    let tried = candidates(&expanded);
    match tried.iter().find(|p| p.is_file()) {
        Some(found) => Ok(found.clone()),
        None => Err(PluginError::NotFound {
            path: path.to_path_buf(),
            tried,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths_follow_the_declaring_file() {
        let p = resolve_relative(
            Path::new("robots/tracked/robot.toml"),
            Path::new("../x/lib"),
        );
        assert_eq!(p, PathBuf::from("robots/tracked/../x/lib"));
        let abs = resolve_relative(Path::new("robots/a.toml"), Path::new("/opt/p.so"));
        assert_eq!(abs, PathBuf::from("/opt/p.so"));
    }

    #[test]
    fn profile_placeholder_is_expanded() {
        let p = expand_placeholders(Path::new("target/{profile}/libx")).unwrap();
        assert_eq!(
            p,
            PathBuf::from(format!("target/{}/libx", profile_dir_name()))
        );
    }

    #[test]
    fn unknown_placeholders_are_errors_and_other_braces_are_kept() {
        let err = expand_placeholders(Path::new("target/{profle}/x")).unwrap_err();
        assert!(
            matches!(err, PluginError::Placeholder { ref placeholder, .. } if placeholder == "profle")
        );
        assert!(err.to_string().contains("{profle}"), "{err}");
        let kept = expand_placeholders(Path::new("a/{not a name}/b{")).unwrap();
        assert_eq!(kept, PathBuf::from("a/{not a name}/b{"));
    }

    #[test]
    fn extension_and_prefix_are_optional() {
        let c = candidates(Path::new("dir/foo"));
        let sfx = std::env::consts::DLL_SUFFIX;
        assert_eq!(c[0], PathBuf::from("dir/foo"));
        assert_eq!(c[1], PathBuf::from(format!("dir/foo{sfx}")));
        if cfg!(unix) {
            assert_eq!(c[2], PathBuf::from(format!("dir/libfoo{sfx}")));
        }
        let full = candidates(Path::new(&format!("dir/libfoo{sfx}")));
        assert_eq!(full.len(), 1);
    }

    #[test]
    fn missing_library_lists_what_was_tried() {
        let err = resolve_library_path(Path::new("/nonexistent/dir/nothing_here")).unwrap_err();
        let PluginError::NotFound { tried, .. } = &err else {
            panic!("{err}")
        };
        assert!(tried.len() >= 2);
        assert!(err.to_string().contains("/nonexistent/dir/nothing_here"));
    }
}
