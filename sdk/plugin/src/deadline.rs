//! Deadlines on plugin calls: a planner's `plan`/`reset`, a constraint's `evaluate` or an
//! embodiment's `holonomic`, `saturate`, `step`, `track` or `coupled_limit` that does not return
//! in time must not hang the host.
//!
//! A thread stuck inside foreign code cannot be stopped, so the only way for the caller to get
//! control back is not to be that thread. With a deadline, a proxy owns one worker thread for
//! its instance; each call is handed to it together with every buffer the plugin may touch (the
//! observation or batch is copied into buffers the call owns), and the caller waits at most the
//! deadline for the answer. Past the deadline the proxy
//!
//! * marks the instance dead (every later call fails at once, without a thread: nothing piles
//!   up), logs one line on stderr, and lets go of the worker: the worker keeps the instance and
//!   the call's buffers, so a call that does return late writes only into memory it owns, and
//!   the worker then destroys the instance and ends; one that never returns keeps its thread
//!   (and its instance) until the process exits;
//! * a planner returns the safe plan (stop in place: the tracking controller brakes to a stop
//!   within the robot's limits) flagged as a fallback with `PlanInfo::error` set; a constraint
//!   returns an error (guidance then fails and the planner falls back as on any term error); an
//!   embodiment returns the safe value (zero command, the robot halted where it is) and
//!   `PluginEmbodiment::failure` names the call.
//!
//! Without a deadline (`deadline_ms = 0`) calls run on the caller's thread, as before, with no
//! copies. The cost of the deadline is the hand-off to the worker and back (two thread wake-ups)
//! plus the copies; `cargo bench -p human2nav-plugin --bench deadline` measures it per call.
//!
//! Constraint terms: guidance calls a term many times per planning call, possibly from several
//! threads. The same mechanism applies per `evaluate` call (a per-planning-call watchdog could
//! only report a hang, not return control to the planner); calls to one term are then
//! serialised through its worker, and each pays the hand-off. Embodiments too: their calls are
//! microseconds of arithmetic on the simulator's step, but one that sleeps hung `robot check`
//! and `bench`; calls to one embodiment, shared by a benchmark's threads, are serialised through
//! its worker.
//!
//! In a helper process ([`crate::process`]) the deadline is the client's wait for the answer;
//! past it the helper is killed.

use std::sync::mpsc;
use std::time::Duration;

/// The deadline a plugin call gets when its declaration sets none
/// (`deadline_ms` absent): one second, ten replanning periods at the benchmark's 10 Hz.
pub const DEFAULT_DEADLINE: Duration = Duration::from_millis(1000);

/// Longest deadline a declaration may set (one hour).
pub const MAX_DEADLINE_MS: f64 = human2nav_core::robot::MAX_PLUGIN_DEADLINE_MS;

/// The deadline a declaration's `deadline_ms` asks for: absent → [`DEFAULT_DEADLINE`];
/// `0` → no deadline (calls run on the caller's thread); otherwise that many milliseconds
/// (finite, positive, at most [`MAX_DEADLINE_MS`]). The error is a phrase about the value.
pub fn deadline_from_ms(ms: Option<f64>) -> Result<Option<Duration>, String> {
    match ms {
        None => Ok(Some(DEFAULT_DEADLINE)),
        Some(0.0) => Ok(None),
        Some(v) if v.is_finite() && v > 0.0 && v <= MAX_DEADLINE_MS => {
            Ok(Some(Duration::from_secs_f64(v / 1000.0)))
        }
        Some(v) => Err(format!(
            "{v} is not a deadline: give milliseconds in (0, {MAX_DEADLINE_MS}], or 0 for none"
        )),
    }
}

/// A deadline for messages: `250 ms`.
pub(crate) fn describe(d: Duration) -> String {
    let ms = d.as_secs_f64() * 1000.0;
    if ms >= 1.0 {
        format!("{ms:.0} ms")
    } else {
        format!("{ms:.3} ms")
    }
}

/// Why a call through a [`Worker`] gave no answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum NoAnswer {
    /// The deadline passed.
    TimedOut,
    /// The worker thread is gone (it panicked in host code).
    Gone,
}

/// One thread that runs jobs of type `J` for one plugin instance, in order.
pub(crate) struct Worker<J> {
    requests: mpsc::Sender<J>,
    answers: mpsc::Receiver<J>,
}

impl<J> std::fmt::Debug for Worker<J> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Worker")
    }
}

impl<J: Send + 'static> Worker<J> {
    /// Starts the thread; `body` runs each job and owns everything it needs (the instance).
    /// When the worker is dropped the thread finishes its current job, drops `body` and ends.
    pub(crate) fn spawn(
        name: String,
        mut body: impl FnMut(&mut J) + Send + 'static,
    ) -> std::io::Result<Self> {
        let (requests, inbox) = mpsc::channel::<J>();
        let (outbox, answers) = mpsc::channel::<J>();
        std::thread::Builder::new().name(name).spawn(move || {
            while let Ok(mut job) = inbox.recv() {
                body(&mut job);
                if outbox.send(job).is_err() {
                    break;
                }
            }
        })?;
        Ok(Self { requests, answers })
    }

    /// Runs `job` on the worker and waits at most `deadline` for it. On a timeout the job
    /// stays with the worker (the call may still be using its buffers).
    pub(crate) fn call(&self, job: J, deadline: Duration) -> Result<J, NoAnswer> {
        self.requests.send(job).map_err(|_| NoAnswer::Gone)?;
        self.answers.recv_timeout(deadline).map_err(|e| match e {
            mpsc::RecvTimeoutError::Timeout => NoAnswer::TimedOut,
            mpsc::RecvTimeoutError::Disconnected => NoAnswer::Gone,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn deadline_settings() {
        assert_eq!(deadline_from_ms(None), Ok(Some(DEFAULT_DEADLINE)));
        assert_eq!(deadline_from_ms(Some(0.0)), Ok(None));
        assert_eq!(
            deadline_from_ms(Some(250.0)),
            Ok(Some(Duration::from_millis(250)))
        );
        for bad in [-1.0, f64::NAN, f64::INFINITY, 1e12] {
            assert!(deadline_from_ms(Some(bad)).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_worker_answers_in_order_and_times_out_without_losing_memory() {
        let calls = Arc::new(AtomicUsize::new(0));
        let seen = Arc::clone(&calls);
        let w = Worker::spawn("test".into(), move |job: &mut Vec<u64>| {
            if job.first() == Some(&0) {
                std::thread::sleep(Duration::from_millis(300));
            }
            job.push(seen.fetch_add(1, Ordering::SeqCst) as u64);
        })
        .expect("spawn");
        let out = w.call(vec![1], Duration::from_secs(5)).expect("answer");
        assert_eq!(out, vec![1, 0]);
        let started = std::time::Instant::now();
        assert_eq!(
            w.call(vec![0], Duration::from_millis(20)),
            Err(NoAnswer::TimedOut)
        );
        assert!(started.elapsed() < Duration::from_millis(250));
        drop(w);
        // The late job still ran to the end on its own buffer.
        std::thread::sleep(Duration::from_millis(400));
        assert_eq!(calls.load(Ordering::SeqCst), 2);
    }
}
