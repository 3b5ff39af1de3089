//! Reading files named by the user, with a size cap.
//!
//! Every file the SDK reads from a path a user gave (robot profiles, URDFs, configuration
//! TOMLs, episode files, datasets, tuple caches) goes through [`read_user_file`] or
//! [`read_user_bytes`]:
//!
//! * the path must name a **regular file** (symbolic links are followed): a directory, a
//!   device (`/dev/zero` would never end), a FIFO (opening one blocks until a writer appears)
//!   or a socket is refused before it is opened;
//! * at most `max_bytes` are read (through [`Read::take`], so a file that grows while it is read,
//!   or a `/proc` file that reports size 0, cannot exhaust memory either); a larger file is an
//!   error naming the cap.
//!
//! The error is an [`io::Error`] whose message names the kind of file, what was wrong and the
//! cap (`episode file: expected a regular file, found a FIFO (named pipe)`, `URDF: the file
//! (20000000 bytes) is larger than the limit of 16 MiB`); the callers' error types add the path,
//! as they do for any other read error.
//!
//! The caps below are generous: each is at least 30 times the largest file of its kind the
//! project ships or reads (ARCHITECTURE.md, "Input limits").

use std::fmt::Write as _;
use std::io::{self, Read};
use std::path::Path;

/// Cap of a `robot.toml` (1 MiB; the shipped ones are under 3 KB).
pub const MAX_PROFILE_BYTES: u64 = 1 << 20;
/// Cap of a URDF (16 MiB; the shipped ones are under 11 KB, large robot descriptions a few MB).
pub const MAX_URDF_BYTES: u64 = 16 << 20;
/// Cap of a configuration TOML (`data.toml`, `bench*.toml`, `planner.toml`, ...; 4 MiB, the
/// shipped ones are under 11 KB).
pub const MAX_CONFIG_BYTES: u64 = 4 << 20;

/// Longest name of a robot, a benchmark method or a suite (characters).
pub const MAX_NAME_CHARS: usize = 64;

/// Checks a name the SDK writes into file names, `results.csv`, reports and the terminal (a
/// robot's, a benchmark method's or suite's): not blank, at most [`MAX_NAME_CHARS`]
/// characters, no control characters, no `/` or `\\`, and not `.` or `..`, so that it can
/// neither leave an output folder nor rewrite a terminal line. The error says what is wrong
/// (the caller adds the file and field).
pub fn check_name(name: &str) -> Result<(), String> {
    let shown = name.escape_debug();
    if name.trim().is_empty() {
        return Err("must not be blank".into());
    }
    if name.chars().count() > MAX_NAME_CHARS {
        return Err(format!(
            "`{shown}` is longer than {MAX_NAME_CHARS} characters"
        ));
    }
    if name.chars().any(char::is_control) {
        return Err(format!("`{shown}` holds a control character"));
    }
    if name.contains(['/', '\\']) || name == "." || name == ".." {
        return Err(format!(
            "`{shown}` is used in file names: no `/`, `\\`, `.` or `..`"
        ));
    }
    Ok(())
}

/// FNV-1a, 64 bit, of `bytes`: the checksum model cards and checkpoint manifests record of
/// their files. It detects a truncated, swapped or altered file, not deliberate tampering.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Reads the whole of a regular file of at most `max_bytes` bytes; `what` names the kind of file
/// in the error ("robot profile", "URDF", ...). See the module docs.
pub fn read_user_bytes(path: &Path, what: &str, max_bytes: u64) -> io::Result<Vec<u8>> {
    // `metadata` follows symbolic links and never opens the file: opening a FIFO would block.
    let meta = std::fs::metadata(path)?;
    check_regular(&meta, what)?;
    if meta.len() > max_bytes {
        return Err(too_large(what, max_bytes, Some(meta.len())));
    }
    let file = std::fs::File::open(path)?;
    // The path may have been replaced between the two calls: check what was opened.
    check_regular(&file.metadata()?, what)?;
    let capacity = usize::try_from(meta.len()).unwrap_or(0);
    let mut bytes = Vec::with_capacity(capacity);
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_large(what, max_bytes, None));
    }
    Ok(bytes)
}

/// [`read_user_bytes`] for UTF-8 text.
pub fn read_user_file(path: &Path, what: &str, max_bytes: u64) -> io::Result<String> {
    let bytes = read_user_bytes(path, what, max_bytes)?;
    String::from_utf8(bytes).map_err(|e| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "{what}: not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// `n` bytes as a short human-readable size (`1 MiB`, `256 MiB`, `3 GiB`, `1500 bytes`).
pub fn format_bytes(n: u64) -> String {
    let mut s = String::new();
    for (unit, name) in [(1u64 << 30, "GiB"), (1 << 20, "MiB"), (1 << 10, "KiB")] {
        if n >= unit && n % unit == 0 {
            let _ = write!(s, "{} {name}", n / unit);
            return s;
        }
    }
    format!("{n} bytes")
}

fn too_large(what: &str, max_bytes: u64, len: Option<u64>) -> io::Error {
    let size = len.map_or_else(String::new, |n| format!(" ({n} bytes)"));
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!(
            "{what}: the file{size} is larger than the limit of {}",
            format_bytes(max_bytes)
        ),
    )
}

fn check_regular(meta: &std::fs::Metadata, what: &str) -> io::Result<()> {
    if meta.is_file() {
        return Ok(());
    }
    Err(io::Error::new(
        io::ErrorKind::InvalidInput,
        format!(
            "{what}: expected a regular file, found {}",
            file_kind(&meta.file_type())
        ),
    ))
}

/// What a non-regular file is, for the error.
fn file_kind(t: &std::fs::FileType) -> &'static str {
    if t.is_dir() {
        return "a directory";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    "something other than a regular file"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_could_leave_a_folder_or_rewrite_a_terminal_are_refused() {
        for good in ["diablo", "go2", "human2nav-alg1+qp", "Über robot 2", "a.b"] {
            assert_eq!(check_name(good), Ok(()), "{good}");
        }
        for (bad, why) in [
            ("", "blank"),
            ("  ", "blank"),
            ("../x", "file names"),
            ("a/b", "file names"),
            ("a\\b", "file names"),
            ("..", "file names"),
            (".", "file names"),
            ("or\u{1b}[2Kca", "control character"),
            ("line\nbreak", "control character"),
        ] {
            let e = check_name(bad).expect_err(bad);
            assert!(e.contains(why), "{bad:?}: {e}");
        }
        assert!(check_name(&"x".repeat(MAX_NAME_CHARS)).is_ok());
        assert!(check_name(&"x".repeat(MAX_NAME_CHARS + 1)).is_err());
    }
    use std::path::PathBuf;

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("h2n-input-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    #[test]
    fn reads_a_regular_file_up_to_the_cap() {
        let p = temp("ok.txt");
        std::fs::write(&p, "0123456789").unwrap();
        assert_eq!(read_user_file(&p, "test file", 10).unwrap(), "0123456789");
        let e = read_user_file(&p, "test file", 9).unwrap_err().to_string();
        assert!(
            e.contains("test file: the file (10 bytes) is larger than the limit of 9 bytes"),
            "{e}"
        );
        let _ = std::fs::remove_file(&p);
    }

    #[test]
    fn refuses_directories_and_non_utf8() {
        let dir = temp("d");
        std::fs::create_dir_all(&dir).unwrap();
        let e = read_user_file(&dir, "robot profile", 100).unwrap_err();
        assert!(
            e.to_string()
                .contains("robot profile: expected a regular file, found a directory"),
            "{e}"
        );
        let p = temp("bin");
        std::fs::write(&p, [0xffu8, 0xfe]).unwrap();
        let e = read_user_file(&p, "URDF", 100).unwrap_err();
        assert!(e.to_string().contains("URDF: not UTF-8 text"), "{e}");
    }

    #[cfg(unix)]
    #[test]
    fn refuses_devices_without_reading_them() {
        let zero = Path::new("/dev/zero");
        if !zero.exists() {
            eprintln!("skipping: no /dev/zero");
            return;
        }
        let e = read_user_bytes(zero, "URDF", MAX_URDF_BYTES).unwrap_err();
        assert!(e.to_string().contains("a character device"), "{e}");
    }

    #[cfg(unix)]
    #[test]
    fn refuses_a_fifo_without_blocking() {
        let p = temp("fifo");
        let _ = std::fs::remove_file(&p);
        match std::process::Command::new("mkfifo").arg(&p).status() {
            Ok(s) if s.success() => {}
            _ => {
                eprintln!("skipping: mkfifo is not available");
                return;
            }
        }
        let e = read_user_file(&p, "robot profile", MAX_PROFILE_BYTES).unwrap_err();
        assert!(e.to_string().contains("a FIFO"), "{e}");
        let _ = std::fs::remove_file(&p);
    }

    #[test]
    fn sizes_read_well() {
        assert_eq!(format_bytes(MAX_PROFILE_BYTES), "1 MiB");
        assert_eq!(format_bytes(4 << 30), "4 GiB");
        assert_eq!(format_bytes(1500), "1500 bytes");
    }
}
