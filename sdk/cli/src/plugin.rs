//! `human2nav plugin ...`

use anyhow::{Context, bail};
use clap::Subcommand;
use human2nav_plugin::inspect_library;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};
use std::time::{Duration, Instant};

#[derive(Debug, Subcommand)]
pub enum PluginCommand {
    /// Load a plugin library and print its name, version, ABI version, what it provides and
    /// everything the host checked (file, tables, function slots, sizes; each factory's
    /// instance when it can be created without a config).
    ///
    /// The library is loaded and checked in a process of its own: a library that aborts,
    /// crashes or hangs while it is loaded or probed ends that process, and this command says
    /// so (with the checks done before it) instead of going down with it.
    ///
    /// The OS's library extension and the `lib` prefix may be omitted, and `{profile}` stands
    /// for this binary's cargo profile (`debug` or `release`), e.g.
    /// `human2nav plugin inspect 'target/{profile}/human2nav_personal_space'`.
    Inspect {
        /// Path of the library.
        library: PathBuf,
        /// Load the library in this process instead (faster; a crashing library then takes
        /// this command down with it).
        #[arg(long)]
        in_process: bool,
        /// How long the inspection may take before its process is killed (s).
        #[arg(long, default_value_t = 30.0)]
        timeout_s: f64,
    },
}

pub fn run(cmd: PluginCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        PluginCommand::Inspect {
            library,
            in_process,
            timeout_s,
        } => {
            if in_process {
                return inspect_here(&library);
            }
            if !(timeout_s.is_finite() && timeout_s > 0.0 && timeout_s <= 3600.0) {
                bail!("--timeout-s {timeout_s}: must be more than 0 and at most 3600 s");
            }
            inspect_isolated(&library, Duration::from_secs_f64(timeout_s))
        }
    }
}

/// Loads the library with every check and reports them (`human2nav_plugin::inspect`).
fn inspect_here(library: &Path) -> anyhow::Result<ExitCode> {
    let report = inspect_library(library);
    print!("{}", report.render());
    match report.error {
        Some(e) => Err(e.into()),
        None => Ok(ExitCode::SUCCESS),
    }
}

/// Runs `plugin inspect --in-process` in a child process of this binary, passes on what it
/// prints and its exit status, and turns a death by signal or a timeout into an error.
fn inspect_isolated(library: &Path, timeout: Duration) -> anyhow::Result<ExitCode> {
    let exe = std::env::current_exe().context("finding this program to inspect in a child")?;
    let mut child = Command::new(exe)
        .args(["plugin", "inspect", "--in-process"])
        .arg(library)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .context("starting the inspecting process")?;
    let readers = [
        child.stdout.take().map(read_all),
        child.stderr.take().map(read_all),
    ];
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child
            .try_wait()
            .context("waiting for the inspecting process")?
        {
            break Some(status);
        }
        if start.elapsed() >= timeout {
            // Already gone if it ended in between: then there is nothing to kill.
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let [stdout, stderr] = readers.map(|r| {
        r.and_then(|h| h.join().ok())
            .map(|b| String::from_utf8_lossy(&b).into_owned())
            .unwrap_or_default()
    });
    print!("{stdout}");
    let Some(status) = status else {
        eprint!("{stderr}");
        bail!(
            "{}: the inspection did not finish within {:.1} s and its process was killed (a \
             library whose entry function or factory never returns would hang a host the same \
             way); --timeout-s sets the limit",
            library.display(),
            timeout.as_secs_f64()
        );
    };
    if let Some(code) = status.code() {
        // The child said everything, its error line included.
        eprint!("{stderr}");
        return Ok(ExitCode::from(u8::try_from(code).unwrap_or(1)));
    }
    eprint!("{stderr}");
    bail!(
        "{}: the library took the inspecting process down ({}) while it was loaded or probed; \
         loaded in a host, it would take that host down too",
        library.display(),
        died_of(status)
    )
}

fn read_all(mut r: impl Read + Send + 'static) -> std::thread::JoinHandle<Vec<u8>> {
    std::thread::spawn(move || {
        let mut buf = Vec::new();
        let _ = r.read_to_end(&mut buf);
        buf
    })
}

#[cfg(unix)]
fn died_of(status: std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match status.signal() {
        Some(sig) => human2nav_plugin::process::signal_name(sig),
        None => format!("{status}"),
    }
}

#[cfg(not(unix))]
fn died_of(status: std::process::ExitStatus) -> String {
    format!("{status}")
}
