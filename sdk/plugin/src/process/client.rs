//! The host side: finding and starting the helper, and the client that sends it calls, waits
//! at most the deadline and restarts it after a failure.

use super::*;

/// Where the helper executable is (see the module docs); `configured` is the host's setting.
pub fn find_helper(configured: Option<&Path>) -> Result<PathBuf, String> {
    if let Some(p) = configured {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os(HELPER_ENV).filter(|p| !p.is_empty()) {
        return Ok(PathBuf::from(p));
    }
    let file = format!("{HELPER_NAME}{}", std::env::consts::EXE_SUFFIX);
    let mut tried = Vec::new();
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    {
        for d in [Some(dir.as_path()), dir.parent()].into_iter().flatten() {
            let p = d.join(&file);
            if p.is_file() {
                return Ok(p);
            }
            tried.push(p.display().to_string());
        }
    }
    Err(format!(
        "cannot find the plugin host executable `{file}` (tried {}; build it with `cargo build \
         -p human2nav-plugin` or set {HELPER_ENV})",
        if tried.is_empty() {
            "nothing: the current executable's directory is unknown".to_owned()
        } else {
            tried.join(", ")
        }
    ))
}

/// A running helper.
struct Running {
    child: Child,
    stdin: ChildStdin,
    /// Messages read by the reader thread; it ends (dropping its sender) at end of input.
    answers: mpsc::Receiver<Vec<u8>>,
}

/// Why a call got no answer.
enum Lost {
    Closed,
    TimedOut,
}

/// One out-of-process instance: its helper (started again after a failure) and its settings.
pub(crate) struct ProcessClient {
    helper: PathBuf,
    init: Vec<u8>,
    /// `planner `straight``: how messages name the instance.
    what: String,
    deadline: Option<Duration>,
    running: Option<Running>,
    restarts: u32,
    /// [`MAX_RESTARTS`], or 0 for an embodiment (never restarted).
    max_restarts: u32,
    /// Set once the restarts are used up: every call fails with it.
    dead: Option<String>,
    enc: Enc,
}

impl std::fmt::Debug for ProcessClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ProcessClient")
            .field("what", &self.what)
            .field("restarts", &self.restarts)
            .field("dead", &self.dead)
            .finish()
    }
}

/// The name of a signal a process died of.
pub fn signal_name(sig: i32) -> String {
    let name = match sig {
        1 => "SIGHUP",
        2 => "SIGINT",
        3 => "SIGQUIT",
        4 => "SIGILL",
        5 => "SIGTRAP",
        6 => "SIGABRT",
        7 if cfg!(target_os = "linux") => "SIGBUS",
        8 => "SIGFPE",
        9 => "SIGKILL",
        10 if !cfg!(target_os = "linux") => "SIGBUS",
        11 => "SIGSEGV",
        13 => "SIGPIPE",
        15 => "SIGTERM",
        _ => return format!("signal {sig}"),
    };
    format!("signal {name}")
}

fn describe_exit(status: std::process::ExitStatus) -> String {
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        if let Some(sig) = status.signal() {
            return signal_name(sig);
        }
    }
    match status.code() {
        Some(c) => format!("exited with status {c}"),
        None => format!("ended ({status})"),
    }
}

impl ProcessClient {
    /// Starts the helper and creates the instance; returns the client and the instance name.
    pub(crate) fn start(
        helper: PathBuf,
        init: &InitRequest,
        deadline: Option<Duration>,
    ) -> Result<(Self, String), String> {
        let mut enc = Enc::default();
        init.encode(&mut enc);
        enc.finish();
        let mut client = Self {
            helper,
            init: enc.0.clone(),
            what: format!("{} `{}`", init.kind, init.factory),
            deadline,
            running: None,
            restarts: 0,
            max_restarts: if init.kind == PluginKind::Embodiment {
                0
            } else {
                MAX_RESTARTS
            },
            dead: None,
            enc,
        };
        let name = client.spawn()?;
        Ok((client, name))
    }

    /// Restarts used so far.
    pub(crate) fn restarts(&self) -> u32 {
        self.restarts
    }

    fn spawn(&mut self) -> Result<String, String> {
        let prefix = format!("plugin process for {}", self.what);
        let mut child = Command::new(&self.helper)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| format!("{prefix}: cannot start {}: {e}", self.helper.display()))?;
        let (Some(mut stdin), Some(mut stdout)) = (child.stdin.take(), child.stdout.take()) else {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("{prefix}: its pipes were not set up"));
        };
        let (tx, answers) = mpsc::channel();
        let spawned = std::thread::Builder::new()
            .name("h2n-proc-reader".into())
            .spawn(move || {
                let mut buf = Vec::new();
                while let Ok(true) = read_message(&mut stdout, &mut buf) {
                    if tx.send(std::mem::take(&mut buf)).is_err() {
                        break;
                    }
                }
            });
        if let Err(e) = spawned {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("{prefix}: cannot start its reader thread: {e}"));
        }
        let start = self
            .deadline
            .map_or(MIN_START_TIME, |d| d.max(MIN_START_TIME));
        let sent = stdin.write_all(&self.init).and_then(|()| stdin.flush());
        let answer = match sent {
            Ok(()) => match answers.recv_timeout(start) {
                Ok(a) => Ok(a),
                Err(mpsc::RecvTimeoutError::Timeout) => Err(Lost::TimedOut),
                Err(mpsc::RecvTimeoutError::Disconnected) => Err(Lost::Closed),
            },
            Err(_) => Err(Lost::Closed),
        };
        let answer = match answer {
            Ok(a) => a,
            Err(lost) => {
                let _ = child.kill();
                let status = child.wait();
                return Err(match (lost, status) {
                    (Lost::TimedOut, _) => format!(
                        "{prefix} did not create the instance within {} (killed)",
                        crate::deadline::describe(start)
                    ),
                    (Lost::Closed, Ok(s)) => {
                        format!(
                            "{prefix} died while creating the instance: {}",
                            describe_exit(s)
                        )
                    }
                    (Lost::Closed, Err(e)) => format!("{prefix} died while creating it: {e}"),
                });
            }
        };
        let mut d = Dec::new(&answer);
        let name = match d.u8() {
            Ok(ANSWER_OK) => d.str(),
            Ok(_) => Err(d.str().unwrap_or_else(|e| e)),
            Err(e) => Err(e),
        };
        match name {
            Ok(name) => {
                self.running = Some(Running {
                    child,
                    stdin,
                    answers,
                });
                Ok(name)
            }
            Err(message) => {
                let _ = child.kill();
                let _ = child.wait();
                Err(message)
            }
        }
    }

    /// Kills the helper (if running) and reports how it ended.
    fn stop(&mut self) -> Option<String> {
        let mut r = self.running.take()?;
        let _ = r.child.kill();
        Some(match r.child.wait() {
            Ok(s) => describe_exit(s),
            Err(e) => format!("could not be waited for: {e}"),
        })
    }

    /// Sends the request in `self.enc` (finished) and waits for the answer. The error is the
    /// message of a failed call (a dead or hung process, or one that could not be restarted).
    fn round_trip(&mut self, call: &str) -> Result<Vec<u8>, String> {
        if let Some(dead) = &self.dead {
            return Err(dead.clone());
        }
        if self.running.is_none() {
            // Restart after a failure.
            self.restarts += 1;
            if let Err(e) = self.spawn() {
                return Err(self.give_up(format!("{e} (restart {})", self.restarts)));
            }
        }
        let deadline = self.deadline;
        let Some(r) = self.running.as_mut() else {
            return Err(format!("plugin process for {} is not running", self.what));
        };
        let sent = r
            .stdin
            .write_all(&self.enc.0)
            .and_then(|()| r.stdin.flush());
        let answer = match (sent, deadline) {
            (Err(_), _) => Err(Lost::Closed),
            (Ok(()), Some(d)) => r.answers.recv_timeout(d).map_err(|e| match e {
                mpsc::RecvTimeoutError::Timeout => Lost::TimedOut,
                mpsc::RecvTimeoutError::Disconnected => Lost::Closed,
            }),
            (Ok(()), None) => r.answers.recv().map_err(|_| Lost::Closed),
        };
        match answer {
            Ok(a) => Ok(a),
            Err(lost) => {
                let how = self.stop().unwrap_or_default();
                let what = &self.what;
                let message = match lost {
                    Lost::Closed => {
                        format!("plugin process for {what} died during `{call}`: {how}")
                    }
                    Lost::TimedOut => format!(
                        "plugin process for {what} did not answer `{call}` within {} (killed)",
                        crate::deadline::describe(deadline.unwrap_or_default())
                    ),
                };
                Err(self.after_failure(message))
            }
        }
    }

    /// Adds the restart policy to a failure's message; past the last restart the client is
    /// dead.
    fn after_failure(&mut self, message: String) -> String {
        if self.restarts >= self.max_restarts {
            return self.give_up(message);
        }
        let left = self.max_restarts - self.restarts;
        let message = format!(
            "{message}; a new process is started for the next call ({left} restart{} left)",
            if left == 1 { "" } else { "s" }
        );
        eprintln!("warning: {message}");
        message
    }

    fn give_up(&mut self, message: String) -> String {
        self.stop();
        let message = if self.max_restarts == 0 {
            format!("{message}; the instance is marked dead (an embodiment is not restarted)")
        } else {
            format!(
                "{message}; no restarts left (at most {}): the instance is marked dead",
                self.max_restarts
            )
        };
        eprintln!("warning: {message}");
        self.dead = Some(message.clone());
        message
    }

    /// True once the restarts are used up.
    pub(crate) fn dead(&self) -> Option<&str> {
        self.dead.as_deref()
    }

    /// `reset` of a planner. A failure is recorded (the next call restarts the process).
    pub(crate) fn reset(&mut self) -> Result<(), String> {
        self.enc.start(OP_RESET);
        self.enc.finish();
        let answer = self.round_trip("reset")?;
        let mut d = Dec::new(&answer);
        self.decoded(decode_unit_answer(&mut d))?
    }

    /// `plan`: `Err` for a failed call (dead or hung process), else the planner's answer.
    pub(crate) fn plan(&mut self, obs: &Observation) -> Result<Result<Plan, PlanError>, String> {
        encode_observation(&mut self.enc, obs);
        self.enc.finish();
        let answer = self.round_trip("plan")?;
        let mut d = Dec::new(&answer);
        self.decoded(decode_plan_answer(&mut d))
    }

    /// `evaluate`, adding into `cost` and `grad` on success.
    pub(crate) fn evaluate(
        &mut self,
        batch: TrajBatch<'_>,
        ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<Result<(), ConstraintError>, String> {
        encode_evaluate(&mut self.enc, batch, ctx, cost, grad);
        self.enc.finish();
        let answer = self.round_trip("evaluate")?;
        let mut d = Dec::new(&answer);
        self.decoded(decode_evaluate_answer(&mut d, cost, grad))
    }

    /// A constraint term's declaration `separable_nonnegative` (asked once, after the start).
    pub(crate) fn separable_nonnegative(&mut self) -> Result<bool, String> {
        self.enc.start(OP_PROPERTIES);
        self.enc.finish();
        let answer = self.round_trip("properties")?;
        let mut d = Dec::new(&answer);
        self.decoded(decode_properties_answer(&mut d))
    }

    /// An embodiment call: `Err` for a failed call (a dead or hung process, which marks the
    /// instance dead), else the value and the failure the helper's proxy recorded, if any.
    pub(crate) fn embodiment(
        &mut self,
        call: &EmbodimentCall<'_>,
    ) -> Result<(EmbodimentValue, Option<String>), String> {
        call.encode(&mut self.enc);
        self.enc.finish();
        let answer = self.round_trip(call.name())?;
        let mut d = Dec::new(&answer);
        self.decoded(decode_embodiment_answer(&mut d, call))
    }

    /// A malformed answer is a failed call; the process is restarted for the next one.
    fn decoded<T>(&mut self, r: Result<T, String>) -> Result<T, String> {
        r.map_err(|e| {
            self.stop();
            let message = format!(
                "plugin process for {} sent a malformed answer: {e} (killed)",
                self.what
            );
            self.after_failure(message)
        })
    }
}

impl Drop for ProcessClient {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Creates an instance in a helper process: `Ok((client, instance name))`.
pub(crate) fn start_instance(
    helper: Option<&Path>,
    kind: PluginKind,
    library: &Path,
    factory: &str,
    config: &str,
    robot: Option<&RobotContext>,
    deadline: Option<Duration>,
) -> Result<(ProcessClient, String), PluginError> {
    let instance = format!("{kind} `{factory}` from {}", library.display());
    let process = |message: String| PluginError::Process {
        instance: instance.clone(),
        message,
    };
    let file = crate::locate::resolve_library_path(library)?;
    let file = std::fs::canonicalize(&file).unwrap_or(file);
    let helper = find_helper(helper).map_err(process)?;
    let init = InitRequest {
        kind,
        library: file,
        factory: factory.to_owned(),
        config: config.to_owned(),
        robot: robot.copied(),
    };
    ProcessClient::start(helper, &init, deadline).map_err(process)
}
