//! One writer per output folder.
//!
//! A command that writes a folder of results (`bench --out`, `scaling`, `train`'s run
//! directory, SARL's) holds a [`DirLock`] on it for as long as it writes: the file
//! [`LOCK_FILE`] in the folder, created exclusively, holding the owner's process id and
//! command. A second run on the same folder gets an error naming the folder and the owner
//! instead of interleaving its files with the first run's.
//!
//! The lock is removed when the [`DirLock`] is dropped. A lock left behind by a run that was
//! killed is taken over, with a note on stderr, when its process no longer exists (checked in
//! `/proc` on Linux; elsewhere a left-over lock has to be removed by hand, and the error says
//! so). A process id reused by an unrelated process keeps the folder locked until that process
//! ends: the error names it.

use std::fs::{self, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Name of the lock file inside a locked folder.
pub const LOCK_FILE: &str = ".human2nav.lock";

/// An exclusive claim on an output folder (module docs). Dropping it releases the folder.
#[derive(Debug)]
pub struct DirLock {
    path: PathBuf,
}

impl DirLock {
    /// Creates `dir` if needed and claims it for this process; `what` says what writes it
    /// (recorded in the lock, shown to a second run).
    pub fn acquire(dir: &Path, what: &str) -> io::Result<Self> {
        fs::create_dir_all(dir)?;
        let path = dir.join(LOCK_FILE);
        // Two attempts: the second after taking over a lock whose owner is gone.
        for _ in 0..2 {
            match OpenOptions::new().write(true).create_new(true).open(&path) {
                Ok(mut f) => {
                    writeln!(f, "pid = {}\nwriter = {what:?}", std::process::id())?;
                    return Ok(Self { path });
                }
                Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {
                    let owner = fs::read_to_string(&path).unwrap_or_default();
                    let pid = owner_pid(&owner);
                    match pid.map(process_alive) {
                        Some(Some(false)) => {
                            eprintln!(
                                "note: {} was left behind by process {} which is gone; taking \
                                 over",
                                path.display(),
                                pid.unwrap_or_default()
                            );
                            fs::remove_file(&path)?;
                        }
                        _ => return Err(busy(dir, &path, &owner, pid)),
                    }
                }
                Err(e) => return Err(e),
            }
        }
        Err(busy(dir, &path, "", None))
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for DirLock {
    fn drop(&mut self) {
        let _ = fs::remove_file(&self.path);
    }
}

fn owner_pid(owner: &str) -> Option<u32> {
    owner
        .lines()
        .find_map(|l| l.strip_prefix("pid = "))
        .and_then(|p| p.trim().parse().ok())
}

/// `Some(alive)` where it can be told, `None` where it cannot.
fn process_alive(pid: u32) -> Option<bool> {
    if cfg!(target_os = "linux") {
        Some(Path::new("/proc").join(pid.to_string()).exists())
    } else {
        None
    }
}

fn busy(dir: &Path, path: &Path, owner: &str, pid: Option<u32>) -> io::Error {
    let writer = owner
        .lines()
        .find_map(|l| l.strip_prefix("writer = "))
        .map(|w| format!(" ({})", w.trim_matches('"')))
        .unwrap_or_default();
    let who = match pid {
        Some(pid) => format!("process {pid}{writer}"),
        None => "another run".to_string(),
    };
    io::Error::new(
        io::ErrorKind::WouldBlock,
        format!(
            "{} is being written by {who}: wait for it to finish or choose another output \
             folder (if no run is writing there, remove {})",
            dir.display(),
            path.display()
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("h2n-lock-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_second_writer_is_refused_until_the_first_is_done() {
        let dir = temp_dir("second");
        let first = DirLock::acquire(&dir, "bench").unwrap();
        let err = DirLock::acquire(&dir, "bench").unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains(&dir.display().to_string()), "{msg}");
        assert!(
            msg.contains(&format!("process {}", std::process::id())),
            "{msg}"
        );
        assert!(msg.contains("(bench)"), "{msg}");
        drop(first);
        assert!(!dir.join(LOCK_FILE).exists());
        let again = DirLock::acquire(&dir, "bench").unwrap();
        assert!(again.path().is_file());
        drop(again);
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_lock_whose_owner_is_gone_is_taken_over() {
        if !cfg!(target_os = "linux") {
            eprintln!("skipped: stale locks are detected through /proc on Linux only");
            return;
        }
        let dir = temp_dir("stale");
        fs::create_dir_all(&dir).unwrap();
        // Process ids are below 2^22 on Linux: this one cannot exist.
        fs::write(dir.join(LOCK_FILE), "pid = 4294967\nwriter = \"bench\"\n").unwrap();
        let lock = DirLock::acquire(&dir, "train").unwrap();
        let text = fs::read_to_string(lock.path()).unwrap();
        assert!(
            text.contains(&format!("pid = {}", std::process::id())),
            "{text}"
        );
        drop(lock);
        // A lock without a readable owner is never taken over.
        fs::write(dir.join(LOCK_FILE), "garbage").unwrap();
        let err = DirLock::acquire(&dir, "train").unwrap_err();
        assert!(err.to_string().contains("another run"), "{err}");
        let _ = fs::remove_dir_all(&dir);
    }
}
