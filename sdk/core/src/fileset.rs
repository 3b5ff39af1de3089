//! Folders of files committed as one set: a checkpoint that is either whole or detected as not.
//!
//! A set is a folder holding a fixed list of files and [`MANIFEST_FILE`], which records the size
//! and FNV-1a checksum ([`crate::input::fnv1a64`]) of each and is written after all of them.
//! [`commit`] writes a set to `<dir>.partial/`, adds the manifest, then replaces `dir` by two
//! renames (the previous set waits as `<dir>.old/` between them), so a crash at any point leaves
//! a complete set behind. [`find_complete`] picks the set to resume from, or says what is wrong.
//!
//! The manifest is TOML: `step = N` (how far the run that wrote it got) and one
//! `[files."<name>"]` table per file with `bytes` and `fnv64` (16 hex digits).

use crate::input::{MAX_CONFIG_BYTES, fnv1a64, read_user_bytes, read_user_file};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The manifest of a set, written after every other file.
pub const MANIFEST_FILE: &str = "manifest.toml";

/// Largest file a manifest checks (64 GiB: far above any checkpoint; the cap only keeps a
/// device or a runaway file from being read without end).
const MAX_SET_FILE_BYTES: u64 = 64 << 30;

/// Why a set could not be written, read or trusted. Each names the folder or file.
#[derive(Debug, thiserror::Error)]
pub enum SetError {
    /// A file of the set could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The manifest does not parse.
    #[error("{path}: not a set manifest: {message}")]
    Manifest {
        /// The manifest file.
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// The set in `path` is not complete: a file is missing or differs from the manifest.
    #[error("{path}: {reason}; the set is incomplete")]
    Incomplete {
        /// The set's folder.
        path: PathBuf,
        /// Which file is missing or altered, and how.
        reason: String,
    },
}

impl SetError {
    fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

#[derive(Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    bytes: u64,
    fnv64: String,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    step: u64,
    files: BTreeMap<String, Entry>,
}

/// `<dir>.<suffix>` beside `dir`.
pub fn sibling(dir: &Path, suffix: &str) -> PathBuf {
    let mut name = dir
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(format!(".{suffix}"));
    dir.with_file_name(name)
}

fn entry(path: &Path) -> Result<Entry, SetError> {
    let bytes =
        read_user_bytes(path, "set file", MAX_SET_FILE_BYTES).map_err(|e| SetError::io(path, e))?;
    Ok(Entry {
        bytes: bytes.len() as u64,
        fnv64: format!("{:016x}", fnv1a64(&bytes)),
    })
}

/// Writes the manifest of the files `files` in `dir`, recording `step`.
pub fn write_manifest(dir: &Path, files: &[&str], step: u64) -> Result<(), SetError> {
    let mut entries = BTreeMap::new();
    for name in files {
        entries.insert((*name).to_string(), entry(&dir.join(name))?);
    }
    let path = dir.join(MANIFEST_FILE);
    let text = toml::to_string_pretty(&Manifest {
        step,
        files: entries,
    })
    .map_err(|e| SetError::Manifest {
        path: path.clone(),
        message: e.to_string(),
    })?;
    std::fs::write(&path, text).map_err(|e| SetError::io(&path, e))
}

/// Why the set in `dir` (which has a manifest) is not complete: `None` when every one of
/// `files` is listed, present and of the recorded size and checksum.
pub fn incomplete(dir: &Path, files: &[&str]) -> Result<Option<String>, SetError> {
    let path = dir.join(MANIFEST_FILE);
    let text = read_user_file(&path, "set manifest", MAX_CONFIG_BYTES)
        .map_err(|e| SetError::io(&path, e))?;
    let manifest: Manifest = toml::from_str(&text).map_err(|e| SetError::Manifest {
        path: path.clone(),
        message: e.to_string(),
    })?;
    for name in files {
        let Some(want) = manifest.files.get(*name) else {
            return Ok(Some(format!("{MANIFEST_FILE} does not list {name}")));
        };
        let file = dir.join(name);
        if !file.is_file() {
            return Ok(Some(format!("{name} is missing")));
        }
        let have = entry(&file)?;
        if have != *want {
            return Ok(Some(format!(
                "{name} has {} bytes (checksum {}), the manifest says {} bytes ({})",
                have.bytes, have.fnv64, want.bytes, want.fnv64
            )));
        }
    }
    Ok(None)
}

/// Writes a set to `dir`: `write` fills the folder it is given (`<dir>.partial/`, created
/// empty) with `files`, then the manifest is added and the folder replaces `dir` (module docs).
/// `step` is recorded in the manifest.
pub fn commit<E: From<SetError>>(
    dir: &Path,
    files: &[&str],
    step: u64,
    write: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), E> {
    let partial = sibling(dir, "partial");
    let old = sibling(dir, "old");
    if partial.exists() {
        std::fs::remove_dir_all(&partial).map_err(|e| SetError::io(&partial, e))?;
    }
    std::fs::create_dir_all(&partial).map_err(|e| SetError::io(&partial, e))?;
    write(&partial)?;
    write_manifest(&partial, files, step)?;
    if dir.exists() {
        if old.exists() {
            std::fs::remove_dir_all(&old).map_err(|e| SetError::io(&old, e))?;
        }
        std::fs::rename(dir, &old).map_err(|e| SetError::io(dir, e))?;
    }
    std::fs::rename(&partial, dir).map_err(|e| SetError::io(dir, e))?;
    if old.exists() {
        std::fs::remove_dir_all(&old).map_err(|e| SetError::io(&old, e))?;
    }
    Ok(())
}

/// The complete set of `files` to resume from at `dir`, if any:
///
/// * `dir` with a manifest that matches its files: `dir`;
/// * otherwise `<dir>.old` with a matching manifest (a commit was interrupted between its two
///   renames): that folder;
/// * no `dir` (or an empty one): `None`, nothing to resume;
/// * `dir` that is a file, a link to nothing or a loop of links: [`SetError::Io`] naming it
///   (never "nothing to resume", which would restart a run from step 0);
/// * anything else (a file missing, a size or checksum that disagrees, files without a
///   manifest, even all of them: nothing says they belong together): [`SetError::Incomplete`]
///   naming the folder and the file.
pub fn find_complete(dir: &Path, files: &[&str]) -> Result<Option<PathBuf>, SetError> {
    let complaint = |reason: String| SetError::Incomplete {
        path: dir.to_path_buf(),
        reason,
    };
    let not_a_folder = |why: &str| {
        SetError::io(
            dir,
            std::io::Error::new(std::io::ErrorKind::InvalidInput, why.to_string()),
        )
    };
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => return Err(not_a_folder("not a folder (a set is a folder of files)")),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            if std::fs::symlink_metadata(dir).is_ok() {
                return Err(not_a_folder(
                    "a symbolic link to a path that does not exist",
                ));
            }
        }
        Err(e) => return Err(SetError::io(dir, e)),
    }
    let problem = if dir.join(MANIFEST_FILE).is_file() {
        match incomplete(dir, files)? {
            None => return Ok(Some(dir.to_path_buf())),
            Some(why) => Some(why),
        }
    } else {
        None
    };
    let old = sibling(dir, "old");
    if old.join(MANIFEST_FILE).is_file() && incomplete(&old, files)?.is_none() {
        return Ok(Some(old));
    }
    if let Some(why) = problem {
        return Err(complaint(why));
    }
    let present: Vec<&str> = files
        .iter()
        .copied()
        .filter(|n| dir.join(n).exists())
        .collect();
    if present.is_empty() {
        let empty = match std::fs::read_dir(dir) {
            Ok(mut d) => d.next().is_none(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => true,
            Err(e) => return Err(SetError::io(dir, e)),
        };
        return if empty {
            Ok(None)
        } else {
            Err(complaint(format!(
                "none of {} in a non-empty folder",
                files.join(", ")
            )))
        };
    }
    if present.len() == files.len() {
        return Err(complaint(format!(
            "{MANIFEST_FILE} is missing, so nothing says {} belong together (a save cut \
             short, or files copied in by hand)",
            files.join(", ")
        )));
    }
    let missing: Vec<&str> = files
        .iter()
        .copied()
        .filter(|n| !present.contains(n))
        .collect();
    Err(complaint(format!(
        "{} missing ({MANIFEST_FILE} too)",
        if missing.len() == 1 {
            format!("{} is", missing[0])
        } else {
            format!("{} are", missing.join(", "))
        }
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILES: [&str; 2] = ["a.bin", "b.toml"];

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("h2n-fileset-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn write_both(dir: &Path, tag: &str) -> Result<(), SetError> {
        for f in FILES {
            std::fs::write(dir.join(f), format!("{f} {tag}")).map_err(|e| SetError::io(dir, e))?;
        }
        Ok(())
    }

    #[test]
    fn a_committed_set_is_found_and_replaced_whole() {
        let root = scratch("commit");
        let ck = root.join("checkpoint");
        assert!(find_complete(&ck, &FILES).unwrap().is_none());
        commit(&ck, &FILES, 3, |d| write_both(d, "one")).unwrap();
        assert_eq!(find_complete(&ck, &FILES).unwrap(), Some(ck.clone()));
        commit(&ck, &FILES, 7, |d| write_both(d, "two")).unwrap();
        assert_eq!(
            std::fs::read_to_string(ck.join("a.bin")).unwrap(),
            "a.bin two"
        );
        let manifest = std::fs::read_to_string(ck.join(MANIFEST_FILE)).unwrap();
        assert!(manifest.contains("step = 7"), "{manifest}");
        assert!(!sibling(&ck, "partial").exists() && !sibling(&ck, "old").exists());
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn a_failed_write_leaves_the_previous_set() {
        let root = scratch("failed");
        let ck = root.join("checkpoint");
        commit(&ck, &FILES, 1, |d| write_both(d, "one")).unwrap();
        let err = commit(&ck, &FILES, 2, |d| {
            std::fs::write(d.join("a.bin"), "half").map_err(|e| SetError::io(d, e))?;
            Err(SetError::io(d, std::io::Error::other("disk full")))
        })
        .unwrap_err();
        assert!(err.to_string().contains("disk full"), "{err}");
        assert_eq!(find_complete(&ck, &FILES).unwrap(), Some(ck.clone()));
        assert_eq!(
            std::fs::read_to_string(ck.join("a.bin")).unwrap(),
            "a.bin one"
        );
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn partial_sets_are_named_or_the_old_set_is_used() {
        let root = scratch("partial");
        let ck = root.join("checkpoint");
        commit(&ck, &FILES, 1, |d| write_both(d, "one")).unwrap();
        // An altered file: its size and checksum disagree with the manifest.
        std::fs::write(ck.join("b.toml"), "changed!").unwrap();
        let err = find_complete(&ck, &FILES).unwrap_err().to_string();
        assert!(
            err.contains("b.toml has 8 bytes") && err.contains("incomplete"),
            "{err}"
        );
        // A missing file.
        std::fs::remove_file(ck.join("b.toml")).unwrap();
        let err = find_complete(&ck, &FILES).unwrap_err().to_string();
        assert!(err.contains("b.toml is missing"), "{err}");
        // Killed between the renames: only `.old` is complete, and it is used.
        let old = sibling(&ck, "old");
        std::fs::rename(&ck, &old).unwrap();
        std::fs::create_dir_all(&ck).unwrap();
        write_both(&ck, "two").unwrap();
        std::fs::remove_file(ck.join("a.bin")).unwrap();
        write_both(&old, "one").unwrap();
        write_manifest(&old, &FILES, 1).unwrap();
        assert_eq!(find_complete(&ck, &FILES).unwrap(), Some(old.clone()));
        // Files without a manifest, one missing: named, never taken as "nothing to resume".
        std::fs::remove_dir_all(&old).unwrap();
        let err = find_complete(&ck, &FILES).unwrap_err().to_string();
        assert!(err.contains("a.bin is missing"), "{err}");
        // Every file without a manifest: nothing checks them, so they are not resumed from.
        write_both(&ck, "legacy").unwrap();
        let err = find_complete(&ck, &FILES).unwrap_err().to_string();
        assert!(err.contains("manifest.toml is missing"), "{err}");
        // A stray file only.
        let other = root.join("stray");
        std::fs::create_dir_all(&other).unwrap();
        std::fs::write(other.join("notes.txt"), "x").unwrap();
        let err = find_complete(&other, &FILES).unwrap_err().to_string();
        assert!(err.contains("none of a.bin, b.toml"), "{err}");
        // A manifest that does not parse.
        std::fs::write(ck.join(MANIFEST_FILE), "step = \"x\"").unwrap();
        let err = find_complete(&ck, &FILES).unwrap_err().to_string();
        assert!(err.contains("not a set manifest"), "{err}");
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn a_path_that_is_no_folder_is_an_error_not_a_fresh_start() {
        let root = scratch("nofolder");
        let file = root.join("checkpoint");
        std::fs::write(&file, "x").unwrap();
        let err = find_complete(&file, &FILES).unwrap_err().to_string();
        assert!(
            err.contains("checkpoint") && err.contains("not a folder"),
            "{err}"
        );
        #[cfg(unix)]
        {
            let a = root.join("a");
            let b = root.join("b");
            std::os::unix::fs::symlink(&b, &a).unwrap();
            std::os::unix::fs::symlink(&a, &b).unwrap();
            let err = find_complete(&a, &FILES).unwrap_err().to_string();
            assert!(err.contains(&a.display().to_string()), "{err}");
            let dangling = root.join("dangling");
            std::os::unix::fs::symlink(root.join("nowhere"), &dangling).unwrap();
            let err = find_complete(&dangling, &FILES).unwrap_err().to_string();
            assert!(err.contains("does not exist"), "{err}");
        }
        // A missing folder is still nothing to resume.
        assert!(find_complete(&root.join("none"), &FILES).unwrap().is_none());
        let _ = std::fs::remove_dir_all(&root);
    }
}
